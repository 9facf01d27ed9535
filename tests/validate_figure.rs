//! Four-panel comparison PNG: layout, separators and colour maps.

use optistim::validate::figure::{self, FigureOptions};
use optistim::validate::ssim::ssim;
use optistim::validate::Raster;

#[test]
fn four_panels_with_separators() {
    let (w, h) = (40, 30);
    let real = Raster::from_fn(w, h, |c, r| (c + r) as f32);
    let mut render = real.clone();
    *render.get_mut(10, 10) -= 20.0; // real > render -> red
    *render.get_mut(20, 15) += 20.0; // real < render -> blue
    let s = ssim(&real, &render, 100.0).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("cmp.png");
    figure::write_comparison_png(
        &p,
        &real,
        &render,
        &s,
        &FigureOptions {
            grey_max: Some(68.0),
            diff_range: Some(20.0),
            gamma: None,
        },
    )
    .unwrap();
    let img = image::open(&p).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), ((4 * w + 3) as u32, h as u32));
    for k in 1..4u32 {
        let x = k * (w as u32 + 1) - 1;
        for y in 0..h as u32 {
            assert_eq!(*img.get_pixel(x, y), figure::SEPARATOR);
        }
    }
    // Grey panels: 0 is black, 68 is white.
    assert_eq!(img.get_pixel(0, 0).0, [0, 0, 0]);
    assert_eq!(img.get_pixel(39, 29).0, [255, 255, 255]);
    assert_eq!(img.get_pixel(41, 0).0, [0, 0, 0]);
    // Difference panel.
    let dx = 2 * (w as u32 + 1);
    assert_eq!(img.get_pixel(dx + 10, 10).0, [255, 0, 0]);
    assert_eq!(img.get_pixel(dx + 20, 15).0, [0, 0, 255]);
    assert_eq!(img.get_pixel(dx, 0).0, [255, 255, 255]);
    // SSIM panel: border grey, identical regions yellow (SSIM = 1).
    let sx = 3 * (w as u32 + 1);
    assert_eq!(*img.get_pixel(sx, 0), figure::SSIM_BORDER);
    assert_eq!(img.get_pixel(sx + 30, 5).0, [255, 255, 0]);
    // Mismatched sizes are refused.
    let small = Raster::filled(20, 20, 0.0);
    assert!(figure::comparison_figure(&small, &small, &s, &FigureOptions::default()).is_err());
}
