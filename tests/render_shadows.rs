//! Cast shadows in the render (`[body] shadows`): a flat DEM changes no
//! pixel; with craters the disk flux drops by exactly the shadowed power,
//! which a quadrature over the sphere written here computes from the
//! horizon map; `auto` mode skips a full disk and takes a grazing view
//! (the bundled Moon's switch against brute force: `relief_switch.rs`);
//! the cache is rebuilt when corrupt.

mod common;
use common::*;

use std::f64::consts::{FRAC_PI_2, PI, TAU};
use std::path::Path;

use glam::DVec3;
use optistim::render::output::write_f32_tiff;
use optistim::scene::horizon::HorizonMap;
use optistim::scene::EquirectMap;

const W: usize = 512;
const H: usize = 256;
/// The test body's radius [m] (common::Setup).
const R: f64 = 1000.0;

fn unit(lat: f64, lon: f64) -> DVec3 {
    DVec3::new(lat.cos() * lon.cos(), lat.cos() * lon.sin(), lat.sin())
}

/// Paraboloid bowls (radius 6 cells, depth 15 m) near the evening
/// terminator (longitudes 55–85°) and one on the morning side.
fn craters() -> Vec<f32> {
    let a = 6.0 * PI * R / H as f64;
    let depth = 15.0;
    let centres: Vec<DVec3> = [
        (0.0, 80.0),
        (20.0, 70.0),
        (-25.0, 84.0),
        (40.0, 60.0),
        (-50.0, 75.0),
        (5.0, 55.0),
        (10.0, -80.0),
    ]
    .iter()
    .map(|&(lat, lon): &(f64, f64)| unit(lat.to_radians(), lon.to_radians()))
    .collect();
    let mut data = vec![0.0f32; W * H];
    for row in 0..H {
        for col in 0..W {
            let lat = FRAC_PI_2 - (row as f64 + 0.5) / H as f64 * PI;
            let lon = (col as f64 + 0.5) / W as f64 * TAU - PI;
            let p = unit(lat, lon);
            for c in &centres {
                let s = R * p.dot(*c).clamp(-1.0, 1.0).acos();
                if s < a {
                    data[row * W + col] = (-depth * (1.0 - s * s / (a * a))) as f32;
                }
            }
        }
    }
    data
}

fn shadows_key(dem: &Path, cache: &Path, mode: &str) -> String {
    format!(
        "shadows = {{ dem = \"{}\", scale = 1.0, azimuths = 16, cache_dir = \"{}\", mode = \"{mode}\" }}",
        dem.display(),
        cache.display()
    )
}

/// With a flat DEM (all heights 0) the shadowed render is the sphere's,
/// pixel by pixel within 1e-9, with interior pixels and with caps only.
#[test]
fn a_flat_dem_changes_no_pixel() {
    let dir = tempfile::tempdir().unwrap();
    let dem = dir.path().join("flat.tiff");
    write_f32_tiff(&dem, W, H, &vec![0.0f32; W * H]).unwrap();
    for (model, alpha, interior) in [
        ("{ model = \"lambert\", albedo = 0.3 }", 30.0, "pixels"),
        (
            "{ model = \"oren_nayar\", albedo = 0.15, roughness = 0.3 }",
            110.0,
            "pixels",
        ),
        (
            "{ model = \"lommel_seeliger\", albedo = 0.1 }",
            70.0,
            "caps",
        ),
    ] {
        let mut plain = Setup::new(model, alpha, 1e3, 300.0);
        plain.extra_render = format!("interior = \"{interior}\"");
        let mut shadowed = Setup::new(model, alpha, 1e3, 300.0);
        shadowed.extra_render = plain.extra_render.clone();
        shadowed.extra_body = shadows_key(&dem, dir.path(), "always");
        let (a, b) = (render(&plain.scene()), render(&shadowed.scene()));
        let d = b.summary.relief_shadows.expect("decision reported");
        assert!(d.applied, "{d:?}");
        let mut worst = 0.0f64;
        for (x, y) in a.radiance.iter().zip(&b.radiance) {
            let (x, y) = (*x as f64, *y as f64);
            worst = worst.max((x - y).abs() / x.abs().max(1e-300));
        }
        assert!(
            worst <= 1e-9,
            "α {alpha}: a pixel changed by {worst:e} relative"
        );
        assert!(a.radiance.iter().any(|&v| v > 0.0));
    }
}

