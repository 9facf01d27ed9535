//! The relief's `auto` switch against brute force: the bundled Moon with
//! the LOLA DEM (`shadows.displace`) rendered with the relief (`mode =
//! "always"`) and without (`"never"`) for a far full Moon, the bundled
//! 30° view and a close grazing view. Where `auto` says the relief's
//! effect is below the frame's per-pixel error target, the two renders
//! differ by less than the target at every pixel; where it says the
//! effect reaches the target, some pixel differs by at least that much;
//! and `auto` renders exactly one of the two.
//!
//! The difference of a pixel is |with − without| over the largest value
//! of either render in its 3 × 3 neighbourhood (a whole pixel of that
//! surface: a limb pixel's change is counted against it), floored at 1 %
//! of the brightest pixel, over the pixels above that floor in either
//! render: the measure the switch's estimate bounds
//! (`render::relief_effect`).

mod common;
use common::*;

use std::path::Path;
use std::sync::Arc;

use glam::{DQuat, DVec3};
use optistim::scene::horizon::{ReliefShadows, ShadowMode};
use optistim::scene::Scene;

/// The renderer's planner floor: pixels below it are judged against it.
const FLOOR: f64 = 0.01;

fn bundled_moon() -> Scene {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    Scene::from_file(&root.join("configs/moon.toml")).expect("bundled relief scene")
}

fn with_mode(scene: &Scene, mode: ShadowMode, target: Option<f64>) -> Scene {
    let mut s = scene.clone();
    let shadows = s
        .body
        .relief
        .shadows
        .clone()
        .expect("the bundled Moon has relief");
    s.body.relief.shadows = Some(Arc::new(ReliefShadows {
        mode,
        ..(*shadows).clone()
    }));
    s.render.max_pixel_error = target;
    s
}

fn attitude(pos: DVec3, target: DVec3) -> DQuat {
    let q = look_at(pos, target);
    DQuat::from_xyzw(q[1], q[2], q[3], q[0])
}

/// The camera resized to `px` square pixels over the same field.
fn resize(scene: &mut Scene, px: usize) {
    let pin = &mut scene.camera.pinhole;
    let k = px as f64 / pin.width as f64;
    (pin.width, pin.height) = (px, px);
    let c = px as f64 / 2.0;
    (pin.fx, pin.fy, pin.cx, pin.cy) = (pin.fx * k, pin.fy * k, c, c);
}

/// Largest and 99th-percentile difference between two renders (module doc).
fn difference(a: &[f32], b: &[f32], width: usize) -> (f64, f64) {
    let height = a.len() / width;
    let peak = a.iter().chain(b).fold(0.0f32, |m, &v| m.max(v)) as f64;
    let floor = FLOOR * peak;
    let mut diffs = Vec::new();
    for y in 0..height {
        for x in 0..width {
            let i = y * width + x;
            let (p, q) = (a[i] as f64, b[i] as f64);
            if p.max(q) < floor {
                continue;
            }
            let mut whole = floor;
            for yy in y.saturating_sub(1)..(y + 2).min(height) {
                for xx in x.saturating_sub(1)..(x + 2).min(width) {
                    let j = yy * width + xx;
                    whole = whole.max(a[j] as f64).max(b[j] as f64);
                }
            }
            diffs.push((p - q).abs() / whole);
        }
    }
    assert!(!diffs.is_empty(), "no lit pixel");
    diffs.sort_by(f64::total_cmp);
    let p99 = diffs[((diffs.len() as f64 * 0.99) as usize).min(diffs.len() - 1)];
    (diffs[diffs.len() - 1], p99)
}

/// Renders `scene` without and with its relief and under `auto` at each
/// target; checks the switch against the two renders' difference.
fn check(name: &str, scene: &Scene, targets: &[Option<f64>]) -> Vec<bool> {
    let never = render(&with_mode(scene, ShadowMode::Never, None)).radiance;
    let always = render(&with_mode(scene, ShadowMode::Always, None)).radiance;
    let (max, p99) = difference(&never, &always, scene.camera.pinhole.width);
    let mut applied = Vec::new();
    for &target in targets {
        let auto = render(&with_mode(scene, ShadowMode::Auto, target));
        let d = auto.summary.relief_shadows.expect("decision reported");
        let t = target.unwrap_or(optistim::render::relief::DEFAULT_TARGET);
        assert_eq!(d.target, t, "{name}: {d:?}");
        let estimate = d.shadow_effect.max(d.shading_effect).max(d.limb_effect);
        eprintln!(
            "{name}: target {t:e}: estimate {estimate:.3e} (shadow {:.3e}, shading {:.3e}, limb {:.3e}) -> {}; renders differ by max {max:.3e}, p99 {p99:.3e}",
            d.shadow_effect, d.shading_effect, d.limb_effect, d.reason
        );
        assert_eq!(d.applied, estimate >= t, "{name}: {d:?}");
        assert_eq!(d.displaced, d.applied, "{name}: {d:?}");
        if d.applied {
            assert!(max >= t, "{name}: applied at target {t}, but the relief changes no pixel by that much (max {max:e})");
            assert!(
                auto.radiance == always,
                "{name}: auto is not the relief render"
            );
        } else {
            assert!(
                max < t,
                "{name}: skipped at target {t}, but the relief changes a pixel by {max:e}"
            );
            assert!(
                auto.radiance == never,
                "{name}: auto is not the plain render"
            );
        }
        applied.push(d.applied);
    }
    applied
}

/// Far and full: the camera between the Sun and the Moon at 1.2e6 km,
/// 1024 px over the 6° field (the disk 28 px across).
#[test]
fn a_far_full_moon() {
    let mut scene = bundled_moon();
    let far = scene.state.sun_position.normalize() * 1.2e9;
    scene.state.camera_position = far;
    scene.state.camera_attitude = attitude(far, DVec3::ZERO);
    // At the default 1 % the limb's relief (8.6e-2 px) matters; at 10 %
    // nothing does (the slopes barely change a full Moon's shading).
    assert_eq!(check("far full", &scene, &[None, Some(0.1)]), [true, false]);
    // `[render] relief = false` (the governor's rungs) overrides even
    // `mode = "always"`: the plain render, bit for bit.
    let mut off = with_mode(&scene, ShadowMode::Always, None);
    off.render.relief = false;
    let off = render(&off);
    let d = off.summary.relief_shadows.expect("decision reported");
    assert!(
        !d.applied && !d.displaced && d.reason == "render.relief = false",
        "{d:?}"
    );
    assert!(off.radiance == render(&with_mode(&scene, ShadowMode::Never, None)).radiance);
}

/// The bundled Moon's own 30° view, 256 px over its field.
#[test]
fn a_mid_phase_moon() {
    let mut scene = bundled_moon();
    resize(&mut scene, 256);
    assert_eq!(check("30°", &scene, &[None, Some(0.5)]), [true, true]);
}

/// Close and grazing: 1.05 R from the centre above a point of the
/// terminator, looking 20° off nadir toward the lit side, 128 px.
#[test]
fn a_close_grazing_view() {
    let mut scene = bundled_moon();
    let radius = scene.body.radius;
    let to_sun = scene.state.sun_position.normalize();
    let across = to_sun.cross(DVec3::Z).normalize();
    let close = across * (1.05 * radius);
    let target = across * radius + to_sun * (0.05 * radius * 20f64.to_radians().tan());
    scene.state.camera_position = close;
    scene.state.camera_attitude = attitude(close, target);
    resize(&mut scene, 128);
    assert_eq!(
        check("close grazing", &scene, &[None, Some(0.5)]),
        [true, true]
    );
}
