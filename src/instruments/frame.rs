//! Camera frames on disk and the statistics a calibration takes of them:
//! [`read_frame`] for 16-bit grey PNG, 16-bit / 32-bit float grey TIFF and
//! FITS (primary HDU), every size checked before allocation; dark
//! subtraction, saturation counts and region statistics that report a
//! saturated frame by its pattern.
//!
//! Pixel (0, 0) is the top-left pixel; data are row-major, top row first.
//! A FITS file's first stored row is taken as the top row (as OpenCV/numpy
//! pipelines write it) unless its header says `ROWORDER = 'BOTTOM-UP'`.

use std::io::{BufReader, Read};
use std::path::Path;

use super::config::{abbreviate, MAX_FRAME_PIXELS};
use super::CameraFrame;
use crate::error::{Error, Result};

/// A frame as read: `(width, height, DN row-major top row first)`.
pub type RawFrame = (usize, usize, Vec<f32>);

/// FITS header blocks read at most before `END` must have appeared.
pub const MAX_FITS_HEADER_BLOCKS: usize = 64;
const FITS_BLOCK: usize = 2880;
const FITS_CARD: usize = 80;

/// Reads a grey frame by its extension (`png`; `tif`/`tiff`;
/// `fits`/`fit`/`fts`, any case). Colour images, other bit depths, images
/// of more than 2^26 pixels and non-finite pixels are errors naming the file.
pub fn read_frame(path: &Path) -> Result<RawFrame> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    let frame = match ext.as_str() {
        "png" => read_png(path),
        "tif" | "tiff" => read_tiff(path),
        "fits" | "fit" | "fts" => read_fits(path),
        _ => Err(Error::parse(
            path,
            "unknown frame format: expected .png, .tif, .tiff or .fits",
        )),
    }?;
    if let Some(i) = frame.2.iter().position(|v| !v.is_finite()) {
        return Err(Error::parse(
            path,
            format!("pixel ({}, {}) is not finite", i % frame.0, i / frame.0),
        ));
    }
    Ok(frame)
}

fn check_size(path: &Path, w: u64, h: u64) -> Result<(usize, usize)> {
    let n = w.checked_mul(h);
    match n {
        Some(n) if w > 0 && h > 0 && n <= MAX_FRAME_PIXELS as u64 => Ok((w as usize, h as usize)),
        _ => Err(Error::parse(
            path,
            format!("image of {w} × {h} pixels: must be non-empty and at most {MAX_FRAME_PIXELS} pixels"),
        )),
    }
}

fn open(path: &Path) -> Result<std::fs::File> {
    std::fs::File::open(path).map_err(|e| Error::io(path, e))
}

fn read_png(path: &Path) -> Result<RawFrame> {
    use image::codecs::png::PngDecoder;
    use image::{ColorType, ImageDecoder, Limits};
    let perr = |e: image::ImageError| Error::parse(path, format!("PNG: {e}"));
    let mut limits = Limits::default();
    limits.max_alloc = Some(MAX_FRAME_PIXELS as u64 * 2 + (1 << 20));
    let dec = PngDecoder::with_limits(BufReader::new(open(path)?), limits).map_err(perr)?;
    let (w, h) = dec.dimensions();
    let (w, h) = check_size(path, w.into(), h.into())?;
    let ct = dec.color_type();
    if !matches!(ct, ColorType::L16 | ColorType::L8) {
        return Err(Error::parse(
            path,
            format!("PNG of colour type {ct:?}: expected 8- or 16-bit grey"),
        ));
    }
    let mut buf = vec![0u8; dec.total_bytes() as usize];
    dec.read_image(&mut buf).map_err(perr)?;
    let data = if ct == ColorType::L16 {
        buf.chunks_exact(2)
            .map(|b| u16::from_ne_bytes([b[0], b[1]]) as f32)
            .collect()
    } else {
        buf.iter().map(|&b| b as f32).collect()
    };
    Ok((w, h, data))
}

