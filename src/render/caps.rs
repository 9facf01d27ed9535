//! Surface caps: their layout over the lit, visible lune, their power
//! coefficients PF_i, and the area-weighted gridding of each PF_i onto the
//! pixels its projected footprint covers.
//!
//! Layout. The unit square (t, s) of [`Lune`] is split recursively until a
//! cell's projection spans at most [`LEAF_CELL_PX`] pixels; cells outside
//! the field of view or behind the camera are dropped on the way. A leaf
//! cell is then cut into n_t × n_s caps, with n chosen from its projected
//! size so every cap projects to about 1/density pixels: the (θ, φ) samples
//! are non-uniform on the sphere and uniform on the image.
//!
//! Integration. Each cap's PF_i is a product rule: the exact closed-form
//! integral of a geometric weight ω over the cap (paper's frame, see
//! [`super::closed_form`]) times the ratio integrand/ω at the cap centre.
//! ω is μ0μ (Lambert), μ (Area) or μ0μ/(μ0+μ) (Lommel–Seeliger), so those
//! models are exact per cap in the distant limit; for the other models and at
//! finite distance the ratio is smooth and the rule is second order in the
//! cap size.
//!
//! Gridding. A cap's footprint is the quadrilateral of its projected
//! corners, shared with its neighbours; its PF_i is split over the pixels by
//! the exact area of the footprint in each. With an albedo map, each cap
//! takes k×k map samples and its PF_i is split over the k×k parts of its
//! footprint in proportion to them (the map varies at pixel scale, the BRDF
//! does not).

use glam::DVec3;

use super::closed_form;
use super::interior::InteriorMask;
use super::lune::Lune;
use super::MapFilter;
use crate::radiometry::fastmath;
use crate::radiometry::reflectance::{MappedParameter, Reflectance};
use crate::radiometry::spectrum::AU;
use crate::radiometry::ScatteringGeometry;
use crate::scene::maps::lat_lon;
use crate::scene::MAX_PARAMETER_MAPS;
use crate::scene::{Body, EquirectMap, Pinhole};

/// Largest projected size [px] of a leaf cell before it is cut into caps.
pub const LEAF_CELL_PX: f64 = 48.0;
const MAX_DEPTH: u32 = 48;

/// Which closed-form weight a model is integrated against.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Weight {
    /// μ0 μ (exact for Lambert).
    Mu0Mu,
    /// μ (exact for Area).
    Mu,
    /// μ0 μ / (μ0 + μ) (exact for Lommel–Seeliger).
    LommelSeeliger,
}

impl Weight {
    /// The weight that makes a model's distant-limit caps exact.
    pub fn for_model(model: &Reflectance) -> Self {
        match model.name() {
            "area" => Weight::Mu,
            "lommel_seeliger" => Weight::LommelSeeliger,
            _ => Weight::Mu0Mu,
        }
    }

    #[inline]
    fn at(self, mu0: f64, mu: f64) -> f64 {
        match self {
            Weight::Mu0Mu => mu0 * mu,
            Weight::Mu => mu,
            Weight::LommelSeeliger => mu0 * mu / (mu0 + mu),
        }
    }

    /// The weight per unit μ: the shape of the radiance, which is the
    /// caps' flux per unit image area. Where it changes across a cap (μ0
    /// rising from zero at the terminator) the cap's flux is split over
    /// pixels along it rather than by area.
    #[inline]
    pub(super) fn radiance_shape(self, mu0: f64, mu: f64) -> f64 {
        let (mu0, mu) = (mu0.max(0.0), mu.max(0.0));
        match self {
            Weight::Mu0Mu => mu0,
            Weight::Mu => 1.0,
            Weight::LommelSeeliger if mu0 + mu > 0.0 => mu0 / (mu0 + mu),
            Weight::LommelSeeliger => 0.0,
        }
    }
}

/// One row of cap corners: their projections on the image and the
/// radiance shape there ([`Weight::radiance_shape`]).
#[derive(Default)]
pub struct CornerRow {
    pos: Vec<(f64, f64)>,
    shape: Vec<f64>,
    /// How the camera sees each corner (only where the frame cuts caps
    /// across occlusion edges, `render::occlusion`).
    sight: Vec<super::occlusion::Sight>,
}

/// A rectangle of the (t, s) square still to be visited or to be cut.
#[derive(Clone, Copy, Debug)]
pub struct Cell {
    pub t0: f64,
    pub t1: f64,
    pub s0: f64,
    pub s1: f64,
    pub depth: u32,
}

/// A leaf cell and the number of caps it is cut into.
#[derive(Clone, Copy, Debug)]
pub struct Leaf {
    pub cell: Cell,
    pub n_t: u32,
    pub n_s: u32,
    /// Pixels the leaf's caps may touch.
    pub rect: Rect,
}

/// Axis-aligned pixel rectangle [x0, x1) × [y0, y1).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Rect {
    pub x0: usize,
    pub y0: usize,
    pub x1: usize,
    pub y1: usize,
}

impl Rect {
    /// Width [px].
    pub fn width(&self) -> usize {
        self.x1.saturating_sub(self.x0)
    }
    /// Height [px].
    pub fn height(&self) -> usize {
        self.y1.saturating_sub(self.y0)
    }
    /// Whether the rectangle has no pixels.
    pub fn is_empty(&self) -> bool {
        self.width() == 0 || self.height() == 0
    }
    /// Smallest rectangle holding both.
    pub fn union(&self, other: &Rect) -> Rect {
        if self.is_empty() {
            return *other;
        }
        if other.is_empty() {
            return *self;
        }
        Rect {
            x0: self.x0.min(other.x0),
            y0: self.y0.min(other.y0),
            x1: self.x1.max(other.x1),
            y1: self.y1.max(other.y1),
        }
    }
}

/// Everything the per-cap loop needs, precomputed once per frame.
#[derive(Clone, Copy)]
pub struct Frame<'a> {
    pub lune: Lune,
    pub camera: &'a Pinhole,
    /// Lester axes in camera coordinates.
    pub axes_cam: [DVec3; 3],
    /// The camera's position relative to the body centre, rotated into the
    /// camera frame, so a surface point is at P_cam = r n_cam − camera_cam.
    pub camera_cam: DVec3,
    /// Lester axes in body-fixed coordinates (for maps).
    pub axes_body: [DVec3; 3],
    pub body: &'a Body,
    /// Reflection model of this (sub-)band: the body's, or the body's
    /// spectral model evaluated at the sub-band's wavelength.
    pub model: &'a Reflectance,
    /// Albedo parameter used where there is no map.
    pub albedo: f64,
    /// Factor on the map's values (1, or w(λ) of a spectral model whose
    /// map is a relative pattern).
    pub map_scale: f64,
    pub weight: Weight,
    pub radius: f64,
    /// Caps per pixel along each image axis.
    pub density: f64,
    /// Minimum caps along each axis of the whole lune.
    pub min_caps: f64,
    pub distant: bool,
    /// Occulter centre (Lester coordinates, relative to the body centre)
    /// and radius, when its shadow can reach the body.
    pub occulter: Option<(DVec3, f64)>,
    /// Albedo samples per cap along each axis (1–4).
    pub texture_samples: usize,
    /// Exact footprint means, k×k samples, or samples refined to exact
    /// where their spread exceeds `map_tolerance`.
    pub map_filter: MapFilter,
    /// Relative spread of the k×k samples above which the adaptive filter
    /// takes the exact mean.
    pub map_tolerance: f64,
    /// The relief's cast shadows, when this frame applies them.
    pub shadows: Option<super::relief::FrameShadows<'a>>,
    /// The displacement (height [m] and its slopes) this frame applies: the
    /// body's, unless the frame skips its relief (`render::relief`).
    pub height: Option<&'a (EquirectMap, EquirectMap, EquirectMap)>,
    /// Marches kept across the sub-bands of one frame, when its renderer
    /// keeps them ([`super::sight_memo`]).
    pub sight_memo: Option<&'a super::sight_memo::SightMemo>,
}

/// Radius of the solar photosphere [m].
pub const SUN_RADIUS: f64 = 6.957e8;

/// Fraction of the solar disk (uniform, no limb darkening) seen from `p`
/// past a spherical occulter; Sun and occulter centres relative to `p`.
pub fn visible_sun_fraction(sun: DVec3, occulter: DVec3, occulter_radius: f64) -> f64 {
    let (ds, dox) = (sun.length(), occulter.length());
    if dox >= ds {
        return 1.0;
    }
    let a = (SUN_RADIUS / ds).min(1.0).asin();
    if dox <= occulter_radius {
        return 0.0;
    }
    let b = (occulter_radius / dox).asin();
    let c = sun.cross(occulter).length().atan2(sun.dot(occulter));
    if c >= a + b {
        return 1.0;
    }
    if c + a <= b {
        return 0.0;
    }
    if c + b <= a {
        return 1.0 - (b / a).powi(2);
    }
    // Lens-shaped overlap of two disks on the sky (small-angle plane).
    let ca = ((c * c + a * a - b * b) / (2.0 * c * a)).clamp(-1.0, 1.0);
    let cb = ((c * c + b * b - a * a) / (2.0 * c * b)).clamp(-1.0, 1.0);
    let k = ((-c + a + b) * (c + a - b) * (c - a + b) * (c + a + b)).max(0.0);
    let overlap = a * a * ca.acos() + b * b * cb.acos() - 0.5 * k.sqrt();
    (1.0 - overlap / (std::f64::consts::PI * a * a)).clamp(0.0, 1.0)
}

