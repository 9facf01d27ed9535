//! The `[calibrate]` section of the facility TOML file: what
//! `optistim calibrate` measures and how (levels, repeats, settle, the
//! camera region and exposure range, the absolute scale, verify thresholds,
//! output paths), with the instruments of
//! [`instruments::config`](crate::instruments::config).
//!
//! ```toml
//! [calibrate]
//! levels = 33                 # drive levels measured (≥ 2), packed toward black
//! spacing_power = 2.0         # level_i = top·(i/(n−1))^p, then made strictly increasing
//! repeats = 2                 # measurements per level (≥ 1), in seeded random order
//! seed = 1
//! settle = 0.5                # s between showing a patch and measuring it
//! reference_level = 255       # re-measured at start and end (drift, warm-up); default the top
//! region = [0.4, 0.4, 0.2, 0.2]  # camera region (x, y, w, h as fractions of the frame)
//! target_fill = 0.6           # auto-ranging: aim the region's brightest pixels at this fraction of saturation
//! max_exposure = 1.0          # s, longest exposure auto-ranging may use
//! ambient = "none"            # "none" | "prompt": screen off, operator asked to press Enter
//! # mismatch_factor = 1.0     # F of docs/CALIBRATION.md when not computed from spectra
//! # screen_spectrum = "screen_white.csv"  # wavelength_nm,value (relative) for F
//! # screen_spectrum_uncertainty_nm = 1.0  # its wavelength-scale uncertainty (budget)
//! # spectrum_levels = [64, 96, 128, 159, 191, 223, 255]  # spectra for F per level (default with a spectroradiometer)
//! # camera_responsivity = 1e-5 # W m⁻² sr⁻¹ per (DN/s) in the region: the scale without a meter
//! out_dir = "calib"           # where the LUT, flat field, reports and checkpoints go
//!
//! [calibrate.flat]
//! levels = [128, 255]         # uniform levels imaged
//! # camera_flat = "camera_flat.tif"  # the camera's own flat (vignetting × PRNU)
//! degree = 4                  # 2-D polynomial degree of the smooth fit
//!
//! [calibrate.verify]
//! patches = 9                 # target radiances across the range
//! # max_error_percent = 2.0   # override of the threshold from the uncertainty budget
//! drift_levels = [64, 128, 255]
//! drift_warn_percent = 1.0
//!
//! [calibrate.geometric]       # see docs/GEOMETRIC.md
//! [calibrate.meter]           # see docs/INSTRUMENTS.md
//! [calibrate.spectroradiometer]  # optional: the screen's spectrum per level (same keys as the meter)
//! [calibrate.camera]
//! ```
//!
//! Every key is range-checked; errors name `calibrate.<key>`.

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::error::{toml_message, Error, Result};
use crate::instruments::config::{CameraConfig, SpotMeterConfig};
use crate::radiometry::spectrum::Table;

/// Largest number of levels (a 10-bit display has 1024).
pub const MAX_LEVELS: usize = 1024;
/// Largest number of repeats.
pub const MAX_REPEATS: usize = 100;

/// How the ambient (screen off) is measured.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum AmbientMode {
    /// Not measured: the camera's dark frame is all that is subtracted and
    /// the ambient is reported as not measured (a dark facility).
    #[default]
    None,
    /// The operator switches the screen off (or covers it) when asked; the
    /// camera and meter then measure the ambient, which is subtracted.
    Prompt,
}

