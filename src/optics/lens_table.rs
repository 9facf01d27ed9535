//! The lens's resampling as a sparse linear map, and the undistortion
//! solves that build it.
//!
//! Resampling an ideal image through a lens ([`super::distortion`]) is
//! linear in the image and fixed by (lens, resolution, supersampling): each
//! camera pixel is a weighted sum of a few ideal pixels. [`WeightTable`]
//! holds those sums once per lens (compressed rows: a `u32` index and an
//! `f32` weight per term, the `n²` sample points' bilinear weights merged),
//! so a frame costs one multiply–add per term over the body's box instead
//! of `n² × 4` bilinear lookups per pixel.

use std::sync::OnceLock;

use glam::DVec2;
use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::instruments::intrinsics::CameraIntrinsics;

/// Camera pixels per side of a tile: the unit the resampling skips when
/// its terms all lie outside the images' non-zero box.
const TILE: usize = 8;

/// OpenCV's distortion of normalised coordinates (x, y) and its Jacobian
/// [[∂x', ∂x'/∂y], [∂y'/∂x, ∂y'/∂y]].
fn distort_with_jacobian(d: &[f64; 5], x: f64, y: f64) -> ((f64, f64), [[f64; 2]; 2]) {
    let [k1, k2, p1, p2, k3] = *d;
    let r2 = x * x + y * y;
    let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
    // d(radial)/d(r²).
    let g = k1 + r2 * (2.0 * k2 + 3.0 * r2 * k3);
    let value = (
        x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
        y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
    );
    let xy = 2.0 * x * y * g;
    let jacobian = [
        [
            radial + 2.0 * x * x * g + 2.0 * p1 * y + 6.0 * p2 * x,
            xy + 2.0 * p1 * x + 2.0 * p2 * y,
        ],
        [
            xy + 2.0 * p1 * x + 2.0 * p2 * y,
            radial + 2.0 * y * y * g + 6.0 * p1 * y + 2.0 * p2 * x,
        ],
    ];
    (value, jacobian)
}

/// The undistorted normalised coordinates (x, y) whose distortion is
/// (xd, yd), by Newton's method from `guess` with the analytic Jacobian;
/// the same convergence test as
/// [`CameraIntrinsics::pixel_to_direction`] (residual under 1e-12, at
/// most 50 steps), None where it fails.
pub fn undistort(d: &[f64; 5], xd: f64, yd: f64, guess: DVec2) -> Option<DVec2> {
    let (mut x, mut y) = (guess.x, guess.y);
    for _ in 0..50 {
        let ((fx, fy), j) = distort_with_jacobian(d, x, y);
        let (ex, ey) = (fx - xd, fy - yd);
        if ex.abs().max(ey.abs()) < 1e-12 {
            return Some(DVec2::new(x, y));
        }
        let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
        if !(det.abs() > 1e-12) {
            return None;
        }
        x -= (j[1][1] * ex - j[0][1] * ey) / det;
        y -= (-j[1][0] * ex + j[0][0] * ey) / det;
        if !(x.is_finite() && y.is_finite()) {
            return None;
        }
    }
    None
}

/// Normalised undistorted coordinates of the pixel positions
/// (i + offset, j + offset) for i < `cols`, j < `rows` (this crate's
/// convention, centres at +0.5), row-major. Along a row each solve starts
/// from its two neighbours' answers extrapolated (the first from the
/// distorted point), so most take one Newton step.
pub fn undistort_grid(
    k: &CameraIntrinsics,
    cols: usize,
    rows: usize,
    offset: f64,
) -> Vec<Option<DVec2>> {
    let m = &k.camera_matrix;
    let (fx, fy, cx, cy) = (m[0][0], m[1][1], m[0][2] + 0.5, m[1][2] + 0.5);
    let mut out = vec![None; cols * rows];
    out.par_chunks_mut(cols).enumerate().for_each(|(j, row)| {
        let yd = (j as f64 + offset - cy) / fy;
        let (mut last, mut before): (Option<DVec2>, Option<DVec2>) = (None, None);
        for (i, o) in row.iter_mut().enumerate() {
            let xd = (i as f64 + offset - cx) / fx;
            let distorted = DVec2::new(xd, yd);
            // Linear extrapolation from the two previous answers is off by
            // the map's curvature over a pixel: one Newton step.
            let start = match (last, before) {
                (Some(a), Some(b)) => 2.0 * a - b,
                (Some(a), None) => a,
                _ => distorted,
            };
            *o = undistort(&k.distortion, xd, yd, start)
                .or_else(|| undistort(&k.distortion, xd, yd, distorted));
            (before, last) = (last, *o);
        }
    });
    out
}

