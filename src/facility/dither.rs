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
//!    Each clipped pixel's radiance error, camera side (what is shown,
//!    `L_level × g × τ ÷ k`, minus the target), is summed into
//!    `moved_white` (≤ 0) or `moved_black` (≥ 0), and the finite targets
//!    into `target_sum`: their ratios are the fractions of the frame's
//!    flux the screen's white and black levels move (pixels of equal solid
//!    angle).
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
    /// Σ of the finite targets (camera side), W m⁻² sr⁻¹ × pixels.
    pub target_sum: f64,
    /// Σ (shown − target) over the pixels clipped at the top level
    /// (camera side, ≤ 0), W m⁻² sr⁻¹ × pixels.
    pub moved_white: f64,
    /// Σ (shown − target) over the pixels clipped at the black level
    /// (camera side, ≥ 0), W m⁻² sr⁻¹ × pixels.
    pub moved_black: f64,
}

impl ConvertStats {
    /// All clipped pixels.
    pub fn clipped(&self) -> u64 {
        self.clipped_high + self.clipped_low
    }

    /// Flux the white level moves, as a fraction of the targets' (≤ 0; 0
    /// when nothing was lit).
    pub fn white_flux_fraction(&self) -> f64 {
        self.fraction(self.moved_white)
    }

    /// Flux the black level moves, as a fraction of the targets' (≥ 0).
    pub fn black_flux_fraction(&self) -> f64 {
        self.fraction(self.moved_black)
    }

    fn fraction(&self, moved: f64) -> f64 {
        let f = moved / self.target_sum;
        if self.target_sum > 0.0 && f.is_finite() {
            f
        } else {
            0.0
        }
    }

