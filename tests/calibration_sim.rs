//! The radiometric calibration of the simulated facility (noise, dark
//! current, a screen spectrum unlike the Sun's, a broadband meter with a
//! computed mismatch factor) recovers the facility's true curve, read from
//! its truth accessor: within 0.5 % RMS over the levels above 1 % of the
//! maximum (the issue's goal).

use std::path::Path;

use optistim::calibration::checkpoint::Checkpoint;
use optistim::calibration::config::CalibrateConfig;
use optistim::calibration::dark::DarkBank;
use optistim::calibration::flat;
use optistim::calibration::mismatch::{table_spectrum, CameraSpectral};
use optistim::calibration::radiometric::{self, Outputs, Setup};
use optistim::calibration::responsivity::CameraResponsivity;
use optistim::calibration::show_level;
use optistim::calibration::verify::{self, AbsoluteCamera, VerifyReport, VerifySetup};
use optistim::facility::lut::DisplayLut;
use optistim::instruments::{Camera, CaptureRequest, SpotMeter, SpotReading};
use optistim::radiometry::spectrum::Table;
use optistim::scene::Scene;
use optistim::simfacility::instruments::SimInstruments;
use optistim::simfacility::{SimFacility, SimMeter};

mod common;
use common::simfacility::bundled_edited;

/// The bundled simulated facility with a 128 × 128 camera (the same
/// focal length, so a 0.7° field around the axis) to keep the test fast.
fn small_facility() -> SimFacility {
    small_facility_with(1, 0.0, 50.0)
}

/// The same with the camera's `seed`, bias (DN) and dark current (e-/s).
fn small_facility_with(seed: u64, bias_dn: f64, dark_current: f64) -> SimFacility {
    bundled_edited(&[
        ("resolution = [1024, 1024]", "resolution = [128, 128]"),
        ("cx = 512.0", "cx = 64.0"),
        ("cy = 512.0", "cy = 64.0"),
        ("seed = 1", &format!("seed = {seed}")),
        ("bias_dn = 0.0", &format!("bias_dn = {bias_dn:?}")),
        (
            "dark_current = 50.0",
            &format!("dark_current = {dark_current:?}"),
        ),
    ])
}

const CALIBRATE: &str = r#"
[calibrate]
levels = 33
repeats = 2
settle = 0.5
screen_spectrum = "data/display/lcd_white_apple_studio_display.csv"
screen_spectrum_uncertainty_nm = 1.0

[calibrate.meter]
kind = "sim"
spectral_response = "configs/meter_flat_380_780.csv"
scale_uncertainty_k2_percent = 1.0

[calibrate.camera]
kind = "sim"
exposure = 2.0e-3
saturation_dn = 4095
resolution = [128, 128]
dark = "shutter"
"#;

/// Runs the radiometric routine on `sim` (warmed up first) with these
/// darks; returns the report and the LUT it wrote.
fn calibrate_lut(sim: &SimFacility, darks: &mut DarkBank) -> (radiometric::Report, DisplayLut) {
    calibrate_lut_with(sim, darks, 1.0, 0.0)
}

/// A meter whose unit is off by `1` factor (reading × factor).
struct ScaledMeter(SimMeter, f64);
impl SpotMeter for ScaledMeter {
    fn measure(&mut self) -> optistim::Result<SpotReading> {
        let mut r = self.0.measure()?;
        r.value *= self.1;
        Ok(r)
    }
    fn describe(&self) -> String {
        format!("{} x {}", self.0.describe(), self.1)
    }
}

/// The screen spectrum file's shape, shifted by `nm` (S'(λ) = S(λ − nm)).
fn screen_spectrum(shift_nm: f64) -> Vec<(f64, f64)> {
    table_spectrum(&Table::from_csv(Path::new(SPECTRUM)).unwrap())
        .into_iter()
        .map(|(l, v)| (l + shift_nm, v))
        .collect()
}

const SPECTRUM: &str = "data/display/lcd_white_apple_studio_display.csv";
const METER_RESPONSE: &str = "configs/meter_flat_380_780.csv";

/// The campaign with the meter's unit scaled by `meter_scale` and the
/// screen spectrum file shifted by `shift_nm`.
fn calibrate_lut_with(
    sim: &SimFacility,
    darks: &mut DarkBank,
    meter_scale: f64,
    shift_nm: f64,
) -> (radiometric::Report, DisplayLut) {
    // An operator warms the screen up first (the simulated warm-up has a
    // 600 s time constant).
    sim.advance(3600.0);
    campaign(sim, darks, meter_scale, shift_nm)
}

