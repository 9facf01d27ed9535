//! Hapke's bidirectional reflectance of a particulate, macroscopically rough
//! surface (Hapke 1984, 2002, 2008; "Theory of Reflectance and Emittance
//! Spectroscopy", 2012), with an optional spectral single-scattering albedo.

use super::{check_nonneg, ReflectanceConfig};
use crate::error::{Error, Result};
use crate::radiometry::geometry::ScatteringGeometry;
use serde::de::{self, Deserializer, SeqAccess, Visitor};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// Wavelength at which [`Hapke::albedo`] reads a spectral w(λ): 550 nm.
pub const REFERENCE_WAVELENGTH_M: f64 = 550e-9;

/// Guard on the effective cosines μ0e, μe: they are O(1) except at the
/// degenerate terminator–limb corner (i, e → 90°, ψ → 180°), where Hapke's
/// expressions become 0/0 while the shadowing function S → 0.
const MU_EFF_MAX: f64 = 1e3;

/// The `w` key of a Hapke configuration: a number, or a table
/// `[[wavelength_nm, w], ...]` (wavelengths strictly increasing).
#[derive(Serialize, Clone, Debug, PartialEq)]
#[serde(untagged)]
pub enum HapkeAlbedo {
    /// The same w at every wavelength.
    Constant(f64),
    /// Rows `[wavelength_nm, w]`.
    Table(Vec<[f64; 2]>),
}

impl<'de> Deserialize<'de> for HapkeAlbedo {
    fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = HapkeAlbedo;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a number or a table [[wavelength_nm, w], ...]")
            }
            fn visit_f64<E: de::Error>(self, v: f64) -> std::result::Result<Self::Value, E> {
                Ok(HapkeAlbedo::Constant(v))
            }
            fn visit_i64<E: de::Error>(self, v: i64) -> std::result::Result<Self::Value, E> {
                Ok(HapkeAlbedo::Constant(v as f64))
            }
            fn visit_u64<E: de::Error>(self, v: u64) -> std::result::Result<Self::Value, E> {
                Ok(HapkeAlbedo::Constant(v as f64))
            }
            fn visit_seq<A: SeqAccess<'de>>(
                self,
                mut seq: A,
            ) -> std::result::Result<Self::Value, A::Error> {
                let mut rows = Vec::new();
                while let Some(row) = seq.next_element::<[f64; 2]>()? {
                    rows.push(row);
                }
                Ok(HapkeAlbedo::Table(rows))
            }
        }
        d.deserialize_any(V)
    }
}

/// A validated w(λ) table, interpolated linearly in wavelength and held
/// constant beyond its ends.
#[derive(Clone, Debug, PartialEq)]
pub struct SpectralAlbedo {
    /// Wavelengths (metres), strictly increasing.
    pub wavelength_m: Vec<f64>,
    /// w at each wavelength, in (0, 1].
    pub w: Vec<f64>,
}

impl SpectralAlbedo {
    /// w at `wavelength_m` (metres).
    pub fn at(&self, wavelength_m: f64) -> f64 {
        let (x, y) = (&self.wavelength_m, &self.w);
        let n = x.len();
        if wavelength_m.is_nan() || wavelength_m <= x[0] {
            return y[0];
        }
        if wavelength_m >= x[n - 1] {
            return y[n - 1];
        }
        let k = x.partition_point(|&xi| xi <= wavelength_m); // 1 ≤ k ≤ n−1
        let t = (wavelength_m - x[k - 1]) / (x[k] - x[k - 1]);
        y[k - 1] + t * (y[k] - y[k - 1])
    }
}

/// A parameter given as a number or a `[[wavelength_nm, value], ...]`
/// table: its value at [`REFERENCE_WAVELENGTH_M`] and the table, checked
/// row by row with `ok` (`range` names the allowed interval in errors).
fn spectral_value(
    v: &HapkeAlbedo,
    field: &str,
    range: &str,
    ok: impl Fn(f64) -> bool,
) -> Result<(f64, Option<SpectralAlbedo>)> {
    let rows = match v {
        HapkeAlbedo::Constant(v) if ok(*v) => return Ok((*v, None)),
        HapkeAlbedo::Constant(v) => {
            return Err(Error::invalid(
                field,
                format!("must be in {range}, got {v}"),
            ))
        }
        HapkeAlbedo::Table(rows) => rows,
    };
    if rows.is_empty() {
        return Err(Error::invalid(
            field,
            "table [[wavelength_nm, value], ...] is empty",
        ));
    }
    for (k, &[l, v]) in rows.iter().enumerate() {
        if !(l.is_finite() && l > 0.0) {
            return Err(Error::invalid(
                field,
                format!("row {k}: wavelength must be finite and > 0 nm, got {l}"),
            ));
        }
        if k > 0 && l <= rows[k - 1][0] {
            return Err(Error::invalid(
                field,
                format!(
                    "row {k}: wavelengths must be strictly increasing ({l} nm after {} nm)",
                    rows[k - 1][0]
                ),
            ));
        }
        if !ok(v) {
            return Err(Error::invalid(
                field,
                format!("row {k}: value must be in {range}, got {v}"),
            ));
        }
    }
    let s = SpectralAlbedo {
        wavelength_m: rows.iter().map(|r| r[0] * 1e-9).collect(),
        w: rows.iter().map(|r| r[1]).collect(),
    };
    Ok((s.at(REFERENCE_WAVELENGTH_M), Some(s)))
}

/// A parameter back as a configuration value.
fn as_config(v: f64, table: &Option<SpectralAlbedo>) -> HapkeAlbedo {
    match table {
        None => HapkeAlbedo::Constant(v),
        Some(s) => HapkeAlbedo::Table(
            s.wavelength_m
                .iter()
                .zip(&s.w)
                .map(|(l, w)| [l * 1e9, *w])
                .collect(),
        ),
    }
}

