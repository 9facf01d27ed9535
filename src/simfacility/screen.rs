//! The simulated screen's radiometry: its spectrum per drive level (the
//! panel's channels of [`super::panel`] plus a black leak), the spatial
//! non-uniformity of [`super::spatial`], the warm-up and drift on the
//! virtual clock; and the spectral integrals per level (camera electron
//! rate, camera-effective radiance, meter reading) computed once, so a
//! capture only looks them up.
//!
//! Spectral radiance of the screen at grey drive level ℓ (x = ℓ / (levels
//! − 1)), screen position p and time t after power-on:
//!
//! S(λ; ℓ, p, t) = A · [(1 − b) Σ_c E_c(x) P_c(λ) U_main(p) + b K(λ) U_leak(p)] · W(t)
//!
//! with A = max_radiance / ∫ shape dλ, P_c = shape · w_c the primaries,
//! E_c the channels' emissions, b = black_level, K(λ) = shape(λ + δ) the
//! black leak's spectrum (δ = spectral_shift_nm: the leak is bluer), and W
//! the warm-up and drift factor ([`ScreenPhysics::warmup`]).

use std::path::Path;

use super::config::{CameraTruth, MeterTruth, ResponseSpec, ScreenTruth};
use super::panel::Panel;
use super::spatial::ScreenPattern;
use crate::error::{Error, Result};
use crate::radiometry::spectrum::{
    band_integrals, integrate, Response, SolarSpectrum, Table, LIGHT_SPEED, PLANCK,
};

/// Photopic luminous efficacy, lm/W.
pub const LUMINOUS_EFFICACY: f64 = 683.0;

/// Wavelengths of a spectroradiometer reading, nm.
pub const METER_SPECTRUM_NM: (f64, f64, f64) = (380.0, 780.0, 5.0);

/// What a spot meter weights the spectrum with.
#[derive(Debug, Clone)]
pub enum MeterResponse {
    /// Flat over a band [m]: a radiometer, W m⁻² sr⁻¹.
    Flat([f64; 2]),
    /// 683 lm/W × V(λ): a photometer, cd m⁻².
    Photopic(Table),
    /// A relative response table.
    Table(Table),
}

impl MeterResponse {
    /// From the meter's configuration.
    pub fn from_config(m: &MeterTruth) -> Result<MeterResponse> {
        Ok(match m.response.as_str() {
            "flat" => MeterResponse::Flat([m.band_nm[0] * 1e-9, m.band_nm[1] * 1e-9]),
            "photopic" => MeterResponse::Photopic(photopic_table()?),
            path => MeterResponse::Table(Table::from_csv(Path::new(path))?),
        })
    }

    fn eval(&self, wavelength: f64) -> f64 {
        match self {
            MeterResponse::Flat([lo, hi]) => {
                if (*lo..=*hi).contains(&wavelength) {
                    1.0
                } else {
                    0.0
                }
            }
            MeterResponse::Photopic(t) => LUMINOUS_EFFICACY * t.eval(wavelength),
            MeterResponse::Table(t) => t.eval(wavelength),
        }
    }

    fn span_and_knots(&self) -> ([f64; 2], Vec<f64>) {
        match self {
            MeterResponse::Flat(b) => (*b, b.to_vec()),
            MeterResponse::Photopic(t) | MeterResponse::Table(t) => (
                [t.wavelengths[0], *t.wavelengths.last().unwrap()],
                t.wavelengths.clone(),
            ),
        }
    }
}

/// The bundled CIE 1924 V(λ) (data/display/cie1924_photopic_v.csv).
pub fn photopic_table() -> Result<Table> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/display/cie1924_photopic_v.csv");
    Table::from_csv(&path)
}

/// Loads a `ResponseSpec` as a [`Response`].
pub fn load_response(spec: &ResponseSpec) -> Result<Response> {
    Ok(match spec {
        ResponseSpec::Constant(v) => Response::Constant(*v),
        ResponseSpec::Table(p) => Response::Table(Table::from_csv(p)?),
    })
}

