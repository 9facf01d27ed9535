//! Finite-distance geometry against an independent quadrature over the
//! visible cap, written here and sharing nothing with the renderer.

mod common;
use common::*;
use std::f64::consts::PI;

#[test]
fn close_range_irradiance_matches_independent_quadrature() {
    let rho = 0.3;
    let lambert = move |mu0: f64, _mu: f64, _cg: f64| rho / PI * mu0;
    let ls = move |mu0: f64, mu: f64, _cg: f64| 2.0 * rho / PI * mu0 / (mu0 + mu);
    for (range_radii, alpha) in [(3.0, 0.0), (3.0, 60.0), (1.5, 120.0), (10.0, 150.0)] {
        for (model, f) in [
            (
                format!("{{ model = \"lambert\", albedo = {rho} }}"),
                &lambert as &dyn Fn(f64, f64, f64) -> f64,
            ),
            (
                format!("{{ model = \"lommel_seeliger\", albedo = {rho} }}"),
                &ls,
            ),
        ] {
            let mut setup = Setup::new(&model, alpha, range_radii, 400.0);
            // Wide enough to hold the whole visible cap.
            setup.resolution = [520, 520];
            let scene = setup.scene();
            let images = render(&scene);
            let e = irradiance_from_image(&scene, &images.radiance);
            let f_1au = images.summary.band_irradiance_1au_w_m2;
            let reference = visible_cap_irradiance(
                setup.radius,
                setup.camera_position(),
                setup.sun_position(),
                f_1au,
                (96, 6000),
                |_, g| f(g.mu0, g.mu, g.cos_g),
            );
            let err = (e - reference) / reference;
            assert!(
                err.abs() < 1e-4,
                "{model} d={range_radii}R α={alpha}: {e} vs {reference} ({err:e})"
            );
        }
    }
}

#[test]
fn finite_distance_differs_from_the_far_field_limit_as_expected() {
    // At d = 3 R and α = 0 the exact irradiance exceeds the far-field law:
    // the renderer's two modes must bracket that difference, and the exact
    // mode must agree with the quadrature (tested above).
    let rho = 0.3;
    let model = format!("{{ model = \"lambert\", albedo = {rho} }}");
    let mut setup = Setup::new(&model, 0.0, 3.0, 400.0);
    setup.resolution = [520, 520];
    let exact = {
        let scene = setup.scene();
        irradiance_from_image(&scene, &render(&scene).radiance)
    };
    setup.geometry = "distant";
    let far = {
        let scene = setup.scene();
        irradiance_from_image(&scene, &render(&scene).radiance)
    };
    assert!(
        (exact - far).abs() / far > 1e-3,
        "modes must differ at 3 R: {exact} {far}"
    );
}
