//! `[[body.dem_tiles]]`, `[[body.albedo_tiles]]` and `body.max_abs_height`
//! against bad input: every bad tile or key is a one-line error naming the
//! key (and the tile's file where the file is at fault); random limits,
//! blends, scales and heights are accepted exactly when they are valid.

mod common;
use common::*;

use std::path::Path;

use optistim::render::output::write_f32_tiff;
use optistim::scene::Scene;
use proptest::prelude::*;

fn scene_with(extra_body: &str) -> Result<Scene, String> {
    let mut s = Setup::new("{ model = \"lambert\", albedo = 0.3 }", 30.0, 100.0, 60.0);
    s.extra_body = extra_body.to_string();
    Scene::from_toml(&s.toml(), Path::new("configs/tiles.toml")).map_err(|e| format!("{e:#}"))
}

/// A flat global DEM for the shadows key, in `dir`.
fn shadows(dir: &Path) -> String {
    shadows_with(dir, 4)
}

fn shadows_with(dir: &Path, azimuths: usize) -> String {
    let global = dir.join("global.tiff");
    write_f32_tiff(&global, 16, 8, &[0.0f32; 128]).unwrap();
    format!(
        "shadows = {{ dem = \"{}\", scale = 1.0, azimuths = {azimuths}, cache_dir = \"{}\" }}\n",
        global.display(),
        dir.join("cache").display()
    )
}

/// A number as TOML writes it (`nan`, `inf`, `-inf` included).
fn num(v: f64) -> String {
    if v.is_nan() {
        "nan".into()
    } else if v.is_infinite() {
        if v > 0.0 { "inf" } else { "-inf" }.into()
    } else {
        format!("{v:e}")
    }
}

fn tile(path: &Path, lat: [f64; 2], lon: [f64; 2], scale: f64, blend: f64) -> String {
    format!(
        "{{ path = \"{}\", lat_min = {}, lat_max = {}, lon_min = {}, lon_max = {}, scale = {}, blend = {} }}",
        path.display(),
        num(lat[0]),
        num(lat[1]),
        num(lon[0]),
        num(lon[1]),
        num(scale),
        num(blend)
    )
}

fn dem_tiles(dir: &Path, tiles: &[String]) -> String {
    format!("{}dem_tiles = [{}]", shadows(dir), tiles.join(", "))
}