fn response_knots(r: &Response) -> Vec<f64> {
    match r {
        Response::Constant(_) => Vec::new(),
        Response::Table(t) | Response::AmpsPerWatt(t) => t.wavelengths.clone(),
    }
}

/// The camera's photon responsivity R(λ) = QE T λ / (h c) over its band,
/// and the solar normalisation of camera-effective radiance.
#[derive(Debug, Clone)]
pub struct CameraResponse {
    /// Band [m].
    pub band: [f64; 2],
    pub qe: Response,
    pub transmission: Response,
    /// ∫_band E☉ dλ / ∫_band E☉ R dλ [J m⁻²... per electron]: L_eff = this
    /// × ∫ S R dλ.
    pub effective_per_rate: f64,
}

impl CameraResponse {
    /// From the camera's configuration.
    pub fn from_config(c: &CameraTruth) -> Result<CameraResponse> {
        let band = [c.band_nm[0] * 1e-9, c.band_nm[1] * 1e-9];
        let qe = load_response(&c.quantum_efficiency)?;
        let transmission = load_response(&c.transmission)?;
        let sun = match c.sun_spectrum.as_str() {
            "blackbody" => SolarSpectrum::blackbody(5772.0, 1361.0)?,
            path => SolarSpectrum::from_csv(Path::new(path), None)?,
        };
        let b = band_integrals(&sun, &qe, &transmission, band, 1)[0];
        if !(b.electron_rate_1au > 0.0 && b.irradiance_1au > 0.0) {
            return Err(Error::invalid(
                "camera.band_nm",
                "the camera sees no sunlight in its band (QE × transmission × Sun is zero)",
            ));
        }
        Ok(CameraResponse {
            band,
            qe,
            transmission,
            effective_per_rate: b.irradiance_1au / b.electron_rate_1au,
        })
    }

    /// R(λ), electrons per joule.
    pub fn eval(&self, wavelength: f64) -> f64 {
        if wavelength < self.band[0] || wavelength > self.band[1] {
            return 0.0;
        }
        self.qe.eval(wavelength) * self.transmission.eval(wavelength) * wavelength
            / (PLANCK * LIGHT_SPEED)
    }

    fn knots(&self) -> Vec<f64> {
        let mut k = response_knots(&self.qe);
        k.extend(response_knots(&self.transmission));
        k.extend(self.band);
        k
    }
}

/// A per-level quantity split into the channels' part (per level, at
/// U_main = 1) and the black leak's (the same at every level, at U_leak = 1).
#[derive(Debug, Clone, PartialEq)]
pub struct Split {
    pub main: Vec<f64>,
    pub leak: f64,
}

impl Split {
    /// Total at `level` with both patterns at 1.
    pub fn total(&self, level: usize) -> f64 {
        self.main[level.min(self.main.len() - 1)] + self.leak
    }

    /// Value at `level` where the patterns are `main` and `leak`.
    pub fn at(&self, level: usize, main: f64, leak: f64) -> f64 {
        self.main[level.min(self.main.len() - 1)] * main + self.leak * leak
    }
}

/// Per-level tables and the spatial and temporal factors of the screen.
#[derive(Debug, Clone)]
pub struct ScreenPhysics {
    cfg: ScreenTruth,
    shape: Table,
    shape_integral: f64,
    panel: Panel,
    /// The spatial non-uniformity and its maps.
    pub pattern: ScreenPattern,
    /// ∫ S R dλ per level at U = W = 1 [e⁻ s⁻¹ m⁻² sr⁻¹].
    pub camera_rate: Vec<f64>,
    /// Camera-effective radiance per level at U = W = 1 [W m⁻² sr⁻¹].
    pub camera_effective: Vec<f64>,
    /// Meter reading per level at U = W = 1 (meter units).
    pub meter: Vec<f64>,
    /// `camera_rate` split into channels and leak.
    pub camera_rate_split: Split,
    /// `camera_effective` split into channels and leak.
    pub camera_effective_split: Split,
    /// `meter` split into channels and leak.
    pub meter_split: Split,
    /// ∫ S dλ split into channels and leak.
    pub radiance_split: Split,
}