    fn merge(mut self, o: ConvertStats) -> ConvertStats {
        self.pixels += o.pixels;
        self.clipped_high += o.clipped_high;
        self.clipped_low += o.clipped_low;
        self.non_finite += o.non_finite;
        self.peak_target = self.peak_target.max(o.peak_target);
        self.peak_screen = self.peak_screen.max(o.peak_screen);
        self.target_sum += o.target_sum;
        self.moved_white += o.moved_white;
        self.moved_black += o.moved_black;
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
    index: LevelIndex,
    /// The threshold matrix with the current frame's offset (reused).
    shifted: Vec<f64>,
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
        if !(k / t).is_finite() {
            return Err(Error::invalid(
                "drive.scale_k",
                format!("k ÷ collimator.transmission = {k:e} ÷ {t:e} overflows"),
            ));
        }
        if screen.0 == 0 || screen.1 == 0 {
            return Err(Error::invalid("screen.resolution", "must be non-zero"));
        }
        if let Some(f) = &flat {
            if f.size() != screen {
                return Err(Error::invalid(
                    "calibration.flat_field",
                    format!(
                        "flat field is {}×{} px but the screen is {}×{} px",
                        f.size().0,
                        f.size().1,
                        screen.0,
                        screen.1
                    ),
                ));
            }
        }
        let index = LevelIndex::new(lut.level_radiances());
        Ok(Converter {
            index,
            shifted: Vec::new(),
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
        let tile = self.settings.block.max(1);
        let (ox, oy) = self.dither_offset(frame_id);
        let n = self.matrix.size;
        self.shifted.clear();
        self.shifted
            .extend((0..n * n).map(|i| self.matrix.get(i % n + ox, i / n + oy) as f64));
        let lut = &self.lut;
        let ctx = PixelCtx {
            lut,
            index: &self.index,
            flat: self.flat.as_ref(),
            thresholds: &self.shifted,
            size: n,
            factor: self.settings.scale_k / self.settings.transmission,
            width: w,
            lowest: if lut.black() > 0.0 {
                lut.black()
            } else {
                f64::from_bits(1)
            },
            max: lut.max_radiance(),
            black_pixel,
            top_pixel: lut.encode_pixel(lut.levels() - 1),
            pixel_mul: lut.encode_pixel(1),
        };
        // Split the ROI rows into bands aligned to the screen's tile grid
        // (without tiles any grouping of rows gives the same result).
        let band_rows = if tile > 1 { tile } else { 8 };
        let mut bands: Vec<(usize, &mut [u32])> = Vec::new();
        let mut rest = &mut frame[roi.y * w..(roi.y + roi.height) * w];
        let mut y = roi.y;
        while y < roi.y + roi.height {
            let y1 = ((y / band_rows + 1) * band_rows).min(roi.y + roi.height);
            let (band, tail) = rest.split_at_mut((y1 - y) * w);
            bands.push((y, band));
            rest = tail;
            y = y1;
        }
        let mut stats = bands
            .into_par_iter()
            .map_init(TileScratch::default, |scratch, (y0, band)| {
                ctx.band(target, roi, y0, band, tile, scratch)
            })
            .reduce(ConvertStats::default, ConvertStats::merge);
        if self.flat.is_none() {
            // l = t·factor rounds monotonically, so the largest l is the
            // largest t times the factor (0 while nothing is larger).
            stats.peak_screen = stats.peak_target * ctx.factor;
        }
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

/// Exact LUT bracket without a search: `k = max{k : L_k ≤ l}`, the level
/// [`DisplayLut::bracket`] finds for non-decreasing level radiances, from a
/// table over the leading bits of `l` (logarithmic buckets) and at most one
/// step up.
#[derive(Clone)]
struct LevelIndex {
    /// Level radiances non-decreasing. Rounding can break this on flat LUT
    /// segments by an ulp; then the walk's start matters and
    /// [`DisplayLut::bracket`] is used as is.
    monotone: bool,
    /// Bucket of `l`: `(l.to_bits() >> shift) − base` (below `len`).
    shift: u32,
    base: u64,
    len: usize,
    /// Per bucket, `k` of the bucket's lowest radiance (of black for the
    /// first bucket, which also takes everything below it). Fixed sizes
    /// here and in `pairs` spare the lookups their bounds checks.
    start: Box<[u16; BUCKETS]>,
    /// Per bucket, `L_{k+1}` of its `start` level `k`: looked up with it,
    /// not after it.
    bound: Box<[f64; BUCKETS]>,
    /// `[L_k, L_{k+1}]` per level `k`, +inf past the top.
    pairs: Box<[[f64; 2]; 1024]>,
    /// No bucket spans more than one level boundary.
    one_step: bool,
}

/// Capacity of [`LevelIndex::start`].
const BUCKETS: usize = 1 << 14;

impl std::fmt::Debug for LevelIndex {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LevelIndex")
            .field("monotone", &self.monotone)
            .field("shift", &self.shift)
            .field("buckets", &self.len)
            .field("one_step", &self.one_step)
            .finish()
    }
}

impl LevelIndex {
    fn new(lr: &[f64]) -> LevelIndex {
        let monotone = lr.windows(2).all(|p| p[0] <= p[1]);
        let at = |k: usize| lr.get(k).copied().unwrap_or(f64::INFINITY);
        let mut index = LevelIndex {
            monotone,
            shift: 0,
            base: 0,
            len: 0,
            start: vec![0; BUCKETS].try_into().expect("BUCKETS entries"),
            bound: vec![0.0; BUCKETS].try_into().expect("BUCKETS entries"),
            pairs: (0..1024)
                .map(|k| [at(k), at(k + 1)])
                .collect::<Vec<_>>()
                .try_into()
                .expect("1024 levels"),
            one_step: false,
        };
        if monotone {
            // 256 … 4096 buckets per octave: the coarsest with one step.
            for bits in 8..=12 {
                index.fill(lr, 52 - bits);
                if index.one_step {
                    break;
                }
            }
        }
        index
    }

    fn fill(&mut self, lr: &[f64], shift: u32) {
        let top = lr.len() - 1;
        let (black, max) = (lr[0], lr[top]);
        // A black of 0 has no octave; start at the first lit level instead.
        let lo = if black > 0.0 {
            black
        } else {
            lr.iter().copied().find(|&v| v > 0.0).unwrap_or(max)
        };
        let last = max.to_bits() >> shift;
        let base = (lo.to_bits() >> shift).max(last.saturating_sub(BUCKETS as u64 - 1));
        let len = (last - base + 1) as usize;
        // Last level with L_k ≤ v, resp. L_k < v, kept below the top.
        let k_le = |v: f64| (lr.partition_point(|&x| x <= v).max(1) - 1).min(top - 1);
        let k_lt = |v: f64| (lr.partition_point(|&x| x < v).max(1) - 1).min(top - 1);
        let lower = |b: usize| f64::from_bits((base + b as u64) << shift);
        let mut walk = 0;
        for b in 0..len {
            let k0 = if b == 0 { k_le(black) } else { k_le(lower(b)) };
            let upper = if b + 1 < len { lower(b + 1) } else { max };
            walk = walk.max(k_lt(upper).saturating_sub(k0));
            self.start[b] = k0 as u16;
            self.bound[b] = lr[k0 + 1];
        }
        self.shift = shift;
        self.base = base;
        self.len = len;
        self.one_step = walk <= 1;
    }
}

/// [`LevelIndex`] lookup for one conversion.
#[derive(Clone, Copy)]
struct Bracketer<'a> {
    lut: &'a DisplayLut,
    index: &'a LevelIndex,
    start: &'a [u16; BUCKETS],
    bound: &'a [f64; BUCKETS],
    pairs: &'a [[f64; 2]; 1024],
    shift: u32,
    base: u64,
}

impl Bracketer<'_> {
    /// `(k, l − L_k, L_{k+1} − L_k)` for `black ≤ l < max`, `l ≠ 0`, so
    /// that `p = (l − L_k)/(L_{k+1} − L_k)` (in `[0, 1]` as `L_k ≤ l <
    /// L_{k+1}`, so [`DisplayLut::bracket`]'s clamping changes nothing).
    /// `FAST` (monotone, one step) must be the index's: loops are compiled
    /// for each, so that the fast one has no call in it.
    #[inline(always)]
    fn get<const FAST: bool>(&self, l: f64) -> (usize, f64, f64) {
        if !FAST {
            let lr = self.lut.level_radiances();
            let k = self.general(l);
            return (k, l - lr[k], lr[k + 1] - lr[k]);
        }
        // l < max keeps the bucket in the table; the mask only tells the
        // compiler so.
        let b = ((l.to_bits() >> self.shift).saturating_sub(self.base)) as usize & (BUCKETS - 1);
        // Branch-free (the data decide, not the predictor): one step up if
        // L_{k+1} ≤ l.
        let k = self.start[b] as usize + usize::from(self.bound[b] <= l);
        let [lo, hi] = self.pairs[k & 1023];
        (k, l - lo, hi - lo)
    }

    /// `k` by a longer walk, or by [`DisplayLut::bracket`] itself if the
    /// level radiances are not monotone.
    #[inline(never)]
    fn general(&self, l: f64) -> usize {
        if !self.index.monotone {
            return self.lut.bracket(l).expect("black ≤ l < max").0 as usize;
        }
        let lr = self.lut.level_radiances();
        let b = (((l.to_bits() >> self.shift).saturating_sub(self.base)) as usize)
            .min(self.index.len - 1);
        let mut k = self.start[b] as usize;
        while lr[k + 1] <= l {
            k += 1;
        }
        k
    }
}

/// Per-conversion constants.
struct PixelCtx<'a> {
    lut: &'a DisplayLut,
    index: &'a LevelIndex,
    flat: Option<&'a FlatField>,
    /// Threshold matrix with this frame's offset applied, as f64.
    thresholds: &'a [f64],
    size: usize,
    factor: f64,
    width: usize,
    /// Lowest screen radiance between two levels: black, or the smallest
    /// positive value if black is 0 (an exact 0 is sky, not a level).
    lowest: f64,
    max: f64,
    black_pixel: u32,
    top_pixel: u32,
    /// Frame pixel = level × `pixel_mul` for levels up to the top.
    pixel_mul: u32,
}

