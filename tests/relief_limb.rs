//! The DEM moves the limb and tilts the normals (`[body] shadows` with
//! `displace = true`): a ridge on the limb against the silhouette of the
//! same DEM computed here, and the renderer's normals against finite
//! differences of the DEM's bilinear surface written here.

mod common;
use common::ring_dem::*;
use common::*;

use glam::DVec3;
use optistim::scene::surface::displaced;
use optistim::scene::EquirectMap;

/// A ring ridge 40 m high (σ = 3°, 12 DEM rows)
/// whose crest is the sphere's limb, on a 1000 m body seen from 4 radii
/// over its pole, 200 px across: the lit limb ends where the DEM's
/// silhouette says, within 0.01 px (0.005 px measured); without the DEM
/// it ends at the sphere's, within 1e-3 px.
#[test]
fn a_ridge_on_the_limb_moves_the_silhouette_by_its_projected_height() {
    let dir = tempfile::tempdir().unwrap();
    let mut setup = Setup::new("{ model = \"area\", albedo = 0.3 }", 30.0, 4.0, 200.0);
    let (radius, d) = (setup.radius, setup.range);
    let limb_lat = (radius / d).asin();
    let (h, sigma) = (40.0, 3f64.to_radians());
    let rows: Vec<f64> = (0..ROWS)
        .map(|j| ridge(row_lat(j), h, limb_lat, sigma))
        .collect();
    let dem = dir.path().join("ridge.tiff");
    write_ring_dem(&dem, &rows);

    // The body's north pole toward the camera.
    let cam = setup.camera_position();
    let body_attitude = pole_toward(cam);
    let scene_of = |setup: &Setup| {
        let toml = setup.toml().replacen("[state]", &body_attitude, 1);
        optistim::scene::Scene::from_toml(&toml, std::path::Path::new("t.toml")).unwrap()
    };
    let plain = scene_of(&setup);
    setup.extra_body = format!(
        "shadows = {{ dem = \"{}\", scale = 1.0, mode = \"always\", displace = true, cache_dir = \"{}\" }}",
        dem.display(),
        dir.path().display()
    );
    let raised = scene_of(&setup);

    // The Sun's side of the image: the camera's x axis (look_at) against
    // the Sun's direction. The Sun stands pole-ward of the ridge there, so
    // its shadow falls on the hidden side.
    let z = -cam.normalize();
    let x_cam = z.cross(DVec3::Z).normalize();
    let sign = if x_cam.dot(setup.sun_position()) > 0.0 {
        1
    } else {
        -1
    };
    let pin = &plain.camera.pinhole;
    let row = pin.cy.floor() as usize;
    // The central pixel is wholly inside the flat polar cap.
    let measure = |scene: &optistim::scene::Scene| {
        let images = render(scene);
        if let Some(d) = images.summary.relief_shadows {
            assert!(d.displaced && d.limb_px > 3.0, "{d:?}");
        }
        let img = images.radiance;
        let full = img[row * pin.width + pin.cx.floor() as usize] as f64;
        assert!(full > 0.0);
        edge_px(&img, pin.width, row, pin.cx, sign, full)
    };

    let (sphere_angle, _) = silhouette(&vec![0.0; ROWS], radius, d, (0.0, 0.6), 200_000);
    assert!((sphere_angle - (radius / d).asin()).abs() < 1e-9);
    let sphere_px = pin.fx * sphere_angle.tan();
    let (ridge_angle, at) = silhouette(&rows, radius, d, (0.0, 0.6), 200_000);
    let ridge_px = pin.fx * ridge_angle.tan();
    // The silhouette point is on the near side (the renderer's caps cover
    // the sphere's visible hemisphere) and the ridge moves it by pixels.
    assert!(at >= limb_lat, "{at} < {limb_lat}");
    assert!(ridge_px - sphere_px > 3.0, "{ridge_px} vs {sphere_px}");

    let got_plain = measure(&plain);
    let got_raised = measure(&raised);
    eprintln!("limb: sphere {got_plain} px (geometry {sphere_px}), ridge {got_raised} px (geometry {ridge_px})");
    assert!(
        (got_plain - sphere_px).abs() < 1e-3,
        "sphere: limb at {got_plain} px, geometry {sphere_px}"
    );
    assert!(
        (got_raised - ridge_px).abs() < 0.01,
        "ridge: limb at {got_raised} px, geometry {ridge_px} (sphere {sphere_px})"
    );
}

