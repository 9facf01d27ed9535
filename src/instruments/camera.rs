//! The real camera backends: `files` (the acquisition software writes one
//! image per pattern into a folder; optistim waits for it) and `command` (a
//! capture command run per pattern, without a shell), and the command
//! template of the latter. Frames are read by [`read_frame`].
//!
//! A frame file is complete when it exists, is not empty and its size is
//! the same at two polls `poll` apart (the acquisition software may still
//! be writing it). Every frame is checked against the configured
//! resolution.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

pub use super::frame::read_frame;
use super::frame::RawFrame;

use super::config::{abbreviate, check_pattern_name, CameraConfig, FrameExtension};
use super::{Camera, CameraFrame, CaptureRequest};
use crate::error::{Error, Result};
use crate::placeholders::{self, Part};

/// Shared by both backends: the config, and turning a file into a frame.
struct Backend {
    cfg: CameraConfig,
    dir: PathBuf,
}

impl Backend {
    fn new(cfg: CameraConfig) -> Result<Backend> {
        let dir = cfg
            .dir
            .clone()
            .ok_or_else(|| Error::invalid("calibrate.camera.dir", "missing"))?;
        Ok(Backend { cfg, dir })
    }

    fn error(&self, pattern: &str, what: &str) -> Error {
        Error::Other(format!(
            "camera `{}`, pattern `{pattern}`: {what}",
            self.cfg.name
        ))
    }

    /// Reads `path` into a frame of `request`, checking its size.
    fn frame(&self, path: &Path, request: &CaptureRequest) -> Result<CameraFrame> {
        let raw = read_frame(path).map_err(|e| self.error(&request.pattern, &e.to_string()))?;
        self.frame_from(raw, path, request)
    }

    /// A frame of `request` from the pixels read from `path`, checking its size.
    fn frame_from(
        &self,
        raw: RawFrame,
        path: &Path,
        request: &CaptureRequest,
    ) -> Result<CameraFrame> {
        let (width, height, data) = raw;
        if let Some([w, h]) = self.cfg.resolution {
            if (w, h) != (width, height) {
                return Err(self.error(
                    &request.pattern,
                    &format!(
                        "{} is {width} × {height} pixels, calibrate.camera.resolution says {w} × {h}",
                        path.display()
                    ),
                ));
            }
        }
        Ok(CameraFrame {
            width,
            height,
            data,
            exposure_s: request.exposure_s,
            saturation_dn: self.cfg.saturation_dn as f32,
        })
    }

    fn check(&self, request: &CaptureRequest) -> Result<()> {
        check_pattern_name(&request.pattern)
            .map_err(|e| self.error(&request.pattern, &e.to_string()))?;
        let e = request.exposure_s;
        if !(e.is_finite() && e > 0.0 && e <= 3600.0) {
            return Err(self.error(
                &request.pattern,
                &format!("exposure {e} s: must be in (0, 3600]"),
            ));
        }
        Ok(())
    }
}

/// The `files` backend: waits for `dir/<pattern>.{png,tif,tiff,fits}`.
///
/// The acquisition software must take each frame at the requested
/// exposure (optistim cannot set it); use an empty folder per campaign, as
/// a file already there is taken as the pattern's frame (so a resumed
/// campaign finds its frames).
pub struct FilesCamera {
    b: Backend,
}

impl FilesCamera {
    /// A camera of a validated `files` config (paths already resolved).
    pub fn new(cfg: CameraConfig) -> Result<FilesCamera> {
        Ok(FilesCamera {
            b: Backend::new(cfg)?,
        })
    }

    /// The candidate files of a pattern.
    fn candidates(&self, pattern: &str) -> Result<Vec<PathBuf>> {
        let stem = self.b.cfg.file_stem(pattern)?;
        Ok(FrameExtension::ALL
            .iter()
            .map(|e| self.b.dir.join(format!("{stem}.{}", e.as_str())))
            .collect())
    }
}

