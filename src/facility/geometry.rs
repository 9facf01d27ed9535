//! Geometric calibration of the screen seen through the collimator, and the
//! pre-warp that uses it: the calibration file (parsing, validation,
//! SHA-256), the smooth map screen pixel → camera direction, and the
//! static per-screen-pixel lookup that resamples an image rendered on an
//! ideal pinhole grid onto the real screen.
//!
//! # File
//!
//! CSV, UTF-8. Lines that are blank or start with `#` are comments. The first
//! other line is the header naming the four columns `u_px`, `v_px`, `tan_x`,
//! `tan_y` (any order, nothing else); then one row per node:
//!
//! * `u_px, v_px`: a screen position in continuous pixel coordinates (pixel
//!   (0, 0) top-left, centres at +0.5);
//! * `tan_x, tan_y`: where the camera sees that position, as x/z and y/z of
//!   the direction in the camera frame at zero attitude (x right, y down,
//!   z boresight).
//!
//! The nodes form a rectangular lattice: every `u_px` value occurs with every
//! `v_px` value, exactly once (rows in any order; spacing free, also
//! non-uniform). The lattice must span the whole screen, `[0, w] × [0, h]`,
//! and the map must be one-to-one: no lattice cell, and no point inside one
//! once interpolated, may fold over (Jacobian of one sign, never zero).
//! Errors name the file and the line (or the column).
//!
//! # Interpolation
//!
//! Between the nodes each tangent coordinate is the tensor product of 1-D
//! cubic Hermite interpolants whose node slopes are those of the parabola
//! through the node and its two neighbours (Catmull–Rom on a uniform
//! lattice, its non-uniform generalisation otherwise; one-sided parabola at
//! the ends). It reproduces quadratics exactly, is C¹, and its error is
//! O(h³ ∂³t). For the bundled example (Brown–Conrady k1 = 0.4 on a 10 838 px
//! focal length, nodes every 32 px) it is below 2e-5 px inside and 1e-4 px
//! in the outer cells, whose end slopes are one-sided (unit test
//! `interpolation_error_of_example_distortion`; bilinear interpolation of
//! the same lattice would err by up to 0.004 px).
//!
//! # Pre-warp
//!
//! The body is rendered by the unchanged renderer on an *ideal* pinhole grid
//! whose focal length is the finest local scale of the map (so it never
//! samples coarser than the screen) and whose extent covers every direction
//! a screen pixel centre shows, plus a margin. Each screen pixel's radiance
//! is the bilinear interpolation of the ideal grid's radiance at its
//! direction. Both the per-pixel lookup (ideal-grid base index and weights)
//! and a coarse inverse (for each [`TILE`]×[`TILE`] tile of the ideal grid,
//! the bounding box of the screen pixels whose bilinear footprint touches
//! it) are built once at start-up; per frame, the screen region to resample
//! is the union of the boxes of the tiles the ideal ROI touches, so the cost
//! scales with the body's pixels, not the screen's.

use std::path::{Path, PathBuf};

use rayon::prelude::*;

use super::dither::Roi;
use super::lut::sha256_hex;
use crate::error::{Error, Result};
use crate::scene::Pinhole;

/// Column names of a geometry file.
pub const GEOMETRY_COLUMNS: [&str; 4] = ["u_px", "v_px", "tan_x", "tan_y"];

/// Side of the ideal-grid tiles of the coarse inverse map, ideal pixels.
pub const TILE: usize = 8;

/// Ideal-grid pixels kept around the directions the screen shows, so every
/// bilinear footprint is inside the grid.
const MARGIN: usize = 3;

/// One lattice axis and its cubic weights.
#[derive(Debug, Clone)]
struct Axis {
    nodes: Vec<f64>,
}

impl Axis {
    /// Slope at node `i` as coefficients of the node values: the derivative
    /// of the parabola through `i` and its neighbours (one-sided at the ends).
    fn slope(&self, i: usize) -> [(usize, f64); 3] {
        let x = &self.nodes;
        let n = x.len();
        if n == 2 {
            let h = x[1] - x[0];
            return [(0, -1.0 / h), (1, 1.0 / h), (1, 0.0)];
        }
        if i == 0 {
            let (a, b) = (x[1] - x[0], x[2] - x[1]);
            let c0 = -(2.0 * a + b) / (a * (a + b));
            let c2 = -a / (b * (a + b));
            return [(0, c0), (1, -c0 - c2), (2, c2)];
        }
        if i == n - 1 {
            let (a, b) = (x[n - 1] - x[n - 2], x[n - 2] - x[n - 3]);
            let c0 = (2.0 * a + b) / (a * (a + b));
            let c2 = a / (b * (a + b));
            return [(n - 1, c0), (n - 2, -c0 - c2), (n - 3, c2)];
        }
        let (a, b) = (x[i] - x[i - 1], x[i + 1] - x[i]);
        let cp = a / (b * (a + b));
        let cm = -b / (a * (a + b));
        [(i + 1, cp), (i - 1, cm), (i, -cp - cm)]
    }

