//! The subcommands' bodies: argument handling around the library.

mod bench;
pub mod bench_plot;
mod bench_shadows;
pub mod calibrate;
pub mod dataset;
pub mod expose;
pub mod plot_log;
pub mod sim_lab;

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use anyhow::{Context, Result};

use optistim::facility::acceptance::Verdict;
use optistim::facility::config::FacilityConfig;
use optistim::facility::display::{SimDisplay, WindowDisplay, WindowOptions};
use optistim::facility::driver::{self, RunPlan, StateSource};
use optistim::facility::serial::{SerialOptions, SerialPortSync, SimSync, SyncPort};
use optistim::facility::trajectory::Trajectory;
use optistim::render::detector::{render_scene, PixelGeometry};
use optistim::render::field::field_check;
use optistim::render::{output, Renderer};
use optistim::scene::Scene;

pub use bench::{bench, BenchSweep};
pub use bench_shadows::bench_shadows;

/// What `optistim render` writes into its `--out` directory.
const RENDER_FILES: [&str; 6] = [
    "radiance.tiff",
    "radiance_effective.tiff",
    "electrons.tiff",
    "dn.png",
    "preview.png",
    "summary.json",
];

/// `optistim render`; refuses an `out` holding an earlier render unless
/// `overwrite`.
pub fn render(
    scene_path: &Path,
    out: &Path,
    caps_per_pixel: Option<f64>,
    max_pixel_error: Option<f64>,
    overwrite: bool,
    labels: bool,
) -> Result<()> {
    let label_files = optistim::labels::files::all_files().filter(|_| labels);
    let files: Vec<_> = RENDER_FILES
        .iter()
        .copied()
        .chain(label_files)
        .map(|f| out.join(f))
        .collect();
    optistim::outfile::check_no_earlier(&files, overwrite)?;
    let mut scene = Scene::from_file(scene_path)?;
    if let Some(d) = caps_per_pixel {
        scene.render.caps_per_pixel = Some(d);
        scene.render.check()?;
    }
    let field = field_check(&scene.camera.pinhole, &scene.state, scene.body.radius);
    if !field.in_field && !scene.render.allow_empty {
        anyhow::bail!(
            "{}: nothing to render: {} (set [render] allow_empty = true to write the empty image)",
            scene_path.display(),
            field.describe()
        );
    }
    let plan = plan_settings(&mut scene, scene_path, max_pixel_error)?;
    let mut renderer = Renderer::new(scene.camera.render_pinhole().clone());
    let pixels = PixelGeometry::new(&renderer);
    let mut images = render_scene(&scene, &mut renderer, &pixels)?;
    images.summary.plan = plan;
    let pin = &scene.camera.pinhole;
    output::write_render(out, pin.width, pin.height, &images)
        .with_context(|| format!("writing {}", out.display()))?;
    if labels {
        let epoch = optistim::scene::epoch_text(scene_path)?;
        let mut l =
            optistim::labels::compute_for(&scene.camera, &scene.state, scene.body.radius, epoch)?;
        optistim::labels::add_stars(&mut l, &scene);
        optistim::labels::files::write(out, &l, "dn.png")
            .with_context(|| format!("writing labels into {}", out.display()))?;
    }
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
        let camera = lime.effective_render_over_lime.map_or(String::new(), |r| {
            format!(", in the camera's electrons {:+.2} %", 100.0 * (r - 1.0))
        });
        tracing::info!(
            "disk irradiance {:.6e} W m-2 against LIME's {:.6e}: render/LIME - 1 = {:+.2} %{camera}{caveat}",
            s.irradiance_all_caps_w_m2,
            lime.disk_irradiance_w_m2,
            100.0 * (lime.render_over_lime - 1.0)
        );
    }
    Ok(())
}

