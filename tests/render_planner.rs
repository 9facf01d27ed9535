//! The offline planner (`render --max-pixel-error`, issue 27 item 2) on the
//! benchmark Moon (`configs/moon_bench.toml`, the scene `optistim bench`
//! renders): for targets 1e-2, 3e-3 and 1e-3 the planner's settings,
//! rendered here, meet the target against an independent converged render
//! (the lune's caps at 6 × 6 per pixel, exact map means: twice the
//! planner's own reference density per axis); looser targets get strictly
//! cheaper settings; bad targets are one-line errors naming the key.
//! On the relief Moon (`configs/moon.toml`, displaced: the caps
//! draw every pixel) the planner judges the whole disk, not an empty
//! interior, and its choice meets the target against the same kind of
//! independent converged render.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use optistim::planner::Planner;
use optistim::render::{Interior, MapFilter, Renderer};
use optistim::scene::Scene;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn bench_moon() -> Scene {
    Scene::from_file(&root().join("configs/moon_bench.toml")).unwrap()
}

/// Caps per pixel and axis of the test's converged render.
const CONVERGED_DENSITY: f64 = 6.0;

/// The test's converged render: every pixel from the lune's caps at
/// [`CONVERGED_DENSITY`]², each cap's parts taking the map's exact mean.
fn converged(scene: &Scene) -> Vec<f32> {
    let mut s = scene.render.clone();
    s.caps_per_pixel = Some(CONVERGED_DENSITY);
    s.min_caps = 1024;
    s.interior = Interior::Caps;
    s.map_filter = MapFilter::Exact;
    s.texture_samples = 4;
    s.check().unwrap();
    let mut r = Renderer::new(scene.camera.pinhole.clone());
    r.render_flux(&scene.body, &scene.state, &s, None);
    r.flux().to_vec()
}

/// The 99th percentile (nearest rank) of |image / truth − 1| over the
/// pixels the render integrated per pixel whose truth is above 1 % of its
/// peak.
fn interior_p99(image: &[f32], truth: &[f32], renderer: &Renderer) -> f64 {
    let width = renderer.camera().width;
    let peak = truth.iter().copied().fold(0.0f32, f32::max) as f64;
    let mut e: Vec<f64> = (0..truth.len())
        .filter(|&k| truth[k] as f64 > 0.01 * peak)
        .filter(|&k| renderer.is_interior_pixel(k % width, k / width))
        .map(|k| (image[k] as f64 / truth[k] as f64 - 1.0).abs())
        .collect();
    assert!(e.len() > 10_000, "{} interior pixels", e.len());
    e.sort_by(f64::total_cmp);
    let rank = (0.99 * e.len() as f64).ceil() as usize - 1;
    e[rank]
}

/// The 99th percentile (nearest rank) of |image / truth − 1| over every
/// pixel whose truth is above 1 % of its peak.
fn disk_p99(image: &[f32], truth: &[f32]) -> f64 {
    let e = common::sorted_relative_errors(image, truth);
    assert!(e.len() > 5_000, "{} disk pixels", e.len());
    common::nearest_rank(&e, 0.99)
}

/// The relief Moon at 384 px (a pixel covers about three DEM cells):
/// displaced, so no pixel is interior. Before the planner judged the
/// disk, it measured an empty interior (p99 0) and kept the scene's own
/// single cap per pixel, 29 % off (24 % since caps are cut at occlusion
/// edges, so the target is 20 %, below that); now the target must be met
/// over the disk.
#[test]
fn where_the_caps_draw_the_disk_the_planner_judges_the_disk() {
    let path = root().join("configs/moon.toml");
    let text = std::fs::read_to_string(&path)
        .unwrap()
        .replace("resolution = [1024, 1024]", "resolution = [384, 384]");
    let scene = Scene::from_toml(&text, &path).unwrap();
    assert_eq!(scene.camera.pinhole.width, 384);
    let truth = converged(&scene);
    let render = |settings| {
        let mut r = Renderer::new(scene.camera.pinhole.clone());
        r.render_flux(&scene.body, &scene.state, settings, None);
        assert!(
            (0..384 * 384).all(|k| !r.is_interior_pixel(k % 384, k / 384)),
            "a displaced relief has no interior pixel"
        );
        disk_p99(r.flux(), &truth)
    };
    let target = 0.20;
    let own = render(&scene.render);
    assert!(own > target, "the scene's own settings: disk p99 {own:.3}");
    let mut planner = Planner::new(&scene);
    let plan = planner.plan(target, "--max-pixel-error").unwrap();
    let measured = render(&plan.settings);
    println!(
        "relief: own settings {own:.3}; planned {} predicted {:.3} measured {measured:.3}",
        plan.label, plan.predicted_pixel_error
    );
    assert_eq!(plan.judged, "disk");
    assert!(measured <= target, "{} measured {measured:.3}", plan.label);
    assert!(
        (0.5..=2.0).contains(&(plan.predicted_pixel_error / measured)),
        "predicted {:.3} measured {measured:.3}",
        plan.predicted_pixel_error
    );
    // A target below what its finest step reaches is refused, not met by
    // an empty interior.
    let err = planner
        .plan(0.02, "--max-pixel-error")
        .unwrap_err()
        .to_string();
    assert!(err.contains("disk p99"), "{err}");
}

