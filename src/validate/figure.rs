//! Comparison figures: one PNG with four panels side by side, separated by a
//! 1-px white line: the real image, the render (both on the same grey
//! scale), the signed difference real − render (blue–white–red, symmetric
//! range) and the SSIM map (black → yellow over [0, 1], placed at its offset
//! inside a grey panel of the image size). No text is drawn.

use std::path::Path;

use image::{Rgb, RgbImage};

use super::raster::Raster;
use super::ssim::SsimResult;
use crate::error::{Error, Result};

/// Display ranges of the figure.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FigureOptions {
    /// Value shown white in the real and render panels (default: the larger
    /// maximum of the two; 0 is black).
    pub grey_max: Option<f32>,
    /// |real − render| shown fully saturated (default: max |difference|).
    pub diff_range: Option<f32>,
    /// Gamma applied to the grey panels (default 1: linear).
    pub gamma: Option<f32>,
}

/// Separator colour.
pub const SEPARATOR: Rgb<u8> = Rgb([255, 255, 255]);
/// Colour of the SSIM panel outside the map.
pub const SSIM_BORDER: Rgb<u8> = Rgb([64, 64, 64]);

fn to_u8(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// Blue (−1) – white (0) – red (+1).
pub fn diverging(t: f32) -> Rgb<u8> {
    let t = t.clamp(-1.0, 1.0);
    if t >= 0.0 {
        Rgb([255, to_u8(1.0 - t), to_u8(1.0 - t)])
    } else {
        Rgb([to_u8(1.0 + t), to_u8(1.0 + t), 255])
    }
}

/// Black (0) – red – yellow (1) ramp for SSIM values.
pub fn heat(t: f32) -> Rgb<u8> {
    let t = t.clamp(0.0, 1.0);
    Rgb([to_u8(2.0 * t), to_u8(2.0 * t - 1.0), 0])
}

/// Builds the four-panel figure.
pub fn comparison_figure(
    real: &Raster,
    render: &Raster,
    ssim: &SsimResult,
    opts: &FigureOptions,
) -> Result<RgbImage> {
    real.check_same_size(render, "figure")?;
    let (w, h) = (real.width, real.height);
    if ssim.map.width + 2 * ssim.offset != w || ssim.map.height + 2 * ssim.offset != h {
        return Err(Error::invalid(
            "figure.ssim",
            "SSIM map does not belong to images of this size",
        ));
    }
    let gmax = opts.grey_max.unwrap_or_else(|| {
        let m = |r: &Raster| r.min_max().map(|(_, hi)| hi).unwrap_or(1.0);
        m(real).max(m(render))
    });
    let gmax = if gmax > 0.0 { gmax } else { 1.0 };
    let gamma = opts.gamma.unwrap_or(1.0);
    let diff: Vec<f32> = real
        .data
        .iter()
        .zip(&render.data)
        .map(|(a, b)| a - b)
        .collect();
    let drange = opts
        .diff_range
        .unwrap_or_else(|| diff.iter().fold(0.0f32, |m, d| m.max(d.abs())));
    let drange = if drange > 0.0 { drange } else { 1.0 };

    let fw = 4 * w + 3;
    let mut out = RgbImage::from_pixel(fw as u32, h as u32, SEPARATOR);
    for r in 0..h {
        for c in 0..w {
            let grey = |v: f32| {
                let g = to_u8((v / gmax).max(0.0).powf(1.0 / gamma));
                Rgb([g, g, g])
            };
            out.put_pixel(c as u32, r as u32, grey(real.get(c, r)));
            out.put_pixel((w + 1 + c) as u32, r as u32, grey(render.get(c, r)));
            out.put_pixel(
                (2 * (w + 1) + c) as u32,
                r as u32,
                diverging(diff[r * w + c] / drange),
            );
            let o = ssim.offset;
            let s = if r >= o && c >= o && r < o + ssim.map.height && c < o + ssim.map.width {
                heat(ssim.map.get(c - o, r - o))
            } else {
                SSIM_BORDER
            };
            out.put_pixel((3 * (w + 1) + c) as u32, r as u32, s);
        }
    }
    Ok(out)
}

/// Builds the figure and writes it as PNG.
pub fn write_comparison_png(
    path: impl AsRef<Path>,
    real: &Raster,
    render: &Raster,
    ssim: &SsimResult,
    opts: &FigureOptions,
) -> Result<()> {
    let path = path.as_ref();
    let img = comparison_figure(real, render, ssim, opts)?;
    img.save_with_format(path, image::ImageFormat::Png)
        .map_err(|e| Error::io(path, std::io::Error::other(e.to_string())))
}

/// Writes a single image as an 8-bit grey PNG, `max` shown white.
pub fn write_grey_png(path: impl AsRef<Path>, img: &Raster, max: f32) -> Result<()> {
    let path = path.as_ref();
    let max = if max > 0.0 { max } else { 1.0 };
    let buf = image::GrayImage::from_fn(img.width as u32, img.height as u32, |c, r| {
        image::Luma([to_u8(img.get(c as usize, r as usize) / max)])
    });
    buf.save_with_format(path, image::ImageFormat::Png)
        .map_err(|e| Error::io(path, std::io::Error::other(e.to_string())))
}
