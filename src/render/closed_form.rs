//! Exact per-cap integrals in the paper's (θ, φ) frame for a distant Sun and
//! observer: μ0 = sinθ cosφ, μ = sinθ cos(α − φ), dΩ = sinθ dθ dφ.
//!
//! The integrands separate into a θ part and a φ part; both are written with
//! sum-to-product identities so that tiny caps keep full relative precision.

use super::caps::Weight;

/// θ part of a cap's weight over [θc − Δ/2, θc + Δ/2]:
/// ∫ sin³θ dθ for μ0μ, ∫ sin²θ dθ for μ and for μ0μ/(μ0+μ).
#[inline]
pub fn theta_weight(weight: Weight, theta_c: f64, delta: f64) -> f64 {
    match weight {
        // ∫ sin³ = [cos3θ/12 − 3cosθ/4]
        Weight::Mu0Mu => {
            1.5 * theta_c.sin() * (0.5 * delta).sin()
                - (3.0 * theta_c).sin() * (1.5 * delta).sin() / 6.0
        }
        // ∫ sin² = [θ/2 − sin2θ/4]
        Weight::Mu | Weight::LommelSeeliger => {
            0.5 * delta - 0.5 * (2.0 * theta_c).cos() * delta.sin()
        }
    }
}

/// ∫ cosφ cos(α−φ) dφ over [φ0, φ1].
#[inline]
pub fn mu0_mu_phi_weight(phi0: f64, phi1: f64, alpha: f64) -> f64 {
    let d = phi1 - phi0;
    let c = 0.5 * (phi0 + phi1);
    0.5 * (d * alpha.cos() + (2.0 * c - alpha).cos() * d.sin())
}

/// ∫ cos(α−φ) dφ over [φ0, φ1].
#[inline]
pub fn mu_phi_weight(phi0: f64, phi1: f64, alpha: f64) -> f64 {
    let d = phi1 - phi0;
    let c = 0.5 * (phi0 + phi1);
    2.0 * (c - alpha).cos() * (0.5 * d).sin()
}

/// ∫ cosφ cos(α−φ) / (cosφ + cos(α−φ)) dφ over [φ0, φ1].
///
/// With ψ = φ − α/2 and h = α/2 the integrand is
/// (cosψ − sin²h secψ) / (2 cos h), whose antiderivative is
/// (sinψ − sin²h atanh(sinψ)) / (2 cos h).
#[inline]
pub fn ls_phi_weight(phi0: f64, phi1: f64, alpha: f64) -> f64 {
    let h = 0.5 * alpha;
    let (sh, ch) = h.sin_cos();
    if ch < 1e-12 {
        return 0.0;
    }
    let anti = |phi: f64| {
        let s = (phi - h).sin().clamp(-1.0 + 1e-16, 1.0 - 1e-16);
        s - sh * sh * s.atanh()
    };
    (anti(phi1) - anti(phi0)) / (2.0 * ch)
}

/// ∫∫ μ0 μ dΩ over θ ∈ [t0, t1], φ ∈ [p0, p1].
pub fn cap_mu0_mu(t0: f64, t1: f64, p0: f64, p1: f64, alpha: f64) -> f64 {
    theta_weight(Weight::Mu0Mu, 0.5 * (t0 + t1), t1 - t0) * mu0_mu_phi_weight(p0, p1, alpha)
}

/// ∫∫ μ dΩ over θ ∈ [t0, t1], φ ∈ [p0, p1].
pub fn cap_mu(t0: f64, t1: f64, p0: f64, p1: f64, alpha: f64) -> f64 {
    theta_weight(Weight::Mu, 0.5 * (t0 + t1), t1 - t0) * mu_phi_weight(p0, p1, alpha)
}

/// ∫∫ μ0 μ / (μ0 + μ) dΩ over θ ∈ [t0, t1], φ ∈ [p0, p1].
pub fn cap_mu0_mu_over_sum(t0: f64, t1: f64, p0: f64, p1: f64, alpha: f64) -> f64 {
    theta_weight(Weight::LommelSeeliger, 0.5 * (t0 + t1), t1 - t0) * ls_phi_weight(p0, p1, alpha)
}
