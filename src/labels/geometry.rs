//! Closed forms of the labels: ray–sphere intersection, the limb ellipse of
//! a projected sphere (the image of its tangent cone) and limb points.

use glam::DVec3;
use serde::Serialize;

use crate::scene::Pinhole;

/// Distance along the unit ray `origin + t · dir` to its first hit of the
/// sphere (`centre`, `radius`) in front of the origin; None on a miss.
pub fn ray_sphere(origin: DVec3, dir: DVec3, centre: DVec3, radius: f64) -> Option<f64> {
    let oc = origin - centre;
    let b = dir.dot(oc);
    let c = oc.length_squared() - radius * radius;
    let disc = b * b - c;
    if disc < 0.0 {
        return None;
    }
    // The nearer root; −b − √disc loses digits when b ≫ √disc, so take it as
    // c / (−b + √disc) (the product of the roots is c).
    let far = -b + disc.sqrt();
    let near = if far > 0.0 { c / far } else { -b - disc.sqrt() };
    (near > 0.0 && near.is_finite()).then_some(near)
}

/// An ellipse in continuous pixel coordinates.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Ellipse {
    /// Centre [px].
    pub centre: [f64; 2],
    /// Semi-major and semi-minor axes [px].
    pub semi_axes: [f64; 2],
    /// Angle of the major axis from +x (right) toward +y (down), in
    /// (−π/2, π/2] [rad].
    pub angle_rad: f64,
    /// Axis-aligned box [x0, y0, x1, y1] [px].
    #[serde(skip)]
    pub bounds: [f64; 4],
}

impl Ellipse {
    /// Axis-aligned box [x0, y0, x1, y1] [px].
    pub fn bbox(&self) -> [f64; 4] {
        self.bounds
    }
}

/// The image of the limb of a sphere of `radius` centred at `centre_cam`
/// (camera frame): the conic (m·C)² = (|C|² − R²)|m|² in normalised
/// coordinates m = (x, y, 1); an ellipse when the whole sphere is in front
/// of the camera's plane (C_z > R), else None.
pub fn limb_ellipse(camera: &Pinhole, centre_cam: DVec3, radius: f64) -> Option<Ellipse> {
    let c = centre_cam;
    let k = c.length_squared() - radius * radius;
    if c.z <= radius || k <= 0.0 {
        return None;
    }
    // q(x, y) = xᵀ A x + 2 bᵀ x + c0, positive inside the disk.
    let a = [[c.x * c.x - k, c.x * c.y], [c.x * c.y, c.y * c.y - k]];
    let b = [c.x * c.z, c.y * c.z];
    let c0 = c.z * c.z - k;
    let det = a[0][0] * a[1][1] - a[0][1] * a[1][0];
    let x0 = -(a[1][1] * b[0] - a[0][1] * b[1]) / det;
    let y0 = -(a[0][0] * b[1] - a[1][0] * b[0]) / det;
    let q0 = c0 + b[0] * x0 + b[1] * y0;
    // (x − x0)ᵀ M (x − x0) = 1 with M = −A / q0, then to pixels u = f x + c.
    let (fx, fy) = (camera.fx, camera.fy);
    let m = [
        -a[0][0] / (q0 * fx * fx),
        -a[0][1] / (q0 * fx * fy),
        -a[1][1] / (q0 * fy * fy),
    ];
    let (l_small, l_big, angle_big) = symmetric_eigen(m[0], m[1], m[2]);
    if !(l_small > 0.0 && l_big.is_finite()) {
        return None;
    }
    let mut angle = angle_big + std::f64::consts::FRAC_PI_2;
    if angle > std::f64::consts::FRAC_PI_2 {
        angle -= std::f64::consts::PI;
    }
    let centre = [camera.cx + fx * x0, camera.cy + fy * y0];
    let det_m = m[0] * m[2] - m[1] * m[1];
    let (hw, hh) = ((m[2] / det_m).sqrt(), (m[0] / det_m).sqrt());
    Some(Ellipse {
        centre,
        semi_axes: [1.0 / l_small.sqrt(), 1.0 / l_big.sqrt()],
        angle_rad: angle,
        bounds: [
            centre[0] - hw,
            centre[1] - hh,
            centre[0] + hw,
            centre[1] + hh,
        ],
    })
}

/// Eigenvalues (smaller, larger) of [[a, b], [b, d]] and the angle of the
/// larger one's eigenvector from +x.
fn symmetric_eigen(a: f64, b: f64, d: f64) -> (f64, f64, f64) {
    let mean = 0.5 * (a + d);
    let half = (0.25 * (a - d) * (a - d) + b * b).sqrt();
    (mean - half, mean + half, 0.5 * (2.0 * b).atan2(a - d))
}

/// `n` points evenly spaced on the sphere's limb (the circle where the
/// camera's rays graze it), projected; those behind the camera left out.
pub fn limb_points(camera: &Pinhole, centre_cam: DVec3, radius: f64, n: usize) -> Vec<[f64; 2]> {
    let d = centre_cam.length();
    limb_circle(centre_cam, radius, n)
        .into_iter()
        .filter(|p| p.z > 1e-9 * d)
        .map(|p| {
            let (u, v) = camera.project(p);
            [u, v]
        })
        .collect()
}

/// `n` points evenly spaced on the sphere's limb circle (camera frame);
/// empty when the camera is inside the sphere.
pub fn limb_circle(centre_cam: DVec3, radius: f64, n: usize) -> Vec<DVec3> {
    let d2 = centre_cam.length_squared();
    if d2 <= radius * radius {
        return Vec::new();
    }
    let axis = centre_cam.normalize();
    let circle_centre = centre_cam * (1.0 - radius * radius / d2);
    let circle_radius = radius * (d2 - radius * radius).sqrt() / d2.sqrt();
    let (e1, e2) = axis.any_orthonormal_pair();
    (0..n)
        .map(|k| std::f64::consts::TAU * k as f64 / n as f64)
        .map(|t| circle_centre + circle_radius * (t.cos() * e1 + t.sin() * e2))
        .collect()
}
