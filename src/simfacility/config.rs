//! The simulated facility's TOML file (`configs/simfacility.toml`): the
//! physical truth of a screen, collimator, camera and spot meter. Every key
//! is documented with its unit and range in `docs/SIMFACILITY.md`.
//!
//! Unknown keys are errors; a parse error names the file, the line and the
//! key; a value out of range names the file and `section.key`. Relative
//! paths resolve against the file's directory.

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::error::{toml_message, Error, Result};

/// Largest screen or camera side, pixels: keeps every buffer bounded.
pub const MAX_SIDE: usize = 16_384;
/// Most camera pixels (4096²): the camera's tables take ~52 bytes a pixel
/// while they are built (36 kept: screen corners, etendue, vignetting, and
/// the sensor's PRNU and DSNU maps).
pub const MAX_CAMERA_PIXELS: usize = 1 << 24;
/// Most screen pixels (e.g. 8192 × 4096).
pub const MAX_SCREEN_PIXELS: usize = 1 << 25;
/// Most bytes of kept frames (2 bytes a screen pixel per frame).
pub const MAX_HISTORY_BYTES: usize = 1 << 29;
/// Largest supersampling factor per axis.
pub const MAX_SUPERSAMPLE: usize = 8;
/// Largest number of frames kept for exposure averaging.
pub const MAX_HISTORY: usize = 64;

/// The whole simulated facility.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimFacilityConfig {
    /// Seed of every random draw (PRNU, noise).
    pub seed: u64,
    pub screen: ScreenTruth,
    pub collimator: CollimatorTruth,
    pub camera: CameraTruth,
    pub meter: MeterTruth,
    /// The declared uncertainties of the camera's lab products.
    #[serde(default)]
    pub lab: LabTruth,
}

/// The screen's physical truth.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScreenTruth {
    /// `[width, height]`, pixels.
    pub resolution: [usize; 2],
    /// Drive bits: 8 or 10.
    #[serde(default = "default_bits")]
    pub bits: u32,
    /// Hz; one `present` advances the virtual clock by one refresh.
    pub refresh_hz: f64,
    /// m.
    pub pixel_pitch: f64,
    /// Exponent of the level → radiance curve.
    pub gamma: f64,
    /// ∫ S(λ) dλ of full white at the screen centre, warmed up, W m⁻² sr⁻¹.
    pub max_radiance: f64,
    /// Radiance at level 0 as a fraction of `max_radiance` (1 / contrast).
    pub black_level: f64,
    /// White spectrum: a CSV (`wavelength_nm, relative`) or `"flat"`
    /// (equal energy over 380–780 nm).
    pub spectrum: String,
    /// nm: the black leak's spectrum is the white one shifted this far
    /// toward the blue (the liquid crystal's leakage is not neutral).
    #[serde(default)]
    pub spectral_shift_nm: f64,
    /// nm: the edges blue|green and green|red of the primaries' windows.
    #[serde(default = "default_primary_edges")]
    pub primary_edges_nm: [f64; 2],
    /// nm: the windows' logistic edge width.
    #[serde(default = "default_primary_width")]
    pub primary_edge_width_nm: f64,
    /// Per channel (R, G, B): γ_c − `gamma`.
    #[serde(default)]
    pub channel_gamma_delta: [f64; 3],
    /// Per channel: the linear toe's weight near black.
    #[serde(default)]
    pub toe: [f64; 3],
    /// The toe's extent, in normalised drive.
    #[serde(default = "default_toe_width")]
    pub toe_width: f64,
    /// Per channel: the shoulder's relative compression at full drive.
    #[serde(default)]
    pub shoulder: [f64; 3],
    /// Fraction of each channel's light leaking into each other channel.
    #[serde(default)]
    pub crosstalk: f64,
    /// Relative rms of the mid-spatial-frequency mura.
    #[serde(default)]
    pub mura_rms: f64,
    /// px: the range of the mura's periods.
    #[serde(default = "default_mura_periods")]
    pub mura_periods_px: [f64; 2],
    /// Number of plane waves of the mura.
    #[serde(default = "default_mura_waves")]
    pub mura_waves: usize,
    /// The black leak's relative excess at the screen's corners (n_x⁴ +
    /// n_y⁴) / 2: dark levels are less uniform.
    #[serde(default)]
    pub black_nonuniformity: f64,
    /// Relative radiance drop from the centre to a corner.
    #[serde(default)]
    pub falloff: f64,
    /// Relative radiance change from the centre to the right and bottom
    /// edges.
    #[serde(default)]
    pub gradient: [f64; 2],
    /// Relative radiance deficit at power-on.
    #[serde(default)]
    pub warmup_amplitude: f64,
    /// s.
    #[serde(default = "default_warmup_time")]
    pub warmup_time_constant: f64,
    /// Relative change per hour after power-on.
    #[serde(default)]
    pub drift_per_hour: f64,
    /// Frames kept for averaging over a long exposure.
    #[serde(default = "default_history")]
    pub history_frames: usize,
}

