//! Band-weighted outputs and the spectral path, against band integrals and
//! the Lambert phase law computed here: sparse response tables (boxcar,
//! triangle; photon- and energy-normalised) give their exact band
//! integrals, and a Lambert sphere whose albedo varies with λ conserves
//! energy sub-band by sub-band.

mod common;
use common::*;
use std::f64::consts::PI;

use optistim::radiometry::spectrum::band_integrals;

const H: f64 = 6.626_070_15e-34;
const C: f64 = 299_792_458.0;
const E_CHARGE: f64 = 1.602_176_634e-19;
const ALPHA_DEG: f64 = 40.0;
const RHO: f64 = 0.3;

/// The test scenes' Sun (5772 K blackbody, 1361 W/m²) [W m⁻² m⁻¹].
fn sun(l: f64) -> f64 {
    let (t, k) = (5772.0, 1.380_649e-23);
    let b = 2.0 * H * C * C / l.powi(5) / ((H * C / (l * k * t)).exp() - 1.0);
    PI * b * 1361.0 / (5.670_374_419e-8 * t.powi(4))
}

/// Composite Simpson on [a, b] with n (even) intervals.
fn simpson(a: f64, b: f64, n: usize, f: impl Fn(f64) -> f64) -> f64 {
    let h = (b - a) / n as f64;
    let mut s = f(a) + f(b);
    for i in 1..n {
        s += f(a + i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 };
    }
    s * h / 3.0
}

/// ∫ f over piecewise segments between `edges` (nm), each by Simpson.
fn piecewise(edges: &[f64], f: impl Fn(f64) -> f64) -> f64 {
    edges
        .windows(2)
        .map(|w| simpson(w[0] * 1e-9, w[1] * 1e-9, 2000, &f))
        .sum()
}

fn lambert_phi(a: f64) -> f64 {
    (a.sin() + (PI - a) * a.cos()) / PI
}

/// A Lambert sphere at 1e5 radii (distant geometry) seen through `camera`
/// extra keys, with `body` extra keys.
fn scene_with(camera: &str, body: &str, render: &str) -> (optistim::scene::Scene, Setup) {
    let mut setup = Setup::new(
        &format!("{{ model = \"lambert\", albedo = {RHO} }}"),
        ALPHA_DEG,
        1e5,
        120.0,
    );
    setup.geometry = "distant";
    setup.extra_body = body.into();
    setup.extra_render = render.into();
    let text = setup.toml().replace("band = [450e-9, 820e-9]", camera);
    let dir = std::env::temp_dir();
    let scene = optistim::scene::Scene::from_toml(&text, &dir.join("band-weighted.toml")).unwrap();
    (scene, setup)
}

/// E_sun · (2/3) · Φ(α) · (R/d)² per unit albedo factor.
fn geometry_factor(setup: &Setup) -> f64 {
    2.0 / 3.0 * RHO * lambert_phi(ALPHA_DEG.to_radians()) * (setup.radius / setup.range).powi(2)
}

#[test]
fn boxcar_and_triangular_responses_give_their_exact_band_integrals() {
    let dir = tempfile::tempdir().unwrap();
    let boxcar = dir.path().join("boxcar.csv");
    let triangle = dir.path().join("triangle.csv");
    std::fs::write(&boxcar, "wavelength_nm,value\n500,0.8\n600,0.8\n").unwrap();
    std::fs::write(&triangle, "wavelength_nm,value\n500,0\n550,0.9\n600,0\n").unwrap();
    // Simpson only samples [500, 600] nm: the boxcar is 0.8 there (a margin
    // keeps the last node, 600e-9 up to rounding, inside).
    let boxcar_qe = |l: f64| {
        if (499.9e-9..=600.1e-9).contains(&l) {
            0.8
        } else {
            0.0
        }
    };
    let triangle_qe = |l: f64| 0.9 * (1.0 - ((l * 1e9 - 550.0) / 50.0).abs()).max(0.0);
    let amps_per_watt = |l: f64| 0.25 * H * C / (l * E_CHARGE) * boxcar_qe(l) / 0.8;
    type Qe<'a> = &'a dyn Fn(f64) -> f64;
    let cases: [(String, Qe, &[f64]); 4] = [
        (
            format!("quantum_efficiency = {:?}", boxcar.to_str().unwrap()),
            &boxcar_qe,
            &[500.0, 600.0],
        ),
        (
            format!(
                "quantum_efficiency = {{ path = {:?}, normalisation = \"photon\" }}",
                triangle.to_str().unwrap()
            ),
            &triangle_qe,
            &[500.0, 550.0, 600.0],
        ),
        (
            format!("quantum_efficiency = {:?}", triangle.to_str().unwrap()),
            &triangle_qe,
            &[500.0, 550.0, 600.0],
        ),
        (
            // 0.25 A/W over 500–600 nm.
            {
                let p = dir.path().join("aw.csv");
                std::fs::write(&p, "wavelength_nm,a_per_w\n500,0.25\n600,0.25\n").unwrap();
                format!(
                    "quantum_efficiency = {{ path = {:?}, normalisation = \"energy\" }}",
                    p.to_str().unwrap()
                )
            },
            &amps_per_watt,
            &[500.0, 600.0],
        ),
    ];
    for (key, qe, edges) in cases {
        let camera = format!("band = [450e-9, 820e-9]\n{key}");
        let (scene, setup) = scene_with(&camera, "", "");
        let cam = &scene.camera;
        // The electron rate of the whole band, exactly.
        let got = band_integrals(
            &scene.sun,
            &cam.quantum_efficiency,
            &cam.transmission,
            cam.band,
            1,
        )[0]
        .electron_rate_1au;
        let photon_response = |l: f64| qe(l) * l / (H * C);
        let expected = piecewise(edges, |l| photon_response(l) * sun(l));
        assert!(
            (got / expected - 1.0).abs() < 1e-9,
            "{key}: {got} vs {expected}"
        );
        // The response-weighted mean irradiance at the pupil.
        let images = render(&scene);
        let s = &images.summary;
        let mean = piecewise(edges, |l| photon_response(l) * sun(l))
            / piecewise(edges, photon_response)
            * geometry_factor(&setup)
            * 1e-9;
        let err = s.response_weighted_irradiance_w_m2_nm / mean - 1.0;
        assert!(
            err.abs() < 2e-4,
            "{key}: {} vs {mean}",
            s.response_weighted_irradiance_w_m2_nm
        );
        // A flat body: the camera-effective radiance is the band radiance.
        for (a, b) in images.radiance.iter().zip(&images.radiance_effective) {
            assert!((a - b).abs() <= 2e-6 * a.abs().max(1e-30), "{a} vs {b}");
        }
    }
}

