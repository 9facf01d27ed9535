//! Point spread functions integrated over each pixel, and their
//! convolution with an image.
//!
//! A kernel holds, per pixel offset, the fraction of a point source's
//! power that lands in that pixel when the source sits at a pixel centre:
//! the PSF integrated over the pixel's square (by Gauss–Legendre quadrature
//! for the Airy pattern, in closed form for the Gaussian). It is truncated
//! where the enclosed energy reaches [`ENCLOSED`] and renormalised, so a
//! convolution conserves the image's power (except what leaves the frame).
//! [`shared_kernel`] builds a camera's kernel once per process; a
//! convolution only visits the part of the frame the image's non-zero
//! pixels can reach.

use std::sync::Arc;

use rayon::prelude::*;
use rustfft::{num_complex::Complex, FftPlanner};

use crate::error::{Error, Result};
use crate::memo::Memo;
pub use crate::scene::camera::Psf;

/// Kernels of the most recent PSFs.
static KERNELS: Memo<Psf, Kernel> = Memo::new(4);

/// The kernel of `psf`, built once per process (an Airy kernel tens of
/// pixels wide takes about a second).
pub fn shared_kernel(psf: &Psf) -> Result<Arc<Kernel>> {
    KERNELS.get_or_build(psf.clone(), || kernel(psf))
}

/// Energy a kernel encloses before it is cut and renormalised.
pub const ENCLOSED: f64 = 0.995;
/// Largest kernel half-width, px (a 257 × 257 kernel).
pub const MAX_HALF_WIDTH: usize = 128;

/// A normalised, pixel-integrated kernel of odd side `2 half + 1`.
#[derive(Debug, Clone, PartialEq)]
pub struct Kernel {
    pub half: usize,
    /// Row-major weights, summing to 1.
    pub weights: Vec<f64>,
}

