//! The Oren & Nayar (1994) model of a rough diffuse surface: V-cavities of
//! Lambertian facets with normally distributed slopes, in its full form
//! (with inter-reflections) and its qualitative simplification.

use crate::radiometry::fastmath;
use crate::radiometry::geometry::ScatteringGeometry;
use std::f64::consts::{FRAC_1_PI, FRAC_2_PI};

/// sin x from cos x, accurate near x = 0 and x = π/2.
#[inline]
fn sin_from_cos(c: f64) -> f64 {
    ((1.0 - c) * (1.0 + c)).max(0.0).sqrt()
}

/// Angles shared by both forms: (α, β) = (max, min)(i, e) with their sines
/// and cosines.
struct AlphaBeta {
    alpha: f64,
    beta: f64,
    sin_alpha: f64,
    sin_beta: f64,
    /// cos β = max(μ0, μ) ≥ μ0.
    cos_beta: f64,
}

#[inline]
fn alpha_beta(g: &ScatteringGeometry) -> AlphaBeta {
    let cos_alpha = g.mu0.min(g.mu);
    let cos_beta = g.mu0.max(g.mu);
    AlphaBeta {
        alpha: fastmath::acos(cos_alpha),
        beta: fastmath::acos(cos_beta),
        sin_alpha: sin_from_cos(cos_alpha),
        sin_beta: sin_from_cos(cos_beta),
        cos_beta,
    }
}

/// Full Oren & Nayar (1994) model, with σ = `roughness` (radians, the
/// standard deviation of the facet slope angle) and cos Δφ = cos ψ, the
/// azimuth between the incidence and emission planes (1 when i or e is 0):
///
/// with α = max(i, e), β = min(i, e),
/// - C1 = 1 − 0.5 σ²/(σ² + 0.33)
/// - C2 = 0.45 σ²/(σ² + 0.09) sin α if cos Δφ ≥ 0, else
///   0.45 σ²/(σ² + 0.09) (sin α − (2β/π)³)
/// - C3 = 0.125 σ²/(σ² + 0.09) (4αβ/π²)²
/// - f_r = ρ/π [C1 + cos Δφ C2 tan β + (1 − |cos Δφ|) C3 tan((α + β)/2)]
///   + 0.17 ρ²/π σ²/(σ² + 0.13) [1 − cos Δφ (2β/π)²].
///
/// Albedo contract: `albedo` = ρ, the albedo of the Lambertian facets
/// (σ = 0 is exactly Lambert with albedo ρ). The model is reciprocal. f_r
/// grows without bound at grazing backscatter (tan β), but r = f_r μ0 stays
/// bounded because tan β μ0 ≤ sin β. In extreme grazing forward scatter the
/// formula can dip below zero; the radiance factor is then clamped to 0.
#[derive(Clone, Debug, PartialEq)]
pub struct OrenNayar {
    /// ρ.
    pub(super) albedo: f64,
    /// σ (radians).
    pub(super) roughness: f64,
    c1: f64,
    c2: f64,
    c3: f64,
    /// 0.17 σ²/(σ² + 0.13) / π.
    c_ir: f64,
}

impl OrenNayar {
    /// Full model with ρ = `albedo` and σ = `roughness` (radians).
    pub fn new(albedo: f64, roughness: f64) -> Self {
        let s2 = roughness * roughness;
        Self {
            albedo,
            roughness,
            c1: 1.0 - 0.5 * s2 / (s2 + 0.33),
            c2: 0.45 * s2 / (s2 + 0.09),
            c3: 0.125 * s2 / (s2 + 0.09),
            c_ir: 0.17 * s2 / (s2 + 0.13) * FRAC_1_PI,
        }
    }

    /// σ (radians).
    pub fn roughness(&self) -> f64 {
        self.roughness
    }

