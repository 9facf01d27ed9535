//! The smooth model screen (u, v) → (tan_x, tan_y) and its robust fit.
//!
//! Model: a homography H (the screen plane's position, rotation and tilt
//! seen through an ideal collimator) followed by a radial distortion about a
//! fitted centre c (the collimator's):
//!
//! ```text
//! q = H(s),  s = ((u − w/2) / n, (v − h/2) / n),  n = max(w, h) / 2
//! t = c + (q − c) · (1 + k1 ρ² + k2 ρ⁴),  ρ = |q − c| / T
//! ```
//!
//! with T a fixed tangent scale (the RMS radius of the measured directions)
//! so that k1, k2 are of order one. Optionally a correction
//! Σ a_jk P_j(x) P_k(y) of total degree ≤ d in Legendre polynomials of
//! x = 2u/w − 1, y = 2v/h − 1 is fitted to the residuals of the parametric
//! model by linear least squares, for what the model does not capture.
//!
//! The 12 parameters (H with h₂₂ = 1, c, k1, k2) are fitted by
//! Levenberg–Marquardt from a direct linear (DLT) homography; outliers are
//! rejected by iterative clipping at `clip_sigma` times the per-axis RMS
//! residual, and the fit repeated until the inlier set is stable.

use crate::error::{Error, Result};

/// Number of parametric model parameters.
const NPARAM: usize = 12;

/// Most clipping rounds.
const MAX_CLIP_ROUNDS: usize = 10;

/// The fitted map screen → direction.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ScreenModel {
    /// Screen size `(w, h)`, pixels.
    pub screen: (usize, usize),
    /// Tangent scale T of the distortion terms.
    pub tan_scale: f64,
    /// h00 h01 h02 h10 h11 h12 h20 h21 (h22 = 1), on normalised screen
    /// coordinates; then the distortion centre (tan_x, tan_y); k1, k2.
    pub params: Vec<f64>,
    /// Total degree of the Legendre correction (0: none).
    pub correction_degree: usize,
    /// Correction coefficients for tan_x and tan_y, in [`basis`] order.
    pub correction: [Vec<f64>; 2],
}

impl ScreenModel {
    fn normalised(&self, u: f64, v: f64) -> [f64; 2] {
        let (w, h) = (self.screen.0 as f64, self.screen.1 as f64);
        let n = 0.5 * w.max(h);
        [(u - 0.5 * w) / n, (v - 0.5 * h) / n]
    }

    /// Direction of screen position (u, v).
    pub fn direction(&self, u: f64, v: f64) -> [f64; 2] {
        let mut t = parametric(&self.params, self.normalised(u, v), self.tan_scale);
        if self.correction_degree > 0 {
            let b = basis(self.correction_degree, self.legendre_xy(u, v));
            for (axis, c) in self.correction.iter().enumerate() {
                t[axis] += b.iter().zip(c).map(|(x, y)| x * y).sum::<f64>();
            }
        }
        t
    }

    fn legendre_xy(&self, u: f64, v: f64) -> [f64; 2] {
        [
            2.0 * u / self.screen.0 as f64 - 1.0,
            2.0 * v / self.screen.1 as f64 - 1.0,
        ]
    }

    /// Distortion coefficients in plain tangent units:
    /// `(1 + k1 r² + k2 r⁴)` with r = |q − c|.
    pub fn radial_coefficients(&self) -> [f64; 2] {
        let t2 = self.tan_scale * self.tan_scale;
        [self.params[10] / t2, self.params[11] / (t2 * t2)]
    }
}

/// The parametric model at normalised screen coordinates `s`.
fn parametric(p: &[f64], s: [f64; 2], tan_scale: f64) -> [f64; 2] {
    let den = p[6] * s[0] + p[7] * s[1] + 1.0;
    let q = [
        (p[0] * s[0] + p[1] * s[1] + p[2]) / den,
        (p[3] * s[0] + p[4] * s[1] + p[5]) / den,
    ];
    let (dx, dy) = (q[0] - p[8], q[1] - p[9]);
    let rho2 = (dx * dx + dy * dy) / (tan_scale * tan_scale);
    let g = 1.0 + rho2 * (p[10] + rho2 * p[11]);
    [p[8] + dx * g, p[9] + dy * g]
}

