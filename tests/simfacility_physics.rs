//! The simulated facility against references written here: the closed-form
//! DN of a uniform screen, the collimator + pinhole geometry evaluated
//! directly, a dot's image position, the noise statistics of a flat patch,
//! and seed reproducibility.

use optistim::facility::display::Display;
use optistim::facility::lut::encode_grey;
use optistim::instruments::{Camera, CaptureRequest, SpotMeter};
use optistim::simfacility::SimFacility;

mod common;
use common::simfacility::{gaussian_dot_frame, show_uniform as uniform, SimToml};

const H: f64 = 6.626_070_15e-34;
const C: f64 = 299_792_458.0;
const KB: f64 = 1.380_649e-23;

/// The small facility (every noise and non-uniformity off) with extra
/// collimator and camera keys.
fn keys(extra_collimator: &str, extra_camera: &str) -> SimToml {
    SimToml::quiet()
        .with("collimator", extra_collimator)
        .with("camera", extra_camera)
}

fn facility(extra_collimator: &str, extra_camera: &str) -> SimFacility {
    keys(extra_collimator, extra_camera).facility()
}

fn capture(f: &SimFacility, exposure: f64) -> Vec<f32> {
    f.camera()
        .capture(&CaptureRequest {
            pattern: "p".into(),
            exposure_s: exposure,
            shutter: Default::default(),
        })
        .unwrap()
        .data
}

/// Solid angle of [x0, x1] × [y0, y1] on the plane z = 1.
fn rect_solid_angle(x0: f64, x1: f64, y0: f64, y1: f64) -> f64 {
    let f = |x: f64, y: f64| (x * y / (1.0 + x * x + y * y).sqrt()).atan();
    f(x1, y1) - f(x0, y1) - f(x1, y0) + f(x0, y0)
}

/// Total spectral radiance of `level` per metre of the flat 380–780 nm
/// spectrum: max × (b + (1 − b) x^γ) / 400 nm.
fn spectral_level(level: f64) -> f64 {
    let x = level / 255.0;
    2.0 * (0.01 + 0.99 * x.powf(2.2)) / 400e-9
}

/// ∫ λ / (h c) dλ over the camera band (450–820 nm) ∩ the flat spectrum
/// (380–780 nm): electrons per joule-metre with QE = T = 1.
fn photons_per_flat() -> f64 {
    (780e-9f64.powi(2) - 450e-9f64.powi(2)) / (2.0 * H * C)
}

#[test]
fn uniform_screen_gives_closed_form_dn() {
    let f = facility("", "");
    let area = std::f64::consts::PI * (0.05f64 / 4.0).powi(2) / 4.0;
    for level in [0u32, 37, 128, 255] {
        uniform(&f, level);
        let dn = capture(&f, 0.01);
        for (i, j) in [(0usize, 0usize), (20, 15), (39, 29), (7, 22)] {
            let x0 = (i as f64 - 20.0) / 4000.0;
            let y0 = (j as f64 - 15.0) / 4000.0;
            let omega = rect_solid_angle(x0, x0 + 1.0 / 4000.0, y0, y0 + 1.0 / 4000.0);
            let (xc, yc) = (x0 + 0.5 / 4000.0, y0 + 0.5 / 4000.0);
            let cos = 1.0 / (1.0 + xc * xc + yc * yc).sqrt();
            let electrons =
                0.01 * 0.8 * area * omega * cos * spectral_level(level as f64) * photons_per_flat();
            let expected = (electrons * 0.05).round();
            let got = dn[j * 40 + i] as f64;
            assert!(
                (got - expected).abs() <= 1.0,
                "level {level} pixel ({i}, {j}): {got} DN, closed form {expected}"
            );
        }
    }
}

