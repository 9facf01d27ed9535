//! Facility configuration: the TOML file describing screen, collimator,
//! alignment, calibration files, drive (scale, dithering), frame-id block,
//! serial sync and timing.
//!
//! ```toml
//! [scenario]
//! scene = "moon.toml"         # body, Sun, flight camera (band, exposure); relative to this file
//! trajectory = "moon_approach.csv"  # optional default replay
//!
//! [screen]
//! resolution = [1920, 1080]   # pixels
//! pixel_pitch = 2.7e-4        # m
//! monitor = 0                 # RandR monitor: index (0 = first) or name, e.g. "DP-1"
//! refresh_hz = 60.0
//! render_block = 1            # screen pixels per rendered pixel along each axis (1–8)
//!
//! [collimator]
//! focal_length = 0.5          # m
//! transmission = 0.85         # (0, 1]
//!
//! [alignment]
//! offset_px = [0.0, 0.0]      # screen position of the optical axis minus the screen centre
//! rotation = 0.0              # rad, image rotation on the screen
//!
//! [calibration]
//! lut = "example_lut.csv"     # relative to this file's directory
//! # flat_field = "flat.tif"   # optional, Gray32Float of the screen size
//! # geometry = "geometry.csv" # optional: screen pixel → camera direction; supersedes [alignment]
//!
//! [drive]
//! scale_k = 1.0               # or: flight_exposure = .., facility_exposure = .. (s), k = flight/facility
//! dither = "bayer"            # or "blue_noise"
//! temporal = true
//! seed = 1
//! bits = 8                    # 8 or 10
//! sub_bands = 1               # renders per frame of a spectral body (1–16)
//!
//! [frame_id]                  # optional section; defaults shown
//! enabled = true
//! corner = "top_left"         # top_left | top_right | bottom_left | bottom_right
//! bits = 24
//! cell_px = 4
//!
//! [sync]                      # optional section
//! port = "/dev/ttyUSB0"       # optional: no port, no sync
//! template = "FRAME {id} {t} {exposure_us}\n"
//! ack = true
//! ack_timeout = 0.05          # s
//! baud = 115200
//!
//! [timing]
//! state_timeout = 0.5         # s
//! refreshes_per_frame = 1     # frame rate = refresh_hz / this
//! governor = "off"            # "auto": per frame the finest render rung that fits its slot; "fixed": always `governor_rung`
//! governor_rung = 0           # with "fixed": the rung (0 = the configured fidelity)
//! governor_max_block = 4      # coarsest render block the ladder goes down to (1–8)
//! governor_max_pixel_error = 0.1  # a frame whose rung's predicted per-pixel error (p99) exceeds this counts as degraded
//!
//! [acceptance]                # optional section; defaults shown (facility::acceptance)
//! max_sync_not_sent = 0
//! max_safe_fraction = 0.01    # closed loop, after the first state
//! missed_degraded = 0.005
//! missed_fail = 0.05
//! max_clip_flux = 0.001       # of a frame's disk flux
//! allow_empty_frames = false
//! ```
//!
//! Unknown keys are errors. Parse errors name the file, line and key;
//! validation errors name the file and the field (`section.key`).

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::error::{toml_message, Error, Result};

use super::acceptance::AcceptanceConfig;
use super::display::MonitorSelect;
use super::dither::DitherKind;
use super::frame_id::Corner;

/// Largest `screen.render_block`.
pub const MAX_RENDER_BLOCK: usize = 8;