/// Half-width (px) of the kernel: the radius enclosing [`ENCLOSED`],
/// plus one pixel for the pixel's own extent.
fn half_width(psf: &Psf) -> Result<usize> {
    let (mut lo, mut hi) = (0.0, 1.0);
    while psf.encircled_energy(hi) < ENCLOSED {
        hi *= 2.0;
        if hi > MAX_HALF_WIDTH as f64 {
            return Err(Error::invalid(
                "camera.psf",
                format!("the PSF is wider than {MAX_HALF_WIDTH} px at {ENCLOSED} of its energy"),
            ));
        }
    }
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if psf.encircled_energy(mid) < ENCLOSED {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Ok(hi.ceil() as usize + 1)
}

/// The pixel-integrated kernel of `psf`.
pub fn kernel(psf: &Psf) -> Result<Kernel> {
    psf.validate("camera.psf")?;
    let half = half_width(psf)?;
    let n = 2 * half + 1;
    let mut weights: Vec<f64> = (0..n * n)
        .into_par_iter()
        .map(|k| {
            let (i, j) = ((k % n) as f64 - half as f64, (k / n) as f64 - half as f64);
            pixel_integral(psf, i, j)
        })
        .collect();
    let sum: f64 = weights.iter().sum();
    weights.iter_mut().for_each(|w| *w /= sum);
    Ok(Kernel { half, weights })
}

/// The PSF integrated over the pixel square centred at offset (i, j).
fn pixel_integral(psf: &Psf, i: f64, j: f64) -> f64 {
    match *psf {
        Psf::Gaussian { sigma_px } => {
            let cdf = |x: f64| 0.5 * libm::erfc(-x / (sigma_px * std::f64::consts::SQRT_2));
            let span = |c: f64| cdf(c + 0.5) - cdf(c - 0.5);
            span(i) * span(j)
        }
        Psf::Airy { .. } => {
            let scale = psf.airy_scale_px();
            // Intensity normalised so that it integrates to 1 over the
            // plane: I(r) = π/(4 s²) · [2 J1(x)/x]², x = π r / s.
            let norm = std::f64::consts::PI / (4.0 * scale * scale);
            let intensity = |x: f64, y: f64| {
                let q = std::f64::consts::PI * (x * x + y * y).sqrt() / scale;
                let a = if q < 1e-8 { 1.0 } else { 2.0 * libm::j1(q) / q };
                norm * a * a
            };
            gauss_legendre_square(i, j, &intensity)
        }
    }
}

/// ∫∫ f over the unit square centred at (i, j): 8 × 8 Gauss–Legendre
/// points on each of 4 × 4 sub-squares (the Airy rings are a pixel or
/// more apart at the f-numbers of navigation cameras).
fn gauss_legendre_square(i: f64, j: f64, f: &dyn Fn(f64, f64) -> f64) -> f64 {
    const X: [f64; 4] = [
        0.183_434_642_495_65,
        0.525_532_409_916_329,
        0.796_666_477_413_627,
        0.960_289_856_497_536,
    ];
    const W: [f64; 4] = [
        0.362_683_783_378_362,
        0.313_706_645_877_887,
        0.222_381_034_453_374,
        0.101_228_536_290_376,
    ];
    let nodes: Vec<(f64, f64)> = X
        .iter()
        .zip(W)
        .flat_map(|(&x, w)| [(-x, w), (x, w)])
        .collect();
    let sub = 4;
    let h = 1.0 / sub as f64;
    let mut sum = 0.0;
    for sy in 0..sub {
        for sx in 0..sub {
            let (cx, cy) = (
                i - 0.5 + (sx as f64 + 0.5) * h,
                j - 0.5 + (sy as f64 + 0.5) * h,
            );
            for &(u, wu) in &nodes {
                for &(v, wv) in &nodes {
                    sum += wu * wv * f(cx + 0.5 * h * u, cy + 0.5 * h * v);
                }
            }
        }
    }
    sum * 0.25 * h * h
}

impl Kernel {
    /// `image` (`width` × `height`, row-major) convolved with the kernel;
    /// light beyond the frame is lost, none comes in from outside it.
    /// Only the box of the non-zero pixels grown by the kernel's half-width
    /// is computed (the rest stays 0). Small kernels directly, large ones
    /// (an Airy pattern's rings reach tens of pixels) by FFT.
    pub fn convolve(&self, image: &[f32], width: usize, height: usize) -> Vec<f32> {
        self.convolve_in_box(image, width, height).0
    }

    /// [`Kernel::convolve`], and the box [x0, x1) × [y0, y1) it computed
    /// (outside it the result is 0; None when the image is all 0).
    pub fn convolve_in_box(
        &self,
        image: &[f32],
        width: usize,
        height: usize,
    ) -> (Vec<f32>, Option<[usize; 4]>) {
        let mut out = image.to_vec();
        let area = self.convolve_in_place(&mut out, width, height);
        (out, area)
    }

    /// [`Kernel::convolve_in_box`] writing the result over `image` (no
    /// new frame: outside the box it computes the image is 0 already).
    pub fn convolve_in_place(
        &self,
        image: &mut [f32],
        width: usize,
        height: usize,
    ) -> Option<[usize; 4]> {
        self.convolve_in_place_within(image, width, height, [0, width, 0, height])
    }

    /// [`Kernel::convolve_in_place`] when every non-zero pixel of `image`
    /// lies in the box `within` = [x0, x1, y0, y1) (a render's region of
    /// interest): the non-zero box is looked for inside it only, so the
    /// frame's other pixels are not read. The result is the same.
    pub fn convolve_in_place_within(
        &self,
        image: &mut [f32],
        width: usize,
        height: usize,
        within: [usize; 4],
    ) -> Option<[usize; 4]> {
        let b = nonzero_box_within(image, width, height, within)?;
        let grow = |lo: usize, hi: usize, n: usize| {
            (lo.saturating_sub(self.half), (hi + self.half).min(n))
        };
        let (x0, x1) = grow(b.0, b.1, width);
        let (y0, y1) = grow(b.2, b.3, height);
        let (cw, ch) = (x1 - x0, y1 - y0);
        // The crop holds every source pixel and every pixel they reach.
        let crop: Vec<f32> = (y0..y1)
            .flat_map(|y| image[y * width + x0..y * width + x1].iter().copied())
            .collect();
        let blurred = if 2 * self.half < DIRECT_MAX_SIDE {
            match self.folded() {
                Some(folded) => {
                    // Written straight over the image's box (the crop
                    // keeps the source).
                    let rows = &mut image[y0 * width..y1 * width];
                    let wide = avx_available();
                    let to = Target { rows, width, x0 };
                    convolve_folded_into(&folded, self.half, &crop, cw, ch, wide, to);
                    return Some([x0, x1, y0, y1]);
                }
                None => self.convolve_direct(&crop, cw, ch),
            }
        } else {
            self.convolve_fft(&crop, cw, ch)
        };
        for (y, row) in blurred.chunks(cw).enumerate() {
            image[(y0 + y) * width + x0..][..cw].copy_from_slice(row);
        }
        Some([x0, x1, y0, y1])
    }

    /// The kernel's quadrant w[dy][dx] (dy, dx in 0..=half, row-major),
    /// when it is mirror-symmetric in x and in y (the Airy and Gaussian
    /// kernels are, to rounding: within 1e-9 of the peak); each weight the
    /// mean of its four mirror images.
    fn folded(&self) -> Option<Vec<f32>> {
        let (h, n) = (self.half, 2 * self.half + 1);
        let w = |x: usize, y: usize| self.weights[y * n + x];
        let peak = self.weights.iter().copied().fold(0.0, f64::max);
        let mut quadrant = Vec::with_capacity((h + 1) * (h + 1));
        for dy in 0..=h {
            for dx in 0..=h {
                let four = [
                    w(h + dx, h + dy),
                    w(h - dx, h + dy),
                    w(h + dx, h - dy),
                    w(h - dx, h - dy),
                ];
                let mean = four.iter().sum::<f64>() / 4.0;
                if four.iter().any(|v| (v - mean).abs() > 1e-9 * peak) {
                    return None;
                }
                quadrant.push(mean as f32);
            }
        }
        Some(quadrant)
    }

    /// Direct convolution, one kernel weight at a time along whole rows
    /// (the inner loop vectorises).
    fn convolve_direct(&self, image: &[f32], width: usize, height: usize) -> Vec<f32> {
        let (h, n) = (self.half, 2 * self.half + 1);
        let weights: Vec<f32> = self.weights.iter().map(|&w| w as f32).collect();
        let mut out = vec![0.0f32; image.len()];
        out.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
            for ky in 0..n {
                // Source row y + h − ky.
                let Some(sy) = (y + h).checked_sub(ky).filter(|&s| s < height) else {
                    continue;
                };
                let src = &image[sy * width..][..width];
                for (kx, &w) in weights[ky * n..][..n].iter().enumerate() {
                    // Output x takes source x + h − kx.
                    let lo = kx.saturating_sub(h);
                    let hi = (width + kx).saturating_sub(h).min(width);
                    if lo >= hi {
                        continue;
                    }
                    let s = &src[lo + h - kx..hi + h - kx];
                    for (o, &v) in row[lo..hi].iter_mut().zip(s) {
                        *o += w * v;
                    }
                }
            }
        });
        out
    }

    /// Linear convolution by FFT on a grid padded by the kernel's
    /// half-width (so nothing wraps around into the frame).
    fn convolve_fft(&self, image: &[f32], width: usize, height: usize) -> Vec<f32> {
        let (pw, ph) = (width + 2 * self.half, height + 2 * self.half);
        let mut img = vec![Complex::new(0.0, 0.0); pw * ph];
        for (y, row) in image.chunks(width).enumerate() {
            for (x, &v) in row.iter().enumerate() {
                img[y * pw + x] = Complex::new(v as f64, 0.0);
            }
        }
        // The kernel's centre at (0, 0), its negative offsets wrapped.
        let n = 2 * self.half + 1;
        let mut ker = vec![Complex::new(0.0, 0.0); pw * ph];
        for ky in 0..n {
            for kx in 0..n {
                let dx = (kx + pw - self.half) % pw;
                let dy = (ky + ph - self.half) % ph;
                ker[dy * pw + dx] = Complex::new(self.weights[ky * n + kx], 0.0);
            }
        }
        let mut planner = FftPlanner::new();
        fft_2d(&mut img, pw, ph, &mut planner, false);
        fft_2d(&mut ker, pw, ph, &mut planner, false);
        img.par_iter_mut().zip(&ker).for_each(|(a, b)| *a *= b);
        fft_2d(&mut img, pw, ph, &mut planner, true);
        let scale = 1.0 / (pw * ph) as f64;
        let mut out = vec![0.0f32; width * height];
        for (y, row) in out.chunks_mut(width).enumerate() {
            for (x, o) in row.iter_mut().enumerate() {
                *o = (img[y * pw + x].re * scale) as f32;
            }
        }
        out
    }
}

