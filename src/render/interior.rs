//! Interior pixels: where a pixel's whole preimage on the sphere is lit,
//! visible and out of any shadow, that preimage is the pixel's cap.
//!
//! Its PF is the product rule at the pixel centre: the exact ray–sphere hit
//! gives the geometry, the albedo is averaged over the preimage (k×k
//! sub-footprints spanned by the exact tangent vectors of the hit), and the
//! pixel's solid angle is the weight. One cap lands in one pixel, so no
//! gridding is needed; this is what makes the facility's frame rate. The
//! smooth factors of that rule (geometry, model, footprint) come from a
//! node lattice where they may (`Lattice`), so most pixels only read the
//! map. Pixels
//! near the limb, the terminator or a shadow edge stay with the lune's caps
//! and their exact polygon gridding ([`super::caps`]).
//!
//! Toward the limb μ ∝ √(distance), and so is μ0 where the Sun is behind
//! the camera: the midpoint rule's relative error there is about
//! 1/(24 μ³ μ0 R²) (R the apparent radius in pixels). Where that exceeds
//! the pixel tolerance (`[render] pixel_tolerance`, default
//! [`DEFAULT_PIXEL_TOLERANCE`]) a pixel takes 2×2 Gauss points, and 4×4
//! where the 2×2 rule moved far from the midpoint or within
//! [`GAUSS2_MIN_PX`] of the limb. With the map's exact mean each Gauss
//! point then takes its own cell's mean (`PixelRays::pixel_flux`).
//!
//! The classification is conservative: a pixel is interior only if every
//! corner of its 3×3 neighbourhood hits the sphere lit and unshadowed, so a
//! curved boundary cannot slip between the corners of an interior pixel.

use glam::{DMat3, DVec3};
use rayon::prelude::*;

use super::caps::{Footprint, Frame, Rect};
use super::polar_sun::{self, PolarNode};
use super::relief::SunAtPoint;
use crate::scene::EquirectMap;

/// Smallest apparent radius [px] at which interior pixels are worth it.
pub const MIN_RADIUS_PX: f64 = 12.0;
pub use crate::render_settings::{DEFAULT_NODE_SPACING, DEFAULT_PIXEL_TOLERANCE};
/// Distance from the limb [px] from which 2×2 Gauss points may suffice.
pub const GAUSS2_MIN_PX: f64 = 1.2;
/// Largest relative change from the midpoint to the 2×2 rule, in pixel
/// tolerances, for which the 2×2 rule is kept; beyond it, 4×4. The
/// midpoint's error is ~20× the 2×2 rule's, so past this step the 2×2
/// rule may exceed the tolerance.
const GAUSS2_MAX_STEP: f64 = 20.0;
/// Which pixels of the ROI are integrated per pixel, with a summed-area
/// table for rectangle queries. Buffers are reused between frames.
#[derive(Default)]
pub struct InteriorMask {
    roi: Rect,
    interior: Vec<bool>,
    /// Count of non-interior pixels over [0, i) × [0, j), (w+1)×(h+1).
    boundary_sat: Vec<u32>,
    corner_ok: Vec<bool>,
    eroded_rows: Vec<bool>,
    count: usize,
    lattice: Lattice,
    /// Centre shadow factors, for the shadow-edge pass.
    centre_factors: super::shadow_edges::CentreFactors,
    /// Shadow-edge pixels re-evaluated in the last frame.
    shadow_edges: usize,
}

impl InteriorMask {
    /// Whether ROI-local pixel index `k` is interior.
    #[inline]
    pub fn is_interior(&self, k: usize) -> bool {
        self.interior[k]
    }

    /// Number of interior pixels.
    pub fn count(&self) -> usize {
        self.count
    }

    /// Whether image pixel (i, j) was integrated per pixel.
    pub fn contains(&self, i: usize, j: usize) -> bool {
        let r = &self.roi;
        let inside = i >= r.x0 && i < r.x1 && j >= r.y0 && j < r.y1;
        inside
            && self
                .interior
                .get((j - r.y0) * r.width() + (i - r.x0))
                .copied()
                .unwrap_or(false)
    }

    /// Whether every pixel of [x0, x1) × [y0, y1) (image coordinates) is
    /// interior.
    #[inline]
    pub fn covers(&self, x0: usize, y0: usize, x1: usize, y1: usize) -> bool {
        let r = &self.roi;
        if x0 < r.x0 || y0 < r.y0 || x1 > r.x1 || y1 > r.y1 || x1 <= x0 || y1 <= y0 {
            return false;
        }
        let s = r.width() + 1;
        let (a, b, c, d) = (x0 - r.x0, x1 - r.x0, y0 - r.y0, y1 - r.y0);
        let sat = &self.boundary_sat;
        sat[d * s + b] + sat[c * s + a] == sat[c * s + b] + sat[d * s + a]
    }

