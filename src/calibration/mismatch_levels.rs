//! The spectral mismatch factor per drive level. An LCD's grey levels mix
//! three channels that follow their own tone curves, so the screen's
//! spectrum, and with it F (docs/CALIBRATION.md), changes with the level.
//! A spectroradiometer measures the spectrum at a few levels
//! ([`measure`]); [`MismatchCurve`] holds F per measured level, interpolates
//! it linearly in level for each meter reading of the absolute scale, and
//! bounds what that interpolation leaves ([`MismatchCurve::trend_k2_percent`]).

use serde::{Deserialize, Serialize};

use super::budget::mismatch_sensitivity_percent;
use super::checkpoint::Checkpoint;
use super::mismatch::{check_screen_spectrum, CameraSpectral};
use super::{read_meter, show_level, Instruments};
use crate::error::{Error, Result};
use crate::instruments::SpotMeter;
use crate::radiometry::spectrum::Table;

/// F at one measured level.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LevelMismatch {
    pub level: u32,
    /// Mean F of the level's spectra.
    pub factor: f64,
    /// Spectra measured at the level.
    pub spectra: usize,
    /// 2 × the standard error of F over the spectra, % (0 for one).
    pub noise_k2_percent: f64,
    /// |F(spectrum shifted by ±`screen_spectrum_uncertainty_nm`) / F − 1|,
    /// %, if that uncertainty is declared.
    pub wavelength_k2_percent: Option<f64>,
}

/// F against drive level: linear between the measured levels, held at the
/// end values outside them.
#[derive(Debug, Clone, PartialEq)]
pub struct MismatchCurve {
    points: Vec<LevelMismatch>,
}

/// The spectra measured at one drive level, `(nm, value)` each.
pub type LevelSpectra = (u32, Vec<Vec<(f64, f64)>>);

/// One spectroradiometer reading, as checkpointed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SpectrumReading {
    pub level: u32,
    pub repeat: usize,
    /// `(nm, W m⁻² sr⁻¹ nm⁻¹)`.
    pub spectrum: Vec<(f64, f64)>,
}

impl MismatchCurve {
    /// From per-level values (e.g. read back from a report): levels
    /// strictly increasing, at least two, every F finite and positive.
    pub fn new(points: Vec<LevelMismatch>) -> Result<MismatchCurve> {
        if points.len() < 2 {
            return Err(Error::invalid(
                "mismatch_by_level",
                format!("needs at least two levels, found {}", points.len()),
            ));
        }
        if let Some(w) = points.windows(2).find(|w| w[1].level <= w[0].level) {
            return Err(Error::invalid(
                "mismatch_by_level",
                format!("levels must increase: {} after {}", w[1].level, w[0].level),
            ));
        }
        if let Some(p) = points
            .iter()
            .find(|p| !(p.factor.is_finite() && p.factor > 0.0))
        {
            return Err(Error::invalid(
                "mismatch_by_level",
                format!("F at level {} is {}", p.level, p.factor),
            ));
        }
        Ok(MismatchCurve { points })
    }

    /// F of every level's spectra (`(level, spectra)` in increasing level)
    /// through the camera's weighting and the meter's response; with
    /// `shift_nm` the per-level sensitivity to the wavelength scale.
    pub fn from_spectra(
        spectral: &CameraSpectral,
        meter: &Table,
        levels: &[LevelSpectra],
        shift_nm: Option<f64>,
    ) -> Result<MismatchCurve> {
        let mut points = Vec::with_capacity(levels.len());
        for (level, spectra) in levels {
            let f: Vec<f64> = spectra
                .iter()
                .map(|s| spectral.mismatch_factor(s, meter))
                .collect::<Result<_>>()
                .map_err(|e| Error::Other(format!("spectrum at drive level {level}: {e}")))?;
            let Some(first) = spectra.first() else {
                return Err(Error::Other(format!(
                    "no spectrum measured at drive level {level}"
                )));
            };
            let wavelength_k2_percent = shift_nm
                .map(|nm| mismatch_sensitivity_percent(spectral, first, meter, nm))
                .transpose()?;
            points.push(LevelMismatch {
                level: *level,
                factor: f.iter().sum::<f64>() / f.len() as f64,
                spectra: f.len(),
                noise_k2_percent: super::budget::scale_fit_k2_percent(&f),
                wavelength_k2_percent,
            });
        }
        MismatchCurve::new(points)
    }

    /// The measured levels.
    pub fn points(&self) -> &[LevelMismatch] {
        &self.points
    }

    /// F at the highest measured level (the white's, on the default levels).
    pub fn top(&self) -> f64 {
        self.points[self.points.len() - 1].factor
    }

