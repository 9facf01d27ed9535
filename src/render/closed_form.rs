//! Exact integrals of the paper's power coefficients PF_i over rectangular
//! surface caps, in the (θ, φ) frame of Lester et al. (1979).
//!
//! Frame: unit sphere; θ is the colatitude from the pole perpendicular to the
//! scattering plane (the plane holding the Sun and observer directions), φ the
//! longitude in the scattering plane measured from the sub-solar point toward
//! the observer. For a distant Sun and observer at phase α ∈ [0, π]:
//!
//! μ0 = sin θ cos φ, μ = sin θ cos(α − φ), dΩ = sin θ dθ dφ,
//!
//! and the lit-and-visible lune is θ ∈ [0, π], φ ∈ [α − π/2, π/2]. Every
//! function here integrates over a cap θ ∈ [t0, t1], φ ∈ [p0, p1] **inside the
//! lune** (t0 ≤ t1, p0 ≤ p1); outside it the expressions are not the integral
//! of a clamped radiance. The integrands are separable, so each result is
//! (θ integral) × (φ integral), both written in forms that keep full relative
//! precision for tiny caps, caps touching the limb or terminator, caps at the
//! poles, and α → π (the lune's half-width h = (π − α)/2 → 0).
//!
//! With the paper's PF_i = Ω R² ∫∫ f_r sin³θ cos φ cos(α − φ) dθ dφ:
//! - Lambert (f_r = ρ/π): PF_i = Ω R² (ρ/π) [`cap_mu0_mu`];
//! - Area (f_r μ0 = ρ/2π): PF_i = Ω R² (ρ/2π) [`cap_mu`];
//! - Lommel–Seeliger (f_r = (2p/π)/(μ0 + μ)): PF_i = Ω R² (2p/π) [`cap_mu0_mu_over_sum`].

/// Δ − sin Δ without cancellation for small Δ.
#[inline]
fn x_minus_sin(d: f64) -> f64 {
    if d.abs() < 0.5 {
        let d2 = d * d;
        // Σ_{k≥1} (−1)^{k+1} Δ^{2k+1}/(2k+1)!, to Δ¹⁹ (next term < 1e−24 relative).
        let mut p = 1.0;
        for k in (2..=9).rev() {
            let (a, b) = ((2 * k) as f64, (2 * k + 1) as f64);
            p = 1.0 - d2 / (a * b) * p;
        }
        d * d2 / 6.0 * p
    } else {
        d - d.sin()
    }
}

/// atanh(y) − y without cancellation for small |y|; |y| < 1 (clamped just
/// below 1, where the result is always multiplied by a vanishing factor).
#[inline]
fn atanh_minus_x(y: f64) -> f64 {
    if y.abs() < 0.5 {
        // Σ_{k≥1} y^{2k+1}/(2k+1)
        let y2 = y * y;
        let y3 = y * y2;
        let mut term = y3;
        let mut sum = 0.0;
        let mut k = 3.0;
        while term.abs() > 1e-18 * y3.abs() {
            sum += term / k;
            term *= y2;
            k += 2.0;
        }
        sum
    } else {
        let y = y.clamp(-1.0 + f64::EPSILON, 1.0 - f64::EPSILON);
        y.atanh() - y
    }
}

/// ∫_{t0}^{t1} sin³θ dθ.
///
/// Antiderivative cos³θ/3 − cos θ, written as
/// d [(sin²t0 + sin²t1)/2 + d²/6] with d = cos t0 − cos t1
/// = 2 sin((t0+t1)/2) sin((t1−t0)/2): all terms non-negative on [0, π].
#[inline]
pub fn int_sin3(t0: f64, t1: f64) -> f64 {
    let d = 2.0 * (0.5 * (t0 + t1)).sin() * (0.5 * (t1 - t0)).sin();
    let (s0, s1) = (t0.sin(), t1.sin());
    d * (0.5 * (s0 * s0 + s1 * s1) + d * d / 6.0)
}

/// ∫_{t0}^{t1} sin²θ dθ = (Δ − sin Δ)/2 + sin Δ sin²((t0+t1)/2), Δ = t1 − t0.
#[inline]
pub fn int_sin2(t0: f64, t1: f64) -> f64 {
    let d = t1 - t0;
    let sm = (0.5 * (t0 + t1)).sin();
    0.5 * x_minus_sin(d) + d.sin() * sm * sm
}