/// Precomputed macroscopic-roughness constants (θ̄ > 0).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Roughness {
    tan_tb: f64,
    /// χ(θ̄) = 1/√(1 + π tan²θ̄).
    chi: f64,
    /// 2/(π tan θ̄): E1(x) = exp(−k1 cot x).
    k1: f64,
    /// 1/(π tan²θ̄): E2(x) = exp(−k2 cot²x).
    k2: f64,
}

/// The phase-function, shadow-hiding and roughness parameters of one
/// point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HapkeShape {
    /// b.
    pub b: f64,
    /// c (c > 0 favours backscatter).
    pub c: f64,
    /// h_S.
    pub h_s: f64,
    /// B_S0.
    pub b_s0: f64,
    /// θ̄ (radians).
    pub theta_bar: f64,
}

impl Roughness {
    /// The constants for θ̄; `None` for θ̄ = 0 (a smooth surface).
    fn of(theta_bar: f64) -> Option<Self> {
        (theta_bar > 0.0).then(|| {
            let t = theta_bar.tan();
            Roughness {
                tan_tb: t,
                chi: 1.0 / (1.0 + PI * t * t).sqrt(),
                k1: 2.0 / (PI * t),
                k2: 1.0 / (PI * t * t),
            }
        })
    }
}

impl HapkeShape {
    /// Double Henyey–Greenstein p(g), Hapke's convention.
    #[inline]
    pub fn phase_function(&self, cos_g: f64) -> f64 {
        let (b, c) = (self.b, self.c);
        let one_m_b2 = 1.0 - b * b;
        let back = 1.0 - 2.0 * b * cos_g + b * b;
        let fwd = 1.0 + 2.0 * b * cos_g + b * b;
        0.5 * (1.0 + c) * one_m_b2 / (back * back.sqrt())
            + 0.5 * (1.0 - c) * one_m_b2 / (fwd * fwd.sqrt())
    }

    /// B_SH(g) = 1 + B_S0/(1 + tan(g/2)/h_S), from tan(g/2).
    #[inline]
    pub fn shoe(&self, tan_half_g: f64) -> f64 {
        1.0 + self.b_s0 / (1.0 + tan_half_g / self.h_s)
    }
}

/// Hapke's bidirectional reflectance (IMSA form with the 2002 H function):
///
/// r = f_r μ0 = K (w/4π) μ0e/(μ0e + μe) [p(g) B_SH(g) + M] B_CB(g) S(i, e, ψ),
///
/// - w — single-scattering albedo. Albedo contract: `albedo` = w ∈ (0, 1];
///   it may be spectral (`w = [[wavelength_nm, w], ...]`, see
///   [`Reflectance::albedo_at`](super::Reflectance::albedo_at)).
/// - p(g) — double Henyey–Greenstein phase function in **Hapke's
///   convention**, `b` = asymmetry (|b| < 1), `c` = lobe weight ∈ [−1, 1]:
///   p(g) = (1+c)/2 (1−b²)/(1 − 2b cos g + b²)^{3/2} +
///   (1−c)/2 (1−b²)/(1 + 2b cos g + b²)^{3/2}.
///   For b > 0 the first lobe peaks at g = 0, so c > 0 favours
///   **backscatter** (verified against published reference values; the other
///   common convention, with c weighting the forward lobe, is c_other = −c).
/// - M = H(μ0e/K) H(μe/K) − 1 with the Hapke (2002) approximation of
///   Chandrasekhar's H: H(x) = 1/(1 − w x (r0 + (1 − 2 r0 x)/2 ln((1+x)/x))),
///   r0 = (1−γ)/(1+γ), γ = √(1−w); H(0) = 1.
/// - B_SH(g) = 1 + B_S0/(1 + tan(g/2)/h_S) — shadow-hiding opposition effect
///   (`b_s0` ≥ 0, `h_s` > 0).
/// - B_CB(g) = 1 + B_C0 [1 + (1 − e^{−x})/x]/(2(1+x)²), x = tan(g/2)/h_C —
///   coherent-backscatter opposition effect (`b_c0` ≥ 0, default 0; `h_c` > 0,
///   default absent = no CBOE).
/// - K — porosity factor (`porosity_k` ≥ 1, default 1).
/// - S, μ0e, μe — Hapke (1984) macroscopic roughness with mean slope θ̄
///   (`theta_bar`, radians, [0, π/2)), both branches i ≤ e and i > e, with
///   χ(θ̄) = 1/√(1 + π tan²θ̄), E1(x) = exp(−2 cot θ̄ cot x/π),
///   E2(x) = exp(−cot²θ̄ cot²x/π), η(x) = χ[cos x + sin x tan θ̄ E2/(2 − E1)]
///   and f(ψ) = exp(−2 tan(ψ/2)). θ̄ = 0 gives S = 1, μ0e = μ0, μe = μ.
///
/// ψ is the azimuth between the incidence and emission planes, ψ = 0 when Sun
/// and camera are on the same side (g = |i − e|), taken from
/// [`ScatteringGeometry::cos_azimuth`].
///
/// Parameters are fixed at build time (constants are precomputed); read them
/// through [`Hapke::params`].
#[derive(Clone, Debug, PartialEq)]
pub struct Hapke {
    /// w (at 550 nm when spectral).
    pub(super) w: f64,
    /// w(λ) when spectral.
    pub(super) spectral: Option<SpectralAlbedo>,
    /// b(λ), c(λ), h_S(λ), B_S0(λ) when given as tables (the lunar phase
    /// curve reddens: its shape changes with λ, not only its level).
    pub(super) phase_tables: Box<[Option<SpectralAlbedo>; 4]>,
    /// b.
    pub(super) b: f64,
    /// c (Hapke's convention: c > 0 favours backscatter).
    pub(super) c: f64,
    /// θ̄ (radians).
    pub(super) theta_bar: f64,
    /// h_S.
    pub(super) h_s: f64,
    /// B_S0.
    pub(super) b_s0: f64,
    /// h_C (None: no CBOE).
    pub(super) h_c: Option<f64>,
    /// B_C0.
    pub(super) b_c0: f64,
    /// K.
    pub(super) porosity_k: f64,
    /// r0 for `w`, cached.
    r0: f64,
    roughness: Option<Roughness>,
}

