//! The simulated facility camera's optics and its capture: where each
//! camera pixel looks on the screen, its etendue, its vignetting, the
//! veiling glare, and a capture from what the screen showed, read out by
//! the one detector model `render` also uses ([`crate::sensor`]).
//!
//! Electrons of pixel (i, j) over an exposure t:
//!
//! e = t · τ · A_pupil · Ω_ij · cos θ_ij · g_ij · ⟨∫ S R dλ⟩_ij
//!
//! with Ω_ij the exact solid angle of the pixel (its four corners
//! undistorted into directions: two spherical triangles), θ_ij the angle of
//! its centre's direction to the boresight, g_ij the camera's own flat, and
//! ⟨·⟩ the mean over the `supersample`² points of the pixel, each seeing
//! the screen (each screen pixel's rate × U at its centre) interpolated
//! bilinearly between pixel centres: a triangle
//! blur one screen pixel wide, standing in for the optics' PSF, which keeps
//! shifts smaller than the sample spacing visible (point samples of the
//! screen's piecewise-constant image would alias them away). Without distortion A Ω cos θ is exactly the
//! renderer's factor (`render::detector`: pupil area × exact Ω × dir.z), so
//! the two agree. Veiling glare adds `veiling_glare` × the image's mean
//! signal to every pixel. The detector is [`crate::sensor::Sensor`] with
//! the camera's keys mapped by [`sensor_params`]: PRNU (its map is the
//! camera's own flat's non-optical part, g = vignetting × PRNU), dark
//! electrons, shot noise (Poisson), the non-linearity e (1 − β e /
//! full_well), read noise and a per-row offset (the same along a row of
//! one frame), the clip at the full well's response, gain, bias, rounding
//! and clipping to [0, largest DN]; capture `index` is the sensor's frame.

use rayon::prelude::*;

use super::config::CameraTruth;
use super::optics::{triangle_solid_angle, CameraOptics, Collimator};
use super::screen::ScreenPhysics;
use crate::error::{Error, Result};
use crate::sensor::{Readout, Sensor, SensorParams};

/// A frame the screen showed during an exposure, with its share of it.
#[derive(Debug, Clone)]
pub struct WindowFrame<'a> {
    /// Drive level per screen pixel.
    pub levels: &'a [u16],
    /// Fraction of the exposure it was up.
    pub weight: f64,
    /// Warm-up and drift factor while it was up.
    pub warmup: f64,
}

/// Static camera tables.
#[derive(Debug, Clone)]
pub struct CameraModel {
    pub cfg: CameraTruth,
    pub optics: CameraOptics,
    /// Screen position of each pixel corner, (w + 1) × (h + 1), row-major.
    corners: Vec<[f64; 2]>,
    /// A_pupil Ω cos θ per pixel, m² sr.
    etendue: Vec<f64>,
    /// Vignetting (the optical part of the flat).
    vignetting: Vec<f32>,
    /// The detector, its PRNU map seeded by the facility's seed.
    sensor: Sensor,
}

impl CameraModel {
    /// Builds the tables (once per facility). A distortion that cannot be
    /// inverted somewhere on the detector is an error naming the corner.
    pub fn new(cfg: &CameraTruth, collimator: &Collimator, seed: u64) -> Result<CameraModel> {
        let optics = CameraOptics::from_config(cfg);
        let [w, h] = cfg.resolution;
        let tans: Vec<(f64, f64)> = (0..(w + 1) * (h + 1))
            .into_par_iter()
            .map(|k| optics.undistort_pixel((k % (w + 1)) as f64, (k / (w + 1)) as f64))
            .collect();
        check_inverse(&optics, &tans, w)?;
        let corners = tans
            .par_iter()
            .map(|&(x, y)| {
                let (u, v) = collimator.tan_to_screen(x, y);
                [u, v]
            })
            .collect();
        let pupil = cfg.pupil_area();
        let etendue = (0..w * h)
            .into_par_iter()
            .map(|k| {
                let (i, j) = (k % w, k / w);
                let c = |di: usize, dj: usize| {
                    let (x, y) = tans[(j + dj) * (w + 1) + i + di];
                    [x, y, 1.0]
                };
                let omega = triangle_solid_angle(c(0, 0), c(1, 0), c(1, 1))
                    + triangle_solid_angle(c(0, 0), c(1, 1), c(0, 1));
                let (x, y) = optics.undistort_pixel(i as f64 + 0.5, j as f64 + 0.5);
                pupil * omega / (1.0 + x * x + y * y).sqrt()
            })
            .collect();
        let vignetting = vignetting(cfg);
        let sensor = Sensor::new(sensor_params(cfg, seed), readout(cfg), w, h);
        Ok(CameraModel {
            cfg: cfg.clone(),
            optics,
            corners,
            etendue,
            vignetting,
            sensor,
        })
    }

