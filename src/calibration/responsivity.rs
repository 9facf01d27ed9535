//! The camera's absolute responsivity from its own (lab) calibration, the
//! independent scale `optistim calibrate verify` measures the screen with:
//!
//! ```toml
//! responsivity_dn_per_s_per_w_m2_sr = 1.234e6   # DN/s per W m⁻² sr⁻¹
//! uncertainty_k2_percent = 1.0                   # expanded (k = 2)
//! ```
//!
//! R is DN/s per W m⁻² sr⁻¹ of camera-effective radiance (as defined in
//! [`mismatch`](super::mismatch)) arriving at the camera's entrance (after
//! the collimator), at the image centre, with the camera's own flat
//! normalised to 1 there. So a screen region seen by camera pixels with
//! flat g and etendue e relative to the centre has
//! L_screen = (DN/s) ÷ (g · e) ÷ (R · τ), τ the collimator's transmission.
//! Other keys (provenance) are ignored.

use std::path::Path;

use serde::Deserialize;

use crate::error::{Error, Result};

/// Key of the responsivity value in the file.
pub const KEY: &str = "responsivity_dn_per_s_per_w_m2_sr";

/// The camera's absolute responsivity and its expanded uncertainty.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
pub struct CameraResponsivity {
    /// DN/s per W m⁻² sr⁻¹ of camera-effective radiance at the entrance.
    pub responsivity_dn_per_s_per_w_m2_sr: f64,
    /// Expanded uncertainty (k = 2), %.
    pub uncertainty_k2_percent: f64,
}

impl CameraResponsivity {
    /// Reads and range-checks the file; errors name the file and the key.
    pub fn load(path: &Path) -> Result<CameraResponsivity> {
        let text = crate::infile::read_text_bounded(path, crate::infile::CONFIG_LIMIT)?;
        CameraResponsivity::parse(&text, path)
    }

    /// Parses the file's text; `path` names it in errors.
    pub fn parse(text: &str, path: &Path) -> Result<CameraResponsivity> {
        let r: CameraResponsivity = toml::from_str(text)
            .map_err(|e| Error::parse(path, crate::error::toml_message(text, &e)))?;
        let r_ok = r.responsivity_dn_per_s_per_w_m2_sr.is_finite()
            && r.responsivity_dn_per_s_per_w_m2_sr > 0.0;
        if !r_ok {
            return Err(Error::parse(
                path,
                format!(
                    "{KEY}: {} is not a positive number",
                    r.responsivity_dn_per_s_per_w_m2_sr
                ),
            ));
        }
        if !(r.uncertainty_k2_percent.is_finite()
            && (0.0..=100.0).contains(&r.uncertainty_k2_percent))
        {
            return Err(Error::parse(
                path,
                format!(
                    "uncertainty_k2_percent: {} is not in [0, 100]",
                    r.uncertainty_k2_percent
                ),
            ));
        }
        Ok(r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_the_two_keys_and_names_bad_ones() {
        let p = Path::new("r.toml");
        let r = CameraResponsivity::parse(
            "responsivity_dn_per_s_per_w_m2_sr = 2.5e6\nuncertainty_k2_percent = 1.5\ncamera = \"x\"\n",
            p,
        )
        .unwrap();
        assert_eq!(r.responsivity_dn_per_s_per_w_m2_sr, 2.5e6);
        assert_eq!(r.uncertainty_k2_percent, 1.5);
        for (text, key) in [
            (
                "responsivity_dn_per_s_per_w_m2_sr = -1.0\nuncertainty_k2_percent = 1.0",
                KEY,
            ),
            (
                "responsivity_dn_per_s_per_w_m2_sr = nan\nuncertainty_k2_percent = 1.0",
                KEY,
            ),
            (
                "responsivity_dn_per_s_per_w_m2_sr = 1.0\nuncertainty_k2_percent = 200.0",
                "uncertainty_k2_percent",
            ),
            ("uncertainty_k2_percent = 1.0", KEY),
        ] {
            let e = CameraResponsivity::parse(text, p).unwrap_err().to_string();
            assert!(e.contains("r.toml") && e.contains(key), "{text}: {e}");
        }
    }
}