impl ScreenPhysics {
    /// Loads the spectrum, draws the mura from `seed`, integrates per
    /// level.
    pub fn new(
        cfg: &ScreenTruth,
        camera: &CameraResponse,
        meter: &MeterResponse,
        seed: u64,
    ) -> Result<ScreenPhysics> {
        let shape = match cfg.spectrum.as_str() {
            "flat" => Table::new(vec![380e-9, 780e-9], vec![1.0, 1.0], "screen.spectrum")?,
            path => Table::from_csv(Path::new(path))?,
        };
        let (lo, hi) = (shape.wavelengths[0], *shape.wavelengths.last().unwrap());
        let shape_integral = integrate(lo, hi, &shape.wavelengths, |l| shape.eval(l));
        if !(shape_integral > 0.0) {
            return Err(Error::invalid("screen.spectrum", "integrates to zero"));
        }
        let mut physics = ScreenPhysics {
            cfg: cfg.clone(),
            shape,
            shape_integral,
            panel: Panel::from_config(cfg)?,
            pattern: ScreenPattern::new(cfg, seed),
            camera_rate: Vec::new(),
            camera_effective: Vec::new(),
            meter: Vec::new(),
            camera_rate_split: Split {
                main: Vec::new(),
                leak: 0.0,
            },
            camera_effective_split: Split {
                main: Vec::new(),
                leak: 0.0,
            },
            meter_split: Split {
                main: Vec::new(),
                leak: 0.0,
            },
            radiance_split: Split {
                main: Vec::new(),
                leak: 0.0,
            },
        };
        physics.radiance_split = physics.split([0.0, 1.0], &[], |_| 1.0);
        let cam_knots = camera.knots();
        physics.camera_rate_split = physics.split(camera.band, &cam_knots, |l| camera.eval(l));
        let (meter_span, meter_knots) = meter.span_and_knots();
        physics.meter_split = physics.split(meter_span, &meter_knots, |l| meter.eval(l));
        let r = &physics.camera_rate_split;
        physics.camera_effective_split = Split {
            main: r
                .main
                .iter()
                .map(|v| v * camera.effective_per_rate)
                .collect(),
            leak: r.leak * camera.effective_per_rate,
        };
        let levels = cfg.levels();
        physics.camera_rate = (0..levels)
            .map(|l| physics.camera_rate_split.total(l))
            .collect();
        physics.camera_effective = (0..levels)
            .map(|l| physics.camera_effective_split.total(l))
            .collect();
        physics.meter = (0..levels).map(|l| physics.meter_split.total(l)).collect();
        Ok(physics)
    }