/// The collimator and its misalignment relative to the camera.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CollimatorTruth {
    /// m.
    pub focal_length: f64,
    /// (0, 1].
    pub transmission: f64,
    /// Radial distortion on the normalised screen radius ρ = r / f:
    /// tan θ = ρ (1 + k1 ρ² + k2 ρ⁴).
    #[serde(default)]
    pub k1: f64,
    #[serde(default)]
    pub k2: f64,
    /// Screen position of the optical axis minus the screen centre, px.
    #[serde(default)]
    pub offset_px: [f64; 2],
    /// rad: the screen's x axis relative to the camera's, about the
    /// boresight, positive from x toward y.
    #[serde(default)]
    pub rotation: f64,
    /// Decentring distortion (Brown): Δa = 2 p1 a b + p2 (ρ² + 2 a²),
    /// Δb = p1 (ρ² + 2 b²) + 2 p2 a b.
    #[serde(default)]
    pub p1: f64,
    #[serde(default)]
    pub p2: f64,
    /// Thin-prism distortion (OpenCV's s1…s4): Δa += s1 ρ² + s2 ρ⁴,
    /// Δb += s3 ρ² + s4 ρ⁴.
    #[serde(default)]
    pub thin_prism: [f64; 4],
}

/// A dimensionless spectral response: a constant or a CSV table.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(untagged)]
pub enum ResponseSpec {
    Constant(f64),
    Table(PathBuf),
}

/// The facility camera.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraTruth {
    /// `[width, height]`, pixels.
    pub resolution: [usize; 2],
    /// Intrinsics, pixels (OpenCV K).
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// OpenCV distortion.
    #[serde(default)]
    pub k1: f64,
    #[serde(default)]
    pub k2: f64,
    #[serde(default)]
    pub p1: f64,
    #[serde(default)]
    pub p2: f64,
    /// m: with `f_number`, the entrance pupil.
    pub focal_length: f64,
    pub f_number: f64,
    /// `[lo, hi]`, nm.
    pub band_nm: [f64; 2],
    #[serde(default = "unit_response")]
    pub quantum_efficiency: ResponseSpec,
    #[serde(default = "unit_response")]
    pub transmission: ResponseSpec,
    /// Solar spectrum defining camera-effective radiance (CSV in
    /// W m⁻² nm⁻¹, or `"blackbody"` at 5772 K).
    pub sun_spectrum: String,
    /// s.
    pub exposure: f64,
    /// DN/e⁻.
    pub gain: f64,
    /// e⁻.
    pub full_well: f64,
    pub bits: u32,
    /// DN added to every pixel before quantisation.
    #[serde(default)]
    pub bias_dn: f64,
    /// Off: the mean charge (no Poisson draw), for deterministic tests of
    /// the optics.
    #[serde(default = "yes")]
    pub shot_noise: bool,
    /// e⁻ rms.
    #[serde(default)]
    pub read_noise: f64,
    /// e⁻/s.
    #[serde(default)]
    pub dark_current: f64,
    /// Relative drop at the image corner beyond the cos⁴ law (quadratic).
    #[serde(default)]
    pub vignetting: f64,
    /// Relative rms of the pixel response non-uniformity.
    #[serde(default)]
    pub prnu: f64,
    /// Sample points per axis per camera pixel.
    #[serde(default = "default_supersample")]
    pub supersample: usize,
    /// Relative response deficit at full well: e' = e (1 − β e / full_well).
    #[serde(default)]
    pub nonlinearity: f64,
    /// e⁻ rms of a per-row, per-frame offset.
    #[serde(default)]
    pub row_noise: f64,
    /// Fraction of the mean signal in the image added to every pixel as a
    /// uniform pedestal (veiling glare of the collimator and lens).
    #[serde(default)]
    pub veiling_glare: f64,
}

