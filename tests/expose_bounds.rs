//! `optistim expose` against the closed-form electron rate of a Lambert
//! sphere: at zero phase the pixel at the disk centre sees radiance
//! L = ρ/π · E, E the solar irradiance at the sub-solar point, so its rate
//! is S = ρ/π · Φ · Ω · A_pupil with Φ = ∫ E_λ λ/(hc) dλ the photon
//! irradiance in the band (blackbody Sun, integrated here by Simpson's
//! rule), Ω the centre pixel's solid angle, 4 atan(a²/√(1 + 2a²)) for a
//! half-width a = 0.5/f_px, and A_pupil = π (f/2N)². The bounds are then
//! found here by bisection on SNR(t) = S t / √((S + D) t + σ_r² + 1/(12K²))
//! and from the ADC's range above the offset.

mod common;

use std::path::Path;
use std::process::Command;

use glam::DVec3;
use optistim::expose::Feature;

const H: f64 = 6.626_070_15e-34;
const C: f64 = 299_792_458.0;
const K_B: f64 = 1.380_649e-23;
const SIGMA: f64 = 5.670_374_419e-8;
const ALBEDO: f64 = 0.3;
const DARK: f64 = 500.0;
const READ: f64 = 20.0;
const GAIN: f64 = 0.05;
const OFFSET: f64 = 100.0;

/// Photon irradiance [photons s⁻¹ m⁻²] of the 5772 K blackbody Sun giving
/// 1361 W m⁻² at 1 au, at `au` au, over 450–820 nm.
fn photon_irradiance(au: f64) -> f64 {
    let t = 5772.0;
    let e = |l: f64| {
        let planck = 2.0 * H * C * C / l.powi(5) / ((H * C / (l * K_B * t)).exp() - 1.0);
        1361.0 * std::f64::consts::PI * planck / (SIGMA * t.powi(4)) * l / (H * C) / (au * au)
    };
    let (a, b, n) = (450e-9, 820e-9, 2000);
    let h = (b - a) / n as f64;
    let mut sum = e(a) + e(b);
    for i in 1..n {
        sum += e(a + i as f64 * h) * if i % 2 == 1 { 4.0 } else { 2.0 };
    }
    sum * h / 3.0
}

/// The exposure at which SNR(t) = `snr`, by bisection on a log scale.
fn floor_by_bisection(rate: f64, snr: f64) -> f64 {
    let sigma2 = READ * READ + 1.0 / (12.0 * GAIN * GAIN);
    let snr_at = |t: f64| rate * t / ((rate + DARK) * t + sigma2).sqrt();
    let (mut lo, mut hi) = (1e-15f64, 1e6f64);
    for _ in 0..200 {
        let mid = (lo * hi).sqrt();
        if snr_at(mid) < snr {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    lo
}

/// The zero-phase Lambert scene (disk 39 px across, centred on a pixel).
fn setup() -> common::Setup {
    let s = common::Setup::new(
        &format!("{{ model = \"lambert\", albedo = {ALBEDO} }}"),
        0.0,
        10.0,
        39.0,
    );
    assert_eq!(s.resolution[0] % 2, 1, "odd: the centre is a pixel centre");
    s
}

fn scene_text(s: &common::Setup) -> String {
    s.toml()
        .replace(
            "full_well = 1e30\nbits = 12",
            &format!("full_well = 1e5\nbits = 12\ngain = {GAIN}"),
        )
        .replace(
            "[sun]",
            &format!(
                "[camera.sensor]\ndark_current = {DARK}\nread_noise = {READ}\noffset = {OFFSET}\n\n[sun]"
            ),
        )
}

/// The closed-form rate of the centre pixel with the Sun at `au` au from
/// the body (the sub-solar point is a radius nearer).
fn centre_rate(s: &common::Setup, au: f64) -> f64 {
    let pitch = 10e-6;
    let a = 0.5 / s.f_px;
    let omega = 4.0 * (a * a / (1.0 + 2.0 * a * a).sqrt()).atan();
    let d = s.f_px * pitch / 2.5;
    let pupil = std::f64::consts::PI * d * d / 4.0;
    let au_surface = au - s.radius / common::AU;
    ALBEDO / std::f64::consts::PI * photon_irradiance(au_surface) * omega * pupil
}

fn run(dir: &Path, extra: &[&str]) -> (i32, Vec<Vec<f64>>, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_optistim"))
        .arg("expose")
        .arg(dir.join("scene.toml"))
        .args(["--trajectory", dir.join("traj.csv").to_str().unwrap()])
        .args(["--out", dir.join("out").to_str().unwrap(), "--overwrite"])
        .args(extra)
        .output()
        .unwrap();
    let csv = std::fs::read_to_string(dir.join("out/exposure.csv"))
        .unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(&out.stderr)));
    let rows = csv
        .lines()
        .skip(1)
        .map(|l| {
            l.split(',')
                .map(|v| match v {
                    "true" => 1.0,
                    "false" => 0.0,
                    v => v.parse().unwrap(),
                })
                .collect()
        })
        .collect();
    let stdout = String::from_utf8_lossy(&out.stdout).to_string();
    (out.status.code().unwrap(), rows, stdout)
}

