//! Finite-distance geometry against an independent quadrature over the
//! visible cap, written here and sharing nothing with the renderer.

mod common;
use common::*;
use glam::DVec3;
use std::f64::consts::PI;

/// E at the camera from a sphere at the origin: ∫ f_r μ0 F(p) μ/|c−p|² cosθ dS
/// over the visible cap, with F(p) the band irradiance at p. Gauss–Legendre
/// in the angle from the sub-camera point, midpoint in azimuth.
fn reference_irradiance(
    radius: f64,
    camera: DVec3,
    sun: DVec3,
    f_1au: f64,
    radiance_factor: impl Fn(f64, f64, f64) -> f64,
) -> f64 {
    let d = camera.length();
    let axis = camera / d;
    let e1 = axis.any_orthonormal_vector();
    let e2 = axis.cross(e1);
    let psi_max = (radius / d).acos();
    // 96-point Gauss–Legendre nodes by Newton iteration on P_n.
    let n = 96;
    let mut nodes = Vec::new();
    for k in 1..=n {
        let mut x = (PI * (k as f64 - 0.25) / (n as f64 + 0.5)).cos();
        for _ in 0..100 {
            let (mut p0, mut p1) = (1.0, x);
            for m in 2..=n {
                let p2 = ((2 * m - 1) as f64 * x * p1 - (m - 1) as f64 * p0) / m as f64;
                p0 = p1;
                p1 = p2;
            }
            let dp = n as f64 * (x * p1 - p0) / (x * x - 1.0);
            let dx = p1 / dp;
            x -= dx;
            if dx.abs() < 1e-16 {
                let w = 2.0 / ((1.0 - x * x) * dp * dp);
                nodes.push((x, w));
                break;
            }
        }
    }
    let n_az: usize = 6000;
    // Rings about the camera axis start (or stop) crossing the terminator at
    // ψ = |α − 90°|; split the Gauss–Legendre rule there.
    let alpha = axis.dot(sun.normalize()).clamp(-1.0, 1.0).acos();
    let kink = (alpha - PI / 2.0).abs();
    let mut pieces = vec![(0.0, psi_max)];
    if kink > 0.0 && kink < psi_max {
        pieces = vec![(0.0, kink), (kink, psi_max)];
    }
    let mut total = 0.0;
    for (a, b) in pieces {
        for &(x, w) in &nodes {
            let psi = a + 0.5 * (b - a) * (x + 1.0);
            let (sp, cp) = psi.sin_cos();
            let mut ring = 0.0;
            for k in 0..n_az {
                let beta = (k as f64 + 0.5) * 2.0 * PI / n_az as f64;
                let nrm = axis * cp + (e1 * beta.cos() + e2 * beta.sin()) * sp;
                let p = nrm * radius;
                let to_sun = sun - p;
                let to_cam = camera - p;
                let (ds, dc) = (to_sun.length(), to_cam.length());
                let (l, v) = (to_sun / ds, to_cam / dc);
                let mu0 = nrm.dot(l);
                let mu = nrm.dot(v);
                if mu0 <= 0.0 || mu <= 0.0 {
                    continue;
                }
                let f = f_1au * (AU / ds).powi(2);
                let cos_theta = (-to_cam / dc).dot(-axis);
                ring += radiance_factor(mu0, mu, l.dot(v)) * f * mu / (dc * dc) * cos_theta;
            }
            total += w * 0.5 * (b - a) * ring * 2.0 * PI / n_az as f64 * sp;
        }
    }
    total * radius * radius
}

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
            let reference = reference_irradiance(
                setup.radius,
                setup.camera_position(),
                setup.sun_position(),
                f_1au,
                f,
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
