//! Comparison figures of `validate amie`, drawn with [`crate::figures`]:
//!
//! - `comparison.png`: four panels cropped around the aligned disk (disk +
//!   [`CROP_MARGIN`] of its radius): real and render on one grey scale, the
//!   difference real − render on a diverging scale symmetric about 0, and
//!   the SSIM map (0..1), each with a colour bar and the disk's limb
//!   outlined; the run's numbers below.
//! - `profile.png`: real and render along the line through the disk centre
//!   towards the lit side's centroid (crossing the bright limb and the
//!   terminator), with their difference below.

use std::path::Path;

use super::background::Disk;
use super::raster::Raster;
use super::ssim::SsimResult;
use crate::error::{Error, Result};
use crate::figures::{
    curve_figure, draw_png, image_panel, text_block, ColourMap, CurveFigure, ImagePanel, Panel,
    Series,
};

/// Crop margin around the disk, in disk radii.
pub const CROP_MARGIN: f64 = 0.25;
/// Pixel size of `comparison.png`.
pub const COMPARISON_SIZE: (u32, u32) = (1500, 1400);
/// Pixel size of `profile.png`.
pub const PROFILE_SIZE: (u32, u32) = (1100, 750);
/// Percentile of |real − render| in the crop at the ends of the
/// difference scale (a few hot pixels do not wash it out).
pub const DIFF_PERCENTILE: f64 = 99.5;

/// What the comparison figures show.
pub struct Comparison<'a> {
    /// Background-free real image [DN].
    pub real: &'a Raster,
    /// Aligned render, scaled to the real signal [DN].
    pub render: &'a Raster,
    pub ssim: &'a SsimResult,
    /// The aligned disk (crop centre and radius), px.
    pub disk: Disk,
    /// Figure title (product, model).
    pub title: String,
    /// Numbers printed under the panels, one per line.
    pub notes: Vec<String>,
}

/// Crop `[x0, x1) × [y0, y1)` around the disk, inside the image.
pub fn crop(disk: &Disk, width: usize, height: usize) -> (usize, usize, usize, usize) {
    let half = disk.radius * (1.0 + CROP_MARGIN) + 2.0;
    let clamp = |v: f64, n: usize| {
        if v.is_finite() {
            v.clamp(0.0, n as f64) as usize
        } else {
            0
        }
    };
    let (x0, x1) = (clamp(disk.cx - half, width), clamp(disk.cx + half, width));
    let (y0, y1) = (clamp(disk.cy - half, height), clamp(disk.cy + half, height));
    if x1 > x0 && y1 > y0 {
        (x0, x1, y0, y1)
    } else {
        (0, width, 0, height)
    }
}

/// `f(col, row)` over the crop, row-major.
fn over_crop(c: (usize, usize, usize, usize), f: impl Fn(usize, usize) -> f64) -> Vec<f64> {
    let (x0, x1, y0, y1) = c;
    (y0..y1)
        .flat_map(|r| (x0..x1).map(move |col| (col, r)))
        .map(|(col, r)| f(col, r))
        .collect()
}

/// Nearest-rank `p`-th percentile of |v| (0 when empty).
fn abs_percentile(v: &[f64], p: f64) -> f64 {
    let mut a: Vec<f64> = v
        .iter()
        .filter(|x| x.is_finite())
        .map(|x| x.abs())
        .collect();
    if a.is_empty() {
        return 0.0;
    }
    a.sort_by(f64::total_cmp);
    let k = (p / 100.0 * a.len() as f64).ceil() as usize;
    a[k.clamp(1, a.len()) - 1]
}

/// Largest real value inside the disk [DN].
fn disk_peak(real: &Raster, disk: &Disk) -> f64 {
    let mut peak = 0.0f64;
    for r in 0..real.height {
        for c in 0..real.width {
            if disk.limb_distance(c as f64 + 0.5, r as f64 + 0.5) <= 0.0 {
                peak = peak.max(real.get(c, r) as f64);
            }
        }
    }
    peak
}

fn check(cmp: &Comparison) -> Result<()> {
    cmp.real.check_same_size(cmp.render, "figure")?;
    let (w, h, s) = (cmp.real.width, cmp.real.height, cmp.ssim);
    if s.map.width + 2 * s.offset != w || s.map.height + 2 * s.offset != h {
        return Err(Error::invalid(
            "figure.ssim",
            "SSIM map does not belong to images of this size",
        ));
    }
    Ok(())
}

