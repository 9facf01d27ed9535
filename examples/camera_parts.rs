//! The camera's stages timed one by one on the benchmark scene's images
//! (issue 28, item 7): the sensor chain's frame and the PSF convolution
//! of one image, each run many times on the electron rate `render_scene`
//! gives, CPU time per call (medians), and per pixel.
//!
//! `cargo run --release --example camera_parts -- SCENE [REPEATS]`
//! (default `configs/moon_bench_camera.toml`, 31 repeats); run it with
//! `RAYON_NUM_THREADS=1` for one core's cost.

mod common;

use common::{cpu_ms, Positional};
use optistim::optics::psf::shared_kernel;
use optistim::render::detector::{render_scene, PixelGeometry};
use optistim::render::Renderer;
use optistim::scene::Scene;
use optistim::sensor::Sensor;

/// Median CPU time [ms] of `repeats` calls of `f` (after one warm call).
fn median_cpu(repeats: usize, mut f: impl FnMut(u64)) -> f64 {
    f(0);
    let mut times: Vec<f64> = (1..=repeats as u64)
        .map(|i| {
            let c = cpu_ms();
            f(i);
            cpu_ms() - c
        })
        .collect();
    times.sort_by(f64::total_cmp);
    times[times.len() / 2]
}

fn main() -> anyhow::Result<()> {
    let mut args = Positional::from_env();
    let path = args.path("configs/moon_bench_camera.toml");
    let repeats: usize = args.value("REPEATS", 31)?;
    let scene = Scene::from_file(&path)?;
    let cam = &scene.camera;
    let mut renderer = Renderer::new(cam.render_pinhole().clone());
    let pixels = PixelGeometry::new(&renderer);
    let images = render_scene(&scene, &mut renderer, &pixels)?;
    let rate = &images.electron_rate;
    let (w, h) = (cam.pinhole.width, cam.pinhole.height);
    let n = (w * h) as f64;
    println!(
        "scene {}; {} threads; medians of {repeats}",
        path.display(),
        rayon::current_num_threads()
    );
    if let Some(params) = cam.sensor {
        let sensor = Sensor::shared(params, cam.readout(), w, h);
        let t = median_cpu(repeats, |f| {
            std::hint::black_box(sensor.expose(rate, cam.exposure, f));
        });
        let dark_only = vec![0.0f32; rate.len()];
        let t_dark = median_cpu(repeats, |f| {
            std::hint::black_box(sensor.expose(&dark_only, cam.exposure, f));
        });
        println!(
            "sensor frame: {t:.2} ms CPU ({:.2} ns per pixel); a dark frame {t_dark:.2} ms ({:.2} ns per pixel)",
            t * 1e6 / n,
            t_dark * 1e6 / n
        );
    }
    if let Some(psf) = &cam.psf {
        let kernel = shared_kernel(psf)?;
        let t = median_cpu(repeats, |_| {
            std::hint::black_box(kernel.convolve(rate, w, h));
        });
        println!(
            "PSF convolution of one image ({} × {} kernel): {t:.2} ms CPU",
            2 * kernel.half + 1,
            2 * kernel.half + 1
        );
    }
    Ok(())
}