    /// r = f_r μ0. Precondition: μ0, μ ∈ (0, 1], cos g ∈ [−1, 1].
    #[inline]
    pub fn radiance_factor(&self, g: &ScatteringGeometry, albedo: f64) -> f64 {
        let ab = alpha_beta(g);
        let cos_dphi = g.cos_azimuth();
        let two_beta_pi = ab.beta * FRAC_2_PI;
        let c2 = if cos_dphi >= 0.0 {
            self.c2 * ab.sin_alpha
        } else {
            self.c2 * (ab.sin_alpha - two_beta_pi * two_beta_pi * two_beta_pi)
        };
        let four_ab = 4.0 * ab.alpha * ab.beta * FRAC_1_PI * FRAC_1_PI;
        let c3 = self.c3 * four_ab * four_ab;
        // tan β μ0 = sin β (μ0 / cos β) with μ0 ≤ cos β.
        let tan_beta_mu0 = ab.sin_beta * (g.mu0 / ab.cos_beta);
        // tan((α+β)/2) = (sin α + sin β)/(cos α + cos β) (half-angle sum
        // identity), with cos α + cos β = μ0 + μ > 0 and μ0 ≤ μ0 + μ.
        let tan_s_mu0 = (ab.sin_alpha + ab.sin_beta) * (g.mu0 / (g.mu0 + g.mu));
        let direct = albedo
            * FRAC_1_PI
            * (self.c1 * g.mu0
                + cos_dphi * c2 * tan_beta_mu0
                + (1.0 - cos_dphi.abs()) * c3 * tan_s_mu0);
        let inter =
            albedo * albedo * self.c_ir * (1.0 - cos_dphi * two_beta_pi * two_beta_pi) * g.mu0;
        direct + inter
    }
}

/// Qualitative Oren & Nayar (1994) model, σ = `roughness` (radians):
/// A = 1 − 0.5 σ²/(σ² + 0.33), B = 0.45 σ²/(σ² + 0.09),
/// f_r = ρ/π [A + B max(0, cos Δφ) sin α tan β], α = max(i, e),
/// β = min(i, e).
///
/// Albedo contract: `albedo` = ρ, the facet albedo (σ = 0 is Lambert).
/// Bounds: ρ A μ0/π ≤ r ≤ ρ (A μ0 + B)/π.
#[derive(Clone, Debug, PartialEq)]
pub struct OrenNayarQualitative {
    /// ρ.
    pub(super) albedo: f64,
    /// σ (radians).
    pub(super) roughness: f64,
    a: f64,
    b: f64,
}

impl OrenNayarQualitative {
    /// Qualitative model with ρ = `albedo` and σ = `roughness` (radians).
    pub fn new(albedo: f64, roughness: f64) -> Self {
        let s2 = roughness * roughness;
        Self {
            albedo,
            roughness,
            a: 1.0 - 0.5 * s2 / (s2 + 0.33),
            b: 0.45 * s2 / (s2 + 0.09),
        }
    }

    /// σ (radians).
    pub fn roughness(&self) -> f64 {
        self.roughness
    }

    /// r = f_r μ0. Precondition: μ0, μ ∈ (0, 1], cos g ∈ [−1, 1].
    #[inline]
    pub fn radiance_factor(&self, g: &ScatteringGeometry, albedo: f64) -> f64 {
        let cos_dphi = g.cos_azimuth().max(0.0);
        let mut r = self.a * g.mu0;
        if cos_dphi > 0.0 {
            let cos_alpha = g.mu0.min(g.mu);
            let cos_beta = g.mu0.max(g.mu);
            // sin α tan β μ0 = sin α sin β (μ0 / cos β) ≤ 1.
            r += self.b
                * cos_dphi
                * sin_from_cos(cos_alpha)
                * sin_from_cos(cos_beta)
                * (g.mu0 / cos_beta);
        }
        albedo * FRAC_1_PI * r
    }
}

