//! The flat-field calibration: the per-screen-pixel gain map that
//! `calibration.flat_field` holds (the ratio of each screen pixel's radiance
//! to the LUT radiance at the same drive level; see
//! [`facility::lut`](crate::facility::lut)), and its uniformity.
//!
//! Method (docs/CALIBRATION.md): for each configured uniform level the
//! camera images the screen (exposure auto-ranged on the whole frame). Each
//! camera pixel is mapped to the screen position it sees — its direction
//! from the camera intrinsics, then the inverse of the geometric calibration
//! (screen (u, v) → direction), found by Newton iterations from an affine
//! guess. The camera's own response is divided out: its flat (vignetting ×
//! PRNU, a TIFF from the camera's calibration) and the pixel's etendue
//! relative to the mean (|∂tan/∂px| / (1 + tan²)², the cos⁴ law with the
//! pixel's solid angle). The remaining signal is the screen's radiance
//! pattern; a 2-D polynomial of low degree in (u, v) is fitted to it by
//! least squares (smoothing the camera's noise and residual PRNU), and
//! normalised to mean 1 over the screen area the radiometric calibration
//! measured (its camera region), because the LUT holds that area's mean.
//! Levels are averaged. Outside the area the camera sees, the gain is the
//! value at the nearest point of that area.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::checkpoint::Checkpoint;
use super::config::CalibrateConfig;
use super::{progress, show_level, AutoExposure, Instruments, Rect};
use crate::error::{Error, Result};
use crate::facility::geometry::GeometryCalibration;
use crate::figures::{heatmap, Heatmap};

/// Name of the routine in checkpoints and reports.
pub const ROUTINE: &str = "flat";

/// What the routine needs besides the instruments.
pub struct FlatSetup<'a> {
    pub cfg: &'a CalibrateConfig,
    pub bits: u32,
    pub screen: (usize, usize),
    /// Camera pixel position (continuous, centres at +0.5) → direction
    /// (tan_x, tan_y) in the camera frame: the intrinsics, undistorted.
    pub pixel_direction: &'a (dyn Fn(f64, f64) -> (f64, f64) + Sync),
    /// Screen (u, v) → direction: the geometric calibration.
    pub geometry: &'a GeometryCalibration,
    /// The camera's own flat (vignetting × PRNU), camera size, mean ~1.
    pub camera_flat: Option<Vec<f32>>,
}

/// One level's fit, as checkpointed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LevelFit {
    pub level: u32,
    pub exposure_s: f64,
    /// Polynomial coefficients, normalised to mean 1 over the reference area.
    pub coefficients: Vec<f64>,
    /// RMS of the pixels about the fit, % (noise and unremoved PRNU).
    pub fit_rms_percent: f64,
    pub pixels: usize,
    /// The measured screen over the polynomial, per cell of
    /// `calibrate.flat.residual_cell_px` screen px (row-major; 1 where no
    /// camera pixel sees the cell): the mura no low-order fit holds.
    #[serde(default)]
    pub residual: Vec<f32>,
}

/// The report.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FlatReport {
    pub levels: Vec<LevelFit>,
    pub degree: usize,
    /// Screen area the camera sees: `[u0, v0, u1, v1]`, px.
    pub seen: [f64; 4],
    pub min_gain: f64,
    pub max_gain: f64,
    /// The 13 points (u, v, gain) and 100·(1 − min/max) over them.
    pub points_13: Vec<(f64, f64, f64)>,
    pub nonuniformity_13_percent: f64,
    /// Largest difference between the levels' gain maps over the seen area, %.
    pub level_disagreement_percent: f64,
    /// Expanded uncertainty (k = 2) of the gain over the seen area, %: the
    /// levels' disagreement and 2 × the fit's standard error (fit RMS ×
    /// √(terms / pixels)) of the worst level, in quadrature. Relative to
    /// the radiometric region (the LUT's scale is the LUT's uncertainty).
    #[serde(default)]
    pub uncertainty_k2_percent: f64,
    pub camera_flat: bool,
    /// Side [screen px] of the residual cells kept beyond the polynomial
    /// (the mura), and the Wiener factor they were shrunk by (0: the camera
    /// could not tell them from its noise); None without them.
    #[serde(default)]
    pub residual_cell_px: Option<usize>,
    #[serde(default)]
    pub residual_gain: Option<f64>,
}

