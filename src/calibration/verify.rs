//! Verification of a calibration: target radiance patches across the LUT's
//! range (log-spaced radiances, so between the calibration's ladder
//! levels) driven through the run's own conversion path
//! ([`dither::Converter`](crate::facility::dither::Converter) with the LUT
//! and the flat field), measured with scales the calibration did not fit:
//!
//! * the camera, at the centre and four off-centre spots, through its own
//!   absolute responsivity R (a lab calibration,
//!   [`responsivity`](super::responsivity)), its own flat and each pixel's
//!   etendue, and the collimator's transmission τ:
//!   L = (DN/s) ÷ (flat · etendue) ÷ (R · τ);
//! * the meter: a spectroradiometer's spectrum gives camera-effective
//!   radiance directly, a broadband meter F × reading (F at the patch's
//!   drive level when the calibration measured F per level).
//!
//! achieved/target − 1 per patch and instrument, in per cent, against a
//! threshold from the uncertainty budget (the LUT's per-level uncertainty
//! combined with R's, or the meter's scale uncertainty), unless
//! `verify.max_error_percent` overrides it; and a quick drift check: a few
//! uniform levels against the LUT (relative, with the radiometric scale).
//! [`VerifyReport::passed`] is false when a patch misses, and
//! `optistim calibrate verify` then exits non-zero. The report also splits
//! the camera's errors into their common mode (one draw per campaign: the
//! lab responsivity's error and the LUT's scale error, judged against
//! those two budgets) and the spots' spread about it (the LUT's shape, the
//! flat field, noise): [`CommonMode`].

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::checkpoint::Checkpoint;
use super::config::CalibrateConfig;
use super::mismatch::CameraSpectral;
use super::mismatch_levels::MismatchCurve;
use super::radiometric::SCALE_FLOOR;
use super::responsivity::CameraResponsivity;
use super::{progress, read_meter, show_level, AutoExposure, Instruments, Rect};
use crate::error::{Error, Result};
use crate::facility::dither::{ConvertSettings, Converter, Roi, ThresholdMatrix};
use crate::facility::lut::{DisplayLut, FlatField};
use crate::figures::{log_x_panels, LogXPanels, Panel, Series};

/// Name of the routine in checkpoints and reports.
pub const ROUTINE: &str = "verify";

/// The camera spots: name and centre as fractions of the frame.
pub const SPOTS: [(&str, f64, f64); 5] = [
    ("centre", 0.5, 0.5),
    ("upper left", 0.25, 0.25),
    ("upper right", 0.75, 0.25),
    ("lower left", 0.25, 0.75),
    ("lower right", 0.75, 0.75),
];

/// The camera as an independent radiometer.
pub struct AbsoluteCamera<'a> {
    pub responsivity: CameraResponsivity,
    /// The collimator's transmission τ.
    pub transmission: f64,
    /// The camera's own flat (camera size, 1 ≈ the centre).
    pub camera_flat: Vec<f32>,
    /// Camera pixel position (centres at +0.5) → direction (tan_x, tan_y):
    /// the intrinsics, for each pixel's etendue.
    pub pixel_direction: &'a (dyn Fn(f64, f64) -> (f64, f64) + Sync),
}

/// What the routine needs besides the instruments.
pub struct VerifySetup<'a> {
    pub cfg: &'a CalibrateConfig,
    pub lut: DisplayLut,
    pub flat: Option<FlatField>,
    pub screen: (usize, usize),
    /// Radiance per DN/s of the radiometric region (the radiometric
    /// report's `scale`): used by the relative drift check only.
    pub camera_scale: f64,
    pub camera: AbsoluteCamera<'a>,
    /// F for a broadband meter.
    pub mismatch_factor: Option<f64>,
    /// F per drive level (the radiometric report's), used instead of
    /// `mismatch_factor` when given.
    pub mismatch_by_level: Option<MismatchCurve>,
    /// The camera's spectral weighting, for a spectroradiometer's spectra.
    pub spectral: Option<CameraSpectral>,
    /// The meter's scale uncertainty (k = 2, %), if declared.
    pub meter_uncertainty_k2_percent: Option<f64>,
    /// The LUT's scale-wide uncertainty (k = 2, %: the radiometric
    /// report's budget without the per-level noise and fit), if known.
    pub lut_scale_k2_percent: Option<f64>,
}

