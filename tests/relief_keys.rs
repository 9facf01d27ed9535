//! `[body] shadows` against bad input: every bad DEM or key is a one-line
//! error naming the key (and the DEM file where the file is at fault);
//! random values are accepted exactly when they are valid.

mod common;
use common::*;

use std::path::Path;

use optistim::render::output::write_f32_tiff;
use optistim::scene::Scene;
use proptest::prelude::*;

fn scene_with(extra_body: &str) -> Result<Scene, String> {
    let mut s = Setup::new("{ model = \"lambert\", albedo = 0.3 }", 30.0, 100.0, 60.0);
    s.extra_body = extra_body.to_string();
    Scene::from_toml(&s.toml(), Path::new("configs/relief.toml")).map_err(|e| format!("{e:#}"))
}

fn key(dem: &Path, cache: &Path, scale: &str, azimuths: &str, mode: &str) -> String {
    format!(
        "shadows = {{ dem = \"{}\", scale = {scale}, azimuths = {azimuths}, cache_dir = \"{}\", mode = {mode} }}",
        dem.display(),
        cache.display()
    )
}

#[test]
fn each_bad_dem_or_key_is_one_line_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let good = dir.path().join("good.tiff");
    write_f32_tiff(&good, 16, 8, &[1.0f32; 128]).unwrap();
    let nan = dir.path().join("nan.tiff");
    let mut v = vec![1.0f32; 128];
    v[37] = f32::NAN;
    write_f32_tiff(&nan, 16, 8, &v).unwrap();
    let tall = dir.path().join("tall.tiff");
    let mut v = vec![1.0f32; 128];
    v[90] = 26.0; // km with scale 1000
    write_f32_tiff(&tall, 16, 8, &v).unwrap();
    // 2048 × 2049 cells × 64 azimuths > 2^28 stored values.
    let huge = dir.path().join("huge.tiff");
    write_f32_tiff(&huge, 2048, 2049, &vec![0.0f32; 2048 * 2049]).unwrap();
    let missing = dir.path().join("no-such.tiff");
    assert!(scene_with(&key(&good, &cache, "1000.0", "16", "\"auto\"")).is_ok());
    let cases = [
        (
            key(&nan, &cache, "1.0", "16", "\"auto\""),
            "body.shadows.dem",
            Some("nan.tiff"),
        ),
        (
            key(&tall, &cache, "1000.0", "16", "\"auto\""),
            "body.shadows.dem",
            Some("tall.tiff"),
        ),
        (
            key(&huge, &cache, "1.0", "64", "\"auto\""),
            "body.shadows.dem",
            Some("huge.tiff"),
        ),
        (
            key(&missing, &cache, "1.0", "16", "\"auto\""),
            "body.shadows.dem",
            Some("no-such.tiff"),
        ),
        (
            key(&good, &cache, "nan", "16", "\"auto\""),
            "body.shadows.scale",
            None,
        ),
        (
            key(&good, &cache, "0.0", "16", "\"auto\""),
            "body.shadows.scale",
            None,
        ),
        (
            key(&good, &cache, "-1.0", "16", "\"auto\""),
            "body.shadows.scale",
            None,
        ),
        (
            key(&good, &cache, "1.0", "3", "\"auto\""),
            "body.shadows.azimuths",
            None,
        ),
        (
            key(&good, &cache, "1.0", "65", "\"auto\""),
            "body.shadows.azimuths",
            None,
        ),
        (
            key(&good, &cache, "1.0", "-16", "\"auto\""),
            "body.shadows.azimuths",
            None,
        ),
        (
            key(&good, &cache, "1.0", "16", "\"sometimes\""),
            "sometimes",
            None,
        ),
        (
            key(&good, &cache, "1.0", "16.5", "\"auto\""),
            "azimuths",
            None,
        ),
        // One DEM for limb, shading and shadows: no second height map.
        (
            format!(
                "{}\ndisplacement_map = {{ path = \"{}\", scale = 1.0 }}",
                key(&good, &cache, "1.0", "16", "\"auto\""),
                good.display()
            ),
            "body.displacement_map",
            None,
        ),
        (
            key(&good, &cache, "1.0", "16", "\"auto\"").replace(" }", ", displace = 1 }"),
            "displace",
            None,
        ),
    ];
    common::assert_one_line_errors(cases, scene_with);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    /// Random scale, azimuth count, mode and DEM values: accepted exactly
    /// when every value is in range, else a one-line error naming a key of
    /// `body.shadows` (or the bad mode's text).
    #[test]
    fn random_shadow_keys_are_accepted_exactly_when_valid(
        scale in prop_oneof![Just(f64::NAN), Just(-1.0), Just(0.0), 1e-3..1e4f64, Just(1e300)],
        azimuths in -5i64..80,
        mode in prop_oneof![Just("auto"), Just("always"), Just("never"), Just("on"), Just("")],
        value in prop_oneof![Just(f32::NAN), Just(f32::INFINITY), -30.0f32..30.0, Just(1e30f32)],
    ) {
        let dir = tempfile::tempdir().unwrap();
        let dem = dir.path().join("dem.tiff");
        let mut v = vec![0.5f32; 16 * 8];
        v[77] = value;
        write_f32_tiff(&dem, 16, 8, &v).unwrap();
        let text = key(&dem, &dir.path().join("c"), &format!("{scale:e}"), &azimuths.to_string(), &format!("\"{mode}\""));
        let valid = scale.is_finite() && scale > 0.0
            && (4..=64).contains(&azimuths)
            && ["auto", "always", "never"].contains(&mode)
            && v.iter().all(|h| (*h as f64 * scale).abs() <= 25e3)
            && v.iter().all(|h| ((*h as f64 * scale) as f32).is_finite());
        match scene_with(&text) {
            Ok(_) => prop_assert!(valid, "accepted: {text}"),
            Err(e) => {
                prop_assert!(!valid, "refused a valid key: {e}");
                prop_assert!(!e.contains('\n'), "not one line: {e}");
                prop_assert!(e.contains("body.shadows") || e.contains(mode) || e.contains("mode"), "{e}");
            }
        }
    }
}

