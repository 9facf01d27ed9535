//! The calibration's instrument configuration: the `[calibrate.meter]` and
//! `[calibrate.camera]` tables of the facility file, their validation, and
//! the functions that open the real instruments they describe.
//!
//! ```toml
//! [calibrate.meter]
//! kind = "serial"               # "serial" | "sim" (the simulated facility's meter)
//! name = "LS-150 photometer"    # for errors and provenance
//! port = "/dev/ttyUSB1"
//! baud = 9600
//! command = "MEAS\r\n"          # sent once per reading (TOML escapes apply)
//! unit_scale = 1.0              # reading = instrument value × unit_scale
//! settle = 0.5                  # s, waited before each command
//! timeout = 5.0                 # s, for the whole reply
//! retries = 2                   # extra attempts after a timeout or a malformed reply
//! # spectral_response = "meter_response.csv"  # M(λ): wavelength_nm,response
//!
//! [calibrate.meter.reply]
//! format = "scalar"             # "scalar" | "spectrum"
//! prefix = "OK"                 # the reply must start with this
//! field = 0                     # scalar: the number's index after the prefix
//! # error_prefix = "ER"         # a reply starting with this is an instrument error
//! # end = "END"                 # spectrum: the line ending the reply
//! # pair_separator = ","        # spectrum: between wavelength and value
//!
//! [calibrate.camera]
//! kind = "files"                # "files" | "command" | "sim"
//! name = "navcam via collimator"
//! dir = "frames"                # where frames appear (files) or are written (command)
//! pattern = "{pattern}"         # file name without extension; {pattern} = the pattern's name
//! # command = "grab --exposure {exposure_us} --out {path}"
//! # extension = "png"           # command: the format {path} asks for
//! timeout = 30.0                # s
//! poll = 0.05                   # s, files: interval between checks
//! exposure = 0.01               # s
//! saturation_dn = 65535
//! # resolution = [1024, 1024]   # expected frame size, checked on every frame
//! dark = "shutter"              # "shutter" | "capture" | "none" | a dark model file (TOML)
//! dark_frames = 4               # closed-shutter frames averaged per exposure
//! # intrinsics = "navcam_intrinsics.toml"
//! # responsivity = "navcam_responsivity.toml"  # absolute DN/s per W m⁻² sr⁻¹ (verify)
//! ```
//!
//! Unknown keys are errors; [`SpotMeterConfig::validate`] and
//! [`CameraConfig::validate`] check every value's range and name the key
//! (`calibrate.meter.timeout`). The reply format is described in
//! [`ReplySpec`] and docs/INSTRUMENTS.md.

use std::path::{Path, PathBuf};

use serde::Deserialize;

use super::camera::{CommandCamera, FilesCamera};
use super::spot_meter::SerialSpotMeter;
use super::{Camera, SpotMeter};
use crate::error::{Error, Result};
use crate::radiometry::spectrum::Table;

/// Key prefix of the meter table, for error messages.
pub const METER_KEY: &str = "calibrate.meter";
/// Key prefix of the camera table, for error messages.
pub const CAMERA_KEY: &str = "calibrate.camera";

/// Longest instrument name, command, prefix or template, characters.
pub const MAX_TEXT: usize = 256;
/// Largest frame a camera may deliver, pixels (2^26, e.g. 8192 × 8192).
pub const MAX_FRAME_PIXELS: usize = 1 << 26;

/// Which spot meter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MeterKind {
    /// A real instrument on a serial port.
    Serial,
    /// The simulated facility's meter (built by the simulated facility).
    Sim,
}