/// The spot meter.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeterTruth {
    /// `"flat"` (radiometer over `band_nm`, W m⁻² sr⁻¹), `"photopic"`
    /// (photometer, cd m⁻²), or a CSV of a relative response.
    pub response: String,
    /// `[lo, hi]`, nm, for `"flat"`.
    #[serde(default = "default_meter_band")]
    pub band_nm: [f64; 2],
    /// Relative rms noise of one reading.
    #[serde(default)]
    pub noise: f64,
    /// Spot centre on the screen, continuous pixel coordinates.
    pub spot_center_px: [f64; 2],
    /// Spot radius, screen pixels.
    pub spot_radius_px: f64,
    /// s: advances the virtual clock per reading.
    #[serde(default = "default_integration")]
    pub integration_time: f64,
    /// A spectroradiometer: readings carry the spectrum (380–780 nm, 5 nm).
    #[serde(default)]
    pub spectrometer: bool,
    /// nm: the spectroradiometer's wavelength scale error (its value at
    /// nominal λ is the true one at λ + error).
    #[serde(default)]
    pub wavelength_error_nm: f64,
    /// Relative rms noise of each spectral bin.
    #[serde(default)]
    pub spectrum_noise: f64,
}

/// Declared uncertainties (k = 2) of what the camera's calibration lab
/// delivers; each product's error is drawn from the seed within them.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LabTruth {
    /// fx, fy, %.
    pub focal_k2_percent: f64,
    /// cx, cy, px.
    pub principal_point_k2_px: f64,
    /// k1 (absolute).
    pub k1_k2: f64,
    /// Per-pixel measurement noise of the camera flat, relative rms.
    pub flat_pixel_noise: f64,
    /// The camera flat's low-order error (tilt and bowl), relative, k = 2.
    pub flat_low_order_k2: f64,
    /// Absolute responsivity, %.
    pub responsivity_k2_percent: f64,
}

impl Default for LabTruth {
    fn default() -> Self {
        LabTruth {
            focal_k2_percent: 0.05,
            principal_point_k2_px: 0.1,
            k1_k2: 0.002,
            flat_pixel_noise: 0.001,
            flat_low_order_k2: 0.002,
            responsivity_k2_percent: 1.5,
        }
    }
}

fn default_bits() -> u32 {
    8
}
fn default_primary_edges() -> [f64; 2] {
    [490.0, 580.0]
}
fn default_primary_width() -> f64 {
    12.0
}
fn default_toe_width() -> f64 {
    0.05
}
fn default_mura_periods() -> [f64; 2] {
    [20.0, 200.0]
}
fn default_mura_waves() -> usize {
    24
}
fn default_warmup_time() -> f64 {
    600.0
}
fn default_history() -> usize {
    8
}
fn unit_response() -> ResponseSpec {
    ResponseSpec::Constant(1.0)
}
fn yes() -> bool {
    true
}
fn default_supersample() -> usize {
    3
}
fn default_meter_band() -> [f64; 2] {
    [380.0, 780.0]
}
fn default_integration() -> f64 {
    0.1
}