/// One camera spot of a patch.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SpotResult {
    pub name: String,
    pub rect: Rect,
    /// Screen radiance from the camera's responsivity, W m⁻² sr⁻¹.
    pub radiance: f64,
    pub error_percent: f64,
}

/// One measured patch.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Patch {
    /// Target screen radiance, W m⁻² sr⁻¹.
    pub target: f64,
    /// The LUT's (fractional) drive level for the target.
    pub drive_level: f64,
    /// The camera spots (the first is the centre).
    pub spots: Vec<SpotResult>,
    /// Meter-measured camera-effective radiance, and its error, %.
    pub meter: Option<f64>,
    pub meter_error_percent: Option<f64>,
    /// Allowed |error| (k = 2), %, for the camera and the meter.
    pub camera_threshold_percent: f64,
    pub meter_threshold_percent: Option<f64>,
    /// The meter's reading counts in the verdict and the statistics: false
    /// for a broadband reading below [`SCALE_FLOOR`] of the LUT's maximum,
    /// where the white's F does not hold (shown, not judged).
    #[serde(default = "judged_by_default")]
    pub meter_judged: bool,
    pub exposure_s: f64,
}

fn judged_by_default() -> bool {
    true
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
    /// Largest |error| over every spot and the meter, %.
    pub max_error_percent: f64,
    /// Means over the patches: the camera's (all spots) and the meter's
    /// error, %.
    pub mean_camera_error_percent: f64,
    pub mean_meter_error_percent: Option<f64>,
    /// `verify.max_error_percent`, when it overrides the budget.
    pub threshold_override_percent: Option<f64>,
    /// The camera responsivity's own uncertainty (k = 2), %.
    pub responsivity_uncertainty_k2_percent: f64,
    /// Whether the LUT gave per-level uncertainties.
    pub lut_uncertainty: bool,
    /// Measurements beyond their threshold.
    pub failures: usize,
    pub max_drift_percent: f64,
    pub drift_warn_percent: f64,
    pub drift_warning: bool,
    pub passed: bool,
    /// The camera's errors split into common mode and spread (absent in
    /// reports written before it was added).
    #[serde(default)]
    pub camera_common_mode: Option<CommonMode>,
}

/// The camera's error over every spot and patch split in two. The common
/// mode (their mean) is one draw per campaign, the lab responsivity's
/// error plus the LUT's scale error, so it is judged against those two
/// budgets alone; what is left per spot (the LUT's shape between levels,
/// the flat field, the camera's noise) is the spread. A per-spot threshold
/// counts the common draw against every spot; when verify fails, a common
/// mode beyond its budget with a small spread points at the scale (the
/// lab responsivity or the LUT's), a wide spread at the LUT's shape or the
/// flat field. Reported, not part of the verdict.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CommonMode {
    /// Mean camera error, %.
    pub mean_percent: f64,
    /// Its budget (k = 2, %): the responsivity's and the LUT scale's in
    /// quadrature (the responsivity's alone when the scale's is unknown).
    pub budget_k2_percent: f64,
    /// The LUT scale's part of that budget, if known.
    pub lut_scale_k2_percent: Option<f64>,
    /// |mean| within the budget.
    pub within: bool,
    /// Largest |spot error − mean|, %.
    pub max_spread_percent: f64,
}

impl CommonMode {
    /// From every spot's error (%), the responsivity's and the LUT scale's
    /// k = 2 uncertainties (%); `None` without spots.
    pub fn of(errors: &[f64], responsivity_k2: f64, lut_scale_k2: Option<f64>) -> Option<Self> {
        if errors.is_empty() {
            return None;
        }
        let mean = errors.iter().sum::<f64>() / errors.len() as f64;
        let budget = responsivity_k2.hypot(lut_scale_k2.unwrap_or(0.0));
        Some(CommonMode {
            mean_percent: mean,
            budget_k2_percent: budget,
            lut_scale_k2_percent: lut_scale_k2,
            within: mean.abs() <= budget,
            max_spread_percent: errors.iter().fold(0.0, |a, e| a.max((e - mean).abs())),
        })
    }

