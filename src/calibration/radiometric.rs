//! The radiometric calibration: drive level → camera-effective radiance of
//! the screen, written as the display LUT `optistim run` reads
//! ([`facility::lut`](crate::facility::lut)), with a JSON report and a
//! PNG plot.
//!
//! Method (docs/CALIBRATION.md): uniform full-screen patches at the levels
//! of [`level_ladder`], each `repeats` times, in a seeded random order,
//! bracketed by the reference level at start and end (drift, warm-up).
//! Optionally the ambient (screen off) first. For each patch the camera
//! gives the relative response C = mean DN of the central region, dark
//! subtracted, divided by the exposure (auto-ranged per patch so nothing
//! saturates and dark patches get signal), minus the ambient; the spot
//! meter (or a known camera responsivity) gives the absolute scale. The
//! repeats' scatter is the noise; data that decrease beyond 3σ of it are
//! refused with the levels named. The LUT is the measured table; the run's
//! PCHIP interpolates it, and leave-one-out PCHIP residuals are reported.
//! With `spectrum_levels` (or a spectroradiometer) the screen's spectrum is
//! measured at several levels after the patches and each meter reading is
//! scaled by F at its own level ([`mismatch_levels`](super::mismatch_levels)).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::budget::{self, Budget, LevelUncertainty};
use super::checkpoint::Checkpoint;
use super::config::{level_ladder, top_level, AmbientMode, CalibrateConfig};
use super::mismatch::{CameraSpectral, Spectrum};
use super::mismatch_levels::{self, LevelMismatch, MismatchCurve};
use super::{progress, read_meter, show_level, AutoExposure, Instruments, Rect};
use crate::error::{Error, Result};
use crate::facility::lut::{Pchip, LUT_HEADER_UNCERTAINTY};
use crate::figures::{curve_figure, CurveFigure, Panel, Series, PALETTE};
use crate::instruments::SpotMeter;
use crate::radiometry::spectrum::Table;

/// Name of the routine in checkpoints and reports.
pub const ROUTINE: &str = "radiometric";

/// One measurement, as checkpointed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Measurement {
    pub level: u32,
    pub repeat: usize,
    /// Exposure used, s.
    pub exposure_s: f64,
    /// Region mean, dark subtracted, per second of exposure (DN/s).
    pub dn_per_s: f64,
    /// Standard error of that mean from the pixels' scatter, DN/s.
    pub dn_per_s_err: f64,
    /// Meter reading (its unit), if there is a meter.
    pub meter: Option<f64>,
    /// Spectroradiometer spectrum `(nm, W m⁻² sr⁻¹ nm⁻¹)`.
    pub spectrum: Option<Vec<(f64, f64)>>,
}

/// What the routine needs besides the instruments.
pub struct Setup<'a> {
    pub cfg: &'a CalibrateConfig,
    /// Bits of the display.
    pub bits: u32,
    /// The camera's spectral weighting (from the scene), for F and for
    /// spectroradiometer spectra.
    pub spectral: Option<CameraSpectral>,
    /// The meter's spectral response M(λ).
    pub meter_response: Option<Table>,
    /// A configured screen spectrum, `(nm, relative)`.
    pub screen_spectrum: Option<Vec<(f64, f64)>>,
    /// The spectroradiometer measuring the screen's spectrum at
    /// `calibrate.spectrum_levels` (none: the meter, if those are given).
    pub spectroradiometer: Option<&'a mut dyn SpotMeter>,
    /// With `ambient = "prompt"`: called with `true` to have the screen
    /// switched off, `false` to have it back on.
    pub screen_power: Option<&'a mut dyn FnMut(bool) -> Result<()>>,
    /// Free text for the provenance header (e.g. the facility file).
    pub source: String,
}

