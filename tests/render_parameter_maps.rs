//! Maps of reflectance parameters other than the albedo (`[body]
//! parameter_maps`): a constant map renders as the model with that value,
//! and a varying map matches a quadrature over the visible cap written
//! here, which evaluates the model point by point from the parameter's
//! formula (no map, no renderer).

mod common;
use common::*;
use glam::DVec3;
use optistim::radiometry::reflectance::{HapkeAlbedo, ReflectanceConfig};
use std::f64::consts::PI;
use std::path::Path;

/// A 16-bit map whose texel at body-fixed direction n holds `t(n)` ∈ [0, 1];
/// returns the smallest and largest value written (the map's own range,
/// which the loader stretches to [min, max]).
fn write_map(path: &Path, t: impl Fn(DVec3) -> f64) -> (f64, f64) {
    let (w, h) = (512u32, 256u32);
    let mut data = Vec::with_capacity((w * h) as usize);
    for row in 0..h {
        let lat = PI / 2.0 - (row as f64 + 0.5) / h as f64 * PI;
        for col in 0..w {
            let lon = (col as f64 + 0.5) / w as f64 * 2.0 * PI - PI;
            let n = DVec3::new(lat.cos() * lon.cos(), lat.cos() * lon.sin(), lat.sin());
            data.push((t(n).clamp(0.0, 1.0) * 65535.0).round() as u16);
        }
    }
    let lo = *data.iter().min().unwrap() as f64 / 65535.0;
    let hi = *data.iter().max().unwrap() as f64 / 65535.0;
    image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(w, h, data)
        .unwrap()
        .save(path)
        .unwrap();
    (lo, hi)
}

/// The parameter's pattern: east–west and north–south asymmetric, so a
/// mirrored, rolled or flipped map changes the disk's signal.
fn pattern(n: DVec3) -> f64 {
    (2.0 + n.y + 0.5 * n.z) / 3.5
}

/// `[body]` lines for one parameter map of `parameter` over [min, max].
fn map_entry(parameter: &str, path: &Path, min: f64, max: f64) -> String {
    format!(
        "parameter_maps = [{{ parameter = \"{parameter}\", path = \"{}\", min = {min}, max = {max} }}]",
        path.display()
    )
}