/// Band integral of a Planck curve at 5772 K by Simpson's rule, weighted by
/// `w(λ)`.
fn planck_band(w: impl Fn(f64) -> f64) -> f64 {
    let n = 20_000;
    let (lo, hi) = (450e-9, 820e-9);
    let h = (hi - lo) / n as f64;
    let planck = |l: f64| 1.0 / (l.powi(5) * ((H * C / (l * KB * 5772.0)).exp() - 1.0));
    (0..=n)
        .map(|k| {
            let l = lo + k as f64 * h;
            let c = if k == 0 || k == n {
                1.0
            } else if k % 2 == 1 {
                4.0
            } else {
                2.0
            };
            c * planck(l) * w(l)
        })
        .sum::<f64>()
        * h
        / 3.0
}

#[test]
fn camera_effective_radiance_matches_the_convention() {
    // L_eff = ∫ S R dλ · ∫ E☉ / ∫ E☉ R, R = λ / hc here (QE = T = 1).
    let f = facility("", "");
    let sun_ratio = planck_band(|_| 1.0) / planck_band(|l| l / (H * C));
    for level in [0usize, 100, 255] {
        let expected = spectral_level(level as f64) * photons_per_flat() * sun_ratio;
        let got = f.true_camera_effective_radiance(level, (32.0, 24.0));
        assert!(
            (got / expected - 1.0).abs() < 1e-6,
            "level {level}: {got} vs {expected}"
        );
    }
}

/// The model written out: screen (u, v) → camera tan, for a collimator
/// with focal length 0.5 m, 0.1 mm pixels, k1, offset and rotation.
fn direct_geometry(u: f64, v: f64, k1: f64, off: (f64, f64), rot: f64) -> (f64, f64) {
    let f_px = 0.5 / 1.0e-4;
    let a = (u - 32.0 - off.0) / f_px;
    let b = (v - 24.0 - off.1) / f_px;
    let k = 1.0 + k1 * (a * a + b * b);
    let (a, b) = (a * k, b * k);
    (a * rot.cos() - b * rot.sin(), a * rot.sin() + b * rot.cos())
}

const MISALIGNED: &str = "k1 = 0.8\noffset_px = [1.5, -2.25]\nrotation = 0.01";

#[test]
fn true_geometry_is_the_collimator_and_pinhole_model() {
    let f = facility(MISALIGNED, "");
    for (u, v) in [(0.0, 0.0), (32.0, 24.0), (63.5, 10.25), (5.0, 47.0)] {
        let (tx, ty) = f.true_geometry(u, v);
        let (ex, ey) = direct_geometry(u, v, 0.8, (1.5, -2.25), 0.01);
        assert!(
            (tx - ex).abs() < 1e-12 && (ty - ey).abs() < 1e-12,
            "({u}, {v}): ({tx}, {ty}) vs ({ex}, {ey})"
        );
    }
}

#[test]
fn a_dot_lands_where_the_projection_predicts() {
    let camera_distortion = "k1 = -0.3\nk2 = 0.1\np1 = 0.001\np2 = -0.0005\nsupersample = 5";
    let f = facility(MISALIGNED, camera_distortion);
    let (w, h) = f.display().size();
    for (du, dv) in [(30usize, 20usize), (40, 30), (22, 14)] {
        // A Gaussian blob (σ = 2 screen px, radiance above black ∝ the
        // Gaussian) centred on the pixel corner (du, dv): well sampled, so
        // its centroid is unbiased by the pixel grid.
        let frame = gaussian_dot_frame(w, h, (du, dv));
        f.display().present(&frame).unwrap();
        let dn = capture(&f, 0.01);
        let bg = {
            uniform(&f, 0);
            capture(&f, 0.01)
        };
        let (mut sx, mut sy, mut s) = (0.0, 0.0, 0.0);
        for (k, (&a, &b)) in dn.iter().zip(&bg).enumerate() {
            let v = (a - b) as f64;
            sx += v * ((k % 40) as f64 + 0.5);
            sy += v * ((k / 40) as f64 + 0.5);
            s += v;
        }
        let (cu, cv) = (sx / s, sy / s);
        // Predicted: the test's geometry, then OpenCV's distortion and K.
        let (x, y) = direct_geometry(du as f64, dv as f64, 0.8, (1.5, -2.25), 0.01);
        let r2 = x * x + y * y;
        let radial = 1.0 - 0.3 * r2 + 0.1 * r2 * r2;
        let xd = x * radial + 2.0 * 0.001 * x * y - 0.0005 * (r2 + 2.0 * x * x);
        let yd = y * radial + 0.001 * (r2 + 2.0 * y * y) + 2.0 * -0.0005 * x * y;
        let (pu, pv) = (4000.0 * xd + 20.0, 4000.0 * yd + 15.0);
        assert!(
            (cu - pu).abs() < 0.02 && (cv - pv).abs() < 0.02,
            "dot at ({du}, {dv}): centroid ({cu:.4}, {cv:.4}), predicted ({pu:.4}, {pv:.4})"
        );
    }
}

