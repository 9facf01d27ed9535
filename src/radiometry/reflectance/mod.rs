//! Reflection models (BRDFs) named in scene files.
//!
//! This module owns the scene-file description of a surface's reflectance
//! ([`ReflectanceConfig`], the `[body.reflectance]` table), its validation, and
//! the built, evaluation-ready model ([`Reflectance`]) used in the render's hot
//! loop. One file per model:
//!
//! | `model =` | type | primary albedo (`albedo` argument) | f_r |
//! |---|---|---|---|
//! | `area` | [`Area`] | ρ | ρ/(2π) sec i |
//! | `lambert` | [`Lambert`] | ρ (hemispherical = Bond albedo) | ρ/π |
//! | `lommel_seeliger` | [`LommelSeeliger`] | p (geometric albedo) | (2p/π)/(μ0+μ) |
//! | `oren_nayar` | [`OrenNayar`] | ρ | full Oren & Nayar (1994) |
//! | `oren_nayar_qualitative` | [`OrenNayarQualitative`] | ρ | qualitative Oren & Nayar (1994) |
//! | `lunar_lambert` | [`LunarLambert`] | A | McEwen's lunar–Lambert |
//! | `minnaert` | [`Minnaert`] | ρ | (ρ/π)(μ0 μ)^(k−1) |
//! | `hapke` | [`Hapke`] | w (single-scattering albedo) | Hapke (1984/2002/2012) |
//!
//! All models are evaluated through [`Reflectance::radiance_factor`], which
//! returns r = f_r μ0 = L/F (radiance per unit solar irradiance on a surface
//! normal to the Sun, 1/sr), guaranteed finite and ≥ 0 for every input.

mod area;
mod hapke;
mod lambert;
mod lommel_seeliger;
mod lunar_lambert;
mod minnaert;
mod oren_nayar;
mod parameter;

pub use area::Area;
pub use hapke::{
    h_function, Hapke, HapkeAlbedo, HapkeShape, SpectralAlbedo, REFERENCE_WAVELENGTH_M,
};
pub use lambert::Lambert;
pub use lommel_seeliger::LommelSeeliger;
pub use lunar_lambert::LunarLambert;
pub use minnaert::Minnaert;
pub use oren_nayar::{OrenNayar, OrenNayarQualitative};
pub use parameter::MappedParameter;

use crate::error::{Error, Result};
use crate::radiometry::geometry::ScatteringGeometry;
use serde::{Deserialize, Serialize};

/// Field path used in error messages by [`ReflectanceConfig::build`].
pub const DEFAULT_FIELD_PREFIX: &str = "body.reflectance";