    /// Weights of nodes `start .. start + 4` for the value (`deriv` false)
    /// or the derivative at `t`.
    fn weights(&self, t: f64, deriv: bool) -> (usize, [f64; 4]) {
        let x = &self.nodes;
        let n = x.len();
        let i = x.partition_point(|&v| v <= t).clamp(1, n - 1) - 1;
        let h = x[i + 1] - x[i];
        let s = (t - x[i]) / h;
        let (h00, h10, h01, h11) = if deriv {
            (
                (6.0 * s * s - 6.0 * s) / h,
                3.0 * s * s - 4.0 * s + 1.0,
                (-6.0 * s * s + 6.0 * s) / h,
                3.0 * s * s - 2.0 * s,
            )
        } else {
            let (s2, s3) = (s * s, s * s * s);
            (
                2.0 * s3 - 3.0 * s2 + 1.0,
                (s3 - 2.0 * s2 + s) * h,
                -2.0 * s3 + 3.0 * s2,
                (s3 - s2) * h,
            )
        };
        let start = i.saturating_sub(1).min(n.saturating_sub(4));
        let mut w = [0.0; 4];
        w[i - start] += h00;
        w[i + 1 - start] += h01;
        for (k, c) in self.slope(i) {
            w[k - start] += h10 * c;
        }
        for (k, c) in self.slope(i + 1) {
            w[k - start] += h11 * c;
        }
        (start, w)
    }
}

/// A validated geometric calibration: screen position → camera direction.
#[derive(Debug, Clone)]
pub struct GeometryCalibration {
    path: PathBuf,
    sha256: String,
    screen: (usize, usize),
    u: Axis,
    v: Axis,
    /// Node directions, row-major (v outer).
    tan: Vec<[f64; 2]>,
    /// Finest local scale of the map, pixels per unit tangent.
    finest_scale: f64,
}

impl GeometryCalibration {
    /// Reads and validates the geometry file of a `screen = (w, h)` screen.
    pub fn load(path: impl AsRef<Path>, screen: (usize, usize)) -> Result<GeometryCalibration> {
        let path = path.as_ref();
        let bytes = crate::infile::read_bounded(path, crate::infile::TABLE_LIMIT)?;
        GeometryCalibration::from_csv_bytes(&bytes, path, screen)
    }

    /// Parses and validates file content; `path` names the file in errors.
    pub fn from_csv_bytes(
        bytes: &[u8],
        path: impl AsRef<Path>,
        screen: (usize, usize),
    ) -> Result<GeometryCalibration> {
        let path = path.as_ref();
        let nodes = read_nodes(bytes, path)?;
        let lattice = Lattice::arrange(&nodes, path, screen)?;
        let sign = lattice.check_cells(&nodes, path)?;
        let Lattice { us, vs, order } = lattice;
        let mut cal = GeometryCalibration {
            path: path.to_path_buf(),
            sha256: sha256_hex(bytes),
            screen,
            u: Axis { nodes: us },
            v: Axis { nodes: vs },
            tan: order.iter().map(|&i| nodes[i].tan()).collect(),
            finest_scale: 0.0,
        };
        let line = |iu: usize, iv: usize| nodes[order[iv * cal.u.nodes.len() + iu]].line;
        cal.finest_scale = cal.check_interpolated(sign, path, line)?;
        check_ideal_grid(&cal).map_err(|m| Error::parse(path, m))?;
        Ok(cal)
    }

    /// The interpolated map does not fold inside any lattice cell either
    /// (a cubic can overshoot between nodes that do not fold): its
    /// Jacobian keeps the nodes' orientation `sign` on a 4 × 4 grid per
    /// cell. Returns the map's finest local scale (pixels per unit tangent).
    fn check_interpolated(
        &self,
        sign: f64,
        path: &Path,
        line: impl Fn(usize, usize) -> usize,
    ) -> Result<f64> {
        const SUB: usize = 4;
        let (us, vs) = (&self.u.nodes, &self.v.nodes);
        let mut finest: f64 = 0.0;
        for iv in 0..vs.len() - 1 {
            for iu in 0..us.len() - 1 {
                for b in 0..=SUB {
                    for a in 0..=SUB {
                        let fu = a as f64 / SUB as f64;
                        let fv = b as f64 / SUB as f64;
                        let u = us[iu] * (1.0 - fu) + us[iu + 1] * fu;
                        let v = vs[iv] * (1.0 - fv) + vs[iv + 1] * fv;
                        let j = self.jacobian(u, v);
                        let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
                        if !(det * sign > 0.0) {
                            return Err(line_error(
                                path,
                                line(iu, iv),
                                format!(
                                    "the interpolated map folds at ({u}, {v}) inside the lattice cell \
                                     starting at node ({}, {}) (Jacobian determinant {det:e})",
                                    us[iu], vs[iv]
                                ),
                            ));
                        }
                        finest = finest.max(1.0 / smallest_singular_value(j));
                    }
                }
            }
        }
        Ok(finest)
    }

    /// File the calibration was read from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Hex SHA-256 of the file bytes.
    pub fn sha256(&self) -> &str {
        &self.sha256
    }

