//! The facility camera's intrinsics in the OpenCV model (K and the
//! distortion k1, k2, p1, p2, k3): the forward projection of a direction
//! to a pixel, and its inverse by Newton iteration, which turns a measured
//! centroid into the camera-frame direction (tan_x, tan_y).
//!
//! Pixel coordinates are the project's continuous ones (pixel (0, 0)
//! top-left, centres at +0.5). OpenCV puts pixel centres at integers, so a
//! principal point from OpenCV is `cx + 0.5, cy + 0.5` here; the intrinsics
//! file reader says which convention its file uses.

use crate::error::{Error, Result};

/// Pinhole plus Brown–Conrady distortion, OpenCV's 5-coefficient model.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Intrinsics {
    /// Focal lengths, pixels.
    pub fx: f64,
    pub fy: f64,
    /// Principal point, continuous pixel coordinates (centres at +0.5).
    pub cx: f64,
    pub cy: f64,
    pub k1: f64,
    pub k2: f64,
    pub p1: f64,
    pub p2: f64,
    pub k3: f64,
}

impl Intrinsics {
    /// A distortion-free pinhole.
    pub fn pinhole(f: f64, cx: f64, cy: f64) -> Intrinsics {
        Intrinsics {
            fx: f,
            fy: f,
            cx,
            cy,
            k1: 0.0,
            k2: 0.0,
            p1: 0.0,
            p2: 0.0,
            k3: 0.0,
        }
    }

    /// Checks every value is finite and the focal lengths positive.
    pub fn validate(&self) -> Result<()> {
        let v = [
            ("fx", self.fx),
            ("fy", self.fy),
            ("cx", self.cx),
            ("cy", self.cy),
            ("k1", self.k1),
            ("k2", self.k2),
            ("p1", self.p1),
            ("p2", self.p2),
            ("k3", self.k3),
        ];
        for (name, x) in v {
            if !x.is_finite() {
                return Err(Error::invalid(format!("intrinsics.{name}"), "not finite"));
            }
        }
        if !(self.fx > 0.0 && self.fy > 0.0) {
            return Err(Error::invalid("intrinsics.fx", "focal lengths must be > 0"));
        }
        Ok(())
    }

    /// Distorted normalised coordinates of the ideal ones `(x, y)`, and the
    /// Jacobian ∂(xd, yd)/∂(x, y).
    fn distort(&self, x: f64, y: f64) -> ([f64; 2], [[f64; 2]; 2]) {
        let (k1, k2, k3, p1, p2) = (self.k1, self.k2, self.k3, self.p1, self.p2);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        // d(radial)/d(r2)
        let dr = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2);
        let xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
        let j = [
            [
                radial + 2.0 * x * x * dr + 2.0 * p1 * y + 6.0 * p2 * x,
                2.0 * x * y * dr + 2.0 * p1 * x + 2.0 * p2 * y,
            ],
            [
                2.0 * x * y * dr + 2.0 * p1 * x + 2.0 * p2 * y,
                radial + 2.0 * y * y * dr + 6.0 * p1 * y + 2.0 * p2 * x,
            ],
        ];
        ([xd, yd], j)
    }

    /// Pixel where the camera sees direction `(tan_x, tan_y)`.
    pub fn project(&self, t: [f64; 2]) -> [f64; 2] {
        let ([xd, yd], _) = self.distort(t[0], t[1]);
        [self.fx * xd + self.cx, self.fy * yd + self.cy]
    }

    /// Direction `(tan_x, tan_y)` seen at pixel `p`: the inverse of
    /// [`project`](Self::project), by Newton's method from the distorted
    /// coordinates. None when it does not converge (a pixel outside the
    /// domain where the distortion polynomial is one-to-one).
    pub fn direction(&self, p: [f64; 2]) -> Option<[f64; 2]> {
        let target = [(p[0] - self.cx) / self.fx, (p[1] - self.cy) / self.fy];
        let mut x = target;
        for _ in 0..50 {
            let (d, j) = self.distort(x[0], x[1]);
            let (ex, ey) = (d[0] - target[0], d[1] - target[1]);
            if ex.hypot(ey) < 1e-15 * (1.0 + x[0].hypot(x[1])) {
                return Some(x);
            }
            let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
            if !(det.abs() > 1e-12) {
                return None;
            }
            x[0] -= (j[1][1] * ex - j[0][1] * ey) / det;
            x[1] -= (-j[1][0] * ex + j[0][0] * ey) / det;
            if !(x[0].is_finite() && x[1].is_finite()) {
                return None;
            }
        }
        let (d, _) = self.distort(x[0], x[1]);
        let err = (d[0] - target[0]).hypot(d[1] - target[1]);
        (err < 1e-12).then_some(x)
    }
}

