//! The bundled examples load and do what their comments say: one scene per
//! reflection model renders a finite, lit Moon of the expected size; the
//! close-range scene runs off the frame's left edge with its lit limb in
//! view; the roughness-map scene's map is seen; the facility examples per
//! common screen load at their sizes.

use std::path::{Path, PathBuf};

use optistim::facility::config::FacilityConfig;
use optistim::render::detector::{render_scene, PixelGeometry};
use optistim::render::Renderer;
use optistim::scene::Scene;

fn configs() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("configs")
}

/// Renders `file`; returns the radiance, checked finite and non-negative.
fn render(file: &Path) -> (Scene, Vec<f32>) {
    let scene = Scene::from_file(file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
    let mut renderer = Renderer::new(scene.camera.pinhole.clone());
    let pixels = PixelGeometry::new(&renderer);
    let images = render_scene(&scene, &mut renderer, &pixels).unwrap();
    for (k, &v) in images.radiance.iter().enumerate() {
        assert!(
            v.is_finite() && v >= 0.0,
            "{}: pixel {k} = {v}",
            file.display()
        );
    }
    assert!(images.summary.saturated_pixels == 0, "{}", file.display());
    (scene, images.radiance)
}

/// Every model family of `ReflectanceConfig` has its example, each renders
/// a lit area within 10 % of the lit fraction of the disk, (1 + cos α)/2 of
/// π r², r from the pinhole's focal length and the Moon's angular radius.
#[test]
fn one_example_per_reflection_model_renders_a_lit_moon() {
    let models = [
        "area",
        "lambert",
        "lommel_seeliger",
        "oren_nayar",
        "oren_nayar_qualitative",
        "lunar_lambert",
        "minnaert",
        "hapke",
    ];
    for model in models {
        let file = configs().join(format!("examples/moon_{model}.toml"));
        let (scene, radiance) = render(&file);
        // The file is the model it is named after.
        let toml = format!("model = \"{model}\"");
        assert!(std::fs::read_to_string(&file).unwrap().contains(&toml));
        assert_eq!(scene.body.reflectance.name(), model, "{}", file.display());

        let st = &scene.state;
        let range = (st.camera_position - st.body_position).length();
        let sun = (st.sun_position - st.body_position).normalize();
        let view = (st.camera_position - st.body_position).normalize();
        let phase = sun.dot(view).clamp(-1.0, 1.0).acos();
        let f_px = scene.camera.pinhole.fx;
        let r_px = f_px * (scene.body.radius / range).asin().tan();
        let expected = std::f64::consts::PI * r_px * r_px * (1.0 + phase.cos()) / 2.0;
        let lit = radiance.iter().filter(|&&v| v > 0.0).count() as f64;
        assert!(
            (lit / expected - 1.0).abs() < 0.1,
            "{model}: {lit} lit pixels, expected ~{expected:.0}"
        );
    }
}

#[test]
fn close_range_example_runs_off_the_left_edge_with_its_limb_in_view() {
    let (scene, radiance) = render(&configs().join("examples/phobos_close_range.toml"));
    let (w, h) = (scene.camera.pinhole.width, scene.camera.pinhole.height);
    let lit = |x: usize, y: usize| radiance[y * w + x] > 0.0;
    let column = |x: usize| (0..h).filter(|&y| lit(x, y)).count();
    // A few body radii: the camera is within 5 radii of the centre.
    let st = &scene.state;
    let range = (st.camera_position - st.body_position).length();
    assert!(range < 5.0 * scene.body.radius);
    assert!(column(0) > h / 2, "left edge: {} lit", column(0));
    assert_eq!(column(w - 1), 0, "the right edge shows sky");
    // The lit limb crosses the middle row inside the frame.
    let row: Vec<bool> = (0..w).map(|x| lit(x, h / 2)).collect();
    let last = row.iter().rposition(|&l| l).unwrap();
    assert!(last > w / 2 && last < w - 1, "limb at x = {last}");
}

#[test]
fn facility_examples_per_common_screen_load_at_their_size() {
    for (w, h) in [(1920, 1080), (2560, 1440), (3840, 2160)] {
        let file = configs().join(format!("bench_facility_{w}.toml"));
        let config = FacilityConfig::load(&file).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(config.screen_size(), (w, h), "{}", file.display());
        // The comments' µrad per screen pixel is pitch / collimator focal length.
        let text = std::fs::read_to_string(&file).unwrap();
        let ifov = config.screen.pixel_pitch / config.collimator.focal_length * 1e6;
        assert!(
            text.contains(&format!("{ifov:.1} µrad")),
            "{}: {ifov:.1}",
            file.display()
        );
        assert!(text.contains(&format!("{w}×{h}")));
    }
}

/// The roughness-map example differs from the uniform Oren–Nayar example
/// only by its σ map: the two images' ratio varies across the disk (the
/// map is seen), and the lit area is the same.
#[test]
fn roughness_map_example_varies_the_brightness_across_the_disk() {
    let (scene, mapped) = render(&configs().join("examples/moon_oren_nayar_roughness_map.toml"));
    assert_eq!(scene.body.parameter_maps.len(), 1);
    let (_, uniform) = render(&configs().join("examples/moon_oren_nayar.toml"));
    let peak = uniform.iter().cloned().fold(0.0f32, f32::max);
    let ratios: Vec<f32> = mapped
        .iter()
        .zip(&uniform)
        .filter(|(_, &u)| u > 0.2 * peak)
        .map(|(&m, &u)| m / u)
        .collect();
    let lo = ratios.iter().cloned().fold(f32::INFINITY, f32::min);
    let hi = ratios.iter().cloned().fold(0.0f32, f32::max);
    eprintln!(
        "mapped / uniform over {} pixels: {lo:.4} … {hi:.4}",
        ratios.len()
    );
    assert!(ratios.len() > 10_000);
    assert!(hi / lo > 1.02, "the σ map is not seen: {lo} … {hi}");
    let lit = |v: &[f32]| v.iter().filter(|&&x| x > 0.0).count() as f64;
    assert!((lit(&mapped) / lit(&uniform) - 1.0).abs() < 1e-3);
}
