//! The paper's method. A [`Renderer`] owns the pixel grid of one camera (or
//! of the facility screen seen through the collimator) and, for each state,
//! turns the body into a point cloud of surface caps with power coefficients
//! PF_i ([`caps`]), integrates each cap ([`closed_form`]), and grids it onto
//! the pixels its footprint covers. Pixels whose whole preimage is lit and
//! visible take that preimage as their one cap ([`interior`]), so only the
//! edges need the lune's caps. [`detector`] then applies the paper's Eq. 2,
//! and [`output`] writes the files of `optistim render`; [`field`] says
//! whether the body can be in the frame at all.
//!
//! The renderer's primary product is the *collected flux* image: for each
//! pixel, Σ_i ∫_cap f_r μ0 (AU/d_sun)² μ / d² dS, the irradiance the pixel's
//! caps produce at the camera per unit solar irradiance at 1 au. Radiance,
//! electrons and DN follow from it with scalars from the band integrals.

pub mod caps;
pub mod closed_form;
pub mod detector;
pub mod field;
pub mod interior;
pub mod lune;
pub mod occlusion;
pub mod output;
mod polar_sun;
pub mod relief;
pub mod relief_effect;
pub mod shadow_edges;
pub mod sight;
pub mod sight_memo;

use std::time::Instant;

use glam::DVec3;
use rayon::prelude::*;
use serde::Serialize;

use crate::radiometry::reflectance::Reflectance;
use crate::scene::{Body, Pinhole, State};
use caps::{Cell, CornerRow, Frame, Leaf, Rect, Sink, Weight};
use interior::{InteriorMask, PixelRays};
use lune::Lune;

pub use crate::render_settings::{
    GeometryMode, Interior, MapFilter, RenderSettings, DEFAULT_DENSITY, DEFAULT_MAP_TOLERANCE,
};

/// What one call of [`Renderer::render_flux`] did.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct RenderStats {
    /// Caps laid out inside or near the field of view.
    pub caps: u64,
    /// Caps whose PF was integrated and gridded: those not lying wholly
    /// on interior pixels (with a positive PF).
    pub caps_integrated: u64,
    /// Leaf cells.
    pub cells: usize,
    /// Σ PF_i of the integrated caps, per unit solar irradiance at 1 au:
    /// the body's irradiance at the camera from the caps near the field.
    pub total_flux: f64,
    /// Phase angle at the body centre [rad].
    pub phase_angle: f64,
    /// Pixels integrated per pixel (their preimage is the cap).
    pub interior_pixels: usize,
    /// How many interior pixels were evaluated directly rather than
    /// interpolated from the node lattice, by quadrature rule.
    pub interior_direct: interior::DirectCounts,
    /// Pixels that may hold signal.
    #[serde(skip)]
    pub roi: Rect,
    /// Wall time of each stage.
    pub stages: StageTimes,
    /// Whether the relief's cast shadows were applied, and why (None: the
    /// body has no `shadows`).
    pub shadows: Option<relief::ShadowDecision>,
}

/// Wall time [s] of the stages of one [`Renderer::render_flux`] call, in
/// order; they sum to the call's time less clearing the last frame.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct StageTimes {
    /// Lune and cap layout: the recursive split with culling (serial).
    pub layout: f64,
    /// Interior-pixel classification and dropping the leaves it covers.
    pub mask: f64,
    /// Edge caps: integration, gridding and the workers' reduction.
    pub caps: f64,
    /// Interior pixels.
    pub interior: f64,
}

/// One worker's accumulation buffer (over the ROI) and corner-row scratch.
type Worker = (Vec<f32>, [CornerRow; 2]);

/// Renders bodies onto one pixel grid. Buffers are kept between calls and
/// only grow up to the image size, so a frame loop does not allocate.
pub struct Renderer {
    camera: Pinhole,
    flux: Vec<f32>,
    dirty: Rect,
    workers: Vec<Worker>,
    leaves: Vec<Leaf>,
    stack: Vec<Cell>,
    chunks: Vec<std::ops::Range<usize>>,
    interior: InteriorMask,
    sight: sight_memo::SightMemo,
}