#[test]
fn spectral_lambert_sphere_follows_the_phase_law_per_sub_band() {
    // s(λ) linear between sub-band edges (10 nm from 450 nm): each sub-band
    // sees a linear albedo, which its irradiance-weighted centroid
    // integrates exactly, so the render must equal ∫ s E☉ dλ · (2/3) ρ Φ(α) (R/d)².
    let spectrum = "albedo_spectrum = [[450.0, 0.5], [640.0, 1.2], [820.0, 0.8]]";
    let s = |l: f64| {
        let nm = l * 1e9;
        if nm <= 640.0 {
            0.5 + 0.7 * (nm - 450.0) / 190.0
        } else {
            1.2 - 0.4 * (nm - 640.0) / 180.0
        }
    };
    for (band, render_keys) in [
        ([450.0, 820.0], "sub_bands = 37"),
        ([450.0, 460.0], ""),
        ([630.0, 650.0], "sub_bands = 2"),
        ([800.0, 820.0], ""),
    ] {
        let camera = format!("band = [{}e-9, {}e-9]", band[0], band[1]);
        let (scene, setup) = scene_with(&camera, spectrum, render_keys);
        let images = render(&scene);
        let sm = &images.summary;
        assert!(sm.sub_bands >= 1);
        let expected = piecewise(&[band[0], band[0].max(640.0).min(band[1]), band[1]], |l| {
            s(l) * sun(l)
        }) * geometry_factor(&setup);
        let err = sm.irradiance_at_pupil_w_m2 / expected - 1.0;
        assert!(
            err.abs() < 2e-4,
            "{band:?}: {} vs {expected} ({err:e})",
            sm.irradiance_at_pupil_w_m2
        );
    }
    // The camera-effective irradiance with a triangular QE: ∫E R dλ ∫E☉ / ∫E☉ R.
    let dir = tempfile::tempdir().unwrap();
    let tri = dir.path().join("tri.csv");
    std::fs::write(&tri, "wavelength_nm,qe\n450,0\n640,1\n820,0\n").unwrap();
    let qe = |l: f64| {
        (1.0 - ((l * 1e9 - 640.0) / if l * 1e9 < 640.0 { 190.0 } else { 180.0 }).abs()).max(0.0)
    };
    let camera = format!(
        "band = [450e-9, 820e-9]\nquantum_efficiency = {:?}",
        tri.to_str().unwrap()
    );
    let edges = [450.0, 640.0, 820.0];
    let r = |l: f64| qe(l) * l / (H * C);
    // Each sub-band takes the albedo at its solar-weighted centroid, not
    // at its response-weighted one: an O(Δλ²) error in the QE-weighted
    // outputs, ~3e-4 at 10 nm, which finer sub-bands remove.
    for (sub_bands, tolerance) in [(37, 1e-3), (370, 1e-5)] {
        let (scene, setup) = scene_with(&camera, spectrum, &format!("sub_bands = {sub_bands}"));
        let images = render(&scene);
        let e_r = piecewise(&edges, |l| s(l) * sun(l) * r(l)) * geometry_factor(&setup);
        let expected = e_r * piecewise(&edges, sun) / piecewise(&edges, |l| sun(l) * r(l));
        let got = images.summary.effective_irradiance_at_pupil_w_m2;
        assert!(
            (got / expected - 1.0).abs() < tolerance,
            "{sub_bands}: {got} vs {expected}"
        );
        let mean = e_r / piecewise(&edges, r) * 1e-9;
        let got = images.summary.response_weighted_irradiance_w_m2_nm;
        assert!(
            (got / mean - 1.0).abs() < tolerance,
            "{sub_bands}: {got} vs {mean}"
        );
    }
}
