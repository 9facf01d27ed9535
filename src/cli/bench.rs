//! `optistim bench`: time against error for a sweep of render settings,
//! each against the converged reference of its phase (the lune's caps at
//! 4× the densest density, with the exact map filter on every part).

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result};
use glam::{DQuat, DVec3};
use serde::Serialize;

use optistim::render::{output, Interior, MapFilter, RenderSettings, Renderer};
use optistim::scene::{Pinhole, Scene};

use super::bench_plot;

#[derive(Serialize)]
pub(crate) struct BenchRow {
    pub(crate) phase_deg: f64,
    pub(crate) interior: Interior,
    pub(crate) caps_per_pixel: f64,
    pub(crate) texture_samples: usize,
    pub(crate) map_filter: MapFilter,
    /// The adaptive filter's threshold (the scene's with other filters).
    pub(crate) map_tolerance: f64,
    pub(crate) node_spacing: usize,
    pub(crate) pixel_tolerance: f64,
    pub(crate) interior_pixels: usize,
    /// Interior pixels evaluated directly, by quadrature rule.
    pub(crate) interior_direct: optistim::render::interior::DirectCounts,
    pub(crate) caps: u64,
    /// Caps integrated: laid out and not wholly on interior pixels.
    pub(crate) caps_integrated: u64,
    pub(crate) median_ms: f64,
    pub(crate) p90_ms: f64,
    pub(crate) flux_error: f64,
    pub(crate) pixel_error_p50: f64,
    pub(crate) pixel_error_p99: f64,
    pub(crate) pixel_error_max: f64,
    /// p99 over the interior pixels alone (integrated per pixel; NaN with
    /// `interior = "caps"`): the map filter's share, without the edges.
    pub(crate) interior_error_p99: f64,
    /// Median wall time of each stage: layout, mask, caps, interior [ms].
    pub(crate) stage_median_ms: [f64; 4],
    /// This setting's image under `--images DIR` (file name in DIR).
    pub(crate) image: Option<String>,
    /// With `--max-pixel-error`: the planner's step and the interior p99 it
    /// measured against its own converged render.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) planned: Option<PlannedStep>,
}

/// The planner's choice behind a bench row.
#[derive(Serialize)]
pub(crate) struct PlannedStep {
    pub(crate) max_pixel_error: f64,
    pub(crate) label: String,
    pub(crate) predicted_pixel_error: f64,
    pub(crate) why: String,
}

/// `bench --images`: one render as radiance per unit solar irradiance at
/// 1 au (flux over the pixel's exact solid angle), an f32 TIFF, so other
/// renderers (tools/mitsuba_moon.py) can be compared pixel by pixel.
fn save_bench_image(
    dir: &Path,
    name: &str,
    flux: &[f32],
    solid_angle: &[f32],
    pin: &Pinhole,
) -> Result<()> {
    let radiance: Vec<f32> = flux
        .iter()
        .zip(solid_angle)
        .map(|(&f, &o)| if o > 0.0 { f / o } else { 0.0 })
        .collect();
    let path = dir.join(format!("{name}.tiff"));
    output::write_f32_tiff(&path, pin.width, pin.height, &radiance)
        .with_context(|| format!("writing {}", path.display()))
}

/// `bench --images`: the geometry of one phase (the camera moved by
/// `at_phase`) and the pinhole, as JSON, so another renderer sees the same
/// scene.
fn write_bench_state(dir: &Path, phase: f64, scene: &Scene) -> Result<()> {
    let st = &scene.state;
    let pin = &scene.camera.pinhole;
    let quat = |q: DQuat| [q.w, q.x, q.y, q.z];
    let state = serde_json::json!({
        "phase_deg": phase,
        "width": pin.width, "height": pin.height,
        "fx": pin.fx, "fy": pin.fy, "cx": pin.cx, "cy": pin.cy,
        "body_position": st.body_position.to_array(),
        "body_attitude": quat(st.body_attitude),
        "camera_position": st.camera_position.to_array(),
        "camera_attitude": quat(st.camera_attitude),
        "sun_position": st.sun_position.to_array(),
    });
    let path = dir.join(format!("phase{phase}_state.json"));
    std::fs::write(&path, serde_json::to_string_pretty(&state)?)
        .with_context(|| format!("writing {}", path.display()))
}

