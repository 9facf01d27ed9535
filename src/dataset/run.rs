//! Rendering a shard's items and merging: each item is written into a
//! temporary directory and renamed into `items/NNNNNNN/` when complete;
//! `item.json` holds the SHA-256 of every other file, so an item on disk
//! is reused only when all its hashes verify (resume after a kill).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;

use serde::{Deserialize, Serialize};
use serde_json::Value;
use sha2::{Digest, Sha256};

use super::shard::Shard;
use super::spec::{hex, Item, Spec};
use crate::error::{Error, Result};
use crate::labels;
use crate::render::detector::{render_scene, PixelGeometry};
use crate::render::output::{write_f32_tiff, write_u16_png};
use crate::render::Renderer;

/// Schema of `item.json` and `manifest.json`.
pub const SCHEMA: &str = "optistim-dataset/1";

/// `item.json`: what the item is and the hashes of its files.
#[derive(Serialize, Deserialize, PartialEq, Debug)]
pub struct ItemRecord {
    /// [`SCHEMA`].
    pub schema: String,
    /// Item index.
    pub index: usize,
    /// The spec's hash.
    pub spec_hash: String,
    /// Seed of the item's detector noise.
    pub noise_seed: u64,
    /// File name → SHA-256 (hex).
    pub files: BTreeMap<String, String>,
}

/// What one shard run did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ShardReport {
    /// Items of the shard.
    pub items: usize,
    /// Rendered now.
    pub rendered: usize,
    /// Found on disk, verified and kept.
    pub reused: usize,
}

/// `out/items`.
pub fn items_dir(spec: &Spec) -> PathBuf {
    spec.out.join("items")
}

/// SHA-256 (hex) of a file.
pub fn file_hash(path: &Path) -> Result<String> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    Ok(hex(&Sha256::digest(&bytes)))
}

/// The item's record when its directory holds exactly the expected files
/// with the hashes `item.json` states, for this spec; None otherwise.
pub fn verify(spec: &Spec, item: &Item) -> Option<ItemRecord> {
    let dir = items_dir(spec).join(&item.name);
    let text = std::fs::read_to_string(dir.join("item.json")).ok()?;
    let record: ItemRecord = serde_json::from_str(&text).ok()?;
    let expected: Vec<&str> = item_files(spec);
    let same_item = record.schema == SCHEMA
        && record.index == item.index
        && record.spec_hash == spec.hash
        && record.noise_seed == item.noise_seed
        && record
            .files
            .keys()
            .map(String::as_str)
            .eq(expected.iter().copied());
    let on_disk = std::fs::read_dir(&dir).ok()?.count() == expected.len() + 1;
    let hashes_hold = || {
        record
            .files
            .iter()
            .all(|(f, h)| file_hash(&dir.join(f)).is_ok_and(|got| &got == h))
    };
    (same_item && on_disk && hashes_hold()).then_some(record)
}

/// The files of an item besides `item.json`, sorted.
fn item_files(spec: &Spec) -> Vec<&'static str> {
    let mut f: Vec<&str> = Vec::new();
    if spec.outputs.image {
        f.extend(IMAGE_FILES);
    }
    if spec.outputs.labels {
        f.extend(labels::files::all_files());
    }
    f.sort_unstable();
    f
}

const IMAGE_FILES: [&str; 4] = ["radiance.tiff", "electrons.tiff", "dn.png", "render.json"];

/// One worker: a single-threaded pool (an item's bytes do not depend on
/// the machine's core count) and a renderer reused across items.
struct Worker {
    pool: rayon::ThreadPool,
    renderer: Renderer,
    pixels: PixelGeometry,
}

impl Worker {
    fn new(spec: &Spec) -> Result<Worker> {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .map_err(|e| Error::Other(e.to_string()))?;
        let renderer = pool.install(|| Renderer::new(spec.scene.camera.render_pinhole().clone()));
        let pixels = pool.install(|| PixelGeometry::new(&renderer));
        Ok(Worker {
            pool,
            renderer,
            pixels,
        })
    }