/// A tile: `tw` columns from `x0`, `rows` rows from `y0` (screen).
#[derive(Clone, Copy)]
struct Tile {
    x0: usize,
    y0: usize,
    tw: usize,
    rows: usize,
}

/// Running sums over a tile's candidates, in row-major order.
#[derive(Clone, Copy)]
struct TileSums {
    /// Σ p·step: the radiance owed above the lower levels, summed in the
    /// rule's order (for the same bits).
    excess: f64,
    step_min: f64,
    /// 0 while there are no candidates.
    step_max: f64,
}

/// Bucket mark of a tile pixel that is not between two levels (not a
/// repeated byte, so that filling with it is no call to memset).
const NOT_BETWEEN: u16 = 0xFFFE;

impl PixelCtx<'_> {
    /// Converts the rows of one band (starting at screen row `y0`).
    fn band(
        &self,
        target: &[f32],
        roi: Roi,
        y0: usize,
        band: &mut [u32],
        tile: usize,
        scratch: &mut TileScratch,
    ) -> ConvertStats {
        let w = self.width;
        let mut st = ConvertStats::default();
        let rows = band.len() / w;
        let fast = self.index.monotone && self.index.one_step;
        let trow = |r: usize| &target[(y0 + r - roi.y) * roi.width..][..roi.width];
        // Columns outside every row's lit span are empty sky: black, not
        // clipped, no peak; written here at the cost of a fill.
        let (mut lo, mut hi) = (roi.width, 0);
        for r in 0..rows {
            let t = trow(r);
            let (l, h) = lit_span(t);
            st.pixels += t.len() as u64;
            if l < h {
                let (peak, sum) = finite_max_sum(&t[l..h]);
                st.peak_target = st.peak_target.max(peak as f64);
                st.target_sum += sum;
                (lo, hi) = (lo.min(l), hi.max(h));
            }
        }
        if lo >= hi {
            (lo, hi) = (0, 0);
        }
        for r in 0..rows {
            let row = &mut band[r * w + roi.x..][..roi.width];
            row[..lo].fill(self.black_pixel);
            row[hi..].fill(self.black_pixel);
        }
        if lo == hi {
            return st;
        }
        // The lit columns on the screen, widened to the tile grid.
        let x_end = roi.x + hi;
        let x_start = ((roi.x + lo) / tile * tile).max(roi.x);
        if tile == 1 {
            for r in 0..rows {
                let y = y0 + r;
                let t = &trow(r)[lo..hi];
                let out = &mut band[r * w + roi.x + lo..r * w + x_end];
                let th = &mut scratch.th;
                let x = roi.x + lo;
                match (fast, self.flat.is_some()) {
                    (true, false) => self.plain_row::<true, false>(t, out, x, y, &mut st, th),
                    (true, true) => self.plain_row::<true, true>(t, out, x, y, &mut st, th),
                    (false, false) => self.plain_row::<false, false>(t, out, x, y, &mut st, th),
                    (false, true) => self.plain_row::<false, true>(t, out, x, y, &mut st, th),
                }
            }
            return st;
        }
        scratch.reserve(rows * tile.min(roi.width), tile * tile);
        let mut x0 = x_start;
        while x0 < x_end {
            let x1 = ((x0 / tile + 1) * tile).min(x_end);
            let geo = Tile {
                x0,
                y0,
                tw: x1 - x0,
                rows,
            };
            let s = &mut *scratch;
            let sums = match (fast, self.flat.is_some()) {
                (true, false) => self.classify::<true, false>(target, roi, band, geo, s, &mut st),
                (true, true) => self.classify::<true, true>(target, roi, band, geo, s, &mut st),
                (false, false) => self.classify::<false, false>(target, roi, band, geo, s, &mut st),
                (false, true) => self.classify::<false, true>(target, roi, band, geo, s, &mut st),
            };
            if sums.step_max > 0.0 {
                self.raise(band, geo, scratch, sums);
            }
            x0 = x1;
        }
        st
    }

    /// Plain ordered dithering of the pixels `x0 …` of row `y`.
    fn plain_row<const FAST: bool, const FLAT: bool>(
        &self,
        t: &[f32],
        out: &mut [u32],
        x0: usize,
        y: usize,
        st: &mut ConvertStats,
        th_buf: &mut Vec<f64>,
    ) {
        let n = t.len();
        let out = &mut out[..n];
        if self.sky(t, out) {
            return;
        }
        let th = self.segment_thresholds(x0, y, n, th_buf);
        let gains = self.gains::<FLAT>(x0, y, n);
        let (bracket, mul) = (self.bracketer(), self.pixel_mul);
        let mut peak_l = st.peak_screen;
        for c in 0..n {
            let (t, l) = self.screen::<FLAT>(t[c], gains, c, &mut peak_l);
            if !(l >= self.lowest && l < self.max) {
                out[c] = self.edge(t, l, st);
                continue;
            }
            let (k, above, step) = bracket.get::<FAST>(l);
            out[c] = (k as u32 + u32::from(above / step > th[c])) * mul;
        }
        st.peak_screen = peak_l;
    }

    /// First pass over a tile: converts every pixel, those between two
    /// levels to level `k`, and notes for these their [`key_bucket`] (the
    /// others [`NOT_BETWEEN`]), key and step in `scratch`, and counts and
    /// sums their steps per bucket.
    #[inline(never)]
    fn classify<const FAST: bool, const FLAT: bool>(
        &self,
        target: &[f32],
        roi: Roi,
        band: &mut [u32],
        geo: Tile,
        scratch: &mut TileScratch,
        st: &mut ConvertStats,
    ) -> TileSums {
        let (w, tw) = (self.width, geo.tw);
        let nb = scratch.buckets;
        let TileScratch {
            bucket,
            cand,
            count,
            sum,
            th: th_buf,
            ..
        } = scratch;
        let (count, sum) = (&mut count[..nb], &mut sum[..nb]);
        let bracket = self.bracketer();
        let (lowest, max, mul, half) = (self.lowest, self.max, self.pixel_mul, (nb / 2) as f64);
        let mut zeroed = false;
        let mut excess = 0.0;
        let (mut step_min, mut step_max) = (f64::INFINITY, 0.0);
        let mut peak_l = st.peak_screen;
        for r in 0..geo.rows {
            let y = geo.y0 + r;
            let t = &target[(y - roi.y) * roi.width + geo.x0 - roi.x..][..tw];
            let out = &mut band[r * w + geo.x0..][..tw];
            let marks = &mut bucket[r * tw..][..tw];
            if self.sky(t, out) {
                marks.fill(NOT_BETWEEN);
                continue;
            }
            if !zeroed {
                // Only now: all-sky tiles need no tallies.
                count.fill(0);
                sum.fill(0.0);
                zeroed = true;
            }
            let th = &self.segment_thresholds(geo.x0, y, tw, th_buf)[..tw];
            let gains = self.gains::<FLAT>(geo.x0, y, tw);
            let cand = &mut cand[r * tw..][..tw];
            // The lookups, then the divisions: two short dependency chains
            // per pixel instead of one long one keep more pixels in flight.
            for c in 0..tw {
                let (t, l) = self.screen::<FLAT>(t[c], gains, c, &mut peak_l);
                if !(l >= lowest && l < max) {
                    out[c] = self.edge(t, l, st);
                    marks[c] = NOT_BETWEEN;
                    continue;
                }
                let (k, above, s) = bracket.get::<FAST>(l);
                cand[c] = (above, s);
                marks[c] = 0;
                out[c] = k as u32 * mul;
            }
            for c in 0..tw {
                if marks[c] != NOT_BETWEEN {
                    let (above, s) = cand[c];
                    let p = above / s;
                    let key = p - th[c];
                    cand[c] = (key, s);
                    marks[c] = key_bucket(key, half, nb) as u16;
                    excess += p * s;
                    step_min = if s < step_min { s } else { step_min };
                    step_max = if s > step_max { s } else { step_max };
                }
            }
            // Tallied apart: in the loop above the bucket is known only
            // after the division, too late for the stores to sum[b] not to
            // stall later loads.
            for (&b, &(_, s)) in marks.iter().zip(cand.iter()) {
                if b != NOT_BETWEEN {
                    count[b as usize] += 1;
                    sum[b as usize] += s;
                }
            }
        }
        st.peak_screen = peak_l;
        TileSums {
            excess,
            step_min,
            step_max,
        }
    }

    /// If the targets of a row segment are all exact zeros (empty sky:
    /// black, not clipped), writes them black and returns true.
    #[inline(always)]
    fn sky(&self, t: &[f32], out: &mut [u32]) -> bool {
        if t.iter().fold(0, |a, &v| a | (v.to_bits() << 1)) == 0 {
            out.fill(self.black_pixel);
            return true;
        }
        false
    }

    /// The LUT lookup, its fields copied out of `self` so that the hot loops
    /// keep them in registers.
    #[inline(always)]
    fn bracketer(&self) -> Bracketer<'_> {
        let index = self.index;
        Bracketer {
            lut: self.lut,
            index,
            start: &index.start,
            bound: &index.bound,
            pairs: &index.pairs,
            shift: index.shift,
            base: index.base,
        }
    }

    /// Thresholds of the pixels `x0 … x0 + n` of row `y`.
    #[inline(always)]
    fn segment_thresholds<'b>(
        &'b self,
        x0: usize,
        y: usize,
        n: usize,
        buf: &'b mut Vec<f64>,
    ) -> &'b [f64] {
        let (size, mask) = (self.size, self.size - 1);
        let row = &self.thresholds[(y & mask) * size..][..size];
        let xm = x0 & mask;
        if xm + n <= size {
            &row[xm..xm + n]
        } else {
            buf.clear();
            buf.extend((x0..x0 + n).map(|x| row[x & mask]));
            buf
        }
    }

    /// Flat-field gains of the pixels `x0 … x0 + n` of row `y` (none
    /// without a flat field).
    #[inline(always)]
    fn gains<const FLAT: bool>(&self, x0: usize, y: usize, n: usize) -> &[f32] {
        match self.flat {
            Some(f) if FLAT => &f.gains()[y * self.width + x0..][..n],
            _ => &[],
        }
    }

    /// Target `t` as f64 and the screen radiance it requires on the pixel
    /// with gain `gains[c]`; with a flat field also raises `peak_l` (see
    /// [`Converter::convert`] for without).
    #[inline(always)]
    fn screen<const FLAT: bool>(
        &self,
        t: f32,
        gains: &[f32],
        c: usize,
        peak_l: &mut f64,
    ) -> (f64, f64) {
        let t = t as f64;
        if !FLAT {
            // Dividing by a gain of 1 would change nothing.
            return (t, t * self.factor);
        }
        let l = t * self.factor / gains[c] as f64;
        if t.is_finite() {
            *peak_l = peak_l.max(l);
        }
        (t, l)
    }

    /// Frame pixel of a target that is not between two levels: non-finite,
    /// exact 0 (sky), or clipped.
    #[inline(always)]
    fn edge(&self, t: f64, l: f64, st: &mut ConvertStats) -> u32 {
        // A finite target can still overflow into a non-finite screen
        // radiance (an extreme k or τ): black, counted, never a panic.
        if !t.is_finite() || !l.is_finite() {
            st.non_finite += 1;
            return self.black_pixel;
        }
        // Camera side, a screen radiance L shows L × t / l (t / l = g τ / k).
        if l == 0.0 {
            self.black_pixel
        } else if l < self.lut.black() {
            st.clipped_low += 1;
            st.moved_black += self.lut.black() * (t / l) - t;
            self.black_pixel
        } else if l >= self.max {
            if l > self.max {
                st.clipped_high += 1;
                st.moved_white += self.max * (t / l) - t;
            }
            self.top_pixel
        } else {
            // Only reached if a caller routed an in-range pixel here; black
            // is the safe answer in the render thread.
            st.non_finite += 1;
            self.black_pixel
        }
    }

    /// Raises the best-ranked candidates of a tile (its pixels between two
    /// levels, marked by their key bucket in `scratch`) to `k + 1`.
    ///
    /// The rule ([`PixelCtx::raise_exact`]) walks the ranking and adds up
    /// steps in that order; only the candidates near where the sum crosses
    /// the excess need ranking. So the walk goes bucket by bucket (Σ step
    /// per bucket) up to the bucket `b` where it crosses, and ranks only
    /// that bucket's candidates. With one step size in the tile the number
    /// raised does not depend on the order and is replayed exactly.
    /// Otherwise the sums here and the rule's add the same positive terms
    /// in other orders, so they differ by rounding only, less than
    /// (m + buckets)·ε relative: where every decision clears a margin four
    /// times that, the result is the rule's; else the exact ranking decides.
    #[inline(never)]
    fn raise(&self, band: &mut [u32], geo: Tile, scratch: &mut TileScratch, sums: TileSums) {
        let (w, mul, nb) = (self.width, self.pixel_mul, scratch.buckets);
        let area = geo.rows * geo.tw;
        let TileScratch {
            bucket,
            cand,
            count,
            sum,
            group,
            ..
        } = scratch;
        let (bucket, cand) = (&bucket[..area], &cand[..area]);
        let (count, sum) = (&count[..nb], &sum[..nb]);
        let excess = sums.excess;
        let m = count.iter().map(|&c| c as usize).sum();
        let same_step = sums.step_min == sums.step_max;
        let step_min = sums.step_min;
        let (mut b, mut before, mut below) = (0, 0, 0.0);
        let mut n = 0;
        if same_step {
            n = walk(m, excess, |_| step_min);
            while b < nb && before + (count[b] as usize) < n {
                before += count[b] as usize;
                b += 1;
            }
        } else {
            while b < nb && !(below + sum[b] > excess) {
                below += sum[b];
                before += count[b] as usize;
                b += 1;
            }
        }
        // Raise the earlier buckets (level k + 1 is one `mul` above level k).
        let below_b = b as u16;
        for r in 0..geo.rows {
            let marks = &bucket[r * geo.tw..][..geo.tw];
            let out = &mut band[r * w + geo.x0..][..geo.tw];
            for (o, &v) in out.iter_mut().zip(marks) {
                *o += mul * u32::from(v < below_b);
            }
        }
        // Bucket b by position.
        let mut g = 0;
        for (i, &v) in bucket.iter().enumerate() {
            group[g] = i as u32;
            g += usize::from(v as usize == b);
        }
        // Bucket b in rank order: a stable insertion sort by key descending.
        let group = &mut group[..g];
        for q in 1..g {
            let cur = group[q];
            let mut z = q;
            while z > 0 && cand[group[z - 1] as usize].0 < cand[cur as usize].0 {
                group[z] = group[z - 1];
                z -= 1;
            }
            group[z] = cur;
        }
        let take = if same_step {
            n - before
        } else {
            let tol = 4.0 * (m + nb + 4) as f64 * f64::EPSILON;
            let mut cum = below;
            // Past the last bucket: nothing crossed, all raised.
            let (mut take, mut certain) = (0, b == nb && excess - cum > tol * excess);
            for (q, &i) in group.iter().enumerate() {
                let s = cand[i as usize].1;
                if cum + s > excess {
                    let margin = tol * (excess + s);
                    let (over, under) = (cum + s - excess, excess - cum);
                    take = if over < under { q + 1 } else { q };
                    certain = over > margin
                        && (before + q == 0 || under > margin)
                        && (over - under).abs() > 2.0 * margin;
                    break;
                }
                cum += s;
            }
            if !certain {
                for r in 0..geo.rows {
                    let marks = &bucket[r * geo.tw..][..geo.tw];
                    let out = &mut band[r * w + geo.x0..][..geo.tw];
                    for (o, &v) in out.iter_mut().zip(marks) {
                        *o -= mul * u32::from(v < below_b);
                    }
                }
                self.raise_exact(band, geo, scratch, excess);
                return;
            }
            take
        };
        for &pos in &group[..take] {
            let pos = pos as usize;
            band[(pos / geo.tw) * w + geo.x0 + pos % geo.tw] += mul;
        }
    }

    /// The rule itself: candidates ranked by key descending, equal keys by
    /// position (row, then column), the first `n` raised with `n` from
    /// [`walk`]: the tile's emitted radiance closest to its target,
    /// |error| ≤ half the largest step in the tile.
    fn raise_exact(&self, band: &mut [u32], geo: Tile, scratch: &mut TileScratch, excess: f64) {
        #[cfg(test)]
        EXACT_RANKINGS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let area = geo.rows * geo.tw;
        let TileScratch {
            bucket,
            group,
            cand,
            ..
        } = scratch;
        let mut m = 0;
        for pos in (0..area).filter(|&i| bucket[i] != NOT_BETWEEN) {
            group[m] = pos as u32;
            m += 1;
        }
        let order = &mut group[..m];
        order.sort_unstable_by(|&a, &b| {
            cand[b as usize]
                .0
                .total_cmp(&cand[a as usize].0)
                .then(a.cmp(&b))
        });
        let n = walk(m, excess, |q| cand[order[q] as usize].1);
        for &pos in &order[..n] {
            let pos = pos as usize;
            band[(pos / geo.tw) * self.width + geo.x0 + pos % geo.tw] += self.pixel_mul;
        }
    }
}

