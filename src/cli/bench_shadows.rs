//! `optistim bench --shadows`: what the relief's cast shadows cost. Each
//! phase is rendered with the scene's shadows (forced on) and without them,
//! alternating render by render so both see the same machine load; the
//! cost is the median of the per-pair ratios. Then the horizon map's
//! one-time cost: computed into an empty cache directory (cold), then read
//! back from it (warm).

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use serde::Serialize;

use optistim::render::Renderer;
use optistim::scene::horizon::{CacheOutcome, HorizonMap, ReliefShadows, ShadowMode};
use optistim::scene::{EquirectMap, Scene};

/// One phase: both medians and the pairs' ratio.
#[derive(Serialize)]
struct ShadowRow {
    phase_deg: f64,
    /// Median render time without and with shadows [ms].
    median_ms_without: f64,
    median_ms_with: f64,
    /// Median interior stage without and with [ms].
    interior_ms_without: f64,
    interior_ms_with: f64,
    /// Median of with/without over the alternating pairs, and its
    /// 10th and 90th percentiles.
    ratio_median: f64,
    ratio_p10: f64,
    ratio_p90: f64,
    interior_pixels: usize,
    /// How the interior pixels' shadows were taken (the last render with
    /// shadows): wholly dark (flux skipped), from the polar nodes, exact.
    dark_pixels: usize,
    polar_pixels: usize,
    exact_pixels: usize,
}

/// The horizon map's one-time cost [s].
#[derive(Serialize)]
struct OneTime {
    dem_load_s: f64,
    cold_s: f64,
    cold_outcome: CacheOutcome,
    warm_s: f64,
    warm_outcome: CacheOutcome,
}

fn median(v: &mut [f64]) -> f64 {
    percentile(v, 0.5)
}

fn percentile(v: &mut [f64], p: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * p).round() as usize]
}