/// Projection of a lune point, or None behind the camera.
#[inline]
fn project(frame: &Frame, theta: f64, phi: f64) -> Option<(f64, f64)> {
    let (st, ct) = theta.sin_cos();
    let (sp, cp) = phi.sin_cos();
    let [x, y, z] = frame.axes_cam;
    let p = (x * (st * cp) + y * (st * sp) + z * ct) * frame.radius - frame.camera_cam;
    if p.z <= 1e-9 * frame.lune.camera_range {
        None
    } else {
        Some(frame.camera.project(p))
    }
}

impl Frame<'_> {
    #[inline]
    fn theta(&self, t: f64) -> f64 {
        // Rows crowd toward both ends of the θ range (a sine stretching,
        // dθ/dt ∝ 1 − cos 2πt), where the lune's φ width changes like a
        // square root at finite range; the midpoint rule in θ then keeps
        // its order up to the tips of a crescent.
        let lo = self.lune.theta_min;
        let stretched = t - (std::f64::consts::TAU * t).sin() / std::f64::consts::TAU;
        lo + stretched * (self.lune.theta_max() - lo)
    }

    #[inline]
    fn phi(&self, theta: f64, s: f64) -> f64 {
        let (lo, hi) = self.lune.phi_range(theta.sin());
        lo + s * (hi - lo).max(0.0)
    }

    /// The fewest caps along t and s of a cell: [`Frame::min_caps`] across
    /// the whole t range, and across the lune's widest φ arc (the equator
    /// row, sin θ = 1) pro rata of the arc the cell's rows span on the
    /// sphere. The rows near the lune's tips are short circles (sin θ → 0):
    /// a minimum per unit s gave them as many caps as the equator's, and
    /// hundreds of caps landed in the pixel holding a tip.
    fn min_caps_of(&self, cell: &Cell) -> (f64, f64) {
        let arc_of = |st: f64| {
            let (lo, hi) = self.lune.phi_range(st);
            st * (hi - lo).max(0.0)
        };
        let widest = arc_of(1.0);
        // The cell's widest row: at its edges or middle (the φ arc is
        // smooth in θ, so three rows bound it closely).
        let arc = [cell.t0, 0.5 * (cell.t0 + cell.t1), cell.t1]
            .iter()
            .map(|&t| arc_of(self.theta(t).sin()))
            .fold(0.0, f64::max)
            * (cell.s1 - cell.s0);
        let min_s = if widest > 0.0 {
            (self.min_caps * arc / widest).ceil()
        } else {
            1.0
        };
        ((self.min_caps * (cell.t1 - cell.t0)).ceil(), min_s)
    }

    /// How far [px] the displacement can move a point on the image: the
    /// largest height over the nearest distance from the camera to the
    /// surface (0 without a displacement).
    pub(super) fn relief_margin_px(&self) -> f64 {
        let h = self.body.relief.height_bound;
        if self.height.is_none() || h <= 0.0 {
            return 0.0;
        }
        let nearest = (self.lune.camera_range - self.radius - h).max(1e-3 * self.radius);
        h * self.camera.fx.max(self.camera.fy) / nearest
    }

    /// Whether the sample rows `ts` and columns `ss` of a cell hold points
    /// on both sides of the sphere's limb (n·ĉ against R/D).
    fn straddles_limb(&self, ts: &[f64; 3], ss: &[f64; 3]) -> bool {
        let (mut inside, mut past) = (false, false);
        for &t in ts {
            let theta = self.theta(t);
            for &s in ss {
                let mu = theta.sin() * (self.phi(theta, s) - self.lune.alpha).cos();
                inside |= mu >= self.lune.k_view;
                past |= mu < self.lune.k_view;
            }
        }
        inside && past
    }

    /// A cell's extent [px] along t and s seen face-on from the camera's
    /// distance to the sphere's limb.
    fn face_on_px(&self, cell: &Cell) -> (f64, f64) {
        let (d, r) = (self.lune.camera_range, self.radius);
        let to_limb = (d * d - r * r).max(0.0).sqrt().max(1e-3 * r);
        let px_per_rad = self.camera.fx.max(self.camera.fy) * r / to_limb;
        let d_theta = self.theta(cell.t1) - self.theta(cell.t0);
        let arc = [cell.t0, 0.5 * (cell.t0 + cell.t1), cell.t1]
            .iter()
            .map(|&t| {
                let st = self.theta(t).sin();
                let (lo, hi) = self.lune.phi_range(st);
                st * (hi - lo).max(0.0)
            })
            .fold(0.0, f64::max)
            * (cell.s1 - cell.s0);
        (d_theta * px_per_rad, arc * px_per_rad)
    }

    /// Visit a cell: drop it, cut it, or store it as a leaf. Returns the
    /// pixel bounds the leaf may touch.
    pub fn visit(&self, cell: Cell, stack: &mut Vec<Cell>, leaves: &mut Vec<Leaf>) -> Option<Rect> {
        let tm = 0.5 * (cell.t0 + cell.t1);
        let sm = 0.5 * (cell.s0 + cell.s1);
        let ts = [cell.t0, tm, cell.t1];
        let ss = [cell.s0, sm, cell.s1];
        let mut pts = [[(0.0, 0.0); 3]; 3];
        let mut behind = 0;
        for (a, &t) in ts.iter().enumerate() {
            let theta = self.theta(t);
            for (b, &s) in ss.iter().enumerate() {
                match project(self, theta, self.phi(theta, s)) {
                    Some(p) => pts[a][b] = p,
                    None => behind += 1,
                }
            }
        }
        let split = |stack: &mut Vec<Cell>| {
            for (t0, t1) in [(cell.t0, tm), (tm, cell.t1)] {
                for (s0, s1) in [(cell.s0, sm), (sm, cell.s1)] {
                    stack.push(Cell {
                        t0,
                        t1,
                        s0,
                        s1,
                        depth: cell.depth + 1,
                    });
                }
            }
        };
        if behind == 9 && cell.depth > 2 {
            return None;
        }
        if behind > 0 {
            if cell.depth < MAX_DEPTH {
                split(stack);
            }
            return None;
        }
        let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
        for p in pts.iter().flatten() {
            x0 = x0.min(p.0);
            y0 = y0.min(p.1);
            x1 = x1.max(p.0);
            y1 = y1.max(p.1);
        }
        let margin = 0.3 * (x1 - x0).max(y1 - y0) + 2.0 + self.relief_margin_px();
        let (w, h) = (self.camera.width as f64, self.camera.height as f64);
        if x1 + margin < 0.0 || y1 + margin < 0.0 || x0 - margin > w || y0 - margin > h {
            return None;
        }
        let dist =
            |a: (f64, f64), b: (f64, f64)| ((a.0 - b.0).powi(2) + (a.1 - b.1).powi(2)).sqrt();
        let mut along_t: f64 = 0.0;
        let mut along_s: f64 = 0.0;
        for (k, row) in pts.iter().enumerate() {
            along_t = along_t.max(dist(pts[0][k], pts[1][k]) + dist(pts[1][k], pts[2][k]));
            along_s = along_s.max(dist(row[0], row[1]) + dist(row[1], row[2]));
        }
        // A cell across the sphere's limb folds on the image (its far part
        // projects back inside the disk), so its projected size undercounts
        // the caps it needs: it takes its size seen face-on there.
        if self.lune.widened() && self.straddles_limb(&ts, &ss) {
            let (face_t, face_s) = self.face_on_px(&cell);
            along_t = along_t.max(face_t);
            along_s = along_s.max(face_s);
        }
        let big = along_t.max(along_s) > LEAF_CELL_PX;
        // Near the top levels the 3×3 samples may miss curvature: always
        // refine the first levels.
        if (big || cell.depth < 3) && cell.depth < MAX_DEPTH {
            split(stack);
            return None;
        }
        let (min_t, min_s) = self.min_caps_of(&cell);
        let n_t = (along_t * self.density)
            .ceil()
            .max(min_t)
            .clamp(1.0, 4096.0) as u32;
        let n_s = (along_s * self.density)
            .ceil()
            .max(min_s)
            .clamp(1.0, 4096.0) as u32;
        let clamp = |v: f64, hi: f64| v.clamp(0.0, hi) as usize;
        let rect = Rect {
            x0: clamp((x0 - margin).floor(), w),
            y0: clamp((y0 - margin).floor(), h),
            x1: clamp((x1 + margin).ceil() + 1.0, w),
            y1: clamp((y1 + margin).ceil() + 1.0, h),
        };
        leaves.push(Leaf {
            cell,
            n_t,
            n_s,
            rect,
        });
        Some(rect)
    }

    /// Project one row of cap corners (θ fixed, s from s0 in n steps of
    /// ds) into `out`; a corner behind the camera is NaN.
    fn corner_row(
        &self,
        theta: f64,
        (s0, ds): (f64, f64),
        n: u32,
        out: &mut CornerRow,
        tape: &mut super::sight_memo::SightTape,
    ) {
        out.pos.clear();
        out.shape.clear();
        out.sight.clear();
        let cut_edges = self.cuts_occlusion_edges();
        let (st, ct) = theta.sin_cos();
        let (lo, hi) = self.lune.phi_range(st);
        let width = (hi - lo).max(0.0);
        let (mut sp, mut cp) = (lo + s0 * width).sin_cos();
        let (sd, cd) = (ds * width).sin_cos();
        let (sin_a, cos_a) = self.lune.alpha.sin_cos();
        let [xc, yc, zc] = self.axes_cam;
        let base = zc * (ct * self.radius) - self.camera_cam;
        let (xs, ys) = (xc * (st * self.radius), yc * (st * self.radius));
        let height = self.height.map(|h| &h.0);
        let tiles = self.body.relief.height_tiles.as_deref();
        let [xb, yb, zb] = self.axes_body;
        for _ in 0..=n {
            let mut p = base + xs * cp + ys * sp;
            if let Some(h) = height {
                // The corner on the displaced surface: the limb moves with
                // the relief (`scene::surface`).
                let n_body = xb * (st * cp) + yb * (st * sp) + zb * ct;
                let r =
                    crate::scene::surface::displaced_radius_tiled(h, tiles, self.radius, n_body);
                p = (p + self.camera_cam) * (r / self.radius) - self.camera_cam;
            }
            out.pos.push(if p.z > 0.0 {
                self.camera.project(p)
            } else {
                (f64::NAN, f64::NAN)
            });
            let (mu0, mu) = (st * cp, st * (cp * cos_a + sp * sin_a));
            out.shape.push(self.weight.radiance_shape(mu0, mu));
            if cut_edges {
                out.sight
                    .push(self.sight_taped(DVec3::new(st * cp, st * sp, ct), tape));
            }
            (sp, cp) = (sp * cd + cp * sd, cp * cd - sp * sd);
        }
    }

    /// What identifies `leaf` of this view for the sub-band memo
    /// ([`super::sight_memo::LeafKey`]).
    fn leaf_key(&self, leaf: &Leaf) -> super::sight_memo::LeafKey {
        let c = leaf.cell;
        let [x, y, z] = self.axes_body;
        let words = [c.t0, c.t1, c.s0, c.s1]
            .into_iter()
            .map(f64::to_bits)
            .chain([
                leaf.n_t as u64,
                leaf.n_s as u64,
                self.shadows.is_some() as u64,
            ])
            .chain(
                [self.lune.camera_local(), x, y, z]
                    .into_iter()
                    .flat_map(|v| v.to_array())
                    .map(f64::to_bits),
            );
        let mut key = [0; 19];
        key.iter_mut().zip(words).for_each(|(k, w)| *k = w);
        key
    }

    /// Integrate and grid every cap of a leaf into `sink`. `rows` is
    /// scratch space. Returns the sum of the caps' PF (per unit solar
    /// irradiance at 1 au) that the sink kept or that fell outside it.
    pub fn grid_leaf(&self, leaf: &Leaf, sink: &mut Sink, rows: &mut [CornerRow; 2]) -> f64 {
        let cell = leaf.cell;
        let dt = (cell.t1 - cell.t0) / leaf.n_t as f64;
        let ds = (cell.s1 - cell.s0) / leaf.n_s as f64;
        let alpha = self.lune.alpha;
        let (sin_a, cos_a) = alpha.sin_cos();
        let [xb, yb, zb] = self.axes_body;
        let cam_local = self.lune.camera_local();
        let d_cam = self.lune.camera_range;
        let d_sun = self.lune.sun_range;
        let r = self.radius;
        let model = self.model;
        let needs_body_dir = self.body.albedo_map.is_some()
            || !self.body.parameter_maps.is_empty()
            || self.height.is_some()
            || self.body.relief.normals.is_some()
            || self.shadows.is_some()
            || self.body.relief.albedo_tiles.is_some();
        let widened = self.lune.widened();
        let cut_edges = self.cuts_occlusion_edges();
        let mut total = 0.0;
        let [upper, lower] = rows;
        if self.sight_memo.is_some() {
            sink.tape.start(self.sight_memo, self.leaf_key(leaf));
        }
        self.corner_row(
            self.theta(cell.t0),
            (cell.s0, ds),
            leaf.n_s,
            lower,
            &mut sink.tape,
        );
        for a in 0..leaf.n_t {
            std::mem::swap(upper, lower);
            let t_next = cell.t0 + (a + 1) as f64 * dt;
            self.corner_row(
                self.theta(t_next),
                (cell.s0, ds),
                leaf.n_s,
                lower,
                &mut sink.tape,
            );
            let theta0 = self.theta(cell.t0 + a as f64 * dt);
            let theta1 = self.theta(cell.t0 + (a + 1) as f64 * dt);
            let d_theta = theta1 - theta0;
            let theta = 0.5 * (theta0 + theta1);
            let (st, ct) = theta.sin_cos();
            let (lo, hi) = self.lune.phi_range(st);
            if hi <= lo {
                continue;
            }
            let d_phi = ds * (hi - lo);
            let w_theta = match self.weight {
                Weight::Mu0Mu => closed_form::int_sin3(theta0, theta1),
                Weight::Mu | Weight::LommelSeeliger => closed_form::int_sin2(theta0, theta1),
            };
            let phi_start = lo + (cell.s0 + 0.5 * ds) * (hi - lo);
            let (mut sp, mut cp) = phi_start.sin_cos();
            let (sd, cd) = d_phi.sin_cos();
            let half_sin = (0.5 * d_phi).sin();
            for b in 0..leaf.n_s as usize {
                let (sp_c, cp_c) = (sp, cp);
                // Advance φ by one cap (angle-addition recurrence).
                (sp, cp) = (sp * cd + cp * sd, cp * cd - sp * sd);
                let (sp, cp) = (sp_c, cp_c);
                let quad = [
                    upper.pos[b],
                    upper.pos[b + 1],
                    lower.pos[b + 1],
                    lower.pos[b],
                ];
                let shape = [
                    upper.shape[b],
                    upper.shape[b + 1],
                    lower.shape[b + 1],
                    lower.shape[b],
                ];
                if sink.covers_quad(&quad) {
                    continue;
                }
                // Corners seen and corners hidden by relief: an occlusion
                // edge crosses the cap (`render::occlusion`).
                if cut_edges {
                    let sight = [
                        upper.sight[b],
                        upper.sight[b + 1],
                        lower.sight[b + 1],
                        lower.sight[b],
                    ];
                    if super::occlusion::crosses_edge(&sight) {
                        let corners = std::array::from_fn(|k| super::occlusion::EdgePoint {
                            pos: quad[k],
                            shape: shape[k],
                            sight: sight[k],
                        });
                        let s_lo = cell.s0 + b as f64 * ds;
                        total += self.grid_edge_cap(
                            sink,
                            (theta0, theta1),
                            (s_lo, s_lo + ds),
                            corners,
                            0,
                        );
                        continue;
                    }
                }
                // Far-field cosines and the closed-form weight of the cap.
                let cos_pa = cp * cos_a + sp * sin_a;
                let mu0_far = st * cp;
                let mu_far = st * cos_pa;
                let w_phi = match self.weight {
                    Weight::Mu0Mu => {
                        let cos_2pa = (cp * cp - sp * sp) * cos_a + 2.0 * sp * cp * sin_a;
                        0.5 * (d_phi * cos_a + cos_2pa * sd)
                    }
                    Weight::Mu => 2.0 * cos_pa * half_sin,
                    Weight::LommelSeeliger => {
                        let phi = phi_start + b as f64 * d_phi;
                        closed_form::phi_mu0_mu_over_sum(
                            phi - 0.5 * d_phi,
                            phi + 0.5 * d_phi,
                            alpha,
                        )
                    }
                };
                // Past the sphere's limb (or within a cap of it) the
                // closed-form weight's centre value crosses zero: the cap
                // takes its plain area there (only with relief, which
                // widens the lune past the limb).
                let (w_theta, w_phi, omega) = if widened && mu_far < self.lune.k_view + d_phi {
                    (theta0.cos() - theta1.cos(), d_phi, 1.0)
                } else {
                    (w_theta, w_phi, self.weight.at(mu0_far, mu_far))
                };
                if !(omega > 0.0) {
                    continue;
                }
                let n_local = DVec3::new(st * cp, st * sp, ct);
                let n_body = if needs_body_dir {
                    xb * n_local.x + yb * n_local.y + zb * n_local.z
                } else {
                    DVec3::Z
                };
                let mut texture = Texture::default();
                let albedo = match &self.body.albedo_map {
                    None => self.albedo,
                    Some(map) => {
                        // Albedo sampled k×k times over the cap's footprint.
                        let e1 = (xb * (ct * cp) + yb * (ct * sp) - zb * st) * d_theta;
                        let e2 = (yb * cp - xb * sp) * (st * d_phi);
                        texture.sample(map, n_body, e1, e2, self) * self.map_scale
                    }
                };
                // Albedo tiles: their point value at the cap centre, blended
                // over the map's (the cap is then spread uniformly).
                let albedo = match self.body.relief.albedo_tiles.as_deref() {
                    Some(t) if t.covers_dir(n_body) => {
                        texture.k = 1;
                        t.albedo_dir(n_body, self.map_scale, albedo)
                    }
                    _ => albedo,
                };
                let integrand = self.integrand(
                    n_local, n_body, albedo, mu0_far, mu_far, cos_a, cam_local, d_cam, d_sun, r,
                    model,
                );
                let pf = r * r * w_theta * w_phi * integrand / omega;
                if !(pf > 0.0) {
                    continue;
                }
                sink.integrated += 1;
                total += pf;
                if quad.iter().all(|p| p.0.is_finite()) {
                    if texture.k > 1 {
                        texture.grid(sink, &quad, &shape, pf);
                    } else {
                        grid_quad_shaped(sink, &quad, &shape, pf);
                    }
                }
            }
        }
        sink.tape.finish(self.sight_memo);
        total - std::mem::take(&mut sink.skipped)
    }

    /// Unit normal (Lester coordinates) of the displaced bilinear surface
    /// at the body-fixed direction `n_body`, where its radius is `r`
    /// ([`crate::scene::surface::surface_normal_tiled`]); the sphere's
    /// without a displacement.
    #[inline]
    pub(super) fn surface_normal_local(&self, n_body: DVec3, r: f64) -> DVec3 {
        let [xb, yb, zb] = self.axes_body;
        let n = match self.height {
            Some(h) => crate::scene::surface::surface_normal_tiled(
                &h.0,
                self.body.relief.height_tiles.as_deref(),
                self.radius,
                n_body,
                r,
            ),
            None => n_body,
        };
        DVec3::new(n.dot(xb), n.dot(yb), n.dot(zb))
    }

    /// The albedo at the body-fixed direction `n_body`: the map's point
    /// value (or the model's albedo), with the albedo tiles blended over.
    pub(super) fn point_albedo(&self, n_body: DVec3) -> f64 {
        let albedo = match &self.body.albedo_map {
            None => self.albedo,
            Some(map) => map.sample_dir(n_body) * self.map_scale,
        };
        match self.body.relief.albedo_tiles.as_deref() {
            Some(t) if t.covers_dir(n_body) => t.albedo_dir(n_body, self.map_scale, albedo),
            _ => albedo,
        }
    }

    /// The model's radiance factor at the body-fixed direction `n_body`:
    /// with the model's own parameters, or those the body's parameter maps
    /// give there.
    #[inline]
    fn reflect(
        &self,
        model: &Reflectance,
        g: &ScatteringGeometry,
        albedo: f64,
        n_body: DVec3,
    ) -> f64 {
        let maps = &self.body.parameter_maps;
        if maps.is_empty() {
            return model.radiance_factor(g, albedo);
        }
        let mut values = [(MappedParameter::Roughness, 0.0); MAX_PARAMETER_MAPS];
        for (v, (p, map)) in values.iter_mut().zip(maps) {
            *v = (*p, map.sample_dir(n_body));
        }
        model.radiance_factor_with(g, albedo, &values[..maps.len()])
    }

    /// Integrand (per unit solar irradiance at 1 au, without dS) at a cap
    /// centre: f_r μ0 (AU/d_sun)² μ / d_cam² with exact geometry.
    #[allow(clippy::too_many_arguments)]
    #[inline]
    pub(super) fn integrand(
        &self,
        n_local: DVec3,
        n_body: DVec3,
        albedo: f64,
        mu0_far: f64,
        mu_far: f64,
        cos_a: f64,
        cam_local: DVec3,
        d_cam: f64,
        d_sun: f64,
        r: f64,
        model: &Reflectance,
    ) -> f64 {
        if self.height.is_none() && self.body.relief.normals.is_none() {
            let (mu0, mu, cos_g, sun_sq, cam_sq) = if self.distant {
                (mu0_far, mu_far, cos_a, d_sun * d_sun, d_cam * d_cam)
            } else {
                let ns = d_sun * mu0_far;
                let nc = d_cam * mu_far;
                let sun_sq = (d_sun * d_sun - 2.0 * r * ns + r * r).max(0.0);
                let cam_sq = (d_cam * d_cam - 2.0 * r * nc + r * r).max(0.0);
                let ds = sun_sq.sqrt();
                let dc = cam_sq.sqrt();
                let sc = d_sun * cam_local.x; // S·C with S = (d_sun, 0, 0)
                let cos_g = (sc - r * (ns + nc) + r * r) / (ds * dc);
                (
                    (ns - r) / ds,
                    (nc - r) / dc,
                    cos_g.clamp(-1.0, 1.0),
                    sun_sq,
                    cam_sq,
                )
            };
            if mu0 <= 0.0 || mu <= 0.0 {
                return 0.0;
            }
            let g = ScatteringGeometry { mu0, mu, cos_g };
            let shadow = self.sun_fraction(n_local * r) * self.relief_shadow(n_local, n_body, r);
            return self.reflect(model, &g, albedo, n_body) * (AU * AU / sun_sq) * mu / cam_sq
                * shadow;
        }
        self.relief_integrand(n_local, n_body, cam_local, d_sun, r, model, albedo, false)
    }

    /// [`Frame::integrand`] of a part of a cap cut at an occlusion edge
    /// (`render::occlusion`): with a displacement, the projected area is
    /// the bilinear surface's at the centre. A part is far smaller than a
    /// DEM cell and sits at a fold, where the smooth slope maps can face
    /// the camera while the surface its footprint lies on does not.
    pub(super) fn part_integrand(&self, n_local: DVec3, n_body: DVec3, albedo: f64) -> f64 {
        let (sin_a, cos_a) = self.lune.alpha.sin_cos();
        let (mu0_far, mu_far) = (n_local.x, n_local.x * cos_a + n_local.y * sin_a);
        let (cam_local, d_cam, d_sun) = (
            self.lune.camera_local(),
            self.lune.camera_range,
            self.lune.sun_range,
        );
        if self.height.is_none() {
            return self.integrand(
                n_local,
                n_body,
                albedo,
                mu0_far,
                mu_far,
                cos_a,
                cam_local,
                d_cam,
                d_sun,
                self.radius,
                self.model,
            );
        }
        self.relief_integrand(
            n_local,
            n_body,
            cam_local,
            d_sun,
            self.radius,
            self.model,
            albedo,
            true,
        )
    }

    /// Share of the solar disk lighting a point (Lester coordinates).
    #[inline]
    pub(super) fn sun_fraction(&self, p: DVec3) -> f64 {
        match self.occulter {
            None => 1.0,
            Some((centre, radius)) => visible_sun_fraction(
                DVec3::new(self.lune.sun_range, 0.0, 0.0) - p,
                centre - p,
                radius,
            ),
        }
    }

    /// Share of the Sun's power that clears the relief's horizon at the
    /// point `r` n_local (Lester coordinates; `n_body` the same direction
    /// body-fixed): one horizon-map lookup, 1 when the frame applies no
    /// cast shadows.
    #[inline]
    pub(super) fn relief_shadow(&self, n_local: DVec3, n_body: DVec3, r: f64) -> f64 {
        let Some(shadows) = &self.shadows else {
            return 1.0;
        };
        shadows.factor(n_body, self.sun_direction_body(n_local, r))
    }

    /// Body-fixed unit vector to the Sun's centre from the point `r`
    /// n_local (Lester coordinates).
    #[inline]
    pub(super) fn sun_direction_body(&self, n_local: DVec3, r: f64) -> DVec3 {
        let l = if self.distant {
            DVec3::X
        } else {
            (DVec3::new(self.lune.sun_range, 0.0, 0.0) - n_local * r).normalize()
        };
        let [xb, yb, zb] = self.axes_body;
        xb * l.x + yb * l.y + zb * l.z
    }

    /// Integrand with displacement and/or normal maps: local radius from the
    /// height, geometric normal from its slopes, shading normal from the
    /// normal map; cast shadows from the horizon map (`relief_shadow`).
    #[allow(clippy::too_many_arguments)]
    fn relief_integrand(
        &self,
        n_local: DVec3,
        n_body: DVec3,
        cam_local: DVec3,
        d_sun: f64,
        radius: f64,
        model: &Reflectance,
        albedo: f64,
        surface_area: bool,
    ) -> f64 {
        let (r, geometric) = match self.height {
            Some(h) => crate::scene::surface::displaced_tiled(
                h,
                self.body.relief.height_tiles.as_deref(),
                radius,
                n_body,
            ),
            None => (radius, n_body),
        };
        let shading = match &self.body.relief.normals {
            Some(map) => {
                let (lat, lon) = lat_lon(n_body);
                let east = DVec3::new(-lon.sin(), lon.cos(), 0.0);
                let north = n_body.cross(east);
                let t = map.sample(lat, lon);
                (east * t.x + north * t.y + geometric * t.z).normalize()
            }
            None => geometric,
        };
        let [xb, yb, zb] = self.axes_body;
        let to_local = |v: DVec3| DVec3::new(v.dot(xb), v.dot(yb), v.dot(zb));
        let geometric = to_local(geometric);
        let shading = to_local(shading);
        let p = n_local * r;
        let sun = DVec3::new(d_sun, 0.0, 0.0) - p;
        let cam = cam_local - p;
        let (sun_sq, cam_sq) = (sun.length_squared(), cam.length_squared());
        let l = sun / sun_sq.sqrt();
        let v = cam / cam_sq.sqrt();
        let g = ScatteringGeometry::from_vectors(shading, l, v);
        if g.mu0 <= 0.0 || g.mu <= 0.0 {
            return 0.0;
        }
        let area_normal = if surface_area {
            self.surface_normal_local(n_body, r)
        } else {
            geometric
        };
        let projected = area_normal.dot(v) / area_normal.dot(n_local).max(1e-6);
        if projected <= 0.0 {
            return 0.0;
        }
        if self.camera_visible(n_body, cam, r) == 0.0 {
            return 0.0;
        }
        let area_scale = (r / radius) * (r / radius);
        self.reflect(model, &g, albedo, n_body) * (AU * AU / sun_sq) * projected * area_scale
            / cam_sq
            * self.sun_fraction(p)
            * self.relief_shadow(n_local, n_body, r)
    }

    /// 0 where nearer relief hides the point `r` n_body (body-fixed
    /// direction `n_body`) from the camera (`cam`: the point to the
    /// camera, Lester coordinates), else 1. With a displacement, a point
    /// seeing the camera below its local horizontal (past the sphere's
    /// limb, or raised near it) marches its line of sight through the DEM
    /// ([`super::sight`]); above it, where the frame applies the shadows,
    /// the horizon map in the camera's azimuth clears it, and the march
    /// confirms what the map hides. The flat sphere's points are hidden by
    /// nothing.
    #[inline]
    pub(super) fn camera_visible(&self, n_body: DVec3, cam: DVec3, r: f64) -> f64 {
        let Some(height) = self.height else {
            return 1.0;
        };
        let [xb, yb, zb] = self.axes_body;
        let v = (xb * cam.x + yb * cam.y + zb * cam.z).normalize();
        let march = || {
            let relief = super::sight::Relief {
                height: &height.0,
                tiles: self.body.relief.height_tiles.as_deref(),
                radius: self.radius,
                bound: self.body.relief.height_bound,
            };
            let clear = match self.sight_memo {
                Some(memo) => memo.clears(&relief, n_body * r, v),
                None => relief.clears(n_body * r, v),
            };
            if clear {
                1.0
            } else {
                0.0
            }
        };
        if v.dot(n_body) < 0.0 {
            return march();
        }
        match &self.shadows {
            // The interpolated horizon errs near its edge: a point it hides
            // is confirmed by the march (hidden points add nothing, so the
            // cost stays with them).
            Some(shadows) if shadows.camera_visible(n_body, v) == 0.0 => march(),
            _ => 1.0,
        }
    }
}