impl Renderer {
    /// Renderer for a pixel grid.
    pub fn new(camera: Pinhole) -> Self {
        let n = camera.width * camera.height;
        let threads = rayon::current_num_threads().max(1);
        Self {
            camera,
            flux: crate::resident_vec(0.0, n),
            dirty: Rect::default(),
            workers: (0..threads)
                .map(|_| (Vec::new(), Default::default()))
                .collect(),
            leaves: Vec::new(),
            stack: Vec::new(),
            chunks: Vec::new(),
            sight: Default::default(),
            interior: InteriorMask::default(),
        }
    }

    /// Whether image pixel (i, j) was integrated per pixel in the last
    /// render with `interior = "pixels"` (else it came from the caps).
    pub fn is_interior_pixel(&self, i: usize, j: usize) -> bool {
        self.interior.contains(i, j)
    }

    /// The pixel grid.
    pub fn camera(&self) -> &Pinhole {
        &self.camera
    }

    /// The collected-flux image of the last render (row-major), zero outside
    /// its ROI.
    pub fn flux(&self) -> &[f32] {
        &self.flux
    }

    /// Render the body's collected flux per unit solar irradiance at 1 au.
    /// `albedo` overrides the model's albedo parameter where there is no
    /// map.
    pub fn render_flux(
        &mut self,
        body: &Body,
        state: &State,
        settings: &RenderSettings,
        albedo: Option<f64>,
    ) -> RenderStats {
        let band = BandModel {
            albedo,
            ..BandModel::default()
        };
        self.render_flux_band(body, state, settings, &band)
    }

    /// Until [`Self::end_sub_bands`], the renders are sub-bands of one
    /// frame (one body and state): the lines of sight marched through the
    /// relief in the first are read back by the others
    /// ([`sight_memo`]).
    pub fn begin_sub_bands(&mut self) {
        self.sight.begin();
    }

    /// Ends [`Self::begin_sub_bands`] and frees what it kept.
    pub fn end_sub_bands(&mut self) {
        self.sight.end();
    }

    /// What [`Self::begin_sub_bands`] keeps.
    pub fn sub_band_memo(&self) -> &sight_memo::SightMemo {
        &self.sight
    }

