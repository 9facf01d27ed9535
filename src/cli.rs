//! The subcommands' bodies: argument handling around the library.

pub mod bench_plot;
pub mod calibrate;
pub mod plot_log;

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result};
use glam::{DQuat, DVec3};
use serde::Serialize;

use optistim::facility::config::FacilityConfig;
use optistim::facility::display::{SimDisplay, WindowDisplay, WindowOptions};
use optistim::facility::driver::{self, RunPlan, StateSource};
use optistim::facility::serial::{SerialOptions, SerialPortSync, SimSync, SyncPort};
use optistim::facility::trajectory::Trajectory;
use optistim::render::detector::{render_scene, PixelGeometry};
use optistim::render::{output, Interior, MapFilter, Renderer};
use optistim::scene::Scene;

/// `optistim render`.
pub fn render(scene_path: &Path, out: &Path, caps_per_pixel: Option<f64>) -> Result<()> {
    let mut scene = Scene::from_file(scene_path)?;
    if let Some(d) = caps_per_pixel {
        scene.render.caps_per_pixel = Some(d);
        scene.render.check()?;
    }
    let mut renderer = Renderer::new(scene.camera.pinhole.clone());
    let pixels = PixelGeometry::new(&renderer);
    let images = render_scene(&scene, &mut renderer, &pixels)?;
    let pin = &scene.camera.pinhole;
    output::write_render(out, pin.width, pin.height, &images)
        .with_context(|| format!("writing {}", out.display()))?;
    let s = &images.summary;
    tracing::info!(
        phase_deg = format!("{:.3}", s.phase_angle_deg),
        irradiance_w_m2 = format!("{:.6e}", s.irradiance_at_pupil_w_m2),
        samples = s.samples,
        max_dn = s.max_dn,
        saturated = s.saturated_pixels,
        render_ms = format!("{:.2}", s.render_ms),
        "rendered {} into {}",
        scene_path.display(),
        out.display()
    );
    if let Some(lime) = &s.lime {
        let caveat = match lime.extrapolated.as_slice() {
            [] => String::new(),
            why => format!(" (LIME extrapolated: {})", why.join("; ")),
        };
        tracing::info!(
            "disk irradiance {:.6e} W m-2 against LIME's {:.6e}: render/LIME - 1 = {:+.2} %{caveat}",
            s.irradiance_all_caps_w_m2,
            lime.disk_irradiance_w_m2,
            100.0 * (lime.render_over_lime - 1.0)
        );
    }
    Ok(())
}

#[derive(Serialize)]
pub(crate) struct BenchRow {
    phase_deg: f64,
    interior: Interior,
    caps_per_pixel: f64,
    texture_samples: usize,
    map_filter: MapFilter,
    /// The adaptive filter's threshold (the scene's with other filters).
    map_tolerance: f64,
    node_spacing: usize,
    pixel_tolerance: f64,
    interior_pixels: usize,
    /// Interior pixels evaluated directly, by quadrature rule.
    interior_direct: optistim::render::interior::DirectCounts,
    caps: u64,
    /// Caps integrated: laid out and not wholly on interior pixels.
    caps_integrated: u64,
    median_ms: f64,
    p90_ms: f64,
    flux_error: f64,
    pixel_error_p50: f64,
    pixel_error_p99: f64,
    pixel_error_max: f64,
    /// p99 over the interior pixels alone (integrated per pixel; NaN with
    /// `interior = "caps"`): the map filter's share, without the edges.
    interior_error_p99: f64,
    /// Median wall time of each stage: layout, mask, caps, interior [ms].
    stage_median_ms: [f64; 4],
    /// This setting's image under `--images DIR` (file name in DIR).
    image: Option<String>,
}