fn read_tiff(path: &Path) -> Result<RawFrame> {
    use tiff::decoder::{Decoder, DecodingResult, Limits};
    let terr = |e: tiff::TiffError| Error::parse(path, format!("TIFF: {e}"));
    let mut limits = Limits::default();
    limits.decoding_buffer_size = MAX_FRAME_PIXELS * 4;
    limits.intermediate_buffer_size = 64 << 20;
    limits.ifd_value_size = 1 << 20;
    let mut dec = Decoder::new(BufReader::new(open(path)?))
        .map_err(terr)?
        .with_limits(limits);
    let (w, h) = dec.dimensions().map_err(terr)?;
    let (w, h) = check_size(path, w.into(), h.into())?;
    let ct = dec.colortype().map_err(terr)?;
    let data: Vec<f32> = match (ct, dec.read_image().map_err(terr)?) {
        (tiff::ColorType::Gray(16), DecodingResult::U16(v)) => {
            v.into_iter().map(f32::from).collect()
        }
        (tiff::ColorType::Gray(32), DecodingResult::F32(v)) => v,
        (tiff::ColorType::Gray(8), DecodingResult::U8(v)) => v.into_iter().map(f32::from).collect(),
        (ct, _) => {
            return Err(Error::parse(
                path,
                format!("TIFF of colour type {ct:?}: expected 16-bit or 32-bit float grey"),
            ))
        }
    };
    if data.len() != w * h {
        return Err(Error::parse(
            path,
            "TIFF: pixel count differs from its size",
        ));
    }
    Ok((w, h, data))
}

/// What the FITS reader needs from a primary header.
struct FitsHeader {
    bitpix: i64,
    width: usize,
    height: usize,
    bzero: f64,
    bscale: f64,
    bottom_up: bool,
    /// Header length, bytes (whole blocks).
    length: usize,
}

fn read_fits(path: &Path) -> Result<RawFrame> {
    let mut file = open(path)?;
    let file_len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    let hdr = read_fits_header(path, &mut file)?;
    let bytes_per = (hdr.bitpix.unsigned_abs() / 8) as usize;
    let n = hdr.width * hdr.height;
    let data_len = n
        .checked_mul(bytes_per)
        .ok_or_else(|| Error::parse(path, "FITS: data size overflows"))?;
    if (hdr.length as u64).saturating_add(data_len as u64) > file_len {
        return Err(Error::parse(
            path,
            format!("FITS: truncated: {data_len} data bytes expected after the header, file has {file_len} bytes"),
        ));
    }
    let mut raw = vec![0u8; data_len];
    file.read_exact(&mut raw).map_err(|e| Error::io(path, e))?;
    let value = |b: &[u8]| -> f64 {
        match hdr.bitpix {
            8 => b[0] as f64,
            16 => i16::from_be_bytes([b[0], b[1]]) as f64,
            32 => i32::from_be_bytes([b[0], b[1], b[2], b[3]]) as f64,
            -32 => f32::from_be_bytes([b[0], b[1], b[2], b[3]]) as f64,
            _ => f64::from_be_bytes(b.try_into().unwrap_or([0; 8])),
        }
    };
    let mut data: Vec<f32> = raw
        .chunks_exact(bytes_per)
        .map(|b| (hdr.bzero + hdr.bscale * value(b)) as f32)
        .collect();
    if hdr.bottom_up {
        let rows: Vec<&[f32]> = data.chunks_exact(hdr.width).rev().collect();
        data = rows.concat();
    }
    Ok((hdr.width, hdr.height, data))
}

fn read_fits_header(path: &Path, file: &mut impl Read) -> Result<FitsHeader> {
    let perr = |m: String| Error::parse(path, format!("FITS header: {m}"));
    let mut keys: Vec<(String, String)> = Vec::new();
    let mut block = [0u8; FITS_BLOCK];
    for b in 0..MAX_FITS_HEADER_BLOCKS {
        file.read_exact(&mut block).map_err(|_| {
            perr(format!(
                "truncated in block {b} (a header is 2880-byte blocks ending with END)"
            ))
        })?;
        for (i, card) in block.chunks_exact(FITS_CARD).enumerate() {
            let card_no = b * (FITS_BLOCK / FITS_CARD) + i + 1;
            let card = std::str::from_utf8(card)
                .ok()
                .filter(|c| c.bytes().all(|x| (0x20..=0x7e).contains(&x)))
                .ok_or_else(|| perr(format!("card {card_no} is not printable ASCII")))?;
            let key = card[..8].trim_end();
            if key == "END" {
                return fits_header_from(&keys, (b + 1) * FITS_BLOCK).map_err(perr);
            }
            if card_no == 1 && !(key == "SIMPLE" && card_value(card) == "T") {
                return Err(perr(
                    "not a FITS file: the first card must be SIMPLE = T".into(),
                ));
            }
            if &card[8..10] == "= " {
                keys.push((key.to_string(), card_value(card).to_string()));
            }
        }
    }
    Err(perr(format!(
        "no END card within {MAX_FITS_HEADER_BLOCKS} blocks"
    )))
}

