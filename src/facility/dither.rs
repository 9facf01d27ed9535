//! Conversion of a rendered radiance image into integer screen drive levels:
//! facility scaling, collimator and flat-field compensation, and
//! deterministic ordered dithering so that the mean radiance over a few
//! pixels is right even below one drive-level step.
//!
//! # Per pixel
//!
//! 1. `L_screen = target × k ÷ τ ÷ g(x, y)`: `target` is the radiance the
//!    camera must see (W m⁻² sr⁻¹, in its band), `k` the facility scale factor
//!    (e.g. flight exposure ÷ facility exposure), `τ` the collimator
//!    transmission and `g` the flat-field gain of that screen pixel.
//! 2. If `black ≤ L_screen < max`, find `k` with `L_k ≤ L_screen < L_{k+1}`
//!    (radiances of integer levels from the [`DisplayLut`]) and emit `k+1`
//!    when `p = (L_screen − L_k)/(L_{k+1} − L_k)` exceeds the threshold of the
//!    pixel, else `k`. Thresholds `(rank + ½)/N²` come from an N×N
//!    [`ThresholdMatrix`] tiled over the screen, so over any N×N window every
//!    threshold occurs once and the mean emitted radiance equals the mean
//!    target up to `1/N²` of a step.
//! 3. `L_screen ≥ max` → top level, counted in `clipped_high` if `> max`.
//!    `0 < L_screen < black` or `L_screen < 0` → level 0, counted in
//!    `clipped_low`. An exact `0` (empty sky) → level 0, not counted as
//!    clipped: the screen's black is the best it can do and sky is expected
//!    there. NaN/inf → level 0, counted in `non_finite`.
//!
//! # Tile correction
//!
//! Plain ordered dithering is exact only where `p` is constant over the
//! matrix: on a gradient the Bayer columns' uneven threshold sets leave
//! errors of several pixel-steps in an 8×8 block (up to ≈ 6.6 steps at a
//! slope of 0.06 level/pixel), which at the dark end of a gamma display,
//! where one step is ~15 % of the radiance, is far more than 0.2 %. So by
//! default (`block = 8`) the screen is cut into 8×8 tiles aligned to the
//! screen grid; in each tile (∩ ROI) the pixels between two levels are ranked
//! by `p − threshold` (descending; equal values by position in the tile, row
//! first, then column) and exactly the `n` best-ranked are raised to `k+1`,
//! `n` chosen so the tile's emitted radiance is closest to its target
//! (error ≤ ½ of the largest step in the tile, i.e. ≤ 1/128 of a step per
//! pixel). Where `p` is uniform this selects the same pixels as the ordered
//! dither. Tiles are independent, so the work stays parallel and local.
//!
//! With `temporal` on, the threshold matrix is shifted by an offset derived
//! from `(seed, frame id)` so that dithering patterns differ between frames
//! (still fully reproducible from the frame id).
//!
//! # Region of interest
//!
//! Only the ROI (the body's bounding box on the screen) is written, plus the
//! previous call's ROI, which is cleared to black first. Cost therefore
//! scales with the body's pixels, not the screen's. This relies on the same
//! frame buffer being passed on every call and on it starting black; after
//! drawing anything else into it call [`Converter::clear_all`] (or
//! [`Converter::forget_previous_roi`] if you cleared it yourself).

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

use super::lut::{DisplayLut, FlatField};

/// Which threshold matrix to dither with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum DitherKind {
    /// 16×16 recursive Bayer matrix.
    #[default]
    Bayer,
    /// 64×64 blue-noise mask built by void-and-cluster from the seed.
    BlueNoise,
}

/// An N×N (N a power of two) matrix of thresholds `(rank + ½)/N²`, each rank
/// `0 … N²−1` occurring once.
#[derive(Debug, Clone)]
pub struct ThresholdMatrix {
    size: usize,
    thresholds: Vec<f32>,
}

impl ThresholdMatrix {
    /// Recursive Bayer index matrix of `size` (2, 4, … 256):
    /// `M₂ₙ = [[4Mₙ, 4Mₙ+2], [4Mₙ+3, 4Mₙ+1]]`.
    pub fn bayer(size: usize) -> Result<ThresholdMatrix> {
        if !size.is_power_of_two() || !(2..=256).contains(&size) {
            return Err(Error::invalid(
                "dither.size",
                format!("Bayer size must be a power of two in 2..=256, found {size}"),
            ));
        }
        let mut m = vec![0u32];
        let mut n = 1;
        while n < size {
            let mut next = vec![0u32; 4 * n * n];
            for y in 0..n {
                for x in 0..n {
                    let v = 4 * m[y * n + x];
                    next[y * 2 * n + x] = v;
                    next[y * 2 * n + x + n] = v + 2;
                    next[(y + n) * 2 * n + x] = v + 3;
                    next[(y + n) * 2 * n + x + n] = v + 1;
                }
            }
            m = next;
            n *= 2;
        }
        Ok(ThresholdMatrix::from_ranks(size, &m))
    }

    /// Blue-noise mask of `size` (power of two, 4…128) by Ulichney's
    /// void-and-cluster method (Gaussian σ = 1.5 px, toroidal), initial
    /// pattern drawn from `seed`. Deterministic.
    pub fn blue_noise(size: usize, seed: u64) -> Result<ThresholdMatrix> {
        if !size.is_power_of_two() || !(4..=128).contains(&size) {
            return Err(Error::invalid(
                "dither.size",
                format!("blue-noise size must be a power of two in 4..=128, found {size}"),
            ));
        }
        Ok(ThresholdMatrix::from_ranks(
            size,
            &void_and_cluster(size, seed),
        ))
    }