/// Lanes of one block of output pixels [`convolve_folded`] keeps in
/// registers.
const LANES: usize = 8;

/// Direct convolution with a mirror-symmetric kernel given by its
/// quadrant `quadrant` (see [`Kernel::folded`]): per output row, the
/// source rows y ± dy are summed first, then each sum is convolved with
/// the quadrant's row dy, pairing x ± dx; blocks of [`LANES`] output
/// pixels accumulate every (dy, dx) in registers. A third of the
/// multiplications of the plain sum, and no accumulator traffic.
#[cfg(test)]
fn convolve_folded(
    quadrant: &[f32],
    half: usize,
    image: &[f32],
    width: usize,
    height: usize,
) -> Vec<f32> {
    convolve_folded_blocks(quadrant, half, image, width, height, avx_available())
}

/// [`convolve_folded`] in blocks of [`WIDE`] pixels ([`folded_block_avx`])
/// when `wide` (the CPU must have AVX), else of [`LANES`].
#[cfg(test)]
fn convolve_folded_blocks(
    quadrant: &[f32],
    half: usize,
    image: &[f32],
    width: usize,
    height: usize,
    wide: bool,
) -> Vec<f32> {
    let mut out = vec![0.0f32; image.len()];
    let to = Target {
        rows: &mut out,
        width,
        x0: 0,
    };
    convolve_folded_into(quadrant, half, image, width, height, wide, to);
    out
}