/// `[calibrate]`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrateConfig {
    #[serde(default = "default_levels")]
    pub levels: usize,
    #[serde(default = "default_spacing_power")]
    pub spacing_power: f64,
    #[serde(default = "default_repeats")]
    pub repeats: usize,
    #[serde(default = "default_seed")]
    pub seed: u64,
    #[serde(default = "default_settle")]
    pub settle: f64,
    #[serde(default)]
    pub reference_level: Option<u32>,
    #[serde(default = "default_region")]
    pub region: [f64; 4],
    #[serde(default = "default_fill")]
    pub target_fill: f64,
    #[serde(default = "default_max_exposure")]
    pub max_exposure: f64,
    #[serde(default)]
    pub ambient: AmbientMode,
    #[serde(default)]
    pub mismatch_factor: Option<f64>,
    #[serde(default)]
    pub screen_spectrum: Option<PathBuf>,
    /// Drive levels at which the screen's spectrum is measured, for F per
    /// level (any order; repeats are merged). Default with a
    /// spectroradiometer: [`default_spectrum_levels`].
    /// (Signed, so a negative level gets this key's range error.)
    #[serde(default)]
    pub spectrum_levels: Option<Vec<i64>>,
    /// Declared uncertainty of the collimator's focal length, %: the
    /// geometric routine flags a larger disagreement with the focal
    /// length its fit implies.
    #[serde(default)]
    pub collimator_focal_length_uncertainty_percent: Option<f64>,
    /// Declared uncertainty of the screen spectrum's wavelength scale, nm
    /// (the budget evaluates F with the spectrum shifted by it).
    #[serde(default)]
    pub screen_spectrum_uncertainty_nm: Option<f64>,
    #[serde(default)]
    pub camera_responsivity: Option<f64>,
    #[serde(default = "default_out_dir")]
    pub out_dir: PathBuf,
    #[serde(default)]
    pub flat: FlatConfig,
    #[serde(default)]
    pub verify: VerifyConfig,
    #[serde(default)]
    pub meter: Option<SpotMeterConfig>,
    /// `[calibrate.spectroradiometer]`: measures the screen's spectrum at
    /// `spectrum_levels` (the meter's keys).
    #[serde(default)]
    pub spectroradiometer: Option<SpotMeterConfig>,
    pub camera: CameraConfig,
    /// `[calibrate.geometric]`, read by
    /// [`geometric::GeometricConfig`](super::geometric::GeometricConfig).
    #[serde(default)]
    pub geometric: Option<toml::Value>,
}

/// `[calibrate.flat]`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FlatConfig {
    #[serde(default = "default_flat_levels")]
    pub levels: Vec<u32>,
    #[serde(default)]
    pub camera_flat: Option<PathBuf>,
    #[serde(default = "default_degree")]
    pub degree: usize,
    /// Side [screen px] of the cells in which the residual about the
    /// polynomial is kept (mura, finer than any low-order fit); 0: the
    /// polynomial alone.
    #[serde(default = "default_residual_cell_px")]
    pub residual_cell_px: usize,
}

fn default_residual_cell_px() -> usize {
    8
}

impl Default for FlatConfig {
    fn default() -> Self {
        FlatConfig {
            levels: default_flat_levels(),
            camera_flat: None,
            degree: default_degree(),
            residual_cell_px: default_residual_cell_px(),
        }
    }
}

/// `[calibrate.verify]`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VerifyConfig {
    #[serde(default = "default_patches")]
    pub patches: usize,
    /// Override of the pass/fail threshold (default: the uncertainty
    /// budget combined with the camera responsivity's).
    #[serde(default)]
    pub max_error_percent: Option<f64>,
    #[serde(default = "default_drift_levels")]
    pub drift_levels: Vec<u32>,
    #[serde(default = "default_drift_warn")]
    pub drift_warn_percent: f64,
    /// Verify's own dark source (default: the campaign's
    /// `calibrate.camera.dark`). With the campaign's `"none"` verify needs
    /// one: a verify without darks shares that omission and cannot see it.
    #[serde(default)]
    pub dark: Option<crate::instruments::config::DarkSource>,
}

impl Default for VerifyConfig {
    fn default() -> Self {
        VerifyConfig {
            patches: default_patches(),
            max_error_percent: None,
            drift_levels: default_drift_levels(),
            drift_warn_percent: default_drift_warn(),
            dark: None,
        }
    }
}