    /// `(width, height)`.
    pub fn size(&self) -> (usize, usize) {
        (self.cfg.resolution[0], self.cfg.resolution[1])
    }

    /// Vignetting × PRNU, row-major.
    pub fn flat(&self) -> Vec<f32> {
        self.vignetting
            .iter()
            .zip(self.sensor.prnu_map())
            .map(|(v, g)| v * g)
            .collect()
    }

    /// A_pupil Ω cos θ of each pixel, m² sr.
    pub fn etendue(&self) -> &[f64] {
        &self.etendue
    }

    /// Screen position seen at fractional position (a, b) ∈ [0, 1]² of
    /// pixel (i, j): bilinear between the pixel's corners.
    #[inline]
    fn screen_point(&self, i: usize, j: usize, a: f64, b: f64) -> (f64, f64) {
        let w1 = self.cfg.resolution[0] + 1;
        let c00 = self.corners[j * w1 + i];
        let c10 = self.corners[j * w1 + i + 1];
        let c01 = self.corners[(j + 1) * w1 + i];
        let c11 = self.corners[(j + 1) * w1 + i + 1];
        let p = |k: usize| {
            (1.0 - b) * ((1.0 - a) * c00[k] + a * c10[k]) + b * ((1.0 - a) * c01[k] + a * c11[k])
        };
        (p(0), p(1))
    }

    /// Electron rate per unit etendue of pixel (i, j) before τ and the
    /// flat: the mean over its sample points of the screen's `image`.
    fn mean_rate(&self, i: usize, j: usize, image: &[f32], (sw, sh): (usize, usize)) -> f64 {
        let n = self.cfg.supersample;
        let mut sum = 0.0;
        for sj in 0..n {
            for si in 0..n {
                let a = (si as f64 + 0.5) / n as f64;
                let b = (sj as f64 + 0.5) / n as f64;
                let (u, v) = self.screen_point(i, j, a, b);
                if !(u >= 0.0 && v >= 0.0 && u < sw as f64 && v < sh as f64) {
                    continue; // the screen's bezel: dark
                }
                sum += bilinear(u, v, sw, sh, |p| image[p] as f64);
            }
        }
        sum / (n * n) as f64
    }

    /// The detector (its parameters and PRNU map).
    pub fn sensor(&self) -> &Sensor {
        &self.sensor
    }

    /// Mean signal electrons per pixel, veiling glare and PRNU included
    /// (no dark, no noise, no clipping).
    pub fn expected_electrons(
        &self,
        screen: &ScreenPhysics,
        transmission: f64,
        frames: &[WindowFrame],
        exposure: f64,
    ) -> Vec<f64> {
        let mut signal = self.incident_electrons(screen, transmission, frames, exposure);
        for (s, &g) in signal.iter_mut().zip(self.sensor.prnu_map()) {
            *s *= g as f64;
        }
        signal
    }

    /// Mean electrons per pixel before the detector's PRNU: the screen
    /// through the optics and the vignetting, plus the veiling glare.
    fn incident_electrons(
        &self,
        screen: &ScreenPhysics,
        transmission: f64,
        frames: &[WindowFrame],
        exposure: f64,
    ) -> Vec<f64> {
        let (w, h) = self.size();
        let image = screen_image(screen, frames);
        let [sw, sh] = screen.config().resolution;
        let mut signal: Vec<f64> = (0..w * h)
            .into_par_iter()
            .map(|k| {
                let rate = self.mean_rate(k % w, k / w, &image, (sw, sh));
                exposure * transmission * self.etendue[k] * self.vignetting[k] as f64 * rate
            })
            .collect();
        if self.cfg.veiling_glare > 0.0 {
            let pedestal =
                self.cfg.veiling_glare * signal.iter().sum::<f64>() / signal.len() as f64;
            signal.iter_mut().for_each(|s| *s += pedestal);
        }
        signal
    }

    /// One frame in DN: the incident electrons read out as frame `index`
    /// of the detector ([`crate::sensor::Sensor::expose`]). `seed` must be
    /// the one the model was built with (the sensor's).
    pub fn capture(
        &self,
        screen: &ScreenPhysics,
        transmission: f64,
        frames: &[WindowFrame],
        exposure: f64,
        seed: u64,
        index: u64,
    ) -> Vec<f32> {
        debug_assert_eq!(seed, self.sensor.params().seed, "the model's seed");
        let signal = self.incident_electrons(screen, transmission, frames, exposure);
        // The sensor takes a rate: electrons per second of the exposure.
        let rate: Vec<f32> = signal.iter().map(|&e| (e / exposure) as f32).collect();
        let frame = self.sensor.expose(&rate, exposure, index);
        frame.dn.into_iter().map(f32::from).collect()
    }
}

