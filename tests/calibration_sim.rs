//! The radiometric calibration of the simulated facility (noise, dark
//! current, a screen spectrum unlike the Sun's, a broadband meter with a
//! computed mismatch factor) recovers the facility's true curve, read from
//! its truth accessor: within 0.5 % RMS over the levels above 1 % of the
//! maximum (the issue's goal).

use std::path::Path;

use optistim::calibration::checkpoint::Checkpoint;
use optistim::calibration::config::CalibrateConfig;
use optistim::calibration::mismatch::{table_spectrum, CameraSpectral};
use optistim::calibration::radiometric::{self, Outputs, Setup};
use optistim::calibration::Instruments;
use optistim::facility::lut::DisplayLut;
use optistim::radiometry::spectrum::Table;
use optistim::scene::Scene;
use optistim::simfacility::{SimFacility, SimFacilityConfig};

/// The bundled simulated facility with a 128 × 128 camera (the same
/// focal length, so a 0.7° field around the axis) to keep the test fast.
fn small_facility() -> SimFacility {
    let path = Path::new("configs/simfacility.toml");
    let text = std::fs::read_to_string(path)
        .unwrap()
        .replace("resolution = [1024, 1024]", "resolution = [128, 128]")
        .replace("cx = 512.0", "cx = 64.0")
        .replace("cy = 512.0", "cy = 64.0");
    let mut cfg = SimFacilityConfig::parse(&text, path).unwrap();
    cfg.resolve_paths(Path::new("configs"));
    SimFacility::new(cfg).unwrap()
}

const CALIBRATE: &str = r#"
[calibrate]
levels = 33
repeats = 2
settle = 0.5
screen_spectrum = "data/display/lcd_white_apple_studio_display.csv"

[calibrate.meter]
kind = "sim"
spectral_response = "configs/meter_flat_380_780.csv"

[calibrate.camera]
kind = "sim"
exposure = 2.0e-3
saturation_dn = 4095
resolution = [128, 128]
"#;

#[test]
fn radiometric_calibration_recovers_the_simulated_screen_within_half_a_percent() {
    let sim = small_facility();
    // An operator warms the screen up first (the simulated warm-up has a
    // 600 s time constant).
    sim.advance(3600.0);
    let cfg = CalibrateConfig::parse(CALIBRATE, "calibrate.toml", 8).unwrap();
    let scene = Scene::from_file(Path::new("configs/moon.toml")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let mut ckpt =
        Checkpoint::open(&dir.path().join("c.jsonl"), "fp", "radiometric", false).unwrap();
    let (mut display, mut camera, mut meter) = (sim.display(), sim.camera(), sim.meter());
    let clock = sim.clone();
    let mut wait = move |s: f64| clock.advance(s);
    let mut inst = Instruments {
        display: &mut display,
        camera: &mut camera,
        meter: Some(&mut meter),
        wait: &mut wait,
    };
    let mut setup = Setup {
        cfg: &cfg,
        bits: 8,
        spectral: Some(CameraSpectral::from_scene(&scene)),
        meter_response: Some(Table::from_csv(Path::new("configs/meter_flat_380_780.csv")).unwrap()),
        screen_spectrum: Some(table_spectrum(
            &Table::from_csv(Path::new("data/display/lcd_white_apple_studio_display.csv")).unwrap(),
        )),
        dark: None,
        screen_power: None,
        source: "test".into(),
    };
    let report = radiometric::run(&mut inst, &mut setup, &mut ckpt).unwrap();
    radiometric::write(&report, &setup, &Outputs::in_dir(dir.path())).unwrap();
    let lut = DisplayLut::load(dir.path().join("lut.csv"), 8).unwrap();
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
}