/// One ideal pixel's share of a camera pixel.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C)]
pub struct Term {
    /// Row-major index into the ideal image.
    pub index: u32,
    /// Its weight (the mean over the pixel's sample points of their
    /// bilinear weights).
    pub weight: f32,
}

/// The resampling of ideal images onto the camera's pixels as compressed
/// rows: camera pixel p is Σ `weight × ideal[index]` over its terms. The
/// terms are built per band of [`TILE`] camera rows on first use, so a
/// frame pays only for the bands its body's box reaches, once per lens.
pub struct WeightTable {
    width: usize,
    height: usize,
    ideal: (usize, usize),
    supersample: usize,
    /// Where each pixel corner lies in the ideal image ((width + 1) ×
    /// (height + 1)); None where it does not undistort.
    corners: Vec<Option<(f64, f64)>>,
    /// Per tile of [`TILE`]² camera pixels (row-major over tiles), a box
    /// [x0, x1) × [y0, y1) of ideal pixels holding every one its terms
    /// read (from the corners; empty when none).
    tiles: Vec<[u32; 4]>,
    bands: Vec<OnceLock<Band>>,
}

/// The terms of one band of camera rows: pixel p of the band (row-major)
/// has `terms[start[p]..start[p + 1]]`.
struct Band {
    start: Vec<u32>,
    terms: Vec<Term>,
}

impl WeightTable {
    /// The table of a `width × height` camera whose pixel corners
    /// ((width + 1) × (height + 1), row-major) lie at `corners` in the
    /// `ideal_width × ideal_height` ideal image's continuous coordinates
    /// (None where a corner does not undistort: its pixels stay 0), each
    /// pixel sampled at `n × n` points interpolated bilinearly between its
    /// corners, each point read bilinearly between ideal pixel centres (0
    /// outside the ideal image).
    pub fn new(
        corners: Vec<Option<(f64, f64)>>,
        (width, height): (usize, usize),
        ideal: (usize, usize),
        n: usize,
    ) -> Result<WeightTable> {
        if ideal.0 * ideal.1 > u32::MAX as usize {
            return Err(Error::invalid(
                "camera.distortion",
                format!(
                    "a {}×{} ideal grid: more pixels than a u32 index holds",
                    ideal.0, ideal.1
                ),
            ));
        }
        let (tx, ty) = (width.div_ceil(TILE), height.div_ceil(TILE));
        let tiles = (0..tx * ty)
            .into_par_iter()
            .map(|t| {
                let (x0, y0) = ((t % tx) * TILE, (t / tx) * TILE);
                let row = |y: usize| y * (width + 1);
                let (mut lo, mut hi) = ((f64::MAX, f64::MAX), (f64::MIN, f64::MIN));
                for y in y0..=(y0 + TILE).min(height) {
                    let span = row(y) + x0..=row(y) + (x0 + TILE).min(width);
                    for &(u, v) in corners[span].iter().flatten() {
                        (lo, hi) = ((lo.0.min(u), lo.1.min(v)), (hi.0.max(u), hi.1.max(v)));
                    }
                }
                // Every pixel's reach lies in the reach of its tile's box.
                let empty = [u32::MAX, 0, u32::MAX, 0];
                if lo.0 > hi.0 {
                    return empty;
                }
                reach(&[lo, hi, lo, hi], ideal).unwrap_or(empty)
            })
            .collect();
        Ok(WeightTable {
            width,
            height,
            ideal,
            supersample: n,
            corners,
            tiles,
            bands: (0..ty).map(|_| OnceLock::new()).collect(),
        })
    }

