//! The EMVA 1288 sensor chain: mean electrons per pixel in, a noisy
//! quantised DN frame out. Owns the `[camera.sensor]` parameters, the
//! seeded per-pixel PRNU and DSNU maps, and the order the effects apply in
//! (the EMVA 1288 reference simulator's):
//!
//! 1. light mean μ_k = PRNU_k · rate_k · t + smear_c, smear_c =
//!    `transfer_time` / height · Σ_column PRNU · rate (frame transfer: every
//!    pixel's charge crosses its whole column while the shutter is open,
//!    collecting in each photosite it passes);
//! 2. charge q_k = Poisson(dark_current · t) + Poisson(μ_k) + DSNU_k (one
//!    Poisson draw of the summed mean: the same distribution);
//! 3. optional blooming: charge above the full well spills along the
//!    column, half up and half down, into pixels with room (conserved
//!    unless the whole column is full);
//! 4. read noise: q_k + σ_read · N(0, 1);
//! 5. full-well clip, system gain K [DN/e⁻], offset, rounding and the ADC
//!    range [0, 2^bits − 1].
//!
//! Three optional effects ([`extras`], off by default) complete it for the
//! simulated facility's camera, which reads out through this same chain:
//! the non-linearity e (1 − β e / full_well) of the charge before the read
//! noise (the clip then sits at the full well's response), a per-row offset
//! σ_row · N(0, 1) added with the read noise, and shot noise off.
//!
//! PRNU_k = max(0, 1 + prnu · N(0, 1)) and DSNU_k = dsnu · N(0, 1) are
//! fixed per pixel by `seed`; the temporal noise of frame f is drawn from
//! (seed, f, pixel), so a frame is reproducible whatever the thread count.
//! [`Sensor::shared`] keeps the maps of recent cameras, so a render loop
//! builds them once. The light and dark charge is one exact Poisson draw
//! ([`sampler::poisson`]: inversion below a mean of 10 e⁻, Ahrens and
//! Dieter's PD above; tests/sensor_sampler.rs checks it against the pmf).
//!
//! A dark pixel (light mean exactly 0: no rate in its row span and no
//! smear in its column) has charge Poisson(d) + σ_read N(0, 1) + DSNU_k,
//! d = dark current × exposure: one distribution shifted by DSNU_k. It is
//! drawn from [`dark::DarkTable`], 2¹⁶ equally likely cells each holding
//! that distribution's mean over the cell, with 16 bits of one 64-bit hash
//! per pixel (4 pixels a hash); the table's mean is exact and its variance
//! within 10⁻⁵ of d + σ² (tests/sensor_dark_table.rs, which also checks
//! dark frames' DN histograms by chi-square and KS). A row offset shifts
//! it like DSNU. The table applies when σ_read > 0, shot noise is on, β is
//! 0 and no dark pixel can reach the full well; other pixels are drawn one
//! by one as above.
//!
//! A pixel whose only light is its column's smear (rate 0 in a smeared
//! column) draws Poisson(d + smear_c) by inversion of its column's table
//! ([`column::PoissonTable`], when the column has one) with 32 bits of its
//! hash, and its read noise from 16 others as a lit pixel does.

pub mod column;
pub mod dark;
pub mod extras;
pub mod rng;
pub mod sampler;

use std::sync::Arc;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::memo::Memo;
use dark::DarkTable;
use rng::Stream;

/// Sensors (their maps) of the most recent cameras.
static SENSORS: Memo<(SensorParams, Readout, usize, usize), Sensor> = Memo::new(2);

/// Random stream of the PRNU and DSNU maps.
const MAP_STREAM: u64 = 1;
/// Random streams of frames start here (+ frame index).
const FRAME_STREAM: u64 = 1 << 32;
/// Random streams of the dark pixels' table draws (+ frame index).
const DARK_STREAM: u64 = 1 << 33;

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
    #[serde(default)]
    nonlinearity: f64,
    #[serde(default)]
    row_noise: f64,
    /// Absent: on.
    #[serde(default)]
    shot_noise: Option<bool>,
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
    /// Non-linearity β: the charge reads as e (1 − β e / full_well).
    pub nonlinearity: f64,
    /// Per-row offset [e⁻ rms], the same along a row of one frame.
    pub row_noise: f64,
    /// Poisson charge (true) or its mean (false).
    pub shot_noise: bool,
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
            nonlinearity: range(self.nonlinearity, 0.0, 0.5, "nonlinearity")?,
            row_noise: range(self.row_noise, 0.0, 1e6, "row_noise")?,
            shot_noise: self.shot_noise.unwrap_or(true),
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
    /// The largest DSNU [e⁻]: whether a dark pixel can reach the full well.
    dsnu_max: f64,
    /// `readout.max_dn()`, computed once (it is a power of two less one).
    max_dn: f64,
    /// The charge the clip after the read noise caps at: the full well's
    /// response ([`extras::response`]; the full well when β = 0).
    full_scale: f64,
}