/// `value` must be finite and within `[lo, hi]`.
fn in_range(key: &str, value: f64, lo: f64, hi: f64) -> Result<()> {
    if value.is_finite() && value >= lo && value <= hi {
        Ok(())
    } else {
        Err(Error::invalid(
            key,
            format!("{value} is outside [{lo}, {hi}]"),
        ))
    }
}

/// `value` must be finite, > 0 and at most `hi`.
fn positive(key: &str, value: f64, hi: f64) -> Result<()> {
    if value.is_finite() && value > 0.0 && value <= hi {
        Ok(())
    } else {
        Err(Error::invalid(key, format!("{value} is not in (0, {hi}]")))
    }
}

fn side(key: &str, value: [usize; 2]) -> Result<()> {
    if value.iter().all(|&s| (1..=MAX_SIDE).contains(&s)) {
        Ok(())
    } else {
        Err(Error::invalid(
            key,
            format!("{value:?}: each side must be 1..={MAX_SIDE} pixels"),
        ))
    }
}

fn pixels(key: &str, value: [usize; 2], max: usize) -> Result<()> {
    if value[0] * value[1] <= max {
        Ok(())
    } else {
        Err(Error::invalid(
            key,
            format!("{value:?}: more than {max} pixels"),
        ))
    }
}

fn band(key: &str, b: [f64; 2]) -> Result<()> {
    in_range(key, b[0], 100.0, 3000.0)?;
    in_range(key, b[1], 100.0, 3000.0)?;
    if b[1] <= b[0] {
        return Err(Error::invalid(key, "upper edge must exceed the lower"));
    }
    Ok(())
}

fn response(key: &str, r: &ResponseSpec) -> Result<()> {
    match r {
        ResponseSpec::Constant(v) => in_range(key, *v, 0.0, 1.0),
        ResponseSpec::Table(_) => Ok(()),
    }
}

impl ScreenTruth {
    fn validate(&self) -> Result<()> {
        side("screen.resolution", self.resolution)?;
        pixels("screen.resolution", self.resolution, MAX_SCREEN_PIXELS)?;
        if !matches!(self.bits, 8 | 10) {
            return Err(Error::invalid("screen.bits", "must be 8 or 10"));
        }
        positive("screen.refresh_hz", self.refresh_hz, 1000.0)?;
        positive("screen.pixel_pitch", self.pixel_pitch, 0.01)?;
        in_range("screen.gamma", self.gamma, 0.5, 5.0)?;
        positive("screen.max_radiance", self.max_radiance, 1e6)?;
        in_range("screen.black_level", self.black_level, 0.0, 0.5)?;
        if self.spectrum.trim().is_empty() {
            return Err(Error::invalid("screen.spectrum", "is empty"));
        }
        in_range(
            "screen.spectral_shift_nm",
            self.spectral_shift_nm,
            -50.0,
            50.0,
        )?;
        self.validate_panel()?;
        in_range("screen.falloff", self.falloff, 0.0, 0.5)?;
        in_range("screen.gradient", self.gradient[0], -0.3, 0.3)?;
        in_range("screen.gradient", self.gradient[1], -0.3, 0.3)?;
        in_range("screen.warmup_amplitude", self.warmup_amplitude, 0.0, 0.9)?;
        positive(
            "screen.warmup_time_constant",
            self.warmup_time_constant,
            1e6,
        )?;
        in_range("screen.drift_per_hour", self.drift_per_hour, -0.5, 0.5)?;
        let frame_bytes = 2 * self.resolution[0] * self.resolution[1];
        if !(1..=MAX_HISTORY).contains(&self.history_frames)
            || self.history_frames * frame_bytes > MAX_HISTORY_BYTES
        {
            return Err(Error::invalid(
                "screen.history_frames",
                format!(
                    "{} is not in 1..={}: at most {MAX_HISTORY} frames and {} MiB of frames",
                    self.history_frames,
                    MAX_HISTORY.min(MAX_HISTORY_BYTES / frame_bytes),
                    MAX_HISTORY_BYTES >> 20
                ),
            ));
        }
        Ok(())
    }

