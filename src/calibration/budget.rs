//! The radiometric calibration's uncertainty budget: per drive level, the
//! expanded uncertainty (k = 2, % of the radiance) of the LUT value from
//! its components, combined in quadrature:
//!
//! | component | from |
//! |---|---|
//! | noise | 2 × the repeats' standard error of the camera response |
//! | fit | the level's leave-one-out PCHIP residual ÷ 4 (leaving a level out doubles the spacing; PCHIP's error on smooth data falls at least as h²) |
//! | meter scale | `calibrate.meter.scale_uncertainty_k2_percent` (the meter's own calibration) |
//! | spectral mismatch | \|F(S shifted by `screen_spectrum_uncertainty_nm`) / F − 1\|, the larger of ±shift |
//! | scale fit | 2 × the standard error of the meter/camera ratios the scale is fitted to |
//! | spectral trend | with F per level ([`mismatch_levels`](super::mismatch_levels)): what its interpolation in level leaves, with the measured F's noise; with one F: 2 × \|s / r_top − 1\| / √3, the fitted scale s against the top level's own ratio r_top, where the screen shows the white whose spectrum F comes from (a broadband meter only; greys whose spectrum differs carry their F error into s) |
//! | drift | 2 × \|drift\| / √3 (the reference's change over the campaign, as a rectangular bound) |
//!
//! A component that is not declared counts 0 and the report says so.

use serde::{Deserialize, Serialize};

use super::mismatch::{CameraSpectral, Spectrum};
use crate::error::Result;
use crate::radiometry::spectrum::Table;

/// The scale-wide components (the same for every level), k = 2, %.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Budget {
    /// The meter's own calibration; `None`: not declared.
    pub meter_scale_k2_percent: Option<f64>,
    /// The spectral mismatch factor's sensitivity to the screen spectrum's
    /// declared wavelength uncertainty; `None`: not declared or not used.
    pub mismatch_k2_percent: Option<f64>,
    /// The absolute scale's statistical uncertainty.
    pub scale_fit_k2_percent: f64,
    /// The scale's departure from the white's own ratio ([`spectral_trend_k2_percent`]).
    #[serde(default)]
    pub spectral_trend_k2_percent: f64,
    /// The campaign's drift.
    pub drift_k2_percent: f64,
}

/// One level's components and total, k = 2, %.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct LevelUncertainty {
    pub noise_k2_percent: f64,
    pub fit_k2_percent: f64,
    pub total_k2_percent: f64,
}

impl Budget {
    /// Quadrature sum of the scale-wide components, %.
    pub fn scale_total(&self) -> f64 {
        [
            self.meter_scale_k2_percent.unwrap_or(0.0),
            self.mismatch_k2_percent.unwrap_or(0.0),
            self.scale_fit_k2_percent,
            self.spectral_trend_k2_percent,
            self.drift_k2_percent,
        ]
        .iter()
        .map(|c| c * c)
        .sum::<f64>()
        .sqrt()
    }

    /// A level's uncertainty from its relative noise (standard error ÷
    /// value) and its leave-one-out residual (%), if it has one.
    pub fn level(&self, relative_noise: f64, loo_percent: Option<f64>) -> LevelUncertainty {
        let noise = if relative_noise.is_finite() {
            200.0 * relative_noise.abs()
        } else {
            100.0
        };
        let fit = loo_percent.map_or(0.0, |r| r.abs() / 4.0);
        LevelUncertainty {
            noise_k2_percent: noise,
            fit_k2_percent: fit,
            // Capped where the LUT file's column stops (1000 %).
            total_k2_percent: (noise * noise + fit * fit + self.scale_total().powi(2))
                .sqrt()
                .min(1000.0),
        }
    }

    /// The lines of the LUT header and report that list the components.
    pub fn describe(&self) -> String {
        let opt = |v: Option<f64>| v.map_or("not declared".to_string(), |v| format!("{v:.3} %"));
        format!(
            "uncertainty (k = 2): meter scale {}, spectral mismatch {}, scale fit {:.3} %, spectral trend {:.3} %, drift {:.3} %; per level also noise and fit (column uncertainty_k2_percent)",
            opt(self.meter_scale_k2_percent),
            opt(self.mismatch_k2_percent),
            self.scale_fit_k2_percent,
            self.spectral_trend_k2_percent,
            self.drift_k2_percent
        )
    }
}