    /// Screen size `(w, h)` the file was validated for.
    pub fn screen(&self) -> (usize, usize) {
        self.screen
    }

    /// Finest local scale of the map, screen pixels per unit tangent: the
    /// largest singular value of ∂(u, v)/∂(tan_x, tan_y) found.
    pub fn finest_scale(&self) -> f64 {
        self.finest_scale
    }

    fn eval(&self, u: f64, v: f64, du: bool, dv: bool) -> [f64; 2] {
        let (su, wu) = self.u.weights(u, du);
        let (sv, wv) = self.v.weights(v, dv);
        let nu = self.u.nodes.len();
        let (ku, kv) = (nu.min(4), self.v.nodes.len().min(4));
        let mut out = [0.0; 2];
        for (b, &wb) in wv.iter().enumerate().take(kv) {
            let row = &self.tan[(sv + b) * nu + su..];
            for (a, &wa) in wu.iter().enumerate().take(ku) {
                let t = row[a];
                out[0] += wa * wb * t[0];
                out[1] += wa * wb * t[1];
            }
        }
        out
    }

    /// Direction (tan_x, tan_y) the camera sees screen position (u, v) at.
    pub fn direction(&self, u: f64, v: f64) -> [f64; 2] {
        self.eval(u, v, false, false)
    }

    /// ∂(tan_x, tan_y)/∂(u, v) at (u, v): `[[∂tx/∂u, ∂tx/∂v], [∂ty/∂u, ∂ty/∂v]]`.
    pub fn jacobian(&self, u: f64, v: f64) -> [[f64; 2]; 2] {
        let du = self.eval(u, v, true, false);
        let dv = self.eval(u, v, false, true);
        [[du[0], dv[0]], [du[1], dv[1]]]
    }
}

fn line_error(path: &Path, line: usize, msg: String) -> Error {
    Error::parse(path, format!("line {line}: {msg}"))
}

/// One row of a geometry file: screen pixel (u, v), tangent direction.
struct Node {
    values: [f64; 4],
    line: usize,
}

impl Node {
    fn tan(&self) -> [f64; 2] {
        [self.values[2], self.values[3]]
    }
}

/// Which cell holds each of [`GEOMETRY_COLUMNS`], from the header row.
fn column_order(header: &crate::infile::csv_table::Row, path: &Path) -> Result<[usize; 4]> {
    let hl = header.line;
    let mut col = [usize::MAX; 4];
    for (i, name) in header.cells.iter().enumerate() {
        let Some(k) = GEOMETRY_COLUMNS.iter().position(|c| *c == name) else {
            return Err(line_error(
                path,
                hl,
                format!(
                    "unknown column `{}` (columns: u_px, v_px, tan_x, tan_y)",
                    crate::error::abbreviate(name, 40)
                ),
            ));
        };
        if col[k] != usize::MAX {
            return Err(line_error(
                path,
                hl,
                format!("column `{name}` appears twice"),
            ));
        }
        col[k] = i;
    }
    if let Some(k) = col.iter().position(|&c| c == usize::MAX) {
        return Err(line_error(
            path,
            hl,
            format!("missing column `{}` in the header", GEOMETRY_COLUMNS[k]),
        ));
    }
    Ok(col)
}

/// The file's rows: a header naming the columns, then finite numbers.
fn read_nodes(bytes: &[u8], path: &Path) -> Result<Vec<Node>> {
    let mut rows = crate::infile::csv_table::rows(path, bytes, b',');
    let header = rows.next().transpose()?.ok_or_else(|| {
        Error::parse(
            path,
            "empty file: expected a header naming u_px, v_px, tan_x, tan_y",
        )
    })?;
    let col = column_order(&header, path)?;
    let mut nodes = Vec::new();
    for row in rows {
        let row = row?;
        let ln = row.line;
        if row.cells.len() != header.cells.len() {
            return Err(line_error(
                path,
                ln,
                format!(
                    "expected {} fields, found {}",
                    header.cells.len(),
                    row.cells.len()
                ),
            ));
        }
        let mut values = [0.0f64; 4];
        for (k, v) in values.iter_mut().enumerate() {
            let s = &row.cells[col[k]];
            let what = GEOMETRY_COLUMNS[k];
            let shown = crate::error::abbreviate(s, 40);
            *v = s
                .parse()
                .map_err(|_| line_error(path, ln, format!("{what}: not a number: `{shown}`")))?;
            if !v.is_finite() {
                return Err(line_error(
                    path,
                    ln,
                    format!("{what}: non-finite value `{shown}`"),
                ));
            }
        }
        nodes.push(Node { values, line: ln });
    }
    Ok(nodes)
}

/// The nodes as a rectangular lattice: its distinct u and v values and,
/// row-major (v outer), the node at each.
struct Lattice {
    us: Vec<f64>,
    vs: Vec<f64>,
    order: Vec<usize>,
}

