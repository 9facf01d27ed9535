//! Whether a render's relief moves it toward the real image. Over the
//! disk's interior, the relief's change to the render d = (with relief −
//! without) is set against the residual of the render without relief
//! e = real − without. The correlation says whether the DEM's shadows and
//! slopes sit where the image's do; the gain (the least-squares scale of
//! d that best explains e) says whether their contrast is the image's
//! (1), too strong (< 1) or too weak (> 1). Adding d lowers the residual's
//! energy only where the gain exceeds 1/2 (‖e − d‖² < ‖e‖² ⇔
//! 2 cov(d, e) > var(d)), which the structure term follows.

use serde::Serialize;

use super::background::Disk;
use super::Raster;

/// Pixels this far inside the limb [px] or more are the disk's interior:
/// the limb itself moves with the sub-pixel alignment.
pub const INSET_PX: f64 = 3.0;

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
}

/// [`ReliefSignal`] of the renders `with` and `without` relief against
/// `real`, over the pixels at least [`INSET_PX`] inside `disk`; `None`
/// where fewer than two pixels are inside or the relief changes nothing.
pub fn relief_signal(
    real: &Raster,
    with: &Raster,
    without: &Raster,
    disk: &Disk,
) -> Option<ReliefSignal> {
    let mut pairs = Vec::new();
    for row in 0..real.height {
        for col in 0..real.width {
            if disk.limb_distance(col as f64 + 0.5, row as f64 + 0.5) <= -INSET_PX {
                let base = without.get(col, row) as f64;
                let d = with.get(col, row) as f64 - base;
                let e = real.get(col, row) as f64 - base;
                pairs.push((d, e));
            }
        }
    }
    let n = pairs.len() as f64;
    if pairs.len() < 2 {
        return None;
    }
    let (md, me) = pairs
        .iter()
        .fold((0.0, 0.0), |(a, b), (d, e)| (a + d / n, b + e / n));
    let (mut dd, mut ee, mut de, mut rr) = (0.0, 0.0, 0.0, 0.0);
    for (d, e) in &pairs {
        let (d, e) = (d - md, e - me);
        dd += d * d;
        ee += e * e;
        de += d * e;
        rr += (e - d) * (e - d);
    }
    if !(dd > 0.0 && ee > 0.0) {
        return None;
    }
    Some(ReliefSignal {
        correlation: de / (dd * ee).sqrt(),
        gain: de / dd,
        residual_change: (rr / ee).sqrt() - 1.0,
        pixels: pairs.len(),
        inset_px: INSET_PX,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn raster(f: impl Fn(usize, usize) -> f64) -> Raster {
        let (w, h) = (40, 40);
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
