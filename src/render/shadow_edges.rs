//! Cast-shadow edges inside interior pixels. An interior pixel takes the
//! relief's shadow factor at its centre, which aliases where a shadow's
//! edge crosses the pixel: a pixel half in shadow reads 0 or 1, and 1 %
//! of a relief Moon's pixels were 36–100 % off a converged render
//! (BENCHMARKS.md, "Relief: per-pixel error"). After the interior pass,
//! each pixel whose centre factor lies in the penumbra or differs from an
//! interior neighbour's takes the mean factor over [`EDGE_POINTS`]² points
//! of its preimage instead: the shading is smooth across the pixel, the
//! shadow is not, so the pixel's flux is its unshadowed flux times that
//! mean. A pixel whose centre is wholly lit or dark first probes the four
//! corner points of those [`EDGE_POINTS`]² and keeps its centre's factor
//! where all four agree (the edge passed beside it); else the probes
//! count among the points. (The eight neighbours, not the four sharing an
//! edge: with four, shadows whose edges curve within a pixel or two were
//! missed, and the 105° p99 of `tests/render_shadow_edges.rs` rose from
//! 14.8 % to 16.3 %.) A shadow smaller than a pixel that reaches no pixel
//! centre or probe is still missed.

use rayon::prelude::*;

use super::caps::{Frame, Rect};

/// Points per axis over which an edge pixel's shadow factor is averaged.
pub const EDGE_POINTS: usize = 4;

/// Neighbouring centre factors closer than this are the same.
const SAME: f32 = 1e-6;

/// Marks a pixel whose centre factor was not recorded (not interior).
const NONE: f32 = f32::NAN;

/// The centre factor of every interior pixel of the ROI, row-major,
/// [`NONE`] elsewhere; reused between frames.
#[derive(Default)]
pub struct CentreFactors {
    pub roi: Rect,
    pub factors: Vec<f32>,
}

impl CentreFactors {
    /// Clear for `roi`: every pixel unrecorded. Without `record` (a frame
    /// without cast shadows) each row keeps a single slot, so the rows
    /// still pair with the image's in one pass and nothing grows.
    pub fn reset(&mut self, roi: Rect, record: bool) {
        self.roi = roi;
        let row = if record { roi.width().max(1) } else { 1 };
        self.factors.clear();
        self.factors.resize(row * roi.height(), NONE);
    }

    /// One mutable slice per ROI row (a row's factors, or its single slot
    /// without recording), for the interior pass.
    pub fn rows_mut(&mut self) -> rayon::slice::ChunksMut<'_, f32> {
        let row = (self.factors.len() / self.roi.height().max(1)).max(1);
        self.factors.par_chunks_mut(row)
    }

    /// Whether ROI pixel (ii, jj) is a shadow edge: its factor in the
    /// penumbra, or an interior neighbour's different.
    fn is_edge(&self, ii: usize, jj: usize) -> bool {
        let (w, h) = (self.roi.width(), self.roi.height());
        let s = self.factors[jj * w + ii];
        if s.is_nan() {
            return false;
        }
        if s > 0.0 && s < 1.0 {
            return true;
        }
        let (i0, i1) = (ii.saturating_sub(1), (ii + 1).min(w - 1));
        let (j0, j1) = (jj.saturating_sub(1), (jj + 1).min(h - 1));
        (j0..=j1).any(|j| {
            self.factors[j * w + i0..=j * w + i1]
                .iter()
                .any(|&n| !n.is_nan() && (n - s).abs() > SAME)
        })
    }
}

/// How a pixel is evaluated, as the interior pass does it.
pub trait PixelShadow: Sync {
    /// The relief's shadow factor at continuous pixel position (u, v).
    fn shadow_at(&self, frame: &Frame, u: f64, v: f64) -> f64;
    /// The pixel's flux without cast shadows.
    fn unshadowed(&self, frame: &Frame, i: usize, j: usize) -> f64;
}

/// Re-evaluate the shadow-edge pixels of `centre` in `flux` (the whole
/// image, `width` wide). Returns the change of the flux's sum and the
/// number of edge pixels.
pub fn refine(
    frame: &Frame,
    pixels: &impl PixelShadow,
    centre: &CentreFactors,
    flux: &mut [f32],
    width: usize,
) -> (f64, usize) {
    let roi = centre.roi;
    flux.par_chunks_mut(width)
        .enumerate()
        .skip(roi.y0)
        .take(roi.height())
        .map(|(j, row)| {
            let (mut delta, mut edges) = (0.0, 0usize);
            for ii in 0..roi.width() {
                if !centre.is_edge(ii, j - roi.y0) {
                    continue;
                }
                let i = roi.x0 + ii;
                let s = centre.factors[(j - roi.y0) * roi.width() + ii] as f64;
                let Some(mean) = mean_factor(frame, pixels, i, j, s) else {
                    continue;
                };
                let unshadowed = if s > 0.5 {
                    row[i] as f64 / s
                } else {
                    pixels.unshadowed(frame, i, j)
                };
                let new = unshadowed * mean;
                delta += new - row[i] as f64;
                row[i] = new as f32;
                edges += 1;
            }
            (delta, edges)
        })
        .reduce(|| (0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1))
}

/// Indices into the [`EDGE_POINTS`]² points (row-major) of the four
/// corner points, the probes.
const PROBES: [usize; 4] = [
    0,
    EDGE_POINTS - 1,
    EDGE_POINTS * (EDGE_POINTS - 1),
    EDGE_POINTS * EDGE_POINTS - 1,
];

/// Mean shadow factor over [`EDGE_POINTS`]² points of pixel (i, j), or
/// None where the centre's factor `s` (0 or 1) holds at the four
/// [`PROBES`] too: the edge passed beside the pixel, not through it.
fn mean_factor(
    frame: &Frame,
    pixels: &impl PixelShadow,
    i: usize,
    j: usize,
    s: f64,
) -> Option<f64> {
    const N: usize = EDGE_POINTS;
    let point = |k: usize| {
        let offset = |m: usize| (m as f64 + 0.5) / N as f64;
        pixels.shadow_at(frame, i as f64 + offset(k % N), j as f64 + offset(k / N))
    };
    let mut factors = [f64::NAN; N * N];
    if s == 0.0 || s == 1.0 {
        // Stops at the first probe that disagrees; the rest are points.
        let agree = PROBES.iter().all(|&k| {
            factors[k] = point(k);
            factors[k] == s
        });
        if agree {
            return None;
        }
    }
    let sum: f64 = factors
        .iter()
        .enumerate()
        .map(|(k, &f)| if f.is_nan() { point(k) } else { f })
        .sum();
    Some(sum / (N * N) as f64)
}
