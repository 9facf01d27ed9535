//! Display radiometric calibration: the measured screen radiance versus drive
//! level (LUT), its monotone interpolant and inverse, and the per-pixel
//! flat-field gain map.
//!
//! # LUT file
//!
//! CSV, UTF-8. Lines that are blank or start with `#` are comments. The first
//! other line is the header, exactly `drive_level,radiance_w_m2_sr`; then at
//! least two rows `level,radiance` with
//!
//! * levels finite and strictly increasing, the first one `0` and the last one
//!   the top level of the display (`255` for 8 bit, `1023` for 10 bit): the
//!   table must cover the whole drive range, nothing is extrapolated;
//! * radiance (W m⁻² sr⁻¹, in the band of the camera, measured at the screen)
//!   finite, non-negative and non-decreasing, with the last value above the
//!   first.
//!
//! Every error names the file and the line.
//!
//! # Black level
//!
//! The black level is the measured radiance at drive level 0 (the first row),
//! not an override: the screen cannot emit less than that, so any target
//! below it is clipped (see [`dither`](super::dither)).
//!
//! # Interpolation
//!
//! Between the measured rows, radiance(level) is the monotone piecewise-cubic
//! Hermite interpolant of Fritsch & Carlson (1980) with the PCHIP slope rule
//! (weighted harmonic mean of the adjacent secants, zero at local extrema,
//! shape-preserving three-point end slopes), so it never overshoots the
//! measurements and stays non-decreasing. The radiance of every integer level
//! is tabulated, and a dense inverse table of `max(4096, 16 × levels)`
//! entries maps a target radiance to a fractional drive level. The table is
//! uniform in `u = ((L − black)/(max − black))^(1/3)`, which puts its entries
//! densely at the dark end where gamma-like display curves are flat (and the
//! inverse is steep), so linear interpolation in it stays accurate there.
//!
//! # Flat field
//!
//! A 32-bit float greyscale TIFF of exactly the screen size. Each pixel holds
//! the gain of that screen pixel: the ratio of its radiance to the LUT
//! radiance for the same drive level (1 = as calibrated). Gains must be finite
//! and positive.

use std::path::{Path, PathBuf};

use sha2::{Digest, Sha256};

use crate::error::{Error, Result};
use crate::infile::csv_table;

/// Exact header line of a LUT file.
pub const LUT_HEADER: &str = "drive_level,radiance_w_m2_sr";
/// The header of a LUT with the optional per-level expanded uncertainty
/// (k = 2, % of the radiance) written by `optistim calibrate radiometric`.
pub const LUT_HEADER_UNCERTAINTY: &str = "drive_level,radiance_w_m2_sr,uncertainty_k2_percent";

/// Hex SHA-256 of `bytes`.
pub fn sha256_hex(bytes: &[u8]) -> String {
    let digest = Sha256::digest(bytes);
    digest.iter().map(|b| format!("{b:02x}")).collect()
}

/// Monotone cubic (Fritsch–Carlson / PCHIP) interpolant through `(x, y)`.
#[derive(Debug, Clone)]
pub struct Pchip {
    x: Vec<f64>,
    y: Vec<f64>,
    m: Vec<f64>,
}

impl Pchip {
    /// Builds the interpolant; `x` strictly increasing, `y` the same length
    /// (≥ 2 points). Monotone data give a monotone interpolant.
    pub fn new(x: Vec<f64>, y: Vec<f64>) -> Result<Pchip> {
        let n = x.len();
        if n < 2 || y.len() != n {
            return Err(Error::invalid(
                "pchip",
                "need at least two points of x and y",
            ));
        }
        if x.windows(2)
            .any(|w| w[1].partial_cmp(&w[0]) != Some(std::cmp::Ordering::Greater))
            || x.iter().chain(&y).any(|v| !v.is_finite())
        {
            return Err(Error::invalid(
                "pchip",
                "x must be finite and strictly increasing",
            ));
        }
        let h: Vec<f64> = x.windows(2).map(|w| w[1] - w[0]).collect();
        let d: Vec<f64> = (0..n - 1).map(|i| (y[i + 1] - y[i]) / h[i]).collect();
        let mut m = vec![0.0; n];
        if n == 2 {
            m[0] = d[0];
            m[1] = d[0];
        } else {
            for i in 1..n - 1 {
                if d[i - 1] * d[i] > 0.0 {
                    let w1 = 2.0 * h[i] + h[i - 1];
                    let w2 = h[i] + 2.0 * h[i - 1];
                    m[i] = (w1 + w2) / (w1 / d[i - 1] + w2 / d[i]);
                }
            }
            m[0] = end_slope(h[0], h[1], d[0], d[1]);
            m[n - 1] = end_slope(h[n - 2], h[n - 3], d[n - 2], d[n - 3]);
        }
        Ok(Pchip { x, y, m })
    }

