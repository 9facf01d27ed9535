//! The EMVA 1288 sensor chain: mean electrons per pixel in, a noisy
//! quantised DN frame out. Owns the `[camera.sensor]` parameters, the
//! seeded per-pixel PRNU and DSNU maps, and the order the effects apply in
//! (the EMVA 1288 reference simulator's):
//!
//! 1. light mean μ_k = PRNU_k · (rate_k · t + smear_k), smear_k =
//!    `transfer_time` / height · Σ_column rate (frame transfer: every pixel
//!    crosses its whole column while the shutter is open);
//! 2. charge q_k = Poisson(dark_current · t) + Poisson(μ_k) + DSNU_k;
//! 3. optional blooming: charge above the full well spills along the
//!    column, half up and half down, into pixels with room (conserved
//!    unless the whole column is full);
//! 4. read noise: q_k + σ_read · N(0, 1);
//! 5. full-well clip, system gain K [DN/e⁻], offset, rounding and the ADC
//!    range [0, 2^bits − 1].
//!
//! PRNU_k = max(0, 1 + prnu · N(0, 1)) and DSNU_k = dsnu · N(0, 1) are
//! fixed per pixel by `seed`; the temporal noise of frame f is drawn from
//! (seed, f, pixel), so a frame is reproducible whatever the thread count.

pub mod rng;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use rng::Rng;

/// Random stream of the PRNU map.
const PRNU_STREAM: u64 = 1;
/// Random stream of the DSNU map.
const DSNU_STREAM: u64 = 2;
/// Random streams of frames start here (+ frame index).
const FRAME_STREAM: u64 = 1 << 32;

/// `[camera.sensor]` of a scene file (docs/SCENE.md), as written.
#[derive(Deserialize, Clone, Debug, Default)]
#[serde(deny_unknown_fields)]
pub struct SensorFile {
    #[serde(default)]
    seed: u64,
    #[serde(default)]
    dark_current: f64,
    #[serde(default)]
    read_noise: f64,
    #[serde(default)]
    prnu: f64,
    #[serde(default)]
    dsnu: f64,
    #[serde(default)]
    offset: f64,
    #[serde(default)]
    transfer_time: f64,
    #[serde(default)]
    blooming: bool,
}

/// Checked sensor parameters (the camera's full well, gain and bits
/// complete them).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SensorParams {
    /// Seed of the PRNU/DSNU maps and of every frame's noise.
    pub seed: u64,
    /// Dark current [e⁻/s].
    pub dark_current: f64,
    /// Read noise [e⁻ rms].
    pub read_noise: f64,
    /// PRNU: relative rms of the per-pixel response.
    pub prnu: f64,
    /// DSNU: rms of the per-pixel dark offset [e⁻].
    pub dsnu: f64,
    /// Offset (bias) [DN].
    pub offset: f64,
    /// Frame-transfer time [s] (0: no smear).
    pub transfer_time: f64,
    /// Charge above the full well spills along the column.
    pub blooming: bool,
}

impl SensorFile {
    /// Range-checks every key; `max_dn` bounds the offset.
    pub fn check(&self, max_dn: f64) -> Result<SensorParams> {
        Ok(SensorParams {
            seed: self.seed,
            dark_current: range(self.dark_current, 0.0, 1e9, "dark_current")?,
            read_noise: range(self.read_noise, 0.0, 1e6, "read_noise")?,
            prnu: range(self.prnu, 0.0, 1.0, "prnu")?,
            dsnu: range(self.dsnu, 0.0, 1e6, "dsnu")?,
            offset: range(self.offset, 0.0, max_dn, "offset")?,
            transfer_time: range(self.transfer_time, 0.0, 1e3, "transfer_time")?,
            blooming: self.blooming,
        })
    }
}

fn range(value: f64, lo: f64, hi: f64, key: &str) -> Result<f64> {
    if value.is_finite() && (lo..=hi).contains(&value) {
        Ok(value)
    } else {
        Err(Error::invalid(
            format!("camera.sensor.{key}"),
            format!("must be within [{lo:e}, {hi:e}], got {value:e}"),
        ))
    }
}

/// The camera's ADC side: what turns electrons into DN.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Readout {
    /// Full-well capacity [e⁻].
    pub full_well: f64,
    /// System gain K [DN/e⁻].
    pub gain: f64,
    /// ADC bits.
    pub bits: u32,
}