#[cfg(test)]
mod tests {
    use super::super::test_util::hemispherical_albedo;
    use super::super::Reflectance;
    use super::*;
    use std::f64::consts::PI;

    fn angles() -> Vec<(f64, f64, f64)> {
        let mut v = Vec::new();
        for &i in &[0.0, 0.1, 0.5, 0.9, 1.3, 1.55, 1.5706] {
            for &e in &[0.0, 0.2, 0.6, 1.0, 1.4, 1.565] {
                for &psi in &[0.0, 0.7, PI / 2.0, 2.2, PI] {
                    v.push((i, e, psi));
                }
            }
        }
        v
    }

    /// The paper's formula, written directly with angles and tangents.
    fn reference_full(rho: f64, sigma: f64, i: f64, e: f64, psi: f64) -> f64 {
        let s2 = sigma * sigma;
        let (a, b) = (i.max(e), i.min(e));
        let cp = if i == 0.0 || e == 0.0 { 1.0 } else { psi.cos() };
        let c1 = 1.0 - 0.5 * s2 / (s2 + 0.33);
        let c2 = if cp >= 0.0 {
            0.45 * s2 / (s2 + 0.09) * a.sin()
        } else {
            0.45 * s2 / (s2 + 0.09) * (a.sin() - (2.0 * b / PI).powi(3))
        };
        let c3 = 0.125 * s2 / (s2 + 0.09) * (4.0 * a * b / (PI * PI)).powi(2);
        rho / PI * (c1 + cp * c2 * b.tan() + (1.0 - cp.abs()) * c3 * ((a + b) / 2.0).tan())
            + 0.17 * rho * rho / PI * s2 / (s2 + 0.13) * (1.0 - cp * (2.0 * b / PI).powi(2))
    }

    #[test]
    fn full_matches_formula() {
        for &sigma in &[0.1, 0.3, 0.7] {
            let m = Reflectance::OrenNayar(OrenNayar::new(0.6, sigma));
            for (i, e, psi) in angles() {
                let f = m.brdf(&ScatteringGeometry::from_angles(i, e, psi), 0.6);
                let r = reference_full(0.6, sigma, i, e, psi).max(0.0);
                // The model takes α, β from fastmath::acos (±3e-8 rad),
                // which tan β amplifies at grazing angles: compare the
                // radiance factors r = f_r μ0 to 1e-8.
                assert!(
                    (f - r).abs() <= 1e-9 * r.max(1e-3) + 1e-8 / i.cos().max(1e-12),
                    "σ={sigma} {i} {e} {psi}: {f} vs {r}"
                );
            }
        }
    }

    #[test]
    fn full_sigma_zero_is_lambert() {
        let m = Reflectance::OrenNayar(OrenNayar::new(0.3, 0.0));
        for (i, e, psi) in angles() {
            let f = m.brdf(&ScatteringGeometry::from_angles(i, e, psi), 0.3);
            assert!((f - 0.3 / PI).abs() < 1e-15, "{i} {e} {psi}: {f}");
        }
        let m = Reflectance::OrenNayarQualitative(OrenNayarQualitative::new(0.3, 0.0));
        for (i, e, psi) in angles() {
            let f = m.brdf(&ScatteringGeometry::from_angles(i, e, psi), 0.3);
            assert!((f - 0.3 / PI).abs() < 1e-15, "{i} {e} {psi}: {f}");
        }
    }

    #[test]
    fn full_is_reciprocal() {
        let m = Reflectance::OrenNayar(OrenNayar::new(0.5, 0.4));
        for (i, e, psi) in angles() {
            if i >= PI / 2.0 || e >= PI / 2.0 {
                continue;
            }
            let a = m.brdf(&ScatteringGeometry::from_angles(i, e, psi), 0.5);
            let b = m.brdf(&ScatteringGeometry::from_angles(e, i, psi), 0.5);
            assert!(
                (a - b).abs() <= 1e-9 * a.max(1e-3),
                "{i} {e} {psi}: {a} vs {b}"
            );
        }
    }