/// `[calibrate.meter]`: a spot meter speaking a line protocol.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpotMeterConfig {
    /// Backend.
    pub kind: MeterKind,
    /// Instrument name for errors and provenance.
    #[serde(default = "default_meter_name")]
    pub name: String,
    /// Serial device (required for `serial`).
    #[serde(default)]
    pub port: Option<PathBuf>,
    /// Baud rate.
    #[serde(default = "default_meter_baud")]
    pub baud: u32,
    /// Bytes sent per reading, e.g. `"MEAS\r\n"`.
    #[serde(default = "default_meter_command")]
    pub command: String,
    /// How to read the reply.
    #[serde(default)]
    pub reply: ReplySpec,
    /// Reading = instrument value × this (to W m⁻² sr⁻¹ for a radiometer;
    /// a spectroradiometer's spectrum values are scaled by it too).
    #[serde(default = "one_f64")]
    pub unit_scale: f64,
    /// Expanded uncertainty (k = 2, %) of the meter's own calibration
    /// (its absolute scale), for the uncertainty budget.
    #[serde(default)]
    pub scale_uncertainty_k2_percent: Option<f64>,
    /// Wait before each command, s.
    #[serde(default)]
    pub settle: f64,
    /// Time allowed for the whole reply, s.
    #[serde(default = "default_meter_timeout")]
    pub timeout: f64,
    /// Extra attempts after a timeout or a malformed reply.
    #[serde(default = "default_retries")]
    pub retries: u32,
    /// The meter's spectral response M(λ): CSV `wavelength_nm,response`.
    #[serde(default)]
    pub spectral_response: Option<PathBuf>,
}

/// Whether a reply holds one number or a spectrum.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum ReplyFormat {
    /// One line; the reading is one number in it.
    #[default]
    Scalar,
    /// `wavelength,value` records (one per line or `;`-separated) until a
    /// terminator line.
    Spectrum,
}

/// `[calibrate.meter.reply]`: how a reply is parsed (see docs/INSTRUMENTS.md).
///
/// A reply is text. Its first line must start with `prefix` (after leading
/// whitespace), which is removed. A reply starting with `error_prefix`
/// instead is the instrument reporting an error.
///
/// - `scalar`: the reply is one line (ended by `\r` or `\n`). After the
///   prefix, it is split into tokens at whitespace, `,` and `;`; token
///   number `field` (0-based) is the number (Rust/C float syntax, e.g.
///   `12.34E+00`). Other tokens (units, status words) are ignored.
/// - `spectrum`: the reply is records separated by line ends or `;` until a
///   line equal to `end` (trimmed). Each non-empty record is
///   `wavelength_nm <pair_separator> value`; wavelengths strictly
///   increasing, at least two records. The scalar value is the spectrum's
///   trapezoid integral.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReplySpec {
    /// Scalar or spectrum.
    #[serde(default)]
    pub format: ReplyFormat,
    /// Text the reply starts with (removed before parsing).
    #[serde(default)]
    pub prefix: String,
    /// Scalar: index of the number among the tokens after the prefix.
    #[serde(default)]
    pub field: usize,
    /// A reply starting with this is an instrument error.
    #[serde(default)]
    pub error_prefix: Option<String>,
    /// Spectrum: the terminator line.
    #[serde(default)]
    pub end: Option<String>,
    /// Spectrum: separator between wavelength and value.
    #[serde(default = "default_pair_separator")]
    pub pair_separator: String,
}

impl Default for ReplySpec {
    fn default() -> Self {
        ReplySpec {
            format: ReplyFormat::Scalar,
            prefix: String::new(),
            field: 0,
            error_prefix: None,
            end: None,
            pair_separator: default_pair_separator(),
        }
    }
}

/// Largest `reply.field`.
pub const MAX_FIELD: usize = 64;

fn default_meter_name() -> String {
    "spot meter".into()
}
fn default_meter_baud() -> u32 {
    9600
}
fn default_meter_command() -> String {
    "MEAS\r\n".into()
}
fn one_f64() -> f64 {
    1.0
}
fn default_meter_timeout() -> f64 {
    5.0
}
fn default_retries() -> u32 {
    2
}
fn default_pair_separator() -> String {
    ",".into()
}

/// Which camera backend.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CameraKind {
    /// The acquisition software writes one file per pattern into `dir`.
    Files,
    /// `command` is run per pattern and writes `{path}`.
    Command,
    /// The simulated facility's camera (built by the simulated facility).
    Sim,
}

/// Image file format a `command` camera is asked to write.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum FrameExtension {
    /// 16-bit grey PNG.
    #[default]
    Png,
    /// 16-bit or 32-bit float grey TIFF.
    Tif,
    /// Same as `tif`.
    Tiff,
    /// FITS primary HDU.
    Fits,
}

impl FrameExtension {
    /// The file extension, without the dot.
    pub fn as_str(self) -> &'static str {
        match self {
            FrameExtension::Png => "png",
            FrameExtension::Tif => "tif",
            FrameExtension::Tiff => "tiff",
            FrameExtension::Fits => "fits",
        }
    }

    /// Every extension the `files` backend looks for.
    pub const ALL: [FrameExtension; 4] = [
        FrameExtension::Png,
        FrameExtension::Tif,
        FrameExtension::Tiff,
        FrameExtension::Fits,
    ];
}

