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
//!
//! The points' Sun geometry (horizon-map position, elevation, azimuth) is
//! smooth across a pixel while the horizon is not: each pixel corner's
//! geometry is computed once (a ray–sphere hit and three `atan2`s, shared
//! with the neighbours along the row) and interpolated bilinearly to the
//! points (with the exact centre as a fifth node), and each point pays
//! only its horizon lookup, bilinear at the map's own resolution
//! ([`FrameShadows::factor_of_angles`]). Where that model does not hold
//! (a corner off the sphere, the azimuth turning fast near a pole or the
//! subsolar point, or the corners' bilinear centre off the exact one) the
//! points take the exact geometry. Cheap points buy more of them: 5 × 5
//! per pixel, not 4 × 4, which halves the edge pixels' error against a
//! brute-force mean (`tests/shadow_lattice.rs`).

use std::cell::RefCell;
use std::f64::consts::TAU;

use rayon::prelude::*;

use super::caps::{Frame, Rect};
use super::relief::{FrameShadows, SunAngles, SunAtPoint};

/// Points per axis over which an edge pixel's shadow factor is averaged.
pub const EDGE_POINTS: usize = 5;

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

    /// For each pixel of ROI row `jj`, whether its 3 × 3 block (clamped
    /// to the ROI, as in [`Self::is_edge`]) holds one value bit for bit:
    /// such a pixel (most of them: lit, dark, or off the disk) is no edge
    /// unless its factor lies in the penumbra.
    /// Per row, in passes the compiler vectorises: `vertical` (scratch)
    /// marks the columns whose three rows agree.
    fn uniform_blocks(&self, jj: usize, vertical: &mut Vec<bool>, out: &mut Vec<bool>) {
        let (w, h) = (self.roi.width(), self.roi.height());
        let row = |j: usize| &self.factors[j * w..(j + 1) * w];
        let (a, b, c) = (row(jj.saturating_sub(1)), row(jj), row((jj + 1).min(h - 1)));
        vertical.clear();
        vertical.extend(
            a.iter()
                .zip(b)
                .zip(c)
                .map(|((x, y), z)| x.to_bits() == y.to_bits() && z.to_bits() == y.to_bits()),
        );
        out.clear();
        out.extend((0..w).map(|ii| {
            let (i0, i1) = (ii.saturating_sub(1), (ii + 1).min(w - 1));
            vertical[i0]
                & vertical[ii]
                & vertical[i1]
                & (b[i0].to_bits() == b[ii].to_bits())
                & (b[i1].to_bits() == b[ii].to_bits())
        }));
    }

    /// Whether ROI pixel (ii, jj) is a shadow edge: its factor in the
    /// penumbra, or an interior neighbour's different.
    #[inline]
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
    /// The Sun's geometry at continuous pixel position (u, v), None off
    /// the sphere or without shadows: `shadow_at` is
    /// [`FrameShadows::factor_at`] of it.
    fn sun_at(&self, frame: &Frame, u: f64, v: f64) -> Option<SunAtPoint>;
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
    let Some(shadows) = frame.shadows.as_ref() else {
        return (0.0, 0);
    };
    flux.par_chunks_mut(width)
        .enumerate()
        .skip(roi.y0)
        .take(roi.height())
        .map(|(j, row)| {
            let (mut delta, mut edges) = (0.0, 0usize);
            CORNERS.with_borrow_mut(|corners| {
                corners.reset(roi, j);
                let mut uniform = std::mem::take(&mut corners.uniform);
                centre.uniform_blocks(j - roi.y0, &mut corners.vertical, &mut uniform);
                for (ii, &uniform) in uniform.iter().enumerate() {
                    let s = centre.factors[(j - roi.y0) * roi.width() + ii] as f64;
                    let penumbra = s > 0.0 && s < 1.0;
                    if (uniform && !penumbra) || !centre.is_edge(ii, j - roi.y0) {
                        continue;
                    }
                    let i = roi.x0 + ii;
                    let sun = corners.pixel(frame, shadows, pixels, ii);
                    let Some(mean) = mean_factor(frame, shadows, pixels, (i, j), s, sun) else {
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
                corners.uniform = uniform;
            });
            (delta, edges)
        })
        .reduce(|| (0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1))
}

/// Largest turn of the Sun's azimuth [rad] between a pixel's corners for
/// which its angles are interpolated: near a pole or the subsolar point
/// the azimuth turns fast (and not linearly) across a pixel.
const MAX_AZIMUTH_SPREAD: f64 = 0.05;

/// Largest miss of the corners' bilinear position at the pixel's centre
/// [horizon-map cells], against the exact one: past it the map is not
/// smooth enough across the pixel (near the limb, a pole) to interpolate.
const CENTRE_POSITION_TOLERANCE: f64 = 0.05;

/// Largest miss of the corners' bilinear elevation or azimuth at the
/// pixel's centre [rad] (past it, as above).
const CENTRE_ANGLE_TOLERANCE: f64 = 2e-4;

/// Where a pixel spans more than the tolerances above, the misses allowed
/// grow to this share of its span (corner to corner, per quantity): the
/// points lie a fifth of a pixel apart, and a miss a tenth of that moves
/// the pixel's estimate less than its own sampling does (a small Moon's
/// pixel spans many horizon-map cells).
const CENTRE_SPAN_SHARE: f64 = 0.02;

thread_local! {
    /// A row's pixel-corner Suns ([`CornerRows`]), kept between frames.
    static CORNERS: RefCell<CornerRows> = const {
        RefCell::new(CornerRows {
            top: Vec::new(),
            bottom: Vec::new(),
            row: 0,
            x0: 0,
            j: 0,
            vertical: Vec::new(),
            uniform: Vec::new(),
        })
    };
}

/// The Sun at the pixel corners above and below one image row (`top[ii]`
/// at (x0 + ii, j), `bottom[ii]` at (x0 + ii, j + 1)), each computed once
/// when a pixel first needs it: neighbouring edge pixels share corners.
/// A slot holds the row number it was computed for, so moving to the
/// next row forgets every corner without writing the slots.
struct CornerRows {
    top: Vec<(u64, Option<SunAngles>)>,
    bottom: Vec<(u64, Option<SunAngles>)>,
    /// Rows started so far (never 0 after the first `reset`).
    row: u64,
    x0: usize,
    j: usize,
    /// Scratch of [`CentreFactors::uniform_blocks`] for the row.
    vertical: Vec<bool>,
    /// The row's pixels whose 3 × 3 block is uniform (no edge).
    uniform: Vec<bool>,
}

impl CornerRows {
    /// Forget every corner; the row is image row `j` of `roi`.
    fn reset(&mut self, roi: Rect, j: usize) {
        self.row += 1;
        for corners in [&mut self.top, &mut self.bottom] {
            if corners.len() < roi.width() + 1 {
                corners.resize(roi.width() + 1, (0, None));
            }
        }
        (self.x0, self.j) = (roi.x0, j);
    }

    /// The corner at ROI column `ii` of the top or bottom corner row.
    fn corner(
        &mut self,
        frame: &Frame,
        pixels: &impl PixelShadow,
        ii: usize,
        bottom: bool,
    ) -> Option<SunAngles> {
        let (slot, v) = if bottom {
            (&mut self.bottom[ii], self.j + 1)
        } else {
            (&mut self.top[ii], self.j)
        };
        if slot.0 != self.row {
            let sun = pixels.sun_at(frame, (self.x0 + ii) as f64, v as f64);
            *slot = (self.row, sun.map(|g| SunAngles::of(&g)));
        }
        slot.1
    }

    /// The interpolated Sun of ROI pixel `ii` of the row, if all four of
    /// its corners see the sphere and the azimuth turns little across it.
    fn pixel(
        &mut self,
        frame: &Frame,
        shadows: &FrameShadows,
        pixels: &impl PixelShadow,
        ii: usize,
    ) -> Option<PixelSun> {
        let corners = [
            self.corner(frame, pixels, ii, false)?,
            self.corner(frame, pixels, ii + 1, false)?,
            self.corner(frame, pixels, ii, true)?,
            self.corner(frame, pixels, ii + 1, true)?,
        ];
        PixelSun::new(corners, shadows.map.width() as f64)
    }
}

/// `d` wrapped into [−period/2, period/2].
#[inline]
fn wrap(d: f64, period: f64) -> f64 {
    d - period * (d / period).round()
}

/// The Sun at a pixel's four corners (top left, top right, bottom left,
/// bottom right), the map column and the azimuth unwrapped to the first's,
/// interpolated bilinearly to points inside the pixel, plus a bubble
/// 16 a(1 − a) b(1 − b) that makes it exact at the centre too (it takes
/// out the second derivative's symmetric part).
struct PixelSun {
    corners: [SunAngles; 4],
    /// Exact minus bilinear at the centre, per quantity.
    bubble: [f64; 5],
    /// The map's width [cells] (its columns wrap).
    map_width: f64,
    /// Largest change across the pixel of the position [cells] and of the
    /// angles [rad], corner to corner.
    span: (f64, f64),
}

/// The largest change of the position [cells] and of the angles [rad]
/// between any two of `corners` (unwrapped).
fn spans(corners: &[SunAngles; 4]) -> (f64, f64) {
    let (mut position, mut angle) = (0.0f64, 0.0f64);
    for a in corners {
        for b in corners {
            position = position.max((a.x - b.x).abs()).max((a.y - b.y).abs());
            angle = angle
                .max((a.elevation - b.elevation).abs())
                .max((a.azimuth - b.azimuth).abs());
        }
    }
    (position, angle)
}

/// The quantities interpolated, in [`PixelSun::bubble`]'s order.
fn parts(g: &SunAngles) -> [f64; 5] {
    [g.x, g.y, g.sin_e, g.elevation, g.azimuth]
}

impl PixelSun {
    fn new(mut corners: [SunAngles; 4], map_width: f64) -> Option<PixelSun> {
        let first = corners[0];
        for c in &mut corners[1..] {
            c.x = first.x + wrap(c.x - first.x, map_width);
            c.azimuth = first.azimuth + wrap(c.azimuth - first.azimuth, TAU);
            if (c.azimuth - first.azimuth).abs() > MAX_AZIMUTH_SPREAD {
                return None;
            }
        }
        Some(PixelSun {
            corners,
            bubble: [0.0; 5],
            map_width,
            span: spans(&corners),
        })
    }

    /// The Sun at fractional position (a, b) ∈ [0, 1]² of the pixel.
    #[inline]
    fn at(&self, a: f64, b: f64) -> SunAngles {
        let [c00, c10, c01, c11] = self.corners.each_ref().map(parts);
        let w = [(1.0 - a) * (1.0 - b), a * (1.0 - b), (1.0 - a) * b, a * b];
        let bubble = 16.0 * w[0] * w[3];
        let v: [f64; 5] = std::array::from_fn(|q| {
            w[0] * c00[q] + w[1] * c10[q] + w[2] * c01[q] + w[3] * c11[q] + bubble * self.bubble[q]
        });
        SunAngles {
            x: v[0],
            y: v[1],
            sin_e: v[2],
            elevation: v[3],
            azimuth: v[4],
        }
    }

    /// Takes `exact`, the Sun at the pixel's centre, into the
    /// interpolation if the bilinear one meets it within the tolerances
    /// above; false (the pixel's points take the exact geometry) if not.
    fn fit_centre(&mut self, exact: &SunAngles) -> bool {
        let m = self.at(0.5, 0.5);
        let mut exact = *exact;
        exact.x = m.x + wrap(exact.x - m.x, self.map_width);
        exact.azimuth = m.azimuth + wrap(exact.azimuth - m.azimuth, TAU);
        let (pe, pm) = (parts(&exact), parts(&m));
        self.bubble = std::array::from_fn(|q| pe[q] - pm[q]);
        let position = CENTRE_POSITION_TOLERANCE.max(CENTRE_SPAN_SHARE * self.span.0);
        let angle = CENTRE_ANGLE_TOLERANCE.max(CENTRE_SPAN_SHARE * self.span.1);
        let xy = wrap(m.x - exact.x, self.map_width).abs() <= position
            && (m.y - exact.y).abs() <= position;
        let e = (m.elevation - exact.elevation).abs() <= angle;
        let az = wrap(m.azimuth - exact.azimuth, TAU).abs() <= angle;
        xy && e && az
    }
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
/// With `sun` the points' geometry is interpolated from the corners and
/// the exact centre (where the corners' bilinear model meets the centre
/// within the tolerances; the probes too), else exact.
fn mean_factor(
    frame: &Frame,
    shadows: &FrameShadows,
    pixels: &impl PixelShadow,
    (i, j): (usize, usize),
    s: f64,
    mut sun: Option<PixelSun>,
) -> Option<f64> {
    const N: usize = EDGE_POINTS;
    if let Some(p) = &mut sun {
        let exact = pixels.sun_at(frame, i as f64 + 0.5, j as f64 + 0.5);
        if !exact.is_some_and(|g| p.fit_centre(&SunAngles::of(&g))) {
            sun = None;
        }
    }
    let offset = |m: usize| (m as f64 + 0.5) / N as f64;
    let point = |k: usize, sun: &Option<PixelSun>| match sun {
        Some(p) => shadows.factor_of_angles(&p.at(offset(k % N), offset(k / N))),
        None => pixels.shadow_at(frame, i as f64 + offset(k % N), j as f64 + offset(k / N)),
    };
    let mut factors = [f64::NAN; N * N];
    if s == 0.0 || s == 1.0 {
        // Stops at the first probe that disagrees; the rest are points.
        let agree = PROBES.iter().all(|&k| {
            factors[k] = point(k, &sun);
            factors[k] == s
        });
        if agree {
            return None;
        }
    }
    let sum: f64 = factors
        .iter()
        .enumerate()
        .map(|(k, &f)| if f.is_nan() { point(k, &sun) } else { f })
        .sum();
    Some(sum / (N * N) as f64)
}
