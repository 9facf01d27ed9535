//! The README's stars figure: a rendered frame with the sensor's noise and
//! the bundled catalogue's stars, the Moon saturated by a long exposure,
//! beside its exact labels around the Moon (masks, depth, latitude) and
//! the count of stars `labels.json` lists.
//!
//!     cargo run --release --example stars_figure -- [SCENE] [OUT.png]
//!
//! Defaults: configs/moon_stars.toml, docs/moon_stars.png.

use std::path::PathBuf;

use optistim::figures::{draw_png, image_panel, text_block, ColourMap, ImagePanel};
use optistim::labels;
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
    let mut l = labels::compute(&pin, &scene.state, scene.body.radius, None);
    labels::add_stars(&mut l, &scene);
    let listed = l.frame.stars.len();
    // The labels around the Moon: its disk and a third of a radius more.
    let d = &l.frame.disk;
    let (cx, cy) = d.projected_centre.map_or((0.0, 0.0), |c| (c[0], c[1]));
    let half = (d.apparent_radius_px * 1.35).ceil() as usize;
    let zx = (cx as usize).saturating_sub(half).min(pin.width - 2 * half);
    let zy = (cy as usize)
        .saturating_sub(half)
        .min(pin.height - 2 * half);
    let zoom = |f: &dyn Fn(usize) -> f64| -> Vec<f64> {
        (0..4 * half * half)
            .map(|k| f((zy + k / (2 * half)) * pin.width + zx + k % (2 * half)))
            .collect()
    };
    let im = &l.images;
    let on_body = |k: usize, v: f64| if im.body[k] == 1 { v } else { f64::NAN };
    let masks = zoom(&|k| (im.body[k] + im.lit[k] - im.shadow[k]) as f64);
    let depth = zoom(&|k| on_body(k, im.depth[k] as f64 / 1e6));
    let lat = zoom(&|k| on_body(k, (im.latitude[k] as f64).to_degrees()));
    let finite = |v: &[f64]| {
        let f = v.iter().copied().filter(|x| x.is_finite());
        (
            f.clone().fold(f64::INFINITY, f64::min),
            f.fold(f64::NEG_INFINITY, f64::max),
        )
    };
    let limb = Some((cx, cy, d.apparent_radius_px));
    let label_panel = |title: &str, unit: &str, values, range, map| ImagePanel {
        title: title.into(),
        value_label: unit.into(),
        origin: (zx as f64, zy as f64),
        width: 2 * half,
        height: 2 * half,
        values,
        range,
        map,
        circle: limb,
    };
    let labels_panels = [
        label_panel(
            "labels: 0 sky, 1 body, 2 lit",
            "mask",
            &masks,
            (0.0, 2.0),
            ColourMap::Viridis,
        ),
        label_panel(
            "labels: depth",
            "depth (1000 km)",
            &depth,
            finite(&depth),
            ColourMap::Viridis,
        ),
        label_panel(
            "labels: latitude",
            "latitude (deg)",
            &lat,
            finite(&lat),
            ColourMap::Diverging,
        ),
    ];
    draw_png(&out, (1600, 1180), |root| {
        let (head, body) = root.split_vertically(70);
        let lines = [
            format!(
                "{}: the Moon beside the Pleiades with sensor noise, and its exact labels",
                scene_path.display()
            ),
            format!("left: the central 512 x 512 px of the frame; bundled Hipparcos stars, Gaussian PSF (sigma 0.8 px); labels.json lists {listed} stars in the image. Right: labels around the Moon (orange: limb)"),
        ];
        text_block(&head, &lines, 18, &out)?;
        let (left, right) = body.split_horizontally(1000);
        image_panel(&left, &panel, &out)?;
        for (area, p) in right.split_evenly((3, 1)).iter().zip(&labels_panels) {
            image_panel(area, p, &out)?;
        }
        Ok(())
    })?;
    println!(
        "wrote {} ({drawn} stars drawn, {occulted} occulted, {} saturated pixels)",
        out.display(),
        images.summary.saturated_pixels
    );
    Ok(())
}