/// With a per-pixel error target (`--max-pixel-error`, else the scene's
/// `[render] max_pixel_error`): the planner's settings put in `scene`, and
/// its report.
fn plan_settings(
    scene: &mut Scene,
    scene_path: &Path,
    flag: Option<f64>,
) -> Result<Option<optistim::planner::Plan>> {
    use optistim::planner;
    let Some((target, source)) = planner::target(flag, scene) else {
        return Ok(None);
    };
    // The relief's `auto` switch judges against the same target.
    scene.render.max_pixel_error = Some(target);
    let plan = planner::Planner::new(scene)
        .plan(target, source)
        .with_context(|| format!("{}", scene_path.display()))?;
    tracing::info!(
        "planned for {} p99 <= {target:e}: {} (measured {:.2e}, flux {:.1e}; planning {:.0} ms)",
        plan.judged,
        plan.label,
        plan.predicted_pixel_error,
        plan.predicted_flux_error,
        plan.planning_ms
    );
    scene.render = plan.settings.clone();
    Ok(Some(plan))
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
    /// The simulated facility's clock file (JSON, docs/SIMFACILITY.md):
    /// virtual time continues from it and is saved back at the end.
    #[arg(long, requires = "sim_facility")]
    pub sim_clock: Option<std::path::PathBuf>,
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
    /// Frame log (JSON lines). Default: frames.jsonl in a new directory
    /// under `--runs-dir`. An existing log is refused unless `--append`.
    #[arg(long)]
    pub log: Option<std::path::PathBuf>,
    /// Run summary (JSON). Default: run_summary.json in the run's new
    /// directory. An existing summary is refused unless `--overwrite`.
    #[arg(long)]
    pub summary: Option<std::path::PathBuf>,
    /// Where each run without `--log`/`--summary` gets its own directory,
    /// named by its UTC start (`20261126T183155Z`, `-2` … if taken).
    #[arg(long, default_value = "out/runs")]
    pub runs_dir: std::path::PathBuf,
    /// Add this run to an existing `--log` (runs are told apart by their id).
    #[arg(long)]
    pub append: bool,
    /// Replace an existing `--summary`, and the earlier frames
    /// (`frame_*.png`) in `--dump` or `--captures` (removed first).
    #[arg(long)]
    pub overwrite: bool,
    /// Write the last frames shown on the simulated display as PNG here.
    #[arg(long)]
    pub dump: Option<std::path::PathBuf>,
    /// Exit with status 3 when the verdict is `degraded` (default 0).
    #[arg(long)]
    pub strict: bool,
}

/// Exit status of a run whose verdict is `fail`.
pub const EXIT_FAIL: u8 = 4;
/// Exit status of a `degraded` run under `--strict`.
pub const EXIT_DEGRADED_STRICT: u8 = 3;

/// A sync port that does nothing (`--serial none`): its frames have no
/// sync line, and none is counted as not sent.
struct NoSync;