    fn validate_panel(&self) -> Result<()> {
        let [e1, e2] = self.primary_edges_nm;
        in_range("screen.primary_edges_nm", e1, 400.0, 700.0)?;
        in_range("screen.primary_edges_nm", e2, 400.0, 700.0)?;
        if e2 <= e1 {
            return Err(Error::invalid(
                "screen.primary_edges_nm",
                "the green|red edge must exceed the blue|green edge",
            ));
        }
        in_range(
            "screen.primary_edge_width_nm",
            self.primary_edge_width_nm,
            1.0,
            50.0,
        )?;
        for d in self.channel_gamma_delta {
            in_range("screen.channel_gamma_delta", d, -0.5, 0.5)?;
            in_range("screen.channel_gamma_delta", self.gamma + d, 0.5, 5.0)?;
        }
        for t in self.toe {
            in_range("screen.toe", t, 0.0, 0.05)?;
        }
        in_range("screen.toe_width", self.toe_width, 0.005, 0.5)?;
        for s in self.shoulder {
            in_range("screen.shoulder", s, 0.0, 0.2)?;
        }
        in_range("screen.crosstalk", self.crosstalk, 0.0, 0.05)?;
        in_range("screen.mura_rms", self.mura_rms, 0.0, 0.02)?;
        let [p0, p1] = self.mura_periods_px;
        in_range("screen.mura_periods_px", p0, 2.0, 1e4)?;
        in_range("screen.mura_periods_px", p1, p0, 1e4)?;
        if !(1..=256).contains(&self.mura_waves) {
            return Err(Error::invalid(
                "screen.mura_waves",
                format!("{} is not in 1..=256", self.mura_waves),
            ));
        }
        in_range(
            "screen.black_nonuniformity",
            self.black_nonuniformity,
            -0.5,
            1.0,
        )
    }

    /// Number of drive levels.
    pub fn levels(&self) -> usize {
        1 << self.bits
    }
}

impl CollimatorTruth {
    fn validate(&self, screen: &ScreenTruth) -> Result<()> {
        positive("collimator.focal_length", self.focal_length, 100.0)?;
        positive("collimator.transmission", self.transmission, 1.0)?;
        in_range("collimator.k1", self.k1, -2.0, 2.0)?;
        in_range("collimator.k2", self.k2, -2.0, 2.0)?;
        let [w, h] = screen.resolution;
        in_range(
            "collimator.offset_px",
            self.offset_px[0],
            -(w as f64),
            w as f64,
        )?;
        in_range(
            "collimator.offset_px",
            self.offset_px[1],
            -(h as f64),
            h as f64,
        )?;
        in_range("collimator.rotation", self.rotation, -0.5, 0.5)?;
        in_range("collimator.p1", self.p1, -1.0, 1.0)?;
        in_range("collimator.p2", self.p2, -1.0, 1.0)?;
        for s in self.thin_prism {
            in_range("collimator.thin_prism", s, -1e4, 1e4)?;
        }
        // The radial part must stay monotone over the screen: d tanθ / dρ > 0
        // (the full distortion's Jacobian is checked when the facility is built).
        let rho = 0.5 * screen.pixel_pitch * ((w * w + h * h) as f64).sqrt() / self.focal_length
            + (self.offset_px[0].hypot(self.offset_px[1])) * screen.pixel_pitch / self.focal_length;
        let slope = 1.0 + 3.0 * self.k1 * rho * rho + 5.0 * self.k2 * rho.powi(4);
        if !(slope > 0.05) {
            return Err(Error::invalid(
                "collimator.k1",
                "the distortion folds over inside the screen",
            ));
        }
        Ok(())
    }
}