/// Lambert, distant geometry: the flux a camera at phase α receives from
/// a point is ∝ μ0 μ per unit area, times the share of the Sun that clears
/// the relief. The shadowed power is the quadrature of μ0 μ (1 − share)
/// over the lit, visible sphere with the share from the horizon map's
/// public lookup and the local Sun elevation and azimuth computed here;
/// the render's drop in disk flux, relative, must match it.
#[test]
fn the_disk_flux_drops_by_the_shadowed_power() {
    let dir = tempfile::tempdir().unwrap();
    let dem_path = dir.path().join("craters.tiff");
    write_f32_tiff(&dem_path, W, H, &craters()).unwrap();
    let map = HorizonMap::compute(&EquirectMap::load(&dem_path).unwrap(), R, 16);
    let model = "{ model = \"lambert\", albedo = 0.3 }";
    for alpha in [60.0f64, 100.0] {
        let mut plain = Setup::new(model, alpha, 1e5, 600.0);
        plain.geometry = "distant";
        let mut shadowed = Setup::new(model, alpha, 1e5, 600.0);
        shadowed.geometry = "distant";
        shadowed.extra_body = shadows_key(&dem_path, dir.path(), "always");
        let e_plain = render(&plain.scene()).summary.irradiance_all_caps_w_m2;
        let e_shadow = render(&shadowed.scene()).summary.irradiance_all_caps_w_m2;
        let drop = 1.0 - e_shadow / e_plain;
        let want = shadowed_share(&map, alpha);
        println!("α {alpha}°: disk flux drop: render {drop:.7}, quadrature {want:.7}");
        assert!(want > 1e-3, "the craters shadow too little to test: {want}");
        assert!(
            (drop - want).abs() < 0.01 * want,
            "α {alpha}°: render drop {drop} vs shadowed share {want}"
        );
    }
}

/// The reference: a 4096 × 2048 midpoint quadrature in latitude and
/// longitude of μ0 μ (1 − share) over μ0 μ; the Sun along +x (body-fixed),
/// the camera at longitude α.
fn shadowed_share(map: &HorizonMap, alpha: f64) -> f64 {
    let sun_radius = (6.957e8 / AU).asin();
    let (sun, cam) = (DVec3::X, unit(0.0, alpha.to_radians()));
    let (nx, ny) = (4096, 2048);
    let (mut lit, mut lost) = (0.0, 0.0);
    for j in 0..ny {
        let lat = FRAC_PI_2 - (j as f64 + 0.5) / ny as f64 * PI;
        for i in 0..nx {
            let lon = (i as f64 + 0.5) / nx as f64 * TAU - PI;
            let n = unit(lat, lon);
            let (mu0, mu) = (n.dot(sun), n.dot(cam));
            if mu0 <= 0.0 || mu <= 0.0 {
                continue;
            }
            let east = DVec3::new(-lon.sin(), lon.cos(), 0.0);
            let north = n.cross(east);
            let azimuth = sun.dot(north).atan2(sun.dot(east));
            let share = map.relief_factor(lat, lon, azimuth, mu0.asin(), sun_radius);
            let w = mu0 * mu * lat.cos();
            lit += w;
            lost += w * (1.0 - share);
        }
    }
    lost / lit
}

/// `auto`: at zero phase no shadow shows (it lies behind its relief), so
/// the frame skips them; a grazing, close view near the terminator takes
/// them. Both say so in the summary.
#[test]
fn auto_mode_skips_a_full_disk_and_takes_a_grazing_view() {
    let dir = tempfile::tempdir().unwrap();
    let dem_path = dir.path().join("craters.tiff");
    write_f32_tiff(&dem_path, W, H, &craters()).unwrap();
    let model = "{ model = \"lambert\", albedo = 0.3 }";
    let mut full = Setup::new(model, 0.0, 1e4, 100.0);
    full.extra_body = shadows_key(&dem_path, dir.path(), "auto");
    let d = render(&full.scene()).summary.relief_shadows.unwrap();
    assert!(
        !d.applied && d.reason == "auto: below the error target",
        "{d:?}"
    );
    assert!(d.shadow_effect < d.target && d.target == 1e-2, "{d:?}");
    let mut grazing = Setup::new(model, 85.0, 1e2, 400.0);
    grazing.extra_body = shadows_key(&dem_path, dir.path(), "auto");
    let images = render(&grazing.scene());
    let d = images.summary.relief_shadows.unwrap();
    assert!(
        d.applied && d.reason == "auto: reaches the error target",
        "{d:?}"
    );
    assert!(
        d.shadow_effect >= d.target && d.min_sun_elevation_deg < 5.0,
        "{d:?}"
    );
    assert_eq!(d.shadow_effect, d.shadow_px.min(1.0));
    // `never` overrides.
    grazing.extra_body = shadows_key(&dem_path, dir.path(), "never");
    let d = render(&grazing.scene()).summary.relief_shadows.unwrap();
    assert!(!d.applied && d.reason == "mode = never", "{d:?}");
}