    /// [`render_flux`](Self::render_flux) for one sub-band of a spectral
    /// scene: the model, albedo and map scale of that band.
    pub fn render_flux_band(
        &mut self,
        body: &Body,
        state: &State,
        settings: &RenderSettings,
        band: &BandModel,
    ) -> RenderStats {
        let model = band.model.unwrap_or(&body.reflectance);
        self.clear_previous_frame();
        let camera_rel = state.camera_position - state.body_position;
        let sun_rel = state.sun_position - state.body_position;
        let distant = settings.geometry == GeometryMode::Distant;
        let lune = Lune::new(camera_rel, sun_rel, body.radius, distant);
        let mut stats = RenderStats {
            phase_angle: lune.alpha,
            ..Default::default()
        };
        // Out of the field, nothing to lay out (and the cap layout of a
        // body near the camera's plane would split cells without end).
        if lune.empty || !field::field_check(&self.camera, state, body.radius).in_field {
            return stats;
        }
        let to_camera = state.camera_attitude.inverse();
        let to_body = state.body_attitude.inverse();
        let sight_memo = self.sight.prepare(body);
        let frame = Frame {
            lune,
            camera: &self.camera,
            axes_cam: [to_camera * lune.x, to_camera * lune.y, to_camera * lune.z],
            camera_cam: to_camera * camera_rel,
            axes_body: [to_body * lune.x, to_body * lune.y, to_body * lune.z],
            body,
            model,
            albedo: band.albedo.unwrap_or_else(|| model.albedo()),
            map_scale: band.map_scale,
            weight: Weight::for_model(model),
            radius: body.radius,
            density: settings.density(),
            min_caps: settings.min_caps as f64,
            distant,
            texture_samples: settings.texture_samples,
            map_filter: settings.map_filter,
            map_tolerance: settings.map_tolerance,
            occulter: occulter_near(state, &lune, body.radius),
            shadows: None,
            height: body.relief.height.as_ref(),
            sight_memo,
        };
        let mut frame = frame;
        if body.relief.shadows.is_some() && !settings.relief {
            frame.height = None;
            stats.shadows = Some(relief::ShadowDecision {
                reason: "render.relief = false",
                ..Default::default()
            });
        } else if let Some(s) = &body.relief.shadows {
            let target = relief::target_of(settings.max_pixel_error);
            let mut decision = relief::decide_for_frame(s, &frame, target);
            if decision.applied {
                let sun_radius = (caps::SUN_RADIUS / lune.sun_range).min(1.0).asin();
                frame.shadows = Some(relief::FrameShadows::new(&s.map, sun_radius));
            }
            // The DEM's displacement (`shadows.displace`) goes with it.
            relief::decide_displacement(s, &mut frame, &mut decision);
            stats.shadows = Some(decision);
        }
        // Terrain past the sphere's limb that the displacement can lift
        // into view: its caps join the lune (`render::sight` hides them
        // where nearer relief covers them).
        if frame.height.is_some() && body.relief.far_limb {
            frame.lune.widen_view(body.radius, body.relief.height_bound);
        }

        // Lay out the caps: recursive split with culling.
        let t_layout = Instant::now();
        let roi = lay_out(&frame, &mut self.stack, &mut self.leaves);
        stats.roi = roi;
        if self.leaves.is_empty() || roi.is_empty() {
            return stats;
        }

        // Interior pixels: classify, and drop the leaves they cover.
        let t_mask = Instant::now();
        stats.stages.layout = (t_mask - t_layout).as_secs_f64();
        let rays = match settings.interior {
            Interior::Pixels => PixelRays::new(&frame, settings.pixel_tolerance),
            Interior::Caps => None,
        };
        let rays = rays.filter(|r| {
            self.interior.build(&frame, r, roi);
            self.interior.count() > 0
        });
        let mask = rays.as_ref().map(|_| &self.interior);
        if let Some(m) = mask {
            self.leaves
                .retain(|l| !m.covers(l.rect.x0, l.rect.y0, l.rect.x1, l.rect.y1));
        }
        stats.cells = self.leaves.len();
        let t_caps = Instant::now();
        stats.stages.mask = (t_caps - t_mask).as_secs_f64();

        // The caps, over the workers, then summed into the image.
        stats.caps = balance(&self.leaves, self.workers.len(), &mut self.chunks);
        (stats.total_flux, stats.caps_integrated) = integrate_leaves(
            &frame,
            &self.leaves,
            &self.chunks,
            &mut self.workers,
            roi,
            mask,
        );
        let w = self.camera.width;
        sum_workers(&mut self.flux, w, &self.workers[..self.chunks.len()], roi);
        let t_interior = Instant::now();
        stats.stages.caps = (t_interior - t_caps).as_secs_f64();

        if let Some(r) = &rays {
            let (flux, direct) = self.interior.integrate(
                &frame,
                r,
                &mut self.flux,
                w,
                (settings.node_spacing, settings.shadow_edges),
            );
            stats.total_flux += flux;
            stats.interior_pixels = self.interior.count();
            stats.interior_direct = direct;
            if let Some(d) = &mut stats.shadows {
                d.edge_pixels = self.interior.shadow_edges();
            }
        }
        stats.stages.interior = t_interior.elapsed().as_secs_f64();
        self.dirty = roi;
        stats
    }

    /// Clears what the previous frame wrote (its region only).
    fn clear_previous_frame(&mut self) {
        let w = self.camera.width;
        let dirty = self.dirty;
        for row in dirty.y0..dirty.y1 {
            self.flux[row * w + dirty.x0..row * w + dirty.x1].fill(0.0);
        }
        self.dirty = Rect::default();
    }
}

/// The occulter of `state` in the lune's frame, when some point of the body
/// can be in its penumbra (margin: the body's own angular size); None
/// skips the per-cap shadow test.
fn occulter_near(state: &State, lune: &Lune, body_radius: f64) -> Option<(DVec3, f64)> {
    let o = state.occulter?;
    let rel = o.position - state.body_position;
    let local = DVec3::new(rel.dot(lune.x), rel.dot(lune.y), rel.dot(lune.z));
    let sun_dir = DVec3::X;
    let dist = local.length();
    let sep = sun_dir.cross(local).length().atan2(sun_dir.dot(local));
    let a = (caps::SUN_RADIUS / lune.sun_range).asin();
    let b = (o.radius / dist).min(1.0).asin();
    let margin = 2.0 * (body_radius / dist).min(1.0).asin();
    (dist < lune.sun_range && sep < a + b + margin).then_some((local, o.radius))
}