/// The result per level.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LevelResult {
    pub level: u32,
    /// Mean relative camera response over the repeats, DN/s.
    pub camera_dn_per_s: f64,
    /// Its noise (standard error from the repeats, or from the pixels for
    /// one repeat), DN/s.
    pub noise_dn_per_s: f64,
    /// Mean meter reading (ambient subtracted), if any.
    pub meter: Option<f64>,
    /// Camera-effective radiance, W m⁻² sr⁻¹ (the LUT value).
    pub radiance: f64,
    /// Leave-one-out PCHIP residual, % (interior levels).
    pub loo_residual_percent: Option<f64>,
    /// Scatter of the repeats, % of the mean.
    pub repeat_scatter_percent: Option<f64>,
    /// Expanded uncertainty of the LUT value and its per-level components.
    #[serde(default)]
    pub uncertainty: LevelUncertainty,
}

/// The report (also written as JSON).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Report {
    pub levels: Vec<LevelResult>,
    pub repeats: usize,
    pub reference_level: u32,
    /// Reference level's camera response at end / start − 1, %.
    pub drift_percent: f64,
    /// How the absolute scale was set.
    pub scale_method: String,
    /// Radiance per DN/s.
    pub scale: f64,
    /// Spectral mismatch factor used (scalar meter); with F per level, the
    /// highest measured level's.
    pub mismatch_factor: Option<f64>,
    /// F per measured level, when the spectra were measured (applied to
    /// each reading interpolated in level).
    #[serde(default)]
    pub mismatch_by_level: Vec<LevelMismatch>,
    /// The scale-wide components of the uncertainty budget.
    #[serde(default)]
    pub budget: Budget,
    /// Ambient in camera-effective radiance (W m⁻² sr⁻¹), if measured.
    pub ambient_radiance: Option<f64>,
    pub black_radiance: f64,
    pub max_radiance: f64,
    /// Leave-one-out residuals over levels above 1 % of the maximum, %.
    pub loo_rms_percent: f64,
    pub loo_max_percent: f64,
    pub camera: String,
    pub meter: String,
    /// How the frames were dark-corrected.
    #[serde(default)]
    pub dark: String,
    pub exposure_range_s: [f64; 2],
    pub region: Rect,
    pub date: String,
    pub software: String,
}

/// Runs the measurements (resuming from `ckpt`) and reduces them.
pub fn run(inst: &mut Instruments, setup: &mut Setup, ckpt: &mut Checkpoint) -> Result<Report> {
    let cfg = setup.cfg;
    let top = top_level(setup.bits)?;
    let ladder = level_ladder(cfg.levels, top, cfg.spacing_power);
    let reference = cfg.reference(setup.bits);
    let mut order: Vec<(u32, usize)> = (0..cfg.repeats)
        .flat_map(|r| ladder.iter().map(move |&l| (l, r)))
        .collect();
    super::shuffle(&mut order, cfg.seed);
    let camera_name = inst.camera.describe();
    let meter_name = inst
        .meter
        .as_ref()
        .map_or("none".to_string(), |m| m.describe());

    let power = setup.screen_power.take();
    let spectroradiometer = setup.spectroradiometer.take();
    let setup: &Setup = setup;
    let mut taker = Taker::new(setup, inst)?;
    let ambient = match cfg.ambient {
        AmbientMode::None => None,
        AmbientMode::Prompt => Some(taker.ambient(inst, power, ckpt)?),
    };
    let total = order.len() as u64 + 2;
    let bar = progress(total, "radiometric");
    let mut all = Vec::with_capacity(order.len());
    let start = taker.take(inst, ckpt, "ref_start", reference, 0, &bar)?;
    for &(level, repeat) in &order {
        let name = format!("level_{level:04}_r{repeat}");
        all.push(taker.take(inst, ckpt, &name, level, repeat, &bar)?);
    }
    let end = taker.take(inst, ckpt, "ref_end", reference, 0, &bar)?;
    bar.finish_and_clear();
    let drift_percent = (end.dn_per_s / start.dn_per_s - 1.0) * 100.0;
    let curve = measured_mismatch(inst, spectroradiometer, setup, ckpt)?;

    let mut levels = reduce(&ladder, &all, cfg.repeats, ambient.as_ref())?;
    check_monotone(&levels)?;
    let scale = absolute_scale(&mut levels, setup, curve.as_ref())?;
    for l in &mut levels {
        l.radiance = (scale.factor * l.camera_dn_per_s).max(0.0);
    }
    pool_adjacent_violators(&mut levels);
    if levels.last().map(|l| l.radiance) <= levels.first().map(|l| l.radiance) {
        return Err(Error::Other(
            "the screen does not respond: the top level is not brighter than black".into(),
        ));
    }
    let (rms, max) = leave_one_out(&mut levels)?;
    let budget = Budget {
        meter_scale_k2_percent: scale.meter_k2_percent,
        mismatch_k2_percent: scale.mismatch_k2_percent,
        scale_fit_k2_percent: scale.fit_k2_percent,
        spectral_trend_k2_percent: scale.spectral_trend_k2_percent,
        drift_k2_percent: budget::drift_k2_percent(drift_percent),
    };
    for l in &mut levels {
        let rel = l.noise_dn_per_s / l.camera_dn_per_s;
        l.uncertainty = budget.level(rel, l.loo_residual_percent);
    }
    Ok(Report {
        budget,
        repeats: cfg.repeats,
        reference_level: reference,
        drift_percent,
        scale_method: scale.method,
        scale: scale.factor,
        mismatch_factor: scale.mismatch,
        mismatch_by_level: curve.map_or(Vec::new(), |c| c.points().to_vec()),
        ambient_radiance: ambient.map(|a| a.dn_per_s * scale.factor),
        black_radiance: levels[0].radiance,
        max_radiance: levels.last().map_or(0.0, |l| l.radiance),
        loo_rms_percent: rms,
        loo_max_percent: max,
        levels,
        camera: camera_name,
        meter: meter_name,
        dark: inst.darks.describe(),
        exposure_range_s: taker.exposure_range,
        region: taker.rect,
        date: crate::utc::now(),
        software: format!("optistim {}", env!("CARGO_PKG_VERSION")),
    })
}

