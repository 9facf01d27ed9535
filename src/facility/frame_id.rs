//! Frame-id block: the frame number drawn as binary cells in a screen corner
//! (so every camera image says which frame it saw), and its decoder.
//!
//! # Layout
//!
//! A block of `(bits + 7) × 3` cells of `cell_px × cell_px` screen pixels,
//! placed flush in the configured corner. The outer ring of cells is black
//! (quiet zone); the middle row holds, left to right:
//!
//! `START(on) GUARD(off) d[bits-1] … d[0] PARITY GUARD(off) END(on)`
//!
//! where `d` are the bits of `id mod 2^bits` (most significant first), `on`
//! is the top drive level and `off` level 0, and `PARITY` makes the number
//! of `on` cells among data + parity even. The decoder thresholds each cell
//! centre halfway between the START and first GUARD values, checks START,
//! GUARDs, END and parity, and returns the id.

use serde::Deserialize;

use crate::error::{Error, Result};

use super::dither::Roi;
use super::lut::{decode_grey, encode_grey};

/// Screen corner of the block.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Corner {
    /// Upper left.
    #[default]
    TopLeft,
    /// Upper right.
    TopRight,
    /// Lower left.
    BottomLeft,
    /// Lower right.
    BottomRight,
}

/// Why a block could not be decoded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    /// The block region is not inside the image.
    #[error("frame-id block does not fit in the image")]
    OutOfImage,
    /// START is not brighter than GUARD: no block there.
    #[error("no frame-id block (no contrast between start and guard cells)")]
    NoContrast,
    /// START/GUARD/END cells have the wrong value.
    #[error("frame-id framing cells wrong")]
    Framing,
    /// Parity check failed.
    #[error("frame-id parity error")]
    Parity,
}

/// Encoder/decoder of frame ids for one screen.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameIdCode {
    /// Drawn at all.
    pub enabled: bool,
    /// Corner.
    pub corner: Corner,
    /// Data bits, 8 … 32.
    pub bits: u32,
    /// Cell side in pixels.
    pub cell_px: usize,
    /// Bits per channel of the display (8 or 10).
    pub display_bits: u32,
    screen: (usize, usize),
}

impl FrameIdCode {
    /// Block size in pixels `(width, height)` for `bits` and `cell_px`.
    pub fn block_size_for(bits: u32, cell_px: usize) -> (usize, usize) {
        // Saturating: an absurd cell size must fail the fit check, not wrap.
        (
            (bits as usize + 7).saturating_mul(cell_px),
            3usize.saturating_mul(cell_px),
        )
    }

    /// New code for a `screen = (width, height)` display.
    pub fn new(
        enabled: bool,
        corner: Corner,
        bits: u32,
        cell_px: usize,
        display_bits: u32,
        screen: (usize, usize),
    ) -> Result<FrameIdCode> {
        if !(8..=32).contains(&bits) {
            return Err(Error::invalid(
                "frame_id.bits",
                format!("must be 8 … 32, found {bits}"),
            ));
        }
        if cell_px == 0 {
            return Err(Error::invalid("frame_id.cell_px", "must be ≥ 1"));
        }
        let (bw, bh) = Self::block_size_for(bits, cell_px);
        if bw > screen.0 || bh > screen.1 {
            return Err(Error::invalid(
                "frame_id.cell_px",
                format!(
                    "the {bw}×{bh} block does not fit the {}×{} screen",
                    screen.0, screen.1
                ),
            ));
        }
        Ok(FrameIdCode {
            enabled,
            corner,
            bits,
            cell_px,
            display_bits,
            screen,
        })
    }

    /// The screen rectangle of the block (including the quiet zone).
    pub fn region(&self) -> Roi {
        let (bw, bh) = Self::block_size_for(self.bits, self.cell_px);
        let (w, h) = self.screen;
        let (x, y) = match self.corner {
            Corner::TopLeft => (0, 0),
            Corner::TopRight => (w - bw, 0),
            Corner::BottomLeft => (0, h - bh),
            Corner::BottomRight => (w - bw, h - bh),
        };
        Roi::new(x, y, bw, bh)
    }