impl Lattice {
    /// Every (u, v) pair exactly once, at least 2 × 2, covering the screen.
    fn arrange(nodes: &[Node], path: &Path, screen: (usize, usize)) -> Result<Lattice> {
        let distinct = |k: usize| {
            let mut xs: Vec<f64> = nodes.iter().map(|n| n.values[k]).collect();
            xs.sort_by(f64::total_cmp);
            xs.dedup();
            xs
        };
        let (us, vs) = (distinct(0), distinct(1));
        if us.len() < 2 || vs.len() < 2 {
            return Err(Error::parse(
                path,
                format!(
                    "need a lattice of at least 2 × 2 nodes, found {} u_px and {} v_px values",
                    us.len(),
                    vs.len()
                ),
            ));
        }
        let (nu, nv) = (us.len(), vs.len());
        let mut slot: Vec<Option<usize>> = vec![None; nu * nv];
        for (idx, n) in nodes.iter().enumerate() {
            let iu = us.partition_point(|&x| x < n.values[0]);
            let iv = vs.partition_point(|&x| x < n.values[1]);
            if let Some(prev) = slot[iv * nu + iu] {
                return Err(line_error(
                    path,
                    n.line,
                    format!(
                        "node ({}, {}) repeats line {}",
                        n.values[0], n.values[1], nodes[prev].line
                    ),
                ));
            }
            slot[iv * nu + iu] = Some(idx);
        }
        if let Some(k) = slot.iter().position(Option::is_none) {
            return Err(Error::parse(
                path,
                format!(
                    "not a rectangular lattice: node (u_px {}, v_px {}) is missing \
                     ({} rows for {nu} u_px × {nv} v_px values)",
                    us[k % nu],
                    vs[k / nu],
                    nodes.len()
                ),
            ));
        }
        let (w, h) = (screen.0 as f64, screen.1 as f64);
        for (name, xs, size) in [("u_px", &us, w), ("v_px", &vs, h)] {
            if xs[0] > 0.0 || xs[xs.len() - 1] < size {
                return Err(Error::parse(
                    path,
                    format!(
                        "column {name}: nodes span [{}, {}] but must cover the screen [0, {size}]",
                        xs[0],
                        xs[xs.len() - 1]
                    ),
                ));
            }
        }
        let order = slot.into_iter().map(Option::unwrap).collect();
        Ok(Lattice { us, vs, order })
    }

    /// No folding at the nodes: every lattice cell keeps one orientation
    /// at its four corners. Returns that orientation (±1).
    fn check_cells(&self, nodes: &[Node], path: &Path) -> Result<f64> {
        let (us, vs) = (&self.us, &self.vs);
        let (nu, nv) = (us.len(), vs.len());
        let node = |iu: usize, iv: usize| &nodes[self.order[iv * nu + iu]];
        let p = |(iu, iv): (usize, usize)| node(iu, iv).tan();
        let cross = |o: [f64; 2], a: [f64; 2], b: [f64; 2]| {
            (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
        };
        let sign = cross(p((0, 0)), p((1, 0)), p((0, 1))).signum();
        for iv in 0..nv - 1 {
            for iu in 0..nu - 1 {
                // Corner, its neighbour along u, its neighbour along v;
                // the orientation of (along u, along v) at each corner.
                let corners = [
                    ((iu, iv), (iu + 1, iv), (iu, iv + 1), 1.0),
                    ((iu + 1, iv), (iu, iv), (iu + 1, iv + 1), -1.0),
                    ((iu, iv + 1), (iu + 1, iv + 1), (iu, iv), -1.0),
                    ((iu + 1, iv + 1), (iu, iv + 1), (iu + 1, iv), 1.0),
                ];
                for (o, a, b, s) in corners {
                    if !(s * cross(p(o), p(a), p(b)) * sign > 0.0) {
                        return Err(line_error(
                            path,
                            node(o.0, o.1).line,
                            format!(
                                "the map folds at node ({}, {}): the lattice cell [{}, {}] × [{}, {}] \
                                 is flipped or degenerate there (a calibration must map the screen one-to-one)",
                                us[o.0], vs[o.1], us[iu], us[iu + 1], vs[iv], vs[iv + 1]
                            ),
                        ));
                    }
                }
            }
        }
        Ok(sign)
    }
}

fn smallest_singular_value(j: [[f64; 2]; 2]) -> f64 {
    // Closed form without the cancellation of the eigenvalue route, so a
    // similarity (rotation and scale) gives its scale to rounding.
    let [[a, b], [c, d]] = j;
    0.5 * ((a + d).hypot(c - b) - (a - d).hypot(b + c)).abs()
}

/// Bilinear tap of one screen pixel into the ideal grid.
#[derive(Debug, Clone, Copy)]
struct Tap {
    /// Index of the top-left ideal pixel of the 2×2 footprint.
    base: u32,
    wx: f32,
    wy: f32,
}

/// Screen bounding box `[x0, x1) × [y0, y1)` (empty when x0 ≥ x1).
#[derive(Debug, Clone, Copy)]
struct TileBox {
    x0: u32,
    y0: u32,
    x1: u32,
    y1: u32,
}

impl TileBox {
    const EMPTY: TileBox = TileBox {
        x0: u32::MAX,
        y0: u32::MAX,
        x1: 0,
        y1: 0,
    };

