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
    for key in [
        "pixel_pitch = 1e-5",
        "exposure = 1e-3",
        "f_number = 2.5",
        "temperature = 5772.0",
        "irradiance_1au = 1361.0",
    ] {
        assert!(good.contains(key), "the test scene changed: {key}");
    }
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
        ("pixel pitch 1e308", good.replace("pixel_pitch = 1e-5", "pixel_pitch = 1e308"), "camera.pixel_pitch"),
        ("exposure 1e300", good.replace("exposure = 1e-3", "exposure = 1e300"), "camera.exposure"),
        ("f-number 1e-300", good.replace("f_number = 2.5", "f_number = 1e-300"), "camera.f_number"),
        ("blackbody at 1e-300 K", good.replace("temperature = 5772.0", "temperature = 1e-300"), "sun.temperature"),
        ("irradiance 1e300", good.replace("irradiance_1au = 1361.0", "irradiance_1au = 1e300"), "sun.irradiance_1au"),
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

/// The keys of the spectral Moon: tables in λ, the map's encoding, the
/// albedo spectrum, response normalisation and body files.
#[test]
fn spectral_body_keys_name_their_errors() {
    let good = Setup::new("{ model = \"lambert\", albedo = 0.3 }", 30.0, 100.0, 100.0).toml();
    let hapke = |b: &str| {
        good.replace(
            "{ model = \"lambert\", albedo = 0.3 }",
            &format!("{{ model = \"hapke\", w = 0.3, b = {b}, c = 0.2, theta_bar = 0.3, h_s = 0.1, b_s0 = 1.0 }}"),
        )
    };
    assert!(Scene::from_toml(&hapke("[[400.0, 0.2], [900.0, 0.3]]"), Path::new("ok.toml")).is_ok());
    let map = "albedo_map = { path = \"../data/maps/lroc_color_poles_2k.tif\", min = 0.1, max = 0.2, encoding = \"gamma\" }\n";
    let map_power = |p: &str| {
        format!("albedo_map = {{ path = \"../data/maps/lroc_color_poles_2k.tif\", min = 0.1, max = 0.2, power = {p} }}\n")
    };
    let cases: Vec<(&str, String, &str)> = vec![
        ("b table out of range", hapke("[[400.0, 0.2], [900.0, 1.5]]"), "body.reflectance.b"),
        ("b table not increasing", hapke("[[900.0, 0.2], [400.0, 0.3]]"), "body.reflectance.b"),
        ("b table empty", hapke("[]"), "body.reflectance.b"),
        ("unknown encoding", good.replace("reflectance = { model", &format!("{map}reflectance = {{ model")), "gamma"),
        ("map power 0", good.replace("reflectance = { model", &format!("{}reflectance = {{ model", map_power("0.0"))), "body.albedo_map.power"),
        ("map power negative", good.replace("reflectance = { model", &format!("{}reflectance = {{ model", map_power("-1.5"))), "body.albedo_map.power"),
        ("map power NaN", good.replace("reflectance = { model", &format!("{}reflectance = {{ model", map_power("nan"))), "body.albedo_map.power"),
        ("map power 1e9", good.replace("reflectance = { model", &format!("{}reflectance = {{ model", map_power("1e9"))), "body.albedo_map.power"),
        ("large_scale too large", good.replace("reflectance = { model", &format!("{}reflectance = {{ model", map_power("1.0, large_scale = [0, 0, 0, 0, 0, 0, 0, 2.5]"))), "body.albedo_map.large_scale"),
        ("large_scale NaN", good.replace("reflectance = { model", &format!("{}reflectance = {{ model", map_power("1.0, large_scale = [0, 0, nan, 0, 0, 0, 0, 0]"))), "body.albedo_map.large_scale"),
        ("large_scale too short", good.replace("reflectance = { model", &format!("{}reflectance = {{ model", map_power("1.0, large_scale = [0, 0, 0]"))), "large_scale"),
        ("map power a string", good.replace("reflectance = { model", &format!("{}reflectance = {{ model", map_power("\"2\""))), "power"),
        ("lime_reference not a boolean", good.replace("reflectance = { model", "lime_reference = \"yes\"\nreflectance = { model"), "lime_reference"),
        ("albedo spectrum negative", good.replace("reflectance = { model", "albedo_spectrum = [[400.0, -1.0], [500.0, 1.0]]\nreflectance = { model"), "body.albedo_spectrum"),
        ("albedo spectrum one row", good.replace("reflectance = { model", "albedo_spectrum = [[400.0, 1.0]]\nreflectance = { model"), "body.albedo_spectrum"),
        ("energy transmission", good.replace("band = [450e-9, 820e-9]", "band = [450e-9, 820e-9]\ntransmission = { path = \"../data/amie/qe_assumed.csv\", normalisation = \"energy\" }"), "camera.transmission"),
        ("unknown normalisation", good.replace("band = [450e-9, 820e-9]", "band = [450e-9, 820e-9]\nquantum_efficiency = { path = \"../data/amie/qe_assumed.csv\", normalisation = \"lumens\" }"), "quantum_efficiency"),
        ("missing body file", {
            let start = good.find("[body]").unwrap();
            let end = good.find("[state]").unwrap();
            format!("{}[body]\nfile = \"bodies/none.toml\"\n\n{}", &good[..start], &good[end..])
        }, "none.toml"),
        ("body file with inline keys", {
            let start = good.find("[body]").unwrap();
            format!("{}[body]\nfile = \"bodies/moon.toml\"\nradius = 1.0\n{}", &good[..start], &good[good.find("[state]").unwrap()..])
        }, "radius"),
    ];
    for (what, text, needle) in cases {
        let e = error_of(&text);
        assert!(
            e.contains(needle),
            "{what}: error does not name `{needle}`: {e}"
        );
    }
}