/// `[lo, hi)`: the columns of `t` from its first to its last target that
/// is not an exact 0 (`lo ≥ hi` if there is none).
fn lit_span(t: &[f32]) -> (usize, usize) {
    let sky = |v: &f32| v.to_bits() << 1 == 0;
    let sky8 = |c: &[f32]| c.iter().fold(0, |a, &v| a | (v.to_bits() << 1)) == 0;
    let mut lo = 0;
    while lo + 8 <= t.len() && sky8(&t[lo..lo + 8]) {
        lo += 8;
    }
    while lo < t.len() && sky(&t[lo]) {
        lo += 1;
    }
    let mut hi = t.len();
    while hi >= lo + 8 && sky8(&t[hi - 8..hi]) {
        hi -= 8;
    }
    while hi > lo && sky(&t[hi - 1]) {
        hi -= 1;
    }
    (lo, hi)
}

/// Largest finite value of `t` (−inf if none) and the sum of the finite
/// values, in eight lanes so that it vectorizes.
fn finite_max_sum(t: &[f32]) -> (f32, f64) {
    let mut lanes = [f32::NEG_INFINITY; 8];
    let mut sums = [0.0f64; 8];
    let chunks = t.chunks_exact(8);
    let rest = chunks.remainder();
    for chunk in chunks {
        for ((m, s), &v) in lanes.iter_mut().zip(&mut sums).zip(chunk) {
            let finite = v.is_finite();
            *s += if finite { v as f64 } else { 0.0 };
            let v = if finite { v } else { f32::NEG_INFINITY };
            *m = if v > *m { v } else { *m };
        }
    }
    let sum = sums.iter().sum::<f64>()
        + rest
            .iter()
            .filter(|v| v.is_finite())
            .map(|&v| v as f64)
            .sum::<f64>();
    let max = rest
        .iter()
        .chain(&lanes)
        .filter(|v| v.is_finite())
        .fold(f32::NEG_INFINITY, |a, &v| if v > a { v } else { a });
    (max, sum)
}