    /// Band `b`'s terms, built on first use.
    fn band(&self, b: usize) -> &Band {
        self.bands[b].get_or_init(|| {
            let w = self.width;
            let mut acc = Vec::new();
            let rows = (b * TILE..((b + 1) * TILE).min(self.height)).len();
            let mut start = Vec::with_capacity(rows * w + 1);
            let mut terms = Vec::with_capacity(rows * w * 9);
            start.push(0);
            for y in b * TILE..((b + 1) * TILE).min(self.height) {
                for x in 0..w {
                    let c = |dx: usize, dy: usize| self.corners[(y + dy) * (w + 1) + x + dx];
                    if let (Some(a), Some(b), Some(cc), Some(d)) =
                        (c(0, 0), c(1, 0), c(0, 1), c(1, 1))
                    {
                        let quad = [a, b, cc, d];
                        pixel_terms(&quad, self.ideal, self.supersample, &mut acc, &mut terms);
                    }
                    start.push(terms.len() as u32);
                }
            }
            Band { start, terms }
        })
    }

    /// Number of terms over all pixels (builds every band).
    pub fn len(&self) -> usize {
        (0..self.bands.len())
            .into_par_iter()
            .map(|b| self.band(b).terms.len())
            .sum()
    }

    /// Whether no pixel has a term (builds every band).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Bytes the built bands hold.
    pub fn bytes(&self) -> usize {
        self.bands
            .iter()
            .flat_map(|b| b.get())
            .map(|b| b.start.len() * 4 + b.terms.len() * std::mem::size_of::<Term>())
            .sum()
    }

    /// The terms of camera pixel (x, y).
    pub fn terms(&self, x: usize, y: usize) -> &[Term] {
        let band = self.band(y / TILE);
        let p = (y % TILE) * self.width + x;
        &band.terms[band.start[p] as usize..band.start[p + 1] as usize]
    }

    fn tiles_x(&self) -> usize {
        self.width.div_ceil(TILE)
    }

    /// The camera images of `N` ideal images (row-major, the ideal grid's
    /// size): only the tiles whose terms reach the images' non-zero box
    /// are summed, the others stay 0.
    pub fn apply<const N: usize>(&self, images: [&[f32]; N]) -> [Vec<f32>; N] {
        let w = self.width;
        let mut out: [Vec<f32>; N] = std::array::from_fn(|_| vec![0.0f32; w * self.height]);
        let boxes = images.map(|img| super::psf::nonzero_box(img, self.ideal.0));
        let Some((bx0, bx1, by0, by1)) = boxes.iter().flatten().fold(None, |acc, b| {
            Some(match acc {
                None => *b,
                Some((a, c, d, e)) => (b.0.min(a), b.1.max(c), b.2.min(d), b.3.max(e)),
            })
        }) else {
            return out;
        };
        let [bx0, bx1, by0, by1] = [bx0, bx1, by0, by1].map(|v| v as u32);
        let tx = self.tiles_x();
        let hits = |t: &[u32; 4]| t[0] < bx1 && bx0 < t[1] && t[2] < by1 && by0 < t[3];
        // Per tile row with a tile in the box: its span of tiles and the
        // sums over it.
        let blocks: Vec<(usize, usize, usize, [Vec<f32>; N])> = (0..self.height.div_ceil(TILE))
            .into_par_iter()
            .filter_map(|ty| {
                let row = &self.tiles[ty * tx..(ty + 1) * tx];
                let first = row.iter().position(hits)?;
                let last = row.iter().rposition(hits)?;
                let (x0, x1) = (first * TILE, ((last + 1) * TILE).min(w));
                let (y0, y1) = (ty * TILE, ((ty + 1) * TILE).min(self.height));
                let bw = x1 - x0;
                let mut block: [Vec<f32>; N] =
                    std::array::from_fn(|_| vec![0.0f32; bw * (y1 - y0)]);
                for t in (first..=last).filter(|&t| hits(&row[t])) {
                    for y in y0..y1 {
                        for x in t * TILE..((t + 1) * TILE).min(w) {
                            let mut sums = [0.0f32; N];
                            for term in self.terms(x, y) {
                                for (s, img) in sums.iter_mut().zip(&images) {
                                    *s += term.weight * img[term.index as usize];
                                }
                            }
                            for (b, s) in block.iter_mut().zip(sums) {
                                b[(y - y0) * bw + x - x0] = s;
                            }
                        }
                    }
                }
                Some((x0, y0, bw, block))
            })
            .collect();
        for (x0, y0, bw, block) in blocks {
            for (o, b) in out.iter_mut().zip(&block) {
                for (r, src) in b.chunks(bw).enumerate() {
                    let at = (y0 + r) * w + x0;
                    o[at..at + bw].copy_from_slice(src);
                }
            }
        }
        out
    }
}