/// A card's value field: a quoted string's content, or the text before a
/// `/` comment, trimmed.
fn card_value(card: &str) -> &str {
    let v = card[10..].trim_start();
    if let Some(s) = v.strip_prefix('\'') {
        return s.split('\'').next().unwrap_or("").trim_end();
    }
    v.split('/').next().unwrap_or("").trim()
}

fn fits_header_from(
    keys: &[(String, String)],
    length: usize,
) -> std::result::Result<FitsHeader, String> {
    let get = |k: &str| {
        keys.iter()
            .find(|(key, _)| key == k)
            .map(|(_, v)| v.as_str())
    };
    let int = |k: &str| -> std::result::Result<i64, String> {
        let v = get(k).ok_or(format!("missing {k}"))?;
        v.parse()
            .map_err(|_| format!("{k} = `{}` is not an integer", abbreviate(v, 20)))
    };
    let float = |k: &str, default: f64| -> std::result::Result<f64, String> {
        match get(k) {
            None => Ok(default),
            Some(v) => v
                .replace(['D', 'd'], "E")
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or(format!(
                    "{k} = `{}` is not a finite number",
                    abbreviate(v, 20)
                )),
        }
    };
    let bitpix = int("BITPIX")?;
    if ![8, 16, 32, -32, -64].contains(&bitpix) {
        return Err(format!("BITPIX = {bitpix}: expected 8, 16, 32, -32 or -64"));
    }
    let naxis = int("NAXIS")?;
    if naxis != 2 {
        return Err(format!("NAXIS = {naxis}: expected a 2-D image"));
    }
    let (w, h) = (int("NAXIS1")?, int("NAXIS2")?);
    let ok = w > 0
        && h > 0
        && (w as u64)
            .checked_mul(h as u64)
            .is_some_and(|n| n <= MAX_FRAME_PIXELS as u64);
    if !ok {
        return Err(format!(
            "NAXIS1 × NAXIS2 = {w} × {h}: must be non-empty and at most {MAX_FRAME_PIXELS} pixels"
        ));
    }
    let bottom_up = match get("ROWORDER") {
        None | Some("TOP-DOWN") => false,
        Some("BOTTOM-UP") => true,
        Some(v) => {
            return Err(format!(
                "ROWORDER = `{}`: expected TOP-DOWN or BOTTOM-UP",
                abbreviate(v, 20)
            ))
        }
    };
    Ok(FitsHeader {
        bitpix,
        width: w as usize,
        height: h as usize,
        bzero: float("BZERO", 0.0)?,
        bscale: float("BSCALE", 1.0)?,
        bottom_up,
        length,
    })
}

/// A rectangle of pixels: columns `x .. x + width`, rows `y .. y + height`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Rect {
    pub x: usize,
    pub y: usize,
    pub width: usize,
    pub height: usize,
}

impl Rect {
    /// The centred rectangle covering `fraction` (0, 1] of each side of a
    /// `width × height` frame (at least one pixel).
    pub fn centred(width: usize, height: usize, fraction: f64) -> Rect {
        let f = if fraction.is_finite() {
            fraction.clamp(0.0, 1.0)
        } else {
            1.0
        };
        let side = |n: usize| ((n as f64 * f).round() as usize).clamp(1, n.max(1));
        let (w, h) = (side(width), side(height));
        Rect {
            x: (width - w) / 2,
            y: (height - h) / 2,
            width: w,
            height: h,
        }
    }
}

