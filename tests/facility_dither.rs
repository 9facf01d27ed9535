//! Dithering accuracy against an independent gamma-2.2 display model.
//!
//! The test LUT is written here from the closed form
//! `L(level) = Lmax·(level/255)^2.2 + black` at every integer level, so the
//! radiance of an emitted level is known without the code under test.

use optistim::facility::dither::{ConvertSettings, Converter, Roi, ThresholdMatrix};
use optistim::facility::lut::{decode_grey, DisplayLut, FlatField};

const LMAX: f64 = 80.0;
const BLACK: f64 = 0.05;

fn gamma(level: u32) -> f64 {
    LMAX * (level as f64 / 255.0).powf(2.2) + BLACK
}

fn write_gamma_lut(dir: &std::path::Path) -> std::path::PathBuf {
    let mut csv = String::from("# gamma 2.2 test display\ndrive_level,radiance_w_m2_sr\n");
    for k in 0..=255 {
        csv.push_str(&format!("{k},{:.17e}\n", gamma(k)));
    }
    let p = dir.join("gamma22.csv");
    std::fs::write(&p, csv).unwrap();
    p
}

struct Case {
    settings: ConvertSettings,
    flat: Option<Vec<f32>>,
    matrix: ThresholdMatrix,
    /// Required screen radiance at ROI-relative (fx, fy) ∈ [0, 1]².
    ramp: fn(f64, f64) -> f64,
}

const W: usize = 2100;
const H: usize = 40;

/// Gradient slow enough in drive-level space to be dithered (≈ 0.12 level
/// per pixel along x, a fraction of a level along y), over levels 12 … 250:
/// `L = gamma(ℓ)` with fractional `ℓ`, from the closed form.
fn slow_ramp(fx: f64, fy: f64) -> f64 {
    let level = 12.0 + 238.0 * fx + 0.4 * (std::f64::consts::PI * fy).sin();
    LMAX * (level / 255.0).powf(2.2) + BLACK
}

/// Steep gradient: 1 % … 97 % of the radiance range across 256 pixels
/// (up to several levels per pixel at the dark end, where no dither can
/// make 8×8 means exact; only the per-pixel bound applies).
fn steep_ramp(fx: f64, fy: f64) -> f64 {
    let frac = 0.01 + 0.96 * (0.8 * fx + 0.2 * (0.5 - 0.5 * (std::f64::consts::PI * fy).cos()));
    BLACK + frac * LMAX
}

/// Converts a 2-D gradient and checks per-pixel (and, if given, 8×8-block)
/// accuracy of the recovered camera-side radiance `L(level)·g·τ/k`.
fn check(case: Case, roi: Roi, block_tol: Option<(f64, f64)>) {
    let dir = tempfile::tempdir().unwrap();
    let lut = DisplayLut::load(write_gamma_lut(dir.path()), 8).unwrap();
    let (w, h) = (W, H);
    let flat = case
        .flat
        .clone()
        .map(|g| FlatField::from_gains(w, h, g).unwrap());
    let gain = |x: usize, y: usize| case.flat.as_ref().map_or(1.0, |g| g[y * w + x] as f64);
    let s = case.settings;
    let mut conv = Converter::new(lut, flat, case.matrix, s, (w, h)).unwrap();
    // Required screen radiance spans 1 % … 97 % of the range: smooth in x and y.
    let target: Vec<f32> = (0..roi.area())
        .map(|i| {
            let (u, v) = ((i % roi.width) as f64, (i / roi.width) as f64);
            let fx = u / (roi.width - 1) as f64;
            let fy = v / (roi.height - 1) as f64;
            let l_screen = (case.ramp)(fx, fy);
            let (x, y) = (roi.x + i % roi.width, roi.y + i / roi.width);
            (l_screen * gain(x, y) * s.transmission / s.scale_k) as f32
        })
        .collect();
    let mut frame = vec![0u32; w * h];
    let stats = conv.convert(&target, roi, 17, &mut frame).unwrap();
    assert_eq!(stats.clipped(), 0);
    assert_eq!(stats.non_finite, 0);

    // Recovered camera-side radiance and the local LUT step, per pixel.
    let mut rec = vec![0.0f64; roi.area()];
    for i in 0..roi.area() {
        let (x, y) = (roi.x + i % roi.width, roi.y + i / roi.width);
        let level = decode_grey(frame[y * w + x], 8);
        let scale = gain(x, y) * s.transmission / s.scale_k;
        rec[i] = gamma(level) * scale;
        let t = target[i] as f64;
        let l_screen = t / scale;
        // The two levels bracketing the required screen radiance.
        let k = (0..255).rfind(|&k| gamma(k) <= l_screen).unwrap();
        assert!(
            level == k || level == k + 1,
            "pixel ({x},{y}): level {level}, bracket {k}"
        );
        let step = (gamma(k + 1) - gamma(k)) * scale;
        assert!((rec[i] - t).abs() <= step * (1.0 + 1e-9), "pixel ({x},{y})");
    }
    // Every 8×8 block of the screen grid that lies inside the ROI.
    let Some((aligned_tol, any_tol)) = block_tol else {
        return;
    };
    let block_err = |bx: usize, by: usize| {
        let (mut sr, mut st) = (0.0, 0.0);
        for y in by..by + 8 {
            for x in bx..bx + 8 {
                let i = (y - roi.y) * roi.width + (x - roi.x);
                sr += rec[i];
                st += target[i] as f64;
            }
        }
        (sr - st).abs() / st
    };
    let mut worst_aligned = 0.0f64;
    let mut blocks = 0;
    for by in (roi.y.div_ceil(8) * 8..=roi.y + roi.height - 8).step_by(8) {
        for bx in (roi.x.div_ceil(8) * 8..=roi.x + roi.width - 8).step_by(8) {
            worst_aligned = worst_aligned.max(block_err(bx, by));
            blocks += 1;
        }
    }
    assert!(blocks >= 3 * 250, "{blocks} blocks");
    assert!(
        worst_aligned < aligned_tol,
        "worst aligned 8×8 block error {worst_aligned}"
    );
    // Every 8×8 window at any position (crossing tile borders).
    let mut worst_any = 0.0f64;
    for by in roi.y..=roi.y + roi.height - 8 {
        for bx in roi.x..=roi.x + roi.width - 8 {
            worst_any = worst_any.max(block_err(bx, by));
        }
    }
    eprintln!("worst 8×8 error: aligned {worst_aligned:.2e}, any position {worst_any:.2e}");
    assert!(worst_any < any_tol, "worst 8×8 window error {worst_any}");
    // Outside the ROI the frame stays black.
    for y in 0..h {
        for x in 0..w {
            if !roi.contains(x, y) {
                assert_eq!(frame[y * w + x], 0);
            }
        }
    }
}