    /// Value at `t`, clamped to the end values outside the data range.
    pub fn eval(&self, t: f64) -> f64 {
        let n = self.x.len();
        if t <= self.x[0] {
            return self.y[0];
        }
        if t >= self.x[n - 1] {
            return self.y[n - 1];
        }
        let i = self.x.partition_point(|&v| v <= t) - 1;
        let h = self.x[i + 1] - self.x[i];
        let s = (t - self.x[i]) / h;
        let s2 = s * s;
        let s3 = s2 * s;
        let h00 = 2.0 * s3 - 3.0 * s2 + 1.0;
        let h10 = s3 - 2.0 * s2 + s;
        let h01 = -2.0 * s3 + 3.0 * s2;
        let h11 = s3 - s2;
        h00 * self.y[i] + h10 * h * self.m[i] + h01 * self.y[i + 1] + h11 * h * self.m[i + 1]
    }
}

/// Shape-preserving three-point end slope (as in PCHIP).
fn end_slope(h0: f64, h1: f64, d0: f64, d1: f64) -> f64 {
    let m = ((2.0 * h0 + h1) * d0 - h0 * d1) / (h0 + h1);
    if m.signum() != d0.signum() || d0 == 0.0 {
        0.0
    } else if d0.signum() != d1.signum() && m.abs() > 3.0 * d0.abs() {
        3.0 * d0
    } else {
        m
    }
}

/// Display radiometric LUT: radiance of the screen versus drive level.
#[derive(Debug, Clone)]
pub struct DisplayLut {
    path: PathBuf,
    sha256: String,
    bits: u32,
    curve: Pchip,
    level_radiance: Vec<f64>,
    inverse: Vec<f64>,
    /// Per measured level: (level, expanded uncertainty k = 2, %), when
    /// the file has the third column.
    uncertainty: Option<Vec<(f64, f64)>>,
}

impl DisplayLut {
    /// Reads a LUT file for a display of `bits` (8 or 10) bits per channel.
    pub fn load(path: impl AsRef<Path>, bits: u32) -> Result<DisplayLut> {
        let path = path.as_ref();
        let bytes = crate::infile::read_bounded(path, crate::infile::TABLE_LIMIT)?;
        DisplayLut::from_csv_bytes(&bytes, path, bits)
    }