/// The cache: the second load reads it; a corrupt, truncated or foreign
/// file in its place is rebuilt, and the rebuilt map equals the first.
#[test]
fn a_corrupt_cache_is_rebuilt_never_trusted() {
    use optistim::scene::horizon::{CacheOutcome, HorizonParams};
    let dir = tempfile::tempdir().unwrap();
    let dem_path = dir.path().join("craters.tiff");
    write_f32_tiff(&dem_path, W, H, &craters()).unwrap();
    let dem = EquirectMap::load(&dem_path).unwrap();
    let params = HorizonParams {
        radius: R,
        scale: 1.0,
        azimuths: 8,
    };
    let cache = dir.path().join("cache");
    let (first, outcome, file) =
        HorizonMap::load_or_compute(&dem_path, &dem, &params, &cache).unwrap();
    assert_eq!(outcome, CacheOutcome::Computed);
    assert!(first.max_elevation() > 0.0);
    let (_, outcome, _) = HorizonMap::load_or_compute(&dem_path, &dem, &params, &cache).unwrap();
    assert_eq!(outcome, CacheOutcome::Loaded);
    let good = std::fs::read(&file).unwrap();
    let mut flipped = good.clone();
    let k = flipped.len() / 2;
    flipped[k] ^= 0x40;
    let mut nan = good.clone();
    nan[100..104].copy_from_slice(&f32::NAN.to_le_bytes());
    for (what, bytes) in [
        ("one bit flipped", flipped),
        ("a NaN", nan),
        ("truncated", good[..good.len() - 7].to_vec()),
        ("empty", Vec::new()),
    ] {
        std::fs::write(&file, &bytes).unwrap();
        let (again, outcome, _) =
            HorizonMap::load_or_compute(&dem_path, &dem, &params, &cache).unwrap();
        assert_eq!(outcome, CacheOutcome::Rebuilt, "{what}");
        for (col, row) in [(0, 0), (W / 2, H / 2), (W - 1, H - 1), (370, 120)] {
            for k in 0..8 {
                assert_eq!(again.cell(col, row, k), first.cell(col, row, k), "{what}");
            }
        }
        assert_eq!(std::fs::read(&file).unwrap(), good, "{what}: rewritten");
    }
    // A cache directory that cannot be created (a file is in its way)
    // loses the cache, not the map.
    let blocked = dir.path().join("blocked");
    std::fs::write(&blocked, b"not a directory").unwrap();
    let (uncached, outcome, _) =
        HorizonMap::load_or_compute(&dem_path, &dem, &params, &blocked.join("cache")).unwrap();
    assert_eq!(outcome, CacheOutcome::Computed);
    assert_eq!(uncached.cell(370, 120, 3), first.cell(370, 120, 3));
    // Another azimuth count is another key: its own file.
    let eight = params;
    let sixteen = HorizonParams {
        azimuths: 16,
        ..eight
    };
    let (_, outcome, other) =
        HorizonMap::load_or_compute(&dem_path, &dem, &sixteen, &cache).unwrap();
    assert_eq!(outcome, CacheOutcome::Computed);
    assert_ne!(other, file);
    // A changed DEM (same size) is a changed hash: not the old map.
    let mut data = craters();
    data[5] = -1.0;
    write_f32_tiff(&dem_path, W, H, &data).unwrap();
    let (_, outcome, moved) =
        HorizonMap::load_or_compute(&dem_path, &dem, &params, &cache).unwrap();
    assert_eq!(outcome, CacheOutcome::Computed);
    assert_ne!(moved, file);
}
