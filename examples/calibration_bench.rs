//! The calibration benchmark of issue 14: speed and accuracy of the
//! radiometric, geometric and flat-field routines on the simulated
//! facility (configs/simfacility.toml, realistic noise), scored against the
//! facility's truth accessors. The routines get what a campaign gets: the
//! camera's lab products (`SimFacility::write_lab_camera_files`: its
//! intrinsics and its own flat, each off by an error within what the file
//! declares), never the simulator's truth. Writes a markdown table and a PNG of the LUT
//! error against the number of levels (docs/CALIBRATION_BENCH.md).
//!
//! cargo run --release --example calibration_bench -- [--runs 3] [--radiometric-px 256] [--out out/calbench]

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};

use optistim::calibration::checkpoint::Checkpoint;
use optistim::calibration::config::CalibrateConfig;
use optistim::calibration::dark::DarkBank;
use optistim::calibration::mismatch::{table_spectrum, CameraSpectral};
use optistim::calibration::{flat, geometric, radiometric};
use optistim::facility::config::FacilityConfig;
use optistim::facility::geometry::GeometryCalibration;
use optistim::facility::lut::{DisplayLut, FlatField};
use optistim::figures::{curve_figure, CurveFigure, Panel, Series};
use optistim::instruments::intrinsics::CameraIntrinsics;
use optistim::radiometry::spectrum::Table;
use optistim::scene::Scene;
use optistim::simfacility::instruments::SimInstruments;
use optistim::simfacility::{SimFacility, SimFacilityConfig};

const FACILITY: &str = "configs/facility_calibrate.toml";
const SIMFACILITY: &str = "configs/simfacility.toml";
const LEVELS: [usize; 3] = [17, 33, 65];
const REPEATS: [usize; 3] = [1, 2, 3];
/// Warm-up before each campaign, s (virtual): the screen's 600 s constant.
const WARMUP: f64 = 3600.0;

struct Args {
    runs: usize,
    radiometric_px: usize,
    out: PathBuf,
}

fn args() -> Result<Args> {
    let mut a = Args {
        runs: 3,
        radiometric_px: 256,
        out: PathBuf::from("out/calbench"),
    };
    let v: Vec<String> = std::env::args().skip(1).collect();
    for pair in v.chunks(2) {
        let value = pair.get(1).context("every option takes a value")?;
        match pair[0].as_str() {
            "--runs" => a.runs = value.parse::<usize>()?.clamp(1, 20),
            "--radiometric-px" => a.radiometric_px = value.parse::<usize>()?.clamp(32, 1024),
            "--out" => a.out = PathBuf::from(value),
            o => anyhow::bail!("unknown option {o}"),
        }
    }
    Ok(a)
}

/// The bundled simulated facility with its noise seeded by `seed` and,
/// when `px` is below the camera's size, a centred `px` × `px` camera (the
/// same focal length: the central part of the field).
fn facility(seed: u64, px: Option<usize>) -> Result<SimFacility> {
    let path = Path::new(SIMFACILITY);
    let mut cfg = SimFacilityConfig::parse(&std::fs::read_to_string(path)?, path)?;
    cfg.resolve_paths(Path::new("configs"));
    cfg.seed = seed;
    if let Some(px) = px {
        let c = &mut cfg.camera;
        c.cx += px as f64 / 2.0 - c.resolution[0] as f64 / 2.0;
        c.cy += px as f64 / 2.0 - c.resolution[1] as f64 / 2.0;
        c.resolution = [px, px];
    }
    let sim = SimFacility::new(cfg)?;
    sim.advance(WARMUP);
    Ok(sim)
}

/// The camera's lab products for this facility (intrinsics, own flat),
/// written into `dir` and read back as a campaign reads them.
fn lab(sim: &SimFacility, dir: &Path) -> Result<(CameraIntrinsics, Vec<f32>)> {
    let files = sim.write_lab_camera_files(&dir.join("lab"))?;
    let k = CameraIntrinsics::load(&files.intrinsics)?;
    let flat = optistim::instruments::frame::read_frame(&files.camera_flat)?.2;
    Ok((k, flat))
}

