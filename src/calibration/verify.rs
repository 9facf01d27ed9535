//! Verification of a calibration: target radiance patches across the LUT's
//! range driven through the run's own conversion path
//! ([`dither::Converter`](crate::facility::dither::Converter) with the LUT
//! and the flat field), measured by the camera (with the radiometric
//! calibration's scale, radiance per DN/s) and the meter (F × reading);
//! achieved/target per patch in per cent; and a quick drift check: a few
//! uniform levels against the LUT. Thresholds come from
//! `[calibrate.verify]`; [`VerifyReport::passed`] is false when a patch
//! misses, and `optistim calibrate verify` then exits non-zero.

use serde::{Deserialize, Serialize};

use super::checkpoint::Checkpoint;
use super::config::CalibrateConfig;
use super::{progress, read_meter, show_level, AutoExposure, Instruments, Rect};
use crate::error::{Error, Result};
use crate::facility::dither::{ConvertSettings, Converter, Roi, ThresholdMatrix};
use crate::facility::lut::{DisplayLut, FlatField};

/// Name of the routine in checkpoints and reports.
pub const ROUTINE: &str = "verify";

/// What the routine needs besides the instruments.
pub struct VerifySetup<'a> {
    pub cfg: &'a CalibrateConfig,
    pub lut: DisplayLut,
    pub flat: Option<FlatField>,
    pub screen: (usize, usize),
    /// Radiance per DN/s of the camera region (the radiometric report's
    /// `scale`).
    pub camera_scale: f64,
    /// F for the meter (the radiometric report's `mismatch_factor`).
    pub mismatch_factor: Option<f64>,
}

/// One measured patch.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Patch {
    /// Target screen radiance, W m⁻² sr⁻¹.
    pub target: f64,
    /// Camera-measured radiance, and achieved/target − 1 in %.
    pub camera: f64,
    pub camera_error_percent: f64,
    /// Meter-measured radiance (F × reading), and its error, %.
    pub meter: Option<f64>,
    pub meter_error_percent: Option<f64>,
    pub exposure_s: f64,
}

/// One drift-check level.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DriftPoint {
    pub level: u32,
    pub lut: f64,
    pub measured: f64,
    pub drift_percent: f64,
}

/// The report.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct VerifyReport {
    pub patches: Vec<Patch>,
    pub drift: Vec<DriftPoint>,
    pub max_error_percent: f64,
    pub threshold_percent: f64,
    pub max_drift_percent: f64,
    pub drift_warn_percent: f64,
    pub drift_warning: bool,
    pub passed: bool,
}

/// Target radiances: `n` log-spaced from 3× black (or 1 % of max if the
/// black is 0) to 90 % of the LUT's maximum.
pub fn targets(lut: &DisplayLut, n: usize) -> Vec<f64> {
    let max = lut.max_radiance();
    let lo = if lut.black() > 0.0 {
        (3.0 * lut.black()).min(0.5 * max)
    } else {
        0.01 * max
    };
    let hi = 0.9 * max;
    (0..n)
        .map(|i| lo * (hi / lo).powf(i as f64 / (n - 1).max(1) as f64))
        .collect()
}

/// What every measurement of a verification shares.
struct Session<'s, 'i> {
    inst: &'s mut Instruments<'i>,
    setup: &'s VerifySetup<'s>,
    auto: AutoExposure,
    /// The camera region measured.
    rect: Rect,
}

impl Session<'_, '_> {
    /// The camera's radiance of the region, for the pattern shown now.
    fn measure(&mut self, name: &str, level: u32) -> Result<(f64, f64)> {
        let cfg = self.setup.cfg;
        (self.inst.wait)(cfg.settle);
        let r = self
            .auto
            .capture(self.inst.camera, self.inst.darks, name, level, self.rect)?;
        let radiance = r.stats.mean / r.frame.exposure_s * self.setup.camera_scale;
        Ok((radiance, r.frame.exposure_s))
    }

    /// One patch: a uniform target radiance through the LUT, flat field and
    /// dither (`frame` is the screen buffer), against camera and meter.
    fn patch(
        &mut self,
        name: &str,
        target: f64,
        conv: &mut Converter,
        frame: &mut [u32],
    ) -> Result<Patch> {
        let (w, h) = self.setup.screen;
        let image = vec![target as f32; w * h];
        conv.convert(&image, Roi::full(w, h), 0, frame)?;
        self.inst.display.present(frame)?;
        let level = self.setup.lut.inverse(target).round() as u32;
        let (camera, exposure_s) = self.measure(name, level)?;
        let meter = read_meter(&mut self.inst.meter, name, level)?
            .and_then(|m| self.setup.mismatch_factor.map(|f| f * m.value));
        Ok(Patch {
            target,
            camera,
            camera_error_percent: 100.0 * (camera / target - 1.0),
            meter,
            meter_error_percent: meter.map(|m| 100.0 * (m / target - 1.0)),
            exposure_s,
        })
    }

