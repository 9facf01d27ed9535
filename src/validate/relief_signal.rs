//! Whether a render's relief moves it toward the real image. Over the
//! disk's interior, the relief's change to the render d = (with relief −
//! without) is set against the residual of the render without relief
//! e = real − without. The correlation says whether the DEM's shadows and
//! slopes sit where the image's do; the gain (the least-squares scale of
//! d that best explains e) says whether their contrast is the image's
//! (1), too strong (< 1) or too weak (> 1). Adding d lowers the residual's
//! energy only where the gain exceeds 1/2 (‖e − d‖² < ‖e‖² ⇔
//! 2 cov(d, e) > var(d)), which the structure term follows.
//!
//! The residual near the terminator carries a smooth trend (the model's
//! terminator too bright or too dark over tens of pixels) that any
//! darkening there correlates with, whatever its detail. The same numbers
//! after a high-pass (each of d and e minus its Gaussian blur over the
//! interior, at [`HIGH_PASS_SIGMAS_PX`]) compare only the detail: where
//! the shadows and slopes sit, not how the smooth terminator is shaded;
//! and the whole-pixel shift of the relief's detail that matches the
//! image's best says whether it sits displaced.

use serde::Serialize;

use super::background::Disk;
use super::Raster;

/// Pixels this far inside the limb [px] or more are the disk's interior:
/// the limb itself moves with the sub-pixel alignment.
pub const INSET_PX: f64 = 3.0;
/// Standard deviations [px] of the Gaussians whose blur the high-pass
/// removes: from about an AMIE pixel's worth of DEM cells (2 px ≈ 4.7
/// cells) to the width of the terminator's shading trend.
pub const HIGH_PASS_SIGMAS_PX: [f64; 3] = [2.0, 4.0, 8.0];
/// Largest shift [px] along each axis searched for the high-passed
/// relief's best match ([`HighPassSignal::best_shift_px`]).
pub const MAX_SHIFT_PX: i64 = 4;

/// The relief's change against the residual without it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ReliefSignal {
    /// Pearson correlation of d and e.
    pub correlation: f64,
    /// cov(d, e) / var(d): 1 where the relief's contrast is the image's.
    pub gain: f64,
    /// rms(e − d) / rms(e) − 1 (mean-removed): negative where the relief
    /// brings the render closer to the image.
    pub residual_change: f64,
    /// Interior pixels compared.
    pub pixels: usize,
    /// Their distance inside the limb [px].
    pub inset_px: f64,
    /// The same after removing the Gaussian blur of d and e, per
    /// [`HIGH_PASS_SIGMAS_PX`].
    pub high_pass: Vec<HighPassSignal>,
}

/// Correlation, gain and residual change of the high-passed d and e.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct HighPassSignal {
    /// The blur's standard deviation [px].
    pub sigma_px: f64,
    pub correlation: f64,
    pub gain: f64,
    pub residual_change: f64,
    /// The whole-pixel shift (dx, dy) [px] (x right, y down; within
    /// ±[`MAX_SHIFT_PX`]) of the high-passed relief change that best
    /// correlates with the high-passed residual: (0, 0) where the relief's
    /// detail sits where the image's does; a shift along the Sun's
    /// direction in the image says the image's shadows are longer or
    /// shorter than the DEM's, a shift across it a misregistration.
    pub best_shift_px: [i64; 2],
    /// The correlation at that shift.
    pub best_shift_correlation: f64,
}

/// The shift of `d` within ±[`MAX_SHIFT_PX`] (moving its pattern by
/// (dx, dy)) that correlates best with `e` over `mask`, and that
/// correlation.
fn best_shift(d: &[f64], e: &[f64], mask: &[bool], width: usize) -> ([i64; 2], f64) {
    let height = d.len() / width;
    let mut best = ([0, 0], f64::NEG_INFINITY);
    for dy in -MAX_SHIFT_PX..=MAX_SHIFT_PX {
        for dx in -MAX_SHIFT_PX..=MAX_SHIFT_PX {
            let mut pairs = Vec::new();
            for row in 0..height {
                for col in 0..width {
                    let (c, r) = (col as i64 - dx, row as i64 - dy);
                    if c < 0 || r < 0 || c >= width as i64 || r >= height as i64 {
                        continue;
                    }
                    let (k, src) = (row * width + col, r as usize * width + c as usize);
                    if mask[k] && mask[src] {
                        pairs.push((d[src], e[k]));
                    }
                }
            }
            if let Some((corr, _, _)) = statistics(&pairs) {
                if corr > best.1 {
                    best = ([dx, dy], corr);
                }
            }
        }
    }
    best
}