/// The campaign on `sim` as it is now (warm or not).
fn campaign(
    sim: &SimFacility,
    darks: &mut DarkBank,
    meter_scale: f64,
    shift_nm: f64,
) -> (radiometric::Report, DisplayLut) {
    let cfg = CalibrateConfig::parse(CALIBRATE, "calibrate.toml", 8).unwrap();
    let scene = Scene::from_file(Path::new("configs/moon_plain.toml")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let mut ckpt =
        Checkpoint::open(&dir.path().join("c.jsonl"), "fp", "radiometric", false).unwrap();
    let mut rig = SimInstruments::new(sim);
    let mut meter = ScaledMeter(sim.meter(), meter_scale);
    let mut inst = rig.lend(Some(&mut meter), darks);
    let mut setup = Setup {
        cfg: &cfg,
        bits: 8,
        spectral: Some(CameraSpectral::from_scene(&scene)),
        meter_response: Some(Table::from_csv(Path::new(METER_RESPONSE)).unwrap()),
        screen_spectrum: Some(screen_spectrum(shift_nm)),
        spectroradiometer: None,
        screen_power: None,
        source: "test".into(),
    };
    let report = radiometric::run(&mut inst, &mut setup, &mut ckpt).unwrap();
    radiometric::write(&report, &setup, &Outputs::in_dir(dir.path())).unwrap();
    if let Some(keep) = std::env::var_os("OPTISTIM_KEEP_FIGURES") {
        let to = Path::new(&keep).join("radiometric_sim.png");
        std::fs::copy(dir.path().join("radiometric.png"), to).unwrap();
    }
    let lut = DisplayLut::load(dir.path().join("lut.csv"), 8).unwrap();
    (report, lut)
}

/// The campaign of [`CALIBRATE`] with the screen's spectrum measured by the
/// simulated spectroradiometer at the default levels instead of the white
/// spectrum file: F per level. The spectra come after the patches, so the
/// patches' readings are those of [`calibrate_lut`] on the same facility.
fn calibrate_lut_measured(sim: &SimFacility) -> (radiometric::Report, DisplayLut) {
    sim.advance(3600.0);
    let text = CALIBRATE.replace(
        "screen_spectrum = \"data/display/lcd_white_apple_studio_display.csv\"\n",
        "",
    ) + "\n[calibrate.spectroradiometer]\nkind = \"sim\"\n";
    let cfg = CalibrateConfig::parse(&text, "calibrate.toml", 8).unwrap();
    assert!(cfg.screen_spectrum.is_none() && cfg.spectroradiometer.is_some());
    let scene = Scene::from_file(Path::new("configs/moon_plain.toml")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let mut ckpt =
        Checkpoint::open(&dir.path().join("c.jsonl"), "fp", "radiometric", false).unwrap();
    let (mut rig, mut meter) = (SimInstruments::new(sim), sim.meter());
    let mut spectro = sim.spectroradiometer();
    let mut darks = DarkBank::shutter(4);
    let mut inst = rig.lend(Some(&mut meter), &mut darks);
    let mut setup = Setup {
        cfg: &cfg,
        bits: 8,
        spectral: Some(CameraSpectral::from_scene(&scene)),
        meter_response: Some(Table::from_csv(Path::new(METER_RESPONSE)).unwrap()),
        screen_spectrum: None,
        spectroradiometer: Some(&mut spectro),
        screen_power: None,
        source: "test".into(),
    };
    let report = radiometric::run(&mut inst, &mut setup, &mut ckpt).unwrap();
    radiometric::write(&report, &setup, &Outputs::in_dir(dir.path())).unwrap();
    let lut = DisplayLut::load(dir.path().join("lut.csv"), 8).unwrap();
    (report, lut)
}

/// The screen point on the camera's axis (where the central region looks).
fn axis_screen_point(sim: &SimFacility) -> (f64, f64) {
    let (mut u, mut v) = (960.0, 540.0);
    for _ in 0..50 {
        let (x, y) = sim.true_camera_pixel(u, v);
        u -= (x - 64.0) * 0.9;
        v -= (y - 64.0) * 0.9;
    }
    (u, v)
}

/// A LUT against the truth at the axis: RMS and max |error| over the
/// levels above 1 % of the maximum, and the mean error over those above
/// 10 % (the scale's), fractions.
fn lut_errors(sim: &SimFacility, lut: &DisplayLut) -> (f64, f64, f64) {
    let p = axis_screen_point(sim);
    let top = sim.true_camera_effective_radiance(255, p);
    let (mut s2, mut n, mut worst, mut sum, mut m) = (0.0, 0, 0.0f64, 0.0, 0);
    for level in 0..=255usize {
        let truth = sim.true_camera_effective_radiance(level, p);
        let e = lut.radiance(level as f64) / truth - 1.0;
        if truth > 0.01 * top {
            s2 += e * e;
            n += 1;
            worst = worst.max(e.abs());
        }
        if truth > 0.1 * top {
            sum += e;
            m += 1;
        }
    }
    ((s2 / n as f64).sqrt(), worst, sum / m as f64)
}

/// F per level from the simulated spectroradiometer's spectra: each
/// measured F follows the simulator's own ratio of camera-effective
/// radiance to meter reading (its integrals, not the calibration's) in
/// its change with level, within 0.1 % (the spectra's 0.3 nm wavelength
/// error cancels in the ratio to the white; their noise is 0.2 % per 5 nm
/// bin); and applied to each reading it removes the scale's bias that the
/// white's single F leaves, on the same patches' readings.
#[test]
fn f_per_level_from_measured_spectra_removes_the_scale_bias() {
    let (file_report, file_lut) = calibrate_lut(&small_facility(), &mut DarkBank::shutter(4));
    let sim = small_facility();
    let (report, lut) = calibrate_lut_measured(&sim);
    let screen = sim.screen();
    let f_true = |l: u32| screen.camera_effective[l as usize] / screen.meter[l as usize];
    let points = &report.mismatch_by_level;
    assert_eq!(
        points.iter().map(|p| p.level).collect::<Vec<_>>(),
        [64, 96, 128, 159, 191, 223, 255]
    );
    let white = points.last().unwrap();
    for p in points {
        let measured = p.factor / white.factor;
        let truth = f_true(p.level) / f_true(255);
        println!(
            "level {:3}: F {:.5} (truth {:.5}), relative to white {:.5} (truth {:.5}), noise {:.4} %, 1 nm {:.3} %",
            p.level,
            p.factor,
            f_true(p.level),
            measured,
            truth,
            p.noise_k2_percent,
            p.wavelength_k2_percent.unwrap()
        );
        assert!((measured / truth - 1.0).abs() < 1e-3, "level {}", p.level);
        assert_eq!(p.spectra, 2);
    }
    // The scale, recomputed here: each level's meter reading × F at its
    // level, linear between the measured levels, fitted to the camera
    // response over the levels above 10 % of the top's (and not the
    // white's F for all, which differs by more than 0.1 %).
    let f_at = |level: f64| {
        let k = points
            .iter()
            .position(|p| p.level as f64 >= level)
            .unwrap_or(points.len() - 1)
            .max(1);
        let (a, b) = (&points[k - 1], &points[k]);
        let t = ((level - a.level as f64) / (b.level - a.level) as f64).clamp(0.0, 1.0);
        a.factor + t * (b.factor - a.factor)
    };
    let top = report.levels.last().unwrap().camera_dn_per_s;
    let fit = |f: &dyn Fn(f64) -> f64| {
        let (mut num, mut den) = (0.0, 0.0);
        for l in report
            .levels
            .iter()
            .filter(|l| l.camera_dn_per_s >= 0.1 * top)
        {
            num += l.camera_dn_per_s * f(l.level as f64) * l.meter.unwrap();
            den += l.camera_dn_per_s * l.camera_dn_per_s;
        }
        num / den
    };
    let expect = fit(&f_at);
    assert!(
        (report.scale / expect - 1.0).abs() < 1e-9,
        "{} vs {expect}",
        report.scale
    );
    assert!((fit(&|_| white.factor) / expect - 1.0).abs() > 1e-3);
    // The effect is there to correct: F changes by more than 1 % over the levels.
    assert!(f_true(64) / f_true(255) < 0.99);
    let (rms0, max0, bias0) = lut_errors(&sim, &file_lut);
    let (rms, max, bias) = lut_errors(&sim, &lut);
    println!(
        "white F {:?}: LUT error RMS {:.3} %, max {:.3} %, scale bias {:+.3} %, spectral trend {:.3} %",
        file_report.mismatch_factor,
        100.0 * rms0,
        100.0 * max0,
        100.0 * bias0,
        file_report.budget.spectral_trend_k2_percent
    );
    println!(
        "F per level: LUT error RMS {:.3} %, max {:.3} %, scale bias {:+.3} %, spectral trend {:.3} %; {}",
        100.0 * rms,
        100.0 * max,
        100.0 * bias,
        report.budget.spectral_trend_k2_percent,
        report.budget.describe()
    );
    assert!(rms < 0.005, "LUT RMS error {:.3} %", 100.0 * rms);
    assert!(bias.abs() < bias0.abs(), "{bias} vs {bias0}");
    // The trend term now bounds the interpolation only: below the white F's.
    assert!(report.budget.spectral_trend_k2_percent < file_report.budget.spectral_trend_k2_percent);
}

/// Largest |a/b − 1| over the levels above 1 % of b's maximum, and at
/// level 0.
fn lut_difference(a: &DisplayLut, b: &DisplayLut) -> (f64, f64) {
    let top = b.max_radiance();
    let worst = (0..=255)
        .map(|l| (a.radiance(l as f64), b.radiance(l as f64)))
        .filter(|&(_, y)| y > 0.01 * top)
        .map(|(x, y)| (x / y - 1.0).abs())
        .fold(0.0f64, f64::max);
    (worst, (a.radiance(0.0) / b.radiance(0.0) - 1.0).abs())
}

/// The camera's bias and dark current are taken out by the darks: a camera
/// with 100 DN of bias and 50 e-/s of dark current gives the LUT of one
/// with neither, within the campaign's noise (≤ 1 % above 1 % of the
/// maximum, ≤ 3 % at level 0), for three noise seeds. Without darks the
/// same camera's level 0 is off by far more (the check can fail).
#[test]
fn the_lut_does_not_depend_on_the_camera_bias_and_dark_current() {
    for seed in 1..=3 {
        let clean = small_facility_with(seed, 0.0, 0.0);
        let biased = small_facility_with(seed, 100.0, 50.0);
        let (_, a) = calibrate_lut(&clean, &mut DarkBank::shutter(4));
        let (_, b) = calibrate_lut(&biased, &mut DarkBank::shutter(4));
        let (worst, black) = lut_difference(&b, &a);
        println!(
            "seed {seed}: bias 100 DN + 50 e-/s vs none: max {:.3} % above 1 % of max, {:.3} % at level 0",
            100.0 * worst,
            100.0 * black
        );
        assert!(worst <= 0.01, "seed {seed}: {:.3} %", 100.0 * worst);
        assert!(black <= 0.03, "seed {seed}: level 0 {:.3} %", 100.0 * black);
        if seed == 1 {
            let biased = small_facility_with(seed, 100.0, 50.0);
            let (_, c) = calibrate_lut(&biased, &mut DarkBank::none());
            let (worst, black) = lut_difference(&c, &a);
            println!(
                "seed 1 without darks: max {:.3} % above 1 % of max, {:.3} % at level 0",
                100.0 * worst,
                100.0 * black
            );
            assert!(
                black > 0.03,
                "without darks level 0 is off by {:.3} %",
                100.0 * black
            );
        }
    }
}

#[test]
fn radiometric_calibration_recovers_the_simulated_screen_within_half_a_percent() {
    let sim = small_facility();
    let (report, lut) = calibrate_lut(&sim, &mut DarkBank::shutter(4));
    // The truth where the camera's central region looks: the screen point
    // on the camera's axis.
    let (mut u, mut v) = (960.0, 540.0);
    for _ in 0..50 {
        let (x, y) = sim.true_camera_pixel(u, v);
        u -= (x - 64.0) * 0.9;
        v -= (y - 64.0) * 0.9;
    }
    let top = sim.true_camera_effective_radiance(255, (u, v));
    let (mut s2, mut n, mut worst) = (0.0, 0, 0.0f64);
    for level in 0..=255usize {
        let truth = sim.true_camera_effective_radiance(level, (u, v));
        if truth > 0.01 * top {
            let e = lut.radiance(level as f64) / truth - 1.0;
            s2 += e * e;
            n += 1;
            worst = worst.max(e.abs());
        }
    }
    let rms = (s2 / n as f64).sqrt();
    println!(
        "simulated facility: LUT error RMS {:.3} %, max {:.3} % over {n} levels; leave-one-out RMS {:.3} %; F = {:?}; drift {:+.3} %",
        100.0 * rms,
        100.0 * worst,
        report.loo_rms_percent,
        report.mismatch_factor,
        report.drift_percent
    );
    assert!(rms < 0.005, "LUT RMS error {:.3} %", 100.0 * rms);
    // The budget: the declared meter uncertainty, F's change for the
    // spectrum shifted by its declared 1 nm (computed here from the
    // spectra), and a per-level total that covers the LUT's true error.
    let b = &report.budget;
    assert_eq!(b.meter_scale_k2_percent, Some(1.0));
    let scene = Scene::from_file(Path::new("configs/moon_plain.toml")).unwrap();
    let spectral = CameraSpectral::from_scene(&scene);
    let m = Table::from_csv(Path::new(METER_RESPONSE)).unwrap();
    let f0 = spectral.mismatch_factor(&screen_spectrum(0.0), &m).unwrap();
    let df = [-1.0, 1.0]
        .map(|d| (spectral.mismatch_factor(&screen_spectrum(d), &m).unwrap() / f0 - 1.0).abs());
    let expect = 100.0 * df[0].max(df[1]);
    assert!(
        (b.mismatch_k2_percent.unwrap() - expect).abs() < 1e-9,
        "{b:?}"
    );
    let (mut covered, mut n) = (0, 0);
    for l in &report.levels {
        let truth = sim.true_camera_effective_radiance(l.level as usize, (u, v));
        if truth > 0.01 * top {
            n += 1;
            let e = 100.0 * (l.radiance / truth - 1.0);
            covered += usize::from(e.abs() <= l.uncertainty.total_k2_percent);
        }
    }
    println!(
        "budget: {}; top level U = {:.3} %; {covered} of {n} levels' true errors within U",
        b.describe(),
        report.levels.last().unwrap().uncertainty.total_k2_percent
    );
    assert!(covered as f64 >= 0.95 * n as f64, "{covered} of {n}");
}

/// The flat field of the simulated facility, with the geometry written from
/// the facility's true map and its camera's own flat, has the shape of the
/// facility's true smooth non-uniformity (falloff and gradient): the ratio
/// of the recovered gain to the truth is constant over the area the camera
/// sees. The mura is off here: its 20–200 px periods are beyond the flat's
/// degree-4 polynomial (with the bundled 0.3 % rms the ratio spreads by
/// 1.7 %, tests/closed_loop.rs sees what that costs).
#[test]
fn flat_field_recovers_the_simulated_screen_non_uniformity() {
    let (sim, gains, report) = sim_flat(1.0, 0.0);
    if let Some(keep) = std::env::var_os("OPTISTIM_KEEP_FIGURES") {
        let keep = Path::new(&keep);
        let (json, png) = (keep.join("flat_sim.json"), keep.join("flat_sim.png"));
        flat::write_report(&report, &gains, (1920, 1080), &json, &png).unwrap();
    }
    let [u0, v0, u1, v1] = report.seen;
    let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
    for j in 1..20 {
        for i in 1..20 {
            let u = u0 + (u1 - u0) * i as f64 / 20.0;
            let v = v0 + (v1 - v0) * j as f64 / 20.0;
            let truth = sim.true_camera_effective_radiance(255, (u, v));
            let gain = gains[v as usize * 1920 + u as usize] as f64;
            let ratio = gain / truth;
            lo = lo.min(ratio);
            hi = hi.max(ratio);
        }
    }
    println!(
        "simulated flat field: gain/truth varies by {:.3} % over the seen area {:?} (13-point non-uniformity {:.2} %, declared uncertainty {:.3} % k = 2)",
        100.0 * (hi / lo - 1.0),
        report.seen,
        report.nonuniformity_13_percent,
        report.uncertainty_k2_percent
    );
    // The declared uncertainty covers the shape error (a spread hi/lo of
    // the ratio is at most twice the error of either end).
    assert!(100.0 * (hi / lo - 1.0) <= 2.0 * report.uncertainty_k2_percent);
    // The per-pixel map: between the fit term alone and the area's total
    // (the mean of two levels is half-way, so its spread is half the
    // levels' disagreement).
    let umap = flat::uncertainty_map(&report, (1920, 1080));
    let fit_only = umap.iter().copied().fold(f32::INFINITY, f32::min) as f64;
    let worst = umap.iter().copied().fold(0.0f32, f32::max) as f64;
    println!("flat uncertainty map: {fit_only:.4} … {worst:.4} %");
    assert!(fit_only > 0.0 && worst <= report.uncertainty_k2_percent + 1e-6);
    assert!(
        hi / lo - 1.0 < 0.003,
        "gain/truth spread {:.3} %",
        100.0 * (hi / lo - 1.0)
    );
}

/// The direction (tan x, tan y) of camera pixel (x, y) for a camera of
/// focal length `f` px, principal point (c, c) and radial `k1`: its
/// intrinsics inverted here by fixed-point iteration.
fn pixel_direction(f: f64, c: f64, k1: f64) -> impl Fn(f64, f64) -> (f64, f64) {
    move |x: f64, y: f64| {
        let (xd, yd) = ((x - c) / f, (y - c) / f);
        let (mut tx, mut ty) = (xd, yd);
        for _ in 0..50 {
            let r = 1.0 + k1 * (tx * tx + ty * ty);
            tx = xd / r;
            ty = yd / r;
        }
        (tx, ty)
    }
}

/// The flat routine on a 128 × 128 camera over the bundled 6° field, with
/// the camera's focal length in the intrinsics scaled by `f_scale` and its
/// principal point moved by `dc` px (the truth: 1, 0).
fn sim_flat(f_scale: f64, dc: f64) -> (SimFacility, Vec<f32>, flat::FlatReport) {
    use optistim::calibration::flat::FlatSetup;
    use optistim::facility::geometry::GeometryCalibration;
    // A 128 × 128 camera with 8× larger pixels: the bundled 6° field.
    let sim = bundled_edited(&[
        ("resolution = [1024, 1024]", "resolution = [128, 128]"),
        ("fx = 10247.4", "fx = 1280.925"),
        ("fy = 10247.4", "fy = 1280.925"),
        ("cx = 512.0", "cx = 64.0"),
        ("cy = 512.0", "cy = 64.0"),
        ("supersample = 3", "supersample = 4"),
        ("mura_rms = 0.003", "mura_rms = 0.0"),
    ]);
    sim.advance(3600.0);
    let dir = tempfile::tempdir().unwrap();
    // The geometry file from the truth, nodes every 32 px.
    let mut g = String::from("u_px,v_px,tan_x,tan_y\n");
    let us: Vec<usize> = (0..1920).step_by(32).chain([1920]).collect();
    let vs: Vec<usize> = (0..1080).step_by(32).chain([1080]).collect();
    for &v in &vs {
        for &u in &us {
            let (tx, ty) = sim.true_geometry(u as f64, v as f64);
            g.push_str(&format!("{u},{v},{tx:?},{ty:?}\n"));
        }
    }
    std::fs::write(dir.path().join("g.csv"), g).unwrap();
    let geometry = GeometryCalibration::load(dir.path().join("g.csv"), (1920, 1080)).unwrap();
    let direction = pixel_direction(1280.925 * f_scale, 64.0 + dc, -0.05);
    let cfg = CalibrateConfig::parse(CALIBRATE, "c.toml", 8).unwrap();
    let setup = FlatSetup {
        cfg: &cfg,
        bits: 8,
        screen: (1920, 1080),
        pixel_direction: &direction,
        geometry: &geometry,
        camera_flat: Some(sim.camera_flat()),
    };
    let mut ckpt = Checkpoint::open(&dir.path().join("f.jsonl"), "fp", "flat", false).unwrap();
    let mut rig = SimInstruments::new(&sim);
    let mut darks = DarkBank::shutter(2);
    let mut inst = rig.lend(None, &mut darks);
    let (gains, report) = flat::run(&mut inst, &setup, &mut ckpt).unwrap();
    (sim, gains, report)
}

/// The screen point on the small camera's axis (its central region looks
/// there), by fixed-point iteration on the facility's map.
fn axis_point(sim: &SimFacility) -> (f64, f64) {
    let (mut u, mut v) = (960.0, 540.0);
    for _ in 0..50 {
        let (x, y) = sim.true_camera_pixel(u, v);
        u -= (x - 64.0) * 0.9;
        v -= (y - 64.0) * 0.9;
    }
    (u, v)
}

/// The camera's responsivity as a lab would measure it before the
/// campaign: a known radiance (here the facility's true level-255
/// radiance at the axis, times τ) against the dark-corrected DN/s of the
/// 16 × 16 pixels at the image centre, each divided by the camera's own
/// flat. Declared to 0.5 % (k = 2).
fn lab_responsivity(sim: &SimFacility) -> CameraResponsivity {
    let (mut display, mut camera) = (sim.display(), sim.camera());
    show_level(&mut display, 255, 8).unwrap();
    sim.advance(1.0);
    let t = 1.0e-3;
    let flat = sim.camera_flat();
    let mut mean = |req: fn(&str, f64) -> CaptureRequest| {
        let mut sum = vec![0.0f64; 128 * 128];
        for k in 0..8 {
            let f = camera.capture(&req(&format!("lab_{k}"), t)).unwrap();
            assert!(f.data.iter().all(|&v| v < f.saturation_dn));
            sum.iter_mut()
                .zip(&f.data)
                .for_each(|(s, &v)| *s += v as f64 / 8.0);
        }
        sum
    };
    let light = mean(|n, t| CaptureRequest::light(n, t));
    let dark = mean(|n, t| CaptureRequest::dark(n, t));
    let mut dn = 0.0;
    for y in 56..72 {
        for x in 56..72 {
            let i = y * 128 + x;
            dn += (light[i] - dark[i]) / flat[i] as f64 / 256.0;
        }
    }
    let tau = sim.config().collimator.transmission;
    let l = sim.true_camera_effective_radiance(255, axis_point(sim));
    CameraResponsivity {
        responsivity_dn_per_s_per_w_m2_sr: dn / t / (tau * l),
        uncertainty_k2_percent: 0.5,
    }
}

/// Verify on `sim` with `lut` and the campaign's meter (its unit scaled by
/// `meter_scale`, as in the campaign) (no flat field: the shifts asserted below
/// are differences between verifications, in which the screen's
/// non-uniformity cancels).
fn verify_on(
    sim: &SimFacility,
    lut: DisplayLut,
    report: &radiometric::Report,
    responsivity: CameraResponsivity,
    meter_scale: f64,
) -> VerifyReport {
    let cfg = CalibrateConfig::parse(CALIBRATE, "calibrate.toml", 8).unwrap();
    let scene = Scene::from_file(Path::new("configs/moon_plain.toml")).unwrap();
    let direction = pixel_direction(10247.4, 64.0, -0.05);
    let setup = VerifySetup {
        cfg: &cfg,
        lut,
        flat: None,
        screen: (1920, 1080),
        camera_scale: report.scale,
        camera: AbsoluteCamera {
            responsivity,
            transmission: 0.85,
            camera_flat: sim.camera_flat(),
            pixel_direction: &direction,
        },
        mismatch_factor: report.mismatch_factor,
        mismatch_by_level: None,
        spectral: Some(CameraSpectral::from_scene(&scene)),
        meter_uncertainty_k2_percent: Some(1.0),
        lut_scale_k2_percent: Some(report.budget.scale_total()),
    };
    let dir = tempfile::tempdir().unwrap();
    let mut ckpt = Checkpoint::open(&dir.path().join("v.jsonl"), "fp", "verify", false).unwrap();
    let mut rig = SimInstruments::new(sim);
    let mut meter = ScaledMeter(sim.meter(), meter_scale);
    let mut darks = DarkBank::shutter(4);
    let mut inst = rig.lend(Some(&mut meter), &mut darks);
    let r = verify::run(&mut inst, &setup, &mut ckpt).unwrap();
    println!("{}", verify::summary(&r));
    r
}

/// Shift of a verification's mean error against the baseline's, as the
/// ratio of achieved radiances − 1, %.
fn shift(a: f64, base: f64) -> f64 {
    100.0 * ((1.0 + a / 100.0) / (1.0 + base / 100.0) - 1.0)
}

/// Verify sees what the calibration got wrong, by about the injected
/// amount: a meter unit 1 % high makes the LUT 1 % bright, so the camera
/// (through its own responsivity) finds every patch short by 1/1.01 − 1;
/// a screen spectrum file shifted by 2 nm scales the LUT by F'/F (F' from
/// the shifted spectrum); a LUT 3 % bright gives 1/1.03 − 1 at camera and
/// meter. The meter, which shares F and its unit with the calibration,
/// cannot see the first two (its shift stays ~0), which the test asserts
/// too. Tolerance 0.15 percentage points: three times the largest
/// difference between two campaigns' LUTs on this facility (0.055 %, the
/// bias test above), which a shift between two campaigns contains.
#[test]
fn verify_moves_by_the_injected_error() {
    let tol = 0.15;
    let base_sim = small_facility();
    let (report, lut) = calibrate_lut(&base_sim, &mut DarkBank::shutter(4));
    let resp = lab_responsivity(&base_sim);
    let base = verify_on(&base_sim, lut.clone(), &report, resp, 1.0);
    println!(
        "baseline: mean camera {:+.3} %, meter {:+.3?} %",
        base.mean_camera_error_percent, base.mean_meter_error_percent
    );
    let meter_base = base.mean_meter_error_percent.unwrap();
    let check = |name: &str, r: &VerifyReport, camera_expected: f64, meter_expected: f64| {
        let cam = shift(r.mean_camera_error_percent, base.mean_camera_error_percent);
        let met = shift(r.mean_meter_error_percent.unwrap(), meter_base);
        println!(
            "{name}: camera shift {cam:+.3} % (expected {camera_expected:+.3} %), meter shift {met:+.3} % (expected {meter_expected:+.3} %)"
        );
        assert!((cam - camera_expected).abs() < tol, "{name}: camera {cam}");
        assert!((met - meter_expected).abs() < tol, "{name}: meter {met}");
    };

    // 1 % meter-scale error.
    let sim = small_facility();
    let (rep, l) = calibrate_lut_with(&sim, &mut DarkBank::shutter(4), 1.01, 0.0);
    let r = verify_on(&sim, l, &rep, resp, 1.01);
    check("meter unit +1 %", &r, 100.0 * (1.0 / 1.01 - 1.0), 0.0);

    // Screen spectrum 2 nm off: F' from the shifted file.
    let scene = Scene::from_file(Path::new("configs/moon_plain.toml")).unwrap();
    let spectral = CameraSpectral::from_scene(&scene);
    let m = Table::from_csv(Path::new(METER_RESPONSE)).unwrap();
    let f0 = spectral.mismatch_factor(&screen_spectrum(0.0), &m).unwrap();
    let f2 = spectral.mismatch_factor(&screen_spectrum(2.0), &m).unwrap();
    let sim = small_facility();
    let (rep, l) = calibrate_lut_with(&sim, &mut DarkBank::shutter(4), 1.0, 2.0);
    let r = verify_on(&sim, l, &rep, resp, 1.0);
    println!("F = {f0:.5}, F(+2 nm) = {f2:.5}");
    check("spectrum +2 nm", &r, 100.0 * (f0 / f2 - 1.0), 0.0);

    // A LUT 3 % bright.
    let levels: Vec<f64> = (0..=255).map(|d| d as f64).collect();
    let bright: Vec<f64> = levels.iter().map(|&d| 1.03 * lut.radiance(d)).collect();
    let wrong = DisplayLut::from_points(&levels, &bright, 8).unwrap();
    let r = verify_on(&base_sim, wrong, &report, resp, 1.0);
    let e = 100.0 * (1.0 / 1.03 - 1.0);
    check("LUT +3 %", &r, e, e);
    let shaped: Vec<f64> = levels
        .iter()
        .map(|&d| (1.0 + 0.05 * (1.0 - d / 255.0)) * lut.radiance(d))
        .collect();
    let shaped = DisplayLut::from_points(&levels, &shaped, 8).unwrap();
    let shaped = verify_on(&base_sim, shaped, &report, resp, 1.0);
    common_mode_tells_scale_from_shape(&base, &r, &shaped);
}

/// The split of verify's camera errors (`CommonMode`): a LUT 3 % bright
/// everywhere (`scaled`) moves the common mode beyond its budget (the
/// baseline's mean + 1/1.03 − 1, out of ± hypot(responsivity, LUT scale)
/// ≈ ± 1.5 %) and leaves the spread about it as it was (within 0.1
/// percentage points); a LUT wrong in its shape (`shaped`: 5 % bright at
/// level 0, tapering linearly to 0 at 255) widens the spread by more than
/// a percentage point, since its patches (levels 15–242) move by 4.5 … 0.3 %.
fn common_mode_tells_scale_from_shape(
    base: &VerifyReport,
    scaled: &VerifyReport,
    shaped: &VerifyReport,
) {
    let common = |r: &VerifyReport| r.camera_common_mode.clone().expect("common mode");
    let (b, s, c) = (common(base), common(scaled), common(shaped));
    println!(
        "baseline: {}\nLUT +3 %: {}\nLUT shaped: {}",
        b.describe(),
        s.describe(),
        c.describe()
    );
    let expected = shift_by(b.mean_percent, 1.0 / 1.03);
    assert!(
        (s.mean_percent - expected).abs() < 0.15,
        "{s:?} vs {expected}"
    );
    assert!(b.within && !s.within, "{b:?} {s:?}");
    assert!((s.max_spread_percent - b.max_spread_percent).abs() < 0.1);
    assert!(c.max_spread_percent > b.max_spread_percent + 1.0, "{c:?}");
}

/// `mean` (%) after the measured radiance is scaled by `factor`.
fn shift_by(mean: f64, factor: f64) -> f64 {
    100.0 * ((1.0 + mean / 100.0) * factor - 1.0)
}

/// The sensitivity table of docs/CALIBRATION.md, the rows not measured by
/// the tests above: a cold calibration used on the warm screen, a campaign
/// without darks on a camera with 100 DN bias, and intrinsics errors in
/// the flat field. Each is measured against the same campaign done right;
/// the asserts say what the table says: verify catches the cold campaign
/// (its own drift, 0.2 %, hardly shows it) and the missing darks, and the intrinsics errors move the flat field by
/// less than twice its uncertainty (0.04 %): verify cannot see them.
#[test]
fn sensitivity_of_the_stimulus_to_input_errors() {
    // Cold: the campaign starts at power-on; verify runs an hour later.
    let warm = small_facility();
    let (rep_w, lut_w) = calibrate_lut(&warm, &mut DarkBank::shutter(4));
    let resp = lab_responsivity(&warm);
    let base = verify_on(&warm, lut_w, &rep_w, resp, 1.0);
    let cold = small_facility();
    let (rep_c, lut_c) = campaign(&cold, &mut DarkBank::shutter(4), 1.0, 0.0);
    cold.advance(3600.0);
    let r = verify_on(&cold, lut_c, &rep_c, resp, 1.0);
    let cam = shift(r.mean_camera_error_percent, base.mean_camera_error_percent);
    println!(
        "cold calibration: campaign drift {:+.3} %, verify camera shift {cam:+.3} %, {} beyond threshold",
        rep_c.drift_percent, r.failures
    );
    // The screen is ~2 % dim for the whole (short) campaign: the LUT is
    // ~2 % dark and the stimulus ~2 % bright; verify's camera sees it.
    assert!(cam > 1.5 && r.failures > 0, "{cam}");

    // No darks, 100 DN bias + 50 e-/s: the LUT against the dark-corrected
    // one, and verify (which takes its own darks) on it.
    let sim = small_facility_with(1, 100.0, 50.0);
    sim.advance(3600.0);
    let (rep_d, lut_d) = campaign(&sim, &mut DarkBank::shutter(4), 1.0, 0.0);
    let resp_b = lab_responsivity(&sim);
    let ok = verify_on(&sim, lut_d.clone(), &rep_d, resp_b, 1.0);
    let (rep_n, lut_n) = campaign(&sim, &mut DarkBank::none(), 1.0, 0.0);
    let (worst, black) = lut_difference(&lut_n, &lut_d);
    let r = verify_on(&sim, lut_n, &rep_n, resp_b, 1.0);
    let first = |v: &VerifyReport| v.patches[0].spots[0].error_percent;
    let last = |v: &VerifyReport| v.patches.last().unwrap().spots[0].error_percent;
    println!(
        "no darks: LUT off by {:.2} % at level 0, max {:.2} % above 1 % of max; verify centre at the darkest patch {:+.3} % (with darks {:+.3} %), at the brightest {:+.3} % ({:+.3} %); {} beyond threshold",
        100.0 * black,
        100.0 * worst,
        first(&r),
        first(&ok),
        last(&r),
        last(&ok),
        r.failures
    );
    // With darks the campaign passes its verify. The broadband meter's one
    // F (from the white spectrum) misses the panel's bluer black leak: it
    // reads up to ~3 % high at the darkest patches, so verify shows those
    // readings without judging them (below 10 % of the LUT's maximum,
    // docs/CALIBRATION.md); the camera, reading through its own
    // responsivity, judges them.
    let camera_failures = |v: &VerifyReport| {
        v.patches
            .iter()
            .flat_map(|p| {
                p.spots
                    .iter()
                    .map(move |s| s.error_percent.abs() > p.camera_threshold_percent)
            })
            .filter(|&beyond| beyond)
            .count()
    };
    println!(
        "with darks: {} camera spots and {} meter readings beyond threshold",
        camera_failures(&ok),
        ok.failures - camera_failures(&ok)
    );
    let unjudged: Vec<f64> = ok
        .patches
        .iter()
        .filter(|p| !p.meter_judged)
        .filter_map(|p| p.meter_error_percent)
        .collect();
    println!("broadband readings shown, not judged: {unjudged:.2?} %");
    let floor = 0.1 * lut_d.max_radiance();
    assert!(ok
        .patches
        .iter()
        .all(|p| p.meter_judged == (p.target >= floor)));
    assert!(!unjudged.is_empty());
    assert!(r.failures > 0 && camera_failures(&ok) == 0 && ok.failures == 0);

    // Intrinsics: focal length +0.25 %, principal point +0.5 px.
    let (_, g0, rep0) = sim_flat(1.0, 0.0);
    for (what, fs, dc) in [
        ("focal length +0.25 %", 1.0025, 0.0),
        ("principal point +0.5 px", 1.0, 0.5),
    ] {
        let (_, g, _) = sim_flat(fs, dc);
        let [u0, v0, u1, v1] = rep0.seen;
        let mut worst = 0.0f64;
        for j in 1..20 {
            for i in 1..20 {
                let u = (u0 + (u1 - u0) * i as f64 / 20.0) as usize;
                let v = (v0 + (v1 - v0) * j as f64 / 20.0) as usize;
                worst = worst.max((g[v * 1920 + u] as f64 / g0[v * 1920 + u] as f64 - 1.0).abs());
            }
        }
        println!("{what}: flat field changes by up to {:.4} % over the seen area (its uncertainty {:.3} %)", 100.0 * worst, rep0.uncertainty_k2_percent);
        assert!(100.0 * worst < 2.0 * rep0.uncertainty_k2_percent);
    }
}