/// Albedo sub-samples of one cap: k×k values over its footprint, whose mean
/// is the cap's albedo and whose shares split the cap's PF over the k×k
/// sub-quadrilaterals of its footprint. The BRDF and geometry are smooth
/// and evaluated once per cap; only the map varies at pixel scale.
#[derive(Default)]
struct Texture {
    k: usize,
    values: [f64; 16],
}

impl Texture {
    /// Sample the map over the cap centred on the body-fixed unit direction
    /// `n` with edge vectors `e1` (along θ) and `e2` (along φ), with
    /// `frame`'s samples, filter and threshold; returns the mean.
    #[inline]
    fn sample(&mut self, map: &EquirectMap, n: DVec3, e1: DVec3, e2: DVec3, frame: &Frame) -> f64 {
        Footprint::new(map, n, e1, e2).sample(
            map,
            frame.texture_samples,
            frame.map_filter,
            frame.map_tolerance,
            &mut self.values,
            &mut self.k,
        )
    }

    /// Grid `pf` over the pixels `quad` touches: the pixels' shares of the
    /// whole cap without a map (the plane of its radiance `shape`), each
    /// scaled by the map's weight in that pixel. The weight is the samples'
    /// relative value averaged over the k×k sub-quadrilaterals by their
    /// part of the pixel, so a constant map grids exactly as no map does,
    /// and the shares stay non-negative.
    #[inline]
    fn grid(&self, sink: &mut Sink, quad: &[(f64, f64); 4], shape: &[f64; 4], pf: f64) {
        // A cap inside one pixel needs no split.
        let (x0, y0, x1, y1) = bounds(quad);
        if x0.floor() == x1.floor() && y0.floor() == y1.floor() {
            sink.add(x0.floor() as i64, y0.floor() as i64, pf);
            return;
        }
        let subs = self.sub_quads(quad, shape);
        let subs = &subs[..self.k * self.k];
        let share_sum: f64 = subs.iter().map(|s| s.share).sum();
        let flux_sum: f64 = subs.iter().map(|s| s.flux).sum();
        if !(share_sum > 0.0 && flux_sum > 0.0) {
            return;
        }
        let mut whole = Shares::default();
        grid_quad_shaped(&mut whole, quad, shape, 1.0);
        // Per pixel: the map-weighted and the unweighted sub-quad shares.
        let mut parts = SubShares::default();
        for sub in subs {
            parts.weights = (sub.share / share_sum, sub.flux / flux_sum);
            grid_quad_shaped(&mut parts, &sub.corners, &sub.shape, 1.0);
        }
        if whole.overflow || parts.overflow {
            // A cap over more than 16 pixels: the sub-quadrilaterals alone.
            for sub in subs {
                grid_quad_shaped(sink, &sub.corners, &sub.shape, pf * sub.share / share_sum);
            }
            return;
        }
        // mapped / plain is a weighted mean of share/flux over the subs in
        // the pixel, so it is bounded by their extremes; 1 (the cap's mean)
        // where no sub lands.
        let weight = |i: i64, j: i64| match parts.get(i, j) {
            Some((m, p)) if p > 0.0 => m / p,
            _ => 1.0,
        };
        let mut weighted = [0.0; 16];
        let mut total = 0.0;
        for (w, &(i, j, v)) in weighted.iter_mut().zip(whole.cells()) {
            *w = v * weight(i, j);
            total += *w;
        }
        if !(total > 0.0) {
            return;
        }
        for (&w, &(i, j, _)) in weighted.iter().zip(whole.cells()) {
            sink.add(i, j, pf * w / total);
        }
    }