/// r0 = (1 − γ)/(1 + γ), γ = √(1 − w).
#[inline]
fn r0_of(w: f64) -> f64 {
    let gamma = (1.0 - w).max(0.0).sqrt();
    (1.0 - gamma) / (1.0 + gamma)
}

/// Hapke (2002) approximation of Chandrasekhar's H function, H(0) = 1.
/// Finite for every x ≥ 0 and w ∈ [0, 1) (for w = 1 it grows like x).
pub fn h_function(x: f64, w: f64) -> f64 {
    h_with_r0(x, w, r0_of(w))
}

#[inline]
fn h_with_r0(x: f64, w: f64, r0: f64) -> f64 {
    if x.is_nan() || x <= 0.0 {
        return 1.0;
    }
    // inner = x (r0 + (1 − 2 r0 x)/2 ln((1+x)/x))
    let inner = if x <= 10.0 {
        // ln((1+x)/x), finite even for subnormal x.
        let ln = if x < 1.0 {
            x.ln_1p() - x.ln()
        } else {
            x.recip().ln_1p()
        };
        x * (r0 + 0.5 * (1.0 - 2.0 * r0 * x) * ln)
    } else {
        // Large x: with u = 1/x, x² ln(1+u) = x − 1/2 + Σ_{n≥3} (−1)^{n+1} u^{n−2}/n,
        // so inner = (x/2) ln(1+u) + r0 (1/2 − Σ): no cancellation.
        let u = x.recip();
        let (mut sum, mut term, mut sign) = (0.0, u, 1.0);
        for n in 3..64 {
            sum += sign * term / n as f64;
            term *= u;
            sign = -sign;
            if term < 1e-18 {
                break;
            }
        }
        0.5 * x * u.ln_1p() + r0 * (0.5 - sum)
    };
    1.0 / (1.0 - w * inner)
}

/// sin x from cos x.
#[inline]
fn sin_from_cos(c: f64) -> f64 {
    ((1.0 - c) * (1.0 + c)).max(0.0).sqrt()
}

/// tan(g/2) from cos g, accurate at small g, +∞ at g = π.
#[inline]
fn tan_half_from_cos(cos_g: f64) -> f64 {
    (0.5 * cos_g.clamp(-1.0, 1.0).acos()).tan()
}

impl Hapke {
    /// Builds and validates from a [`ReflectanceConfig::Hapke`]; errors name
    /// `<prefix>.<key>`. Panics if `cfg` is another variant.
    pub(super) fn from_config(cfg: &ReflectanceConfig, prefix: &str) -> Result<Self> {
        let ReflectanceConfig::Hapke {
            w,
            b,
            c,
            theta_bar,
            h_s,
            b_s0,
            h_c,
            b_c0,
            porosity_k,
        } = cfg
        else {
            unreachable!("Hapke::from_config on {cfg:?}")
        };
        let field = |k: &str| format!("{prefix}.{k}");
        let (w_const, spectral) = spectral_value(w, &field("w"), "(0, 1]", |v| {
            v.is_finite() && v > 0.0 && v <= 1.0
        })?;
        let (b_const, b_table) = spectral_value(b, &field("b"), "(-1, 1)", |v| {
            v.is_finite() && v.abs() < 1.0
        })?;
        let (c_const, c_table) = spectral_value(c, &field("c"), "[-1, 1]", |v| {
            v.is_finite() && v.abs() <= 1.0
        })?;
        let (h_s_const, h_s_table) =
            spectral_value(h_s, &field("h_s"), "(0, inf)", |v| v.is_finite() && v > 0.0)?;
        let (b_s0_const, b_s0_table) = spectral_value(b_s0, &field("b_s0"), "[0, inf)", |v| {
            v.is_finite() && v >= 0.0
        })?;
        let phase_tables = Box::new([b_table, c_table, h_s_table, b_s0_table]);
        if !(theta_bar.is_finite() && *theta_bar >= 0.0 && *theta_bar < PI / 2.0) {
            return Err(Error::invalid(
                field("theta_bar"),
                format!("must be in [0, pi/2) radians, got {theta_bar}"),
            ));
        }
        if let Some(h) = h_c {
            if !(h.is_finite() && *h > 0.0) {
                return Err(Error::invalid(
                    field("h_c"),
                    format!("must be finite and > 0, got {h}"),
                ));
            }
        }
        check_nonneg(prefix, "b_c0", *b_c0)?;
        if *b_c0 > 0.0 && h_c.is_none() {
            return Err(Error::invalid(
                field("b_c0"),
                "b_c0 > 0 needs h_c (the CBOE width)",
            ));
        }
        if !(porosity_k.is_finite() && *porosity_k >= 1.0) {
            return Err(Error::invalid(
                field("porosity_k"),
                format!("must be finite and >= 1, got {porosity_k}"),
            ));
        }
        let roughness = Roughness::of(*theta_bar);
        Ok(Self {
            w: w_const,
            spectral,
            phase_tables,
            b: b_const,
            c: c_const,
            theta_bar: *theta_bar,
            h_s: h_s_const,
            b_s0: b_s0_const,
            h_c: *h_c,
            b_c0: *b_c0,
            porosity_k: *porosity_k,
            r0: r0_of(w_const),
            roughness,
        })
    }