/// Whole facility configuration.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FacilityConfig {
    /// What is shown: the scene file and a default trajectory.
    pub scenario: ScenarioConfig,
    /// Display.
    pub screen: ScreenConfig,
    /// Collimator optics.
    pub collimator: CollimatorConfig,
    /// Image placement on the screen.
    #[serde(default)]
    pub alignment: AlignmentConfig,
    /// Calibration files.
    pub calibration: CalibrationConfig,
    /// Radiance → drive level conversion.
    pub drive: DriveConfig,
    /// Frame-id block.
    #[serde(default)]
    pub frame_id: FrameIdConfig,
    /// Serial sync.
    #[serde(default)]
    pub sync: SyncConfig,
    /// Timing.
    #[serde(default)]
    pub timing: TimingConfig,
    /// What a run must meet: its verdict's rules.
    #[serde(default)]
    pub acceptance: AcceptanceConfig,
    /// `[calibrate]`: read by `optistim calibrate`
    /// ([`calibration::config`](crate::calibration::config)), ignored here.
    #[serde(default, rename = "calibrate")]
    pub _calibrate: Option<toml::Value>,
}

/// `[scenario]`
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScenarioConfig {
    /// Scene file (see docs/SCENE.md): body, Sun and the flight camera's
    /// band and exposure. Its `[state]` gives the body pose when a
    /// trajectory omits it.
    pub scene: PathBuf,
    /// Trajectory replayed when the command line gives no source.
    #[serde(default)]
    pub trajectory: Option<PathBuf>,
}

/// `[screen]`
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScreenConfig {
    /// `[width, height]` in pixels.
    pub resolution: [usize; 2],
    /// Pixel pitch, m.
    pub pixel_pitch: f64,
    /// Monitor of `$DISPLAY`'s default X screen: index or RandR name.
    #[serde(default)]
    pub monitor: MonitorSelect,
    /// Refresh rate, Hz.
    pub refresh_hz: f64,
    /// Screen pixels per rendered pixel along each axis: the renderer
    /// integrates blocks of `render_block`² screen pixels, and each pixel
    /// of a block shows the block's mean radiance. 1 renders every screen
    /// pixel; blocks of 2 about halve the render's cost (BENCHMARKS.md).
    /// Each block sends the flux integrated over it; the camera sees that
    /// flux spread over the block, so the limb and the map's finer detail
    /// blur unless the camera's pixels span several blocks.
    #[serde(default = "one")]
    pub render_block: usize,
}

fn one() -> usize {
    1
}

/// `[collimator]`
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CollimatorConfig {
    /// Focal length, m.
    pub focal_length: f64,
    /// Transmission in (0, 1].
    pub transmission: f64,
}

/// `[alignment]`
#[derive(Debug, Clone, PartialEq, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct AlignmentConfig {
    /// Offset of the optical axis from the screen centre, pixels.
    #[serde(default)]
    pub offset_px: [f64; 2],
    /// Image rotation, rad.
    #[serde(default)]
    pub rotation: f64,
}

/// `[calibration]`
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationConfig {
    /// LUT CSV (resolved against the config directory after loading).
    pub lut: PathBuf,
    /// Flat-field TIFF.
    #[serde(default)]
    pub flat_field: Option<PathBuf>,
    /// Geometric calibration CSV (see [`geometry`](super::geometry)); when
    /// given, `[alignment]` must be absent or zero.
    #[serde(default)]
    pub geometry: Option<PathBuf>,
}

/// `[drive]`
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DriveConfig {
    /// Facility scale factor k.
    #[serde(default)]
    pub scale_k: Option<f64>,
    /// Flight exposure, s (with `facility_exposure`: k = flight/facility).
    #[serde(default)]
    pub flight_exposure: Option<f64>,
    /// Facility camera exposure, s.
    #[serde(default)]
    pub facility_exposure: Option<f64>,
    /// Threshold matrix.
    #[serde(default)]
    pub dither: DitherKind,
    /// Per-frame matrix offset.
    #[serde(default)]
    pub temporal: bool,
    /// Seed.
    #[serde(default)]
    pub seed: u64,
    /// Bits per channel (8 or 10).
    #[serde(default = "default_bits")]
    pub bits: u32,
    /// Renders per frame of a spectral body, each over an equal part of
    /// the camera's band, weighted by its share of the camera's electrons
    /// (1: one render at the electron-weighted wavelength). Ignored for a
    /// spectrally flat body.
    #[serde(default = "default_sub_bands")]
    pub sub_bands: usize,
}

fn default_bits() -> u32 {
    8
}

