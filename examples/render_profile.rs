//! A fixed render workload for profilers.
//!
//! `cargo run --release --example render_profile -- SCENE [RENDERS]` renders
//! the scene's own state RENDERS times (default 20) and prints the median
//! of each stage. Unlike `optistim bench` it computes no reference, so a
//! profile (`perf record`, or `valgrind --tool=cachegrind` for counts that
//! do not depend on the machine's load) sees only the renderer.

mod common;

use std::time::Instant;

use common::{median, Positional};

use optistim::render::Renderer;
use optistim::scene::Scene;

fn main() -> anyhow::Result<()> {
    let mut args = Positional::from_env();
    let scene_path = args.path("configs/moon.toml");
    let renders: usize = args.value("RENDERS", 20)?;
    let scene = Scene::from_file(&scene_path)?;
    let mut renderer = Renderer::new(scene.camera.pinhole.clone());
    let mut total = Vec::new();
    let mut stages: [Vec<f64>; 4] = Default::default();
    let mut last = None;
    for _ in 0..renders.max(1) {
        let t = Instant::now();
        let stats = renderer.render_flux(&scene.body, &scene.state, &scene.render, None);
        total.push(t.elapsed().as_secs_f64() * 1e3);
        last = Some(stats);
        let s = stats.stages;
        for (v, x) in stages
            .iter_mut()
            .zip([s.layout, s.mask, s.caps, s.interior])
        {
            v.push(x * 1e3);
        }
    }
    let [layout, mask, caps, interior] = stages.map(median);
    println!(
        "{} renders on {} threads: median {:.2} ms (layout {layout:.2} / mask {mask:.2} / caps {caps:.2} / interior {interior:.2} ms)",
        total.len(),
        rayon::current_num_threads(),
        median(total)
    );
    if let Some(s) = last {
        println!(
            "caps laid out {}, integrated {}, leaf cells {}, interior pixels {} (direct: {} by 1 point, {} by 2×2, {} by 4×4), phase {:.1}°",
            s.caps,
            s.caps_integrated,
            s.cells,
            s.interior_pixels,
            s.interior_direct.midpoint,
            s.interior_direct.gauss2,
            s.interior_direct.gauss4,
            s.phase_angle.to_degrees()
        );
    }
    Ok(())
}