    /// The parameters as a configuration (round-trips through [`ReflectanceConfig::build`]).
    pub fn params(&self) -> ReflectanceConfig {
        ReflectanceConfig::Hapke {
            w: as_config(self.w, &self.spectral),
            b: as_config(self.b, &self.phase_tables[0]),
            c: as_config(self.c, &self.phase_tables[1]),
            theta_bar: self.theta_bar,
            h_s: as_config(self.h_s, &self.phase_tables[2]),
            b_s0: as_config(self.b_s0, &self.phase_tables[3]),
            h_c: self.h_c,
            b_c0: self.b_c0,
            porosity_k: self.porosity_k,
        }
    }

    /// The configured w (w at 550 nm when spectral).
    pub fn albedo(&self) -> f64 {
        self.w
    }

    /// Whether any parameter (w, b, c, h_S, B_S0) is a table in λ.
    pub fn is_spectral(&self) -> bool {
        self.spectral.is_some() || self.phase_tables.iter().any(Option::is_some)
    }

    /// Whether w is a w(λ) table.
    pub fn has_spectral_albedo(&self) -> bool {
        self.spectral.is_some()
    }

    /// The model with every tabulated parameter evaluated at `wavelength_m`
    /// (a model constant in λ, for one sub-band).
    pub fn at_wavelength(&self, wavelength_m: f64) -> Hapke {
        let value =
            |v: f64, t: &Option<SpectralAlbedo>| t.as_ref().map_or(v, |t| t.at(wavelength_m));
        let w = self.albedo_at(wavelength_m);
        Hapke {
            w,
            spectral: None,
            phase_tables: Default::default(),
            b: value(self.b, &self.phase_tables[0]),
            c: value(self.c, &self.phase_tables[1]),
            h_s: value(self.h_s, &self.phase_tables[2]),
            b_s0: value(self.b_s0, &self.phase_tables[3]),
            r0: r0_of(w),
            ..self.clone()
        }
    }

    /// w(λ), or the constant w.
    pub fn albedo_at(&self, wavelength_m: f64) -> f64 {
        match &self.spectral {
            Some(s) => s.at(wavelength_m),
            None => self.w,
        }
    }

    /// Double Henyey–Greenstein p(g), Hapke's convention (c > 0: backscatter).
    #[inline]
    pub fn phase_function(&self, cos_g: f64) -> f64 {
        self.shape().phase_function(cos_g)
    }

    /// B_SH(g) = 1 + B_S0/(1 + tan(g/2)/h_S), from tan(g/2).
    #[inline]
    pub fn shoe(&self, tan_half_g: f64) -> f64 {
        self.shape().shoe(tan_half_g)
    }

    /// The model's own (b, c, h_S, B_S0, θ̄).
    #[inline]
    pub fn shape(&self) -> HapkeShape {
        HapkeShape {
            b: self.b,
            c: self.c,
            h_s: self.h_s,
            b_s0: self.b_s0,
            theta_bar: self.theta_bar,
        }
    }

    /// B_CB(g) = 1 + B_C0 [1 + (1 − e^{−x})/x]/(2(1+x)²), x = tan(g/2)/h_C;
    /// 1 without CBOE. (1 − e^{−x})/x is computed with `expm1` (→ 1 as x → 0).
    #[inline]
    pub fn cboe(&self, tan_half_g: f64) -> f64 {
        let Some(h_c) = self.h_c else {
            return 1.0;
        };
        if self.b_c0 == 0.0 {
            return 1.0;
        }
        let x = tan_half_g / h_c;
        let ratio = if x > 0.0 { -(-x).exp_m1() / x } else { 1.0 };
        let one_px = 1.0 + x;
        1.0 + self.b_c0 * (1.0 + ratio) / (2.0 * one_px * one_px)
    }

    /// Hapke (1984) macroscopic roughness: returns (μ0e, μe, S) for
    /// μ0 = cos i, μ = cos e ∈ (0, 1] and `cos_psi` = cos ψ. θ̄ = 0 gives
    /// (μ0, μ, 1).
    pub fn shadowing(&self, mu0: f64, mu: f64, cos_psi: f64) -> (f64, f64, f64) {
        shadowing(self.roughness.as_ref(), mu0, mu, cos_psi)
    }
}

