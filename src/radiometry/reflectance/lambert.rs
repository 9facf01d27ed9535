//! Lambert's law: an ideal diffuse surface.

use crate::radiometry::geometry::ScatteringGeometry;
use std::f64::consts::FRAC_1_PI;

/// Lambertian surface, f_r = ρ/π.
///
/// Albedo contract: `albedo` = ρ, the hemispherical albedo (equal to the
/// Bond albedo for this law). A Lambert sphere has geometric albedo
/// p = 2ρ/3 and phase function Φ(α) = (sin α + (π − α) cos α)/π.
#[derive(Clone, Debug, PartialEq)]
pub struct Lambert {
    /// ρ.
    pub albedo: f64,
}

impl Lambert {
    /// Lambert with ρ = `albedo`.
    pub fn new(albedo: f64) -> Self {
        Self { albedo }
    }

    /// r = ρ μ0/π. Precondition: μ0, μ ∈ (0, 1].
    #[inline]
    pub fn radiance_factor(&self, g: &ScatteringGeometry, albedo: f64) -> f64 {
        albedo * FRAC_1_PI * g.mu0
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_util::{disk_integral, hemispherical_albedo};
    use super::super::Reflectance;
    use super::*;
    use std::f64::consts::PI;

    #[test]
    fn hemispherical_albedo_is_rho() {
        let m = Reflectance::Lambert(Lambert::new(0.37));
        for i in [0.0, 0.3, 0.8, 1.2, 1.5] {
            let a = hemispherical_albedo(&m, i);
            assert!((a - 0.37).abs() < 1e-12, "i={i}: {a}");
        }
    }

    #[test]
    fn reciprocity() {
        let m = Reflectance::Lambert(Lambert::new(0.37));
        for (i, e, psi) in [(0.2, 1.1, 0.3), (1.4, 0.1, 2.9), (0.7, 0.7, 1.0)] {
            let a = m.brdf(&ScatteringGeometry::from_angles(i, e, psi), 0.37);
            let b = m.brdf(&ScatteringGeometry::from_angles(e, i, psi), 0.37);
            assert!((a - b).abs() < 1e-15 && (a - 0.37 / PI).abs() < 1e-15);
        }
    }

    #[test]
    fn disk_integrated_phase_law() {
        let rho = 0.37;
        let m = Reflectance::Lambert(Lambert::new(rho));
        for alpha in [0.0f64, 0.4, 1.0, 2.0, 3.0] {
            let num = disk_integral(&m, alpha);
            let exact = 2.0 * rho / 3.0 * (alpha.sin() + (PI - alpha) * alpha.cos()) / PI;
            assert!(
                (num - exact).abs() < 1e-12 * rho,
                "α={alpha}: {num} vs {exact}"
            );
        }
    }
}