/// Bucket of a ranking key `p − threshold ∈ (−1, 1)`: `(1 − key)·nb/2`
/// rounded, which never decreases as the key decreases, so larger keys
/// never land in later buckets and equal keys share one.
#[inline(always)]
fn key_bucket(key: f64, half: f64, nb: usize) -> usize {
    // Adding 2^52 rounds a value in [0, 2^51) to an integer in the low bits.
    let x = (1.0 - key) * half + 4_503_599_627_370_496.0;
    ((x.to_bits() as u32) as usize).min(nb - 1)
}

/// Per-band buffers, reused from tile to tile.
#[derive(Default)]
struct TileScratch {
    /// Per tile pixel (row-major): [`key_bucket`] or [`NOT_BETWEEN`], and
    /// for candidates key `p − threshold` and step `L_{k+1} − L_k`.
    bucket: Vec<u16>,
    cand: Vec<(f64, f64)>,
    /// Per bucket: candidates and Σ step.
    count: Vec<u32>,
    sum: Vec<f64>,
    buckets: usize,
    /// Positions of the candidates being ranked.
    group: Vec<u32>,
    /// Thresholds of a row segment that wraps the threshold matrix.
    th: Vec<f64>,
}

impl TileScratch {
    /// Room for tiles of `area` pixels, `tile_area` on the screen grid.
    fn reserve(&mut self, area: usize, tile_area: usize) {
        self.buckets = (tile_area / 2).next_power_of_two().clamp(2, 4096);
        if self.group.len() < area {
            self.bucket.resize(area, 0);
            self.cand.resize(area, (0.0, 0.0));
            self.group.resize(area, 0);
        }
        if self.count.len() < self.buckets {
            self.count.resize(self.buckets, 0);
            self.sum.resize(self.buckets, 0.0);
        }
    }
}