/// [`Hapke::shadowing`] with the roughness constants `rg` (None: θ̄ = 0).
fn shadowing(rg: Option<&Roughness>, mu0: f64, mu: f64, cos_psi: f64) -> (f64, f64, f64) {
    let Some(rg) = rg else {
        return (mu0, mu, 1.0);
    };
    let (t, chi) = (rg.tan_tb, rg.chi);
    let (sin_i, sin_e) = (sin_from_cos(mu0), sin_from_cos(mu));
    // cot x = cos x / sin x (+∞ at x = 0 since cos x > 0); E → 0 there.
    let (cot_i, cot_e) = (mu0 / sin_i, mu / sin_e);
    let e1 = |cot: f64| (-rg.k1 * cot).exp();
    let e2 = |cot: f64| (-rg.k2 * cot * cot).exp();
    let (e1i, e2i, e1e, e2e) = (e1(cot_i), e2(cot_i), e1(cot_e), e2(cot_e));
    let eta = |m: f64, s: f64, e1x: f64, e2x: f64| chi * (m + s * t * e2x / (2.0 - e1x));
    let (eta_i, eta_e) = (eta(mu0, sin_i, e1i, e2i), eta(mu, sin_e, e1e, e2e));
    let cos_psi = cos_psi.clamp(-1.0, 1.0);
    let psi = cos_psi.acos();
    let psi_pi = psi / PI;
    let s2 = 0.5 * (1.0 - cos_psi); // sin²(ψ/2)
    let f = (-2.0 * (0.5 * psi).tan()).exp(); // 0 at ψ = π
    let i_le_e = mu0 >= mu;
    let (num0, nume, den, a) = if i_le_e {
        (
            cos_psi * e2e + s2 * e2i,
            e2e - s2 * e2i,
            2.0 - e1e - psi_pi * e1i,
            mu0 / eta_i,
        )
    } else {
        (
            e2i - s2 * e2e,
            cos_psi * e2i + s2 * e2e,
            2.0 - e1i - psi_pi * e1e,
            mu / eta_e,
        )
    };
    // den ≥ 0; it vanishes only at the terminator–limb corner with ψ = π.
    let den = den.max(f64::MIN_POSITIVE);
    let clamp_mu = |m: f64| {
        if m.is_nan() {
            0.0
        } else {
            m.clamp(0.0, MU_EFF_MAX)
        }
    };
    let mu0e = clamp_mu(chi * (mu0 + sin_i * t * (num0 / den)));
    let mue = clamp_mu(chi * (mu + sin_e * t * (nume / den)));
    // S = (μe/η(e)) (μ0/η(i)) χ / (1 − f + f χ a), a = μ0/η(i) (i ≤ e)
    // or μ/η(e) (i > e). The denominator vanishes only for f = 1 (ψ = 0)
    // and a underflowing to 0: the limit is μe/η(e) for i ≤ e, and 0
    // (μ0 < μ → 0) for i > e.
    let den_s = (1.0 - f) + f * chi * a;
    let s = if den_s > 0.0 {
        (mue / eta_e) * (mu0 / eta_i) * chi / den_s
    } else if i_le_e {
        mue / eta_e
    } else {
        0.0
    };
    (mu0e, mue, s)
}

impl Hapke {
    /// r = f_r μ0 with single-scattering albedo `w` ∈ [0, 1].
    /// Precondition: μ0, μ ∈ (0, 1], cos g ∈ [−1, 1].
    #[inline]
    pub fn radiance_factor(&self, g: &ScatteringGeometry, w: f64) -> f64 {
        self.radiance_factor_shaped(g, w, self.shape())
    }

    /// [`radiance_factor`](Self::radiance_factor) with the phase function,
    /// the shadow-hiding opposition effect and the roughness of `shape` (a
    /// parameter map sets them per point).
    #[inline]
    pub fn radiance_factor_shaped(&self, g: &ScatteringGeometry, w: f64, shape: HapkeShape) -> f64 {
        let r0 = if w == self.w { self.r0 } else { r0_of(w) };
        // The model's own constants unless a map sets θ̄ here.
        let mapped;
        let rg = if shape.theta_bar == self.theta_bar {
            self.roughness.as_ref()
        } else {
            mapped = Roughness::of(shape.theta_bar);
            mapped.as_ref()
        };
        let (mu0e, mue, s) = shadowing(rg, g.mu0, g.mu, g.cos_azimuth());
        let sum = mu0e + mue;
        if sum.is_nan() || sum <= 0.0 || s <= 0.0 {
            return 0.0;
        }
        let k = self.porosity_k;
        let m = h_with_r0(mu0e / k, w, r0) * h_with_r0(mue / k, w, r0) - 1.0;
        let tg = tan_half_from_cos(g.cos_g);
        let single = shape.phase_function(g.cos_g) * shape.shoe(tg);
        k * w / (4.0 * PI) * (mu0e / sum) * (single + m) * self.cboe(tg) * s
    }
}

#[cfg(test)]
mod tests {
    use super::super::Reflectance;
    use super::*;

    fn config(w: f64, theta_bar: f64, b: f64, c: f64, h_s: f64, b_s0: f64) -> ReflectanceConfig {
        ReflectanceConfig::Hapke {
            w: HapkeAlbedo::Constant(w),
            b: HapkeAlbedo::Constant(b),
            c: HapkeAlbedo::Constant(c),
            theta_bar,
            h_s: HapkeAlbedo::Constant(h_s),
            b_s0: HapkeAlbedo::Constant(b_s0),
            h_c: None,
            b_c0: 0.0,
            porosity_k: 1.0,
        }
    }

    fn reference_model() -> Reflectance {
        config(0.526, 13.3f64.to_radians(), 0.187, 0.273, 0.083, 1.0)
            .build()
            .unwrap()
    }

    fn pi_fr(m: &Reflectance, i_deg: f64, e_deg: f64, psi_deg: f64) -> f64 {
        let g = ScatteringGeometry::from_angles(
            i_deg.to_radians(),
            e_deg.to_radians(),
            psi_deg.to_radians(),
        );
        PI * m.brdf(&g, m.albedo())
    }

    /// Published reference values (w = 0.526, θ̄ = 13.3°, b = 0.187,
    /// c = 0.273 in Hapke's convention, h = 0.083, B_S0 = 1, no CBOE, K = 1,
    /// Hapke 2002 H) at i = 30°.
    #[test]
    fn reference_values() {
        let m = reference_model();
        for (e, psi, expected) in [
            (30.0, 0.0, 0.247466),
            (80.0, 0.0, 0.195553),
            (89.0, 180.0, 0.154264),
        ] {
            let v = pi_fr(&m, 30.0, e, psi);
            assert!(
                (v - expected).abs() < 1e-5,
                "e={e} ψ={psi}: {v} vs {expected}"
            );
        }
    }