/// Where [`convolve_folded_into`] writes: output row y at
/// `rows[y * width + x0..]`.
struct Target<'a> {
    rows: &'a mut [f32],
    width: usize,
    x0: usize,
}

/// [`convolve_folded_blocks`] written into `to`. The row sums y ± dy are
/// written in one pass (a + b, or the one row inside the image: the same
/// values as adding them to zeros, the rates being ≥ 0, never −0); the
/// zeros around them are never written.
fn convolve_folded_into(
    quadrant: &[f32],
    half: usize,
    image: &[f32],
    width: usize,
    height: usize,
    wide: bool,
    to: Target,
) {
    let side = half + 1;
    let padded = width.div_ceil(WIDE) * WIDE;
    // A row sum with `half` zeros before it and enough after it.
    let stride = padded + 2 * half;
    let row_of = |sy: usize| &image[sy * width..][..width];
    to.rows
        .par_chunks_mut(to.width)
        .take(height)
        .enumerate()
        .for_each_init(
            || vec![0.0f32; side * stride],
            |sums, (y, out)| {
                let row = &mut out[to.x0..][..width];
                let mut rows = 0;
                for dy in 0..side {
                    let target = &mut sums[dy * stride + half..][..width];
                    let below = (y + dy < height).then(|| row_of(y + dy));
                    let above = (dy > 0 && dy <= y).then(|| row_of(y - dy));
                    match (below, above) {
                        (Some(a), Some(b)) => {
                            for ((t, &a), &b) in target.iter_mut().zip(a).zip(b) {
                                *t = a + b;
                            }
                        }
                        (Some(a), None) | (None, Some(a)) => target.copy_from_slice(a),
                        // No row at this dy, nor at any larger one.
                        (None, None) => break,
                    }
                    rows = dy + 1;
                }
                let mut x0 = 0;
                while x0 < width {
                    let n = if wide { WIDE } else { LANES };
                    let rows_from = |dy: usize| &sums[dy * stride + x0..][..n + 2 * half];
                    let m = n.min(width - x0);
                    if wide {
                        // SAFETY: `wide` is true only when the CPU has AVX.
                        let acc =
                            unsafe { folded_block_avx(rows_from, quadrant, side, rows, half) };
                        row[x0..x0 + m].copy_from_slice(&acc[..m]);
                    } else {
                        let acc = folded_block(rows_from, quadrant, side, rows, half);
                        row[x0..x0 + m].copy_from_slice(&acc[..m]);
                    }
                    x0 += n;
                }
            },
        );
}

/// One block of [`LANES`] output pixels of [`convolve_folded`]:
/// Σ_dy Σ_dx w[dy][dx] (s_dy[x + dx] + s_dy[x − dx]) over the row sums
/// `sum(dy)` (each starting `half` before the block), the even dx and the
/// odd dx in two accumulators that do not wait on each other. SSE2 (part
/// of every x86-64) keeps the accumulators in registers.
#[cfg(target_arch = "x86_64")]
#[inline]
fn folded_block<'a>(
    sum: impl Fn(usize) -> &'a [f32],
    quadrant: &[f32],
    side: usize,
    rows: usize,
    half: usize,
) -> [f32; LANES] {
    use std::arch::x86_64::*;
    // SAFETY: SSE is part of every x86-64; each load and store touches a
    // bounds-checked slice of 4 floats.
    unsafe {
        let load = |s: &[f32], i: usize| _mm_loadu_ps(s[i..i + 4].as_ptr());
        let (mut even0, mut even1) = (_mm_setzero_ps(), _mm_setzero_ps());
        let (mut odd0, mut odd1) = (_mm_setzero_ps(), _mm_setzero_ps());
        for dy in 0..rows {
            let s = sum(dy);
            let w = &quadrant[dy * side..][..side];
            let w0 = _mm_set1_ps(w[0]);
            even0 = _mm_add_ps(even0, _mm_mul_ps(w0, load(s, half)));
            even1 = _mm_add_ps(even1, _mm_mul_ps(w0, load(s, half + 4)));
            for (dx, &weight) in w.iter().enumerate().skip(1) {
                let wd = _mm_set1_ps(weight);
                let p0 = _mm_add_ps(load(s, half + dx), load(s, half - dx));
                let p1 = _mm_add_ps(load(s, half + dx + 4), load(s, half - dx + 4));
                if dx % 2 == 1 {
                    odd0 = _mm_add_ps(odd0, _mm_mul_ps(wd, p0));
                    odd1 = _mm_add_ps(odd1, _mm_mul_ps(wd, p1));
                } else {
                    even0 = _mm_add_ps(even0, _mm_mul_ps(wd, p0));
                    even1 = _mm_add_ps(even1, _mm_mul_ps(wd, p1));
                }
            }
        }
        let mut out = [0.0f32; LANES];
        _mm_storeu_ps(out[..4].as_mut_ptr(), _mm_add_ps(even0, odd0));
        _mm_storeu_ps(out[4..8].as_mut_ptr(), _mm_add_ps(even1, odd1));
        out
    }
}

