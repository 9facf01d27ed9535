//! `optistim expose`: exposure bounds of a scene, or of every state of a
//! trajectory, as a table (exposure.csv), a figure (exposure.png) and a
//! verdict line whose exit status says whether one exposure serves all.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result};

use optistim::expose::{common_window, expose_states, Feature, StateBounds};
use optistim::facility::trajectory::Trajectory;
use optistim::figures::{shaded_band, ShadedBand};
use optistim::scene::{Scene, State};

/// Exit status when no single exposure serves every state.
pub const NO_COMMON_EXPOSURE: u8 = 2;

/// `optistim expose` arguments.
#[derive(clap::Args)]
pub struct ExposeArgs {
    /// Scene file (TOML): camera, Sun, body and the state.
    pub scene: PathBuf,
    /// Trajectory CSV (the facility's format): bounds per state, with the
    /// scene's camera, Sun and body (the body's pose defaults to the
    /// scene's).
    #[arg(long)]
    pub trajectory: Option<PathBuf>,
    /// The feature to expose for: disk-mean (mean over pixels with
    /// signal), brightest, darkest-lit (the darkest pixel with at least
    /// 1 % of the brightest's rate).
    #[arg(long, default_value = "disk-mean")]
    pub feature: String,
    /// Signal-to-noise ratio of the noise floor.
    #[arg(long, default_value_t = 10.0)]
    pub snr: f64,
    /// Output directory (exposure.csv, exposure.png).
    #[arg(long, default_value = "out/expose")]
    pub out: PathBuf,
    /// Replace an earlier exposure.csv / exposure.png.
    #[arg(long)]
    pub overwrite: bool,
}

/// Runs `optistim expose`.
pub fn expose(args: &ExposeArgs) -> Result<ExitCode> {
    let feature = Feature::parse(&args.feature)?;
    let csv_path = args.out.join("exposure.csv");
    let png_path = args.out.join("exposure.png");
    optistim::outfile::check_no_earlier(&[csv_path.clone(), png_path.clone()], args.overwrite)?;
    let scene = Scene::from_file(&args.scene)?;
    let states = states(&scene, args.trajectory.as_deref())?;
    let bounds = expose_states(&scene, &states, feature, args.snr)
        .with_context(|| format!("{}", args.scene.display()))?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("{}", args.out.display()))?;
    write_csv(&csv_path, &bounds)?;
    draw(&png_path, &bounds, feature, args, scene.camera.exposure)?;
    Ok(verdict(&bounds, feature, args.snr, scene.camera.exposure))
}

/// (time, state) of the scene, or of each trajectory state.
fn states(scene: &Scene, trajectory: Option<&Path>) -> Result<Vec<(f64, State)>> {
    let Some(path) = trajectory else {
        return Ok(vec![(0.0, scene.state)]);
    };
    let traj = Trajectory::load(path)?;
    let base = scene.state;
    Ok(traj
        .states
        .iter()
        .map(|s| {
            let state = State {
                body_position: s.body_position.unwrap_or(base.body_position),
                body_attitude: s.body_attitude.unwrap_or(base.body_attitude),
                camera_position: s.camera_position,
                camera_attitude: s.camera_attitude,
                sun_position: s.sun_position,
                occulter: base.occulter,
            };
            (s.t, state)
        })
        .collect())
}

fn write_csv(path: &Path, bounds: &[StateBounds]) -> Result<()> {
    let mut text =
        String::from("t_s,range_m,phase_deg,feature_rate_e_per_s,t_min_s,t_max_s,open\n");
    for s in bounds {
        let (rate, lo, hi, open) = match s.bounds {
            Some(b) => (b.rate, b.t_min, b.t_max, b.is_open()),
            None => (0.0, f64::NAN, f64::NAN, false),
        };
        text += &format!(
            "{},{:.6e},{:.4},{:.6e},{:.6e},{:.6e},{}\n",
            s.t, s.range_m, s.phase_deg, rate, lo, hi, open
        );
    }
    std::fs::write(path, text).with_context(|| format!("{}", path.display()))
}

fn draw(
    path: &Path,
    bounds: &[StateBounds],
    feature: Feature,
    args: &ExposeArgs,
    exposure: f64,
) -> Result<()> {
    let rows = bounds
        .iter()
        .map(|s| {
            let b = s
                .bounds
                .map_or((f64::NAN, f64::NAN), |b| (b.t_min, b.t_max));
            (s.t, b.0, b.1)
        })
        .collect();
    let fig = ShadedBand {
        title: format!(
            "Exposure bounds: {} of {}",
            feature.name(),
            args.scene.file_name().unwrap_or_default().to_string_lossy()
        ),
        x_label: "trajectory time t [s]".into(),
        y_label: "exposure [s]".into(),
        rows,
        lower_label: format!("noise floor (SNR = {})", args.snr),
        upper_label: "saturation (full well or ADC)".into(),
        band_label: "usable exposures".into(),
        lines: vec![(exposure, "scene's camera.exposure".into())],
        size: (900, 560),
    };
    shaded_band(path, &fig)?;
    Ok(())
}

/// Prints the verdict; success when one exposure serves every state.
fn verdict(bounds: &[StateBounds], feature: Feature, snr: f64, exposure: f64) -> ExitCode {
    let n = bounds.len();
    match common_window(bounds) {
        Some((lo, hi)) => {
            let inside = if (lo..=hi).contains(&exposure) {
                "inside"
            } else {
                "outside"
            };
            println!(
                "expose: PASS: exposures {lo:.4e} s to {hi:.4e} s keep the {} at SNR >= {snr} and below saturation in all {n} states (the scene's {exposure:e} s is {inside})",
                feature.name()
            );
            ExitCode::SUCCESS
        }
        None => {
            let dark = bounds.iter().filter(|s| s.bounds.is_none()).count();
            let closed = bounds
                .iter()
                .filter(|s| s.bounds.is_some_and(|b| !b.is_open()))
                .count();
            println!(
                "expose: FAIL: no single exposure keeps the {} at SNR >= {snr} and below saturation in all {n} states ({dark} without signal, {closed} with the noise floor above saturation)",
                feature.name()
            );
            ExitCode::from(NO_COMMON_EXPOSURE)
        }
    }
}