    /// ∫ S f dλ per level over `span`: the three primaries' integrals
    /// combined with each level's emissions, and the leak's.
    fn split(&self, span: [f64; 2], knots: &[f64], f: impl Fn(f64) -> f64) -> Split {
        let a = self.amplitude();
        let b = self.cfg.black_level;
        let primaries = [0, 1, 2].map(|c| {
            self.integrate_over(span, knots, 0.0, |l| {
                self.shape.eval(l) * self.panel.window(c, l) * f(l)
            })
        });
        let delta = self.shift();
        let leak = self.integrate_over(span, knots, delta, |l| self.shape.eval(l + delta) * f(l));
        let main = (0..self.cfg.levels())
            .map(|level| {
                let e = self.panel.emissions(self.normalised(level));
                a * (1.0 - b) * (0..3).map(|c| e[c] * primaries[c]).sum::<f64>()
            })
            .collect();
        Split {
            main,
            leak: a * b * leak,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &ScreenTruth {
        &self.cfg
    }

    /// The panel's channels.
    pub fn panel(&self) -> &Panel {
        &self.panel
    }

    fn amplitude(&self) -> f64 {
        self.cfg.max_radiance / self.shape_integral
    }

    fn normalised(&self, level: usize) -> f64 {
        level.min(self.cfg.levels() - 1) as f64 / (self.cfg.levels() - 1) as f64
    }

    /// The black leak's shift toward the blue, m.
    fn shift(&self) -> f64 {
        self.cfg.spectral_shift_nm * 1e-9
    }

    /// ∫ S(λ; level) dλ at U = W = 1, W m⁻² sr⁻¹: the true curve,
    /// max_radiance · (b + (1 − b) Σ_c E_c(x) ∫ P_c / ∫ shape).
    pub fn total_radiance(&self, level: usize) -> f64 {
        self.radiance_split.total(level)
    }

    /// S(λ; level) at U = W = 1, W m⁻² sr⁻¹ per metre of wavelength.
    pub fn spectral_radiance(&self, level: usize, wavelength: f64) -> f64 {
        let e = self.panel.emissions(self.normalised(level));
        let b = self.cfg.black_level;
        let channels: f64 = (0..3)
            .map(|c| e[c] * self.panel.window(c, wavelength))
            .sum();
        self.amplitude()
            * ((1.0 - b) * channels * self.shape.eval(wavelength)
                + b * self.shape.eval(wavelength + self.shift()))
    }

    /// ∫ g dλ over `span` ∩ the spectrum shifted by `shift`, split at its
    /// knots and at `knots`.
    fn integrate_over(
        &self,
        span: [f64; 2],
        knots: &[f64],
        shift: f64,
        g: impl Fn(f64) -> f64,
    ) -> f64 {
        let mut all: Vec<f64> = self.shape.wavelengths.iter().map(|w| w - shift).collect();
        all.extend_from_slice(knots);
        all.sort_by(f64::total_cmp);
        let lo = span[0].max(all[0]);
        let hi = span[1].min(*all.last().unwrap());
        if hi <= lo {
            return 0.0;
        }
        integrate(lo, hi, &all, g)
    }

    /// U_main at screen position (u, v) (continuous pixel coordinates):
    /// falloff × gradient × (1 + mura). The relative radiance of levels
    /// well above black (the black leak has its own, [`ScreenPattern::leak`]).
    #[inline]
    pub fn uniformity(&self, u: f64, v: f64) -> f64 {
        self.pattern.main(u, v)
    }

    /// Relative camera-weighted radiance of `level` at (u, v) against its
    /// value where both patterns are 1: the channels and the leak each
    /// with their own pattern, so the non-uniformity depends on the level.
    pub fn uniformity_at(&self, level: usize, u: f64, v: f64) -> f64 {
        let r = &self.camera_rate_split;
        r.at(level, self.pattern.main(u, v), self.pattern.leak(u, v)) / r.total(level)
    }

    /// Warm-up and drift factor W at `t` seconds after power-on:
    /// (1 − a e^(−t/τ)) (1 + d t / 3600).
    pub fn warmup(&self, t: f64) -> f64 {
        let c = &self.cfg;
        (1.0 - c.warmup_amplitude * (-t / c.warmup_time_constant).exp())
            * (1.0 + c.drift_per_hour * t / 3600.0)
    }

    /// A spectroradiometer's spectrum of `level` at U = W = 1, the
    /// channels' and the leak's parts apart: pairs (nm, main, leak), W m⁻²
    /// sr⁻¹ nm⁻¹, the instrument's wavelength scale off by
    /// `wavelength_error_nm` (the value at nominal λ is the true one at
    /// λ + error).
    pub fn meter_spectrum(&self, level: usize, wavelength_error_nm: f64) -> Vec<(f64, f64, f64)> {
        let (lo, hi, step) = METER_SPECTRUM_NM;
        let n = ((hi - lo) / step).round() as usize + 1;
        let e = self.panel.emissions(self.normalised(level));
        let (a, b) = (self.amplitude(), self.cfg.black_level);
        (0..n)
            .map(|k| {
                let nm = lo + step * k as f64;
                let l = (nm + wavelength_error_nm) * 1e-9;
                let channels: f64 = (0..3).map(|c| e[c] * self.panel.window(c, l)).sum();
                let main = a * (1.0 - b) * channels * self.shape.eval(l) * 1e-9;
                let leak = a * b * self.shape.eval(l + self.shift()) * 1e-9;
                (nm, main, leak)
            })
            .collect()
    }
}