#[test]
fn planned_settings_meet_each_target_and_looser_targets_cost_less() {
    let scene = bench_moon();
    let truth = converged(&scene);
    let mut planner = Planner::new(&scene);
    let mut steps = Vec::new();
    for target in [1e-2, 3e-3, 1e-3] {
        let plan = planner.plan(target, "--max-pixel-error").unwrap();
        let mut r = Renderer::new(scene.camera.pinhole.clone());
        r.render_flux(&scene.body, &scene.state, &plan.settings, None);
        let measured = interior_p99(r.flux(), &truth, &r);
        println!(
            "target {target:e}: step {} {} predicted {:.3e} measured {measured:.3e}",
            plan.step, plan.label, plan.predicted_pixel_error
        );
        assert!(
            measured <= target,
            "target {target:e}: {} measured {measured:.3e}",
            plan.label
        );
        // The plan's prediction is its own measurement against its own
        // reference: within a factor 2 of this independent one.
        assert!(
            plan.predicted_pixel_error <= target
                && (0.5..=2.0).contains(&(plan.predicted_pixel_error / measured)),
            "predicted {:.3e} measured {measured:.3e}",
            plan.predicted_pixel_error
        );
        steps.push(plan.step);
    }
    // Finest first: a looser target is a strictly later (cheaper) step.
    assert!(
        steps[0] > steps[1] && steps[1] > steps[2],
        "steps {steps:?}"
    );
}

fn optistim(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_optistim"))
        .args(args)
        .current_dir(root())
        .output()
        .unwrap()
}

fn render_error(scene: &Path, out: &Path, flag: Option<&str>) -> String {
    let mut args = vec![
        "render",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    let flag_arg = flag.map(|f| format!("--max-pixel-error={f}"));
    args.extend(flag_arg.as_deref());
    let o = optistim(&args);
    assert!(!o.status.success(), "{flag:?} accepted");
    let err = String::from_utf8_lossy(&o.stderr);
    let line = err
        .lines()
        .find(|l| l.contains("error"))
        .unwrap_or_else(|| panic!("no error line in {err}"))
        .to_string();
    line
}

#[test]
fn bad_targets_are_one_line_errors_naming_the_flag_or_key() {
    let dir = tempfile::tempdir().unwrap();
    let scene = root().join("configs/moon_bench.toml");
    for bad in ["0", "-1e-3", "NaN", "inf", "2"] {
        let line = render_error(&scene, &dir.path().join("o"), Some(bad));
        assert!(line.contains("--max-pixel-error"), "{bad}: {line}");
    }
    // The scene key, out of range and below what the finest step reaches
    // (measured, then refused, nothing written).
    let text = std::fs::read_to_string(&scene)
        .unwrap()
        .replace("../data/", &format!("{}/data/", root().display()));
    for (value, says) in [
        ("0.0", "must be in"),
        ("nan", "must be in"),
        ("1e-7", "finest"),
    ] {
        let path = dir.path().join(format!("scene_{value}.toml"));
        std::fs::write(
            &path,
            format!("{text}\n[render]\nmax_pixel_error = {value}\n"),
        )
        .unwrap();
        let line = render_error(&path, &dir.path().join("o"), None);
        assert!(
            line.contains("render.max_pixel_error") && line.contains(says),
            "{value}: {line}"
        );
        assert!(!dir.path().join("o/summary.json").exists());
    }
}

#[test]
fn the_render_summary_names_the_plan() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r");
    let o = optistim(&[
        "render",
        "configs/moon_bench.toml",
        "--out",
        out.to_str().unwrap(),
        "--max-pixel-error",
        "1e-2",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let plan = &s["plan"];
    assert_eq!(plan["max_pixel_error"], 1e-2);
    let predicted = plan["predicted_pixel_error"].as_f64().unwrap();
    assert!(predicted > 0.0 && predicted <= 1e-2, "{plan}");
    assert!(plan["why"].as_str().unwrap().contains("cheapest"));
    // The settings used are the plan's, and the steps tried are reported
    // coarsest first, the last one the chosen.
    let measured = plan["measured"].as_array().unwrap();
    assert_eq!(measured.last().unwrap()["step"], plan["step"]);
    assert!(plan["settings"]["texture_samples"].as_u64().is_some());
}