impl SyncPort for NoSync {
    fn send(&mut self, _line: &str) -> optistim::Result<optistim::facility::serial::SendOutcome> {
        Ok(optistim::facility::serial::SendOutcome::Disabled)
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

/// `optistim run`: the exit status follows the verdict (0 pass or
/// degraded, [`EXIT_FAIL`] fail, [`EXIT_DEGRADED_STRICT`] degraded with
/// `--strict`).
pub fn run(args: &RunArgs) -> Result<std::process::ExitCode> {
    let config = args.calibration.load_facility(&args.facility)?;
    let scene = Scene::from_file(&config.scenario.scene)?;
    let source = state_source(args, &config)?;
    let (log, summary_path) = run_outputs(args)?;
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        ctrlc::set_handler(move || stop.store(true, Ordering::Relaxed))
            .context("installing the Ctrl-C handler")?;
    }
    let mut sync = sync_port(args, &config)?;
    let plan = RunPlan {
        config,
        scene,
        source,
        frames: args.frames,
        log: log.clone(),
        summary: summary_path.clone(),
    };
    let summary = run_on_display(args, plan, sync.as_mut(), stop)?;
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
    if let Some([lo, hi]) = summary.render_over_lime_range {
        println!(
            "render/LIME - 1 (camera electrons, per frame): {:+.2} % to {:+.2} %",
            100.0 * (lo - 1.0),
            100.0 * (hi - 1.0)
        );
    }
    if let Some(u) = summary.radiometric_u_k2_percent_max {
        println!("radiometric uncertainty of the frames shown (LUT, k = 2): at most {u:.2} %");
    }
    for (name, clip) in [
        ("white", &summary.clip_white),
        ("black", &summary.clip_black),
    ] {
        if let Some(frame) = clip.flux_max_frame {
            println!(
                "clipped at the {name} level: {} frames, up to {} px a frame, moving up to {:.4} % of a frame's disk flux (frame {frame})",
                clip.frames,
                clip.pixels_max,
                100.0 * clip.flux_max
            );
        }
    }
    println!(
        "log: {}  summary: {}",
        log.display(),
        summary_path.display()
    );
    print_verdict(&summary);
    Ok(std::process::ExitCode::from(match summary.verdict {
        Verdict::Pass => 0,
        Verdict::Degraded if args.strict => EXIT_DEGRADED_STRICT,
        Verdict::Degraded => 0,
        Verdict::Fail => EXIT_FAIL,
    }))
}

/// The console's last lines: the verdict, each reason, each hint.
fn print_verdict(summary: &optistim::facility::log::Summary) {
    let planned = summary
        .frames_planned
        .map_or(String::new(), |n| format!(" of {n} planned"));
    println!(
        "verdict: {}  ({} frames{planned}{})",
        summary.verdict.as_str(),
        summary.frames,
        if summary.interrupted {
            ", interrupted"
        } else {
            ""
        }
    );
    for r in &summary.reasons {
        println!("  reason: {r}");
    }
    for h in &summary.hints {
        println!("  hint: {h}");
    }
}

/// The run's frame log and summary: as given, each refused now (not after
/// a campaign's last frame) if it would extend or replace an earlier
/// result without `--append` / `--overwrite`; those not given go into a
/// new directory of their own under `--runs-dir`. Earlier frames in
/// `--dump` or `--captures` are refused likewise.
fn run_outputs(args: &RunArgs) -> Result<(std::path::PathBuf, std::path::PathBuf)> {
    use optistim::outfile;
    if let Some(log) = &args.log {
        outfile::check_appendable(log)?;
        let used = std::fs::metadata(log).is_ok_and(|m| m.len() > 0);
        if used && !args.append {
            anyhow::bail!(
                "{}: holds earlier runs: refusing to add this one without --append",
                log.display()
            );
        }
    }
    if let Some(summary) = &args.summary {
        outfile::check_replaceable(summary)?;
        outfile::check_no_earlier(std::slice::from_ref(summary), args.overwrite)?;
    }
    if let Some(dir) = &args.dump {
        outfile::claim_frames_dir(dir, "frame_", ".png", args.overwrite)?;
    }
    if args.display == "sim-facility" {
        outfile::claim_frames_dir(&args.captures, "frame_", ".png", args.overwrite)?;
    }
    let run_dir = match (&args.log, &args.summary) {
        (Some(_), Some(_)) => None,
        _ => Some(new_run_dir(&args.runs_dir)?),
    };
    let in_run_dir = |name: &str| run_dir.as_ref().map(|d| d.join(name));
    let log = args.log.clone().or_else(|| in_run_dir("frames.jsonl"));
    let summary = args
        .summary
        .clone()
        .or_else(|| in_run_dir("run_summary.json"));
    let (log, summary) = (log.expect("log"), summary.expect("summary"));
    for p in [&log, &summary] {
        if let Some(dir) = p.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        }
    }
    Ok((log, summary))
}

/// A new directory under `runs`, named by the UTC time (a suffix `-2`,
/// `-3` … when two runs start in the same second); created atomically, so
/// two runs never share one.
fn new_run_dir(runs: &Path) -> Result<std::path::PathBuf> {
    std::fs::create_dir_all(runs).with_context(|| format!("creating {}", runs.display()))?;
    let stamp = optistim::utc::compact(optistim::utc::now_secs());
    for n in 1..1000 {
        let name = if n == 1 {
            stamp.clone()
        } else {
            format!("{stamp}-{n}")
        };
        let dir = runs.join(name);
        match std::fs::create_dir(&dir) {
            Ok(()) => return Ok(dir),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(e).with_context(|| format!("creating {}", dir.display())),
        }
    }
    anyhow::bail!("{}: no free run directory for {stamp}", runs.display())
}