    /// Classify the pixels of `roi` for `frame`.
    pub fn build(&mut self, frame: &Frame, rays: &PixelRays, roi: Rect) {
        self.roi = roi;
        let (w, h) = (roi.width(), roi.height());
        let cw = w + 1;
        self.corner_ok.clear();
        self.corner_ok.resize(cw * (h + 1), false);
        self.corner_ok
            .par_chunks_mut(cw)
            .enumerate()
            .for_each(|(jj, row)| {
                let v = (roi.y0 + jj) as f64;
                let ok = |ii: usize| rays.corner_ok(frame, (roi.x0 + ii) as f64, v);
                if rays.convex {
                    fill_interval(row, ok);
                } else {
                    for (ii, c) in row.iter_mut().enumerate() {
                        *c = ok(ii);
                    }
                }
            });
        // Where the lit disk is convex on the image (phase below 90°, no
        // occulter), a pixel with its four corners inside is inside.
        // Otherwise a concave boundary could pass between the corners, so
        // the whole 3×3 neighbourhood's corners must be inside.
        let reach = if rays.convex { 0 } else { 1 };
        let ok = &self.corner_ok;
        self.eroded_rows.clear();
        self.eroded_rows.resize(w * (h + 1), false);
        self.eroded_rows
            .par_chunks_mut(w)
            .zip(ok.par_chunks(cw))
            .for_each(|(out, row)| {
                for (i, o) in out.iter_mut().enumerate() {
                    *o = i >= reach
                        && i + 1 + reach < cw
                        && row[i - reach..=i + 1 + reach].iter().all(|&c| c);
                }
            });
        self.interior.clear();
        self.interior.resize(w * h, false);
        let e = &self.eroded_rows;
        self.interior
            .par_chunks_mut(w)
            .enumerate()
            .filter(|(j, _)| *j >= reach && *j + reach < h)
            .for_each(|(j, out)| {
                for (i, o) in out.iter_mut().enumerate() {
                    *o = (j - reach..=j + 1 + reach).all(|r| e[r * w + i]);
                }
            });
        // Summed-area table: row prefix counts in parallel, then the
        // running sum down the columns.
        self.boundary_sat.clear();
        self.boundary_sat.resize(cw * (h + 1), 0);
        let interior = &self.interior;
        let count: usize = self.boundary_sat[cw..]
            .par_chunks_mut(cw)
            .zip(interior.par_chunks(w))
            .map(|(out, row)| {
                let mut run = 0u32;
                for (o, &inside) in out[1..].iter_mut().zip(row) {
                    run += u32::from(!inside);
                    *o = run;
                }
                row.iter().filter(|&&m| m).count()
            })
            .sum();
        for j in 1..=h {
            let (above, rest) = self.boundary_sat.split_at_mut(j * cw);
            let above = &above[(j - 1) * cw..];
            for (o, a) in rest[..cw].iter_mut().zip(above) {
                *o += a;
            }
        }
        self.count = count;
    }

    /// Write the flux of every interior pixel into `flux` (the whole image,
    /// row-major, `width` wide); returns their sum and how many were
    /// evaluated directly. With `node_spacing` > 1 the smooth factors come
    /// from the node lattice (`Lattice`) where its stencil allows, else
    /// each pixel is evaluated directly.
    pub fn integrate(
        &mut self,
        frame: &Frame,
        rays: &PixelRays,
        flux: &mut [f32],
        width: usize,
        (node_spacing, shadow_edges): (usize, bool),
    ) -> (f64, DirectCounts) {
        let roi = self.roi;
        let w = roi.width();
        // The Sun's nodes serve every model (the Sun's geometry is smooth
        // whatever the reflectance); the flux's nodes only where
        // `lattice_applies` (a Hapke Moon takes the Sun's alone).
        let flux_nodes = rays.lattice_applies(frame);
        let lattice = (node_spacing > 1 && (flux_nodes || frame.shadows.is_some())).then(|| {
            self.lattice
                .build(frame, rays, roi, (node_spacing, flux_nodes));
            &self.lattice
        });
        let interior = &self.interior;
        // The smooth part of a pixel's flux: its cast shadow is applied
        // once, as a factor, and a pixel wholly in shadow skips the rest.
        let smooth = &Frame {
            shadows: None,
            ..*frame
        };
        let shadows = frame.shadows.is_some();
        self.centre_factors.reset(roi, shadows);
        let (sum, counts) = flux
            .par_chunks_mut(width)
            .enumerate()
            .skip(roi.y0)
            .take(roi.height())
            .zip(self.centre_factors.rows_mut())
            .map(|((j, row), centre)| {
                let mask = &interior[(j - roi.y0) * w..(j - roi.y0 + 1) * w];
                let mut counts = DirectCounts::default();
                if !mask.iter().any(|&m| m) {
                    return (0.0, counts);
                }
                // Per-thread scratch, kept between frames: no allocation
                // in the frame loop once warm.
                COLUMNS.with_borrow_mut(|columns| {
                    SUN_COLUMNS.with_borrow_mut(|sun| {
                        columns.clear();
                        if let Some(l) = lattice {
                            if l.flux {
                                l.columns_at_row(
                                    &l.nodes,
                                    (FACTORS_X, l.map_width),
                                    j - roi.y0,
                                    columns,
                                );
                            }
                            l.sun_columns_at_row(j - roi.y0, sun);
                        }
                        let mut sum = 0.0;
                        for (ii, _) in mask.iter().enumerate().filter(|(_, &m)| m) {
                            let i = roi.x0 + ii;
                            let shadow = match lattice {
                                _ if frame.shadows.is_none() => 1.0,
                                Some(l) => {
                                    l.relief_shadow(frame, rays, sun, (ii, i, j), &mut counts)
                                }
                                None => {
                                    counts.shadow_exact += 1;
                                    rays.relief_shadow_at(frame, i, j)
                                }
                            };
                            if shadows {
                                centre[ii] = shadow as f32;
                            }
                            if shadow == 0.0 {
                                counts.dark += 1;
                                row[i] = 0.0;
                                continue;
                            }
                            let interpolated = lattice.filter(|l| l.flux).and_then(|l| {
                                l.interpolate_at(columns, (FACTORS_X, l.map_width), ii)
                                    .map(|q| (l, q))
                            });
                            let f = match interpolated {
                                Some((l, q)) => {
                                    let (f, exact) = l.pixel_flux(smooth, q);
                                    counts.map_exact += usize::from(exact);
                                    f
                                }
                                None => {
                                    let (f, points, exact) =
                                        rays.unshadowed_pixel_flux(smooth, i, j);
                                    counts.add(points);
                                    counts.map_exact += usize::from(exact);
                                    f
                                }
                            } * shadow;
                            row[i] = f as f32;
                            sum += f;
                        }
                        (sum, counts)
                    })
                })
            })
            .reduce(
                || (0.0, DirectCounts::default()),
                |(a, ca), (b, cb)| (a + b, ca.merged(cb)),
            );
        self.shadow_edges = 0;
        if !shadows || !shadow_edges {
            return (sum, counts);
        }
        let (delta, edges) =
            super::shadow_edges::refine(frame, rays, &self.centre_factors, flux, width);
        self.shadow_edges = edges;
        (sum + delta, counts)
    }

    /// Shadow-edge pixels re-evaluated over their preimage in the last
    /// frame ([`super::shadow_edges`]).
    pub fn shadow_edges(&self) -> usize {
        self.shadow_edges
    }
}