/// The geometric normal the renderer shades with (`scene::surface`) is the
/// normal of the DEM's bilinear surface p = n (R + h): at points all over
/// the sphere it matches the cross product of central differences of p
/// over ±1 DEM cell (the bilinear DEM written here) to 1e-6 rad, and the
/// smooth field's analytic normal to the discretisation's order.
#[test]
fn normals_from_the_dem_match_finite_differences_of_its_surface() {
    use std::f64::consts::{FRAC_PI_2, PI, TAU};
    let (w, h, radius) = (256usize, 128usize, 5.0e4);
    let field =
        |lat: f64, lon: f64| 900.0 * (3.0 * lon).sin() * (2.0 * lat).cos() + 400.0 * lat.sin();
    let mut data = vec![0.0f32; w * h];
    for j in 0..h {
        for i in 0..w {
            let lat = FRAC_PI_2 - (j as f64 + 0.5) * PI / h as f64;
            let lon = (i as f64 + 0.5) * TAU / w as f64 - PI;
            data[j * w + i] = field(lat, lon) as f32;
        }
    }
    // The test's own bilinear read (wrap in longitude, clamp in latitude).
    let bilinear = |lat: f64, lon: f64| {
        let x = (lon + PI) / TAU * w as f64 - 0.5;
        let y = ((FRAC_PI_2 - lat) / PI * h as f64 - 0.5).clamp(0.0, (h - 1) as f64);
        let (i0, j0) = (x.floor(), (y.floor() as usize).min(h - 2));
        let (tx, ty) = (x - i0, y - j0 as f64);
        let i0 = (i0 as i64).rem_euclid(w as i64) as usize;
        let i1 = (i0 + 1) % w;
        let v = |i: usize, j: usize| data[j * w + i] as f64;
        let top = v(i0, j0) * (1.0 - tx) + v(i1, j0) * tx;
        let bottom = v(i0, j0 + 1) * (1.0 - tx) + v(i1, j0 + 1) * tx;
        top * (1.0 - ty) + bottom * ty
    };
    let unit =
        |lat: f64, lon: f64| DVec3::new(lat.cos() * lon.cos(), lat.cos() * lon.sin(), lat.sin());
    let surface = |lat: f64, lon: f64, hgt: &dyn Fn(f64, f64) -> f64| {
        unit(lat, lon) * (radius + hgt(lat, lon))
    };
    let height = EquirectMap::new(w, h, data.clone());
    let (d_lat, d_lon) = height.gradients();
    let maps = (height, d_lat, d_lon);
    let (step_lat, step_lon) = (PI / h as f64, TAU / w as f64);
    let mut worst_fd: f64 = 0.0;
    let mut worst_exact: f64 = 0.0;
    let mut tilt: f64 = 0.0;
    for k in 0..2000 {
        let t = k as f64;
        // Away from the first and last rows (clamped there).
        let lat = (t * 0.618_034).sin() * 1.3;
        let lon = (t * 0.414_214).sin() * 3.1;
        let (r, normal) = displaced(&maps, radius, unit(lat, lon));
        assert!(
            (r - radius - bilinear(lat, lon)).abs() < 1e-6,
            "radius at {lat}, {lon}"
        );
        let fd = |hgt: &dyn Fn(f64, f64) -> f64, dl: f64, dn: f64| {
            let e = surface(lat, lon + dn, hgt) - surface(lat, lon - dn, hgt);
            let n = surface(lat + dl, lon, hgt) - surface(lat - dl, lon, hgt);
            e.cross(n).normalize()
        };
        let from_dem = fd(&bilinear, step_lat, step_lon);
        let exact = fd(&field, 1e-6, 1e-6);
        worst_fd = worst_fd.max(normal.angle_between(from_dem));
        worst_exact = worst_exact.max(normal.angle_between(exact));
        tilt = tilt.max(normal.angle_between(unit(lat, lon)));
    }
    // The central differences over ±1 cell move the point by a cell on
    // the sphere too: their normal differs by O(δ²) relative
    // (the O(δ²) terms of the chords, δ = 0.025 rad, times slopes ≤ 0.06).
    assert!(worst_fd < 2e-4, "against the DEM's surface: {worst_fd} rad");
    assert!(
        worst_exact < 1e-3,
        "against the smooth field: {worst_exact} rad"
    );
    eprintln!("normal errors: DEM surface {worst_fd:e} rad, smooth field {worst_exact:e} rad, tilt {tilt}");
    assert!(tilt > 0.02, "the relief tilts the normals ({tilt} rad)");
}
