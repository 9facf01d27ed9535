//! The simulated facility behind the real code paths: its spot meter served
//! over a real pseudo-terminal and read by the real serial meter, and
//! `optistim run --display sim-facility` writing the camera's frames.
#![cfg(unix)]

use std::path::Path;

use optistim::facility::display::Display;
use optistim::facility::lut::encode_grey;
use optistim::instruments::config::{open_spot_meter, SpotMeterConfig};
use optistim::simfacility::pty::PtyMeter;
use optistim::simfacility::{SimFacility, SimFacilityConfig};

mod common;
use common::simfacility::{bundled_path, run_on_sim_facility};

fn bundled() -> SimFacilityConfig {
    SimFacilityConfig::load(bundled_path()).unwrap()
}

fn meter_config(port: &Path, format: &str, unit_scale: f64) -> SpotMeterConfig {
    let end = if format == "spectrum" {
        "end = \"END\"\n"
    } else {
        ""
    };
    toml::from_str(&format!(
        r#"
kind = "serial"
name = "simulated meter over a pty"
port = "{}"
command = "MEAS\r\n"
unit_scale = {unit_scale}
timeout = 2.0
retries = 0
[reply]
format = "{format}"
prefix = "OK"
{end}"#,
        port.display()
    ))
    .unwrap()
}

#[test]
fn serial_meter_reads_the_simulated_meter_over_a_pty() {
    let mut cfg = bundled();
    cfg.meter.noise = 0.0;
    cfg.screen.warmup_amplitude = 0.0;
    cfg.screen.drift_per_hour = 0.0;
    let facility = SimFacility::new(cfg).unwrap();
    let scale = 2.5;
    let spec = meter_config(Path::new("/dev/null"), "scalar", scale).reply;
    let pty = PtyMeter::start(&facility, "MEAS\r\n", &spec, scale).unwrap();
    let mut meter =
        open_spot_meter(&meter_config(pty.path(), "scalar", scale), Path::new(".")).unwrap();
    let mut screen = facility.display();
    let (w, h) = screen.size();
    for level in [0u32, 50, 255] {
        screen.present(&vec![encode_grey(level, 8); w * h]).unwrap();
        let reading = meter.measure().unwrap();
        let expected = facility.true_meter_reading(level as usize);
        assert!(
            (reading.value / expected - 1.0).abs() < 1e-12,
            "level {level}: {} over the pty, {expected} true",
            reading.value
        );
    }
    pty.stop().unwrap();
}

#[test]
fn a_sim_meter_table_becomes_a_serial_meter_on_a_pty() {
    let mut cfg = bundled();
    cfg.meter.noise = 0.0;
    cfg.screen.warmup_amplitude = 0.0;
    cfg.screen.drift_per_hour = 0.0;
    let facility = SimFacility::new(cfg).unwrap();
    let mut table = meter_config(Path::new("/unused"), "scalar", 0.5);
    table.kind = optistim::instruments::config::MeterKind::Sim;
    let (pty, serial) = PtyMeter::for_config(&facility, &table).unwrap();
    assert_eq!(serial.port.as_deref(), Some(pty.path()));
    let mut meter = open_spot_meter(&serial, Path::new(".")).unwrap();
    let mut screen = facility.display();
    let (w, h) = screen.size();
    screen.present(&vec![encode_grey(200, 8); w * h]).unwrap();
    let got = meter.measure().unwrap().value;
    let expected = facility.true_meter_reading(200);
    assert!((got / expected - 1.0).abs() < 1e-12, "{got} vs {expected}");
}