fn write_inputs(dir: &Path, s: &common::Setup) {
    std::fs::write(dir.join("scene.toml"), scene_text(s)).unwrap();
    let cam = s.camera_position();
    let q = common::look_at(cam, DVec3::ZERO);
    let mut csv =
        String::from("t,cam_x,cam_y,cam_z,cam_qw,cam_qx,cam_qy,cam_qz,sun_x,sun_y,sun_z\n");
    for (t, au) in [(0.0, 1.0), (10.0, 2.0)] {
        csv += &format!(
            "{t},{:e},{:e},{:e},{},{},{},{},{:e},0,0\n",
            cam.x,
            cam.y,
            cam.z,
            q[0],
            q[1],
            q[2],
            q[3],
            au * common::AU
        );
    }
    std::fs::write(dir.join("traj.csv"), csv).unwrap();
}

#[test]
fn bounds_follow_the_lambert_sphere_closed_form() {
    let s = setup();
    let dir = tempfile::tempdir().unwrap();
    write_inputs(dir.path(), &s);
    let (code, rows, stdout) = run(dir.path(), &["--feature", "brightest", "--snr", "10"]);
    assert_eq!(code, 0, "{stdout}");
    assert!(stdout.starts_with("expose: PASS"), "{stdout}");
    assert_eq!(rows.len(), 2);
    // The ADC fills before the full well: (4095 − offset)/K = 79 900 e⁻.
    let saturation = (4095.0 - OFFSET) / GAIN;
    for (row, au) in rows.iter().zip([1.0, 2.0]) {
        let rate = centre_rate(&s, au);
        eprintln!(
            "{au} au: rate {:+.2e}, t_min {:+.2e}, t_max {:+.2e} relative",
            row[3] / rate - 1.0,
            row[4] / floor_by_bisection(rate, 10.0) - 1.0,
            row[5] * (rate + DARK) / saturation - 1.0
        );
        assert!(
            (row[3] / rate - 1.0).abs() < 1e-3,
            "rate {} vs {rate}",
            row[3]
        );
        let t_min = floor_by_bisection(rate, 10.0);
        let t_max = saturation / (rate + DARK);
        assert!(
            (row[4] / t_min - 1.0).abs() < 1e-3,
            "t_min {} vs {t_min}",
            row[4]
        );
        assert!(
            (row[5] / t_max - 1.0).abs() < 1e-3,
            "t_max {} vs {t_max}",
            row[5]
        );
        assert_eq!(row[6], 1.0);
    }
    let png = image::open(dir.path().join("out/exposure.png")).unwrap();
    assert!(png.width() > 400 && png.height() > 300);
}

#[test]
fn an_snr_beyond_the_full_well_has_no_exposure() {
    // The best SNR is about √(saturation) ≈ 283: 400 cannot be reached.
    let s = setup();
    let dir = tempfile::tempdir().unwrap();
    write_inputs(dir.path(), &s);
    let (code, rows, stdout) = run(dir.path(), &["--feature", "brightest", "--snr", "400"]);
    assert_eq!(code, 2, "{stdout}");
    assert!(stdout.starts_with("expose: FAIL"), "{stdout}");
    assert!(rows.iter().all(|r| r[6] == 0.0 && r[4] > r[5]));
}

#[test]
fn features_pick_their_pixels() {
    let rate = [0.0f32, 0.1, 10.0, 20.0, 30.0];
    assert_eq!(Feature::Brightest.rate(&rate), Some(30.0));
    // Mean over the pixels with signal.
    let mean = (0.1 + 10.0 + 20.0 + 30.0) / 4.0;
    assert!((Feature::DiskMean.rate(&rate).unwrap() - mean).abs() < 1e-5);
    // 0.1 is under 1 % of the peak: the darkest lit pixel is 10.
    assert_eq!(Feature::DarkestLit.rate(&rate), Some(10.0));
    assert_eq!(Feature::Brightest.rate(&[0.0; 4]), None);
}