/// Where the dark frames (bias + dark current at each exposure) come from.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(from = "PathBuf")]
pub enum DarkSource {
    /// `"shutter"`: the camera closes its shutter; darks are taken at each
    /// exposure the campaign uses, when first needed.
    Shutter,
    /// `"capture"`: the operator covers the camera once and darks are taken
    /// at every exposure of the ladder before the campaign.
    Capture,
    /// `"none"`: no dark correction (said explicitly).
    None,
    /// A dark model file (TOML: camera, size, saturation and dark frames at
    /// exposures; see [`DarkBank`](crate::calibration::dark::DarkBank)).
    /// Write `"./shutter"` etc. for a file of a reserved name.
    File(PathBuf),
}

impl From<PathBuf> for DarkSource {
    fn from(p: PathBuf) -> Self {
        match p.to_str() {
            Some("shutter") => DarkSource::Shutter,
            Some("capture") => DarkSource::Capture,
            Some("none") => DarkSource::None,
            _ => DarkSource::File(p),
        }
    }
}

/// `[calibrate.camera]`: the facility camera.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraConfig {
    /// Backend.
    pub kind: CameraKind,
    /// Camera name for errors and provenance.
    #[serde(default = "default_camera_name")]
    pub name: String,
    /// Folder frames appear in (`files`) or are written to (`command`).
    #[serde(default)]
    pub dir: Option<PathBuf>,
    /// File name without extension; `{pattern}` is the pattern's name.
    #[serde(default = "default_file_pattern")]
    pub pattern: String,
    /// `command`: the capture command, split at whitespace into argv (no
    /// shell); placeholders `{exposure_us}`, `{path}`, `{pattern}`.
    #[serde(default)]
    pub command: Option<String>,
    /// `command`: the format `{path}` asks for.
    #[serde(default)]
    pub extension: FrameExtension,
    /// Time allowed for one frame, s.
    #[serde(default = "default_camera_timeout")]
    pub timeout: f64,
    /// `files`: interval between checks for the file, s.
    #[serde(default = "default_poll")]
    pub poll: f64,
    /// Exposure the calibration asks for, s.
    pub exposure: f64,
    /// DN at or above which a pixel is saturated.
    pub saturation_dn: f64,
    /// Expected `[width, height]`; every frame is checked against it.
    #[serde(default, deserialize_with = "exact_pair")]
    pub resolution: Option<[usize; 2]>,
    /// The dark model; required (`"none"` must be said explicitly).
    #[serde(default)]
    pub dark: Option<DarkSource>,
    /// Closed-shutter frames averaged per exposure.
    #[serde(default = "default_dark_frames")]
    pub dark_frames: usize,
    /// The camera's absolute responsivity file
    /// ([`CameraResponsivity`](crate::calibration::responsivity::CameraResponsivity)).
    #[serde(default)]
    pub responsivity: Option<PathBuf>,
    /// Camera intrinsics file (see [`intrinsics`](super::intrinsics)).
    #[serde(default)]
    pub intrinsics: Option<PathBuf>,
}

/// `[width, height]`, refusing other lengths (a fixed-size array would
/// silently drop a third number).
fn exact_pair<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> std::result::Result<Option<[usize; 2]>, D::Error> {
    use serde::de::Error as _;
    let v: Option<Vec<usize>> = Option::deserialize(d)?;
    v.map(|v| {
        let n = v.len();
        v.try_into()
            .map_err(|_| D::Error::custom(format!("expected [width, height], found {n} numbers")))
    })
    .transpose()
}

fn default_dark_frames() -> usize {
    4
}

fn default_camera_name() -> String {
    "camera".into()
}
fn default_file_pattern() -> String {
    "{pattern}".into()
}
fn default_camera_timeout() -> f64 {
    30.0
}
fn default_poll() -> f64 {
    0.05
}

/// Checks `lo <= v <= hi` (and finite); the error names the key.
pub(crate) fn in_range(key: &str, v: f64, lo: f64, hi: f64) -> Result<()> {
    if v.is_finite() && v >= lo && v <= hi {
        Ok(())
    } else {
        Err(Error::invalid(
            key,
            format!("must be in [{lo}, {hi}], found {v}"),
        ))
    }
}

