//! Relief past the sphere's limb rising into view (`[body] shadows` with
//! `displace = true, far_limb = true`): a ring ridge on the far side of the geometric limb,
//! seen in profile, against the silhouette of the same DEM computed here
//! over latitudes on both sides of the limb; the light it adds against the
//! area of that silhouette; and no pixel lit twice where the sphere in
//! front covers the ridge's lower slopes.

mod common;
use common::ring_dem::*;
use common::*;

use std::f64::consts::PI;

/// One render's measures: the limb's distance [px] from the centre on
/// both sides of the central row, the image's sum over the centre's
/// radiance [px²], and the largest pixel over the centre's.
struct Measured {
    edges: [f64; 2],
    area_px: f64,
    brightest: f64,
}

fn measure(scene: &optistim::scene::Scene) -> Measured {
    let images = render(scene);
    let pin = &scene.camera.pinhole;
    let row = pin.cy.floor() as usize;
    let img = &images.radiance;
    // The central pixel lies wholly inside the flat polar cap.
    let full = img[row * pin.width + pin.cx.floor() as usize] as f64;
    assert!(full > 0.0);
    let edges = [1, -1].map(|sign| edge_px(img, pin.width, row, pin.cx, sign, full));
    let area_px = img.iter().map(|&v| v as f64).sum::<f64>() / full;
    let brightest = img.iter().map(|&v| v as f64).fold(0.0, f64::max) / full;
    Measured {
        edges,
        area_px,
        brightest,
    }
}

/// A ring ridge 40 m high (σ = 3°, 12 DEM rows) whose crest lies 6°
/// past the sphere's limb (latitude asin(R/d) − 6°), with a ridge 15 m
/// high (σ = 2°) just inside the limb and one 30 m high 15° past it that
/// stays behind the limb, on a
/// 1000 m area-law body seen from 4 radii over its north pole, 200 px
/// across, the Sun 5° off the camera (every visible point is lit; caps
/// everywhere, as with a displacement): on both sides of the
/// central row the lit disk ends where the silhouette computed here says,
/// within 0.05 px; the light the ridge adds is its silhouette's annulus
/// (π (r_ridge² − r_sphere²) in pixels) within 0.5 %, and no pixel holds
/// two surfaces' radiance (the deep ridge's slope facing the camera stays
/// hidden behind the limb); a flat DEM leaves every pixel as the sphere's
/// within 1e-9.
#[test]
fn a_ridge_past_the_limb_rises_into_the_profile() {
    let dir = tempfile::tempdir().unwrap();
    let mut setup = Setup::new("{ model = \"area\", albedo = 0.3 }", 5.0, 4.0, 200.0);
    let (radius, d) = (setup.radius, setup.range);
    let limb_lat = (radius / d).asin();
    // (height, crest, σ): the far ridge past the limb, a ridge on the
    // limb, and a deep ridge whose camera-facing slope (up to 46°, steeper
    // than the camera's depression there) faces the camera from behind
    // the limb, too low to clear it (it would need R (sec 15° − 1) = 35 m).
    let ridges = [
        (40.0, limb_lat - 6f64.to_radians(), 3f64.to_radians()),
        (15.0, limb_lat + 0.5f64.to_radians(), 2f64.to_radians()),
        (30.0, limb_lat - 15f64.to_radians(), 1f64.to_radians()),
    ];
    let rows: Vec<f64> = (0..ROWS)
        .map(|j| {
            ridges
                .iter()
                .map(|&(h, crest, sigma)| h * (-0.5 * ((row_lat(j) - crest) / sigma).powi(2)).exp())
                .sum()
        })
        .collect();
    let write = |name: &str, rows: &[f64]| {
        let path = dir.path().join(name);
        write_ring_dem(&path, rows);
        path
    };
    let ridge_dem = write("ridge.tiff", &rows);
    let flat_dem = write("flat.tiff", &vec![0.0; ROWS]);

    // The body's north pole toward the camera.
    let cam = setup.camera_position();
    let body_attitude = pole_toward(cam);
    let scene_of = |setup: &Setup| {
        let toml = setup.toml().replacen("[state]", &body_attitude, 1);
        optistim::scene::Scene::from_toml(&toml, std::path::Path::new("t.toml")).unwrap()
    };
    // Caps everywhere, as the displacement renders.
    setup.extra_render = "interior = \"caps\"".into();
    let plain = scene_of(&setup);
    let with_dem = |setup: &mut Setup, dem: &std::path::Path| {
        setup.extra_body = format!(
            "shadows = {{ dem = \"{}\", scale = 1.0, mode = \"always\", displace = true, far_limb = true, cache_dir = \"{}\" }}",
            dem.display(),
            dir.path().display()
        );
        scene_of(setup)
    };
    let raised = with_dem(&mut setup, &ridge_dem);
    let flat = with_dem(&mut setup, &flat_dem);

    // The geometry, computed here: the ridge's silhouette point lies past
    // the sphere's limb and moves the limb outward by pixels.
    let pin = &plain.camera.pinhole;
    let (sphere_angle, _) = silhouette(&vec![0.0; ROWS], radius, d, (-0.3, 0.6), 300_000);
    assert!((sphere_angle - (radius / d).asin()).abs() < 1e-9);
    let (ridge_angle, at) = silhouette(&rows, radius, d, (-0.3, 0.6), 300_000);
    assert!(at < limb_lat - 2f64.to_radians(), "{at} vs limb {limb_lat}");
    let sphere_px = pin.fx * sphere_angle.tan();
    let ridge_px = pin.fx * ridge_angle.tan();
    assert!(ridge_px - sphere_px > 2.0, "{ridge_px} vs {sphere_px}");

    let sphere = measure(&plain);
    let ridge = measure(&raised);
    eprintln!(
        "limb: sphere {:?} px (geometry {sphere_px}), ridge {:?} px (geometry {ridge_px})",
        sphere.edges, ridge.edges
    );
    // The light the ridge adds: the annulus between the two silhouettes
    // (uniform radiance, every visible point lit).
    let added = ridge.area_px - sphere.area_px;
    let annulus = PI * (ridge_px * ridge_px - sphere_px * sphere_px);
    eprintln!(
        "disk {:.3} px² (π r² {:.3}); ridge adds {added:.3} px² (annulus {annulus:.3}); brightest {:.5} / {:.5} of the centre",
        sphere.area_px,
        PI * sphere_px * sphere_px,
        ridge.brightest,
        sphere.brightest
    );
    for (got, want, what) in [
        (sphere.edges, sphere_px, "sphere"),
        (ridge.edges, ridge_px, "ridge"),
    ] {
        for e in got {
            assert!(
                (e - want).abs() < 0.05,
                "{what}: limb at {e} px, geometry {want}"
            );
        }
    }
    assert!(
        (added / annulus - 1.0).abs() < 5e-3,
        "the ridge adds {added} px², its silhouette's annulus is {annulus} px²"
    );
    // Grazing facets shade with the DEM's slope maps while their corners
    // sit on its bilinear surface: single pixels swing by a few per cent
    // either way (the sum above holds to 0.5 %); terrain lit twice would
    // double a pixel.
    assert!(
        ridge.brightest < 1.05,
        "a pixel at {} of one surface's radiance: hidden slopes add light",
        ridge.brightest
    );

    // A flat DEM: the sphere's image, pixel by pixel.
    let (a, b) = (render(&plain).radiance, render(&flat).radiance);
    let worst = a
        .iter()
        .zip(&b)
        .map(|(&x, &y)| (x as f64 - y as f64).abs() / (x as f64).abs().max(1e-300))
        .fold(0.0, f64::max);
    assert!(worst <= 1e-9, "a flat DEM changed a pixel by {worst:e}");
}