/// Polynomial terms s^a t^b with a + b ≤ degree.
fn terms(degree: usize) -> Vec<(i32, i32)> {
    let mut t = Vec::new();
    for total in 0..=degree as i32 {
        for a in (0..=total).rev() {
            t.push((a, total - a));
        }
    }
    t
}

/// A 2-D polynomial in normalised screen coordinates s = 2u/W − 1,
/// t = 2v/H − 1.
#[derive(Debug, Clone)]
pub struct Poly {
    terms: Vec<(i32, i32)>,
    pub coefficients: Vec<f64>,
    screen: (f64, f64),
}

impl Poly {
    fn new(degree: usize, coefficients: Vec<f64>, screen: (usize, usize)) -> Poly {
        Poly {
            terms: terms(degree),
            coefficients,
            screen: (screen.0 as f64, screen.1 as f64),
        }
    }

    fn basis(&self, u: f64, v: f64, out: &mut [f64]) {
        let s = 2.0 * u / self.screen.0 - 1.0;
        let t = 2.0 * v / self.screen.1 - 1.0;
        for (o, &(a, b)) in out.iter_mut().zip(&self.terms) {
            *o = s.powi(a) * t.powi(b);
        }
    }

    /// Value at screen position (u, v).
    pub fn eval(&self, u: f64, v: f64) -> f64 {
        let mut b = vec![0.0; self.terms.len()];
        self.basis(u, v, &mut b);
        b.iter().zip(&self.coefficients).map(|(x, c)| x * c).sum()
    }
}

/// Camera pixel → screen position, with the pixel's relative etendue.
struct PixelMap {
    /// Camera frame width, px.
    width: usize,
    /// Per camera pixel: screen (u, v) if the pixel sees the screen.
    screen: Vec<Option<(f64, f64)>>,
    /// Per camera pixel: etendue relative to the mean.
    etendue: Vec<f64>,
    seen: [f64; 4],
}

/// One camera row: screen positions and etendues.
type RowMap = (Vec<Option<(f64, f64)>>, Vec<f64>);

fn pixel_map(setup: &FlatSetup, width: usize, height: usize) -> Result<PixelMap> {
    let inv = Inverse::new(setup.geometry)?;
    let dir = setup.pixel_direction;
    let rows: Vec<RowMap> = (0..height)
        .into_par_iter()
        .map(|j| {
            let mut s = Vec::with_capacity(width);
            let mut e = Vec::with_capacity(width);
            for i in 0..width {
                let (x, y) = (i as f64 + 0.5, j as f64 + 0.5);
                let (tx, ty) = dir(x, y);
                s.push(inv.screen_of(tx, ty));
                let (ax, ay) = dir(x + 0.5, y);
                let (bx, by) = dir(x - 0.5, y);
                let (cx, cy) = dir(x, y + 0.5);
                let (dx, dy) = dir(x, y - 0.5);
                let jac = ((ax - bx) * (cy - dy) - (ay - by) * (cx - dx)).abs();
                let r2 = 1.0 + tx * tx + ty * ty;
                e.push(jac / (r2 * r2));
            }
            (s, e)
        })
        .collect();
    let mut all = Vec::with_capacity(width * height);
    let mut etendue = Vec::with_capacity(width * height);
    for (s, e) in rows {
        all.extend(s);
        etendue.extend(e);
    }
    // A pixel at the screen's edge also sees the bezel: use only pixels
    // whose four neighbours see the screen too.
    let screen: Vec<Option<(f64, f64)>> = (0..width * height)
        .map(|k| {
            let (i, j) = (k % width, k / width);
            let inside = i > 0
                && j > 0
                && i + 1 < width
                && j + 1 < height
                && [k - 1, k + 1, k - width, k + width]
                    .iter()
                    .all(|&n| all[n].is_some());
            if inside {
                all[k]
            } else {
                None
            }
        })
        .collect();
    let mean = etendue.iter().sum::<f64>() / etendue.len() as f64;
    if !(mean.is_finite() && mean > 0.0) {
        return Err(Error::Other(
            "camera intrinsics give no valid pixel directions".into(),
        ));
    }
    for e in &mut etendue {
        *e /= mean;
    }
    let mut seen = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for (u, v) in screen.iter().flatten() {
        seen = [
            seen[0].min(*u),
            seen[1].min(*v),
            seen[2].max(*u),
            seen[3].max(*v),
        ];
    }
    if !(seen[2] > seen[0] && seen[3] > seen[1]) {
        return Err(Error::Other(
            "the camera sees none of the screen through the geometric calibration".into(),
        ));
    }
    Ok(PixelMap {
        width,
        screen,
        etendue,
        seen,
    })
}