    /// On/off values of the middle-row cells for `id` (quiet zone excluded).
    pub fn cells(&self, id: u64) -> Vec<bool> {
        let v = id & self.mask();
        let mut c = Vec::with_capacity(self.bits as usize + 5);
        c.extend([true, false]);
        let mut ones = 0;
        for i in (0..self.bits).rev() {
            let b = (v >> i) & 1 == 1;
            ones += u32::from(b);
            c.push(b);
        }
        c.push(ones % 2 == 1);
        c.push(false);
        c.push(true);
        c
    }

    fn mask(&self) -> u64 {
        if self.bits == 64 {
            u64::MAX
        } else {
            (1u64 << self.bits) - 1
        }
    }

    /// Draws the block for `id` into `frame` (nothing if disabled) and
    /// returns the region written.
    pub fn encode(&self, frame: &mut [u32], id: u64) -> Result<Option<Roi>> {
        let (w, h) = self.screen;
        if frame.len() != w * h {
            return Err(Error::invalid(
                "frame",
                format!("frame has {} pixels, screen is {w}×{h}", frame.len()),
            ));
        }
        if !self.enabled {
            return Ok(None);
        }
        let r = self.region();
        let on = encode_grey(
            if self.display_bits == 10 { 1023 } else { 255 },
            self.display_bits,
        );
        let off = encode_grey(0, self.display_bits);
        for y in r.y..r.y + r.height {
            frame[y * w + r.x..y * w + r.x + r.width].fill(off);
        }
        let c = self.cell_px;
        for (i, bit) in self.cells(id).into_iter().enumerate() {
            if bit {
                let x0 = r.x + (i + 1) * c;
                for y in r.y + c..r.y + 2 * c {
                    frame[y * w + x0..y * w + x0 + c].fill(on);
                }
            }
        }
        Ok(Some(r))
    }

    /// Decodes cell values sampled at the middle-row cell centres (in
    /// [`FrameIdCode::cells`] order, any brightness unit).
    pub fn decode_samples(&self, samples: &[f64]) -> std::result::Result<u64, DecodeError> {
        let n = self.bits as usize + 5;
        if samples.len() != n {
            return Err(DecodeError::OutOfImage);
        }
        let (on, off) = (samples[0], samples[1]);
        if on.partial_cmp(&off) != Some(std::cmp::Ordering::Greater) {
            return Err(DecodeError::NoContrast);
        }
        let thr = 0.5 * (on + off);
        let b: Vec<bool> = samples.iter().map(|&s| s > thr).collect();
        if !b[0] || b[1] || b[n - 2] || !b[n - 1] {
            return Err(DecodeError::Framing);
        }
        let data = &b[2..2 + self.bits as usize];
        let ones = data.iter().filter(|&&x| x).count() + usize::from(b[n - 3]);
        if ones % 2 != 0 {
            return Err(DecodeError::Parity);
        }
        Ok(data.iter().fold(0u64, |acc, &x| (acc << 1) | u64::from(x)))
    }

    /// Decodes the block from a frame buffer of the screen size.
    pub fn decode_frame(&self, frame: &[u32]) -> std::result::Result<u64, DecodeError> {
        let (w, h) = self.screen;
        if frame.len() != w * h {
            return Err(DecodeError::OutOfImage);
        }
        self.decode_image(|x, y| decode_grey(frame[y * w + x], self.display_bits) as f64)
    }