/// Takes (or reuses from the checkpoint) single measurements.
struct Taker {
    auto: AutoExposure,
    rect: Rect,
    bits: u32,
    settle: f64,
    exposure_range: [f64; 2],
}

impl Taker {
    fn new(setup: &Setup, inst: &mut Instruments) -> Result<Taker> {
        let cfg = setup.cfg;
        // The region needs the frame size: from the config, else one frame.
        let (w, h) = match cfg.camera.resolution {
            Some([w, h]) => (w, h),
            None => {
                let f = inst
                    .camera
                    .capture(&crate::instruments::CaptureRequest::light(
                        "probe",
                        cfg.camera.exposure,
                    ))?;
                (f.width, f.height)
            }
        };
        Ok(Taker {
            auto: AutoExposure::of(cfg),
            rect: Rect::from_fractions(cfg.region, w, h),
            bits: setup.bits,
            settle: cfg.settle,
            exposure_range: [f64::INFINITY, 0.0],
        })
    }

    fn take(
        &mut self,
        inst: &mut Instruments,
        ckpt: &mut Checkpoint,
        name: &str,
        level: u32,
        repeat: usize,
        bar: &indicatif::ProgressBar,
    ) -> Result<Measurement> {
        let m = match ckpt.get::<Measurement>(name)? {
            Some(m) => m,
            None => {
                show_level(inst.display, level, self.bits)?;
                (inst.wait)(self.settle);
                let r = self
                    .auto
                    .capture(inst.camera, inst.darks, name, level, self.rect)?;
                let reading = read_meter(&mut inst.meter, name, level)?;
                let t = r.frame.exposure_s;
                let m = Measurement {
                    level,
                    repeat,
                    exposure_s: t,
                    dn_per_s: r.stats.mean / t,
                    dn_per_s_err: r.stats.std / (r.stats.pixels as f64).sqrt() / t,
                    meter: reading.as_ref().map(|r| r.value),
                    spectrum: reading.and_then(|r| r.spectrum),
                };
                if !(t.is_finite() && t > 0.0) {
                    return Err(Error::Other(format!(
                        "pattern `{name}` (drive level {level}): camera reported exposure {t} s"
                    )));
                }
                ckpt.record(name, &m)?;
                m
            }
        };
        self.exposure_range[0] = self.exposure_range[0].min(m.exposure_s);
        self.exposure_range[1] = self.exposure_range[1].max(m.exposure_s);
        bar.inc(1);
        bar.set_message(format!(
            "level {level}: {:.4e} DN/s{}",
            m.dn_per_s,
            m.meter
                .map_or(String::new(), |v| format!(", meter {v:.4e}"))
        ));
        Ok(m)
    }