impl Readout {
    /// Largest DN the ADC outputs.
    pub fn max_dn(&self) -> f64 {
        (2f64.powi(self.bits as i32) - 1.0).max(1.0)
    }
}

/// One sensor: parameters, readout and its fixed-pattern maps.
#[derive(Clone, Debug)]
pub struct Sensor {
    params: SensorParams,
    readout: Readout,
    width: usize,
    height: usize,
    prnu: Vec<f32>,
    dsnu: Vec<f32>,
}

/// One frame read out.
#[derive(Clone, Debug)]
pub struct SensorFrame {
    /// Quantised DN, row-major.
    pub dn: Vec<u16>,
    /// Pixels at the full well or the largest DN.
    pub saturated: u64,
}

impl Sensor {
    /// A sensor of `width` × `height` pixels with its seeded maps.
    pub fn new(params: SensorParams, readout: Readout, width: usize, height: usize) -> Sensor {
        let n = width * height;
        let map = |stream: u64, f: &(dyn Fn(f64) -> f64 + Sync)| -> Vec<f32> {
            (0..n as u64)
                .into_par_iter()
                .map(|k| f(Rng::new(params.seed, stream, k).normal()) as f32)
                .collect()
        };
        let prnu = if params.prnu > 0.0 {
            map(PRNU_STREAM, &|z| (1.0 + params.prnu * z).max(0.0))
        } else {
            vec![1.0; n]
        };
        let dsnu = if params.dsnu > 0.0 {
            map(DSNU_STREAM, &|z| params.dsnu * z)
        } else {
            vec![0.0; n]
        };
        Sensor {
            params,
            readout,
            width,
            height,
            prnu,
            dsnu,
        }
    }

    /// The parameters.
    pub fn params(&self) -> &SensorParams {
        &self.params
    }

    /// The PRNU map (relative response per pixel).
    pub fn prnu_map(&self) -> &[f32] {
        &self.prnu
    }

    /// The DSNU map [e⁻].
    pub fn dsnu_map(&self) -> &[f32] {
        &self.dsnu
    }

    /// Frame `frame` of an exposure `exposure` [s] of a scene giving
    /// `rate` [e⁻/s] per pixel (row-major, before PRNU).
    pub fn expose(&self, rate: &[f32], exposure: f64, frame: u64) -> SensorFrame {
        assert_eq!(rate.len(), self.width * self.height, "rate image size");
        let mut charge = self.collect_charge(rate, exposure, frame);
        if self.params.blooming {
            bloom(&mut charge, self.width, self.readout.full_well);
        }
        self.read_out(&charge, frame)
    }

    /// Steps 1–2: smear, PRNU, dark and shot noise, DSNU [e⁻].
    fn collect_charge(&self, rate: &[f32], exposure: f64, frame: u64) -> Vec<f64> {
        let p = &self.params;
        let w = self.width;
        let smear = self.smear(rate);
        let dark = p.dark_current * exposure;
        (0..rate.len())
            .into_par_iter()
            .map(|k| {
                let mut rng = Rng::new(p.seed, FRAME_STREAM + frame, k as u64);
                let light = self.prnu[k] as f64 * (rate[k] as f64 * exposure + smear[k % w]);
                rng.poisson(dark) + rng.poisson(light) + self.dsnu[k] as f64
            })
            .collect()
    }

    /// Smear electrons per column: transfer_time / height · Σ_column rate.
    fn smear(&self, rate: &[f32]) -> Vec<f64> {
        let (w, h) = (self.width, self.height);
        if self.params.transfer_time <= 0.0 {
            return vec![0.0; w];
        }
        let per_row = self.params.transfer_time / h as f64;
        (0..w)
            .into_par_iter()
            .map(|i| per_row * (0..h).map(|j| rate[j * w + i] as f64).sum::<f64>())
            .collect()
    }