/// What [`Sensor::expose_lit`] counts while it writes a frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FrameCounts {
    /// Pixels at the full well or the largest DN.
    pub saturated: u64,
    /// The frame's largest DN.
    pub peak_dn: u16,
}

impl FrameCounts {
    /// The counts of a frame from its rows'.
    fn sum(rows: impl Iterator<Item = FrameCounts>) -> FrameCounts {
        rows.fold(FrameCounts::default(), |a, b| FrameCounts {
            saturated: a.saturated + b.saturated,
            peak_dn: a.peak_dn.max(b.peak_dn),
        })
    }
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
        let (mut prnu, mut dsnu) = (vec![1.0f32; n], vec![0.0f32; n]);
        if params.prnu > 0.0 || params.dsnu > 0.0 {
            let maps = Stream::new(params.seed, MAP_STREAM);
            prnu.par_iter_mut()
                .zip(dsnu.par_iter_mut())
                .enumerate()
                .for_each(|(k, (g, o))| {
                    let mut rng = maps.at(k as u64);
                    *g = (1.0 + params.prnu * rng.normal_fast()).max(0.0) as f32;
                    *o = (params.dsnu * rng.normal_fast()) as f32;
                });
        }
        let dsnu_max = dsnu.iter().copied().fold(0.0f32, f32::max) as f64;
        Sensor {
            params,
            readout,
            width,
            height,
            prnu,
            dsnu,
            dsnu_max,
            max_dn: readout.max_dn(),
            full_scale: extras::response(readout.full_well, params.nonlinearity, readout.full_well),
        }
    }

    /// The sensor of these parameters, its maps built once per process
    /// for the two most recent cameras ([`Sensor::new`] otherwise).
    pub fn shared(
        params: SensorParams,
        readout: Readout,
        width: usize,
        height: usize,
    ) -> Arc<Sensor> {
        let key = (params, readout, width, height);
        let built = SENSORS.get_or_build(key, || {
            Ok::<_, std::convert::Infallible>(Sensor::new(params, readout, width, height))
        });
        match built {
            Ok(sensor) => sensor,
            Err(never) => match never {},
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
        let mut dn = vec![0u16; rate.len()];
        let saturated = self.expose_into(rate, exposure, frame, &mut dn);
        SensorFrame { dn, saturated }
    }

    /// [`Sensor::expose`] written over `dn` (every pixel: a render reuses
    /// its frame), returning the saturated pixels' count.
    pub fn expose_into(&self, rate: &[f32], exposure: f64, frame: u64, dn: &mut [u16]) -> u64 {
        let whole = [0, self.width, 0, self.height];
        self.expose_lit(rate, whole, exposure, frame, dn).saturated
    }

    /// [`Sensor::expose_into`] when every non-zero `rate` lies in the box
    /// `lit` = [x0, x1, y0, y1) (a render knows where its light is): the
    /// rows' lit spans are looked for inside it only, so the rest of the
    /// rate image is not read. The frame is the same as `expose_into`'s.
    pub fn expose_lit(
        &self,
        rate: &[f32],
        lit: [usize; 4],
        exposure: f64,
        frame: u64,
        dn: &mut [u16],
    ) -> FrameCounts {
        assert_eq!(rate.len(), self.width * self.height, "rate image size");
        assert_eq!(dn.len(), rate.len(), "frame size");
        let w = self.width;
        let stream = Stream::new(self.params.seed, FRAME_STREAM + frame);
        let spans = lit_spans(rate, w, lit);
        let smear = self.smear_in(rate, &spans);
        let dark_mean = self.params.dark_current * exposure;
        let columns = if self.params.shot_noise {
            column::column_tables(dark_mean, &smear, &self.unlit_counts(&spans))
        } else {
            vec![None; w]
        };
        let draw = Draw {
            smear,
            columns,
            dark: DarkDraw::new(dark_mean),
            exposure,
            rows: extras::row_offsets(&stream, rate.len(), self.height, self.params.row_noise),
            stream,
            normal_cells: dark::standard_normal_cells(),
        };
        let table = self.dark_table(exposure, &draw.rows);
        let dark = (*table).as_ref().map(|t| DarkLookup::new(t, self, frame));
        let smeared = runs(&draw.smear);
        let r = &self.readout;
        // The saturation level is a whole DN in [0, max_dn] (offset ≥ 0).
        let sat_dn = quantise(self.params.offset + r.gain * self.full_scale, r.max_dn()) as u32;
        let counts_in = |row: &[u16]| FrameCounts {
            saturated: count_at_least(row, sat_dn),
            peak_dn: row.iter().copied().max().unwrap_or(0),
        };
        // One pass draws and digitises every pixel, counts the saturated
        // ones while the row is in cache and notes the columns holding
        // charge over the full well; only those are bloomed. The runs of
        // a row outside its lit span and the smeared columns are dark:
        // drawn from the table when there is one.
        let rows: Vec<(Vec<usize>, FrameCounts)> = dn
            .par_chunks_mut(w)
            .enumerate()
            .map(|(j, row)| {
                let mut over = Vec::new();
                for_segments(w, &smeared, spans[j], |a, b, is_lit| match &dark {
                    Some(dark) if !is_lit => {
                        let dsnu = &self.dsnu[j * w + a..][..b - a];
                        dark.fill(&mut row[a..b], j * w + a, dsnu, draw.rows[j] as f32)
                    }
                    _ => for_span_parts(a, b, spans[j], |a, b, in_span| {
                        if in_span {
                            self.draw_run(rate, &draw, j, a, &mut row[a..b], &mut over)
                        } else {
                            self.draw_smear_only(&draw, j, a, &mut row[a..b], &mut over)
                        }
                    }),
                });
                (over, counts_in(row))
            })
            .collect();
        let mut counts = FrameCounts::sum(rows.iter().map(|(_, c)| *c));
        let mut over: Vec<usize> = rows.into_iter().flat_map(|(o, _)| o).collect();
        over.sort_unstable();
        over.dedup();
        if !over.is_empty() {
            self.bloom_columns(&over, rate, &draw, dn);
            let rows: Vec<FrameCounts> = dn.par_chunks(w).map(counts_in).collect();
            counts = FrameCounts::sum(rows.into_iter());
        }
        counts
    }

    /// The table of this exposure's dark pixels, when one applies: read
    /// noise > 0, shot noise on, no non-linearity (the table holds the
    /// linear charge plus read noise) and no dark pixel can reach the full
    /// well with its DSNU and row offset `rows` (so neither the clip nor
    /// blooming concerns them).
    fn dark_table(&self, exposure: f64, rows: &[f64]) -> Arc<Option<DarkTable>> {
        let p = &self.params;
        if !p.shot_noise || p.nonlinearity != 0.0 {
            return Arc::new(None);
        }
        let row_max = rows.iter().copied().fold(0.0, f64::max);
        let table = DarkTable::shared(p.dark_current * exposure, p.read_noise);
        match table.as_ref() {
            Some(t) if t.upper + self.dsnu_max + row_max < self.readout.full_well => table,
            _ => Arc::new(None),
        }
    }

    /// Step 3 on the columns `columns`: their charge drawn again (the
    /// draws are a function of the pixel), bloomed and digitised into `dn`.
    fn bloom_columns(&self, columns: &[usize], rate: &[f32], draw: &Draw, dn: &mut [u16]) {
        let (w, h) = (self.width, self.height);
        let bloomed: Vec<(usize, Vec<u16>)> = columns
            .par_iter()
            .map(|&i| {
                let (mut charge, read): (Vec<f64>, Vec<f64>) = (0..h)
                    .map(|j| self.collect(rate, draw, i, j * w + i))
                    .unzip();
                bloom_column(&mut charge, self.readout.full_well);
                let column = charge
                    .iter()
                    .zip(&read)
                    .enumerate()
                    .map(|(j, (&q, &r))| self.digitise(q, r + draw.rows[j]))
                    .collect();
                (i, column)
            })
            .collect();
        for (i, column) in bloomed {
            for (j, v) in column.into_iter().enumerate() {
                dn[j * w + i] = v;
            }
        }
    }

    /// Steps 1–5 for the pixels `out` of row `j` from column `a` on,
    /// each drawn as [`Sensor::collect`]; the columns holding charge over
    /// the full well go to `over` when blooming is on.
    fn draw_run(
        &self,
        rate: &[f32],
        draw: &Draw,
        j: usize,
        a: usize,
        out: &mut [u16],
        over: &mut Vec<usize>,
    ) {
        let (n, k0) = (out.len(), j * self.width + a);
        let maps = rate[k0..k0 + n]
            .iter()
            .zip(&self.prnu[k0..k0 + n])
            .zip(&self.dsnu[k0..k0 + n])
            .zip(&draw.smear[a..a + n]);
        let (bloom, full_well, row) = (self.params.blooming, self.readout.full_well, draw.rows[j]);
        for (x, (o, (((&r, &g), &d), &s))) in out.iter_mut().zip(maps).enumerate() {
            let (q, noise) = self.charge(draw, r, g, d, s, a + x, (k0 + x) as u64);
            if bloom && q > full_well {
                over.push(a + x);
            }
            *o = self.digitise(q, noise + row);
        }
    }

    /// [`Sensor::draw_run`] for pixels outside their row's lit span (rate
    /// 0: their light is their column's smear alone), so neither the rate
    /// nor the PRNU map is read: the same draws, the same frame.
    fn draw_smear_only(
        &self,
        draw: &Draw,
        j: usize,
        a: usize,
        out: &mut [u16],
        over: &mut Vec<usize>,
    ) {
        let (n, k0) = (out.len(), j * self.width + a);
        let (bloom, full_well, row) = (self.params.blooming, self.readout.full_well, draw.rows[j]);
        let sigma = self.params.read_noise;
        let columns = draw.columns[a..a + n].iter().zip(&draw.smear[a..a + n]);
        let maps = self.dsnu[k0..k0 + n].iter().zip(columns);
        for (x, (o, (&d, (table, &s)))) in out.iter_mut().zip(maps).enumerate() {
            let k = (k0 + x) as u64;
            let (q, noise) = match table {
                Some(table) => {
                    let bits = draw.stream.bits(k);
                    let read = sigma * draw.normal_cells[(bits & 0xffff) as usize] as f64;
                    (table.draw(column::table_bits(bits)) + d as f64, read)
                }
                // PRNU × 0 is 0: the map's value does not matter.
                None => self.charge(draw, 0.0, 1.0, d, s, a + x, k),
            };
            if bloom && q > full_well {
                over.push(a + x);
            }
            *o = self.digitise(q, noise + row);
        }
    }

    /// Steps 1, 2 and the draw of 4 for pixel `k` (in column `column`):
    /// [`Sensor::charge`] of its maps' values.
    #[inline]
    fn collect(&self, rate: &[f32], draw: &Draw, column: usize, k: usize) -> (f64, f64) {
        let (r, g, d) = (rate[k], self.prnu[k], self.dsnu[k]);
        self.charge(draw, r, g, d, draw.smear[column], column, k as u64)
    }

    /// Steps 1, 2 and the draw of 4 for pixel `k` (in column `column`) of
    /// rate `rate`, PRNU `prnu`, DSNU `dsnu` and smear `smear`: its charge
    /// (light and dark electrons, one exact Poisson draw of their summed
    /// mean, plus DSNU) and its read noise [e⁻]. One 64-bit hash gives 48
    /// bits to the Poisson draw (32 to the column's table for a pixel lit
    /// by smear alone, else [`sampler::poisson_of_hash`]) and 16 to the read
    /// noise, σ times a cell of [`dark::standard_normal_cells`]; only PD's
    /// rare steps Q and E hash again, from the pixel's generator.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn charge(
        &self,
        draw: &Draw,
        rate: f32,
        prnu: f32,
        dsnu: f32,
        smear: f64,
        column: usize,
        k: u64,
    ) -> (f64, f64) {
        let bits = draw.stream.bits(k);
        let read = self.params.read_noise * draw.normal_cells[(bits & 0xffff) as usize] as f64;
        if rate == 0.0 {
            if let Some(table) = &draw.columns[column] {
                let electrons = table.draw(column::table_bits(bits));
                return (electrons + dsnu as f64, read);
            }
        }
        let light = prnu as f64 * rate as f64 * draw.exposure + smear;
        if !self.params.shot_noise {
            return (draw.dark.mean + light + dsnu as f64, read);
        }
        let mean = draw.dark.mean + light;
        let mut more = draw.stream.at(k);
        let more = || more.uniform();
        let electrons = match draw.dark.limit {
            // e^(−mean) once per frame for a dark pixel.
            Some(limit) if light == 0.0 => sampler::poisson_of_hash(mean, bits, more, || limit),
            _ => sampler::poisson_of_hash(mean, bits, more, || (-mean).exp()),
        };
        (electrons + dsnu as f64, read)
    }

    /// Step 5 on charge `charge` and read (and row) noise `noise` [e⁻]:
    /// the non-linearity, full well, gain, offset, rounding and ADC range.
    #[inline]
    fn digitise(&self, charge: f64, noise: f64) -> u16 {
        let r = &self.readout;
        let electrons = extras::response(charge, self.params.nonlinearity, r.full_well) + noise;
        // Not `min`: a plain compare (a NaN charge reads as full scale).
        let clipped = if electrons < self.full_scale {
            electrons
        } else {
            self.full_scale
        };
        quantise(self.params.offset + r.gain * clipped, self.max_dn)
    }

    /// Smear electrons per column: transfer_time / height · Σ_column PRNU · rate.
    #[cfg(test)]
    fn smear(&self, rate: &[f32]) -> Vec<f64> {
        let spans: Vec<_> = rate.chunks(self.width).map(lit_span).collect();
        self.smear_in(rate, &spans)
    }

    /// [`Sensor::smear`] summing each row over its lit span `spans[row]`
    /// only (the rest of the row is 0).
    fn smear_in(&self, rate: &[f32], spans: &[Option<(usize, usize)>]) -> Vec<f64> {
        let (w, h) = (self.width, self.height);
        if self.params.transfer_time <= 0.0 {
            return vec![0.0; w];
        }
        let per_row = self.params.transfer_time / h as f64;
        let mut sums = vec![0.0f64; w];
        for ((row, prnu), span) in rate.chunks(w).zip(self.prnu.chunks(w)).zip(spans) {
            if let Some((a, b)) = *span {
                for ((s, &r), &g) in sums[a..b].iter_mut().zip(&row[a..b]).zip(&prnu[a..b]) {
                    *s += g as f64 * r as f64;
                }
            }
        }
        sums.iter().map(|s| s * per_row).collect()
    }

    /// Per column, the rows outside their lit span `spans[row]`: how many
    /// of its pixels a column table would draw (at least).
    fn unlit_counts(&self, spans: &[Option<(usize, usize)>]) -> Vec<usize> {
        // Rows covering each column, by differences along the row.
        let mut steps = vec![0isize; self.width + 1];
        for &(a, b) in spans.iter().flatten() {
            steps[a] += 1;
            steps[b] -= 1;
        }
        let mut covered = 0isize;
        steps[..self.width]
            .iter()
            .map(|d| {
                covered += d;
                self.height - covered as usize
            })
            .collect()
    }
}