/// How many of `len` ranked steps `step(0), step(1), …` to raise so that
/// their sum lands closest to `excess`: add while the sum stays ≤ `excess`;
/// the first one that would exceed it is raised only if that lands closer.
#[inline(always)]
fn walk(len: usize, excess: f64, step: impl Fn(usize) -> f64) -> usize {
    let mut cum = 0.0;
    for i in 0..len {
        let s = step(i);
        if cum + s > excess {
            let n = if (cum + s - excess) < (excess - cum) {
                i + 1
            } else {
                i
            };
            return n;
        }
        cum += s;
    }
    len
}

/// Tiles decided by [`TileScratch::raise_exact`] (tests check that the
/// fallback is exercised).
#[cfg(test)]
static EXACT_RANKINGS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

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

    /// The flux the white and black levels move, worked out by hand: LUT
    /// radiance = level (black 1, top 256 at level 255), k = 2, τ = 0.5
    /// (screen = 4 × target), flat gain 1. Targets [0.1, 0.2, 10, 100,
    /// 0] need screen 0.4 and 0.8 (below black 1: shown 1/4 = 0.25 each),
    /// 40 (shown as is) and 400 (above 256: shown 64), and sky.
    /// Moved: black (0.25 − 0.1) + (0.25 − 0.2) = 0.2; white 64 − 100 = −36;
    /// disk flux 110.3.
    #[test]
    fn clipped_flux_is_shown_minus_target_per_level() {
        let settings = ConvertSettings {
            transmission: 0.5,
            scale_k: 2.0,
            ..ConvertSettings::default()
        };
        let mut c = Converter::new(
            linear_lut(),
            None,
            ThresholdMatrix::bayer(4).unwrap(),
            settings,
            (5, 1),
        )
        .unwrap();
        let target = [0.1f32, 0.2, 10.0, 100.0, 0.0];
        let mut frame = vec![0; 5];
        let st = c.convert(&target, Roi::full(5, 1), 0, &mut frame).unwrap();
        assert_eq!((st.clipped_low, st.clipped_high), (2, 1));
        let sum: f64 = target.iter().map(|&t| t as f64).sum();
        let black = (0.25 - 0.1f32 as f64) + (0.25 - 0.2f32 as f64);
        assert!((st.target_sum - sum).abs() < 1e-12, "{}", st.target_sum);
        assert!((st.moved_black - black).abs() < 1e-12, "{}", st.moved_black);
        assert!((st.moved_white + 36.0).abs() < 1e-12, "{}", st.moved_white);
        assert!((st.black_flux_fraction() - black / sum).abs() < 1e-15);
        assert!((st.white_flux_fraction() + 36.0 / sum).abs() < 1e-15);
        // Nothing lit: no fraction, not NaN.
        let st = c
            .convert(&[0.0; 5], Roi::full(5, 1), 1, &mut frame)
            .unwrap();
        assert_eq!(
            (st.white_flux_fraction(), st.black_flux_fraction()),
            (0.0, 0.0)
        );
    }

    /// An extreme k ÷ τ is refused up front; a target that still
    /// overflows f64 on the way is black and counted, never a panic in the
    /// render thread.
    #[test]
    fn overflowing_scale_is_refused_or_black() {
        let make = |transmission: f64, scale_k: f64| {
            let settings = ConvertSettings {
                transmission,
                scale_k,
                ..ConvertSettings::default()
            };
            let bayer = ThresholdMatrix::bayer(4).unwrap();
            Converter::new(linear_lut(), None, bayer, settings, (4, 1))
        };
        let e = make(5e-324, 1e308).unwrap_err().to_string();
        assert!(
            e.contains("drive.scale_k") && e.contains("overflows"),
            "{e}"
        );
        let mut c = make(1e-10, 1e290).unwrap();
        let target = [0.0, 1e-40, 3e38, f32::MAX];
        let mut frame = vec![0; 4];
        let st = c.convert(&target, Roi::full(4, 1), 0, &mut frame).unwrap();
        let got: Vec<u32> = frame.iter().map(|&p| decode_grey(p, 8)).collect();
        // 1e-40 × 1e300 is finite and above the top; 3e38 × 1e300 is inf.
        assert_eq!(got, vec![0, 255, 0, 0]);
        assert_eq!((st.clipped_high, st.non_finite), (1, 2), "{st:?}");
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
    /// The counts and peaks equal, the sums to 1e-9 of the targets' sum
    /// (added in other orders).
    fn assert_same_stats(got: &ConvertStats, want: &ConvertStats, what: &str) {
        let sums = |s: &ConvertStats| [s.target_sum, s.moved_white, s.moved_black];
        let counts = |s: &ConvertStats| ConvertStats {
            target_sum: 0.0,
            moved_white: 0.0,
            moved_black: 0.0,
            ..*s
        };
        assert_eq!(counts(got), counts(want), "{what}: stats");
        let scale = want.target_sum.abs() + 1e-30;
        for (a, b) in sums(got).into_iter().zip(sums(want)) {
            assert!(
                (a - b).abs() <= 1e-9 * scale,
                "{what}: sums {:?} vs {:?}",
                sums(got),
                sums(want)
            );
        }
    }

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
                    st.target_sum += t;
                    // What the camera sees of a screen radiance L.
                    let seen = |screen: f64| screen * gain / factor;
                    if l == 0.0 {
                    } else if l < lut.black() {
                        st.clipped_low += 1;
                        st.moved_black += seen(lut.black()) - t;
                    } else if l >= lut.max_radiance() {
                        if l > lut.max_radiance() {
                            st.clipped_high += 1;
                            st.moved_white += seen(lut.max_radiance()) - t;
                        }
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
    /// 0, linear (equal steps, exact ties), dyadic, a hundred levels within
    /// 0.01 % (longer walks), flat stretches (rounding makes them
    /// non-monotone), 10 bit.
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
            {
                let levels: Vec<f64> = (0..256).map(f64::from).collect();
                let rad: Vec<f64> = levels
                    .iter()
                    .map(|&k| match k {
                        k if k < 50.0 => 1.0 + 0.2 * k,
                        k if k <= 150.0 => 11.0 + 1e-5 * (k - 50.0),
                        k => 11.001 + 0.5 * (k - 150.0),
                    })
                    .collect();
                DisplayLut::from_points(&levels, &rad, 8).unwrap()
            },
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
        // Sometimes a disk on empty sky, which may leave whole rows empty.
        let disk = (unit() < 0.3).then(|| {
            let (cx, cy) = (unit() * roi.width as f64, unit() * roi.height as f64);
            (
                cx,
                cy,
                1.0 + unit() * roi.width.max(roi.height) as f64 / 2.0,
            )
        });
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
                if let Some((cx, cy, radius)) = disk {
                    if (u - cx).powi(2) + (v - cy).powi(2) > radius * radius {
                        return 0.0;
                    }
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
        // Every way to the LUT bracket is taken.
        let index = |i: usize| LevelIndex::new(luts[i].level_radiances());
        assert!(index(0).one_step);
        assert!(index(5).monotone && !index(5).one_step);
        assert!(!index(7).monotone);
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
                assert_same_stats(&got, &expect, &format!("case {case}, frame {frame_id}"));
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

    #[test]
    fn exact_ties_between_steps_take_the_exact_ranking() {
        // Two levels in alternate columns, exactly halfway, dyadic steps:
        // with Bayer thresholds the raised half lands exactly on the
        // target, so the bucket walk cannot be certified and the exact
        // ranking (with its tie-break) decides.
        let lut = dyadic_lut();
        let lr = lut.level_radiances().to_vec();
        let (w, h) = (40, 24);
        let before = EXACT_RANKINGS.load(std::sync::atomic::Ordering::Relaxed);
        for (block, n) in [(8, 8), (8, 16), (4, 4), (16, 8)] {
            let settings = ConvertSettings {
                block,
                ..Default::default()
            };
            let matrix = ThresholdMatrix::bayer(n).unwrap();
            let mut conv =
                Converter::new(lut.clone(), None, matrix.clone(), settings, (w, h)).unwrap();
            let roi = Roi::new(3, 2, 33, 19);
            let target: Vec<f32> = (0..roi.area())
                .map(|i| {
                    let k = 100 + (i % roi.width) % 2 + (i / roi.width) / 8;
                    (lr[k] + 0.5 * (lr[k + 1] - lr[k])) as f32
                })
                .collect();
            let mut frame = vec![0; w * h];
            let mut want = frame.clone();
            let got = conv.convert(&target, roi, 0, &mut frame).unwrap();
            let expect = reference_convert(
                &lut,
                None,
                &matrix,
                &settings,
                (0, 0),
                w,
                &target,
                roi,
                &mut want,
            );
            assert_eq!(got, expect);
            assert_eq!(frame, want, "block {block}, Bayer {n}");
        }
        assert!(EXACT_RANKINGS.load(std::sync::atomic::Ordering::Relaxed) > before);
    }
}
