//! Caps across an occlusion edge of the displaced surface. A cap is seen
//! or hidden by the camera test at its centre, and its light fills its
//! whole footprint; where relief hides the terrain behind it, the
//! footprint of a terrain cap whose centre is seen runs under the
//! occluder's image (light twice), and one whose centre is hidden leaves
//! a gap. Behind the ring ridge of `tests/relief_hidden.rs` the grazing
//! pixel just past the crest held 1.41 of one surface's radiance without
//! `far_limb` (a terrain cap's footprint reached 0.42 px under the crest
//! cap's) and 0.947 with it (its wider layout moved the caps: a 0.035 px
//! gap instead): the same centre sampling, not the far limb's march.
//! A cap with a corner seen and a corner hidden by relief is therefore
//! cut into quarters, recursively, until each part's footprint spans at most
//! [`EDGE_PART_PX`]; each part is seen or hidden at its own centre and
//! grids its own footprint. A part's projected area is that of the
//! bilinear surface its corners sit on: the smooth slope maps faced the
//! camera on the crest's far side, whose surface is edge-on there, and
//! put 3 % of a pixel's light into slivers (that pixel without / with
//! `far_limb`: 1/16 px parts 0.991 / 1.041 with the slope maps' area,
//! 0.968 / 1.005 with the surface's; 1/64 px parts 1.018 / 1.026 and
//! 0.995 / 0.990). Parts stop at 1/16 px: 1/64 px parts made
//! `configs/moon.toml` take 107 s of CPU instead of about 3 (the
//! camera test's marches). A cap whose corners are only seen or facing
//! away is a plain fold (the limb, a crest): not cut, since its corners'
//! projections already place the silhouette (cutting it there moved
//! `tests/relief_limb.rs`'s limb from 0.005 to 0.014 px off and cost
//! half of that render's time).

use glam::DVec3;

use super::caps::{bounds, grid_quad_shaped, Frame, Sink};
use super::sight_memo::SightTape;

/// Footprint size [px] below which a part across an occlusion edge is not
/// cut further: the edge lands within half of it.
pub const EDGE_PART_PX: f64 = 1.0 / 16.0;

/// Most cuts of a cap across an occlusion edge (4^depth parts at most, in
/// practice about 2 per level along the edge).
const MAX_DEPTH: u32 = 4;

/// How the camera sees a point of the displaced surface.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sight {
    /// It faces the camera and no relief hides it.
    Seen,
    /// Its surface faces away from the camera: past a fold (the limb, a
    /// crest), which the cap geometry places itself.
    BackFacing,
    /// It faces the camera, but nearer relief hides it.
    Hidden,
}

/// Whether an occlusion edge crosses a cap whose corners the camera sees
/// as `sight`: some corner is seen and some is hidden by relief. Seen and
/// back-facing corners alone are a plain fold: the corners' projections
/// fold there and the silhouette falls where the surface puts it, to
/// 1e-4 px (`tests/relief_limb.rs`); cutting it would place it to half a
/// part.
pub fn crosses_edge(sight: &[Sight; 4]) -> bool {
    sight.contains(&Sight::Seen) && sight.contains(&Sight::Hidden)
}

/// A cap corner: its image position, radiance shape and how the camera
/// sees it.
#[derive(Clone, Copy, Debug)]
pub struct EdgePoint {
    pub pos: (f64, f64),
    pub shape: f64,
    pub sight: Sight,
}