/// Scene-file description of a reflection model, internally tagged by `model`:
///
/// ```toml
/// [body.reflectance]
/// model = "oren_nayar"
/// albedo = 0.15
/// roughness = 0.3
/// ```
///
/// Unknown keys inside a variant are rejected with an error naming the key;
/// missing required keys are rejected with an error naming the key. Value
/// ranges are checked by [`ReflectanceConfig::build`]. All angles in radians.
#[derive(Deserialize, Serialize, Clone, Debug, PartialEq)]
#[serde(tag = "model", rename_all = "snake_case", deny_unknown_fields)]
pub enum ReflectanceConfig {
    /// Area law, f_r = ρ/(2π) sec i; `albedo` = ρ, see [`Area`].
    Area {
        /// ρ ≥ 0.
        albedo: f64,
    },
    /// Lambert, f_r = ρ/π; `albedo` = ρ (hemispherical albedo), see [`Lambert`].
    Lambert {
        /// ρ ≥ 0.
        albedo: f64,
    },
    /// Lommel–Seeliger, f_r = (2p/π)/(μ0+μ); `albedo` = p (geometric
    /// albedo), see [`LommelSeeliger`].
    LommelSeeliger {
        /// p ≥ 0.
        albedo: f64,
    },
    /// Full Oren & Nayar (1994) model, see [`OrenNayar`].
    OrenNayar {
        /// ρ ≥ 0.
        albedo: f64,
        /// σ ≥ 0, the standard deviation of facet slopes (radians).
        roughness: f64,
    },
    /// Qualitative Oren & Nayar (1994) model, see [`OrenNayarQualitative`].
    OrenNayarQualitative {
        /// ρ ≥ 0.
        albedo: f64,
        /// σ ≥ 0 (radians).
        roughness: f64,
    },
    /// McEwen's lunar–Lambert model; `albedo` = A, see [`LunarLambert`].
    LunarLambert {
        /// A ≥ 0.
        albedo: f64,
    },
    /// Minnaert, f_r = (ρ/π)(μ0 μ)^(k−1), see [`Minnaert`].
    Minnaert {
        /// ρ ≥ 0.
        albedo: f64,
        /// Minnaert exponent k ≥ 0 (k = 1: Lambert).
        k: f64,
    },
    /// Hapke model, see [`Hapke`] for every parameter.
    Hapke {
        /// Single-scattering albedo w ∈ (0, 1]: a number, or a table
        /// `[[wavelength_nm, w], ...]` interpolated linearly in wavelength.
        w: HapkeAlbedo,
        /// Double Henyey–Greenstein asymmetry |b| < 1 (number or table in λ,
        /// like `w`).
        b: HapkeAlbedo,
        /// Double Henyey–Greenstein lobe weight c ∈ [−1, 1], Hapke's
        /// convention: c > 0 favours backscatter (number or table in λ).
        c: HapkeAlbedo,
        /// Mean slope angle θ̄ ∈ [0, π/2) of macroscopic roughness (radians).
        theta_bar: f64,
        /// Shadow-hiding opposition width h_S > 0 (number or table in λ).
        h_s: HapkeAlbedo,
        /// Shadow-hiding opposition amplitude B_S0 ≥ 0 (number or table in λ).
        b_s0: HapkeAlbedo,
        /// Coherent-backscatter width h_C > 0; absent: no CBOE.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        h_c: Option<f64>,
        /// Coherent-backscatter amplitude B_C0 ≥ 0 (default 0; > 0 needs h_c).
        #[serde(default)]
        b_c0: f64,
        /// Porosity factor K ≥ 1 (default 1).
        #[serde(default = "one")]
        porosity_k: f64,
    },
}

fn one() -> f64 {
    1.0
}

/// Checks that `value` is finite and ≥ 0.
pub(crate) fn check_nonneg(prefix: &str, name: &str, value: f64) -> Result<f64> {
    if value.is_finite() && value >= 0.0 {
        Ok(value)
    } else {
        Err(Error::invalid(
            format!("{prefix}.{name}"),
            format!("must be finite and >= 0, got {value}"),
        ))
    }
}

impl ReflectanceConfig {
    /// Validates the parameters and builds the model; errors name the field
    /// as `body.reflectance.<key>`.
    pub fn build(&self) -> Result<Reflectance> {
        self.build_at(DEFAULT_FIELD_PREFIX)
    }

    /// As [`build`](Self::build), naming fields `<prefix>.<key>` in errors.
    pub fn build_at(&self, prefix: &str) -> Result<Reflectance> {
        let albedo = |a: f64| check_nonneg(prefix, "albedo", a);
        let roughness = |s: f64| check_nonneg(prefix, "roughness", s);
        Ok(match *self {
            ReflectanceConfig::Area { albedo: a } => Reflectance::Area(Area::new(albedo(a)?)),
            ReflectanceConfig::Lambert { albedo: a } => {
                Reflectance::Lambert(Lambert::new(albedo(a)?))
            }
            ReflectanceConfig::LommelSeeliger { albedo: a } => {
                Reflectance::LommelSeeliger(LommelSeeliger::new(albedo(a)?))
            }
            ReflectanceConfig::OrenNayar {
                albedo: a,
                roughness: s,
            } => Reflectance::OrenNayar(OrenNayar::new(albedo(a)?, roughness(s)?)),
            ReflectanceConfig::OrenNayarQualitative {
                albedo: a,
                roughness: s,
            } => Reflectance::OrenNayarQualitative(OrenNayarQualitative::new(
                albedo(a)?,
                roughness(s)?,
            )),
            ReflectanceConfig::LunarLambert { albedo: a } => {
                Reflectance::LunarLambert(LunarLambert::new(albedo(a)?))
            }
            ReflectanceConfig::Minnaert { albedo: a, k } => {
                Reflectance::Minnaert(Minnaert::new(albedo(a)?, check_nonneg(prefix, "k", k)?))
            }
            ReflectanceConfig::Hapke { .. } => {
                Reflectance::Hapke(Hapke::from_config(self, prefix)?)
            }
        })
    }
}