/// Output pixels of one block of [`folded_block_avx`].
const WIDE: usize = 16;

/// Whether this CPU runs [`folded_block_avx`].
fn avx_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// [`folded_block`] on [`WIDE`] output pixels in 256-bit registers: the
/// same operations in the same order per pixel (no fused multiply-add),
/// so the result is bit for bit [`folded_block`]'s, in half the
/// instructions.
///
/// # Safety
/// The CPU must have AVX ([`avx_available`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
unsafe fn folded_block_avx<'a>(
    sum: impl Fn(usize) -> &'a [f32],
    quadrant: &[f32],
    side: usize,
    rows: usize,
    half: usize,
) -> [f32; WIDE] {
    use std::arch::x86_64::*;
    let (mut even0, mut even1) = (_mm256_setzero_ps(), _mm256_setzero_ps());
    let (mut odd0, mut odd1) = (_mm256_setzero_ps(), _mm256_setzero_ps());
    for dy in 0..rows {
        let s = sum(dy);
        // Every load below reads 8 floats within `s` (its length is
        // WIDE + 2 half): checked once here.
        assert!(s.len() >= WIDE + 2 * half);
        let p = s.as_ptr();
        let w = &quadrant[dy * side..][..side];
        let w0 = _mm256_set1_ps(w[0]);
        even0 = _mm256_add_ps(even0, _mm256_mul_ps(w0, _mm256_loadu_ps(p.add(half))));
        even1 = _mm256_add_ps(even1, _mm256_mul_ps(w0, _mm256_loadu_ps(p.add(half + 8))));
        for (dx, &weight) in w.iter().enumerate().skip(1) {
            let wd = _mm256_set1_ps(weight);
            let p0 = _mm256_add_ps(
                _mm256_loadu_ps(p.add(half + dx)),
                _mm256_loadu_ps(p.add(half - dx)),
            );
            let p1 = _mm256_add_ps(
                _mm256_loadu_ps(p.add(half + dx + 8)),
                _mm256_loadu_ps(p.add(half - dx + 8)),
            );
            if dx % 2 == 1 {
                odd0 = _mm256_add_ps(odd0, _mm256_mul_ps(wd, p0));
                odd1 = _mm256_add_ps(odd1, _mm256_mul_ps(wd, p1));
            } else {
                even0 = _mm256_add_ps(even0, _mm256_mul_ps(wd, p0));
                even1 = _mm256_add_ps(even1, _mm256_mul_ps(wd, p1));
            }
        }
    }
    let mut out = [0.0f32; WIDE];
    _mm256_storeu_ps(out[..8].as_mut_ptr(), _mm256_add_ps(even0, odd0));
    _mm256_storeu_ps(out[8..].as_mut_ptr(), _mm256_add_ps(even1, odd1));
    out
}

/// Never called: [`avx_available`] is false off x86-64.
#[cfg(not(target_arch = "x86_64"))]
unsafe fn folded_block_avx<'a>(
    sum: impl Fn(usize) -> &'a [f32],
    quadrant: &[f32],
    side: usize,
    rows: usize,
    half: usize,
) -> [f32; WIDE] {
    let lo = folded_block(&sum, quadrant, side, rows, half);
    let hi = folded_block(|dy| &sum(dy)[LANES..], quadrant, side, rows, half);
    std::array::from_fn(|l| if l < LANES { lo[l] } else { hi[l - LANES] })
}