    /// F at drive `level`: linear between the measured levels, the end
    /// values outside them.
    pub fn at(&self, level: f64) -> f64 {
        let p = &self.points;
        let k = p
            .partition_point(|q| (q.level as f64) <= level)
            .clamp(1, p.len() - 1);
        let (a, b) = (&p[k - 1], &p[k]);
        let t = ((level - a.level as f64) / (b.level as f64 - a.level as f64)).clamp(0.0, 1.0);
        a.factor + t * (b.factor - a.factor)
    }

    /// Each interior level's F against the line through its two neighbours,
    /// % (leave-one-out).
    pub fn leave_one_out_percent(&self) -> Vec<(u32, f64)> {
        self.points
            .windows(3)
            .map(|w| {
                let t = (w[1].level - w[0].level) as f64 / (w[2].level - w[0].level) as f64;
                let line = w[0].factor + t * (w[2].factor - w[0].factor);
                (w[1].level, 100.0 * (line / w[1].factor - 1.0))
            })
            .collect()
    }

    /// Bound (%) on the error of [`at`](Self::at) over the levels `used`:
    /// inside the measured span, the largest leave-one-out residual ÷ 4
    /// (leaving a level out doubles the spacing; a line's error on smooth
    /// data falls as h²), or with two levels half their F difference; outside
    /// it, the end interval's slope times the distance held flat.
    pub fn interpolation_bound_percent(&self, used: &[u32]) -> f64 {
        let p = &self.points;
        let inside = match self.leave_one_out_percent() {
            loo if !loo.is_empty() => loo.iter().fold(0.0f64, |m, r| m.max(r.1.abs())) / 4.0,
            _ => 50.0 * (p[1].factor / p[0].factor - 1.0).abs(),
        };
        let slope = |a: &LevelMismatch, b: &LevelMismatch| {
            (b.factor - a.factor) / (b.level - a.level) as f64
        };
        let (lo, hi) = (&p[0], &p[p.len() - 1]);
        let (s_lo, s_hi) = (slope(&p[0], &p[1]), slope(&p[p.len() - 2], hi));
        let outside = used
            .iter()
            .map(|&l| {
                if l < lo.level {
                    100.0 * (s_lo * (lo.level - l) as f64 / lo.factor).abs()
                } else if l > hi.level {
                    100.0 * (s_hi * (l - hi.level) as f64 / hi.factor).abs()
                } else {
                    0.0
                }
            })
            .fold(0.0f64, f64::max);
        inside.max(outside)
    }

    /// The budget's spectral-trend term with F per level, k = 2, %: the
    /// interpolation bound over the levels `used` by the scale as a
    /// rectangular limit (2/√3 × bound), in quadrature with the largest
    /// noise of a measured F.
    pub fn trend_k2_percent(&self, used: &[u32]) -> f64 {
        let interp = 2.0 * self.interpolation_bound_percent(used) / 3f64.sqrt();
        let noise = self
            .points
            .iter()
            .fold(0.0f64, |m, p| m.max(p.noise_k2_percent));
        interp.hypot(noise)
    }

    /// The largest wavelength-scale sensitivity over the levels, %, if
    /// declared.
    pub fn wavelength_k2_percent(&self) -> Option<f64> {
        self.points
            .iter()
            .map(|p| p.wavelength_k2_percent)
            .try_fold(0.0f64, |m, w| w.map(|w| m.max(w)))
    }

    /// `level F, …` for headers and reports.
    pub fn describe(&self) -> String {
        let items: Vec<String> = self
            .points
            .iter()
            .map(|p| format!("{} {:.5}", p.level, p.factor))
            .collect();
        format!("F per level (level F): {}", items.join(", "))
    }
}

