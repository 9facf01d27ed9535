//! The README's labels figure: a rendered frame beside its exact labels
//! (masks, depth, world normal z, latitude, longitude), with the limb
//! circle of the label record drawn over each panel.
//!
//!     cargo run --release --example labels_figure -- [SCENE] [OUT.png]
//!
//! Defaults: configs/moon.toml, docs/labels.png.

use std::path::PathBuf;

use optistim::figures::{draw_png, image_panel, text_block, ColourMap, ImagePanel};
use optistim::labels;
use optistim::render::detector::{render_scene, PixelGeometry};
use optistim::render::Renderer;
use optistim::scene::Scene;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let scene_path = PathBuf::from(args.first().map_or("configs/moon.toml", String::as_str));
    let out = PathBuf::from(args.get(1).map_or("docs/labels.png", String::as_str));
    let scene = Scene::from_file(&scene_path)?;
    let pin = scene.camera.pinhole.clone();
    let mut renderer = Renderer::new(pin.clone());
    let pixels = PixelGeometry::new(&renderer);
    let images = render_scene(&scene, &mut renderer, &pixels)?;
    let l = labels::compute(&pin, &scene.state, scene.body.radius, None);
    let im = &l.images;
    let on_body = |k: usize, v: f64| if im.body[k] == 1 { v } else { f64::NAN };
    let dn: Vec<f64> = images.dn.iter().map(|&v| v as f64).collect();
    let masks: Vec<f64> = (0..im.body.len())
        .map(|k| (im.body[k] + im.lit[k] - im.shadow[k]) as f64)
        .collect();
    let depth: Vec<f64> = (0..im.depth.len())
        .map(|k| on_body(k, im.depth[k] as f64 / 1e3))
        .collect();
    let nz: Vec<f64> = (0..im.depth.len())
        .map(|k| on_body(k, im.normals[3 * k + 2] as f64))
        .collect();
    let deg = |v: &[f32]| -> Vec<f64> {
        (0..v.len())
            .map(|k| on_body(k, (v[k] as f64).to_degrees()))
            .collect()
    };
    let (lat, lon) = (deg(&im.latitude), deg(&im.longitude));
    let range = |v: &[f64]| {
        let f = v.iter().copied().filter(|x| x.is_finite());
        (
            f.clone().fold(f64::INFINITY, f64::min),
            f.fold(f64::NEG_INFINITY, f64::max),
        )
    };
    let d = &l.frame.disk;
    let circle = d
        .projected_centre
        .map(|c| (c[0], c[1], d.apparent_radius_px));
    let max_dn = dn.iter().copied().fold(1.0, f64::max);
    let panel = |title: &str, label: &str, values, r, map| {
        make_panel(
            title,
            label,
            values,
            r,
            map,
            (pin.width, pin.height),
            circle,
        )
    };
    let panels = [
        panel(
            "rendered frame (DN)",
            "DN",
            &dn,
            (0.0, max_dn),
            ColourMap::Grey,
        ),
        panel(
            "masks: 0 sky, 1 body, 2 lit",
            "mask",
            &masks,
            (0.0, 2.0),
            ColourMap::Viridis,
        ),
        panel(
            "depth (range along the ray)",
            "depth (km)",
            &depth,
            range(&depth),
            ColourMap::Viridis,
        ),
        panel(
            "surface normal, world z",
            "n_z",
            &nz,
            (-1.0, 1.0),
            ColourMap::Diverging,
        ),
        panel(
            "latitude",
            "latitude (deg)",
            &lat,
            (-90.0, 90.0),
            ColourMap::Diverging,
        ),
        panel(
            "east longitude",
            "longitude (deg)",
            &lon,
            (-180.0, 180.0),
            ColourMap::Diverging,
        ),
    ];
    let size = (1600, 1900);
    draw_png(&out, size, |root| {
        let (head, grid) = root.split_vertically(44);
        let title = format!(
            "{}: frame and exact labels (phase {:.1} deg, disk radius {:.1} px; orange: limb)",
            scene_path.display(),
            l.frame.phase_angle_rad.to_degrees(),
            d.apparent_radius_px
        );
        text_block(&head, &[title], 22, &out)?;
        for (area, p) in grid.split_evenly((3, 2)).iter().zip(&panels) {
            image_panel(area, p, &out)?;
        }
        Ok(())
    })?;
    println!("wrote {}", out.display());
    Ok(())
}

/// One panel over the whole frame.
fn make_panel<'a>(
    title: &str,
    label: &str,
    values: &'a [f64],
    range: (f64, f64),
    map: ColourMap,
    (width, height): (usize, usize),
    circle: Option<(f64, f64, f64)>,
) -> ImagePanel<'a> {
    ImagePanel {
        title: title.into(),
        value_label: label.into(),
        origin: (0.0, 0.0),
        width,
        height,
        values,
        range,
        map,
        circle,
    }
}