fn default_levels() -> usize {
    33
}
fn default_spacing_power() -> f64 {
    2.0
}
fn default_repeats() -> usize {
    2
}
fn default_seed() -> u64 {
    1
}
fn default_settle() -> f64 {
    0.5
}
fn default_region() -> [f64; 4] {
    [0.4, 0.4, 0.2, 0.2]
}
fn default_fill() -> f64 {
    0.6
}
fn default_max_exposure() -> f64 {
    1.0
}
fn default_out_dir() -> PathBuf {
    PathBuf::from("calib")
}
fn default_flat_levels() -> Vec<u32> {
    vec![128, 255]
}
fn default_degree() -> usize {
    4
}
fn default_patches() -> usize {
    9
}
fn default_drift_levels() -> Vec<u32> {
    vec![64, 128, 255]
}
fn default_drift_warn() -> f64 {
    1.0
}

fn key(k: &str) -> String {
    format!("calibrate.{k}")
}

fn in_range(k: &str, v: f64, lo: f64, hi: f64) -> Result<()> {
    if v.is_finite() && v >= lo && v <= hi {
        Ok(())
    } else {
        Err(Error::invalid(
            key(k),
            format!("must be in [{lo}, {hi}], found {v}"),
        ))
    }
}

fn count(k: &str, v: usize, lo: usize, hi: usize) -> Result<()> {
    if (lo..=hi).contains(&v) {
        Ok(())
    } else {
        Err(Error::invalid(
            key(k),
            format!("must be in {lo}..={hi}, found {v}"),
        ))
    }
}

fn levels_in_range(k: &str, levels: &[u32], top: u32) -> Result<()> {
    if levels.is_empty() || levels.len() > MAX_LEVELS {
        return Err(Error::invalid(
            key(k),
            format!("needs 1..={MAX_LEVELS} levels"),
        ));
    }
    if let Some(l) = levels.iter().find(|&&l| l > top) {
        return Err(Error::invalid(
            key(k),
            format!("level {l} above the display's top level {top}"),
        ));
    }
    Ok(())
}

impl CalibrateConfig {
    /// Reads the `[calibrate]` table of a facility file (relative paths
    /// resolved against the file's directory) and validates it for a
    /// display of `bits` bits.
    pub fn load(path: impl AsRef<Path>, bits: u32) -> Result<CalibrateConfig> {
        let path = path.as_ref();
        let text = crate::infile::read_text_bounded(path, crate::infile::CONFIG_LIMIT)?;
        let mut cfg = CalibrateConfig::parse(&text, path, bits)?;
        cfg.resolve_paths(path.parent().unwrap_or(Path::new("")));
        Ok(cfg)
    }

    /// The meter's spectral response, read from the file
    /// `[calibrate.meter] spectral_response` names (None without one).
    pub fn meter_response(&self) -> Result<Option<Table>> {
        let path = self
            .meter
            .as_ref()
            .and_then(|m| m.spectral_response.as_ref());
        path.map(|p| Table::from_csv(p)).transpose()
    }

    /// Parses the `[calibrate]` table out of the whole facility file text.
    pub fn parse(text: &str, path: impl AsRef<Path>, bits: u32) -> Result<CalibrateConfig> {
        let path = path.as_ref();
        let table = calibrate_table(text, path)?;
        let cfg: CalibrateConfig = table.try_into().map_err(|e: toml::de::Error| {
            Error::parse(path, format!("[calibrate]: {}", toml_message(text, &e)))
        })?;
        cfg.validate(bits)
            .map_err(|e| Error::parse(path, e.to_string()))?;
        Ok(cfg)
    }

    /// Makes relative paths relative to `dir`.
    pub fn resolve_paths(&mut self, dir: &Path) {
        let fix = |p: &mut PathBuf| {
            if p.is_relative() {
                *p = dir.join(&*p);
            }
        };
        fix(&mut self.out_dir);
        if let Some(p) = &mut self.screen_spectrum {
            fix(p);
        }
        if let Some(p) = &mut self.flat.camera_flat {
            fix(p);
        }
        if let Some(crate::instruments::config::DarkSource::File(p)) = &mut self.verify.dark {
            fix(p);
        }
        if let Some(m) = &mut self.meter {
            m.resolve_paths(dir);
        }
        if let Some(m) = &mut self.spectroradiometer {
            m.resolve_paths(dir);
        }
        self.camera.resolve_paths(dir);
    }