#[test]
fn flat_patch_noise_is_poisson_plus_read_noise() {
    // Same facility with noise on; the noise-free mean comes from a
    // noise-free twin (the closed form is checked above).
    let noisy = "shot_noise = true\nread_noise = 12.0\ndark_current = 3000.0\nbias_dn = 100.0";
    let clean = facility("", "bias_dn = 100.0\ndark_current = 3000.0");
    let f = facility("", noisy);
    uniform(&clean, 90);
    let reference = capture(&clean, 0.01);
    uniform(&f, 90);
    let (mut n, mut sum, mut sum2, mut expected_var) = (0.0, 0.0, 0.0, 0.0);
    for _ in 0..12 {
        let dn = capture(&f, 0.01);
        for (k, (&d, &r)) in dn.iter().zip(&reference).enumerate() {
            let (i, j) = (k % 40, k / 40);
            if !(2..38).contains(&i) || !(2..28).contains(&j) {
                continue;
            }
            // Mean electrons (signal + dark) of this pixel, from the clean DN.
            let e = (r as f64 - 100.0) / 0.05;
            let x = d as f64 - r as f64;
            n += 1.0;
            sum += x;
            sum2 += x * x;
            expected_var += 0.05f64.powi(2) * (e + 144.0) + 1.0 / 12.0;
        }
    }
    let mean = sum / n;
    let var = sum2 / n - mean * mean;
    let expected_var = expected_var / n;
    // Sampling error of the variance: sqrt(2 / n) ≈ 0.8 %; of the mean:
    // sqrt(var / n); the clean reference is itself rounded (±0.5 DN).
    assert!(
        mean.abs() < 4.0 * (var / n).sqrt() + 0.3,
        "mean offset {mean}"
    );
    assert!(
        (var / expected_var - 1.0).abs() < 0.05,
        "variance {var:.2} DN², Poisson + read model {expected_var:.2}"
    );
}

#[test]
fn same_seed_same_frames_other_seed_other_frames() {
    let noisy = "shot_noise = true\nread_noise = 5.0\nprnu = 0.01";
    let a = facility("", noisy);
    let b = facility("", noisy);
    for f in [&a, &b] {
        uniform(f, 200);
    }
    let (a1, a2) = (capture(&a, 0.01), capture(&a, 0.01));
    let (b1, b2) = (capture(&b, 0.01), capture(&b, 0.01));
    assert_eq!(a1, b1);
    assert_eq!(a2, b2);
    assert_ne!(a1, a2, "two captures must have independent noise");
    let c = keys("", noisy).seed(8).facility();
    uniform(&c, 200);
    assert_ne!(capture(&c, 0.01), a1);
    assert_ne!(c.camera_flat(), a.camera_flat());
    let mut m1 = a.meter();
    let mut m2 = b.meter();
    assert_eq!(m1.measure().unwrap(), m2.measure().unwrap());
}

#[test]
fn meter_reads_the_band_radiance_of_its_spot() {
    // A flat radiometer over 380–780 nm sees all of a flat 380–780 nm
    // spectrum: the true curve's total radiance, max (b + (1 − b) x^γ).
    let f = facility("", "");
    for level in [0u32, 64, 255] {
        uniform(&f, level);
        let r = f.meter().measure().unwrap();
        let x = level as f64 / 255.0;
        let expected = 2.0 * (0.01 + 0.99 * x.powf(2.2));
        assert!(
            (r.value / expected - 1.0).abs() < 1e-9,
            "{level}: {}",
            r.value
        );
    }
}