    fn add(&mut self, x: u32, y: u32) {
        self.x0 = self.x0.min(x);
        self.y0 = self.y0.min(y);
        self.x1 = self.x1.max(x + 1);
        self.y1 = self.y1.max(y + 1);
    }

    fn union(&mut self, o: &TileBox) {
        self.x0 = self.x0.min(o.x0);
        self.y0 = self.y0.min(o.y0);
        self.x1 = self.x1.max(o.x1);
        self.y1 = self.y1.max(o.y1);
    }
}

/// The static pre-warp: ideal grid, per-screen-pixel lookup, coarse inverse,
/// and the ideal radiance of the current frame.
pub struct PreWarp {
    screen: (usize, usize),
    ideal: Pinhole,
    taps: Vec<Tap>,
    tiles_x: usize,
    tiles: Vec<TileBox>,
    /// Ideal radiance, zero outside `dirty`.
    radiance: Vec<f32>,
    dirty: Option<Roi>,
}

/// Largest ideal grid the pre-warp may build, in multiples of the screen's
/// pixels: a smooth map needs about 1–2 (its scale varies by a few per
/// cent); a node moved off the smooth map makes the finest local scale,
/// and so the grid, explode (one moved node asked for 14 GB).
pub const MAX_IDEAL_GRID_RATIO: f64 = 16.0;

/// The ideal grid's size implied by the nodes' extent at the finest scale,
/// refused beyond [`MAX_IDEAL_GRID_RATIO`] screens.
fn check_ideal_grid(cal: &GeometryCalibration) -> std::result::Result<(), String> {
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for t in &cal.tan {
        for k in 0..2 {
            lo[k] = lo[k].min(t[k]);
            hi[k] = hi[k].max(t[k]);
        }
    }
    let f = cal.finest_scale;
    let ideal =
        ((hi[0] - lo[0]) * f + 2.0 * MARGIN as f64) * ((hi[1] - lo[1]) * f + 2.0 * MARGIN as f64);
    let screen = (cal.screen.0 * cal.screen.1) as f64;
    if ideal.is_finite() && ideal <= MAX_IDEAL_GRID_RATIO * screen {
        return Ok(());
    }
    Err(format!(
        "the map's finest local scale ({f:.4e} px per unit tangent) would need a pre-warp grid of \
         {:.1e} pixels, {:.0}× the screen (limit {MAX_IDEAL_GRID_RATIO}×): is a node far off the smooth map?",
        ideal,
        ideal / screen
    ))
}

impl PreWarp {
    /// Builds the ideal grid and the lookups (start-up cost: a few
    /// operations per screen pixel).
    pub fn new(cal: &GeometryCalibration) -> PreWarp {
        Self::with_block(cal, 1)
    }

    /// As [`new`](Self::new) with an ideal grid `block` times coarser than
    /// the screen's finest scale (`screen.render_block`).
    pub fn with_block(cal: &GeometryCalibration, block: usize) -> PreWarp {
        let (w, h) = cal.screen;
        // Per-column and per-row weights: the lattice is a tensor product.
        let cols: Vec<_> = (0..w)
            .map(|i| cal.u.weights(i as f64 + 0.5, false))
            .collect();
        let rows: Vec<_> = (0..h)
            .map(|j| cal.v.weights(j as f64 + 0.5, false))
            .collect();
        let nu = cal.u.nodes.len();
        let (ku, kv) = (nu.min(4), cal.v.nodes.len().min(4));
        let tan: Vec<[f64; 2]> = rows
            .par_iter()
            .flat_map_iter(|(sv, wv)| {
                // Collapse the row weights first: 4 v-nodes → one row of u-nodes.
                let mut line = vec![[0.0; 2]; nu];
                for (b, &wb) in wv.iter().enumerate().take(kv) {
                    for (l, t) in line
                        .iter_mut()
                        .zip(&cal.tan[(sv + b) * nu..(sv + b + 1) * nu])
                    {
                        l[0] += wb * t[0];
                        l[1] += wb * t[1];
                    }
                }
                cols.iter().map(move |(su, wu)| {
                    let mut out = [0.0; 2];
                    for (a, &wa) in wu.iter().enumerate().take(ku) {
                        out[0] += wa * line[su + a][0];
                        out[1] += wa * line[su + a][1];
                    }
                    out
                })
            })
            .collect();
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for t in &tan {
            for k in 0..2 {
                lo[k] = lo[k].min(t[k]);
                hi[k] = hi[k].max(t[k]);
            }
        }
        let f = cal.finest_scale / block.max(1) as f64;
        let m = MARGIN as f64;
        let ideal = Pinhole {
            width: ((hi[0] - lo[0]) * f).ceil() as usize + 2 * MARGIN,
            height: ((hi[1] - lo[1]) * f).ceil() as usize + 2 * MARGIN,
            fx: f,
            fy: f,
            cx: m - f * lo[0],
            cy: m - f * lo[1],
        };
        let wi = ideal.width;
        let taps: Vec<Tap> = tan
            .par_iter()
            .map(|t| {
                // Ideal pixel centres are at +0.5: index space is x − 0.5.
                let qx = f * t[0] + ideal.cx - 0.5;
                let qy = f * t[1] + ideal.cy - 0.5;
                let bx = (qx.floor().max(0.0) as usize).min(wi - 2);
                let by = (qy.floor().max(0.0) as usize).min(ideal.height - 2);
                Tap {
                    base: (by * wi + bx) as u32,
                    wx: (qx - bx as f64).clamp(0.0, 1.0) as f32,
                    wy: (qy - by as f64).clamp(0.0, 1.0) as f32,
                }
            })
            .collect();
        let tiles_x = wi.div_ceil(TILE);
        let tiles_y = ideal.height.div_ceil(TILE);
        let mut tiles = vec![TileBox::EMPTY; tiles_x * tiles_y];
        for (k, tap) in taps.iter().enumerate() {
            let (bx, by) = (tap.base as usize % wi, tap.base as usize / wi);
            let (x, y) = ((k % w) as u32, (k / w) as u32);
            for ty in [by / TILE, (by + 1) / TILE] {
                for tx in [bx / TILE, (bx + 1) / TILE] {
                    tiles[ty * tiles_x + tx].add(x, y);
                }
            }
        }
        let n = ideal.width * ideal.height;
        PreWarp {
            screen: (w, h),
            ideal,
            taps,
            tiles_x,
            tiles,
            radiance: vec![0.0; n],
            dirty: None,
        }
    }