    /// Checks every value's domain for a display of `bits` bits; errors
    /// name `calibrate.<key>`.
    pub fn validate(&self, bits: u32) -> Result<()> {
        let top = top_level(bits)?;
        count("levels", self.levels, 2, (top as usize + 1).min(MAX_LEVELS))?;
        in_range("spacing_power", self.spacing_power, 1.0, 4.0)?;
        count("repeats", self.repeats, 1, MAX_REPEATS)?;
        in_range("settle", self.settle, 0.0, 600.0)?;
        if let Some(r) = self.reference_level {
            if r > top {
                return Err(Error::invalid(
                    key("reference_level"),
                    format!("must be in 1..={top}, found {r}"),
                ));
            }
        }
        let [x, y, w, h] = self.region;
        for (name, v) in [("x", x), ("y", y), ("w", w), ("h", h)] {
            if !(v.is_finite() && (0.0..=1.0).contains(&v)) {
                return Err(Error::invalid(
                    key("region"),
                    format!("{name} must be a fraction in [0, 1], found {v}"),
                ));
            }
        }
        if !(w > 0.0 && h > 0.0 && x + w <= 1.0 && y + h <= 1.0) {
            return Err(Error::invalid(
                key("region"),
                "[x, y, w, h] must have w, h > 0 and lie inside the frame",
            ));
        }
        in_range("target_fill", self.target_fill, 0.05, 0.95)?;
        in_range("max_exposure", self.max_exposure, 1e-6, 3600.0)?;
        if let Some(f) = self.mismatch_factor {
            in_range("mismatch_factor", f, 1e-6, 1e6)?;
        }
        if let Some(r) = self.camera_responsivity {
            in_range("camera_responsivity", r, 1e-30, 1e30)?;
        }
        levels_in_range("flat.levels", &self.flat.levels, top)?;
        count("flat.degree", self.flat.degree, 0, 8)?;
        count("flat.residual_cell_px", self.flat.residual_cell_px, 0, 256)?;
        count("verify.patches", self.verify.patches, 2, 256)?;
        if let Some(m) = self.verify.max_error_percent {
            in_range("verify.max_error_percent", m, 0.0, 100.0)?;
        }
        if let Some(u) = self.collimator_focal_length_uncertainty_percent {
            in_range("collimator_focal_length_uncertainty_percent", u, 0.0, 100.0)?;
        }
        if let Some(u) = self.screen_spectrum_uncertainty_nm {
            in_range("screen_spectrum_uncertainty_nm", u, 0.0, 50.0)?;
        }
        levels_in_range("verify.drift_levels", &self.verify.drift_levels, top)?;
        in_range(
            "verify.drift_warn_percent",
            self.verify.drift_warn_percent,
            0.0,
            100.0,
        )?;
        if let Some(m) = &self.meter {
            m.validate()?;
        }
        if let Some(m) = &self.spectroradiometer {
            m.validate_as(SPECTRORADIOMETER_KEY)?;
        }
        self.validate_spectra(top)?;
        self.camera.validate()?;
        if self.camera.dark.is_none() {
            return Err(Error::invalid(
                "calibrate.camera.dark",
                "missing: a campaign needs dark frames; say \"shutter\", \"capture\", a dark model file, or \"none\" explicitly",
            ));
        }
        if self.camera.exposure > self.max_exposure {
            return Err(Error::invalid(
                key("max_exposure"),
                format!(
                    "{} s is shorter than calibrate.camera.exposure {} s",
                    self.max_exposure, self.camera.exposure
                ),
            ));
        }
        Ok(())
    }