    /// One drive level shown flat, against the LUT's radiance there.
    fn drift(&mut self, name: &str, level: u32) -> Result<DriftPoint> {
        show_level(self.inst.display, level, self.setup.lut.bits())?;
        let (measured, _) = self.measure(name, level)?;
        let lut = self.setup.lut.radiance(level as f64);
        if !(lut > 0.0) {
            return Err(Error::invalid(
                "calibrate.verify.drift_levels",
                format!("level {level} has zero radiance in the LUT"),
            ));
        }
        Ok(DriftPoint {
            level,
            lut,
            measured,
            drift_percent: 100.0 * (measured / lut - 1.0),
        })
    }
}

/// Runs the verification (resuming from `ckpt`).
pub fn run(
    inst: &mut Instruments,
    setup: &VerifySetup,
    ckpt: &mut Checkpoint,
) -> Result<VerifyReport> {
    let cfg = setup.cfg;
    let (w, h) = setup.screen;
    let mut conv = Converter::new(
        setup.lut.clone(),
        setup.flat.clone(),
        ThresholdMatrix::bayer(8)?,
        ConvertSettings::default(),
        setup.screen,
    )?;
    let probe = inst.camera.capture(&crate::instruments::CaptureRequest {
        pattern: "verify_probe".into(),
        exposure_s: cfg.camera.exposure,
        shutter: Default::default(),
    })?;
    let mut session = Session {
        inst,
        setup,
        auto: AutoExposure::of(cfg),
        rect: Rect::from_fractions(cfg.region, probe.width, probe.height),
    };
    let tl = targets(&setup.lut, cfg.verify.patches);
    let bar = progress((tl.len() + cfg.verify.drift_levels.len()) as u64, "verify");
    let mut patches = Vec::new();
    let mut frame = vec![0u32; w * h];
    for (i, &target) in tl.iter().enumerate() {
        let name = format!("verify_patch_{i:02}");
        let p = match ckpt.get::<Patch>(&name)? {
            Some(p) => p,
            None => {
                let p = session.patch(&name, target, &mut conv, &mut frame)?;
                ckpt.record(&name, &p)?;
                p
            }
        };
        bar.inc(1);
        bar.set_message(format!(
            "patch {i}: target {target:.4e}, camera {:+.2} %",
            p.camera_error_percent
        ));
        patches.push(p);
    }
    let mut drift = Vec::new();
    for &level in &cfg.verify.drift_levels {
        let name = format!("verify_drift_{level:04}");
        let d = match ckpt.get::<DriftPoint>(&name)? {
            Some(d) => d,
            None => {
                let d = session.drift(&name, level)?;
                ckpt.record(&name, &d)?;
                d
            }
        };
        bar.inc(1);
        drift.push(d);
    }
    bar.finish_and_clear();
    Ok(VerifyReport::new(patches, drift, cfg))
}

impl VerifyReport {
    fn new(patches: Vec<Patch>, drift: Vec<DriftPoint>, cfg: &CalibrateConfig) -> Self {
        let max_error = patches
            .iter()
            .flat_map(|p| std::iter::once(p.camera_error_percent).chain(p.meter_error_percent))
            .fold(0.0f64, |a, e| a.max(e.abs()));
        let max_drift = drift
            .iter()
            .fold(0.0f64, |a, d| a.max(d.drift_percent.abs()));
        VerifyReport {
            patches,
            drift,
            max_error_percent: max_error,
            threshold_percent: cfg.verify.max_error_percent,
            max_drift_percent: max_drift,
            drift_warn_percent: cfg.verify.drift_warn_percent,
            drift_warning: max_drift > cfg.verify.drift_warn_percent,
            passed: max_error <= cfg.verify.max_error_percent,
        }
    }
}

/// A short table of the report for the terminal.
pub fn summary(r: &VerifyReport) -> String {
    let mut s = String::from("target (W m-2 sr-1)   camera     meter\n");
    for p in &r.patches {
        s.push_str(&format!(
            "{:>18.5e}  {:>+8.3} %  {}\n",
            p.target,
            p.camera_error_percent,
            p.meter_error_percent
                .map_or("      -".into(), |m| format!("{m:>+8.3} %"))
        ));
    }
    for d in &r.drift {
        s.push_str(&format!(
            "drift level {:>4}: {:+.3} % against the LUT\n",
            d.level, d.drift_percent
        ));
    }
    s.push_str(&format!(
        "max |error| {:.3} % (threshold {} %): {}; max |drift| {:.3} % (warn above {} %){}\n",
        r.max_error_percent,
        r.threshold_percent,
        if r.passed { "PASS" } else { "FAIL" },
        r.max_drift_percent,
        r.drift_warn_percent,
        if r.drift_warning {
            ": WARNING, recalibrate"
        } else {
            ""
        }
    ));
    s
}