impl FilesCamera {
    fn timeout_error(
        &self,
        pattern: &str,
        last: Option<(PathBuf, u64)>,
        unreadable: Option<Error>,
    ) -> Error {
        let t = self.b.cfg.timeout;
        let what = match (unreadable, last) {
            (Some(e), _) => format!("unreadable after {t} s: {e}"),
            (None, Some((p, _))) => format!("{} still growing after {t} s", p.display()),
            (None, None) => format!(
                "no frame {}/{}.{{png,tif,tiff,fits}} within {t} s",
                self.b.dir.display(),
                self.b.cfg.pattern.replace("{pattern}", pattern),
            ),
        };
        self.b.error(pattern, &what)
    }
}

/// The size of the first existing, non-empty candidate.
fn first_present(candidates: &[PathBuf]) -> Option<(PathBuf, u64)> {
    candidates.iter().find_map(|p| {
        let len = std::fs::metadata(p).ok()?.len();
        (len > 0).then(|| (p.clone(), len))
    })
}

impl Camera for FilesCamera {
    fn capture(&mut self, request: &CaptureRequest) -> Result<CameraFrame> {
        self.b.check(request)?;
        let candidates = self.candidates(&request.pattern)?;
        let poll = Duration::from_secs_f64(self.b.cfg.poll);
        let deadline = Instant::now() + Duration::from_secs_f64(self.b.cfg.timeout);
        let mut last: Option<(PathBuf, u64)> = None;
        // A file that stopped growing but does not decode may be paused
        // mid-write: it is read again until the timeout.
        let mut unreadable: Option<Error> = None;
        loop {
            let now = first_present(&candidates);
            if let (Some(a), Some(b)) = (&last, &now) {
                if a == b {
                    match read_frame(&b.0) {
                        Ok(raw) => return self.b.frame_from(raw, &b.0, request),
                        Err(e) => unreadable = Some(e),
                    }
                }
            }
            last = now;
            if Instant::now() >= deadline {
                return Err(self.timeout_error(&request.pattern, last, unreadable));
            }
            std::thread::sleep(poll);
        }
    }

    fn describe(&self) -> String {
        format!(
            "{} (files in {}, named {}.{{png,tif,tiff,fits}})",
            self.b.cfg.name,
            self.b.dir.display(),
            self.b.cfg.pattern
        )
    }
}

/// The `command` backend: runs the capture command per pattern; it must
/// write `{path}` and exit 0 within the timeout.
pub struct CommandCamera {
    b: Backend,
    line: CommandLine,
}

impl CommandCamera {
    /// A camera of a validated `command` config (paths already resolved).
    pub fn new(cfg: CameraConfig) -> Result<CommandCamera> {
        let template = cfg
            .command
            .clone()
            .ok_or_else(|| Error::invalid("calibrate.camera.command", "missing"))?;
        let line = CommandLine::parse(&template)
            .map_err(|m| Error::invalid("calibrate.camera.command", m))?;
        Ok(CommandCamera {
            b: Backend::new(cfg)?,
            line,
        })
    }
}

impl Camera for CommandCamera {
    fn capture(&mut self, request: &CaptureRequest) -> Result<CameraFrame> {
        self.b.check(request)?;
        let pattern = &request.pattern;
        let stem = self.b.cfg.file_stem(pattern)?;
        let path = self
            .b
            .dir
            .join(format!("{stem}.{}", self.b.cfg.extension.as_str()));
        // A frame left from an earlier run must not pass for this one.
        match std::fs::remove_file(&path) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => {
                return Err(self.b.error(
                    pattern,
                    &format!("cannot remove old {}: {e}", path.display()),
                ))
            }
        }
        let exposure_us = (request.exposure_s * 1e6).round().max(1.0) as u64;
        let argv = self.line.argv(&CommandValues {
            exposure_us,
            path: &path,
            pattern,
        });
        let timeout = Duration::from_secs_f64(self.b.cfg.timeout);
        run(&argv, timeout).map_err(|m| self.b.error(pattern, &m))?;
        if !path.exists() {
            return Err(self.b.error(
                pattern,
                &format!("the command exited 0 but wrote no {}", path.display()),
            ));
        }
        self.b.frame(&path, request)
    }

    fn describe(&self) -> String {
        format!(
            "{} (command `{}`, frames in {})",
            self.b.cfg.name,
            abbreviate(self.b.cfg.command.as_deref().unwrap_or(""), 120),
            self.b.dir.display()
        )
    }
}

