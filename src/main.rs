//! `optistim` command line: render, expose, run, calibrate, bench, plot-log, validate.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod cli;

/// Radiometrically exact renderer of planets and moons, and driver of a
/// hardware-in-the-loop optical facility.
#[derive(Parser)]
#[command(version, about)]
struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Drive the facility: states in, calibrated frames on the screen,
    /// serial sync, frame log.
    Run(cli::RunArgs),
    /// Render a scene file to radiance.tiff, electrons.tiff, dn.png and
    /// summary.json.
    Render {
        /// Scene file (TOML).
        scene: PathBuf,
        /// Output directory.
        #[arg(long, default_value = "out")]
        out: PathBuf,
        /// Override the caps per pixel of the scene file.
        #[arg(long, value_parser = caps_per_pixel_flag)]
        caps_per_pixel: Option<f64>,
        /// Per-pixel error target (interior p99 against a converged
        /// render, in (0, 1]; replaces `[render] max_pixel_error`): render
        /// with the cheapest settings that meet it (summary.json's `plan`).
        #[arg(long)]
        max_pixel_error: Option<f64>,
        /// Replace an earlier render in `--out`.
        #[arg(long)]
        overwrite: bool,
        /// Also write the exact labels (masks, depth, normals, latitude and
        /// longitude, labels.json, coco.json; docs/DATASETS.md).
        #[arg(long)]
        labels: bool,
    },
    /// Exposure bounds of a scene or of each state of a trajectory: the
    /// exposures keeping a feature between the noise floor at an SNR and
    /// saturation (DIR/exposure.csv, DIR/exposure.png; exit status 2 when
    /// no single exposure serves every state).
    Expose(cli::expose::ExposeArgs),
    /// Time the renderer against its converged reference (speed vs error).
    Bench {
        /// Scene file (TOML); default: the benchmark Moon.
        #[arg(long, default_value = "configs/moon_bench.toml")]
        scene: PathBuf,
        /// Phase angles [deg].
        #[arg(long, value_delimiter = ',', default_value = "30,105")]
        phases: Vec<f64>,
        /// Densities (caps per pixel) to time.
        #[arg(long, value_delimiter = ',', default_value = "0.5,1,1.5,2,3")]
        densities: Vec<f64>,
        /// Interior integrations to time: `pixels`, `caps` (the reference
        /// is always the lune's caps alone, at 4× the densest setting).
        #[arg(long, value_delimiter = ',', default_value = "pixels,caps")]
        interior: Vec<String>,
        /// Albedo-map samples per pixel or cap along each axis (1–4) to
        /// time; default: the scene's.
        #[arg(long, value_delimiter = ',')]
        texture_samples: Vec<usize>,
        /// Albedo-map filters to time: `exact`, `samples`, `adaptive`; default: the
        /// scene's. The reference always takes the exact filter.
        #[arg(long, value_delimiter = ',')]
        map_filter: Vec<String>,
        /// Interior node-lattice spacings [px] to time (1: every pixel
        /// evaluated); default: the scene's.
        #[arg(long, value_delimiter = ',')]
        node_spacing: Vec<usize>,
        /// Interior pixel quadrature tolerances to time (`[render]
        /// pixel_tolerance`); default: the scene's.
        #[arg(long, value_delimiter = ',')]
        pixel_tolerance: Vec<f64>,
        /// Adaptive map filter thresholds to time (`[render]
        /// map_tolerance`, with `--map-filter adaptive`); default: the
        /// scene's.
        #[arg(long, value_delimiter = ',')]
        map_tolerance: Vec<f64>,
        /// The reference's caps per pixel (default: 4× the densest timed).
        #[arg(long)]
        reference_density: Option<f64>,
        /// Per-pixel error target (interior p99, in (0, 1]; else the
        /// scene's `[render] max_pixel_error`): at each phase time only the
        /// cheapest settings that meet it, as the planner chose them.
        #[arg(long)]
        max_pixel_error: Option<f64>,
        /// Repetitions per point (median reported).
        #[arg(long, default_value_t = 30)]
        repeats: usize,
        /// Write the table as JSON here.
        #[arg(long)]
        json: Option<PathBuf>,
        /// Draw speed against error (log-log, one curve per setting, the
        /// targets as lines): DIR/bench.png, or the given PATH.png.
        #[arg(long, value_name = "DIR|PATH.png")]
        plot: Option<PathBuf>,
        /// Also write every setting's image and the reference (radiance per
        /// unit solar irradiance at 1 au, f32 TIFF) and each phase's
        /// geometry (JSON) into DIR, for tools/mitsuba_moon.py.
        #[arg(long, value_name = "DIR")]
        images: Option<PathBuf>,
        /// Replace an earlier `--json` or `--plot` figure.
        #[arg(long)]
        overwrite: bool,
        /// Time the scene's cast shadows instead of the sweep: each phase
        /// rendered with them (mode forced to `always`) and without,
        /// alternating, `--repeats` pairs (median of the pairs' ratios);
        /// then the horizon map's one-time cost, cold cache and warm. The
        /// scene's own render settings; `--json` takes this table.
        #[arg(long)]
        shadows: bool,
    },
    /// Calibrate the facility's screen: `radiometric` (display LUT),
    /// `flat` (flat field), `geometric` (geometry file), `verify`
    /// (docs/CALIBRATION.md).
    Calibrate(cli::calibrate::CalibrateArgs),
    /// Write the simulated facility camera's lab products (intrinsics,
    /// own flat, absolute responsivity, with their errors and declared
    /// uncertainties) into a directory (docs/SIMFACILITY.md).
    SimLab(cli::sim_lab::SimLabArgs),
    /// Draw the timing figure of a frame log: DIR/timing.png (latency
    /// over time with missed deadlines, histogram with p50/p99).
    PlotLog(cli::plot_log::PlotLogArgs),
    /// Render a dataset (or this process's shard of it) from a spec, or
    /// `--merge` the shards (docs/DATASETS.md).
    Dataset(cli::dataset::DatasetArgs),
    /// Validate against real flight images.
    #[command(subcommand)]
    Validate(ValidateCommand),
}