impl super::shadow_edges::PixelShadow for PixelRays {
    fn shadow_at(&self, frame: &Frame, u: f64, v: f64) -> f64 {
        match self.surface(u, v) {
            Some(s) => frame.relief_shadow(s.n_local, s.n_body, self.radius),
            None => 0.0,
        }
    }

    fn sun_at(&self, frame: &Frame, u: f64, v: f64) -> Option<SunAtPoint> {
        let shadows = frame.shadows.as_ref()?;
        let s = self.surface(u, v)?;
        let l = frame.sun_direction_body(s.n_local, self.radius);
        Some(shadows.geometry(s.n_body, l))
    }

    fn unshadowed(&self, frame: &Frame, i: usize, j: usize) -> f64 {
        let smooth = Frame {
            shadows: None,
            ..*frame
        };
        self.unshadowed_pixel_flux(&smooth, i, j).0
    }
}

/// Interior pixels evaluated directly (not from the node lattice), by the
/// points per axis of their quadrature: near the limb the midpoint rule
/// gives way to 2×2 and 4×4 Gauss points (`[render] pixel_tolerance`);
/// and, of all interior pixels, those whose map mean was exact.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct DirectCounts {
    /// Interior pixels (direct or not) whose map mean was exact: all with
    /// the exact filter, those the adaptive filter refined, else none.
    pub map_exact: usize,
    /// One point (the pixel centre).
    pub midpoint: usize,
    /// 2×2 Gauss points.
    pub gauss2: usize,
    /// 4×4 Gauss points.
    pub gauss4: usize,
    /// Interior pixels wholly in a cast shadow: flux 0, nothing else
    /// evaluated.
    pub dark: usize,
    /// Interior pixels whose cast shadow took the exact geometry at the
    /// pixel centre (no lattice there, or the penumbra).
    pub shadow_exact: usize,
    /// Interior pixels whose cast shadow was interpolated from the polar
    /// nodes ([`super::polar_sun`]).
    pub shadow_polar: usize,
}

impl DirectCounts {
    fn add(&mut self, points: usize) {
        match points {
            1 => self.midpoint += 1,
            2 => self.gauss2 += 1,
            _ => self.gauss4 += 1,
        }
    }

    fn merged(self, o: DirectCounts) -> DirectCounts {
        DirectCounts {
            midpoint: self.midpoint + o.midpoint,
            gauss2: self.gauss2 + o.gauss2,
            gauss4: self.gauss4 + o.gauss4,
            map_exact: self.map_exact + o.map_exact,
            dark: self.dark + o.dark,
            shadow_exact: self.shadow_exact + o.shadow_exact,
            shadow_polar: self.shadow_polar + o.shadow_polar,
        }
    }
}

/// Where the body has no map or its map has no relief, an interior pixel's
/// flux is (D + I ρ) ρ: D and I are smooth in the pixel position (geometry,
/// Oren–Nayar's ρ² inter-reflection term in I) and ρ, the map's mean over
/// the pixel's footprint, is not. So D, I and the footprint (texel centre
/// and axes, also smooth) are evaluated exactly on a lattice of pixel
/// centres every `step` pixels, and each pixel interpolates them with a
/// 4×4-node cubic Lagrange stencil (error O(step⁴)); only the map is read
/// per pixel. A pixel whose stencil has a node off the lit disk, near the
/// limb (where the midpoint rule is not enough), near a pole (where the
/// texel coordinates turn fast) or where the model is not quadratic in the
/// albedo, is evaluated directly. The footprint's texel x is unwrapped
/// across the map's seam before it is interpolated. The Sun's nodes (cast
/// shadows) depend on the geometry alone and are built for every model.
#[derive(Default)]
struct Lattice {
    step: usize,
    /// Whether `nodes` hold the flux's factors (else only the Sun's nodes
    /// are built, and `nodes` is empty).
    flux: bool,
    cols: usize,
    /// Node (m, n) at pixel centre (x0 + (m − 1) step, y0 + (n − 1) step)
    /// of the ROI; `None` where it may not be used.
    nodes: Vec<Option<Factors>>,
    /// Lagrange weights of the pixels at offsets 0..step from a node.
    weights: Vec<[f64; 4]>,
    /// For each ROI column: its lattice column (the stencil's second) and
    /// offset from it, so the pixel loop does not divide.
    column_of: Vec<(usize, usize)>,
    /// Map width [texels] (for longitude unwrapping).
    map_width: f64,
    /// The Sun at each node ([`SunNode`]) when the frame casts relief
    /// shadows, else empty; `None` near a pole.
    sun_nodes: Vec<Option<SunNode>>,
    /// Horizon-map width [cells] (for longitude unwrapping).
    horizon_width: f64,
    /// The Sun at each node in the polar frame ([`PolarNode`]) when the
    /// frame casts relief shadows, else empty; `None` outside the cap.
    polar_nodes: Vec<Option<PolarNode>>,
    /// The cap the polar nodes are in: +1 north, −1 south (the one on the
    /// camera's side of the equator).
    cap: f64,
}

/// D, I, and the footprint: texel x, y and axes a1, a2.
type Factors = [f64; 8];

/// The Sun seen from a node, as [`SunAtPoint`]: horizon-map x, y, sin e,
/// east and north components. All are smooth in the pixel position away
/// from the poles (where the nodes are `None`), so a pixel interpolates
/// them like the [`Factors`] and pays no ray–sphere hit or `atan2` for
/// its cast-shadow factor; the interpolation's effect on the factor is
/// bounded in `tests/shadow_lattice.rs`.
type SunNode = [f64; 5];

thread_local! {
    /// A row's lattice columns ([`Lattice::columns_at_row`]).
    static COLUMNS: std::cell::RefCell<Vec<Option<Factors>>> =
        const { std::cell::RefCell::new(Vec::new()) };
    /// A row's lattice columns of the Sun's nodes.
    static SUN_COLUMNS: std::cell::RefCell<SunColumns> =
        const { std::cell::RefCell::new(SunColumns { equatorial: Vec::new(), polar: Vec::new() }) };
}

/// A row's lattice columns of the Sun's nodes, equatorial and polar.
struct SunColumns {
    equatorial: Vec<Option<SunNode>>,
    polar: Vec<Option<PolarNode>>,
}