/// Runs `argv` with a timeout; errors: cannot start, killed at the
/// timeout, non-zero exit with stderr's last line.
fn run(argv: &[std::ffi::OsString], timeout: Duration) -> std::result::Result<(), String> {
    let program = argv[0].to_string_lossy().into_owned();
    let mut child = Command::new(&argv[0])
        .args(&argv[1..])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| format!("cannot run `{program}`: {e}"))?;
    // Drained in a thread so a chatty command never blocks on a full pipe.
    let mut stderr = child.stderr.take().expect("piped stderr");
    let (tail_tx, tail_rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut tail = Vec::new();
        let mut buf = [0u8; 4096];
        while let Ok(n) = stderr.read(&mut buf) {
            if n == 0 {
                break;
            }
            tail.extend_from_slice(&buf[..n]);
            if tail.len() > 8192 {
                tail.drain(..tail.len() - 4096);
            }
        }
        let _ = tail_tx.send(String::from_utf8_lossy(&tail).into_owned());
    });
    let deadline = Instant::now() + timeout;
    let status = loop {
        match child.try_wait() {
            Ok(Some(s)) => break s,
            Ok(None) if Instant::now() >= deadline => {
                let _ = child.kill();
                let _ = child.wait();
                return Err(format!(
                    "`{program}` did not finish within {} s; killed",
                    timeout.as_secs_f64()
                ));
            }
            Ok(None) => std::thread::sleep(Duration::from_millis(10)),
            Err(e) => return Err(format!("waiting for `{program}`: {e}")),
        }
    };
    // A background process the command left behind may hold stderr open:
    // wait for its end only briefly.
    let err = tail_rx
        .recv_timeout(Duration::from_millis(500))
        .unwrap_or_default();
    if status.success() {
        return Ok(());
    }
    let last = err
        .lines()
        .rev()
        .find(|l| !l.trim().is_empty())
        .unwrap_or("(no stderr)");
    Err(format!(
        "`{program}` failed ({status}): {}",
        abbreviate(last.trim(), 120)
    ))
}

/// A field of a command-line argument.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Field {
    ExposureUs,
    Path,
    Pattern,
}

/// The arguments' placeholders, in the order the errors list them.
const FIELDS: [(&str, Field); 3] = [
    ("exposure_us", Field::ExposureUs),
    ("path", Field::Path),
    ("pattern", Field::Pattern),
];

/// A capture command template split into argv (no shell): whitespace
/// separates arguments; `{exposure_us}`, `{path}`, `{pattern}` are
/// substituted inside each argument, so a substituted path may contain
/// spaces; `{{`, `}}` are literal braces.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CommandLine {
    args: Vec<Vec<Part<Field>>>,
}

/// Values substituted into a [`CommandLine`].
#[derive(Debug, Clone, Copy)]
pub struct CommandValues<'a> {
    /// Exposure, µs.
    pub exposure_us: u64,
    /// Output file.
    pub path: &'a std::path::Path,
    /// Pattern name.
    pub pattern: &'a str,
}

impl CommandLine {
    /// Parses a template; the error says which placeholder is wrong.
    pub fn parse(template: &str) -> std::result::Result<CommandLine, String> {
        let args = template
            .split_whitespace()
            .map(|arg| placeholders::parse(arg, &FIELDS))
            .collect::<std::result::Result<Vec<_>, _>>()?;
        if args.is_empty() {
            return Err("empty command".into());
        }
        if !matches!(args[0].as_slice(), [Part::Lit(_)]) {
            return Err("the program name must be literal text".into());
        }
        Ok(CommandLine { args })
    }

    /// The argv with the values substituted.
    pub fn argv(&self, v: &CommandValues) -> Vec<std::ffi::OsString> {
        self.args
            .iter()
            .map(|pieces| {
                let mut a = std::ffi::OsString::new();
                for p in pieces {
                    match p {
                        Part::Lit(s) => a.push(s),
                        Part::Field(Field::ExposureUs) => a.push(v.exposure_us.to_string()),
                        Part::Field(Field::Path) => a.push(v.path.as_os_str()),
                        Part::Field(Field::Pattern) => a.push(v.pattern),
                    }
                }
                a
            })
            .collect()
    }
}