/// Place the camera so that the phase angle at the body is `phase_deg`,
/// keeping its range and pointing it at the body centre.
pub(crate) fn at_phase(scene: &mut Scene, phase_deg: f64) {
    let st = &mut scene.state;
    let range = (st.camera_position - st.body_position).length();
    let sun_dir = (st.sun_position - st.body_position).normalize();
    let pole = sun_dir.any_orthonormal_vector();
    let view = DQuat::from_axis_angle(pole, phase_deg.to_radians()) * sun_dir;
    st.camera_position = st.body_position + view * range;
    let boresight = -view;
    let up_hint = if boresight.cross(DVec3::Z).length() > 1e-6 {
        DVec3::Z
    } else {
        DVec3::X
    };
    let x = boresight.cross(up_hint).normalize();
    let y = boresight.cross(x);
    st.camera_attitude = DQuat::from_mat3(&glam::DMat3::from_cols(x, y, boresight)).normalize();
}

/// The map filter's column suffix: ` exact`, or ` adaptive THRESHOLD`
/// with the fraction of interior pixels whose mean went exact.
fn filter_label(filter: MapFilter, threshold: f64, exact: usize, interior: usize) -> String {
    match filter {
        MapFilter::Samples => String::new(),
        MapFilter::Exact => " exact".into(),
        MapFilter::Adaptive => format!(
            " adaptive {threshold:.0e} ({:.1} % exact)",
            100.0 * exact as f64 / interior.max(1) as f64
        ),
    }
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let k = ((sorted.len() - 1) as f64 * p).round() as usize;
    sorted[k]
}

/// The settings `optistim bench` times: every combination of them at each
/// phase (empty lists: the scene's setting).
pub struct BenchSweep {
    /// Phase angles [deg].
    pub phases: Vec<f64>,
    /// Caps per pixel.
    pub densities: Vec<f64>,
    /// `pixels` and/or `caps`.
    pub interior: Vec<String>,
    /// Map samples per axis.
    pub texture_samples: Vec<usize>,
    /// `exact` and/or `samples`.
    pub map_filters: Vec<String>,
    /// Interior node-lattice spacings [px].
    pub node_spacings: Vec<usize>,
    /// Interior pixel quadrature tolerances.
    pub pixel_tolerances: Vec<f64>,
    /// Adaptive map filter thresholds (only with `adaptive`).
    pub map_tolerances: Vec<f64>,
    /// The reference's caps per pixel; None: 4× the densest timed.
    pub reference_density: Option<f64>,
    /// A per-pixel error target: at each phase the planner's settings
    /// alone are timed (`crate::planner`), in place of the sweep.
    pub max_pixel_error: Option<f64>,
}

/// The values given on the command line, or the scene's own when none.
fn swept_or_scene<'a, T>(given: &'a [T], scene: &'a [T; 1]) -> &'a [T] {
    if given.is_empty() {
        scene
    } else {
        given
    }
}

/// One timed setting of the sweep.
#[derive(Clone, Copy)]
struct Point {
    mode: Interior,
    density: f64,
    samples: usize,
    filter: MapFilter,
    /// The adaptive filter's threshold (the scene's with other filters).
    map_tolerance: f64,
    spacing: usize,
    tolerance: f64,
}

impl Point {
    /// The point of the settings `s`.
    fn of(s: &RenderSettings) -> Point {
        Point {
            mode: s.interior,
            density: s.density(),
            samples: s.texture_samples,
            filter: s.map_filter,
            map_tolerance: s.map_tolerance,
            spacing: s.node_spacing,
            tolerance: s.pixel_tolerance,
        }
    }

    /// `settings` for this point (the scene's `min_caps`).
    fn apply(&self, settings: &mut RenderSettings, min_caps: usize) -> Result<()> {
        settings.map_filter = self.filter;
        settings.map_tolerance = self.map_tolerance;
        settings.node_spacing = self.spacing;
        settings.pixel_tolerance = self.tolerance;
        settings.caps_per_pixel = Some(self.density);
        settings.min_caps = min_caps;
        settings.interior = self.mode;
        settings.texture_samples = self.samples;
        settings.check()?;
        Ok(())
    }
}

fn parse_filter(name: &str) -> Result<MapFilter> {
    match name {
        "exact" => Ok(MapFilter::Exact),
        "samples" => Ok(MapFilter::Samples),
        "adaptive" => Ok(MapFilter::Adaptive),
        other => Err(anyhow::anyhow!(
            "--map-filter: `{other}`: expected exact, samples or adaptive"
        )),
    }
}