/// Nodes where |cos latitude| is below this are not interpolated: the
/// texel coordinates' derivatives grow as 1/cos latitude.
const NODE_MIN_COS_LAT: f64 = 0.3;

/// Nodes closer to the limb than this many lattice steps are not
/// interpolated. The surface normal goes as √d at distance d from the limb,
/// so a cubic's relative error there is about 0.022 (step/d)⁴: 1e-4 at four
/// steps.
const NODE_LIMB_STEPS: f64 = 4.0;

/// Cubic Lagrange weights of nodes −1, 0, 1, 2 at t ∈ [0, 1).
fn lagrange(t: f64) -> [f64; 4] {
    [
        -t * (t - 1.0) * (t - 2.0) / 6.0,
        (t + 1.0) * (t - 1.0) * (t - 2.0) / 2.0,
        -(t + 1.0) * t * (t - 2.0) / 2.0,
        (t + 1.0) * t * (t - 1.0) / 6.0,
    ]
}

/// `x` shifted by a map width toward `reference` (longitude wrap).
#[inline]
fn unwrap(x: f64, reference: f64, width: f64) -> f64 {
    let d = x - reference;
    if d > 0.5 * width {
        x - width
    } else if d < -0.5 * width {
        x + width
    } else {
        x
    }
}

/// Σ w_k q_k over four node sets, component `wrap` (a map x) unwrapped
/// to the first node's where `map_width` > 0.
#[inline]
fn combine<const N: usize>(
    q: [&[f64; N]; 4],
    w: &[f64; 4],
    wrap: usize,
    map_width: f64,
) -> [f64; N] {
    let mut out = [0.0; N];
    for (k, o) in out.iter_mut().enumerate() {
        *o = w[0] * q[0][k] + w[1] * q[1][k] + w[2] * q[2][k] + w[3] * q[3][k];
    }
    if map_width > 0.0 {
        let r = q[0][wrap];
        out[wrap] = w[0] * r
            + w[1] * unwrap(q[1][wrap], r, map_width)
            + w[2] * unwrap(q[2][wrap], r, map_width)
            + w[3] * unwrap(q[3][wrap], r, map_width);
    }
    out
}

/// Component of [`Factors`] holding the albedo map's texel x.
const FACTORS_X: usize = 2;
/// Component of [`SunNode`] holding the horizon map's x.
const SUN_X: usize = 0;
/// Component of [`SunNode`] holding sin(Sun elevation).
const SUN_SIN_E: usize = 2;
/// Component of [`PolarNode`] holding sin(Sun elevation).
const POLAR_SIN_E: usize = polar_sun::SIN_E;

impl Lattice {
    /// The lattice of `roi` every `step` pixels: the Sun's nodes when the
    /// frame casts relief shadows, the flux's where `flux`.
    fn build(&mut self, frame: &Frame, rays: &PixelRays, roi: Rect, (step, flux): (usize, bool)) {
        self.step = step;
        self.flux = flux;
        self.cols = (roi.width() - 1) / step + 4;
        let rows = (roi.height() - 1) / step + 4;
        self.map_width = frame
            .body
            .albedo_map
            .as_ref()
            .map_or(0.0, |m| m.width as f64);
        self.weights.clear();
        self.weights
            .extend((0..step).map(|r| lagrange(r as f64 / step as f64)));
        self.column_of.clear();
        self.column_of
            .extend((0..roi.width()).map(|ii| (ii / step + 1, ii % step)));
        self.nodes.clear();
        let origin_u = roi.x0 as f64 + 0.5 - step as f64;
        let origin_v = roi.y0 as f64 + 0.5 - step as f64;
        self.build_sun_nodes(frame, rays, rows, (origin_u, origin_v));
        if !flux {
            return;
        }
        self.nodes.resize(self.cols * rows, None);
        // Nodes hold the smooth factors: a cast shadow is not smooth, so
        // each pixel applies its own (`Lattice::relief_shadow`).
        let frame = &Frame {
            shadows: None,
            ..*frame
        };
        self.nodes
            .par_chunks_mut(self.cols)
            .enumerate()
            .for_each(|(n, row)| {
                let v = origin_v + (n * step) as f64;
                for (m, node) in row.iter_mut().enumerate() {
                    *node = rays.node(frame, origin_u + (m * step) as f64, v, step);
                }
            });
    }

    /// The Sun at every node (`rows` rows, node (0, 0) at pixel position
    /// `origin`), equatorial and polar, when the frame casts relief
    /// shadows, else none.
    fn build_sun_nodes(
        &mut self,
        frame: &Frame,
        rays: &PixelRays,
        rows: usize,
        (origin_u, origin_v): (f64, f64),
    ) {
        self.sun_nodes.clear();
        self.polar_nodes.clear();
        if frame.shadows.is_none() {
            return;
        }
        self.cap = rays.camera_cap();
        let cap = self.cap;
        self.sun_nodes.resize(self.cols * rows, None);
        self.polar_nodes.resize(self.cols * rows, None);
        let (lattice_step, step) = (self.step, self.step as f64);
        let (cols, horizon_width) = (self.cols, &mut self.horizon_width);
        self.sun_nodes
            .par_chunks_mut(cols)
            .zip(self.polar_nodes.par_chunks_mut(cols))
            .enumerate()
            .for_each(|(n, (row, polar))| {
                let v = origin_v + n as f64 * step;
                for (m, (node, p)) in row.iter_mut().zip(polar).enumerate() {
                    (*node, *p) =
                        rays.sun_nodes(frame, (origin_u + m as f64 * step, v), lattice_step, cap);
                }
            });
        if let Some(shadows) = &frame.shadows {
            *horizon_width = shadows.map.width() as f64;
        }
    }

    /// The Sun's node columns, equatorial and polar, interpolated to ROI
    /// row `jj` (empty without cast shadows).
    fn sun_columns_at_row(&self, jj: usize, out: &mut SunColumns) {
        out.equatorial.clear();
        out.polar.clear();
        if self.sun_nodes.is_empty() {
            return;
        }
        self.columns_at_row(
            &self.sun_nodes,
            (SUN_X, self.horizon_width),
            jj,
            &mut out.equatorial,
        );
        self.columns_at_row(&self.polar_nodes, (0, 0.0), jj, &mut out.polar);
    }

