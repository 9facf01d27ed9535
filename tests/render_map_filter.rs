//! The exact map filter (`EquirectMap::parallelogram_mean`, `[render]
//! map_filter = "exact"`) against references written here: the bilinear
//! interpolant (own code, wrap in x, clamp in y) integrated exactly cell by
//! cell (the parallelogram clipped to each texel cell, triangulated, a
//! rule exact for quadratics), and dense midpoint sampling whose own
//! convergence sets the tolerance.

mod common;

use common::{render, Setup};
use optistim::scene::EquirectMap;

/// The bilinear interpolant with wrap in x and clamp in y, written here.
fn bilinear(m: &EquirectMap, x: f64, y: f64) -> f64 {
    let (w, h) = (m.width as i64, m.height as i64);
    let y = y.clamp(0.0, (h - 1) as f64);
    let j = (y.floor() as i64).min(h - 2);
    let ty = y - j as f64;
    let i = x.floor() as i64;
    let tx = x - i as f64;
    let at = |i: i64, j: i64| m.data[(j * w + i.rem_euclid(w)) as usize] as f64;
    let top = at(i, j) * (1.0 - tx) + at(i + 1, j) * tx;
    let bottom = at(i, j + 1) * (1.0 - tx) + at(i + 1, j + 1) * tx;
    top * (1.0 - ty) + bottom * ty
}

type Pt = (f64, f64);

fn corners(c: Pt, a1: Pt, a2: Pt) -> Vec<Pt> {
    [(-0.5, -0.5), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)]
        .iter()
        .map(|&(s, t)| (c.0 + s * a1.0 + t * a2.0, c.1 + s * a1.1 + t * a2.1))
        .collect()
}

/// Sutherland–Hodgman: the part of `poly` with sign·(coord − at) ≤ 0.
fn clip(poly: &[Pt], axis: usize, at: f64, sign: f64) -> Vec<Pt> {
    let c = |p: Pt| if axis == 0 { p.0 } else { p.1 };
    let inside = |p: Pt| sign * (c(p) - at) <= 0.0;
    let mut out = Vec::new();
    for k in 0..poly.len() {
        let (p, q) = (poly[k], poly[(k + 1) % poly.len()]);
        if inside(p) {
            out.push(p);
        }
        if inside(p) != inside(q) {
            let t = (at - c(p)) / (c(q) - c(p));
            out.push((p.0 + t * (q.0 - p.0), p.1 + t * (q.1 - p.1)));
        }
    }
    out
}

/// Exact mean by cells: in each unit cell the clamped bilinear interpolant
/// is a polynomial of degree ≤ 2, integrated exactly on each triangle of
/// the clipped polygon by the edge-midpoint rule.
fn mean_by_cells(m: &EquirectMap, c: Pt, a1: Pt, a2: Pt) -> f64 {
    let poly = corners(c, a1, a2);
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for p in &poly {
        (x0, x1, y0, y1) = (x0.min(p.0), x1.max(p.0), y0.min(p.1), y1.max(p.1));
    }
    let (mut integral, mut area) = (0.0, 0.0);
    for i in x0.floor() as i64..=x1.floor() as i64 {
        let column = clip(&clip(&poly, 0, i as f64, -1.0), 0, (i + 1) as f64, 1.0);
        for j in y0.floor() as i64..=y1.floor() as i64 {
            let cell = clip(&clip(&column, 1, j as f64, -1.0), 1, (j + 1) as f64, 1.0);
            for k in 1..cell.len().saturating_sub(1) {
                let (p, q, r) = (cell[0], cell[k], cell[k + 1]);
                let a = 0.5 * ((q.0 - p.0) * (r.1 - p.1) - (r.0 - p.0) * (q.1 - p.1)).abs();
                let mid = |u: Pt, v: Pt| bilinear(m, 0.5 * (u.0 + v.0), 0.5 * (u.1 + v.1));
                integral += a * (mid(p, q) + mid(q, r) + mid(r, p)) / 3.0;
                area += a;
            }
        }
    }
    integral / area
}

