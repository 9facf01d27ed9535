//! Timing of `Converter::convert` on a Moon-like ROI.
//!
//! `cargo run --release --example convert_bench`: a 1920×1080 screen with
//! `calib/example_lut.csv`, Bayer 16, 8×8 tile correction, temporal offsets
//! and the facility benchmark's τ = 0.85, k = 0.01; a 400 px disk (limb
//! darkening, phase shading and albedo texture, screen radiance mid-LUT) in
//! a 420×420 ROI whose sky is exact zeros. Prints median and p90 of 200
//! conversions after a short warm-up.

use std::time::Instant;

use optistim::facility::dither::{ConvertSettings, Converter, Roi, ThresholdMatrix};
use optistim::facility::lut::DisplayLut;

const SCREEN: (usize, usize) = (1920, 1080);
const ROI_SIDE: usize = 420;
const DISK_DIAMETER: f64 = 400.0;
const RUNS: usize = 200;
const WARMUP: usize = 20;

/// Deterministic value noise in [0, 1) for the albedo texture.
fn hash01(x: i64, y: i64) -> f64 {
    let mut h = (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    h ^= h >> 31;
    h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h ^= h >> 29;
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// Smoothly interpolated noise with a feature size of `cell` pixels.
fn value_noise(x: f64, y: f64, cell: f64) -> f64 {
    let (u, v) = (x / cell, y / cell);
    let (i, j) = (u.floor() as i64, v.floor() as i64);
    let (fu, fv) = (u - u.floor(), v - v.floor());
    let s = |t: f64| t * t * (3.0 - 2.0 * t);
    let (su, sv) = (s(fu), s(fv));
    let top = hash01(i, j) * (1.0 - su) + hash01(i + 1, j) * su;
    let bottom = hash01(i, j + 1) * (1.0 - su) + hash01(i + 1, j + 1) * su;
    top * (1.0 - sv) + bottom * sv
}

/// Required screen radiance over the ROI (row-major), zero outside the disk.
fn moon_screen_radiance() -> Vec<f64> {
    let c = (ROI_SIDE as f64 - 1.0) / 2.0;
    let r = DISK_DIAMETER / 2.0;
    // Sun 25° from the viewer, to the left: a nearly full, shaded disk.
    let phase = 25f64.to_radians();
    let sun = (-phase.sin(), 0.0, phase.cos());
    let mut out = vec![0.0; ROI_SIDE * ROI_SIDE];
    for y in 0..ROI_SIDE {
        for x in 0..ROI_SIDE {
            let (dx, dy) = ((x as f64 - c) / r, (y as f64 - c) / r);
            let rho2 = dx * dx + dy * dy;
            if rho2 >= 1.0 {
                continue;
            }
            let mu = (1.0 - rho2).sqrt();
            let mu0 = (dx * sun.0 + dy * sun.1 + mu * sun.2).max(0.0);
            // Lommel–Seeliger with a floor so the night sliver stays lit.
            let shade = (mu0 / (mu0 + mu)).max(0.02) * 2.0;
            let albedo = 0.6
                + 0.25 * value_noise(x as f64, y as f64, 37.0)
                + 0.15 * value_noise(x as f64, y as f64, 5.0);
            // Screen radiance 0.05 … 0.9 W m⁻² sr⁻¹ (LUT 0.0011 … 1.099).
            out[y * ROI_SIDE + x] = 0.9 * shade * albedo;
        }
    }
    out
}

fn percentile(sorted: &[f64], q: f64) -> f64 {
    let i = ((sorted.len() - 1) as f64 * q).round() as usize;
    sorted[i]
}

fn main() -> optistim::Result<()> {
    let lut_path = concat!(env!("CARGO_MANIFEST_DIR"), "/calib/example_lut.csv");
    let lut = DisplayLut::load(lut_path, 8)?;
    let settings = ConvertSettings {
        transmission: 0.85,
        scale_k: 0.01,
        temporal: true,
        seed: 1,
        block: 8,
    };
    let mut conv = Converter::new(lut, None, ThresholdMatrix::bayer(16)?, settings, SCREEN)?;
    let factor = settings.transmission / settings.scale_k;
    let target: Vec<f32> = moon_screen_radiance()
        .iter()
        .map(|&l| (l * factor) as f32)
        .collect();
    let lit = target.iter().filter(|&&t| t != 0.0).count();
    // Not aligned to the 8×8 tile grid, like a real bounding box.
    let roi = Roi::new(753, 331, ROI_SIDE, ROI_SIDE);
    let mut frame = vec![0u32; SCREEN.0 * SCREEN.1];
    let mut times = Vec::with_capacity(RUNS);
    let mut checksum = 0u64;
    for i in 0..WARMUP + RUNS {
        let t0 = Instant::now();
        let stats = conv.convert(&target, roi, i as u64, &mut frame)?;
        let dt = t0.elapsed().as_secs_f64() * 1e3;
        if i >= WARMUP {
            times.push(dt);
        }
        checksum = checksum.wrapping_add(stats.pixels);
    }
    // Fingerprint of the last frame, to compare builds.
    let fingerprint = frame.iter().enumerate().fold(0u64, |h, (i, &p)| {
        h.wrapping_mul(0x100_0000_01B3)
            .wrapping_add((i as u64) ^ u64::from(p))
    });
    times.sort_by(f64::total_cmp);
    println!(
        "convert {}×{} ROI, {lit} lit pixels, {} threads: median {:.3} ms, p90 {:.3} ms \
         (min {:.3}, max {:.3}) over {RUNS} runs; frame fingerprint {fingerprint:016x}",
        roi.width,
        roi.height,
        rayon::current_num_threads(),
        percentile(&times, 0.5),
        percentile(&times, 0.9),
        times[0],
        times[times.len() - 1],
    );
    assert_eq!(checksum, ((WARMUP + RUNS) * roi.area()) as u64);
    Ok(())
}
