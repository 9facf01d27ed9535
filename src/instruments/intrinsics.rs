//! The facility camera's intrinsics file (`calibrate.camera.intrinsics`):
//! the OpenCV pinhole model K with Brown–Conrady distortion
//! (k1, k2, p1, p2, k3), as `cv::calibrateCamera` reports it, and the map
//! between camera pixels and directions in the camera frame.
//!
//! TOML (or JSON with the same keys, by the `.json` extension):
//!
//! ```toml
//! width = 1024                       # pixels
//! height = 1024
//! camera_matrix = [[2400.0, 0.0, 511.5],
//!                  [0.0, 2400.0, 511.5],
//!                  [0.0, 0.0, 1.0]]  # pixels, OpenCV's pixel convention
//! distortion = [-0.12, 0.03, 1e-4, -2e-4, 0.0]   # k1, k2, p1, p2, k3
//! ```
//!
//! `cx`, `cy` are as OpenCV writes them: pixel centres at integer
//! coordinates. This crate puts pixel centres at +0.5 (docs/CONVENTIONS.md),
//! so [`CameraIntrinsics::pixel_to_direction`] and
//! [`CameraIntrinsics::direction_to_pixel`] add the half pixel: OpenCV's
//! (cx, cy) is this crate's (cx + 0.5, cy + 0.5).

use std::path::Path;

use glam::DVec3;
use serde::Deserialize;

use crate::error::{toml_message, Error, Result};

/// Largest |coefficient| accepted in `distortion`.
pub const MAX_DISTORTION: f64 = 1e3;

/// The file as written: arrays of any length, checked in
/// [`CameraIntrinsics::from_file`] (a fixed-size array would silently drop
/// an eight-coefficient rational model's k4 … k6).
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct IntrinsicsFile {
    width: usize,
    height: usize,
    camera_matrix: Vec<Vec<f64>>,
    distortion: Vec<f64>,
}

/// The file's content.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraIntrinsics {
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// K, OpenCV convention (pixel centres at integers).
    pub camera_matrix: [[f64; 3]; 3],
    /// k1, k2, p1, p2, k3.
    pub distortion: [f64; 5],
}