    /// Parses LUT file content; `path` names the file in errors.
    pub fn from_csv_bytes(bytes: &[u8], path: impl AsRef<Path>, bits: u32) -> Result<DisplayLut> {
        let path = path.as_ref();
        let err = |line: usize, msg: String| Error::parse(path, format!("line {line}: {msg}"));
        let levels = levels_for_bits(bits)?;
        let mut rows = csv_table::rows(path, bytes, b',');
        let header = rows.next().transpose()?.ok_or_else(|| {
            Error::parse(path, format!("empty file: expected header `{LUT_HEADER}`"))
        })?;
        let hl = header.line;
        let with_u = header.joined() == LUT_HEADER_UNCERTAINTY;
        if header.joined() != LUT_HEADER && !with_u {
            return Err(err(
                hl,
                format!(
                    "header must be `{LUT_HEADER}` (optionally `,uncertainty_k2_percent`), found `{}`",
                    crate::error::abbreviate(&header.joined(), 60)
                ),
            ));
        }
        let mut xs: Vec<f64> = Vec::new();
        let mut ys: Vec<f64> = Vec::new();
        let mut us: Vec<(f64, f64)> = Vec::new();
        let mut last_line = hl;
        for row in rows {
            let row = row?;
            let ln = row.line;
            last_line = ln;
            let cells: Vec<&str> = row.cells.iter().collect();
            let fields = if with_u { 3 } else { 2 };
            if cells.len() != fields {
                return Err(err(
                    ln,
                    format!("expected {fields} fields, found {}", cells.len()),
                ));
            }
            let num = |s: &str, what: &str| -> Result<f64> {
                let v: f64 = s.parse().map_err(|_| {
                    err(
                        ln,
                        format!(
                            "{what}: not a number: `{}`",
                            crate::error::abbreviate(s, 40)
                        ),
                    )
                })?;
                if !v.is_finite() {
                    return Err(err(
                        ln,
                        format!(
                            "{what}: non-finite value `{}`",
                            crate::error::abbreviate(s, 40)
                        ),
                    ));
                }
                Ok(v)
            };
            let x = num(cells[0], "drive_level")?;
            let y = num(cells[1], "radiance_w_m2_sr")?;
            if y < 0.0 {
                return Err(err(ln, format!("radiance_w_m2_sr: negative value {y}")));
            }
            if let (Some(&px), Some(&py)) = (xs.last(), ys.last()) {
                if x <= px {
                    return Err(err(
                        ln,
                        format!("drive_level {x} is not above the previous level {px}"),
                    ));
                }
                if y < py {
                    return Err(err(
                        ln,
                        format!("radiance_w_m2_sr {y} decreases (previous row {py})"),
                    ));
                }
            } else if x != 0.0 {
                return Err(err(
                    ln,
                    format!("first drive_level must be 0 (black), found {x}"),
                ));
            }
            if x > (levels - 1) as f64 {
                return Err(err(
                    ln,
                    format!(
                        "drive_level {x} above the {bits}-bit maximum {}",
                        levels - 1
                    ),
                ));
            }
            if with_u {
                let u = num(cells[2], "uncertainty_k2_percent")?;
                if !(0.0..=1000.0).contains(&u) {
                    return Err(err(
                        ln,
                        format!("uncertainty_k2_percent: {u} is not in [0, 1000]"),
                    ));
                }
                us.push((x, u));
            }
            xs.push(x);
            ys.push(y);
        }
        if xs.len() < 2 {
            return Err(Error::parse(
                path,
                format!("need at least 2 rows, found {}", xs.len()),
            ));
        }
        if *xs.last().unwrap() != (levels - 1) as f64 {
            return Err(err(
                last_line,
                format!(
                    "last drive_level must be the {bits}-bit maximum {}, found {}",
                    levels - 1,
                    xs.last().unwrap()
                ),
            ));
        }
        if ys.last().unwrap() <= &ys[0] {
            return Err(Error::parse(
                path,
                "radiance is constant: the display does not respond",
            ));
        }
        let mut lut = DisplayLut::build(xs, ys, bits)?;
        lut.uncertainty = with_u.then_some(us);
        lut.path = path.to_path_buf();
        lut.sha256 = sha256_hex(bytes);
        Ok(lut)
    }

    /// Builds a LUT from measured points directly (no file; empty hash).
    pub fn from_points(levels: &[f64], radiance: &[f64], bits: u32) -> Result<DisplayLut> {
        let mut text = format!("{LUT_HEADER}\n");
        for (x, y) in levels.iter().zip(radiance) {
            text.push_str(&format!("{x:?},{y:?}\n"));
        }
        if levels.len() != radiance.len() {
            return Err(Error::invalid(
                "lut",
                "levels and radiance differ in length",
            ));
        }
        let mut lut = DisplayLut::from_csv_bytes(text.as_bytes(), "<points>", bits)?;
        lut.sha256.clear();
        Ok(lut)
    }