/// Legendre products P_j(x) P_k(y), j + k ≤ degree, in order of j then k.
pub fn basis(degree: usize, xy: [f64; 2]) -> Vec<f64> {
    let legendre = |x: f64| {
        let mut p = vec![1.0, x];
        for n in 1..degree {
            let nf = n as f64;
            p.push(((2.0 * nf + 1.0) * x * p[n] - nf * p[n - 1]) / (nf + 1.0));
        }
        p
    };
    let (px, py) = (legendre(xy[0]), legendre(xy[1]));
    let mut out = Vec::new();
    for (j, pj) in px.iter().enumerate().take(degree + 1) {
        for pk in py.iter().take(degree + 1 - j) {
            out.push(pj * pk);
        }
    }
    out
}

/// Solves the square system `a x = b` (row-major `n × n`) by Gaussian
/// elimination with partial pivoting. None when singular.
pub fn solve(mut a: Vec<f64>, mut b: Vec<f64>) -> Option<Vec<f64>> {
    let n = b.len();
    let scale = a.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    for col in 0..n {
        let piv =
            (col..n).max_by(|&i, &j| a[i * n + col].abs().total_cmp(&a[j * n + col].abs()))?;
        if !(a[piv * n + col].abs() > 1e-14 * scale) {
            return None;
        }
        if piv != col {
            for k in 0..n {
                a.swap(piv * n + k, col * n + k);
            }
            b.swap(piv, col);
        }
        for row in col + 1..n {
            let f = a[row * n + col] / a[col * n + col];
            for k in col..n {
                a[row * n + k] -= f * a[col * n + k];
            }
            b[row] -= f * b[col];
        }
    }
    let mut x = vec![0.0; n];
    for row in (0..n).rev() {
        let s: f64 = (row + 1..n).map(|k| a[row * n + k] * x[k]).sum();
        x[row] = (b[row] - s) / a[row * n + row];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Linear least squares `min |X c − y|` by the normal equations
/// (`rows` of length `m`).
fn least_squares(rows: &[Vec<f64>], y: &[f64]) -> Option<Vec<f64>> {
    let m = rows.first()?.len();
    let mut a = vec![0.0; m * m];
    let mut b = vec![0.0; m];
    for (r, &yi) in rows.iter().zip(y) {
        for i in 0..m {
            b[i] += r[i] * yi;
            for j in 0..m {
                a[i * m + j] += r[i] * r[j];
            }
        }
    }
    solve(a, b)
}

/// Homography `s → t` from ≥ 4 correspondences by the direct linear method
/// (h22 = 1, targets normalised for conditioning). Entries as in
/// [`ScreenModel::params`].
pub fn homography(s: &[[f64; 2]], t: &[[f64; 2]]) -> Option<[f64; 8]> {
    if s.len() < 4 {
        return None;
    }
    let n = t.len() as f64;
    let m = [
        t.iter().map(|p| p[0]).sum::<f64>() / n,
        t.iter().map(|p| p[1]).sum::<f64>() / n,
    ];
    let sc = (t
        .iter()
        .map(|p| (p[0] - m[0]).powi(2) + (p[1] - m[1]).powi(2))
        .sum::<f64>()
        / n)
        .sqrt();
    if !(sc > 0.0) {
        return None;
    }
    let (mut rows, mut y) = (Vec::new(), Vec::new());
    for (a, b) in s.iter().zip(t) {
        let (x, yy) = (a[0], a[1]);
        let (bx, by) = ((b[0] - m[0]) / sc, (b[1] - m[1]) / sc);
        rows.push(vec![x, yy, 1.0, 0.0, 0.0, 0.0, -x * bx, -yy * bx]);
        y.push(bx);
        rows.push(vec![0.0, 0.0, 0.0, x, yy, 1.0, -x * by, -yy * by]);
        y.push(by);
    }
    let h = least_squares(&rows, &y)?;
    Some([
        sc * h[0] + m[0] * h[6],
        sc * h[1] + m[0] * h[7],
        sc * h[2] + m[0],
        sc * h[3] + m[1] * h[6],
        sc * h[4] + m[1] * h[7],
        sc * h[5] + m[1],
        h[6],
        h[7],
    ])
}

/// Evaluates a bare homography on normalised coordinates.
pub fn apply_homography(h: &[f64; 8], s: [f64; 2]) -> [f64; 2] {
    let den = h[6] * s[0] + h[7] * s[1] + 1.0;
    [
        (h[0] * s[0] + h[1] * s[1] + h[2]) / den,
        (h[3] * s[0] + h[4] * s[1] + h[5]) / den,
    ]
}

/// Normalised screen coordinates of (u, v) on a `screen`, as the model uses.
pub fn normalise(screen: (usize, usize), u: f64, v: f64) -> [f64; 2] {
    let (w, h) = (screen.0 as f64, screen.1 as f64);
    let n = 0.5 * w.max(h);
    [(u - 0.5 * w) / n, (v - 0.5 * h) / n]
}

/// Settings of [`fit`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FitSettings {
    /// Reject points beyond this many per-axis RMS residuals.
    pub clip_sigma: f64,
    /// Never reject a point closer than this (tangent units): a noise-free
    /// fit's residuals are rounding, not outliers.
    pub floor: f64,
    /// Total degree of the Legendre correction (0: none).
    pub correction_degree: usize,
}

/// A fitted model and which points it kept.
#[derive(Debug, Clone)]
pub struct Fit {
    pub model: ScreenModel,
    /// Per input point: kept by the clipping.
    pub inlier: Vec<bool>,
    /// Per input point: measured minus modelled direction.
    pub residual: Vec<[f64; 2]>,
}

/// Fits the model to screen positions `uv` and measured directions `tan`.
pub fn fit(
    screen: (usize, usize),
    uv: &[[f64; 2]],
    tan: &[[f64; 2]],
    settings: &FitSettings,
) -> Result<Fit> {
    let n_corr = if settings.correction_degree > 0 {
        basis(settings.correction_degree, [0.0, 0.0]).len()
    } else {
        0
    };
    let needed = (NPARAM + n_corr).div_ceil(2) + 2;
    if uv.len() < needed {
        return Err(Error::Other(format!(
            "geometric fit: {} dots for {} parameters (at least {needed} dots needed)",
            uv.len(),
            NPARAM + 2 * n_corr
        )));
    }
    let s: Vec<[f64; 2]> = uv.iter().map(|p| normalise(screen, p[0], p[1])).collect();
    let h = homography(&s, tan)
        .ok_or_else(|| Error::Other("geometric fit: degenerate dot positions".into()))?;
    let n = tan.len() as f64;
    let mean = [
        tan.iter().map(|t| t[0]).sum::<f64>() / n,
        tan.iter().map(|t| t[1]).sum::<f64>() / n,
    ];
    let tan_scale = (tan
        .iter()
        .map(|t| (t[0] - mean[0]).powi(2) + (t[1] - mean[1]).powi(2))
        .sum::<f64>()
        / n)
        .sqrt();
    let centre = apply_homography(&h, [0.0, 0.0]);
    let mut params: Vec<f64> = h.to_vec();
    params.extend([centre[0], centre[1], 0.0, 0.0]);
    let mut model = ScreenModel {
        screen,
        tan_scale,
        params,
        correction_degree: settings.correction_degree,
        correction: [vec![0.0; n_corr], vec![0.0; n_corr]],
    };
    let mut inlier = vec![true; uv.len()];
    for _ in 0..MAX_CLIP_ROUNDS {
        let idx: Vec<usize> = (0..uv.len()).filter(|&i| inlier[i]).collect();
        if idx.len() < needed {
            return Err(Error::Other(format!(
                "geometric fit: only {} of {} dots left after outlier rejection (at least {needed} needed)",
                idx.len(),
                uv.len()
            )));
        }
        let si: Vec<[f64; 2]> = idx.iter().map(|&i| s[i]).collect();
        let ti: Vec<[f64; 2]> = idx.iter().map(|&i| tan[i]).collect();
        model.params = levenberg_marquardt(&model.params, &si, &ti, tan_scale);
        if n_corr > 0 {
            model.correction = [vec![0.0; n_corr], vec![0.0; n_corr]];
            fit_correction(&mut model, &idx, uv, tan)?;
        }
        let residual = residuals(&model, uv, tan);
        let ss: f64 = idx
            .iter()
            .map(|&i| residual[i][0].powi(2) + residual[i][1].powi(2))
            .sum();
        let rms_axis = (ss / (2.0 * idx.len() as f64)).sqrt();
        let limit = (settings.clip_sigma * rms_axis).max(settings.floor);
        let next: Vec<bool> = residual.iter().map(|r| r[0].hypot(r[1]) <= limit).collect();
        if next == inlier {
            return Ok(Fit {
                model,
                inlier,
                residual,
            });
        }
        inlier = next;
    }
    let residual = residuals(&model, uv, tan);
    Ok(Fit {
        model,
        inlier,
        residual,
    })
}

fn residuals(model: &ScreenModel, uv: &[[f64; 2]], tan: &[[f64; 2]]) -> Vec<[f64; 2]> {
    uv.iter()
        .zip(tan)
        .map(|(p, t)| {
            let m = model.direction(p[0], p[1]);
            [t[0] - m[0], t[1] - m[1]]
        })
        .collect()
}

/// Least-squares Legendre correction of the parametric residuals of the
/// points `idx`.
fn fit_correction(
    model: &mut ScreenModel,
    idx: &[usize],
    uv: &[[f64; 2]],
    tan: &[[f64; 2]],
) -> Result<()> {
    let d = model.correction_degree;
    let rows: Vec<Vec<f64>> = idx
        .iter()
        .map(|&i| basis(d, model.legendre_xy(uv[i][0], uv[i][1])))
        .collect();
    for axis in [0, 1] {
        let y: Vec<f64> = idx
            .iter()
            .map(|&i| {
                let s = model.normalised(uv[i][0], uv[i][1]);
                tan[i][axis] - parametric(&model.params, s, model.tan_scale)[axis]
            })
            .collect();
        model.correction[axis] = least_squares(&rows, &y).ok_or_else(|| {
            Error::Other(format!(
                "geometric fit: the dots do not constrain a degree-{d} correction \
                 (too few or too clustered; lower correction_degree)"
            ))
        })?;
    }
    Ok(())
}

/// Sum of squared residuals of parameters `p`.
fn cost(p: &[f64], s: &[[f64; 2]], t: &[[f64; 2]], tan_scale: f64) -> f64 {
    s.iter()
        .zip(t)
        .map(|(si, ti)| {
            let m = parametric(p, *si, tan_scale);
            (m[0] - ti[0]).powi(2) + (m[1] - ti[1]).powi(2)
        })
        .sum()
}

/// Levenberg–Marquardt on the parametric model, Jacobian by central
/// differences, Marquardt's diagonal scaling (floored, so parameters the
/// data do not yet constrain, such as the distortion centre while k1 = k2
/// = 0, stay put instead of making the system singular).
fn levenberg_marquardt(p0: &[f64], s: &[[f64; 2]], t: &[[f64; 2]], tan_scale: f64) -> Vec<f64> {
    let mut p = p0.to_vec();
    let mut c = cost(&p, s, t, tan_scale);
    let mut lambda = 1e-3;
    for _ in 0..200 {
        let (a, g) = normal_equations(&p, s, t, tan_scale);
        let dmax = (0..NPARAM).map(|j| a[j * NPARAM + j]).fold(0.0, f64::max);
        let mut improved = false;
        while lambda < 1e12 {
            let mut damped = a.clone();
            for j in 0..NPARAM {
                damped[j * NPARAM + j] += lambda * a[j * NPARAM + j].max(1e-9 * dmax);
            }
            let neg_g: Vec<f64> = g.iter().map(|v| -v).collect();
            let Some(step) = solve(damped, neg_g) else {
                lambda *= 10.0;
                continue;
            };
            let trial: Vec<f64> = p.iter().zip(&step).map(|(a, b)| a + b).collect();
            let ct = cost(&trial, s, t, tan_scale);
            if ct < c {
                let gain = (c - ct) / c.max(f64::MIN_POSITIVE);
                p = trial;
                c = ct;
                lambda = (lambda / 3.0).max(1e-12);
                improved = gain > 1e-14;
                break;
            }
            lambda *= 4.0;
        }
        if !improved {
            break;
        }
    }
    p
}

/// JᵀJ and Jᵀr of the parametric residuals at `p`.
fn normal_equations(
    p: &[f64],
    s: &[[f64; 2]],
    t: &[[f64; 2]],
    tan_scale: f64,
) -> (Vec<f64>, Vec<f64>) {
    const STEP: f64 = 1e-7;
    let mut a = vec![0.0; NPARAM * NPARAM];
    let mut g = vec![0.0; NPARAM];
    let mut pp = p.to_vec();
    for (si, ti) in s.iter().zip(t) {
        let m = parametric(p, *si, tan_scale);
        let r = [m[0] - ti[0], m[1] - ti[1]];
        let mut jac = [[0.0; NPARAM]; 2];
        for j in 0..NPARAM {
            pp[j] = p[j] + STEP;
            let up = parametric(&pp, *si, tan_scale);
            pp[j] = p[j] - STEP;
            let down = parametric(&pp, *si, tan_scale);
            pp[j] = p[j];
            jac[0][j] = (up[0] - down[0]) / (2.0 * STEP);
            jac[1][j] = (up[1] - down[1]) / (2.0 * STEP);
        }
        for row in 0..2 {
            for i in 0..NPARAM {
                g[i] += jac[row][i] * r[row];
                for j in 0..NPARAM {
                    a[i * NPARAM + j] += jac[row][i] * jac[row][j];
                }
            }
        }
    }
    (a, g)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solve_matches_a_hand_solution() {
        // y = 1, 2x + y = 5, x − 3y + z = 0 → (2, 1, 1); the first pivot is 0.
        let x = solve(
            vec![0.0, 1.0, 0.0, 2.0, 1.0, 0.0, 1.0, -3.0, 1.0],
            vec![1.0, 5.0, 0.0],
        );
        let x = x.unwrap();
        assert!(
            (x[0] - 2.0).abs() < 1e-12 && (x[1] - 1.0).abs() < 1e-12 && (x[2] - 1.0).abs() < 1e-12
        );
        assert!(solve(vec![1.0, 2.0, 2.0, 4.0], vec![1.0, 2.0]).is_none());
    }

    #[test]
    fn legendre_basis_is_orthogonal_on_a_fine_grid() {
        // ∫∫ P_a P_b over [-1,1]² vanishes for different products.
        let n = 400;
        let d = 3;
        let m = basis(d, [0.0, 0.0]).len();
        let mut gram = vec![0.0; m * m];
        for i in 0..n {
            for j in 0..n {
                let xy = [
                    (i as f64 + 0.5) / n as f64 * 2.0 - 1.0,
                    (j as f64 + 0.5) / n as f64 * 2.0 - 1.0,
                ];
                let b = basis(d, xy);
                for a in 0..m {
                    for c in 0..m {
                        gram[a * m + c] += b[a] * b[c];
                    }
                }
            }
        }
        for a in 0..m {
            for c in 0..m {
                if a != c {
                    assert!(gram[a * m + c].abs() < 1e-3 * gram[a * m + a], "{a},{c}");
                }
            }
        }
    }

    #[test]
    fn recovers_a_homography_with_radial_distortion() {
        let screen = (640, 480);
        // The truth, written independently: rotate, scale, tilt, then
        // distort about an off-centre point.
        let truth = |u: f64, v: f64| {
            let (x, y) = ((u - 330.0) * 2e-4, (v - 236.0) * 2e-4);
            let (c, s) = (0.01f64.cos(), 0.01f64.sin());
            let (x, y) = (c * x - s * y, s * x + c * y);
            let den = 1.0 + 0.02 * x - 0.01 * y;
            let (x, y) = (x / den, y / den);
            let (dx, dy) = (x - 0.002, y + 0.001);
            let r2 = dx * dx + dy * dy;
            let g = 1.0 + 0.4 * r2 + 3.0 * r2 * r2;
            [0.002 + dx * g, -0.001 + dy * g]
        };
        let mut uv = Vec::new();
        for j in 0..15 {
            for i in 0..20 {
                uv.push([16.0 + 32.0 * i as f64, 16.0 + 32.0 * j as f64]);
            }
        }
        let mut tan: Vec<[f64; 2]> = uv.iter().map(|p| truth(p[0], p[1])).collect();
        // Two gross outliers.
        tan[17][0] += 1e-3;
        tan[200][1] -= 5e-4;
        let f = fit(
            screen,
            &uv,
            &tan,
            &FitSettings {
                clip_sigma: 3.5,
                floor: 1e-9,
                correction_degree: 0,
            },
        )
        .unwrap();
        assert!(!f.inlier[17] && !f.inlier[200]);
        assert_eq!(f.inlier.iter().filter(|&&b| !b).count(), 2);
        for (u, v) in [(0.0, 0.0), (640.0, 480.0), (100.0, 400.0), (320.0, 240.0)] {
            let (a, b) = (f.model.direction(u, v), truth(u, v));
            assert!(
                (a[0] - b[0]).hypot(a[1] - b[1]) < 1e-9,
                "({u},{v}): {a:?} {b:?}"
            );
        }
    }
}