/// [`folded_block`] without SSE, in the same order of operations.
#[cfg(not(target_arch = "x86_64"))]
fn folded_block<'a>(
    sum: impl Fn(usize) -> &'a [f32],
    quadrant: &[f32],
    side: usize,
    rows: usize,
    half: usize,
) -> [f32; LANES] {
    let (mut even, mut odd) = ([0.0f32; LANES], [0.0f32; LANES]);
    for dy in 0..rows {
        let s = sum(dy);
        let w = &quadrant[dy * side..][..side];
        for l in 0..LANES {
            even[l] += w[0] * s[half + l];
        }
        for dx in 1..side {
            let acc = if dx % 2 == 1 { &mut odd } else { &mut even };
            for l in 0..LANES {
                acc[l] += w[dx] * (s[half + dx + l] + s[half - dx + l]);
            }
        }
    }
    std::array::from_fn(|l| even[l] + odd[l])
}

/// A point source's pixels: `weights` (row-major, side `2 half + 1`,
/// summing to 1) for the block centred on pixel (`i0`, `j0`).
#[derive(Debug, Clone, PartialEq)]
pub struct Stamp {
    pub i0: isize,
    pub j0: isize,
    pub half: usize,
    pub weights: Vec<f64>,
}

/// The PSF of a point source at continuous pixel position (`u`, `v`)
/// integrated over each pixel of the block around the pixel holding it,
/// cut and renormalised as a [`Kernel`] is (so a star's sub-pixel
/// position survives, which a kernel centred on a pixel would lose).
pub fn point_stamp(psf: &Psf, u: f64, v: f64) -> Result<Stamp> {
    psf.validate("camera.psf")?;
    let half = half_width(psf)?;
    let (i0, j0) = (u.floor() as isize, v.floor() as isize);
    let n = 2 * half + 1;
    let mut weights: Vec<f64> = (0..n * n)
        .map(|k| {
            let i = i0 + (k % n) as isize - half as isize;
            let j = j0 + (k / n) as isize - half as isize;
            pixel_integral(psf, i as f64 + 0.5 - u, j as f64 + 0.5 - v)
        })
        .collect();
    let sum: f64 = weights.iter().sum();
    weights.iter_mut().for_each(|w| *w /= sum);
    Ok(Stamp {
        i0,
        j0,
        half,
        weights,
    })
}

/// The span [a, b) from a row's first to its last non-zero value (NaN
/// counts as non-zero), None if all are 0: whole chunks of 16 are tested
/// first (a test that vectorises), so an empty row costs little.
pub fn nonzero_span(row: &[f32]) -> Option<(usize, usize)> {
    const CHUNK: usize = 16;
    #[inline]
    fn nonzero(c: &[f32]) -> bool {
        let mut bits = 0u32;
        for v in c {
            // Without the sign bit: −0 is 0.
            bits |= v.to_bits() << 1;
        }
        bits != 0
    }
    let chunks = row.len().div_ceil(CHUNK);
    let chunk = |i: usize| &row[i * CHUNK..((i + 1) * CHUNK).min(row.len())];
    let first_chunk = (0..chunks).find(|&i| nonzero(chunk(i)))?;
    let last_chunk = (first_chunk..chunks).rev().find(|&i| nonzero(chunk(i)))?;
    let lit = |v: &f32| v.to_bits() << 1 != 0;
    let a = first_chunk * CHUNK + row[first_chunk * CHUNK..].iter().position(lit)?;
    let end = (last_chunk * CHUNK + CHUNK).min(row.len());
    let b = row[..end].iter().rposition(lit)? + 1;
    Some((a, b))
}

/// The box [x0, x1) × [y0, y1) of the non-zero pixels, None if all are 0.
pub(crate) fn nonzero_box(image: &[f32], width: usize) -> Option<(usize, usize, usize, usize)> {
    let height = image.len() / width.max(1);
    nonzero_box_within(image, width, height, [0, width, 0, height])
}

/// [`nonzero_box`] of the pixels inside `within` = [x0, x1, y0, y1)
/// (clipped to the frame); the pixels outside it are not read.
pub(crate) fn nonzero_box_within(
    image: &[f32],
    width: usize,
    height: usize,
    within: [usize; 4],
) -> Option<(usize, usize, usize, usize)> {
    let [x0, x1, y0, y1] = within;
    let (x1, y1) = (x1.min(width), y1.min(height));
    if x0 >= x1 || y0 >= y1 {
        return None;
    }
    let rows: Vec<(usize, usize, usize)> = image[y0 * width..y1 * width]
        .par_chunks(width)
        .enumerate()
        .filter_map(|(y, row)| nonzero_span(&row[x0..x1]).map(|(a, b)| (y0 + y, x0 + a, x0 + b)))
        .collect();
    let (y0, y1) = (rows.first()?.0, rows.last()?.0 + 1);
    let x0 = rows.iter().map(|r| r.1).min()?;
    let x1 = rows.iter().map(|r| r.2).max()?;
    Some((x0, x1, y0, y1))
}