/// Checks `lo < v <= hi` (and finite); the error names the key.
pub(crate) fn in_range_open(key: &str, v: f64, lo: f64, hi: f64) -> Result<()> {
    if v.is_finite() && v > lo && v <= hi {
        Ok(())
    } else {
        Err(Error::invalid(
            key,
            format!("must be in ({lo}, {hi}], found {v}"),
        ))
    }
}

fn text(key: &str, s: &str, may_be_empty: bool) -> Result<()> {
    if !may_be_empty && s.trim().is_empty() {
        return Err(Error::invalid(key, "must not be empty"));
    }
    if s.chars().count() > MAX_TEXT {
        return Err(Error::invalid(
            key,
            format!("longer than {MAX_TEXT} characters"),
        ));
    }
    Ok(())
}

impl SpotMeterConfig {
    /// Checks every value's range; errors name the key
    /// (`calibrate.meter.<key>`).
    pub fn validate(&self) -> Result<()> {
        self.validate_as(METER_KEY)
    }

    /// [`validate`](Self::validate) for the same table under another key
    /// (`calibrate.spectroradiometer`); errors name `<table>.<key>`.
    pub fn validate_as(&self, table: &str) -> Result<()> {
        let k = |key: &str| format!("{table}.{key}");
        text(&k("name"), &self.name, false)?;
        if self.kind == MeterKind::Serial {
            match &self.port {
                None => {
                    return Err(Error::invalid(
                        k("port"),
                        "missing: a serial meter needs a port",
                    ))
                }
                Some(p) if p.as_os_str().is_empty() => {
                    return Err(Error::invalid(k("port"), "must not be empty"))
                }
                _ => {}
            }
        }
        if !(50..=4_000_000).contains(&self.baud) {
            return Err(Error::invalid(
                k("baud"),
                format!("must be in 50..=4000000, found {}", self.baud),
            ));
        }
        if self.command.is_empty() {
            return Err(Error::invalid(k("command"), "must not be empty"));
        }
        text(&k("command"), &self.command, true)?;
        in_range(&k("unit_scale"), self.unit_scale, 1e-15, 1e15)?;
        if let Some(u) = self.scale_uncertainty_k2_percent {
            in_range(&k("scale_uncertainty_k2_percent"), u, 0.0, 100.0)?;
        }
        in_range(&k("settle"), self.settle, 0.0, 600.0)?;
        in_range_open(&k("timeout"), self.timeout, 0.0, 600.0)?;
        if self.retries > 20 {
            return Err(Error::invalid(
                k("retries"),
                format!("must be in 0..=20, found {}", self.retries),
            ));
        }
        self.reply.validate(&k("reply"))
    }

    /// The meter's spectral response M(λ) from `spectral_response`, if
    /// given (CSV `wavelength_nm,response`; the table holds metres).
    pub fn load_spectral_response(&self) -> Result<Option<Table>> {
        self.spectral_response
            .as_deref()
            .map(Table::from_csv)
            .transpose()
    }

    /// Makes a relative `spectral_response` relative to `dir`.
    pub fn resolve_paths(&mut self, dir: &Path) {
        if let Some(p) = &mut self.spectral_response {
            fix(p, dir);
        }
    }
}

impl ReplySpec {
    /// Checks the spec; `key` is the table's key (`calibrate.meter.reply`).
    pub fn validate(&self, key: &str) -> Result<()> {
        let k = |f: &str| format!("{key}.{f}");
        text(&k("prefix"), &self.prefix, true)?;
        if self.prefix.contains(['\r', '\n']) {
            return Err(Error::invalid(k("prefix"), "must not contain a line end"));
        }
        if self.field > MAX_FIELD {
            return Err(Error::invalid(
                k("field"),
                format!("must be in 0..={MAX_FIELD}, found {}", self.field),
            ));
        }
        if let Some(e) = &self.error_prefix {
            text(&k("error_prefix"), e, false)?;
        }
        match self.format {
            ReplyFormat::Scalar => {
                if self.end.is_some() {
                    return Err(Error::invalid(k("end"), "only for format = \"spectrum\""));
                }
            }
            ReplyFormat::Spectrum => {
                let Some(end) = &self.end else {
                    return Err(Error::invalid(
                        k("end"),
                        "missing: a spectrum reply needs its terminator line",
                    ));
                };
                text(&k("end"), end, false)?;
                if end.contains(['\r', '\n', ';']) {
                    return Err(Error::invalid(
                        k("end"),
                        "must not contain a line end or `;`",
                    ));
                }
                let sep = &self.pair_separator;
                // A space is a valid separator: only emptiness is refused.
                text(&k("pair_separator"), sep, true)?;
                if sep.is_empty() {
                    return Err(Error::invalid(k("pair_separator"), "must not be empty"));
                }
                if sep.contains(['\r', '\n', ';'])
                    || sep
                        .chars()
                        .any(|c| c.is_ascii_digit() || c == '.' || c == '-' || c == '+')
                {
                    return Err(Error::invalid(
                        k("pair_separator"),
                        "must not contain a line end, `;`, a digit, `.`, `+` or `-`",
                    ));
                }
            }
        }
        Ok(())
    }
}

