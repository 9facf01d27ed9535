//! The label files of one frame: masks (8-bit TIFF, 0/1), depth, latitude
//! and longitude (f32 TIFF), normals (3 × f32 TIFF), `labels.json` (schema
//! [`SCHEMA`](super::SCHEMA)) and a COCO-style `coco.json`.

use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

use serde::Serialize;
use serde_json::{json, Value};

use super::{FrameLabels, LabelImages, Labels, SCHEMA};
use crate::error::{Error, Result};
use crate::render::output::write_f32_tiff;

/// File names of the label images, in the order written.
pub const IMAGE_FILES: [&str; 7] = [
    "body_mask.tiff",
    "lit_mask.tiff",
    "shadow_mask.tiff",
    "depth.tiff",
    "normals.tiff",
    "latitude.tiff",
    "longitude.tiff",
];

/// File names of the JSON label files.
pub const JSON_FILES: [&str; 2] = ["labels.json", "coco.json"];

/// All files [`write`] creates: the images, then the JSON files.
pub fn all_files() -> impl Iterator<Item = &'static str> {
    IMAGE_FILES.into_iter().chain(JSON_FILES)
}

/// `labels.json`.
#[derive(Serialize)]
struct LabelsFile<'a> {
    schema: &'static str,
    #[serde(flatten)]
    frame: &'a FrameLabels,
    files: Value,
}

/// Writes the labels into `dir` (which must exist); `image_file` is the
/// name COCO's `images[0].file_name` gives the rendered frame.
pub fn write(dir: &Path, labels: &Labels, image_file: &str) -> Result<()> {
    let im = &labels.images;
    let (w, h) = (im.width, im.height);
    write_u8_tiff(&dir.join(IMAGE_FILES[0]), w, h, &im.body)?;
    write_u8_tiff(&dir.join(IMAGE_FILES[1]), w, h, &im.lit)?;
    write_u8_tiff(&dir.join(IMAGE_FILES[2]), w, h, &im.shadow)?;
    write_f32_tiff(&dir.join(IMAGE_FILES[3]), w, h, &im.depth)?;
    write_rgb_f32_tiff(&dir.join(IMAGE_FILES[4]), w, h, &im.normals)?;
    write_f32_tiff(&dir.join(IMAGE_FILES[5]), w, h, &im.latitude)?;
    write_f32_tiff(&dir.join(IMAGE_FILES[6]), w, h, &im.longitude)?;
    let record = LabelsFile {
        schema: SCHEMA,
        frame: &labels.frame,
        files: json!({
            "body_mask": IMAGE_FILES[0], "lit_mask": IMAGE_FILES[1],
            "shadow_mask": IMAGE_FILES[2], "depth": IMAGE_FILES[3],
            "normals": IMAGE_FILES[4], "latitude": IMAGE_FILES[5],
            "longitude": IMAGE_FILES[6], "coco": JSON_FILES[1],
        }),
    };
    write_json(&dir.join(JSON_FILES[0]), &record)?;
    let coco = coco(&[(image_file.to_string(), labels)]);
    write_json(&dir.join(JSON_FILES[1]), &coco)
}

/// A COCO document over frames (file name, labels): one image and one
/// `body` annotation per frame with a body pixel (bbox, area, RLE).
pub fn coco(frames: &[(String, &Labels)]) -> Value {
    let mut images = Vec::new();
    let mut annotations = Vec::new();
    for (k, (file, labels)) in frames.iter().enumerate() {
        let id = k + 1;
        let im = &labels.images;
        images.push(json!({"id": id, "file_name": file, "width": im.width, "height": im.height}));
        let Some(bbox) = labels.frame.disk.bbox else {
            continue;
        };
        if labels.frame.pixel_counts.body == 0 {
            continue;
        }
        annotations.push(json!({
            "id": annotations.len() + 1,
            "image_id": id,
            "category_id": 1,
            "bbox": bbox,
            "area": labels.frame.pixel_counts.body,
            "iscrowd": 0,
            "segmentation": {"size": [im.height, im.width], "counts": rle(im)},
        }));
    }
    json!({
        "info": {"description": "optistim exact labels", "schema": SCHEMA},
        "images": images,
        "annotations": annotations,
        "categories": [{"id": 1, "name": "body", "supercategory": "body"}],
    })
}

/// COCO's uncompressed run-length encoding of the body mask: column-major
/// runs, starting with a (possibly empty) run of zeros.
pub fn rle(im: &LabelImages) -> Vec<u64> {
    let mut counts = Vec::new();
    let mut current = 0u8;
    let mut run = 0u64;
    for i in 0..im.width {
        for j in 0..im.height {
            let v = im.body[j * im.width + i];
            if v != current {
                counts.push(run);
                run = 0;
                current = v;
            }
            run += 1;
        }
    }
    counts.push(run);
    counts
}

/// Pretty JSON with a final newline.
pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<()> {
    let text = serde_json::to_string_pretty(value).map_err(|e| Error::Other(e.to_string()))?;
    std::fs::write(path, text + "\n").map_err(|e| Error::io(path, e))
}

fn encoder(path: &Path) -> Result<tiff::encoder::TiffEncoder<BufWriter<File>>> {
    let file = File::create(path).map_err(|e| Error::io(path, e))?;
    tiff::encoder::TiffEncoder::new(BufWriter::new(file))
        .map_err(|e| Error::parse(path, e.to_string()))
}

/// Single-channel 8-bit TIFF.
pub fn write_u8_tiff(path: &Path, width: usize, height: usize, data: &[u8]) -> Result<()> {
    encoder(path)?
        .write_image::<tiff::encoder::colortype::Gray8>(width as u32, height as u32, data)
        .map_err(|e| Error::parse(path, e.to_string()))
}

/// Three-channel f32 TIFF (interleaved).
pub fn write_rgb_f32_tiff(path: &Path, width: usize, height: usize, data: &[f32]) -> Result<()> {
    encoder(path)?
        .write_image::<tiff::encoder::colortype::RGB32Float>(width as u32, height as u32, data)
        .map_err(|e| Error::parse(path, e.to_string()))
}
