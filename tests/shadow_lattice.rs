//! The interior lattice's cast-shadow factor against the exact one.
//!
//! Interior pixels interpolate the Sun's geometry (horizon-map position,
//! sin elevation, east and north components) from the node lattice instead
//! of hitting the sphere per pixel (`render::interior`). Here every
//! interior pixel's applied factor, the ratio of its flux with and without
//! shadows (the same lattice gives both the same unshadowed flux), is
//! checked against an exact evaluation written in this test: the pixel
//! centre's ray–sphere hit, the local Sun elevation and azimuth, and the
//! horizon map's public lookup. Rough terrain, grazing Suns at the
//! terminator, random body attitudes, a pole in view and under the camera
//! (near a pole the Sun comes from the polar nodes, `render::polar_sun`),
//! and the bundled close-range polar view with the LOLA DEM.

mod common;
use common::*;

use std::f64::consts::{FRAC_PI_2, PI, TAU};

use glam::{DQuat, DVec3};
use optistim::render::output::write_f32_tiff;
use optistim::render::Renderer;
use optistim::scene::horizon::HorizonMap;
use optistim::scene::EquirectMap;
use rayon::prelude::*;

const W: usize = 512;
const H: usize = 256;
/// The test body's radius [m] (common::Setup).
const R: f64 = 1000.0;
/// Largest |lattice factor − exact factor| allowed at any pixel. The
/// interpolated geometry (cubic Lagrange on a 4-pixel lattice) is off by
/// up to Δ ≈ 2e-5 rad in elevation-equivalent here (before penumbra pixels
/// were made exact the factor was off by 2.6e-3 there, at a slope of
/// ~120 per radian). Lit or dark by the interpolated geometry, the exact
/// factor is within 0.6 (Δ/ρ)^{3/2} ≈ 2e-4 of it (the disk share's ends
/// are flat, ρ = 4.65 mrad); the two f32 images add ~3e-7. Shadow-edge
/// pixels carry the mean of 4 × 4 exact factors over the pixel
/// (`render::shadow_edges`), recomputed here the same way; an edge
/// pixel's unshadowed flux is recovered from the f32 image.
const MAX_FACTOR_ERROR: f64 = 3e-4;

/// Rough terrain: a sum of incommensurate ridges, ±30 m on a 1 km body
/// (cells 12 m), so slopes up to ~40° cast shadows at most elevations.
fn rough() -> Vec<f32> {
    let mut data = vec![0.0f32; W * H];
    for row in 0..H {
        let lat = FRAC_PI_2 - (row as f64 + 0.5) / H as f64 * PI;
        for col in 0..W {
            let lon = (col as f64 + 0.5) / W as f64 * TAU - PI;
            let p = DVec3::new(lat.cos() * lon.cos(), lat.cos() * lon.sin(), lat.sin());
            let h = 12.0 * (23.0 * p.x + 7.0 * p.y).sin()
                + 10.0 * (31.0 * p.y - 11.0 * p.z).sin()
                + 8.0 * (41.0 * p.z + 13.0 * p.x).sin();
            data[row * W + col] = h as f32;
        }
    }
    data
}

/// The exact factor at pixel (i, j): ray through the pixel centre, first
/// hit on the sphere, Sun direction from the hit, the map's lookup.
fn exact_factor(
    scene: &optistim::scene::Scene,
    map: &HorizonMap,
    radius: f64,
    i: usize,
    j: usize,
) -> Option<f64> {
    exact_factor_at(scene, map, radius, i as f64 + 0.5, j as f64 + 0.5)
}

/// Points per axis of the brute-force mean over an edge pixel.
const BRUTE_POINTS: usize = 16;