#[derive(Subcommand)]
enum ValidateCommand {
    /// Render a SMART-1 AMIE image's scene and compare it with the image:
    /// writes DIR/comparison.png and DIR/report.json (docs/VALIDATION.md).
    Amie {
        /// AMIE PDS3 product (.IMG).
        img: PathBuf,
        /// Reflection model: oren_nayar, hapke, lambert, lommel_seeliger.
        #[arg(long, default_value = "oren_nayar")]
        model: String,
        /// Output directory.
        #[arg(long, default_value = "out/validate")]
        out: PathBuf,
        /// Data directory (maps, solar spectrum, assumed AMIE response).
        #[arg(long, default_value = "data")]
        data: PathBuf,
        /// SPICE kernel directory (tools/fetch_kernels.sh): Sun and Moon
        /// orientation from DE421 and the lunar BPC instead of the analytic
        /// ephemerides; also prints how far the two differ.
        #[arg(long)]
        kernels: Option<PathBuf>,
        /// Relief from the bundled LOLA DEM (DATA/maps/ldem_4.tif), in
        /// every frame: `none`, `shadows` (cast shadows) or `full` (cast
        /// shadows, and the same DEM moves the limb and tilts the normals).
        #[arg(long, default_value = "none")]
        relief: String,
        /// With `--relief`: the DEM's heights times this factor (an
        /// experiment on how long the image's shadows are; 1: the LOLA
        /// heights; the scaled heights must stay within ±25 km).
        #[arg(long, default_value_t = 1.0, value_parser = height_scale_flag)]
        relief_height_scale: f64,
        /// A Gaussian PSF of this standard deviation [px] on the render
        /// (AMIE publishes none; default: no PSF).
        #[arg(long)]
        psf_sigma: Option<f64>,
        /// Surface caps per pixel of the render (default: the renderer's;
        /// a displaced DEM needs about 4 to converge, BENCHMARKS.md).
        #[arg(long, value_parser = caps_per_pixel_flag)]
        caps_per_pixel: Option<f64>,
        /// Replace an earlier validation in `--out`.
        #[arg(long)]
        overwrite: bool,
    },
}

