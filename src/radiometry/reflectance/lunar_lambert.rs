//! McEwen's lunar–Lambert law: a phase-dependent blend of Lommel–Seeliger
//! and Lambert.

use crate::radiometry::geometry::ScatteringGeometry;
use std::f64::consts::FRAC_1_PI;

/// McEwen's lunar–Lambert model:
/// I/F = π f_r μ0 = A [2 L(g) μ0/(μ0 + μ) + (1 − L(g)) μ0],
/// L(g) = 1 − 0.019 g + 2.42·10⁻⁴ g² − 1.46·10⁻⁶ g³ (g in degrees).
///
/// Albedo contract: `albedo` = A, the normal albedo scale: at L = 0 the law
/// is Lambert with ρ = A, at L = 1 it is 2A μ0/(μ0 + μ), i.e.
/// Lommel–Seeliger with geometric albedo p = A.
///
/// The cubic L(g) is a fit valid for g ≲ 100°; beyond it leaves [0, 1]
/// (it is negative from g ≈ 104°). L is clamped to [0, 1] so the law stays a
/// blend of two non-negative laws.
#[derive(Clone, Debug, PartialEq)]
pub struct LunarLambert {
    /// A.
    pub albedo: f64,
}

impl LunarLambert {
    /// Lunar–Lambert with A = `albedo`.
    pub fn new(albedo: f64) -> Self {
        Self { albedo }
    }

    /// McEwen's limb-darkening weight L(g), `g_deg` in degrees, clamped to [0, 1].
    #[inline]
    pub fn limb_weight(g_deg: f64) -> f64 {
        (1.0 + g_deg * (-0.019 + g_deg * (2.42e-4 - 1.46e-6 * g_deg))).clamp(0.0, 1.0)
    }

    /// r = (A/π) [2L μ0/(μ0 + μ) + (1 − L) μ0]. Precondition: μ0, μ ∈ (0, 1].
    #[inline]
    pub fn radiance_factor(&self, g: &ScatteringGeometry, albedo: f64) -> f64 {
        let l = Self::limb_weight(g.phase().to_degrees());
        Self::blend(g, albedo, l)
    }

    #[inline]
    fn blend(g: &ScatteringGeometry, albedo: f64, l: f64) -> f64 {
        albedo * FRAC_1_PI * (2.0 * l * (g.mu0 / (g.mu0 + g.mu)) + (1.0 - l) * g.mu0)
    }
}

#[cfg(test)]
mod tests {
    use super::super::{Lambert, LommelSeeliger, Reflectance};
    use super::*;

    #[test]
    fn end_members() {
        let a = 0.2;
        for (i, e, psi) in [(0.3, 0.9, 0.2), (1.2, 0.4, 2.5), (0.0, 1.5, 0.0)] {
            let g = ScatteringGeometry::from_angles(i, e, psi);
            // L = 1: 2A μ0/(μ0+μ)/π, the Lommel–Seeliger form with p = A.
            let ls = LunarLambert::blend(&g, a, 1.0);
            assert!((ls - 2.0 * a * g.mu0 / (g.mu0 + g.mu) / std::f64::consts::PI).abs() < 1e-15);
            assert!((ls - LommelSeeliger::new(a).radiance_factor(&g, a)).abs() < 1e-15);
            // L = 0: Lambert with ρ = A.
            let la = LunarLambert::blend(&g, a, 0.0);
            assert!((la - Lambert::new(a).radiance_factor(&g, a)).abs() < 1e-15);
        }
    }

    #[test]
    fn limb_weight_polynomial() {
        assert_eq!(LunarLambert::limb_weight(0.0), 1.0);
        // 1 − 0.019·60 + 2.42e−4·3600 − 1.46e−6·216000 = 1 − 1.14 + 0.8712 − 0.31536
        assert!((LunarLambert::limb_weight(60.0) - 0.41584).abs() < 1e-12);
        assert_eq!(LunarLambert::limb_weight(150.0), 0.0);
    }

    #[test]
    fn opposition_iof_is_a() {
        // At g = 0 (i = e) L = 1 and I/F = A·2μ0/(2μ0) = A.
        let m = Reflectance::LunarLambert(LunarLambert::new(0.2));
        for i in [0.0f64, 0.5, 1.2] {
            let g = ScatteringGeometry::from_angles(i, i, 0.0);
            let iof = std::f64::consts::PI * m.radiance_factor(&g, 0.2);
            assert!((iof - 0.2).abs() < 1e-12, "{iof}");
        }
    }

    #[test]
    fn reciprocity() {
        let m = Reflectance::LunarLambert(LunarLambert::new(0.2));
        for (i, e, psi) in [(0.2, 1.1, 0.3), (1.4, 0.1, 2.9), (0.7, 0.7, 1.0)] {
            let a = m.brdf(&ScatteringGeometry::from_angles(i, e, psi), 0.2);
            let b = m.brdf(&ScatteringGeometry::from_angles(e, i, psi), 0.2);
            assert!((a - b).abs() < 1e-13 * a);
        }
    }
}
