//! The simulated facility's clock file: virtual time, and so the screen's
//! warm-up, continues from one command to the next; a missing file is a
//! fresh power-on; a bad file is a one-line error naming it.

use std::path::Path;

use optistim::instruments::SpotMeter;
use optistim::simfacility::clock::{self, ClockStart, SimClock};
use optistim::simfacility::SimFacility;

mod common;
use common::simfacility::{run_on_sim_facility, show_uniform, SimToml};

/// A small facility whose white reads 2 W m⁻² sr⁻¹ × (1 − 0.05 e^(−t/100 s)).
fn facility() -> SimFacility {
    SimToml::small()
        .seed(3)
        .with(
            "screen",
            "resolution = [32, 24]\nwarmup_amplitude = 0.05\nwarmup_time_constant = 100.0",
        )
        .with("camera", "resolution = [8, 6]\ncx = 4.0\ncy = 3.0")
        .with(
            "meter",
            "spot_center_px = [16.0, 12.0]\nspot_radius_px = 3.0",
        )
        .facility()
}

/// One command: shows white, reads the meter once (0.1 s integration) and
/// lets `seconds` pass; returns the reading and how the clock started.
fn command(path: &Path, seconds: f64) -> (f64, ClockStart) {
    let f = facility();
    let clock = SimClock::attach(&f, path).unwrap();
    show_uniform(&f, 255);
    let reading = f.meter().measure().unwrap().value;
    f.advance(seconds);
    (reading, clock.start)
    // `clock` dropped here: saved.
}

#[test]
fn the_warm_up_continues_from_one_command_to_the_next() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("clock.json");
    let white = |t: f64| 2.0 * (1.0 - 0.05 * (-t / 100.0f64).exp());
    // First command: a fresh power-on; the present takes one refresh, the
    // reading 0.1 s (taken at its middle), then 250 s pass.
    let (first, start) = command(&path, 250.0);
    assert_eq!(start, ClockStart::PowerOn);
    let t_read = 1.0 / 60.0 + 0.05;
    assert!((first / white(t_read) - 1.0).abs() < 1e-9, "{first}");
    let t1 = 1.0 / 60.0 + 0.1 + 250.0;
    let saved = clock::load(&path).unwrap().unwrap();
    assert!((saved - t1).abs() < 1e-9, "{saved} vs {t1}");
    // Second command: continues at t1; its reading sees the warmer screen.
    let (second, start) = command(&path, 0.0);
    assert_eq!(start, ClockStart::Continued(saved));
    let expected = white(t1 + t_read);
    assert!(
        (second / expected - 1.0).abs() < 1e-9,
        "{second} vs {expected}"
    );
    // 2.5 time constants later the deficit is e^-2.5 of the first one.
    let (d1, d2) = (1.0 - first / 2.0, 1.0 - second / 2.0);
    assert!((d2 / d1 - (-t1 / 100.0f64).exp()).abs() < 1e-6, "{d1} {d2}");
}

#[test]
fn a_bad_clock_file_is_a_one_line_error_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    for (name, text) in [
        ("garbage.json", "not json at all"),
        (
            "negative.json",
            r#"{"format": "optistim-simclock-1", "seconds_since_power_on": -5.0}"#,
        ),
        (
            "huge.json",
            r#"{"format": "optistim-simclock-1", "seconds_since_power_on": 1e999}"#,
        ),
        (
            "nan.json",
            r#"{"format": "optistim-simclock-1", "seconds_since_power_on": "NaN"}"#,
        ),
        (
            "format.json",
            r#"{"format": "other", "seconds_since_power_on": 5.0}"#,
        ),
        ("missing.json", r#"{"format": "optistim-simclock-1"}"#),
    ] {
        let path = dir.path().join(name);
        std::fs::write(&path, text).unwrap();
        let err = SimClock::attach(&facility(), &path)
            .err()
            .expect(name)
            .to_string();
        assert!(err.contains(name) && !err.contains('\n'), "{name}: {err}");
    }
}

/// `optistim run --display sim-facility --sim-clock FILE`, three frames.
fn run(dir: &Path, clock: &Path) -> std::process::Output {
    run_on_sim_facility(3, 1000)
        .arg("--captures")
        .arg(dir.join("cap"))
        .arg("--log")
        .arg(dir.join("f.jsonl"))
        .arg("--summary")
        .arg(dir.join("s.json"))
        // The runs share one log and summary on purpose.
        .args(["--append", "--overwrite"])
        .arg("--sim-clock")
        .arg(clock)
        .output()
        .unwrap()
}

#[test]
fn run_continues_the_clock_and_refuses_a_corrupt_one() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("clock.json");
    // Three presents of one refresh (60 Hz) each per run.
    for (k, expected) in [(1, 3.0 / 60.0), (2, 6.0 / 60.0)] {
        let out = run(dir.path(), &path);
        let stderr = String::from_utf8_lossy(&out.stderr);
        // 0 or the verdict's 4 (the simulated camera's captures can make a
        // short run miss deadlines): the run ran, and kept the clock.
        assert!(matches!(out.status.code(), Some(0 | 4)), "{stderr}");
        let said = if k == 1 {
            "fresh power-on"
        } else {
            "continuing at t = 0.050 s"
        };
        assert!(stderr.contains(said), "{stderr}");
        let t = clock::load(&path).unwrap().unwrap();
        assert!((t - expected).abs() < 1e-9, "run {k}: {t} vs {expected}");
    }
    std::fs::write(
        &path,
        "{\"format\": \"optistim-simclock-1\", \"seconds_since_power_on\": -1}",
    )
    .unwrap();
    let out = run(dir.path(), &path);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    let lines: Vec<&str> = stderr
        .lines()
        .filter(|l| l.contains("clock.json"))
        .collect();
    assert_eq!(lines.len(), 1, "{stderr}");
    assert!(lines[0].contains("seconds_since_power_on"), "{stderr}");
}