/// A built reflection model with its constants precomputed.
///
/// Enum dispatch (no trait objects): this is evaluated once per surface cap
/// and per frame in the render's hot loop.
#[derive(Clone, Debug)]
pub enum Reflectance {
    /// See [`Area`].
    Area(Area),
    /// See [`Lambert`].
    Lambert(Lambert),
    /// See [`LommelSeeliger`].
    LommelSeeliger(LommelSeeliger),
    /// See [`OrenNayar`].
    OrenNayar(OrenNayar),
    /// See [`OrenNayarQualitative`].
    OrenNayarQualitative(OrenNayarQualitative),
    /// See [`LunarLambert`].
    LunarLambert(LunarLambert),
    /// See [`Minnaert`].
    Minnaert(Minnaert),
    /// See [`Hapke`].
    Hapke(Hapke),
}

/// Geometry restricted to the lit-and-visible domain: `None` unless
/// μ0 > 0 and μ > 0; μ0, μ clamped to ≤ 1 and cos g to [−1, 1].
#[inline]
fn lit_and_visible(g: &ScatteringGeometry) -> Option<ScatteringGeometry> {
    if g.mu0 > 0.0 && g.mu > 0.0 && !g.cos_g.is_nan() {
        Some(ScatteringGeometry {
            mu0: g.mu0.min(1.0),
            mu: g.mu.min(1.0),
            cos_g: g.cos_g.clamp(-1.0, 1.0),
        })
    } else {
        None
    }
}

/// `x` if finite and > 0, else 0.
#[inline]
pub(crate) fn finite_nonneg(x: f64) -> f64 {
    if x.is_finite() && x > 0.0 {
        x
    } else {
        0.0
    }
}

impl Reflectance {
    /// Radiance factor r = f_r μ0 = L/F [1/sr]: the radiance scattered toward
    /// the camera per unit solar irradiance on a surface normal to the Sun
    /// (I/F = π r).
    ///
    /// `albedo` is the model's primary albedo at this point, so that an albedo
    /// map can vary it per point: ρ for `area`, `lambert`, `oren_nayar*`,
    /// `minnaert`; p (geometric albedo) for `lommel_seeliger`; A for
    /// `lunar_lambert`; w for `hapke` (clamped to [0, 1]). A negative or NaN
    /// albedo counts as 0.
    ///
    /// Always finite and ≥ 0; exactly 0 when μ0 ≤ 0 or μ ≤ 0 (or NaN). μ0, μ
    /// are clamped to ≤ 1 and cos g to [−1, 1]. A non-finite result (only
    /// possible with an infinite albedo) is returned as 0.
    #[inline]
    pub fn radiance_factor(&self, g: &ScatteringGeometry, albedo: f64) -> f64 {
        self.radiance_factor_by(g, albedo, |g, a| match self {
            Reflectance::Area(m) => m.radiance_factor(g, a),
            Reflectance::Lambert(m) => m.radiance_factor(g, a),
            Reflectance::LommelSeeliger(m) => m.radiance_factor(g, a),
            Reflectance::OrenNayar(m) => m.radiance_factor(g, a),
            Reflectance::OrenNayarQualitative(m) => m.radiance_factor(g, a),
            Reflectance::LunarLambert(m) => m.radiance_factor(g, a),
            Reflectance::Minnaert(m) => m.radiance_factor(g, a),
            Reflectance::Hapke(m) => m.radiance_factor(g, a.min(1.0)),
        })
    }

    /// The domain and albedo contract of [`radiance_factor`](Self::radiance_factor)
    /// around `model(g, albedo)`.
    #[inline(always)]
    fn radiance_factor_by(
        &self,
        g: &ScatteringGeometry,
        albedo: f64,
        model: impl Fn(&ScatteringGeometry, f64) -> f64,
    ) -> f64 {
        let Some(g) = lit_and_visible(g) else {
            return 0.0;
        };
        let a = if albedo > 0.0 { albedo } else { 0.0 };
        finite_nonneg(model(&g, a))
    }

