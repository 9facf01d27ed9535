//! Image alignment by normalised cross-correlation (NCC): an exhaustive
//! integer search over shifts within ±N px, then sub-pixel refinement by a
//! parabola through the peak and its two neighbours, separately along x and
//! y; plus a bilinear resampler to apply the shift.
//!
//! Shift convention: `moving(x, y) ≈ reference(x − dx, y − dy)`, i.e. the
//! content of `moving` sits `(dx, dy)` pixels right/down of where it is in
//! `reference`. [`shift_bilinear`]`(moving, -dx, -dy)` brings it back.

use rayon::prelude::*;

use super::raster::Raster;
use crate::error::{Error, Result};

/// Result of [`ncc_align`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Alignment {
    /// Shift of `moving` relative to `reference`, px (right positive).
    pub dx: f64,
    /// Shift of `moving` relative to `reference`, px (down positive).
    pub dy: f64,
    /// NCC at the best integer shift, in [-1, 1].
    pub peak_ncc: f64,
    /// Best integer shift before refinement.
    pub integer_shift: (i32, i32),
}

/// NCC between `reference(x − dx, y − dy)` and `moving(x, y)` over their
/// overlap (means and norms taken over the overlap only). Returns 0 when
/// either side is flat over the overlap.
pub fn ncc_at(reference: &Raster, moving: &Raster, dx: i32, dy: i32) -> f64 {
    let (w, h) = (reference.width as i32, reference.height as i32);
    let (x0, x1) = (dx.max(0), (w + dx).min(w));
    let (y0, y1) = (dy.max(0), (h + dy).min(h));
    if x1 <= x0 || y1 <= y0 {
        return 0.0;
    }
    let n = ((x1 - x0) * (y1 - y0)) as f64;
    let (mut sa, mut sb) = (0.0f64, 0.0f64);
    for y in y0..y1 {
        for x in x0..x1 {
            sa += reference.get((x - dx) as usize, (y - dy) as usize) as f64;
            sb += moving.get(x as usize, y as usize) as f64;
        }
    }
    let (ma, mb) = (sa / n, sb / n);
    let (mut sab, mut saa, mut sbb) = (0.0f64, 0.0f64, 0.0f64);
    for y in y0..y1 {
        for x in x0..x1 {
            let a = reference.get((x - dx) as usize, (y - dy) as usize) as f64 - ma;
            let b = moving.get(x as usize, y as usize) as f64 - mb;
            sab += a * b;
            saa += a * a;
            sbb += b * b;
        }
    }
    if saa <= 0.0 || sbb <= 0.0 {
        return 0.0;
    }
    sab / (saa * sbb).sqrt()
}

/// Vertex offset of the parabola through (−1, a), (0, b), (+1, c), clamped
/// to ±0.5 (0 when the three points are not a maximum).
fn parabola_peak(a: f64, b: f64, c: f64) -> f64 {
    let den = a - 2.0 * b + c;
    if den >= 0.0 {
        return 0.0;
    }
    (0.5 * (a - c) / den).clamp(-0.5, 0.5)
}

/// Finds the shift of `moving` relative to `reference` (same size) within
/// ±`max_shift` px by NCC, refined to sub-pixel by parabolic fits.
pub fn ncc_align(reference: &Raster, moving: &Raster, max_shift: usize) -> Result<Alignment> {
    reference.check_same_size(moving, "ncc_align")?;
    let m = max_shift as i32;
    if 2 * m + 2 > reference.width.min(reference.height) as i32 {
        return Err(Error::invalid(
            "ncc_align.max_shift",
            format!(
                "±{max_shift} px is too large for a {}x{} image",
                reference.width, reference.height
            ),
        ));
    }
    // Search one pixel beyond the window so the refinement has neighbours.
    let side = 2 * (m + 1) + 1;
    let scores: Vec<f64> = (0..side * side)
        .into_par_iter()
        .map(|i| ncc_at(reference, moving, i % side - (m + 1), i / side - (m + 1)))
        .collect();
    let at = |dx: i32, dy: i32| scores[((dy + m + 1) * side + dx + m + 1) as usize];
    let mut best = (0, 0);
    let mut best_v = f64::NEG_INFINITY;
    for dy in -m..=m {
        for dx in -m..=m {
            let v = at(dx, dy);
            if v > best_v {
                best_v = v;
                best = (dx, dy);
            }
        }
    }
    let (bx, by) = best;
    let fx = parabola_peak(at(bx - 1, by), best_v, at(bx + 1, by));
    let fy = parabola_peak(at(bx, by - 1), best_v, at(bx, by + 1));
    Ok(Alignment {
        dx: bx as f64 + fx,
        dy: by as f64 + fy,
        peak_ncc: best_v,
        integer_shift: best,
    })
}

/// `out(x, y) = img(x − dx, y − dy)` with bilinear interpolation; samples
/// falling outside the image take `fill`.
pub fn shift_bilinear(img: &Raster, dx: f64, dy: f64, fill: f32) -> Raster {
    let (w, h) = (img.width as i64, img.height as i64);
    Raster::from_fn(img.width, img.height, |x, y| {
        let (sx, sy) = (x as f64 - dx, y as f64 - dy);
        let (x0, y0) = (sx.floor(), sy.floor());
        let (tx, ty) = (sx - x0, sy - y0);
        let (x0, y0) = (x0 as i64, y0 as i64);
        let px = |xx: i64, yy: i64| {
            if xx < 0 || yy < 0 || xx >= w || yy >= h {
                fill as f64
            } else {
                img.get(xx as usize, yy as usize) as f64
            }
        };
        let v = (1.0 - ty) * ((1.0 - tx) * px(x0, y0) + tx * px(x0 + 1, y0))
            + ty * ((1.0 - tx) * px(x0, y0 + 1) + tx * px(x0 + 1, y0 + 1));
        v as f32
    })
}
