//! Bad camera input from issue 28: a resolution whose images would not fit
//! the memory bound fails before anything is allocated, and a camera whose
//! band response integrates to zero is an error instead of NaN in the
//! summary. Both are one-line errors naming the file and the key.

mod common;

use std::path::Path;
use std::process::Command;

use optistim::scene::{Scene, IMAGE_BYTES_PER_PIXEL, MAX_IMAGE_BYTES};

/// The common test scene with its camera lines edited.
fn scene_text(edit: impl Fn(String) -> String) -> String {
    edit(common::Setup::new(r#"{ model = "lambert", albedo = 0.3 }"#, 30.0, 10.0, 40.0).toml())
}

fn with_resolution(w: usize, h: usize) -> String {
    scene_text(|t| {
        let line = t
            .lines()
            .find(|l| l.starts_with("resolution"))
            .unwrap()
            .to_string();
        t.replace(&line, &format!("resolution = [{w}, {h}]"))
    })
}

fn load(text: &str) -> Result<Scene, String> {
    Scene::from_toml(text, Path::new("cam.toml")).map_err(|e| e.to_string())
}

#[test]
fn resolutions_beyond_the_memory_bound_fail_fast() {
    for (w, h) in [(20_000, 20_000), (65_536, 1024)] {
        let err = load(&with_resolution(w, h)).expect_err("accepted");
        assert!(
            err.contains("cam.toml") && err.contains("camera.resolution") && !err.contains('\n'),
            "{err}"
        );
        // The bound is the implied memory, written out here: pixels ×
        // bytes per pixel against the limit.
        assert!((w * h) as f64 * IMAGE_BYTES_PER_PIXEL > MAX_IMAGE_BYTES);
    }
    // A 4k × 4k camera (16.8 Mpx) is within the bound.
    assert!(load(&with_resolution(4096, 4096)).is_ok());
}

#[test]
fn the_cli_refuses_a_huge_camera_with_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("huge.toml");
    std::fs::write(&path, with_resolution(20_000, 20_000)).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_optistim"))
        .args(["render", path.to_str().unwrap(), "--out"])
        .arg(dir.path().join("out"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    let lines: Vec<&str> = stderr.lines().collect();
    assert_eq!(lines.len(), 1, "{stderr}");
    assert!(lines[0].contains("huge.toml") && lines[0].contains("camera.resolution"));
    assert!(!dir.path().join("out").exists(), "nothing written");
}

#[test]
fn a_band_response_of_zero_is_an_error() {
    let qe_zero = scene_text(|t| t.replace("bits = 12", "bits = 12\nquantum_efficiency = 0.0"));
    let err = load(&qe_zero).expect_err("QE 0 accepted");
    assert!(
        err.contains("camera.quantum_efficiency") && err.contains("cam.toml"),
        "{err}"
    );
    let t_zero = scene_text(|t| t.replace("bits = 12", "bits = 12\ntransmission = 0.0"));
    let err = load(&t_zero).expect_err("T 0 accepted");
    assert!(err.contains("camera.transmission"), "{err}");

    // A QE table that is zero only outside the band: the response is zero
    // over the band (tables are zero beyond their rows).
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("qe.csv"),
        "wavelength_nm,qe\n900,0.5\n1000,0.5\n",
    )
    .unwrap();
    let text = scene_text(|t| t.replace("bits = 12", "bits = 12\nquantum_efficiency = \"qe.csv\""));
    let err = Scene::from_toml(&text, &dir.path().join("cam.toml"))
        .expect_err("QE outside the band accepted")
        .to_string();
    assert!(
        err.contains("camera.quantum_efficiency") && !err.contains('\n'),
        "{err}"
    );
    // The same table over the band renders.
    std::fs::write(
        dir.path().join("qe.csv"),
        "wavelength_nm,qe\n400,0.5\n900,0.5\n",
    )
    .unwrap();
    assert!(Scene::from_toml(&text, &dir.path().join("cam.toml")).is_ok());
}