/// Midpoint rule with n × n points in (s, t).
fn mean_by_points(m: &EquirectMap, c: Pt, a1: Pt, a2: Pt, n: usize) -> f64 {
    let mut sum = 0.0;
    for p in 0..n {
        let s = (p as f64 + 0.5) / n as f64 - 0.5;
        for q in 0..n {
            let t = (q as f64 + 0.5) / n as f64 - 0.5;
            sum += bilinear(m, c.0 + s * a1.0 + t * a2.0, c.1 + s * a1.1 + t * a2.1);
        }
    }
    sum / (n * n) as f64
}

fn checkerboard() -> EquirectMap {
    let (w, h) = (64, 32);
    let data = (0..w * h).map(|k| ((k % w + k / w) % 2) as f32).collect();
    EquirectMap::new(w, h, data)
}

fn lroc() -> EquirectMap {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/data/maps/lroc_color_poles_2k.tif"
    );
    let mut m = EquirectMap::load(std::path::Path::new(path)).expect("map");
    m.stretch(0.16, 0.40);
    m
}

/// Footprints (centre, a1, a2) on a map of the given size: sub-texel,
/// a few texels, rotated and sheared, across the seam, over both poles'
/// clamp, and large.
fn footprints(w: f64, h: f64) -> Vec<(&'static str, Pt, Pt, Pt)> {
    vec![
        ("sub-texel", (10.3, 7.6), (0.31, 0.05), (-0.07, 0.27)),
        ("axis box", (20.5, 9.25), (2.0, 0.0), (0.0, 1.5)),
        ("rotated", (33.71, 12.13), (2.3, 1.1), (-0.9, 1.9)),
        ("sheared", (5.2, 20.9), (3.7, 0.4), (2.9, 1.3)),
        ("seam", (w - 0.4, 15.2), (1.7, -0.6), (0.5, 2.2)),
        ("seam, left side", (0.2, 11.7), (-2.6, 0.3), (0.4, 1.1)),
        ("north pole", (17.0, 0.1), (9.0, 0.7), (-0.3, 1.4)),
        ("south pole", (40.0, h - 1.2), (1.1, 0.4), (0.6, 2.9)),
        ("large", (30.0, 14.0), (23.0, 6.0), (-4.0, 9.0)),
        (
            "nearly the map's width",
            (12.0, 16.0),
            (0.93 * w, 0.5),
            (0.2, 1.3),
        ),
    ]
}

fn check_map(m: &EquirectMap, label: &str) {
    let (w, h) = (m.width as f64, m.height as f64);
    for (name, c, a1, a2) in footprints(w, h) {
        let exact = m.parallelogram_mean(c.0, c.1, a1, a2);
        let cells = mean_by_cells(m, c, a1, a2);
        assert!(
            (exact - cells).abs() <= 1e-9 * cells.abs(),
            "{label} {name}: exact {exact} against cells {cells}"
        );
        // Dense sampling: the gap to the exact mean shrinks with n like the
        // sampling's own step (n to 2n), so it is the sampling's error.
        let coarse = mean_by_points(m, c, a1, a2, 256);
        let fine = mean_by_points(m, c, a1, a2, 512);
        let own = (fine - coarse).abs();
        assert!(
            (exact - fine).abs() <= 2.0 * own + 1e-12,
            "{label} {name}: exact {exact}, 512² points {fine} (step {own:e})"
        );
        // A footprint turned around (a1 → −a1) is the same set.
        let flipped = m.parallelogram_mean(c.0, c.1, (-a1.0, -a1.1), a2);
        assert!((flipped - exact).abs() <= 1e-12 * exact.abs().max(1.0));
    }
}

#[test]
fn exact_mean_matches_cell_integration_on_a_checkerboard() {
    check_map(&checkerboard(), "checkerboard");
}

