//! The camera's lab products from the simulated facility: not the truth,
//! but within their declared uncertainties (k = 2), their errors drawn from
//! the seed with the declared spread; the responsivity's truth checked
//! against a capture of a uniform screen; the spectroradiometer's
//! wavelength error and bin noise.

use optistim::facility::lut::FlatField;
use optistim::instruments::intrinsics::CameraIntrinsics;
use optistim::instruments::SpotMeter;
use optistim::simfacility::SimFacility;

mod common;
use common::simfacility::{lcd_white_spectrum, show_uniform, SimToml};

/// The small facility with the bundled LCD white spectrum, a 4100 px fy,
/// barrel distortion, vignetting and PRNU, no shot noise.
fn keys(seed: u64, extra_meter: &str) -> SimToml {
    let spectrum = format!("spectrum = \"{}\"", lcd_white_spectrum().display());
    SimToml::quiet()
        .seed(seed)
        .with("screen", &spectrum)
        .with(
            "camera",
            "fy = 4100.0\nk1 = -0.1\nvignetting = 0.05\nprnu = 0.01",
        )
        .with("meter", extra_meter)
}

fn facility(seed: u64) -> SimFacility {
    keys(seed, "").facility()
}

/// rms of `v`.
fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
}

#[test]
fn lab_intrinsics_and_responsivity_err_within_their_declared_uncertainty() {
    // Defaults (k = 2): fx, fy 0.05 %, cx, cy 0.1 px, k1 0.002,
    // responsivity 1.5 %: standard deviations of half that.
    let (mut dfx, mut dcx, mut dk1, mut dr) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let dir = tempfile::tempdir().unwrap();
    for seed in 0..40 {
        let f = facility(seed);
        let files = f
            .write_lab_camera_files(&dir.path().join(seed.to_string()))
            .unwrap();
        let k = CameraIntrinsics::load(&files.intrinsics).unwrap();
        let m = k.camera_matrix;
        dfx.push(m[0][0] / 4000.0 - 1.0);
        dfx.push(m[1][1] / 4100.0 - 1.0);
        dcx.push(m[0][2] - 19.5); // OpenCV's convention: the config's − 0.5
        dcx.push(m[1][2] - 14.5);
        dk1.push(k.distortion[0] + 0.1);
        assert_eq!(k.distortion[1..], [0.0; 4]);
        let text = std::fs::read_to_string(&files.responsivity).unwrap();
        let t: toml::Table = toml::from_str(&text).unwrap();
        let r = t["responsivity_dn_per_s_per_w_m2_sr"].as_float().unwrap();
        assert_eq!(t["uncertainty_k2_percent"].as_float(), Some(1.5));
        dr.push(r / f.true_responsivity().0 - 1.0);
    }
    for (what, d, sigma) in [
        ("fx, fy", &dfx, 0.00025),
        ("cx, cy", &dcx, 0.05),
        ("k1", &dk1, 0.001),
        ("responsivity", &dr, 0.0075),
    ] {
        // 80 or 40 draws: the rms within ±30 % of σ; none is zero (not the
        // truth), none beyond 4σ.
        let r = rms(d);
        assert!((r / sigma - 1.0).abs() < 0.3, "{what}: rms {r}, σ {sigma}");
        assert!(
            d.iter().all(|x| *x != 0.0 && x.abs() < 4.0 * sigma),
            "{what}: {d:?}"
        );
    }
}

#[test]
fn true_responsivity_is_what_a_uniform_screen_gives() {
    // DN/s over the region per W m⁻² sr⁻¹ of camera-effective radiance at
    // the camera's entrance (τ × the screen's, uniform here).
    let f = facility(1);
    show_uniform(&f, 200);
    let t = 0.01;
    let frame = f.capture_last(t).unwrap().data;
    let (truth, [x0, y0, rw, rh]) = f.true_responsivity();
    assert_eq!([x0, y0, rw, rh], [12, 7, 16, 16]);
    let mut sum = 0.0;
    for y in y0..y0 + rh {
        for x in x0..x0 + rw {
            sum += frame[y * 40 + x] as f64;
        }
    }
    let dn_per_s = sum / (rw * rh) as f64 / t;
    let l_eff = 0.8 * f.true_camera_effective_radiance(200, (32.0, 24.0));
    let measured = dn_per_s / l_eff;
    assert!(
        (measured / truth - 1.0).abs() < 1e-4,
        "{measured} vs {truth}"
    );
}

