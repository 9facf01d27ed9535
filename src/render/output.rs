//! Files written by `optistim render`: f32 TIFFs of radiance, camera-effective
//! radiance and electrons,
//! a 16-bit PNG of DN, and `summary.json`.

use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

use crate::error::{Error, Result};
use crate::render::detector::SceneImages;

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

/// Write the four products of a render into `dir` (created if needed).
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
    let path = dir.join("summary.json");
    let text =
        serde_json::to_string_pretty(&images.summary).map_err(|e| Error::Other(e.to_string()))?;
    std::fs::write(&path, text + "\n").map_err(|e| Error::io(&path, e))
}