#[test]
fn exact_mean_matches_cell_integration_on_the_lroc_map() {
    let m = lroc();
    check_map(&m, "lroc");
    // And footprints at the real map's own scale (2048 × 1024).
    let (w, h) = (m.width as f64, m.height as f64);
    for (name, c, a1, a2) in [
        ("pixel", (1033.4, 411.7), (2.4, 0.3), (-0.2, 2.6)),
        ("limb", (700.2, 520.9), (30.5, 4.0), (0.7, 2.5)),
        ("seam", (w - 0.7, 600.0), (3.1, 0.8), (-0.5, 2.4)),
        ("pole", (1500.0, 0.4), (180.0, 2.0), (1.0, 2.2)),
        ("south", (100.0, h - 0.9), (2.0, 0.2), (0.3, 1.9)),
    ] {
        let exact = m.parallelogram_mean(c.0, c.1, a1, a2);
        let cells = mean_by_cells(&m, c, a1, a2);
        assert!(
            (exact - cells).abs() <= 1e-9 * cells,
            "lroc {name}: exact {exact} against cells {cells}"
        );
    }
}

/// At a pole a footprint may span several turns of longitude; it is
/// narrowed to one turn, which for a box aligned with the rows changes
/// nothing: whole turns of a row average to its period mean.
#[test]
fn footprints_of_several_turns_are_bounded_and_exact_for_row_boxes() {
    for m in [checkerboard(), lroc()] {
        let (w, h) = (m.width as f64, m.height as f64);
        for (c, turns, tall) in [((5.3, 0.2), 3.0, 1.4), ((w - 1.0, h - 1.6), 40.0, 2.5)] {
            let a1 = (turns * w, 0.0);
            let a2 = (0.0, tall);
            let exact = m.parallelogram_mean(c.0, c.1, a1, a2);
            let cells = mean_by_cells(&m, c, (w, 0.0), a2);
            assert!(
                (exact - cells).abs() <= 1e-9 * cells.abs(),
                "{turns} turns: {exact} against {cells}"
            );
        }
    }
}

#[test]
fn constant_and_linear_maps_give_closed_forms() {
    let (w, h) = (64usize, 32usize);
    let constant = EquirectMap::new(w, h, vec![0.37; w * h]);
    for (name, c, a1, a2) in footprints(w as f64, h as f64) {
        let v = constant.parallelogram_mean(c.0, c.1, a1, a2);
        assert!((v - 0.37f32 as f64).abs() < 1e-12, "constant {name}: {v}");
    }
    // Linear in x (away from the seam) and in y (inside the clamp): the
    // mean over a centred parallelogram is the value at its centre.
    let ramp = EquirectMap::new(
        w,
        h,
        (0..w * h)
            .map(|k| (0.25 + 0.5 * (k % w) as f64 + 0.125 * (k / w) as f64) as f32)
            .collect(),
    );
    for (c, a1, a2) in [
        ((20.3, 10.6), (3.1, 0.7), (-0.4, 2.2)),
        ((40.0, 20.0), (0.2, 0.1), (0.05, 0.3)),
        ((31.5, 15.5), (12.0, 5.0), (-3.0, 8.0)),
    ] {
        let v = ramp.parallelogram_mean(c.0, c.1, a1, a2);
        let want = 0.25 + 0.5 * c.0 + 0.125 * c.1;
        assert!(
            (v - want).abs() < 1e-9 * want,
            "ramp at {c:?}: {v} against {want}"
        );
    }
}

/// A map that is the same everywhere renders as the same body without a
/// map, with the exact filter: every pixel within 1e-6 of the peak, and
/// the total flux within 1e-6. At the edge pixels this holds because a
/// mapped cap's PF is split as the unmapped cap's is, each pixel's share
/// weighted by the map relative to the cap's mean (before: split over
/// the k×k sub-footprints, 4.3e-4 of the peak away).
const EDGE_SPLIT: f64 = 1e-6;

