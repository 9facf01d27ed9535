//! The simulated screen's radiometry: its spectrum per drive level, the
//! level → radiance curve, the smooth spatial non-uniformity and the
//! warm-up and drift on the virtual clock; and the spectral integrals per
//! level (camera electron rate, camera-effective radiance, meter reading)
//! computed once, so a capture only looks them up.
//!
//! Spectral radiance of the screen at drive level ℓ (x = ℓ / (levels − 1)),
//! screen position p and time t after power-on:
//!
//! S(λ; ℓ, p, t) = A(ℓ) · shape(λ + δ(ℓ)) · U(p) · W(t)
//!
//! with A(ℓ) = max_radiance · (b + (1 − b) x^γ) / ∫ shape dλ, δ(ℓ) =
//! spectral_shift_nm · (1 − x) (dark levels bluer), U the non-uniformity
//! and W the warm-up and drift factor (see [`ScreenPhysics::uniformity`] and
//! [`ScreenPhysics::warmup`]).

use std::path::Path;

use super::config::{CameraTruth, MeterTruth, ResponseSpec, ScreenTruth};
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

/// Per-level tables and the spatial and temporal factors of the screen.
#[derive(Debug, Clone)]
pub struct ScreenPhysics {
    cfg: ScreenTruth,
    shape: Table,
    shape_integral: f64,
    /// ∫ S R dλ per level at U = W = 1 [e⁻ s⁻¹ m⁻² sr⁻¹].
    pub camera_rate: Vec<f64>,
    /// Camera-effective radiance per level at U = W = 1 [W m⁻² sr⁻¹].
    pub camera_effective: Vec<f64>,
    /// Meter reading per level at U = W = 1 (meter units).
    pub meter: Vec<f64>,
}

impl ScreenPhysics {
    /// Loads the spectrum and integrates it per level.
    pub fn new(
        cfg: &ScreenTruth,
        camera: &CameraResponse,
        meter: &MeterResponse,
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
            camera_rate: Vec::new(),
            camera_effective: Vec::new(),
            meter: Vec::new(),
        };
        let cam_knots = camera.knots();
        let (meter_span, meter_knots) = meter.span_and_knots();
        for level in 0..cfg.levels() {
            let rate = physics.integrate_with(level, camera.band, &cam_knots, |l| camera.eval(l));
            physics.camera_rate.push(rate);
            physics
                .camera_effective
                .push(rate * camera.effective_per_rate);
            let m = physics.integrate_with(level, meter_span, &meter_knots, |l| meter.eval(l));
            physics.meter.push(m);
        }
        Ok(physics)
    }

    /// The configuration.
    pub fn config(&self) -> &ScreenTruth {
        &self.cfg
    }

    fn normalised(&self, level: usize) -> f64 {
        level.min(self.cfg.levels() - 1) as f64 / (self.cfg.levels() - 1) as f64
    }

    /// ∫ S(λ; level) dλ at U = W = 1, W m⁻² sr⁻¹: the true curve.
    pub fn total_radiance(&self, level: usize) -> f64 {
        let x = self.normalised(level);
        let b = self.cfg.black_level;
        self.cfg.max_radiance * (b + (1.0 - b) * x.powf(self.cfg.gamma))
    }

    /// Spectral shift toward the blue at `level`, m.
    fn shift(&self, level: usize) -> f64 {
        self.cfg.spectral_shift_nm * 1e-9 * (1.0 - self.normalised(level))
    }

    /// S(λ; level) at U = W = 1, W m⁻² sr⁻¹ per metre of wavelength.
    pub fn spectral_radiance(&self, level: usize, wavelength: f64) -> f64 {
        let amplitude = self.total_radiance(level) / self.shape_integral;
        amplitude * self.shape.eval(wavelength + self.shift(level))
    }

    /// ∫ S(λ; level) f(λ) dλ over `span`, split at the shifted spectrum's
    /// knots and at `knots`.
    fn integrate_with(
        &self,
        level: usize,
        span: [f64; 2],
        knots: &[f64],
        f: impl Fn(f64) -> f64,
    ) -> f64 {
        let shift = self.shift(level);
        let mut all: Vec<f64> = self.shape.wavelengths.iter().map(|w| w - shift).collect();
        all.extend_from_slice(knots);
        all.sort_by(f64::total_cmp);
        let lo = span[0].max(all[0]);
        let hi = span[1].min(*all.last().unwrap());
        if hi <= lo {
            return 0.0;
        }
        integrate(lo, hi, &all, |l| self.spectral_radiance(level, l) * f(l))
    }

    /// Relative radiance U at screen position (u, v) (continuous pixel
    /// coordinates): a quadratic falloff from the centre (`falloff` at the
    /// corners) times a linear gradient (`gradient` at the right and
    /// bottom edges).
    #[inline]
    pub fn uniformity(&self, u: f64, v: f64) -> f64 {
        let [w, h] = self.cfg.resolution;
        let nx = (u - 0.5 * w as f64) / (0.5 * w as f64);
        let ny = (v - 0.5 * h as f64) / (0.5 * h as f64);
        let falloff = 1.0 - 0.5 * self.cfg.falloff * (nx * nx + ny * ny);
        let [gx, gy] = self.cfg.gradient;
        falloff * (1.0 + gx * nx + gy * ny)
    }

    /// Warm-up and drift factor W at `t` seconds after power-on:
    /// (1 − a e^(−t/τ)) (1 + d t / 3600).
    pub fn warmup(&self, t: f64) -> f64 {
        let c = &self.cfg;
        (1.0 - c.warmup_amplitude * (-t / c.warmup_time_constant).exp())
            * (1.0 + c.drift_per_hour * t / 3600.0)
    }

    /// A spectroradiometer's spectrum of `level` at U = W = 1: pairs
    /// (nm, W m⁻² sr⁻¹ nm⁻¹).
    pub fn meter_spectrum(&self, level: usize) -> Vec<(f64, f64)> {
        let (lo, hi, step) = METER_SPECTRUM_NM;
        let n = ((hi - lo) / step).round() as usize + 1;
        (0..n)
            .map(|k| {
                let nm = lo + step * k as f64;
                (nm, self.spectral_radiance(level, nm * 1e-9) * 1e-9)
            })
            .collect()
    }
}