/// Times `scene` at each phase with and without its shadows (`repeats`
/// pairs), then the horizon map cold and warm; prints both tables.
pub fn bench_shadows(
    scene_path: &Path,
    phases: &[f64],
    repeats: usize,
    json: Option<&Path>,
    overwrite: bool,
) -> Result<()> {
    let outputs: Vec<_> = json.map(Path::to_path_buf).into_iter().collect();
    optistim::outfile::check_no_earlier(&outputs, overwrite)?;
    let base = Scene::from_file(scene_path)?;
    let Some(shadows) = base.body.relief.shadows.clone() else {
        bail!(
            "{}: --shadows needs a scene with `[body] shadows`",
            scene_path.display()
        );
    };
    let mut on = base.body.clone();
    on.relief.shadows = Some(Arc::new(ReliefShadows {
        mode: ShadowMode::Always,
        ..(*shadows).clone()
    }));
    let mut off = base.body.clone();
    off.relief.shadows = None;
    let pin = base.camera.pinhole.clone();
    let mut renderer = Renderer::new(pin.clone());
    println!(
        "machine: {} threads; image {}x{}; {} pairs per phase, alternating",
        rayon::current_num_threads(),
        pin.width,
        pin.height,
        repeats
    );
    println!("| phase [deg] | interior px | without [ms] | with [ms] | interior without / with [ms] | with / without (median of pairs) | p10 – p90 |");
    println!("|---|---|---|---|---|---|---|");
    let mut rows = Vec::new();
    for &phase in phases {
        let mut scene = base.clone();
        super::bench::at_phase(&mut scene, phase);
        let settings = &scene.render;
        let (mut t_off, mut t_on, mut i_off, mut i_on, mut ratios) =
            (vec![], vec![], vec![], vec![], vec![]);
        let mut interior_pixels = 0;
        let mut paths = optistim::render::interior::DirectCounts::default();
        // One warm-up of each, untimed.
        for body in [&on, &off] {
            renderer.render_flux(body, &scene.state, settings, None);
        }
        for k in 0..repeats.max(1) {
            let mut pair = [0.0; 2];
            // Alternate which goes first, so a drift in load hits both.
            for which in [k % 2, 1 - k % 2] {
                let body = if which == 0 { &off } else { &on };
                let t = Instant::now();
                let stats = renderer.render_flux(body, &scene.state, settings, None);
                let ms = t.elapsed().as_secs_f64() * 1e3;
                let interior = stats.stages.interior * 1e3;
                pair[which] = ms;
                if which == 0 {
                    t_off.push(ms);
                    i_off.push(interior);
                    interior_pixels = stats.interior_pixels;
                } else {
                    t_on.push(ms);
                    i_on.push(interior);
                    paths = stats.interior_direct;
                }
            }
            ratios.push(pair[1] / pair[0]);
        }
        let row = ShadowRow {
            phase_deg: phase,
            median_ms_without: median(&mut t_off),
            median_ms_with: median(&mut t_on),
            interior_ms_without: median(&mut i_off),
            interior_ms_with: median(&mut i_on),
            ratio_median: median(&mut ratios),
            ratio_p10: percentile(&mut ratios, 0.1),
            ratio_p90: percentile(&mut ratios, 0.9),
            interior_pixels,
            dark_pixels: paths.dark,
            polar_pixels: paths.shadow_polar,
            exact_pixels: paths.shadow_exact,
        };
        println!(
            "| {:.0} | {} | {:.2} | {:.2} | {:.2} / {:.2} | {:.3} | {:.3} – {:.3} |",
            row.phase_deg,
            row.interior_pixels,
            row.median_ms_without,
            row.median_ms_with,
            row.interior_ms_without,
            row.interior_ms_with,
            row.ratio_median,
            row.ratio_p10,
            row.ratio_p90
        );
        rows.push(row);
    }
    for row in &rows {
        println!(
            "phase {:.0}: interior shadows {} dark (flux skipped), {} from polar nodes, {} exact (no lattice, or penumbra)",
            row.phase_deg, row.dark_pixels, row.polar_pixels, row.exact_pixels
        );
    }
    let one_time = horizon_cost(&shadows)?;
    println!(
        "horizon map {}×{}, {} azimuths: DEM load {:.2} s; cold ({:?}) {:.2} s; warm ({:?}) {:.2} s",
        shadows.map.width(),
        shadows.map.height(),
        shadows.map.azimuths(),
        one_time.dem_load_s,
        one_time.cold_outcome,
        one_time.cold_s,
        one_time.warm_outcome,
        one_time.warm_s
    );
    if let Some(path) = json {
        let doc =
            serde_json::json!({ "scene": scene_path, "phases": rows, "horizon_map": one_time });
        std::fs::write(path, serde_json::to_string_pretty(&doc)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

/// The horizon map of `shadows` computed into a fresh cache directory
/// (cold: DEM hash, march, write) and read back (warm: hash, read, checks).
fn horizon_cost(shadows: &ReliefShadows) -> Result<OneTime> {
    let stamp = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos());
    let dir = std::env::temp_dir().join(format!(
        "optistim-bench-horizon-{}-{stamp}",
        std::process::id()
    ));
    let t = Instant::now();
    let mut dem = EquirectMap::load(&shadows.dem_path)?;
    dem.scale(shadows.params.scale);
    let dem_load_s = t.elapsed().as_secs_f64();
    let run = || -> Result<(f64, CacheOutcome)> {
        let t = Instant::now();
        let (_, outcome, _) =
            HorizonMap::load_or_compute(&shadows.dem_path, &dem, &shadows.params, &dir)?;
        Ok((t.elapsed().as_secs_f64(), outcome))
    };
    let cold = run();
    let warm = run();
    let _ = std::fs::remove_dir_all(&dir);
    let ((cold_s, cold_outcome), (warm_s, warm_outcome)) = (cold?, warm?);
    Ok(OneTime {
        dem_load_s,
        cold_s,
        cold_outcome,
        warm_s,
        warm_outcome,
    })
}