    fn build(xs: Vec<f64>, ys: Vec<f64>, bits: u32) -> Result<DisplayLut> {
        let levels = levels_for_bits(bits)?;
        let curve = Pchip::new(xs, ys)?;
        let level_radiance: Vec<f64> = (0..levels).map(|k| curve.eval(k as f64)).collect();
        let black = level_radiance[0];
        let max = level_radiance[levels as usize - 1];
        let n = (16 * levels as usize).max(4096);
        let inverse = (0..n)
            .map(|j| {
                let u = j as f64 / (n - 1) as f64;
                let target = black + (max - black) * u * u * u;
                invert(&curve, &level_radiance, target)
            })
            .collect();
        Ok(DisplayLut {
            path: PathBuf::new(),
            sha256: String::new(),
            bits,
            curve,
            level_radiance,
            inverse,
            uncertainty: None,
        })
    }

    /// The expanded uncertainty (k = 2, %) of the radiance at `radiance`:
    /// the file's column interpolated linearly in drive level at the
    /// LUT's inverse; `None` for a LUT without the column.
    pub fn uncertainty_k2_percent(&self, radiance: f64) -> Option<f64> {
        let u = self.uncertainty.as_ref()?;
        let level = self.inverse(radiance);
        let k = u.partition_point(|p| p.0 <= level).clamp(1, u.len() - 1);
        let ((x0, u0), (x1, u1)) = (u[k - 1], u[k]);
        let w = ((level - x0) / (x1 - x0)).clamp(0.0, 1.0);
        Some(u0 + w * (u1 - u0))
    }

    /// File the LUT was read from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Hex SHA-256 of the file bytes (empty for [`DisplayLut::from_points`]).
    pub fn sha256(&self) -> &str {
        &self.sha256
    }

    /// Bits per channel (8 or 10).
    pub fn bits(&self) -> u32 {
        self.bits
    }

    /// Number of drive levels (256 or 1024).
    pub fn levels(&self) -> u32 {
        self.level_radiance.len() as u32
    }

    /// Radiance at drive level 0, W m⁻² sr⁻¹.
    pub fn black(&self) -> f64 {
        self.level_radiance[0]
    }

    /// Radiance at the top drive level, W m⁻² sr⁻¹.
    pub fn max_radiance(&self) -> f64 {
        *self.level_radiance.last().unwrap()
    }

    /// Interpolated radiance at a (fractional) drive level, clamped to range.
    pub fn radiance(&self, level: f64) -> f64 {
        self.curve.eval(level)
    }

    /// Radiance of every integer drive level, index = level.
    pub fn level_radiances(&self) -> &[f64] {
        &self.level_radiance
    }

    /// Number of entries of the dense inverse table.
    pub fn inverse_len(&self) -> usize {
        self.inverse.len()
    }

    /// Fractional drive level whose interpolated radiance is `radiance`
    /// (clamped to `[0, levels-1]`), from the dense inverse table.
    pub fn inverse(&self, radiance: f64) -> f64 {
        let black = self.black();
        let max = self.max_radiance();
        if radiance.is_nan() || radiance <= black {
            return 0.0;
        }
        if radiance >= max {
            return (self.levels() - 1) as f64;
        }
        let n = self.inverse.len();
        let u = ((radiance - black) / (max - black)).cbrt() * (n - 1) as f64;
        let j = (u as usize).min(n - 2);
        let f = u - j as f64;
        self.inverse[j] * (1.0 - f) + self.inverse[j + 1] * f
    }

    /// For `black ≤ radiance < max`: the level `k` with
    /// `L_k ≤ radiance < L_{k+1}` and `p = (radiance − L_k)/(L_{k+1} − L_k)`.
    /// Returns `None` outside that range (or for NaN).
    #[inline]
    pub fn bracket(&self, radiance: f64) -> Option<(u32, f64)> {
        let lr = &self.level_radiance;
        let top = lr.len() - 1;
        if !(radiance >= lr[0] && radiance < lr[top]) {
            return None;
        }
        let mut k = (self.inverse(radiance) as usize).min(top - 1);
        while k > 0 && lr[k] > radiance {
            k -= 1;
        }
        while k + 1 < top && lr[k + 1] <= radiance {
            k += 1;
        }
        let span = lr[k + 1] - lr[k];
        let p = if span > 0.0 {
            (radiance - lr[k]) / span
        } else {
            0.0
        };
        Some((k as u32, p.clamp(0.0, 1.0)))
    }

