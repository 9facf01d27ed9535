//! Structural similarity (SSIM) exactly as in Wang, Bovik, Sheikh &
//! Simoncelli, "Image quality assessment: from error visibility to
//! structural similarity", IEEE TIP 13(4), 2004, and their reference
//! implementation `ssim_index.m`:
//!
//! - local statistics with an 11×11 circular-symmetric Gaussian window,
//!   σ = 1.5 samples, normalised to unit sum;
//! - C1 = (K1 L)², C2 = (K2 L)², K1 = 0.01, K2 = 0.03, C3 = C2 / 2;
//! - biased local (co)variances (window-weighted, no N−1 correction);
//! - the map is computed only where the window fits inside the image
//!   ("valid" filtering), so it is (W−10)×(H−10); the mean SSIM is its mean.
//!
//! `L` is the dynamic range of the pixel values; for AMIE DN images use
//! `L = 1023` (10-bit full scale, [`AMIE_DATA_RANGE`]), so the constants do
//! not depend on the image content. Alongside SSIM = l·c·s the three
//! components are returned as image means: luminance
//! l = (2μxμy + C1)/(μx² + μy² + C1), contrast c = (2σxσy + C2)/(σx² + σy² + C2),
//! structure s = (σxy + C3)/(σxσy + C3). With C3 = C2/2 the product of the
//! three maps equals the SSIM map pixel by pixel (not so for their means).

use super::raster::Raster;
use crate::error::{Error, Result};

/// K1 of Wang et al. 2004.
pub const K1: f64 = 0.01;
/// K2 of Wang et al. 2004.
pub const K2: f64 = 0.03;
/// Window size (11) and Gaussian σ (1.5 px).
pub const WINDOW: usize = 11;
pub const SIGMA: f64 = 1.5;
/// Dynamic range to use for AMIE DN images (10-bit full scale).
pub const AMIE_DATA_RANGE: f64 = 1023.0;

/// SSIM of two images.
#[derive(Debug, Clone)]
pub struct SsimResult {
    /// Mean SSIM over the map.
    pub mssim: f64,
    /// Mean luminance term l.
    pub luminance: f64,
    /// Mean contrast term c.
    pub contrast: f64,
    /// Mean structure term s.
    pub structure: f64,
    /// SSIM map, (W−10)×(H−10); map pixel (i, j) is centred on image pixel
    /// (i + 5, j + 5) ([`SsimResult::offset`]).
    pub map: Raster,
    pub luminance_map: Raster,
    pub contrast_map: Raster,
    pub structure_map: Raster,
    /// Offset of the map's pixel (0, 0) in the images (5).
    pub offset: usize,
}

/// Normalised 1-D Gaussian of `size` taps; the 2-D window is its outer
/// product (separable and identical to the normalised 2-D Gaussian).
pub fn gaussian_kernel(size: usize, sigma: f64) -> Vec<f64> {
    let c = (size as f64 - 1.0) / 2.0;
    let k: Vec<f64> = (0..size)
        .map(|i| (-((i as f64 - c).powi(2)) / (2.0 * sigma * sigma)).exp())
        .collect();
    let s: f64 = k.iter().sum();
    k.into_iter().map(|v| v / s).collect()
}

/// "Valid" separable filtering of a row-major f64 image.
fn filter_valid(img: &[f64], w: usize, h: usize, k: &[f64]) -> (Vec<f64>, usize, usize) {
    let n = k.len();
    let (ow, oh) = (w + 1 - n, h + 1 - n);
    let mut tmp = vec![0.0; ow * h];
    for r in 0..h {
        let row = &img[r * w..(r + 1) * w];
        for c in 0..ow {
            tmp[r * ow + c] = k.iter().zip(&row[c..c + n]).map(|(a, b)| a * b).sum();
        }
    }
    let mut out = vec![0.0; ow * oh];
    for r in 0..oh {
        for c in 0..ow {
            let mut s = 0.0;
            for (i, kv) in k.iter().enumerate() {
                s += kv * tmp[(r + i) * ow + c];
            }
            out[r * ow + c] = s;
        }
    }
    (out, ow, oh)
}

/// SSIM of `a` and `b` (same size, at least 11×11) with dynamic range
/// `data_range` (L).
pub fn ssim(a: &Raster, b: &Raster, data_range: f64) -> Result<SsimResult> {
    a.check_same_size(b, "ssim")?;
    if a.width < WINDOW || a.height < WINDOW {
        return Err(Error::invalid(
            "ssim",
            format!(
                "images of {}x{} are smaller than the 11x11 window",
                a.width, a.height
            ),
        ));
    }
    if data_range.is_nan() || data_range <= 0.0 {
        return Err(Error::invalid(
            "ssim.data_range",
            format!("{data_range} must be positive"),
        ));
    }
    let (w, h) = (a.width, a.height);
    let x: Vec<f64> = a.data.iter().map(|&v| v as f64).collect();
    let y: Vec<f64> = b.data.iter().map(|&v| v as f64).collect();
    let k = gaussian_kernel(WINDOW, SIGMA);
    let prod = |p: &[f64], q: &[f64]| p.iter().zip(q).map(|(u, v)| u * v).collect::<Vec<f64>>();
    let (mx, ow, oh) = filter_valid(&x, w, h, &k);
    let (my, _, _) = filter_valid(&y, w, h, &k);
    let (mxx, _, _) = filter_valid(&prod(&x, &x), w, h, &k);
    let (myy, _, _) = filter_valid(&prod(&y, &y), w, h, &k);
    let (mxy, _, _) = filter_valid(&prod(&x, &y), w, h, &k);
    let c1 = (K1 * data_range).powi(2);
    let c2 = (K2 * data_range).powi(2);
    let c3 = c2 / 2.0;
    let n = ow * oh;
    let (mut m_s, mut m_l, mut m_c, mut m_st) =
        (vec![0f32; n], vec![0f32; n], vec![0f32; n], vec![0f32; n]);
    let (mut sum_s, mut sum_l, mut sum_c, mut sum_st) = (0.0, 0.0, 0.0, 0.0);
    for i in 0..n {
        let (ux, uy) = (mx[i], my[i]);
        let vx = (mxx[i] - ux * ux).max(0.0);
        let vy = (myy[i] - uy * uy).max(0.0);
        let cxy = mxy[i] - ux * uy;
        let (sx, sy) = (vx.sqrt(), vy.sqrt());
        let l = (2.0 * ux * uy + c1) / (ux * ux + uy * uy + c1);
        let c = (2.0 * sx * sy + c2) / (vx + vy + c2);
        let st = (cxy + c3) / (sx * sy + c3);
        // Wang's combined form (identical to l*c*st when C3 = C2/2).
        let s =
            ((2.0 * ux * uy + c1) * (2.0 * cxy + c2)) / ((ux * ux + uy * uy + c1) * (vx + vy + c2));
        m_s[i] = s as f32;
        m_l[i] = l as f32;
        m_c[i] = c as f32;
        m_st[i] = st as f32;
        sum_s += s;
        sum_l += l;
        sum_c += c;
        sum_st += st;
    }
    let nf = n as f64;
    Ok(SsimResult {
        mssim: sum_s / nf,
        luminance: sum_l / nf,
        contrast: sum_c / nf,
        structure: sum_st / nf,
        map: Raster::new(ow, oh, m_s)?,
        luminance_map: Raster::new(ow, oh, m_l)?,
        contrast_map: Raster::new(ow, oh, m_c)?,
        structure_map: Raster::new(ow, oh, m_st)?,
        offset: WINDOW / 2,
    })
}