    /// Bidirectional reflectance f_r = r/μ0 [1/sr]; 0 where
    /// [`radiance_factor`](Self::radiance_factor) is 0 by domain (μ0 ≤ 0 or
    /// μ ≤ 0). Never NaN or negative. It may be +∞ only where f_r is
    /// mathematically infinite, i.e. as μ0 → 0⁺ with r ↛ 0: `area` (sec i),
    /// `lommel_seeliger` and `minnaert` with k < 1 as μ0 + μ → 0, rough
    /// `hapke` at grazing incidence near opposition. The overflow happens only
    /// for μ0 near the smallest normal f64 (~1e-308).
    #[inline]
    pub fn brdf(&self, g: &ScatteringGeometry, albedo: f64) -> f64 {
        let r = self.radiance_factor(g, albedo);
        if r > 0.0 {
            r / g.mu0.min(1.0)
        } else {
            0.0
        }
    }

    /// The configured primary albedo (see [`radiance_factor`](Self::radiance_factor));
    /// for spectral Hapke, w at [`REFERENCE_WAVELENGTH_M`] (550 nm).
    pub fn albedo(&self) -> f64 {
        match self {
            Reflectance::Area(m) => m.albedo,
            Reflectance::Lambert(m) => m.albedo,
            Reflectance::LommelSeeliger(m) => m.albedo,
            Reflectance::OrenNayar(m) => m.albedo,
            Reflectance::OrenNayarQualitative(m) => m.albedo,
            Reflectance::LunarLambert(m) => m.albedo,
            Reflectance::Minnaert(m) => m.albedo,
            Reflectance::Hapke(m) => m.albedo(),
        }
    }

    /// The model at one wavelength: a Hapke model with tables in λ
    /// evaluated there (constant in λ); every other model as is.
    pub fn at_wavelength(&self, wavelength_m: f64) -> Reflectance {
        match self {
            Reflectance::Hapke(m) => Reflectance::Hapke(m.at_wavelength(wavelength_m)),
            other => other.clone(),
        }
    }

    /// Whether the albedo parameter itself is a table in λ (Hapke `w(λ)`):
    /// with an albedo map, the map is then a relative pattern multiplied by
    /// the table.
    pub fn has_spectral_albedo(&self) -> bool {
        matches!(self, Reflectance::Hapke(m) if m.has_spectral_albedo())
    }

    /// False only for a Hapke model with a parameter tabulated in λ: then
    /// the radiance factor, and so PF_i, differ between wavelengths.
    pub fn is_spectrally_flat(&self) -> bool {
        match self {
            Reflectance::Hapke(m) => !m.is_spectral(),
            _ => true,
        }
    }

    /// The primary albedo at `wavelength_m` (metres): w(λ) for spectral
    /// Hapke, [`albedo`](Self::albedo) otherwise.
    pub fn albedo_at(&self, wavelength_m: f64) -> f64 {
        match self {
            Reflectance::Hapke(m) => m.albedo_at(wavelength_m),
            _ => self.albedo(),
        }
    }

    /// Whether the radiance factor is a ρ + b ρ² in the albedo parameter
    /// at fixed geometry (all models but Hapke, whose H-functions are not).
    pub fn is_albedo_quadratic(&self) -> bool {
        !matches!(self, Reflectance::Hapke(_))
    }

    /// The scene-file name of the model (`model = "..."`).
    pub fn name(&self) -> &'static str {
        match self {
            Reflectance::Area(_) => "area",
            Reflectance::Lambert(_) => "lambert",
            Reflectance::LommelSeeliger(_) => "lommel_seeliger",
            Reflectance::OrenNayar(_) => "oren_nayar",
            Reflectance::OrenNayarQualitative(_) => "oren_nayar_qualitative",
            Reflectance::LunarLambert(_) => "lunar_lambert",
            Reflectance::Minnaert(_) => "minnaert",
            Reflectance::Hapke(_) => "hapke",
        }
    }
}

/// Numerical helpers shared by the model tests.
#[cfg(test)]
pub(crate) mod test_util {
    use super::*;
    use glam::DVec3;
    use std::f64::consts::PI;