/// Kernels up to this side are applied directly.
const DIRECT_MAX_SIDE: usize = 15;

/// In-place 2-D FFT (unnormalised) of a `w × h` row-major grid: rows, then
/// columns through a transpose.
fn fft_2d(
    data: &mut [Complex<f64>],
    w: usize,
    h: usize,
    planner: &mut FftPlanner<f64>,
    inverse: bool,
) {
    let plan = |p: &mut FftPlanner<f64>, n: usize| {
        if inverse {
            p.plan_fft_inverse(n)
        } else {
            p.plan_fft_forward(n)
        }
    };
    let rows = plan(planner, w);
    data.par_chunks_mut(w).for_each(|r| rows.process(r));
    let mut t = vec![Complex::new(0.0, 0.0); w * h];
    for y in 0..h {
        for x in 0..w {
            t[x * h + y] = data[y * w + x];
        }
    }
    let cols = plan(planner, h);
    t.par_chunks_mut(h).for_each(|c| cols.process(c));
    for x in 0..w {
        for y in 0..h {
            data[y * w + x] = t[x * h + y];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kernels_sum_to_one_and_are_symmetric() {
        for psf in [
            Psf::Gaussian { sigma_px: 0.7 },
            Psf::Airy {
                f_number: 4.0,
                wavelength_m: 650e-9,
                pitch_m: 5.5e-6,
            },
        ] {
            let k = kernel(&psf).unwrap();
            let n = 2 * k.half + 1;
            assert!((k.weights.iter().sum::<f64>() - 1.0).abs() < 1e-12);
            for y in 0..n {
                for x in 0..n {
                    let (a, b) = (k.weights[y * n + x], k.weights[x * n + (n - 1 - y)]);
                    assert!((a - b).abs() < 1e-12 * k.weights[k.half * n + k.half]);
                }
            }
        }
    }

    /// FFT and direct convolution agree (an asymmetric image, a kernel
    /// made wide enough for the FFT path).
    #[test]
    fn fft_and_direct_convolution_agree() {
        let k = kernel(&Psf::Gaussian { sigma_px: 3.0 }).unwrap();
        assert!(2 * k.half + 1 > DIRECT_MAX_SIDE);
        let (w, h) = (37, 23);
        let img: Vec<f32> = (0..w * h).map(|i| ((i * 7919) % 101) as f32).collect();
        let (a, b) = (k.convolve_direct(&img, w, h), k.convolve_fft(&img, w, h));
        for (x, y) in a.iter().zip(&b) {
            assert!((x - y).abs() < 1e-3, "{x} vs {y}");
        }
    }

    /// The folded (symmetric) convolution equals the plain direct sum for
    /// the Gaussian and Airy kernels, on an image with edges and zeros.
    #[test]
    fn folded_and_direct_convolution_agree() {
        for psf in [
            Psf::Gaussian { sigma_px: 1.1 },
            Psf::Airy {
                f_number: 2.5,
                wavelength_m: 650e-9,
                pitch_m: 13.3e-6,
            },
            Psf::Airy {
                f_number: 4.0,
                wavelength_m: 650e-9,
                pitch_m: 5.5e-6,
            },
        ] {
            let k = kernel(&psf).unwrap();
            let folded = k.folded().expect("symmetric kernel");
            let (w, h) = (29, 17);
            let img: Vec<f32> = (0..w * h)
                .map(|i| {
                    if i % 5 == 0 {
                        0.0
                    } else {
                        ((i * 7919) % 101) as f32
                    }
                })
                .collect();
            let (a, b) = (
                k.convolve_direct(&img, w, h),
                convolve_folded(&folded, k.half, &img, w, h),
            );
            for (x, y) in a.iter().zip(&b) {
                assert!(
                    (x - y).abs() < 1e-4 * x.abs().max(1.0),
                    "{psf:?}: {x} vs {y}"
                );
            }
        }
        // An asymmetric kernel is not folded.
        let mut k = kernel(&Psf::Gaussian { sigma_px: 1.1 }).unwrap();
        k.weights[0] *= 1.5;
        assert!(k.folded().is_none());
    }

    /// The AVX blocks give the SSE blocks' result bit for bit (same
    /// operations per pixel), on widths that are not a multiple of 16.
    #[test]
    fn wide_blocks_equal_narrow_ones_bit_for_bit() {
        if !avx_available() {
            return;
        }
        let k = kernel(&Psf::Airy {
            f_number: 2.5,
            wavelength_m: 650e-9,
            pitch_m: 13.3e-6,
        })
        .unwrap();
        let folded = k.folded().expect("symmetric kernel");
        for (w, h) in [(37usize, 19usize), (16, 5), (3, 4)] {
            let img: Vec<f32> = (0..w * h)
                .map(|i| ((i * 7919) % 101) as f32 * 0.37)
                .collect();
            let wide = convolve_folded_blocks(&folded, k.half, &img, w, h, true);
            let narrow = convolve_folded_blocks(&folded, k.half, &img, w, h, false);
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&wide), bits(&narrow), "{w} × {h}");
        }
    }

    /// A box holding every non-zero pixel gives the whole frame's result;
    /// a box that misses some shows they are not read.
    #[test]
    fn convolution_within_a_box_equals_the_whole_frame() {
        let k = kernel(&Psf::Gaussian { sigma_px: 1.1 }).unwrap();
        let (w, h) = (50usize, 40usize);
        let mut img = vec![0.0f32; w * h];
        for (x, y, v) in [(10, 12, 3.0), (30, 25, 1.5), (31, 12, 2.0)] {
            img[y * w + x] = v;
        }
        let mut whole = img.clone();
        let whole_box = k.convolve_in_place(&mut whole, w, h);
        for within in [[10, 32, 12, 26], [0, 50, 5, 30], [8, 60, 0, 99]] {
            let mut part = img.clone();
            let part_box = k.convolve_in_place_within(&mut part, w, h, within);
            assert_eq!(part_box, whole_box, "{within:?}");
            assert_eq!(part, whole, "{within:?}");
        }
        let mut missed = img.clone();
        k.convolve_in_place_within(&mut missed, w, h, [0, 20, 0, 40]);
        assert_ne!(missed, whole);
    }

    /// The crop to the non-zero box changes nothing: a small blob in a
    /// large frame convolves as the brute-force sum written here does.
    #[test]
    fn cropped_convolution_matches_brute_force() {
        for sigma in [0.8, 3.0] {
            let k = kernel(&Psf::Gaussian { sigma_px: sigma }).unwrap();
            let (w, h) = (60usize, 45usize);
            let mut img = vec![0.0f32; w * h];
            for (x, y, v) in [(3, 40, 5.0), (20, 21, 1.0), (22, 23, 2.0), (58, 2, 7.0)] {
                img[y * w + x] = v;
            }
            let got = k.convolve(&img, w, h);
            let n = 2 * k.half as isize + 1;
            for y in 0..h as isize {
                for x in 0..w as isize {
                    let mut want = 0.0f64;
                    for ky in 0..n {
                        for kx in 0..n {
                            let (sx, sy) = (x + k.half as isize - kx, y + k.half as isize - ky);
                            if (0..w as isize).contains(&sx) && (0..h as isize).contains(&sy) {
                                want += k.weights[(ky * n + kx) as usize]
                                    * img[(sy * w as isize + sx) as usize] as f64;
                            }
                        }
                    }
                    let g = got[(y * w as isize + x) as usize] as f64;
                    assert!((g - want).abs() < 1e-5, "{sigma} ({x}, {y}): {g} vs {want}");
                }
            }
        }
    }

    /// The chunked span finds the first and last non-zero value as a
    /// plain scan does, across chunk edges, with −0 as 0 and NaN as not.
    #[test]
    fn nonzero_span_matches_a_plain_scan() {
        for len in [1usize, 15, 16, 17, 40] {
            for a in 0..len {
                for b in a..len {
                    let mut row = vec![0.0f32; len];
                    row[a] = 1.0;
                    row[b] = f32::NAN;
                    if a > 0 {
                        row[a - 1] = -0.0;
                    }
                    assert_eq!(nonzero_span(&row), Some((a, b + 1)), "{len} {a} {b}");
                }
            }
            assert_eq!(nonzero_span(&vec![-0.0f32; len]), None);
        }
    }

    #[test]
    fn shared_kernels_equal_fresh_ones() {
        let psf = Psf::Gaussian { sigma_px: 1.3 };
        let a = shared_kernel(&psf).unwrap();
        let b = shared_kernel(&psf).unwrap();
        assert!(Arc::ptr_eq(&a, &b));
        assert_eq!(*a, kernel(&psf).unwrap());
    }

    #[test]
    fn bad_parameters_are_refused() {
        assert!(kernel(&Psf::Gaussian { sigma_px: f64::NAN }).is_err());
        assert!(kernel(&Psf::Gaussian { sigma_px: 0.0 }).is_err());
        let wide = Psf::Airy {
            f_number: 500.0,
            wavelength_m: 1e-5,
            pitch_m: 1e-6,
        };
        let e = kernel(&wide).unwrap_err().to_string();
        assert!(e.contains("camera.psf"), "{e}");
    }
}
