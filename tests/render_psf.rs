//! `camera.psf` in the render: a body far smaller than a pixel, centred on
//! a pixel centre, is a point source, so the rendered electrons are its
//! total spread exactly as the Gaussian's pixel integrals (products of
//! error-function differences, written here) and the Airy pattern's
//! enclosed energy (1 − J0² − J1², written here); the PSF conserves the
//! frame's power.

mod common;
use common::*;
use optistim::scene::Scene;
use std::path::Path;

const LAMBERT: &str = "{ model = \"lambert\", albedo = 0.3 }";

/// The electrons of a sub-pixel body (0.2 px across) at the centre of a
/// 63 × 63 frame, rendered with `psf` (a TOML inline table) or without.
fn point_source(psf: Option<&str>) -> Vec<f64> {
    let mut setup = Setup::new(LAMBERT, 30.0, 1e4, 0.2);
    setup.resolution = [63, 63];
    let mut toml = setup.toml();
    if let Some(p) = psf {
        toml = toml.replacen("[camera]\n", &format!("[camera]\npsf = {p}\n"), 1);
    }
    let scene = Scene::from_toml(&toml, Path::new("psf-scene.toml")).unwrap();
    render(&scene).electrons.iter().map(|&e| e as f64).collect()
}

#[test]
fn a_point_source_takes_the_gaussians_pixel_integrals() {
    let sigma = 1.5;
    let sharp = point_source(None);
    let total: f64 = sharp.iter().sum();
    // All of it in the centre pixel without a PSF.
    assert!(sharp[31 * 63 + 31] / total > 0.999);
    let blurred = point_source(Some(&format!(
        "{{ model = \"gaussian\", sigma_px = {sigma} }}"
    )));
    let blurred_total: f64 = blurred.iter().sum();
    assert!(
        (blurred_total / total - 1.0).abs() < 1e-5,
        "power {blurred_total} vs {total}"
    );
    let phi = |x: f64| 0.5 * libm::erfc(-x / (sigma * std::f64::consts::SQRT_2));
    let span = |c: f64| phi(c + 0.5) - phi(c - 0.5);
    let peak = total * span(0.0) * span(0.0);
    let mut worst = 0.0f64;
    for y in 0..63 {
        for x in 0..63 {
            let exact = total * span(x as f64 - 31.0) * span(y as f64 - 31.0);
            worst = worst.max((blurred[y * 63 + x] - exact).abs() / peak);
        }
    }
    println!("gaussian: worst pixel difference {worst:.2e} of the peak");
    assert!(worst < 2e-3, "{worst}");
}

#[test]
fn a_point_source_encloses_the_airy_energy() {
    // The test camera: f/2.5, 10 µm pixels; at 8 µm wavelength λN = 2 px.
    let blurred = point_source(Some("{ model = \"airy\", wavelength = 8e-6 }"));
    let total: f64 = point_source(None).iter().sum();
    let s = 8e-6 * 2.5 / 10e-6;
    for r in [3.0f64, 5.0, 8.0] {
        let (mut inside, mut count) = (0.0, 0usize);
        for y in 0..63 {
            for x in 0..63 {
                if ((x as f64 - 31.0).powi(2) + (y as f64 - 31.0).powi(2)).sqrt() <= r {
                    inside += blurred[y * 63 + x];
                    count += 1;
                }
            }
        }
        let x = std::f64::consts::PI * (count as f64 / std::f64::consts::PI).sqrt() / s;
        let exact = 1.0 - libm::j0(x).powi(2) - libm::j1(x).powi(2);
        println!(
            "airy r = {r} px: {:.4} of the power, closed form {exact:.4}",
            inside / total
        );
        // The kernel is cut at 99.5 % of the energy and renormalised, and
        // the frame keeps what falls inside it.
        assert!((inside / total - exact).abs() < 0.01, "r = {r}");
    }
}

#[test]
fn a_bad_psf_is_a_one_line_error_naming_the_key() {
    let setup = Setup::new(LAMBERT, 30.0, 1e4, 10.0);
    for (psf, what) in [
        ("{ model = \"gaussian\", sigma_px = -1.0 }", "sigma_px"),
        ("{ model = \"gaussian\", sigma_px = nan }", "sigma_px"),
        ("{ model = \"airy\", wavelength = 0.0 }", "wavelength"),
        ("{ model = \"moffat\", beta = 2.0 }", "moffat"),
    ] {
        let toml = setup
            .toml()
            .replacen("[camera]\n", &format!("[camera]\npsf = {psf}\n"), 1);
        let e = Scene::from_toml(&toml, Path::new("psf-scene.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("psf") || e.contains(what), "{psf}: {e}");
        assert!(!e.contains('\n'), "{e}");
    }
}