    /// Gauss–Legendre nodes and weights on [−1, 1] (Newton on P_n).
    pub fn gauss_legendre(n: usize) -> Vec<(f64, f64)> {
        let mut out = Vec::with_capacity(n);
        for k in 0..n {
            let mut x = (PI * (k as f64 + 0.75) / (n as f64 + 0.5)).cos();
            let mut dp = 0.0;
            for _ in 0..100 {
                let (mut p0, mut p1) = (1.0, x);
                for j in 2..=n {
                    let p2 = ((2 * j - 1) as f64 * x * p1 - (j - 1) as f64 * p0) / j as f64;
                    p0 = p1;
                    p1 = p2;
                }
                dp = n as f64 * (x * p1 - p0) / (x * x - 1.0);
                let dx = p1 / dp;
                x -= dx;
                if dx.abs() < 1e-16 {
                    break;
                }
            }
            out.push((x, 2.0 / ((1.0 - x * x) * dp * dp)));
        }
        out
    }

    /// ∫_a^b f by composite Gauss–Legendre (`panels` panels of `n` nodes).
    pub fn integrate(a: f64, b: f64, panels: usize, n: usize, f: impl Fn(f64) -> f64) -> f64 {
        let gl = gauss_legendre(n);
        let h = (b - a) / panels as f64;
        let mut s = 0.0;
        for p in 0..panels {
            let c = a + (p as f64 + 0.5) * h;
            for &(x, w) in &gl {
                s += w * f(c + 0.5 * h * x);
            }
        }
        0.5 * h * s
    }

    /// Hemispherical albedo ∫ f_r μ dΩ at incidence `i` (over e, ψ).
    pub fn hemispherical_albedo(m: &Reflectance, i: f64) -> f64 {
        integrate(0.0, PI / 2.0, 16, 16, |e| {
            integrate(0.0, PI, 8, 16, |psi| {
                let g = ScatteringGeometry::from_angles(i, e, psi);
                2.0 * m.brdf(&g, m.albedo()) * e.cos() * e.sin()
            })
        })
    }