    /// Frame-buffer pixel for a grey drive level: `0x00LLLLLL` for 8 bit,
    /// `x2r10g10b10` (`L<<20 | L<<10 | L`) for 10 bit.
    #[inline]
    pub fn encode_pixel(&self, level: u32) -> u32 {
        encode_grey(level, self.bits)
    }
}

/// Frame-buffer pixel for grey `level` at `bits` per channel (see
/// [`DisplayLut::encode_pixel`]).
#[inline]
pub fn encode_grey(level: u32, bits: u32) -> u32 {
    if bits == 10 {
        let l = level.min(1023);
        (l << 20) | (l << 10) | l
    } else {
        let l = level.min(255);
        (l << 16) | (l << 8) | l
    }
}

/// Inverse of [`encode_grey`] (takes the green channel).
#[inline]
pub fn decode_grey(pixel: u32, bits: u32) -> u32 {
    if bits == 10 {
        (pixel >> 10) & 0x3ff
    } else {
        (pixel >> 8) & 0xff
    }
}

fn levels_for_bits(bits: u32) -> Result<u32> {
    match bits {
        8 => Ok(256),
        10 => Ok(1024),
        _ => Err(Error::invalid(
            "drive.bits",
            format!("must be 8 or 10, found {bits}"),
        )),
    }
}