    /// The nodes of every lattice column interpolated to ROI row `jj`.
    fn columns_at_row<const N: usize>(
        &self,
        nodes: &[Option<[f64; N]>],
        (wrap, map_width): (usize, f64),
        jj: usize,
        out: &mut Vec<Option<[f64; N]>>,
    ) {
        let (n, w) = (jj / self.step + 1, &self.weights[jj % self.step]);
        let c = self.cols;
        out.clear();
        out.extend((0..c).map(|m| {
            let q0 = nodes[(n - 1) * c + m].as_ref()?;
            let q1 = nodes[n * c + m].as_ref()?;
            let q2 = nodes[(n + 1) * c + m].as_ref()?;
            let q3 = nodes[(n + 2) * c + m].as_ref()?;
            Some(combine([q0, q1, q2, q3], w, wrap, map_width))
        }));
    }

    /// The node values at ROI column `ii` of the row whose columns are
    /// given.
    #[inline]
    fn interpolate_at<const N: usize>(
        &self,
        columns: &[Option<[f64; N]>],
        (wrap, map_width): (usize, f64),
        ii: usize,
    ) -> Option<[f64; N]> {
        let (m, offset) = self.column_of[ii];
        let q = [
            columns[m - 1].as_ref()?,
            columns[m].as_ref()?,
            columns[m + 1].as_ref()?,
            columns[m + 2].as_ref()?,
        ];
        Some(combine(q, &self.weights[offset], wrap, map_width))
    }

    /// Component `k` alone of [`Self::interpolate_at`] (not one that
    /// wraps), in the same arithmetic.
    #[inline]
    fn interpolate_one<const N: usize>(
        &self,
        columns: &[Option<[f64; N]>],
        ii: usize,
        k: usize,
    ) -> Option<f64> {
        let (m, offset) = self.column_of[ii];
        let w = &self.weights[offset];
        let (a, b) = (columns[m - 1].as_ref()?[k], columns[m].as_ref()?[k]);
        let (c, d) = (columns[m + 1].as_ref()?[k], columns[m + 2].as_ref()?[k]);
        Some(w[0] * a + w[1] * b + w[2] * c + w[3] * d)
    }

    /// The relief's cast-shadow factor of pixel (i, j), ROI column `ii`:
    /// from the interpolated Sun where the row's Sun columns allow
    /// (equatorial nodes, else polar ones), else exact at the pixel centre
    /// (and in the penumbra).
    #[inline]
    fn relief_shadow(
        &self,
        frame: &Frame,
        rays: &PixelRays,
        sun: &SunColumns,
        (ii, i, j): (usize, usize, usize),
        counts: &mut DirectCounts,
    ) -> f64 {
        let Some(shadows) = &frame.shadows else {
            return 1.0;
        };
        // A Sun above every horizon needs only its elevation (most pixels
        // of a frame away from the terminator): interpolated alone first.
        let equatorial_sin_e = self.interpolate_one(&sun.equatorial, ii, SUN_SIN_E);
        let polar_sin_e = || self.interpolate_one(&sun.polar, ii, POLAR_SIN_E);
        let f = if let Some(sin_e) = equatorial_sin_e {
            if shadows.is_clear(sin_e) {
                return 1.0;
            }
            let [x, y, sin_e, east, north] = self
                .interpolate_at(&sun.equatorial, (SUN_X, self.horizon_width), ii)
                .expect("every node of the stencil is there");
            shadows.factor_at(&SunAtPoint {
                x,
                y,
                sin_e,
                east,
                north,
            })
        } else if let Some(sin_e) = polar_sin_e() {
            counts.shadow_polar += 1;
            if shadows.is_clear(sin_e) {
                return 1.0;
            }
            let q = self
                .interpolate_at(&sun.polar, (0, 0.0), ii)
                .expect("every node of the stencil is there");
            shadows.factor_at(&polar_sun::sun_at(shadows.map, &q, self.cap))
        } else {
            counts.shadow_exact += 1;
            return rays.relief_shadow_at(frame, i, j);
        };
        // In the penumbra the factor is steep (≈ 2/(π ρ) per radian): the
        // exact geometry there. Lit or dark, it is flat within reach of the
        // interpolation's error (the disk share goes as (1 − |u|)^{3/2} at
        // its ends), so the interpolated answer stands.
        if f > 0.0 && f < 1.0 {
            counts.shadow_exact += 1;
            rays.relief_shadow_at(frame, i, j)
        } else {
            f
        }
    }

    /// A pixel's flux from its interpolated factors, and whether the map's
    /// mean was exact.
    #[inline]
    fn pixel_flux(&self, frame: &Frame, q: Factors) -> (f64, bool) {
        let (rho, exact) = match &frame.body.albedo_map {
            None => (1.0, false),
            Some(map) => {
                // Back into [0, W) (a division-free rem_euclid: x is within
                // a map width of it).
                let w = self.map_width;
                let x = if q[2] < 0.0 {
                    q[2] + w
                } else if q[2] >= w {
                    q[2] - w
                } else {
                    q[2]
                };
                let (mean, exact) = Footprint {
                    x,
                    y: q[3],
                    a1: (q[4], q[5]),
                    a2: (q[6], q[7]),
                }
                .filtered_mean(
                    map,
                    frame.texture_samples,
                    frame.map_filter,
                    frame.map_tolerance,
                );
                (mean * frame.map_scale, exact)
            }
        };
        (((q[0] + q[1] * rho) * rho).max(0.0), exact)
    }
}

/// Spacing [corners] of the coarse scan of [`fill_interval`].
const SCAN_STEP: usize = 8;

