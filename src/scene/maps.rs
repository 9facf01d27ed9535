//! Equirectangular body maps: albedo, displacement and normal maps, and their
//! bilinear sampling by body-fixed direction.
//!
//! Maps are equirectangular, longitude 0 at the image centre (−180° at the
//! left edge), north up. Body-fixed frame: +z north pole, +x through
//! (lat 0, lon 0), +y through (lat 0, lon +90° east).

use std::f64::consts::{FRAC_PI_2, PI, TAU};
use std::path::Path;
use std::sync::OnceLock;

use glam::DVec3;

use crate::error::{Error, Result};

/// Largest map accepted, in pixels (16384 × 8192: 22 m per pixel on the
/// Moon's equator). Checked from the header before any pixel is decoded, so
/// a small file that claims a huge image is refused rather than allocated.
pub const MAX_MAP_PIXELS: u64 = 1 << 27;

/// TIFF decoder limits for a float map of at most [`MAX_MAP_PIXELS`].
fn map_tiff_limits() -> tiff::decoder::Limits {
    let mut limits = tiff::decoder::Limits::default();
    limits.decoding_buffer_size = (MAX_MAP_PIXELS * 4) as usize;
    limits.intermediate_buffer_size = (MAX_MAP_PIXELS * 4) as usize;
    limits
}

/// Opens an 8/16-bit image with its size checked against
/// [`MAX_MAP_PIXELS`] before decoding.
fn open_bounded(path: &Path) -> Result<image::DynamicImage> {
    let perr = |e: image::ImageError| Error::parse(path, e.to_string());
    let reader = || -> Result<image::ImageReader<std::io::BufReader<std::fs::File>>> {
        image::ImageReader::open(path)
            .map_err(|e| Error::io(path, e))?
            .with_guessed_format()
            .map_err(|e| Error::io(path, e))
    };
    let (w, h) = reader()?.into_dimensions().map_err(perr)?;
    check_map_size(path, w, h)?;
    let mut decoding = reader()?;
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(MAX_MAP_PIXELS * 8);
    decoding.limits(limits);
    decoding.decode().map_err(perr)
}

fn check_map_size(path: &Path, w: u32, h: u32) -> Result<()> {
    if w as u64 * h as u64 > MAX_MAP_PIXELS {
        return Err(Error::parse(
            path,
            format!("map is {w}×{h} pixels; at most {MAX_MAP_PIXELS} pixels are accepted"),
        ));
    }
    Ok(())
}

/// A scalar map sampled bilinearly.
#[derive(Clone, Debug)]
pub struct EquirectMap {
    /// Width [px] (longitude).
    pub width: usize,
    /// Height [px] (latitude).
    pub height: usize,
    /// Row-major values, row 0 at the north edge.
    pub data: Vec<f32>,
    /// Summed-area table, built on first use of [`Self::box_average`].
    sat: OnceLock<Vec<f64>>,
    /// Longitude-averaged levels, built on first use of
    /// [`Self::sample_stretched`]: level L averages 2^L texels along x.
    x_levels: OnceLock<Vec<Vec<f32>>>,
    /// Per-row prefix integrals of the bilinear interpolant along x, for
    /// [`Self::parallelogram_mean`]: (width + 1) f64 per row (16.8 MB for a
    /// 2048 × 1024 map), built at scene load when the scene asks for the
    /// exact filter ([`Self::prepare_filters`]), else on first use.
    row_prefix: OnceLock<Vec<f64>>,
}

/// Samples of one footprint width from the longitude-averaged levels
/// ([`EquirectMap::stretched`]).
pub struct Stretched<'a> {
    map: &'a EquirectMap,
    levels: &'a [Vec<f32>],
    lower: usize,
    upper: usize,
    frac: f64,
}

impl Stretched<'_> {
    /// Mean over the footprint centred at continuous texel coordinates.
    #[inline(always)]
    pub fn sample(&self, x: f64, y: f64) -> f64 {
        let a = self
            .map
            .sample_level(&self.levels[self.lower], self.lower, x, y);
        if self.frac <= 0.0 {
            return a;
        }
        let b = self
            .map
            .sample_level(&self.levels[self.upper], self.upper, x, y);
        a + (b - a) * self.frac
    }
}

/// Bilinear sample of a `w` × `h` row-major grid at continuous texel
/// coordinates (integer = texel centre); wraps in x, clamps in y. The
/// hottest loop of a textured render: written so that the common case
/// costs one bounds check and no division.
#[inline(always)]
fn bilinear(data: &[f32], w: usize, h: usize, x: f64, y: f64) -> f64 {
    // y ∈ [0, h − 1], so truncation is the floor.
    let y = y.clamp(0.0, (h - 1) as f64);
    let y0 = (y as i32).min(h as i32 - 2).max(0) as usize;
    let ty = y - y0 as f64;
    let x0 = x.floor();
    let tx = x - x0;
    let xi = x0 as i64;
    // Samples stay within a few texels of [0, w): wrap without a division
    // in the common case.
    let i0 = if (xi as u64) < w as u64 {
        xi as usize
    } else {
        (xi.rem_euclid(w as i64) as usize).min(w - 1)
    };
    let i1 = if i0 + 1 == w { 0 } else { i0 + 1 };
    let rows = &data[y0 * w..(y0 + 2) * w];
    let (top, bottom) = rows.split_at(w);
    let lerp = |a: f32, b: f32| a as f64 + (b as f64 - a as f64) * tx;
    let t = lerp(top[i0], top[i1]);
    let b = lerp(bottom[i0], bottom[i1]);
    t + (b - t) * ty
}