    /// Decodes from any image in screen coordinates, given a sampler
    /// `(x, y) → brightness` (e.g. a camera image remapped to the screen).
    pub fn decode_image(
        &self,
        sample: impl Fn(usize, usize) -> f64,
    ) -> std::result::Result<u64, DecodeError> {
        let r = self.region();
        let c = self.cell_px;
        let y = r.y + c + c / 2;
        let samples: Vec<f64> = (0..self.bits as usize + 5)
            .map(|i| sample(r.x + (i + 1) * c + c / 2, y))
            .collect();
        self.decode_samples(&samples)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn code(corner: Corner, bits: u32, cell: usize) -> FrameIdCode {
        FrameIdCode::new(true, corner, bits, cell, 8, (100, 60)).unwrap()
    }

    #[test]
    fn round_trips_in_every_corner() {
        for corner in [
            Corner::TopLeft,
            Corner::TopRight,
            Corner::BottomLeft,
            Corner::BottomRight,
        ] {
            for (bits, cell) in [(16, 3), (24, 2), (32, 1)] {
                let c = code(corner, bits, cell);
                let mut frame = vec![0x0012_3456; 100 * 60];
                for id in [0u64, 1, 0xA5A5, (1 << bits) - 1, 123_456_789] {
                    let r = c.encode(&mut frame, id).unwrap().unwrap();
                    assert!(r.fits(100, 60));
                    assert_eq!(c.decode_frame(&frame).unwrap(), id & ((1u64 << bits) - 1));
                }
                // Pixels outside the block untouched.
                let r = c.region();
                for y in 0..60 {
                    for x in 0..100 {
                        if !r.contains(x, y) {
                            assert_eq!(frame[y * 100 + x], 0x0012_3456);
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn region_sits_in_the_corner() {
        let c = code(Corner::BottomRight, 16, 3);
        // (16 + 7) cells × 3 px wide, 3 cells × 3 px high.
        assert_eq!(c.region(), Roi::new(100 - 69, 60 - 9, 69, 9));
        assert_eq!(code(Corner::TopLeft, 16, 3).region(), Roi::new(0, 0, 69, 9));
    }

    #[test]
    fn cell_layout_is_as_documented() {
        let c = code(Corner::TopLeft, 8, 1);
        // id 0b1011_0001: four ones → parity 0.
        let cells = c.cells(0b1011_0001);
        let want = [1, 0, 1, 0, 1, 1, 0, 0, 0, 1, 0, 0, 1];
        assert_eq!(cells, want.map(|b| b == 1));
        // Drawn: middle row, cell i at x = (i+1)·cell.
        let mut frame = vec![0; 100 * 60];
        c.encode(&mut frame, 0b1011_0001).unwrap();
        let row: Vec<bool> = (1..14).map(|x| frame[100 + x] == 0x00FF_FFFF).collect();
        assert_eq!(row, want.map(|b| b == 1));
        assert!(frame[..100].iter().all(|&p| p == 0), "quiet zone row");
    }

    #[test]
    fn corrupted_blocks_are_rejected() {
        let c = code(Corner::TopLeft, 16, 2);
        let mut frame = vec![0; 100 * 60];
        c.encode(&mut frame, 0x1234).unwrap();
        // Flip one data cell: parity error.
        let (x, y) = (2 * 4 + 1, 3);
        frame[y * 100 + x] ^= 0x00FF_FFFF;
        assert_eq!(c.decode_frame(&frame), Err(DecodeError::Parity));
        assert_eq!(
            c.decode_frame(&vec![0; 100 * 60]),
            Err(DecodeError::NoContrast)
        );
        assert_eq!(c.decode_frame(&[0; 10]), Err(DecodeError::OutOfImage));
        let mut disabled = c.clone();
        disabled.enabled = false;
        let mut f2 = vec![7; 100 * 60];
        assert_eq!(disabled.encode(&mut f2, 5).unwrap(), None);
        assert!(f2.iter().all(|&p| p == 7));
        assert!(FrameIdCode::new(true, Corner::TopLeft, 32, 4, 8, (100, 60)).is_err());
        assert!(FrameIdCode::new(true, Corner::TopLeft, 4, 4, 8, (100, 60)).is_err());
    }

    #[test]
    fn decodes_from_a_noisy_float_image() {
        let c = code(Corner::TopRight, 24, 3);
        let mut frame = vec![0; 100 * 60];
        c.encode(&mut frame, 0xBEEF42).unwrap();
        // Camera-like: low contrast, offset and deterministic noise.
        let img = |x: usize, y: usize| {
            let v = decode_grey(frame[y * 100 + x], 8) as f64 / 255.0;
            0.2 + 0.3 * v + 0.02 * (((x * 31 + y * 17) % 7) as f64 / 7.0 - 0.5)
        };
        assert_eq!(c.decode_image(img), Ok(0xBEEF42));
    }
}
