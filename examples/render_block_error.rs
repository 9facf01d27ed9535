//! Speed against error of `screen.render_block`, as the camera sees it.
//!
//! `cargo run --release --example render_block_error -- FACILITY.toml
//! [RANGE_M] [PHASE_DEG] [RENDERS]` renders the facility's scene (camera at
//! RANGE_M from the body on −z, Sun at PHASE_DEG, as `tools/make_hold.py`)
//! with blocks of 1, 2 and 3 screen pixels, and integrates each screen image
//! over the pixels of the scene's camera looking through the collimator
//! (both on the optical axis; the overlap of camera and screen pixels is
//! computed here, in the tangent plane). It prints the median render time of
//! each block size and the camera-pixel error against blocks of 1, over the
//! camera pixels above 5 % of the peak.
//!
//! Needs a facility file without a geometry calibration or rotation (the
//! bundled `configs/bench_facility_*.toml`); an alignment offset is kept.

mod common;

use std::time::Instant;

use common::{median, Positional};

use glam::{DQuat, DVec3};

use optistim::facility::config::FacilityConfig;
use optistim::facility::driver::{screen_pinhole, ScreenModel};
use optistim::scene::{Pinhole, Scene};

const AU: f64 = 1.495_978_707e11;

/// Overlap [camera px] of each screen pixel's interval with camera pixels:
/// for screen index i, (first camera index, weights of it and the next).
fn overlaps(screen: (f64, f64, usize), camera: (f64, f64, usize)) -> Vec<(usize, [f64; 2])> {
    let (fs, cs, ns) = screen;
    let (fc, cc, nc) = camera;
    (0..ns)
        .map(|i| {
            let a = (i as f64 - cs) / fs * fc + cc;
            let b = (i as f64 + 1.0 - cs) / fs * fc + cc;
            let k = a.floor();
            if k < 0.0 || k + 1.0 >= nc as f64 {
                return (0, [0.0, 0.0]);
            }
            let split = (k + 1.0).min(b);
            (k as usize, [split - a, b - split])
        })
        .collect()
}

fn camera_image(img: &[f64], screen: &Pinhole, camera: &Pinhole) -> Vec<f64> {
    let ox = overlaps(
        (screen.fx, screen.cx, screen.width),
        (camera.fx, camera.cx, camera.width),
    );
    let oy = overlaps(
        (screen.fy, screen.cy, screen.height),
        (camera.fy, camera.cy, camera.height),
    );
    let mut out = vec![0.0; camera.width * camera.height];
    for (j, &(kj, wy)) in oy.iter().enumerate() {
        for (i, &(ki, wx)) in ox.iter().enumerate() {
            let l = img[j * screen.width + i];
            if l == 0.0 {
                continue;
            }
            for (dy, wy) in wy.iter().enumerate() {
                for (dx, wx) in wx.iter().enumerate() {
                    out[(kj + dy) * camera.width + ki + dx] += l * wx * wy;
                }
            }
        }
    }
    out
}

fn main() -> anyhow::Result<()> {
    let mut args = Positional::from_env();
    let path = args.path("configs/bench_facility_2560.toml");
    let range: f64 = args.value("RANGE_M", 1.1181e8)?;
    let phase: f64 = args.value("PHASE_DEG", 60.0)?;
    let renders: usize = args.value("RENDERS", 15)?;
    let base = FacilityConfig::load(&path)?;
    let mut scene = Scene::from_file(&base.scenario.scene)?;
    let p = phase.to_radians();
    scene.state.camera_position = DVec3::new(0.0, 0.0, -range);
    scene.state.camera_attitude = DQuat::IDENTITY;
    scene.state.sun_position = DVec3::new(AU * p.sin(), 0.0, -AU * p.cos());
    let screen = screen_pinhole(&base);
    let camera = scene.camera.pinhole.clone();
    let (w, h) = base.screen_size();
    println!(
        "{}: {w}x{h} screen, {:.1} µrad per screen pixel; camera {:.1} µrad per pixel; phase {phase}°; {} threads",
        path.display(),
        1e6 / screen.fx,
        1e6 / camera.fx,
        rayon::current_num_threads()
    );
    println!("| render_block | render median [ms] | camera px checked | error p50 | p99 | max | total flux error |");
    println!("|---|---|---|---|---|---|---|");
    let mut reference: Option<Vec<f64>> = None;
    for block in [1, 2, 3] {
        let mut config = base.clone();
        config.screen.render_block = block;
        let mut model = ScreenModel::new(&config, &scene, None);
        let mut times = Vec::new();
        let mut roi = None;
        for _ in 0..renders.max(1) {
            let t = Instant::now();
            roi = model.render(&scene, &scene.state);
            times.push(t.elapsed().as_secs_f64() * 1e3);
        }
        let mut img = vec![0.0; w * h];
        if let Some(r) = roi {
            for (k, &l) in model.target().iter().enumerate() {
                img[(r.y + k / r.width) * w + r.x + k % r.width] = l as f64;
            }
        }
        let cam = camera_image(&img, &screen, &camera);
        let Some(truth) = &reference else {
            println!("| 1 | {:.2} | – | – | – | – | – |", median(times));
            reference = Some(cam);
            continue;
        };
        let peak = truth.iter().cloned().fold(0.0, f64::max);
        let mut errors: Vec<f64> = truth
            .iter()
            .zip(&cam)
            .filter(|(t, _)| **t > 0.05 * peak)
            .map(|(t, c)| (c - t).abs() / t)
            .collect();
        errors.sort_by(f64::total_cmp);
        let pick = |q: f64| errors[((errors.len() - 1) as f64 * q).round() as usize];
        let total = |v: &[f64]| v.iter().sum::<f64>();
        println!(
            "| {block} | {:.2} | {} | {:.2e} | {:.2e} | {:.2e} | {:.1e} |",
            median(times),
            errors.len(),
            pick(0.5),
            pick(0.99),
            pick(1.0),
            (total(&cam) / total(truth) - 1.0).abs()
        );
    }
    Ok(())
}