fn default_sub_bands() -> usize {
    1
}

impl DriveConfig {
    /// The effective k (validated configs only).
    pub fn k(&self) -> Result<f64> {
        match (self.scale_k, self.flight_exposure, self.facility_exposure) {
            (Some(k), None, None) => Ok(k),
            (None, Some(f), Some(s)) => Ok(f / s),
            (Some(_), _, _) => Err(Error::invalid(
                "drive.scale_k",
                "give either scale_k or flight_exposure and facility_exposure, not both",
            )),
            _ => Err(Error::invalid(
                "drive.scale_k",
                "missing: give scale_k, or both flight_exposure and facility_exposure",
            )),
        }
    }
}

/// `[frame_id]`
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FrameIdConfig {
    /// Draw the block.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Corner.
    #[serde(default)]
    pub corner: Corner,
    /// Data bits (8 … 32).
    #[serde(default = "default_id_bits")]
    pub bits: u32,
    /// Cell side, pixels.
    #[serde(default = "default_cell")]
    pub cell_px: usize,
}

fn yes() -> bool {
    true
}
fn default_id_bits() -> u32 {
    24
}
fn default_cell() -> usize {
    4
}

impl Default for FrameIdConfig {
    fn default() -> Self {
        FrameIdConfig {
            enabled: true,
            corner: Corner::default(),
            bits: default_id_bits(),
            cell_px: default_cell(),
        }
    }
}

/// `[sync]`
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SyncConfig {
    /// Serial device path; `None` = no sync hardware.
    #[serde(default)]
    pub port: Option<PathBuf>,
    /// Command template (see [`serial`](super::serial)).
    #[serde(default = "default_template")]
    pub template: String,
    /// Wait for an acknowledgement line.
    #[serde(default)]
    pub ack: bool,
    /// Ack timeout, s.
    #[serde(default = "default_ack_timeout")]
    pub ack_timeout: f64,
    /// Baud rate.
    #[serde(default = "default_baud")]
    pub baud: u32,
}

fn default_template() -> String {
    "FRAME {id} {t} {exposure_us}\n".into()
}
fn default_ack_timeout() -> f64 {
    0.05
}
fn default_baud() -> u32 {
    115_200
}

impl Default for SyncConfig {
    fn default() -> Self {
        SyncConfig {
            port: None,
            template: default_template(),
            ack: false,
            ack_timeout: default_ack_timeout(),
            baud: default_baud(),
        }
    }
}

/// `[timing]`
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimingConfig {
    /// A state older than this is not rendered again, s.
    #[serde(default = "default_state_timeout")]
    pub state_timeout: f64,
    /// Start each frame as late as its recent render, conversion and
    /// present times allow before its slot (late latching), so the state
    /// shown is as fresh as possible; false: start as soon as a buffer is
    /// free.
    #[serde(default = "default_late_latch")]
    pub late_latch: bool,
    /// Screen refreshes each frame is shown for: the frame rate is
    /// `screen.refresh_hz / refreshes_per_frame`. Each frame must be up by
    /// the first refresh of its slot, so it is shown for all of them.
    #[serde(default = "default_refreshes_per_frame")]
    pub refreshes_per_frame: u32,
    /// The frame-time governor ([`crate::facility::governor`]).
    #[serde(default)]
    pub governor: GovernorMode,
    /// The rung of `governor = "fixed"` (0: the configured fidelity).
    #[serde(default)]
    pub governor_rung: usize,
    /// The coarsest render block of the governor's ladder.
    #[serde(default = "default_governor_max_block")]
    pub governor_max_block: usize,
    /// Predicted per-pixel error (p99, against the finest rung) above
    /// which a frame counts as degraded.
    #[serde(default = "default_governor_max_pixel_error")]
    pub governor_max_pixel_error: f64,
}

/// `timing.governor`.
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum GovernorMode {
    /// Every frame at the configured fidelity.
    #[default]
    Off,
    /// Per frame, the finest rung predicted to fit its slot.
    Auto,
    /// Every frame at `governor_rung`.
    Fixed,
}