    /// The k×k sub-quadrilaterals of `quad` (corners at (t0,s0), (t0,s1),
    /// (t1,s1), (t1,s0)), their radiance shape interpolated from the
    /// corners, the flux that shape gives over each one's area, and that
    /// flux times its sample.
    #[inline]
    fn sub_quads(&self, quad: &[(f64, f64); 4], shape: &[f64; 4]) -> [SubQuad; 16] {
        let k = self.k;
        let weights = |v: f64, u: f64| [(1.0 - v) * (1.0 - u), (1.0 - v) * u, v * u, v * (1.0 - u)];
        let at = |v: f64, u: f64| {
            let w = weights(v, u);
            let x = w[0] * quad[0].0 + w[1] * quad[1].0 + w[2] * quad[2].0 + w[3] * quad[3].0;
            let y = w[0] * quad[0].1 + w[1] * quad[1].1 + w[2] * quad[2].1 + w[3] * quad[3].1;
            let h = w[0] * shape[0] + w[1] * shape[1] + w[2] * shape[2] + w[3] * shape[3];
            ((x, y), h)
        };
        let step = 1.0 / k as f64;
        let mut subs = [SubQuad::default(); 16];
        for p in 0..k {
            let (v0, v1) = (p as f64 * step, (p + 1) as f64 * step);
            for q in 0..k {
                let (u0, u1) = (q as f64 * step, (q + 1) as f64 * step);
                let c = [at(v0, u0), at(v0, u1), at(v1, u1), at(v1, u0)];
                let shape = [c[0].1, c[1].1, c[2].1, c[3].1];
                let corners = [c[0].0, c[1].0, c[2].0, c[3].0];
                let flux = quad_area(&corners) * 0.25 * (shape[0] + shape[1] + shape[2] + shape[3]);
                subs[p * k + q] = SubQuad {
                    corners,
                    shape,
                    flux,
                    share: self.values[p * k + q] * flux,
                };
            }
        }
        subs
    }
}