/// Set `row[i] = ok(i)` where `ok` holds on one interval of indices (a row
/// of a convex region): a coarse scan finds it, bisection its ends. An
/// interval shorter than the scan step may be missed, which only leaves
/// its corners out (conservative: those pixels go to the lune's caps).
fn fill_interval(row: &mut [bool], ok: impl Fn(usize) -> bool) {
    row.fill(false);
    let n = row.len();
    let mut samples = (0..n).step_by(SCAN_STEP).chain(std::iter::once(n - 1));
    let Some(first) = samples.by_ref().find(|&i| ok(i)) else {
        return;
    };
    let mut last = first;
    for i in samples {
        if !ok(i) {
            break;
        }
        last = i;
    }
    // Leftmost true in (first − step, first]: ok is monotone there.
    let lo = first.saturating_sub(SCAN_STEP);
    let start = if lo == first || ok(lo) {
        lo
    } else {
        first_true(lo, first, &ok)
    };
    // Rightmost true in [last, last + step).
    let hi = (last + SCAN_STEP).min(n - 1);
    let end = if ok(hi) {
        hi
    } else {
        first_true(last, hi, |i| !ok(i)) - 1
    };
    row[start..=end].fill(true);
}

/// The smallest i in (lo, hi] with `pred(i)`, by bisection, where `pred`
/// is false at `lo`, true at `hi` and monotone between.
fn first_true(mut lo: usize, mut hi: usize, pred: impl Fn(usize) -> bool) -> usize {
    while hi - lo > 1 {
        let mid = (lo + hi) / 2;
        if pred(mid) {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    hi
}

/// Rays of the pixel grid against the body sphere, in the camera frame.
pub struct PixelRays {
    /// Body centre in the camera frame [m].
    centre: DVec3,
    radius: f64,
    /// Camera frame → body-fixed frame.
    cam_to_body: DMat3,
    /// Camera frame → Lester frame.
    cam_to_local: DMat3,
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    sin_a: f64,
    cos_a: f64,
    camera_local: DVec3,
    /// Apparent radius [px].
    radius_px: f64,
    /// Whether the lit, visible disk is convex on the image.
    pub convex: bool,
    /// Estimated relative quadrature error allowed per pixel.
    tolerance: f64,
}

impl PixelRays {
    /// Rays for `frame`, or None when interior pixels do not apply: the
    /// distant-observer mode, a displacement map (the silhouette is not the
    /// sphere's), the camera inside the sphere, or a body too small.
    /// `tolerance`: see [`super::RenderSettings::pixel_tolerance`].
    pub fn new(frame: &Frame, tolerance: f64) -> Option<PixelRays> {
        if frame.distant || frame.height.is_some() {
            return None;
        }
        let centre = -frame.camera_cam;
        let radius = frame.radius;
        let c = centre.length_squared() - radius * radius;
        if !(c > 0.0) {
            return None;
        }
        let cam = frame.camera;
        let apparent = cam.fx.min(cam.fy) * (radius / c.sqrt());
        if apparent < MIN_RADIUS_PX {
            return None;
        }
        let [a0, a1, a2] = frame.axes_cam;
        let cam_to_local = DMat3::from_cols(a0, a1, a2).transpose();
        let [b0, b1, b2] = frame.axes_body;
        let local_to_body = DMat3::from_cols(b0, b1, b2);
        Some(PixelRays {
            centre,
            radius,
            cam_to_body: local_to_body * cam_to_local,
            cam_to_local,
            fx: cam.fx,
            fy: cam.fy,
            cx: cam.cx,
            cy: cam.cy,
            sin_a: frame.lune.alpha.sin(),
            cos_a: frame.lune.alpha.cos(),
            camera_local: frame.lune.camera_local(),
            radius_px: apparent,
            convex: frame.lune.alpha <= std::f64::consts::FRAC_PI_2 && frame.occulter.is_none(),
            tolerance,
        })
    }

    /// Camera-frame ray (x, y, 1) through continuous pixel position (u, v)
    /// and the distance factor t of its first hit (P = t·ray), if any.
    #[inline]
    fn hit(&self, u: f64, v: f64) -> Option<(DVec3, f64, DVec3)> {
        let d = DVec3::new((u - self.cx) / self.fx, (v - self.cy) / self.fy, 1.0);
        let a = d.length_squared();
        let b = d.dot(self.centre);
        if b <= 0.0 {
            return None;
        }
        // Miss distance from the perpendicular component of the centre, not
        // from b² − a(|C|² − R²), which cancels catastrophically at
        // planetary distances.
        let perp = self.centre - d * (b / a);
        let disc = self.radius * self.radius - perp.length_squared();
        if !(disc > 0.0) {
            return None;
        }
        let back = (disc / a).sqrt();
        let t = b / a - back;
        let n_cam = (-perp - d * back) / self.radius;
        Some((d, t, n_cam))
    }

    /// Whether the surface point seen through (u, v) is lit by the whole
    /// solar disk (the lune's lit condition, and no occulter shadow).
    #[inline]
    fn corner_ok(&self, frame: &Frame, u: f64, v: f64) -> bool {
        let Some((_, _, n_cam)) = self.hit(u, v) else {
            return false;
        };
        let n_local = self.cam_to_local * n_cam;
        n_local.x > frame.lune.k_sun
            && (frame.occulter.is_none() || frame.sun_fraction(n_local * self.radius) >= 1.0)
    }

    /// Surface point and frames seen through continuous pixel position
    /// (u, v).
    #[inline]
    fn surface(&self, u: f64, v: f64) -> Option<Surface> {
        let (d, t, n_cam) = self.hit(u, v)?;
        let p = d * t;
        let d_n = d.dot(n_cam);
        if !(d_n < 0.0) {
            return None;
        }
        Some(Surface {
            d,
            t,
            p,
            n_cam,
            n_local: self.cam_to_local * n_cam,
            n_body: self.cam_to_body * n_cam,
            d_n,
        })
    }

    /// The map footprint of one pixel at `s`: the tangent vectors of the hit
    /// per pixel step (unit sphere), dP/du = t (∂d/∂u − d (∂d/∂u·n)/(d·n)).
    #[inline]
    fn footprint(&self, map: &EquirectMap, s: &Surface) -> Footprint {
        let du = DVec3::new(1.0 / self.fx, 0.0, 0.0);
        let dv = DVec3::new(0.0, 1.0 / self.fy, 0.0);
        let scale = s.t / self.radius;
        let e_u = (du - s.d * (du.dot(s.n_cam) / s.d_n)) * scale;
        let e_v = (dv - s.d * (dv.dot(s.n_cam) / s.d_n)) * scale;
        Footprint::new(
            map,
            s.n_body,
            self.cam_to_body * e_v,
            self.cam_to_body * e_u,
        )
    }

    /// ∫ f_r μ0 (AU/d_sun)² dΩ over the pixel at `s` for a given albedo, by
    /// the product rule at its centre.
    #[inline]
    fn flux_at(&self, frame: &Frame, s: &Surface, albedo: f64) -> f64 {
        let mu0_far = s.n_local.x;
        let mu_far = s.n_local.x * self.cos_a + s.n_local.y * self.sin_a;
        let integrand = frame.integrand(
            s.n_local,
            s.n_body,
            albedo,
            mu0_far,
            mu_far,
            self.cos_a,
            self.camera_local,
            frame.lune.camera_range,
            frame.lune.sun_range,
            self.radius,
            frame.model,
        );
        // integrand · dS with dS = |P|² / μ · dΩ and dΩ = du dv / (fx fy |d|³).
        let dist = s.p.length();
        let mu = -s.p.dot(s.n_cam) / dist;
        let d_len = s.d.length();
        let omega = 1.0 / (self.fx * self.fy * d_len * d_len * d_len);
        integrand * dist * dist / mu * omega
    }

    /// The Sun seen from the surface through pixel position (u, v), as an
    /// equatorial and a polar lattice node of a lattice `step` pixels
    /// apart: both None off the sphere or within [`NODE_LIMB_STEPS`] steps
    /// of the limb, the equatorial one also where |cos latitude| is below [`NODE_MIN_COS_LAT`]
    /// (local east turns fast near a pole), the polar one None outside
    /// the polar cap `cap` ([`polar_sun::polar_node`]).
    fn sun_nodes(
        &self,
        frame: &Frame,
        (u, v): (f64, f64),
        step: usize,
        cap: f64,
    ) -> (Option<SunNode>, Option<PolarNode>) {
        let (Some(shadows), Some(s)) = (frame.shadows.as_ref(), self.surface(u, v)) else {
            return (None, None);
        };
        // Near the limb the normal goes as √(distance): not a cubic.
        if self.to_limb(&s) < NODE_LIMB_STEPS * step as f64 {
            return (None, None);
        }
        let l = frame.sun_direction_body(s.n_local, self.radius);
        let polar = polar_sun::polar_node(shadows, s.n_body, l, cap);
        if s.n_body.x.hypot(s.n_body.y) < NODE_MIN_COS_LAT {
            return (None, polar);
        }
        let g = shadows.geometry(s.n_body, l);
        (Some([g.x, g.y, g.sin_e, g.east, g.north]), polar)
    }

    /// The polar cap on the camera's side of the body's equator: +1
    /// north, −1 south.
    fn camera_cap(&self) -> f64 {
        let camera_body = self.cam_to_body * -self.centre;
        if camera_body.z < 0.0 {
            -1.0
        } else {
            1.0
        }
    }

    /// The relief's cast-shadow factor at the centre of pixel (i, j).
    #[inline]
    fn relief_shadow_at(&self, frame: &Frame, i: usize, j: usize) -> f64 {
        if frame.shadows.is_none() {
            return 1.0;
        }
        match self.surface(i as f64 + 0.5, j as f64 + 0.5) {
            Some(s) => frame.relief_shadow(s.n_local, s.n_body, self.radius),
            None => 0.0,
        }
    }

    /// Whether interior pixels may interpolate a [`Lattice`]'s flux: no occulter
    /// (its penumbra is not smooth), no parameter maps (the model's terms
    /// then vary per point), and without an albedo map any model, with one
    /// a model quadratic in the albedo.
    fn lattice_applies(&self, frame: &Frame) -> bool {
        frame.occulter.is_none()
            && frame.body.parameter_maps.is_empty()
            && frame.body.relief.albedo_tiles.is_none()
            && (frame.body.albedo_map.is_none() || frame.model.is_albedo_quadratic())
    }

    /// μ, the cosine of the emission angle at `s`.
    #[inline]
    fn mu(s: &Surface) -> f64 {
        -s.p.dot(s.n_cam) / s.p.length()
    }

    /// Distance [px] from `s` to the limb on the image (sin e = 1 − d/R).
    #[inline]
    fn to_limb(&self, s: &Surface) -> f64 {
        let mu = Self::mu(s);
        self.radius_px * (1.0 - (1.0 - mu * mu).max(0.0).sqrt())
    }

    /// Whether one point per pixel is enough at `s`: the midpoint rule's
    /// estimated relative error 1/(24 μ³ μ0 R²) is within the pixel
    /// tolerance.
    #[inline]
    fn midpoint_suffices(&self, s: &Surface) -> bool {
        let mu = Self::mu(s);
        let mu0 = s.n_local.x.max(1e-6);
        let r2 = self.radius_px * self.radius_px;
        24.0 * mu * mu * mu * mu0 * r2 * self.tolerance >= 1.0
    }

    /// The lattice factors at pixel position (u, v), or None where a pixel
    /// may not interpolate them (see [`Lattice`]).
    fn node(&self, frame: &Frame, u: f64, v: f64, step: usize) -> Option<Factors> {
        let s = self.surface(u, v)?;
        let mu0 = s.n_local.x;
        if !(mu0 > frame.lune.k_sun)
            || !self.midpoint_suffices(&s)
            || self.to_limb(&s) < NODE_LIMB_STEPS * step as f64
        {
            return None;
        }
        let Some(map) = &frame.body.albedo_map else {
            return Some([
                self.flux_at(frame, &s, frame.albedo),
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
            ]);
        };
        if s.n_body.x.hypot(s.n_body.y) < NODE_MIN_COS_LAT {
            return None;
        }
        // (D + I ρ) ρ from ρ = 1 and ρ = 1/2.
        let one = self.flux_at(frame, &s, 1.0);
        let half = self.flux_at(frame, &s, 0.5);
        if !(one > 0.0 && half > 0.0) {
            return None;
        }
        let i = 2.0 * (one - 2.0 * half);
        let f = self.footprint(map, &s);
        Some([one - i, i, f.x, f.y, f.a1.0, f.a1.1, f.a2.0, f.a2.1])
    }

    /// Collected flux of interior pixel (i, j) per unit solar irradiance at
    /// 1 au, evaluated directly without its cast shadow (the caller applies
    /// one factor at the pixel centre, as on the lattice), the quadrature's points per axis, and
    /// whether the map's mean was exact.
    ///
    /// With the exact mean (the exact filter, or the adaptive one where
    /// it refined), each Gauss point takes the exact mean of its own cell
    /// of the pixel (cut where the points' weights add up), mapped by the
    /// point's own footprint: the product rule per cell, which keeps the
    /// map's variation across the pixel that a single mean times every
    /// point's geometry loses.
    #[inline]
    fn unshadowed_pixel_flux(&self, frame: &Frame, i: usize, j: usize) -> (f64, usize, bool) {
        let (u, v) = (i as f64 + 0.5, j as f64 + 0.5);
        let Some(s) = self.surface(u, v) else {
            return (0.0, 1, false);
        };
        let (albedo, exact) = match &frame.body.albedo_map {
            None => (frame.albedo, None),
            Some(map) => {
                let f = self.footprint(map, &s);
                let (mean, exact) = f.filtered_mean(
                    map,
                    frame.texture_samples,
                    frame.map_filter,
                    frame.map_tolerance,
                );
                (mean * frame.map_scale, exact.then_some(map))
            }
        };
        // Albedo tiles: their value at the pixel centre, blended over the
        // map's mean, for the whole pixel.
        let (albedo, exact) = match frame.body.relief.albedo_tiles.as_deref() {
            Some(t) if t.covers_dir(s.n_body) => {
                (t.albedo_dir(s.n_body, frame.map_scale, albedo), None)
            }
            _ => (albedo, exact),
        };
        let midpoint = self.flux_at(frame, &s, albedo);
        if self.midpoint_suffices(&s) {
            return (midpoint, 1, exact.is_some());
        }
        let to_limb = self.to_limb(&s);
        // The rule with the pixel's mean albedo (which decides between 2×2
        // and 4×4, as the geometry alone would) and with each cell's.
        let gauss = |rule: &[(f64, f64)]| {
            let cells = gauss_cells(rule);
            let (mut whole, mut by_cell) = (0.0, 0.0);
            for (&(du, wu), &cu) in rule.iter().zip(&cells) {
                for (&(dv, wv), &cv) in rule.iter().zip(&cells) {
                    let Some(g) = self.surface(u + du, v + dv) else {
                        continue;
                    };
                    let w = wu * wv;
                    let f = self.flux_at(frame, &g, albedo);
                    whole += w * f;
                    by_cell += match &exact {
                        None => w * f,
                        Some(map) => {
                            // The cell around the point, on the point's own
                            // footprint: near the limb the centre's
                            // parallelogram is a poor map of the pixel's
                            // outer cells.
                            let fp = self.footprint(map, &g);
                            let c = fp.part((cu.0 - du, cu.1 - du), (cv.0 - dv, cv.1 - dv));
                            let a = map.parallelogram_mean(c.x, c.y, c.a1, c.a2) * frame.map_scale;
                            w * self.flux_at(frame, &g, a)
                        }
                    };
                }
            }
            (whole, by_cell)
        };
        let (two, two_cells) = gauss(&GAUSS2);
        let max_step = GAUSS2_MAX_STEP * self.tolerance;
        if to_limb >= GAUSS2_MIN_PX && (two - midpoint).abs() <= max_step * two.abs() {
            (two_cells, 2, exact.is_some())
        } else {
            (gauss(&GAUSS4).1, 4, exact.is_some())
        }
    }
}

/// The cells [lo, hi] [px from the pixel centre] of a Gauss rule's points
/// along one axis: the pixel cut where the weights add up, so each cell's
/// width is its point's weight and holds the point.
fn gauss_cells(rule: &[(f64, f64)]) -> [(f64, f64); 4] {
    let mut cells = [(0.0, 0.0); 4];
    let mut lo = -0.5;
    for (c, &(_, w)) in cells.iter_mut().zip(rule) {
        *c = (lo, lo + w);
        lo += w;
    }
    cells
}

/// Gauss–Legendre offsets [px] from a pixel centre and weights (summing to
/// 1) of 2 and 4 points.
const GAUSS2: [(f64, f64); 2] = [
    (-0.288_675_134_594_812_9, 0.5),
    (0.288_675_134_594_812_9, 0.5),
];
const GAUSS4: [(f64, f64); 4] = [
    (-0.430_568_155_797_026_3, 0.173_927_422_568_726_9),
    (-0.169_990_521_792_428_1, 0.326_072_577_431_273_1),
    (0.169_990_521_792_428_1, 0.326_072_577_431_273_1),
    (0.430_568_155_797_026_3, 0.173_927_422_568_726_9),
];

/// A ray's first hit on the sphere, in the frames the integrand needs.
struct Surface {
    /// Ray (x, y, 1) in the camera frame.
    d: DVec3,
    /// P = t d.
    t: f64,
    p: DVec3,
    n_cam: DVec3,
    n_local: DVec3,
    n_body: DVec3,
    /// d · n (negative on the visible side).
    d_n: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every interval of a row up to 40 wide, brute force as the reference:
    /// the fill never marks a corner outside the interval, and finds the
    /// interval exactly once it is at least one scan step long.
    #[test]
    fn fill_interval_finds_every_long_interval_and_never_overshoots() {
        for n in [1, 2, 7, 8, 9, 17, 40] {
            for a in 0..n {
                for b in a..=n {
                    let mut row = vec![true; n];
                    fill_interval(&mut row, |i| (a..b).contains(&i));
                    for (i, &c) in row.iter().enumerate() {
                        assert!(!c || (a..b).contains(&i), "n {n} [{a}, {b}) marks {i}");
                    }
                    if b - a >= SCAN_STEP || (a == 0 && b > 0) || b == n && b > a {
                        let count = row.iter().filter(|&&c| c).count();
                        assert_eq!(count, b - a, "n {n} [{a}, {b})");
                    }
                }
            }
        }
    }
}
