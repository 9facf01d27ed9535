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
//! A cap whose four corners disagree on being seen is therefore cut into
//! quarters, recursively, until each part's footprint spans at most
//! [`EDGE_PART_PX`]; each part is seen or hidden at its own centre and
//! grids its own footprint. A part's projected area is that of the
//! bilinear surface its corners sit on: the smooth slope maps faced the
//! camera on the crest's far side, whose surface is edge-on there, and
//! put 3 % of a pixel's light into slivers (that pixel without / with
//! `far_limb`: 1/16 px parts 0.991 / 1.041 with the slope maps' area,
//! 0.968 / 1.005 with the surface's; 1/64 px parts 1.018 / 1.026 and
//! 0.995 / 0.990). Parts stop at 1/16 px: near a relief Moon's limb most
//! caps are cut, and 1/64 px parts made `configs/moon_relief.toml` take
//! 107 s of CPU instead of about 3 (the camera test's marches).

use glam::DVec3;

use super::caps::{bounds, grid_quad_shaped, Frame, Sink};

/// Footprint size [px] below which a part across an occlusion edge is not
/// cut further: the edge lands within half of it.
pub const EDGE_PART_PX: f64 = 1.0 / 16.0;

/// Most cuts of a cap across an occlusion edge (4^depth parts at most, in
/// practice about 2 per level along the edge).
const MAX_DEPTH: u32 = 4;

/// A cap corner: its image position, radiance shape and whether the
/// camera sees it.
#[derive(Clone, Copy, Debug)]
pub struct EdgePoint {
    pub pos: (f64, f64),
    pub shape: f64,
    pub seen: bool,
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
        let Some(height) = self.height else {
            return true;
        };
        let [xb, yb, zb] = self.axes_body;
        let n_body = xb * n_local.x + yb * n_local.y + zb * n_local.z;
        let tiles = self.body.relief.height_tiles.as_deref();
        let r =
            crate::scene::surface::displaced_radius_tiled(&height.0, tiles, self.radius, n_body);
        let cam = self.lune.camera_local() - n_local * r;
        self.surface_normal_local(n_body, r).dot(cam) > 0.0
            && self.camera_visible(n_body, cam, r) > 0.0
    }

    /// The cap corner at colatitude `theta` and lune coordinate `s`.
    fn edge_point(&self, theta: f64, s: f64) -> EdgePoint {
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
            seen: self.seen(n_local),
        }
    }

    /// Integrates and grids the cap θ ∈ `theta`, s ∈ `s` whose corners
    /// (θ0 s0, θ0 s1, θ1 s1, θ1 s0) are `c`: cut into quarters while its
    /// corners disagree on being seen and its footprint exceeds
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
        let mixed = c.iter().any(|p| p.seen != c[0].seen)
            && quad.iter().all(|p| p.0.is_finite() && p.1.is_finite());
        let (x0, y0, x1, y1) = bounds(&quad);
        let extent = (x1 - x0).max(y1 - y0);
        if !(mixed && depth < MAX_DEPTH && extent > EDGE_PART_PX) {
            return self.grid_part(sink, theta, s, &c);
        }
        let (tm, sm) = (0.5 * (theta.0 + theta.1), 0.5 * (s.0 + s.1));
        let top = self.edge_point(theta.0, sm);
        let right = self.edge_point(tm, s.1);
        let bottom = self.edge_point(theta.1, sm);
        let left = self.edge_point(tm, s.0);
        let mid = self.edge_point(tm, sm);
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