/// One of a cap's k×k sub-quadrilaterals in the image.
#[derive(Clone, Copy, Default)]
struct SubQuad {
    corners: [(f64, f64); 4],
    shape: [f64; 4],
    /// The radiance shape's integral over it (area × mean shape).
    flux: f64,
    /// `flux` times its map sample.
    share: f64,
}

/// The range of a footprint's k×k samples: the adaptive filter's cheap
/// estimate of the detail it holds.
struct Spread {
    lo: f64,
    hi: f64,
}

impl Default for Spread {
    fn default() -> Self {
        Spread {
            lo: f64::INFINITY,
            hi: f64::NEG_INFINITY,
        }
    }
}

impl Spread {
    #[inline(always)]
    fn add(&mut self, v: f64) {
        self.lo = self.lo.min(v);
        self.hi = self.hi.max(v);
    }

    /// Whether (max − min) reaches `tolerance` × |mean| (always at 0).
    #[inline(always)]
    fn exceeds(&self, mean: f64, tolerance: f64) -> bool {
        self.hi - self.lo >= tolerance * mean.abs()
    }
}

/// A cap's (or pixel's) footprint on an albedo map: its centre in texel
/// coordinates and its two edge vectors in texels (x east, y south).
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Footprint {
    pub x: f64,
    pub y: f64,
    pub a1: (f64, f64),
    pub a2: (f64, f64),
}

impl Footprint {
    /// Footprint of the patch centred on the body-fixed unit direction `n`
    /// with edge vectors `e1`, `e2` (unit-sphere displacements).
    #[inline]
    pub(super) fn new(map: &EquirectMap, n: DVec3, e1: DVec3, e2: DVec3) -> Footprint {
        let cos_lat = (n.x * n.x + n.y * n.y).sqrt();
        let lat = fastmath::asin(n.z);
        let lon = fastmath::atan2(n.y, n.x);
        let (east, north) = if cos_lat > 1e-9 {
            let (co, so) = (n.x / cos_lat, n.y / cos_lat);
            (
                DVec3::new(-so, co, 0.0),
                DVec3::new(-n.z * co, -n.z * so, cos_lat),
            )
        } else {
            (DVec3::Y, DVec3::X)
        };
        let kx = map.width as f64 / (std::f64::consts::TAU * cos_lat.max(1e-6));
        let ky = map.height as f64 / std::f64::consts::PI;
        let (x, y) = map.texel_of(lat, lon);
        Footprint {
            x,
            y,
            a1: (e1.dot(east) * kx, -e1.dot(north) * ky),
            a2: (e2.dot(east) * kx, -e2.dot(north) * ky),
        }
    }

    /// Mean albedo over a pixel's footprint: exact, k×k samples, or
    /// (adaptive) the samples unless their spread reaches `tolerance`; and
    /// whether it is the exact mean.
    #[inline]
    pub(super) fn filtered_mean(
        &self,
        map: &EquirectMap,
        k: usize,
        filter: MapFilter,
        tolerance: f64,
    ) -> (f64, bool) {
        let exact = || {
            (
                map.parallelogram_mean(self.x, self.y, self.a1, self.a2),
                true,
            )
        };
        match filter {
            MapFilter::Exact => exact(),
            MapFilter::Samples => (self.samples_mean(map, k, |_, _| ()), false),
            MapFilter::Adaptive => {
                let mut spread = Spread::default();
                let mean = self.samples_mean(map, k, |_, v| spread.add(v));
                if spread.exceeds(mean, tolerance) {
                    exact()
                } else {
                    (mean, false)
                }
            }
        }
    }