/// Where states come from: `--listen`, else `--trajectory`, else the
/// facility file's `scenario.trajectory`.
fn state_source(args: &RunArgs, config: &FacilityConfig) -> Result<StateSource> {
    Ok(
        match (&args.listen, &args.trajectory, &config.scenario.trajectory) {
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
        },
    )
}

/// The sync port: `--serial`, else the facility file's `sync.port`, else
/// the simulated one.
fn sync_port(args: &RunArgs, config: &FacilityConfig) -> Result<Box<dyn SyncPort>> {
    let choice = args
        .serial
        .clone()
        .or_else(|| config.sync.port.as_ref().map(|p| p.display().to_string()))
        .unwrap_or_else(|| "sim".into());
    Ok(match choice.as_str() {
        // The last exchanges only: a long run must not grow.
        "sim" => Box::new(SimSync::with_history(64)),
        "none" => Box::new(NoSync),
        path => Box::new(SerialPortSync::open(SerialOptions::new(
            path,
            config.sync.baud,
        ))?),
    })
}

/// Runs `plan` on the display `--display` names.
fn run_on_display(
    args: &RunArgs,
    plan: RunPlan,
    sync: &mut dyn SyncPort,
    stop: Arc<AtomicBool>,
) -> Result<optistim::facility::log::Summary> {
    let (w, h) = plan.config.screen_size();
    Ok(match args.display.as_str() {
        "sim" => {
            let keep = if args.dump.is_some() { 120 } else { 1 };
            let mut display = SimDisplay::new(w, h, keep);
            let s = driver::run(plan, &mut display, sync, stop)?;
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
            driver::run(plan, &mut display, sync, stop)?
        }
        "sim-facility" => {
            let path = args
                .sim_facility
                .as_ref()
                .context("--display sim-facility needs --sim-facility FILE")?;
            let facility = optistim::simfacility::SimFacility::load(path)?;
            let _clock = args
                .sim_clock
                .as_deref()
                .map(|p| optistim::simfacility::clock::SimClock::attach(&facility, p))
                .transpose()?;
            let mut display = optistim::simfacility::RecordingScreen::new(
                &facility,
                &args.captures,
                args.capture_every,
            )?;
            let s = driver::run(plan, &mut display, sync, stop)?;
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
    })
}

/// What `optistim validate amie` writes into its `--out` directory.
const VALIDATE_FILES: [&str; 3] = ["comparison.png", "profile.png", "report.json"];

/// `optistim validate amie`; refuses an `out` holding an earlier
/// validation unless `overwrite`.
pub fn validate_amie(
    img: &Path,
    model: &str,
    out: &Path,
    data: &Path,
    kernels: Option<&Path>,
    (relief, height_scale, psf_sigma, caps_per_pixel): (&str, f64, Option<f64>, Option<f64>),
    overwrite: bool,
) -> Result<()> {
    use optistim::scene::{horizon::ShadowMode, ShadowsSpec};
    use optistim::validate::compare;
    let files: Vec<_> = VALIDATE_FILES.iter().map(|f| out.join(f)).collect();
    optistim::outfile::check_no_earlier(&files, overwrite)?;
    let mut options = compare::ValidationOptions::new(data);
    if let Some(dir) = kernels {
        print_ephemeris_difference(img, dir)?;
        options.kernels = Some(dir.to_path_buf());
    }
    let dem = data.join("maps/ldem_4.tif");
    options.relief = match relief {
        "none" => None,
        "shadows" => Some(ShadowsSpec::km_dem(dem, ShadowMode::Always, false)),
        "full" => Some(ShadowsSpec::km_dem(dem, ShadowMode::Always, true)),
        other => anyhow::bail!("--relief must be `none`, `shadows` or `full`, not `{other}`"),
    };
    if let Some(spec) = &mut options.relief {
        spec.scale *= height_scale;
    }
    options.psf_sigma_px = psf_sigma;
    options.caps_per_pixel = caps_per_pixel;
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
    if let Some(s) = &r.relief_signal {
        println!("{} {model}: {}", r.product_id, compare::relief_note(s));
        for line in compare::relief_high_pass_notes(s) {
            println!("{} {model}: {line}", r.product_id);
        }
    }
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
