//! Geometry of the rendered image and the hard cases: limb position,
//! off-axis bodies, partial frames, bodies behind the camera, extreme
//! phases, ranges and apparent sizes.

mod common;
use common::*;
use glam::DVec3;

const AREA: &str = "{ model = \"area\", albedo = 0.3 }";
const LAMBERT: &str = "{ model = \"lambert\", albedo = 0.3 }";

fn assert_sane(radiance: &[f32], what: &str) {
    for (k, &v) in radiance.iter().enumerate() {
        assert!(v.is_finite() && v >= 0.0, "{what}: pixel {k} = {v}");
    }
}

#[test]
fn limb_lies_at_the_angular_radius() {
    // Area model at zero phase: the disk has uniform radiance, so each pixel
    // holds L0 × its covered fraction and the covered area measures the limb.
    for range_radii in [3.0, 20.0, 1e4] {
        let setup = Setup::new(AREA, 0.0, range_radii, 200.0);
        let scene = setup.scene();
        let images = render(&scene);
        assert_sane(&images.radiance, "limb");
        let pin = &scene.camera.pinhole;
        let centre = images.radiance[(pin.height / 2) * pin.width + pin.width / 2] as f64;
        let mut area = 0.0;
        let (mut mx, mut my) = (0.0, 0.0);
        for j in 0..pin.height {
            for i in 0..pin.width {
                let f = images.radiance[j * pin.width + i] as f64 / centre;
                area += f;
                mx += f * (i as f64 + 0.5);
                my += f * (j as f64 + 0.5);
            }
        }
        // Limb circle on the image plane: radius f·tan(asin(R/d)).
        let expected = pin.fx * (1.0 / range_radii).asin().tan();
        let measured = (area / std::f64::consts::PI).sqrt();
        assert!(
            (measured - expected).abs() < 0.1,
            "d={range_radii}R: {measured} vs {expected} px"
        );
        assert!((mx / area - pin.cx).abs() < 0.05 && (my / area - pin.cy).abs() < 0.05);
    }
}

#[test]
fn off_axis_body_keeps_its_irradiance() {
    let mut setup = Setup::new(LAMBERT, 40.0, 1e4, 150.0);
    setup.resolution = [1400, 400];
    let on_axis = {
        let scene = setup.scene();
        irradiance_from_image(&scene, &render(&scene).radiance)
    };
    setup.off_axis_deg = 4.0;
    setup.f_px = 150.0 / 2.0 / (1e-4f64).asin().tan();
    // 4° off-axis must stay in the frame: widen the field.
    let fov_half = (setup.resolution[0] as f64 / 2.0 / setup.f_px)
        .atan()
        .to_degrees();
    assert!(fov_half < 4.0, "the test needs a narrow camera: {fov_half}");
    setup.f_px = setup.resolution[0] as f64 / 2.0 / 5f64.to_radians().tan();
    let e_on = {
        let mut s = Setup::new(LAMBERT, 40.0, 1e4, 1.0);
        s.resolution = setup.resolution;
        s.f_px = setup.f_px;
        let scene = s.scene();
        irradiance_from_image(&scene, &render(&scene).radiance)
    };
    let scene = setup.scene();
    let images = render(&scene);
    assert_sane(&images.radiance, "off-axis");
    let e_off = irradiance_from_image(&scene, &images.radiance);
    assert!(((e_off - e_on) / e_on).abs() < 1e-4, "{e_off} vs {e_on}");
    assert!(on_axis > 0.0);
}

#[test]
fn body_half_outside_the_frame_keeps_the_inside_share() {
    // Uniform disk (Area, α=0) centred on the right image edge: exactly half
    // of its flux is inside.
    let mut setup = Setup::new(AREA, 0.0, 1e4, 100.0);
    setup.resolution = [120, 120];
    let full = {
        let scene = setup.scene();
        irradiance_from_image(&scene, &render(&scene).radiance)
    };
    // Turn the camera so the body centre lands on x = width (the edge).
    setup.off_axis_deg = -(60.0 / setup.f_px).atan().to_degrees();
    let scene = setup.scene();
    let images = render(&scene);
    assert_sane(&images.radiance, "half out");
    let half = irradiance_from_image(&scene, &images.radiance);
    assert!((half / full - 0.5).abs() < 2e-3, "{}", half / full);
}

#[test]
fn body_behind_the_camera_draws_nothing() {
    let mut setup = Setup::new(LAMBERT, 30.0, 10.0, 100.0);
    setup.off_axis_deg = 180.0;
    let scene = setup.scene();
    let images = render(&scene);
    assert!(images.radiance.iter().all(|&v| v == 0.0));
    assert_eq!(images.summary.max_dn, 0);
}

