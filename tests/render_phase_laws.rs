//! Disk-integrated phase laws: E = Σ L Ω cosθ from the radiance image must
//! match E_sun · p · Φ(α) · (R/d)² from closed forms and published values.

mod common;
use common::*;
use std::f64::consts::PI;

const PHASES: [f64; 7] = [0.0, 30.0, 60.0, 90.0, 120.0, 150.0, 170.0];

fn lambert_phi(a: f64) -> f64 {
    (a.sin() + (PI - a) * a.cos()) / PI
}

fn lommel_seeliger_phi(a: f64) -> f64 {
    if a == 0.0 {
        return 1.0;
    }
    1.0 - (a / 2.0).sin() * (a / 2.0).tan() * (1.0 / (a / 4.0).tan()).ln()
}

fn area_phi(a: f64) -> f64 {
    (1.0 + a.cos()) / 2.0
}

/// Relative error of the image irradiance against p·Φ(α).
fn phase_law_error(
    model: &str,
    geometry: &'static str,
    alpha_deg: f64,
    range_radii: f64,
    p: f64,
    phi: f64,
) -> f64 {
    let mut setup = Setup::new(model, alpha_deg, range_radii, 300.0);
    setup.geometry = geometry;
    let scene = setup.scene();
    let images = render(&scene);
    let e = irradiance_from_image(&scene, &images.radiance);
    let expected = sun_at_body(&scene, &images) * p * phi * (setup.radius / setup.range).powi(2);
    (e - expected) / expected
}

#[test]
fn lambert_lommel_seeliger_and_area_follow_their_phase_laws() {
    let rho = 0.3;
    for geometry in ["distant", "exact"] {
        for &deg in &PHASES {
            let a = deg.to_radians();
            let cases = [
                (
                    format!("{{ model = \"lambert\", albedo = {rho} }}"),
                    2.0 / 3.0 * rho,
                    lambert_phi(a),
                ),
                (
                    format!("{{ model = \"lommel_seeliger\", albedo = {rho} }}"),
                    rho,
                    lommel_seeliger_phi(a),
                ),
                (
                    format!("{{ model = \"area\", albedo = {rho} }}"),
                    rho / 2.0,
                    area_phi(a),
                ),
            ];
            for (model, p, phi) in cases {
                // d = 1e6 R: the finite-distance terms (≈ 6 R/d) stay below 1e-5.
                let err = phase_law_error(&model, geometry, deg, 1e6, p, phi);
                assert!(
                    err.abs() < 1e-4,
                    "{model} {geometry} α={deg}°: relative error {err:e}"
                );
            }
        }
    }
}

#[test]
fn full_oren_nayar_matches_published_phase_curve() {
    // σ = 0.3, ρ = 0.15: geometric albedo 0.106976 and normalised Φ values.
    let model = "{ model = \"oren_nayar\", albedo = 0.15, roughness = 0.3 }";
    let p = 0.106976;
    for (deg, phi) in [
        (0.0, 1.0),
        (30.0, 0.825745),
        (60.0, 0.526578),
        (90.0, 0.247121),
        (120.0, 0.073287),
    ] {
        for geometry in ["distant", "exact"] {
            let err = phase_law_error(model, geometry, deg, 1e6, p, phi);
            assert!(
                err.abs() < 1e-3,
                "Oren-Nayar {geometry} α={deg}°: relative error {err:e}"
            );
        }
    }
}

#[test]
fn phase_laws_hold_at_1e5_radii_in_distant_mode() {
    // The configuration: d = 1e5 R, narrow field, a few hundred px.
    for &deg in &PHASES {
        let a = deg.to_radians();
        let err = phase_law_error(
            "{ model = \"lambert\", albedo = 0.2 }",
            "distant",
            deg,
            1e5,
            0.2 * 2.0 / 3.0,
            lambert_phi(a),
        );
        assert!(err.abs() < 1e-4, "α={deg}°: {err:e}");
    }
}

#[test]
fn spectral_hapke_sub_bands_add_up_to_the_flat_band() {
    // A w(λ) table that is constant is "spectrally varying" to the planner,
    // so it is rendered in ~10 nm sub-bands; the sum over sub-bands must
    // equal the single-band render of the same constant w.
    let params = "b = 0.187, c = 0.273, theta_bar = 0.2321, h_s = 0.083, b_s0 = 1.0";
    let flat = format!("{{ model = \"hapke\", w = 0.526, {params} }}");
    let table = format!("{{ model = \"hapke\", w = [[400.0, 0.526], [900.0, 0.526]], {params} }}");
    let e = |model: &str| {
        let scene = Setup::new(model, 50.0, 1e4, 120.0).scene();
        let images = render(&scene);
        (
            irradiance_from_image(&scene, &images.radiance),
            images.summary.sub_bands,
            images.summary.total_electrons,
        )
    };
    let (e_flat, n_flat, el_flat) = e(&flat);
    let (e_table, n_table, el_table) = e(&table);
    assert_eq!(n_flat, 1);
    assert!(n_table >= 30, "{n_table} sub-bands");
    assert!(
        ((e_table - e_flat) / e_flat).abs() < 1e-6,
        "{e_table} vs {e_flat}"
    );
    assert!(
        ((el_table - el_flat) / el_flat).abs() < 1e-5,
        "{el_table} vs {el_flat}"
    );
}