/// |F(S shifted by ±`shift_nm`) / F(S) − 1| (the larger), %.
pub fn mismatch_sensitivity_percent(
    spectral: &CameraSpectral,
    screen: &Spectrum,
    meter: &Table,
    shift_nm: f64,
) -> Result<f64> {
    let f0 = spectral.mismatch_factor(screen, meter)?;
    let mut worst = 0.0f64;
    for sign in [-1.0, 1.0] {
        let shifted: Vec<(f64, f64)> = screen
            .iter()
            .map(|&(l, v)| (l + sign * shift_nm, v))
            .collect();
        let f = spectral.mismatch_factor(&shifted, meter)?;
        worst = worst.max((f / f0 - 1.0).abs());
    }
    Ok(100.0 * worst)
}

/// 2 × the standard error of the mean of `ratios`, % of the mean (0 for
/// fewer than two).
pub fn scale_fit_k2_percent(ratios: &[f64]) -> f64 {
    let n = ratios.len() as f64;
    if ratios.len() < 2 {
        return 0.0;
    }
    let mean = ratios.iter().sum::<f64>() / n;
    let var = ratios.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / (n - 1.0);
    200.0 * (var / n).sqrt() / mean.abs()
}

/// 2 × |`scale` / `top_ratio` − 1| / √3, %: the fitted scale against the
/// top level's own meter/camera ratio, as a rectangular bound (like the
/// drift). A broadband meter's F is the white's; the greys that also set
/// the scale may have another spectrum (an LCD's channels follow their own
/// tone curves), and this is the trend they carry into it.
pub fn spectral_trend_k2_percent(scale: f64, top_ratio: f64) -> f64 {
    if !(scale.is_finite() && top_ratio.is_finite() && top_ratio > 0.0) {
        return 0.0;
    }
    200.0 * (scale / top_ratio - 1.0).abs() / 3f64.sqrt()
}

/// 2 × |drift| / √3, %.
pub fn drift_k2_percent(drift_percent: f64) -> f64 {
    2.0 * drift_percent.abs() / 3f64.sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn components_combine_in_quadrature() {
        let b = Budget {
            meter_scale_k2_percent: Some(3.0),
            mismatch_k2_percent: None,
            scale_fit_k2_percent: 0.0,
            spectral_trend_k2_percent: 0.0,
            drift_k2_percent: drift_k2_percent(3f64.sqrt() * 2.0),
        };
        assert!((b.drift_k2_percent - 4.0).abs() < 1e-12);
        assert!((b.scale_total() - 5.0).abs() < 1e-12);
        // Noise 0.6 % standard error → 1.2 %; LOO 6.4 % → 1.6 %; with 5: √(1.44 + 2.56 + 25).
        let l = b.level(0.006, Some(-6.4));
        assert!((l.noise_k2_percent - 1.2).abs() < 1e-12);
        assert!((l.fit_k2_percent - 1.6).abs() < 1e-12);
        assert!((l.total_k2_percent - 29f64.sqrt()).abs() < 1e-12);
        // Ratios 1, 2, 3: mean 2, sd 1, se 1/√3 → 2·(1/√3)/2 = 57.7 %.
        assert!((scale_fit_k2_percent(&[1.0, 2.0, 3.0]) - 100.0 / 3f64.sqrt()).abs() < 1e-9);
        assert!(b.describe().contains("spectral mismatch not declared"));
        // A scale 0.3 % above the white's ratio: 2 · 0.3 / √3 = 0.3464 %.
        let t = spectral_trend_k2_percent(1.003, 1.0);
        assert!((t - 0.6 / 3f64.sqrt()).abs() < 1e-9, "{t}");
        assert_eq!(spectral_trend_k2_percent(1.0, 0.0), 0.0);
        let with = Budget {
            spectral_trend_k2_percent: 12.0,
            ..b.clone()
        };
        assert!((with.scale_total() - 13.0).abs() < 1e-12);
    }
}