#[test]
fn a_constant_map_renders_as_no_map() {
    let map = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/data/maps/lroc_color_poles_2k.tif"
    );
    for (interior, spacing) in [("pixels", 1), ("pixels", 4), ("caps", 4)] {
        let scene_with = |extra_body: String| {
            let mut setup = Setup::new(
                "{ model = \"oren_nayar\", albedo = 0.15, roughness = 0.3 }",
                40.0,
                60.0,
                200.0,
            );
            setup.extra_body = extra_body;
            setup.extra_render = format!(
                "map_filter = \"exact\"\ninterior = \"{interior}\"\nnode_spacing = {spacing}"
            );
            setup.scene()
        };
        let scene = scene_with(String::new());
        let width = scene.camera.pinhole.width;
        let plain = render(&scene).radiance;
        let mapped = render(&scene_with(format!(
            "albedo_map = {{ path = \"{map}\", min = 0.15, max = 0.15 }}"
        )))
        .radiance;
        let total = |v: &[f32]| v.iter().map(|&x| x as f64).sum::<f64>();
        let (a, b) = (total(&plain), total(&mapped));
        assert!((a - b).abs() < 1e-6 * a, "{interior}: flux {a} against {b}");
        if interior == "caps" {
            continue;
        }
        let peak = plain.iter().cloned().fold(0.0f32, f32::max) as f64;
        let lit = |i: i64, j: i64| {
            let (i, j) = (i.clamp(0, width as i64 - 1), j.clamp(0, width as i64 - 1));
            plain[j as usize * width + i as usize] > 0.0
        };
        let mut checked = 0;
        let mut edge_worst = 0.0f64;
        for (k, (&p, &m)) in plain.iter().zip(&mapped).enumerate() {
            let (i, j) = ((k % width) as i64, (k / width) as i64);
            let inside = (-3..=3).all(|di| (-3..=3).all(|dj| lit(i + di, j + dj)));
            if !inside {
                edge_worst = edge_worst.max((p as f64 - m as f64).abs() / peak);
            } else {
                checked += 1;
                let d = (p as f64 - m as f64).abs() / peak;
                assert!(
                    d < 1e-6,
                    "{interior} {spacing}: pixel {i},{j}: {p} against {m}"
                );
            }
        }
        assert!(checked > 10_000, "{checked} interior pixels");
        eprintln!("{interior} {spacing}: edge pixels within {edge_worst:.2e} of the peak");
        assert!(
            edge_worst < EDGE_SPLIT,
            "{interior} {spacing}: an edge pixel differs by {edge_worst:.2e} of the peak"
        );
    }
}

/// An unknown filter is refused with an error naming the key.
#[test]
fn an_unknown_map_filter_is_a_named_error() {
    let mut setup = Setup::new("{ model = \"lambert\", albedo = 0.12 }", 30.0, 60.0, 100.0);
    setup.extra_render = "map_filter = \"bicubic\"".into();
    let Err(err) = optistim::scene::Scene::from_toml(&setup.toml(), std::path::Path::new("t.toml"))
    else {
        panic!("an unknown map_filter was accepted");
    };
    assert!(err.to_string().contains("map_filter"), "{err}");
}

/// The LROC map on a Lambert sphere 200 px across at `alpha_deg`, with
/// `render` as its `[render]` table.
fn lroc_scene(alpha_deg: f64, render: &str) -> optistim::scene::Scene {
    let map = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/data/maps/lroc_color_poles_2k.tif"
    );
    let mut setup = Setup::new(
        "{ model = \"lambert\", albedo = 0.12 }",
        alpha_deg,
        60.0,
        200.0,
    );
    setup.extra_body = format!("albedo_map = {{ path = \"{map}\", min = 0.08, max = 0.25 }}");
    setup.extra_render = render.into();
    setup.scene()
}

/// The flux image of `scene` with its map filter and threshold replaced.
fn flux_with(
    scene: &optistim::scene::Scene,
    filter: optistim::render::MapFilter,
    threshold: f64,
) -> Vec<f32> {
    let mut settings = scene.render.clone();
    settings.map_filter = filter;
    settings.map_tolerance = threshold;
    settings.check().expect("valid settings");
    let mut renderer = optistim::render::Renderer::new(scene.camera.pinhole.clone());
    renderer.render_flux(&scene.body, &scene.state, &settings, None);
    renderer.flux().to_vec()
}