    /// Disk-integrated ∫ r μ dΩ over the sunlit, visible part of a unit
    /// sphere at phase `alpha`, by quadrature of the model itself in the
    /// (θ, φ) frame (geometry built from vectors).
    pub fn disk_integral(m: &Reflectance, alpha: f64) -> f64 {
        let l = DVec3::X;
        let v = DVec3::new(alpha.cos(), alpha.sin(), 0.0);
        integrate(alpha - PI / 2.0, PI / 2.0, 8, 20, |phi| {
            integrate(0.0, PI, 8, 20, |theta| {
                let n = DVec3::new(
                    theta.sin() * phi.cos(),
                    theta.sin() * phi.sin(),
                    theta.cos(),
                );
                let g = ScatteringGeometry::from_vectors(n, l, v);
                m.radiance_factor(&g, m.albedo()) * g.mu.max(0.0) * theta.sin()
            })
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn parse(s: &str) -> std::result::Result<ReflectanceConfig, String> {
        toml::from_str::<ReflectanceConfig>(s).map_err(|e| e.to_string())
    }

    #[test]
    fn parses_every_model() {
        let cases = [
            ("model = \"area\"\nalbedo = 0.2", "area"),
            ("model = \"lambert\"\nalbedo = 1", "lambert"),
            ("model = \"lommel_seeliger\"\nalbedo = 0.1", "lommel_seeliger"),
            (
                "model = \"oren_nayar\"\nalbedo = 0.15\nroughness = 0.3",
                "oren_nayar",
            ),
            (
                "model = \"oren_nayar_qualitative\"\nalbedo = 0.15\nroughness = 0.3",
                "oren_nayar_qualitative",
            ),
            ("model = \"lunar_lambert\"\nalbedo = 0.1", "lunar_lambert"),
            ("model = \"minnaert\"\nalbedo = 0.1\nk = 0.7", "minnaert"),
            (
                "model = \"hapke\"\nw = 0.5\nb = 0.2\nc = 0.3\ntheta_bar = 0.2\nh_s = 0.08\nb_s0 = 1",
                "hapke",
            ),
        ];
        for (s, name) in cases {
            let cfg = parse(s).unwrap();
            let m = cfg.build().unwrap();
            assert_eq!(m.name(), name);
            // Round trip through TOML.
            let back: ReflectanceConfig = toml::from_str(&toml::to_string(&cfg).unwrap()).unwrap();
            assert_eq!(back, cfg);
        }
    }

    #[test]
    fn unknown_key_is_named() {
        let e = parse("model = \"oren_nayar\"\nalbedo = 0.15\nroughness = 0.3\nroughnes = 1")
            .unwrap_err();
        assert!(e.contains("roughnes"), "{e}");
        assert!(e.contains("unknown field"), "{e}");
        let e = parse("model = \"lambert\"\nalbedo = 0.15\nk = 1").unwrap_err();
        assert!(e.contains("`k`"), "{e}");
        let e = parse(
            "model = \"hapke\"\nw = 0.5\nb = 0.2\nc = 0.3\ntheta_bar = 0.2\nh_s = 0.08\nb_s0 = 1\nhc = 0.1",
        )
        .unwrap_err();
        assert!(e.contains("`hc`"), "{e}");
    }

    #[test]
    fn unknown_model_is_named() {
        let e = parse("model = \"phong\"\nalbedo = 0.15").unwrap_err();
        assert!(e.contains("phong"), "{e}");
    }

    #[test]
    fn missing_key_is_named() {
        let e = parse("model = \"oren_nayar\"\nalbedo = 0.15").unwrap_err();
        assert!(e.contains("missing field `roughness`"), "{e}");
        let e = parse("model = \"hapke\"\nw = 0.5\nb = 0.2\nc = 0.3\nh_s = 0.08\nb_s0 = 1")
            .unwrap_err();
        assert!(e.contains("missing field `theta_bar`"), "{e}");
        let e = parse("albedo = 0.15").unwrap_err();
        assert!(e.contains("model"), "{e}");
    }

    fn build_err(s: &str) -> String {
        parse(s).unwrap().build().unwrap_err().to_string()
    }

    #[test]
    fn bad_range_names_the_field() {
        let e = build_err("model = \"oren_nayar\"\nalbedo = 0.15\nroughness = -0.3");
        assert!(e.contains("body.reflectance.roughness"), "{e}");
        let e = build_err("model = \"lambert\"\nalbedo = -1");
        assert!(e.contains("body.reflectance.albedo"), "{e}");
        let e = build_err("model = \"lambert\"\nalbedo = nan");
        assert!(e.contains("body.reflectance.albedo"), "{e}");
        let e = build_err("model = \"minnaert\"\nalbedo = 0.1\nk = -0.5");
        assert!(e.contains("body.reflectance.k"), "{e}");
        let hapke = |extra: &str, w: &str| {
            format!(
                "model = \"hapke\"\nw = {w}\nb = 0.2\nc = 0.3\ntheta_bar = 0.2\nh_s = 0.08\nb_s0 = 1\n{extra}"
            )
        };
        for (extra, w, field) in [
            ("", "0", "w"),
            ("", "1.5", "w"),
            ("", "[[500, 0.5], [400, 0.6]]", "w"),
            ("", "[[500, 0.5], [600, 1.6]]", "w"),
            ("", "[]", "w"),
            ("porosity_k = 0.5", "0.5", "porosity_k"),
            ("h_c = 0", "0.5", "h_c"),
            ("b_c0 = 1", "0.5", "b_c0"),
            ("b_c0 = -1\nh_c = 0.1", "0.5", "b_c0"),
        ] {
            let e = build_err(&hapke(extra, w));
            assert!(
                e.contains(&format!("body.reflectance.{field}")),
                "{field}: {e}"
            );
        }
        for (key, value) in [
            ("b", "1"),
            ("b", "-1"),
            ("c", "1.5"),
            ("theta_bar", "1.6"),
            ("theta_bar", "-0.1"),
            ("h_s", "0"),
            ("b_s0", "-1"),
        ] {
            let base = [
                ("w", "0.5"),
                ("b", "0.2"),
                ("c", "0.3"),
                ("theta_bar", "0.2"),
                ("h_s", "0.08"),
                ("b_s0", "1"),
            ];
            let mut s = "model = \"hapke\"\n".to_string();
            for (k, v) in base {
                s += &format!("{k} = {}\n", if k == key { value } else { v });
            }
            let e = build_err(&s);
            assert!(e.contains(&format!("body.reflectance.{key}")), "{key}: {e}");
        }
        let e = parse("model = \"lambert\"\nalbedo = -1")
            .unwrap()
            .build_at("bodies.moon.reflectance")
            .unwrap_err()
            .to_string();
        assert!(e.contains("bodies.moon.reflectance.albedo"), "{e}");
    }

    #[test]
    fn hapke_w_type_error_is_readable() {
        let e = parse(
            "model = \"hapke\"\nw = \"high\"\nb = 0.2\nc = 0.3\ntheta_bar = 0.2\nh_s = 0.08\nb_s0 = 1",
        )
        .unwrap_err();
        assert!(e.contains("wavelength_nm"), "{e}");
    }

    #[test]
    fn spectral_queries() {
        let m = parse("model = \"lambert\"\nalbedo = 0.3")
            .unwrap()
            .build()
            .unwrap();
        assert!(m.is_spectrally_flat());
        assert_eq!(m.albedo(), 0.3);
        assert_eq!(m.albedo_at(700e-9), 0.3);
        let m = parse(
            "model = \"hapke\"\nw = [[500, 0.4], [600, 0.6]]\nb = 0.2\nc = 0.3\ntheta_bar = 0.2\nh_s = 0.08\nb_s0 = 1",
        )
        .unwrap()
        .build()
        .unwrap();
        assert!(!m.is_spectrally_flat());
        assert!((m.albedo() - 0.5).abs() < 1e-12);
        assert!((m.albedo_at(525e-9) - 0.45).abs() < 1e-12);
        assert_eq!(m.albedo_at(400e-9), 0.4);
        assert_eq!(m.albedo_at(700e-9), 0.6);
        let m = parse(
            "model = \"hapke\"\nw = 0.5\nb = 0.2\nc = 0.3\ntheta_bar = 0.2\nh_s = 0.08\nb_s0 = 1",
        )
        .unwrap()
        .build()
        .unwrap();
        assert!(m.is_spectrally_flat());
        assert_eq!(m.albedo_at(400e-9), 0.5);
    }

    #[test]
    fn zero_outside_lit_and_visible() {
        for m in all_models() {
            for g in [
                ScatteringGeometry {
                    mu0: 0.0,
                    mu: 0.5,
                    cos_g: 0.0,
                },
                ScatteringGeometry {
                    mu0: 0.5,
                    mu: 0.0,
                    cos_g: 0.0,
                },
                ScatteringGeometry {
                    mu0: -0.5,
                    mu: 0.5,
                    cos_g: -0.5,
                },
                ScatteringGeometry {
                    mu0: 0.5,
                    mu: -0.5,
                    cos_g: -0.5,
                },
                ScatteringGeometry {
                    mu0: f64::NAN,
                    mu: 0.5,
                    cos_g: 0.5,
                },
            ] {
                assert_eq!(m.radiance_factor(&g, m.albedo()), 0.0, "{}", m.name());
                assert_eq!(m.brdf(&g, m.albedo()), 0.0, "{}", m.name());
            }
        }
    }

    /// A spread of models, including parameter extremes.
    pub(crate) fn all_models() -> Vec<Reflectance> {
        let hapke = |w: &str, extra: &str| format!("model = \"hapke\"\nw = {w}\n{extra}");
        [
            "model = \"area\"\nalbedo = 0.2".to_string(),
            "model = \"lambert\"\nalbedo = 0.3".to_string(),
            "model = \"lommel_seeliger\"\nalbedo = 0.1".to_string(),
            "model = \"oren_nayar\"\nalbedo = 0.15\nroughness = 0.3".to_string(),
            "model = \"oren_nayar\"\nalbedo = 1\nroughness = 1.5".to_string(),
            "model = \"oren_nayar\"\nalbedo = 0.5\nroughness = 0".to_string(),
            "model = \"oren_nayar_qualitative\"\nalbedo = 0.15\nroughness = 0.3".to_string(),
            "model = \"oren_nayar_qualitative\"\nalbedo = 1\nroughness = 1.5".to_string(),
            "model = \"lunar_lambert\"\nalbedo = 0.1".to_string(),
            "model = \"minnaert\"\nalbedo = 0.1\nk = 0.7".to_string(),
            "model = \"minnaert\"\nalbedo = 0.1\nk = 0".to_string(),
            "model = \"minnaert\"\nalbedo = 0.1\nk = 2.5".to_string(),
            hapke("0.526", "b = 0.187\nc = 0.273\ntheta_bar = 0.2321\nh_s = 0.083\nb_s0 = 1"),
            hapke("1", "b = 0.99\nc = 1\ntheta_bar = 1.5\nh_s = 1e-300\nb_s0 = 5\nh_c = 1e-300\nb_c0 = 1"),
            hapke("1e-9", "b = -0.9\nc = -1\ntheta_bar = 0\nh_s = 10\nb_s0 = 0\nporosity_k = 3"),
            hapke("0.9", "b = 0.3\nc = 0.5\ntheta_bar = 1e-12\nh_s = 0.05\nb_s0 = 1\nh_c = 0.02\nb_c0 = 0.5\nporosity_k = 1.5"),
            hapke("[[400, 0.3], [900, 0.7]]", "b = 0.3\nc = 0.5\ntheta_bar = 0.7\nh_s = 0.05\nb_s0 = 1"),
        ]
        .iter()
        .map(|s| parse(s).unwrap().build().unwrap())
        .collect()
    }

    /// Cosines with many extreme values.
    fn cosine() -> impl Strategy<Value = f64> {
        prop_oneof![
            Just(0.0),
            Just(1.0),
            Just(-1.0),
            Just(f64::MIN_POSITIVE),
            Just(5e-324),
            Just(1e-300),
            Just(1.0 - f64::EPSILON),
            Just(6.123233995736766e-17),
            (-20.0f64..0.0).prop_map(|x| 10f64.powf(x)),
            (-20.0f64..0.0).prop_map(|x| 1.0 - 10f64.powf(x)),
            -1.0f64..=1.0,
            0.0f64..=1.0,
        ]
    }

    /// Azimuths ψ ∈ [0, π] with the ends and near-ends.
    fn azimuth() -> impl Strategy<Value = f64> {
        prop_oneof![
            Just(0.0),
            Just(std::f64::consts::PI),
            (-20.0f64..0.0).prop_map(|x| 10f64.powf(x)),
            (-20.0f64..0.0).prop_map(|x| std::f64::consts::PI - 10f64.powf(x)),
            0.0f64..=std::f64::consts::PI,
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(4000))]

        /// radiance_factor is finite and ≥ 0 (brdf ≥ 0, +∞ only from overflow
        /// of r/μ0 at μ0 ~ 1e-308) for every model at consistent
        /// (μ0, μ, cos g) triples, including the extremes.
        #[test]
        fn finite_and_nonnegative(mu0 in cosine(), mu in cosine(), psi in azimuth(),
                                  albedo_scale in prop_oneof![Just(0.0), Just(1.0), Just(2.0), 0.0f64..1.5]) {
            let si = (1.0 - mu0 * mu0).max(0.0).sqrt();
            let se = (1.0 - mu * mu).max(0.0).sqrt();
            let g = ScatteringGeometry { mu0, mu, cos_g: (mu0 * mu + si * se * psi.cos()).clamp(-1.0, 1.0) };
            for m in all_models() {
                let a = m.albedo() * albedo_scale;
                let r = m.radiance_factor(&g, a);
                prop_assert!(r.is_finite() && r >= 0.0, "{} r={r} at {g:?}", m.name());
                if mu0 <= 0.0 || mu <= 0.0 {
                    prop_assert_eq!(r, 0.0);
                }
                let f = m.brdf(&g, a);
                prop_assert!(f >= 0.0, "{} f={f} at {g:?}", m.name());
                prop_assert!(f.is_finite() || mu0 < 1e-290, "{} f={f} at {g:?}", m.name());
            }
        }

        /// Arbitrary (even inconsistent or out-of-range) inputs never give
        /// NaN, ∞ or negative values.
        #[test]
        fn finite_for_any_input(mu0 in -2.0f64..2.0, mu in -2.0f64..2.0, cos_g in -2.0f64..2.0,
                                albedo in -1.0f64..3.0) {
            let g = ScatteringGeometry { mu0, mu, cos_g };
            for m in all_models() {
                let r = m.radiance_factor(&g, albedo);
                prop_assert!(r.is_finite() && r >= 0.0, "{} r={r} at {g:?}", m.name());
            }
        }
    }
}