/// The screen point imaged at camera pixel (x, y), by fixed-point iteration
/// on the truth.
fn screen_point_at(sim: &SimFacility, x: f64, y: f64) -> (f64, f64) {
    let [w, h] = sim.config().screen.resolution;
    let (mut u, mut v) = (w as f64 / 2.0, h as f64 / 2.0);
    for _ in 0..50 {
        let (px, py) = sim.true_camera_pixel(u, v);
        u -= (px - x) * 0.9;
        v -= (py - y) * 0.9;
    }
    (u, v)
}

fn rms_max(errors: &[f64]) -> (f64, f64) {
    let n = errors.len().max(1) as f64;
    let rms = (errors.iter().map(|e| e * e).sum::<f64>() / n).sqrt();
    (rms, errors.iter().fold(0.0f64, |m, e| m.max(e.abs())))
}

fn median(mut t: Vec<f64>) -> f64 {
    t.sort_by(|a, b| a.total_cmp(b));
    t[t.len() / 2]
}

struct Common {
    fac: FacilityConfig,
    cfg: CalibrateConfig,
    scene: Scene,
}

fn common() -> Result<Common> {
    let fac = FacilityConfig::load(FACILITY)?;
    let cfg = CalibrateConfig::load(FACILITY, fac.drive.bits)?;
    let scene = Scene::from_file(&fac.scenario.scene)?;
    Ok(Common { fac, cfg, scene })
}

/// One radiometric campaign: wall time (s), the written LUT's error
/// against the truth at every drive level above 1 % of the maximum
/// (fractions: RMS, max), the facility time it would take (s: the
/// simulated clock, settle times and exposures, which dominate a real
/// campaign), and the RMS error once a common scale is divided out.
fn radiometric_once(
    c: &Common,
    levels: usize,
    repeats: usize,
    seed: u64,
    px: usize,
    dir: &Path,
) -> Result<(f64, f64, f64, f64, f64)> {
    let sim = facility(seed, Some(px))?;
    let mut cfg = c.cfg.clone();
    cfg.levels = levels;
    cfg.repeats = repeats;
    cfg.seed = seed;
    cfg.camera.resolution = Some([px, px]);
    std::fs::create_dir_all(dir)?;
    let _ = std::fs::remove_file(dir.join("c.jsonl"));
    let start = Instant::now();
    let mut ckpt = Checkpoint::open(&dir.join("c.jsonl"), "bench", "radiometric", false)?;
    let (mut rig, mut meter) = (SimInstruments::new(&sim), sim.meter());
    let mut darks = DarkBank::shutter(4);
    let mut inst = rig.lend(Some(&mut meter), &mut darks);
    let meter_response = cfg.meter_response()?;
    let screen_spectrum = match &cfg.screen_spectrum {
        Some(p) => Some(table_spectrum(&Table::from_csv(p)?)),
        None => None,
    };
    let mut setup = radiometric::Setup {
        cfg: &cfg,
        bits: c.fac.drive.bits,
        spectral: Some(CameraSpectral::from_scene(&c.scene)),
        meter_response,
        screen_spectrum,
        spectroradiometer: None,
        screen_power: None,
        source: "calibration_bench".into(),
    };
    let report = radiometric::run(&mut inst, &mut setup, &mut ckpt)?;
    radiometric::write(&report, &setup, &radiometric::Outputs::in_dir(dir))?;
    let seconds = start.elapsed().as_secs_f64();
    let lut = DisplayLut::load(dir.join("lut.csv"), c.fac.drive.bits)?;
    // The truth where the camera's central region looks, at the end of the
    // campaign (warm-up and drift included).
    let centre = px as f64 / 2.0;
    let at = screen_point_at(&sim, centre, centre);
    let top = sim.true_camera_effective_radiance(255, at);
    let errors: Vec<f64> = (0..=255usize)
        .map(|l| (l, sim.true_camera_effective_radiance(l, at)))
        .filter(|&(_, truth)| truth > 0.01 * top)
        .map(|(l, truth)| lut.radiance(l as f64) / truth - 1.0)
        .collect();
    let (rms, max) = rms_max(&errors);
    // The curve's shape error: what is left once a common scale (the
    // meter's reading, the drift since it was taken) is divided out.
    let mean = errors.iter().sum::<f64>() / errors.len().max(1) as f64;
    let shape: Vec<f64> = errors
        .iter()
        .map(|e| (1.0 + e) / (1.0 + mean) - 1.0)
        .collect();
    let (shape_rms, _) = rms_max(&shape);
    Ok((seconds, rms, max, sim.now() - WARMUP, shape_rms))
}