/// `[body] parameter_maps`: the parameter must be one of the model's, once,
/// with a range it accepts; at most four maps.
#[test]
fn parameter_map_keys_name_their_errors() {
    let on = Setup::new(
        "{ model = \"oren_nayar\", albedo = 0.2, roughness = 0.3 }",
        30.0,
        100.0,
        100.0,
    )
    .toml();
    let lambert = Setup::new("{ model = \"lambert\", albedo = 0.2 }", 30.0, 100.0, 100.0).toml();
    let map = |parameter: &str, min: &str, max: &str| {
        format!("{{ parameter = \"{parameter}\", path = \"../data/maps/lroc_color_poles_2k.tif\", min = {min}, max = {max} }}")
    };
    let with = |text: &str, entries: &[String]| {
        text.replace(
            "reflectance = { model",
            &format!(
                "parameter_maps = [{}]\nreflectance = {{ model",
                entries.join(", ")
            ),
        )
    };
    let ok = with(&on, &[map("roughness", "0.1", "0.6")]);
    let scene = Scene::from_toml(&ok, Path::new("configs/ok.toml")).expect("a roughness map");
    assert_eq!(scene.body.parameter_maps.len(), 1);
    let cases: Vec<(&str, String, &str)> = vec![
        ("not a parameter of the model", with(&on, &[map("b", "0.1", "0.2")]), "body.parameter_maps[0].parameter"),
        ("the albedo", with(&on, &[map("albedo", "0.1", "0.2")]), "albedo_map"),
        ("a model without parameters", with(&lambert, &[map("roughness", "0.1", "0.2")]), "body.parameter_maps[0].parameter"),
        ("mapped twice", with(&on, &[map("roughness", "0.1", "0.2"), map("roughness", "0.2", "0.3")]), "body.parameter_maps[1].parameter"),
        ("out of range", with(&on, &[map("roughness", "0.1", "2.0")]), "body.parameter_maps[0]"),
        ("NaN", with(&on, &[map("roughness", "nan", "0.2")]), "body.parameter_maps[0]"),
        ("min above max", with(&on, &[map("roughness", "0.5", "0.2")]), "body.parameter_maps[0]"),
        ("five maps", with(&on, &vec![map("roughness", "0.1", "0.2"); 5]), "body.parameter_maps"),
        ("unknown key", with(&on, &["{ parameter = \"roughness\", path = \"x.png\", min = 0.1, max = 0.2, scale = 2 }".to_string()]), "scale"),
        ("missing file", with(&on, &["{ parameter = \"roughness\", path = \"none.png\", min = 0.1, max = 0.2 }".to_string()]), "body.parameter_maps[0].path"),
    ];
    for (what, text, needle) in cases {
        let e = error_of(&text);
        assert!(
            e.contains(needle),
            "{what}: error does not name `{needle}`: {e}"
        );
        assert!(!e.contains('\n'), "{what}: not one line: {e}");
    }
}

