//! The Lommel–Seeliger law: single scattering by a dark, isotropically
//! scattering particulate medium.

use crate::radiometry::geometry::ScatteringGeometry;
use std::f64::consts::FRAC_2_PI;

/// Lommel–Seeliger, f_r = (2p/π)/(μ0 + μ).
///
/// Albedo contract: `albedo` = p, the geometric albedo of a sphere with this
/// law (equivalently f_r = (w/4π)/(μ0 + μ) with single-scattering albedo
/// w = 8p). Its phase function is Φ(α) = 1 − sin(α/2) tan(α/2) ln cot(α/4).
/// f_r diverges at the terminator–limb corner μ0 + μ → 0; the radiance factor
/// r = (2p/π) μ0/(μ0 + μ) stays in [0, 2p/π].
#[derive(Clone, Debug, PartialEq)]
pub struct LommelSeeliger {
    /// p.
    pub albedo: f64,
}

impl LommelSeeliger {
    /// Lommel–Seeliger with geometric albedo p = `albedo`.
    pub fn new(albedo: f64) -> Self {
        Self { albedo }
    }

    /// r = (2p/π) μ0/(μ0 + μ). Precondition: μ0, μ ∈ (0, 1].
    #[inline]
    pub fn radiance_factor(&self, g: &ScatteringGeometry, albedo: f64) -> f64 {
        // μ0/(μ0+μ) ∈ (0, 1) for μ0, μ > 0, even when both are subnormal.
        albedo * FRAC_2_PI * (g.mu0 / (g.mu0 + g.mu))
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_util::{disk_integral, hemispherical_albedo};
    use super::super::Reflectance;
    use super::*;

    #[test]
    fn hemispherical_albedo_closed_form() {
        // ∫ f_r μ dΩ = 2π (2p/π) ∫₀¹ μ/(μ0+μ) dμ = 4p [1 − μ0 ln((1+μ0)/μ0)].
        let p = 0.12;
        let m = Reflectance::LommelSeeliger(LommelSeeliger::new(p));
        for i in [0.0f64, 0.3, 0.8, 1.2, 1.5] {
            let mu0 = i.cos();
            let a = hemispherical_albedo(&m, i);
            let exact = 4.0 * p * (1.0 - mu0 * ((1.0 + mu0) / mu0).ln());
            assert!((a - exact).abs() < 1e-10, "i={i}: {a} vs {exact}");
        }
    }

    #[test]
    fn reciprocity() {
        let m = Reflectance::LommelSeeliger(LommelSeeliger::new(0.1));
        for (i, e, psi) in [(0.2, 1.1, 0.3), (1.4, 0.1, 2.9), (0.7, 0.7, 1.0)] {
            let a = m.brdf(&ScatteringGeometry::from_angles(i, e, psi), 0.1);
            let b = m.brdf(&ScatteringGeometry::from_angles(e, i, psi), 0.1);
            assert!((a - b).abs() < 1e-14 * a);
        }
    }

    #[test]
    fn equals_w_form() {
        // (w/4π)/(μ0+μ) with w = 8p.
        let p = 0.1;
        let m = Reflectance::LommelSeeliger(LommelSeeliger::new(p));
        let g = ScatteringGeometry::from_angles(0.4, 0.9, 1.3);
        let w = 8.0 * p;
        let exact = w / (4.0 * std::f64::consts::PI) / (g.mu0 + g.mu);
        assert!((m.brdf(&g, p) - exact).abs() < 1e-15);
    }

    #[test]
    fn terminator_limb_corner_is_finite() {
        let m = Reflectance::LommelSeeliger(LommelSeeliger::new(0.1));
        for t in [1e-3, 1e-12, 1e-300, 5e-324] {
            let g = ScatteringGeometry {
                mu0: t,
                mu: t,
                cos_g: -1.0,
            };
            let r = m.radiance_factor(&g, 0.1);
            assert!((r - 0.1 * FRAC_2_PI * 0.5).abs() < 1e-15, "{t}: {r}");
        }
    }

    #[test]
    fn disk_integrated_phase_law() {
        let p = 0.11;
        let m = Reflectance::LommelSeeliger(LommelSeeliger::new(p));
        for alpha in [0.0f64, 0.4, 1.0, 2.0, 3.0] {
            let num = disk_integral(&m, alpha);
            let phi = if alpha == 0.0 {
                1.0
            } else {
                1.0 - (alpha / 2.0).sin() * (alpha / 2.0).tan() * (1.0 / (alpha / 4.0).tan()).ln()
            };
            // Disk integral = p Φ(α) (I = p F R² Φ, distance factors aside).
            assert!(
                (num - p * phi).abs() < 1e-9 * p,
                "α={alpha}: {num} vs {}",
                p * phi
            );
        }
    }
}
