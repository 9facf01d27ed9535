//! The simulated facility's TOML file: the bundled example loads; every bad
//! value is a one-line error naming the file and the key; the parser never
//! panics on arbitrary input.

use std::path::Path;

use optistim::simfacility::{SimFacility, SimFacilityConfig};
use proptest::prelude::*;

mod common;
use common::simfacility::bundled_path;

fn bundled_text() -> String {
    std::fs::read_to_string(bundled_path()).unwrap()
}

/// The bundled file with the line starting with `key =` in `[section]`
/// replaced by `key = value` (or removed when `value` is None).
fn with(section: &str, key: &str, value: Option<&str>) -> String {
    let mut out = String::new();
    let mut current = String::new();
    let mut found = false;
    for line in bundled_text().lines() {
        let t = line.trim();
        if t.starts_with('[') {
            current = t.trim_matches(|c| c == '[' || c == ']').to_string();
        }
        let is_key = t
            .split('=')
            .next()
            .map(|k| k.trim() == key)
            .unwrap_or(false);
        if current == section && is_key && t.contains('=') {
            found = true;
            if let Some(v) = value {
                out.push_str(&format!("{key} = {v}\n"));
            }
            continue;
        }
        out.push_str(line);
        out.push('\n');
    }
    assert!(found, "{section}.{key} not in the bundled file");
    out
}

#[test]
fn bundled_example_loads_and_builds() {
    let path = bundled_path();
    let f = SimFacility::load(&path).unwrap();
    assert_eq!(f.config().screen.resolution, [1920, 1080]);
    assert_eq!(f.config().camera.resolution, [1024, 1024]);
}