/// Measures the screen's spectrum `repeats` times at each of `levels`
/// (after the campaign's other patches; F depends on the spectrum's shape
/// only, so the screen's drift does not matter) with `instrument`, or the
/// campaign's meter when there is none. Each spectrum must cover the
/// camera's band (`band_nm`) as a screen spectrum file must. Checkpointed
/// as `spectrum_<level>_r<repeat>`.
#[allow(clippy::too_many_arguments)]
pub fn measure(
    inst: &mut Instruments,
    mut instrument: Option<&mut dyn SpotMeter>,
    ckpt: &mut Checkpoint,
    levels: &[u32],
    repeats: usize,
    bits: u32,
    settle: f64,
    band_nm: [f64; 2],
) -> Result<Vec<LevelSpectra>> {
    let mut out = Vec::with_capacity(levels.len());
    for &level in levels {
        let mut spectra = Vec::with_capacity(repeats);
        for repeat in 0..repeats {
            let name = format!("spectrum_{level:04}_r{repeat}");
            let reading = match ckpt.get::<SpectrumReading>(&name)? {
                Some(r) => r,
                None => {
                    show_level(inst.display, level, bits)?;
                    (inst.wait)(settle);
                    let r = match instrument.as_deref_mut() {
                        Some(m) => read_meter(&mut Some(m), &name, level)?,
                        None => read_meter(&mut inst.meter, &name, level)?,
                    };
                    let spectrum = r.and_then(|r| r.spectrum).ok_or_else(|| {
                        Error::invalid(
                            "calibrate.spectrum_levels",
                            format!(
                                "drive level {level}: the instrument gave no spectrum \
                                 (configure [calibrate.spectroradiometer])"
                            ),
                        )
                    })?;
                    let r = SpectrumReading {
                        level,
                        repeat,
                        spectrum,
                    };
                    ckpt.record(&name, &r)?;
                    r
                }
            };
            check_spectrum(&reading.spectrum, band_nm).map_err(|e| {
                Error::Other(format!("spectrum `{name}` (drive level {level}): {e}"))
            })?;
            spectra.push(reading.spectrum);
        }
        out.push((level, spectra));
    }
    Ok(out)
}

