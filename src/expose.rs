//! Exposure bounds for camera sizing (`optistim expose`): from the
//! electron rate S of a chosen image feature, the exposures t in which the
//! feature sits between the noise floor at a stated SNR and saturation.
//!
//! With the sensor's temporal noise (EMVA 1288: dark current D, read noise
//! σ_r, quantisation 1/12 DN² = 1/(12 K²) e⁻²; none of them for the ideal
//! detector but the quantisation),
//!
//! SNR(t) = S t / √(S t + D t + σ²),  σ² = σ_r² + 1/(12 K²),
//!
//! so SNR(t) = n at the positive root of S² t² − n² (S + D) t − n² σ² = 0,
//! the lower bound; the upper is (S + D) t = the saturation charge, the
//! full well or what fits the ADC above the offset, min(FW, (2^bits − 1 −
//! offset)/K), whichever is smaller.

use serde::Serialize;

use crate::error::{Error, Result};
use crate::render::detector::{render_scene, PixelGeometry};
use crate::render::Renderer;
use crate::scene::{Camera, Scene, State};

/// Which pixel statistic of the rendered electron rate the bounds are for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Feature {
    /// Mean over the pixels with signal.
    DiskMean,
    /// The brightest pixel.
    Brightest,
    /// The darkest pixel with signal (at least 1 % of the brightest, so
    /// limb pixels the disk barely touches do not count).
    DarkestLit,
}

impl Feature {
    /// `disk-mean`, `brightest` or `darkest-lit`.
    pub fn parse(name: &str) -> Result<Feature> {
        match name {
            "disk-mean" => Ok(Feature::DiskMean),
            "brightest" => Ok(Feature::Brightest),
            "darkest-lit" => Ok(Feature::DarkestLit),
            other => Err(Error::invalid(
                "--feature",
                format!("unknown feature {other:?}: use disk-mean, brightest or darkest-lit"),
            )),
        }
    }

    /// The feature's name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Feature::DiskMean => "disk-mean",
            Feature::Brightest => "brightest",
            Feature::DarkestLit => "darkest-lit",
        }
    }

    /// The feature's electron rate [e⁻/s] in a rate image; None when no
    /// pixel has signal.
    pub fn rate(self, rate: &[f32]) -> Option<f64> {
        let peak = rate.iter().copied().fold(0.0f32, f32::max) as f64;
        if !(peak > 0.0) {
            return None;
        }
        let lit = rate.iter().map(|&r| r as f64).filter(|&r| r > 0.0);
        Some(match self {
            Feature::Brightest => peak,
            Feature::DiskMean => {
                let (sum, n) = lit.fold((0.0, 0usize), |(s, n), r| (s + r, n + 1));
                sum / n as f64
            }
            Feature::DarkestLit => lit.filter(|&r| r >= 0.01 * peak).fold(peak, f64::min),
        })
    }
}

/// The camera's temporal noise and saturation, in electrons.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct NoiseModel {
    /// Dark current [e⁻/s].
    pub dark_current: f64,
    /// σ² = σ_r² + 1/(12 K²) [e⁻²].
    pub floor_variance: f64,
    /// Charge at saturation [e⁻]: min(full well, ADC range above offset / K).
    pub saturation: f64,
}

impl NoiseModel {
    /// The camera's: its `[camera.sensor]`, or the ideal detector's
    /// quantisation alone.
    pub fn of(camera: &Camera) -> NoiseModel {
        let (dark, read, offset) = camera.sensor.map_or((0.0, 0.0, 0.0), |s| {
            (s.dark_current, s.read_noise, s.offset)
        });
        let k = camera.gain;
        NoiseModel {
            dark_current: dark,
            floor_variance: read * read + 1.0 / (12.0 * k * k),
            saturation: camera.full_well.min((camera.max_dn() - offset) / k),
        }
    }

    /// The exposure range for a feature of rate `rate` [e⁻/s] at `snr`.
    pub fn bounds(&self, rate: f64, snr: f64) -> Bounds {
        let (s, d, n2) = (rate, self.dark_current, snr * snr);
        let b = n2 * (s + d);
        let t_min = (b + (b * b + 4.0 * s * s * n2 * self.floor_variance).sqrt()) / (2.0 * s * s);
        Bounds {
            rate,
            t_min,
            t_max: self.saturation / (s + d),
        }
    }
}

/// The exposures [s] between the noise floor and saturation.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Bounds {
    /// The feature's electron rate [e⁻/s].
    pub rate: f64,
    /// Shortest exposure reaching the SNR [s].
    pub t_min: f64,
    /// Longest exposure before saturation [s].
    pub t_max: f64,
}

impl Bounds {
    /// Whether any exposure works.
    pub fn is_open(&self) -> bool {
        self.t_min <= self.t_max
    }
}

/// One state's bounds.
#[derive(Clone, Debug, Serialize)]
pub struct StateBounds {
    /// State time [s] (0 for a scene file's state).
    pub t: f64,
    /// Camera–body distance [m].
    pub range_m: f64,
    /// Phase angle at the body centre [deg].
    pub phase_deg: f64,
    /// None when no pixel has signal (the body out of the field or unlit).
    pub bounds: Option<Bounds>,
}

/// Renders every state of `states` (time, state) with the scene's camera,
/// Sun and body and bounds the exposure of `feature` at `snr`.
pub fn expose_states(
    scene: &Scene,
    states: &[(f64, State)],
    feature: Feature,
    snr: f64,
) -> Result<Vec<StateBounds>> {
    if !(snr.is_finite() && snr > 0.0 && snr <= 1e6) {
        return Err(Error::invalid(
            "--snr",
            format!("must be in (0, 1e6], got {snr}"),
        ));
    }
    let noise = NoiseModel::of(&scene.camera);
    let mut renderer = Renderer::new(scene.camera.render_pinhole().clone());
    let pixels = PixelGeometry::new(&renderer);
    let mut scene = scene.clone();
    // The sensor's DN is not needed: only the mean rate.
    scene.camera.sensor = None;
    let mut out = Vec::with_capacity(states.len());
    for (i, &(t, state)) in states.iter().enumerate() {
        state.check(scene.body.radius, &format!("state {i} (t = {t} s)"))?;
        scene.state = state;
        let images = render_scene(&scene, &mut renderer, &pixels)?;
        out.push(StateBounds {
            t,
            range_m: (state.camera_position - state.body_position).length(),
            phase_deg: images.summary.phase_angle_deg,
            bounds: feature
                .rate(&images.electron_rate)
                .map(|r| noise.bounds(r, snr)),
        });
    }
    Ok(out)
}

/// The exposures that serve every state: [max t_min, min t_max]; None when
/// a state has no signal or the range is empty.
pub fn common_window(states: &[StateBounds]) -> Option<(f64, f64)> {
    let mut window = (0.0f64, f64::INFINITY);
    for s in states {
        let b = s.bounds?;
        window = (window.0.max(b.t_min), window.1.min(b.t_max));
    }
    (window.0 <= window.1 && !states.is_empty()).then_some(window)
}