    fn ambient(
        &mut self,
        inst: &mut Instruments,
        power: Option<&mut (dyn FnMut(bool) -> Result<()> + '_)>,
        ckpt: &mut Checkpoint,
    ) -> Result<Measurement> {
        if let Some(m) = ckpt.get::<Measurement>("ambient")? {
            return Ok(m);
        }
        let power = power.ok_or_else(|| {
            Error::invalid(
                "calibrate.ambient",
                "\"prompt\" needs an operator (or a simulated screen switch)",
            )
        })?;
        power(false)?;
        (inst.wait)(self.settle);
        let frame = inst
            .camera
            .capture(&crate::instruments::CaptureRequest::light(
                "ambient",
                self.auto.longest(),
            ))?;
        let dark = inst.darks.dark_for(inst.camera, &frame)?;
        let stats = super::region_stats(&frame, dark.as_deref().map(|d| d.as_slice()), self.rect)?;
        let reading = read_meter(&mut inst.meter, "ambient", 0)?;
        power(true)?;
        let t = frame.exposure_s;
        let m = Measurement {
            level: 0,
            repeat: 0,
            exposure_s: t,
            dn_per_s: stats.mean / t,
            dn_per_s_err: stats.std / (stats.pixels as f64).sqrt() / t,
            meter: reading.as_ref().map(|r| r.value),
            spectrum: reading.and_then(|r| r.spectrum),
        };
        ckpt.record("ambient", &m)?;
        Ok(m)
    }
}

/// F per level from spectra measured now at `calibrate.spectrum_levels`,
/// when a spectroradiometer or those levels are configured.
fn measured_mismatch(
    inst: &mut Instruments,
    spectroradiometer: Option<&mut dyn SpotMeter>,
    setup: &Setup,
    ckpt: &mut Checkpoint,
) -> Result<Option<MismatchCurve>> {
    let cfg = setup.cfg;
    let Some(levels) = cfg.spectrum_levels(setup.bits) else {
        return Ok(None);
    };
    let (Some(spectral), Some(meter)) = (&setup.spectral, &setup.meter_response) else {
        return Err(Error::invalid(
            "calibrate.meter.spectral_response",
            "missing: F per level needs the meter's spectral response and the scene's camera",
        ));
    };
    let spectra = mismatch_levels::measure(
        inst,
        spectroradiometer,
        ckpt,
        &levels,
        cfg.repeats,
        setup.bits,
        cfg.settle,
        spectral.band_nm,
    )?;
    MismatchCurve::from_spectra(
        spectral,
        meter,
        &spectra,
        cfg.screen_spectrum_uncertainty_nm,
    )
    .map(Some)
}

/// Averages the repeats of each level (ambient subtracted).
fn reduce(
    ladder: &[u32],
    all: &[Measurement],
    repeats: usize,
    ambient: Option<&Measurement>,
) -> Result<Vec<LevelResult>> {
    let amb = ambient.map_or(0.0, |a| a.dn_per_s);
    let amb_meter = ambient.and_then(|a| a.meter).unwrap_or(0.0);
    ladder
        .iter()
        .map(|&level| {
            let ms: Vec<&Measurement> = all.iter().filter(|m| m.level == level).collect();
            let n = ms.len() as f64;
            let mean = ms.iter().map(|m| m.dn_per_s).sum::<f64>() / n - amb;
            let noise = if ms.len() >= 2 {
                let mu = mean + amb;
                let var = ms.iter().map(|m| (m.dn_per_s - mu).powi(2)).sum::<f64>() / (n - 1.0);
                // The repeats' scatter, but never below the pixels' own noise.
                let pix = ms.iter().map(|m| m.dn_per_s_err).fold(0.0, f64::max);
                (var / n).sqrt().max(pix / n.sqrt())
            } else {
                ms[0].dn_per_s_err
            };
            let meters: Vec<f64> = ms.iter().filter_map(|m| m.meter).collect();
            let meter = (!meters.is_empty())
                .then(|| meters.iter().sum::<f64>() / meters.len() as f64 - amb_meter);
            let scatter = (ms.len() >= 2 && mean.abs() > 0.0).then(|| {
                let mu = mean + amb;
                let sd =
                    (ms.iter().map(|m| (m.dn_per_s - mu).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
                100.0 * sd / mu.abs()
            });
            if !mean.is_finite() {
                return Err(Error::Other(format!(
                    "drive level {level}: non-finite response"
                )));
            }
            let _ = repeats;
            Ok(LevelResult {
                level,
                camera_dn_per_s: mean,
                noise_dn_per_s: noise,
                meter,
                radiance: 0.0,
                loo_residual_percent: None,
                repeat_scatter_percent: scatter,
                uncertainty: LevelUncertainty::default(),
            })
        })
        .collect()
}

/// Refuses a response that decreases beyond 3σ of the noise, naming the
/// levels.
pub fn check_monotone(levels: &[LevelResult]) -> Result<()> {
    let mut bad = Vec::new();
    for j in 1..levels.len() {
        for i in 0..j {
            let (a, b) = (&levels[i], &levels[j]);
            let sigma = a.noise_dn_per_s.hypot(b.noise_dn_per_s);
            if b.camera_dn_per_s < a.camera_dn_per_s - 3.0 * sigma {
                bad.push(format!(
                    "level {} ({:.4e} DN/s) below level {} ({:.4e} DN/s) by {:.1}σ",
                    b.level,
                    b.camera_dn_per_s,
                    a.level,
                    a.camera_dn_per_s,
                    (a.camera_dn_per_s - b.camera_dn_per_s) / sigma.max(f64::MIN_POSITIVE)
                ));
                break;
            }
        }
    }
    if bad.is_empty() {
        Ok(())
    } else {
        Err(Error::Other(format!(
            "the screen's response is not monotone beyond its noise: {}",
            bad.join("; ")
        )))
    }
}

/// Makes the radiances non-decreasing (within-noise dips are pooled with
/// their neighbours) and non-negative, as the LUT file requires.
fn pool_adjacent_violators(levels: &mut [LevelResult]) {
    let mut blocks: Vec<(f64, usize)> = Vec::new();
    for l in levels.iter() {
        blocks.push((l.radiance, 1));
        while blocks.len() >= 2 && blocks[blocks.len() - 2].0 > blocks[blocks.len() - 1].0 {
            let (v2, n2) = blocks.pop().unwrap();
            let (v1, n1) = blocks.pop().unwrap();
            blocks.push((
                (v1 * n1 as f64 + v2 * n2 as f64) / (n1 + n2) as f64,
                n1 + n2,
            ));
        }
    }
    let mut i = 0;
    for (v, n) in blocks {
        for l in &mut levels[i..i + n] {
            l.radiance = v.max(0.0);
        }
        i += n;
    }
}

struct Scale {
    factor: f64,
    method: String,
    mismatch: Option<f64>,
    /// Budget components, k = 2, %.
    fit_k2_percent: f64,
    meter_k2_percent: Option<f64>,
    mismatch_k2_percent: Option<f64>,
    spectral_trend_k2_percent: f64,
}

/// Fraction of the top level's signal above which the meter sets the
/// absolute scale: where its relative noise is smallest and where a
/// broadband meter's single F (from the screen's white spectrum) holds.
pub const SCALE_FLOOR: f64 = 0.1;

/// Radiance per DN/s: least squares of the meter's camera-effective
/// radiance against the camera response over the levels above 10 % of the
/// top (where the meter's relative noise is smallest), or the configured
/// camera responsivity.
fn absolute_scale(
    levels: &mut [LevelResult],
    setup: &Setup,
    curve: Option<&MismatchCurve>,
) -> Result<Scale> {
    let cfg = setup.cfg;
    let has_meter = levels.iter().any(|l| l.meter.is_some());
    if !has_meter {
        let r = cfg.camera_responsivity.ok_or_else(|| {
            Error::invalid(
                "calibrate.camera_responsivity",
                "missing: without a spot meter the absolute scale needs the camera's responsivity",
            )
        })?;
        return Ok(Scale {
            factor: r,
            method: format!("camera responsivity {r:e} W m⁻² sr⁻¹ per DN/s"),
            mismatch: None,
            fit_k2_percent: 0.0,
            meter_k2_percent: None,
            mismatch_k2_percent: None,
            spectral_trend_k2_percent: 0.0,
        });
    }
    let (targets, method, mismatch) = match curve {
        Some(c) => per_level_radiances(levels, c),
        None => meter_radiances(levels, setup)?,
    };
    let top = levels.last().map_or(0.0, |l| l.camera_dn_per_s);
    let (mut num, mut den, mut ratios, mut used) = (0.0, 0.0, Vec::new(), Vec::new());
    for (l, t) in levels.iter().zip(&targets) {
        if let Some(t) = t {
            if l.camera_dn_per_s >= SCALE_FLOOR * top {
                num += l.camera_dn_per_s * t;
                den += l.camera_dn_per_s * l.camera_dn_per_s;
                ratios.push(t / l.camera_dn_per_s);
                used.push(l.level);
            }
        }
    }
    if !(den > 0.0 && num > 0.0) {
        return Err(Error::Other(
            "no meter readings above 10 % of the top level's signal to set the absolute scale"
                .into(),
        ));
    }
    let mismatch_k2_percent = match (
        curve,
        cfg.screen_spectrum_uncertainty_nm,
        &setup.spectral,
        &setup.meter_response,
        &setup.screen_spectrum,
    ) {
        (Some(curve), ..) => curve.wavelength_k2_percent(),
        (None, Some(nm), Some(c), Some(m), Some(sp))
            if mismatch.is_some() && cfg.mismatch_factor.is_none() =>
        {
            Some(budget::mismatch_sensitivity_percent(c, sp, m, nm)?)
        }
        _ => None,
    };
    // With F per level: what its interpolation leaves. With one F (the
    // white's, shown at the top level): the scale against the top level's
    // own ratio.
    let spectral_trend_k2_percent = match (curve, mismatch, ratios.last()) {
        (Some(c), ..) => c.trend_k2_percent(&used),
        (None, Some(_), Some(&top_ratio)) => {
            budget::spectral_trend_k2_percent(num / den, top_ratio)
        }
        _ => 0.0,
    };
    Ok(Scale {
        factor: num / den,
        method,
        mismatch,
        spectral_trend_k2_percent,
        fit_k2_percent: budget::scale_fit_k2_percent(&ratios),
        meter_k2_percent: cfg
            .meter
            .as_ref()
            .and_then(|m| m.scale_uncertainty_k2_percent),
        mismatch_k2_percent,
    })
}

/// The meter's camera-effective radiance per level: from its spectra
/// (spectroradiometer) or F × reading.
fn meter_radiances(
    levels: &[LevelResult],
    setup: &Setup,
) -> Result<(Vec<Option<f64>>, String, Option<f64>)> {
    let cfg = setup.cfg;
    let f = match cfg.mismatch_factor {
        Some(f) => f,
        None => {
            let spectral = setup.spectral.as_ref().ok_or_else(|| {
                Error::invalid(
                    "calibrate.mismatch_factor",
                    "missing, and no scene camera to compute it",
                )
            })?;
            let m = setup.meter_response.as_ref().ok_or_else(|| {
                Error::invalid(
                    "calibrate.mismatch_factor",
                    "missing: give it, or calibrate.meter.spectral_response and \
                     calibrate.screen_spectrum to compute it",
                )
            })?;
            let s: &Spectrum = setup.screen_spectrum.as_deref().ok_or_else(|| {
                Error::invalid(
                    "calibrate.screen_spectrum",
                    "missing: needed with the meter's spectral response to compute F",
                )
            })?;
            spectral.mismatch_factor(s, m)?
        }
    };
    let targets = levels.iter().map(|l| l.meter.map(|v| f * v)).collect();
    Ok((
        targets,
        format!("spot meter × spectral mismatch factor F = {f:.6}"),
        Some(f),
    ))
}

/// The meter's camera-effective radiance per level with F at the level.
fn per_level_radiances(
    levels: &[LevelResult],
    curve: &MismatchCurve,
) -> (Vec<Option<f64>>, String, Option<f64>) {
    let targets = levels
        .iter()
        .map(|l| l.meter.map(|v| curve.at(l.level as f64) * v))
        .collect();
    let measured: Vec<String> = curve.points().iter().map(|p| p.level.to_string()).collect();
    (
        targets,
        format!(
            "spot meter × spectral mismatch factor F(level), linear in level between spectra measured at levels {} ({})",
            measured.join(" "),
            curve.describe()
        ),
        Some(curve.top()),
    )
}

/// Leave-one-out PCHIP residuals at the interior levels; returns (RMS,
/// max |·|) over levels above 1 % of the maximum, %.
fn leave_one_out(levels: &mut [LevelResult]) -> Result<(f64, f64)> {
    let n = levels.len();
    let max = levels[n - 1].radiance;
    let (mut s2, mut k, mut worst) = (0.0, 0usize, 0.0f64);
    for i in 1..n.saturating_sub(1) {
        let (x, y): (Vec<f64>, Vec<f64>) = levels
            .iter()
            .enumerate()
            .filter(|(j, _)| *j != i)
            .map(|(_, l)| (l.level as f64, l.radiance))
            .unzip();
        let p = Pchip::new(x, y)?;
        let truth = levels[i].radiance;
        if truth > 0.0 {
            let r = 100.0 * (p.eval(levels[i].level as f64) / truth - 1.0);
            levels[i].loo_residual_percent = Some(r);
            if truth > 0.01 * max {
                s2 += r * r;
                k += 1;
                worst = worst.max(r.abs());
            }
        }
    }
    Ok((if k > 0 { (s2 / k as f64).sqrt() } else { 0.0 }, worst))
}

/// Output files of the routine.
pub struct Outputs {
    pub lut: PathBuf,
    pub report: PathBuf,
    pub plot: PathBuf,
}

impl Outputs {
    /// `lut.csv`, `radiometric_report.json`, `radiometric.png` in `dir`.
    pub fn in_dir(dir: &Path) -> Outputs {
        Outputs {
            lut: dir.join("lut.csv"),
            report: dir.join("radiometric_report.json"),
            plot: dir.join("radiometric.png"),
        }
    }
}

/// Writes the LUT CSV (with its provenance header), the JSON report and the
/// plot.
pub fn write(report: &Report, setup: &Setup, out: &Outputs) -> Result<()> {
    for p in [&out.lut, &out.report, &out.plot] {
        if let Some(d) = p.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(d).map_err(|e| Error::io(d, e))?;
        }
    }
    std::fs::write(&out.lut, lut_csv(report, setup)).map_err(|e| Error::io(&out.lut, e))?;
    let json = serde_json::to_string_pretty(report).map_err(|e| Error::Other(e.to_string()))?;
    std::fs::write(&out.report, json).map_err(|e| Error::io(&out.report, e))?;
    plot(report, &out.plot)
}

/// The LUT file's text.
pub fn lut_csv(r: &Report, setup: &Setup) -> String {
    let cfg = setup.cfg;
    let band = setup
        .spectral
        .as_ref()
        .map_or("the scene camera's band".to_string(), |s| {
            format!("[{:.1}, {:.1}] nm", s.band_nm[0], s.band_nm[1])
        });
    let levels: Vec<String> = r.levels.iter().map(|l| l.level.to_string()).collect();
    let mut t = String::new();
    let mut line = |s: String| {
        t.push_str("# ");
        t.push_str(&s.replace(['\n', '\r'], " "));
        t.push('\n');
    };
    line("display LUT written by `optistim calibrate radiometric` (docs/CALIBRATION.md)".into());
    line(format!(
        "quantity: camera-effective radiance of the screen, W m^-2 sr^-1, at the screen \
         (before the collimator), weighted by the camera's QE x T over {band} and normalised \
         to the solar spectrum"
    ));
    line(format!(
        "date: {}; software: {}; source: {}",
        r.date, r.software, setup.source
    ));
    line(format!(
        "camera: {}; region {} px; exposure {:.3e}..{:.3e} s (auto-ranged, normalised to DN/s)",
        r.camera, r.region, r.exposure_range_s[0], r.exposure_range_s[1]
    ));
    line(format!("dark: {}", r.dark));
    line(format!("meter: {}; scale: {}", r.meter, r.scale_method));
    line(format!(
        "levels: {} ({}), spacing power {}; repeats: {}; settle {} s; seed {}",
        r.levels.len(),
        levels.join(" "),
        cfg.spacing_power,
        r.repeats,
        cfg.settle,
        cfg.seed
    ));
    line(format!(
        "black: {:.6e} W m^-2 sr^-1; max: {:.6e}; ambient: {}",
        r.black_radiance,
        r.max_radiance,
        r.ambient_radiance
            .map_or("not measured".to_string(), |a| format!(
                "{a:.6e} W m^-2 sr^-1 (subtracted)"
            ))
    ));
    line(format!(
        "drift: reference level {} changed by {:+.3} % from start to end",
        r.reference_level, r.drift_percent
    ));
    line(format!(
        "leave-one-out PCHIP residual over levels above 1 % of max: RMS {:.3} %, max {:.3} %",
        r.loo_rms_percent, r.loo_max_percent
    ));
    line(r.budget.describe());
    t.push_str(LUT_HEADER_UNCERTAINTY);
    t.push('\n');
    for l in &r.levels {
        t.push_str(&format!(
            "{},{:?},{:.4}\n",
            l.level, l.radiance, l.uncertainty.total_k2_percent
        ));
    }
    t
}

/// The curve on a log axis with the measured points, and the leave-one-out
/// residuals below.
pub fn plot(r: &Report, path: &Path) -> Result<()> {
    let pts: Vec<(f64, f64)> = r
        .levels
        .iter()
        .map(|l| (l.level as f64, l.radiance))
        .collect();
    let xs: Vec<f64> = pts.iter().map(|p| p.0).collect();
    let ys: Vec<f64> = pts.iter().map(|p| p.1).collect();
    let curve = Pchip::new(xs.clone(), ys)?;
    let top = *xs.last().unwrap_or(&255.0);
    let line: Vec<(f64, f64)> = (0..=512)
        .map(|k| {
            let x = top * k as f64 / 512.0;
            (x, curve.eval(x))
        })
        .collect();
    // Signed residuals; those of levels above 1 % of the maximum enter the
    // statistics in the title (as in the LUT header), the others are drawn
    // apart.
    let max = r.max_radiance;
    let (inside, outside): (Vec<&LevelResult>, Vec<&LevelResult>) = r
        .levels
        .iter()
        .filter(|l| l.loo_residual_percent.is_some())
        .partition(|l| l.radiance > 0.01 * max);
    let res = |ls: &[&LevelResult]| -> Vec<(f64, f64)> {
        ls.iter()
            .filter_map(|l| l.loo_residual_percent.map(|v| (l.level as f64, v)))
            .collect()
    };
    let grey = plotters::style::RGBColor(150, 150, 150);
    curve_figure(
        path,
        &CurveFigure {
            title: format!(
                "Display LUT; leave-one-out residual over levels > 1 % of max (blue; grey: left out): RMS {:.2} %, max {:.2} %; drift {:+.2} %",
                r.loo_rms_percent, r.loo_max_percent, r.drift_percent
            ),
            x_label: "drive level".into(),
            main: Panel {
                y_label: "L_eff (W m⁻² sr⁻¹)".into(),
                log_y: true,
                series: vec![
                    Series::line("PCHIP (as run uses it)", line),
                    Series::points("measured", pts),
                ],
            },
            residuals: Some(Panel {
                // No legend box (it would hide the dark levels' points):
                // the label says which colour is which.
                y_label: "leave-one-out residual (%)".into(),
                log_y: false,
                series: vec![
                    Series::line("", vec![(0.0, 0.0), (top, 0.0)]).with_colour(grey),
                    Series::points("", res(&outside)).with_colour(grey),
                    Series::points("", res(&inside)).with_colour(PALETTE[0]),
                ],
            }),
            size: (1200, 760),
        },
    )
}