/// Cap longitudes relative to the lune: (Δ, sin(h+m), sin(h−m), m) with
/// Δ = p1 − p0, m = (p0+p1)/2 − α/2 (the cap centre from the lune's centre
/// line), h + m = distance of the cap centre from the limb edge
/// φ = α − π/2, h − m = its distance from the terminator edge φ = π/2.
///
/// sin(h+m) = cos(α − φm) and sin(h−m) = cos φm are evaluated as cosines of
/// the given (floating-point) angles, not of differences with a rounded π/2:
/// near an edge that keeps full relative precision for the caps as given.
#[inline]
fn lune_offsets(p0: f64, p1: f64, alpha: f64) -> (f64, f64, f64, f64) {
    let pm = 0.5 * (p0 + p1);
    (p1 - p0, (alpha - pm).cos(), pm.cos(), pm - 0.5 * alpha)
}

/// ∫∫ μ0 μ dΩ over θ ∈ [t0, t1], φ ∈ [p0, p1] (a cap inside the lune).
///
/// Lambert: PF_i = Ω R² (ρ/π) × this. The integrand is
/// sin³θ cos φ cos(α − φ); the φ factor is
/// ∫ cos φ cos(α − φ) dφ = sin Δ sin(h+m) sin(h−m) + (Δ − sin Δ) cos α / 2
/// (see the module doc for h, m). Over the full lune:
/// (2/3)(sin α + (π − α) cos α).
pub fn cap_mu0_mu(t0: f64, t1: f64, p0: f64, p1: f64, alpha: f64) -> f64 {
    let (d, s_limb, s_term, _) = lune_offsets(p0, p1, alpha);
    let phi = d.sin() * s_limb * s_term + 0.5 * x_minus_sin(d) * alpha.cos();
    int_sin3(t0, t1) * phi
}

/// ∫∫ μ dΩ over θ ∈ [t0, t1], φ ∈ [p0, p1] (a cap inside the lune).
///
/// Area law (f_r μ0 = ρ/2π): PF_i = Ω R² (ρ/2π) × this. The integrand is
/// sin²θ cos(α − φ); ∫ cos(α − φ) dφ = 2 sin(h+m) sin(Δ/2). Over the full
/// lune: (π/2)(1 + cos α).
pub fn cap_mu(t0: f64, t1: f64, p0: f64, p1: f64, alpha: f64) -> f64 {
    let (d, s_limb, _, _) = lune_offsets(p0, p1, alpha);
    int_sin2(t0, t1) * 2.0 * s_limb * (0.5 * d).sin()
}

/// ∫∫ μ0 μ/(μ0 + μ) dΩ over θ ∈ [t0, t1], φ ∈ [p0, p1] (a cap inside the
/// lune).
///
/// Lommel–Seeliger (f_r = (2p/π)/(μ0 + μ)): PF_i = Ω R² (2p/π) × this.
///
/// The integrand is sin²θ g(φ) with, using cos φ + cos(α − φ) =
/// 2 cos(α/2) cos u, u = φ − α/2, and h = (π − α)/2,
/// g = (sin²h − sin²u)/(2 sin h cos u). With x = sin u,
/// ∫ g du = [x − cos²h atanh x]/(2 sin h). Over the cap, with
/// D = x1 − x0 = 2 cos m sin(Δ/2), 1 − x0 x1 = cos²m + sin²(Δ/2),
/// sin²h − x0 x1 = sin(h+m) sin(h−m) + sin²(Δ/2) and
/// atanh x1 − atanh x0 = atanh y, y = D/(1 − x0 x1):
///
/// ∫ g du = [D (sin²h − x0 x1)/(1 − x0 x1) − cos²h (atanh y − y)]/(2 sin h),
///
/// where the two terms never cancel catastrophically. Over the full lune
/// (π/2)[1 − sin(α/2) tan(α/2) ln cot(α/4)]. Returns 0 for α ≥ π (empty lune).
pub fn cap_mu0_mu_over_sum(t0: f64, t1: f64, p0: f64, p1: f64, alpha: f64) -> f64 {
    int_sin2(t0, t1) * phi_mu0_mu_over_sum(p0, p1, alpha)
}