/// The geometric routine's geometry against the truth, over a 1-screen-px
/// lattice (step 8 px) of the screen the camera sees: camera px and arcsec
/// (RMS, max).
fn geometric_once(c: &Common, seed: u64, dir: &Path) -> Result<(f64, [f64; 4])> {
    let sim = facility(seed, None)?;
    let mut g: geometric::GeometricConfig = c
        .cfg
        .geometric
        .clone()
        .context("calibrate.geometric missing")?
        .try_into()?;
    g.resolve_paths(Path::new("configs"));
    // The simulated screen changes at once: no real sleep.
    g.settle = 0.0;
    g.output = PathBuf::from("geometry.csv");
    std::fs::create_dir_all(dir)?;
    let (k, _) = lab(&sim, dir)?;
    let (mut display, mut camera) = (sim.display(), sim.camera());
    let start = Instant::now();
    let report = geometric::calibrate_geometric_with(&mut display, &mut camera, &k, &g, dir)?;
    let seconds = start.elapsed().as_secs_f64();
    let [w, h] = sim.config().screen.resolution;
    let geo = GeometryCalibration::load(&report.geometry_csv, (w, h))?;
    let (cw, ch) = (k.width as f64, k.height as f64);
    let (mut px, mut arc) = (Vec::new(), Vec::new());
    for v in (0..h).step_by(8) {
        for u in (0..w).step_by(8) {
            let (u, v) = (u as f64 + 0.5, v as f64 + 0.5);
            let (tx, ty) = sim.true_camera_pixel(u, v);
            if !(tx >= 0.0 && ty >= 0.0 && tx <= cw && ty <= ch) {
                continue;
            }
            let [gx, gy] = geo.direction(u, v);
            let d = glam::DVec3::new(gx, gy, 1.0);
            let Some((mx, my)) = k.direction_to_pixel(d) else {
                continue;
            };
            px.push((mx - tx).hypot(my - ty));
            let (ax, ay) = sim.true_geometry(u, v);
            let t = glam::DVec3::new(ax, ay, 1.0);
            arc.push(d.angle_between(t).to_degrees() * 3600.0);
        }
    }
    let (pr, pm) = rms_max(&px);
    let (ar, am) = rms_max(&arc);
    Ok((seconds, [pr, pm, ar, am]))
}

/// Drive levels at which the flat field is scored: the fitted ones and a
/// dim one it was not measured at (the non-uniformity depends on the level).
const FLAT_SCORED: [usize; 3] = [255, 128, 32];

