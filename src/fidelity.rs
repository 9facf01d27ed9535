//! Render fidelity steps and how their error is measured, shared by the
//! facility's frame-time governor ([`crate::facility::governor`]) and the
//! offline planner of `optistim render`/`bench` ([`crate::planner`]): the
//! settings steps from a configured fidelity down, the finer steps the
//! planner adds above the defaults, the converged reference's settings,
//! the per-pixel and disk-flux errors against it, and the planner's
//! report.

use serde::Serialize;

use crate::render_settings::{Interior, MapFilter, RenderSettings};

/// Caps per pixel along each axis of the converged reference render.
pub const REFERENCE_DENSITY: f64 = 3.0;

/// The looser interior quadrature tolerance of the first coarser step
/// (BENCHMARKS.md, "the interior pixels' quadrature tolerance": −20 to
/// −50 % of the interior stage with the map's error unchanged).
pub const LOOSE_PIXEL_TOLERANCE: f64 = 1e-3;

/// One fidelity step: a label saying what changed, and the settings.
#[derive(Clone, Debug)]
pub struct Step {
    pub label: String,
    pub settings: RenderSettings,
}

/// From `base` down, each step cheaper than the one before: `base`
/// (labelled `first`); the looser interior tolerance; one albedo-map
/// sample per cap instead of k×k. Steps that would not change anything
/// are left out.
pub fn coarser_steps(base: &RenderSettings, first: &str) -> Vec<Step> {
    let mut steps = vec![Step {
        label: first.to_string(),
        settings: base.clone(),
    }];
    let mut loose = base.clone();
    loose.pixel_tolerance = base.pixel_tolerance.max(LOOSE_PIXEL_TOLERANCE);
    if loose.pixel_tolerance > base.pixel_tolerance {
        steps.push(Step {
            label: format!("tolerance {LOOSE_PIXEL_TOLERANCE:e}"),
            settings: loose.clone(),
        });
    }
    if loose.texture_samples > 1 {
        loose.texture_samples = 1;
        steps.push(Step {
            label: format!("tolerance {LOOSE_PIXEL_TOLERANCE:e}, 1 map sample"),
            settings: loose,
        });
    }
    steps
}

/// The offline planner's ladder on `base`'s geometry, caps and lattice,
/// finest first, each step cheaper than the one before (the order of the
/// benchmark's times, BENCHMARKS.md): the exact map mean; 4×4, 3×3 and
/// 2×2 map samples (2×2 is the default); then [`coarser_steps`]. Interior
/// pixels are integrated per pixel in every step.
pub fn planner_ladder(base: &RenderSettings) -> Vec<Step> {
    let mut anchor = base.clone();
    anchor.interior = Interior::Pixels;
    anchor.map_filter = MapFilter::Samples;
    let with = |filter: MapFilter, k: usize| {
        let mut s = anchor.clone();
        s.map_filter = filter;
        s.texture_samples = k;
        s
    };
    let mut steps = vec![
        Step {
            label: "exact map mean".into(),
            settings: with(MapFilter::Exact, 2),
        },
        Step {
            label: "4×4 map samples".into(),
            settings: with(MapFilter::Samples, 4),
        },
        Step {
            label: "3×3 map samples".into(),
            settings: with(MapFilter::Samples, 3),
        },
    ];
    let default = with(MapFilter::Samples, 2);
    steps.extend(
        coarser_steps(&default, "2×2 map samples")
            .into_iter()
            .enumerate()
            .map(|(i, mut s)| {
                if i > 0 {
                    s.label = format!("2×2 map samples, {}", s.label);
                }
                s
            }),
    );
    steps
}

/// Settings of the converged reference: the lune's caps everywhere at
/// [`REFERENCE_DENSITY`] per pixel and axis, exact map means.
pub fn reference_settings(base: &RenderSettings) -> RenderSettings {
    let mut s = base.clone();
    s.caps_per_pixel = Some(REFERENCE_DENSITY);
    s.min_caps = s.min_caps.max(256);
    s.interior = Interior::Caps;
    s.map_filter = MapFilter::Exact;
    s
}

/// The 99th percentile of |image / reference − 1| over the pixels `k`
/// where the reference is above `floor` × its peak and `include(k)`
/// holds; 0 when there are none.
pub fn pixel_error_p99(
    image: &[f32],
    reference: &[f32],
    floor: f32,
    include: impl Fn(usize) -> bool,
) -> f64 {
    let peak = reference.iter().copied().fold(0.0f32, f32::max);
    if !(peak > 0.0) {
        return 0.0;
    }
    let mut errors: Vec<f64> = image
        .iter()
        .zip(reference)
        .enumerate()
        .filter(|&(k, (_, &r))| r > floor * peak && include(k))
        .map(|(_, (&a, &r))| (a as f64 / r as f64 - 1.0).abs())
        .collect();
    errors.sort_by(f64::total_cmp);
    errors
        .get((errors.len() * 99 / 100).min(errors.len().saturating_sub(1)))
        .copied()
        .unwrap_or(0.0)
}