/// Errors inside a body file name the body file.
#[test]
fn body_file_errors_name_the_body_file() {
    let dir = tempfile::tempdir().unwrap();
    let body = dir.path().join("rock.toml");
    std::fs::write(
        &body,
        "[body]\nradius = -5.0\nreflectance = { model = \"lambert\", albedo = 0.3 }\n",
    )
    .unwrap();
    let good = Setup::new("{ model = \"lambert\", albedo = 0.3 }", 30.0, 100.0, 100.0).toml();
    let start = good.find("[body]").unwrap();
    let end = good.find("[state]").unwrap();
    let text = format!(
        "{}[body]\nfile = \"rock.toml\"\n\n{}",
        &good[..start],
        &good[end..]
    );
    let e = Scene::from_toml(&text, &dir.path().join("scene.toml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("rock.toml") && e.contains("body.radius"), "{e}");
    std::fs::write(
        &body,
        "[body]\nradius = 5.0\nreflectance = { model = \"lambert\", albedo = 0.3 }\n",
    )
    .unwrap();
    let scene = Scene::from_toml(&text, &dir.path().join("scene.toml")).unwrap();
    assert_eq!(scene.body.radius, 5.0);
}

mod spectral_tables {
    use super::*;
    use optistim::radiometry::geometry::ScatteringGeometry;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// Any numbers in the λ tables and the albedo spectrum: Ok or a
        /// named error, never a panic; when Ok, the model at any wavelength
        /// gives a finite, non-negative radiance factor.
        #[test]
        fn any_table_is_ok_or_a_named_error(
            b in -2.0f64..2.0, c in -2.0f64..2.0, h in -1.0f64..2.0, s0 in -1.0f64..5.0,
            l0 in -100.0f64..2000.0, l1 in -100.0f64..2000.0, s in -1.0f64..3.0,
            at in 1e-7f64..3e-6,
        ) {
            let good = Setup::new("{ model = \"lambert\", albedo = 0.3 }", 30.0, 100.0, 100.0).toml();
            let model = format!(
                "{{ model = \"hapke\", w = [[{l0}, 0.3], [{l1}, 0.4]], b = [[{l0}, {b}], [{l1}, 0.1]], c = [[500.0, {c}]], theta_bar = 0.3, h_s = [[500.0, {h}]], b_s0 = [[500.0, {s0}]] }}\nalbedo_spectrum = [[{l0}, {s}], [{l1}, 1.0]]"
            );
            let text = good.replace("{ model = \"lambert\", albedo = 0.3 }", &model);
            match Scene::from_toml(&text, Path::new("configs/prop.toml")) {
                Ok(scene) => {
                    let m = scene.body.reflectance.at_wavelength(at);
                    let g = ScatteringGeometry::from_angles(0.4, 0.3, 0.5);
                    let r = m.radiance_factor(&g, m.albedo() * scene.body.albedo_factor(at));
                    prop_assert!(r.is_finite() && r >= 0.0);
                }
                Err(e) => {
                    let e = e.to_string();
                    prop_assert!(e.contains("prop.toml"), "{}", e);
                    prop_assert!(e.contains("body."), "{}", e);
                }
            }
        }
    }
}

/// A scene with `model` and the body line `map_line`, which may name the
/// 4×2 test map `m.png` written beside it; parsed as `prop.toml` in that
/// folder (kept alive by the returned guard).
fn scene_with_tiny_map(
    model: &str,
    map_line: &str,
) -> (tempfile::TempDir, optistim::error::Result<Scene>) {
    let dir = tempfile::tempdir().unwrap();
    let pixels: Vec<u8> = vec![0, 1, 37, 128, 200, 255, 255, 3];
    image::GrayImage::from_raw(4, 2, pixels)
        .unwrap()
        .save(dir.path().join("m.png"))
        .unwrap();
    let good = Setup::new(model, 30.0, 100.0, 100.0).toml();
    let text = good.replace(
        "reflectance = { model",
        &format!("{map_line}\nreflectance = {{ model"),
    );
    let parsed = Scene::from_toml(&text, &dir.path().join("prop.toml"));
    (dir, parsed)
}

mod parameter_maps {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// Any parameter name and range: Ok with every value of the map
        /// finite and within [min, max], or an error naming the entry.
        #[test]
        fn any_entry_is_ok_or_a_named_error(
            parameter in prop_oneof![Just("roughness".to_string()), Just("b".to_string()), Just("albedo".to_string()), Just("k".to_string()), "[a-z_]{0,12}"],
            lo in prop_oneof![-3.0f64..3.0, Just(f64::NAN), Just(f64::INFINITY), Just(0.0)],
            span in -1.0f64..3.0,
        ) {
            let hi = lo + span;
            let num = |v: f64| if v.is_nan() { "nan".to_string() } else if v.is_infinite() { "inf".to_string() } else { format!("{v:e}") };
            let (_dir, parsed) = scene_with_tiny_map("{ model = \"oren_nayar\", albedo = 0.2, roughness = 0.3 }", &format!("parameter_maps = [{{ parameter = \"{parameter}\", path = \"m.png\", min = {}, max = {} }}]", num(lo), num(hi)));
            match parsed {
                Ok(scene) => {
                    prop_assert_eq!(parameter.as_str(), "roughness");
                    let (_, map) = &scene.body.parameter_maps[0];
                    for v in &map.data {
                        let v = *v as f64;
                        prop_assert!(v.is_finite() && v >= lo - 1e-6 && v <= hi + 1e-6, "{} not in [{}, {}]", v, lo, hi);
                    }
                }
                Err(e) => {
                    let e = e.to_string();
                    prop_assert!(e.contains("prop.toml"), "{}", e);
                    prop_assert!(e.contains("body.parameter_maps"), "{}", e);
                }
            }
        }
    }
}