    /// Matrix for a [`DitherKind`] with its default size.
    pub fn for_kind(kind: DitherKind, seed: u64) -> Result<ThresholdMatrix> {
        match kind {
            DitherKind::Bayer => ThresholdMatrix::bayer(16),
            DitherKind::BlueNoise => ThresholdMatrix::blue_noise(64, seed),
        }
    }

    fn from_ranks(size: usize, ranks: &[u32]) -> ThresholdMatrix {
        let n2 = (size * size) as f32;
        ThresholdMatrix {
            size,
            thresholds: ranks.iter().map(|&r| (r as f32 + 0.5) / n2).collect(),
        }
    }

    /// Side length N.
    pub fn size(&self) -> usize {
        self.size
    }

    /// Threshold at `(x, y)` of the tiled matrix.
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> f32 {
        let m = self.size - 1;
        self.thresholds[(y & m) * self.size + (x & m)]
    }

    /// Rank (0 … N²−1) at `(x, y)`, i.e. `threshold × N² − ½`.
    pub fn rank(&self, x: usize, y: usize) -> u32 {
        (self.get(x, y) * (self.size * self.size) as f32 - 0.5).round() as u32
    }
}

/// SplitMix64 step (deterministic, no dependency).
fn splitmix64(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Void-and-cluster ranks (Ulichney 1993) on a `size`² torus.
fn void_and_cluster(size: usize, seed: u64) -> Vec<u32> {
    let n = size * size;
    let sigma2 = 2.0 * 1.5f64 * 1.5;
    let mut kernel = vec![0.0f64; n];
    for dy in 0..size {
        for dx in 0..size {
            let ddx = dx.min(size - dx) as f64;
            let ddy = dy.min(size - dy) as f64;
            kernel[dy * size + dx] = (-(ddx * ddx + ddy * ddy) / sigma2).exp();
        }
    }
    let mask = size - 1;
    let update = |energy: &mut [f64], p: usize, sign: f64| {
        let (px, py) = (p % size, p / size);
        for qy in 0..size {
            let ky = ((qy + size - py) & mask) * size;
            for qx in 0..size {
                energy[qy * size + qx] += sign * kernel[ky + ((qx + size - px) & mask)];
            }
        }
    };
    let argmax_ones = |e: &[f64], bits: &[bool]| {
        (0..n)
            .filter(|&i| bits[i])
            .max_by(|&a, &b| e[a].total_cmp(&e[b]))
            .expect("at least one minority pixel")
    };
    let argmin_zeros = |e: &[f64], bits: &[bool]| {
        (0..n)
            .filter(|&i| !bits[i])
            .min_by(|&a, &b| e[a].total_cmp(&e[b]))
            .expect("at least one majority pixel")
    };

    // Initial random pattern with n/10 minority pixels.
    let mut rng = seed ^ 0x6F70_7469_7374_696D;
    let mut bits = vec![false; n];
    let mut energy = vec![0.0f64; n];
    let ones = (n / 10).max(1);
    let mut placed = 0;
    while placed < ones {
        let i = (splitmix64(&mut rng) % n as u64) as usize;
        if !bits[i] {
            bits[i] = true;
            update(&mut energy, i, 1.0);
            placed += 1;
        }
    }
    // Relax: move the tightest cluster into the largest void until stable.
    for _ in 0..(4 * n) {
        let c = argmax_ones(&energy, &bits);
        bits[c] = false;
        update(&mut energy, c, -1.0);
        let v = argmin_zeros(&energy, &bits);
        bits[v] = true;
        update(&mut energy, v, 1.0);
        if v == c {
            break;
        }
    }
    let mut rank = vec![0u32; n];
    // Phase 1: remove clusters from a copy, ranks ones-1 … 0.
    let (mut b1, mut e1) = (bits.clone(), energy.clone());
    for r in (0..ones).rev() {
        let c = argmax_ones(&e1, &b1);
        b1[c] = false;
        update(&mut e1, c, -1.0);
        rank[c] = r as u32;
    }
    // Phase 2/3: fill voids, ranks ones … n-1. (The tightest cluster of
    // zeros is the void of ones, so one rule covers both halves.)
    for r in ones..n {
        let v = argmin_zeros(&energy, &bits);
        bits[v] = true;
        update(&mut energy, v, 1.0);
        rank[v] = r as u32;
    }
    rank
}

/// A rectangle of screen pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Roi {
    /// Left column.
    pub x: usize,
    /// Top row.
    pub y: usize,
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
}

impl Roi {
    /// New rectangle.
    pub fn new(x: usize, y: usize, width: usize, height: usize) -> Roi {
        Roi {
            x,
            y,
            width,
            height,
        }
    }

    /// The whole screen.
    pub fn full(width: usize, height: usize) -> Roi {
        Roi::new(0, 0, width, height)
    }

    /// Number of pixels.
    pub fn area(&self) -> usize {
        self.width * self.height
    }

    /// True if no pixels.
    pub fn is_empty(&self) -> bool {
        self.area() == 0
    }

    /// True if `(x, y)` lies inside.
    pub fn contains(&self, x: usize, y: usize) -> bool {
        x >= self.x && y >= self.y && x < self.x + self.width && y < self.y + self.height
    }