impl Frame<'_> {
    /// Whether this frame cuts caps across occlusion edges: it applies a
    /// displacement that is not flat (a flat DEM hides nothing).
    #[inline]
    pub fn cuts_occlusion_edges(&self) -> bool {
        self.height.is_some() && self.body.relief.height_bound > 0.0
    }

    /// Whether the camera sees the displaced surface over the unit
    /// direction `n_local` (Lester coordinates): it faces the camera and
    /// no relief hides it (the centre test of the integrand).
    pub fn seen(&self, n_local: DVec3) -> bool {
        self.sight(n_local) == Sight::Seen
    }

    /// How the camera sees the displaced surface over the unit direction
    /// `n_local` (Lester coordinates).
    pub fn sight(&self, n_local: DVec3) -> Sight {
        self.sight_now(n_local)
    }

    /// [`Self::sight`], read back from the worker's `tape` where an
    /// earlier sub-band of the frame recorded it ([`super::sight_memo`]).
    pub fn sight_taped(&self, n_local: DVec3, tape: &mut SightTape) -> Sight {
        tape.sight(n_local, || self.sight_now(n_local))
    }

    /// [`Self::sight`], computed.
    fn sight_now(&self, n_local: DVec3) -> Sight {
        let Some(height) = self.height else {
            return Sight::Seen;
        };
        let [xb, yb, zb] = self.axes_body;
        let n_body = xb * n_local.x + yb * n_local.y + zb * n_local.z;
        let tiles = self.body.relief.height_tiles.as_deref();
        let r =
            crate::scene::surface::displaced_radius_tiled(&height.0, tiles, self.radius, n_body);
        let cam = self.lune.camera_local() - n_local * r;
        if self.surface_normal_local(n_body, r).dot(cam) <= 0.0 {
            Sight::BackFacing
        } else if self.camera_visible(n_body, cam, r) > 0.0 {
            Sight::Seen
        } else {
            Sight::Hidden
        }
    }

    /// The cap corner at colatitude `theta` and lune coordinate `s`.
    fn edge_point(&self, theta: f64, s: f64, tape: &mut SightTape) -> EdgePoint {
        let (st, ct) = theta.sin_cos();
        let (lo, hi) = self.lune.phi_range(st);
        let (sp, cp) = (lo + s * (hi - lo).max(0.0)).sin_cos();
        let n_local = DVec3::new(st * cp, st * sp, ct);
        let [xc, yc, zc] = self.axes_cam;
        let mut p = (xc * n_local.x + yc * n_local.y + zc * n_local.z) * self.radius;
        if let Some(h) = self.height {
            let [xb, yb, zb] = self.axes_body;
            let n_body = xb * n_local.x + yb * n_local.y + zb * n_local.z;
            let tiles = self.body.relief.height_tiles.as_deref();
            let r = crate::scene::surface::displaced_radius_tiled(&h.0, tiles, self.radius, n_body);
            p *= r / self.radius;
        }
        let p = p - self.camera_cam;
        let (sin_a, cos_a) = self.lune.alpha.sin_cos();
        EdgePoint {
            pos: if p.z > 0.0 {
                self.camera.project(p)
            } else {
                (f64::NAN, f64::NAN)
            },
            shape: self
                .weight
                .radiance_shape(st * cp, st * (cp * cos_a + sp * sin_a)),
            sight: self.sight_taped(n_local, tape),
        }
    }

    /// Integrates and grids the cap θ ∈ `theta`, s ∈ `s` whose corners
    /// (θ0 s0, θ0 s1, θ1 s1, θ1 s0) are `c`: cut into quarters while an
    /// occlusion edge crosses it ([`crosses_edge`]) and its footprint exceeds
    /// [`EDGE_PART_PX`]. Returns the PF of the parts gridded.
    pub fn grid_edge_cap(
        &self,
        sink: &mut Sink,
        theta: (f64, f64),
        s: (f64, f64),
        c: [EdgePoint; 4],
        depth: u32,
    ) -> f64 {
        let quad = c.map(|p| p.pos);
        let mixed = crosses_edge(&c.map(|p| p.sight))
            && quad.iter().all(|p| p.0.is_finite() && p.1.is_finite());
        let (x0, y0, x1, y1) = bounds(&quad);
        let extent = (x1 - x0).max(y1 - y0);
        if !(mixed && depth < MAX_DEPTH && extent > EDGE_PART_PX) {
            return self.grid_part(sink, theta, s, &c);
        }
        let (tm, sm) = (0.5 * (theta.0 + theta.1), 0.5 * (s.0 + s.1));
        let tape = &mut sink.tape;
        let top = self.edge_point(theta.0, sm, tape);
        let right = self.edge_point(tm, s.1, tape);
        let bottom = self.edge_point(theta.1, sm, tape);
        let left = self.edge_point(tm, s.0, tape);
        let mid = self.edge_point(tm, sm, tape);
        let (upper, lower) = ((theta.0, tm), (tm, theta.1));
        let (west, east) = ((s.0, sm), (sm, s.1));
        self.grid_edge_cap(sink, upper, west, [c[0], top, mid, left], depth + 1)
            + self.grid_edge_cap(sink, upper, east, [top, c[1], right, mid], depth + 1)
            + self.grid_edge_cap(sink, lower, east, [mid, right, c[2], bottom], depth + 1)
            + self.grid_edge_cap(sink, lower, west, [left, mid, bottom, c[3]], depth + 1)
    }

    /// One part: the integrand at its centre times its area on the sphere
    /// (parts are small: no closed-form weight), gridded over its
    /// footprint; albedo sampled at the centre.
    fn grid_part(
        &self,
        sink: &mut Sink,
        theta: (f64, f64),
        s: (f64, f64),
        c: &[EdgePoint; 4],
    ) -> f64 {
        let tm = 0.5 * (theta.0 + theta.1);
        let (st, ct) = tm.sin_cos();
        let (lo, hi) = self.lune.phi_range(st);
        if hi <= lo {
            return 0.0;
        }
        let (sp, cp) = (lo + 0.5 * (s.0 + s.1) * (hi - lo)).sin_cos();
        let n_local = DVec3::new(st * cp, st * sp, ct);
        // The integrand is zero where the surface faces away or relief
        // hides it (the same two tests): a part that is
        // not seen skips it, and the sight is read back in later sub-bands.
        if self.sight_taped(n_local, &mut sink.tape) != Sight::Seen {
            return 0.0;
        }
        let [xb, yb, zb] = self.axes_body;
        let n_body = xb * n_local.x + yb * n_local.y + zb * n_local.z;
        let albedo = self.point_albedo(n_body);
        let integrand = self.part_integrand(n_local, n_body, albedo);
        let area = (theta.0.cos() - theta.1.cos()) * (s.1 - s.0) * (hi - lo);
        let pf = self.radius * self.radius * area * integrand;
        if !(pf > 0.0) {
            return 0.0;
        }
        sink.integrated += 1;
        let quad = c.map(|p| p.pos);
        if quad.iter().all(|p| p.0.is_finite()) {
            grid_quad_shaped(sink, &quad, &c.map(|p| p.shape), pf);
        }
        pf
    }
}
