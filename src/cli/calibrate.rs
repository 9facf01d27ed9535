//! `optistim calibrate radiometric|flat|geometric|verify`: builds the
//! instruments (the simulated facility's, or the real window display and
//! the instruments of `[calibrate]`), opens the campaign's checkpoint and
//! runs one routine of [`optistim::calibration`].

use std::io::{BufRead, Write};
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};

use optistim::calibration::checkpoint::{fingerprint, Checkpoint};
use optistim::calibration::config::SPECTRORADIOMETER_KEY;
use optistim::calibration::config::{calibrate_table, CalibrateConfig};
use optistim::calibration::dark::DarkBank;
use optistim::calibration::mismatch::{check_screen_spectrum, table_spectrum, CameraSpectral};
use optistim::calibration::mismatch_levels::MismatchCurve;
use optistim::calibration::responsivity::CameraResponsivity;
use optistim::calibration::{
    flat, focal, geometric, radiometric, sleep, verify, AutoExposure, Instruments,
};
use optistim::facility::config::FacilityConfig;
use optistim::facility::display::{Display, WindowDisplay, WindowOptions};
use optistim::facility::geometry::GeometryCalibration;
use optistim::facility::lut::{DisplayLut, FlatField};
use optistim::instruments::config::{open_camera, open_spot_meter, open_spot_meter_as, DarkSource};
use optistim::instruments::intrinsics::CameraIntrinsics;
use optistim::instruments::{Camera, SpotMeter};
use optistim::radiometry::spectrum::Table;
use optistim::scene::Scene;
use optistim::simfacility::SimFacility;

/// Which routine.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Routine {
    Radiometric,
    Flat,
    Geometric,
    Verify,
}

/// Arguments of `optistim calibrate`.
#[derive(clap::Args)]
pub struct CalibrateArgs {
    /// The routine to run.
    #[arg(value_enum)]
    pub routine: Routine,
    /// Facility file (TOML) with a `[calibrate]` section.
    pub facility: PathBuf,
    /// Calibrate the simulated facility of this file instead of the real
    /// screen and instruments (docs/SIMFACILITY.md).
    #[arg(long)]
    pub sim_facility: Option<PathBuf>,
    /// The simulated facility's clock file (docs/SIMFACILITY.md).
    #[arg(long, requires = "sim_facility")]
    pub sim_clock: Option<PathBuf>,
    /// Output directory (default: `calibrate.out_dir`).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Continue the campaign recorded in the output directory's checkpoint.
    #[arg(long)]
    pub resume: bool,
    /// The files `flat` (geometry) and `verify` (LUT, flat field) use.
    #[command(flatten)]
    pub calibration: super::CalibrationFiles,
}

/// The instruments of one campaign.
struct Rig {
    display: Box<dyn Display>,
    camera: Box<dyn Camera>,
    meter: Option<Box<dyn SpotMeter>>,
    /// `[calibrate.spectroradiometer]`.
    spectroradiometer: Option<Box<dyn SpotMeter>>,
    sim: Option<SimFacility>,
}

fn open_rig(args: &CalibrateArgs, fac: &FacilityConfig, cfg: &CalibrateConfig) -> Result<Rig> {
    let base = args.facility.parent().unwrap_or(Path::new("."));
    if let Some(path) = &args.sim_facility {
        let sim = SimFacility::load(path)?;
        if sim.config().screen.bits != fac.drive.bits || {
            let [w, h] = sim.config().screen.resolution;
            (w, h) != fac.screen_size()
        } {
            bail!(
                "{}: the simulated screen differs from the facility file's screen (resolution, bits)",
                path.display()
            );
        }
        return Ok(Rig {
            display: Box::new(sim.display()),
            camera: Box::new(sim.camera()),
            meter: cfg.meter.as_ref().map(|m| {
                Box::new(ScaledMeter {
                    inner: sim.meter(),
                    scale: m.unit_scale,
                }) as Box<dyn SpotMeter>
            }),
            spectroradiometer: cfg.spectroradiometer.as_ref().map(|m| {
                Box::new(ScaledMeter {
                    inner: sim.spectroradiometer(),
                    scale: m.unit_scale,
                }) as Box<dyn SpotMeter>
            }),
            sim: Some(sim),
        });
    }
    let (w, h) = fac.screen_size();
    let display = WindowDisplay::open(&WindowOptions {
        monitor: fac.screen.monitor.clone(),
        resolution: Some((w, h)),
        title: "optistim calibrate".into(),
    })?;
    let camera = open_camera(&cfg.camera, base)?;
    let meter = match &cfg.meter {
        Some(m) => Some(open_spot_meter(m, base)?),
        None => None,
    };
    let spectroradiometer = match &cfg.spectroradiometer {
        Some(m) => Some(open_spot_meter_as(m, base, SPECTRORADIOMETER_KEY)?),
        None => None,
    };
    Ok(Rig {
        display: Box::new(display),
        camera,
        meter,
        spectroradiometer,
        sim: None,
    })
}