    /// True if the rectangle lies inside a `width × height` screen.
    pub fn fits(&self, width: usize, height: usize) -> bool {
        self.x.checked_add(self.width).is_some_and(|r| r <= width)
            && self.y.checked_add(self.height).is_some_and(|b| b <= height)
    }
}

/// Fixed conversion parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ConvertSettings {
    /// Collimator transmission τ, in (0, 1].
    pub transmission: f64,
    /// Facility scale factor k, > 0.
    pub scale_k: f64,
    /// Shift the threshold matrix per frame.
    pub temporal: bool,
    /// Seed of the temporal offsets (and of the blue-noise mask).
    pub seed: u64,
    /// Side of the error-correcting tiles (see the module docs); 0 or 1
    /// gives plain ordered dithering.
    pub block: usize,
}

impl Default for ConvertSettings {
    fn default() -> Self {
        ConvertSettings {
            transmission: 1.0,
            scale_k: 1.0,
            temporal: false,
            seed: 0,
            block: 8,
        }
    }
}

/// What happened in one conversion.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct ConvertStats {
    /// Pixels converted (ROI area).
    pub pixels: u64,
    /// Pixels whose required screen radiance exceeded the screen maximum.
    pub clipped_high: u64,
    /// Pixels with required screen radiance negative or in (0, black).
    pub clipped_low: u64,
    /// NaN or infinite targets (emitted black).
    pub non_finite: u64,
    /// Largest finite target radiance (camera side), W m⁻² sr⁻¹.
    pub peak_target: f64,
    /// Largest required screen radiance `target·k/τ/g`, W m⁻² sr⁻¹.
    pub peak_screen: f64,
}

impl ConvertStats {
    /// All clipped pixels.
    pub fn clipped(&self) -> u64 {
        self.clipped_high + self.clipped_low
    }

    fn merge(mut self, o: ConvertStats) -> ConvertStats {
        self.pixels += o.pixels;
        self.clipped_high += o.clipped_high;
        self.clipped_low += o.clipped_low;
        self.non_finite += o.non_finite;
        self.peak_target = self.peak_target.max(o.peak_target);
        self.peak_screen = self.peak_screen.max(o.peak_screen);
        self
    }
}

/// Converts radiance images into frame buffers for one screen.
#[derive(Debug, Clone)]
pub struct Converter {
    lut: DisplayLut,
    flat: Option<FlatField>,
    matrix: ThresholdMatrix,
    settings: ConvertSettings,
    width: usize,
    height: usize,
    prev_roi: Option<Roi>,
}

impl Converter {
    /// New converter for a `screen = (width, height)` display.
    pub fn new(
        lut: DisplayLut,
        flat: Option<FlatField>,
        matrix: ThresholdMatrix,
        settings: ConvertSettings,
        screen: (usize, usize),
    ) -> Result<Converter> {
        let t = settings.transmission;
        if !(t.is_finite() && t > 0.0 && t <= 1.0) {
            return Err(Error::invalid(
                "collimator.transmission",
                format!("must be in (0, 1], found {t}"),
            ));
        }
        let k = settings.scale_k;
        if !(k.is_finite() && k > 0.0) {
            return Err(Error::invalid(
                "drive.scale_k",
                format!("must be finite and > 0, found {k}"),
            ));
        }
        if screen.0 == 0 || screen.1 == 0 {
            return Err(Error::invalid("screen.resolution", "must be non-zero"));
        }
        if let Some(f) = &flat {
            if f.size() != screen {
                return Err(Error::invalid(
                    "calibration.flat_field",
                    format!("flat field is {:?} but the screen is {screen:?}", f.size()),
                ));
            }
        }
        Ok(Converter {
            lut,
            flat,
            matrix,
            settings,
            width: screen.0,
            height: screen.1,
            prev_roi: None,
        })
    }

    /// The display LUT.
    pub fn lut(&self) -> &DisplayLut {
        &self.lut
    }

    /// The settings.
    pub fn settings(&self) -> &ConvertSettings {
        &self.settings
    }

    /// Screen size.
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// ROI written by the previous conversion.
    pub fn previous_roi(&self) -> Option<Roi> {
        self.prev_roi
    }

    /// The frame-buffer pixel of drive level 0 (the screen's black).
    pub fn black_pixel(&self) -> u32 {
        self.lut.encode_pixel(0)
    }

    /// Forgets the previous ROI (the caller cleared it).
    pub fn forget_previous_roi(&mut self) {
        self.prev_roi = None;
    }

    /// Clears the whole frame to black (cost: the screen) and forgets the ROI.
    pub fn clear_all(&mut self, frame: &mut [u32]) {
        let black = self.lut.encode_pixel(0);
        frame.fill(black);
        self.prev_roi = None;
    }

    /// Threshold-matrix offset used for `frame_id`.
    pub fn dither_offset(&self, frame_id: u64) -> (usize, usize) {
        let mut s = self.settings.seed
            ^ if self.settings.temporal {
                frame_id.wrapping_mul(0xD1B5_4A32_D192_ED03)
            } else {
                0
            };
        let h = splitmix64(&mut s);
        let n = self.matrix.size() as u64;
        ((h % n) as usize, ((h >> 32) % n) as usize)
    }