/// The flat-field routine (on the geometric run's `geometry_csv`) against
/// the true non-uniformity of each of [`FLAT_SCORED`] over the seen area,
/// both normalised to their mean there: wall time and (RMS, max) per level,
/// fractions.
fn flat_once(
    c: &Common,
    seed: u64,
    geometry_csv: &Path,
    dir: &Path,
) -> Result<(f64, Vec<(f64, f64)>)> {
    let sim = facility(seed, None)?;
    let screen = c.fac.screen_size();
    let geometry = GeometryCalibration::load(geometry_csv, screen)?;
    std::fs::create_dir_all(dir)?;
    let (k, camera_flat) = lab(&sim, dir)?;
    let direction = move |x: f64, y: f64| match k.pixel_to_direction(x, y) {
        Some(d) => (d.x / d.z, d.y / d.z),
        None => (f64::NAN, f64::NAN),
    };
    let setup = flat::FlatSetup {
        cfg: &c.cfg,
        bits: c.fac.drive.bits,
        screen,
        pixel_direction: &direction,
        geometry: &geometry,
        camera_flat: Some(camera_flat),
    };
    let _ = std::fs::remove_file(dir.join("f.jsonl"));
    let mut ckpt = Checkpoint::open(&dir.join("f.jsonl"), "bench", flat::ROUTINE, false)?;
    let mut rig = SimInstruments::new(&sim);
    let mut darks = DarkBank::shutter(4);
    let mut inst = rig.lend(None, &mut darks);
    let start = Instant::now();
    let (gains, report) = flat::run(&mut inst, &setup, &mut ckpt)?;
    let tif = dir.join("flat_field.tif");
    flat::write_tiff(&tif, &gains, screen)?;
    let seconds = start.elapsed().as_secs_f64();
    let ff = FlatField::load(&tif, screen)?;
    let [u0, v0, u1, v1] = report.seen;
    let scores = FLAT_SCORED
        .iter()
        .map(|&level| {
            let mut ratios = Vec::new();
            for v in (v0.max(0.0) as usize..(v1 as usize).min(screen.1)).step_by(4) {
                for u in (u0.max(0.0) as usize..(u1 as usize).min(screen.0)).step_by(4) {
                    let (x, y) = (u as f64 + 0.5, v as f64 + 0.5);
                    let truth = sim.screen().uniformity_at(level, x, y);
                    ratios.push(ff.gain(u, v) as f64 / truth);
                }
            }
            let mean = ratios.iter().sum::<f64>() / ratios.len().max(1) as f64;
            let errors: Vec<f64> = ratios.iter().map(|r| r / mean - 1.0).collect();
            rms_max(&errors)
        })
        .collect();
    Ok((seconds, scores))
}

