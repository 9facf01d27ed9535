//! Reflectance parameters other than the albedo that a map may set per
//! point (`[body] parameter_maps`): which ones each model has, their valid
//! ranges, and the model evaluated with them.

use std::f64::consts::FRAC_PI_2;

use super::{HapkeShape, Minnaert, OrenNayar, OrenNayarQualitative, Reflectance};
use crate::radiometry::geometry::ScatteringGeometry;

/// A model parameter a map can set per point.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MappedParameter {
    /// σ of `oren_nayar` and `oren_nayar_qualitative` [rad].
    Roughness,
    /// k of `minnaert`.
    MinnaertK,
    /// b of `hapke`.
    HapkeB,
    /// c of `hapke`.
    HapkeC,
    /// h_S of `hapke`.
    HapkeHs,
    /// B_S0 of `hapke`.
    HapkeBs0,
    /// θ̄ of `hapke` [rad].
    HapkeThetaBar,
}

impl MappedParameter {
    /// The parameter called `name` (its scene-file key) in `model`, or the
    /// keys `model` accepts.
    pub fn of(model: &Reflectance, name: &str) -> Result<Self, &'static str> {
        use MappedParameter::*;
        let known: &[(&str, MappedParameter)] = match model {
            Reflectance::OrenNayar(_) | Reflectance::OrenNayarQualitative(_) => {
                &[("roughness", Roughness)]
            }
            Reflectance::Minnaert(_) => &[("k", MinnaertK)],
            Reflectance::Hapke(_) => &[
                ("b", HapkeB),
                ("c", HapkeC),
                ("h_s", HapkeHs),
                ("b_s0", HapkeBs0),
                ("theta_bar", HapkeThetaBar),
            ],
            _ => &[],
        };
        known
            .iter()
            .find(|(key, _)| *key == name)
            .map(|&(_, p)| p)
            .ok_or(match model {
                Reflectance::OrenNayar(_) | Reflectance::OrenNayarQualitative(_) => "roughness",
                Reflectance::Minnaert(_) => "k",
                Reflectance::Hapke(_) => "b, c, h_s, b_s0 or theta_bar",
                _ => "none (this model has only its albedo: use albedo_map)",
            })
    }

    /// The scene-file key.
    pub fn name(self) -> &'static str {
        match self {
            MappedParameter::Roughness => "roughness",
            MappedParameter::MinnaertK => "k",
            MappedParameter::HapkeB => "b",
            MappedParameter::HapkeC => "c",
            MappedParameter::HapkeHs => "h_s",
            MappedParameter::HapkeBs0 => "b_s0",
            MappedParameter::HapkeThetaBar => "theta_bar",
        }
    }

    /// Whether `v` is a valid value (the same ranges the model's own keys
    /// are checked against; roughness up to π/2, k up to 10, h_S and B_S0
    /// up to 100, θ̄ below π/2).
    pub fn accepts(self, v: f64) -> bool {
        v.is_finite()
            && match self {
                MappedParameter::Roughness => (0.0..=FRAC_PI_2).contains(&v),
                MappedParameter::MinnaertK => (0.0..=10.0).contains(&v),
                MappedParameter::HapkeB => v.abs() < 1.0,
                MappedParameter::HapkeC => v.abs() <= 1.0,
                MappedParameter::HapkeHs => v > 0.0 && v <= 100.0,
                MappedParameter::HapkeBs0 => (0.0..=100.0).contains(&v),
                MappedParameter::HapkeThetaBar => (0.0..FRAC_PI_2).contains(&v),
            }
    }
}

impl Reflectance {
    /// [`radiance_factor`](Self::radiance_factor) with the parameters in
    /// `values` replacing the model's own at this point (values outside a
    /// parameter's range are clamped to it; parameters the model does not
    /// have are ignored). Without values, the model's own.
    #[inline]
    pub fn radiance_factor_with(
        &self,
        g: &ScatteringGeometry,
        albedo: f64,
        values: &[(MappedParameter, f64)],
    ) -> f64 {
        if values.is_empty() {
            return self.radiance_factor(g, albedo);
        }
        let get = |p: MappedParameter, own: f64| {
            values
                .iter()
                .find(|(q, _)| *q == p)
                .map_or(own, |&(_, v)| clamp_to(p, v))
        };
        match self {
            Reflectance::OrenNayar(m) => {
                let sigma = get(MappedParameter::Roughness, m.roughness);
                Reflectance::OrenNayar(OrenNayar::new(m.albedo, sigma)).radiance_factor(g, albedo)
            }
            Reflectance::OrenNayarQualitative(m) => {
                let sigma = get(MappedParameter::Roughness, m.roughness);
                Reflectance::OrenNayarQualitative(OrenNayarQualitative::new(m.albedo, sigma))
                    .radiance_factor(g, albedo)
            }
            Reflectance::Minnaert(m) => {
                let k = get(MappedParameter::MinnaertK, m.k);
                Reflectance::Minnaert(Minnaert::new(m.albedo, k)).radiance_factor(g, albedo)
            }
            Reflectance::Hapke(m) => {
                let own = m.shape();
                let shape = HapkeShape {
                    b: get(MappedParameter::HapkeB, own.b),
                    c: get(MappedParameter::HapkeC, own.c),
                    h_s: get(MappedParameter::HapkeHs, own.h_s),
                    b_s0: get(MappedParameter::HapkeBs0, own.b_s0),
                    theta_bar: get(MappedParameter::HapkeThetaBar, own.theta_bar),
                };
                self.radiance_factor_by(g, albedo, |g, a| {
                    m.radiance_factor_shaped(g, a.min(1.0), shape)
                })
            }
            _ => self.radiance_factor(g, albedo),
        }
    }
}

/// `v` moved into the parameter's range (a bilinear map stays within its
/// texels' range, so this only guards rounding).
fn clamp_to(p: MappedParameter, v: f64) -> f64 {
    let v = if v.is_finite() { v } else { 0.0 };
    match p {
        MappedParameter::Roughness => v.clamp(0.0, FRAC_PI_2),
        MappedParameter::MinnaertK => v.clamp(0.0, 10.0),
        MappedParameter::HapkeB => v.clamp(-0.999_999, 0.999_999),
        MappedParameter::HapkeC => v.clamp(-1.0, 1.0),
        MappedParameter::HapkeHs => v.clamp(1e-12, 100.0),
        MappedParameter::HapkeBs0 => v.clamp(0.0, 100.0),
        MappedParameter::HapkeThetaBar => v.clamp(0.0, 1.57),
    }
}
