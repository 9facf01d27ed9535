//! Files written by `optistim render`: f32 TIFFs of radiance, camera-effective
//! radiance and electrons, a 16-bit PNG of DN, an 8-bit stretched quick-look
//! `preview.png`, and `summary.json` (the render's numbers and the preview's
//! stretch).

use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

use serde::Serialize;

use crate::error::{Error, Result};
use crate::render::detector::{SceneImages, Summary};

/// Percentile of the lit pixels' DN shown white in `preview.png`.
pub const PREVIEW_WHITE_PERCENTILE: f64 = 99.9;

/// The stretch of `preview.png`: grey = 255 · clamp((DN − black) / (white −
/// black), 0, 1)^(1/gamma), rounded.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Preview {
    pub file: String,
    pub black_dn: u16,
    pub white_dn: u16,
    pub gamma: f64,
    /// How `white_dn` was chosen.
    pub white_rule: String,
}

impl Preview {
    /// Black at DN 0 (the model has no bias: the sky is 0), white at the
    /// [`PREVIEW_WHITE_PERCENTILE`] (nearest rank) of the pixels above 0,
    /// so a small disk in a dark frame still fills the grey range; 1 for
    /// an all-dark image.
    pub fn for_dn(dn: &[u16]) -> Preview {
        let mut lit: Vec<u16> = dn.iter().copied().filter(|&v| v > 0).collect();
        lit.sort_unstable();
        let white = if lit.is_empty() {
            1
        } else {
            let rank = (PREVIEW_WHITE_PERCENTILE / 100.0 * lit.len() as f64).ceil() as usize;
            lit[rank.clamp(1, lit.len()) - 1]
        };
        Preview {
            file: "preview.png".into(),
            black_dn: 0,
            white_dn: white,
            gamma: 1.0,
            white_rule: format!(
                "{PREVIEW_WHITE_PERCENTILE}th percentile (nearest rank) of the DN of pixels above 0"
            ),
        }
    }

    /// The 8-bit grey level of `dn`.
    pub fn grey(&self, dn: u16) -> u8 {
        let span = (self.white_dn as f64 - self.black_dn as f64).max(1.0);
        let t = ((dn as f64 - self.black_dn as f64) / span).clamp(0.0, 1.0);
        (255.0 * t.powf(1.0 / self.gamma)).round() as u8
    }
}

/// `summary.json`: the render's numbers and the preview's stretch.
#[derive(Serialize)]
struct SummaryFile<'a> {
    #[serde(flatten)]
    summary: &'a Summary,
    preview: &'a Preview,
}

/// Write a single-channel f32 TIFF.
pub fn write_f32_tiff(path: &Path, width: usize, height: usize, data: &[f32]) -> Result<()> {
    let file = File::create(path).map_err(|e| Error::io(path, e))?;
    let mut encoder = tiff::encoder::TiffEncoder::new(BufWriter::new(file))
        .map_err(|e| Error::parse(path, e.to_string()))?;
    encoder
        .write_image::<tiff::encoder::colortype::Gray32Float>(width as u32, height as u32, data)
        .map_err(|e| Error::parse(path, e.to_string()))
}

/// Write a 16-bit grey PNG.
pub fn write_u16_png(path: &Path, width: usize, height: usize, data: &[u16]) -> Result<()> {
    let img = image::ImageBuffer::<image::Luma<u16>, _>::from_raw(
        width as u32,
        height as u32,
        data.to_vec(),
    )
    .ok_or_else(|| Error::Other("image size mismatch".into()))?;
    img.save(path)
        .map_err(|e| Error::parse(path, e.to_string()))
}

/// Write the 8-bit quick-look of `dn` with the stretch `preview`.
pub fn write_preview_png(
    path: &Path,
    width: usize,
    height: usize,
    dn: &[u16],
    preview: &Preview,
) -> Result<()> {
    let grey: Vec<u8> = dn.iter().map(|&v| preview.grey(v)).collect();
    let img = image::GrayImage::from_raw(width as u32, height as u32, grey)
        .ok_or_else(|| Error::Other("image size mismatch".into()))?;
    img.save(path)
        .map_err(|e| Error::parse(path, e.to_string()))
}

/// Write the products of a render into `dir` (created if needed).
pub fn write_render(dir: &Path, width: usize, height: usize, images: &SceneImages) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    write_f32_tiff(&dir.join("radiance.tiff"), width, height, &images.radiance)?;
    write_f32_tiff(
        &dir.join("radiance_effective.tiff"),
        width,
        height,
        &images.radiance_effective,
    )?;
    write_f32_tiff(
        &dir.join("electrons.tiff"),
        width,
        height,
        &images.electrons,
    )?;
    write_u16_png(&dir.join("dn.png"), width, height, &images.dn)?;
    let preview = Preview::for_dn(&images.dn);
    write_preview_png(
        &dir.join(&preview.file),
        width,
        height,
        &images.dn,
        &preview,
    )?;
    let path = dir.join("summary.json");
    let file = SummaryFile {
        summary: &images.summary,
        preview: &preview,
    };
    let text = serde_json::to_string_pretty(&file).map_err(|e| Error::Other(e.to_string()))?;
    std::fs::write(&path, text + "\n").map_err(|e| Error::io(&path, e))
}