/// Threshold 0 refines every footprint (pixels and caps' parts) and so is
/// the exact filter; a threshold above k² (the largest range of k×k
/// non-negative samples over their mean) refines none and so is the
/// samples, bit for bit.
#[test]
fn adaptive_spans_samples_to_exact() {
    use optistim::render::MapFilter;
    let scene = lroc_scene(40.0, "interior = \"pixels\"");
    let exact = flux_with(&scene, MapFilter::Exact, 0.0);
    let samples = flux_with(&scene, MapFilter::Samples, 0.0);
    let peak = exact.iter().cloned().fold(0.0f32, f32::max) as f64;
    let all = flux_with(&scene, MapFilter::Adaptive, 0.0);
    let none = flux_with(&scene, MapFilter::Adaptive, 100.0);
    let differ = exact
        .iter()
        .zip(&samples)
        .filter(|(a, b)| (**a as f64 - **b as f64).abs() > 1e-6 * peak)
        .count();
    assert!(
        differ > 1000,
        "exact and samples differ at {differ} pixels only"
    );
    for (k, ((&a, &e), (&n, &s))) in all
        .iter()
        .zip(&exact)
        .zip(none.iter().zip(&samples))
        .enumerate()
    {
        assert!(
            (a as f64 - e as f64).abs() <= 1e-12 * peak,
            "pixel {k}: adaptive at 0 {a} against exact {e}"
        );
        assert_eq!(
            n.to_bits(),
            s.to_bits(),
            "pixel {k}: adaptive at 100 {n} against samples {s}"
        );
    }
}

/// A threshold outside [0, 100] (or NaN) is refused, naming the key; the
/// adaptive filter is accepted by name.
#[test]
fn map_tolerance_is_range_checked() {
    for bad in ["-0.1", "101.0", "nan", "inf"] {
        let mut setup = Setup::new("{ model = \"lambert\", albedo = 0.12 }", 30.0, 60.0, 100.0);
        setup.extra_render = format!("map_filter = \"adaptive\"\nmap_tolerance = {bad}");
        let Err(err) =
            optistim::scene::Scene::from_toml(&setup.toml(), std::path::Path::new("t.toml"))
        else {
            panic!("map_tolerance = {bad} was accepted");
        };
        assert!(err.to_string().contains("map_tolerance"), "{bad}: {err}");
    }
    let mut setup = Setup::new("{ model = \"lambert\", albedo = 0.12 }", 30.0, 60.0, 100.0);
    setup.extra_render = "map_filter = \"adaptive\"\nmap_tolerance = 0.05".into();
    let scene = optistim::scene::Scene::from_toml(&setup.toml(), std::path::Path::new("t.toml"))
        .expect("adaptive accepted");
    assert_eq!(
        scene.render.map_filter,
        optistim::render::MapFilter::Adaptive
    );
}