fn parse_interior(name: &str) -> Result<Interior> {
    match name {
        "pixels" => Ok(Interior::Pixels),
        "caps" => Ok(Interior::Caps),
        other => Err(anyhow::anyhow!(
            "--interior: `{other}`: expected pixels or caps"
        )),
    }
}

impl BenchSweep {
    /// Every combination of the swept settings, the scene's where a list
    /// is empty; the map thresholds apply to the adaptive filter only.
    fn points(&self, base: &Scene) -> Result<Vec<Point>> {
        let modes = self
            .interior
            .iter()
            .map(|m| parse_interior(m))
            .collect::<Result<Vec<_>>>()?;
        let filters = self
            .map_filters
            .iter()
            .map(|m| parse_filter(m))
            .collect::<Result<Vec<_>>>()?;
        let r = &base.render;
        let filters = swept_or_scene(&filters, &[r.map_filter]).to_vec();
        let samples = swept_or_scene(&self.texture_samples, &[r.texture_samples]).to_vec();
        let spacings = swept_or_scene(&self.node_spacings, &[r.node_spacing]).to_vec();
        let tolerances = swept_or_scene(&self.pixel_tolerances, &[r.pixel_tolerance]).to_vec();
        let map_tolerances = swept_or_scene(&self.map_tolerances, &[r.map_tolerance]).to_vec();
        let mut points = Vec::new();
        for &mode in &modes {
            for &density in &self.densities {
                for &k in &samples {
                    for &filter in &filters {
                        let thresholds = if filter == MapFilter::Adaptive {
                            &map_tolerances[..]
                        } else {
                            std::slice::from_ref(&r.map_tolerance)
                        };
                        for &map_tolerance in thresholds {
                            for &spacing in &spacings {
                                for &tolerance in &tolerances {
                                    points.push(Point {
                                        mode,
                                        density,
                                        samples: k,
                                        filter,
                                        map_tolerance,
                                        spacing,
                                        tolerance,
                                    });
                                }
                            }
                        }
                    }
                }
            }
        }
        Ok(points)
    }
}

/// The converged reference of `scene`: the lune's caps at `density` per
/// pixel, each part taking the map's exact mean (no sampling error of its
/// own).
fn reference_flux(renderer: &mut Renderer, scene: &Scene, density: f64) -> Result<Vec<f32>> {
    let mut settings = scene.render.clone();
    settings.caps_per_pixel = Some(density);
    settings.min_caps = settings.min_caps.max(256);
    settings.interior = Interior::Caps;
    settings.map_filter = MapFilter::Exact;
    settings.check().context("--reference-density")?;
    renderer.render_flux(&scene.body, &scene.state, &settings, None);
    Ok(renderer.flux().to_vec())
}

/// Medians of `repeats` renders of one setting.
struct Timing {
    median_ms: f64,
    p90_ms: f64,
    stage_median_ms: [f64; 4],
    stats: optistim::render::RenderStats,
}

fn time_renders(
    renderer: &mut Renderer,
    scene: &Scene,
    settings: &RenderSettings,
    repeats: usize,
) -> Timing {
    let mut times = Vec::with_capacity(repeats);
    let mut stages: [Vec<f64>; 4] = Default::default();
    let mut last = None;
    for _ in 0..repeats.max(1) {
        let t = Instant::now();
        let stats = renderer.render_flux(&scene.body, &scene.state, settings, None);
        times.push(t.elapsed().as_secs_f64() * 1e3);
        let st = stats.stages;
        for (v, x) in stages
            .iter_mut()
            .zip([st.layout, st.mask, st.caps, st.interior])
        {
            v.push(x * 1e3);
        }
        last = Some(stats);
    }
    times.sort_by(f64::total_cmp);
    Timing {
        median_ms: percentile(&times, 0.5),
        p90_ms: percentile(&times, 0.9),
        stage_median_ms: stages.map(|mut v| {
            v.sort_by(f64::total_cmp);
            percentile(&v, 0.5)
        }),
        stats: last.expect("at least one render"),
    }
}

