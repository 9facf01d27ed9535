//! AMIE background removal: the dark/offset level, its large-scale gradient
//! and the scattered-light halo around the Moon, none of which the renderer
//! models. One fixed method, tuned once on image 00208_00030 and used
//! unchanged for every image ([`BackgroundParams::amie`]):
//!
//! 1. **Sky pixels**: farther than `sky_margin_px` outside the Moon's limb
//!    (disk from the scene geometry, preferably after NCC alignment), and
//!    below saturation (drops the hot pixel in the corner).
//! 2. **Dark level + gradient**: a 2-D polynomial of degree 2 in normalised
//!    image coordinates, least-squares fitted to the sky pixels with
//!    iterative κ-σ clipping (σ from the median absolute deviation), which
//!    rejects stars and cosmic-ray hits. AMIE frames show a smooth top-to-bottom
//!    ramp (≈29→47 DN on 00208_00030, ≈51→86 DN on 00101_00010), so a plane
//!    or a single median would leave residuals of ±10 DN.
//! 3. **Scattered light**: the median of the residual (image − polynomial)
//!    in rings of distance from the limb (edges `halo_bins_px`), clamped to
//!    ≥ 0 and forced non-increasing outward; linear in between, 0 beyond the
//!    last ring, and held at its limb value inside the disk.
//! 4. **Subtraction**: image − (polynomial + halo), clipped at 0.
//!
//! The dark level reported is the median of the sky pixels farther than the
//! last halo ring from the limb.

#![allow(clippy::needless_range_loop)] // small fixed-size matrix code reads better with indices

use super::raster::Raster;
use crate::error::{Error, Result};

/// Apparent Moon disk in pixel coordinates (pixel centres at +0.5).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Disk {
    pub cx: f64,
    pub cy: f64,
    pub radius: f64,
}

impl Disk {
    /// Signed distance (px) from the limb: negative inside the disk.
    pub fn limb_distance(&self, x: f64, y: f64) -> f64 {
        (x - self.cx).hypot(y - self.cy) - self.radius
    }
}

/// Tuning of the background model.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct BackgroundParams {
    /// Sky pixels used for the polynomial are at least this far outside the limb.
    pub sky_margin_px: f64,
    /// Pixels at or above this DN are ignored (saturation / hot pixels).
    pub saturation_dn: f32,
    /// κ of the κ-σ clipping.
    pub clip_sigma: f64,
    /// Number of clipping iterations.
    pub clip_iterations: usize,
    /// Ring edges (px from the limb, increasing, starting at 0) of the halo profile.
    pub halo_bins_px: Vec<f64>,
}

impl BackgroundParams {
    /// The one tuning used for every AMIE image.
    pub fn amie() -> Self {
        Self {
            sky_margin_px: 15.0,
            saturation_dn: 1023.0,
            clip_sigma: 3.0,
            clip_iterations: 5,
            halo_bins_px: vec![0.0, 3.0, 6.0, 10.0, 15.0, 25.0, 40.0, 60.0],
        }
    }
}

/// The fitted background.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct BackgroundModel {
    /// Median sky level far from the Moon, DN.
    pub dark_level_dn: f64,
    /// Coefficients of 1, u, v, u², uv, v² with u = 2x/W − 1, v = 2y/H − 1.
    pub poly: [f64; 6],
    /// Robust σ of the sky residuals, DN.
    pub sky_sigma_dn: f64,
    /// Halo profile: (ring centre px from the limb, DN).
    pub halo: Vec<(f64, f64)>,
    /// Number of sky pixels kept by the final clipping pass.
    pub sky_pixels: usize,
    width: usize,
    height: usize,
    disk: Disk,
}

fn basis(x: f64, y: f64, w: usize, h: usize) -> [f64; 6] {
    let u = 2.0 * x / w as f64 - 1.0;
    let v = 2.0 * y / h as f64 - 1.0;
    [1.0, u, v, u * u, u * v, v * v]
}

fn median(v: &mut [f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    let n = v.len();
    Some(if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    })
}

fn solve6(mut a: [[f64; 6]; 6], mut b: [f64; 6]) -> Option<[f64; 6]> {
    for col in 0..6 {
        let piv = (col..6).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        if a[piv][col].abs() < 1e-12 {
            return None;
        }
        a.swap(col, piv);
        b.swap(col, piv);
        for r in col + 1..6 {
            let f = a[r][col] / a[col][col];
            for c in col..6 {
                a[r][c] -= f * a[col][c];
            }
            b[r] -= f * b[col];
        }
    }
    let mut x = [0.0; 6];
    for r in (0..6).rev() {
        let s: f64 = (r + 1..6).map(|c| a[r][c] * x[c]).sum();
        x[r] = (b[r] - s) / a[r][r];
    }
    Some(x)
}

