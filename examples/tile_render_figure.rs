//! Figure of a close-range render over a DEM tile: the rendered radiance
//! (grey, W m⁻² sr⁻¹) beside the tile's heights (viridis, m), each with a
//! colour bar. Run after rendering the example scene:
//!
//! ```text
//! cargo run --release -- render configs/examples/moon_polar_crater_field.toml --out out/polar
//! cargo run --release --example tile_render_figure -- out/polar/radiance.tiff \
//!     data/tiles/crater_field_s85.tif docs/tiles_polar_crater_field.png
//! ```

use std::path::Path;

use optistim::figures::{draw_png, image_panel, ColourMap, ImagePanel};
use optistim::scene::EquirectMap;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [radiance, tile, out] = args.as_slice() else {
        eprintln!("usage: tile_render_figure RADIANCE_TIFF TILE_TIFF OUT_PNG");
        std::process::exit(2);
    };
    let load = |p: &str| {
        EquirectMap::load(Path::new(p)).unwrap_or_else(|e| {
            eprintln!("tile_render_figure: {e}");
            std::process::exit(2);
        })
    };
    let (r, t) = (load(radiance), load(tile));
    let values = |m: &EquirectMap| m.data.iter().map(|&v| v as f64).collect::<Vec<f64>>();
    let (rv, tv) = (values(&r), values(&t));
    let range = |v: &[f64], q: f64| {
        let mut s = v.to_vec();
        s.sort_by(f64::total_cmp);
        (s[0], s[((s.len() - 1) as f64 * q) as usize])
    };
    let out = Path::new(out);
    draw_png(out, (1500, 640), |root| {
        let (left, right) = root.split_horizontally(750);
        image_panel(
            &left,
            &ImagePanel {
                title: "Render: 10 km over (−85.5°, 0°), Sun 4.5° high in the north (up)".into(),
                value_label: "radiance (W m⁻² sr⁻¹)".into(),
                origin: (0.0, 0.0),
                width: r.width,
                height: r.height,
                values: &rv,
                range: range(&rv, 0.999),
                map: ColourMap::Grey,
                circle: None,
            },
            out,
        )?;
        image_panel(
            &right,
            &ImagePanel {
                title: "DEM tile: 256 × 256 cells of 40 m (north up)".into(),
                value_label: "height above 1737.4 km (m)".into(),
                origin: (0.0, 0.0),
                width: t.width,
                height: t.height,
                values: &tv,
                range: range(&tv, 1.0),
                map: ColourMap::Viridis,
                circle: None,
            },
            out,
        )
    })
    .unwrap_or_else(|e| {
        eprintln!("tile_render_figure: {e}");
        std::process::exit(1);
    });
}
