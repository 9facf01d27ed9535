//! The governor's pre-flight: before the first frame, every rung of the
//! ladder renders states spanning the run's range of apparent sizes; the
//! times give each rung's cost model and the images, compared with a
//! converged render of the same state (the lune's caps at
//! [`REFERENCE_DENSITY`]² per pixel, the map's exact footprint means), its
//! per-pixel and disk-flux error ([`crate::facility::governor`]).

use std::time::Instant;

use super::screen::ScreenModel;
use crate::facility::config::FacilityConfig;
use crate::facility::geometry::GeometryCalibration;
use crate::facility::governor::{ladder, ladder_with_relief, Rung, RungProfile, Sample};
use crate::scene::{Scene, State};

pub use crate::fidelity::{reference_settings, REFERENCE_DENSITY};

/// States profiled per rung.
const SAMPLE_STATES: usize = 5;
/// Renders per state and rung; the fastest counts (the others absorb
/// first-use costs and the machine's noise).
const REPEATS: usize = 2;
/// Pixels below this fraction of the finest render's peak are left out of
/// the per-pixel error (the dark side and the sky).
const PIXEL_FLOOR: f32 = 0.05;

/// Apparent disk area of the body in `state`, screen px², for a screen of
/// `f_px` pixels per unit tangent.
pub fn apparent_area(scene: &Scene, state: &State, f_px: f64) -> f64 {
    let d = (state.body_position - state.camera_position).length();
    let r = scene.body.radius;
    if !(d > r) {
        return f64::INFINITY;
    }
    let tan = r / (d * d - r * r).sqrt();
    std::f64::consts::PI * (f_px * tan).powi(2)
}

/// Up to [`SAMPLE_STATES`] of `states` at evenly spaced quantiles of their
/// apparent area (smallest and largest included).
pub fn sample_states(states: &[State], scene: &Scene, f_px: f64) -> Vec<State> {
    let mut by_area: Vec<(f64, State)> = states
        .iter()
        .map(|s| (apparent_area(scene, s, f_px), *s))
        .filter(|(a, _)| a.is_finite())
        .collect();
    by_area.sort_by(|a, b| a.0.total_cmp(&b.0));
    if by_area.len() <= SAMPLE_STATES {
        return by_area.into_iter().map(|x| x.1).collect();
    }
    let last = by_area.len() - 1;
    (0..SAMPLE_STATES)
        .map(|i| by_area[i * last / (SAMPLE_STATES - 1)].1)
        .collect()
}

/// States of the scene's own geometry with the camera moved along its line
/// of sight so the body spans 1/16 to 4 × its apparent area: the sizes a
/// closed loop may bring, when no trajectory says.
pub fn scaled_states(state: &State) -> Vec<State> {
    [4.0, 2.0, 1.0, 0.5, 0.25]
        .iter()
        .map(|&k| {
            let mut s = *state;
            s.camera_position = s.body_position + (s.camera_position - s.body_position) * k;
            s
        })
        .collect()
}

/// One model per rung of the ladder of `config` (finest first).
pub fn rung_models(
    config: &FacilityConfig,
    scene: &Scene,
    geometry: Option<&GeometryCalibration>,
) -> (Vec<Rung>, Vec<ScreenModel>) {
    // A body with relief: rungs without it below the configured block's.
    let ladder = if scene.body.relief.shadows.is_some() {
        ladder_with_relief
    } else {
        ladder
    };
    let rungs = ladder(
        &scene.render,
        config.screen.render_block,
        config
            .timing
            .governor_max_block
            .max(config.screen.render_block),
    );
    let models = rungs
        .iter()
        .map(|r| ScreenModel::with_fidelity(config, scene, geometry, r.block, r.settings.clone()))
        .collect();
    (rungs, models)
}

/// The converged reference model of `config`'s screen.
pub fn reference_model(
    config: &FacilityConfig,
    scene: &Scene,
    geometry: Option<&GeometryCalibration>,
) -> ScreenModel {
    let settings = reference_settings(&scene.render);
    ScreenModel::with_fidelity(
        config,
        scene,
        geometry,
        config.screen.render_block,
        settings,
    )
}

/// Profiles every rung on `samples`: times, and errors against the
/// converged `reference` render of each state.
pub fn profile(
    rungs: Vec<Rung>,
    models: &mut [ScreenModel],
    reference: &mut ScreenModel,
    scene: &Scene,
    samples: &[State],
    f_px: f64,
) -> Vec<RungProfile> {
    let mut per_rung: Vec<Vec<Sample>> = vec![Vec::new(); models.len()];
    for state in samples {
        let area_px = apparent_area(scene, state, f_px);
        reference.render(scene, state);
        let truth = screen_image(reference);
        for (i, model) in models.iter_mut().enumerate() {
            let seconds = fastest_render(model, scene, state);
            let (pixel_error, flux_error) = compare(&screen_image(model), &truth);
            per_rung[i].push(Sample {
                area_px,
                seconds,
                pixel_error,
                flux_error,
            });
        }
    }
    rungs
        .into_iter()
        .zip(per_rung)
        .map(|(r, s)| RungProfile::new(r, s))
        .collect()
}

/// The fastest of [`REPEATS`] renders of `state`, s.
fn fastest_render(model: &mut ScreenModel, scene: &Scene, state: &State) -> f64 {
    (0..REPEATS)
        .map(|_| {
            let t = Instant::now();
            model.render(scene, state);
            t.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
}

/// The last render's radiance over the whole screen, row-major.
pub fn screen_image(model: &ScreenModel) -> Vec<f32> {
    let (w, h) = model.screen;
    let mut image = vec![0.0f32; w * h];
    if let Some(roi) = model.last_roi() {
        for (k, &v) in model.target().iter().enumerate() {
            let (x, y) = (roi.x + k % roi.width, roi.y + k / roi.width);
            image[y * w + x] = v;
        }
    }
    image
}

/// (p99 of |image / reference − 1| over the reference's pixels above
/// [`PIXEL_FLOOR`] of its peak, |Σ image / Σ reference − 1|).
pub fn compare(image: &[f32], reference: &[f32]) -> (f64, f64) {
    (
        crate::fidelity::pixel_error_p99(image, reference, PIXEL_FLOOR, |_| true),
        crate::fidelity::flux_error(image, reference),
    )
}