/// G(x, y) = ∫₀ˣ f(s, y) ds on one texel cell of the bilinear map: per
/// row (prefix at the cell's left edge, value there, half the slope).
struct GreenCell {
    x0: f64,
    y0: f64,
    rows: [(f64, f64, f64); 2],
}

impl GreenCell {
    /// G at (x, y), y already clamped to the map's rows.
    #[inline(always)]
    fn g(&self, x: f64, y: f64) -> f64 {
        let u = x - self.x0;
        let [(b0, v0, s0), (b1, v1, s1)] = self.rows;
        let g0 = b0 + u * (v0 + s0 * u);
        let g1 = b1 + u * (v1 + s1 * u);
        g0 + (y - self.y0) * (g1 - g0)
    }
}

/// A position along one axis of a summed-area table: the cell it falls in
/// and the fraction into it, for x clamped to [0, n].
#[derive(Clone, Copy)]
struct SatPos {
    i: usize,
    f: f64,
}

impl SatPos {
    #[inline(always)]
    fn new(x: f64, n: usize) -> SatPos {
        let x = x.clamp(0.0, n as f64);
        let i = (x as i64 as usize).min(n - 1);
        SatPos { i, f: x - i as f64 }
    }
}

/// The sRGB decoding curve: encoded value in [0, 1] to linear light.
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// Latitude and longitude [rad] of a body-fixed direction (need not be unit).
#[inline]
pub fn lat_lon(n: DVec3) -> (f64, f64) {
    let lat = (n.z / n.length()).clamp(-1.0, 1.0).asin();
    let lon = n.y.atan2(n.x);
    (lat, lon)
}

/// exp(p(n)) of [`EquirectMap::modulate_large_scale`] at (lat, lon).
pub fn large_scale_factor(c: &[f64; 8], lat: f64, lon: f64) -> f64 {
    let (sl, cl) = lat.sin_cos();
    let (so, co) = lon.sin_cos();
    let (x, y, z) = (cl * co, cl * so, sl);
    let p = c[0] * z
        + c[1] * x
        + c[2] * y
        + c[3] * 0.5 * (3.0 * z * z - 1.0)
        + c[4] * x * z
        + c[5] * y * z
        + c[6] * 0.5 * (x * x - y * y)
        + c[7] * x * y;
    p.exp()
}

impl EquirectMap {
    /// Map from row-major values.
    pub fn new(width: usize, height: usize, data: Vec<f32>) -> Self {
        assert_eq!(data.len(), width * height, "map size");
        let mut resident = crate::resident_vec(0.0f32, data.len());
        resident.copy_from_slice(&data);
        Self {
            width,
            height,
            data: resident,
            sat: OnceLock::new(),
            x_levels: OnceLock::new(),
            row_prefix: OnceLock::new(),
        }
    }

    /// Read an image file as a single channel: 8/16-bit grey or colour
    /// (colour channels are averaged) normalised to [0, 1], or 32-bit float
    /// TIFF kept as is.
    pub fn load(path: &Path) -> Result<Self> {
        if let Some(map) = Self::load_float_tiff(path)? {
            return Ok(map);
        }
        let img = open_bounded(path)?;
        let (width, height) = (img.width() as usize, img.height() as usize);
        let rgb = img.to_rgb32f();
        let data = rgb
            .pixels()
            .map(|p| (p.0[0] + p.0[1] + p.0[2]) / 3.0)
            .collect();
        Self::checked(path, width, height, data)
    }

    /// Read an 8/16-bit sRGB-encoded image (a visual mosaic) and undo the
    /// sRGB transfer curve per channel before averaging, so that values are
    /// proportional to reflected light (IEC 61966-2-1).
    pub fn load_srgb(path: &Path) -> Result<Self> {
        let img = open_bounded(path)?;
        let (width, height) = (img.width() as usize, img.height() as usize);
        let rgb = img.to_rgb32f();
        let data = rgb
            .pixels()
            .map(|p| p.0.iter().map(|&c| srgb_to_linear(c)).sum::<f32>() / 3.0)
            .collect();
        Self::checked(path, width, height, data)
    }