#[test]
fn long_exposure_averages_the_frames_shown() {
    // 60 Hz: a 2-refresh exposure after frames at levels 255 then 0
    // averages the two; an exposure inside one refresh sees the last only.
    let f = facility("", "");
    let mut d = f.display();
    let (w, h) = d.size();
    d.present(&vec![encode_grey(255, 8); w * h]).unwrap();
    d.present(&vec![encode_grey(0, 8); w * h]).unwrap();
    let both = f.capture_last(2.0 / 60.0).unwrap().data;
    let last = f.capture_last(1.0 / 60.0).unwrap().data;
    uniform(&f, 255);
    let white = f.capture_last(2.0 / 60.0).unwrap().data; // 255 and 0 again
    let k = 15 * 40 + 20;
    let white_alone = {
        // The 255 frame alone over one refresh, scaled to two.
        let g = facility("", "");
        uniform(&g, 255);
        g.capture_last(1.0 / 60.0).unwrap().data[k] as f64 * 2.0
    };
    let black2 = last[k] as f64 * 2.0;
    let expected = 0.5 * (white_alone + black2);
    assert!(
        (both[k] as f64 - expected).abs() <= 2.0,
        "{} vs {expected}",
        both[k]
    );
    assert!((white[k] as f64 - expected).abs() <= 2.0);
}

#[test]
fn camera_files_a_campaign_gets() {
    let f = facility("", "vignetting = 0.1\nprnu = 0.02\nk1 = -0.2\np2 = 0.001");
    let dir = tempfile::tempdir().unwrap();
    // Intrinsics: OpenCV's convention, pixel centres at integers.
    let path = dir.path().join("intrinsics.toml");
    f.write_camera_intrinsics(&path).unwrap();
    let t: toml::Table = toml::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    let get = |k: &str| t[k].as_float().unwrap();
    assert_eq!(
        [
            get("fx"),
            get("fy"),
            get("cx"),
            get("cy"),
            get("k1"),
            get("p2")
        ],
        [4000.0, 4000.0, 19.5, 14.5, -0.2, 0.001]
    );
    // The camera's own flat, as a Gray32Float TIFF of the camera's size.
    let tiff = dir.path().join("camera_flat.tif");
    f.write_camera_flat(&tiff).unwrap();
    let flat = optistim::facility::lut::FlatField::load(&tiff, (40, 30)).unwrap();
    let own = f.camera_flat();
    assert_eq!(flat.gains(), own.as_slice());
    // Vignetting 1 − 0.1 r² / r²_corner times PRNU of 2 % rms: divide the
    // vignetting out, the rest has mean 1 and rms 0.02.
    let corner2 = 20.0f64.powi(2) + 15.0f64.powi(2);
    let prnu: Vec<f64> = own
        .iter()
        .enumerate()
        .map(|(k, &g)| {
            let (x, y) = ((k % 40) as f64 + 0.5 - 20.0, (k / 40) as f64 + 0.5 - 15.0);
            g as f64 / (1.0 - 0.1 * (x * x + y * y) / corner2)
        })
        .collect();
    let n = prnu.len() as f64;
    let mean = prnu.iter().sum::<f64>() / n;
    let rms = (prnu.iter().map(|p| (p - mean).powi(2)).sum::<f64>() / n).sqrt();
    // 1200 pixels: sampling error of the mean 0.0006, of the rms 2 %.
    assert!((mean - 1.0).abs() < 0.003, "{mean}");
    assert!((rms / 0.02 - 1.0).abs() < 0.1, "{rms}");
}

