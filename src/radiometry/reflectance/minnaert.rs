//! Minnaert's law: an empirical limb-darkening power law.

use crate::radiometry::geometry::ScatteringGeometry;
use std::f64::consts::FRAC_1_PI;

/// Smallest μ used in μ^(k−1): keeps r finite as μ → 0 for k < 1 (where the
/// law itself diverges at the limb). Far below any cosine a render meets.
const MU_FLOOR: f64 = 1e-150;

/// Minnaert, f_r = (ρ/π)(μ0 μ)^(k−1), so r = (ρ/π) μ0^k μ^(k−1).
///
/// Albedo contract: `albedo` = ρ, the normal albedo scale (k = 1 is Lambert
/// with albedo ρ). For k < 1, f_r and r diverge as μ → 0 (limb); r is
/// evaluated with μ ≥ 10⁻¹⁵⁰ so it stays finite.
#[derive(Clone, Debug, PartialEq)]
pub struct Minnaert {
    /// ρ.
    pub albedo: f64,
    /// k.
    pub k: f64,
}

impl Minnaert {
    /// Minnaert with ρ = `albedo` and exponent `k`.
    pub fn new(albedo: f64, k: f64) -> Self {
        Self { albedo, k }
    }

    /// r = (ρ/π) μ0^k μ^(k−1). Precondition: μ0, μ ∈ (0, 1].
    #[inline]
    pub fn radiance_factor(&self, g: &ScatteringGeometry, albedo: f64) -> f64 {
        albedo * FRAC_1_PI * g.mu0.powf(self.k) * g.mu.max(MU_FLOOR).powf(self.k - 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::super::{Lambert, Reflectance};
    use super::*;

    #[test]
    fn k_one_is_lambert() {
        let m = Reflectance::Minnaert(Minnaert::new(0.3, 1.0));
        for (i, e, psi) in [
            (0.3, 0.9, 0.2),
            (1.2, 0.4, 2.5),
            (0.0, 1.5, 0.0),
            (1.57, 1.57, 3.0),
        ] {
            let g = ScatteringGeometry::from_angles(i, e, psi);
            let l = Lambert::new(0.3).radiance_factor(&g, 0.3);
            assert!((m.radiance_factor(&g, 0.3) - l).abs() < 1e-16);
        }
    }

    #[test]
    fn power_law_and_reciprocity() {
        let m = Reflectance::Minnaert(Minnaert::new(0.3, 0.7));
        for (i, e, psi) in [(0.3f64, 0.9f64, 0.2), (1.2, 0.4, 2.5)] {
            let a = m.brdf(&ScatteringGeometry::from_angles(i, e, psi), 0.3);
            let b = m.brdf(&ScatteringGeometry::from_angles(e, i, psi), 0.3);
            let exact = 0.3 / std::f64::consts::PI * (i.cos() * e.cos()).powf(-0.3);
            assert!((a - exact).abs() < 1e-14 && (b - exact).abs() < 1e-14);
        }
    }

    #[test]
    fn limb_is_finite_for_small_k() {
        let m = Reflectance::Minnaert(Minnaert::new(0.3, 0.0));
        let g = ScatteringGeometry {
            mu0: 0.5,
            mu: 5e-324,
            cos_g: 0.0,
        };
        assert!(m.radiance_factor(&g, 0.3).is_finite());
    }
}