fn default_governor_max_block() -> usize {
    4
}

fn default_governor_max_pixel_error() -> f64 {
    0.1
}

fn default_refreshes_per_frame() -> u32 {
    1
}

fn default_state_timeout() -> f64 {
    0.5
}

fn default_late_latch() -> bool {
    true
}

impl Default for TimingConfig {
    fn default() -> Self {
        TimingConfig {
            state_timeout: default_state_timeout(),
            late_latch: default_late_latch(),
            refreshes_per_frame: default_refreshes_per_frame(),
            governor: GovernorMode::Off,
            governor_rung: 0,
            governor_max_block: default_governor_max_block(),
            governor_max_pixel_error: default_governor_max_pixel_error(),
        }
    }
}

/// Largest screen side accepted, px (a 16K panel): bounds every buffer
/// sized from `screen.resolution`.
pub const MAX_SCREEN_SIDE: usize = 16_384;

/// Largest frame-id cell, px: keeps the block's size far from overflow.
pub const MAX_CELL_PX: usize = 256;

/// `v` finite and in `[lo, hi]`: checked before any conversion (a
/// `Duration` from 1e308 s panics; a rate of 1e-300 Hz is a 1e300 s period).
fn in_range(field: &str, v: f64, lo: f64, hi: f64) -> Result<()> {
    if v.is_finite() && (lo..=hi).contains(&v) {
        Ok(())
    } else {
        Err(Error::invalid(
            field,
            format!("must be in [{lo:e}, {hi:e}], found {v:e}"),
        ))
    }
}

impl FacilityConfig {
    /// Reads, parses, resolves relative paths against the file's directory
    /// and validates.
    pub fn load(path: impl AsRef<Path>) -> Result<FacilityConfig> {
        let path = path.as_ref();
        let text = crate::infile::read_text_bounded(path, crate::infile::CONFIG_LIMIT)?;
        let mut cfg = FacilityConfig::parse(&text, path)?;
        let dir = path.parent().unwrap_or(Path::new(""));
        cfg.resolve_paths(dir);
        Ok(cfg)
    }

    /// Parses and validates TOML text (paths left as written); `path` names
    /// the file in errors.
    pub fn parse(text: &str, path: impl AsRef<Path>) -> Result<FacilityConfig> {
        let path = path.as_ref();
        let cfg: FacilityConfig =
            toml::from_str(text).map_err(|e| Error::parse(path, toml_message(text, &e)))?;
        cfg.validate()
            .map_err(|e| Error::parse(path, e.to_string()))?;
        Ok(cfg)
    }

    /// Makes relative calibration paths relative to `dir`.
    pub fn resolve_paths(&mut self, dir: &Path) {
        let fix = |p: &mut PathBuf| {
            if p.is_relative() {
                *p = dir.join(&*p);
            }
        };
        fix(&mut self.scenario.scene);
        if let Some(t) = &mut self.scenario.trajectory {
            fix(t);
        }
        fix(&mut self.calibration.lut);
        if let Some(f) = &mut self.calibration.flat_field {
            fix(f);
        }
        if let Some(g) = &mut self.calibration.geometry {
            fix(g);
        }
    }

    /// Checks every value's domain; errors name the field.
    pub fn validate(&self) -> Result<()> {
        self.screen.validate()?;
        self.collimator.validate()?;
        self.alignment
            .validate(self.calibration.geometry.is_some())?;
        self.drive.validate()?;
        self.frame_id.validate(self.screen.resolution)?;
        self.sync.validate()?;
        self.timing.validate()?;
        self.acceptance.validate()
    }

    /// Screen size `(width, height)`.
    pub fn screen_size(&self) -> (usize, usize) {
        (self.screen.resolution[0], self.screen.resolution[1])
    }
}