fn main() -> Result<()> {
    let a = args()?;
    let c = common()?;
    std::fs::create_dir_all(&a.out)?;
    let mut md = String::new();
    let seeds: Vec<u64> = (1..=a.runs as u64).collect();

    // Geometric, full camera.
    let mut geo = Vec::new();
    for &s in &seeds {
        let r = geometric_once(&c, s, &a.out.join(format!("geometric_{s}")))?;
        eprintln!("geometric seed {s}: {:.2} s, {:?}", r.0, r.1);
        geo.push(r);
    }
    let worst = |i: usize| geo.iter().map(|g| g.1[i]).fold(0.0f64, f64::max);
    let mean = |i: usize| geo.iter().map(|g| g.1[i]).sum::<f64>() / geo.len() as f64;
    md += &format!(
        "| geometric (1024 px camera) | {:.4} | {:.4} | {:.3} | {:.3} | {:.2} |\n",
        mean(0),
        worst(1),
        mean(2),
        worst(3),
        median(geo.iter().map(|g| g.0).collect())
    );
    let geo_table = std::mem::take(&mut md);

    // Flat field, full camera, on the first geometric run's geometry.
    let geometry_csv = a.out.join("geometric_1").join("geometry.csv");
    let mut fl = Vec::new();
    for &s in &seeds {
        let r = flat_once(&c, s, &geometry_csv, &a.out.join(format!("flat_{s}")))?;
        eprintln!(
            "flat seed {s}: {:.2} s, (rms, max) per level {:?}",
            r.0, r.1
        );
        fl.push(r);
    }
    let mut flat_table = String::new();
    for (i, level) in FLAT_SCORED.iter().enumerate() {
        flat_table += &format!(
            "| {level} | {:.3} | {:.3} | {:.2} |\n",
            100.0 * fl.iter().map(|f| f.1[i].0).sum::<f64>() / fl.len() as f64,
            100.0 * fl.iter().map(|f| f.1[i].1).fold(0.0f64, f64::max),
            median(fl.iter().map(|f| f.0).collect())
        );
    }
    let flat_title = format!(
        "flat field: 1024 px camera, levels {:?} fitted at degree {} with residual cells",
        c.cfg.flat.levels, c.cfg.flat.degree
    );

    // Radiometric grid.
    let mut rad_table = String::new();
    let mut curves = Vec::new();
    for &repeats in &REPEATS {
        let mut curve = Vec::new();
        for &levels in &LEVELS {
            let mut runs = Vec::new();
            for &s in &seeds {
                let dir = a.out.join(format!("radiometric_{levels}x{repeats}_{s}"));
                let r = radiometric_once(&c, levels, repeats, s, a.radiometric_px, &dir)?;
                eprintln!(
                    "radiometric {levels} levels x {repeats} seed {s}: {:.2} s ({:.1} min at the facility), rms {:.4} % max {:.4} %",
                    r.0,
                    r.3 / 60.0,
                    100.0 * r.1,
                    100.0 * r.2
                );
                runs.push(r);
            }
            let rms = runs.iter().map(|r| r.1).sum::<f64>() / runs.len() as f64;
            let shape = runs.iter().map(|r| r.4).sum::<f64>() / runs.len() as f64;
            let max = runs.iter().map(|r| r.2).fold(0.0f64, f64::max);
            rad_table += &format!(
                "| {levels} | {repeats} | {:.3} | {:.3} | {:.3} | {:.2} | {:.1} |\n",
                100.0 * rms,
                100.0 * max,
                100.0 * shape,
                median(runs.iter().map(|r| r.0).collect()),
                median(runs.iter().map(|r| r.3).collect()) / 60.0
            );
            curve.push((levels as f64, 100.0 * rms));
        }
        curves.push(Series::line(format!("{repeats} repeat(s)"), curve));
    }
    curves.push(Series::line(
        "goal 0.5 %",
        vec![(LEVELS[0] as f64, 0.5), (LEVELS[2] as f64, 0.5)],
    ));
    let png = a.out.join("calibration_bench_lut.png");
    curve_figure(
        &png,
        &CurveFigure {
            title: format!(
                "Display LUT error vs levels (simulated facility, mean of {} runs)",
                a.runs
            ),
            x_label: "levels measured".into(),
            main: Panel {
                y_label: "LUT error RMS over levels > 1 % of max (%)".into(),
                log_y: false,
                series: curves,
            },
            residuals: None,
            size: (900, 600),
        },
    )?;

    let table = format!(
        "Radiometric ({px} × {px} px central camera, {runs} runs: seeds 1..{runs}; error = mean RMS, worst max over the runs; time = median wall time)\n\n\
         | levels | repeats | LUT error RMS (%) | LUT error max (%) | RMS after a common scale (%) | compute time (s) | facility time (min) |\n|---:|---:|---:|---:|---:|---:|---:|\n{rad_table}\n\
         Geometric ({runs} runs; residual against the true geometry on an 8-px screen lattice over the seen area; mean RMS, worst max)\n\n\
         | routine | RMS (camera px) | max (camera px) | RMS (arcsec) | max (arcsec) | wall time (s) |\n|---|---:|---:|---:|---:|---:|\n{geo_table}\n\
         Flat field ({flat_title}; {runs} runs; gain/true uniformity of the scored level − 1 over the seen area, both normalised to their mean there)\n\n\
         | scored at level | error RMS (%) | error max (%) | wall time (s) |\n|---:|---:|---:|---:|\n{flat_table}",
        px = a.radiometric_px,
        runs = a.runs
    );
    let path = a.out.join("calibration_bench.md");
    std::fs::write(&path, &table)?;
    println!("{table}\nwrote {} and {}", path.display(), png.display());
    Ok(())
}