/// Mean and sample standard deviation of a region, DN.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RegionStats {
    pub mean: f64,
    pub std: f64,
    pub pixels: usize,
}

/// `frame − dark`, pixel by pixel. The dark must have the frame's size and
/// exposure (a dark at another exposure has another dark current).
pub fn subtract_dark(frame: &CameraFrame, dark: &CameraFrame) -> Result<Vec<f32>> {
    if (frame.width, frame.height) != (dark.width, dark.height) {
        return Err(Error::Other(format!(
            "dark frame is {} × {} pixels, the frame {} × {}",
            dark.width, dark.height, frame.width, frame.height
        )));
    }
    let rel =
        (frame.exposure_s - dark.exposure_s).abs() / frame.exposure_s.abs().max(f64::MIN_POSITIVE);
    if !(rel <= 1e-6) {
        return Err(Error::Other(format!(
            "dark frame exposure {} s differs from the frame's {} s: take a dark at each exposure",
            dark.exposure_s, frame.exposure_s
        )));
    }
    Ok(frame
        .data
        .iter()
        .zip(&dark.data)
        .map(|(a, b)| a - b)
        .collect())
}

/// Pixels at or above the frame's saturation level.
pub fn saturated_pixels(frame: &CameraFrame) -> usize {
    frame
        .data
        .iter()
        .filter(|&&v| v >= frame.saturation_dn)
        .count()
}

/// The error for a frame with `pixels` saturated pixels, naming its pattern.
pub fn saturated_error(pattern: &str, pixels: usize, saturation_dn: f32) -> Error {
    Error::Other(format!(
        "saturated frame for pattern `{pattern}`: {pixels} pixels at or above {saturation_dn} DN; lower the exposure"
    ))
}

/// Mean and standard deviation of `rect` of `frame − dark` (dark optional).
/// A saturated pixel in the region (of the raw frame) is an error naming
/// `pattern` and the count; a region outside the frame is an error.
pub fn region_mean(
    frame: &CameraFrame,
    dark: Option<&CameraFrame>,
    rect: Rect,
    pattern: &str,
) -> Result<RegionStats> {
    let inside = rect.width > 0
        && rect.height > 0
        && rect
            .x
            .checked_add(rect.width)
            .is_some_and(|e| e <= frame.width)
        && rect
            .y
            .checked_add(rect.height)
            .is_some_and(|e| e <= frame.height);
    if !inside || frame.data.len() != frame.width * frame.height {
        return Err(Error::Other(format!(
            "pattern `{pattern}`: region columns {}..{}, rows {}..{} is not inside the {} × {} frame",
            rect.x,
            rect.x.saturating_add(rect.width),
            rect.y,
            rect.y.saturating_add(rect.height),
            frame.width,
            frame.height
        )));
    }
    let corrected;
    let values: &[f32] = match dark {
        Some(d) => {
            corrected = subtract_dark(frame, d)?;
            &corrected
        }
        None => &frame.data,
    };
    let rows = || {
        (rect.y..rect.y + rect.height).map(|r| {
            let start = r * frame.width + rect.x;
            start..start + rect.width
        })
    };
    let saturated: usize = rows()
        .map(|r| {
            frame.data[r]
                .iter()
                .filter(|&&v| v >= frame.saturation_dn)
                .count()
        })
        .sum();
    if saturated > 0 {
        return Err(saturated_error(pattern, saturated, frame.saturation_dn));
    }
    let n = (rect.width * rect.height) as f64;
    let sum_of = |f: &dyn Fn(f64) -> f64| -> f64 {
        rows()
            .map(|r| values[r].iter().map(|&v| f(v as f64)).sum::<f64>())
            .sum()
    };
    let mean = sum_of(&|v| v) / n;
    // Two passes: no cancellation for a bright, quiet region.
    let var = if n > 1.0 {
        sum_of(&|v| (v - mean) * (v - mean)) / (n - 1.0)
    } else {
        0.0
    };
    Ok(RegionStats {
        mean,
        std: var.sqrt(),
        pixels: rect.width * rect.height,
    })
}
