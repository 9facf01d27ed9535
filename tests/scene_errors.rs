//! Malformed scene files: every case yields an error naming the file and
//! the offending key, never a panic.

mod common;
use common::*;
use optistim::scene::Scene;
use std::path::Path;

fn error_of(text: &str) -> String {
    match Scene::from_toml(text, Path::new("configs/broken.toml")) {
        Ok(_) => panic!("accepted a broken scene:\n{text}"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn each_malformed_scene_names_its_error() {
    let good = Setup::new("{ model = \"lambert\", albedo = 0.3 }", 30.0, 100.0, 100.0).toml();
    assert!(Scene::from_toml(&good, Path::new("ok.toml")).is_ok());
    let cases: Vec<(&str, String, &str)> = vec![
        ("missing key", good.replace("f_number = 2.5\n", ""), "f_number"),
        ("wrong type", good.replace("radius = 1e3", "radius = \"big\""), "radius"),
        ("negative radius", good.replace("radius = 1e3", "radius = -1e3"), "body.radius"),
        ("NaN", good.replace("exposure = 1e-3", "exposure = nan"), "camera.exposure"),
        ("zero quaternion", {
            let start = good.find("camera_attitude").unwrap();
            let end = start + good[start..].find('\n').unwrap();
            format!("{}camera_attitude = [0.0, 0.0, 0.0, 0.0]{}", &good[..start], &good[end..])
        }, "state.camera_attitude"),
        ("missing map file", good.replace(
            "reflectance = { model",
            "albedo_map = { path = \"no/such/map.png\", min = 0.1, max = 0.2 }\nreflectance = { model",
        ), "body.albedo_map.path"),
        ("unknown key", good.replace("bits = 12", "bits = 12\ncolour = true"), "colour"),
        ("unknown model", good.replace("\"lambert\"", "\"phong\""), "phong"),
        ("node spacing 0", good.replace("[render]\n", "[render]\nnode_spacing = 0\n"), "render.node_spacing"),
        ("pixel tolerance 0.5", good.replace("[render]\n", "[render]\npixel_tolerance = 0.5\n"), "render.pixel_tolerance"),
        ("pixel tolerance NaN", good.replace("[render]\n", "[render]\npixel_tolerance = nan\n"), "render.pixel_tolerance"),
        ("texture samples 9", good.replace("[render]\n", "[render]\ntexture_samples = 9\n"), "render.texture_samples"),
        ("band in nm", good.replace("band = [450e-9, 820e-9]", "band = [450, 820]"), "camera.band"),
        ("camera inside body", good.replace("[state]\ncamera_position = [", "[state]\ncamera_position = [1.0, 0.0, 0.0]\nignored = ["), "ignored"),
    ];
    for (what, text, needle) in cases {
        let e = error_of(&text);
        assert!(
            e.contains("broken.toml"),
            "{what}: error does not name the file: {e}"
        );
        assert!(
            e.contains(needle),
            "{what}: error does not name `{needle}`: {e}"
        );
    }
}

#[test]
fn camera_inside_the_body_is_rejected() {
    let mut setup = Setup::new("{ model = \"lambert\", albedo = 0.3 }", 30.0, 2.0, 100.0);
    setup.range = 500.0;
    let e = error_of(&setup.toml());
    assert!(
        e.contains("state.camera_position") && e.contains("inside"),
        "{e}"
    );
}