/// The simulated meter with `calibrate.meter.unit_scale` applied, as the
/// serial meter applies it (reading = instrument value × unit_scale).
struct ScaledMeter<M> {
    inner: M,
    scale: f64,
}

impl<M: SpotMeter> SpotMeter for ScaledMeter<M> {
    fn measure(&mut self) -> optistim::Result<optistim::instruments::SpotReading> {
        let mut r = self.inner.measure()?;
        r.value *= self.scale;
        if let Some(s) = &mut r.spectrum {
            s.iter_mut().for_each(|p| p.1 *= self.scale);
        }
        Ok(r)
    }
    fn describe(&self) -> String {
        if self.scale == 1.0 {
            self.inner.describe()
        } else {
            format!("{} × unit_scale {}", self.inner.describe(), self.scale)
        }
    }
}

/// Asks the operator to do something and waits for Enter.
fn ask(what: &str) -> optistim::Result<()> {
    eprint!("optistim calibrate: {what}, then press Enter ");
    std::io::stderr().flush().ok();
    let mut line = String::new();
    std::io::stdin()
        .lock()
        .read_line(&mut line)
        .map_err(|e| optistim::Error::Other(format!("waiting for the operator: {e}")))?;
    Ok(())
}

/// Where a routine's darks come from: the campaign's
/// `calibrate.camera.dark`, or for verify its own `calibrate.verify.dark`
/// (required when the campaign's is `"none"`).
fn dark_source(cfg: &CalibrateConfig, routine: Routine) -> Result<Option<DarkSource>> {
    if routine != Routine::Verify {
        return Ok(cfg.camera.dark.clone());
    }
    match (&cfg.verify.dark, &cfg.camera.dark) {
        (Some(v), _) => Ok(Some(v.clone())),
        (None, Some(DarkSource::None)) => bail!(
            "calibrate.verify.dark: missing while calibrate.camera.dark = \"none\": a verify without darks shares the campaign's omission; say \"shutter\", \"capture\" or a dark model file"
        ),
        (None, c) => Ok(c.clone()),
    }
}

/// The routine's dark frames from `source`.
fn dark_bank(cfg: &CalibrateConfig, source: Option<DarkSource>, rig: &mut Rig) -> Result<DarkBank> {
    let frames = cfg.camera.dark_frames;
    let operator = rig.sim.is_none();
    Ok(match &source {
        None => bail!("calibrate.camera.dark: missing; say \"shutter\", \"capture\", a dark model file, or \"none\""),
        Some(DarkSource::None) => DarkBank::none(),
        Some(DarkSource::Shutter) => DarkBank::shutter(frames),
        Some(DarkSource::File(p)) => DarkBank::from_file(p, &rig.camera.describe())?,
        Some(DarkSource::Capture) => {
            // The simulated camera's closed shutter stands in for the cover.
            let mut cover = |on: bool| {
                if !operator {
                    Ok(())
                } else if on {
                    ask("cover the camera (no light at all) for its dark frames")
                } else {
                    ask("uncover the camera")
                }
            };
            let ladder = AutoExposure::of(cfg).ladder();
            DarkBank::capture_ladder(rig.camera.as_mut(), &ladder, frames, &mut cover)?
        }
    })
}

