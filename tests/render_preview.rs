//! `render`'s quick-look `preview.png`: 8-bit, the camera's size, and the
//! stretch stated in `summary.json` applied to `dn.png` gives it pixel for
//! pixel; the sky is black and the brightest pixel white.

mod common;
use common::*;

use std::path::Path;

use optistim::render::output;
use optistim::scene::Scene;

const LAMBERT: &str = "{ model = \"lambert\", albedo = 0.3 }";

#[test]
fn preview_is_the_stated_stretch_of_dn() {
    // The test camera's full well (1e30 e⁻) leaves every DN at 0: set it
    // to 1.25× the brightest pixel's electrons, so the disk spans the DN range.
    let setup = Setup::new(LAMBERT, 40.0, 20.0, 60.0);
    let peak_e = render(&setup.scene())
        .electrons
        .iter()
        .fold(0.0f32, |m, &e| m.max(e)) as f64;
    assert!(peak_e > 0.0);
    let toml = setup.toml().replace(
        "full_well = 1e30",
        &format!("full_well = {:e}", 1.25 * peak_e),
    );
    let scene = Scene::from_toml(&toml, Path::new("preview-scene.toml")).unwrap();
    let images = render(&scene);
    let (w, h) = (scene.camera.pinhole.width, scene.camera.pinhole.height);
    let dir = tempfile::tempdir().unwrap();
    output::write_render(dir.path(), w, h, &images).unwrap();

    let dn = image::open(dir.path().join("dn.png")).unwrap().to_luma16();
    let preview = image::open(dir.path().join("preview.png")).unwrap();
    assert_eq!(preview.color(), image::ColorType::L8, "8-bit grey");
    let preview = preview.to_luma8();
    assert_eq!((preview.width(), preview.height()), (w as u32, h as u32));

    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("summary.json")).unwrap())
            .unwrap();
    assert!(
        summary["phase_angle_deg"].is_number(),
        "render numbers kept"
    );
    let p = &summary["preview"];
    assert_eq!(p["file"], "preview.png");
    let black = p["black_dn"].as_f64().unwrap();
    let white = p["white_dn"].as_f64().unwrap();
    let gamma = p["gamma"].as_f64().unwrap();

    // The stated rule, recomputed here: 99.9th percentile (nearest rank)
    // of the lit pixels of dn.png.
    let mut lit: Vec<u16> = dn.pixels().map(|p| p.0[0]).filter(|&v| v > 0).collect();
    lit.sort_unstable();
    assert!(lit.len() > 1000, "the disk is lit: {} px", lit.len());
    let rank = (0.999 * lit.len() as f64).ceil() as usize;
    assert_eq!(white, lit[rank - 1] as f64);
    assert_eq!((black, gamma), (0.0, 1.0));

    // The stretch formula applied to dn.png gives preview.png.
    for (d, g) in dn.pixels().zip(preview.pixels()) {
        let t = ((d.0[0] as f64 - black) / (white - black)).clamp(0.0, 1.0);
        let want = (255.0 * t.powf(1.0 / gamma)).round() as u8;
        assert_eq!(g.0[0], want, "DN {}", d.0[0]);
    }
    let brightest = (0..dn.as_raw().len())
        .max_by_key(|&k| dn.as_raw()[k])
        .unwrap();
    assert_eq!(preview.as_raw()[brightest], 255, "brightest pixel white");
    // Corner: dark sky, DN 0, black.
    assert_eq!(dn.get_pixel(0, 0).0[0], 0);
    assert_eq!(preview.get_pixel(0, 0).0[0], 0, "sky black");
}

#[test]
fn all_dark_image_previews_black() {
    let p = output::Preview::for_dn(&[0; 16]);
    assert_eq!((p.black_dn, p.white_dn), (0, 1));
    assert_eq!(p.grey(0), 0);
}