    /// The ideal pinhole grid to render on (camera attitude unchanged).
    pub fn ideal_pinhole(&self) -> &Pinhole {
        &self.ideal
    }

    /// Continuous ideal-grid coordinates the centre of screen pixel (i, j)
    /// samples (from the lookup table).
    pub fn ideal_position(&self, i: usize, j: usize) -> (f64, f64) {
        let t = self.taps[j * self.screen.0 + i];
        let wi = self.ideal.width;
        let (bx, by) = (t.base as usize % wi, t.base as usize / wi);
        (bx as f64 + t.wx as f64 + 0.5, by as f64 + t.wy as f64 + 0.5)
    }

    /// Screen region whose pixels may sample the ideal region `ideal_roi`:
    /// every screen pixel with a non-zero result lies inside it.
    pub fn screen_roi(&self, ideal_roi: Roi) -> Option<Roi> {
        if ideal_roi.area() == 0 {
            return None;
        }
        let tx0 = ideal_roi.x / TILE;
        let ty0 = ideal_roi.y / TILE;
        let tiles_y = self.tiles.len() / self.tiles_x;
        let tx1 = ((ideal_roi.x + ideal_roi.width - 1) / TILE).min(self.tiles_x - 1);
        let ty1 = ((ideal_roi.y + ideal_roi.height - 1) / TILE).min(tiles_y - 1);
        let mut b = TileBox::EMPTY;
        for ty in ty0..=ty1 {
            for tx in tx0..=tx1 {
                b.union(&self.tiles[ty * self.tiles_x + tx]);
            }
        }
        (b.x0 < b.x1 && b.y0 < b.y1).then(|| {
            Roi::new(
                b.x0 as usize,
                b.y0 as usize,
                (b.x1 - b.x0) as usize,
                (b.y1 - b.y0) as usize,
            )
        })
    }