/// A frame's dark pixels: their table in DN and their random bits.
struct DarkLookup {
    /// offset + K · value + ½ per table cell [DN] (⌊·⌋ of it rounds).
    dn: Vec<f32>,
    /// K [DN/e⁻], for the DSNU.
    gain: f32,
    max_dn: f32,
    stream: Stream,
}

impl DarkLookup {
    fn new(table: &DarkTable, sensor: &Sensor, frame: u64) -> DarkLookup {
        let (k, offset) = (sensor.readout.gain, sensor.params.offset);
        DarkLookup {
            dn: table
                .values
                .iter()
                .map(|&y| (offset + k * y + 0.5) as f32)
                .collect(),
            gain: k as f32,
            max_dn: sensor.max_dn.min(u16::MAX as f64) as f32,
            stream: Stream::new(sensor.params.seed, DARK_STREAM + frame),
        }
    }

    /// Steps 2–5 for dark pixels `k0..k0 + out.len()` of DSNU `dsnu`, in
    /// a row of offset `row` [e⁻]: pixel k takes bits 16 (k mod 4) to
    /// 16 (k mod 4) + 15 of the hash of k / 4 as its table cell.
    fn fill(&self, out: &mut [u16], k0: usize, dsnu: &[f32], row: f32) {
        let head = ((4 - k0 % 4) % 4).min(out.len());
        let (first, rest) = out.split_at_mut(head);
        for (i, (o, &s)) in first.iter_mut().zip(dsnu).enumerate() {
            let k = k0 + i;
            *o = self.level(self.stream.bits((k / 4) as u64), k % 4, s + row);
        }
        let group0 = (k0 + head) / 4;
        let tail_group = group0 + rest.len() / 4;
        let mut outs = rest.chunks_exact_mut(4);
        let mut offsets = dsnu[head..].chunks_exact(4);
        for (g, (o, s)) in (&mut outs).zip(&mut offsets).enumerate() {
            let bits = self.stream.bits((group0 + g) as u64);
            self.levels4(bits, s, row, o);
        }
        let bits = self.stream.bits(tail_group as u64);
        let tail = outs.into_remainder();
        for (lane, (o, &s)) in tail.iter_mut().zip(offsets.remainder()).enumerate() {
            *o = self.level(bits, lane, s + row);
        }
    }