#[test]
fn bad_values_name_their_key() {
    let cases: &[(&str, &str, Option<&str>, &str)] = &[
        (
            "screen",
            "resolution",
            Some("[0, 1080]"),
            "screen.resolution",
        ),
        (
            "screen",
            "resolution",
            Some("[100000, 1080]"),
            "screen.resolution",
        ),
        (
            "screen",
            "resolution",
            Some("[16384, 16384]"),
            "screen.resolution",
        ),
        ("screen", "bits", Some("12"), "screen.bits"),
        ("screen", "refresh_hz", Some("0.0"), "screen.refresh_hz"),
        ("screen", "refresh_hz", Some("nan"), "screen.refresh_hz"),
        ("screen", "pixel_pitch", Some("-1e-4"), "screen.pixel_pitch"),
        ("screen", "gamma", Some("inf"), "screen.gamma"),
        ("screen", "max_radiance", Some("0.0"), "screen.max_radiance"),
        ("screen", "black_level", Some("-0.1"), "screen.black_level"),
        ("screen", "spectrum", Some("\"\""), "screen.spectrum"),
        (
            "screen",
            "spectral_shift_nm",
            Some("500.0"),
            "screen.spectral_shift_nm",
        ),
        ("screen", "falloff", Some("0.9"), "screen.falloff"),
        ("screen", "gradient", Some("[0.5, 0.0]"), "screen.gradient"),
        (
            "screen",
            "warmup_amplitude",
            Some("1.0"),
            "screen.warmup_amplitude",
        ),
        (
            "screen",
            "warmup_time_constant",
            Some("0.0"),
            "screen.warmup_time_constant",
        ),
        (
            "screen",
            "drift_per_hour",
            Some("2.0"),
            "screen.drift_per_hour",
        ),
        (
            "screen",
            "history_frames",
            Some("0"),
            "screen.history_frames",
        ),
        (
            "screen",
            "history_frames",
            Some("1000"),
            "screen.history_frames",
        ),
        (
            "collimator",
            "focal_length",
            Some("0.0"),
            "collimator.focal_length",
        ),
        (
            "collimator",
            "transmission",
            Some("1.5"),
            "collimator.transmission",
        ),
        ("collimator", "k1", Some("-2.5"), "collimator.k1"),
        ("collimator", "k1", Some("-1e9"), "collimator.k1"),
        (
            "collimator",
            "offset_px",
            Some("[1e9, 0.0]"),
            "collimator.offset_px",
        ),
        ("collimator", "rotation", Some("3.0"), "collimator.rotation"),
        (
            "camera",
            "resolution",
            Some("[1024, 0]"),
            "camera.resolution",
        ),
        (
            "camera",
            "resolution",
            Some("[8192, 8192]"),
            "camera.resolution",
        ),
        ("camera", "fx", Some("-5.0"), "camera.fx"),
        ("camera", "cy", Some("1e9"), "camera.cy"),
        ("camera", "k2", Some("nan"), "camera.k2"),
        ("camera", "p1", Some("0.5"), "camera.p1"),
        ("camera", "f_number", Some("0.0"), "camera.f_number"),
        (
            "camera",
            "band_nm",
            Some("[820.0, 450.0]"),
            "camera.band_nm",
        ),
        ("camera", "band_nm", Some("[10.0, 450.0]"), "camera.band_nm"),
        (
            "camera",
            "quantum_efficiency",
            Some("1.5"),
            "camera.quantum_efficiency",
        ),
        (
            "camera",
            "transmission",
            Some("-0.5"),
            "camera.transmission",
        ),
        ("camera", "exposure", Some("0.0"), "camera.exposure"),
        ("camera", "gain", Some("inf"), "camera.gain"),
        ("camera", "full_well", Some("-1.0"), "camera.full_well"),
        ("camera", "bits", Some("0"), "camera.bits"),
        ("camera", "bits", Some("17"), "camera.bits"),
        ("camera", "read_noise", Some("-1.0"), "camera.read_noise"),
        ("camera", "dark_current", Some("nan"), "camera.dark_current"),
        ("camera", "vignetting", Some("1.0"), "camera.vignetting"),
        ("camera", "prnu", Some("0.5"), "camera.prnu"),
        ("camera", "supersample", Some("0"), "camera.supersample"),
        ("camera", "supersample", Some("100"), "camera.supersample"),
        ("meter", "noise", Some("-0.1"), "meter.noise"),
        (
            "meter",
            "spot_center_px",
            Some("[5000.0, 10.0]"),
            "meter.spot_center_px",
        ),
        (
            "meter",
            "spot_radius_px",
            Some("0.0"),
            "meter.spot_radius_px",
        ),
        (
            "meter",
            "integration_time",
            Some("-1.0"),
            "meter.integration_time",
        ),
        ("meter", "band_nm", Some("[780.0, 380.0]"), "meter.band_nm"),
        (
            "screen",
            "primary_edges_nm",
            Some("[600.0, 500.0]"),
            "screen.primary_edges_nm",
        ),
        (
            "screen",
            "primary_edge_width_nm",
            Some("0.0"),
            "screen.primary_edge_width_nm",
        ),
        (
            "screen",
            "channel_gamma_delta",
            Some("[0.0, 1.0, 0.0]"),
            "screen.channel_gamma_delta",
        ),
        ("screen", "toe", Some("[0.0, nan, 0.0]"), "screen.toe"),
        ("screen", "toe_width", Some("0.0"), "screen.toe_width"),
        (
            "screen",
            "shoulder",
            Some("[0.5, 0.0, 0.0]"),
            "screen.shoulder",
        ),
        ("screen", "crosstalk", Some("0.5"), "screen.crosstalk"),
        ("screen", "mura_rms", Some("-0.001"), "screen.mura_rms"),
        (
            "screen",
            "mura_periods_px",
            Some("[200.0, 20.0]"),
            "screen.mura_periods_px",
        ),
        ("screen", "mura_waves", Some("0"), "screen.mura_waves"),
        (
            "screen",
            "black_nonuniformity",
            Some("inf"),
            "screen.black_nonuniformity",
        ),
        ("collimator", "p1", Some("5.0"), "collimator.p1"),
        (
            "collimator",
            "thin_prism",
            Some("[0.0, 1e9, 0.0, 0.0]"),
            "collimator.thin_prism",
        ),
        ("camera", "nonlinearity", Some("0.5"), "camera.nonlinearity"),
        ("camera", "row_noise", Some("-1.0"), "camera.row_noise"),
        (
            "camera",
            "veiling_glare",
            Some("nan"),
            "camera.veiling_glare",
        ),
        (
            "meter",
            "wavelength_error_nm",
            Some("50.0"),
            "meter.wavelength_error_nm",
        ),
        (
            "meter",
            "spectrum_noise",
            Some("-0.1"),
            "meter.spectrum_noise",
        ),
    ];
    for (section, key, value, expected) in cases {
        let text = with(section, key, *value);
        let err = SimFacilityConfig::parse(&text, "sim.toml")
            .expect_err(&format!("{section}.{key} = {value:?} must be refused"))
            .to_string();
        assert!(
            err.contains("sim.toml") && err.contains(expected) && !err.contains('\n'),
            "{section}.{key} = {value:?}: {err}"
        );
    }
}