/// Fractional level with `curve(level) = target`, by bisection inside the
/// integer interval that brackets it (lowest level on flat parts).
fn invert(curve: &Pchip, lr: &[f64], target: f64) -> f64 {
    let top = lr.len() - 1;
    if target <= lr[0] {
        return 0.0;
    }
    if target >= lr[top] {
        return top as f64;
    }
    let k = lr
        .partition_point(|&v| v < target)
        .saturating_sub(1)
        .min(top - 1);
    let (mut lo, mut hi) = (k as f64, (k + 1) as f64);
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if curve.eval(mid) < target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Per-pixel screen gain map (see the module docs).
#[derive(Debug, Clone)]
pub struct FlatField {
    width: usize,
    height: usize,
    gain: Vec<f32>,
    sha256: String,
}

impl FlatField {
    /// Gain 1 everywhere.
    pub fn uniform(width: usize, height: usize) -> FlatField {
        FlatField {
            width,
            height,
            gain: vec![1.0; width * height],
            sha256: String::new(),
        }
    }

    /// From a row-major gain vector (validated like a file).
    pub fn from_gains(width: usize, height: usize, gain: Vec<f32>) -> Result<FlatField> {
        if gain.len() != width * height {
            return Err(Error::invalid(
                "flat_field",
                format!("{} gains for a {width}×{height} screen", gain.len()),
            ));
        }
        if let Some(i) = gain.iter().position(|g| !(g.is_finite() && *g > 0.0)) {
            return Err(Error::invalid(
                "flat_field",
                format!(
                    "gain {} at pixel ({}, {}) is not finite and > 0",
                    gain[i],
                    i % width,
                    i / width
                ),
            ));
        }
        Ok(FlatField {
            width,
            height,
            gain,
            sha256: String::new(),
        })
    }

    /// Reads a Gray32Float TIFF that must be exactly `screen = (width, height)`.
    pub fn load(path: impl AsRef<Path>, screen: (usize, usize)) -> Result<FlatField> {
        let path = path.as_ref();
        let bytes = crate::infile::read_bounded(path, crate::infile::TABLE_LIMIT)?;
        let terr = |e: tiff::TiffError| Error::parse(path, format!("TIFF: {e}"));
        let mut dec = tiff::decoder::Decoder::new(std::io::Cursor::new(&bytes)).map_err(terr)?;
        let (w, h) = dec.dimensions().map_err(terr)?;
        let (w, h) = (w as usize, h as usize);
        if (w, h) != screen {
            return Err(Error::parse(
                path,
                format!(
                    "flat field is {w}×{h} pixels but the screen is {}×{}",
                    screen.0, screen.1
                ),
            ));
        }
        let ct = dec.colortype().map_err(terr)?;
        if ct != tiff::ColorType::Gray(32) {
            return Err(Error::parse(
                path,
                format!("expected 32-bit float greyscale, found {ct:?}"),
            ));
        }
        let gain = match dec.read_image().map_err(terr)? {
            tiff::decoder::DecodingResult::F32(v) => v,
            _ => {
                return Err(Error::parse(
                    path,
                    "expected 32-bit float samples (SampleFormat = IEEE float)",
                ))
            }
        };
        let mut ff =
            FlatField::from_gains(w, h, gain).map_err(|e| Error::parse(path, e.to_string()))?;
        ff.sha256 = sha256_hex(&bytes);
        Ok(ff)
    }

    /// Writes the map as a Gray32Float TIFF (for tools and tests).
    pub fn save(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        let file = std::fs::File::create(path).map_err(|e| Error::io(path, e))?;
        let mut enc = tiff::encoder::TiffEncoder::new(std::io::BufWriter::new(file))
            .map_err(|e| Error::parse(path, format!("TIFF: {e}")))?;
        enc.write_image::<tiff::encoder::colortype::Gray32Float>(
            self.width as u32,
            self.height as u32,
            &self.gain,
        )
        .map_err(|e| Error::parse(path, format!("TIFF: {e}")))
    }

    /// Screen size.
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// Gain of pixel `(x, y)`.
    #[inline]
    pub fn gain(&self, x: usize, y: usize) -> f32 {
        self.gain[y * self.width + x]
    }

    /// Row-major gains.
    pub fn gains(&self) -> &[f32] {
        &self.gain
    }

    /// Hex SHA-256 of the file bytes (empty if not read from a file).
    pub fn sha256(&self) -> &str {
        &self.sha256
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gamma_csv(step: usize) -> String {
        let mut s = format!("# synthetic\n{LUT_HEADER}\n");
        let mut k = 0;
        loop {
            let l = 0.02 + 120.0 * (k as f64 / 255.0).powf(2.2);
            s.push_str(&format!("{k},{l}\n"));
            if k == 255 {
                break;
            }
            k = (k + step).min(255);
        }
        s
    }

    #[test]
    fn optional_uncertainty_column_is_read_and_interpolated() {
        let text = format!("{LUT_HEADER_UNCERTAINTY}\n0,1.0,4.0\n100,2.0,2.0\n255,3.0,1.0\n");
        let lut = DisplayLut::from_csv_bytes(text.as_bytes(), "u.csv", 8).unwrap();
        // At level 50 (half-way between the first two rows): 3 %.
        let l50 = lut.radiance(50.0);
        assert!((lut.uncertainty_k2_percent(l50).unwrap() - 3.0).abs() < 1e-3);
        assert_eq!(lut.uncertainty_k2_percent(3.0), Some(1.0));
        let old = DisplayLut::from_csv_bytes(gamma_csv(5).as_bytes(), "o.csv", 8).unwrap();
        assert_eq!(old.uncertainty_k2_percent(1.0), None);
        for (bad, what) in [("4.0\n100", "expected 3 fields"), ("4.0", "")] {
            let t = text.replacen(",4.0", if what.is_empty() { ",-4.0" } else { "" }, 1);
            let e = DisplayLut::from_csv_bytes(t.as_bytes(), "u.csv", 8)
                .unwrap_err()
                .to_string();
            assert!(e.contains("u.csv") && e.contains("line 2"), "{bad}: {e}");
        }
    }

    #[test]
    fn sha256_matches_known_vector() {
        // FIPS 180-2 test vector for "abc".
        assert_eq!(
            sha256_hex(b"abc"),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
    }

    #[test]
    fn pchip_reproduces_linear_data_and_nodes() {
        let p = Pchip::new(vec![0.0, 1.0, 3.0, 4.0], vec![1.0, 3.0, 7.0, 9.0]).unwrap();
        for t in [0.0, 0.3, 1.0, 2.2, 3.9, 4.0] {
            assert!((p.eval(t) - (1.0 + 2.0 * t)).abs() < 1e-12, "t={t}");
        }
        let q = Pchip::new(vec![0.0, 1.0, 2.0], vec![0.0, 0.0, 5.0]).unwrap();
        assert_eq!(
            q.eval(0.5),
            0.0,
            "flat segment must stay flat (no overshoot)"
        );
        assert_eq!(q.eval(2.0), 5.0);
    }

    proptest::proptest! {
        #[test]
        fn pchip_is_monotone_and_bounded(
            steps in proptest::collection::vec((0.1f64..10.0, 0.0f64..5.0), 2..12),
        ) {
            let mut x = vec![0.0];
            let mut y = vec![0.0];
            for (dx, dy) in &steps {
                x.push(x.last().unwrap() + dx);
                y.push(y.last().unwrap() + dy);
            }
            let p = Pchip::new(x.clone(), y.clone()).unwrap();
            let n = 2000;
            let mut prev = f64::NEG_INFINITY;
            for i in 0..=n {
                let t = x[0] + (x[x.len() - 1] - x[0]) * i as f64 / n as f64;
                let v = p.eval(t);
                proptest::prop_assert!(v >= prev - 1e-9);
                // Within the bracketing data interval (no overshoot).
                let j = x.partition_point(|&xi| xi <= t).clamp(1, x.len() - 1);
                proptest::prop_assert!(v >= y[j - 1] - 1e-9 && v <= y[j] + 1e-9);
                prev = v;
            }
        }
    }

    #[test]
    fn lut_interpolates_gamma_table_closely() {
        // Sparse table (every 15 levels) vs the exact gamma law.
        let lut = DisplayLut::from_csv_bytes(gamma_csv(15).as_bytes(), "g.csv", 8).unwrap();
        assert_eq!(lut.levels(), 256);
        assert!(lut.inverse_len() >= 4096);
        assert_eq!(lut.black(), 0.02);
        assert!((lut.max_radiance() - 120.02).abs() < 1e-12);
        for k in 0..256 {
            let exact = 0.02 + 120.0 * (k as f64 / 255.0).powf(2.2);
            let got = lut.level_radiances()[k];
            assert!(
                (got - exact).abs() < 0.003 * 120.0,
                "level {k}: {got} vs {exact}"
            );
        }
        assert_eq!(lut.sha256(), sha256_hex(gamma_csv(15).as_bytes()));
    }

    #[test]
    fn inverse_round_trips_and_bracket_is_consistent() {
        let lut = DisplayLut::from_csv_bytes(gamma_csv(1).as_bytes(), "g.csv", 8).unwrap();
        for i in 1..1000 {
            let level = 255.0 * i as f64 / 1000.0;
            let l = lut.radiance(level);
            let back = lut.inverse(l);
            assert!((back - level).abs() < 0.02, "{level} → {l} → {back}");
            let (k, p) = lut.bracket(l).unwrap();
            let lr = lut.level_radiances();
            assert!(lr[k as usize] <= l && l < lr[k as usize + 1]);
            let recon = lr[k as usize] + p * (lr[k as usize + 1] - lr[k as usize]);
            assert!((recon - l).abs() < 1e-9 * l);
        }
        assert!(lut.bracket(lut.max_radiance()).is_none());
        assert!(lut.bracket(0.01).is_none());
        assert!(lut.bracket(f64::NAN).is_none());
    }

    #[test]
    fn example_calibration_file_loads() {
        let p = concat!(env!("CARGO_MANIFEST_DIR"), "/calib/example_lut.csv");
        let lut = DisplayLut::load(p, 8).unwrap();
        let bytes = std::fs::read(p).unwrap();
        assert_eq!(lut.sha256(), sha256_hex(&bytes));
        // The first and last data rows are the black and maximum radiance.
        let text = String::from_utf8(bytes).unwrap();
        let rows: Vec<&str> = text
            .lines()
            .filter(|l| l.starts_with(char::is_numeric))
            .collect();
        let first: f64 = rows[0].split(',').nth(1).unwrap().parse().unwrap();
        let last: f64 = rows[rows.len() - 1]
            .split(',')
            .nth(1)
            .unwrap()
            .parse()
            .unwrap();
        assert_eq!(lut.black(), first);
        assert_eq!(lut.max_radiance(), last);
    }

    #[test]
    fn ten_bit_lut_and_pixel_encoding() {
        let lut = DisplayLut::from_points(&[0.0, 1023.0], &[0.1, 100.1], 10).unwrap();
        assert_eq!(lut.levels(), 1024);
        assert!((lut.level_radiances()[512] - (0.1 + 100.0 * 512.0 / 1023.0)).abs() < 1e-9);
        assert_eq!(encode_grey(1023, 10), 0x3fff_ffff);
        assert_eq!(encode_grey(0x80, 8), 0x0080_8080);
        assert_eq!(decode_grey(encode_grey(700, 10), 10), 700);
        assert!(DisplayLut::from_points(&[0.0, 255.0], &[0.0, 1.0], 12).is_err());
    }

    #[test]
    fn lut_errors_name_file_and_line() {
        let e = |s: &str| {
            DisplayLut::from_csv_bytes(s.as_bytes(), "cal/lut.csv", 8)
                .unwrap_err()
                .to_string()
        };
        let h = LUT_HEADER;
        let cases = [
            (format!("{h}\n0,0.1\n10,0.5\n10,0.6\n255,9\n"), "line 4"),
            (format!("{h}\n0,0.1\n10,0.5\n20,0.4\n255,9\n"), "line 4"),
            (format!("{h}\n0,0.1\n10,NaN\n255,9\n"), "line 3"),
            (format!("{h}\n0,0.1\n10,inf\n255,9\n"), "line 3"),
            (format!("{h}\n0,0.1\n10,abc\n255,9\n"), "line 3"),
            (format!("{h}\n0,0.1\n"), "at least 2 rows"),
            (format!("{h}\n5,0.1\n255,9\n"), "line 2"),
            (format!("{h}\n0,0.1\n200,9\n"), "line 3"),
            (format!("{h}\n0,0.1\n256,9\n"), "line 3"),
            (format!("{h}\n0,0.1,3\n255,9\n"), "line 2"),
            ("level,radiance\n0,1\n255,2\n".to_string(), "line 1"),
            (format!("{h}\n0,1\n255,1\n"), "constant"),
            (String::new(), "empty"),
        ];
        for (text, want) in cases {
            let m = e(&text);
            assert!(
                m.contains("cal/lut.csv") && m.contains(want),
                "{text:?}: {m}"
            );
        }
    }

    #[test]
    fn flat_field_round_trip_and_errors() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("ff.tif");
        let gains: Vec<f32> = (0..12).map(|i| 0.9 + 0.01 * i as f32).collect();
        FlatField::from_gains(4, 3, gains.clone())
            .unwrap()
            .save(&p)
            .unwrap();
        let ff = FlatField::load(&p, (4, 3)).unwrap();
        assert_eq!(ff.gains(), &gains[..]);
        assert_eq!(ff.gain(1, 2), gains[9]);
        assert_eq!(ff.sha256(), sha256_hex(&std::fs::read(&p).unwrap()));
        let m = FlatField::load(&p, (3, 4)).unwrap_err().to_string();
        assert!(m.contains("ff.tif") && m.contains("4×3"), "{m}");

        // NaN and non-positive gains are rejected with the pixel named.
        let mut bad = gains.clone();
        bad[5] = f32::NAN;
        let bp = dir.path().join("bad.tif");
        let enc_file = std::fs::File::create(&bp).unwrap();
        tiff::encoder::TiffEncoder::new(enc_file)
            .unwrap()
            .write_image::<tiff::encoder::colortype::Gray32Float>(4, 3, &bad)
            .unwrap();
        let m = FlatField::load(&bp, (4, 3)).unwrap_err().to_string();
        assert!(m.contains("bad.tif") && m.contains("(1, 1)"), "{m}");
        assert!(FlatField::from_gains(4, 3, vec![0.0; 12]).is_err());

        // Integer TIFF is refused.
        let ip = dir.path().join("int.tif");
        tiff::encoder::TiffEncoder::new(std::fs::File::create(&ip).unwrap())
            .unwrap()
            .write_image::<tiff::encoder::colortype::Gray16>(4, 3, &[1u16; 12])
            .unwrap();
        assert!(FlatField::load(&ip, (4, 3))
            .unwrap_err()
            .to_string()
            .contains("float"));
    }
}