/// |Σ image / Σ reference − 1|: the disk-flux error; 0 for an empty
/// reference.
pub fn flux_error(image: &[f32], reference: &[f32]) -> f64 {
    let sum = |v: &[f32]| v.iter().map(|&x| x as f64).sum::<f64>();
    let r = sum(reference);
    if !(r > 0.0) {
        return 0.0;
    }
    (sum(image) / r - 1.0).abs()
}

/// What one step of the planner's ladder measured on a scene
/// ([`crate::planner`]).
#[derive(Clone, Debug, Serialize)]
pub struct StepMeasure {
    pub step: usize,
    pub label: String,
    /// p99 of the interior pixels' relative error (the planned error).
    pub interior_pixel_error_p99: f64,
    /// p99 over all pixels above the floor, edges included.
    pub pixel_error_p99: f64,
    /// |Σ render / Σ converged − 1|.
    pub flux_error: f64,
    /// Its render time, ms (one render; for orientation only: the choice
    /// follows the ladder's order, not this time).
    pub render_ms: f64,
}

/// The plan: the settings chosen, their measured error and why (the
/// `plan` of a render's `summary.json`).
#[derive(Clone, Debug, Serialize)]
pub struct Plan {
    /// The target, and the key or flag it came from.
    pub max_pixel_error: f64,
    pub source: String,
    /// The chosen step (0 the finest of the ladder) and its label.
    pub step: usize,
    pub label: String,
    pub settings: RenderSettings,
    /// Which pixels `predicted_pixel_error` is taken over: `"interior"`
    /// (the pixels integrated per pixel) or `"disk"` (every disk pixel,
    /// where the caps draw most of them).
    pub judged: String,
    /// Its measured p99 over the judged pixels, all-pixel p99 and
    /// disk-flux error against the converged render: the errors this
    /// render is predicted to have.
    pub predicted_pixel_error: f64,
    pub predicted_pixel_error_all: f64,
    pub predicted_flux_error: f64,
    /// One sentence: why these settings.
    pub why: String,
    /// The ladder's labels, finest first.
    pub ladder: Vec<String>,
    /// The steps measured, coarsest first.
    pub measured: Vec<StepMeasure>,
    /// The converged render's caps per pixel and map parts per cap and
    /// axis (each part the map's exact mean).
    pub reference_caps_per_pixel: f64,
    pub reference_map_parts: usize,
    /// Time spent planning (the converged render and the steps), ms.
    pub planning_ms: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn p99_and_flux_error_by_hand() {
        // 200 pixels of reference 1: 198 exact, two 10 % high; one dark
        // pixel (below the floor) 100 % off is left out.
        let reference: Vec<f32> = (0..201)
            .map(|k| if k == 200 { 0.001 } else { 1.0 })
            .collect();
        let mut image = reference.clone();
        image[3] = 1.1;
        image[7] = 1.1;
        image[200] = 0.002;
        // Index 198 of the 200 sorted errors: the first of the two 10 %.
        assert!((pixel_error_p99(&image, &reference, 0.01, |_| true) - 0.1).abs() < 1e-6);
        // Leaving out pixel 3 and 7: no error.
        assert_eq!(
            pixel_error_p99(&image, &reference, 0.01, |k| k != 3 && k != 7),
            0.0
        );
        let expected = (200.0 + 0.2 + 0.002) / (200.0 + 0.001) - 1.0;
        assert!((flux_error(&image, &reference) - expected).abs() < 1e-9);
    }

    #[test]
    fn ladders_step_down_from_finest() {
        let base = RenderSettings::default();
        let l = planner_ladder(&base);
        assert_eq!(l[0].settings.map_filter, MapFilter::Exact);
        let k: Vec<usize> = l.iter().map(|s| s.settings.texture_samples).collect();
        assert_eq!(k, [2, 4, 3, 2, 2, 1]);
        assert_eq!(l[3].settings, base);
        assert_eq!(l[4].settings.pixel_tolerance, LOOSE_PIXEL_TOLERANCE);
        // Nothing to loosen: one step.
        let mut fine = base.clone();
        fine.pixel_tolerance = 1e-2;
        fine.texture_samples = 1;
        assert_eq!(coarser_steps(&fine, "x").len(), 1);
    }
}