/// Per case (name, phase [deg]): the largest mean and p99 of |edge
/// pixel's factor − its [`BRUTE_POINTS`]² brute-force mean| over the edge
/// candidates. These are the errors of the renderer before the edge pass
/// interpolated the points' geometry from the pixel corners (4 × 4 exact
/// points, commit 4347c13), rounded up in the third digit: the
/// interpolated pass (5 × 5 points) may be no less accurate.
const EDGE_LIMITS: [(&str, f64, f64, f64); 11] = [
    ("grazing, equator", 95.0, 2.60e-3, 1.94e-2),
    ("crescent", 120.0, 3.00e-3, 2.57e-2),
    ("gibbous", 30.0, 5.45e-3, 5.92e-2),
    ("random attitude", 60.0, 4.23e-3, 4.48e-2),
    ("random attitude", 88.0, 5.29e-3, 5.52e-2),
    ("random attitude", 105.0, 4.68e-3, 4.95e-2),
    ("pole-centred", 85.0, 3.31e-3, 3.99e-2),
    ("pole-centred", 95.0, 3.99e-3, 4.27e-2),
    ("pole in view", 50.0, 6.25e-3, 6.19e-2),
    ("pole in view", 100.0, 4.43e-3, 5.22e-2),
    ("close range", 88.0, 1.18e-4, 1.20e-3),
];

/// Whether interior pixel k is a shadow-edge candidate by the exact
/// centre factors: its centre in the penumbra, or an interior
/// neighbour's centre factor different.
fn is_edge_candidate(centre: &[Option<f64>], width: usize, k: usize) -> bool {
    let (i, j) = (k % width, k / width);
    let s = centre[k].expect("an interior pixel hits the sphere");
    let height = centre.len() / width;
    let neighbour_differs = (j.saturating_sub(1)..=(j + 1).min(height - 1)).any(|jj| {
        (i.saturating_sub(1)..=(i + 1).min(width - 1))
            .any(|ii| centre[jj * width + ii].is_some_and(|n| (n - s).abs() > 1e-6))
    });
    (s > 0.0 && s < 1.0) || neighbour_differs
}

/// The mean exact factor over [`BRUTE_POINTS`]² points of pixel (i, j):
/// the share of its preimage the Sun lights, by brute force.
fn brute_force_mean(
    scene: &optistim::scene::Scene,
    map: &HorizonMap,
    radius: f64,
    i: usize,
    j: usize,
) -> f64 {
    let n = BRUTE_POINTS;
    let mut sum = 0.0;
    for b in 0..n {
        for a in 0..n {
            let u = i as f64 + (a as f64 + 0.5) / n as f64;
            let v = j as f64 + (b as f64 + 0.5) / n as f64;
            sum += exact_factor_at(scene, map, radius, u, v).unwrap_or(0.0);
        }
    }
    sum / (n * n) as f64
}

/// The exact factor at continuous pixel position (u, v).
fn exact_factor_at(
    scene: &optistim::scene::Scene,
    map: &HorizonMap,
    radius: f64,
    u: f64,
    v: f64,
) -> Option<f64> {
    let pin = &scene.camera.pinhole;
    let st = &scene.state;
    let d_cam = DVec3::new((u - pin.cx) / pin.fx, (v - pin.cy) / pin.fy, 1.0);
    let d = (st.camera_attitude * d_cam).normalize();
    let c = st.camera_position - st.body_position;
    let b = d.dot(c);
    let disc = b * b - (c.length_squared() - radius * radius);
    if disc <= 0.0 {
        return None;
    }
    let p = c + d * (-b - disc.sqrt());
    let to_body = st.body_attitude.inverse();
    let n = (to_body * p).normalize();
    let sun = st.sun_position - st.body_position;
    let l = (to_body * (sun - p)).normalize();
    let rho = (6.957e8 / sun.length()).asin();
    let lat = n.z.asin();
    let lon = n.y.atan2(n.x);
    let east = DVec3::new(-lon.sin(), lon.cos(), 0.0);
    let north = n.cross(east);
    let azimuth = l.dot(north).atan2(l.dot(east));
    let elevation = l.dot(n).asin();
    Some(map.relief_factor(lat, lon, azimuth, elevation, rho))
}