#[test]
fn a_distortion_that_folds_over_is_refused() {
    // k1 = −2 over a ±60° field: r (1 − 2 r²) turns back at r = 0.41.
    let text = with("camera", "k1", Some("-2.0")).replace("fx = 10247.4", "fx = 300.0");
    let mut cfg = SimFacilityConfig::parse(&text, "sim.toml").unwrap();
    cfg.resolve_paths(&Path::new(env!("CARGO_MANIFEST_DIR")).join("configs"));
    let err = SimFacility::new(cfg).err().expect("refused").to_string();
    assert!(err.contains("camera.k1") && err.contains("folds"), "{err}");
}

#[test]
fn frame_history_memory_is_bounded() {
    // 64 frames of an 8K screen would be 4 GiB of kept frames.
    let text = with("screen", "history_frames", Some("64"))
        .replace("resolution = [1920, 1080]", "resolution = [7680, 4320]");
    let err = SimFacilityConfig::parse(&text, "sim.toml")
        .unwrap_err()
        .to_string();
    assert!(err.contains("screen.history_frames"), "{err}");
    let text = with("screen", "history_frames", Some("4"))
        .replace("resolution = [1920, 1080]", "resolution = [7680, 4320]")
        .replace(
            "spot_center_px = [960.0, 540.0]",
            "spot_center_px = [3840.0, 2160.0]",
        );
    SimFacilityConfig::parse(&text, "sim.toml").unwrap();
}

#[test]
fn missing_unknown_and_mistyped_keys_name_line_and_key() {
    let text = with("camera", "gain", None);
    let err = SimFacilityConfig::parse(&text, "sim.toml")
        .unwrap_err()
        .to_string();
    assert!(err.contains("sim.toml") && err.contains("gain"), "{err}");
    let text = with("camera", "gain", Some("0.04\ngian = 1.0"));
    let err = SimFacilityConfig::parse(&text, "sim.toml")
        .unwrap_err()
        .to_string();
    let line = text.lines().position(|l| l.starts_with("gian")).unwrap() + 1;
    assert!(
        err.contains("gian") && err.contains(&format!("line {line}")) && !err.contains('\n'),
        "{err}"
    );
    let text = with("camera", "bits", Some("\"twelve\""));
    let err = SimFacilityConfig::parse(&text, "sim.toml")
        .unwrap_err()
        .to_string();
    assert!(err.contains("line") && !err.contains('\n'), "{err}");
}

#[test]
fn missing_spectrum_file_names_it() {
    let mut cfg = SimFacilityConfig::parse(&bundled_text(), "sim.toml").unwrap();
    cfg.resolve_paths(&Path::new(env!("CARGO_MANIFEST_DIR")).join("configs"));
    cfg.screen.spectrum = "/nonexistent/white.csv".into();
    let err = SimFacility::new(cfg).err().expect("refused").to_string();
    assert!(err.contains("/nonexistent/white.csv"), "{err}");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Arbitrary text: Ok or a named error, never a panic.
    #[test]
    fn parser_never_panics_on_text(text in "\\PC{0,400}") {
        let _ = SimFacilityConfig::parse(&text, "sim.toml");
    }

    /// The bundled file with one value replaced by an arbitrary number:
    /// Ok with every value in range, or an error naming the file.
    #[test]
    fn parser_never_panics_on_numbers(
        idx in 0usize..12,
        value in prop_oneof![
            any::<f64>(),
            Just(f64::NAN),
            Just(f64::INFINITY),
            -1e12f64..1e12,
        ],
    ) {
        let keys = [
            ("screen", "gamma"), ("screen", "max_radiance"), ("screen", "black_level"),
            ("screen", "refresh_hz"), ("collimator", "k1"), ("collimator", "focal_length"),
            ("camera", "fx"), ("camera", "k1"), ("camera", "exposure"), ("camera", "gain"),
            ("meter", "spot_radius_px"), ("meter", "noise"),
        ];
        let (section, key) = keys[idx];
        let v = if value.is_nan() { "nan".to_string() } else if value.is_infinite() {
            if value > 0.0 { "inf".into() } else { "-inf".into() }
        } else { format!("{value:?}") };
        let text = with(section, key, Some(&v));
        match SimFacilityConfig::parse(&text, "sim.toml") {
            Ok(cfg) => prop_assert!(cfg.validate().is_ok()),
            Err(e) => prop_assert!(e.to_string().contains("sim.toml")),
        }
    }
}