mod map_power {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// Any `albedo_map.power` (and any min/max): Ok with every map value
        /// finite and within [min, max], or an error naming the key.
        #[test]
        fn any_power_is_ok_or_a_named_error(
            power in prop_oneof![-20.0f64..20.0, Just(f64::NAN), Just(f64::INFINITY), Just(1e-300), Just(0.1), Just(10.0)],
            lo in -0.5f64..1.0, span in -0.5f64..1.0,
        ) {
            let hi = lo + span;
            let power = if power.is_nan() { "nan".to_string() } else if power.is_infinite() { "inf".to_string() } else { format!("{power:e}") };
            let (_dir, parsed) = scene_with_tiny_map("{ model = \"lambert\", albedo = 0.3 }", &format!("albedo_map = {{ path = \"m.png\", min = {lo:e}, max = {hi:e}, power = {power} }}"));
            match parsed {
                Ok(scene) => {
                    let map = scene.body.albedo_map.unwrap();
                    for v in &map.data {
                        let v = *v as f64;
                        prop_assert!(v.is_finite() && v >= lo - 1e-6 && v <= hi + 1e-6, "{} not in [{}, {}]", v, lo, hi);
                    }
                }
                Err(e) => {
                    let e = e.to_string();
                    prop_assert!(e.contains("prop.toml"), "{}", e);
                    prop_assert!(e.contains("body.albedo_map"), "{}", e);
                }
            }
        }
    }
}

mod map_large_scale {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// Any `albedo_map.large_scale`: Ok with every map value finite
        /// and positive, or an error naming the key.
        #[test]
        fn any_coefficients_are_ok_or_a_named_error(
            c in proptest::collection::vec(prop_oneof![-5.0f64..5.0, Just(f64::NAN), Just(f64::INFINITY), Just(2.0), Just(-2.0)], 8),
        ) {
            let list: Vec<String> = c.iter().map(|v| if v.is_nan() { "nan".into() } else if v.is_infinite() { "inf".into() } else { format!("{v:e}") }).collect();
            let (_dir, parsed) = scene_with_tiny_map("{ model = \"lambert\", albedo = 0.3 }", &format!("albedo_map = {{ path = \"m.png\", min = 0.1, max = 0.4, large_scale = [{}] }}", list.join(", ")));
            match parsed {
                Ok(scene) => {
                    prop_assert!(c.iter().all(|v| v.abs() <= 2.0));
                    let map = scene.body.albedo_map.unwrap();
                    for v in &map.data {
                        prop_assert!(v.is_finite() && *v > 0.0, "{}", v);
                    }
                }
                Err(e) => {
                    let e = e.to_string();
                    prop_assert!(e.contains("prop.toml"), "{}", e);
                    prop_assert!(e.contains("body.albedo_map.large_scale"), "{}", e);
                }
            }
        }
    }
}

