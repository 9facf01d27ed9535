//! Displacement and normal maps against closed-form consequences: a constant
//! height is a bigger sphere; a flat normal map changes nothing.

mod common;
use common::*;

fn irradiance(setup: &Setup) -> f64 {
    let scene = setup.scene();
    let images = render(&scene);
    assert!(images.radiance.iter().all(|v| v.is_finite() && *v >= 0.0));
    irradiance_from_image(&scene, &images.radiance)
}

#[test]
fn constant_displacement_scales_the_flux_as_the_radius_squared() {
    let dir = tempfile::tempdir().unwrap();
    let map = dir.path().join("height.tiff");
    // 0.25 map units × 40 m/unit = 10 m on a 1000 m body.
    optistim::render::output::write_f32_tiff(&map, 64, 32, &vec![0.25f32; 64 * 32]).unwrap();
    let model = "{ model = \"lambert\", albedo = 0.3 }";
    for alpha in [0.0, 60.0, 120.0] {
        let plain = Setup::new(model, alpha, 1e5, 200.0);
        let mut raised = Setup::new(model, alpha, 1e5, 200.0);
        raised.extra_body = format!(
            "displacement_map = {{ path = \"{}\", scale = 40.0 }}",
            map.display()
        );
        let ratio = irradiance(&raised) / irradiance(&plain);
        let expected = (1010.0f64 / 1000.0).powi(2);
        assert!(
            (ratio / expected - 1.0).abs() < 2e-4,
            "α={alpha}: {ratio} vs {expected}"
        );
    }
}

#[test]
fn a_flat_normal_map_leaves_the_image_unchanged() {
    let dir = tempfile::tempdir().unwrap();
    let map = dir.path().join("normals.png");
    // Tangent-space (0, 0, 1) in 16-bit: (32768, 32768, 65535) ≈ (1.5e-5, 1.5e-5, 1).
    let img = image::ImageBuffer::<image::Rgb<u16>, _>::from_fn(64, 32, |_, _| {
        image::Rgb([32768u16, 32768, 65535])
    });
    img.save(&map).unwrap();
    let model = "{ model = \"oren_nayar\", albedo = 0.15, roughness = 0.3 }";
    let plain = Setup::new(model, 45.0, 1e4, 150.0);
    let mut mapped = Setup::new(model, 45.0, 1e4, 150.0);
    mapped.extra_body = format!("normal_map = {{ path = \"{}\" }}", map.display());
    let ratio = irradiance(&mapped) / irradiance(&plain);
    assert!((ratio - 1.0).abs() < 1e-3, "{ratio}");
}