impl ScreenConfig {
    fn validate(&self) -> Result<()> {
        if self
            .resolution
            .iter()
            .any(|&n| n == 0 || n > MAX_SCREEN_SIDE)
        {
            return Err(Error::invalid(
                "screen.resolution",
                format!("each side must be in 1..={MAX_SCREEN_SIDE}"),
            ));
        }
        if let MonitorSelect::Name(n) = &self.monitor {
            if n.trim().is_empty() {
                return Err(Error::invalid(
                    "screen.monitor",
                    "empty name: give a RandR monitor name or an index",
                ));
            }
        }
        in_range("screen.pixel_pitch", self.pixel_pitch, 1e-7, 1.0)?;
        in_range("screen.refresh_hz", self.refresh_hz, 1.0, 1000.0)?;
        if !(1..=MAX_RENDER_BLOCK).contains(&self.render_block) {
            return Err(Error::invalid(
                "screen.render_block",
                format!(
                    "must be an integer in 1..={MAX_RENDER_BLOCK}, found {}",
                    self.render_block
                ),
            ));
        }
        Ok(())
    }
}

impl CollimatorConfig {
    fn validate(&self) -> Result<()> {
        in_range("collimator.focal_length", self.focal_length, 1e-3, 1e3)?;
        // Below 1e-6 the screen would need a million times the scene's
        // radiance: no screen emits that, and the product overflows.
        in_range("collimator.transmission", self.transmission, 1e-6, 1.0)
    }
}

impl AlignmentConfig {
    /// `with_geometry`: a geometric calibration file is given, which
    /// already holds the screen's placement.
    fn validate(&self, with_geometry: bool) -> Result<()> {
        for v in self.offset_px {
            in_range("alignment.offset_px", v, -1e6, 1e6)?;
        }
        in_range(
            "alignment.rotation",
            self.rotation,
            -std::f64::consts::TAU,
            std::f64::consts::TAU,
        )?;
        if with_geometry {
            let superseded = "must be absent or zero when calibration.geometry is given \
                              (the geometry file already holds the screen's placement)";
            if self.offset_px != [0.0, 0.0] {
                return Err(Error::invalid("alignment.offset_px", superseded));
            }
            if self.rotation != 0.0 {
                return Err(Error::invalid("alignment.rotation", superseded));
            }
        }
        Ok(())
    }
}

impl DriveConfig {
    fn validate(&self) -> Result<()> {
        if let Some(k) = self.scale_k {
            in_range("drive.scale_k", k, 1e-12, 1e12)?;
        }
        if let Some(v) = self.flight_exposure {
            in_range("drive.flight_exposure", v, 1e-9, 1e4)?;
        }
        if let Some(v) = self.facility_exposure {
            in_range("drive.facility_exposure", v, 1e-9, 1e4)?;
        }
        if self.scale_k.is_none()
            && (self.flight_exposure.is_some() != self.facility_exposure.is_some())
        {
            let missing = if self.flight_exposure.is_none() {
                "drive.flight_exposure"
            } else {
                "drive.facility_exposure"
            };
            return Err(Error::invalid(
                missing,
                "missing: both exposures are needed to derive k",
            ));
        }
        self.k()?;
        if self.bits != 8 && self.bits != 10 {
            return Err(Error::invalid(
                "drive.bits",
                format!("must be 8 or 10, found {}", self.bits),
            ));
        }
        if !(1..=16).contains(&self.sub_bands) {
            return Err(Error::invalid(
                "drive.sub_bands",
                format!("must be 1 to 16, found {}", self.sub_bands),
            ));
        }
        Ok(())
    }
}

impl FrameIdConfig {
    /// On a screen of `resolution`, which the block must fit.
    fn validate(&self, resolution: [usize; 2]) -> Result<()> {
        if !(8..=32).contains(&self.bits) {
            return Err(Error::invalid(
                "frame_id.bits",
                format!("must be 8 … 32, found {}", self.bits),
            ));
        }
        if !(1..=MAX_CELL_PX).contains(&self.cell_px) {
            return Err(Error::invalid(
                "frame_id.cell_px",
                format!("must be in 1..={MAX_CELL_PX}, found {}", self.cell_px),
            ));
        }
        if self.enabled {
            let (w, h) = super::frame_id::FrameIdCode::block_size_for(self.bits, self.cell_px);
            if w > resolution[0] || h > resolution[1] {
                return Err(Error::invalid(
                    "frame_id.cell_px",
                    format!("the {w}×{h} block does not fit on the screen"),
                ));
            }
        }
        Ok(())
    }
}