/// Sorted per-pixel relative errors of `flux` against `reference` over the
/// pixels above 1 % of the reference's peak: all of them, and (with
/// `interior = "pixels"`) those integrated per pixel alone.
fn pixel_errors(
    flux: &[f32],
    reference: &[f32],
    renderer: &Renderer,
    mode: Interior,
) -> (Vec<f64>, Vec<f64>) {
    let width = renderer.camera().width;
    let peak = reference.iter().cloned().fold(0.0f32, f32::max) as f64;
    let (mut all, mut interior) = (Vec::new(), Vec::new());
    for (k, (&v, &r)) in flux.iter().zip(reference).enumerate() {
        if (r as f64) <= 0.01 * peak {
            continue;
        }
        let e = ((v - r) as f64 / r as f64).abs();
        all.push(e);
        if mode == Interior::Pixels && renderer.is_interior_pixel(k % width, k / width) {
            interior.push(e);
        }
    }
    all.sort_by(f64::total_cmp);
    interior.sort_by(f64::total_cmp);
    (all, interior)
}

impl BenchRow {
    fn new(
        phase: f64,
        p: &Point,
        t: &Timing,
        flux_error: f64,
        errors: (Vec<f64>, Vec<f64>),
    ) -> Self {
        let (all, interior) = errors;
        let s = &t.stats;
        BenchRow {
            phase_deg: phase,
            interior: p.mode,
            caps_per_pixel: p.density,
            texture_samples: p.samples,
            map_filter: p.filter,
            map_tolerance: p.map_tolerance,
            node_spacing: p.spacing,
            pixel_tolerance: p.tolerance,
            interior_pixels: s.interior_pixels,
            interior_direct: s.interior_direct,
            caps: s.caps,
            caps_integrated: s.caps_integrated,
            median_ms: t.median_ms,
            p90_ms: t.p90_ms,
            flux_error,
            pixel_error_p50: percentile(&all, 0.5),
            pixel_error_p99: percentile(&all, 0.99),
            pixel_error_max: all.last().copied().unwrap_or(f64::NAN),
            interior_error_p99: percentile(&interior, 0.99),
            stage_median_ms: t.stage_median_ms,
            image: None,
            planned: None,
        }
    }

    /// The row of the printed table.
    fn markdown(&self) -> String {
        let [lay, mask, cap, int] = self.stage_median_ms;
        let k = self.texture_samples;
        let filter = filter_label(
            self.map_filter,
            self.map_tolerance,
            self.interior_direct.map_exact,
            self.interior_pixels,
        );
        format!(
            "| {:.0} | {:?} | {} | {k}×{k}{filter} | {} | {:.0e} | {} | {} | {} | {:.2} | {:.2} | {lay:.2} / {mask:.2} / {cap:.2} / {int:.2} | {:.1e} | {:.2e} | {:.2e} | {:.2e} | {:.2e} |",
            self.phase_deg,
            self.interior,
            self.caps_per_pixel,
            self.node_spacing,
            self.pixel_tolerance,
            self.caps,
            self.caps_integrated,
            self.interior_pixels,
            self.median_ms,
            self.p90_ms,
            self.flux_error,
            self.pixel_error_p50,
            self.pixel_error_p99,
            self.pixel_error_max,
            self.interior_error_p99
        )
    }
}

fn total(flux: &[f32]) -> f64 {
    flux.iter().map(|&v| v as f64).sum()
}