/// Appends to `terms` one pixel's terms (row-major by ideal index): its
/// `n²` sample points' bilinear weights, merged in `acc` (scratch) over
/// the box of ideal pixels the corners `quad` ([top-left, top-right,
/// bottom-left, bottom-right]) reach (None, and no terms, when it is
/// outside the image).
fn pixel_terms(
    quad: &[(f64, f64); 4],
    (iw, ih): (usize, usize),
    n: usize,
    acc: &mut Vec<f64>,
    terms: &mut Vec<Term>,
) -> Option<()> {
    let [a, b, c, d] = *quad;
    let [gx0, gx1, gy0, gy1] = reach(quad, (iw, ih))?.map(|v| v as usize);
    let (bw, bh) = (gx1 - gx0, gy1 - gy0);
    acc.clear();
    acc.resize(bw * bh, 0.0);
    let inv = 1.0 / n as f64;
    for sy in 0..n {
        let t = (sy as f64 + 0.5) * inv;
        // The sample row runs from the left edge's point to the right's.
        let left = (a.0 + t * (c.0 - a.0), a.1 + t * (c.1 - a.1));
        let right = (b.0 + t * (d.0 - b.0), b.1 + t * (d.1 - b.1));
        for sx in 0..n {
            let s = (sx as f64 + 0.5) * inv;
            let (fx, fy) = (
                (1.0 - s) * left.0 + s * right.0 - 0.5,
                (1.0 - s) * left.1 + s * right.1 - 0.5,
            );
            let (x0, y0) = (floor(fx), floor(fy));
            let (tx, ty) = (fx - x0 as f64, fy - y0 as f64);
            let (x, y) = (x0 - gx0 as i64, y0 - gy0 as i64);
            let neighbours = [
                (x, y, (1.0 - tx) * (1.0 - ty)),
                (x + 1, y, tx * (1.0 - ty)),
                (x, y + 1, (1.0 - tx) * ty),
                (x + 1, y + 1, tx * ty),
            ];
            for (x, y, wt) in neighbours {
                // Outside the box is outside the image: 0 there.
                if (x as u64) < bw as u64 && (y as u64) < bh as u64 {
                    acc[y as usize * bw + x as usize] += wt;
                }
            }
        }
    }
    let scale = inv * inv;
    for (k, &wt) in acc.iter().enumerate() {
        if wt != 0.0 {
            let (x, y) = (gx0 + k % bw, gy0 + k / bw);
            terms.push(Term {
                index: (y * iw + x) as u32,
                weight: (wt * scale) as f32,
            });
        }
    }
    Some(())
}

/// The ideal pixels, [x0, x1) × [y0, y1) within the `iw × ih` image, that
/// a bilinear lookup at a convex combination of the points `quad` can
/// touch (None when none is in the image). The slack keeps a point that
/// rounding puts just past a corner.
fn reach(quad: &[(f64, f64); 4], (iw, ih): (usize, usize)) -> Option<[u32; 4]> {
    let lo = |v: [f64; 4]| v.into_iter().fold(f64::MAX, f64::min);
    let hi = |v: [f64; 4]| v.into_iter().fold(f64::MIN, f64::max);
    let xs = quad.map(|p| p.0);
    let ys = quad.map(|p| p.1);
    let slack = 1e-9;
    let x0 = floor(lo(xs) - 0.5 - slack).max(0);
    let y0 = floor(lo(ys) - 0.5 - slack).max(0);
    let x1 = (floor(hi(xs) - 0.5 + slack) + 2).min(iw as i64);
    let y1 = (floor(hi(ys) - 0.5 + slack) + 2).min(ih as i64);
    (x1 > x0 && y1 > y0).then(|| [x0, x1, y0, y1].map(|v| v as u32))
}

/// ⌊v⌋ for |v| < 2⁶³ without a libm call (the baseline x86-64 target has
/// no rounding instruction).
fn floor(v: f64) -> i64 {
    let i = v as i64;
    i - i64::from((i as f64) > v)
}