    fn load_float_tiff(path: &Path) -> Result<Option<Self>> {
        let is_tiff = matches!(
            path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase),
            Some(ref e) if e == "tif" || e == "tiff"
        );
        if !is_tiff {
            return Ok(None);
        }
        let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
        let mut decoder = tiff::decoder::Decoder::new(std::io::BufReader::new(file))
            .map_err(|e| Error::parse(path, e.to_string()))?
            .with_limits(map_tiff_limits());
        if decoder.colortype().ok() != Some(tiff::ColorType::Gray(32)) {
            return Ok(None);
        }
        let (w, h) = decoder
            .dimensions()
            .map_err(|e| Error::parse(path, e.to_string()))?;
        check_map_size(path, w, h)?;
        match decoder
            .read_image()
            .map_err(|e| Error::parse(path, e.to_string()))?
        {
            tiff::decoder::DecodingResult::F32(data) => {
                Self::checked(path, w as usize, h as usize, data).map(Some)
            }
            _ => Ok(None),
        }
    }

    fn checked(path: &Path, width: usize, height: usize, data: Vec<f32>) -> Result<Self> {
        if width < 2 || height < 2 || data.len() != width * height {
            return Err(Error::parse(path, "map must be at least 2x2 pixels"));
        }
        if let Some(k) = data.iter().position(|v| !v.is_finite()) {
            return Err(Error::parse(
                path,
                format!("non-finite value at pixel ({}, {})", k % width, k / width),
            ));
        }
        Ok(Self::new(width, height, data))
    }

    /// Smallest and largest value.
    pub fn range(&self) -> (f32, f32) {
        self.data
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| {
                (lo.min(v), hi.max(v))
            })
    }

    /// Map every value linearly so that the map's own range becomes
    /// [lo, hi].
    pub fn stretch(&mut self, lo: f64, hi: f64) {
        self.stretch_power(lo, hi, 1.0);
    }

    /// Normalise the map's own range to t ∈ [0, 1], then set every value
    /// to lo + t^power · (hi − lo): a power ≠ 1 changes the contrast
    /// between dark and bright terrain (maria and highlands) without
    /// moving the ends. Applied once at load, so a render pays nothing.
    pub fn stretch_power(&mut self, lo: f64, hi: f64, power: f64) {
        self.forget_derived();
        let (a, b) = self.range();
        let span = (b - a) as f64;
        for v in &mut self.data {
            let t = if span > 0.0 {
                (*v - a) as f64 / span
            } else {
                0.5
            };
            // power 1 skips powf: the default stays bit-identical to a
            // linear stretch.
            let bent = if power == 1.0 { t } else { t.powf(power) };
            *v = (lo + bent * (hi - lo)) as f32;
        }
    }

    /// Multiply every texel by exp(p(n)), p a polynomial of degree ≤ 2 in
    /// the body-fixed unit direction n = (x, y, z) of the texel centre (x
    /// toward longitude 0, z north) without a constant term:
    /// `coefficients` multiply z, x, y, (3z² − 1)/2, xz, yz, (x² − y²)/2,
    /// xy (the real spherical harmonics of degree 1 and 2, unnormalised).
    /// A smooth large-scale correction of a mosaic's brightness (e.g. its
    /// photometric normalisation toward the limbs and poles), applied once
    /// at load.
    pub fn modulate_large_scale(&mut self, coefficients: &[f64; 8]) {
        self.forget_derived();
        let (width, height) = (self.width, self.height);
        for (row, values) in self.data.chunks_mut(width).enumerate() {
            let lat = FRAC_PI_2 - (row as f64 + 0.5) / height as f64 * PI;
            for (col, v) in values.iter_mut().enumerate() {
                let lon = (col as f64 + 0.5) / width as f64 * TAU - PI;
                *v = (*v as f64 * large_scale_factor(coefficients, lat, lon)) as f32;
            }
        }
    }

    /// Multiply every value.
    pub fn scale(&mut self, factor: f64) {
        self.forget_derived();
        for v in &mut self.data {
            *v = (*v as f64 * factor) as f32;
        }
    }

    /// Continuous texel coordinates (integer = texel centre) of lat/lon.
    #[inline]
    fn texel(&self, lat: f64, lon: f64) -> (f64, f64) {
        let x = (lon + PI) / TAU * self.width as f64 - 0.5;
        let y = (FRAC_PI_2 - lat) / PI * self.height as f64 - 0.5;
        (x, y)
    }

    /// Continuous texel coordinates of lat/lon (integer = texel centre).
    #[inline]
    pub fn texel_of(&self, lat: f64, lon: f64) -> (f64, f64) {
        self.texel(lat, lon)
    }

    /// Latitude/longitude of continuous texel coordinates.
    #[inline]
    pub fn lat_lon_of(&self, x: f64, y: f64) -> (f64, f64) {
        (
            FRAC_PI_2 - (y + 0.5) / self.height as f64 * PI,
            (x + 0.5) / self.width as f64 * TAU - PI,
        )
    }

    /// Bilinear sample at continuous texel coordinates (integer = texel
    /// centre); wraps in x, clamps in y.
    #[inline(always)]
    pub fn sample_texel(&self, x: f64, y: f64) -> f64 {
        bilinear(&self.data, self.width, self.height, x, y)
    }

    /// Bilinear sample at latitude/longitude [rad]; wraps in longitude,
    /// clamps in latitude.
    #[inline]
    pub fn sample(&self, lat: f64, lon: f64) -> f64 {
        let (x, y) = self.texel(lat, lon);
        self.sample_texel(x, y)
    }

    /// Bilinear sample along a body-fixed direction.
    #[inline]
    pub fn sample_dir(&self, n: DVec3) -> f64 {
        let (lat, lon) = lat_lon(n);
        self.sample(lat, lon)
    }

    fn x_levels(&self) -> &[Vec<f32>] {
        self.x_levels.get_or_init(|| {
            let h = self.height;
            let mut first = crate::resident_vec(0.0f32, self.data.len());
            first.copy_from_slice(&self.data);
            let mut levels = vec![first];
            let mut w = self.width;
            while w.is_multiple_of(2) && w >= 8 {
                let prev = levels.last().expect("level 0");
                let half = w / 2;
                let mut next = crate::resident_vec(0.0f32, half * h);
                for j in 0..h {
                    for i in 0..half {
                        next[j * half + i] = 0.5 * (prev[j * w + 2 * i] + prev[j * w + 2 * i + 1]);
                    }
                }
                levels.push(next);
                w = half;
            }
            levels
        })
    }

    /// Bilinear sample of level `level` at level-0 texel coordinates.
    #[inline(always)]
    fn sample_level(&self, level: &[f32], shift: usize, x: f64, y: f64) -> f64 {
        // 2^-shift is exact: the same value as dividing by 2^shift.
        let x = (x + 0.5) * f64::from_bits((1023 - shift as u64) << 52) - 0.5;
        bilinear(level, self.width >> shift, self.height, x, y)
    }

    /// Sampler of footprints `width` texels wide along x (longitude) and at
    /// most ~1.5 texels tall: see [`Self::sample_stretched`]. The level
    /// choice depends on the width only, so samples of one footprint share
    /// it.
    #[inline]
    pub fn stretched(&self, width: f64) -> Stretched<'_> {
        let levels = self.x_levels();
        let top = (levels.len() - 1) as f64;
        // A level-L sample (a 2^L box seen through a 2^L bilinear tent) has
        // the spread of a box 1.7 × 2^L wide.
        let l = (width / 1.7).max(1.0).log2().min(top);
        let l0 = l.floor();
        let lower = l0 as usize;
        Stretched {
            map: self,
            levels,
            lower,
            upper: (lower + 1).min(levels.len() - 1),
            frac: l - l0,
        }
    }

    /// Mean over a footprint `width` texels wide along x (longitude) and
    /// at most ~1.5 texels tall, at continuous texel coordinates: bilinear
    /// samples of the two x-averaged levels bracketing the width, blended
    /// in log₂ width. Near the poles an equirectangular map is stretched
    /// along x only, so this replaces most box averages at 4 reads each.
    #[inline]
    pub fn sample_stretched(&self, x: f64, y: f64, width: f64) -> f64 {
        self.stretched(width).sample(x, y)
    }

    fn sat(&self) -> &[f64] {
        self.sat.get_or_init(|| {
            let (w, h) = (self.width, self.height);
            let mut sat = vec![0.0f64; (w + 1) * (h + 1)];
            for j in 0..h {
                let mut row = 0.0;
                for i in 0..w {
                    row += self.data[j * w + i] as f64;
                    sat[(j + 1) * (w + 1) + i + 1] = sat[j * (w + 1) + i + 1] + row;
                }
            }
            sat
        })
    }

    /// ∫ of the texel-constant map over [0, x] × [0, y] (texel units):
    /// bilinear in the summed-area table `sat` (rows `s` wide), exact.
    #[inline(always)]
    fn cumulative(sat: &[f64], s: usize, x: SatPos, y: SatPos) -> f64 {
        // Rows y.i and y.i + 1, columns x.i and x.i + 1: one bounds check.
        let r = &sat[y.i * s + x.i..][..s + 2];
        let a = r[0] * (1.0 - x.f) + r[1] * x.f;
        let b = r[s] * (1.0 - x.f) + r[s + 1] * x.f;
        a * (1.0 - y.f) + b * y.f
    }

    /// Mean of the map over a box centred at lat/lon with half-sizes in
    /// texels, each texel taken as constant. A half-size of 0.5 texel
    /// reproduces bilinear interpolation; callers widen small boxes to that,
    /// so the mean is continuous from point sampling to area averaging.
    pub fn box_average(&self, lat: f64, lon: f64, half_x: f64, half_y: f64) -> f64 {
        let (x, y) = self.texel(lat, lon);
        self.box_average_texel(x, y, half_x, half_y)
    }

    /// [`box_average`](Self::box_average) at continuous texel coordinates
    /// (integer = texel centre).
    #[inline]
    pub fn box_average_texel(&self, x: f64, y: f64, half_x: f64, half_y: f64) -> f64 {
        let (w, h) = (self.width, self.height);
        let sat = self.sat();
        let wf = w as f64;
        // In the table, texel i spans [i, i + 1). Callers may pass a
        // longitude past ±π (a footprint straddling the seam): wrap it so
        // the box starts in [0, W), without a division unless it is far off.
        let (texel_x, texel_y) = (x, y);
        let mut x = x + 0.5;
        if x < 0.0 {
            x += wf;
        } else if x >= wf {
            x -= wf;
        }
        if !(0.0..wf).contains(&x) {
            x = x.rem_euclid(wf);
        }
        let y = y + 0.5;
        let half_x = half_x.min(0.5 * wf);
        let (y0, y1) = ((y - half_y).max(0.0), (y + half_y).min(h as f64));
        if y1 <= y0 {
            return self.sample_texel(texel_x, texel_y);
        }
        let s = w + 1;
        let (r0, r1) = (SatPos::new(y0, h), SatPos::new(y1, h));
        let strip = |x0: f64, x1: f64| {
            let (c0, c1) = (SatPos::new(x0, w), SatPos::new(x1, w));
            Self::cumulative(sat, s, c1, r1)
                - Self::cumulative(sat, s, c0, r1)
                - Self::cumulative(sat, s, c1, r0)
                + Self::cumulative(sat, s, c0, r0)
        };
        let (mut x0, mut x1) = (x - half_x, x + half_x);
        if x0 < 0.0 {
            x0 += wf;
            x1 += wf;
        }
        let total = if x1 > wf {
            strip(x0, wf) + strip(0.0, x1 - wf)
        } else {
            strip(x0, x1)
        };
        total / ((x1 - x0) * (y1 - y0))
    }

    /// Drop the tables derived from the values (they are rebuilt on use).
    fn forget_derived(&mut self) {
        self.sat.take();
        self.x_levels.take();
        self.row_prefix.take();
    }

    /// Build the exact filter's table now (scene load) rather than in the
    /// first render.
    pub fn prepare_filters(&self) {
        self.row_prefix();
    }

    /// Row j's entries k = 0..=W: C_j(k) = ∫₀ᵏ f_j(s) ds of the row's
    /// periodic piecewise-linear interpolant f_j (C_j(W) is the row total).
    fn row_prefix(&self) -> &[f64] {
        self.row_prefix.get_or_init(|| {
            let (w, h) = (self.width, self.height);
            let mut table = crate::resident_vec(0.0f64, (w + 1) * h);
            for (row, out) in self.data.chunks_exact(w).zip(table.chunks_exact_mut(w + 1)) {
                let mut acc = 0.0;
                for i in 0..w {
                    out[i] = acc;
                    let next = if i + 1 == w { row[0] } else { row[i + 1] };
                    acc += 0.5 * (row[i] as f64 + next as f64);
                }
                out[w] = acc;
            }
            table
        })
    }

    /// Exact mean of the bilinear interpolant ([`Self::sample_texel`],
    /// wrapped in x, clamped in y) over the parallelogram
    /// (x, y) + s a1 + t a2, s, t ∈ [−½, ½], in texel coordinates.
    ///
    /// Green's theorem: ∬ f = ∮ G dy with G(x, y) = ∫₀ˣ f(s, y) ds. Between
    /// rows j and j + 1, G = (1 − t) G_j + t G_{j+1} with G_j a row's
    /// prefix integral (the table plus the partial cell's quadratic), so
    /// along an edge cut at every texel row and column line G is a cubic
    /// in the edge parameter and Simpson's rule is exact on each piece.
    /// The cost is proportional to the perimeter in texels, plus 4;
    /// footprints wider than the map (at a pole) are narrowed to one turn.
    pub fn parallelogram_mean(&self, x: f64, y: f64, a1: (f64, f64), a2: (f64, f64)) -> f64 {
        let area = a1.0 * a2.1 - a1.1 * a2.0;
        let size2 = a1.0 * a1.0 + a1.1 * a1.1 + a2.0 * a2.0 + a2.1 * a2.1;
        // A degenerate footprint: its mean is the interpolant's along a
        // segment, within its second derivative of the centre value.
        if !(area.abs() > 1e-9 * size2) || !x.is_finite() || !y.is_finite() {
            return self.sample_texel(x, y);
        }
        let wf = self.width as f64;
        let x = if (0.0..wf).contains(&x) {
            x
        } else {
            x.rem_euclid(wf)
        };
        // At a pole the footprint's x extent grows like 1/cos(lat), and so
        // would the work: beyond one full turn of longitude, shrink it in x
        // to one turn (each row is then averaged over its whole period; the
        // preimage there is a polar cap, not a parallelogram in x, y).
        let extent = a1.0.abs() + a2.0.abs();
        let (a1, a2, area) = if extent > wf {
            let k = wf / extent;
            ((a1.0 * k, a1.1), (a2.0 * k, a2.1), area * k)
        } else {
            (a1, a2, area)
        };
        let (h1, h2) = ((0.5 * a1.0, 0.5 * a1.1), (0.5 * a2.0, 0.5 * a2.1));
        let corners = [
            (x - h1.0 - h2.0, y - h1.1 - h2.1),
            (x + h1.0 - h2.0, y + h1.1 - h2.1),
            (x + h1.0 + h2.0, y + h1.1 + h2.1),
            (x - h1.0 + h2.0, y - h1.1 + h2.1),
        ];
        let table = self.row_prefix();
        let mut sum = 0.0;
        for k in 0..4 {
            sum += self.edge_integral(table, corners[k], corners[(k + 1) & 3]);
        }
        sum / area
    }

    /// ∫ G dy along the segment p → q, cut at every texel column line and
    /// every row line within the clamp range [0, H − 1]. G is continuous,
    /// so each cut point's value serves the pieces on both sides.
    #[inline]
    fn edge_integral(&self, table: &[f64], p: (f64, f64), q: (f64, f64)) -> f64 {
        let (dx, dy) = (q.0 - p.0, q.1 - p.1);
        if dy == 0.0 {
            return 0.0;
        }
        let top = (self.height - 1) as f64;
        let (inv_dx, inv_dy) = (1.0 / dx, 1.0 / dy);
        // Next column line kx and row line ky crossed, and their parameters.
        let (sx, sy) = (dx.signum(), dy.signum());
        let mut kx = if dx > 0.0 {
            p.0.floor() + 1.0
        } else {
            p.0.ceil() - 1.0
        };
        let mut ky = if dy > 0.0 {
            (p.1.floor() + 1.0).max(0.0)
        } else {
            (p.1.ceil() - 1.0).min(top)
        };
        let tau_x = |kx: f64| {
            if dx == 0.0 {
                f64::INFINITY
            } else {
                (kx - p.0) * inv_dx
            }
        };
        let tau_y = |ky: f64| {
            if (0.0..=top).contains(&ky) {
                (ky - p.1) * inv_dy
            } else {
                f64::INFINITY
            }
        };
        let (mut tx, mut ty) = (tau_x(kx), tau_y(ky));
        let mut ta = 0.0;
        let mut ga = f64::NAN;
        let mut sum = 0.0;
        loop {
            let tb = tx.min(ty).min(1.0);
            if tb > ta {
                let cell = self.cell_at(
                    table,
                    p.0 + dx * 0.5 * (ta + tb),
                    p.1 + dy * 0.5 * (ta + tb),
                );
                let g = |t: f64| cell.g(p.0 + dx * t, (p.1 + dy * t).clamp(0.0, top));
                if ga.is_nan() {
                    ga = g(ta);
                }
                let (gm, gb) = (g(0.5 * (ta + tb)), g(tb));
                // Simpson's rule, exact for the cubic.
                sum += (tb - ta) * (ga + 4.0 * gm + gb);
                ga = gb;
            }
            if tb >= 1.0 {
                return sum * dy / 6.0;
            }
            if tx <= tb {
                kx += sx;
                tx = tau_x(kx);
            }
            if ty <= tb {
                ky += sy;
                ty = tau_y(ky);
            }
            ta = tb;
        }
    }

    /// G's polynomial on the texel cell holding (x, y): the two rows'
    /// prefix integrals there, blended in y.
    #[inline(always)]
    fn cell_at(&self, table: &[f64], x: f64, y: f64) -> GreenCell {
        let (w, h) = (self.width, self.height);
        let j = (y.clamp(0.0, (h - 1) as f64) as usize).min(h - 2);
        let x0 = x.floor();
        let xi = x0 as i64;
        // Pieces lie within a few map widths of [0, W): wrap without a
        // division in the common case.
        let turns = if (xi as u64) < w as u64 {
            0
        } else {
            xi.div_euclid(w as i64)
        };
        let i = (xi - turns * w as i64) as usize;
        let next = if i + 1 == w { 0 } else { i + 1 };
        let row = |r: usize| {
            let c = &table[r * (w + 1)..][..w + 1];
            let v = self.data[r * w + i] as f64;
            let half_slope = 0.5 * (self.data[r * w + next] as f64 - v);
            (c[i] + turns as f64 * c[w], v, half_slope)
        };
        GreenCell {
            x0,
            y0: j as f64,
            rows: [row(j), row(j + 1)],
        }
    }

    /// Derivatives of the map [value per radian] with respect to latitude
    /// and longitude, by central differences, as two maps.
    pub fn gradients(&self) -> (EquirectMap, EquirectMap) {
        let (w, h) = (self.width, self.height);
        let mut d_lat = vec![0.0f32; w * h];
        let mut d_lon = vec![0.0f32; w * h];
        let per_px_lon = w as f64 / TAU;
        let per_px_lat = h as f64 / PI;
        for j in 0..h {
            let up = j.saturating_sub(1);
            let down = (j + 1).min(h - 1);
            let rows = (down - up) as f64;
            for i in 0..w {
                let left = (i + w - 1) % w;
                let right = (i + 1) % w;
                let dx = (self.data[j * w + right] - self.data[j * w + left]) as f64 / 2.0;
                // Row index grows southward: d/dlat = -d/dy.
                let dy = (self.data[down * w + i] - self.data[up * w + i]) as f64 / rows;
                d_lon[j * w + i] = (dx * per_px_lon) as f32;
                d_lat[j * w + i] = (-dy * per_px_lat) as f32;
            }
        }
        (EquirectMap::new(w, h, d_lat), EquirectMap::new(w, h, d_lon))
    }
}