    /// `spectrum_levels` within the display's range with at least two
    /// distinct levels, and one source of the screen's spectral shape.
    fn validate_spectra(&self, top: u32) -> Result<()> {
        if let Some(levels) = &self.spectrum_levels {
            if let Some(l) = levels.iter().find(|&&l| !(0..=top as i64).contains(&l)) {
                return Err(Error::invalid(
                    key("spectrum_levels"),
                    format!("level {l} outside the display's levels 0..={top}"),
                ));
            }
            levels_in_range("spectrum_levels", &self.spectrum_level_set(), top)?;
            let mut distinct = levels.clone();
            distinct.sort_unstable();
            distinct.dedup();
            if distinct.len() < 2 {
                return Err(Error::invalid(
                    key("spectrum_levels"),
                    format!("needs at least two distinct levels, found {levels:?}"),
                ));
            }
        }
        let measured = self.spectrum_levels.is_some() || self.spectroradiometer.is_some();
        if measured && self.screen_spectrum.is_some() {
            return Err(Error::invalid(
                key("screen_spectrum"),
                "given with measured spectra (spectrum_levels or [calibrate.spectroradiometer]): \
                 keep one source of the screen's spectrum",
            ));
        }
        if measured && self.mismatch_factor.is_some() {
            return Err(Error::invalid(
                key("mismatch_factor"),
                "given with measured spectra (spectrum_levels or [calibrate.spectroradiometer]): \
                 F comes from the spectra; remove one",
            ));
        }
        Ok(())
    }

    /// The levels whose spectra give F per level, sorted and distinct:
    /// `spectrum_levels`, else [`default_spectrum_levels`] with a
    /// spectroradiometer, else none (F from `screen_spectrum`).
    pub fn spectrum_levels(&self, bits: u32) -> Option<Vec<u32>> {
        match (&self.spectrum_levels, &self.spectroradiometer) {
            (Some(_), _) => Some(self.spectrum_level_set()),
            (None, Some(_)) => Some(default_spectrum_levels(top_level(bits).unwrap_or(255))),
            (None, None) => None,
        }
    }

    /// `spectrum_levels` sorted and distinct (negative ones dropped:
    /// [`validate`](Self::validate) refuses them).
    fn spectrum_level_set(&self) -> Vec<u32> {
        let mut l: Vec<u32> = self
            .spectrum_levels
            .iter()
            .flatten()
            .filter_map(|&l| u32::try_from(l).ok())
            .collect();
        l.sort_unstable();
        l.dedup();
        l
    }

    /// The reference level (default: the top level).
    pub fn reference(&self, bits: u32) -> u32 {
        self.reference_level
            .unwrap_or_else(|| top_level(bits).unwrap_or(255))
    }
}

/// Key of the spectroradiometer's table.
pub const SPECTRORADIOMETER_KEY: &str = "calibrate.spectroradiometer";

/// Default levels of the spectra: round(top · j/8), j = 2 … 8 (64 … 255 on
/// 8 bits), spanning the levels above 10 % of the top's signal that set
/// the absolute scale (≥ ~90 for a gamma-2.2 screen) with room below.
pub fn default_spectrum_levels(top: u32) -> Vec<u32> {
    (2..=8)
        .map(|j| (top as f64 * j as f64 / 8.0).round() as u32)
        .collect()
}

/// Top drive level of a `bits`-bit display.
pub fn top_level(bits: u32) -> Result<u32> {
    match bits {
        8 => Ok(255),
        10 => Ok(1023),
        _ => Err(Error::invalid(
            "drive.bits",
            format!("must be 8 or 10, found {bits}"),
        )),
    }
}

/// The `[calibrate]` table of a facility file's text.
pub fn calibrate_table(text: &str, path: &Path) -> Result<toml::Value> {
    let doc: toml::Value =
        toml::from_str(text).map_err(|e| Error::parse(path, toml_message(text, &e)))?;
    doc.get("calibrate").cloned().ok_or_else(|| {
        Error::parse(
            path,
            "no [calibrate] section: add one (docs/CALIBRATION.md)",
        )
    })
}