/// `far_limb` is on by default with `displace` and off without it;
/// `far_limb = true` without `displace` is refused with a one-line error
/// naming the key, while shadows alone (or `far_limb = false`) load.
#[test]
fn far_limb_needs_the_displacement() {
    let dir = tempfile::tempdir().unwrap();
    let dem = dir.path().join("flat.tiff");
    optistim::render::output::write_f32_tiff(&dem, COLS, ROWS, &vec![0.0f32; COLS * ROWS]).unwrap();
    let mut setup = Setup::new("{ model = \"area\", albedo = 0.3 }", 5.0, 4.0, 50.0);
    let far_limb_of = |setup: &mut Setup, keys: &str| {
        setup.extra_body = format!(
            "shadows = {{ dem = \"{}\", scale = 1.0, {keys}cache_dir = \"{}\" }}",
            dem.display(),
            dir.path().display()
        );
        let scene =
            optistim::scene::Scene::from_toml(&setup.toml(), std::path::Path::new("t.toml"))
                .unwrap_or_else(|e| panic!("{keys}: {e}"));
        scene.body.relief.far_limb
    };
    assert!(far_limb_of(&mut setup, "displace = true, "));
    assert!(!far_limb_of(
        &mut setup,
        "displace = true, far_limb = false, "
    ));
    assert!(!far_limb_of(&mut setup, ""));
    assert!(!far_limb_of(&mut setup, "far_limb = false, "));
    setup.extra_body = format!(
        "shadows = {{ dem = \"{}\", scale = 1.0, far_limb = true, cache_dir = \"{}\" }}",
        dem.display(),
        dir.path().display()
    );
    let Err(err) = optistim::scene::Scene::from_toml(&setup.toml(), std::path::Path::new("t.toml"))
    else {
        panic!("far_limb without displace was accepted");
    };
    let msg = err.to_string();
    assert!(
        msg.contains("body.shadows.far_limb") && !msg.contains('\n'),
        "{msg}"
    );
}
