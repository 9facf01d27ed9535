//! Dark frames of a campaign: the camera's bias and dark current at each
//! exposure the routines use, averaged over `dark_frames` closed-shutter
//! frames and cached per exposure ([`DarkBank`]). Exposures lie on the
//! ladder `base × 2^k` of [`AutoExposure`](super::AutoExposure), so a
//! campaign needs only a few darks.
//!
//! Sources (`[calibrate.camera] dark`): `"shutter"` (taken when an exposure
//! is first used), `"capture"` (the operator covers the camera once; darks
//! at every ladder exposure up front), `"none"`, or a dark model file:
//!
//! ```toml
//! camera = "simulated facility camera 128x128 (12 bit, gain 0.04 DN/e-, seed 1)"
//! resolution = [128, 128]
//! saturation_dn = 4095
//! [[frame]]
//! exposure_s = 0.001
//! path = "dark_0001.tif"
//! [[frame]]
//! exposure_s = 1.0
//! path = "dark_1000.tif"
//! ```
//!
//! At an exposure between two of the file's frames the dark is their linear
//! interpolation (bias + rate × t is linear in t); outside them, or from
//! another camera, size or bit depth, it is an error naming the file.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use serde::Deserialize;

use crate::error::{Error, Result};
use crate::instruments::{Camera, CameraFrame, CaptureRequest};

/// Relative tolerance for two exposures to be the same.
const SAME_EXPOSURE: f64 = 1e-6;

/// One dark frame: mean DN per pixel at `exposure_s`.
type Dark = (f64, Arc<Vec<f32>>);

enum Source {
    None,
    Shutter,
    /// Taken up front; an exposure not in the cache is an error.
    Prepared,
    File(DarkFile),
}

/// Dark frames per exposure, cached for the campaign.
pub struct DarkBank {
    source: Source,
    frames: usize,
    cache: Vec<Dark>,
    /// Closed-shutter frames taken so far (for reports).
    pub taken: usize,
}

impl DarkBank {
    /// No dark correction (`dark = "none"`).
    pub fn none() -> DarkBank {
        DarkBank::with(Source::None, 1)
    }

    /// Darks taken with the shutter closed, `frames` averaged, when an
    /// exposure is first used.
    pub fn shutter(frames: usize) -> DarkBank {
        DarkBank::with(Source::Shutter, frames)
    }

    /// The operator covers the camera (`cover(true)`), darks are taken at
    /// every exposure of `ladder`, then `cover(false)`.
    pub fn capture_ladder(
        camera: &mut dyn Camera,
        ladder: &[f64],
        frames: usize,
        cover: &mut dyn FnMut(bool) -> Result<()>,
    ) -> Result<DarkBank> {
        let mut bank = DarkBank::with(Source::Shutter, frames);
        cover(true)?;
        for &t in ladder {
            bank.take(camera, t, None)?;
        }
        cover(false)?;
        bank.source = Source::Prepared;
        Ok(bank)
    }

    /// A dark model file, checked against the camera's `describe()` line.
    pub fn from_file(path: &Path, camera: &str) -> Result<DarkBank> {
        Ok(DarkBank::with(
            Source::File(DarkFile::load(path, camera)?),
            1,
        ))
    }

    fn with(source: Source, frames: usize) -> DarkBank {
        DarkBank {
            source,
            frames: frames.max(1),
            cache: Vec::new(),
            taken: 0,
        }
    }

    /// One line for provenance.
    pub fn describe(&self) -> String {
        match &self.source {
            Source::None => "none (dark = \"none\")".into(),
            Source::Shutter => format!(
                "closed shutter, {} frames averaged per exposure (bias + dark current)",
                self.frames
            ),
            Source::Prepared => format!(
                "camera covered, {} frames averaged at each of {} ladder exposures",
                self.frames,
                self.cache.len()
            ),
            Source::File(f) => format!("dark model {}", f.path.display()),
        }
    }