/// The φ factor of [`cap_mu0_mu_over_sum`]:
/// ∫ cos φ cos(α − φ) / (cos φ + cos(α − φ)) dφ over [p0, p1].
pub fn phi_mu0_mu_over_sum(p0: f64, p1: f64, alpha: f64) -> f64 {
    // h = (π − α)/2: sin h = cos(α/2), cos h = sin(α/2), evaluated from α
    // itself (no rounded π).
    let (cos_h, sin_h) = (0.5 * alpha).sin_cos();
    let (d, s_limb, s_term, m) = lune_offsets(p0, p1, alpha);
    if sin_h <= 0.0 || d == 0.0 {
        return 0.0;
    }
    let sd = (0.5 * d).sin();
    let sd2 = sd * sd;
    let cm = m.cos();
    let dx = 2.0 * cm * sd;
    let one_m_x0x1 = cm * cm + sd2;
    let num = s_limb * s_term + sd2;
    let y = dx / one_m_x0x1;
    let j = dx * num / one_m_x0x1 - cos_h * cos_h * atanh_minus_x(y);
    j / (2.0 * sin_h)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::{FRAC_PI_2, PI};

    /// Adaptive Gauss–Kronrod (7, 15) on [a, b] to relative tolerance `tol`.
    fn gk15(f: &dyn Fn(f64) -> f64, a: f64, b: f64, tol: f64) -> f64 {
        const XK: [f64; 8] = [
            0.991_455_371_120_812_6,
            0.949_107_912_342_758_5,
            0.864_864_423_359_769_1,
            0.741_531_185_599_394_4,
            0.586_087_235_467_691_1,
            0.405_845_151_377_397_2,
            0.207_784_955_007_898_5,
            0.0,
        ];
        const WK: [f64; 8] = [
            0.022_935_322_010_529_22,
            0.063_092_092_629_978_55,
            0.104_790_010_322_250_2,
            0.140_653_259_715_525_9,
            0.169_004_726_639_267_9,
            0.190_350_578_064_785_4,
            0.204_432_940_075_298_9,
            0.209_482_141_084_727_8,
        ];
        const WG: [f64; 4] = [
            0.129_484_966_168_869_7,
            0.279_705_391_489_276_7,
            0.381_830_050_505_118_9,
            0.417_959_183_673_469_4,
        ];
        fn rule(f: &dyn Fn(f64) -> f64, a: f64, b: f64) -> (f64, f64) {
            let c = 0.5 * (a + b);
            let h = 0.5 * (b - a);
            let fc = f(c);
            let (mut k, mut g) = (WK[7] * fc, WG[3] * fc);
            for j in 0..7 {
                let (f1, f2) = (f(c - h * XK[j]), f(c + h * XK[j]));
                k += WK[j] * (f1 + f2);
                if j % 2 == 1 {
                    g += WG[j / 2] * (f1 + f2);
                }
            }
            (k * h, (k - g).abs() * h)
        }
        fn go(
            f: &dyn Fn(f64) -> f64,
            a: f64,
            b: f64,
            whole: (f64, f64),
            abs_tol: f64,
            depth: u32,
        ) -> f64 {
            let (k, err) = whole;
            // Stop at the tolerance, or at the rounding-noise floor of K − G.
            if err <= abs_tol.max(1e-15 * k.abs()) || depth == 0 {
                return k;
            }
            let c = 0.5 * (a + b);
            let (l, r) = (rule(f, a, c), rule(f, c, b));
            go(f, a, c, l, 0.5 * abs_tol, depth - 1) + go(f, c, b, r, 0.5 * abs_tol, depth - 1)
        }
        // Absolute tolerance relative to the whole integral, halved per split
        // so that the summed error estimate stays below tol·|I|.
        let whole = rule(f, a, b);
        go(f, a, b, whole, tol * whole.0.abs(), 14)
    }

    /// (sin x, cos x) at x = a + s, s ∈ [0, b − a], by angle addition from
    /// the nearer end: quadrature nodes are placed by their offset, so their
    /// rounding does not swamp the integrand where it vanishes at an end
    /// (poles, limb, terminator).
    fn sincos_at(a: f64, b: f64, s: f64) -> (f64, f64) {
        let w = b - a;
        if s <= 0.5 * w {
            let ((sa, ca), (ss, cs)) = (a.sin_cos(), s.sin_cos());
            (sa * cs + ca * ss, ca * cs - sa * ss)
        } else {
            let r = w - s; // x = b − r
            let ((sb, cb), (sr, cr)) = (b.sin_cos(), r.sin_cos());
            (sb * cr - cb * sr, cb * cr + sb * sr)
        }
    }

    /// ∫∫ f_r(μ0, μ) sin³θ cos φ cos(α − φ) dθ dφ over the cap, the paper's
    /// PF_i integrand (without Ω R²), by nested adaptive quadrature over the
    /// offsets θ − t0, φ − p0.
    fn pf_quadrature(
        fr: fn(f64, f64) -> f64,
        t0: f64,
        t1: f64,
        p0: f64,
        p1: f64,
        alpha: f64,
    ) -> f64 {
        let (dt, dp) = (t1 - t0, p1 - p0);
        let outer = |sp: f64| {
            let (_, cos_phi) = sincos_at(p0, p1, sp);
            // α − φ runs from α − p1 (at sp = Δφ) up to α − p0 (at sp = 0).
            let (_, cos_aphi) = sincos_at(alpha - p1, alpha - p0, dp - sp);
            let inner = |st: f64| {
                let (s, _) = sincos_at(t0, t1, st);
                let (mu0, mu) = (s * cos_phi, s * cos_aphi);
                fr(mu0, mu) * s * s * s * cos_phi * cos_aphi
            };
            gk15(&inner, 0.0, dt, 1e-13)
        };
        gk15(&outer, 0.0, dp, 1e-13)
    }

    fn fr_lambert(_: f64, _: f64) -> f64 {
        1.0
    }
    fn fr_area(mu0: f64, _: f64) -> f64 {
        1.0 / mu0
    }
    fn fr_ls(mu0: f64, mu: f64) -> f64 {
        1.0 / (mu0 + mu)
    }

    /// SplitMix64, for reproducible random caps.
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> f64 {
            self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
        }
        /// A sub-interval of [lo, hi]: random, touching either end, tiny, or whole.
        fn interval(&mut self, lo: f64, hi: f64) -> (f64, f64) {
            let w = hi - lo;
            let (a, b) = (lo + w * self.next(), lo + w * self.next());
            let (a, b) = (a.min(b), a.max(b));
            // Tiny, but not below 2e-5 rad: a cap of width δ touching an edge
            // where the integrand vanishes is known only to ~1e-16/δ relative,
            // as its edges are rounded angles.
            let tiny = (w * 10f64.powf(-1.0 - 4.0 * self.next())).max(2e-5).min(w);
            match (self.next() * 7.0) as u32 {
                0 => (lo, b),
                1 => (a, hi),
                2 => (lo, lo + tiny),
                3 => (hi - tiny, hi),
                4 => (a, (a + tiny).min(hi)),
                5 => (lo, hi),
                _ => (a, b),
            }
        }
    }

    fn alphas() -> Vec<f64> {
        vec![
            0.0,
            1e-6,
            0.01,
            0.3,
            1.0,
            FRAC_PI_2,
            2.0,
            2.8,
            3.1,
            PI - 1e-3,
        ]
    }

    fn check_random_caps(
        name: &str,
        closed: fn(f64, f64, f64, f64, f64) -> f64,
        fr: fn(f64, f64) -> f64,
    ) {
        let mut rng = Rng(0x5eed_0000 + name.len() as u64);
        let mut worst: f64 = 0.0;
        for alpha in alphas() {
            for _ in 0..60 {
                let (t0, t1) = rng.interval(0.0, PI);
                let (p0, p1) = rng.interval(alpha - FRAC_PI_2, FRAC_PI_2);
                if t1 <= t0 || p1 <= p0 {
                    continue;
                }
                let c = closed(t0, t1, p0, p1, alpha);
                let q = pf_quadrature(fr, t0, t1, p0, p1, alpha);
                let rel = (c - q).abs() / q.abs();
                worst = worst.max(rel);
                assert!(
                    rel < 1e-10,
                    "{name} α={alpha} θ∈[{t0}, {t1}] φ∈[{p0}, {p1}]: closed {c:e} vs quadrature {q:e} (rel {rel:e})"
                );
            }
        }
        eprintln!("{name}: worst relative error {worst:e}");
    }

    #[test]
    fn lambert_caps_match_quadrature() {
        check_random_caps("mu0_mu", cap_mu0_mu, fr_lambert);
    }

    #[test]
    fn area_caps_match_quadrature() {
        check_random_caps("mu", cap_mu, fr_area);
    }

    #[test]
    fn lommel_seeliger_caps_match_quadrature() {
        check_random_caps("mu0_mu_over_sum", cap_mu0_mu_over_sum, fr_ls);
    }

    #[test]
    fn polar_and_edge_caps() {
        // Hand-picked caps at the poles, the limb, the terminator and both
        // corners, at several phases.
        for alpha in [0.0, 0.5, 2.0, 3.0] {
            let (pl, pt) = (alpha - FRAC_PI_2, FRAC_PI_2);
            let w = pt - pl;
            for (t0, t1) in [
                (0.0, 1e-4),
                (PI - 1e-4, PI),
                (0.0, 0.3),
                (1.5, 1.6),
                (0.0, PI),
            ] {
                for (p0, p1) in [
                    (pl, pl + 1e-3 * w),
                    (pt - 1e-3 * w, pt),
                    (pl, pl + 0.1 * w),
                    (pt - 0.1 * w, pt),
                ] {
                    for (name, closed, fr) in [
                        (
                            "mu0_mu",
                            cap_mu0_mu as fn(f64, f64, f64, f64, f64) -> f64,
                            fr_lambert as fn(f64, f64) -> f64,
                        ),
                        ("mu", cap_mu, fr_area),
                        ("ls", cap_mu0_mu_over_sum, fr_ls),
                    ] {
                        let c = closed(t0, t1, p0, p1, alpha);
                        let q = pf_quadrature(fr, t0, t1, p0, p1, alpha);
                        assert!(
                            (c - q).abs() <= 1e-10 * q.abs(),
                            "{name} α={alpha} θ∈[{t0}, {t1}] φ∈[{p0}, {p1}]: {c:e} vs {q:e}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn caps_add_up() {
        // Splitting a cap in two gives the same total (exactness of the
        // antiderivatives, independent of quadrature).
        let alpha = 1.3;
        let (t0, tm, t1) = (0.2, 1.1, 2.9);
        let (p0, pm, p1) = (alpha - FRAC_PI_2 + 0.01, 0.4, FRAC_PI_2);
        for f in [cap_mu0_mu, cap_mu, cap_mu0_mu_over_sum] {
            let whole = f(t0, t1, p0, p1, alpha);
            let parts = f(t0, tm, p0, pm, alpha)
                + f(tm, t1, p0, pm, alpha)
                + f(t0, tm, pm, p1, alpha)
                + f(tm, t1, pm, p1, alpha);
            assert!((whole - parts).abs() < 1e-14 * whole);
        }
    }

    #[test]
    fn full_lune_phase_laws() {
        for k in 0..=60 {
            let alpha = PI * k as f64 / 60.0;
            let (pl, pt) = (alpha - FRAC_PI_2, FRAC_PI_2);
            // Lambert: ∫ μ0 μ dΩ = (2/3)(sin α + (π − α) cos α), so with
            // f_r = ρ/π: p = 2ρ/3, Φ = (sin α + (π − α) cos α)/π.
            let lam = cap_mu0_mu(0.0, PI, pl, pt, alpha);
            let exact = 2.0 / 3.0 * (alpha.sin() + (PI - alpha) * alpha.cos());
            assert!((lam - exact).abs() <= 1e-13, "α={alpha}: {lam} vs {exact}");
            let p_phi = lam / PI; // ρ = 1
            assert!(
                (p_phi - 2.0 / 3.0 * (alpha.sin() + (PI - alpha) * alpha.cos()) / PI).abs() < 1e-14
            );
            // Area: (ρ/2π) ∫ μ dΩ = (ρ/2)(1 + cos α)/2.
            let area = cap_mu(0.0, PI, pl, pt, alpha) / (2.0 * PI);
            assert!(
                (area - 0.5 * (1.0 + alpha.cos()) / 2.0).abs() < 1e-14,
                "α={alpha}: {area}"
            );
            // Lommel–Seeliger: (2p/π) ∫ μ0 μ/(μ0+μ) dΩ = p Φ(α),
            // Φ = 1 − sin(α/2) tan(α/2) ln cot(α/4).
            let ls = 2.0 / PI * cap_mu0_mu_over_sum(0.0, PI, pl, pt, alpha);
            let phi = if alpha == 0.0 {
                1.0
            } else if k == 60 {
                0.0
            } else {
                1.0 - (alpha / 2.0).sin() * (alpha / 2.0).tan() * (1.0 / (alpha / 4.0).tan()).ln()
            };
            assert!((ls - phi).abs() < 1e-12, "α={alpha}: {ls} vs {phi}");
        }
        // At α = 0 exactly: p = 2/3 (Lambert, ρ = 1), p = 1/2 (Area), Φ_LS = 1.
        assert!((cap_mu0_mu(0.0, PI, -FRAC_PI_2, FRAC_PI_2, 0.0) / PI - 2.0 / 3.0).abs() < 1e-15);
        assert!((cap_mu(0.0, PI, -FRAC_PI_2, FRAC_PI_2, 0.0) / (2.0 * PI) - 0.5).abs() < 1e-15);
    }

    #[test]
    fn near_opposition_and_near_conjunction_relative_accuracy() {
        // α → π: the lune's width ε = π − α → 0. Exact asymptotics:
        // ∫ μ0 μ dΩ = (2/3)(sin ε − ε cos ε) = (2/3)(ε³/3 − ε⁵/30 + …),
        // ∫ μ dΩ = (π/2)(1 − cos ε) = π sin²(ε/2).
        for eps in [1e-2, 1e-4, 1e-6] {
            let alpha = PI - eps;
            let eps = PI - alpha; // exact in floating point
            let (pl, pt) = (alpha - FRAC_PI_2, FRAC_PI_2);
            let lam = cap_mu0_mu(0.0, PI, pl, pt, alpha);
            let e2 = eps * eps;
            let exact = 2.0 / 3.0 * eps * e2 * (1.0 / 3.0 - e2 / 30.0 + e2 * e2 / 840.0);
            assert!(
                (lam - exact).abs() < 1e-9 * exact,
                "ε={eps}: {lam:e} vs {exact:e}"
            );
            let area = cap_mu(0.0, PI, pl, pt, alpha);
            let exact = PI * (eps / 2.0).sin().powi(2);
            assert!(
                (area - exact).abs() < 1e-9 * exact,
                "ε={eps}: {area:e} vs {exact:e}"
            );
            // Lommel–Seeliger, by quadrature of the paper's integrand.
            let ls = cap_mu0_mu_over_sum(0.0, PI, pl, pt, alpha);
            let q = pf_quadrature(fr_ls, 0.0, PI, pl, pt, alpha);
            assert!((ls - q).abs() < 1e-9 * q, "ε={eps}: {ls:e} vs {q:e}");
        }
        // α = π exactly: empty lune.
        assert_eq!(cap_mu0_mu_over_sum(0.0, PI, FRAC_PI_2, FRAC_PI_2, PI), 0.0);
        assert_eq!(cap_mu0_mu(0.0, PI, FRAC_PI_2, FRAC_PI_2, PI), 0.0);
    }

    #[test]
    fn helper_series() {
        for d in [1e-8f64, 1e-3, 0.05, 0.0999, 0.1, 0.5] {
            // Reference: Taylor series summed to convergence.
            let (mut term, mut sum, mut k) = (d * d * d / 6.0, 0.0, 3.0);
            while term.abs() > 1e-30 {
                sum += term;
                term *= -d * d / ((k + 1.0) * (k + 2.0));
                k += 2.0;
            }
            assert!((x_minus_sin(d) - sum).abs() < 1e-14 * sum, "{d}");
        }
        for y in [1e-8f64, 1e-3, 0.05, 0.0999, 0.1, 0.5, -0.3] {
            let (mut p, mut sum, mut k) = (y * y * y, 0.0, 3.0);
            while p.abs() > 1e-30 {
                sum += p / k;
                p *= y * y;
                k += 2.0;
            }
            assert!((atanh_minus_x(y) - sum).abs() < 1e-14 * sum.abs(), "{y}");
        }
        assert!(atanh_minus_x(1.0).is_finite());
    }
}