/// `optistim calibrate`.
pub fn calibrate(args: &CalibrateArgs) -> Result<()> {
    let fac = args.calibration.load_facility(&args.facility)?;
    let bits = fac.drive.bits;
    let mut cfg = CalibrateConfig::load(&args.facility, bits)?;
    if let Some(out) = &args.out {
        cfg.out_dir = out.clone();
    }
    std::fs::create_dir_all(&cfg.out_dir)
        .with_context(|| format!("creating {}", cfg.out_dir.display()))?;
    let text = optistim::infile::read_text_bounded(&args.facility, optistim::infile::CONFIG_LIMIT)?;
    let table = calibrate_table(&text, &args.facility)?;
    let name = match args.routine {
        Routine::Radiometric => radiometric::ROUTINE,
        Routine::Flat => flat::ROUTINE,
        Routine::Geometric => "geometric",
        Routine::Verify => verify::ROUTINE,
    };
    let fp = fingerprint(&table, name, fac.screen_size(), bits);
    let mut rig = open_rig(args, &fac, &cfg)?;
    let _clock = match (&args.sim_clock, &rig.sim) {
        (Some(p), Some(sim)) => Some(optistim::simfacility::clock::SimClock::attach(sim, p)?),
        _ => None,
    };
    _clock.as_ref().map(|c| c.save_on_interrupt()).transpose()?;
    if args.routine == Routine::Geometric {
        return run_geometric(&fac, &cfg, &args.facility, &mut rig);
    }
    let ckpt_path = cfg.out_dir.join(format!("{name}.checkpoint.jsonl"));
    let mut ckpt = Checkpoint::open(&ckpt_path, &fp, name, args.resume)?;
    if !ckpt.is_empty() {
        eprintln!(
            "optistim calibrate: resuming {} measurements from {}",
            ckpt.len(),
            ckpt_path.display()
        );
    }
    let source = dark_source(&cfg, args.routine)?;
    let mut darks = dark_bank(&cfg, source, &mut rig)?;
    let sim = rig.sim.clone();
    let mut wait = move |s: f64| match &sim {
        Some(f) => f.advance(s),
        None => sleep(s),
    };
    let mut inst = Instruments {
        display: rig.display.as_mut(),
        camera: rig.camera.as_mut(),
        meter: rig.meter.as_mut().map(|m| m.as_mut() as &mut dyn SpotMeter),
        darks: &mut darks,
        wait: &mut wait,
    };
    match args.routine {
        Routine::Radiometric => {
            let spectro = rig
                .spectroradiometer
                .as_mut()
                .map(|m| m.as_mut() as &mut dyn SpotMeter);
            run_radiometric(&fac, &cfg, &args.facility, &mut inst, spectro, &mut ckpt)
        }
        Routine::Flat => run_flat(&fac, &cfg, &mut inst, &mut ckpt),
        Routine::Verify => run_verify(&fac, &cfg, &mut inst, &mut ckpt),
        Routine::Geometric => unreachable!("handled above"),
    }
}

fn run_radiometric(
    fac: &FacilityConfig,
    cfg: &CalibrateConfig,
    facility: &Path,
    inst: &mut Instruments,
    spectroradiometer: Option<&mut dyn SpotMeter>,
    ckpt: &mut Checkpoint,
) -> Result<()> {
    let scene = Scene::from_file(&fac.scenario.scene)?;
    let meter_response = cfg.meter_response()?;
    let spectral = CameraSpectral::from_scene(&scene);
    let screen_spectrum = match &cfg.screen_spectrum {
        Some(p) => {
            let s = table_spectrum(&Table::from_csv(p)?);
            check_screen_spectrum(&s, spectral.band_nm)
                .with_context(|| format!("{}: calibrate.screen_spectrum", p.display()))?;
            Some(s)
        }
        None => None,
    };
    let mut power = |on: bool| {
        if on {
            ask("switch the screen back on")
        } else {
            ask("switch the screen off (or cover it) for the ambient")
        }
    };
    let mut setup = radiometric::Setup {
        cfg,
        bits: fac.drive.bits,
        spectral: Some(spectral),
        meter_response,
        screen_spectrum,
        spectroradiometer: spectroradiometer.map(|m| m as &mut dyn SpotMeter),
        screen_power: Some(&mut power),
        source: facility.display().to_string(),
    };
    let report = radiometric::run(inst, &mut setup, ckpt)?;
    let out = radiometric::Outputs::in_dir(&cfg.out_dir);
    radiometric::write(&report, &setup, &out)?;
    println!(
        "LUT {} ({} levels, black {:.4e}, max {:.4e} W m-2 sr-1); leave-one-out RMS {:.3} %, max {:.3} %; drift {:+.3} %",
        out.lut.display(),
        report.levels.len(),
        report.black_radiance,
        report.max_radiance,
        report.loo_rms_percent,
        report.loo_max_percent,
        report.drift_percent
    );
    println!("{}", report.budget.describe());
    println!(
        "report {}, plot {}; set `calibration.lut` to the LUT to use it",
        out.report.display(),
        out.plot.display()
    );
    Ok(())
}

/// Camera pixel → direction: the camera's intrinsics file (from its own
/// geometric calibration; never the simulator's truth).
fn intrinsics(cfg: &CalibrateConfig) -> Result<CameraIntrinsics> {
    match &cfg.camera.intrinsics {
        Some(p) => Ok(CameraIntrinsics::load(p)?),
        None => bail!("calibrate.camera.intrinsics: missing; the flat field maps camera pixels to the screen through the camera's intrinsics file"),
    }
}

