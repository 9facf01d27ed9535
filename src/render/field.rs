//! Whether a body can appear in a camera's frame at all: its sphere against
//! the frame's pyramid of view (behind the camera, off a side of the
//! frame), and the angles that say why not, for the one-line error of a
//! render or a facility state that would show nothing.

use crate::scene::{Pinhole, State};

/// Where the body is relative to the field of view.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FieldCheck {
    /// Some part of the body's sphere may be inside the frame's pyramid.
    pub in_field: bool,
    /// Angle of the body's centre off the boresight [deg].
    pub off_axis_deg: f64,
    /// The body's angular radius seen from the camera [deg].
    pub angular_radius_deg: f64,
    /// The field's half-angle: boresight to the frame's farthest corner [deg].
    pub half_angle_deg: f64,
}

impl FieldCheck {
    /// `the body is entirely out of the field: its centre is 121.40° off
    /// the boresight (behind the camera), angular radius 0.26°, field
    /// half-angle 4.24°`.
    pub fn describe(&self) -> String {
        let behind = if self.off_axis_deg > 90.0 {
            " (behind the camera)"
        } else {
            ""
        };
        format!(
            "the body is entirely out of the field: its centre is {:.2}° off the boresight{behind}, \
             angular radius {:.2}°, field half-angle {:.2}°",
            self.off_axis_deg, self.angular_radius_deg, self.half_angle_deg
        )
    }
}

/// The body (a sphere of `radius` [m] at `state.body_position`) against the
/// field of `camera` in `state`. Out of the field means entirely beyond one
/// side plane of the frame's pyramid (the four sides' half-spaces meet only
/// in front of the camera, so a body behind it is beyond one of them); a
/// body that clips a corner's edge without crossing a side counts as in.
pub fn field_check(camera: &Pinhole, state: &State, radius: f64) -> FieldCheck {
    let c = state.camera_attitude.inverse() * (state.body_position - state.camera_position);
    let d = c.length();
    let (w, h) = (camera.width as f64, camera.height as f64);
    let (left, right) = (camera.cx / camera.fx, (w - camera.cx) / camera.fx);
    let (top, bottom) = (camera.cy / camera.fy, (h - camera.cy) / camera.fy);
    let half_angle = left
        .abs()
        .max(right.abs())
        .hypot(top.abs().max(bottom.abs()));
    // Inward normals of the side planes: left X + (cx/fx) Z ≥ 0, and so on.
    let sides = [
        glam::DVec3::new(1.0, 0.0, left),
        glam::DVec3::new(-1.0, 0.0, right),
        glam::DVec3::new(0.0, 1.0, top),
        glam::DVec3::new(0.0, -1.0, bottom),
    ];
    let outside = d > radius && sides.iter().any(|n| n.normalize().dot(c) < -radius);
    FieldCheck {
        in_field: !outside,
        off_axis_deg: (c.z / d).clamp(-1.0, 1.0).acos().to_degrees(),
        angular_radius_deg: (radius / d).min(1.0).asin().to_degrees(),
        half_angle_deg: half_angle.atan().to_degrees(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{DQuat, DVec3};

    /// 100 × 50 px, f = 100 px, centred: half-widths tan 0.5 and 0.25.
    fn pinhole() -> Pinhole {
        Pinhole {
            width: 100,
            height: 50,
            fx: 100.0,
            fy: 100.0,
            cx: 50.0,
            cy: 25.0,
        }
    }

    /// A body of radius 1 at distance 100 in direction (θx, θy) off the
    /// boresight (camera at the origin, looking down +z).
    fn at(direction: DVec3, attitude: DQuat) -> State {
        State {
            body_position: 100.0 * direction.normalize(),
            body_attitude: DQuat::IDENTITY,
            camera_position: DVec3::ZERO,
            camera_attitude: attitude,
            sun_position: DVec3::new(0.0, 0.0, -1e9),
            occulter: None,
        }
    }

    #[test]
    fn sides_corners_and_behind() {
        let p = pinhole();
        let r = 1.0;
        // Half-angle to the corner: atan(hypot(0.5, 0.25)).
        let half = 0.5f64.hypot(0.25).atan().to_degrees();
        let check = |dir: DVec3| field_check(&p, &at(dir, DQuat::IDENTITY), r);
        let c = check(DVec3::Z);
        assert!(c.in_field && c.off_axis_deg.abs() < 1e-9);
        assert!((c.half_angle_deg - half).abs() < 1e-12);
        assert!((c.angular_radius_deg - (0.01f64).asin().to_degrees()).abs() < 1e-12);
        // Just inside and just beyond the right side (x/z = 0.5): the
        // sphere's centre at distance 100 reaches 1 past its plane.
        let plane_dist = |x: f64| (0.5 - x) / (1.0f64 + 0.25).sqrt() * 100.0 / (1.0 + x * x).sqrt();
        for (x, inside) in [(0.5, true), (0.51, true), (0.53, false)] {
            let c = check(DVec3::new(x, 0.0, 1.0));
            assert_eq!(c.in_field, plane_dist(x) >= -r, "x/z = {x}");
            assert_eq!(c.in_field, inside, "x/z = {x}");
        }
        // Behind the camera: off-axis 180°, out, and said so.
        let c = check(-DVec3::Z);
        assert!(!c.in_field && (c.off_axis_deg - 180.0).abs() < 1e-9);
        let text = c.describe();
        assert!(
            text.contains("180.00° off the boresight (behind the camera)"),
            "{text}"
        );
        assert!(
            text.contains(&format!("field half-angle {half:.2}°")),
            "{text}"
        );
        // The camera turned 90° about y: the body straight ahead of the
        // world is 90° off its boresight.
        let turned = field_check(
            &p,
            &at(
                DVec3::Z,
                DQuat::from_rotation_y(std::f64::consts::FRAC_PI_2),
            ),
            r,
        );
        assert!(!turned.in_field && (turned.off_axis_deg - 90.0).abs() < 1e-9);
        // A camera inside the body sees it whatever the direction.
        let inside = field_check(&p, &at(-DVec3::Z, DQuat::IDENTITY), 200.0);
        assert!(inside.in_field);
    }
}
