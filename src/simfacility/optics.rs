//! Geometry of the simulated facility: the camera's OpenCV model (K and
//! k1, k2, p1, p2) and the collimator (focal length, radial distortion,
//! misalignment), between a camera pixel and a screen position.
//!
//! Screen → camera (the truth a geometry file approximates): screen pixel
//! (u, v) → offset from the collimator axis s = ((u, v) − (w/2, h/2) −
//! offset_px) · pitch → (a, b) = s / f_coll, r² = a² + b² → in the
//! screen's axes
//!
//! a' = a (1 + k1 r² + k2 r⁴) + 2 p1 a b + p2 (r² + 2 a²) + s1 r² + s2 r⁴
//! b' = b (1 + k1 r² + k2 r⁴) + p1 (r² + 2 b²) + 2 p2 a b + s3 r² + s4 r⁴
//!
//! (radial, Brown decentring and thin prism) → turned by `rotation` into
//! the camera frame: the camera sees the point at (tan_x, tan_y) = x/z,
//! y/z. Camera pixel → screen inverts each step (the OpenCV distortion by
//! fixed-point iteration, the collimator's by Newton's method).

use super::config::{CameraTruth, CollimatorTruth, ScreenTruth};

/// Fixed-point iterations to invert the OpenCV distortion.
const UNDISTORT_ITERATIONS: usize = 50;

/// The camera's intrinsics and distortion.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraOptics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub k1: f64,
    pub k2: f64,
    pub p1: f64,
    pub p2: f64,
}

impl CameraOptics {
    /// From the camera's configuration.
    pub fn from_config(c: &CameraTruth) -> CameraOptics {
        CameraOptics {
            fx: c.fx,
            fy: c.fy,
            cx: c.cx,
            cy: c.cy,
            k1: c.k1,
            k2: c.k2,
            p1: c.p1,
            p2: c.p2,
        }
    }

    /// OpenCV distortion of ideal normalised coordinates.
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let r2 = x * x + y * y;
        let radial = 1.0 + self.k1 * r2 + self.k2 * r2 * r2;
        (
            x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x),
            y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y,
        )
    }

    /// Ideal normalised coordinates (tan_x, tan_y) of continuous pixel
    /// position (u, v): the distortion inverted by fixed-point iteration.
    pub fn undistort_pixel(&self, u: f64, v: f64) -> (f64, f64) {
        let xd = (u - self.cx) / self.fx;
        let yd = (v - self.cy) / self.fy;
        let (mut x, mut y) = (xd, yd);
        for _ in 0..UNDISTORT_ITERATIONS {
            let (dx, dy) = self.distort(x, y);
            let (nx, ny) = (x + (xd - dx), y + (yd - dy));
            let step = (nx - x).abs() + (ny - y).abs();
            (x, y) = (nx, ny);
            if step < 1e-15 {
                break;
            }
        }
        (x, y)
    }

    /// Continuous pixel position of a camera-frame direction (x/z, y/z).
    pub fn project(&self, tan_x: f64, tan_y: f64) -> (f64, f64) {
        let (x, y) = self.distort(tan_x, tan_y);
        (self.fx * x + self.cx, self.fy * y + self.cy)
    }
}

/// The collimator and the screen behind it.
#[derive(Debug, Clone, PartialEq)]
pub struct Collimator {
    /// Screen pixels per unit of ρ (focal length / pitch).
    f_px: f64,
    k1: f64,
    k2: f64,
    p1: f64,
    p2: f64,
    prism: [f64; 4],
    /// Screen position of the optical axis, px.
    axis: (f64, f64),
    rotation: f64,
}

impl Collimator {
    /// From the screen's and collimator's configuration.
    pub fn from_config(screen: &ScreenTruth, c: &CollimatorTruth) -> Collimator {
        let [w, h] = screen.resolution;
        Collimator {
            f_px: c.focal_length / screen.pixel_pitch,
            k1: c.k1,
            k2: c.k2,
            p1: c.p1,
            p2: c.p2,
            prism: c.thin_prism,
            axis: (
                0.5 * w as f64 + c.offset_px[0],
                0.5 * h as f64 + c.offset_px[1],
            ),
            rotation: c.rotation,
        }
    }

    fn radial(&self, r2: f64) -> f64 {
        1.0 + self.k1 * r2 + self.k2 * r2 * r2
    }

    /// The distortion (a, b) → (a', b') in the screen's axes.
    fn distort(&self, a: f64, b: f64) -> (f64, f64) {
        let r2 = a * a + b * b;
        let k = self.radial(r2);
        let [s1, s2, s3, s4] = self.prism;
        (
            a * k + 2.0 * self.p1 * a * b + self.p2 * (r2 + 2.0 * a * a) + s1 * r2 + s2 * r2 * r2,
            b * k + self.p1 * (r2 + 2.0 * b * b) + 2.0 * self.p2 * a * b + s3 * r2 + s4 * r2 * r2,
        )
    }