/// `optistim bench`: time against error for every setting of `sweep` at
/// each phase, against that phase's converged reference; prints a table,
/// and writes it as JSON, a figure and the images where asked.
pub fn bench(
    scene_path: &Path,
    sweep: &BenchSweep,
    repeats: usize,
    json: Option<&Path>,
    plot: Option<&Path>,
    images: Option<&Path>,
    overwrite: bool,
) -> Result<()> {
    // Refused before the timing, not after it.
    let mut outputs: Vec<_> = json.map(Path::to_path_buf).into_iter().collect();
    if let Some(plot) = plot {
        outputs.push(bench_plot::figure_path(plot)?);
    }
    optistim::outfile::check_no_earlier(&outputs, overwrite)?;
    let base = Scene::from_file(scene_path)?;
    let points = sweep.points(&base)?;
    if let Some(t) = sweep.max_pixel_error {
        optistim::render_settings::check_pixel_error_target("--max-pixel-error", t)?;
    }
    let pin = base.camera.pinhole.clone();
    let mut renderer = Renderer::new(pin.clone());
    let solid_angle = images.map(|_| pin.solid_angle_table());
    if let Some(dir) = images {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    println!(
        "machine: {} threads; image {}x{}; model {}",
        rayon::current_num_threads(),
        pin.width,
        pin.height,
        base.body.reflectance.name()
    );
    println!("| phase [deg] | interior | caps/px | map samples | node spacing | pixel tol. | caps | integrated | interior px | median [ms] | p90 [ms] | layout / mask / caps / interior [ms] | flux error | pixel err p50 | p99 | max | interior p99 |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    // Reference: 16× the caps of the densest setting (4× per axis).
    let planning = optistim::planner::target(sweep.max_pixel_error, &base).is_some();
    let densest = if planning {
        base.render.density()
    } else {
        sweep.densities.iter().cloned().fold(0.0, f64::max)
    };
    let ref_density = sweep.reference_density.unwrap_or(4.0 * densest);
    // One step per reference render and per timed setting.
    let per_phase = if planning { 1 } else { points.len() };
    let steps = sweep.phases.len() * (per_phase + 1);
    let progress = optistim::progress::bar(steps as u64, "bench");
    let mut rows: Vec<BenchRow> = Vec::new();
    for &phase in &sweep.phases {
        progress.set_message(format!("{phase}° reference"));
        let mut scene = base.clone();
        at_phase(&mut scene, phase);
        let reference = reference_flux(&mut renderer, &scene, ref_density)?;
        progress.inc(1);
        if let (Some(dir), Some(omega)) = (images, &solid_angle) {
            write_bench_state(dir, phase, &scene)?;
            save_bench_image(dir, &format!("phase{phase}_ref"), &reference, omega, &pin)?;
        }
        let plan = match optistim::planner::target(sweep.max_pixel_error, &scene) {
            Some((target, source)) => {
                progress.set_message(format!("{phase}° planning"));
                let plan = optistim::planner::Planner::new(&scene)
                    .plan(target, source)
                    .with_context(|| format!("{}", scene_path.display()))?;
                progress.suspend(|| println!("{phase}°: planned: {}", plan.why));
                Some(plan)
            }
            None => None,
        };
        let planned_points = plan.as_ref().map(|p| vec![Point::of(&p.settings)]);
        let mut settings = scene.render.clone();
        for p in planned_points.as_ref().unwrap_or(&points) {
            p.apply(&mut settings, scene.render.min_caps)?;
            progress.set_message(format!("{phase}° {:?} {} caps/px", p.mode, p.density));
            let timing = time_renders(&mut renderer, &scene, &settings, repeats);
            let flux = renderer.flux();
            let flux_error = (total(flux) - total(&reference)).abs() / total(&reference);
            let errors = pixel_errors(flux, &reference, &renderer, p.mode);
            let mut row = BenchRow::new(phase, p, &timing, flux_error, errors);
            row.planned = plan.as_ref().map(|p| PlannedStep {
                max_pixel_error: p.max_pixel_error,
                label: p.label.clone(),
                predicted_pixel_error: p.predicted_pixel_error,
                why: p.why.clone(),
            });
            if let (Some(dir), Some(omega)) = (images, &solid_angle) {
                let name = format!("phase{phase}_row{}", rows.len());
                save_bench_image(dir, &name, renderer.flux(), omega, &pin)?;
                row.image = Some(format!("{name}.tiff"));
            }
            // The bar steps aside while the row is printed.
            progress.suspend(|| println!("{}", row.markdown()));
            progress.inc(1);
            rows.push(row);
        }
    }
    progress.finish_and_clear();
    write_outputs(&rows, json, plot, scene_path, &base)
}

/// `--json` and `--plot`.
fn write_outputs(
    rows: &[BenchRow],
    json: Option<&Path>,
    plot: Option<&Path>,
    scene_path: &Path,
    base: &Scene,
) -> Result<()> {
    if let Some(path) = json {
        std::fs::write(path, serde_json::to_string_pretty(rows)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    if let Some(plot) = plot {
        let path = bench_plot::figure_path(plot)?;
        let name = scene_path.file_name().unwrap_or_default().to_string_lossy();
        let pin = &base.camera.pinhole;
        let what = format!(
            "{name}, {}×{} px, {}, {} threads",
            pin.width,
            pin.height,
            base.body.reflectance.name(),
            rayon::current_num_threads()
        );
        bench_plot::write_bench_figure(&path, rows, &what)?;
        tracing::info!("wrote {}", path.display());
    }
    Ok(())
}