#[test]
fn each_bad_tile_or_key_is_one_line_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let good = d.join("good.tiff");
    write_f32_tiff(&good, 12, 12, &[100.0f32; 144]).unwrap();
    let other = d.join("other.tiff");
    write_f32_tiff(&other, 12, 12, &[50.0f32; 144]).unwrap();
    let fine = d.join("fine.tiff");
    write_f32_tiff(&fine, 48, 48, &[20.0f32; 48 * 48]).unwrap();
    let nan = d.join("nan.tiff");
    let mut v = vec![1.0f32; 144];
    v[40] = f32::NAN;
    write_f32_tiff(&nan, 12, 12, &v).unwrap();
    let tall = d.join("tall.tiff");
    let mut v = vec![1.0f32; 144];
    v[17] = 26.0; // km with scale 1000
    write_f32_tiff(&tall, 12, 12, &v).unwrap();
    // 2048 × 2049 cells × 64 azimuths > 2^28 horizon values.
    let huge = d.join("huge.tiff");
    write_f32_tiff(&huge, 2048, 2049, &vec![0.0f32; 2048 * 2049]).unwrap();
    let t = |p: &Path, lat: [f64; 2], lon: [f64; 2]| tile(p, lat, lon, 1.0, 2.0);
    let ok = dem_tiles(d, &[t(&good, [10.0, 11.0], [20.0, 21.0])]);
    assert!(scene_with(&ok).is_ok(), "{:?}", scene_with(&ok).err());
    // A finer tile over a coarser one: the finer wins, no error.
    let nested = dem_tiles(
        d,
        &[
            t(&good, [10.0, 11.0], [20.0, 21.0]),
            t(&fine, [10.2, 10.6], [20.2, 20.6]),
        ],
    );
    assert!(
        scene_with(&nested).is_ok(),
        "{:?}",
        scene_with(&nested).err()
    );
    let cases: Vec<(String, &str, Option<&str>)> = vec![
        (dem_tiles(d, &[t(&good, [-91.0, 11.0], [20.0, 21.0])]), "body.dem_tiles[0].lat_min", None),
        (dem_tiles(d, &[t(&good, [10.0, 11.0], [20.0, 181.0])]), "body.dem_tiles[0].lon_max", None),
        (dem_tiles(d, &[t(&good, [11.0, 10.0], [20.0, 21.0])]), "body.dem_tiles[0].lat_max", None),
        (dem_tiles(d, &[t(&good, [10.0, 10.0], [20.0, 21.0])]), "body.dem_tiles[0].lat_max", None),
        (dem_tiles(d, &[t(&good, [10.0, 11.0], [21.0, 20.0])]), "body.dem_tiles[0].lon_max", None),
        (dem_tiles(d, &[t(&good, [10.0, f64::NAN], [20.0, 21.0])]), "body.dem_tiles[0].lat_max", None),
        (
            dem_tiles(d, &[t(&good, [10.0, 11.0], [20.0, 21.0]), t(&other, [10.5, 11.5], [20.5, 21.5])]),
            "body.dem_tiles[1]",
            Some("other.tiff"),
        ),
        (dem_tiles(d, &[t(&nan, [10.0, 11.0], [20.0, 21.0])]), "body.dem_tiles[0].path", Some("nan.tiff")),
        (
            dem_tiles(d, &[tile(&tall, [10.0, 11.0], [20.0, 21.0], 1000.0, 2.0)]),
            "body.dem_tiles[0].path",
            Some("tall.tiff"),
        ),
        (
            format!("max_abs_height = 50.0\n{}", dem_tiles(d, &[t(&good, [10.0, 11.0], [20.0, 21.0])])),
            "body.dem_tiles[0].path",
            Some("good.tiff"),
        ),
        (
            format!("max_abs_height = -1.0\n{ok}"),
            "body.max_abs_height",
            None,
        ),
        (
            format!("{}dem_tiles = [{}]", shadows_with(d, 64), t(&huge, [10.0, 11.0], [20.0, 21.0])),
            "body.dem_tiles",
            Some("huge.tiff"),
        ),
        (dem_tiles(d, &[tile(&good, [10.0, 11.0], [20.0, 21.0], 0.0, 2.0)]), "body.dem_tiles[0].scale", None),
        (dem_tiles(d, &[tile(&good, [10.0, 11.0], [20.0, 21.0], 1.0, 6.0)]), "body.dem_tiles[0].blend", Some("good.tiff")),
        (dem_tiles(d, &[tile(&good, [10.0, 11.0], [20.0, 21.0], 1.0, -1.0)]), "body.dem_tiles[0].blend", None),
        (dem_tiles(d, &[t(&d.join("none.tiff"), [10.0, 11.0], [20.0, 21.0])]), "body.dem_tiles[0].path", Some("none.tiff")),
        (
            format!("dem_tiles = [{}]", t(&good, [10.0, 11.0], [20.0, 21.0])),
            "body.dem_tiles",
            None,
        ),
        (
            format!(
                "albedo_tiles = [{{ path = \"{}\", lat_min = 1.0, lat_max = 2.0, lon_min = 3.0, lon_max = 4.0, min = 0.3, max = 0.1 }}]",
                good.display()
            ),
            "body.albedo_tiles[0]",
            None,
        ),
        (
            format!(
                "albedo_tiles = [{{ path = \"{}\", lat_min = 1.0, lat_max = 2.0, lon_min = 3.0, lon_max = -200.0, min = 0.1, max = 0.3 }}]",
                good.display()
            ),
            "body.albedo_tiles[0].lon_max",
            None,
        ),
    ];
    common::assert_one_line_errors(cases, scene_with);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    /// Random limits, blend, scale and one height: accepted exactly when
    /// every value is in range, else a one-line error naming a key of
    /// `body.dem_tiles`.
    #[test]
    fn random_tile_keys_are_accepted_exactly_when_valid(
        lat in prop_oneof![Just(f64::NAN), -100.0..100.0f64, Just(90.0), Just(-90.0)],
        dlat in prop_oneof![Just(0.0), Just(-1.0), 0.01..20.0f64],
        lon in prop_oneof![Just(f64::INFINITY), -200.0..200.0f64, Just(-180.0)],
        dlon in prop_oneof![Just(0.0), -5.0..5.0f64],
        blend in prop_oneof![Just(f64::NAN), Just(-0.5), 0.0..8.0f64],
        scale in prop_oneof![Just(f64::NAN), Just(0.0), Just(-2.0), 1e-3..1e4f64],
        value in prop_oneof![Just(f32::NAN), -30.0f32..30.0, Just(1e30f32)],
    ) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("tile.tiff");
        let mut v = vec![0.25f32; 12 * 12];
        v[50] = value;
        write_f32_tiff(&path, 12, 12, &v).unwrap();
        let (s, n, w, e) = (lat, lat + dlat, lon, lon + dlon);
        let text = dem_tiles(dir.path(), &[tile(&path, [s, n], [w, e], scale, blend)]);
        let valid = s.abs() <= 90.0 && n.abs() <= 90.0 && s < n
            && w.abs() <= 180.0 && e.abs() <= 180.0 && w < e
            && (0.0..6.0).contains(&blend)
            && scale.is_finite() && scale > 0.0
            && v.iter().all(|h| ((*h as f64 * scale) as f32).abs() as f64 <= 25e3);
        match scene_with(&text) {
            Ok(_) => prop_assert!(valid, "accepted: {text}"),
            Err(err) => {
                prop_assert!(!valid, "refused a valid key: {err}");
                prop_assert!(!err.contains('\n'), "not one line: {err}");
                prop_assert!(err.contains("body.dem_tiles[0]"), "{err}");
            }
        }
    }
}