/// Finite, increasing wavelengths and finite values, covering the band.
fn check_spectrum(s: &[(f64, f64)], band_nm: [f64; 2]) -> Result<()> {
    if s.iter().any(|p| !(p.0.is_finite() && p.1.is_finite())) {
        return Err(Error::Other("a non-finite value".into()));
    }
    if s.windows(2).any(|w| w[1].0 <= w[0].0) {
        return Err(Error::Other("wavelengths do not increase".into()));
    }
    check_screen_spectrum(s, band_nm)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::radiometry::spectrum::{Response, SolarSpectrum, LIGHT_SPEED, PLANCK};

    fn point(level: u32, factor: f64) -> LevelMismatch {
        LevelMismatch {
            level,
            factor,
            spectra: 1,
            noise_k2_percent: 0.0,
            wavelength_k2_percent: None,
        }
    }

    /// Two synthetic screens (a "white" and a bluer "grey"), a flat camera
    /// and a meter whose response falls to the red: F of each against
    /// brute-force midpoint sums written here, and F(level) between them
    /// the straight line, held outside.
    #[test]
    fn f_per_level_matches_an_independent_quadrature_and_interpolates_linearly() {
        let cam = CameraSpectral {
            band_nm: [450.0, 820.0],
            qe: Response::Constant(0.5),
            transmission: Response::Constant(1.0),
            sun: SolarSpectrum::blackbody(5778.0, 1361.0).unwrap(),
        };
        let gauss = |c: f64, w: f64| move |nm: f64| (-((nm - c) / w).powi(2)).exp();
        let white =
            |nm: f64| gauss(450.0, 20.0)(nm) + gauss(545.0, 25.0)(nm) + gauss(620.0, 20.0)(nm);
        let grey = |nm: f64| {
            1.4 * gauss(450.0, 20.0)(nm) + gauss(545.0, 25.0)(nm) + 0.8 * gauss(620.0, 20.0)(nm)
        };
        let tab = |f: &dyn Fn(f64) -> f64| -> Vec<(f64, f64)> {
            (0..=400)
                .map(|k| (380.0 + k as f64, f(380.0 + k as f64)))
                .collect()
        };
        // Meter: 1 at 380 nm falling linearly to 0.2 at 780 nm.
        let meter = Table::new(vec![380e-9, 780e-9], vec![1.0, 0.2], "m").unwrap();
        let m = |nm: f64| 1.0 - 0.8 * (nm - 380.0) / 400.0;
        // Independent F: midpoint sums at 0.01 nm of the tabulated (linear)
        // spectra, R = QE λ/(hc) in the band, and the Sun's norm.
        let lin = |s: &[(f64, f64)], nm: f64| {
            let k = ((nm - 380.0).floor() as usize).min(399);
            let t = nm - s[k].0;
            s[k].1 + t * (s[k + 1].1 - s[k].1)
        };
        let r = |nm: f64| 0.5 * nm * 1e-9 / (PLANCK * LIGHT_SPEED);
        let mid = |lo: f64, hi: f64, f: &dyn Fn(f64) -> f64| {
            let n = ((hi - lo) / 0.01).round() as usize;
            (0..n).map(|k| f(lo + (k as f64 + 0.5) * 0.01)).sum::<f64>() * 0.01
        };
        let norm = mid(450.0, 820.0, &|nm| cam.sun.eval(nm * 1e-9))
            / mid(450.0, 820.0, &|nm| cam.sun.eval(nm * 1e-9) * r(nm));
        let f_ref = |s: &[(f64, f64)]| {
            mid(450.0, 780.0, &|nm| lin(s, nm) * r(nm))
                / mid(380.0, 780.0, &|nm| lin(s, nm) * m(nm))
                * norm
        };
        let (sw, sg) = (tab(&white), tab(&grey));
        let (fw, fg) = (f_ref(&sw), f_ref(&sg));
        // Two spectra of the grey at different scales: F is shape only.
        let sg2: Vec<(f64, f64)> = sg.iter().map(|&(l, v)| (l, 3.0 * v)).collect();
        let curve = MismatchCurve::from_spectra(
            &cam,
            &meter,
            &[(100, vec![sg.clone(), sg2]), (255, vec![sw.clone()])],
            Some(1.0),
        )
        .unwrap();
        let p = curve.points();
        assert!(
            (p[0].factor / fg - 1.0).abs() < 1e-5,
            "{} vs {fg}",
            p[0].factor
        );
        assert!(
            (p[1].factor / fw - 1.0).abs() < 1e-5,
            "{} vs {fw}",
            p[1].factor
        );
        // The bluer grey has a smaller F (the meter favours the blue).
        assert!(fg < fw * 0.99, "{fg} {fw}");
        assert!(p[0].noise_k2_percent < 1e-9 && p[0].spectra == 2);
        // Linear in level between, held outside.
        let expect = fg + (177.5 - 100.0) / 155.0 * (fw - fg);
        assert!((curve.at(177.5) / expect - 1.0).abs() < 1e-5);
        assert!((curve.at(40.0) / fg - 1.0).abs() < 1e-5);
        assert_eq!(curve.at(255.0), curve.top());
        // Two levels: the bound is half their difference, and a level held
        // 100 below the lowest adds the slope's extrapolation.
        let half = 50.0 * (fw / fg - 1.0).abs();
        // (F's own 1e-5 agreement with the reference allows 1e-3 relative.)
        let b = curve.interpolation_bound_percent(&[150]);
        assert!((b / half - 1.0).abs() < 1e-3, "{b} vs {half}");
        let slope = 100.0 * (fw - fg) / 155.0 * 100.0 / fg;
        let b = curve.interpolation_bound_percent(&[0, 150]);
        assert!(slope.abs() > half, "{slope} {half}");
        assert!((b / slope.abs() - 1.0).abs() < 1e-3, "{b} vs {slope}");
    }

    /// F quadratic in level: the leave-one-out residual of each interior
    /// point is the closed form −a (Δ)² / F, the bound a quarter of the
    /// largest, and the trend term 2/√3 of that.
    #[test]
    fn leave_one_out_of_a_quadratic_f() {
        let a = 1e-7;
        let f = |l: f64| 0.8 - a * (l - 255.0).powi(2);
        let levels = [64u32, 128, 192, 255];
        let curve =
            MismatchCurve::new(levels.iter().map(|&l| point(l, f(l as f64))).collect()).unwrap();
        let loo = curve.leave_one_out_percent();
        assert_eq!(loo.len(), 2);
        // For f = c − a (l − 255)² the chord through the neighbours lies
        // below the parabola by a (l1 − l0)(l2 − l1).
        for (k, &(level, r)) in loo.iter().enumerate() {
            let (l0, l1, l2) = (levels[k] as f64, levels[k + 1] as f64, levels[k + 2] as f64);
            let expect = 100.0 * (-a * (l1 - l0) * (l2 - l1)) / f(l1);
            assert_eq!(level, levels[k + 1]);
            assert!((r - expect).abs() < 1e-9, "{r} vs {expect}");
        }
        let worst = loo.iter().fold(0.0f64, |m, r| m.max(r.1.abs()));
        assert!((curve.interpolation_bound_percent(&[128, 255]) - worst / 4.0).abs() < 1e-12);
        assert!((curve.trend_k2_percent(&[128]) - 2.0 * worst / 4.0 / 3f64.sqrt()).abs() < 1e-12);
        // Bad curves are refused.
        assert!(MismatchCurve::new(vec![point(10, 0.8)]).is_err());
        assert!(MismatchCurve::new(vec![point(10, 0.8), point(10, 0.8)]).is_err());
        assert!(MismatchCurve::new(vec![point(10, 0.8), point(20, f64::NAN)]).is_err());
    }
}