    /// The dark (mean DN per pixel) for `frame`, at its exposure; `None`
    /// with `dark = "none"`.
    pub fn dark_for(
        &mut self,
        camera: &mut dyn Camera,
        frame: &CameraFrame,
    ) -> Result<Option<Arc<Vec<f32>>>> {
        let t = frame.exposure_s;
        if let Some((_, d)) = self.cache.iter().find(|(e, _)| same(*e, t)) {
            check_size(d.len(), frame, "the cached dark")?;
            return Ok(Some(d.clone()));
        }
        match &self.source {
            Source::None => Ok(None),
            Source::Shutter => self.take(camera, t, Some(frame)).map(Some),
            Source::Prepared => Err(Error::Other(format!(
                "no dark frame at exposure {t} s: it is not on the exposure ladder the darks were taken at"
            ))),
            Source::File(f) => {
                let d = Arc::new(f.at(frame)?);
                self.cache.push((t, d.clone()));
                Ok(Some(d))
            }
        }
    }

    /// Averages `frames` closed-shutter frames at `exposure`.
    fn take(
        &mut self,
        camera: &mut dyn Camera,
        exposure: f64,
        like: Option<&CameraFrame>,
    ) -> Result<Arc<Vec<f32>>> {
        let mut sum: Vec<f64> = Vec::new();
        for i in 0..self.frames {
            let name = format!("dark_{:.0}us_{i}", exposure * 1e6);
            let f = camera.capture(&CaptureRequest::dark(name.clone(), exposure))?;
            if !same(f.exposure_s, exposure) {
                return Err(Error::Other(format!(
                    "dark `{name}`: the camera reported exposure {} s for a {exposure} s request",
                    f.exposure_s
                )));
            }
            if let Some(l) = like {
                check_size(f.data.len(), l, &format!("dark `{name}`"))?;
                if f.saturation_dn != l.saturation_dn {
                    return Err(Error::Other(format!(
                        "dark `{name}`: saturation {} DN, the frames' {} DN (another bit depth)",
                        f.saturation_dn, l.saturation_dn
                    )));
                }
            }
            if sum.is_empty() {
                sum = vec![0.0; f.data.len()];
            } else if sum.len() != f.data.len() {
                return Err(Error::Other(format!("dark `{name}`: frame size changed")));
            }
            sum.iter_mut()
                .zip(&f.data)
                .for_each(|(s, &v)| *s += v as f64);
            self.taken += 1;
        }
        let n = self.frames as f64;
        let d = Arc::new(sum.iter().map(|s| (s / n) as f32).collect::<Vec<f32>>());
        self.cache.push((exposure, d.clone()));
        Ok(d)
    }
}

fn same(a: f64, b: f64) -> bool {
    (a - b).abs() <= SAME_EXPOSURE * a.abs().max(b.abs())
}