    /// One line for the terminal and the failure message.
    pub fn describe(&self) -> String {
        format!(
            "camera common mode {:+.3} % against ± {:.2} % (responsivity and LUT scale{}): {}; spread about it ≤ {:.3} %",
            self.mean_percent,
            self.budget_k2_percent,
            self.lut_scale_k2_percent
                .map_or(", the scale's unknown".into(), |u| format!(" {u:.2} %")),
            if self.within { "within" } else { "BEYOND" },
            self.max_spread_percent
        )
    }
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

/// A camera spot: its rectangle and per-pixel flat × relative etendue.
struct Spot {
    name: &'static str,
    rect: Rect,
    weight: Vec<f64>,
}

/// The spots of a `width × height` camera, each the size of the
/// radiometric region.
fn spots(
    cam: &AbsoluteCamera,
    cfg: &CalibrateConfig,
    width: usize,
    height: usize,
) -> Result<Vec<Spot>> {
    if cam.camera_flat.len() != width * height {
        return Err(Error::Other(format!(
            "calibrate.flat.camera_flat has {} pixels, the camera frame {width}×{height}",
            cam.camera_flat.len()
        )));
    }
    let dir = cam.pixel_direction;
    let etendue = |x: f64, y: f64| {
        let (tx, ty) = dir(x, y);
        let (ax, ay) = dir(x + 0.5, y);
        let (bx, by) = dir(x - 0.5, y);
        let (cx, cy) = dir(x, y + 0.5);
        let (dx, dy) = dir(x, y - 0.5);
        let jac = ((ax - bx) * (cy - dy) - (ay - by) * (cx - dx)).abs();
        let r2 = 1.0 + tx * tx + ty * ty;
        jac / (r2 * r2)
    };
    let centre = etendue(width as f64 / 2.0, height as f64 / 2.0);
    let [_, _, w, h] = cfg.region;
    SPOTS
        .iter()
        .map(|&(name, fx, fy)| {
            let f = [
                (fx - w / 2.0).clamp(0.0, 1.0 - w),
                (fy - h / 2.0).clamp(0.0, 1.0 - h),
                w,
                h,
            ];
            let rect = Rect::from_fractions(f, width, height);
            let mut weight = Vec::with_capacity(rect.w * rect.h);
            for y in rect.y..rect.y + rect.h {
                for x in rect.x..rect.x + rect.w {
                    let g = cam.camera_flat[y * width + x] as f64;
                    let e = etendue(x as f64 + 0.5, y as f64 + 0.5) / centre;
                    if !(g.is_finite() && g > 0.0 && e.is_finite() && e > 0.0) {
                        return Err(Error::Other(format!(
                            "verify spot `{name}`: camera pixel ({x}, {y}) has flat {g} and etendue {e}: \
                             check calibrate.flat.camera_flat and calibrate.camera.intrinsics"
                        )));
                    }
                    weight.push(g * e);
                }
            }
            Ok(Spot { name, rect, weight })
        })
        .collect()
}

/// What every measurement of a verification shares.
struct Session<'s, 'i> {
    inst: &'s mut Instruments<'i>,
    setup: &'s VerifySetup<'s>,
    auto: AutoExposure,
    /// The radiometric region (drift check).
    rect: Rect,
    spots: Vec<Spot>,
}

impl Session<'_, '_> {
    /// One auto-ranged, dark-corrected frame of what the screen shows now.
    fn frame(&mut self, name: &str, level: u32) -> Result<super::Ranged> {
        (self.inst.wait)(self.setup.cfg.settle);
        let all = self.spots.iter().fold(self.rect, |a, s| union(a, s.rect));
        self.auto
            .capture(self.inst.camera, self.inst.darks, name, level, all)
    }