/// Tangent-space normal map (east, north, up), RGB-encoded as (n + 1) / 2.
#[derive(Clone, Debug)]
pub struct NormalMap {
    east: EquirectMap,
    north: EquirectMap,
    up: EquirectMap,
}

impl NormalMap {
    /// Read an RGB normal map.
    pub fn load(path: &Path) -> Result<Self> {
        let img = open_bounded(path)?;
        let (width, height) = (img.width() as usize, img.height() as usize);
        if width < 2 || height < 2 {
            return Err(Error::parse(path, "map must be at least 2x2 pixels"));
        }
        let rgb = img.to_rgb32f();
        let channel = |c: usize| {
            EquirectMap::new(
                width,
                height,
                rgb.pixels().map(|p| 2.0 * p.0[c] - 1.0).collect(),
            )
        };
        Ok(Self {
            east: channel(0),
            north: channel(1),
            up: channel(2),
        })
    }

    /// Unit tangent-space normal (east, north, up) at lat/lon.
    pub fn sample(&self, lat: f64, lon: f64) -> DVec3 {
        let v = DVec3::new(
            self.east.sample(lat, lon),
            self.north.sample(lat, lon),
            self.up.sample(lat, lon),
        );
        let len = v.length();
        if len > 1e-9 && v.z > 0.0 {
            v / len
        } else {
            DVec3::Z
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map(width: usize, height: usize, f: impl Fn(f64, f64) -> f64) -> EquirectMap {
        let mut data = Vec::new();
        for j in 0..height {
            for i in 0..width {
                let lat = FRAC_PI_2 - (j as f64 + 0.5) / height as f64 * PI;
                let lon = -PI + (i as f64 + 0.5) / width as f64 * TAU;
                data.push(f(lat, lon) as f32);
            }
        }
        EquirectMap::new(width, height, data)
    }

    #[test]
    fn longitude_zero_is_the_centre_and_north_is_up() {
        let m = map(360, 180, |lat, lon| {
            lat.to_degrees() * 1000.0 + lon.to_degrees()
        });
        // Texel centres reproduce their own coordinates.
        let v = m.sample(10.5f64.to_radians(), 0.5f64.to_radians());
        assert!((v - 10_500.5).abs() < 1e-3, "{v}");
        let v = m.sample_dir(DVec3::new(0.0, 0.0, 1.0));
        assert!(v > 89_000.0, "north pole reads the top row: {v}");
    }

    #[test]
    fn box_average_is_the_texel_mean_and_reduces_to_bilinear() {
        let m = map(16, 8, |lat, lon| 3.0 * lat + lon.sin());
        // A box covering exactly texels (2..6) x (1..3): their plain mean.
        let lon = -PI + 4.0 / 16.0 * TAU;
        let lat = FRAC_PI_2 - 2.0 / 8.0 * PI;
        let mut mean = 0.0;
        for j in 1..3 {
            for i in 2..6 {
                mean += m.data[j * 16 + i] as f64 / 8.0;
            }
        }
        assert!((m.box_average(lat, lon, 2.0, 1.0) - mean).abs() < 1e-9);
        // Half-texel boxes equal bilinear interpolation.
        for (lat, lon) in [(0.3, 1.0), (-0.7, -2.9), (0.1, 3.1)] {
            let a = m.box_average(lat, lon, 0.5, 0.5);
            assert!(
                (a - m.sample(lat, lon)).abs() < 1e-6,
                "{a} {}",
                m.sample(lat, lon)
            );
        }
    }

    #[test]
    fn large_scale_factor_is_the_harmonics_at_known_directions() {
        let c = [0.1, -0.2, 0.3, 0.05, -0.07, 0.11, 0.13, -0.17];
        let r = std::f64::consts::FRAC_1_SQRT_2;
        // (lat, lon, p) with p written out from the basis at x, y, z.
        let cases = [
            (90.0, 0.0, c[0] + c[3]),
            (-90.0, 0.0, -c[0] + c[3]),
            (0.0, 0.0, c[1] - 0.5 * c[3] + 0.5 * c[6]),
            (0.0, 90.0, c[2] - 0.5 * c[3] - 0.5 * c[6]),
            (0.0, 180.0, -c[1] - 0.5 * c[3] + 0.5 * c[6]),
            (
                45.0,
                0.0,
                r * (c[0] + c[1]) + 0.25 * c[3] + 0.5 * c[4] + 0.25 * c[6],
            ),
            (0.0, 45.0, r * (c[1] + c[2]) - 0.5 * c[3] + 0.5 * c[7]),
        ];
        for (lat, lon, p) in cases {
            let f = large_scale_factor(&c, f64::to_radians(lat), f64::to_radians(lon));
            assert!(
                (f - f64::exp(p)).abs() < 1e-12,
                "({lat}, {lon}): {f} vs {}",
                p.exp()
            );
        }
        // On a map: each texel times the factor at its centre.
        let mut m = EquirectMap::new(8, 4, vec![0.5; 32]);
        m.modulate_large_scale(&c);
        for (k, &v) in m.data.iter().enumerate() {
            let (lat, lon) = m.lat_lon_of((k % 8) as f64, (k / 8) as f64);
            let want = 0.5 * large_scale_factor(&c, lat, lon);
            assert!((v as f64 - want).abs() < 1e-6 * want, "texel {k}");
        }
    }

    #[test]
    fn power_stretch_keeps_the_ends_and_bends_the_middle() {
        // Values 2, 3, 4, 6: normalised t = 0, ¼, ½, 1.
        let raw = vec![2.0f32, 3.0, 4.0, 6.0];
        for power in [1.0, 0.5, 1.7, 3.0] {
            let mut m = EquirectMap::new(2, 2, raw.clone());
            m.stretch_power(0.2, 0.9, power);
            for (v, t) in m.data.iter().zip([0.0f64, 0.25, 0.5, 1.0]) {
                let want = 0.2 + 0.7 * t.powf(power);
                assert!(
                    (*v as f64 - want).abs() < 1e-6,
                    "power {power}: {v} vs {want}"
                );
            }
        }
        let (mut a, mut b) = (
            EquirectMap::new(2, 2, raw.clone()),
            EquirectMap::new(2, 2, raw),
        );
        a.stretch(0.1, 0.5);
        b.stretch_power(0.1, 0.5, 1.0);
        assert_eq!(a.data, b.data);
    }

    #[test]
    fn stretched_samples_average_along_longitude() {
        // Columns alternating 0/1: any footprint ≥ 4 texels wide sees the
        // mean ½; a 1-texel one still sees the bilinear value.
        let w = 64;
        let data: Vec<f32> = (0..w * 8).map(|k| (k % 2) as f32).collect();
        let m = EquirectMap::new(w, 8, data);
        for x in [3.0, 10.25, 40.5, 63.7] {
            for width in [4.0, 9.0, 30.0] {
                let v = m.sample_stretched(x, 3.5, width);
                assert!((v - 0.5).abs() < 1e-6, "x {x} width {width}: {v}");
            }
        }
        assert!((m.sample_stretched(10.0, 3.0, 1.0) - m.sample_texel(10.0, 3.0)).abs() < 1e-12);
        // A linear ramp in x (away from the wrap) is reproduced at any width.
        let ramp: Vec<f32> = (0..w * 8).map(|k| (k % w) as f32).collect();
        let m = EquirectMap::new(w, 8, ramp);
        for width in [2.0, 5.0, 12.0] {
            let v = m.sample_stretched(31.5, 2.0, width);
            assert!((v - 31.5).abs() < 1e-4, "width {width}: {v}");
        }
    }

    #[test]
    fn sampling_wraps_across_the_date_line() {
        let m = map(8, 4, |_, lon| lon.cos());
        let a = m.sample(0.0, PI - 1e-9);
        let b = m.sample(0.0, -PI + 1e-9);
        assert!((a - b).abs() < 1e-6);
    }

    /// A box centred past the seam (longitude beyond ±π, as a footprint
    /// straddling it gives) is the plain mean of the texels it wraps onto:
    /// here the last column and the first.
    #[test]
    fn box_average_wraps_past_the_seam() {
        let m = map(16, 8, |lat, lon| {
            3.0 * lat + lon.sin() + 2.0 * (lon + 3.0).cos()
        });
        let lat = FRAC_PI_2 - 3.0 / 8.0 * PI; // the edge between rows 2 and 3
        let mean = (m.data[2 * 16 + 15] + m.data[2 * 16] + m.data[3 * 16 + 15] + m.data[3 * 16])
            as f64
            / 4.0;
        for turns in [-1.0, 0.0, 1.0] {
            let lon = PI + turns * TAU; // the seam itself, seen from either side
            let a = m.box_average(lat, lon, 1.0, 1.0);
            assert!((a - mean).abs() < 1e-6, "lon {lon}: {a} against {mean}");
        }
    }

    #[test]
    fn gradients_of_a_smooth_field() {
        let m = map(720, 360, |lat, lon| lat.sin() + 0.5 * lon.sin());
        let (d_lat, d_lon) = m.gradients();
        let (lat, lon) = (0.3, 1.1);
        assert!((d_lat.sample(lat, lon) - lat.cos()).abs() < 1e-3);
        assert!((d_lon.sample(lat, lon) - 0.5 * lon.cos()).abs() < 1e-3);
    }
}