#[test]
fn spectroradiometer_over_a_pty_sends_the_screen_spectrum() {
    let mut cfg = bundled();
    cfg.meter.noise = 0.0;
    cfg.meter.spectrometer = true;
    // The true spectrum: no wavelength error, no bin noise, an unshifted
    // black leak.
    cfg.meter.wavelength_error_nm = 0.0;
    cfg.meter.spectrum_noise = 0.0;
    cfg.screen.spectral_shift_nm = 0.0;
    let facility = SimFacility::new(cfg).unwrap();
    let spec = meter_config(Path::new("/dev/null"), "spectrum", 1.0).reply;
    let pty = PtyMeter::start(&facility, "MEAS\r\n", &spec, 1.0).unwrap();
    let mut meter =
        open_spot_meter(&meter_config(pty.path(), "spectrum", 1.0), Path::new(".")).unwrap();
    let mut screen = facility.display();
    let (w, h) = screen.size();
    screen.present(&vec![encode_grey(255, 8); w * h]).unwrap();
    let reading = meter.measure().unwrap();
    let spectrum = reading.spectrum.expect("a spectrum");
    assert_eq!(spectrum.len(), 81);
    // At full white (every channel's emission 1, the leak unshifted) the
    // spectrum is the bundled white's shape, read here from the data file,
    // times one scale.
    let file = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("data/display/lcd_white_apple_studio_display.csv"),
    )
    .unwrap();
    let shape: Vec<(f64, f64)> = file
        .lines()
        .filter(|l| l.starts_with(|c: char| c.is_ascii_digit()))
        .map(|l| {
            let (a, b) = l.split_once(',').unwrap();
            (a.parse().unwrap(), b.parse().unwrap())
        })
        .collect();
    assert_eq!(shape.len(), spectrum.len());
    let scale = spectrum[60].1 / shape[60].1; // 680 nm
    for ((nm, v), (nm_file, s)) in spectrum.iter().zip(&shape) {
        assert_eq!(nm, nm_file);
        assert!(
            (v - scale * s).abs() < 1e-9 * scale,
            "{nm} nm: {v} vs {}",
            scale * s
        );
    }
    // Its integral (trapezoid, 5 nm) is the flat 380–780 nm radiometer's
    // reading of the same spot.
    let integral: f64 = spectrum.windows(2).map(|p| 2.5 * (p[0].1 + p[1].1)).sum();
    let flat = facility.true_meter_reading(255);
    assert!((integral / flat - 1.0).abs() < 0.01, "{integral} vs {flat}");
    pty.stop().unwrap();
}

#[test]
fn run_on_the_simulated_facility_writes_camera_frames() {
    let tmp = tempfile::tempdir().unwrap();
    let out = run_on_sim_facility(3, 2)
        .arg("--captures")
        .arg(tmp.path().join("cap"))
        .arg("--log")
        .arg(tmp.path().join("f.jsonl"))
        .arg("--summary")
        .arg(tmp.path().join("s.json"))
        .output()
        .unwrap();
    // 0, or 4 for a `fail` verdict: the simulated camera's work makes
    // frames miss their deadlines.
    assert!(
        matches!(out.status.code(), Some(0 | 4)),
        "stderr: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    // Frames 0 and 2 of 3.
    let mut names: Vec<String> = std::fs::read_dir(tmp.path().join("cap"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    assert_eq!(names, ["frame_000000.png", "frame_000002.png"]);
    let img = image::open(tmp.path().join("cap/frame_000002.png")).unwrap();
    let img = img.as_luma16().expect("16-bit grey").clone();
    assert_eq!(img.dimensions(), (1024, 1024));
    // The Moon 4e8 m away (configs/moon_approach.csv): a disk of about 44
    // camera pixels radius (6100 px, less its unlit part) on a dark sky
    // (the screen's black level, dark current, read noise). The threshold
    // is a tenth of the peak: the maria are well below half the highlands.
    let v: Vec<u16> = img.into_raw();
    let sky = v[0];
    let peak = *v.iter().max().unwrap();
    let disk = v.iter().filter(|&&x| x > sky + (peak - sky) / 10).count();
    assert!(sky < 50 && peak > 400, "sky {sky} DN, peak {peak} DN");
    assert!((2_000..12_000).contains(&disk), "{disk} pixels in the disk");
}