    /// The screen radiance each spot sees, from the camera's responsivity.
    fn spot_radiances(&self, r: &super::Ranged) -> Vec<(f64, Rect, &'static str)> {
        let cam = &self.setup.camera;
        let scale = cam.responsivity.responsivity_dn_per_s_per_w_m2_sr * cam.transmission;
        let t = r.frame.exposure_s;
        let width = r.frame.width;
        self.spots
            .iter()
            .map(|s| {
                let mut sum = 0.0;
                let mut k = 0;
                for y in s.rect.y..s.rect.y + s.rect.h {
                    for x in s.rect.x..s.rect.x + s.rect.w {
                        let i = y * width + x;
                        let d = r.dark.as_ref().map_or(0.0, |d| d[i] as f64);
                        sum += (r.frame.data[i] as f64 - d) / s.weight[k];
                        k += 1;
                    }
                }
                (sum / k as f64 / t / scale, s.rect, s.name)
            })
            .collect()
    }

    /// The meter's camera-effective radiance of what the screen shows now,
    /// and whether it came through F (a broadband reading) rather than a
    /// spectrum.
    fn meter(&mut self, name: &str, level: u32) -> Result<Option<(f64, bool)>> {
        let Some(m) = read_meter(&mut self.inst.meter, name, level)? else {
            return Ok(None);
        };
        match (
            &m.spectrum,
            &self.setup.spectral,
            self.setup.mismatch_factor,
        ) {
            (Some(s), Some(c), _) => c.effective_radiance(s).map(|l| Some((l, false))),
            (_, _, Some(f)) => {
                let f = self
                    .setup
                    .mismatch_by_level
                    .as_ref()
                    .map_or(f, |c| c.at(level as f64));
                Ok(Some((f * m.value, true)))
            }
            _ => Err(Error::invalid(
                "calibrate.mismatch_factor",
                "verify needs F (or a spectroradiometer) to read the meter",
            )),
        }
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
        let drive_level = self.setup.lut.inverse(target);
        let level = drive_level.round() as u32;
        let r = self.frame(name, level)?;
        let spots = self
            .spot_radiances(&r)
            .into_iter()
            .map(|(radiance, rect, name)| SpotResult {
                name: name.into(),
                rect,
                radiance,
                error_percent: 100.0 * (radiance / target - 1.0),
            })
            .collect();
        let reading = self.meter(name, level)?;
        let meter = reading.map(|r| r.0);
        // F holds for the spectrum it was computed from, the white; a dim
        // patch's spectrum is the black leak's as much as the channels'
        // (bluer on an LCD), so a broadband reading there is shown, not
        // judged: the camera spots judge it in the camera's own band.
        let judged = reading.is_some_and(|(_, broadband)| {
            !broadband || target >= SCALE_FLOOR * self.setup.lut.max_radiance()
        });
        let lut_u = self.setup.lut.uncertainty_k2_percent(target).unwrap_or(0.0);
        let r_u = self.setup.camera.responsivity.uncertainty_k2_percent;
        let override_u = self.setup.cfg.verify.max_error_percent;
        Ok(Patch {
            target,
            drive_level,
            spots,
            meter,
            meter_error_percent: meter.map(|m| 100.0 * (m / target - 1.0)),
            camera_threshold_percent: override_u.unwrap_or(lut_u.hypot(r_u)),
            meter_threshold_percent: self
                .setup
                .meter_uncertainty_k2_percent
                .map(|m| override_u.unwrap_or(lut_u.hypot(m)))
                .or(override_u),
            meter_judged: judged,
            exposure_s: r.frame.exposure_s,
        })
    }