fn check_size(len: usize, frame: &CameraFrame, what: &str) -> Result<()> {
    if len == frame.width * frame.height {
        Ok(())
    } else {
        Err(Error::Other(format!(
            "{what} has {len} pixels, the camera frame {}×{}",
            frame.width, frame.height
        )))
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct DarkFileToml {
    camera: String,
    resolution: [usize; 2],
    saturation_dn: f64,
    frame: Vec<DarkFrameEntry>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct DarkFrameEntry {
    exposure_s: f64,
    path: PathBuf,
}

/// A dark model file: frames at increasing exposures.
struct DarkFile {
    path: PathBuf,
    resolution: [usize; 2],
    saturation_dn: f64,
    frames: Vec<(f64, Vec<f32>)>,
}

impl DarkFile {
    fn load(path: &Path, camera: &str) -> Result<DarkFile> {
        let text = crate::infile::read_text_bounded(path, crate::infile::CONFIG_LIMIT)?;
        let t: DarkFileToml = toml::from_str(&text)
            .map_err(|e| Error::parse(path, crate::error::toml_message(&text, &e)))?;
        let bad = |key: &str, msg: String| Error::parse(path, format!("{key}: {msg}"));
        if t.camera.trim() != camera.trim() {
            return Err(bad(
                "camera",
                format!("`{}` is not this campaign's camera `{camera}`", t.camera),
            ));
        }
        if !(t.saturation_dn.is_finite() && t.saturation_dn > 0.0) {
            return Err(bad(
                "saturation_dn",
                format!("{} is not > 0", t.saturation_dn),
            ));
        }
        if t.frame.is_empty() {
            return Err(bad("frame", "no dark frames listed".into()));
        }
        let dir = path.parent().unwrap_or(Path::new(""));
        let mut frames = Vec::new();
        for (i, e) in t.frame.iter().enumerate() {
            let key = format!("frame[{i}]");
            if !(e.exposure_s.is_finite() && e.exposure_s > 0.0 && e.exposure_s <= 3600.0) {
                return Err(bad(
                    &format!("{key}.exposure_s"),
                    format!("{} is not in (0, 3600] s", e.exposure_s),
                ));
            }
            if let Some(&(prev, _)) = frames.last() {
                if e.exposure_s <= prev {
                    return Err(bad(
                        &format!("{key}.exposure_s"),
                        "exposures must increase".into(),
                    ));
                }
            }
            let p = dir.join(&e.path);
            let (w, h, data) = crate::instruments::frame::read_frame(&p)?;
            if [w, h] != t.resolution {
                return Err(bad(
                    &format!("{key}.path"),
                    format!("{} is {w}×{h}, not {:?}", p.display(), t.resolution),
                ));
            }
            if data.iter().any(|&v| v as f64 >= t.saturation_dn) {
                return Err(bad(
                    &format!("{key}.path"),
                    format!("{} has saturated pixels", p.display()),
                ));
            }
            frames.push((e.exposure_s, data));
        }
        Ok(DarkFile {
            path: path.to_path_buf(),
            resolution: t.resolution,
            saturation_dn: t.saturation_dn,
            frames,
        })
    }

    /// The dark at `frame`'s exposure (linear between the file's frames).
    fn at(&self, frame: &CameraFrame) -> Result<Vec<f32>> {
        let p = self.path.display();
        if [frame.width, frame.height] != self.resolution {
            return Err(Error::Other(format!(
                "{p}: dark model is {}×{}, the camera frame {}×{}",
                self.resolution[0], self.resolution[1], frame.width, frame.height
            )));
        }
        if frame.saturation_dn as f64 != self.saturation_dn {
            return Err(Error::Other(format!(
                "{p}: dark model saturates at {} DN, the camera at {} DN (another bit depth)",
                self.saturation_dn, frame.saturation_dn
            )));
        }
        let t = frame.exposure_s;
        if let Some((_, d)) = self.frames.iter().find(|(e, _)| same(*e, t)) {
            return Ok(d.clone());
        }
        let hi = self.frames.iter().position(|(e, _)| *e > t);
        match hi {
            Some(j) if j > 0 => {
                let ((t0, d0), (t1, d1)) = (&self.frames[j - 1], &self.frames[j]);
                let w = (t - t0) / (t1 - t0);
                Ok(d0
                    .iter()
                    .zip(d1)
                    .map(|(&a, &b)| (a as f64 + w * (b as f64 - a as f64)) as f32)
                    .collect())
            }
            _ => Err(Error::Other(format!(
                "{p}: no dark at exposure {t} s (the file covers {} … {} s)",
                self.frames[0].0,
                self.frames[self.frames.len() - 1].0
            ))),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A camera whose dark is bias 100 DN + 50 DN/s × t, exactly.
    struct Cam(usize);
    impl Camera for Cam {
        fn capture(&mut self, r: &CaptureRequest) -> Result<CameraFrame> {
            self.0 += 1;
            let v = if r.shutter == crate::instruments::Shutter::Closed {
                100.0 + 50.0 * r.exposure_s
            } else {
                1000.0
            };
            Ok(CameraFrame {
                width: 2,
                height: 1,
                data: vec![v as f32; 2],
                exposure_s: r.exposure_s,
                saturation_dn: 4095.0,
            })
        }
        fn describe(&self) -> String {
            "cam".into()
        }
    }

    fn light(t: f64) -> CameraFrame {
        CameraFrame {
            width: 2,
            height: 1,
            data: vec![1000.0; 2],
            exposure_s: t,
            saturation_dn: 4095.0,
        }
    }

    #[test]
    fn shutter_darks_are_cached_per_exposure() {
        let mut cam = Cam(0);
        let mut bank = DarkBank::shutter(3);
        let d = bank.dark_for(&mut cam, &light(2.0)).unwrap().unwrap();
        assert_eq!(d[0], 200.0);
        bank.dark_for(&mut cam, &light(2.0)).unwrap();
        assert_eq!(cam.0, 3, "the second request reuses the cache");
        let d = bank.dark_for(&mut cam, &light(4.0)).unwrap().unwrap();
        assert_eq!(d[1], 300.0);
        assert_eq!(bank.taken, 6);
        assert!(DarkBank::none()
            .dark_for(&mut cam, &light(1.0))
            .unwrap()
            .is_none());
    }

    #[test]
    fn a_prepared_ladder_refuses_other_exposures() {
        let mut cam = Cam(0);
        let mut covered = Vec::new();
        let mut cover = |c: bool| {
            covered.push(c);
            Ok(())
        };
        let mut bank = DarkBank::capture_ladder(&mut cam, &[1.0, 2.0], 2, &mut cover).unwrap();
        assert_eq!(covered, [true, false]);
        assert_eq!(
            bank.dark_for(&mut cam, &light(2.0)).unwrap().unwrap()[0],
            200.0
        );
        assert!(bank.dark_for(&mut cam, &light(3.0)).is_err());
    }

    #[test]
    fn dark_model_file_interpolates_and_refuses_mismatches() {
        let dir = tempfile::tempdir().unwrap();
        for (name, v) in [("d1.tif", 150.0f32), ("d3.tif", 250.0)] {
            crate::render::output::write_f32_tiff(&dir.path().join(name), 2, 1, &[v; 2]).unwrap();
        }
        let text = "camera = \"cam\"\nresolution = [2, 1]\nsaturation_dn = 4095\n\
                    [[frame]]\nexposure_s = 1.0\npath = \"d1.tif\"\n\
                    [[frame]]\nexposure_s = 3.0\npath = \"d3.tif\"\n";
        let p = dir.path().join("dark.toml");
        std::fs::write(&p, text).unwrap();
        let mut cam = Cam(0);
        let mut bank = DarkBank::from_file(&p, "cam").unwrap();
        // Linear between (1 s, 150) and (3 s, 250): 200 at 2 s.
        assert_eq!(
            bank.dark_for(&mut cam, &light(2.0)).unwrap().unwrap()[0],
            200.0
        );
        let e = bank
            .dark_for(&mut cam, &light(4.0))
            .unwrap_err()
            .to_string();
        assert!(e.contains("dark.toml") && e.contains("4 s"), "{e}");
        let e = DarkBank::from_file(&p, "other").err().unwrap().to_string();
        assert!(e.contains("dark.toml") && e.contains("camera"), "{e}");
        let mut big = light(2.2);
        big.saturation_dn = 65535.0;
        let e = bank.dark_for(&mut cam, &big).unwrap_err().to_string();
        assert!(e.contains("bit depth"), "{e}");
        let mut wide = light(2.5);
        wide.width = 1;
        wide.data.pop();
        assert!(bank.dark_for(&mut cam, &wide).is_err());
        std::fs::write(&p, text.replace("[2, 1]", "[4, 1]")).unwrap();
        let e = DarkBank::from_file(&p, "cam").err().unwrap().to_string();
        assert!(e.contains("dark.toml"), "{e}");
    }
}