#[test]
fn warm_up_and_drift_follow_the_virtual_clock() {
    // Reading of full white at virtual time t (integration 0.1 s ending at
    // t + 0.1, taken at its middle): 2 W m⁻² sr⁻¹ × (1 − a e^(−t/τ)) ×
    // (1 + d t / 3600), with a = 5 %, τ = 100 s, d = 1 %/h.
    let f = keys("", "")
        .with(
            "screen",
            "warmup_amplitude = 0.05\nwarmup_time_constant = 100.0\ndrift_per_hour = 0.01",
        )
        .facility();
    uniform(&f, 255);
    for t in [10.0, 100.0, 3600.0] {
        f.advance(t - f.now());
        let got = f.meter().measure().unwrap().value;
        let mid = t + 0.05;
        let expected = 2.0 * (1.0 - 0.05 * (-mid / 100.0f64).exp()) * (1.0 + 0.01 * mid / 3600.0);
        assert!(
            (got / expected - 1.0).abs() < 1e-4,
            "t {t}: {got} vs {expected}"
        );
    }
}

#[test]
fn the_black_leak_is_shifted_toward_the_blue() {
    // Flat 380–780 nm white; the black leak (1 % of full white) is that
    // spectrum shifted 10 nm blue, so the camera band (450–820 nm) sees
    // 450–770 nm of it. Level 0 is the leak alone; full white is 99 %
    // channels (the unshifted white) plus the leak.
    let f = keys("", "")
        .with("screen", "spectral_shift_nm = 10.0")
        .facility();
    let sun_ratio = planck_band(|_| 1.0) / planck_band(|l| l / (H * C));
    let shifted = (770e-9f64.powi(2) - 450e-9f64.powi(2)) / (2.0 * H * C);
    let a = 2.0 / 400e-9;
    let expected = a * 0.01 * shifted * sun_ratio;
    let got = f.true_camera_effective_radiance(0, (32.0, 24.0));
    assert!((got / expected - 1.0).abs() < 1e-6, "{got} vs {expected}");
    let white = a * (0.99 * photons_per_flat() + 0.01 * shifted) * sun_ratio;
    let got = f.true_camera_effective_radiance(255, (32.0, 24.0));
    assert!((got / white - 1.0).abs() < 1e-6, "{got} vs {white}");
}

#[test]
fn screen_non_uniformity_reaches_the_camera() {
    // 10 % corner falloff, +4 % gradient to the right: the camera's DN
    // ratio between two pixels is the ratio of U at the screen points they
    // see (the etendue ratio divided out).
    let f = keys("", "")
        .with("screen", "falloff = 0.1\ngradient = [0.04, 0.0]")
        .facility();
    uniform(&f, 255);
    let dn = capture(&f, 0.01);
    let u = |x: f64, y: f64| {
        let (nx, ny) = ((x - 32.0) / 32.0, (y - 24.0) / 24.0);
        (1.0 - 0.05 * (nx * nx + ny * ny)) * (1.0 + 0.04 * nx)
    };
    let etendue = |i: usize, j: usize| {
        let x0 = (i as f64 - 20.0) / 4000.0;
        let y0 = (j as f64 - 15.0) / 4000.0;
        let (xc, yc) = (x0 + 0.5 / 4000.0, y0 + 0.5 / 4000.0);
        rect_solid_angle(x0, x0 + 1.0 / 4000.0, y0, y0 + 1.0 / 4000.0)
            / (1.0 + xc * xc + yc * yc).sqrt()
    };
    // Camera pixel (i, j) centre sees screen (32 + 1.25 (i + 0.5 − 20), …).
    let screen = |i: usize, j: usize| {
        (
            32.0 + 1.25 * (i as f64 + 0.5 - 20.0),
            24.0 + 1.25 * (j as f64 + 0.5 - 15.0),
        )
    };
    let (a, b) = ((20usize, 15usize), (38usize, 28usize));
    let ratio = (dn[b.1 * 40 + b.0] as f64 / etendue(b.0, b.1))
        / (dn[a.1 * 40 + a.0] as f64 / etendue(a.0, a.1));
    let (sa, sb) = (screen(a.0, a.1), screen(b.0, b.1));
    let expected = u(sb.0, sb.1) / u(sa.0, sa.1);
    assert!(
        (ratio / expected - 1.0).abs() < 2e-3,
        "{ratio} vs {expected}"
    );
}
