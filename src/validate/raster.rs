//! `Raster`: the row-major single-channel `f32` image shared by the validation
//! tools (AMIE frames, renders, SSIM maps). Row 0 is the top of the image;
//! pixel `(col, row)` covers `[col, col+1) x [row, row+1)`, so its centre is at
//! `(col + 0.5, row + 0.5)` in pixel coordinates.

use crate::error::{Error, Result};

/// Row-major single-channel image.
#[derive(Debug, Clone, PartialEq)]
pub struct Raster {
    /// Number of columns.
    pub width: usize,
    /// Number of rows.
    pub height: usize,
    /// `width * height` values, row by row, top row first.
    pub data: Vec<f32>,
}

impl Raster {
    /// Wraps `data`; fails if its length is not `width * height`.
    pub fn new(width: usize, height: usize, data: Vec<f32>) -> Result<Self> {
        if data.len() != width * height {
            return Err(Error::invalid(
                "raster.data",
                format!("{} values for a {width}x{height} image", data.len()),
            ));
        }
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// An image filled with `value`.
    pub fn filled(width: usize, height: usize, value: f32) -> Self {
        Self {
            width,
            height,
            data: vec![value; width * height],
        }
    }

    /// Builds an image from `f(col, row)`.
    pub fn from_fn(width: usize, height: usize, mut f: impl FnMut(usize, usize) -> f32) -> Self {
        let mut data = Vec::with_capacity(width * height);
        for r in 0..height {
            for c in 0..width {
                data.push(f(c, r));
            }
        }
        Self {
            width,
            height,
            data,
        }
    }

    /// Value at column `col`, row `row` (panics when out of range).
    #[inline]
    pub fn get(&self, col: usize, row: usize) -> f32 {
        self.data[row * self.width + col]
    }

    /// Mutable value at column `col`, row `row`.
    #[inline]
    pub fn get_mut(&mut self, col: usize, row: usize) -> &mut f32 {
        &mut self.data[row * self.width + col]
    }

    /// The image upside down (row `r` becomes row `height - 1 - r`).
    pub fn flipped_rows(&self) -> Self {
        let mut data = Vec::with_capacity(self.data.len());
        for r in (0..self.height).rev() {
            data.extend_from_slice(&self.data[r * self.width..(r + 1) * self.width]);
        }
        Self {
            width: self.width,
            height: self.height,
            data,
        }
    }

    /// Fails unless `other` has the same size; `what` names the comparison.
    pub fn check_same_size(&self, other: &Raster, what: &str) -> Result<()> {
        if self.width != other.width || self.height != other.height {
            return Err(Error::invalid(
                what,
                format!(
                    "image sizes differ: {}x{} vs {}x{}",
                    self.width, self.height, other.width, other.height
                ),
            ));
        }
        Ok(())
    }

    /// Minimum and maximum of the finite values (`None` if there are none).
    pub fn min_max(&self) -> Option<(f32, f32)> {
        let mut it = self.data.iter().copied().filter(|v| v.is_finite());
        let first = it.next()?;
        Some(it.fold((first, first), |(lo, hi), v| (lo.min(v), hi.max(v))))
    }
}