/// Writes `comparison.png`.
pub fn write_comparison_png(path: impl AsRef<Path>, cmp: &Comparison) -> Result<()> {
    let path = path.as_ref();
    check(cmp)?;
    let (real, render) = (cmp.real, cmp.render);
    let c = crop(&cmp.disk, real.width, real.height);
    let (cw, ch) = (c.1 - c.0, c.3 - c.2);
    let real_v = over_crop(c, |x, y| real.get(x, y) as f64);
    let render_v = over_crop(c, |x, y| render.get(x, y) as f64);
    let diff: Vec<f64> = real_v.iter().zip(&render_v).map(|(a, b)| a - b).collect();
    let o = cmp.ssim.offset;
    let ssim_v = over_crop(c, |x, y| {
        let (i, j) = (x.wrapping_sub(o), y.wrapping_sub(o));
        if i < cmp.ssim.map.width && j < cmp.ssim.map.height {
            cmp.ssim.map.get(i, j) as f64
        } else {
            f64::NAN
        }
    });
    let grey_max =
        real_v
            .iter()
            .chain(&render_v)
            .fold(0.0f64, |m, &v| if v.is_finite() { m.max(v) } else { m });
    let d = abs_percentile(&diff, DIFF_PERCENTILE).max(1e-6);
    let peak = disk_peak(real, &cmp.disk);
    let pct = if peak > 0.0 {
        100.0 * d / peak
    } else {
        f64::NAN
    };
    let panel = |title: String, label: &str, values, range, map| ImagePanel {
        title,
        value_label: label.into(),
        origin: (c.0 as f64, c.2 as f64),
        width: cw,
        height: ch,
        values,
        range,
        map,
        circle: Some((cmp.disk.cx, cmp.disk.cy, cmp.disk.radius)),
    };
    let panels = [
        panel(
            "real (background removed)".into(),
            "DN",
            &real_v,
            (0.0, grey_max),
            ColourMap::Grey,
        ),
        panel(
            "render (aligned, scaled to the real signal)".into(),
            "DN",
            &render_v,
            (0.0, grey_max),
            ColourMap::Grey,
        ),
        panel(
            format!("real − render (scale ±{d:.0} DN = ±{pct:.1} % of the disk peak {peak:.0} DN)"),
            "real − render (DN)",
            &diff,
            (-d, d),
            ColourMap::Diverging,
        ),
        panel(
            "SSIM map".into(),
            "SSIM",
            &ssim_v,
            (0.0, 1.0),
            ColourMap::Viridis,
        ),
    ];
    draw_png(path, COMPARISON_SIZE, |root| {
        let (head, rest) = root.split_vertically(50);
        let (grid, foot) = rest.split_vertically(COMPARISON_SIZE.1 - 50 - 170);
        text_block(&head, std::slice::from_ref(&cmp.title), 24, path)?;
        for (area, p) in grid.split_evenly((2, 2)).iter().zip(&panels) {
            image_panel(area, p, path)?;
        }
        let mut notes = cmp.notes.clone();
        notes.push(format!(
            "Orange circle: the aligned disk's limb; crop: the disk + {:.0} % of its radius.",
            100.0 * CROP_MARGIN
        ));
        text_block(&foot, &notes, 17, path)?;
        Ok(())
    })
}

/// Samples of the profile: distance along the line [px] and bilinear
/// values of `img` there, from −`half` to +`half` in 0.5 px steps.
fn profile(img: &Raster, disk: &Disk, dir: (f64, f64), half: f64) -> Vec<(f64, f64)> {
    let n = (2.0 * half / 0.5) as i64;
    (0..=n)
        .map(|k| -half + 0.5 * k as f64)
        .filter_map(|s| {
            let (x, y) = (disk.cx + s * dir.0, disk.cy + s * dir.1);
            bilinear(img, x, y).map(|v| (s, v))
        })
        .collect()
}

/// Bilinear value at continuous image coordinates (pixel centres at +0.5);
/// `None` outside the image.
fn bilinear(img: &Raster, x: f64, y: f64) -> Option<f64> {
    let (u, v) = (x - 0.5, y - 0.5);
    if !(u >= 0.0 && v >= 0.0) {
        return None;
    }
    let (c, r) = (u.floor() as usize, v.floor() as usize);
    if c + 1 >= img.width || r + 1 >= img.height {
        return None;
    }
    let (fx, fy) = (u - c as f64, v - r as f64);
    let g = |c, r| img.get(c, r) as f64;
    let top = g(c, r) * (1.0 - fx) + g(c + 1, r) * fx;
    let bottom = g(c, r + 1) * (1.0 - fx) + g(c + 1, r + 1) * fx;
    Some(top * (1.0 - fy) + bottom * fy)
}

/// Unit vector from the disk centre to the centroid of the real disk's
/// signal (towards the Sun in the image); +x when the disk is evenly lit.
pub fn lit_direction(real: &Raster, disk: &Disk) -> (f64, f64) {
    let (mut sx, mut sy, mut sw) = (0.0, 0.0, 0.0);
    for r in 0..real.height {
        for c in 0..real.width {
            let (x, y) = (c as f64 + 0.5, r as f64 + 0.5);
            let v = real.get(c, r) as f64;
            if v > 0.0 && disk.limb_distance(x, y) <= 0.0 {
                sx += v * (x - disk.cx);
                sy += v * (y - disk.cy);
                sw += v;
            }
        }
    }
    let len = sx.hypot(sy);
    if sw > 0.0 && len > 0.02 * disk.radius * sw {
        (sx / len, sy / len)
    } else {
        (1.0, 0.0)
    }
}

/// Writes `profile.png`.
pub fn write_profile_png(path: impl AsRef<Path>, cmp: &Comparison) -> Result<()> {
    let path = path.as_ref();
    check(cmp)?;
    let dir = lit_direction(cmp.real, &cmp.disk);
    let half = cmp.disk.radius * (1.0 + CROP_MARGIN);
    let real = profile(cmp.real, &cmp.disk, dir, half);
    let render = profile(cmp.render, &cmp.disk, dir, half);
    let diff = real
        .iter()
        .zip(&render)
        .map(|(a, b)| (a.0, a.1 - b.1))
        .collect();
    let fig = CurveFigure {
        title: format!("{}: profile to the lit limb", cmp.title),
        x_label: format!(
            "distance from the disk centre along ({:+.2}, {:+.2}) in the image (px; limb at ±{:.0})",
            dir.0, dir.1, cmp.disk.radius
        ),
        main: Panel {
            y_label: "signal (DN)".into(),
            log_y: false,
            series: vec![Series::line("real", real), Series::line("render", render)],
        },
        residuals: Some(Panel {
            y_label: "real − render (DN)".into(),
            log_y: false,
            series: vec![Series::line("real − render", diff)],
        }),
        size: PROFILE_SIZE,
    };
    curve_figure(path, &fig)
}