/// A varying map of Oren–Nayar's σ, and of Hapke's b and θ̄, against the
/// quadrature, at two phases; the same scene with the map's range collapsed
/// to its midpoint must differ, so the test sees the map.
#[test]
fn a_varying_parameter_map_matches_a_quadrature_written_here() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("parameter.png");
    let (t_lo, t_hi) = write_map(&path, pattern);
    // Hapke with b and θ̄ (the mapped one set to v).
    let hapke = |b: f64, theta_bar: f64| {
        format!(
            "{{ model = \"hapke\", w = 0.3, b = {b}, c = 0.3, theta_bar = {theta_bar}, h_s = 0.08, b_s0 = 1.0 }}"
        )
    };
    let cases = [
        ("oren_nayar", "roughness", 0.05, 0.9),
        ("hapke", "b", 0.1, 0.6),
        ("hapke", "theta_bar", 0.05, 0.6),
    ];
    for (model, parameter, p_lo, p_hi) in cases {
        let value_at = |n: DVec3| p_lo + (pattern(n) - t_lo) / (t_hi - t_lo) * (p_hi - p_lo);
        let config = |v: f64| match parameter {
            "roughness" => format!("{{ model = \"oren_nayar\", albedo = 0.2, roughness = {v} }}"),
            "b" => hapke(v, 0.35),
            _ => hapke(0.25, v),
        };
        let point_model = |v: f64| {
            let c = HapkeAlbedo::Constant;
            let (b, theta_bar) = if parameter == "b" {
                (v, 0.35)
            } else {
                (0.25, v)
            };
            match model {
                "oren_nayar" => ReflectanceConfig::OrenNayar {
                    albedo: 0.2,
                    roughness: v,
                },
                _ => ReflectanceConfig::Hapke {
                    w: c(0.3),
                    b: c(b),
                    c: c(0.3),
                    theta_bar,
                    h_s: c(0.08),
                    b_s0: c(1.0),
                    h_c: None,
                    b_c0: 0.0,
                    porosity_k: 1.0,
                },
            }
            .build()
            .unwrap()
        };
        for alpha in [30.0, 100.0] {
            let mut setup = Setup::new(&config(0.5 * (p_lo + p_hi)), alpha, 3.0, 300.0);
            setup.resolution = [400, 400];
            setup.extra_body = map_entry(parameter, &path, p_lo, p_hi);
            let scene = setup.scene();
            let images = render(&scene);
            let e = irradiance_from_image(&scene, &images.radiance);
            let albedo = if model == "hapke" { 0.3 } else { 0.2 };
            let reference = visible_cap_irradiance(
                setup.radius,
                setup.camera_position(),
                setup.sun_position(),
                images.summary.band_irradiance_1au_w_m2,
                (64, 3000),
                |n, g| point_model(value_at(n)).radiance_factor(g, albedo),
            );
            let err = e / reference - 1.0;
            // The map held at its midpoint: how much the map matters here.
            let mut flat = Setup::new(&config(0.5 * (p_lo + p_hi)), alpha, 3.0, 300.0);
            flat.resolution = [400, 400];
            let mid = 0.5 * (p_lo + p_hi);
            flat.extra_body = map_entry(parameter, &path, mid, mid);
            let flat_scene = flat.scene();
            let e_flat = irradiance_from_image(&flat_scene, &render(&flat_scene).radiance);
            eprintln!(
                "{model} {parameter} α {alpha}°: render/quadrature − 1 = {err:+.2e}; a flat map differs by {:+.2e}",
                e_flat / reference - 1.0
            );
            assert!(
                err.abs() < 3e-4,
                "{model} {parameter} α {alpha}°: {e} vs {reference}"
            );
            assert!(
                (e_flat / reference - 1.0).abs() > 30.0 * err.abs(),
                "{model} {parameter} α {alpha}°: the map barely matters ({e_flat} flat vs {e})"
            );
        }
    }
}

/// A map holding one value everywhere renders as the model with that value
/// (every pixel within 1e-6 of the peak), Oren–Nayar and Hapke.
#[test]
fn a_constant_parameter_map_renders_as_the_model_with_that_value() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("parameter.png");
    write_map(&path, pattern);
    let cases = [
        (
            "{ model = \"oren_nayar\", albedo = 0.2, roughness = 0.1 }",
            "{ model = \"oren_nayar\", albedo = 0.2, roughness = 0.5 }",
            "roughness",
            0.5,
        ),
        (
            "{ model = \"hapke\", w = 0.3, b = 0.2, c = 0.3, theta_bar = 0.35, h_s = 0.08, b_s0 = 1.0 }",
            "{ model = \"hapke\", w = 0.3, b = 0.45, c = 0.3, theta_bar = 0.35, h_s = 0.08, b_s0 = 1.0 }",
            "b",
            0.45,
        ),
    ];
    for (mapped_model, plain_model, parameter, value) in cases {
        let mut mapped = Setup::new(mapped_model, 50.0, 20.0, 150.0);
        mapped.extra_body = map_entry(parameter, &path, value, value);
        // The map makes interior pixels skip the node lattice: compare with
        // every pixel evaluated directly.
        mapped.extra_render = "node_spacing = 1".into();
        let mut plain = Setup::new(plain_model, 50.0, 20.0, 150.0);
        plain.extra_render = "node_spacing = 1".into();
        let a = render(&mapped.scene()).radiance;
        let b = render(&plain.scene()).radiance;
        let peak = b.iter().cloned().fold(0.0f32, f32::max) as f64;
        assert!(peak > 0.0);
        let worst = a
            .iter()
            .zip(&b)
            .map(|(&x, &y)| (x as f64 - y as f64).abs() / peak)
            .fold(0.0f64, f64::max);
        assert!(
            worst < 1e-6,
            "{parameter}: a pixel differs by {worst:e} of the peak"
        );
    }
}
