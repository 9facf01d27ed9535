//! `[camera] distortion` and `distortion_supersample` against arbitrary
//! values: the scene parser never panics; it accepts a lens only with
//! finite coefficients in range and a supersampling in 1 … 16, and the lens
//! it accepts has finite, positive pixel solid angles and unit directions;
//! everything else is a one-line error naming the key (a value of the
//! wrong TOML type by its line, which holds the key).

use optistim::instruments::intrinsics::MAX_DISTORTION;
use optistim::optics::distortion::{MAX_GROWTH, MAX_SUPERSAMPLE};
use optistim::scene::Scene;
use proptest::prelude::*;

const W: usize = 40;
const H: usize = 30;
const FX: f64 = 60.0;

/// What `camera.distortion` is set to.
#[derive(Clone, Copy, Debug)]
enum Key {
    Absent,
    LensFile,
    MissingFile,
    Number,
}

/// A Brown–Conrady coefficient.
fn coefficient() -> impl Strategy<Value = f64> {
    // Mostly in range, so that whole lenses in range come up often.
    prop_oneof![
        1 => Just(f64::NAN),
        1 => Just(f64::INFINITY),
        1 => Just(-2e3),
        8 => -0.3..0.3f64,
        2 => -3.0..3.0f64,
        3 => Just(0.0),
    ]
}

fn toml_float(v: f64) -> String {
    if v.is_nan() {
        "nan".into()
    } else if v.is_infinite() {
        if v > 0.0 { "inf" } else { "-inf" }.into()
    } else {
        format!("{v:e}")
    }
}

fn scene_text(key: Key, supersample: &Option<String>) -> String {
    let distortion = match key {
        Key::Absent => String::new(),
        Key::LensFile => "distortion = \"intrinsics.toml\"\n".into(),
        Key::MissingFile => "distortion = \"no-such-intrinsics.toml\"\n".into(),
        Key::Number => "distortion = 3\n".into(),
    };
    let supersample = supersample
        .as_ref()
        .map_or(String::new(), |s| format!("distortion_supersample = {s}\n"));
    format!(
        "[camera]\nresolution = [{W}, {H}]\npixel_pitch = 10e-6\nfocal_length = {f}\nf_number = 4.0\nexposure = 1e-3\nfull_well = 1e12\nbits = 16\nband = [500e-9, 700e-9]\n{distortion}{supersample}\n[sun]\nspectrum = \"blackbody\"\ntemperature = 5772.0\nirradiance_1au = 1361.0\n\n[body]\nradius = 10.0\nreflectance = {{ model = \"lambert\", albedo = 0.3 }}\n\n[state]\ncamera_position = [0.0, 0.0, 0.0]\ncamera_attitude = [1.0, 0.0, 0.0, 0.0]\nbody_position = [0.0, 0.0, 1000.0]\nsun_position = [0.0, 0.0, -1.5e11]\n",
        f = FX * 10e-6
    )
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 128, ..ProptestConfig::default() })]

    #[test]
    fn random_distortion_keys_are_accepted_in_range_or_refused_naming_the_key(
        key in prop_oneof![Just(Key::Absent), Just(Key::LensFile), Just(Key::LensFile), Just(Key::MissingFile), Just(Key::Number)],
        d in proptest::array::uniform5(coefficient()),
        supersample in prop_oneof![
            2 => Just(None),
            4 => (-3i64..20).prop_map(|n| Some(n.to_string())),
            1 => Just(Some("1.5".to_string())),
            1 => Just(Some("\"4\"".to_string())),
            1 => Just(Some("1e9".to_string())),
        ],
    ) {
        let dir = tempfile::tempdir().unwrap();
        let coefficients: Vec<String> = d.iter().map(|&v| toml_float(v)).collect();
        std::fs::write(
            dir.path().join("intrinsics.toml"),
            format!(
                "width = {W}\nheight = {H}\ncamera_matrix = [[{FX}, 0.0, 19.5], [0.0, {FX}, 14.5], [0.0, 0.0, 1.0]]\ndistortion = [{}]\n",
                coefficients.join(", ")
            ),
        )
        .unwrap();
        let text = scene_text(key, &supersample);
        let supersample_ok = supersample.as_ref().is_none_or(|s| {
            s.parse::<usize>().is_ok_and(|n| (1..=MAX_SUPERSAMPLE).contains(&n))
        });
        let coefficients_ok = d.iter().all(|v| v.is_finite() && v.abs() <= MAX_DISTORTION);
        match Scene::from_toml(&text, &dir.path().join("scene.toml")).map_err(|e| format!("{e:#}")) {
            Ok(scene) => {
                prop_assert!(supersample_ok, "accepted supersample {supersample:?}");
                match key {
                    Key::Absent => {
                        prop_assert!(supersample.is_none(), "supersample without a lens");
                        prop_assert!(scene.camera.distortion.is_none());
                    }
                    Key::LensFile => {
                        prop_assert!(coefficients_ok, "accepted {d:?}");
                        let lens = scene.camera.distortion.as_ref().expect("a lens");
                        prop_assert!(lens.ideal.width as f64 <= MAX_GROWTH * W as f64);
                        prop_assert!(lens.ideal.height as f64 <= MAX_GROWTH * H as f64);
                        let tables = lens.resampler().expect("tables");
                        prop_assert!(tables.solid_angle.iter().all(|o| o.is_finite() && *o > 0.0));
                        prop_assert!(tables.direction.iter().all(|v| (v.length() - 1.0).abs() < 1e-9));
                    }
                    Key::MissingFile | Key::Number => prop_assert!(false, "accepted {key:?}"),
                }
            }
            Err(e) => {
                prop_assert!(!e.contains('\n'), "not one line: {e}");
                // A value of the wrong type is named by its line
                // (`distortion_supersample = 1.5`), the others by the key.
                let names = e.contains("camera.distortion") || e.contains("(`distortion");
                prop_assert!(names, "does not name the key: {e}");
                let absent_and_fine = matches!(key, Key::Absent) && supersample.is_none();
                prop_assert!(!absent_and_fine, "refused a camera without a lens: {e}");
                // A supersampling without a lens, or a bad one beside a
                // lens file whose values are in range, is what it names.
                let supersample_at_fault = match key {
                    Key::Absent => supersample.is_some(),
                    Key::LensFile => !supersample_ok && coefficients_ok,
                    Key::MissingFile | Key::Number => false,
                };
                if supersample_at_fault {
                    prop_assert!(e.contains("distortion_supersample"), "{e}");
                }
            }
        }
    }
}

/// The base case the random one varies: a mild barrel lens resampled at
/// 4 × 4 is accepted and its tables hold the image's field.
#[test]
fn a_lens_in_range_is_accepted() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("intrinsics.toml"),
        format!("width = {W}\nheight = {H}\ncamera_matrix = [[{FX}, 0.0, 19.5], [0.0, {FX}, 14.5], [0.0, 0.0, 1.0]]\ndistortion = [-0.1, 0.01, 0.0, 0.0, 0.0]\n"),
    )
    .unwrap();
    let text = scene_text(Key::LensFile, &Some("4".into()));
    let scene = Scene::from_toml(&text, &dir.path().join("scene.toml")).expect("accepted");
    let lens = scene.camera.distortion.expect("a lens");
    assert_eq!(lens.supersample, 4);
    assert!(lens.ideal.width > W, "barrel: a wider ideal grid");
}
