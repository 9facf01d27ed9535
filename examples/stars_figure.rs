//! The README's stars figure: a rendered frame with the sensor's noise and
//! the bundled catalogue's stars, the Moon saturated by a long exposure.
//!
//!     cargo run --release --example stars_figure -- [SCENE] [OUT.png]
//!
//! Defaults: configs/moon_stars.toml, docs/moon_stars.png.

use std::path::PathBuf;

use optistim::figures::{draw_png, image_panel, text_block, ColourMap, ImagePanel};
use optistim::render::detector::{render_scene, PixelGeometry};
use optistim::render::Renderer;
use optistim::scene::Scene;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let scene_path = PathBuf::from(
        args.first()
            .map_or("configs/moon_stars.toml", String::as_str),
    );
    let out = PathBuf::from(args.get(1).map_or("docs/moon_stars.png", String::as_str));
    let scene = Scene::from_file(&scene_path)?;
    let pin = scene.camera.pinhole.clone();
    let mut renderer = Renderer::new(pin.clone());
    let pixels = PixelGeometry::new(&renderer);
    let images = render_scene(&scene, &mut renderer, &pixels)?;
    // The central half of the frame (the cluster and the Moon), in log10
    // of the DN: the faint stars and the saturated Moon in one scale.
    let (x0, y0, side) = (pin.width / 4 - 64, pin.height / 4 + 56, pin.width / 2);
    let values: Vec<f64> = (0..side * side)
        .map(|k| {
            let (i, j) = (x0 + k % side, y0 + k / side);
            (images.dn[j * pin.width + i].max(1) as f64).log10()
        })
        .collect();
    let floor = scene.camera.sensor.map_or(0.0, |s| s.offset).max(1.0);
    let max_dn = scene.camera.max_dn();
    let stars = images.summary.stars.as_ref();
    let drawn = stars.map_or(0, |s| s.in_field - s.occulted);
    let occulted = stars.map_or(0, |s| s.occulted);
    let panel = ImagePanel {
        title: format!(
            "DN, {} ms exposure: {drawn} stars in the frame (V <= {:.1}), {occulted} behind the Moon",
            scene.camera.exposure * 1e3,
            stars.map_or(f64::NAN, |s| s.mag_limit)
        ),
        value_label: "log10(DN)".into(),
        origin: (x0 as f64, y0 as f64),
        width: side,
        height: side,
        values: &values,
        range: (floor.log10(), max_dn.log10()),
        map: ColourMap::Grey,
        circle: None,
    };
    draw_png(&out, (1100, 1180), |root| {
        let (head, body) = root.split_vertically(70);
        let lines = [
            format!(
                "{}: the Moon beside the Pleiades with sensor noise",
                scene_path.display()
            ),
            "the central 512 x 512 px of the frame; bundled Hipparcos stars, Gaussian PSF (sigma 0.8 px)".into(),
        ];
        text_block(&head, &lines, 20, &out)?;
        image_panel(&body, &panel, &out)
    })?;
    println!(
        "wrote {} ({drawn} stars drawn, {occulted} occulted, {} saturated pixels)",
        out.display(),
        images.summary.saturated_pixels
    );
    Ok(())
}