    /// Renders `item` into `dir` and returns its record.
    fn write_item(&mut self, spec: &Spec, item: &Item, dir: &Path) -> Result<ItemRecord> {
        let mut scene = spec.scene.clone();
        scene.state = item.state;
        // With `[camera.sensor]`, the item's own temporal noise.
        scene.camera.sensor_frame = item.noise_seed;
        let pin = scene.camera.pinhole.clone();
        if spec.outputs.image {
            let (renderer, pixels) = (&mut self.renderer, &self.pixels);
            let images = self
                .pool
                .install(|| render_scene(&scene, renderer, pixels))?;
            write_f32_tiff(
                &dir.join("radiance.tiff"),
                pin.width,
                pin.height,
                &images.radiance,
            )?;
            write_f32_tiff(
                &dir.join("electrons.tiff"),
                pin.width,
                pin.height,
                &images.electrons,
            )?;
            write_u16_png(&dir.join("dn.png"), pin.width, pin.height, &images.dn)?;
            // The summary without its wall-clock times: an item's bytes are
            // a function of (spec, index) alone.
            let mut summary =
                serde_json::to_value(&images.summary).map_err(|e| Error::Other(e.to_string()))?;
            if let Value::Object(m) = &mut summary {
                m.remove("render_ms");
                m.remove("psf_ms");
                m.remove("distortion_ms");
                if let Some(Value::Object(sensor)) = m.get_mut("sensor") {
                    sensor.remove("sensor_ms");
                }
            }
            labels::files::write_json(&dir.join("render.json"), &summary)?;
        }
        if spec.outputs.labels {
            let mut l = self.pool.install(|| {
                labels::compute_for(
                    &scene.camera,
                    &item.state,
                    scene.body.radius,
                    spec.epoch.clone(),
                )
            })?;
            labels::add_stars(&mut l, &scene);
            let image = if spec.outputs.image { "dn.png" } else { "" };
            labels::files::write(dir, &l, image)?;
        }
        let files = item_files(spec)
            .into_iter()
            .map(|f| Ok((f.to_string(), file_hash(&dir.join(f))?)))
            .collect::<Result<_>>()?;
        let record = ItemRecord {
            schema: SCHEMA.into(),
            index: item.index,
            spec_hash: spec.hash.clone(),
            noise_seed: item.noise_seed,
            files,
        };
        labels::files::write_json(&dir.join("item.json"), &record)?;
        Ok(record)
    }
}

/// Renders (or verifies and keeps) the items of `shard` with `jobs`
/// workers, logging progress every `progress_every` seconds.
pub fn render_shard(
    spec: &Spec,
    shard: Shard,
    jobs: usize,
    progress_every: f64,
) -> Result<ShardReport> {
    let items_dir = items_dir(spec);
    std::fs::create_dir_all(&items_dir).map_err(|e| Error::io(&items_dir, e))?;
    let mine: Vec<usize> = (0..spec.count).filter(|&i| shard.owns(i)).collect();
    let next = AtomicUsize::new(0);
    let done = AtomicUsize::new(0);
    let reused = AtomicUsize::new(0);
    let first_error: Mutex<Option<Error>> = Mutex::new(None);
    let start = Instant::now();
    let last_log = Mutex::new(Instant::now());
    let work = || -> Result<()> {
        let mut worker: Option<Worker> = None;
        while first_error.lock().map(|e| e.is_none()).unwrap_or(false) {
            let Some(&i) = mine.get(next.fetch_add(1, Ordering::Relaxed)) else {
                return Ok(());
            };
            let item = spec.item(i);
            if verify(spec, &item).is_some() {
                reused.fetch_add(1, Ordering::Relaxed);
            } else {
                let w = match &mut worker {
                    Some(w) => w,
                    None => worker.insert(Worker::new(spec)?),
                };
                write_atomically(spec, &item, w)?;
            }
            let n = done.fetch_add(1, Ordering::Relaxed) + 1;
            log_progress(&last_log, progress_every, shard, n, mine.len(), start);
        }
        Ok(())
    };
    std::thread::scope(|s| {
        for _ in 0..jobs.clamp(1, mine.len().max(1)) {
            s.spawn(|| {
                if let Err(e) = work() {
                    first_error.lock().unwrap().get_or_insert(e);
                }
            });
        }
    });
    if let Some(e) = first_error.into_inner().unwrap() {
        return Err(e);
    }
    let reused = reused.into_inner();
    Ok(ShardReport {
        items: mine.len(),
        rendered: mine.len() - reused,
        reused,
    })
}

fn log_progress(
    last: &Mutex<Instant>,
    every: f64,
    shard: Shard,
    n: usize,
    total: usize,
    start: Instant,
) {
    let mut last = last.lock().unwrap();
    if last.elapsed().as_secs_f64() >= every || n == total {
        *last = Instant::now();
        let rate = n as f64 / start.elapsed().as_secs_f64().max(1e-9);
        tracing::info!(
            "shard {}/{}: {n}/{total} items ({rate:.2} items/s)",
            shard.index,
            shard.count
        );
    }
}

/// Writes `item` into a temporary directory and renames it into place,
/// replacing a stale or corrupt earlier version and leftover temporaries.
fn write_atomically(spec: &Spec, item: &Item, worker: &mut Worker) -> Result<()> {
    let items = items_dir(spec);
    remove_temporaries(&items, &item.name)?;
    let tmp = items.join(format!(".{}.tmp.{}", item.name, std::process::id()));
    std::fs::create_dir_all(&tmp).map_err(|e| Error::io(&tmp, e))?;
    let dest = items.join(&item.name);
    let done = worker
        .write_item(spec, item, &tmp)
        .and_then(|_| replace(&tmp, &dest));
    if let Err(e) = done {
        // A failed item (a full disk, say) leaves nothing behind.
        let _ = std::fs::remove_dir_all(&tmp);
        return Err(Error::Other(format!("item {}: {e}", item.index)));
    }
    Ok(())
}