/// Over several phases (grazing terminators included) and body attitudes
/// (random ones, and a pole between Sun and camera), every interior pixel's
/// applied factor agrees with the exact one within [`MAX_FACTOR_ERROR`];
/// a good share of pixels (a fifth or more) are interpolated, and
/// many are partly or wholly shadowed.
#[test]
fn lattice_shadow_factor_matches_the_exact_factor() {
    let dir = tempfile::tempdir().unwrap();
    let dem_path = dir.path().join("rough.tiff");
    write_f32_tiff(&dem_path, W, H, &rough()).unwrap();
    let map = HorizonMap::compute(&EquirectMap::load(&dem_path).unwrap(), R, 16);
    assert!(map.max_elevation() > 0.3, "{}", map.max_elevation());
    let key = format!(
        "shadows = {{ dem = \"{}\", scale = 1.0, azimuths = 16, cache_dir = \"{}\", mode = \"always\" }}",
        dem_path.display(),
        dir.path().display()
    );
    // A fixed sequence of attitudes (golden-ratio walk over axis and angle).
    let random = |k: usize| {
        let t = k as f64;
        let z = (t * 0.618_034).fract() * 2.0 - 1.0;
        let phi = t * 2.399_963;
        let axis = DVec3::new(
            (1.0 - z * z).sqrt() * phi.cos(),
            (1.0 - z * z).sqrt() * phi.sin(),
            z,
        );
        DQuat::from_axis_angle(axis, (t * 0.414_214).fract() * TAU)
    };
    let mut cases: Vec<(f64, DQuat, &str)> = vec![
        (95.0, DQuat::IDENTITY, "grazing, equator"),
        (120.0, DQuat::IDENTITY, "crescent"),
        (30.0, DQuat::IDENTITY, "gibbous"),
    ];
    for (alpha, k) in [(60.0, 1), (88.0, 2), (105.0, 3)] {
        cases.push((alpha, random(k), "random attitude"));
    }
    for (alpha, pole) in [(85.0f64, DVec3::Z), (95.0, -DVec3::Z)] {
        // A pole under the camera, the Sun 5° above or below its horizon.
        let camera = DVec3::new(alpha.to_radians().cos(), alpha.to_radians().sin(), 0.0);
        cases.push((
            alpha,
            DQuat::from_rotation_arc(pole, camera),
            "pole-centred",
        ));
    }
    for alpha in [50.0f64, 100.0] {
        // The north pole between the Sun (+x) and the camera.
        let half = (0.5 * alpha).to_radians();
        let pole = DVec3::new(half.cos(), half.sin(), 0.0);
        cases.push((
            alpha,
            DQuat::from_rotation_arc(DVec3::Z, pole),
            "pole in view",
        ));
    }
    for (alpha, attitude, what) in cases {
        let mut setup = Setup::new("{ model = \"lambert\", albedo = 0.3 }", alpha, 20.0, 300.0);
        setup.extra_body = key.clone();
        setup.extra_render = "interior = \"pixels\"\nnode_spacing = 4".into();
        let mut scene = setup.scene();
        scene.state.body_attitude = attitude;
        // One point per pixel, so a pixel's shadow is its centre's.
        let mut settings = scene.render.clone();
        settings.pixel_tolerance = f64::INFINITY;
        let checked = check_factors(&scene, &settings, &map, R, what);
        assert!(
            checked.lattice * 5 > checked.interior,
            "{what}, α {alpha}: only {} of {} interior pixels interpolated",
            checked.lattice,
            checked.interior
        );
        // The polar cap (latitude ≥ 64°) is a fifth of the disk's
        // area seen from over the pole, the lit half of it at 85–95°.
        if what == "pole-centred" {
            assert!(
                checked.polar * 10 > checked.interior,
                "{what}, α {alpha}: only {} of {} shadows from polar nodes",
                checked.polar,
                checked.interior
            );
        }
    }
}