    /// k×k values over the footprint into `values` (k recorded in
    /// `k_out`), each the mean of its part (exact) or a sample of it
    /// (adaptive: the exact means where the samples' spread exceeds
    /// `tolerance`); returns their mean.
    #[inline]
    pub(super) fn sample(
        &self,
        map: &EquirectMap,
        k: usize,
        filter: MapFilter,
        tolerance: f64,
        values: &mut [f64; 16],
        k_out: &mut usize,
    ) -> f64 {
        let k = k.clamp(1, 4);
        *k_out = k;
        let store = |i: usize, v: f64| values[i] = v;
        match filter {
            MapFilter::Exact => self.exact_parts(map, k, store),
            MapFilter::Samples => self.samples_mean(map, k, store),
            MapFilter::Adaptive => {
                let mean = self.samples_mean(map, k, store);
                let mut spread = Spread::default();
                values[..k * k].iter().for_each(|&v| spread.add(v));
                if spread.exceeds(mean, tolerance) {
                    self.exact_parts(map, k, |i, v| values[i] = v)
                } else {
                    mean
                }
            }
        }
    }

    /// The k×k samples' mean (k clamped to 1..=4), each passed to `store`.
    #[inline(always)]
    fn samples_mean(&self, map: &EquirectMap, k: usize, store: impl FnMut(usize, f64)) -> f64 {
        match k.clamp(1, 4) {
            1 => self.sample_k::<1>(map, store),
            2 => self.sample_k::<2>(map, store),
            3 => self.sample_k::<3>(map, store),
            _ => self.sample_k::<4>(map, store),
        }
    }

    /// The part of this footprint over the pixel offsets [u0, u1] × [v0,
    /// v1] (u along `a2`, v along `a1`, the whole footprint being
    /// [−½, ½]²): the same parallelogram, cut.
    #[inline]
    pub(super) fn part(&self, (u0, u1): (f64, f64), (v0, v1): (f64, f64)) -> Footprint {
        let (a1, a2) = (self.a1, self.a2);
        let (u, v) = (0.5 * (u0 + u1), 0.5 * (v0 + v1));
        let (su, sv) = (u1 - u0, v1 - v0);
        Footprint {
            x: self.x + a1.0 * v + a2.0 * u,
            y: self.y + a1.1 * v + a2.1 * u,
            a1: (a1.0 * sv, a1.1 * sv),
            a2: (a2.0 * su, a2.1 * su),
        }
    }

    /// K×K samples over the footprint, each passed to `store` (row-major
    /// index); returns their mean. Samples smaller than a texel are
    /// bilinear; those stretched along longitude only read the map's
    /// x-averaged levels; others average a box of their size. All samples
    /// of a footprint have the same size, so the choice is made once.
    #[inline(always)]
    fn sample_k<const K: usize>(
        &self,
        map: &EquirectMap,
        mut store: impl FnMut(usize, f64),
    ) -> f64 {
        let (sx2, sy2) = self.part_box2(K);
        if sx2 <= BOX_MIN2 && sy2 <= BOX_MIN2 {
            self.each::<K>(|x, y| map.sample_texel(x, y), &mut store)
        } else if sy2 <= BOX_MIN2 {
            let stretched = map.stretched(sx2.sqrt());
            self.each::<K>(|x, y| stretched.sample(x, y), &mut store)
        } else {
            let (hx, hy) = (0.5 * (1.0 + sx2).sqrt(), 0.5 * (1.0 + sy2).sqrt());
            self.each::<K>(|x, y| map.box_average_texel(x, y, hx, hy), &mut store)
        }
    }

    /// The exact means of the k×k parts, passed to `store`; their mean
    /// (the whole footprint's exact mean: the parts have equal areas).
    fn exact_parts(&self, map: &EquirectMap, k: usize, mut store: impl FnMut(usize, f64)) -> f64 {
        let (a1, a2) = (self.a1, self.a2);
        let kf = k as f64;
        let (b1, b2) = ((a1.0 / kf, a1.1 / kf), (a2.0 / kf, a2.1 / kf));
        let mut sum = 0.0;
        for p in 0..k {
            let v = (p as f64 + 0.5) / kf - 0.5;
            for q in 0..k {
                let u = (q as f64 + 0.5) / kf - 0.5;
                let x = self.x + a1.0 * v + a2.0 * u;
                let y = self.y + a1.1 * v + a2.1 * u;
                let s = map.parallelogram_mean(x, y, b1, b2);
                store(p * k + q, s);
                sum += s;
            }
        }
        sum / (k * k) as f64
    }

    /// Squared size (sx², sy²) [texels²] of the box standing for one of
    /// the k×k parts: the part's bounding box shrunk to its area. Squared,
    /// so the common case takes no root.
    #[inline(always)]
    fn part_box2(&self, k: usize) -> (f64, f64) {
        let (a1, a2) = (self.a1, self.a2);
        let kf = k as f64;
        let bx = (a1.0.abs() + a2.0.abs()) / kf;
        let by = (a1.1.abs() + a2.1.abs()) / kf;
        let area = (a1.0 * a2.1 - a1.1 * a2.0).abs() / (kf * kf);
        if bx * by > 0.0 {
            (bx * area / by, by * area / bx)
        } else {
            (bx * bx, by * by)
        }
    }

    /// `value` at the centres of the K×K parts, passed to `store`; their
    /// mean.
    #[inline(always)]
    fn each<const K: usize>(
        &self,
        value: impl Fn(f64, f64) -> f64,
        store: &mut impl FnMut(usize, f64),
    ) -> f64 {
        let (a1, a2) = (self.a1, self.a2);
        let kf = K as f64;
        let mut sum = 0.0;
        for p in 0..K {
            let v = (p as f64 + 0.5) / kf - 0.5;
            for q in 0..K {
                let u = (q as f64 + 0.5) / kf - 0.5;
                let x = self.x + a1.0 * v + a2.0 * u;
                let y = self.y + a1.1 * v + a2.1 * u;
                let s = value(x, y);
                store(p * K + q, s);
                sum += s;
            }
        }
        sum / (K * K) as f64
    }
}

/// Parts of a footprint larger than this [texels] along an axis are
/// averaged over a box, not sampled (squared).
const BOX_MIN2: f64 = 1.5 * 1.5;

/// A convex polygon of at most 8 vertices.
#[derive(Clone, Copy)]
struct Polygon {
    v: [(f64, f64); 8],
    n: usize,
}

impl Polygon {
    fn from_quad(quad: &[(f64, f64); 4]) -> Polygon {
        let mut poly = Polygon {
            v: [(0.0, 0.0); 8],
            n: 4,
        };
        poly.v[..4].copy_from_slice(quad);
        poly
    }

    /// The part below grid line `k + 1` along `axis`, leaving the rest in
    /// `self`; the whole rest at the last line `last`.
    #[inline]
    fn split_at(&mut self, axis: usize, k: i64, last: i64) -> Polygon {
        if k == last {
            return *self;
        }
        let low = self.clip(axis, (k + 1) as f64, true);
        *self = self.clip(axis, (k + 1) as f64, false);
        low
    }

    /// Area and first moment (∫x dA, ∫y dA), unsigned whichever the
    /// vertex order.
    fn area_moment(&self) -> (f64, (f64, f64)) {
        let (mut a, mut mx, mut my) = (0.0, 0.0, 0.0);
        for k in 0..self.n {
            let (p, q) = (self.v[k], self.v[(k + 1) % self.n]);
            let c = p.0 * q.1 - q.0 * p.1;
            a += c;
            mx += (p.0 + q.0) * c;
            my += (p.1 + q.1) * c;
        }
        let sign = if a < 0.0 { -1.0 } else { 1.0 };
        (0.5 * a * sign, (mx * sign / 6.0, my * sign / 6.0))
    }

    fn area(&self) -> f64 {
        let mut a = 0.0;
        for k in 0..self.n {
            let (p, q) = (self.v[k], self.v[(k + 1) % self.n]);
            a += p.0 * q.1 - q.0 * p.1;
        }
        0.5 * a.abs()
    }

    /// The part with coordinate `axis` (0: x, 1: y) on the `keep_low` side
    /// of `at` (Sutherland–Hodgman against one line).
    fn clip(&self, axis: usize, at: f64, keep_low: bool) -> Polygon {
        let coord = |p: (f64, f64)| if axis == 0 { p.0 } else { p.1 };
        let inside = |p: (f64, f64)| (coord(p) <= at) == keep_low;
        let mut out = Polygon {
            v: [(0.0, 0.0); 8],
            n: 0,
        };
        for k in 0..self.n {
            let (p, q) = (self.v[k], self.v[(k + 1) % self.n]);
            let (ip, iq) = (inside(p), inside(q));
            if ip && out.n < 8 {
                out.v[out.n] = p;
                out.n += 1;
            }
            if ip != iq && out.n < 8 {
                let t = (at - coord(p)) / (coord(q) - coord(p));
                out.v[out.n] = (p.0 + t * (q.0 - p.0), p.1 + t * (q.1 - p.1));
                out.n += 1;
            }
        }
        out
    }
}