#[test]
fn hard_cases_stay_finite_and_non_negative() {
    let on = "{ model = \"oren_nayar\", albedo = 0.15, roughness = 0.3 }";
    // Phase 179.9°.
    let scene = Setup::new(LAMBERT, 179.9, 100.0, 200.0).scene();
    assert_sane(&render(&scene).radiance, "phase 179.9");
    let scene = Setup::new(on, 179.9, 100.0, 200.0).scene();
    assert_sane(&render(&scene).radiance, "phase 179.9 ON");
    // Terminator exactly through pixel centres: α = 90° puts it on the
    // central column, which holds pixel centres with an even... odd width.
    let mut s = Setup::new(LAMBERT, 90.0, 1e4, 101.0);
    s.resolution = [131, 131];
    let scene = s.scene();
    assert_sane(&render(&scene).radiance, "terminator");
    // Camera at 1.001 R.
    let mut s = Setup::new(on, 30.0, 1.001, 100.0);
    s.f_px = 500.0;
    s.resolution = [256, 256];
    let scene = s.scene();
    let images = render(&scene);
    assert_sane(&images.radiance, "1.001 R");
    assert!(
        images.radiance.iter().any(|&v| v > 0.0),
        "ground fills the view"
    );
    // A body 10 000 px wide, seen partly.
    let mut s = Setup::new(on, 60.0, 50.0, 10_000.0);
    s.resolution = [512, 512];
    let scene = s.scene();
    let images = render(&scene);
    assert_sane(&images.radiance, "10 000 px");
    assert!(images.radiance.iter().filter(|&&v| v > 0.0).count() > 100_000);
}

#[test]
fn mars_at_2_5_au_as_a_tenth_of_a_pixel_keeps_its_exact_flux() {
    // Lambert Mars at 2.5 au from the camera, 0.1 px across; the Sun at
    // 1.52 au from Mars. E must match p Φ(α) (R/d)² E_sun.
    let radius = 3389.5e3;
    let range = 2.5 * AU;
    let alpha: f64 = 20.0;
    let mut s = Setup::new(LAMBERT, alpha, range / radius, 0.1);
    s.radius = radius;
    s.range = range;
    s.sun_au = 1.52;
    s.resolution = [32, 32];
    let scene = s.scene();
    let images = render(&scene);
    assert_sane(&images.radiance, "Mars");
    let lit: Vec<_> = images.radiance.iter().filter(|&&v| v > 0.0).collect();
    assert!(!lit.is_empty() && lit.len() <= 4, "{} pixels", lit.len());
    let a = alpha.to_radians();
    let phi = (a.sin() + (std::f64::consts::PI - a) * a.cos()) / std::f64::consts::PI;
    let expected = sun_at_body(&scene, &images) * 0.2 * phi * (radius / range).powi(2);
    let e = irradiance_from_image(&scene, &images.radiance);
    assert!(
        ((e - expected) / expected).abs() < 1e-4,
        "{e} vs {expected}"
    );
}

#[test]
fn electrons_carry_the_cos4_falloff_and_radiance_does_not() {
    // A uniform disk (Area, α=0) seen on-axis and 3° off-axis: radiance is
    // the same; electrons per pixel scale as Ω·cosθ ≈ cos⁴θ.
    let f_px = 350.0 / 4f64.to_radians().tan();
    // Range giving a 40 px disk at that focal length.
    let range = 1.0 / (20.0 / f_px).atan().sin();
    let mut s = Setup::new(AREA, 0.0, range, 40.0);
    s.resolution = [700, 64];
    s.f_px = f_px;
    let centre_pixel = |s: &Setup| {
        let scene = s.scene();
        let im = render(&scene);
        let pin = &scene.camera.pinhole;
        // The pixel holding the body centre's image.
        let st = &scene.state;
        let c = st.camera_attitude.inverse() * (st.body_position - st.camera_position);
        let (u, v) = (pin.fx * c.x / c.z + pin.cx, pin.fy * c.y / c.z + pin.cy);
        let (i, j) = (u.floor() as usize, v.floor() as usize);
        let k = j * pin.width + i;
        let dir = DVec3::new(
            (i as f64 + 0.5 - pin.cx) / pin.fx,
            (j as f64 + 0.5 - pin.cy) / pin.fy,
            1.0,
        )
        .normalize();
        (im.radiance[k] as f64, im.electrons[k] as f64, dir.z)
    };
    let (l0, e0, c0) = centre_pixel(&s);
    s.off_axis_deg = 3.0;
    let (l1, e1, c1) = centre_pixel(&s);
    assert!(((l1 - l0) / l0).abs() < 1e-4, "radiance {l0} vs {l1}");
    let expected = (c1 / c0).powi(4);
    assert!(
        ((e1 / e0) / expected - 1.0).abs() < 1e-3,
        "{} vs {}",
        e1 / e0,
        expected
    );
    assert!(c1 < 0.999);
}