const SLOW_ROI: Roi = Roi {
    x: 27,
    y: 4,
    width: 2048,
    height: 32,
};
const STEEP_ROI: Roi = Roi {
    x: 3,
    y: 1,
    width: 256,
    height: 38,
};

fn smooth_flat() -> Vec<f32> {
    // Vignetting-like flat field, 0.9 … 1.05.
    (0..W * H)
        .map(|i| {
            let (x, y) = (
                (i % W) as f64 / W as f64 - 0.5,
                (i / W) as f64 / H as f64 - 0.5,
            );
            (1.05 - 0.3 * (x * x + y * y)) as f32
        })
        .collect()
}

#[test]
fn bayer8_smooth_gradient_per_pixel_and_every_8x8_block() {
    let case = Case {
        settings: ConvertSettings::default(),
        flat: None,
        matrix: ThresholdMatrix::bayer(8).unwrap(),
        ramp: slow_ramp,
    };
    check(case, SLOW_ROI, Some((0.002, 0.01)));
}

#[test]
fn bayer16_with_scale_transmission_flat_field_and_temporal_offset() {
    let case = Case {
        settings: ConvertSettings {
            transmission: 0.72,
            scale_k: 0.35,
            temporal: true,
            seed: 99,
            ..Default::default()
        },
        flat: Some(smooth_flat()),
        matrix: ThresholdMatrix::bayer(16).unwrap(),
        ramp: slow_ramp,
    };
    check(case, SLOW_ROI, Some((0.002, 0.01)));
}

#[test]
fn blue_noise_smooth_gradient() {
    // Tile correction makes screen-grid blocks exact for any mask; windows
    // across tile borders are looser with blue noise than with Bayer.
    let case = Case {
        settings: ConvertSettings {
            temporal: true,
            seed: 5,
            ..Default::default()
        },
        flat: Some(smooth_flat()),
        matrix: ThresholdMatrix::blue_noise(64, 5).unwrap(),
        ramp: slow_ramp,
    };
    check(case, SLOW_ROI, Some((0.002, 0.015)));
}

#[test]
fn steep_gradient_is_within_one_step_per_pixel() {
    for matrix in [
        ThresholdMatrix::bayer(8).unwrap(),
        ThresholdMatrix::blue_noise(64, 1).unwrap(),
    ] {
        let case = Case {
            settings: ConvertSettings::default(),
            flat: None,
            matrix,
            ramp: steep_ramp,
        };
        check(case, STEEP_ROI, None);
    }
}