impl CameraTruth {
    fn validate(&self) -> Result<()> {
        side("camera.resolution", self.resolution)?;
        pixels("camera.resolution", self.resolution, MAX_CAMERA_PIXELS)?;
        let [w, h] = self.resolution;
        positive("camera.fx", self.fx, 1e7)?;
        positive("camera.fy", self.fy, 1e7)?;
        in_range("camera.cx", self.cx, -(w as f64), 2.0 * w as f64)?;
        in_range("camera.cy", self.cy, -(h as f64), 2.0 * h as f64)?;
        for (k, v) in [("camera.k1", self.k1), ("camera.k2", self.k2)] {
            in_range(k, v, -2.0, 2.0)?;
        }
        for (k, v) in [("camera.p1", self.p1), ("camera.p2", self.p2)] {
            in_range(k, v, -0.1, 0.1)?;
        }
        positive("camera.focal_length", self.focal_length, 100.0)?;
        positive("camera.f_number", self.f_number, 1000.0)?;
        band("camera.band_nm", self.band_nm)?;
        response("camera.quantum_efficiency", &self.quantum_efficiency)?;
        response("camera.transmission", &self.transmission)?;
        if self.sun_spectrum.trim().is_empty() {
            return Err(Error::invalid("camera.sun_spectrum", "is empty"));
        }
        positive("camera.exposure", self.exposure, 3600.0)?;
        positive("camera.gain", self.gain, 1e4)?;
        positive("camera.full_well", self.full_well, 1e9)?;
        if !(1..=16).contains(&self.bits) {
            return Err(Error::invalid("camera.bits", "must be 1..=16"));
        }
        in_range("camera.bias_dn", self.bias_dn, 0.0, 65535.0)?;
        in_range("camera.read_noise", self.read_noise, 0.0, 1e4)?;
        in_range("camera.dark_current", self.dark_current, 0.0, 1e7)?;
        in_range("camera.vignetting", self.vignetting, 0.0, 0.9)?;
        in_range("camera.prnu", self.prnu, 0.0, 0.2)?;
        in_range("camera.nonlinearity", self.nonlinearity, 0.0, 0.05)?;
        in_range("camera.row_noise", self.row_noise, 0.0, 1e4)?;
        in_range("camera.veiling_glare", self.veiling_glare, 0.0, 0.05)?;
        if !(1..=MAX_SUPERSAMPLE).contains(&self.supersample) {
            return Err(Error::invalid(
                "camera.supersample",
                format!("{} is not in 1..={MAX_SUPERSAMPLE}", self.supersample),
            ));
        }
        Ok(())
    }

    /// Entrance pupil area, m².
    pub fn pupil_area(&self) -> f64 {
        let d = self.focal_length / self.f_number;
        std::f64::consts::PI * d * d / 4.0
    }

    /// Collected electrons after the non-linearity: e (1 − β e / full_well)
    /// (the detector's curve, [`crate::sensor::extras::response`]).
    pub fn response(&self, electrons: f64) -> f64 {
        crate::sensor::extras::response(electrons, self.nonlinearity, self.full_well)
    }

    /// DN at or above which a pixel is saturated: a full well (after the
    /// non-linearity) less four standard deviations of the read and row
    /// noise, or the largest DN if that is lower.
    pub fn saturation_dn(&self) -> f64 {
        let noise = self.read_noise.hypot(self.row_noise);
        let full = self.gain * (self.response(self.full_well) - 4.0 * noise) + self.bias_dn;
        full.floor().clamp(1.0, self.max_dn())
    }

    /// Largest DN.
    pub fn max_dn(&self) -> f64 {
        (2f64.powi(self.bits as i32) - 1.0).max(1.0)
    }
}