    /// [`DarkLookup::level`] of the 4 lanes of `bits` at once, with DSNU
    /// `dsnu` and row offset `row` (4 each): the same operations in the
    /// same order on 4 SSE lanes, so the same DN.
    #[cfg(all(target_arch = "x86_64", target_feature = "sse4.1"))]
    #[inline(always)]
    fn levels4(&self, bits: u64, dsnu: &[f32], row: f32, out: &mut [u16]) {
        use std::arch::x86_64::*;
        assert!(dsnu.len() == 4 && out.len() == 4);
        let cell = |lane: u32| self.dn[(bits >> (16 * lane)) as u16 as usize];
        // SAFETY: SSE4.1 is enabled at compile time (the cfg above);
        // `dsnu` holds 4 f32 and `out` 4 u16 (8 bytes), asserted above,
        // and both intrinsics take unaligned addresses.
        unsafe {
            let table = _mm_setr_ps(cell(0), cell(1), cell(2), cell(3));
            let dsnu = _mm_loadu_ps(dsnu.as_ptr());
            let shift = _mm_add_ps(dsnu, _mm_set1_ps(row));
            let v = _mm_add_ps(table, _mm_mul_ps(_mm_set1_ps(self.gain), shift));
            // max(v, 0) is v > 0 ? v : 0 and min(v, m) is v < m ? v : m, as
            // in `level` (a NaN gives 0); v is then in [0, 65535]: truncation.
            let v = _mm_min_ps(_mm_max_ps(v, _mm_setzero_ps()), _mm_set1_ps(self.max_dn));
            let words = _mm_cvttps_epi32(v);
            let packed = _mm_packus_epi32(words, words);
            _mm_storel_epi64(out.as_mut_ptr() as *mut __m128i, packed);
        }
    }

