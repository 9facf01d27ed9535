//! The area law: a surface whose brightness per unit projected area is
//! uniform over the lit disk (the paper's "Area" model).

use crate::radiometry::geometry::ScatteringGeometry;
use std::f64::consts::PI;

/// Area law, f_r = ρ/(2π) sec i, so r = f_r μ0 = ρ/(2π) on the whole lit,
/// visible surface.
///
/// Albedo contract: `albedo` = ρ. A sphere with this law has geometric albedo
/// p = ρ/2 and phase function Φ(α) = (1 + cos α)/2 (the lit fraction of the
/// disk). f_r diverges as i → 90° (sec i); the radiance factor does not.
/// Not reciprocal.
#[derive(Clone, Debug, PartialEq)]
pub struct Area {
    /// ρ.
    pub albedo: f64,
}

impl Area {
    /// Area law with ρ = `albedo`.
    pub fn new(albedo: f64) -> Self {
        Self { albedo }
    }

    /// r = ρ/(2π). Precondition: μ0, μ ∈ (0, 1] (as checked by
    /// [`super::Reflectance::radiance_factor`]).
    #[inline]
    pub fn radiance_factor(&self, _g: &ScatteringGeometry, albedo: f64) -> f64 {
        albedo * (0.5 / PI)
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_util::{disk_integral, hemispherical_albedo};
    use super::super::Reflectance;

    #[test]
    fn hemispherical_albedo_is_rho_over_2mu0() {
        let m = Reflectance::Area(super::Area::new(0.4));
        for i in [0.0f64, 0.3, 0.8, 1.2, 1.5] {
            let a = hemispherical_albedo(&m, i);
            assert!((a - 0.4 / (2.0 * i.cos())).abs() < 1e-12, "i={i}: {a}");
        }
    }

    #[test]
    fn disk_integrated_phase_law() {
        // ∫ r μ dΩ over the lit, visible hemisphere = p Φ(α), with p = ρ/2
        // and Φ = (1 + cos α)/2.
        let rho = 0.4;
        let m = Reflectance::Area(super::Area::new(rho));
        for alpha in [0.0f64, 0.4, 1.0, 2.0, 3.0] {
            let num = disk_integral(&m, alpha);
            let exact = rho / 2.0 * (1.0 + alpha.cos()) / 2.0;
            assert!(
                (num - exact).abs() < 1e-12 * rho,
                "α={alpha}: {num} vs {exact}"
            );
        }
        // I(0) = p F R²: p = ρ/2 independently of π factors.
        assert!((disk_integral(&m, 0.0) - rho / 2.0).abs() < 1e-12);
    }
}