/// A scene naming a body file may add `shadows` (paths against the
/// scene's directory); a body file with its own is refused in one line
/// naming the key and the body file.
#[test]
fn a_scene_adds_shadows_to_a_body_file_once() {
    let dir = tempfile::tempdir().unwrap();
    let dem = dir.path().join("dem.tiff");
    write_f32_tiff(&dem, 16, 8, &[1.0f32; 128]).unwrap();
    let shadows = format!(
        "shadows = {{ dem = \"dem.tiff\", scale = 1.0, cache_dir = \"{}\" }}",
        dir.path().join("cache").display()
    );
    let body = |extra: &str| {
        format!("[body]\nradius = 1000.0\nreflectance = {{ model = \"lambert\", albedo = 0.3 }}\n{extra}\n")
    };
    let scene_text = Setup::new("{ model = \"lambert\", albedo = 0.3 }", 30.0, 100.0, 60.0)
        .toml()
        .replace(
            "[body]\nradius = 1e3\nreflectance = { model = \"lambert\", albedo = 0.3 }\n",
            &format!("[body]\nfile = \"body.toml\"\n{shadows}\n"),
        );
    assert!(scene_text.contains("file = \"body.toml\""), "{scene_text}");
    let scene_path = dir.path().join("scene.toml");
    std::fs::write(dir.path().join("body.toml"), body("")).unwrap();
    let scene = Scene::from_toml(&scene_text, &scene_path).unwrap();
    assert!(scene.body.relief.shadows.is_some());
    std::fs::write(
        dir.path().join("body.toml"),
        body(&shadows.replace("dem.tiff", &dem.display().to_string())),
    )
    .unwrap();
    let e = format!(
        "{:#}",
        Scene::from_toml(&scene_text, &scene_path).unwrap_err()
    );
    assert!(
        !e.contains('\n') && e.contains("body.shadows") && e.contains("body.toml"),
        "{e}"
    );
}