    #[test]
    fn qualitative_bounds() {
        let rho = 0.5;
        for &sigma in &[0.1, 0.5, 1.5] {
            let m = OrenNayarQualitative::new(rho, sigma);
            let (a, b) = (m.a, m.b);
            let m = Reflectance::OrenNayarQualitative(m);
            for (i, e, psi) in angles() {
                let g = ScatteringGeometry::from_angles(i, e, psi);
                let r = m.radiance_factor(&g, rho);
                let lo = rho / PI * a * g.mu0;
                let hi = rho / PI * (a * g.mu0 + b);
                assert!(
                    r >= lo * (1.0 - 1e-12) && r <= hi * (1.0 + 1e-12),
                    "{i} {e} {psi}: {r}"
                );
                if g.cos_azimuth() <= 0.0 {
                    assert!((r - lo).abs() <= 1e-15);
                }
                // Energy: the rough surface never exceeds the Lambert-like cap A+B.
                assert!(r <= rho / PI * (a + b) + 1e-15);
            }
        }
    }

    #[test]
    fn qualitative_matches_formula() {
        let (rho, sigma) = (0.4f64, 0.35f64);
        let s2 = sigma * sigma;
        let m = Reflectance::OrenNayarQualitative(OrenNayarQualitative::new(rho, sigma));
        for (i, e, psi) in angles() {
            let f = m.brdf(&ScatteringGeometry::from_angles(i, e, psi), rho);
            let cp = if i == 0.0 || e == 0.0 { 1.0 } else { psi.cos() };
            let exact = rho / PI
                * (1.0 - 0.5 * s2 / (s2 + 0.33)
                    + 0.45 * s2 / (s2 + 0.09) * cp.max(0.0) * i.max(e).sin() * i.min(e).tan());
            assert!(
                (f - exact).abs() <= 1e-9 * exact,
                "{i} {e} {psi}: {f} vs {exact}"
            );
        }
    }

    #[test]
    fn grazing_is_finite() {
        // tan β → ∞ as i, e → 90°: r stays bounded by ρ(C1 + C2 + C3 + C_ir)/π.
        let m = Reflectance::OrenNayar(OrenNayar::new(1.0, 1.0));
        for t in [1e-3f64, 1e-9, 1e-300, 5e-324] {
            for psi in [0.0, 1.0, PI] {
                let g = ScatteringGeometry::from_angles(t.acos(), t.acos(), psi);
                let g = ScatteringGeometry { mu0: t, mu: t, ..g };
                let r = m.radiance_factor(&g, 1.0);
                assert!(r.is_finite() && (0.0..1.0).contains(&r), "{t} {psi}: {r}");
            }
        }
    }

    #[test]
    fn undefined_azimuth_is_harmless() {
        // At i = 0 every ψ gives the same geometry; the result must be finite
        // and continuous with i → 0.
        let m = Reflectance::OrenNayar(OrenNayar::new(0.5, 0.5));
        let r0 = m.radiance_factor(&ScatteringGeometry::from_angles(0.0, 0.7, 2.0), 0.5);
        let r1 = m.radiance_factor(&ScatteringGeometry::from_angles(1e-9, 0.7, 0.0), 0.5);
        assert!(r0.is_finite() && (r0 - r1).abs() < 1e-8);
    }

    #[test]
    fn hemispherical_albedo_below_one() {
        // Energy check of the full model at ρ = 1: rough surfaces lose light
        // to shadowing but gain by inter-reflection; the albedo stays below 1.
        let m = Reflectance::OrenNayar(OrenNayar::new(1.0, 0.5));
        for i in [0.0, 0.5, 1.0, 1.4] {
            let a = hemispherical_albedo(&m, i);
            assert!(a > 0.5 && a < 1.05, "i={i}: {a}");
        }
    }
}