    /// [`DarkLookup::level`] of the 4 lanes of `bits`, one by one.
    #[cfg(not(all(target_arch = "x86_64", target_feature = "sse4.1")))]
    #[inline(always)]
    fn levels4(&self, bits: u64, dsnu: &[f32], row: f32, out: &mut [u16]) {
        for lane in 0..4 {
            out[lane] = self.level(bits, lane, dsnu[lane] + row);
        }
    }

    /// One dark pixel in lane `lane` of `bits`, shifted by `shift` (its
    /// DSNU plus its row's offset) [e⁻]: DN.
    #[inline]
    fn level(&self, bits: u64, lane: usize, shift: f32) -> u16 {
        let cell = (bits >> (16 * lane)) as u16;
        // The table holds its DN plus ½: ⌊v⌋ rounds (see `quantise`).
        let v = self.dn[cell as usize] + self.gain * shift;
        let v = if v > 0.0 { v } else { 0.0 };
        let v = if v < self.max_dn { v } else { self.max_dn };
        v as i32 as u16
    }
}

/// ⌊`y` + ½⌋ within [0, min(`max_dn`, 65535)]: rounding (half up; `round`
/// differs only on negative ties, which clip to 0 anyway) by compares
/// and a truncation, no range checks per pixel (a NaN gives 0).
#[inline(always)]
fn quantise(y: f64, max_dn: f64) -> u16 {
    let top = max_dn.min(u16::MAX as f64) + 0.5;
    let z = y + 0.5;
    let z = if z > 0.0 { z } else { 0.0 };
    let z = if z < top { z } else { top };
    z as i32 as u16
}