    /// Converts `target` (camera-side radiance, row-major, exactly
    /// `roi.width × roi.height` values covering `roi`) into grey drive levels
    /// written into `frame` (`width × height`, row-major, see
    /// [`DisplayLut::encode_pixel`]). The previous ROI is cleared to black
    /// first; nothing else outside `roi` is touched.
    pub fn convert(
        &mut self,
        target: &[f32],
        roi: Roi,
        frame_id: u64,
        frame: &mut [u32],
    ) -> Result<ConvertStats> {
        let (w, h) = (self.width, self.height);
        if frame.len() != w * h {
            return Err(Error::invalid(
                "frame",
                format!("frame has {} pixels, screen is {w}×{h}", frame.len()),
            ));
        }
        if !roi.fits(w, h) {
            return Err(Error::invalid(
                "roi",
                format!("{roi:?} does not fit in the {w}×{h} screen"),
            ));
        }
        if target.len() != roi.area() {
            return Err(Error::invalid(
                "target",
                format!(
                    "{} values for a {}×{} ROI",
                    target.len(),
                    roi.width,
                    roi.height
                ),
            ));
        }
        let black_pixel = self.lut.encode_pixel(0);
        if let Some(prev) = self.prev_roi.take() {
            clear_outside(frame, w, prev, roi, black_pixel);
        }
        self.prev_roi = Some(roi);
        if roi.is_empty() {
            return Ok(ConvertStats::default());
        }
        let (ox, oy) = self.dither_offset(frame_id);
        let tile = self.settings.block.max(1);
        let ctx = PixelCtx {
            lut: &self.lut,
            flat: self.flat.as_ref(),
            matrix: &self.matrix,
            factor: self.settings.scale_k / self.settings.transmission,
            offset: (ox, oy),
        };
        // Split the ROI rows into bands aligned to the screen's tile grid.
        let mut bands: Vec<(usize, &mut [u32])> = Vec::new();
        let mut rest = &mut frame[roi.y * w..(roi.y + roi.height) * w];
        let mut y = roi.y;
        while y < roi.y + roi.height {
            let y1 = ((y / tile + 1) * tile).min(roi.y + roi.height);
            let (band, tail) = rest.split_at_mut((y1 - y) * w);
            bands.push((y, band));
            rest = tail;
            y = y1;
        }
        let stats = bands
            .into_par_iter()
            .map(|(y0, band)| {
                let mut st = ConvertStats::default();
                let mut cands: Vec<Candidate> = Vec::with_capacity(tile * tile);
                let x_end = roi.x + roi.width;
                let mut x0 = roi.x;
                while x0 < x_end {
                    let x1 = ((x0 / tile + 1) * tile).min(x_end);
                    cands.clear();
                    for (r, row) in band.chunks_mut(w).enumerate() {
                        let y = y0 + r;
                        let trow = &target[(y - roi.y) * roi.width..][..roi.width];
                        for x in x0..x1 {
                            row[x] = ctx.pixel(trow[x - roi.x], x, y, tile, &mut st, |c| {
                                cands.push(Candidate { r, ..c })
                            });
                        }
                    }
                    if tile > 1 && !cands.is_empty() {
                        exact_tile(&ctx, band, w, &mut cands);
                    }
                    x0 = x1;
                }
                st
            })
            .reduce(ConvertStats::default, ConvertStats::merge);
        Ok(stats)
    }
}

/// Blackens the pixels of `prev` that are outside `roi` (every pixel of
/// `roi` is written by the conversion anyway).
fn clear_outside(frame: &mut [u32], w: usize, prev: Roi, roi: Roi, black: u32) {
    let (prev_end, roi_end) = (prev.x + prev.width, roi.x + roi.width);
    for y in prev.y..prev.y + prev.height {
        let row = &mut frame[y * w..(y + 1) * w];
        if roi.width > 0 && y >= roi.y && y < roi.y + roi.height {
            if prev.x < roi.x {
                row[prev.x..prev_end.min(roi.x)].fill(black);
            }
            if prev_end > roi_end {
                row[prev.x.max(roi_end)..prev_end].fill(black);
            }
        } else {
            row[prev.x..prev_end].fill(black);
        }
    }
}

/// A pixel whose level is `k` or `k + 1`, waiting for the tile decision.
#[derive(Debug, Clone, Copy)]
struct Candidate {
    /// Row within the band.
    r: usize,
    x: usize,
    k: u32,
    p: f64,
    step: f64,
    /// p − threshold: who deserves the upper level most.
    key: f64,
}

/// Per-conversion constants.
struct PixelCtx<'a> {
    lut: &'a DisplayLut,
    flat: Option<&'a FlatField>,
    matrix: &'a ThresholdMatrix,
    factor: f64,
    offset: (usize, usize),
}

impl PixelCtx<'_> {
    /// Classifies one pixel, updates `st`, returns its pixel value; for a
    /// pixel between two levels with `tile > 1`, returns level `k` and hands
    /// a [`Candidate`] to `defer` instead of deciding.
    #[inline]
    fn pixel(
        &self,
        t: f32,
        x: usize,
        y: usize,
        tile: usize,
        st: &mut ConvertStats,
        mut defer: impl FnMut(Candidate),
    ) -> u32 {
        let lut = self.lut;
        st.pixels += 1;
        let t = t as f64;
        if !t.is_finite() {
            st.non_finite += 1;
            return lut.encode_pixel(0);
        }
        let gain = self.flat.map_or(1.0, |f| f.gain(x, y) as f64);
        let l = t * self.factor / gain;
        st.peak_target = st.peak_target.max(t);
        st.peak_screen = st.peak_screen.max(l);
        let level = if l == 0.0 {
            0
        } else if l < lut.black() {
            st.clipped_low += 1;
            0
        } else if l >= lut.max_radiance() {
            if l > lut.max_radiance() {
                st.clipped_high += 1;
            }
            lut.levels() - 1
        } else {
            match lut.bracket(l) {
                Some((k, p)) => {
                    let th = self.matrix.get(x + self.offset.0, y + self.offset.1) as f64;
                    if tile > 1 {
                        let lr = lut.level_radiances();
                        let step = lr[k as usize + 1] - lr[k as usize];
                        defer(Candidate {
                            r: 0,
                            x,
                            k,
                            p,
                            step,
                            key: p - th,
                        });
                        k
                    } else {
                        k + u32::from(p > th)
                    }
                }
                None => 0,
            }
        };
        lut.encode_pixel(level)
    }
}