/// Splits the lune recursively into leaves of caps, culling what the
/// camera cannot see; returns the image region they cover.
fn lay_out(frame: &Frame, stack: &mut Vec<Cell>, leaves: &mut Vec<Leaf>) -> Rect {
    leaves.clear();
    stack.clear();
    stack.push(Cell {
        t0: 0.0,
        t1: 1.0,
        s0: 0.0,
        s1: 1.0,
        depth: 0,
    });
    let mut roi = Rect::default();
    while let Some(cell) = stack.pop() {
        if let Some(r) = frame.visit(cell, stack, leaves) {
            roi = roi.union(&r);
        }
    }
    roi
}

/// Splits `leaves` into at most `workers` consecutive runs of about equal
/// cap counts (into `chunks`); returns the caps in all.
fn balance(leaves: &[Leaf], workers: usize, chunks: &mut Vec<std::ops::Range<usize>>) -> u64 {
    let caps: u64 = leaves.iter().map(|l| l.n_t as u64 * l.n_s as u64).sum();
    let k = workers as u64;
    chunks.clear();
    let mut start = 0;
    let mut acc = 0u64;
    for (i, leaf) in leaves.iter().enumerate() {
        acc += leaf.n_t as u64 * leaf.n_s as u64;
        if acc * k >= caps * (chunks.len() as u64 + 1) && chunks.len() + 1 < workers {
            chunks.push(start..i + 1);
            start = i + 1;
        }
    }
    chunks.push(start..leaves.len());
    caps
}

/// Integrates each chunk of leaves into its worker's buffer over `roi`;
/// returns the flux and the caps integrated.
fn integrate_leaves(
    frame: &Frame,
    leaves: &[Leaf],
    chunks: &[std::ops::Range<usize>],
    workers: &mut [Worker],
    roi: Rect,
    mask: Option<&InteriorMask>,
) -> (f64, u64) {
    let area = roi.width() * roi.height();
    workers
        .par_iter_mut()
        .zip(chunks.par_iter())
        .map(|(worker, range)| {
            let (buf, rows) = worker;
            buf.clear();
            buf.resize(area, 0.0);
            let mut sink = Sink {
                buf,
                roi,
                interior: mask,
                skipped: 0.0,
                integrated: 0,
                tape: Default::default(),
            };
            let flux = leaves[range.clone()]
                .iter()
                .map(|leaf| frame.grid_leaf(leaf, &mut sink, rows))
                .sum::<f64>();
            (flux, sink.integrated)
        })
        .reduce(|| (0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1))
}

/// Sums the workers' buffers (each over `roi`) into the image `flux` of
/// width `w`.
fn sum_workers(flux: &mut [f32], w: usize, workers: &[Worker], roi: Rect) {
    let rw = roi.width();
    flux.par_chunks_mut(w)
        .enumerate()
        .skip(roi.y0)
        .take(roi.height())
        .for_each(|(row, out)| {
            let local = (row - roi.y0) * rw;
            let out = &mut out[roi.x0..roi.x1];
            out.copy_from_slice(&workers[0].0[local..local + rw]);
            for buf in &workers[1..] {
                for (o, v) in out.iter_mut().zip(&buf.0[local..local + rw]) {
                    *o += v;
                }
            }
        });
}

/// What one (sub-)band of a render changes: the reflection model (the
/// body's spectral model at the band's wavelength), the albedo where there
/// is no map, and the factor on the map's values.
#[derive(Clone, Copy, Debug)]
pub struct BandModel<'a> {
    /// Model of this band; None: the body's.
    pub model: Option<&'a Reflectance>,
    /// Albedo where there is no map; None: the model's.
    pub albedo: Option<f64>,
    /// Factor on the albedo map's values.
    pub map_scale: f64,
}

impl Default for BandModel<'_> {
    fn default() -> Self {
        Self {
            model: None,
            albedo: None,
            map_scale: 1.0,
        }
    }
}

/// Unit vector from the camera to the body centre, in the camera frame.
pub fn line_of_sight(state: &State) -> DVec3 {
    (state.camera_attitude.inverse() * (state.body_position - state.camera_position)).normalize()
}