/// The measured levels: `n` levels from 0 to `top` packed toward black,
/// `round(top·(i/(n−1))^p)`, each then raised to at least one above the
/// previous one (so dark levels stay distinct; the top stays `top` because
/// `n ≤ top + 1`).
pub fn level_ladder(n: usize, top: u32, power: f64) -> Vec<u32> {
    let mut out: Vec<u32> = Vec::with_capacity(n);
    for i in 0..n {
        let t = i as f64 / (n - 1) as f64;
        let mut l = (top as f64 * t.powf(power)).round() as u32;
        if let Some(&p) = out.last() {
            l = l.max(p + 1);
        }
        out.push(l);
    }
    // Going up from the bottom can push the end past the top: pull the
    // tail back down, keeping the levels distinct.
    let mut cap = top;
    for l in out.iter_mut().rev() {
        *l = (*l).min(cap);
        cap = l.saturating_sub(1);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    const CAMERA: &str =
        "[calibrate.camera]\nkind = \"sim\"\nexposure = 0.002\nsaturation_dn = 4095\ndark = \"shutter\"\n";

    #[test]
    fn ladder_is_strictly_increasing_from_black_to_top_and_packed_toward_black() {
        for (n, top) in [(2, 255), (33, 255), (65, 255), (256, 255), (17, 1023)] {
            let l = level_ladder(n, top, 2.0);
            assert_eq!(l.len(), n);
            assert_eq!(l[0], 0);
            assert_eq!(*l.last().unwrap(), top);
            assert!(l.windows(2).all(|w| w[1] > w[0]), "{l:?}");
        }
        let l = level_ladder(33, 255, 2.0);
        // Half of the levels lie below a quarter of the range (t² < 1/4).
        assert!(l[16] <= 64, "{l:?}");
    }

    #[test]
    fn bad_keys_are_named() {
        let cases = [
            ("levels = 1", "calibrate.levels"),
            ("repeats = 0", "calibrate.repeats"),
            ("settle = -1.0", "calibrate.settle"),
            ("reference_level = 300", "calibrate.reference_level"),
            ("region = [0.9, 0.4, 0.2, 0.2]", "calibrate.region"),
            ("target_fill = 1.5", "calibrate.target_fill"),
            ("max_exposure = 0.0", "calibrate.max_exposure"),
            ("mismatch_factor = nan", "calibrate.mismatch_factor"),
            ("spacing_power = 9.0", "calibrate.spacing_power"),
        ];
        for (line, name) in cases {
            let text = format!("[calibrate]\n{line}\n{CAMERA}");
            let e = CalibrateConfig::parse(&text, "f.toml", 8)
                .unwrap_err()
                .to_string();
            assert!(e.contains(name), "{line}: {e}");
            assert!(e.contains("f.toml"), "{e}");
        }
        let text = format!("[calibrate]\n[calibrate.verify]\ndrift_levels = [999]\n{CAMERA}");
        let e = CalibrateConfig::parse(&text, "f.toml", 8)
            .unwrap_err()
            .to_string();
        assert!(e.contains("calibrate.verify.drift_levels"), "{e}");
        let text = format!("[calibrate]\nbogus = 1\n{CAMERA}");
        let e = CalibrateConfig::parse(&text, "f.toml", 8)
            .unwrap_err()
            .to_string();
        assert!(e.contains("bogus"), "{e}");
        // A campaign without a dark model is refused in one line.
        let text = format!(
            "[calibrate]\n{}",
            CAMERA.replace("dark = \"shutter\"\n", "")
        );
        let e = CalibrateConfig::parse(&text, "f.toml", 8)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("calibrate.camera.dark") && !e.contains('\n'),
            "{e}"
        );
        let e = CalibrateConfig::parse("[screen]\n", "f.toml", 8)
            .unwrap_err()
            .to_string();
        assert!(e.contains("[calibrate]"), "{e}");
    }

    #[test]
    fn defaults() {
        let c = CalibrateConfig::parse(&format!("[calibrate]\n{CAMERA}"), "f.toml", 8).unwrap();
        assert_eq!((c.levels, c.repeats), (33, 2));
        assert_eq!(c.reference(8), 255);
        assert_eq!(c.reference(10), 1023);
    }

    #[test]
    fn spectrum_levels_are_checked_sorted_and_defaulted() {
        let parse = |extra: &str| {
            CalibrateConfig::parse(&format!("[calibrate]\n{extra}\n{CAMERA}"), "f.toml", 8)
        };
        let cases = [
            (
                "spectrum_levels = [300, 255]",
                "calibrate.spectrum_levels",
                "outside",
            ),
            (
                "spectrum_levels = [128, 128]",
                "calibrate.spectrum_levels",
                "two distinct",
            ),
            (
                "spectrum_levels = []",
                "calibrate.spectrum_levels",
                "levels",
            ),
            (
                "spectrum_levels = [-1, 5]",
                "calibrate.spectrum_levels",
                "outside",
            ),
            (
                "spectrum_levels = [64, 255]\nscreen_spectrum = \"w.csv\"",
                "calibrate.screen_spectrum",
                "one source",
            ),
            (
                "mismatch_factor = 0.8\n[calibrate.spectroradiometer]\nkind = \"sim\"",
                "calibrate.mismatch_factor",
                "",
            ),
            (
                "[calibrate.spectroradiometer]\nkind = \"serial\"",
                "calibrate.spectroradiometer.port",
                "",
            ),
        ];
        for (extra, name, what) in cases {
            let e = parse(extra).unwrap_err().to_string();
            assert!(e.contains(name) && e.contains(what), "{extra}: {e}");
            assert!(e.contains("f.toml") && !e.contains('\n'), "{e}");
        }
        let c = parse("spectrum_levels = [255, 64, 128, 64]").unwrap();
        assert_eq!(c.spectrum_levels(8), Some(vec![64, 128, 255]));
        assert_eq!(parse("").unwrap().spectrum_levels(8), None);
        let c = parse("[calibrate.spectroradiometer]\nkind = \"sim\"").unwrap();
        // round(255 j / 8), j = 2 … 8.
        assert_eq!(
            c.spectrum_levels(8),
            Some(vec![64, 96, 128, 159, 191, 223, 255])
        );
        assert_eq!(default_spectrum_levels(1023)[0], 256);
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(64))]
        /// Any list of levels is accepted exactly when every level is at
        /// most the top and at least two differ; then it is used sorted and
        /// without repeats.
        #[test]
        fn spectrum_levels_are_accepted_exactly_when_valid(
            levels in proptest::collection::vec(0u32..400, 0..8)
        ) {
            let list: Vec<String> = levels.iter().map(|l| l.to_string()).collect();
            let text = format!("[calibrate]\nspectrum_levels = [{}]\n{CAMERA}", list.join(", "));
            let mut set = levels.clone();
            set.sort_unstable();
            set.dedup();
            let valid = set.len() >= 2 && set.iter().all(|&l| l <= 255);
            match CalibrateConfig::parse(&text, "f.toml", 8) {
                Ok(c) => {
                    proptest::prop_assert!(valid, "{levels:?} accepted");
                    proptest::prop_assert_eq!(c.spectrum_levels(8), Some(set));
                }
                Err(e) => {
                    proptest::prop_assert!(!valid, "{levels:?}: {e}");
                    proptest::prop_assert!(e.to_string().contains("calibrate.spectrum_levels"));
                }
            }
        }

        /// Arbitrary text in the table is Ok or a named error, never a panic.
        #[test]
        fn parser_never_panics(body in "[a-z_ =0-9.\\[\\],\"\n-]{0,120}") {
            let text = format!("[calibrate]\n{body}\n{CAMERA}");
            let _ = CalibrateConfig::parse(&text, "f.toml", 8);
        }
    }
}