fn run_flat(
    fac: &FacilityConfig,
    cfg: &CalibrateConfig,
    inst: &mut Instruments,
    ckpt: &mut Checkpoint,
) -> Result<()> {
    let screen = fac.screen_size();
    let gpath = fac.calibration.geometry.as_ref().context(
        "calibration.geometry: missing; run `optistim calibrate geometric` first and set it, or give --geometry",
    )?;
    let geometry = GeometryCalibration::load(gpath, screen)?;
    let k = intrinsics(cfg)?;
    let direction = move |x: f64, y: f64| match k.pixel_to_direction(x, y) {
        Some(d) => (d.x / d.z, d.y / d.z),
        None => (f64::NAN, f64::NAN),
    };
    let camera_flat = match &cfg.flat.camera_flat {
        Some(p) => Some(optistim::instruments::frame::read_frame(p)?.2),
        None => bail!("calibrate.flat.camera_flat: missing; the camera's own flat (vignetting × PRNU, from its lab calibration) must be divided out"),
    };
    let setup = flat::FlatSetup {
        cfg,
        bits: fac.drive.bits,
        screen,
        pixel_direction: &direction,
        geometry: &geometry,
        camera_flat,
    };
    let (gains, report) = flat::run(inst, &setup, ckpt)?;
    let tif = cfg.out_dir.join("flat_field.tif");
    flat::write_tiff(&tif, &gains, screen)?;
    let (json, png) = (
        cfg.out_dir.join("flat_report.json"),
        cfg.out_dir.join("flat_field.png"),
    );
    flat::write_report(&report, &gains, screen, &json, &png)?;
    let utif = cfg.out_dir.join("flat_field_uncertainty.tif");
    flat::write_tiff(&utif, &flat::uncertainty_map(&report, screen), screen)?;
    println!(
        "flat field {} (gain {:.4}..{:.4} over the area seen, 13-point non-uniformity {:.2} %, levels agree within {:.3} %, uncertainty {:.3} % (k = 2), per pixel in {}); report {}, map {}; set `calibration.flat_field` to use it",
        tif.display(),
        report.min_gain,
        report.max_gain,
        report.nonuniformity_13_percent,
        report.level_disagreement_percent,
        report.uncertainty_k2_percent,
        utif.display(),
        json.display(),
        png.display()
    );
    Ok(())
}

fn run_verify(
    fac: &FacilityConfig,
    cfg: &CalibrateConfig,
    inst: &mut Instruments,
    ckpt: &mut Checkpoint,
) -> Result<()> {
    let screen = fac.screen_size();
    let lut = DisplayLut::load(&fac.calibration.lut, fac.drive.bits)?;
    let flat = match &fac.calibration.flat_field {
        Some(p) => Some(FlatField::load(p, screen)?),
        None => None,
    };
    let rpath = cfg.out_dir.join("radiometric_report.json");
    let text = optistim::infile::read_text_bounded(&rpath, optistim::infile::CONFIG_LIMIT)
        .with_context(|| {
            format!(
                "{}: verify needs the radiometric calibration's report (its camera scale)",
                rpath.display()
            )
        })?;
    let rep: radiometric::Report =
        serde_json::from_str(&text).with_context(|| format!("{}", rpath.display()))?;
    if !(rep.scale.is_finite() && rep.scale > 0.0) {
        bail!(
            "{}: scale {} is not a positive number",
            rpath.display(),
            rep.scale
        );
    }
    let responsivity = match &cfg.camera.responsivity {
        Some(p) => CameraResponsivity::load(p)?,
        None => bail!("calibrate.camera.responsivity: missing; verify measures the screen through the camera's own absolute responsivity (a lab calibration), not the radiometric calibration's scale"),
    };
    let k = intrinsics(cfg)?;
    let direction = move |x: f64, y: f64| match k.pixel_to_direction(x, y) {
        Some(d) => (d.x / d.z, d.y / d.z),
        None => (f64::NAN, f64::NAN),
    };
    let camera_flat = match &cfg.flat.camera_flat {
        Some(p) => optistim::instruments::frame::read_frame(p)?.2,
        None => bail!("calibrate.flat.camera_flat: missing; verify divides the camera's own flat out of each spot"),
    };
    let scene = Scene::from_file(&fac.scenario.scene)?;
    let setup = verify::VerifySetup {
        cfg,
        lut,
        flat,
        screen,
        camera_scale: rep.scale,
        camera: verify::AbsoluteCamera {
            responsivity,
            transmission: fac.collimator.transmission,
            camera_flat,
            pixel_direction: &direction,
        },
        mismatch_factor: rep.mismatch_factor,
        mismatch_by_level: match rep.mismatch_by_level.is_empty() {
            true => None,
            false => Some(
                MismatchCurve::new(rep.mismatch_by_level.clone())
                    .with_context(|| format!("{}", rpath.display()))?,
            ),
        },
        spectral: Some(CameraSpectral::from_scene(&scene)),
        meter_uncertainty_k2_percent: cfg
            .meter
            .as_ref()
            .and_then(|m| m.scale_uncertainty_k2_percent),
        lut_scale_k2_percent: Some(rep.budget.scale_total()),
    };
    let report = verify::run(inst, &setup, ckpt)?;
    let json = cfg.out_dir.join("verify_report.json");
    std::fs::write(&json, serde_json::to_string_pretty(&report)?)
        .with_context(|| format!("writing {}", json.display()))?;
    let png = cfg.out_dir.join("verify.png");
    verify::plot(&report, &png)?;
    print!("{}", verify::summary(&report));
    println!("report {}, figure {}", json.display(), png.display());
    if report.drift_warning {
        tracing::warn!(
            "drift {:.3} % beyond calibrate.verify.drift_warn_percent {} %: recalibrate",
            report.max_drift_percent,
            report.drift_warn_percent
        );
    }
    if !report.passed {
        bail!(
            "verification failed: {} measurements beyond their threshold (max |achieved/target − 1| {:.3} %){}",
            report.failures,
            report.max_error_percent,
            report
                .camera_common_mode
                .as_ref()
                .map_or(String::new(), |c| format!("; {}", c.describe()))
        );
    }
    Ok(())
}