/// `bench --images`: one render as radiance per unit solar irradiance at
/// 1 au (flux over the pixel's exact solid angle), an f32 TIFF, so other
/// renderers (tools/mitsuba_moon.py) can be compared pixel by pixel.
fn save_bench_image(
    dir: &Path,
    name: &str,
    flux: &[f32],
    solid_angle: &[f32],
    pin: &optistim::scene::Pinhole,
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
fn at_phase(scene: &mut Scene, phase_deg: f64) {
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
}

/// The values given on the command line, or the scene's own when none.
fn swept_or_scene<'a, T>(given: &'a [T], scene: &'a [T; 1]) -> &'a [T] {
    if given.is_empty() {
        scene
    } else {
        given
    }
}

/// `optistim bench`: time against error for several densities, against the
/// same renderer at 16× the highest linear... reference density.
pub fn bench(
    scene_path: &Path,
    sweep: &BenchSweep,
    repeats: usize,
    json: Option<&Path>,
    plot: Option<&Path>,
    images: Option<&Path>,
) -> Result<()> {
    let BenchSweep {
        phases,
        densities,
        interior,
        texture_samples,
        map_filters,
        node_spacings,
        pixel_tolerances,
        map_tolerances,
        reference_density,
    } = sweep;
    let filters = map_filters
        .iter()
        .map(|m| match m.as_str() {
            "exact" => Ok(MapFilter::Exact),
            "samples" => Ok(MapFilter::Samples),
            "adaptive" => Ok(MapFilter::Adaptive),
            other => Err(anyhow::anyhow!(
                "--map-filter: `{other}`: expected exact, samples or adaptive"
            )),
        })
        .collect::<Result<Vec<_>>>()?;
    let modes = interior
        .iter()
        .map(|m| match m.as_str() {
            "pixels" => Ok(Interior::Pixels),
            "caps" => Ok(Interior::Caps),
            other => Err(anyhow::anyhow!(
                "--interior: `{other}`: expected pixels or caps"
            )),
        })
        .collect::<Result<Vec<_>>>()?;
    let base = Scene::from_file(scene_path)?;
    let scene_samples = [base.render.texture_samples];
    let scene_spacing = [base.render.node_spacing];
    let scene_tolerance = [base.render.pixel_tolerance];
    let node_spacings = swept_or_scene(node_spacings, &scene_spacing);
    let pixel_tolerances = swept_or_scene(pixel_tolerances, &scene_tolerance);
    let texture_samples = swept_or_scene(texture_samples, &scene_samples);
    let scene_filter = [base.render.map_filter];
    let filters = swept_or_scene(&filters, &scene_filter);
    let scene_map_tolerance = [base.render.map_tolerance];
    let map_tolerances = swept_or_scene(map_tolerances, &scene_map_tolerance);
    // (filter, threshold): the thresholds apply to the adaptive filter only.
    let filters: Vec<(MapFilter, f64)> = filters
        .iter()
        .flat_map(|&f| {
            let tols: &[f64] = if f == MapFilter::Adaptive {
                map_tolerances
            } else {
                &scene_map_tolerance
            };
            tols.iter().map(move |&t| (f, t))
        })
        .collect();
    let filters = &filters;
    let pin = base.camera.pinhole.clone();
    let mut renderer = Renderer::new(pin.clone());
    let solid_angle = images.map(|_| pin.solid_angle_table());
    if let Some(dir) = images {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let mut rows = Vec::new();
    println!(
        "machine: {} threads; image {}x{}; model {}",
        rayon::current_num_threads(),
        pin.width,
        pin.height,
        base.body.reflectance.name()
    );
    println!("| phase [deg] | interior | caps/px | map samples | node spacing | pixel tol. | caps | integrated | interior px | median [ms] | p90 [ms] | layout / mask / caps / interior [ms] | flux error | pixel err p50 | p99 | max | interior p99 |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    let per_phase = modes.len()
        * filters.len()
        * densities.len()
        * texture_samples.len()
        * node_spacings.len()
        * pixel_tolerances.len();
    // One step per reference render and per timed setting.
    let progress = optistim::progress::bar((phases.len() * (per_phase + 1)) as u64, "bench");
    for &phase in phases {
        progress.set_message(format!("{phase}° reference"));
        let mut scene = base.clone();
        at_phase(&mut scene, phase);
        // Reference: 16× the sample density of the densest setting (4× per axis).
        let ref_density = reference_density
            .unwrap_or_else(|| 4.0 * densities.iter().cloned().fold(0.0, f64::max));
        let mut settings = scene.render.clone();
        settings.caps_per_pixel = Some(ref_density);
        settings.min_caps = settings.min_caps.max(256);
        settings.interior = Interior::Caps;
        // The map's exact means over each cap's parts: a reference that
        // converges without sampling error of its own.
        settings.map_filter = MapFilter::Exact;
        settings.check().context("--reference-density")?;
        renderer.render_flux(&scene.body, &scene.state, &settings, None);
        progress.inc(1);
        let reference: Vec<f32> = renderer.flux().to_vec();
        if let (Some(dir), Some(omega)) = (images, &solid_angle) {
            write_bench_state(dir, phase, &scene)?;
            save_bench_image(dir, &format!("phase{phase}_ref"), &reference, omega, &pin)?;
        }
        let ref_total: f64 = reference.iter().map(|&v| v as f64).sum();
        let ref_peak = reference.iter().cloned().fold(0.0f32, f32::max) as f64;
        let points = modes.iter().flat_map(|&m| {
            densities
                .iter()
                .flat_map(move |&d| texture_samples.iter().map(move |&k| (m, d, k)))
                .flat_map(move |(m, d, k)| filters.iter().map(move |&f| (m, d, k, f)))
                .flat_map(move |(m, d, k, f)| node_spacings.iter().map(move |&n| (m, d, k, f, n)))
                .flat_map(move |(m, d, k, f, n)| {
                    pixel_tolerances.iter().map(move |&e| (m, d, k, f, n, e))
                })
        });
        for (mode, density, samples, (filter, map_tolerance), spacing, tolerance) in points {
            settings.map_filter = filter;
            settings.map_tolerance = map_tolerance;
            settings.node_spacing = spacing;
            settings.pixel_tolerance = tolerance;
            settings.caps_per_pixel = Some(density);
            settings.min_caps = scene.render.min_caps;
            settings.interior = mode;
            settings.texture_samples = samples;
            settings.check()?;
            progress.set_message(format!("{phase}° {mode:?} {density} caps/px"));
            let mut times = Vec::with_capacity(repeats);
            let mut stages: [Vec<f64>; 4] = Default::default();
            let mut caps = 0;
            let mut caps_integrated = 0;
            let mut interior_pixels = 0;
            let mut interior_direct = Default::default();
            for _ in 0..repeats.max(1) {
                let t = Instant::now();
                let stats = renderer.render_flux(&scene.body, &scene.state, &settings, None);
                times.push(t.elapsed().as_secs_f64() * 1e3);
                let st = stats.stages;
                for (v, x) in stages
                    .iter_mut()
                    .zip([st.layout, st.mask, st.caps, st.interior])
                {
                    v.push(x * 1e3);
                }
                caps = stats.caps;
                caps_integrated = stats.caps_integrated;
                interior_pixels = stats.interior_pixels;
                interior_direct = stats.interior_direct;
            }
            times.sort_by(f64::total_cmp);
            let stage_median_ms = stages.map(|mut v| {
                v.sort_by(f64::total_cmp);
                percentile(&v, 0.5)
            });
            let flux = renderer.flux();
            let image = match (images, &solid_angle) {
                (Some(dir), Some(omega)) => {
                    let name = format!("phase{phase}_row{}", rows.len());
                    save_bench_image(dir, &name, flux, omega, &pin)?;
                    Some(format!("{name}.tiff"))
                }
                _ => None,
            };
            let total: f64 = flux.iter().map(|&v| v as f64).sum();
            // Per-pixel relative error over pixels above 1 % of the peak.
            let mut errors: Vec<f64> = flux
                .iter()
                .zip(&reference)
                .filter(|(_, &r)| r as f64 > 0.01 * ref_peak)
                .map(|(&v, &r)| ((v - r) as f64 / r as f64).abs())
                .collect();
            errors.sort_by(f64::total_cmp);
            let mut interior_errors: Vec<f64> = Vec::new();
            if mode == Interior::Pixels {
                for (k, (&v, &r)) in flux.iter().zip(&reference).enumerate() {
                    let (i, j) = (k % pin.width, k / pin.width);
                    if r as f64 > 0.01 * ref_peak && renderer.is_interior_pixel(i, j) {
                        interior_errors.push(((v - r) as f64 / r as f64).abs());
                    }
                }
            }
            interior_errors.sort_by(f64::total_cmp);
            let row = BenchRow {
                phase_deg: phase,
                interior: mode,
                caps_per_pixel: density,
                texture_samples: samples,
                map_filter: filter,
                map_tolerance,
                node_spacing: spacing,
                pixel_tolerance: tolerance,
                interior_pixels,
                interior_direct,
                caps,
                caps_integrated,
                median_ms: percentile(&times, 0.5),
                p90_ms: percentile(&times, 0.9),
                flux_error: (total - ref_total).abs() / ref_total,
                pixel_error_p50: percentile(&errors, 0.5),
                pixel_error_p99: percentile(&errors, 0.99),
                pixel_error_max: errors.last().copied().unwrap_or(f64::NAN),
                interior_error_p99: percentile(&interior_errors, 0.99),
                stage_median_ms,
                image,
            };
            let [lay, mask, cap, int] = stage_median_ms;
            // The bar steps aside while the row is printed.
            progress.suspend(|| println!(
                "| {:.0} | {:?} | {} | {}×{}{} | {spacing} | {tolerance:.0e} | {} | {} | {} | {:.2} | {:.2} | {lay:.2} / {mask:.2} / {cap:.2} / {int:.2} | {:.1e} | {:.2e} | {:.2e} | {:.2e} | {:.2e} |",
                row.phase_deg,
                row.interior,
                row.caps_per_pixel,
                samples,
                samples,
                filter_label(filter, map_tolerance, interior_direct.map_exact, interior_pixels),
                row.caps,
                row.caps_integrated,
                row.interior_pixels,
                row.median_ms,
                row.p90_ms,
                row.flux_error,
                row.pixel_error_p50,
                row.pixel_error_p99,
                row.pixel_error_max,
                row.interior_error_p99
            ));
            progress.inc(1);
            rows.push(row);
        }
    }
    progress.finish_and_clear();
    if let Some(path) = json {
        std::fs::write(path, serde_json::to_string_pretty(&rows)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    if let Some(plot) = plot {
        let path = bench_plot::figure_path(plot)?;
        let name = scene_path.file_name().unwrap_or_default().to_string_lossy();
        let what = format!(
            "{name}, {}×{} px, {}, {} threads",
            pin.width,
            pin.height,
            base.body.reflectance.name(),
            rayon::current_num_threads()
        );
        bench_plot::write_bench_figure(&path, &rows, &what)?;
        tracing::info!("wrote {}", path.display());
    }
    Ok(())
}

/// Calibration files given on the command line, in place of the facility
/// file's `[calibration]` entries: how a campaign's outputs are tried
/// before the facility file is edited to point at them.
#[derive(clap::Args, Default)]
pub struct CalibrationFiles {
    /// Display LUT CSV (replaces `calibration.lut`).
    #[arg(long)]
    pub lut: Option<std::path::PathBuf>,
    /// Flat-field TIFF (replaces `calibration.flat_field`).
    #[arg(long)]
    pub flat_field: Option<std::path::PathBuf>,
    /// Geometric calibration CSV (replaces `calibration.geometry`).
    #[arg(long)]
    pub geometry: Option<std::path::PathBuf>,
}

impl CalibrationFiles {
    /// Loads the facility file with these files in place of its own, and
    /// validates the result as a whole (a geometry file supersedes
    /// `[alignment]`).
    pub fn load_facility(&self, path: &std::path::Path) -> Result<FacilityConfig> {
        let mut config = FacilityConfig::load(path)?;
        let c = &mut config.calibration;
        if let Some(p) = &self.lut {
            c.lut.clone_from(p);
        }
        if let Some(p) = &self.flat_field {
            c.flat_field = Some(p.clone());
        }
        if let Some(p) = &self.geometry {
            c.geometry = Some(p.clone());
        }
        config.validate()?;
        Ok(config)
    }
}

/// Arguments of `optistim run`.
#[derive(clap::Args)]
pub struct RunArgs {
    /// Facility file (TOML).
    pub facility: std::path::PathBuf,
    #[command(flatten)]
    pub calibration: CalibrationFiles,
    /// Replay this trajectory (default: the facility file's).
    #[arg(long, conflicts_with = "listen")]
    pub trajectory: Option<std::path::PathBuf>,
    /// SPICE kernel directory (tools/fetch_kernels.sh) for a trajectory
    /// with an `epoch` column (docs/FACILITY.md).
    #[arg(long)]
    pub kernels: Option<std::path::PathBuf>,
    /// Closed loop: receive states on udp://HOST:PORT.
    #[arg(long)]
    pub listen: Option<String>,
    /// Closed loop: accept datagrams only from this address (port 0: any
    /// port of that host).
    #[arg(long, default_value = "127.0.0.1:0")]
    pub sender: String,
    /// `sim` (in memory), `window` (full-screen X11) or `sim-facility`
    /// (the simulated facility of `--sim-facility`, its camera capturing).
    #[arg(long, default_value = "sim")]
    pub display: String,
    /// Simulated facility file (TOML, docs/SIMFACILITY.md), for
    /// `--display sim-facility`.
    #[arg(long)]
    pub sim_facility: Option<std::path::PathBuf>,
    /// Where the simulated camera's frames go (16-bit PNG), for
    /// `--display sim-facility`.
    #[arg(long, default_value = "out/captures")]
    pub captures: std::path::PathBuf,
    /// Capture every Nth frame shown.
    #[arg(long, default_value_t = 1)]
    pub capture_every: u64,
    /// `sim`, `none`, or a serial device path (default: the facility
    /// file's `sync.port`, else `sim`).
    #[arg(long)]
    pub serial: Option<String>,
    /// Stop after N frames (N ≥ 1).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    pub frames: Option<u64>,
    /// Frame log (JSON lines, appended).
    #[arg(long, default_value = "out/frames.jsonl")]
    pub log: std::path::PathBuf,
    /// Run summary (JSON).
    #[arg(long, default_value = "out/run_summary.json")]
    pub summary: std::path::PathBuf,
    /// Write the last frames shown on the simulated display as PNG here.
    #[arg(long)]
    pub dump: Option<std::path::PathBuf>,
}

/// A sync port that does nothing (`--serial none`).
struct NoSync;

impl SyncPort for NoSync {
    fn send(&mut self, _line: &str) -> optistim::Result<optistim::facility::serial::SendOutcome> {
        Ok(optistim::facility::serial::SendOutcome::DeviceGone)
    }
    fn wait_ack(&mut self, _t: std::time::Duration) -> optistim::Result<Option<String>> {
        Ok(None)
    }
    fn is_connected(&self) -> bool {
        false
    }
    fn stats(&self) -> optistim::facility::serial::SyncStats {
        Default::default()
    }
}

/// `optistim run`.
pub fn run(args: &RunArgs) -> Result<()> {
    let config = args.calibration.load_facility(&args.facility)?;
    let scene = Scene::from_file(&config.scenario.scene)?;
    let source = match (&args.listen, &args.trajectory, &config.scenario.trajectory) {
        (Some(url), _, _) => {
            let addr = url.strip_prefix("udp://").unwrap_or(url);
            StateSource::Udp {
                bind: addr
                    .parse()
                    .with_context(|| format!("--listen: `{url}` is not udp://HOST:PORT"))?,
                sender: args
                    .sender
                    .parse()
                    .with_context(|| format!("--sender: `{}` is not HOST:PORT", args.sender))?,
            }
        }
        (None, Some(path), _) | (None, None, Some(path)) => {
            StateSource::Replay(load_trajectory(path, args.kernels.as_deref())?)
        }
        (None, None, None) => anyhow::bail!(
            "no state source: give --trajectory or --listen, or set scenario.trajectory in {}",
            args.facility.display()
        ),
    };
    for p in [&args.log, &args.summary] {
        if let Some(dir) = p.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        }
    }
    // Refused now, not after a campaign's last frame.
    optistim::outfile::check_appendable(&args.log)?;
    optistim::outfile::check_replaceable(&args.summary)?;
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        ctrlc::set_handler(move || stop.store(true, Ordering::Relaxed))
            .context("installing the Ctrl-C handler")?;
    }
    let serial_choice = args
        .serial
        .clone()
        .or_else(|| config.sync.port.as_ref().map(|p| p.display().to_string()))
        .unwrap_or_else(|| "sim".into());
    let mut sync: Box<dyn SyncPort> = match serial_choice.as_str() {
        // The last exchanges only: a long run must not grow.
        "sim" => Box::new(SimSync::with_history(64)),
        "none" => Box::new(NoSync),
        path => Box::new(SerialPortSync::open(SerialOptions::new(
            path,
            config.sync.baud,
        ))?),
    };
    let (w, h) = config.screen_size();
    let plan = RunPlan {
        config,
        scene,
        source,
        frames: args.frames,
        log: args.log.clone(),
        summary: args.summary.clone(),
    };
    let summary = match args.display.as_str() {
        "sim" => {
            let keep = if args.dump.is_some() { 120 } else { 1 };
            let mut display = SimDisplay::new(w, h, keep);
            let s = driver::run(plan, &mut display, sync.as_mut(), stop)?;
            if let Some(dir) = &args.dump {
                let files = display.dump_png(dir)?;
                tracing::info!("wrote {} frames to {}", files.len(), dir.display());
            }
            s
        }
        "window" => {
            let mut display = WindowDisplay::open(&WindowOptions {
                monitor: plan.config.screen.monitor.clone(),
                resolution: Some((w, h)),
                title: "optistim".into(),
            })?;
            driver::run(plan, &mut display, sync.as_mut(), stop)?
        }
        "sim-facility" => {
            let path = args
                .sim_facility
                .as_ref()
                .context("--display sim-facility needs --sim-facility FILE")?;
            let facility = optistim::simfacility::SimFacility::load(path)?;
            let mut display = optistim::simfacility::RecordingScreen::new(
                &facility,
                &args.captures,
                args.capture_every,
            )?;
            let s = driver::run(plan, &mut display, sync.as_mut(), stop)?;
            let written = display.written.len();
            tracing::info!(
                "the simulated camera wrote {written} frames to {}",
                args.captures.display()
            );
            s
        }
        other => {
            anyhow::bail!("--display must be `sim`, `window` or `sim-facility`, not `{other}`")
        }
    };
    let lat = &summary.latency_state_to_present;
    let ms = |v: Option<f64>| v.map_or("-".to_string(), |x| format!("{:.2} ms", x * 1e3));
    println!(
        "frames {}  missed deadlines {}  dropped states {}  latency state->present p50 {} p99 {} max {}",
        summary.frames,
        summary.missed_deadlines,
        summary.dropped_states,
        ms(lat.p50),
        ms(lat.p99),
        ms(lat.max)
    );
    println!(
        "log: {}  summary: {}",
        args.log.display(),
        args.summary.display()
    );
    Ok(())
}

/// `optistim validate amie`.
pub fn validate_amie(
    img: &Path,
    model: &str,
    out: &Path,
    data: &Path,
    kernels: Option<&Path>,
) -> Result<()> {
    use optistim::validate::compare;
    let mut options = compare::ValidationOptions::new(data);
    if let Some(dir) = kernels {
        print_ephemeris_difference(img, dir)?;
        options.kernels = Some(dir.to_path_buf());
    }
    let run = compare::run(img, model, &options)
        .with_context(|| format!("validating {} with {model}", img.display()))?;
    compare::write_outputs(&run, out).with_context(|| format!("writing {}", out.display()))?;
    let r = &run.report;
    println!(
        "{} {model}: shift ({:.2}, {:.2}) px; SSIM {:.5} (luminance {:.5}, contrast {:.5}, structure {:.5}); \
         unnormalised luminance {:.5}; real/render total signal {:.4}; phase {:.3} vs label {:.2} deg",
        r.product_id,
        r.alignment.dx,
        r.alignment.dy,
        r.ssim.mssim,
        r.ssim.luminance,
        r.ssim.contrast,
        r.ssim.structure,
        r.ssim_unnormalised.luminance,
        r.total_signal_ratio,
        r.phase_derived_deg,
        r.phase_label_deg
    );
    Ok(())
}

/// Prints how far the analytic ephemerides are from the SPICE kernels at
/// an AMIE image's epoch.
fn print_ephemeris_difference(img: &Path, kernels: &Path) -> Result<()> {
    use optistim::validate::{amie, ephem};
    let spice = optistim::ephemeris::Spice::from_dir(kernels)?;
    let scene = amie::load(img)?.scene;
    let d = amie::ephemeris_difference(&scene, &ephem::Analytic, &spice)?;
    println!(
        "{} analytic - SPICE: Moon position {:.1} km, Sun direction {:.5} deg, \
         Sun distance {:.0} km, Moon orientation {:.5} deg",
        scene.label.product_id,
        d.moon_position_km,
        d.sun_direction_deg,
        d.sun_distance_km,
        d.moon_orientation_deg
    );
    Ok(())
}

/// A trajectory file: by epoch (Sun and Moon from the kernels in
/// `kernels`) when its header has an `epoch` column, else explicit states.
fn load_trajectory(path: &Path, kernels: Option<&Path>) -> Result<Trajectory> {
    use optistim::facility::epoch_trajectory;
    let text = optistim::infile::read_text_bounded(path, optistim::infile::DATA_LIMIT)?;
    if !epoch_trajectory::is_epoch_header(&text) {
        return Ok(Trajectory::load(path)?);
    }
    let dir = kernels.with_context(|| {
        format!(
            "{}: a trajectory with an `epoch` column needs --kernels DIR",
            path.display()
        )
    })?;
    let spice = optistim::ephemeris::Spice::from_dir(dir)?;
    Ok(epoch_trajectory::load(path, &spice)?)
}