impl BackgroundModel {
    /// Fits the model to `img` given the Moon's disk.
    pub fn fit(img: &Raster, disk: Disk, p: &BackgroundParams) -> Result<Self> {
        let (w, h) = (img.width, img.height);
        if p.halo_bins_px.len() < 2 || p.halo_bins_px.windows(2).any(|b| b[1] <= b[0]) {
            return Err(Error::invalid(
                "background.halo_bins_px",
                "need at least two increasing ring edges",
            ));
        }
        let mut sky = vec![];
        for r in 0..h {
            for c in 0..w {
                let (x, y) = (c as f64 + 0.5, r as f64 + 0.5);
                let v = img.get(c, r);
                if v.is_finite()
                    && v < p.saturation_dn
                    && disk.limb_distance(x, y) > p.sky_margin_px
                {
                    sky.push((x, y, v as f64));
                }
            }
        }
        if sky.len() < 100 {
            return Err(Error::invalid(
                "background",
                format!("only {} sky pixels outside the disk", sky.len()),
            ));
        }
        let mut keep = vec![true; sky.len()];
        let mut poly = [0.0; 6];
        let mut sigma = 0.0;
        for _ in 0..=p.clip_iterations {
            let (mut ata, mut atb) = ([[0.0; 6]; 6], [0.0; 6]);
            for (k, &(x, y, v)) in sky.iter().enumerate() {
                if keep[k] {
                    let b = basis(x, y, w, h);
                    for i in 0..6 {
                        for j in 0..6 {
                            ata[i][j] += b[i] * b[j];
                        }
                        atb[i] += b[i] * v;
                    }
                }
            }
            poly = solve6(ata, atb).ok_or_else(|| {
                Error::invalid(
                    "background",
                    "singular sky fit (sky pixels too few or collinear)",
                )
            })?;
            let res: Vec<f64> = sky
                .iter()
                .map(|&(x, y, v)| v - eval(&poly, x, y, w, h))
                .collect();
            let mut kept: Vec<f64> = res
                .iter()
                .zip(&keep)
                .filter(|(_, &k)| k)
                .map(|(r, _)| r.abs())
                .collect();
            sigma = 1.4826 * median(&mut kept).unwrap_or(0.0);
            let lim = p.clip_sigma * sigma.max(1e-6);
            for (k, r) in res.iter().enumerate() {
                keep[k] = r.abs() <= lim;
            }
        }
        let sky_pixels = keep.iter().filter(|&&k| k).count();

        // Halo: residual medians in rings outside the limb.
        let edges = &p.halo_bins_px;
        let nb = edges.len() - 1;
        let mut rings: Vec<Vec<f64>> = vec![vec![]; nb];
        let mut far = vec![];
        let last = *edges.last().expect("edges");
        for r in 0..h {
            for c in 0..w {
                let (x, y) = (c as f64 + 0.5, r as f64 + 0.5);
                let v = img.get(c, r);
                if !v.is_finite() || v >= p.saturation_dn {
                    continue;
                }
                let d = disk.limb_distance(x, y);
                if d >= last {
                    far.push(v as f64);
                } else if d >= edges[0] {
                    let i = edges
                        .windows(2)
                        .position(|e| d >= e[0] && d < e[1])
                        .expect("inside the rings");
                    rings[i].push(v as f64 - eval(&poly, x, y, w, h));
                }
            }
        }
        let mut halo = Vec::with_capacity(nb);
        let mut prev = f64::INFINITY;
        for (i, ring) in rings.iter_mut().enumerate() {
            let m = median(ring).unwrap_or(0.0).max(0.0).min(prev);
            prev = m;
            halo.push((0.5 * (edges[i] + edges[i + 1]), m));
        }
        let dark = median(&mut far)
            .or_else(|| median(&mut sky.iter().map(|s| s.2).collect::<Vec<_>>()))
            .unwrap_or(0.0);
        Ok(Self {
            dark_level_dn: dark,
            poly,
            sky_sigma_dn: sigma,
            halo,
            sky_pixels,
            width: w,
            height: h,
            disk,
        })
    }

    /// Halo value at signed limb distance `d` (px).
    pub fn halo_at(&self, d: f64) -> f64 {
        let h = &self.halo;
        if h.is_empty() {
            return 0.0;
        }
        if d <= h[0].0 {
            return h[0].1;
        }
        for win in h.windows(2) {
            let ((d0, v0), (d1, v1)) = (win[0], win[1]);
            if d <= d1 {
                return v0 + (v1 - v0) * (d - d0) / (d1 - d0);
            }
        }
        // Beyond the last ring centre, fall linearly to 0 over one ring width.
        let (dl, vl) = *h.last().expect("non-empty");
        let width = if h.len() > 1 {
            dl - h[h.len() - 2].0
        } else {
            1.0
        };
        (vl * (1.0 - (d - dl) / width)).max(0.0)
    }

    /// Background (DN) at pixel coordinates (x, y).
    pub fn at(&self, x: f64, y: f64) -> f64 {
        eval(&self.poly, x, y, self.width, self.height)
            + self.halo_at(self.disk.limb_distance(x, y))
    }

    /// The model as an image.
    pub fn render(&self) -> Raster {
        Raster::from_fn(self.width, self.height, |c, r| {
            self.at(c as f64 + 0.5, r as f64 + 0.5) as f32
        })
    }
}

fn eval(p: &[f64; 6], x: f64, y: f64, w: usize, h: usize) -> f64 {
    basis(x, y, w, h).iter().zip(p).map(|(b, c)| b * c).sum()
}

/// Fits the background of `img` and returns `max(img − background, 0)`
/// with the model.
pub fn remove_background(
    img: &Raster,
    disk: Disk,
    p: &BackgroundParams,
) -> Result<(Raster, BackgroundModel)> {
    let model = BackgroundModel::fit(img, disk, p)?;
    let out = Raster::from_fn(img.width, img.height, |c, r| {
        let v = img.get(c, r) as f64 - model.at(c as f64 + 0.5, r as f64 + 0.5);
        v.max(0.0) as f32
    });
    Ok((out, model))
}