    /// Jacobian of [`Self::distort`]: [[∂a'/∂a, ∂a'/∂b], [∂b'/∂a, ∂b'/∂b]].
    fn jacobian(&self, a: f64, b: f64) -> [[f64; 2]; 2] {
        let r2 = a * a + b * b;
        let k = self.radial(r2);
        let dk = 2.0 * self.k1 + 4.0 * self.k2 * r2; // ∂k/∂a = dk · a
        let [s1, s2, s3, s4] = self.prism;
        let (p1, p2) = (self.p1, self.p2);
        [
            [
                k + dk * a * a + 2.0 * p1 * b + 6.0 * p2 * a + 2.0 * s1 * a + 4.0 * s2 * r2 * a,
                dk * a * b + 2.0 * p1 * a + 2.0 * p2 * b + 2.0 * s1 * b + 4.0 * s2 * r2 * b,
            ],
            [
                dk * a * b + 2.0 * p1 * a + 2.0 * p2 * b + 2.0 * s3 * a + 4.0 * s4 * r2 * a,
                k + dk * b * b + 6.0 * p1 * b + 2.0 * p2 * a + 2.0 * s3 * b + 4.0 * s4 * r2 * b,
            ],
        ]
    }

    /// det of the distortion's Jacobian at screen position (u, v): it must
    /// stay positive over the screen (no fold-over).
    pub fn jacobian_det(&self, u: f64, v: f64) -> f64 {
        let a = (u - self.axis.0) / self.f_px;
        let b = (v - self.axis.1) / self.f_px;
        let j = self.jacobian(a, b);
        j[0][0] * j[1][1] - j[0][1] * j[1][0]
    }

    /// Direction (tan_x, tan_y) in the camera frame at zero attitude under
    /// which the camera sees screen position (u, v).
    pub fn screen_to_tan(&self, u: f64, v: f64) -> (f64, f64) {
        let a = (u - self.axis.0) / self.f_px;
        let b = (v - self.axis.1) / self.f_px;
        let (a, b) = self.distort(a, b);
        let (s, c) = self.rotation.sin_cos();
        (a * c - b * s, a * s + b * c)
    }

    /// Screen position (u, v) seen under camera direction (tan_x, tan_y).
    pub fn tan_to_screen(&self, tx: f64, ty: f64) -> (f64, f64) {
        let (s, c) = self.rotation.sin_cos();
        let (ta, tb) = (tx * c + ty * s, -tx * s + ty * c);
        // Solve distort(a, b) = (ta, tb) by Newton's method.
        let (mut a, mut b) = (ta, tb);
        for _ in 0..50 {
            let (fa, fb) = self.distort(a, b);
            let (ra, rb) = (fa - ta, fb - tb);
            let j = self.jacobian(a, b);
            let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
            let da = (j[1][1] * ra - j[0][1] * rb) / det;
            let db = (j[0][0] * rb - j[1][0] * ra) / det;
            a -= da;
            b -= db;
            if da.abs() + db.abs() < 1e-16 {
                break;
            }
        }
        (self.axis.0 + a * self.f_px, self.axis.1 + b * self.f_px)
    }
}

/// Solid angle of the spherical triangle with (unnormalised) vertex
/// directions a, b, c (Van Oosterom & Strackee, 1983).
pub fn triangle_solid_angle(a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> f64 {
    let dot = |p: [f64; 3], q: [f64; 3]| p[0] * q[0] + p[1] * q[1] + p[2] * q[2];
    let norm = |p: [f64; 3]| dot(p, p).sqrt();
    let (la, lb, lc) = (norm(a), norm(b), norm(c));
    let cross = [
        b[1] * c[2] - b[2] * c[1],
        b[2] * c[0] - b[0] * c[2],
        b[0] * c[1] - b[1] * c[0],
    ];
    let num = dot(a, cross).abs();
    let den = la * lb * lc + dot(a, b) * lc + dot(a, c) * lb + dot(b, c) * la;
    2.0 * num.atan2(den)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn collimator_round_trip() {
        let c = Collimator {
            f_px: 5000.0,
            k1: 0.8,
            k2: 0.1,
            p1: 0.01,
            p2: -0.02,
            prism: [0.01, 3.0, -0.005, -2.0],
            axis: (33.5, 21.75),
            rotation: 0.01,
        };
        for (u, v) in [(30.0, 20.0), (0.0, 0.0), (63.0, 47.0)] {
            let (x, y) = c.screen_to_tan(u, v);
            let (u2, v2) = c.tan_to_screen(x, y);
            assert!((u2 - u).abs() < 1e-9 && (v2 - v).abs() < 1e-9, "{u2} {v2}");
        }
    }

    #[test]
    fn undistort_inverts_distort() {
        let o = CameraOptics {
            fx: 4000.0,
            fy: 4100.0,
            cx: 20.0,
            cy: 15.0,
            k1: -0.3,
            k2: 0.1,
            p1: 0.001,
            p2: -0.0005,
        };
        for (x, y) in [(0.004, -0.003), (-0.05, 0.02)] {
            let (u, v) = o.project(x, y);
            let (x2, y2) = o.undistort_pixel(u, v);
            assert!((x2 - x).abs() < 1e-14 && (y2 - y).abs() < 1e-14);
        }
    }
}