/// A Hapke body with an albedo map (the bundled Moon's case) has no flux
/// lattice (Hapke is not quadratic in the albedo), yet its interior pixels
/// take the Sun from the lattice's nodes: most shadows are interpolated,
/// and every factor agrees with the exact one as for the Lambert body
/// (the shadow factor does not depend on the reflectance, so the same
/// views keep the same edge limits).
#[test]
fn hapke_body_interpolates_the_sun_without_the_flux_lattice() {
    let dir = tempfile::tempdir().unwrap();
    let dem_path = dir.path().join("rough.tiff");
    write_f32_tiff(&dem_path, W, H, &rough()).unwrap();
    let map = HorizonMap::compute(&EquirectMap::load(&dem_path).unwrap(), R, 16);
    let albedo = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/data/maps/lroc_color_poles_2k.tif"
    );
    let hapke = "{ model = \"hapke\", w = 0.3, b = 0.25, c = 0.3, theta_bar = 0.35, h_s = 0.08, b_s0 = 1.0 }";
    for (alpha, what) in [(95.0, "grazing, equator"), (30.0, "gibbous")] {
        let mut setup = Setup::new(hapke, alpha, 20.0, 300.0);
        setup.extra_body = format!(
            "shadows = {{ dem = \"{}\", scale = 1.0, azimuths = 16, cache_dir = \"{}\", mode = \"always\" }}\nalbedo_map = {{ path = \"{albedo}\", min = 0.16, max = 0.40 }}",
            dem_path.display(),
            dir.path().display()
        );
        setup.extra_render = "interior = \"pixels\"\nnode_spacing = 4".into();
        let scene = setup.scene();
        let mut settings = scene.render.clone();
        settings.pixel_tolerance = f64::INFINITY;
        let checked = check_factors(&scene, &settings, &map, R, what);
        assert_eq!(
            checked.lattice, 0,
            "{what}: the flux lattice is off for Hapke"
        );
        assert!(
            checked.shadow_exact * 2 < checked.interior,
            "{what}, α {alpha}: {} of {} interior shadows took the exact geometry",
            checked.shadow_exact,
            checked.interior
        );
    }
}

/// The bundled close-range view (`configs/moon_close_shadows.toml`: the
/// camera 1.05 R over a pole, the LOLA DEM, an albedo map) turned to
/// phase 88° as `optistim bench --shadows --phases 88` turns it: the Sun
/// grazes the terminator in the frame, the albedo's lattice is off (near
/// the pole) and the shadows come from the polar nodes; every interior
/// pixel's factor agrees with the exact one.
#[test]
fn close_range_polar_view_matches_the_exact_factor() {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/moon_close_shadows.toml");
    let mut scene = optistim::scene::Scene::from_file(&path).unwrap();
    // The bench's `at_phase`: the camera turned from the Sun by the phase
    // about an axis normal to it, looking at the centre.
    let st = &mut scene.state;
    let range = (st.camera_position - st.body_position).length();
    let sun_dir = (st.sun_position - st.body_position).normalize();
    let view =
        DQuat::from_axis_angle(sun_dir.any_orthonormal_vector(), 88f64.to_radians()) * sun_dir;
    st.camera_position = st.body_position + view * range;
    let boresight = -view;
    let x = boresight.cross(DVec3::Z).normalize();
    let y = boresight.cross(x);
    st.camera_attitude = DQuat::from_mat3(&glam::DMat3::from_cols(x, y, boresight)).normalize();
    let shadows = scene
        .body
        .relief
        .shadows
        .clone()
        .expect("the config casts shadows");
    let mut settings = scene.render.clone();
    settings.pixel_tolerance = f64::INFINITY;
    let radius = scene.body.radius;
    let checked = check_factors(&scene, &settings, &shadows.map, radius, "close range");
    assert!(
        checked.polar * 2 > checked.interior,
        "only {} of {} shadows from polar nodes",
        checked.polar,
        checked.interior
    );
}

/// What [`check_factors`] counted.
struct Checked {
    interior: usize,
    /// Interior pixels whose unshadowed flux came from the lattice.
    lattice: usize,
    /// Interior pixels whose shadow came from the polar nodes.
    polar: usize,
    /// Interior pixels whose shadow took the exact geometry (no Sun
    /// nodes, or the penumbra).
    shadow_exact: usize,
}

