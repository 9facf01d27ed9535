//! The camera's cost against the render's (issue 28, item 7).
//!
//! `cargo run --release --example camera_bench -- SCENE [RENDERS]` renders
//! SCENE (default `configs/moon_bench_camera.toml`) RENDERS times (default
//! 15) through the whole chain (`render_scene`) twice per round: once with
//! the camera as configured (sensor chain, PSF, distortion) and once with
//! them removed, in one process, so the per-camera tables are built on the
//! first render and reused after it, as a frame loop or a dataset does.
//! Prints the first (cold) render's times and the medians.

mod common;

use std::time::Instant;

use common::{cpu_ms, median, Positional};

use optistim::render::detector::{render_scene, PixelGeometry, Summary};
use optistim::render::Renderer;
use optistim::scene::Scene;

/// One `render_scene` call: its wall and CPU times [ms] and its summary.
fn timed(scene: &Scene, renderer: &mut Renderer, pixels: &PixelGeometry) -> (f64, f64, Summary) {
    let (t, c) = (Instant::now(), cpu_ms());
    let images = render_scene(scene, renderer, pixels).expect("render");
    (
        t.elapsed().as_secs_f64() * 1e3,
        cpu_ms() - c,
        images.summary,
    )
}

/// The camera's own stages of a summary [ms]: PSF, sensor.
fn stages(s: &Summary) -> (f64, f64, f64) {
    (
        s.psf_ms.unwrap_or(0.0),
        s.distortion_ms.unwrap_or(0.0),
        s.sensor.as_ref().map_or(0.0, |x| x.sensor_ms),
    )
}

fn main() -> anyhow::Result<()> {
    let mut args = Positional::from_env();
    let path = args.path("configs/moon_bench_camera.toml");
    let renders: usize = args.value("RENDERS", 15)?;
    let camera = Scene::from_file(&path)?;
    let mut bare = camera.clone();
    bare.camera.sensor = None;
    bare.camera.psf = None;
    bare.camera.distortion = None;
    let mut r_cam = Renderer::new(camera.camera.render_pinhole().clone());
    let p_cam = PixelGeometry::new(&r_cam);
    let mut r_bare = Renderer::new(bare.camera.pinhole.clone());
    let p_bare = PixelGeometry::new(&r_bare);
    let (mut with, mut without, mut psf, mut lens, mut sensor, mut flux) = Default::default();
    let (mut cpu_with, mut cpu_without) = (Vec::new(), Vec::new());
    let push = |v: &mut Vec<f64>, x: f64| v.push(x);
    let mut cold = None;
    for round in 0..renders.max(1) + 1 {
        let (t, c, s) = timed(&camera, &mut r_cam, &p_cam);
        let (tb, cb, _) = timed(&bare, &mut r_bare, &p_bare);
        let (p, l, q) = stages(&s);
        if round == 0 {
            cold = Some((t, c, p, l, q));
            continue;
        }
        push(&mut with, t);
        push(&mut without, tb);
        push(&mut cpu_with, c);
        push(&mut cpu_without, cb);
        push(&mut psf, p);
        push(&mut lens, l);
        push(&mut sensor, q);
        push(&mut flux, s.render_ms);
    }
    let (cold_t, cold_cpu, cold_psf, cold_lens, cold_sensor) = cold.unwrap_or_default();
    let (w, wo) = (median(with), median(without));
    println!(
        "scene {}; {} threads; {} rounds after a cold one",
        path.display(),
        rayon::current_num_threads(),
        renders.max(1)
    );
    println!(
        "cold: whole chain {cold_t:.1} ms (PSF {cold_psf:.1} ms, distortion {cold_lens:.1} ms, sensor {cold_sensor:.1} ms); CPU {cold_cpu:.1} ms"
    );
    println!("| quantity | median [ms] |");
    println!("|---|---|");
    println!("| render_scene without the camera's effects | {wo:.1} |");
    println!("| render_scene with them | {w:.1} |");
    println!(
        "| of which the flux render (`render_ms`) | {:.1} |",
        median(flux)
    );
    println!("| of which the PSF (`psf_ms`) | {:.1} |", median(psf));
    println!(
        "| of which the distortion (`distortion_ms`) | {:.1} |",
        median(lens)
    );
    println!(
        "| of which the sensor chain (`sensor_ms`) | {:.1} |",
        median(sensor)
    );
    println!(
        "| added by the camera, (with − without) / without | {:.1} % |",
        100.0 * (w - wo) / wo
    );
    let (cw, cwo) = (median(cpu_with), median(cpu_without));
    println!("| CPU time (all threads) without / with [ms] | {cwo:.1} / {cw:.1} |");
    println!(
        "| added by the camera in CPU time | {:.1} % |",
        100.0 * (cw - cwo) / cwo
    );
    Ok(())
}