impl SyncConfig {
    fn validate(&self) -> Result<()> {
        // Its errors already name `sync.template`.
        super::serial::CommandTemplate::parse(&self.template)?;
        in_range("sync.ack_timeout", self.ack_timeout, 1e-4, 60.0)?;
        if !(1..=10_000_000).contains(&self.baud) {
            return Err(Error::invalid("sync.baud", "must be in 1..=10000000"));
        }
        Ok(())
    }
}

impl TimingConfig {
    fn validate(&self) -> Result<()> {
        in_range("timing.state_timeout", self.state_timeout, 1e-3, 3600.0)?;
        if !(1..=120).contains(&self.refreshes_per_frame) {
            return Err(Error::invalid(
                "timing.refreshes_per_frame",
                "must be in 1..=120",
            ));
        }
        if !(1..=MAX_RENDER_BLOCK).contains(&self.governor_max_block) {
            return Err(Error::invalid(
                "timing.governor_max_block",
                format!("must be in 1..={MAX_RENDER_BLOCK}"),
            ));
        }
        if self.governor_rung > 16 {
            return Err(Error::invalid(
                "timing.governor_rung",
                "must be in 0..=16 (and exist in the ladder: checked at start)",
            ));
        }
        in_range(
            "timing.governor_max_pixel_error",
            self.governor_max_pixel_error,
            1e-6,
            10.0,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"
[scenario]
scene = "moon.toml"

[screen]
resolution = [1920, 1080]
pixel_pitch = 2.7e-4
monitor = 0
refresh_hz = 60.0

[collimator]
focal_length = 0.5
transmission = 0.85

[alignment]
offset_px = [1.5, -2.0]
rotation = 0.001

[calibration]
lut = "lut.csv"
flat_field = "/abs/flat.tif"

[drive]
flight_exposure = 0.01
facility_exposure = 0.04
dither = "blue_noise"
temporal = true
seed = 3
bits = 8

[frame_id]
enabled = true
corner = "bottom_right"
bits = 16
cell_px = 3

[sync]
template = "FRAME {id} {t} {exposure_us}\n"
ack = true
ack_timeout = 0.02
baud = 9600

[timing]
state_timeout = 0.25
"#;

    #[test]
    fn loads_resolves_paths_and_derives_k() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("facility.toml");
        std::fs::write(&p, GOOD).unwrap();
        let c = FacilityConfig::load(&p).unwrap();
        assert_eq!(c.calibration.lut, dir.path().join("lut.csv"));
        assert_eq!(
            c.calibration.flat_field.as_deref(),
            Some(Path::new("/abs/flat.tif"))
        );
        assert_eq!(c.drive.k().unwrap(), 0.01 / 0.04);
        assert_eq!(c.drive.dither, DitherKind::BlueNoise);
        assert_eq!(c.frame_id.corner, Corner::BottomRight);
        assert_eq!(c.sync.template, "FRAME {id} {t} {exposure_us}\n");
        assert_eq!(c.screen_size(), (1920, 1080));
        assert_eq!(
            c.screen.render_block, 1,
            "default: every screen pixel rendered"
        );
        assert_eq!(c.timing.state_timeout, 0.25);
    }

    #[test]
    fn errors_name_file_and_key() {
        let e = |text: String| {
            FacilityConfig::parse(&text, "cfg/f.toml")
                .unwrap_err()
                .to_string()
        };
        let cases = [
            (
                GOOD.replace("rotation = 0.001", "rotation = 0.001\nrotaton = 1"),
                "rotaton",
            ),
            (
                GOOD.replace("transmission = 0.85", "transmission = 1.5"),
                "collimator.transmission",
            ),
            (
                GOOD.replace("pixel_pitch = 2.7e-4", "pixel_pitch = -1.0"),
                "screen.pixel_pitch",
            ),
            (
                GOOD.replace("pixel_pitch = 2.7e-4", "pixel_pitch = nan"),
                "screen.pixel_pitch",
            ),
            (
                GOOD.replace("facility_exposure = 0.04\n", ""),
                "drive.facility_exposure",
            ),
            (
                GOOD.replace(
                    "flight_exposure = 0.01",
                    "scale_k = 2.0\nflight_exposure = 0.01",
                ),
                "drive.scale_k",
            ),
            (GOOD.replace("bits = 8", "bits = 12"), "drive.bits"),
            (
                GOOD.replace("bits = 8", "bits = 8\nsub_bands = 0"),
                "drive.sub_bands",
            ),
            (
                GOOD.replace("bits = 8", "bits = 8\nsub_bands = 17"),
                "drive.sub_bands",
            ),
            (
                GOOD.replace("dither = \"blue_noise\"", "dither = \"floyd\""),
                "dither",
            ),
            (GOOD.replace("bits = 16", "bits = 40"), "frame_id.bits"),
            (GOOD.replace("{exposure_us}", "{exposure}"), "sync.template"),
            (
                GOOD.replace("state_timeout = 0.25", "state_timeout = 0"),
                "timing.state_timeout",
            ),
            (
                GOOD.replace(
                    "state_timeout = 0.25",
                    "state_timeout = 0.25\nrefreshes_per_frame = 0",
                ),
                "timing.refreshes_per_frame",
            ),
            (GOOD.replace("lut = \"lut.csv\"\n", ""), "lut"),
            (
                GOOD.replace(
                    "lut = \"lut.csv\"",
                    "lut = \"lut.csv\"\ngeometry = \"g.csv\"",
                ),
                "alignment.offset_px",
            ),
            (
                GOOD.replace(
                    "lut = \"lut.csv\"",
                    "lut = \"lut.csv\"\ngeometry = \"g.csv\"",
                )
                .replace("offset_px = [1.5, -2.0]", "offset_px = [0.0, 0.0]"),
                "alignment.rotation",
            ),
            (
                GOOD.replace("resolution = [1920, 1080]", "resolution = [8, 8]"),
                "frame_id.cell_px",
            ),
            (
                GOOD.replace("monitor = 0", "monitor = \"\""),
                "screen.monitor",
            ),
            (GOOD.replace("monitor = 0", "monitor = -1"), "monitor"),
            (GOOD.replace("monitor = 0", "monitor = 1.5"), "monitor"),
            (
                GOOD.replace("refresh_hz = 60.0", "refresh_hz = 60.0\nrender_block = 0"),
                "screen.render_block",
            ),
            (
                GOOD.replace("refresh_hz = 60.0", "refresh_hz = 60.0\nrender_block = 9"),
                "screen.render_block",
            ),
            (
                GOOD.replace("refresh_hz = 60.0", "refresh_hz = 60.0\nrender_block = 1.5"),
                "render_block",
            ),
        ];
        for (text, key) in cases {
            let m = e(text);
            assert!(m.contains("cfg/f.toml") && m.contains(key), "{key}: {m}");
            assert_eq!(
                m.matches(&format!("`{key}`")).count().min(1),
                m.matches(&format!("`{key}`")).count(),
                "{key} named once: {m}"
            );
        }
    }

    /// The hostile values of the hardening issue: each is refused by name
    /// before any `Duration` or buffer is built from it.
    #[test]
    fn extreme_values_are_refused_by_name() {
        let cases = [
            (
                "refresh_hz = 60.0",
                "refresh_hz = 1e-300",
                "screen.refresh_hz",
            ),
            (
                "refresh_hz = 60.0",
                "refresh_hz = 1e308",
                "screen.refresh_hz",
            ),
            (
                "state_timeout = 0.25",
                "state_timeout = 1e308",
                "timing.state_timeout",
            ),
            (
                "transmission = 0.85",
                "transmission = 5e-324",
                "collimator.transmission",
            ),
            (
                "resolution = [1920, 1080]",
                "resolution = [65536, 65536]",
                "screen.resolution",
            ),
            ("rotation = 0.001", "rotation = 1e300", "alignment.rotation"),
            (
                "offset_px = [1.5, -2.0]",
                "offset_px = [1e300, 0.0]",
                "alignment.offset_px",
            ),
            (
                "flight_exposure = 0.01",
                "flight_exposure = 1e300",
                "drive.flight_exposure",
            ),
        ];
        for (from, to, key) in cases {
            let text = GOOD.replace(from, to);
            assert_ne!(text, GOOD, "{from} not in the template");
            let m = FacilityConfig::parse(&text, "cfg/f.toml")
                .unwrap_err()
                .to_string();
            assert!(m.contains("cfg/f.toml") && m.contains(key), "{key}: {m}");
        }
        for (from, to, key) in [
            (
                "ack_timeout = 0.02",
                "ack_timeout = 1e308",
                "sync.ack_timeout",
            ),
            (
                "cell_px = 3",
                "cell_px = 4611686018427387904",
                "frame_id.cell_px",
            ),
        ] {
            let text = GOOD.replace(from, to);
            assert_ne!(text, GOOD, "{from} not in the template");
            let m = FacilityConfig::parse(&text, "f.toml")
                .unwrap_err()
                .to_string();
            assert!(m.contains(key), "{key}: {m}");
        }
    }

    #[test]
    fn monitor_is_an_index_or_a_name() {
        let m = |v: &str| {
            FacilityConfig::parse(&GOOD.replace("monitor = 0", v), "f.toml")
                .unwrap()
                .screen
                .monitor
        };
        assert_eq!(m("monitor = 0"), MonitorSelect::Index(0));
        assert_eq!(m("monitor = 2"), MonitorSelect::Index(2));
        assert_eq!(m("monitor = \"DP-1\""), MonitorSelect::Name("DP-1".into()));
        assert_eq!(m(""), MonitorSelect::Index(0), "default: first monitor");
        let e = FacilityConfig::parse(&GOOD.replace("monitor = 0", "monitor = true"), "f.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("monitor index") && e.contains("monitor name"),
            "{e}"
        );
    }

    #[test]
    fn defaults_for_optional_sections() {
        let text = r#"
[scenario]
scene = "s.toml"

[screen]
resolution = [640, 480]
pixel_pitch = 1e-4
refresh_hz = 60
[collimator]
focal_length = 0.3
transmission = 1.0
[calibration]
lut = "l.csv"
[drive]
scale_k = 1.0
"#;
        let c = FacilityConfig::parse(text, "x.toml").unwrap();
        assert_eq!(c.drive.bits, 8);
        assert_eq!(c.drive.dither, DitherKind::Bayer);
        assert!(c.frame_id.enabled);
        assert!(c.sync.port.is_none());
        assert!(!c.sync.ack);
        assert_eq!(c.alignment.offset_px, [0.0, 0.0]);
        assert!(c.calibration.geometry.is_none());
    }

    #[test]
    fn geometry_file_with_zero_or_absent_alignment() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("facility.toml");
        let text = GOOD
            .replace(
                "lut = \"lut.csv\"",
                "lut = \"lut.csv\"\ngeometry = \"g.csv\"",
            )
            .replace("offset_px = [1.5, -2.0]", "offset_px = [0.0, 0.0]")
            .replace("rotation = 0.001", "rotation = 0.0");
        std::fs::write(&p, &text).unwrap();
        let c = FacilityConfig::load(&p).unwrap();
        assert_eq!(c.calibration.geometry, Some(dir.path().join("g.csv")));
        let absent = text.replace("[alignment]\noffset_px = [0.0, 0.0]\nrotation = 0.0\n", "");
        assert!(!absent.contains("[alignment]"));
        FacilityConfig::parse(&absent, "f.toml").unwrap();
    }
}