/// Per screen pixel, ⟨W ∫ S R dλ⟩ over the exposure × U at its centre
/// [e⁻ s⁻¹ m⁻² sr⁻¹]: what the camera's samples interpolate.
fn screen_image(screen: &ScreenPhysics, frames: &[WindowFrame]) -> Vec<f32> {
    let [sw, sh] = screen.config().resolution;
    let rate = &screen.camera_rate_split;
    let (main, leak) = (&screen.pattern.main_map, &screen.pattern.leak_map);
    let mut image = vec![0.0f32; sw * sh];
    image.par_chunks_mut(sw).enumerate().for_each(|(y, row)| {
        for (x, out) in row.iter_mut().enumerate() {
            let p = y * sw + x;
            let (um, ul) = (main[p] as f64, leak[p] as f64);
            let shown: f64 = frames
                .iter()
                .map(|f| f.weight * f.warmup * rate.at(f.levels[p] as usize, um, ul))
                .sum();
            *out = shown as f32;
        }
    });
    image
}

/// Every corner's direction must map back onto its pixel position: a
/// distortion that folds over has no inverse there.
fn check_inverse(optics: &CameraOptics, tans: &[(f64, f64)], w: usize) -> Result<()> {
    let bad = tans.par_iter().enumerate().find_any(|(k, &(x, y))| {
        let (u, v) = optics.project(x, y);
        let (i, j) = ((k % (w + 1)) as f64, (k / (w + 1)) as f64);
        !((u - i).abs() < 1e-6 && (v - j).abs() < 1e-6)
    });
    match bad {
        Some((k, _)) => Err(Error::invalid(
            "camera.k1",
            format!(
                "the distortion (k1, k2, p1, p2) cannot be inverted at pixel corner ({}, {}): it folds over on the detector",
                k % (w + 1),
                k / (w + 1)
            ),
        )),
        None => Ok(()),
    }
}

/// `value` of the screen pixels around continuous position (u, v),
/// interpolated bilinearly between pixel centres (clamped at the edges).
#[inline]
fn bilinear(u: f64, v: f64, w: usize, h: usize, value: impl Fn(usize) -> f64) -> f64 {
    let (x, y) = ((u - 0.5).max(0.0), (v - 0.5).max(0.0));
    let (x0, y0) = ((x as usize).min(w - 1), (y as usize).min(h - 1));
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (a, b) = ((x - x0 as f64).min(1.0), (y - y0 as f64).min(1.0));
    let row = |y: usize| (1.0 - a) * value(y * w + x0) + a * value(y * w + x1);
    (1.0 - b) * row(y0) + b * row(y1)
}

/// The detector parameters of the camera's keys: its dark current, read
/// noise, PRNU, bias, non-linearity, row noise and shot-noise switch, with
/// the facility's `seed` (no DSNU, smear or blooming: the facility camera
/// has none).
pub fn sensor_params(cfg: &CameraTruth, seed: u64) -> SensorParams {
    SensorParams {
        seed,
        dark_current: cfg.dark_current,
        read_noise: cfg.read_noise,
        prnu: cfg.prnu,
        dsnu: 0.0,
        offset: cfg.bias_dn,
        transfer_time: 0.0,
        blooming: false,
        nonlinearity: cfg.nonlinearity,
        row_noise: cfg.row_noise,
        shot_noise: cfg.shot_noise,
    }
}

/// The camera's full well, gain and bits.
pub fn readout(cfg: &CameraTruth) -> Readout {
    Readout {
        full_well: cfg.full_well,
        gain: cfg.gain,
        bits: cfg.bits,
    }
}

/// Quadratic vignetting: `vignetting` at the corner farthest from the
/// principal point.
fn vignetting(cfg: &CameraTruth) -> Vec<f32> {
    let [w, h] = cfg.resolution;
    let corner2 = [
        (0.0, 0.0),
        (w as f64, 0.0),
        (0.0, h as f64),
        (w as f64, h as f64),
    ]
    .iter()
    .map(|(x, y)| (x - cfg.cx).powi(2) + (y - cfg.cy).powi(2))
    .fold(0.0, f64::max)
    .max(1.0);
    (0..w * h)
        .into_par_iter()
        .map(|k| {
            let (x, y) = ((k % w) as f64 + 0.5, (k / w) as f64 + 0.5);
            let r2 = ((x - cfg.cx).powi(2) + (y - cfg.cy).powi(2)) / corner2;
            (1.0 - cfg.vignetting * r2) as f32
        })
        .collect()
}