/// (correlation, gain, residual change) of mean-removed pairs (d, e);
/// `None` where either has no variance.
fn statistics(pairs: &[(f64, f64)]) -> Option<(f64, f64, f64)> {
    let n = pairs.len() as f64;
    if pairs.len() < 2 {
        return None;
    }
    let (md, me) = pairs
        .iter()
        .fold((0.0, 0.0), |(a, b), (d, e)| (a + d / n, b + e / n));
    let (mut dd, mut ee, mut de, mut rr) = (0.0, 0.0, 0.0, 0.0);
    for (d, e) in pairs {
        let (d, e) = (d - md, e - me);
        dd += d * d;
        ee += e * e;
        de += d * e;
        rr += (e - d) * (e - d);
    }
    (dd > 0.0 && ee > 0.0).then(|| (de / (dd * ee).sqrt(), de / dd, (rr / ee).sqrt() - 1.0))
}

/// `values` minus their Gaussian blur (standard deviation `sigma` [px])
/// over the pixels where `mask` is set, normalised by the blurred mask so
/// that the pixels outside do not leak in; 0 outside the mask.
fn high_pass(values: &[f64], mask: &[bool], width: usize, sigma: f64) -> Vec<f64> {
    let reach = (3.0 * sigma).ceil() as i64;
    let kernel: Vec<f64> = (-reach..=reach)
        .map(|k| (-0.5 * (k as f64 / sigma).powi(2)).exp())
        .collect();
    let height = values.len() / width;
    let blur = |v: &[f64]| {
        let pass = |v: &[f64], along_rows: bool| {
            let mut out = vec![0.0; v.len()];
            for row in 0..height {
                for col in 0..width {
                    let mut acc = 0.0;
                    for (k, w) in (-reach..=reach).zip(&kernel) {
                        let (c, r) = if along_rows {
                            (col as i64 + k, row as i64)
                        } else {
                            (col as i64, row as i64 + k)
                        };
                        if c >= 0 && r >= 0 && (c as usize) < width && (r as usize) < height {
                            acc += w * v[r as usize * width + c as usize];
                        }
                    }
                    out[row * width + col] = acc;
                }
            }
            out
        };
        pass(&pass(v, true), false)
    };
    let m: Vec<f64> = mask.iter().map(|&b| if b { 1.0 } else { 0.0 }).collect();
    let vm: Vec<f64> = values.iter().zip(&m).map(|(v, m)| v * m).collect();
    let (num, den) = (blur(&vm), blur(&m));
    (0..values.len())
        .map(|k| {
            if mask[k] {
                values[k] - num[k] / den[k]
            } else {
                0.0
            }
        })
        .collect()
}