    #[test]
    fn c_convention_is_hapkes() {
        // With the opposite convention (c weighting the forward lobe) the
        // reference values are missed by far.
        let m = config(0.526, 13.3f64.to_radians(), 0.187, -0.273, 0.083, 1.0)
            .build()
            .unwrap();
        assert!((pi_fr(&m, 30.0, 30.0, 0.0) - 0.247466).abs() > 0.01);
        // And for b > 0, c > 0 the phase function is larger at g = 0 than at g = π.
        let Reflectance::Hapke(h) = reference_model() else {
            unreachable!()
        };
        assert!(h.phase_function(1.0) > h.phase_function(-1.0));
    }

    #[test]
    fn phase_function_is_normalised() {
        // (1/4π) ∫ p dΩ = (1/2) ∫_{-1}^{1} p(cos g) d cos g = 1.
        let Reflectance::Hapke(h) = config(0.5, 0.0, 0.6, -0.4, 0.1, 0.0).build().unwrap() else {
            unreachable!()
        };
        let n = 200_000;
        let s: f64 = (0..n)
            .map(|k| h.phase_function(-1.0 + 2.0 * (k as f64 + 0.5) / n as f64))
            .sum::<f64>()
            * 2.0
            / n as f64;
        assert!((0.5 * s - 1.0).abs() < 1e-6, "{s}");
    }

    #[test]
    fn h_function_values() {
        assert_eq!(h_function(0.0, 0.5), 1.0);
        assert_eq!(h_function(0.0, 1.0), 1.0);
        // x → 0 is continuous, including subnormal x.
        for x in [1e-12, 1e-300, 5e-324] {
            assert!((h_function(x, 0.9) - 1.0).abs() < 1e-9, "{x}");
        }
        // Conservative scattering, Hapke (2002) approximation vs
        // Chandrasekhar's exact H(1) = 2.9078 (within the ~1% of the approximation).
        assert!((h_function(1.0, 1.0) - 2.9078).abs() < 0.03 * 2.9078);
        // w = 0: no multiple scattering.
        assert_eq!(h_function(0.7, 0.0), 1.0);
        // Direct formula at a moderate x.
        let (x, w) = (0.6f64, 0.8f64);
        let r0 = (1.0 - (1.0 - w).sqrt()) / (1.0 + (1.0 - w).sqrt());
        let direct = 1.0 / (1.0 - w * x * (r0 + (1.0 - 2.0 * r0 * x) / 2.0 * ((1.0 + x) / x).ln()));
        assert!((h_function(x, w) - direct).abs() < 1e-14);
        // The large-x branch joins the small-x branch continuously.
        let lo = h_function(10.0, 0.9);
        let hi = h_function(10.0 * (1.0 + 1e-15), 0.9);
        assert!((lo - hi).abs() < 1e-12, "{lo} {hi}");
        // Large x: finite, approaches 1/(1 − w(1+r0)/2).
        let w = 0.9f64;
        let r0 = (1.0 - (1.0 - w).sqrt()) / (1.0 + (1.0 - w).sqrt());
        assert!((h_function(1e300, w) - 1.0 / (1.0 - w * (1.0 + r0) / 2.0)).abs() < 1e-12);
    }

    #[test]
    fn smooth_surface_reduces_to_imsa() {
        // θ̄ = 0: S = 1, μ0e = μ0, μe = μ; compare with the formula written out.
        let (w, b, c, h, b0) = (0.6, 0.3, 0.4, 0.05, 0.8);
        let m = config(w, 0.0, b, c, h, b0).build().unwrap();
        let Reflectance::Hapke(hp) = &m else {
            unreachable!()
        };
        assert_eq!(hp.shadowing(0.3, 0.8, -0.2), (0.3, 0.8, 1.0));
        for (i, e, psi) in [(0.3f64, 0.9f64, 0.2f64), (1.2, 0.4, 2.5), (0.0, 1.5, 0.0)] {
            let geo = ScatteringGeometry::from_angles(i, e, psi);
            let (mu0, mu) = (i.cos(), e.cos());
            let g = geo.phase();
            let p = (1.0 + c) / 2.0 * (1.0 - b * b) / (1.0 - 2.0 * b * g.cos() + b * b).powf(1.5)
                + (1.0 - c) / 2.0 * (1.0 - b * b) / (1.0 + 2.0 * b * g.cos() + b * b).powf(1.5);
            let bsh = 1.0 + b0 / (1.0 + (g / 2.0).tan() / h);
            let hf = |x: f64| {
                let r0 = (1.0 - (1.0 - w).sqrt()) / (1.0 + (1.0 - w).sqrt());
                1.0 / (1.0 - w * x * (r0 + (1.0 - 2.0 * r0 * x) / 2.0 * ((1.0 + x) / x).ln()))
            };
            let r = w / (4.0 * PI) * mu0 / (mu0 + mu) * (p * bsh + hf(mu0) * hf(mu) - 1.0);
            let v = m.radiance_factor(&geo, w);
            assert!((v - r).abs() < 1e-13, "{i} {e} {psi}: {v} vs {r}");
        }
        // Tiny θ̄ is continuous with θ̄ = 0.
        let m2 = config(w, 1e-9, b, c, h, b0).build().unwrap();
        for (i, e, psi) in [(0.3f64, 0.9f64, 0.2f64), (1.2, 0.4, 2.5), (1.5, 1.5, 3.1)] {
            let geo = ScatteringGeometry::from_angles(i, e, psi);
            let (a, bb) = (m.radiance_factor(&geo, w), m2.radiance_factor(&geo, w));
            assert!((a - bb).abs() < 1e-7 * a, "{i} {e} {psi}: {a} vs {bb}");
        }
    }