impl CameraIntrinsics {
    /// Reads and validates a TOML (or `.json`) intrinsics file; errors name
    /// the file and the key.
    pub fn load(path: &Path) -> Result<CameraIntrinsics> {
        let text = crate::infile::read_text_bounded(path, crate::infile::CONFIG_LIMIT)?;
        let json = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("json"));
        Self::parse(&text, json, path)
    }

    /// Parses and validates; `path` names the file in errors.
    pub fn parse(text: &str, json: bool, path: &Path) -> Result<CameraIntrinsics> {
        if text.len() > 1 << 16 {
            return Err(Error::parse(
                path,
                "larger than 64 KiB: not an intrinsics file",
            ));
        }
        let f: IntrinsicsFile = if json {
            serde_json::from_str(text).map_err(|e| Error::parse(path, e.to_string()))?
        } else {
            toml::from_str(text).map_err(|e| Error::parse(path, toml_message(text, &e)))?
        };
        let k = Self::from_file(f).map_err(|e| Error::parse(path, e.to_string()))?;
        k.validate()
            .map_err(|e| Error::parse(path, e.to_string()))?;
        Ok(k)
    }

    fn from_file(f: IntrinsicsFile) -> Result<CameraIntrinsics> {
        let rows: Vec<[f64; 3]> = f
            .camera_matrix
            .iter()
            .filter_map(|r| r.as_slice().try_into().ok())
            .collect();
        let camera_matrix: [[f64; 3]; 3] = rows
            .try_into()
            .ok()
            .filter(|_| f.camera_matrix.len() == 3)
            .ok_or_else(|| Error::invalid("camera_matrix", "must be 3 rows of 3 numbers"))?;
        let distortion: [f64; 5] = f.distortion.as_slice().try_into().map_err(|_| {
            Error::invalid(
                "distortion",
                format!(
                    "must be the 5 coefficients k1, k2, p1, p2, k3, found {} (the rational and thin-prism models are not supported)",
                    f.distortion.len()
                ),
            )
        })?;
        Ok(CameraIntrinsics {
            width: f.width,
            height: f.height,
            camera_matrix,
            distortion,
        })
    }

    /// Checks sizes, K's form and finite coefficients.
    pub fn validate(&self) -> Result<()> {
        for (key, n) in [("width", self.width), ("height", self.height)] {
            if !(1..=65_536).contains(&n) {
                return Err(Error::invalid(
                    key,
                    format!("must be in 1..=65536, found {n}"),
                ));
            }
        }
        let m = &self.camera_matrix;
        if !m.iter().flatten().all(|v| v.is_finite()) {
            return Err(Error::invalid("camera_matrix", "must be finite"));
        }
        if m[0][1] != 0.0 || m[1][0] != 0.0 || m[2] != [0.0, 0.0, 1.0] {
            return Err(Error::invalid(
                "camera_matrix",
                "must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew)",
            ));
        }
        if !(m[0][0] > 0.0 && m[1][1] > 0.0) {
            return Err(Error::invalid("camera_matrix", "fx and fy must be > 0"));
        }
        let (w, h) = (self.width as f64, self.height as f64);
        if !((-w..=2.0 * w).contains(&m[0][2]) && (-h..=2.0 * h).contains(&m[1][2])) {
            return Err(Error::invalid(
                "camera_matrix",
                "the principal point (cx, cy) lies far outside the image",
            ));
        }
        if !self
            .distortion
            .iter()
            .all(|d| d.is_finite() && d.abs() <= MAX_DISTORTION)
        {
            return Err(Error::invalid(
                "distortion",
                format!("k1, k2, p1, p2, k3 must be finite, |value| ≤ {MAX_DISTORTION}"),
            ));
        }
        Ok(())
    }

    /// Distorts normalised image coordinates (x, y) = (X/Z, Y/Z).
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let [k1, k2, p1, p2, k3] = self.distortion;
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        (
            x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
        )
    }

    /// The pixel (this crate's convention, centres at +0.5) where the camera
    /// sees direction `d` (camera frame, z along the boresight); `None`
    /// behind the camera.
    pub fn direction_to_pixel(&self, d: DVec3) -> Option<(f64, f64)> {
        if !(d.z > 0.0) {
            return None;
        }
        let (xd, yd) = self.distort(d.x / d.z, d.y / d.z);
        let m = &self.camera_matrix;
        Some((m[0][0] * xd + m[0][2] + 0.5, m[1][1] * yd + m[1][2] + 0.5))
    }

    /// The unit direction (camera frame) seen at pixel (u, v) (centres at
    /// +0.5), inverting the distortion by Newton iteration; `None` where it
    /// does not converge to 1e-12 (far outside the calibrated field).
    pub fn pixel_to_direction(&self, u: f64, v: f64) -> Option<DVec3> {
        let m = &self.camera_matrix;
        let xd = (u - 0.5 - m[0][2]) / m[0][0];
        let yd = (v - 0.5 - m[1][2]) / m[1][1];
        let (mut x, mut y) = (xd, yd);
        for _ in 0..50 {
            let (fx, fy) = self.distort(x, y);
            let (ex, ey) = (fx - xd, fy - yd);
            if ex.abs().max(ey.abs()) < 1e-12 {
                return Some(DVec3::new(x, y, 1.0).normalize());
            }
            // Jacobian by central differences: the model is smooth.
            let h = 1e-7;
            let (ax, ay) = self.distort(x + h, y);
            let (bx, by) = self.distort(x - h, y);
            let (cx, cy) = self.distort(x, y + h);
            let (dx, dy) = self.distort(x, y - h);
            let (j11, j21) = ((ax - bx) / (2.0 * h), (ay - by) / (2.0 * h));
            let (j12, j22) = ((cx - dx) / (2.0 * h), (cy - dy) / (2.0 * h));
            let det = j11 * j22 - j12 * j21;
            if !(det.abs() > 1e-12) {
                return None;
            }
            x -= (j22 * ex - j12 * ey) / det;
            y -= (-j21 * ex + j11 * ey) / det;
            if !(x.is_finite() && y.is_finite()) {
                return None;
            }
        }
        None
    }
}
