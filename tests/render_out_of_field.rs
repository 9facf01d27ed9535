//! Nothing rendered is an error: `optistim render` of a state with the
//! body entirely out of the field stops with a one-line error naming the
//! geometry (angle off the boresight, angular radius, field half-angle),
//! unless the scene allows an empty image; a facility replay with such a
//! state stops before its first frame unless the facility file allows it,
//! and then logs the frame and fails or passes accordingly.

mod common;

use std::path::Path;
use std::process::Command;

use glam::DVec3;

use optistim::scene::Scene;

const RANGE: f64 = 4.7e8;
const RADIUS: f64 = 1737.4e3;
const SUN: [f64; 3] = [7.48e10, 0.0, -1.29557e11];

/// The test scene with the camera turned 90° about its y axis (scalar-first
/// quaternion cos 45°, 0, sin 45°, 0): the body, straight ahead of the
/// world's +z, is 90° off the boresight.
fn turned_scene(extra: &str) -> String {
    let h = std::f64::consts::FRAC_1_SQRT_2;
    common::facility_scene_toml(DVec3::new(0.0, 0.0, -RANGE), DVec3::from_array(SUN)).replace(
        "camera_attitude = [1.0, 0.0, 0.0, 0.0]",
        &format!("camera_attitude = [{h}, 0.0, {h}, 0.0]"),
    ) + extra
}

fn render(scene: &Path, out: &Path) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_optistim"))
        .arg("render")
        .arg(scene)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap()
}

#[test]
fn render_of_a_body_out_of_the_field_is_an_error_naming_the_geometry() {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("turned.toml");
    std::fs::write(&scene, turned_scene("")).unwrap();
    let out = render(&scene, &dir.path().join("out"));
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    let line = err.lines().last().unwrap();
    // The expected angles, from the scene's own pinhole.
    let pin = Scene::from_file(&scene).unwrap().camera.pinhole;
    let half = ((pin.width as f64 / 2.0 / pin.fx).hypot(pin.height as f64 / 2.0 / pin.fy))
        .atan()
        .to_degrees();
    let radius = (RADIUS / RANGE).asin().to_degrees();
    for part in [
        "turned.toml: nothing to render".to_string(),
        "90.00° off the boresight".into(),
        format!("angular radius {radius:.2}°"),
        format!("field half-angle {half:.2}°"),
        "allow_empty".into(),
    ] {
        assert!(line.contains(&part), "{part:?} not in {err}");
    }
    assert_eq!(err.trim_end().lines().count(), 1, "one line: {err}");
    assert!(!dir.path().join("out").exists(), "nothing written");

    // Allowed: the empty image is written.
    std::fs::write(&scene, turned_scene("\n[render]\nallow_empty = true\n")).unwrap();
    let out = render(&scene, &dir.path().join("out"));
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let img = image::open(dir.path().join("out/dn.png"))
        .unwrap()
        .to_luma16();
    assert!(
        img.pixels().all(|p| p.0[0] == img.get_pixel(0, 0).0[0]),
        "an empty, uniform image"
    );
}