    /// Steps 4–5: read noise, full well, gain, offset, rounding, ADC.
    fn read_out(&self, charge: &[f64], frame: u64) -> SensorFrame {
        let p = &self.params;
        let r = &self.readout;
        let max_dn = r.max_dn();
        // The read noise takes draws after the charge's: a second stream.
        let stream = FRAME_STREAM + frame + (1 << 31);
        let dn: Vec<u16> = charge
            .par_iter()
            .enumerate()
            .map(|(k, &q)| {
                let read = if p.read_noise > 0.0 {
                    p.read_noise * Rng::new(p.seed, stream, k as u64).normal()
                } else {
                    0.0
                };
                let e = (q + read).min(r.full_well);
                (p.offset + r.gain * e)
                    .round()
                    .clamp(0.0, max_dn)
                    .min(u16::MAX as f64) as u16
            })
            .collect();
        let sat_dn = (p.offset + r.gain * r.full_well).round().min(max_dn);
        let saturated = dn.iter().filter(|&&v| v as f64 >= sat_dn).count() as u64;
        SensorFrame { dn, saturated }
    }
}

/// Charge above `full_well` spills along each column: half of a pixel's
/// excess runs down and half up, each passing full pixels until one has
/// room; what reaches an end of the column turns back. Charge is
/// conserved unless the whole column fills (the rest is drained).
pub fn bloom(charge: &mut [f64], width: usize, full_well: f64) {
    let height = charge.len() / width;
    let mut columns: Vec<Vec<f64>> = (0..width)
        .map(|i| (0..height).map(|j| charge[j * width + i]).collect())
        .collect();
    columns
        .par_iter_mut()
        .for_each(|c| bloom_column(c, full_well));
    for (i, c) in columns.iter().enumerate() {
        for (j, &q) in c.iter().enumerate() {
            charge[j * width + i] = q;
        }
    }
}

/// One column of [`bloom`].
fn bloom_column(c: &mut [f64], full_well: f64) {
    let n = c.len();
    let mut up = vec![0.0; n];
    let mut down = 0.0;
    // Split each excess; sweep the downward halves to the bottom.
    for j in 0..n {
        let excess = (c[j] - full_well).max(0.0);
        c[j] -= excess;
        up[j] = excess / 2.0;
        let room = full_well - c[j];
        let carried = down + excess / 2.0;
        let taken = carried.min(room).max(0.0);
        c[j] += taken;
        down = carried - taken;
    }
    // The upward halves (and what reached the bottom) sweep to the top.
    let mut carried = down;
    for j in (0..n).rev() {
        carried += up[j];
        let taken = carried.min(full_well - c[j]).max(0.0);
        c[j] += taken;
        carried -= taken;
    }
    // What reached the top turns back down into any room left.
    for q in c.iter_mut() {
        let taken = carried.min(full_well - *q).max(0.0);
        *q += taken;
        carried -= taken;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blooming_conserves_charge_and_fills_neighbours() {
        let fw = 100.0;
        let mut c = vec![10.0, 20.0, 450.0, 30.0, 0.0, 5.0];
        let before: f64 = c.iter().sum();
        bloom_column(&mut c, fw);
        let after: f64 = c.iter().sum();
        assert!((before - after).abs() < 1e-9, "{before} {after}");
        assert!(c.iter().all(|&q| q <= fw + 1e-12), "{c:?}");
        // 350 e⁻ excess: 175 down fills pixel 3 (70) then 4 (100), 5 gets 5;
        // 175 up fills pixel 1 (80) and 0 (90), 5 left turn back down.
        assert_eq!(c[2], fw);
        assert_eq!(c[3], fw);
        assert_eq!(c[1], fw);
        assert_eq!(c[0], fw);
    }

    #[test]
    fn a_full_column_drains_the_rest() {
        let mut c = vec![300.0, 300.0];
        bloom_column(&mut c, 100.0);
        assert_eq!(c, vec![100.0, 100.0]);
    }

    #[test]
    fn smear_adds_the_column_mean_over_the_transfer() {
        let params = SensorParams {
            seed: 1,
            dark_current: 0.0,
            read_noise: 0.0,
            prnu: 0.0,
            dsnu: 0.0,
            offset: 0.0,
            transfer_time: 0.01,
            blooming: false,
        };
        let readout = Readout {
            full_well: 1e9,
            gain: 1.0,
            bits: 16,
        };
        let s = Sensor::new(params, readout, 2, 4);
        let rate = [0.0, 0.0, 4000.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        // Column 0 holds 4000 e⁻/s: each of its pixels gets 0.01/4 × 4000 =
        // 10 e⁻ of smear; column 1 none.
        assert_eq!(s.smear(&rate), vec![10.0, 0.0]);
    }
}