fn fix(p: &mut PathBuf, dir: &Path) {
    if p.is_relative() {
        *p = dir.join(&*p);
    }
}

impl CameraConfig {
    /// Checks every value's range; errors name the key
    /// (`calibrate.camera.<key>`).
    pub fn validate(&self) -> Result<()> {
        let k = |key: &str| format!("{CAMERA_KEY}.{key}");
        text(&k("name"), &self.name, false)?;
        check_file_pattern(&k("pattern"), &self.pattern)?;
        match self.kind {
            CameraKind::Files => {
                if self.dir.is_none() {
                    return Err(Error::invalid(
                        k("dir"),
                        "missing: the folder frames appear in",
                    ));
                }
                if self.command.is_some() {
                    return Err(Error::invalid(k("command"), "only for kind = \"command\""));
                }
            }
            CameraKind::Command => {
                if self.dir.is_none() {
                    return Err(Error::invalid(
                        k("dir"),
                        "missing: the folder frames are written to",
                    ));
                }
                let Some(c) = &self.command else {
                    return Err(Error::invalid(k("command"), "missing: the capture command"));
                };
                text(&k("command"), c, false)?;
                super::camera::CommandLine::parse(c)
                    .map_err(|m| Error::invalid(k("command"), m))?;
            }
            CameraKind::Sim => {}
        }
        in_range_open(&k("timeout"), self.timeout, 0.0, 3600.0)?;
        in_range(&k("poll"), self.poll, 0.001, 10.0)?;
        if !(1..=64).contains(&self.dark_frames) {
            return Err(Error::invalid(
                k("dark_frames"),
                format!("must be 1..=64, found {}", self.dark_frames),
            ));
        }
        in_range_open(&k("exposure"), self.exposure, 0.0, 3600.0)?;
        in_range_open(&k("saturation_dn"), self.saturation_dn, 0.0, 1e9)?;
        if let Some([w, h]) = self.resolution {
            let ok =
                (1..=65_536).contains(&w) && (1..=65_536).contains(&h) && w * h <= MAX_FRAME_PIXELS;
            if !ok {
                return Err(Error::invalid(
                    k("resolution"),
                    format!(
                        "must be 1..=65536 each and at most {MAX_FRAME_PIXELS} pixels, found [{w}, {h}]"
                    ),
                ));
            }
        }
        Ok(())
    }

    /// Makes relative `dir`, `dark` and `intrinsics` relative to `dir`.
    pub fn resolve_paths(&mut self, dir: &Path) {
        if let Some(p) = &mut self.dir {
            fix(p, dir);
        }
        if let Some(DarkSource::File(p)) = &mut self.dark {
            fix(p, dir);
        }
        if let Some(p) = &mut self.intrinsics {
            fix(p, dir);
        }
        if let Some(p) = &mut self.responsivity {
            fix(p, dir);
        }
    }

    /// `pattern` with `{pattern}` replaced by `name` (the file name without
    /// extension). `name` must be a safe file-name part (letters, digits,
    /// `_ - .`, not starting with `.`).
    pub fn file_stem(&self, name: &str) -> Result<String> {
        check_pattern_name(name)?;
        Ok(self.pattern.replace("{pattern}", name))
    }
}