/// How many of `row` are at least `level`.
fn count_at_least(row: &[u16], level: u32) -> u64 {
    if level > u16::MAX as u32 {
        return 0;
    }
    let level = level as u16;
    // Counted in u16 lanes (8 per SSE register) over chunks short enough
    // not to overflow them.
    row.chunks(1 << 15)
        .map(|c| c.iter().fold(0u16, |n, &v| n + (v >= level) as u16) as u64)
        .sum()
}

/// The runs [a, b) of non-zero values.
fn runs(values: &[f64]) -> Vec<(usize, usize)> {
    let mut out: Vec<(usize, usize)> = Vec::new();
    for (i, &v) in values.iter().enumerate() {
        if v != 0.0 {
            match out.last_mut() {
                Some(run) if run.1 == i => run.1 = i + 1,
                _ => out.push((i, i + 1)),
            }
        }
    }
    out
}

/// The span [a, b) from the row's first to its last non-zero rate (NaN
/// counts as non-zero).
fn lit_span(row: &[f32]) -> Option<(usize, usize)> {
    crate::optics::psf::nonzero_span(row)
}

/// Each row's [`lit_span`] when every non-zero value of `rate` (rows of
/// `width`) lies in the box `lit` = [x0, x1, y0, y1) (clipped to the
/// frame): only the box is read.
fn lit_spans(rate: &[f32], width: usize, lit: [usize; 4]) -> Vec<Option<(usize, usize)>> {
    let height = rate.len() / width.max(1);
    let [x0, x1, y0, y1] = lit;
    let (x1, y1) = (x1.min(width), y1.min(height));
    let mut spans = vec![None; height];
    if x0 < x1 && y0 < y1 {
        spans[y0..y1]
            .par_iter_mut()
            .zip(rate[y0 * width..y1 * width].par_chunks(width))
            .for_each(|(span, row)| {
                *span = lit_span(&row[x0..x1]).map(|(a, b)| (x0 + a, x0 + b));
            });
    }
    spans
}

