//! The simulated screen's spatial non-uniformity: a smooth falloff and
//! gradient, a seeded mid-spatial-frequency mura, and the black leak's own
//! pattern (an edge glow), with maps of both at the pixel centres.
//!
//! With n the position relative to the screen centre (−1 … 1 across each
//! axis):
//!
//! U_main(p) = (1 − falloff/2 · (n_x² + n_y²)) · (1 + g_x n_x + g_y n_y) · (1 + m(p))
//! U_leak(p) = U_main(p) · (1 + black_nonuniformity · (n_x⁴ + n_y⁴) / 2)
//!
//! m(p) = mura_rms · √(2/N) · Σ_i cos(2π (u cos θ_i + v sin θ_i) / P_i + φ_i)
//!
//! over N = `mura_waves` plane waves with periods P_i log-uniform in
//! `mura_periods_px`, directions θ_i and phases φ_i uniform (seeded): its
//! rms over a large area is `mura_rms`.

use rayon::prelude::*;

use super::config::ScreenTruth;
use super::noise::Rng;

/// Random stream of the mura's waves.
const MURA_STREAM: u64 = 3;

/// One mura wave: wave vector (cycles per px × 2π) and phase.
#[derive(Debug, Clone, PartialEq)]
struct Wave {
    kx: f64,
    ky: f64,
    phase: f64,
}

/// The screen's non-uniformity: the functions, and maps at pixel centres.
#[derive(Debug, Clone)]
pub struct ScreenPattern {
    size: [usize; 2],
    falloff: f64,
    gradient: [f64; 2],
    amplitude: f64,
    black_nonuniformity: f64,
    waves: Vec<Wave>,
    /// U_main at pixel centres, row-major.
    pub main_map: Vec<f32>,
    /// U_leak at pixel centres, row-major.
    pub leak_map: Vec<f32>,
}

impl ScreenPattern {
    /// Draws the mura from `seed` and tabulates both maps.
    pub fn new(cfg: &ScreenTruth, seed: u64) -> ScreenPattern {
        let mut rng = Rng::new(seed, MURA_STREAM, 0);
        let [p0, p1] = cfg.mura_periods_px;
        let n = if cfg.mura_rms > 0.0 {
            cfg.mura_waves
        } else {
            0
        };
        let waves = (0..n)
            .map(|_| {
                let period = (p0.ln() + (p1.ln() - p0.ln()) * rng.uniform()).exp();
                let theta = std::f64::consts::TAU * rng.uniform();
                let k = std::f64::consts::TAU / period;
                Wave {
                    kx: k * theta.cos(),
                    ky: k * theta.sin(),
                    phase: std::f64::consts::TAU * rng.uniform(),
                }
            })
            .collect();
        let mut p = ScreenPattern {
            size: cfg.resolution,
            falloff: cfg.falloff,
            gradient: cfg.gradient,
            amplitude: if n > 0 {
                cfg.mura_rms * (2.0 / n as f64).sqrt()
            } else {
                0.0
            },
            black_nonuniformity: cfg.black_nonuniformity,
            waves,
            main_map: Vec::new(),
            leak_map: Vec::new(),
        };
        p.tabulate();
        p
    }

    /// Fills the maps; each wave's cosine split into row and column
    /// factors (cos(a + b) = cos a cos b − sin a sin b).
    fn tabulate(&mut self) {
        let [w, h] = self.size;
        let centre = |n: usize| (0..n).map(|i| i as f64 + 0.5).collect::<Vec<_>>();
        let (us, vs) = (centre(w), centre(h));
        let cols: Vec<Vec<(f64, f64)>> = self
            .waves
            .iter()
            .map(|wv| {
                us.iter()
                    .map(|u| (wv.kx * u + wv.phase).sin_cos())
                    .collect()
            })
            .collect();
        let mut main = vec![0f32; w * h];
        let mut leak = vec![0f32; w * h];
        main.par_chunks_mut(w)
            .zip(leak.par_chunks_mut(w))
            .enumerate()
            .for_each(|(y, (mrow, lrow))| {
                let v = vs[y];
                let rows: Vec<(f64, f64)> =
                    self.waves.iter().map(|wv| (wv.ky * v).sin_cos()).collect();
                for x in 0..w {
                    let mut sum = 0.0;
                    for (col, (sb, cb)) in cols.iter().zip(&rows) {
                        let (sa, ca) = col[x];
                        sum += ca * cb - sa * sb;
                    }
                    let u = us[x];
                    let m = self.smooth(u, v) * (1.0 + self.amplitude * sum);
                    mrow[x] = m as f32;
                    lrow[x] = (m * self.leak_factor(u, v)) as f32;
                }
            });
        self.main_map = main;
        self.leak_map = leak;
    }

    fn normalised(&self, u: f64, v: f64) -> (f64, f64) {
        let [w, h] = self.size;
        (
            (u - 0.5 * w as f64) / (0.5 * w as f64),
            (v - 0.5 * h as f64) / (0.5 * h as f64),
        )
    }

    /// Falloff × gradient at (u, v).
    pub fn smooth(&self, u: f64, v: f64) -> f64 {
        let (nx, ny) = self.normalised(u, v);
        let falloff = 1.0 - 0.5 * self.falloff * (nx * nx + ny * ny);
        falloff * (1.0 + self.gradient[0] * nx + self.gradient[1] * ny)
    }

    /// The mura m(u, v), relative.
    pub fn mura(&self, u: f64, v: f64) -> f64 {
        let sum: f64 = self
            .waves
            .iter()
            .map(|w| (w.kx * u + w.ky * v + w.phase).cos())
            .sum();
        self.amplitude * sum
    }

    /// U_leak / U_main at (u, v): the black leak's edge glow.
    pub fn leak_factor(&self, u: f64, v: f64) -> f64 {
        let (nx, ny) = self.normalised(u, v);
        1.0 + self.black_nonuniformity * 0.5 * (nx.powi(4) + ny.powi(4))
    }

    /// U_main at continuous position (u, v).
    pub fn main(&self, u: f64, v: f64) -> f64 {
        self.smooth(u, v) * (1.0 + self.mura(u, v))
    }

    /// U_leak at continuous position (u, v).
    pub fn leak(&self, u: f64, v: f64) -> f64 {
        self.main(u, v) * self.leak_factor(u, v)
    }
}