    #[test]
    fn roughness_branches_meet_at_i_equals_e() {
        // The i ≤ e and i > e branches agree as e → i.
        let Reflectance::Hapke(h) = reference_model() else {
            unreachable!()
        };
        for &mu in &[0.9, 0.5, 0.1] {
            for &cp in &[1.0, 0.3, -0.5, -1.0] {
                let a = h.shadowing(mu, mu, cp);
                let b = h.shadowing(mu, mu * (1.0 - 1e-12), cp);
                let c = h.shadowing(mu * (1.0 - 1e-12), mu, cp);
                for (x, y) in [(a, b), (a, c)] {
                    assert!(
                        (x.0 - y.0).abs() < 1e-9
                            && (x.1 - y.1).abs() < 1e-9
                            && (x.2 - y.2).abs() < 1e-9
                    );
                }
            }
        }
    }

    #[test]
    fn shadowing_limits() {
        let Reflectance::Hapke(h) = reference_model() else {
            unreachable!()
        };
        // Normal incidence and emission: η(0) = χ, f(0) = 1, so μ0e = μe = χ
        // and S = (χ/χ)(1/χ) χ / (χ/χ) = 1.
        let (m0, me, s) = h.shadowing(1.0, 1.0, 1.0);
        let chi = 1.0 / (1.0 + PI * (13.3f64.to_radians().tan()).powi(2)).sqrt();
        assert!((m0 - chi).abs() < 1e-15 && (me - chi).abs() < 1e-15 && (s - 1.0).abs() < 1e-15);
        // Effective cosines finite and non-negative, S ∈ [0, ~1] everywhere.
        // Hapke's (1984) S is not bounded by 1 exactly: e.g. at μ0 = 0.7,
        // μ = 0.001, ψ = π it is 1.0713, and over a 1° grid its maximum is
        // 1.085 for θ̄ = 13.3° (1.096 for θ̄ = 60°), per an independent
        // transcription of the formulas; so allow up to 1.1.
        for &mu0 in &[1.0, 0.7, 0.2, 1e-3, 1e-9, 1e-300] {
            for &mu in &[1.0, 0.7, 0.2, 1e-3, 1e-9, 1e-300] {
                for &cp in &[1.0, 0.5, 0.0, -0.5, -1.0] {
                    let (a, b, s) = h.shadowing(mu0, mu, cp);
                    assert!(
                        a.is_finite() && b.is_finite() && s.is_finite(),
                        "{mu0} {mu} {cp}"
                    );
                    assert!(
                        a >= 0.0 && b >= 0.0 && (0.0..=1.1).contains(&s),
                        "{mu0} {mu} {cp}: {s}"
                    );
                }
            }
        }
    }

    #[test]
    fn terminator_limb_corner() {
        // μ0 + μ → 0 for every azimuth: finite and bounded. (At ψ = 0, i.e.
        // g → 0, a rough surface keeps a finite radiance factor at the corner:
        // S → μe/η(e), μ0e ≠ 0; away from opposition r → 0.)
        let m = reference_model();
        for &t in &[1e-3, 1e-6, 1e-12, 1e-300, 5e-324] {
            for &cp in &[1.0, 0.5, -0.5, -1.0] {
                let si = sin_from_cos(t);
                let g = ScatteringGeometry {
                    mu0: t,
                    mu: t,
                    cos_g: t * t + si * si * cp,
                };
                let r = m.radiance_factor(&g, m.albedo());
                assert!((0.0..0.2).contains(&r), "{t} {cp}: {r}");
                if cp < 0.0 {
                    assert!(r < 1e-2, "{t} {cp}: {r}");
                }
            }
        }
        // Approaching the corner, r decreases.
        let r = |t: f64| {
            m.radiance_factor(
                &ScatteringGeometry::from_angles(t.acos(), t.acos(), PI),
                m.albedo(),
            )
        };
        assert!(r(1e-6) < r(1e-3) && r(1e-3) < r(1e-1));
    }

    #[test]
    fn grazing_angles() {
        // tan → ∞ as i or e → 90°: finite and continuous.
        let m = reference_model();
        for psi in [0.0, 1.0, PI] {
            for (i, e) in [
                (PI / 2.0, 0.3),
                (0.3, PI / 2.0),
                (PI / 2.0 - 1e-12, 0.0),
                (0.0, PI / 2.0 - 1e-12),
            ] {
                let g = ScatteringGeometry::from_angles(i, e, psi);
                let r = m.radiance_factor(&g, m.albedo());
                assert!(r.is_finite() && r >= 0.0, "{i} {e} {psi}: {r}");
            }
            let a = m.radiance_factor(
                &ScatteringGeometry::from_angles(0.3, PI / 2.0 - 1e-6, psi),
                0.526,
            );
            let b = m.radiance_factor(
                &ScatteringGeometry::from_angles(0.3, PI / 2.0 - 2e-6, psi),
                0.526,
            );
            assert!((a - b).abs() < 1e-4 * a.max(1e-6), "{psi}: {a} {b}");
        }
    }