/// Brute force over one pixel, written here: n×n rays, each hitting the
/// sphere (ray–sphere in the world frame), the bilinear map at the hit
/// times the exact Lambert geometry. Returns the pixel's flux per unit
/// solar irradiance at 1 au, the same flux with the map's area-weighted
/// mean over the pixel's preimage in place of the map (the whole-pixel
/// product rule at its best: exact geometry, exact mean), and μ at the
/// pixel centre.
fn brute_force_pixel(
    scene: &optistim::scene::Scene,
    map: &EquirectMap,
    i: usize,
    j: usize,
    n: usize,
) -> (f64, f64, f64) {
    use glam::DVec3;
    let cam = &scene.camera.pinhole;
    let (c, q) = (scene.state.camera_position, scene.state.camera_attitude);
    let (r, sun) = (scene.body.radius, scene.state.sun_position);
    let au = common::AU;
    let hit = |u: f64, v: f64| {
        let d_cam = DVec3::new((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, 1.0);
        let d = (q * d_cam).normalize();
        let b = d.dot(c);
        let disc = b * b - (c.length_squared() - r * r);
        (disc > 0.0).then(|| {
            let p = c + d * (-b - disc.sqrt());
            (p, d, d_cam.length())
        })
    };
    let (mut flux, mut geometry, mut rho_area, mut area) = (0.0, 0.0, 0.0, 0.0);
    for a in 0..n {
        for b in 0..n {
            let u = i as f64 + (b as f64 + 0.5) / n as f64;
            let v = j as f64 + (a as f64 + 0.5) / n as f64;
            let Some((p, d, d_len)) = hit(u, v) else {
                continue;
            };
            let normal = p / r;
            let to_sun = sun - p;
            let mu0 = normal.dot(to_sun.normalize()).max(0.0);
            let omega = 1.0 / ((n * n) as f64 * cam.fx * cam.fy * d_len.powi(3));
            let g = mu0 / std::f64::consts::PI * au * au / to_sun.length_squared() * omega;
            let (lat, lon) = (normal.z.asin(), normal.y.atan2(normal.x));
            let x = (lon + std::f64::consts::PI) / std::f64::consts::TAU * map.width as f64 - 0.5;
            let y = (std::f64::consts::FRAC_PI_2 - lat) / std::f64::consts::PI * map.height as f64
                - 0.5;
            let rho = bilinear(map, x, y);
            let mu = -normal.dot(d);
            let da = omega * (p - c).length_squared() / mu;
            flux += g * rho;
            geometry += g;
            rho_area += rho * da;
            area += da;
        }
    }
    let centre = hit(i as f64 + 0.5, j as f64 + 0.5).expect("pixel centre on the sphere");
    let mu_centre = -(centre.0 / r).dot(centre.1);
    (flux, geometry * rho_area / area, mu_centre)
}

/// In the limb band (μ < 0.3 at interior pixels, where the rule takes 2×2
/// or 4×4 Gauss points) the exact filter gives each Gauss point its own
/// cell's mean: against 256² rays per pixel written here it is 5× closer
/// than the whole-pixel product rule even with exact geometry and the
/// exact mean (what the map's mean alone can reach there). Measured: RMS
/// 2.6e-4 against 3.45e-3; the renderer's whole-pixel mean gave 2.1e-3,
/// cells cut from the centre's footprint 1.6e-3.
#[test]
fn limb_band_cells_beat_the_whole_pixel_mean() {
    use optistim::render::MapFilter;
    let scene = lroc_scene(30.0, "interior = \"pixels\"\nnode_spacing = 1");
    let map = scene.body.albedo_map.as_ref().expect("map");
    let width = scene.camera.pinhole.width;
    let mut settings = scene.render.clone();
    settings.map_filter = MapFilter::Exact;
    let mut renderer = optistim::render::Renderer::new(scene.camera.pinhole.clone());
    renderer.render_flux(&scene.body, &scene.state, &settings, None);
    let flux = renderer.flux().to_vec();
    let (mut cells2, mut whole2, mut count) = (0.0, 0.0, 0);
    for j in 0..scene.camera.pinhole.height {
        for i in 0..width {
            if !renderer.is_interior_pixel(i, j) || (i + j) % 2 != 0 {
                continue;
            }
            // μ at the centre from a one-ray brute force (cheap filter).
            let (_, _, mu) = brute_force_pixel(&scene, map, i, j, 1);
            if mu >= 0.3 {
                continue;
            }
            let (reference, whole, _) = brute_force_pixel(&scene, map, i, j, 256);
            let got = flux[j * width + i] as f64;
            cells2 += ((got - reference) / reference).powi(2);
            whole2 += ((whole - reference) / reference).powi(2);
            count += 1;
        }
    }
    let (cells, whole) = (
        (cells2 / count as f64).sqrt(),
        (whole2 / count as f64).sqrt(),
    );
    eprintln!("{count} limb-band pixels: RMS error {cells:.2e} by cells, {whole:.2e} whole-pixel");
    assert!(count > 50, "{count} limb-band pixels");
    assert!(
        cells < 0.7 * whole,
        "cells {cells:.2e} against whole-pixel {whole:.2e}"
    );
}