/// [`ReliefSignal`] of the renders `with` and `without` relief against
/// `real`, over the pixels at least [`INSET_PX`] inside `disk`, as they
/// are and high-passed; `None` where fewer than two pixels are inside or
/// the relief changes nothing.
pub fn relief_signal(
    real: &Raster,
    with: &Raster,
    without: &Raster,
    disk: &Disk,
) -> Option<ReliefSignal> {
    let (w, h) = (real.width, real.height);
    let mut mask = vec![false; w * h];
    let (mut d, mut e) = (vec![0.0; w * h], vec![0.0; w * h]);
    for row in 0..h {
        for col in 0..w {
            let k = row * w + col;
            mask[k] = disk.limb_distance(col as f64 + 0.5, row as f64 + 0.5) <= -INSET_PX;
            let base = without.get(col, row) as f64;
            d[k] = with.get(col, row) as f64 - base;
            e[k] = real.get(col, row) as f64 - base;
        }
    }
    let pairs = |d: &[f64], e: &[f64]| -> Vec<(f64, f64)> {
        (0..w * h)
            .filter(|&k| mask[k])
            .map(|k| (d[k], e[k]))
            .collect()
    };
    let all = pairs(&d, &e);
    let (correlation, gain, residual_change) = statistics(&all)?;
    let high_pass = HIGH_PASS_SIGMAS_PX
        .iter()
        .filter_map(|&sigma| {
            let (dh, eh) = (
                high_pass(&d, &mask, w, sigma),
                high_pass(&e, &mask, w, sigma),
            );
            let (correlation, gain, residual_change) = statistics(&pairs(&dh, &eh))?;
            let (best_shift_px, best_shift_correlation) = best_shift(&dh, &eh, &mask, w);
            Some(HighPassSignal {
                sigma_px: sigma,
                correlation,
                gain,
                residual_change,
                best_shift_px,
                best_shift_correlation,
            })
        })
        .collect();
    Some(ReliefSignal {
        correlation,
        gain,
        residual_change,
        pixels: all.len(),
        inset_px: INSET_PX,
        high_pass,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn raster(f: impl Fn(usize, usize) -> f64) -> Raster {
        raster_of(40, f)
    }

    fn raster_of(n: usize, f: impl Fn(usize, usize) -> f64) -> Raster {
        let (w, h) = (n, n);
        let data = (0..w * h).map(|k| f(k % w, k / w) as f32).collect();
        Raster::new(w, h, data).unwrap()
    }

    fn disk() -> Disk {
        Disk {
            cx: 20.0,
            cy: 20.0,
            radius: 15.0,
        }
    }

    /// A relief pattern and an independent one (orthogonal over the
    /// disk in expectation).
    fn pattern(x: usize, y: usize) -> f64 {
        ((x as f64) * 0.9).sin() * ((y as f64) * 0.7).cos()
    }

    fn other(x: usize, y: usize) -> f64 {
        ((x as f64) * 2.3 + 1.0).cos() * ((y as f64) * 1.9).sin()
    }

    #[test]
    fn a_relief_at_half_the_image_contrast_has_gain_one_half() {
        let without = raster(|x, _| 100.0 + x as f64);
        let with = raster(|x, y| 100.0 + x as f64 + 10.0 * pattern(x, y));
        let real = raster(|x, y| 100.0 + x as f64 + 5.0 * pattern(x, y));
        let s = relief_signal(&real, &with, &without, &disk()).unwrap();
        assert!((s.correlation - 1.0).abs() < 1e-5, "{s:?}");
        assert!((s.gain - 0.5).abs() < 1e-5, "{s:?}");
        // e − d = −e: the residual is as large as before.
        assert!(s.residual_change.abs() < 1e-5, "{s:?}");
        // Pixels at least INSET_PX inside a 15 px limb: about π 12².
        let area = std::f64::consts::PI * 12.0f64.powi(2);
        assert!((s.pixels as f64 / area - 1.0).abs() < 0.05, "{}", s.pixels);
    }

    #[test]
    fn a_misplaced_relief_does_not_correlate_and_grows_the_residual() {
        let without = raster(|_, _| 100.0);
        let with = raster(|x, y| 100.0 + 4.0 * pattern(x, y));
        let real = raster(|x, y| 100.0 + 4.0 * other(x, y));
        let s = relief_signal(&real, &with, &without, &disk()).unwrap();
        assert!(s.correlation.abs() < 0.1, "{s:?}");
        // Two uncorrelated equal-energy signals: rms(e − d) ≈ √2 rms(e).
        assert!(
            (s.residual_change - (2f64.sqrt() - 1.0)).abs() < 0.1,
            "{s:?}"
        );
    }

    /// A relief whose detail is the image's at 0.6 its contrast, plus a
    /// smooth darkening where the image has a smooth brightening (a
    /// terminator shaded too dark): the raw correlation is negative, the
    /// high-passed one near 1 with the detail's gain 0.6 (a Gaussian
    /// high-pass scales a sinusoid by the same factor in d and e).
    #[test]
    fn the_high_pass_sees_the_detail_under_an_opposite_trend() {
        // A 120 px frame, disk radius 48: the ramp's residue within 3σ of
        // the mask's edge stays small against the detail.
        let big = Disk {
            cx: 60.0,
            cy: 60.0,
            radius: 48.0,
        };
        let trend = |x: usize| (x as f64 - 60.0) / 45.0;
        let without = raster_of(120, |_, _| 100.0);
        let with = raster_of(120, |x, y| 100.0 + 2.0 * pattern(x, y) - 8.0 * trend(x));
        let real = raster_of(120, |x, y| 100.0 + 1.2 * pattern(x, y) + 8.0 * trend(x));
        let s = relief_signal(&real, &with, &without, &big).unwrap();
        assert!(s.correlation < -0.9, "{s:?}");
        assert_eq!(s.high_pass.len(), HIGH_PASS_SIGMAS_PX.len());
        // The narrowest high-pass leaves the least of the ramp (its blur
        // is asymmetric only within a few σ of the mask's edge).
        let hp = &s.high_pass[0];
        assert_eq!(hp.sigma_px, HIGH_PASS_SIGMAS_PX[0]);
        assert!(hp.correlation > 0.95, "{hp:?}");
        assert!((hp.gain - 0.6).abs() < 0.05, "{hp:?}");
        // 2 cov > var: the relief's detail lowers the high-passed residual.
        assert!(hp.residual_change < 0.0, "{hp:?}");
    }

    /// The image's detail is the relief's moved by (2, −1) px: the search
    /// finds that shift with a correlation near 1, while the unshifted
    /// correlation is far lower.
    #[test]
    fn the_best_shift_finds_a_displaced_pattern() {
        let big = Disk {
            cx: 40.0,
            cy: 40.0,
            radius: 34.0,
        };
        let without = raster_of(80, |_, _| 50.0);
        let with = raster_of(80, |x, y| 50.0 + 3.0 * other(x, y));
        let real = raster_of(80, |x, y| {
            let (xs, ys) = (x as i64 - 2, y as i64 + 1);
            50.0 + 1.5 * other(xs.max(0) as usize, ys.max(0) as usize)
        });
        let s = relief_signal(&real, &with, &without, &big).unwrap();
        let hp = &s.high_pass[0];
        assert_eq!(hp.best_shift_px, [2, -1], "{hp:?}");
        assert!(hp.best_shift_correlation > 0.95, "{hp:?}");
        assert!(hp.correlation < 0.5, "{hp:?}");
    }

    #[test]
    fn the_high_pass_removes_a_constant_and_a_ramp_away_from_the_edge() {
        let (w, h) = (40, 40);
        let mask: Vec<bool> = (0..w * h)
            .map(|k| disk().limb_distance((k % w) as f64 + 0.5, (k / w) as f64 + 0.5) <= -INSET_PX)
            .collect();
        let ramp: Vec<f64> = (0..w * h).map(|k| 7.0 + 0.5 * (k % w) as f64).collect();
        let hp = high_pass(&ramp, &mask, w, 2.0);
        for k in 0..w * h {
            let inner =
                disk().limb_distance((k % w) as f64 + 0.5, (k / w) as f64 + 0.5) <= -INSET_PX - 9.0;
            if inner {
                // A symmetric kernel (±6 px square) wholly inside the
                // mask keeps a ramp.
                assert!(hp[k].abs() < 1e-9, "{k}: {}", hp[k]);
            }
            if !mask[k] {
                assert_eq!(hp[k], 0.0);
            }
        }
    }

    #[test]
    fn no_change_or_no_disk_gives_none() {
        let flat = raster(|_, _| 1.0);
        assert!(relief_signal(&flat, &flat, &flat, &disk()).is_none());
        let far = Disk {
            cx: -100.0,
            cy: -100.0,
            radius: 5.0,
        };
        let with = raster(pattern);
        assert!(relief_signal(&flat, &with, &flat, &far).is_none());
    }
}
