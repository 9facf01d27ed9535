//! The collimator focal length a geometry calibration implies near the
//! optical axis, f = pixel pitch ÷ |∂tan/∂u| (and ∂v), against the
//! configured one. The geometry is measured through the camera's
//! intrinsics, so a focal-length error in the intrinsics scales every
//! tangent and shows here as a collimator focal length off by the same
//! fraction: flagged beyond `calibrate.collimator_focal_length_uncertainty_percent`.

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::facility::geometry::GeometryCalibration;

/// The check's result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FocalCheck {
    /// Screen position (px) of the optical axis (tan = 0).
    pub axis_px: [f64; 2],
    /// Focal length implied along u and v, m.
    pub implied_m: [f64; 2],
    pub configured_m: f64,
    /// Mean implied / configured − 1, %.
    pub disagreement_percent: f64,
    /// The declared uncertainty, %; `None`: not checked.
    pub uncertainty_percent: Option<f64>,
    /// Disagreement beyond the declared uncertainty.
    pub flagged: bool,
}

/// The axis by Newton iterations from the screen centre, then the
/// Jacobian's column lengths there.
pub fn check(
    geometry: &GeometryCalibration,
    pixel_pitch_m: f64,
    configured_m: f64,
    uncertainty_percent: Option<f64>,
) -> Result<FocalCheck> {
    let (w, h) = geometry.screen();
    let (mut u, mut v) = (w as f64 / 2.0, h as f64 / 2.0);
    for _ in 0..30 {
        let t = geometry.direction(u, v);
        let j = geometry.jacobian(u, v);
        let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
        if !(det.abs() > 0.0 && det.is_finite()) {
            return Err(Error::Other(format!(
                "{}: the geometry is singular near ({u:.1}, {v:.1}) px",
                geometry.path().display()
            )));
        }
        let du = (j[1][1] * t[0] - j[0][1] * t[1]) / det;
        let dv = (-j[1][0] * t[0] + j[0][0] * t[1]) / det;
        u = (u - du).clamp(0.0, w as f64);
        v = (v - dv).clamp(0.0, h as f64);
    }
    let j = geometry.jacobian(u, v);
    let implied = [
        pixel_pitch_m / j[0][0].hypot(j[1][0]),
        pixel_pitch_m / j[0][1].hypot(j[1][1]),
    ];
    let disagreement = 100.0 * ((implied[0] + implied[1]) / 2.0 / configured_m - 1.0);
    if !disagreement.is_finite() {
        return Err(Error::Other(format!(
            "{}: no finite focal length implied near the axis",
            geometry.path().display()
        )));
    }
    Ok(FocalCheck {
        axis_px: [u, v],
        implied_m: implied,
        configured_m,
        disagreement_percent: disagreement,
        uncertainty_percent,
        flagged: uncertainty_percent.is_some_and(|u| disagreement.abs() > u),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A pinhole collimator of focal length f (pitch p), axis at (u0, v0),
    /// with radial distortion and a small rotation: the implied focal
    /// length is f at the axis, whatever the distortion.
    fn geometry(f: f64, p: f64, scale: f64) -> GeometryCalibration {
        let (u0, v0, rot, k1) = (203.2, 148.1, 0.002f64, 0.4);
        let mut g = String::from("u_px,v_px,tan_x,tan_y\n");
        for v in (0..=300).step_by(10) {
            for u in (0..=400).step_by(10) {
                let (x, y) = ((u as f64 - u0) * p / f, (v as f64 - v0) * p / f);
                let (x, y) = (x * rot.cos() - y * rot.sin(), x * rot.sin() + y * rot.cos());
                let r = 1.0 + k1 * (x * x + y * y);
                g.push_str(&format!(
                    "{u},{v},{:?},{:?}\n",
                    scale * x * r,
                    scale * y * r
                ));
            }
        }
        GeometryCalibration::from_csv_bytes(g.as_bytes(), "g.csv", (400, 300)).unwrap()
    }

    #[test]
    fn implied_focal_length_and_the_flag() {
        let c = check(&geometry(3.0, 2.768e-4, 1.0), 2.768e-4, 3.0, Some(0.1)).unwrap();
        assert!(
            (c.axis_px[0] - 203.2).abs() < 0.05 && (c.axis_px[1] - 148.1).abs() < 0.05,
            "{c:?}"
        );
        assert!(c.disagreement_percent.abs() < 0.01, "{c:?}");
        assert!(!c.flagged);
        // Intrinsics whose focal length is 0.25 % short make every tangent
        // 0.25 % large: the collimator looks 1/1.0025 − 1 = −0.249 % short.
        let c = check(&geometry(3.0, 2.768e-4, 1.0025), 2.768e-4, 3.0, Some(0.1)).unwrap();
        assert!(
            (c.disagreement_percent - 100.0 * (1.0 / 1.0025 - 1.0)).abs() < 0.01,
            "{c:?}"
        );
        assert!(c.flagged);
        assert!(
            !check(&geometry(3.0, 2.768e-4, 1.0025), 2.768e-4, 3.0, None)
                .unwrap()
                .flagged
        );
    }
}