/// Twice the signed area of the part of a convex polygon with coordinate
/// `AXIS` (0: x, 1: y) ≤ `at`, accumulated edge by edge without building
/// the clipped polygon.
#[inline]
fn half_plane_area2<const AXIS: usize>(v: &[(f64, f64)], at: f64) -> f64 {
    let coord = |p: (f64, f64)| if AXIS == 0 { p.0 } else { p.1 };
    let cross = |p: (f64, f64), q: (f64, f64)| p.0 * q.1 - q.0 * p.1;
    let lerp = |p: (f64, f64), q: (f64, f64)| {
        let t = (at - coord(p)) / (coord(q) - coord(p));
        (p.0 + t * (q.0 - p.0), p.1 + t * (q.1 - p.1))
    };
    let mut acc = 0.0;
    let (mut exit, mut enter) = ((0.0, 0.0), (0.0, 0.0));
    let mut cut = false;
    let n = v.len();
    for k in 0..n {
        let (p, q) = (v[k], v[if k + 1 == n { 0 } else { k + 1 }]);
        match (coord(p) <= at, coord(q) <= at) {
            (true, true) => acc += cross(p, q),
            (true, false) => {
                let i = lerp(p, q);
                acc += cross(p, i);
                exit = i;
                cut = true;
            }
            (false, true) => {
                let i = lerp(p, q);
                acc += cross(i, q);
                enter = i;
            }
            (false, false) => {}
        }
    }
    if cut {
        acc += cross(exit, enter);
    }
    acc
}

/// The part of a quadrilateral with x ≤ `at` (at most 5 vertices).
#[inline]
fn clip_quad_left(quad: &[(f64, f64); 4], at: f64) -> ([(f64, f64); 6], usize) {
    let mut out = [(0.0, 0.0); 6];
    let mut n = 0;
    for k in 0..4 {
        let (p, q) = (quad[k], quad[(k + 1) & 3]);
        let (ip, iq) = (p.0 <= at, q.0 <= at);
        if ip {
            out[n] = p;
            n += 1;
        }
        if ip != iq {
            let t = (at - p.0) / (q.0 - p.0);
            out[n] = (at, p.1 + t * (q.1 - p.1));
            n += 1;
        }
    }
    (out, n)
}

/// Where gridded caps land: a worker's buffer over the ROI, minus the
/// pixels integrated per pixel (see [`super::interior`]), whose share of a
/// cap is dropped and counted in `skipped`.
pub struct Sink<'a> {
    pub buf: &'a mut [f32],
    pub roi: Rect,
    pub interior: Option<&'a InteriorMask>,
    /// PF dropped on interior pixels since the last take.
    pub skipped: f64,
    /// Caps integrated (not covered by interior pixels).
    pub integrated: u64,
    /// Sights of the leaf being gridded, kept across a frame's sub-bands
    /// ([`super::sight_memo`]).
    pub tape: super::sight_memo::SightTape,
}

/// Where gridding puts a cap's value: the frame ([`Sink`]) or one cap's
/// pixel shares ([`Shares`]).
pub(super) trait PixelAdd {
    fn add(&mut self, i: i64, j: i64, value: f64);
}

impl PixelAdd for Sink<'_> {
    #[inline]
    fn add(&mut self, i: i64, j: i64, value: f64) {
        let roi = &self.roi;
        if i >= roi.x0 as i64 && i < roi.x1 as i64 && j >= roi.y0 as i64 && j < roi.y1 as i64 {
            let k = (j as usize - roi.y0) * roi.width() + (i as usize - roi.x0);
            if self.interior.is_some_and(|m| m.is_interior(k)) {
                self.skipped += value;
            } else {
                self.buf[k] += value as f32;
            }
        }
    }
}

/// One cap's value split over the few pixels it touches, before it goes
/// to the frame; `overflow` when it touched more than 16.
#[derive(Clone, Copy)]
struct Shares {
    cells: [(i64, i64, f64); 16],
    n: usize,
    overflow: bool,
}

impl Default for Shares {
    fn default() -> Self {
        Shares {
            cells: [(0, 0, 0.0); 16],
            n: 0,
            overflow: false,
        }
    }
}

impl Shares {
    fn cells(&self) -> &[(i64, i64, f64)] {
        &self.cells[..self.n]
    }
}

impl PixelAdd for Shares {
    #[inline]
    fn add(&mut self, i: i64, j: i64, value: f64) {
        if let Some(c) = self.cells[..self.n]
            .iter_mut()
            .find(|c| c.0 == i && c.1 == j)
        {
            c.2 += value;
        } else if self.n < self.cells.len() {
            self.cells[self.n] = (i, j, value);
            self.n += 1;
        } else {
            self.overflow = true;
        }
    }
}

/// A mapped cap's k×k sub-quadrilaterals gridded together: per pixel the
/// sum of their parts weighted by their map share and by their flux share
/// (`weights`, set before each sub-quadrilateral is gridded).
#[derive(Clone, Copy)]
struct SubShares {
    cells: [(i64, i64, f64, f64); 16],
    n: usize,
    weights: (f64, f64),
    overflow: bool,
}

impl Default for SubShares {
    fn default() -> Self {
        SubShares {
            cells: [(0, 0, 0.0, 0.0); 16],
            n: 0,
            weights: (0.0, 0.0),
            overflow: false,
        }
    }
}

impl SubShares {
    /// (map-weighted, flux-weighted) sums for pixel (i, j).
    #[inline]
    fn get(&self, i: i64, j: i64) -> Option<(f64, f64)> {
        self.cells[..self.n]
            .iter()
            .find(|c| c.0 == i && c.1 == j)
            .map(|c| (c.2, c.3))
    }
}

impl PixelAdd for SubShares {
    #[inline]
    fn add(&mut self, i: i64, j: i64, value: f64) {
        let (ws, wf) = self.weights;
        if let Some(c) = self.cells[..self.n]
            .iter_mut()
            .find(|c| c.0 == i && c.1 == j)
        {
            c.2 += value * ws;
            c.3 += value * wf;
        } else if self.n < self.cells.len() {
            self.cells[self.n] = (i, j, value * ws, value * wf);
            self.n += 1;
        } else {
            self.overflow = true;
        }
    }
}

impl Sink<'_> {
    /// Whether every pixel a footprint's bounding box touches is interior,
    /// so the cap can be skipped.
    #[inline]
    fn covers_quad(&self, quad: &[(f64, f64); 4]) -> bool {
        let Some(mask) = self.interior else {
            return false;
        };
        if !quad.iter().all(|p| p.0.is_finite() && p.1.is_finite()) {
            return false;
        }
        let (x0, y0, x1, y1) = bounds(quad);
        if !(x0 >= 0.0 && y0 >= 0.0) {
            return false;
        }
        mask.covers(x0 as usize, y0 as usize, x1 as usize + 1, y1 as usize + 1)
    }
}

/// Bounding box (x0, y0, x1, y1) of a projected footprint.
#[inline]
pub(super) fn bounds(quad: &[(f64, f64); 4]) -> (f64, f64, f64, f64) {
    // Plain comparisons (one instruction each, not NaN-aware min/max):
    // callers pass finite corners.
    let lo = |a: f64, b: f64| if b < a { b } else { a };
    let hi = |a: f64, b: f64| if b > a { b } else { a };
    let (mut x0, mut y0, mut x1, mut y1) = (quad[0].0, quad[0].1, quad[0].0, quad[0].1);
    for p in &quad[1..] {
        x0 = lo(x0, p.0);
        x1 = hi(x1, p.0);
        y0 = lo(y0, p.1);
        y1 = hi(y1, p.1);
    }
    (x0, y0, x1, y1)
}

/// Relative change of the radiance shape across a cap below which the
/// area split is kept: its error in a pixel's share is then below ~1e-3 of
/// the cap, and the split by area is the cheaper one.
const SHAPE_FLAT: f64 = 1e-2;

/// Gridding of one cap whose radiance changes across it (the terminator,
/// where μ0 rises from zero): the radiance is taken as the plane through
/// the corners' `shape` values (its gradient from the two diagonals), and
/// each pixel receives the plane's integral over its part of the
/// footprint, from the part's area and first moment. Elsewhere the shape
/// is flat and this is [`grid_quad`].
#[inline]
pub(super) fn grid_quad_shaped(
    sink: &mut impl PixelAdd,
    quad: &[(f64, f64); 4],
    shape: &[f64; 4],
    value: f64,
) {
    let (x0, y0, x1, y1) = bounds(quad);
    let (i0, i1) = (x0.floor() as i64, x1.floor() as i64);
    let (j0, j1) = (y0.floor() as i64, y1.floor() as i64);
    let mean = 0.25 * (shape[0] + shape[1] + shape[2] + shape[3]);
    let spread = shape.iter().fold(0.0f64, |m, &h| m.max((h - mean).abs()));
    if (i0 == i1 && j0 == j1) || !(spread > SHAPE_FLAT * mean) {
        return grid_quad(sink, quad, value);
    }
    let Some(slope) = plane_slope(quad, shape) else {
        return grid_quad(sink, quad, value);
    };
    let centre = (
        0.25 * (quad[0].0 + quad[1].0 + quad[2].0 + quad[3].0),
        0.25 * (quad[0].1 + quad[1].1 + quad[2].1 + quad[3].1),
    );
    // ∫ over a part of (mean + slope · (p − centre)).
    let weight = |part: &Polygon| {
        let (a, (mx, my)) = part.area_moment();
        (a * mean + slope.0 * (mx - a * centre.0) + slope.1 * (my - a * centre.1)).max(0.0)
    };
    let mut cells = [(0i64, 0i64, 0.0f64); 16];
    let mut n = 0;
    let mut total = 0.0;
    let mut rest = Polygon::from_quad(quad);
    for i in i0..=i1 {
        let column = rest.split_at(0, i, i1);
        let mut col_rest = column;
        for j in j0..=j1 {
            let cell = col_rest.split_at(1, j, j1);
            if cell.n < 3 {
                continue;
            }
            let w = weight(&cell);
            total += w;
            if n < cells.len() {
                cells[n] = (i, j, w);
                n += 1;
            } else {
                // Caps span a few pixels at most; a larger one keeps the area split.
                return grid_quad(sink, quad, value);
            }
        }
    }
    if !(total > 0.0) {
        return grid_quad(sink, quad, value);
    }
    for &(i, j, w) in &cells[..n] {
        sink.add(i, j, value * w / total);
    }
}