/// Calls `f(a, b, lit)` on consecutive segments covering 0..`width`:
/// lit where a run of `columns` or the span `span` covers it.
fn for_segments(
    width: usize,
    columns: &[(usize, usize)],
    span: Option<(usize, usize)>,
    mut f: impl FnMut(usize, usize, bool),
) {
    let mut pos = 0;
    let mut current: Option<(usize, usize)> = None;
    let mut extra = span;
    let mut next_run = columns.iter().copied().peekable();
    loop {
        // The next interval by start: a column run or the span.
        let next = match (next_run.peek().copied(), extra) {
            (Some(r), Some(s)) if s.0 < r.0 => extra.take(),
            (Some(_), _) => next_run.next(),
            (None, Some(_)) => extra.take(),
            (None, None) => None,
        };
        match (current, next) {
            (Some((cs, ce)), Some((s, e))) if s <= ce => current = Some((cs, ce.max(e))),
            (cur, nxt) => {
                if let Some((cs, ce)) = cur {
                    if pos < cs {
                        f(pos, cs, false);
                    }
                    f(cs, ce, true);
                    pos = ce;
                }
                current = nxt;
                if nxt.is_none() {
                    break;
                }
            }
        }
    }
    if pos < width {
        f(pos, width, false);
    }
}

/// Calls `f(a, b, in_span)` on the parts of [`a`, `b`) inside and outside
/// the row's lit span `span`, in order.
fn for_span_parts(
    a: usize,
    b: usize,
    span: Option<(usize, usize)>,
    mut f: impl FnMut(usize, usize, bool),
) {
    let (s, e) = span.map_or((b, b), |(s, e)| (s.clamp(a, b), e.clamp(a, b)));
    if a < s {
        f(a, s, false);
    }
    if s < e {
        f(s, e, true);
    }
    if e < b {
        f(e, b, false);
    }
}