/// Renders `scene` with and without its shadows and checks every interior
/// pixel's applied factor (the ratio of the two) against
/// [`exact_factor`] within [`MAX_FACTOR_ERROR`].
fn check_factors(
    scene: &optistim::scene::Scene,
    settings: &optistim::render::RenderSettings,
    map: &HorizonMap,
    radius: f64,
    what: &str,
) -> Checked {
    let width = scene.camera.pinhole.width;
    let mut renderer = Renderer::new(scene.camera.pinhole.clone());
    let shadowed = renderer.render_flux(&scene.body, &scene.state, settings, None);
    assert!(shadowed.shadows.is_some_and(|d| d.applied));
    let with: Vec<f32> = renderer.flux().to_vec();
    let interior: Vec<bool> = (0..with.len())
        .map(|k| renderer.is_interior_pixel(k % width, k / width))
        .collect();
    let mut plain_body = scene.body.clone();
    plain_body.relief.shadows = None;
    let plain = renderer.render_flux(&plain_body, &scene.state, settings, None);
    let without = renderer.flux();
    let direct = plain.interior_direct;
    let lattice = plain.interior_pixels - direct.midpoint - direct.gauss2 - direct.gauss4;
    let centre: Vec<Option<f64>> = (0..with.len())
        .map(|k| {
            interior[k]
                .then(|| exact_factor(scene, map, radius, k % width, k / width))
                .flatten()
        })
        .collect();
    let (mut worst, mut compared, mut partial, mut dark) = (0.0f64, 0usize, 0usize, 0usize);
    let mut edges = Vec::new();
    for (k, (&a, &b)) in with.iter().zip(without).enumerate() {
        if !interior[k] || b <= 0.0 {
            continue;
        }
        let got = a as f64 / b as f64;
        compared += 1;
        let s = centre[k].expect("an interior pixel hits the sphere");
        partial += usize::from(s > 0.0 && s < 1.0);
        dark += usize::from(s == 0.0);
        if is_edge_candidate(&centre, width, k) {
            edges.push((k, got));
        } else {
            worst = worst.max((got - s).abs());
        }
    }
    let mut edge_errors: Vec<f64> = edges
        .par_iter()
        .map(|&(k, got)| (got - brute_force_mean(scene, map, radius, k % width, k / width)).abs())
        .collect();
    edge_errors.sort_by(f64::total_cmp);
    let mean_edge = edge_errors.iter().sum::<f64>() / edge_errors.len().max(1) as f64;
    let p99_edge = edge_errors
        .get((edge_errors.len() * 99 / 100).min(edge_errors.len().saturating_sub(1)))
        .copied()
        .unwrap_or(0.0);
    let polar = shadowed.interior_direct.shadow_polar;
    println!(
        "{what}, phase {:.0}°: {compared} interior pixels ({lattice} interpolated, {polar} shadows from polar nodes), {partial} in penumbra, {dark} dark; worst |Δ factor| off edges {worst:.2e}; {} edge candidates, |Δ| to the {BRUTE_POINTS}² mean: mean {mean_edge:.4e}, p99 {p99_edge:.4e}",
        shadowed.phase_angle.to_degrees(),
        edge_errors.len()
    );
    assert!(compared > 10_000, "{what}: {compared}");
    assert!(
        dark + partial > compared / 50,
        "{what}: too few shadows to test"
    );
    assert!(worst <= MAX_FACTOR_ERROR, "{what}: factor off by {worst:e}");
    let phase = shadowed.phase_angle.to_degrees();
    let &(_, _, max_mean, max_p99) = EDGE_LIMITS
        .iter()
        .find(|(w, a, _, _)| *w == what && (a - phase).abs() < 0.5)
        .expect("a limit for every case");
    assert!(
        edge_errors.len() > 1000,
        "{what}: {} edge pixels",
        edge_errors.len()
    );
    assert!(
        mean_edge <= max_mean && p99_edge <= max_p99,
        "{what}, {phase:.0}°: edge pixels off the brute-force mean by {mean_edge:.4e} (mean), {p99_edge:.4e} (p99); limits {max_mean:e}, {max_p99:e}"
    );
    Checked {
        interior: plain.interior_pixels,
        lattice,
        polar,
        shadow_exact: shadowed.interior_direct.shadow_exact,
    }
}