/// Area of a quadrilateral (shoelace).
#[inline]
fn quad_area(q: &[(f64, f64); 4]) -> f64 {
    let cross = |a: (f64, f64), b: (f64, f64)| a.0 * b.1 - b.0 * a.1;
    0.5 * (cross(q[0], q[1]) + cross(q[1], q[2]) + cross(q[2], q[3]) + cross(q[3], q[0])).abs()
}

/// Gradient of the plane through a quadrilateral's corner values, from its
/// two diagonals (exact when the values are linear); `None` when the
/// quadrilateral is degenerate.
#[inline]
fn plane_slope(quad: &[(f64, f64); 4], shape: &[f64; 4]) -> Option<(f64, f64)> {
    let d02 = (quad[2].0 - quad[0].0, quad[2].1 - quad[0].1);
    let d13 = (quad[3].0 - quad[1].0, quad[3].1 - quad[1].1);
    let (h02, h13) = (shape[2] - shape[0], shape[3] - shape[1]);
    let det = d02.0 * d13.1 - d02.1 * d13.0;
    let scale = (d02.0 * d02.0 + d02.1 * d02.1) * (d13.0 * d13.0 + d13.1 * d13.1);
    if !(det * det > 1e-12 * scale) {
        return None;
    }
    Some((
        (h02 * d13.1 - h13 * d02.1) / det,
        (d02.0 * h13 - d13.0 * h02) / det,
    ))
}

/// Area-weighted gridding of one cap (the paper's countermeasure against
/// aliasing): `value` is split over the pixels in proportion to the area of
/// the cap's projected footprint, the quadrilateral of its projected
/// corners, that falls in each. Neighbouring caps share corners, so the
/// footprints tile the image without gaps or overlaps.
#[inline]
fn grid_quad(sink: &mut impl PixelAdd, quad: &[(f64, f64); 4], value: f64) {
    let (x0, y0, x1, y1) = bounds(quad);
    let (i0, i1) = (x0.floor() as i64, x1.floor() as i64);
    let (j0, j1) = (y0.floor() as i64, y1.floor() as i64);
    if i0 == i1 && j0 == j1 {
        sink.add(i0, j0, value);
        return;
    }
    let signed2 = (quad[0].0 * quad[1].1 - quad[1].0 * quad[0].1)
        + (quad[1].0 * quad[2].1 - quad[2].0 * quad[1].1)
        + (quad[2].0 * quad[3].1 - quad[3].0 * quad[2].1)
        + (quad[3].0 * quad[0].1 - quad[0].0 * quad[3].1);
    let area = 0.5 * signed2.abs();
    if !(area > 1e-12 * (x1 - x0 + y1 - y0).powi(2)) {
        let cx = 0.25 * (quad[0].0 + quad[1].0 + quad[2].0 + quad[3].0);
        let cy = 0.25 * (quad[0].1 + quad[1].1 + quad[2].1 + quad[3].1);
        sink.add(cx.floor() as i64, cy.floor() as i64, value);
        return;
    }
    let per_area = value / area;
    if i1 - i0 <= 1 && j1 - j0 <= 1 {
        // At most 2×2 pixels: inclusion–exclusion on one vertical and one
        // horizontal grid line.
        let (xs, ys) = ((i0 + 1) as f64, (j0 + 1) as f64);
        let sign = 0.5f64.copysign(signed2);
        let a_left = if i1 > i0 {
            sign * half_plane_area2::<0>(quad, xs)
        } else {
            area
        };
        let (a_top, a_left_top) = if j1 > j0 {
            let top = sign * half_plane_area2::<1>(quad, ys);
            let left_top = if i1 > i0 {
                let (left, n) = clip_quad_left(quad, xs);
                sign * half_plane_area2::<1>(&left[..n], ys)
            } else {
                top
            };
            (top, left_top)
        } else {
            (area, a_left)
        };
        sink.add(i0, j0, a_left_top.max(0.0) * per_area);
        if i1 > i0 {
            sink.add(i1, j0, (a_top - a_left_top).max(0.0) * per_area);
        }
        if j1 > j0 {
            sink.add(i0, j1, (a_left - a_left_top).max(0.0) * per_area);
            if i1 > i0 {
                let rest = area - a_left - a_top + a_left_top;
                sink.add(i1, j1, rest.max(0.0) * per_area);
            }
        }
        return;
    }
    let mut poly = Polygon {
        v: [(0.0, 0.0); 8],
        n: 4,
    };
    poly.v[..4].copy_from_slice(quad);
    // Larger footprints: clip column by column, then row by row.
    let mut rest = poly;
    for i in i0..=i1 {
        let column = if i < i1 {
            let c = rest.clip(0, (i + 1) as f64, true);
            rest = rest.clip(0, (i + 1) as f64, false);
            c
        } else {
            rest
        };
        let mut col_rest = column;
        for j in j0..=j1 {
            let cell = if j < j1 {
                let c = col_rest.clip(1, (j + 1) as f64, true);
                col_rest = col_rest.clip(1, (j + 1) as f64, false);
                c
            } else {
                col_rest
            };
            if cell.n >= 3 {
                sink.add(i, j, cell.area() * per_area);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid_into(buf: &mut [f32], roi: &Rect, quad: &[(f64, f64); 4], value: f64) {
        let mut sink = Sink {
            buf,
            roi: *roi,
            interior: None,
            skipped: 0.0,
            integrated: 0,
            tape: Default::default(),
        };
        grid_quad(&mut sink, quad, value);
    }

    #[test]
    fn inline_cap_weights_equal_the_closed_forms() {
        // The per-cap loop evaluates the φ factors from the cap centre's
        // sin/cos; they must equal closed_form's cap integrals.
        for &(alpha, p0, d) in &[(0.3f64, -1.0f64, 0.01f64), (1.7, 0.2, 0.3), (2.9, 1.3, 0.2)] {
            let (sa, ca) = alpha.sin_cos();
            let pc = p0 + 0.5 * d;
            let (sp, cp) = pc.sin_cos();
            let cos_2pa = (cp * cp - sp * sp) * ca + 2.0 * sp * cp * sa;
            let mu0mu = 0.5 * (d * ca + cos_2pa * d.sin());
            let cos_pa = cp * ca + sp * sa;
            let mu = 2.0 * cos_pa * (0.5 * d).sin();
            let (t0, t1) = (0.4, 0.9);
            let s3 = closed_form::int_sin3(t0, t1);
            let s2 = closed_form::int_sin2(t0, t1);
            let a = closed_form::cap_mu0_mu(t0, t1, p0, p0 + d, alpha);
            let b = closed_form::cap_mu(t0, t1, p0, p0 + d, alpha);
            assert!(
                (s3 * mu0mu - a).abs() <= 1e-12 * a.abs(),
                "{} {a}",
                s3 * mu0mu
            );
            assert!((s2 * mu - b).abs() <= 1e-12 * b.abs(), "{} {b}", s2 * mu);
        }
    }

    #[test]
    fn sun_fraction_limits_and_partial_overlap() {
        let sun = DVec3::X * 1.5e11;
        let a = (SUN_RADIUS / 1.5e11).asin();
        // Occulter far off the line: full Sun; centred and larger: none.
        assert_eq!(visible_sun_fraction(sun, DVec3::Y * 1e8, 1e6), 1.0);
        assert_eq!(visible_sun_fraction(sun, DVec3::X * 1e8, 1e7), 0.0);
        // Half-overlap of equal disks: separation c = a gives the lens area
        // 2a²·acos(1/2) − (a²/2)·√3 (independent closed form).
        let d = 1e9;
        let b_radius = d * a.sin();
        let occ = DVec3::new(a.cos(), a.sin(), 0.0) * d;
        let f = visible_sun_fraction(sun, occ, b_radius);
        let lens = 2.0 * a * a * (0.5f64).acos() - 0.5 * a * a * 3f64.sqrt();
        let expected = 1.0 - lens / (std::f64::consts::PI * a * a);
        assert!((f - expected).abs() < 1e-3, "{f} vs {expected}");
    }

    #[test]
    fn gridding_splits_by_exact_area() {
        let roi = Rect {
            x0: 0,
            y0: 0,
            x1: 8,
            y1: 8,
        };
        // A unit square centred on a pixel corner lands a quarter in each.
        let mut buf = vec![0.0f32; 64];
        let q = [(2.5, 2.5), (3.5, 2.5), (3.5, 3.5), (2.5, 3.5)];
        grid_into(&mut buf, &roi, &q, 1.0);
        for k in [2 * 8 + 2, 2 * 8 + 3, 3 * 8 + 2, 3 * 8 + 3] {
            assert!((buf[k] - 0.25).abs() < 1e-6);
        }
        // A triangle-like sliver and a big rotated square conserve value.
        for quad in [
            [(1.2, 1.1), (4.7, 2.3), (3.9, 5.6), (0.4, 3.3)],
            [(3.2, 3.9), (4.1, 3.05), (4.3, 3.9), (3.4, 4.4)],
        ] {
            let mut buf = vec![0.0f32; 64];
            grid_into(&mut buf, &roi, &quad, 1.0);
            let sum: f32 = buf.iter().sum();
            assert!((sum - 1.0).abs() < 1e-6, "{sum}");
        }
        // Straddling the image edge keeps only the inside share.
        let mut buf = vec![0.0f32; 64];
        let q = [(-0.5, 4.0), (0.5, 4.0), (0.5, 5.0), (-0.5, 5.0)];
        grid_into(&mut buf, &roi, &q, 1.0);
        let sum: f32 = buf.iter().sum();
        assert!((sum - 0.5).abs() < 1e-6);
    }
}