    #[test]
    fn undefined_azimuth() {
        // At i = 0 or e = 0 ψ is undefined; every ψ gives the same value and
        // it is continuous with i → 0.
        let m = reference_model();
        let at = |i: f64, e: f64, psi: f64| {
            m.radiance_factor(&ScatteringGeometry::from_angles(i, e, psi), 0.526)
        };
        for psi in [0.0, 1.0, PI] {
            assert_eq!(at(0.0, 0.6, psi), at(0.0, 0.6, 0.0));
            assert_eq!(at(0.6, 0.0, psi), at(0.6, 0.0, 0.0));
            assert!((at(1e-9, 0.6, psi) - at(0.0, 0.6, 0.0)).abs() < 1e-7);
            assert!((at(0.6, 1e-9, psi) - at(0.6, 0.0, 0.0)).abs() < 1e-7);
        }
        // Azimuth undefined on both sides (i = e = 0).
        assert!(at(0.0, 0.0, 0.0).is_finite());
        // At i = 0 the roughness terms do not depend on ψ (direct check).
        let Reflectance::Hapke(h) = &m else {
            unreachable!()
        };
        assert_eq!(h.shadowing(1.0, 0.5, 1.0), h.shadowing(1.0, 0.5, -1.0));
        assert_eq!(h.shadowing(0.5, 1.0, 1.0), h.shadowing(0.5, 1.0, -1.0));
    }

    #[test]
    fn opposition_effects() {
        // B_SH → 1 + B_S0 as g → 0 for any h > 0; finite at g = 0 with tiny h.
        for h_s in [0.5, 0.083, 1e-6, 1e-300] {
            let Reflectance::Hapke(hp) = config(0.5, 0.2, 0.2, 0.3, h_s, 1.5).build().unwrap()
            else {
                unreachable!()
            };
            assert_eq!(hp.shoe(0.0), 2.5);
            let near = hp.shoe(1e-9 * h_s);
            assert!((near - 2.5).abs() < 2e-9 && near < 2.5, "{h_s}: {near}");
            assert!(hp.shoe(tan_half_from_cos(-1.0)).is_finite());
            let g = ScatteringGeometry::from_angles(0.4, 0.4, 0.0);
            assert!(hp.radiance_factor(&g, 0.5).is_finite());
        }
        // B_CB: x → 0 gives 1 + B_C0 (expm1 branch), continuous; → 1 far away.
        let mut cfg = config(0.5, 0.2, 0.2, 0.3, 0.1, 1.0);
        if let ReflectanceConfig::Hapke { h_c, b_c0, .. } = &mut cfg {
            *h_c = Some(0.02);
            *b_c0 = 0.7;
        }
        let Reflectance::Hapke(hp) = cfg.build().unwrap() else {
            unreachable!()
        };
        assert_eq!(hp.cboe(0.0), 1.7);
        for t in [1e-20, 1e-12, 1e-8] {
            assert!((hp.cboe(t) - 1.7).abs() < 1e-5, "{t}");
        }
        // Direct formula at a moderate x.
        let x: f64 = 0.3;
        let direct = 1.0 + 0.7 * (1.0 + (1.0 - (-x).exp()) / x) / (2.0 * (1.0 + x).powi(2));
        assert!((hp.cboe(0.3 * 0.02) - direct).abs() < 1e-14);
        assert!((hp.cboe(tan_half_from_cos(-1.0)) - 1.0).abs() < 1e-12);
        // No CBOE by default.
        let Reflectance::Hapke(hp) = reference_model() else {
            unreachable!()
        };
        assert_eq!(hp.cboe(0.0), 1.0);
    }

    #[test]
    fn porosity_factor() {
        // K multiplies the result and divides the H arguments.
        let mut cfg = config(0.6, 0.0, 0.2, 0.3, 0.1, 1.0);
        if let ReflectanceConfig::Hapke { porosity_k, .. } = &mut cfg {
            *porosity_k = 1.7;
        }
        let m = cfg.build().unwrap();
        let Reflectance::Hapke(hp) = &m else {
            unreachable!()
        };
        let geo = ScatteringGeometry::from_angles(0.5, 0.9, 1.0);
        let (mu0, mu) = (geo.mu0, geo.mu);
        let tg = tan_half_from_cos(geo.cos_g);
        let expected = 1.7 * 0.6 / (4.0 * PI) * mu0 / (mu0 + mu)
            * (hp.phase_function(geo.cos_g) * hp.shoe(tg)
                + h_function(mu0 / 1.7, 0.6) * h_function(mu / 1.7, 0.6)
                - 1.0);
        assert!((m.radiance_factor(&geo, 0.6) - expected).abs() < 1e-15);
    }

    #[test]
    fn params_round_trip() {
        let cfg = config(0.526, 0.2, 0.187, 0.273, 0.083, 1.0);
        let Reflectance::Hapke(h) = cfg.build().unwrap() else {
            unreachable!()
        };
        assert_eq!(h.params(), cfg);
    }

    #[test]
    fn spectral_albedo_interpolation() {
        let s = SpectralAlbedo {
            wavelength_m: vec![400e-9, 500e-9, 800e-9],
            w: vec![0.2, 0.4, 0.7],
        };
        assert_eq!(s.at(300e-9), 0.2);
        assert_eq!(s.at(900e-9), 0.7);
        assert!((s.at(450e-9) - 0.3).abs() < 1e-12);
        assert!((s.at(500e-9) - 0.4).abs() < 1e-12);
        assert!((s.at(650e-9) - 0.55).abs() < 1e-12);
        let one = SpectralAlbedo {
            wavelength_m: vec![500e-9],
            w: vec![0.3],
        };
        assert_eq!(one.at(1e-6), 0.3);
    }

    #[test]
    fn per_point_albedo_is_used() {
        // The `albedo` argument is w at this point (albedo map), not the configured w.
        let m = reference_model();
        let g = ScatteringGeometry::from_angles(0.5, 0.3, 0.4);
        assert!(m.radiance_factor(&g, 0.8) > m.radiance_factor(&g, 0.526));
        let m8 = config(0.8, 13.3f64.to_radians(), 0.187, 0.273, 0.083, 1.0)
            .build()
            .unwrap();
        assert_eq!(m.radiance_factor(&g, 0.8), m8.radiance_factor(&g, 0.8));
    }
}