/// Raises the `n` candidates with the largest `p − threshold` to `k + 1`,
/// with `n` chosen so that the tile's emitted radiance is closest to its
/// target: |error| ≤ half the largest step in the tile. Equal keys rank by
/// position (row, then column), so the result does not depend on the sort.
fn exact_tile(ctx: &PixelCtx<'_>, band: &mut [u32], w: usize, cands: &mut [Candidate]) {
    let excess: f64 = cands.iter().map(|c| c.p * c.step).sum();
    cands.sort_unstable_by(|a, b| b.key.total_cmp(&a.key).then((a.r, a.x).cmp(&(b.r, b.x))));
    let mut cum = 0.0;
    let mut n = cands.len();
    for (i, c) in cands.iter().enumerate() {
        if cum + c.step > excess {
            // Stop before i or include it, whichever lands closer.
            n = if (cum + c.step - excess) < (excess - cum) {
                i + 1
            } else {
                i
            };
            break;
        }
        cum += c.step;
    }
    for c in &cands[..n] {
        band[c.r * w + c.x] = ctx.lut.encode_pixel(c.k + 1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::facility::lut::decode_grey;

    fn linear_lut() -> DisplayLut {
        // L = 1 + level (black 1, max 256): every step is 1.
        DisplayLut::from_points(&[0.0, 255.0], &[1.0, 256.0], 8).unwrap()
    }

    #[test]
    #[allow(clippy::needless_range_loop)]
    fn bayer_matches_published_matrices() {
        // Bayer (1973) index matrices.
        let m2 = ThresholdMatrix::bayer(2).unwrap();
        let want2 = [[0, 2], [3, 1]];
        let m4 = ThresholdMatrix::bayer(4).unwrap();
        let want4 = [[0, 8, 2, 10], [12, 4, 14, 6], [3, 11, 1, 9], [15, 7, 13, 5]];
        for y in 0..2 {
            for x in 0..2 {
                assert_eq!(m2.rank(x, y), want2[y][x]);
            }
        }
        for y in 0..4 {
            for x in 0..4 {
                assert_eq!(m4.rank(x, y), want4[y][x]);
                assert_eq!(m4.get(x, y), (want4[y][x] as f32 + 0.5) / 16.0);
            }
        }
        assert!(ThresholdMatrix::bayer(12).is_err());
    }

    fn is_permutation(m: &ThresholdMatrix) -> bool {
        let n = m.size();
        let mut seen = vec![false; n * n];
        for y in 0..n {
            for x in 0..n {
                let r = m.rank(x, y) as usize;
                if r >= n * n || seen[r] {
                    return false;
                }
                seen[r] = true;
            }
        }
        true
    }

    #[test]
    fn blue_noise_is_a_deterministic_well_spread_permutation() {
        let a = ThresholdMatrix::blue_noise(32, 7).unwrap();
        let b = ThresholdMatrix::blue_noise(32, 7).unwrap();
        assert!(is_permutation(&a));
        assert!(is_permutation(&ThresholdMatrix::bayer(16).unwrap()));
        assert_eq!(a.thresholds, b.thresholds);
        assert_ne!(
            a.thresholds,
            ThresholdMatrix::blue_noise(32, 8).unwrap().thresholds
        );
        // Blue noise has little low-frequency power: at 25 % coverage every
        // aligned 8×8 block holds close to 16 dots. White noise would have a
        // standard deviation of √(64·¼·¾) ≈ 3.5 dots per block, so among 16
        // blocks several would deviate by more than 4.
        let n = a.size();
        let mut worst = 0i64;
        for by in 0..n / 8 {
            for bx in 0..n / 8 {
                let mut count = 0i64;
                for y in 0..8 {
                    for x in 0..8 {
                        count += i64::from(a.get(bx * 8 + x, by * 8 + y) < 0.25);
                    }
                }
                worst = worst.max((count - 16).abs());
            }
        }
        assert!(worst <= 3, "block count deviates by {worst}");
        // No two adjacent dots at 10 % coverage (a property of void-and-cluster).
        let mut adjacent = 0;
        for y in 0..n {
            for x in 0..n {
                if a.get(x, y) < 0.1 && (a.get(x + 1, y) < 0.1 || a.get(x, y + 1) < 0.1) {
                    adjacent += 1;
                }
            }
        }
        assert_eq!(adjacent, 0);
    }

    #[test]
    fn only_roi_and_previous_roi_are_touched() {
        let (w, h) = (40, 30);
        let mut c = Converter::new(
            linear_lut(),
            None,
            ThresholdMatrix::bayer(8).unwrap(),
            ConvertSettings::default(),
            (w, h),
        )
        .unwrap();
        let sentinel = 0x00AB_CDEF;
        let mut frame = vec![sentinel; w * h];
        let r1 = Roi::new(3, 4, 10, 5);
        c.convert(&vec![100.5; r1.area()], r1, 0, &mut frame)
            .unwrap();
        for y in 0..h {
            for x in 0..w {
                let v = frame[y * w + x];
                if r1.contains(x, y) {
                    let l = decode_grey(v, 8);
                    assert!(l == 99 || l == 100, "({x},{y}) level {l}");
                } else {
                    assert_eq!(v, sentinel);
                }
            }
        }
        let r2 = Roi::new(20, 10, 6, 6);
        c.convert(&vec![50.0; r2.area()], r2, 1, &mut frame)
            .unwrap();
        for y in 0..h {
            for x in 0..w {
                let v = frame[y * w + x];
                if r2.contains(x, y) {
                    assert_eq!(decode_grey(v, 8), 49); // exactly L_49 = 50
                } else if r1.contains(x, y) {
                    assert_eq!(v, 0, "previous ROI cleared to black");
                } else {
                    assert_eq!(v, sentinel);
                }
            }
        }
        // Bad inputs are errors, not panics.
        assert!(c
            .convert(&[1.0; 4], Roi::new(39, 0, 2, 2), 0, &mut frame)
            .is_err());
        assert!(c
            .convert(&[1.0; 3], Roi::new(0, 0, 2, 2), 0, &mut frame)
            .is_err());
        assert!(c
            .convert(&[1.0; 4], Roi::new(0, 0, 2, 2), 0, &mut frame[1..])
            .is_err());
    }

    #[test]
    fn scale_transmission_and_flat_field_are_applied() {
        let (w, h) = (4, 2);
        // gains 2 in the left half, 0.5 in the right half.
        let gains: Vec<f32> = (0..8).map(|i| if i % 4 < 2 { 2.0 } else { 0.5 }).collect();
        let flat = FlatField::from_gains(w, h, gains.clone()).unwrap();
        let settings = ConvertSettings {
            transmission: 0.8,
            scale_k: 0.4,
            ..Default::default()
        };
        let mut c = Converter::new(
            linear_lut(),
            Some(flat),
            ThresholdMatrix::bayer(4).unwrap(),
            settings,
            (w, h),
        )
        .unwrap();
        // Choose targets so that the required screen radiance is exactly
        // L_level = 1 + level for the wanted level: target = L·g·τ/k.
        let want = [10u32, 20, 30, 40, 50, 60, 70, 80];
        let target: Vec<f32> = want
            .iter()
            .zip(&gains)
            .map(|(&lv, &g)| ((1.0 + lv as f64) * g as f64 * 0.8 / 0.4) as f32)
            .collect();
        let mut frame = vec![0; w * h];
        let st = c.convert(&target, Roi::full(w, h), 0, &mut frame).unwrap();
        let got: Vec<u32> = frame.iter().map(|&p| decode_grey(p, 8)).collect();
        assert_eq!(got, want);
        assert_eq!(st.clipped(), 0);
        assert_eq!(st.pixels, 8);
        let peak = target.iter().cloned().fold(0.0f32, f32::max) as f64;
        assert_eq!(st.peak_target, peak);
        assert!((st.peak_screen - 81.0).abs() < 1e-4);
    }

    #[test]
    fn clipping_and_non_finite_are_counted() {
        let mut c = Converter::new(
            linear_lut(),
            None,
            ThresholdMatrix::bayer(4).unwrap(),
            ConvertSettings::default(),
            (8, 1),
        )
        .unwrap();
        let target = [0.0, 0.5, -3.0, 256.0, 300.0, f32::NAN, f32::INFINITY, 1.0];
        let mut frame = vec![0; 8];
        let st = c.convert(&target, Roi::full(8, 1), 0, &mut frame).unwrap();
        let got: Vec<u32> = frame.iter().map(|&p| decode_grey(p, 8)).collect();
        assert_eq!(got, vec![0, 0, 0, 255, 255, 0, 0, 0]);
        assert_eq!(st.clipped_low, 2); // 0.5 (below black 1) and -3
        assert_eq!(st.clipped_high, 1); // 300 (256 is exactly max)
        assert_eq!(st.non_finite, 2);
        assert_eq!(st.peak_target, 300.0);
    }

    #[test]
    fn temporal_offset_changes_pattern_not_mean() {
        let settings = ConvertSettings {
            temporal: true,
            seed: 42,
            ..Default::default()
        };
        let mut c = Converter::new(
            linear_lut(),
            None,
            ThresholdMatrix::bayer(8).unwrap(),
            settings,
            (16, 16),
        )
        .unwrap();
        let target = vec![100.3f32; 256];
        let mut f1 = vec![0; 256];
        let mut f2 = vec![0; 256];
        let mut f1b = vec![0; 256];
        c.convert(&target, Roi::full(16, 16), 1, &mut f1).unwrap();
        c.convert(&target, Roi::full(16, 16), 2, &mut f2).unwrap();
        c.forget_previous_roi();
        c.convert(&target, Roi::full(16, 16), 1, &mut f1b).unwrap();
        assert_eq!(f1, f1b, "same frame id, same pattern");
        let offsets: std::collections::HashSet<_> = (0..20).map(|i| c.dither_offset(i)).collect();
        assert!(offsets.len() > 5, "offsets barely change: {offsets:?}");
        let ones = |f: &[u32]| f.iter().filter(|&&p| decode_grey(p, 8) == 100).count();
        // p = 0.3 of 256 pixels in four complete 8×8 tiles: round(0.3·64)·4.
        assert_eq!(ones(&f1), 19 * 4);
        assert_eq!(ones(&f2), 19 * 4);
    }

    /// The conversion as the module docs state it, one pixel at a time and
    /// one full sort per tile (by key descending, then row, then column).
    /// Writes `roi` into `frame` and returns the statistics.
    #[allow(clippy::too_many_arguments)]
    fn reference_convert(
        lut: &DisplayLut,
        flat: Option<&FlatField>,
        matrix: &ThresholdMatrix,
        s: &ConvertSettings,
        offset: (usize, usize),
        width: usize,
        target: &[f32],
        roi: Roi,
        frame: &mut [u32],
    ) -> ConvertStats {
        struct Cand {
            x: usize,
            y: usize,
            k: u32,
            p: f64,
            step: f64,
            key: f64,
        }
        let lr = lut.level_radiances();
        let top = lut.levels() - 1;
        let factor = s.scale_k / s.transmission;
        let tile = s.block.max(1);
        let mut st = ConvertStats::default();
        let mut cands: Vec<Cand> = Vec::new();
        for y in roi.y..roi.y + roi.height {
            for x in roi.x..roi.x + roi.width {
                st.pixels += 1;
                let t = target[(y - roi.y) * roi.width + x - roi.x] as f64;
                let mut level = 0;
                if !t.is_finite() {
                    st.non_finite += 1;
                } else {
                    let gain = flat.map_or(1.0, |f| f.gain(x, y) as f64);
                    let l = t * factor / gain;
                    st.peak_target = st.peak_target.max(t);
                    st.peak_screen = st.peak_screen.max(l);
                    if l == 0.0 {
                    } else if l < lut.black() {
                        st.clipped_low += 1;
                    } else if l >= lut.max_radiance() {
                        st.clipped_high += u64::from(l > lut.max_radiance());
                        level = top;
                    } else {
                        let (k, p) = lut.bracket(l).unwrap();
                        let th = matrix.get(x + offset.0, y + offset.1) as f64;
                        level = k;
                        if tile == 1 {
                            level += u32::from(p > th);
                        } else {
                            let step = lr[k as usize + 1] - lr[k as usize];
                            let key = p - th;
                            cands.push(Cand {
                                x,
                                y,
                                k,
                                p,
                                step,
                                key,
                            });
                        }
                    }
                }
                frame[y * width + x] = lut.encode_pixel(level);
            }
        }
        // Tiles of the screen grid, candidates in row-major order.
        let mut tiles: std::collections::BTreeMap<(usize, usize), Vec<Cand>> = Default::default();
        for c in cands {
            tiles.entry((c.y / tile, c.x / tile)).or_default().push(c);
        }
        for (_, mut cs) in tiles {
            let excess: f64 = cs.iter().map(|c| c.p * c.step).sum();
            cs.sort_by(|a, b| b.key.total_cmp(&a.key).then((a.y, a.x).cmp(&(b.y, b.x))));
            let mut cum = 0.0;
            let mut n = cs.len();
            for (i, c) in cs.iter().enumerate() {
                if cum + c.step > excess {
                    n = if cum + c.step - excess < excess - cum {
                        i + 1
                    } else {
                        i
                    };
                    break;
                }
                cum += c.step;
            }
            for c in &cs[..n] {
                frame[c.y * width + c.x] = lut.encode_pixel(c.k + 1);
            }
        }
        st
    }

    /// A node at every level with dyadic radiances `1 + k + k²/256`: the
    /// LUT holds them exactly, and steps differ from level to level.
    fn dyadic_lut() -> DisplayLut {
        let levels: Vec<f64> = (0..256).map(f64::from).collect();
        let rad: Vec<f64> = levels.iter().map(|k| 1.0 + k + k * k / 256.0).collect();
        DisplayLut::from_points(&levels, &rad, 8).unwrap()
    }

    /// Display LUTs with different shapes: measured-like, gamma with black
    /// 0, linear (equal steps, exact ties), dyadic, flat stretches, 10 bit.
    fn test_luts() -> Vec<DisplayLut> {
        let example = concat!(env!("CARGO_MANIFEST_DIR"), "/calib/example_lut.csv");
        let gamma = |bits: u32, black: f64, n: usize| {
            let top = ((1u32 << bits) - 1) as f64;
            let levels: Vec<f64> = (0..n).map(|i| top * i as f64 / (n - 1) as f64).collect();
            let rad: Vec<f64> = levels
                .iter()
                .map(|l| black + 90.0 * (l / top).powf(2.2))
                .collect();
            DisplayLut::from_points(&levels, &rad, bits).unwrap()
        };
        vec![
            DisplayLut::load(example, 8).unwrap(),
            gamma(8, 0.0, 18),
            gamma(10, 0.05, 33),
            linear_lut(),
            dyadic_lut(),
            DisplayLut::from_points(&[0.0, 1023.0], &[0.5, 1024.5], 10).unwrap(),
            DisplayLut::from_points(
                &[0.0, 40.0, 100.0, 200.0, 255.0],
                &[0.2, 0.2, 3.0, 3.0, 9.0],
                8,
            )
            .unwrap(),
        ]
    }

    /// A random target for `roi` at screen radiances spanning `lut`, as a
    /// mix of patterns (all with exact zeros and, sometimes, NaN/inf).
    fn random_target(rng: &mut Rng, lut: &DisplayLut, factor: f64, roi: Roi) -> Vec<f32> {
        let mut unit = || rng.unit();
        let (black, max) = (lut.black(), lut.max_radiance());
        let lr = lut.level_radiances();
        let top = (lut.levels() - 1) as f64;
        let pattern = (unit() * 7.0) as u32;
        let (lvl0, slope_x, slope_y) = (unit() * top, (unit() - 0.5) * 4.0, (unit() - 0.5) * 0.5);
        let zeros = unit() * 0.4;
        let weird = unit() < 0.3;
        let quarter = unit() * 4.0;
        (0..roi.area())
            .map(|i| {
                let (u, v) = ((i % roi.width) as f64, (i / roi.width) as f64);
                let r = unit();
                if r < zeros {
                    return 0.0;
                }
                if weird && r > 0.97 {
                    return [f32::NAN, f32::INFINITY, -1.0, f32::NEG_INFINITY]
                        [(r * 1e4) as usize % 4];
                }
                let level = match pattern {
                    // Gradient in level space.
                    0 => lvl0 + slope_x * u + slope_y * v,
                    // Noise.
                    1 => unit() * top,
                    // Exact level radiances and quarters between them.
                    2 => (lvl0 + u * 0.25).floor() + (quarter.floor() * 0.25),
                    // Straddling black and the maximum.
                    3 => {
                        if unit() < 0.5 {
                            -0.5 + unit() * 2.0
                        } else {
                            top - 1.5 + unit() * 2.5
                        }
                    }
                    // Constant.
                    4 => lvl0,
                    // Two levels in alternate columns, halfway: with Bayer
                    // thresholds the walk lands exactly on a tie.
                    5 => lvl0.floor() + (u % 2.0) + 0.5,
                    // Slow gradient.
                    _ => lvl0 + 0.03 * u + 0.02 * v,
                };
                let l = if level <= 0.0 {
                    black * (1.0 + level) // below black or at it
                } else if level >= top {
                    max * (1.0 + 0.01 * (level - top))
                } else {
                    let k = level.floor() as usize;
                    lr[k] + (level - k as f64) * (lr[k + 1] - lr[k])
                };
                (l / factor) as f32
            })
            .collect()
    }

    /// Deterministic test randomness.
    struct Rng(u64);

    impl Rng {
        fn next(&mut self) -> u64 {
            splitmix64(&mut self.0)
        }

        /// Uniform in [0, 1).
        fn unit(&mut self) -> f64 {
            (self.next() >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    #[test]
    fn convert_matches_the_reference_on_random_inputs() {
        let luts = test_luts();
        let matrices = [
            ThresholdMatrix::bayer(4).unwrap(),
            ThresholdMatrix::bayer(16).unwrap(),
            ThresholdMatrix::blue_noise(16, 3).unwrap(),
        ];
        let (w, h) = (70, 45);
        let mut rng = Rng(0x5EED);
        for case in 0..400 {
            let lut = luts[case % luts.len()].clone();
            let matrix = matrices[(rng.unit() * 3.0) as usize].clone();
            let transmission = 0.5 + 0.5 * rng.unit();
            let settings = ConvertSettings {
                transmission,
                // Sometimes exactly 1 ÷ τ·k = 1, so exact radiances survive.
                scale_k: if rng.unit() < 0.3 {
                    transmission
                } else {
                    0.1 + 2.0 * rng.unit()
                },
                temporal: rng.unit() < 0.5,
                seed: rng.next(),
                block: [0, 1, 2, 3, 8, 8, 8, 16][(rng.unit() * 8.0) as usize],
            };
            let flat = (rng.unit() < 0.4).then(|| {
                let gains = (0..w * h)
                    .map(|_| (0.6 + 0.8 * rng.unit()) as f32)
                    .collect();
                FlatField::from_gains(w, h, gains).unwrap()
            });
            let mut conv =
                Converter::new(lut.clone(), flat.clone(), matrix.clone(), settings, (w, h))
                    .unwrap();
            let factor = settings.scale_k / settings.transmission;
            let mut frame = vec![0x0012_3456; w * h];
            let mut want = frame.clone();
            // Two conversions into the same frame: the second clears the first.
            let mut prev: Option<Roi> = None;
            for frame_id in [7u64, 8] {
                let rw = 1 + (rng.unit() * 60.0) as usize;
                let rh = 1 + (rng.unit() * 40.0) as usize;
                let roi = Roi::new(
                    (rng.unit() * (w - rw) as f64) as usize,
                    (rng.unit() * (h - rh) as f64) as usize,
                    rw,
                    rh,
                );
                let target = random_target(&mut rng, &lut, factor, roi);
                let got = conv.convert(&target, roi, frame_id, &mut frame).unwrap();
                if let Some(p) = prev {
                    for y in p.y..p.y + p.height {
                        want[y * w + p.x..y * w + p.x + p.width].fill(lut.encode_pixel(0));
                    }
                }
                let expect = reference_convert(
                    &lut,
                    flat.as_ref(),
                    &matrix,
                    &settings,
                    conv.dither_offset(frame_id),
                    w,
                    &target,
                    roi,
                    &mut want,
                );
                assert_eq!(got, expect, "case {case}, frame {frame_id}: stats");
                if let Some(i) = (0..w * h).find(|&i| frame[i] != want[i]) {
                    panic!(
                        "case {case}, frame {frame_id}, {roi:?}, {settings:?}: pixel ({}, {}) is {:#x}, want {:#x}",
                        i % w,
                        i / w,
                        frame[i],
                        want[i]
                    );
                }
                prev = Some(roi);
            }
        }
    }
}