/// A little-endian baseline TIFF header whose one strip holds 16 bytes but
/// whose tags claim `width` × `height` single-channel pixels of `bits`
/// (float when `float`): what a corrupt or hostile map file looks like.
fn tiff_claiming(width: u32, height: u32, bits: u16, float: bool) -> Vec<u8> {
    let tags: [(u16, u16, u32); 9] = [
        (256, 4, width),  // ImageWidth
        (257, 4, height), // ImageLength
        (258, 3, bits as u32),
        (259, 3, 1),                  // no compression
        (262, 3, 1),                  // black is zero
        (273, 4, 8 + 2 + 9 * 12 + 4), // the strip follows the IFD
        (277, 3, 1),
        (278, 4, height),
        (279, 4, 16),
    ];
    let mut t = b"II*\0".to_vec();
    t.extend_from_slice(&8u32.to_le_bytes());
    let n = tags.len() as u16 + u16::from(float);
    t.extend_from_slice(&n.to_le_bytes());
    let entry = |tag: u16, kind: u16, value: u32, t: &mut Vec<u8>| {
        t.extend_from_slice(&tag.to_le_bytes());
        t.extend_from_slice(&kind.to_le_bytes());
        t.extend_from_slice(&1u32.to_le_bytes());
        match kind {
            3 => t.extend_from_slice(&[value as u8, (value >> 8) as u8, 0, 0]),
            _ => t.extend_from_slice(&value.to_le_bytes()),
        }
    };
    for &(tag, kind, value) in &tags {
        entry(tag, kind, value, &mut t);
    }
    if float {
        entry(339, 3, 3, &mut t); // SampleFormat: IEEE float
    }
    t.extend_from_slice(&0u32.to_le_bytes());
    // With SampleFormat the strip starts 12 bytes later; pad so either works.
    t.extend_from_slice(&[0u8; 32]);
    t
}

/// A map file whose header claims 100 000 × 100 000 pixels is refused from
/// its header, as a float TIFF and as an 8-bit one, without allocating.
#[test]
fn a_map_claiming_a_huge_size_is_refused_before_decoding() {
    let dir = tempfile::tempdir().unwrap();
    for (bits, float) in [(32u16, true), (8, false), (16, false)] {
        let path = dir.path().join(format!("huge_{bits}.tif"));
        std::fs::write(&path, tiff_claiming(100_000, 100_000, bits, float)).unwrap();
        let start = std::time::Instant::now();
        let err = optistim::scene::EquirectMap::load(&path)
            .err()
            .unwrap_or_else(|| panic!("{bits}-bit map accepted"))
            .to_string();
        assert!(err.contains("huge_"), "{err}");
        assert!(start.elapsed().as_secs_f64() < 5.0, "{bits}-bit: slow");
        assert!(!err.contains('\n'), "{err}");
        println!("{err}");
    }
}

/// Scenes at the corners of every accepted range (pixel pitch, focal
/// length, exposure, Sun temperature and irradiance) render to finite
/// results or fail with an error: never a success with NaN.
#[test]
fn extreme_accepted_values_never_succeed_with_nan() {
    let good = Setup::new("{ model = \"lambert\", albedo = 0.3 }", 30.0, 100.0, 20.0).toml();
    let mut cases = 0;
    for pitch in ["1e-8", "0.1"] {
        for exposure in ["1e-12", "1e6"] {
            for temperature in ["1.0", "1e6"] {
                for irradiance in ["1e-12", "1e12"] {
                    let text = good
                        .replace("pixel_pitch = 1e-5", &format!("pixel_pitch = {pitch}"))
                        .replace("exposure = 1e-3", &format!("exposure = {exposure}"))
                        .replace(
                            "temperature = 5772.0",
                            &format!("temperature = {temperature}"),
                        )
                        .replace(
                            "irradiance_1au = 1361.0",
                            &format!("irradiance_1au = {irradiance}"),
                        );
                    let Ok(scene) = Scene::from_toml(&text, Path::new("corner.toml")) else {
                        continue;
                    };
                    let mut renderer =
                        optistim::render::Renderer::new(scene.camera.pinhole.clone());
                    let pixels = optistim::render::detector::PixelGeometry::new(&renderer);
                    cases += 1;
                    if let Ok(images) =
                        optistim::render::detector::render_scene(&scene, &mut renderer, &pixels)
                    {
                        let s = &images.summary;
                        for v in [
                            s.irradiance_at_pupil_w_m2,
                            s.total_electrons,
                            s.effective_irradiance_at_pupil_w_m2,
                        ] {
                            assert!(
                                v.is_finite(),
                                "{pitch} {exposure} {temperature} {irradiance}: {v}"
                            );
                        }
                        assert!(images
                            .radiance
                            .iter()
                            .chain(&images.electrons)
                            .all(|v| v.is_finite()));
                    }
                }
            }
        }
    }
    assert_eq!(cases, 16, "every corner is an accepted scene");
}