    /// Takes the ideal radiance of `ideal_roi` (row-major over it, zero
    /// elsewhere), resamples it onto the screen into `out` (row-major over
    /// the returned screen ROI). None when no screen pixel sees it.
    pub fn apply(
        &mut self,
        ideal_roi: Roi,
        ideal_radiance: &[f32],
        out: &mut Vec<f32>,
    ) -> Option<Roi> {
        let wi = self.ideal.width;
        if let Some(d) = self.dirty.take() {
            for row in d.y..d.y + d.height {
                self.radiance[row * wi + d.x..row * wi + d.x + d.width].fill(0.0);
            }
        }
        if ideal_roi.area() == 0 {
            return None;
        }
        assert!(
            ideal_roi.fits(wi, self.ideal.height) && ideal_radiance.len() == ideal_roi.area(),
            "ideal ROI outside the ideal grid"
        );
        for (r, src) in ideal_radiance.chunks_exact(ideal_roi.width).enumerate() {
            let k = (ideal_roi.y + r) * wi + ideal_roi.x;
            self.radiance[k..k + ideal_roi.width].copy_from_slice(src);
        }
        self.dirty = Some(ideal_roi);
        let roi = self.screen_roi(ideal_roi)?;
        out.clear();
        out.resize(roi.area(), 0.0);
        let (taps, rad, sw) = (&self.taps, &self.radiance, self.screen.0);
        out.par_chunks_mut(roi.width)
            .enumerate()
            .for_each(|(r, row)| {
                let k = (roi.y + r) * sw + roi.x;
                for (o, t) in row.iter_mut().zip(&taps[k..k + roi.width]) {
                    let b = t.base as usize;
                    let (a, c) = (rad[b], rad[b + 1]);
                    let (d, e) = (rad[b + wi], rad[b + wi + 1]);
                    let top = a + t.wx * (c - a);
                    let bottom = d + t.wx * (e - d);
                    *o = top + t.wy * (bottom - top);
                }
            });
        Some(roi)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Lattice CSV of `f(u, v)` on nodes `us × vs`.
    fn csv(us: &[f64], vs: &[f64], f: impl Fn(f64, f64) -> [f64; 2]) -> String {
        let mut s = String::from("u_px,v_px,tan_x,tan_y\n");
        for &v in vs {
            for &u in us {
                let t = f(u, v);
                s.push_str(&format!("{u},{v},{:e},{:e}\n", t[0], t[1]));
            }
        }
        s
    }

    fn nodes(step: f64, end: f64) -> Vec<f64> {
        let mut xs: Vec<f64> = (0..)
            .map(|k| k as f64 * step)
            .take_while(|&x| x < end)
            .collect();
        xs.push(end);
        xs
    }

    #[test]
    fn reproduces_quadratics_on_a_non_uniform_lattice() {
        let f = |u: f64, v: f64| {
            [
                1e-3 * u - 2e-4 * v + 3e-7 * u * u + 1e-7 * u * v - 2e-7 * v * v,
                5e-4 * v + 1e-4 * u + 2e-7 * v * v - 1e-7 * u * v,
            ]
        };
        let us = [0.0, 7.0, 20.0, 31.0, 50.0, 64.0];
        let vs = [0.0, 10.0, 13.0, 40.0, 48.0];
        let g = GeometryCalibration::from_csv_bytes(csv(&us, &vs, f).as_bytes(), "q.csv", (64, 48))
            .unwrap();
        for (u, v) in [
            (0.0, 0.0),
            (3.3, 47.9),
            (63.5, 12.1),
            (25.0, 25.0),
            (64.0, 48.0),
        ] {
            let (a, b) = (g.direction(u, v), f(u, v));
            assert!(
                (a[0] - b[0]).abs() < 1e-15 && (a[1] - b[1]).abs() < 1e-15,
                "{u},{v}"
            );
            // Derivatives of the quadratic, by hand.
            let j = g.jacobian(u, v);
            let dtx_du = 1e-3 + 6e-7 * u + 1e-7 * v;
            let dty_dv = 5e-4 + 4e-7 * v - 1e-7 * u;
            assert!((j[0][0] - dtx_du).abs() < 1e-14 && (j[1][1] - dty_dv).abs() < 1e-14);
        }
    }

    #[test]
    fn two_node_axes_are_linear() {
        let f = |u: f64, v: f64| [2e-3 * (u - 5.0), 2e-3 * (v - 4.0)];
        let g = GeometryCalibration::from_csv_bytes(
            csv(&[0.0, 10.0], &[0.0, 8.0], f).as_bytes(),
            "l.csv",
            (10, 8),
        )
        .unwrap();
        let t = g.direction(7.25, 1.5);
        assert!((t[0] - 4.5e-3).abs() < 1e-15 && (t[1] + 5e-3).abs() < 1e-15);
        assert!((g.finest_scale() - 500.0).abs() < 1e-9);
    }

    /// The example's model (tools/make_geometry.py): Brown–Conrady k1 on the
    /// rotated, offset pinhole.
    fn example(u: f64, v: f64) -> [f64; 2] {
        let f = 3.0 / 2.768e-4;
        let (k1, rot, dx, dy) = (0.4, 0.002f64, 3.2, -2.1);
        let (x, y) = ((u - 960.0 - dx) / f, (v - 540.0 - dy) / f);
        let (c, s) = (rot.cos(), rot.sin());
        let (x, y) = (c * x - s * y, s * x + c * y);
        let r2 = x * x + y * y;
        [x * (1.0 + k1 * r2), y * (1.0 + k1 * r2)]
    }

    #[test]
    fn interpolation_error_of_example_distortion() {
        let g = GeometryCalibration::from_csv_bytes(
            csv(&nodes(32.0, 1920.0), &nodes(32.0, 1080.0), example).as_bytes(),
            "e.csv",
            (1920, 1080),
        )
        .unwrap();
        let f = 3.0 / 2.768e-4;
        let (mut worst, mut inner): (f64, f64) = (0.0, 0.0);
        for j in 0..108 {
            for i in 0..192 {
                let (u, v) = (i as f64 * 10.0 + 3.7, j as f64 * 10.0 + 1.3);
                let (a, b) = (g.direction(u, v), example(u, v));
                let e = (a[0] - b[0]).hypot(a[1] - b[1]) * f;
                worst = worst.max(e);
                if u > 32.0 && u < 1888.0 && v > 32.0 && v < 1056.0 {
                    inner = inner.max(e);
                }
            }
        }
        // Largest in the outer cells, whose end slopes are one-sided.
        assert!(worst < 1e-4, "interpolation error {worst} px");
        assert!(inner < 2e-5, "interpolation error {inner} px inside");
        assert!(inner > 0.0);
    }

    #[test]
    fn detects_folds_between_and_at_nodes() {
        let f = |u: f64, v: f64| [u * 1e-3, v * 1e-3];
        let us = nodes(10.0, 40.0);
        let vs = nodes(10.0, 30.0);
        // Swap two nodes' directions: the cells around them flip.
        let mut text = csv(&us, &vs, f);
        text = text.replace("10,10,1e-2,1e-2", "10,10,2.1e-2,1e-2");
        let e = GeometryCalibration::from_csv_bytes(text.as_bytes(), "fold.csv", (40, 30))
            .unwrap_err()
            .to_string();
        assert!(e.contains("fold.csv") && e.contains("folds"), "{e}");
        // A mirrored map (consistent orientation) is fine.
        let m = |u: f64, v: f64| [-u * 1e-3, v * 1e-3];
        GeometryCalibration::from_csv_bytes(csv(&us, &vs, m).as_bytes(), "m.csv", (40, 30))
            .unwrap();
    }

    #[test]
    fn lookup_matches_the_interpolated_map() {
        let (w, h) = (70, 50);
        let f = |u: f64, v: f64| {
            let (x, y) = ((u - 30.0) / 60.0, (v - 27.0) / 60.0);
            let g = 1.0 + 0.2 * (x * x + y * y);
            [x * g + 0.01 * y, y * g]
        };
        let g = GeometryCalibration::from_csv_bytes(
            csv(&nodes(9.0, 70.0), &nodes(11.0, 50.0), f).as_bytes(),
            "d.csv",
            (w, h),
        )
        .unwrap();
        let warp = PreWarp::new(&g);
        let p = warp.ideal_pinhole();
        for j in 0..h {
            for i in 0..w {
                let t = g.direction(i as f64 + 0.5, j as f64 + 0.5);
                let (x, y) = warp.ideal_position(i, j);
                let (ex, ey) = (p.fx * t[0] + p.cx, p.fy * t[1] + p.cy);
                assert!((x - ex).abs() < 1e-4 && (y - ey).abs() < 1e-4, "({i},{j})");
                assert!(
                    x > 1.0 && y > 1.0 && x < p.width as f64 - 1.0 && y < p.height as f64 - 1.0
                );
            }
        }
    }

    #[test]
    fn bilinear_resampling_is_exact_for_linear_radiance() {
        // Screen = ideal pinhole shifted by a fraction of a pixel and
        // rotated: a linear ideal radiance must come back exactly.
        let (w, h) = (48, 32);
        let fpx = 400.0;
        let rot: f64 = 0.3;
        let (c, s) = (rot.cos(), rot.sin());
        let f = move |u: f64, v: f64| {
            let (x, y) = ((u - 24.3) / fpx, (v - 15.8) / fpx);
            [c * x - s * y, s * x + c * y]
        };
        let g = GeometryCalibration::from_csv_bytes(
            csv(&nodes(8.0, 48.0), &nodes(8.0, 32.0), f).as_bytes(),
            "r.csv",
            (w, h),
        )
        .unwrap();
        let mut warp = PreWarp::new(&g);
        let ideal = warp.ideal_pinhole().clone();
        assert!((ideal.fx - fpx).abs() < 1e-6);
        let lin = |x: f64, y: f64| (1.0 + 0.01 * x + 0.02 * y) as f32;
        let roi = Roi::full(ideal.width, ideal.height);
        let img: Vec<f32> = (0..roi.area())
            .map(|k| lin((k % roi.width) as f64 + 0.5, (k / roi.width) as f64 + 0.5))
            .collect();
        let mut out = Vec::new();
        let sroi = warp.apply(roi, &img, &mut out).unwrap();
        assert_eq!((sroi.width, sroi.height), (w, h));
        for j in 0..h {
            for i in 0..w {
                let t = f(i as f64 + 0.5, j as f64 + 0.5);
                let (x, y) = (ideal.fx * t[0] + ideal.cx, ideal.fy * t[1] + ideal.cy);
                let got = out[j * w + i];
                assert!(
                    (got - lin(x, y)).abs() < 2e-5,
                    "({i},{j}): {got} vs {}",
                    lin(x, y)
                );
            }
        }
        // A small ideal ROI maps to a small screen ROI containing every
        // pixel that samples it, and stale radiance is cleared.
        let small = Roi::new(20, 20, 4, 4);
        let sroi = warp.apply(small, &[1.0; 16], &mut out).unwrap();
        assert!(sroi.area() < w * h / 2, "{sroi:?}");
        for j in 0..h {
            for i in 0..w {
                let (x, y) = warp.ideal_position(i, j);
                let touches = x + 0.5 > 20.0 && x - 0.5 < 24.0 && y + 0.5 > 20.0 && y - 0.5 < 24.0;
                if touches {
                    assert!(
                        sroi.contains(i, j),
                        "({i},{j}) at ({x},{y}) outside {sroi:?}"
                    );
                }
                let v = if sroi.contains(i, j) {
                    out[(j - sroi.y) * sroi.width + i - sroi.x]
                } else {
                    0.0
                };
                if !touches {
                    assert_eq!(v, 0.0, "({i},{j})");
                }
            }
        }
    }
}