/// `--caps-per-pixel`, range-checked so its error names the flag.
fn caps_per_pixel_flag(text: &str) -> Result<f64, String> {
    use optistim::render_settings::{density_in_range, MAX_DENSITY};
    let d: f64 = text.parse().map_err(|e| format!("{e}"))?;
    if density_in_range(d) {
        Ok(d)
    } else {
        Err(format!("must be in (0, {MAX_DENSITY}]"))
    }
}

/// `--relief-height-scale`: positive and at most 10.
fn height_scale_flag(text: &str) -> Result<f64, String> {
    let k: f64 = text.parse().map_err(|e| format!("{e}"))?;
    if k > 0.0 && k <= 10.0 {
        Ok(k)
    } else {
        Err("must be in (0, 10]".into())
    }
}

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_env("OPTISTIM_LOG")
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .with_writer(std::io::stderr)
        // Colour codes only on a terminal: a redirected log stays plain text.
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
    let args = Args::parse();
    let result = match args.command {
        Command::Run(args) => return finish(cli::run(&args)),
        Command::Expose(args) => return finish(cli::expose::expose(&args)),
        Command::Calibrate(args) => cli::calibrate::calibrate(&args),
        Command::PlotLog(args) => cli::plot_log::plot_log(&args),
        Command::SimLab(args) => cli::sim_lab::sim_lab(&args),
        Command::Dataset(args) => cli::dataset::dataset(&args),
        Command::Render {
            scene,
            out,
            caps_per_pixel,
            max_pixel_error,
            overwrite,
            labels,
        } => cli::render(
            &scene,
            &out,
            caps_per_pixel,
            max_pixel_error,
            overwrite,
            labels,
        ),
        Command::Bench {
            scene,
            phases,
            repeats,
            json,
            overwrite,
            shadows: true,
            ..
        } => cli::bench_shadows(&scene, &phases, repeats, json.as_deref(), overwrite),
        Command::Bench {
            scene,
            phases,
            densities,
            interior,
            texture_samples,
            map_filter,
            node_spacing,
            pixel_tolerance,
            map_tolerance,
            reference_density,
            max_pixel_error,
            repeats,
            json,
            plot,
            images,
            overwrite,
            shadows: false,
        } => cli::bench(
            &scene,
            &cli::BenchSweep {
                phases,
                densities,
                interior,
                texture_samples,
                map_filters: map_filter,
                node_spacings: node_spacing,
                pixel_tolerances: pixel_tolerance,
                map_tolerances: map_tolerance,
                reference_density,
                max_pixel_error,
            },
            repeats,
            json.as_deref(),
            plot.as_deref(),
            images.as_deref(),
            overwrite,
        ),
        Command::Validate(ValidateCommand::Amie {
            img,
            model,
            out,
            data,
            kernels,
            relief,
            relief_height_scale,
            psf_sigma,
            caps_per_pixel,
            overwrite,
        }) => cli::validate_amie(
            &img,
            &model,
            &out,
            &data,
            kernels.as_deref(),
            (&relief, relief_height_scale, psf_sigma, caps_per_pixel),
            overwrite,
        ),
    };
    finish(result.map(|()| ExitCode::SUCCESS))
}

/// The exit status of a command's result; an error is printed on one line.
fn finish(result: anyhow::Result<ExitCode>) -> ExitCode {
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("optistim: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