fn run_geometric(
    fac: &FacilityConfig,
    cfg: &CalibrateConfig,
    facility: &Path,
    rig: &mut Rig,
) -> Result<()> {
    let table = cfg.geometric.clone().context(
        "calibrate.geometric: missing; the geometric routine needs its table (docs/GEOMETRIC.md)",
    )?;
    let mut g: geometric::GeometricConfig = table.try_into().map_err(|e: toml::de::Error| {
        anyhow::anyhow!(
            "{}: [calibrate.geometric]: {}",
            facility.display(),
            optistim::error::toml_message("", &e)
        )
    })?;
    g.resolve_paths(facility.parent().unwrap_or(Path::new(".")));
    let report = geometric::calibrate_geometric(
        rig.display.as_mut(),
        rig.camera.as_mut(),
        &g,
        &cfg.out_dir,
    )?;
    println!(
        "geometry {} ({} dots used, {} rejected): residual RMS {:.4} camera px ({:.2}\"), max {:.4} px ({:.2}\"); report {}; set `calibration.geometry` to use it",
        report.geometry_csv.display(),
        report.dots_used,
        report.dots_rejected,
        report.rms_px,
        report.rms_arcsec,
        report.max_px,
        report.max_arcsec,
        report.report_json.display()
    );
    let geometry = GeometryCalibration::load(&report.geometry_csv, fac.screen_size())?;
    let c = focal::check(
        &geometry,
        fac.screen.pixel_pitch,
        fac.collimator.focal_length,
        cfg.collimator_focal_length_uncertainty_percent,
    )?;
    let json = cfg.out_dir.join("collimator_focal_length.json");
    std::fs::write(&json, serde_json::to_string_pretty(&c)?)
        .with_context(|| format!("writing {}", json.display()))?;
    println!(
        "collimator focal length implied near the axis ({:.1}, {:.1}) px: {:.5} m (u), {:.5} m (v) against the configured {} m: {:+.3} % ({}); {}",
        c.axis_px[0],
        c.axis_px[1],
        c.implied_m[0],
        c.implied_m[1],
        c.configured_m,
        c.disagreement_percent,
        match c.uncertainty_percent {
            Some(u) => format!("declared uncertainty {u} %"),
            None => "no calibrate.collimator_focal_length_uncertainty_percent: not checked".into(),
        },
        json.display()
    );
    if c.flagged {
        tracing::warn!(
            "the geometry implies a collimator focal length {:+.3} % from the configured one, beyond its declared {} %: check the camera intrinsics' focal length and collimator.focal_length",
            c.disagreement_percent,
            c.uncertainty_percent.unwrap_or(0.0)
        );
    }
    Ok(())
}