    /// One drive level shown flat, against the LUT's radiance there
    /// (relative: the radiometric scale).
    fn drift(&mut self, name: &str, level: u32) -> Result<DriftPoint> {
        show_level(self.inst.display, level, self.setup.lut.bits())?;
        let r = self.frame(name, level)?;
        let d = r.dark.as_deref().map(|d| d.as_slice());
        let stats = super::region_stats(&r.frame, d, self.rect)?;
        let measured = stats.mean / r.frame.exposure_s * self.setup.camera_scale;
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

/// The smallest rectangle holding both.
fn union(a: Rect, b: Rect) -> Rect {
    let (x, y) = (a.x.min(b.x), a.y.min(b.y));
    Rect {
        x,
        y,
        w: (a.x + a.w).max(b.x + b.w) - x,
        h: (a.y + a.h).max(b.y + b.h) - y,
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
    let probe = inst
        .camera
        .capture(&crate::instruments::CaptureRequest::light(
            "verify_probe",
            cfg.camera.exposure,
        ))?;
    let mut session = Session {
        inst,
        setup,
        auto: AutoExposure::of(cfg),
        rect: Rect::from_fractions(cfg.region, probe.width, probe.height),
        spots: spots(&setup.camera, cfg, probe.width, probe.height)?,
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
            "patch {i}: target {target:.4e}, camera centre {:+.2} %",
            p.spots.first().map_or(f64::NAN, |s| s.error_percent)
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
    Ok(VerifyReport::new(patches, drift, setup))
}

impl VerifyReport {
    fn new(patches: Vec<Patch>, drift: Vec<DriftPoint>, setup: &VerifySetup) -> Self {
        let cfg = setup.cfg;
        let mut failures = 0;
        let mut max_error = 0.0f64;
        let mut camera_errors = Vec::new();
        let (mut meter_sum, mut meter_n) = (0.0, 0usize);
        for p in &patches {
            for s in &p.spots {
                max_error = max_error.max(s.error_percent.abs());
                camera_errors.push(s.error_percent);
                failures += usize::from(!(s.error_percent.abs() <= p.camera_threshold_percent));
            }
            if let Some(e) = p.meter_error_percent.filter(|_| p.meter_judged) {
                max_error = max_error.max(e.abs());
                meter_sum += e;
                meter_n += 1;
                if let Some(t) = p.meter_threshold_percent {
                    failures += usize::from(!(e.abs() <= t));
                }
            }
        }
        let max_drift = drift
            .iter()
            .fold(0.0f64, |a, d| a.max(d.drift_percent.abs()));
        let r_u = setup.camera.responsivity.uncertainty_k2_percent;
        let common = CommonMode::of(&camera_errors, r_u, setup.lut_scale_k2_percent);
        VerifyReport {
            patches,
            drift,
            max_error_percent: max_error,
            mean_camera_error_percent: common.as_ref().map_or(0.0, |c| c.mean_percent),
            mean_meter_error_percent: (meter_n > 0).then(|| meter_sum / meter_n as f64),
            threshold_override_percent: cfg.verify.max_error_percent,
            responsivity_uncertainty_k2_percent: r_u,
            lut_uncertainty: setup
                .lut
                .uncertainty_k2_percent(setup.lut.max_radiance())
                .is_some(),
            failures,
            max_drift_percent: max_drift,
            drift_warn_percent: cfg.verify.drift_warn_percent,
            drift_warning: max_drift > cfg.verify.drift_warn_percent,
            passed: failures == 0,
            camera_common_mode: common,
        }
    }
}

/// A short table of the report for the terminal.
pub fn summary(r: &VerifyReport) -> String {
    let mut s = String::from(
        "target (W m-2 sr-1)  level    camera: centre  up-left  up-right  lo-left  lo-right  (± U)      meter (± U)\n",
    );
    for p in &r.patches {
        let spots: Vec<String> = p
            .spots
            .iter()
            .map(|s| format!("{:+7.3}", s.error_percent))
            .collect();
        s.push_str(&format!(
            "{:>18.5e}  {:>6.2}  {} %  (± {:.2} %)  {}\n",
            p.target,
            p.drive_level,
            spots.join("  "),
            p.camera_threshold_percent,
            match (p.meter_error_percent, p.meter_threshold_percent) {
                (Some(m), _) if !p.meter_judged => {
                    format!("{m:+.3} % (not judged: broadband, below the white's F)")
                }
                (Some(m), Some(t)) => format!("{m:+.3} % (± {t:.2} %)"),
                (Some(m), None) => format!("{m:+.3} % (no declared uncertainty)"),
                _ => "-".into(),
            }
        ));
    }
    for d in &r.drift {
        s.push_str(&format!(
            "drift level {:>4}: {:+.3} % against the LUT\n",
            d.level, d.drift_percent
        ));
    }
    s.push_str(&format!(
        "mean camera error {:+.3} %{}; max |error| {:.3} %; {} beyond threshold ({}): {}; max |drift| {:.3} % (warn above {} %){}\n",
        r.mean_camera_error_percent,
        r.mean_meter_error_percent
            .map_or(String::new(), |m| format!(", meter {m:+.3} %")),
        r.max_error_percent,
        r.failures,
        match r.threshold_override_percent {
            Some(t) => format!("override {t} %"),
            None => format!(
                "uncertainty budget: responsivity {:.2} % (k = 2){}",
                r.responsivity_uncertainty_k2_percent,
                if r.lut_uncertainty { " with the LUT's per-level uncertainty" } else { "; the LUT gives no uncertainty" }
            ),
        },
        if r.passed { "PASS" } else { "FAIL" },
        r.max_drift_percent,
        r.drift_warn_percent,
        if r.drift_warning {
            ": WARNING, recalibrate"
        } else {
            ""
        }
    ));
    if let Some(c) = &r.camera_common_mode {
        s.push_str(&c.describe());
        s.push('\n');
    }
    s
}

/// verify.png: achieved/target − 1 per patch against the target radiance,
/// the camera's spots and the meter, each with its ± threshold band.
pub fn plot(r: &VerifyReport, path: &Path) -> Result<()> {
    let band = |f: &dyn Fn(&Patch) -> Option<f64>, sign: f64| -> Vec<(f64, f64)> {
        r.patches
            .iter()
            .filter_map(|p| f(p).map(|t| (p.target, sign * t)))
            .collect()
    };
    let mut camera: Vec<Series> = (0..SPOTS.len())
        .map(|k| {
            Series::line_points(
                SPOTS[k].0,
                r.patches
                    .iter()
                    .filter_map(|p| p.spots.get(k).map(|s| (p.target, s.error_percent)))
                    .collect(),
            )
        })
        .collect();
    let grey = plotters::style::RGBColor(120, 120, 120);
    let cam_t = |p: &Patch| Some(p.camera_threshold_percent);
    camera.push(Series::line("± threshold (k = 2)", band(&cam_t, 1.0)).with_colour(grey));
    camera.push(Series::line("", band(&cam_t, -1.0)).with_colour(grey));
    let met_t = |p: &Patch| p.meter_threshold_percent.filter(|_| p.meter_judged);
    let meter_points = |judged: bool| -> Vec<(f64, f64)> {
        r.patches
            .iter()
            .filter(|p| p.meter_judged == judged)
            .filter_map(|p| p.meter_error_percent.map(|e| (p.target, e)))
            .collect()
    };
    let mut meter = vec![
        Series::line_points("meter", meter_points(true)),
        Series::line("± threshold (k = 2)", band(&met_t, 1.0)).with_colour(grey),
        Series::line("", band(&met_t, -1.0)).with_colour(grey),
    ];
    let unjudged = meter_points(false);
    if !unjudged.is_empty() {
        meter.push(
            Series::line_points("meter, not judged (broadband, < 10 % of max)", unjudged)
                .with_colour(plotters::style::RGBColor(230, 140, 0)),
        );
    }
    log_x_panels(
        path,
        &LogXPanels {
            title: format!(
                "Verify: achieved/target − 1 (camera common mode {:+.2} % of ± {:.2} %, spread ≤ {:.2} %; {} beyond threshold: {})",
                r.mean_camera_error_percent,
                r.camera_common_mode.as_ref().map_or(f64::NAN, |c| c.budget_k2_percent),
                r.camera_common_mode.as_ref().map_or(f64::NAN, |c| c.max_spread_percent),
                r.failures,
                if r.passed { "PASS" } else { "FAIL" }
            ),
            x_label: "target screen radiance (W m⁻² sr⁻¹)".into(),
            panels: vec![
                Panel {
                    y_label: "camera (responsivity): achieved/target − 1 (%)".into(),
                    log_y: false,
                    series: camera,
                },
                Panel {
                    y_label: "meter: achieved/target − 1 (%)".into(),
                    log_y: false,
                    series: meter,
                },
            ],
            size: (1300, 600),
        },
    )
}