/// Pattern names become file names: only `[A-Za-z0-9_.-]`, not starting
/// with `.`, 1–128 characters.
pub fn check_pattern_name(name: &str) -> Result<()> {
    let ok = !name.is_empty()
        && name.len() <= 128
        && !name.starts_with('.')
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'));
    if ok {
        Ok(())
    } else {
        Err(Error::Other(format!(
            "pattern name `{}`: use 1–128 of A–Z a–z 0–9 _ - . (not starting with .)",
            abbreviate(name, 80)
        )))
    }
}

fn check_file_pattern(key: &str, p: &str) -> Result<()> {
    text(key, p, false)?;
    if !p.contains("{pattern}") {
        return Err(Error::invalid(key, "must contain `{pattern}`"));
    }
    if p.contains(['/', '\\']) || p.replace("{pattern}", "").contains(['{', '}']) {
        return Err(Error::invalid(
            key,
            "a file name without folders; the only placeholder is `{pattern}`",
        ));
    }
    Ok(())
}

/// `s` on one line, at most `max` characters, control characters shown as
/// `\r`, `\n`, `\xNN`, `…` where cut (for quoting instrument replies in
/// errors).
pub fn abbreviate(s: &str, max: usize) -> String {
    let mut out = String::new();
    for c in s.chars() {
        let piece = match c {
            '\r' => "\\r".to_string(),
            '\n' => "\\n".to_string(),
            '\t' => "\\t".to_string(),
            c if c.is_control() => format!("\\x{:02x}", c as u32 & 0xff),
            c => c.to_string(),
        };
        if out.chars().count() + piece.chars().count() > max.saturating_sub(1) {
            out.push('…');
            return out;
        }
        out.push_str(&piece);
    }
    out
}

/// Opens the real spot meter `cfg` describes; relative paths resolve
/// against `base_dir` (the facility file's folder). `kind = "sim"` is an
/// error here: the simulated facility builds its own meter.
pub fn open_spot_meter(cfg: &SpotMeterConfig, base_dir: &Path) -> Result<Box<dyn SpotMeter>> {
    open_spot_meter_as(cfg, base_dir, METER_KEY)
}

/// [`open_spot_meter`] for the table under `table` (its errors name it):
/// the same protocol serves a spectroradiometer
/// (`calibrate.spectroradiometer`).
pub fn open_spot_meter_as(
    cfg: &SpotMeterConfig,
    base_dir: &Path,
    table: &str,
) -> Result<Box<dyn SpotMeter>> {
    cfg.validate_as(table)?;
    let mut cfg = cfg.clone();
    cfg.resolve_paths(base_dir);
    match cfg.kind {
        MeterKind::Serial => Ok(Box::new(SerialSpotMeter::open(cfg)?)),
        MeterKind::Sim => Err(Error::invalid(
            format!("{table}.kind"),
            "\"sim\" is the simulated facility's meter: it is built by the simulated facility, not opened here",
        )),
    }
}