/// Renames `tmp` to `dest`, removing whatever `dest` held before.
fn replace(tmp: &Path, dest: &Path) -> Result<()> {
    let removed = match std::fs::symlink_metadata(dest) {
        Ok(m) if m.is_dir() => std::fs::remove_dir_all(dest),
        Ok(_) => std::fs::remove_file(dest),
        Err(_) => Ok(()),
    };
    removed.map_err(|e| Error::io(dest, e))?;
    std::fs::rename(tmp, dest).map_err(|e| Error::io(dest, e))
}

/// Removes `.NAME.tmp.*` left by a killed run (only this item's owner
/// shard writes them, so none is in use).
fn remove_temporaries(items: &Path, name: &str) -> Result<()> {
    let prefix = format!(".{name}.tmp.");
    for entry in std::fs::read_dir(items).map_err(|e| Error::io(items, e))? {
        let path = entry.map_err(|e| Error::io(items, e))?.path();
        let stale = path
            .file_name()
            .and_then(|n| n.to_str())
            .is_some_and(|n| n.starts_with(&prefix));
        if stale {
            std::fs::remove_dir_all(&path).map_err(|e| Error::io(&path, e))?;
        }
    }
    Ok(())
}

/// `manifest.json`.
#[derive(Serialize)]
struct Manifest<'a> {
    schema: &'static str,
    spec_hash: &'a str,
    count: usize,
    items: Vec<ManifestItem>,
}

#[derive(Serialize)]
struct ManifestItem {
    index: usize,
    dir: String,
    item_json: String,
    files: BTreeMap<String, String>,
}

/// Checks that every item is present and verifies, then writes
/// `manifest.json` (and with labels, a dataset-wide `coco.json`).
/// Returns the number of items.
pub fn merge(spec: &Spec) -> Result<usize> {
    let mut missing = Vec::new();
    let mut items = Vec::new();
    for i in 0..spec.count {
        let item = spec.item(i);
        match verify(spec, &item) {
            Some(record) => {
                let dir = items_dir(spec).join(&item.name);
                items.push(ManifestItem {
                    index: i,
                    dir: format!("items/{}", item.name),
                    item_json: file_hash(&dir.join("item.json"))?,
                    files: record.files,
                });
            }
            None => missing.push(i),
        }
    }
    if !missing.is_empty() {
        let first: Vec<String> = missing.iter().take(10).map(|i| i.to_string()).collect();
        return Err(Error::Other(format!(
            "{}: {} of {} items missing or failing their hashes (first: {}); re-run the shards",
            spec.out.display(),
            missing.len(),
            spec.count,
            first.join(", ")
        )));
    }
    if spec.outputs.labels {
        write_coco(spec)?;
    }
    let manifest = Manifest {
        schema: SCHEMA,
        spec_hash: &spec.hash,
        count: spec.count,
        items,
    };
    labels::files::write_json(&spec.out.join("manifest.json"), &manifest)?;
    Ok(spec.count)
}

/// The items' COCO files as one: image ids are index + 1, file names
/// relative to `out`.
fn write_coco(spec: &Spec) -> Result<()> {
    let mut images = Vec::new();
    let mut annotations = Vec::new();
    for i in 0..spec.count {
        let name = spec.item(i).name;
        let path = items_dir(spec).join(&name).join("coco.json");
        let text = std::fs::read_to_string(&path).map_err(|e| Error::io(&path, e))?;
        let mut doc: Value =
            serde_json::from_str(&text).map_err(|e| Error::parse(&path, e.to_string()))?;
        let file = if spec.outputs.image {
            format!("items/{name}/dn.png")
        } else {
            format!("items/{name}/body_mask.tiff")
        };
        for mut im in take_array(&mut doc, "images") {
            im["id"] = (i + 1).into();
            im["file_name"] = file.clone().into();
            images.push(im);
        }
        for mut a in take_array(&mut doc, "annotations") {
            a["id"] = (annotations.len() + 1).into();
            a["image_id"] = (i + 1).into();
            annotations.push(a);
        }
    }
    let mut doc = labels::files::coco(&[]);
    doc["images"] = images.into();
    doc["annotations"] = annotations.into();
    labels::files::write_json(&spec.out.join("coco.json"), &doc)
}

fn take_array(doc: &mut Value, key: &str) -> Vec<Value> {
    match doc.get_mut(key).map(Value::take) {
        Some(Value::Array(a)) => a,
        _ => Vec::new(),
    }
}