impl MeterTruth {
    fn validate(&self, screen: &ScreenTruth) -> Result<()> {
        if self.response.trim().is_empty() {
            return Err(Error::invalid("meter.response", "is empty"));
        }
        band("meter.band_nm", self.band_nm)?;
        in_range("meter.noise", self.noise, 0.0, 0.5)?;
        let [w, h] = screen.resolution;
        in_range(
            "meter.spot_center_px",
            self.spot_center_px[0],
            0.0,
            w as f64,
        )?;
        in_range(
            "meter.spot_center_px",
            self.spot_center_px[1],
            0.0,
            h as f64,
        )?;
        in_range(
            "meter.spot_radius_px",
            self.spot_radius_px,
            0.5,
            (w.max(h)) as f64,
        )?;
        in_range("meter.integration_time", self.integration_time, 0.0, 3600.0)?;
        in_range(
            "meter.wavelength_error_nm",
            self.wavelength_error_nm,
            -5.0,
            5.0,
        )?;
        in_range("meter.spectrum_noise", self.spectrum_noise, 0.0, 0.5)?;
        Ok(())
    }
}

impl LabTruth {
    fn validate(&self) -> Result<()> {
        in_range("lab.focal_k2_percent", self.focal_k2_percent, 0.0, 10.0)?;
        in_range(
            "lab.principal_point_k2_px",
            self.principal_point_k2_px,
            0.0,
            100.0,
        )?;
        in_range("lab.k1_k2", self.k1_k2, 0.0, 1.0)?;
        in_range("lab.flat_pixel_noise", self.flat_pixel_noise, 0.0, 0.1)?;
        in_range("lab.flat_low_order_k2", self.flat_low_order_k2, 0.0, 0.1)?;
        in_range(
            "lab.responsivity_k2_percent",
            self.responsivity_k2_percent,
            0.0,
            50.0,
        )
    }
}

impl SimFacilityConfig {
    /// Reads, checks and resolves relative paths against the file's folder.
    pub fn load(path: impl AsRef<Path>) -> Result<SimFacilityConfig> {
        let path = path.as_ref();
        let text = crate::infile::read_text_bounded(path, crate::infile::CONFIG_LIMIT)?;
        let mut cfg = SimFacilityConfig::parse(&text, path)?;
        cfg.resolve_paths(path.parent().unwrap_or(Path::new("")));
        Ok(cfg)
    }

    /// Parses and checks TOML text (paths left as written); `path` names
    /// the file in errors.
    pub fn parse(text: &str, path: impl AsRef<Path>) -> Result<SimFacilityConfig> {
        let path = path.as_ref();
        let cfg: SimFacilityConfig =
            toml::from_str(text).map_err(|e| Error::parse(path, toml_message(text, &e)))?;
        cfg.validate()
            .map_err(|e| Error::parse(path, e.to_string()))?;
        Ok(cfg)
    }

    /// Checks every value's range; errors name `section.key`.
    pub fn validate(&self) -> Result<()> {
        self.screen.validate()?;
        self.collimator.validate(&self.screen)?;
        self.camera.validate()?;
        self.meter.validate(&self.screen)?;
        self.lab.validate()
    }

    /// Makes relative file paths relative to `dir`.
    pub fn resolve_paths(&mut self, dir: &Path) {
        let fix = |s: &mut String| {
            if is_file_spec(s) && Path::new(s.as_str()).is_relative() {
                *s = dir.join(s.as_str()).display().to_string();
            }
        };
        fix(&mut self.screen.spectrum);
        fix(&mut self.camera.sun_spectrum);
        fix(&mut self.meter.response);
        for r in [
            &mut self.camera.quantum_efficiency,
            &mut self.camera.transmission,
        ] {
            if let ResponseSpec::Table(p) = r {
                if p.is_relative() {
                    *p = dir.join(&*p);
                }
            }
        }
    }
}

/// True unless `s` is one of the built-in names.
pub fn is_file_spec(s: &str) -> bool {
    !matches!(s, "flat" | "photopic" | "blackbody")
}