/// Opens the real camera `cfg` describes; relative paths resolve against
/// `base_dir`. `kind = "sim"` is an error here: the simulated facility
/// builds its own camera.
pub fn open_camera(cfg: &CameraConfig, base_dir: &Path) -> Result<Box<dyn Camera>> {
    cfg.validate()?;
    let mut cfg = cfg.clone();
    cfg.resolve_paths(base_dir);
    if let Some(dir) = &cfg.dir {
        if !dir.is_dir() {
            return Err(Error::invalid(
                format!("{CAMERA_KEY}.dir"),
                format!("{} is not a folder", dir.display()),
            ));
        }
    }
    match cfg.kind {
        CameraKind::Files => Ok(Box::new(FilesCamera::new(cfg)?)),
        CameraKind::Command => Ok(Box::new(CommandCamera::new(cfg)?)),
        CameraKind::Sim => Err(Error::invalid(
            format!("{CAMERA_KEY}.kind"),
            "\"sim\" is the simulated facility's camera: it is built by the simulated facility, not opened here",
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Deserialize)]
    struct Calibrate {
        meter: SpotMeterConfig,
        camera: CameraConfig,
    }
    #[derive(Deserialize)]
    struct File {
        calibrate: Calibrate,
    }

    const GOOD: &str = r#"
[calibrate.meter]
kind = "serial"
name = "photometer"
port = "/dev/ttyUSB1"
baud = 9600
command = "MEAS\r\n"
unit_scale = 1.0
settle = 0.5
timeout = 5.0
retries = 2

[calibrate.meter.reply]
format = "scalar"
prefix = "OK"
field = 0

[calibrate.camera]
kind = "command"
dir = "frames"
pattern = "cal_{pattern}"
command = "grab --exposure {exposure_us} --out {path}"
timeout = 30.0
exposure = 0.01
saturation_dn = 65535
resolution = [1024, 1024]
dark = "capture"
"#;

    fn parse(text: &str) -> Result<(SpotMeterConfig, CameraConfig)> {
        let f: File = toml::from_str(text).map_err(|e| Error::parse("f.toml", e.to_string()))?;
        f.calibrate.meter.validate()?;
        f.calibrate.camera.validate()?;
        Ok((f.calibrate.meter, f.calibrate.camera))
    }

    #[test]
    fn good_config_parses_with_its_values() {
        let (m, c) = parse(GOOD).unwrap();
        assert_eq!(m.command, "MEAS\r\n");
        assert_eq!(m.reply.prefix, "OK");
        assert_eq!(c.dark, Some(DarkSource::Capture));
        assert_eq!(c.file_stem("level_0001").unwrap(), "cal_level_0001");
        assert!(c.file_stem("../x").is_err());
        let text = GOOD.replace("dark = \"capture\"", "dark = \"d.toml\"");
        let (_, mut c) = parse(&text).unwrap();
        c.resolve_paths(Path::new("/base"));
        assert_eq!(c.dark, Some(DarkSource::File("/base/d.toml".into())));
        for (word, want) in [("shutter", DarkSource::Shutter), ("none", DarkSource::None)] {
            let (_, c) = parse(&GOOD.replace("\"capture\"", &format!("\"{word}\""))).unwrap();
            assert_eq!(c.dark, Some(want));
        }

        assert_eq!(c.dir, Some(PathBuf::from("/base/frames")));
    }

    #[test]
    fn bad_values_name_their_key() {
        let cases = [
            ("timeout = 5.0", "timeout = -1.0", "calibrate.meter.timeout"),
            ("timeout = 5.0", "timeout = nan", "calibrate.meter.timeout"),
            ("settle = 0.5", "settle = 1e9", "calibrate.meter.settle"),
            ("retries = 2", "retries = 99", "calibrate.meter.retries"),
            ("baud = 9600", "baud = 0", "calibrate.meter.baud"),
            (
                "unit_scale = 1.0",
                "unit_scale = 0.0",
                "calibrate.meter.unit_scale",
            ),
            ("port = \"/dev/ttyUSB1\"\n", "", "calibrate.meter.port"),
            ("field = 0", "field = 1000", "calibrate.meter.reply.field"),
            (
                "format = \"scalar\"",
                "format = \"spectrum\"",
                "calibrate.meter.reply.end",
            ),
            (
                "exposure = 0.01",
                "exposure = 0",
                "calibrate.camera.exposure",
            ),
            (
                "saturation_dn = 65535",
                "saturation_dn = inf",
                "calibrate.camera.saturation_dn",
            ),
            (
                "resolution = [1024, 1024]",
                "resolution = [100000, 1000]",
                "calibrate.camera.resolution",
            ),
            ("[1024, 1024]", "[1024, 1024, 3]", "width, height"),
            ("cal_{pattern}", "cal_{level}", "calibrate.camera.pattern"),
            ("cal_{pattern}", "../{pattern}", "calibrate.camera.pattern"),
            ("cal_{pattern}", "cal", "calibrate.camera.pattern"),
            ("--out {path}", "--out {file}", "calibrate.camera.command"),
            (
                "kind = \"command\"",
                "kind = \"files\"",
                "calibrate.camera.command",
            ),
            ("retries = 2", "retries = 2\nretry = 1", "retry"),
            ("kind = \"serial\"", "kind = \"usb\"", "kind"),
        ];
        for (from, to, key) in cases {
            let text = GOOD.replacen(from, to, 1);
            assert_ne!(text, GOOD, "{from}");
            let e = parse(&text).unwrap_err().to_string();
            assert!(e.contains(key), "{key}: {e}");
        }
    }

    #[test]
    fn abbreviate_is_one_bounded_line() {
        let s = "OK 1\r\n".repeat(40);
        let a = abbreviate(&s, 80);
        assert!(a.chars().count() <= 80, "{a}");
        assert!(!a.contains(['\r', '\n']));
        assert!(a.ends_with('…'));
        assert_eq!(abbreviate("ER 05\r", 80), "ER 05\\r");
    }
}