/// What one frame's draws share.
struct Draw {
    /// Smear electrons per column.
    smear: Vec<f64>,
    /// Per column, the inversion table of its pixels lit by smear alone.
    columns: Vec<Option<column::PoissonTable>>,
    dark: DarkDraw,
    exposure: f64,
    /// The frame's random stream: pixel k draws from `stream.at(k)`.
    stream: Stream,
    /// Row offsets [e⁻] ([`extras::row_offsets`]).
    rows: Vec<f64>,
    /// The read noise's N(0, 1) in 2¹⁶ cells.
    normal_cells: &'static [f32],
}

/// The dark charge's mean over one exposure and, below
/// [`sampler::PD_MEAN`], its e^(−mean).
struct DarkDraw {
    mean: f64,
    limit: Option<f64>,
}

impl DarkDraw {
    fn new(mean: f64) -> DarkDraw {
        DarkDraw {
            mean,
            limit: (mean < sampler::PD_MEAN).then(|| (-mean).exp()),
        }
    }
}

/// Charge above `full_well` spills along each column: half of a pixel's
/// excess runs down and half up, each passing full pixels until one has
/// room; what reaches an end of the column turns back. Charge is
/// conserved unless the whole column fills (the rest is drained).
pub fn bloom(charge: &mut [f64], width: usize, full_well: f64) {
    let height = charge.len() / width;
    // Only columns holding a pixel over the full well change.
    let mut over = vec![false; width];
    for row in charge.chunks(width) {
        for (o, &q) in over.iter_mut().zip(row) {
            *o |= q > full_well;
        }
    }
    let mut columns: Vec<(usize, Vec<f64>)> = (0..width)
        .filter(|&i| over[i])
        .map(|i| (i, (0..height).map(|j| charge[j * width + i]).collect()))
        .collect();
    columns
        .par_iter_mut()
        .for_each(|(_, c)| bloom_column(c, full_well));
    for (i, c) in &columns {
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

    /// The 4-lane dark levels against [`DarkLookup::level`] lane by lane,
    /// over table values, DSNU and row offsets that clip at 0 and at the
    /// largest DN, and a NaN DSNU.
    #[test]
    fn four_dark_levels_at_once_equal_one_by_one() {
        let lookup = DarkLookup {
            dn: (0..1 << 16).map(|i| i as f32 * 0.07 - 300.0).collect(),
            gain: 0.37,
            max_dn: 4095.0,
            stream: Stream::new(5, 9),
        };
        let mut rng = rng::Rng::new(1, 2, 3);
        for trial in 0..20_000 {
            let bits = rng.next_u64();
            let mut dsnu: Vec<f32> = (0..4)
                .map(|_| ((rng.uniform() - 0.5) * 2e3) as f32)
                .collect();
            if trial % 97 == 0 {
                dsnu[trial % 4] = f32::NAN;
            }
            let row = ((rng.uniform() - 0.5) * 40.0) as f32;
            let mut four = [0u16; 4];
            lookup.levels4(bits, &dsnu, row, &mut four);
            for lane in 0..4 {
                let one = lookup.level(bits, lane, dsnu[lane] + row);
                assert_eq!(four[lane], one, "{trial} {lane}: {dsnu:?} {row}");
            }
        }
    }

    /// The parts of a segment in and out of a span: in order, covering
    /// it, each pixel in the span part exactly when the span holds it.
    #[test]
    fn span_parts_split_a_segment_in_order() {
        let spans = [
            None,
            Some((0, 3)),
            Some((2, 5)),
            Some((4, 9)),
            Some((7, 12)),
            Some((3, 3)),
        ];
        for a in 0..10 {
            for b in a + 1..11 {
                for span in spans {
                    let mut pixels = Vec::new();
                    for_span_parts(a, b, span, |s, e, inside| {
                        assert!(s < e, "{a} {b} {span:?}: empty part");
                        pixels.extend((s..e).map(|x| (x, inside)));
                    });
                    let want: Vec<_> = (a..b)
                        .map(|x| (x, span.is_some_and(|(s, e)| (s..e).contains(&x))))
                        .collect();
                    assert_eq!(pixels, want, "{a} {b} {span:?}");
                }
            }
        }
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
            nonlinearity: 0.0,
            row_noise: 0.0,
            shot_noise: true,
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