#[test]
fn lab_camera_flat_has_its_declared_noise_and_low_order_error() {
    let f = facility(5);
    let dir = tempfile::tempdir().unwrap();
    let files = f.write_lab_camera_files(dir.path()).unwrap();
    let lab = FlatField::load(&files.camera_flat, (40, 30)).unwrap();
    let truth = f.camera_flat();
    let ratio: Vec<f64> = lab
        .gains()
        .iter()
        .zip(&truth)
        .map(|(a, b)| *a as f64 / *b as f64 - 1.0)
        .collect();
    // Least squares on 1, n_x, n_y, n_x² + n_y² − 2/3: the low-order error
    // and the per-pixel noise apart.
    let basis = |k: usize| {
        let nx = ((k % 40) as f64 + 0.5) / 20.0 - 1.0;
        let ny = ((k / 40) as f64 + 0.5) / 15.0 - 1.0;
        [1.0, nx, ny, nx * nx + ny * ny - 2.0 / 3.0]
    };
    let mut a = [[0.0; 4]; 4];
    let mut b = [0.0; 4];
    for (k, r) in ratio.iter().enumerate() {
        let p = basis(k);
        for ((row, bi), pi) in a.iter_mut().zip(b.iter_mut()).zip(p) {
            *bi += pi * r;
            for (x, pj) in row.iter_mut().zip(p) {
                *x += pi * pj;
            }
        }
    }
    let c = solve4(a, b);
    let resid: Vec<f64> = ratio
        .iter()
        .enumerate()
        .map(|(k, r)| r - basis(k).iter().zip(&c).map(|(p, c)| p * c).sum::<f64>())
        .collect();
    // Declared: 0.1 % per pixel (1200 pixels: rms within ±10 %), low order
    // 0.2 % at k = 2 (each coefficient within 4σ = 0.4 %, not all zero).
    assert!(
        (rms(&resid) / 0.001 - 1.0).abs() < 0.1,
        "pixel noise {}",
        rms(&resid)
    );
    assert!(c[1..].iter().all(|x| x.abs() < 0.004), "{c:?}");
    assert!(c[1..].iter().any(|x| x.abs() > 1e-5), "{c:?}");
    let text = std::fs::read_to_string(&files.camera_flat_uncertainty).unwrap();
    let t: toml::Table = toml::from_str(&text).unwrap();
    assert_eq!(t["pixel_noise_rms"].as_float(), Some(0.001));
    assert_eq!(t["low_order_k2"].as_float(), Some(0.002));
}

fn solve4(mut a: [[f64; 4]; 4], mut b: [f64; 4]) -> [f64; 4] {
    for i in 0..4 {
        let p = (i..4)
            .max_by(|&x, &y| a[x][i].abs().total_cmp(&a[y][i].abs()))
            .unwrap();
        a.swap(i, p);
        b.swap(i, p);
        let (pivot, bi) = (a[i], b[i]);
        for r in i + 1..4 {
            let f = a[r][i] / pivot[i];
            for (x, p) in a[r].iter_mut().zip(pivot).skip(i) {
                *x -= f * p;
            }
            b[r] -= f * bi;
        }
    }
    let mut x = [0.0; 4];
    for i in (0..4).rev() {
        x[i] = (b[i] - (i + 1..4).map(|c| a[i][c] * x[c]).sum::<f64>()) / a[i][i];
    }
    x
}

#[test]
fn spectroradiometer_has_a_wavelength_error_and_bin_noise() {
    // 0.3 nm scale error, 0.2 % per-bin noise: the reading at nominal λ is
    // the true spectrum at λ + 0.3 nm × (1 + 0.002 N(0, 1)).
    let f = keys(
        2,
        "spectrometer = true\nwavelength_error_nm = 0.3\nspectrum_noise = 0.002",
    )
    .facility();
    show_uniform(&f, 255);
    let spectrum = f.meter().measure().unwrap().spectrum.unwrap();
    let peak = spectrum.iter().map(|p| p.1).fold(0.0, f64::max);
    let (mut shifted, mut unshifted) = (Vec::new(), Vec::new());
    for &(nm, v) in spectrum.iter().filter(|p| p.1 > 0.01 * peak) {
        let truth = |l: f64| f.screen().spectral_radiance(255, l * 1e-9) * 1e-9;
        shifted.push(v / truth(nm + 0.3) - 1.0);
        unshifted.push(v / truth(nm) - 1.0);
    }
    let n = shifted.len();
    assert!(n > 50, "{n} bins");
    let r = rms(&shifted);
    assert!(
        (r / 0.002 - 1.0).abs() < 0.35,
        "bin noise rms {r} over {n} bins"
    );
    // Against the nominal wavelengths the error is larger than the noise.
    assert!(rms(&unshifted) > 2.0 * r, "{} vs {r}", rms(&unshifted));
}