/// The intrinsics file: TOML with `fx, fy, cx, cy` (pixels) and the
/// OpenCV distortion `k1, k2, p1, p2, k3` (each 0 when absent);
/// `cx, cy` are in OpenCV's pixel convention (centres at integers), as
/// OpenCV's calibration writes them.
#[derive(Debug, Clone, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct IntrinsicsFile {
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    #[serde(default)]
    k1: f64,
    #[serde(default)]
    k2: f64,
    #[serde(default)]
    p1: f64,
    #[serde(default)]
    p2: f64,
    #[serde(default)]
    k3: f64,
}

impl Intrinsics {
    /// Reads and validates an intrinsics file (see [`IntrinsicsFile`]).
    pub fn load(path: &std::path::Path) -> Result<Intrinsics> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let f: IntrinsicsFile =
            toml::from_str(&text).map_err(|e| Error::parse(path, e.to_string()))?;
        let i = Intrinsics {
            fx: f.fx,
            fy: f.fy,
            cx: f.cx + 0.5,
            cy: f.cy + 0.5,
            k1: f.k1,
            k2: f.k2,
            p1: f.p1,
            p2: f.p2,
            k3: f.k3,
        };
        i.validate()
            .map_err(|e| Error::parse(path, e.to_string()))?;
        Ok(i)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> Intrinsics {
        Intrinsics {
            fx: 2100.0,
            fy: 2090.0,
            cx: 1024.3,
            cy: 767.8,
            k1: -0.21,
            k2: 0.09,
            p1: 6e-4,
            p2: -3e-4,
            k3: -0.01,
        }
    }

    #[test]
    fn direction_inverts_the_opencv_forward_model() {
        let c = camera();
        for j in 0..=12 {
            for i in 0..=16 {
                let p = [i as f64 * 128.0, j as f64 * 128.0];
                let t = c.direction(p).expect("converges");
                // The forward model written out here, OpenCV's formulas.
                let (x, y) = (t[0], t[1]);
                let r2 = x * x + y * y;
                let rad = 1.0 + c.k1 * r2 + c.k2 * r2 * r2 + c.k3 * r2 * r2 * r2;
                let xd = x * rad + 2.0 * c.p1 * x * y + c.p2 * (r2 + 2.0 * x * x);
                let yd = y * rad + c.p1 * (r2 + 2.0 * y * y) + 2.0 * c.p2 * x * y;
                let (u, v) = (c.fx * xd + c.cx, c.fy * yd + c.cy);
                assert!((u - p[0]).abs() < 1e-9 && (v - p[1]).abs() < 1e-9, "{p:?}");
            }
        }
    }

    #[test]
    fn pinhole_direction_is_linear() {
        let c = Intrinsics::pinhole(1000.0, 512.0, 384.0);
        let t = c.direction([612.0, 334.0]).unwrap();
        assert!((t[0] - 0.1).abs() < 1e-15 && (t[1] + 0.05).abs() < 1e-15);
    }

    #[test]
    fn validate_names_the_bad_value() {
        let mut c = camera();
        c.k2 = f64::NAN;
        assert!(c.validate().unwrap_err().to_string().contains("k2"));
        c.k2 = 0.0;
        c.fy = 0.0;
        assert!(c.validate().is_err());
    }
}