/// Inverse of the geometric calibration: direction → screen (u, v).
struct Inverse<'g> {
    g: &'g GeometryCalibration,
    /// (u, v) ≈ A (tan_x, tan_y, 1).
    affine: [[f64; 3]; 2],
}

impl<'g> Inverse<'g> {
    fn new(g: &'g GeometryCalibration) -> Result<Inverse<'g>> {
        let (w, h) = g.screen();
        let mut ata = [[0.0; 3]; 3];
        let mut atb = [[0.0; 3]; 2];
        for j in 0..=16 {
            for i in 0..=16 {
                let (u, v) = (w as f64 * i as f64 / 16.0, h as f64 * j as f64 / 16.0);
                let d = g.direction(u, v);
                let row = [d[0], d[1], 1.0];
                for a in 0..3 {
                    for b in 0..3 {
                        ata[a][b] += row[a] * row[b];
                    }
                    atb[0][a] += row[a] * u;
                    atb[1][a] += row[a] * v;
                }
            }
        }
        let flat: Vec<f64> = ata.iter().flatten().copied().collect();
        let mut affine = [[0.0; 3]; 2];
        for k in 0..2 {
            let x = solve(&flat, &atb[k], 3)
                .ok_or_else(|| Error::Other("geometric calibration is degenerate".into()))?;
            affine[k].copy_from_slice(&x);
        }
        Ok(Inverse { g, affine })
    }

    fn screen_of(&self, tx: f64, ty: f64) -> Option<(f64, f64)> {
        let a = &self.affine;
        let mut u = a[0][0] * tx + a[0][1] * ty + a[0][2];
        let mut v = a[1][0] * tx + a[1][1] * ty + a[1][2];
        let (w, h) = self.g.screen();
        for _ in 0..20 {
            let d = self.g.direction(u, v);
            let (rx, ry) = (d[0] - tx, d[1] - ty);
            let j = self.g.jacobian(u, v);
            let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
            if det == 0.0 || !det.is_finite() {
                return None;
            }
            let du = (j[1][1] * rx - j[0][1] * ry) / det;
            let dv = (-j[1][0] * rx + j[0][0] * ry) / det;
            u -= du;
            v -= dv;
            if du.abs() < 1e-9 && dv.abs() < 1e-9 {
                break;
            }
        }
        (u.is_finite() && v.is_finite() && u >= 0.0 && v >= 0.0 && u <= w as f64 && v <= h as f64)
            .then_some((u, v))
    }
}

/// Solves the n×n system `a x = b` (row-major) by Gaussian elimination
/// with partial pivoting; `None` when singular.
fn solve(a: &[f64], b: &[f64], n: usize) -> Option<Vec<f64>> {
    let mut m: Vec<f64> = Vec::with_capacity(n * (n + 1));
    for r in 0..n {
        m.extend_from_slice(&a[r * n..r * n + n]);
        m.push(b[r]);
    }
    let w = n + 1;
    for c in 0..n {
        let p = (c..n).max_by(|&x, &y| m[x * w + c].abs().total_cmp(&m[y * w + c].abs()))?;
        if m[p * w + c].abs() < 1e-300 {
            return None;
        }
        for k in 0..w {
            m.swap(c * w + k, p * w + k);
        }
        for r in 0..n {
            if r != c {
                let f = m[r * w + c] / m[c * w + c];
                for k in c..w {
                    m[r * w + k] -= f * m[c * w + k];
                }
            }
        }
    }
    Some((0..n).map(|r| m[r * w + n] / m[r * w + r]).collect())
}

/// Runs the measurements (resuming from `ckpt`) and builds the gain map
/// (row-major, screen size) and the report.
pub fn run(
    inst: &mut Instruments,
    setup: &FlatSetup,
    ckpt: &mut Checkpoint,
) -> Result<(Vec<f32>, FlatReport)> {
    let cfg = setup.cfg;
    let probe = inst.camera.capture(&crate::instruments::CaptureRequest {
        pattern: "flat_probe".into(),
        exposure_s: cfg.camera.exposure,
        shutter: Default::default(),
    })?;
    let (cw, ch) = (probe.width, probe.height);
    let check = |what: &str, len: usize| -> Result<()> {
        if len != cw * ch {
            return Err(Error::Other(format!(
                "{what} has {len} pixels, the camera frame {cw}×{ch}"
            )));
        }
        Ok(())
    };
    if let Some(f) = &setup.camera_flat {
        check("calibrate.flat.camera_flat", f.len())?;
        if f.iter().any(|g| !(g.is_finite() && *g > 0.0)) {
            return Err(Error::invalid(
                "calibrate.flat.camera_flat",
                "gains must be finite and > 0",
            ));
        }
    }
    let map = pixel_map(setup, cw, ch)?;
    let region = Rect::from_fractions(cfg.region, cw, ch);
    let auto = AutoExposure::of(cfg);
    let bar = progress(cfg.flat.levels.len() as u64, "flat field");
    let mut fits = Vec::new();
    for &level in &cfg.flat.levels {
        let name = format!("flat_{level:04}");
        let fit = match ckpt.get::<LevelFit>(&name)? {
            Some(f) => f,
            None => {
                show_level(inst.display, level, setup.bits)?;
                (inst.wait)(cfg.settle);
                let full = Rect {
                    x: 0,
                    y: 0,
                    w: cw,
                    h: ch,
                };
                let r = auto.capture(inst.camera, inst.darks, &name, level, full)?;
                check(&format!("pattern `{name}`"), r.frame.data.len())?;
                let dark = r.dark.as_deref().map(|d| d.as_slice());
                let f = fit_level(setup, &map, &r.frame, dark, level, region)?;
                ckpt.record(&name, &f)?;
                f
            }
        };
        bar.inc(1);
        bar.set_message(format!(
            "level {level}: fit RMS {:.3} %",
            fit.fit_rms_percent
        ));
        fits.push(fit);
    }
    bar.finish_and_clear();
    build(setup, &map, fits)
}

/// Fits one level's screen pattern, normalised over the reference region.
fn fit_level(
    setup: &FlatSetup,
    map: &PixelMap,
    frame: &crate::instruments::CameraFrame,
    dark: Option<&[f32]>,
    level: u32,
    region: Rect,
) -> Result<LevelFit> {
    let degree = setup.cfg.flat.degree;
    let poly = Poly::new(degree, Vec::new(), setup.screen);
    let n = poly.terms.len();
    let t = frame.exposure_s;
    let value = |k: usize| -> Option<(f64, f64, f64)> {
        let (u, v) = map.screen[k]?;
        let dark = dark.map_or(0.0, |d| d[k] as f64);
        let cam = setup.camera_flat.as_ref().map_or(1.0, |f| f[k] as f64);
        let y = (frame.data[k] as f64 - dark) / (t * cam * map.etendue[k]);
        y.is_finite().then_some((u, v, y))
    };
    let (ata, atb, count) = (0..frame.data.len())
        .into_par_iter()
        .fold(
            || (vec![0.0; n * n], vec![0.0; n], 0usize),
            |(mut ata, mut atb, mut c), k| {
                if let Some((u, v, y)) = value(k) {
                    let mut b = vec![0.0; n];
                    poly.basis(u, v, &mut b);
                    for p in 0..n {
                        for q in 0..n {
                            ata[p * n + q] += b[p] * b[q];
                        }
                        atb[p] += b[p] * y;
                    }
                    c += 1;
                }
                (ata, atb, c)
            },
        )
        .reduce(
            || (vec![0.0; n * n], vec![0.0; n], 0usize),
            |(mut a, mut b, c), (a2, b2, c2)| {
                a.iter_mut().zip(&a2).for_each(|(x, y)| *x += y);
                b.iter_mut().zip(&b2).for_each(|(x, y)| *x += y);
                (a, b, c + c2)
            },
        );
    if count < 4 * n {
        return Err(Error::Other(format!(
            "flat field at level {level}: only {count} camera pixels see the screen, \
             too few for a degree-{degree} fit"
        )));
    }
    let coefficients = solve(&ata, &atb, n).ok_or_else(|| {
        Error::Other(format!(
            "flat field at level {level}: the fit is singular (the camera sees too little of the screen)"
        ))
    })?;
    let mut poly = Poly::new(degree, coefficients, setup.screen);
    // Normalise to mean 1 over the radiometric calibration's region.
    let (mut s, mut m) = (0.0, 0usize);
    for y in region.y..region.y + region.h {
        for x in region.x..region.x + region.w {
            if let Some((u, v)) = map.screen[y * frame.width + x] {
                s += poly.eval(u, v);
                m += 1;
            }
        }
    }
    if m == 0 || !(s > 0.0) {
        return Err(Error::Other(format!(
            "flat field at level {level}: the radiometric region sees no lit screen"
        )));
    }
    let norm = s / m as f64;
    // Residual RMS relative to the fit, on the unnormalised scale.
    let (mut r2, mut k2) = (0.0, 0usize);
    for k in (0..frame.data.len()).step_by(7) {
        if let Some((u, v, y)) = value(k) {
            let f = poly.eval(u, v);
            if f > 0.0 {
                r2 += (y / f - 1.0).powi(2);
                k2 += 1;
            }
        }
    }
    let residual = residual_cells(setup, map, &poly, &value, region, frame.width);
    for c in &mut poly.coefficients {
        *c /= norm;
    }
    Ok(LevelFit {
        level,
        exposure_s: t,
        coefficients: poly.coefficients,
        fit_rms_percent: 100.0 * (r2 / k2.max(1) as f64).sqrt(),
        pixels: count,
        residual,
    })
}

/// The grid of residual cells over the screen: (columns, rows, side px).
/// A cell spans at least two camera pixels each way (a cell no camera
/// pixel falls in would hold no measurement).
fn cell_grid(setup: &FlatSetup, map: &PixelMap) -> Option<(usize, usize, usize)> {
    let wanted = setup.cfg.flat.residual_cell_px;
    if wanted == 0 {
        return None;
    }
    let side = wanted.max((2.0 * screen_px_per_camera_px(map)).ceil() as usize);
    Some((
        setup.screen.0.div_ceil(side),
        setup.screen.1.div_ceil(side),
        side,
    ))
}

/// Screen pixels per camera pixel: the median step between horizontally
/// adjacent camera pixels that both see the screen.
fn screen_px_per_camera_px(map: &PixelMap) -> f64 {
    let w = map.width;
    let mut steps: Vec<f64> = (0..map.screen.len().saturating_sub(1))
        .step_by(17)
        .filter(|k| (k + 1) % w != 0)
        .filter_map(|k| {
            let (a, b) = (map.screen[k]?, map.screen[k + 1]?);
            Some((a.0 - b.0).hypot(a.1 - b.1))
        })
        .collect();
    if steps.is_empty() {
        return 1.0;
    }
    steps.sort_by(f64::total_cmp);
    steps[steps.len() / 2]
}

/// Mean of measured / polynomial per residual cell, normalised to mean 1
/// over the camera pixels of `region` (so the polynomial keeps the
/// region's scale); 1 in cells no camera pixel sees.
fn residual_cells(
    setup: &FlatSetup,
    map: &PixelMap,
    poly: &Poly,
    value: &dyn Fn(usize) -> Option<(f64, f64, f64)>,
    region: Rect,
    width: usize,
) -> Vec<f32> {
    let Some((gw, gh, side)) = cell_grid(setup, map) else {
        return Vec::new();
    };
    let cell_of = |u: f64, v: f64| {
        let (i, j) = ((u / side as f64) as usize, (v / side as f64) as usize);
        j.min(gh - 1) * gw + i.min(gw - 1)
    };
    let (mut sum, mut n) = (vec![0.0f64; gw * gh], vec![0u32; gw * gh]);
    for k in 0..map.screen.len() {
        if let Some((u, v, y)) = value(k) {
            let f = poly.eval(u, v);
            if f > 0.0 {
                let c = cell_of(u, v);
                sum[c] += y / f;
                n[c] += 1;
            }
        }
    }
    let cells: Vec<f64> = sum
        .iter()
        .zip(&n)
        .map(|(&s, &c)| if c > 0 { s / c as f64 } else { 1.0 })
        .collect();
    let (mut s, mut m) = (0.0, 0usize);
    for y in region.y..region.y + region.h {
        for x in region.x..region.x + region.w {
            if let Some((u, v)) = map.screen[y * width + x] {
                s += cells[cell_of(u, v)];
                m += 1;
            }
        }
    }
    let norm = if m > 0 && s > 0.0 { s / m as f64 } else { 1.0 };
    cells.iter().map(|&c| (c / norm) as f32).collect()
}

/// The residual cells kept: their mean over the levels, shrunk toward 1 by
/// the Wiener factor 1 − noise / total variance, the noise estimated from
/// the levels' differences (the mura is common to the levels, the
/// camera's noise is not), so that a camera too coarse or too noisy to
/// see the mura adds no noise to the flat.
struct Residual {
    grid: (usize, usize, usize),
    cells: Vec<f64>,
    /// The Wiener factor applied.
    gain: f64,
}

impl Residual {
    fn new(grid: Option<(usize, usize, usize)>, fits: &[LevelFit]) -> Option<Residual> {
        let (gw, gh, side) = grid?;
        let n = gw * gh;
        if fits.is_empty() || fits.iter().any(|f| f.residual.len() != n) {
            return None;
        }
        let m = fits.len() as f64;
        let mean: Vec<f64> = (0..n)
            .map(|k| fits.iter().map(|f| f.residual[k] as f64).sum::<f64>() / m)
            .collect();
        // Cells with data differ from 1; the exact 1s are cells no pixel saw.
        let seen: Vec<usize> = (0..n).filter(|&k| mean[k] != 1.0).collect();
        let total =
            seen.iter().map(|&k| (mean[k] - 1.0).powi(2)).sum::<f64>() / seen.len().max(1) as f64;
        // Variance of the mean's noise: the levels' scatter about it / m.
        let noise = if fits.len() >= 2 {
            seen.iter()
                .map(|&k| {
                    fits.iter()
                        .map(|f| (f.residual[k] as f64 - mean[k]).powi(2))
                        .sum::<f64>()
                        / (m - 1.0)
                        / m
                })
                .sum::<f64>()
                / seen.len().max(1) as f64
        } else {
            total
        };
        let gain = if total > 0.0 {
            (1.0 - noise / total).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let cells = mean.iter().map(|&r| 1.0 + gain * (r - 1.0)).collect();
        Some(Residual {
            grid: (gw, gh, side),
            cells,
            gain,
        })
    }

    /// Bilinear between cell centres at screen (u, v).
    fn at(&self, u: f64, v: f64) -> f64 {
        let (gw, gh, side) = self.grid;
        let c = |i: usize, j: usize| self.cells[j * gw + i];
        let x = (u / side as f64 - 0.5).clamp(0.0, (gw - 1) as f64);
        let y = (v / side as f64 - 0.5).clamp(0.0, (gh - 1) as f64);
        let (i0, j0) = (x.floor() as usize, y.floor() as usize);
        let (i1, j1) = ((i0 + 1).min(gw - 1), (j0 + 1).min(gh - 1));
        let (a, b) = (x - i0 as f64, y - j0 as f64);
        (1.0 - b) * ((1.0 - a) * c(i0, j0) + a * c(i1, j0))
            + b * ((1.0 - a) * c(i0, j1) + a * c(i1, j1))
    }
}

/// The 13 measuring points of a uniformity figure, as fractions of the
/// measured area: centre, 4 at the quarter points, 4 edge midpoints and 4
/// corners at 10 % in from the edges.
pub const POINTS_13: [(f64, f64); 13] = [
    (0.5, 0.5),
    (0.25, 0.25),
    (0.75, 0.25),
    (0.25, 0.75),
    (0.75, 0.75),
    (0.5, 0.1),
    (0.5, 0.9),
    (0.1, 0.5),
    (0.9, 0.5),
    (0.1, 0.1),
    (0.9, 0.1),
    (0.1, 0.9),
    (0.9, 0.9),
];

fn build(setup: &FlatSetup, map: &PixelMap, fits: Vec<LevelFit>) -> Result<(Vec<f32>, FlatReport)> {
    let degree = setup.cfg.flat.degree;
    let n = terms(degree).len();
    let mut mean = vec![0.0; n];
    for f in &fits {
        if f.coefficients.len() != n {
            return Err(Error::Other(format!(
                "checkpointed flat fit of level {} has {} terms, degree {degree} needs {n}",
                f.level,
                f.coefficients.len()
            )));
        }
        mean.iter_mut()
            .zip(&f.coefficients)
            .for_each(|(m, c)| *m += c / fits.len() as f64);
    }
    let poly = Poly::new(degree, mean, setup.screen);
    let [u0, v0, u1, v1] = map.seen;
    let (w, h) = setup.screen;
    let residual = Residual::new(cell_grid(setup, map), &fits);
    let residual = residual.as_ref();
    let gains: Vec<f32> = (0..h)
        .into_par_iter()
        .flat_map_iter(|y| {
            let poly = &poly;
            (0..w).map(move |x| {
                let u = (x as f64 + 0.5).clamp(u0, u1);
                let v = (y as f64 + 0.5).clamp(v0, v1);
                (poly.eval(u, v) * residual.map_or(1.0, |r| r.at(u, v))) as f32
            })
        })
        .collect();
    if let Some(i) = gains.iter().position(|g| !(g.is_finite() && *g > 0.0)) {
        return Err(Error::Other(format!(
            "flat-field gain {} at screen pixel ({}, {}) is not positive: the fit failed \
             (lower calibrate.flat.degree)",
            gains[i],
            i % w,
            i / w
        )));
    }
    // Uniformity over the seen area.
    let (mut lo, mut hi, mut disagree) = (f64::INFINITY, 0.0f64, 0.0f64);
    let level_polys: Vec<Poly> = fits
        .iter()
        .map(|f| Poly::new(degree, f.coefficients.clone(), setup.screen))
        .collect();
    for j in 0..=40 {
        for i in 0..=40 {
            let u = u0 + (u1 - u0) * i as f64 / 40.0;
            let v = v0 + (v1 - v0) * j as f64 / 40.0;
            let g = poly.eval(u, v);
            lo = lo.min(g);
            hi = hi.max(g);
            for p in &level_polys {
                disagree = disagree.max((p.eval(u, v) / g - 1.0).abs() * 100.0);
            }
        }
    }
    let points_13: Vec<(f64, f64, f64)> = POINTS_13
        .iter()
        .map(|&(a, b)| {
            let (u, v) = (u0 + a * (u1 - u0), v0 + b * (v1 - v0));
            (u, v, poly.eval(u, v))
        })
        .collect();
    let pmin = points_13.iter().map(|p| p.2).fold(f64::INFINITY, f64::min);
    let pmax = points_13.iter().map(|p| p.2).fold(0.0, f64::max);
    let report = FlatReport {
        uncertainty_k2_percent: flat_uncertainty(&fits, degree, disagree),
        levels: fits,
        degree,
        seen: map.seen,
        min_gain: lo,
        max_gain: hi,
        points_13,
        nonuniformity_13_percent: 100.0 * (1.0 - pmin / pmax),
        level_disagreement_percent: disagree,
        camera_flat: setup.camera_flat.is_some(),
        residual_cell_px: residual.map(|r| r.grid.2),
        residual_gain: residual.map(|r| r.gain),
    };
    // The area's figure is the per-pixel map's largest value (the grid
    // above can miss the map's peak between its points).
    let worst = uncertainty_map(&report, setup.screen)
        .iter()
        .fold(0.0f64, |m, &u| m.max(u as f64));
    let report = FlatReport {
        uncertainty_k2_percent: report.uncertainty_k2_percent.max(worst),
        ..report
    };
    Ok((gains, report))
}

/// The per-pixel expanded uncertainty (k = 2, %) of the gain map: at each
/// screen pixel (clamped to the seen area, as the gains are) the largest
/// disagreement of a level's fit with the mean, and the fit's standard
/// error term of [`FlatReport::uncertainty_k2_percent`], in quadrature.
pub fn uncertainty_map(report: &FlatReport, screen: (usize, usize)) -> Vec<f32> {
    let degree = report.degree;
    let polys: Vec<Poly> = report
        .levels
        .iter()
        .map(|f| Poly::new(degree, f.coefficients.clone(), screen))
        .collect();
    let fit = flat_uncertainty(&report.levels, degree, 0.0);
    let [u0, v0, u1, v1] = report.seen;
    let (w, h) = screen;
    (0..w * h)
        .into_par_iter()
        .map(|k| {
            let u = ((k % w) as f64 + 0.5).clamp(u0, u1);
            let v = ((k / w) as f64 + 0.5).clamp(v0, v1);
            let g: Vec<f64> = polys.iter().map(|p| p.eval(u, v)).collect();
            let mean = g.iter().sum::<f64>() / g.len().max(1) as f64;
            let spread = g
                .iter()
                .map(|x| (x / mean - 1.0).abs() * 100.0)
                .fold(0.0f64, f64::max);
            spread.hypot(fit) as f32
        })
        .collect()
}

/// The flat field's expanded uncertainty (k = 2), % (see
/// [`FlatReport::uncertainty_k2_percent`]).
fn flat_uncertainty(fits: &[LevelFit], degree: usize, disagreement_percent: f64) -> f64 {
    let terms = terms(degree).len() as f64;
    let fit = fits
        .iter()
        .map(|f| 2.0 * f.fit_rms_percent * (terms / f.pixels.max(1) as f64).sqrt())
        .fold(0.0f64, f64::max);
    fit.hypot(disagreement_percent)
}

/// Writes a Gray32Float TIFF of `gains` (`screen` size), as
/// [`FlatField::load`](crate::facility::lut::FlatField::load) reads it.
pub fn write_tiff(path: &std::path::Path, gains: &[f32], screen: (usize, usize)) -> Result<()> {
    if let Some(d) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(d).map_err(|e| Error::io(d, e))?;
    }
    let file = std::fs::File::create(path).map_err(|e| Error::io(path, e))?;
    let terr =
        |e: tiff::TiffError| Error::Other(format!("{}: cannot write TIFF: {e}", path.display()));
    let mut enc = tiff::encoder::TiffEncoder::new(std::io::BufWriter::new(file)).map_err(terr)?;
    enc.write_image::<tiff::encoder::colortype::Gray32Float>(
        screen.0 as u32,
        screen.1 as u32,
        gains,
    )
    .map_err(terr)?;
    Ok(())
}

/// Writes the report JSON and the gain map PNG (with a colour bar).
pub fn write_report(
    report: &FlatReport,
    gains: &[f32],
    screen: (usize, usize),
    json: &std::path::Path,
    png: &std::path::Path,
) -> Result<()> {
    let text = serde_json::to_string_pretty(report).map_err(|e| Error::Other(e.to_string()))?;
    std::fs::write(json, text).map_err(|e| Error::io(json, e))?;
    let [u0, v0, u1, v1] = report.seen;
    let values: Vec<f64> = gains
        .iter()
        .enumerate()
        .map(|(i, &g)| {
            let (x, y) = ((i % screen.0) as f64 + 0.5, (i / screen.0) as f64 + 0.5);
            if x >= u0 && x <= u1 && y >= v0 && y <= v1 {
                g as f64
            } else {
                f64::NAN
            }
        })
        .collect();
    heatmap(
        png,
        &Heatmap {
            title: format!(
                "Flat-field gain (13-point non-uniformity {:.2} %; white: not seen by the camera)",
                report.nonuniformity_13_percent
            ),
            x_label: "screen u (px)".into(),
            y_label: "screen v (px)".into(),
            value_label: "gain (screen radiance / LUT radiance)".into(),
            width: screen.0,
            height: screen.1,
            values: &values,
            size: (1000, 620),
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solve_against_a_hand_system() {
        // 2x + y = 5, x − 3y = −8 → x = 1, y = 3.
        let x = solve(&[2.0, 1.0, 1.0, -3.0], &[5.0, -8.0], 2).unwrap();
        assert!((x[0] - 1.0).abs() < 1e-12 && (x[1] - 3.0).abs() < 1e-12);
        assert!(solve(&[1.0, 2.0, 2.0, 4.0], &[1.0, 2.0], 2).is_none());
    }

    #[test]
    fn terms_count_is_triangular() {
        for d in 0..6 {
            assert_eq!(terms(d).len(), (d + 1) * (d + 2) / 2);
        }
    }
}
