//! The clock file: the simulated facility's virtual time since power-on,
//! carried from one command to the next, so a calibration, a later run and
//! a verify see the screen's warm-up and drift as they are then.
//!
//! JSON: `{"format": "optistim-simclock-1", "seconds_since_power_on": 1234.5}`.
//! Loaded when a command starts (a missing file is a fresh power-on),
//! saved atomically (a temporary file, then a rename) when it ends or is
//! interrupted.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::SimFacility;
use crate::error::{Error, Result};

/// The format tag of a clock file.
pub const FORMAT: &str = "optistim-simclock-1";

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ClockFile {
    format: String,
    seconds_since_power_on: f64,
}

/// How a command's clock started.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ClockStart {
    /// No clock file: the screen was switched on when the command began.
    PowerOn,
    /// Continued from the file's time, s.
    Continued(f64),
}

impl ClockStart {
    /// One line for stderr and reports.
    pub fn describe(&self, path: &Path) -> String {
        match self {
            ClockStart::PowerOn => format!(
                "simulated clock: {} does not exist: a fresh power-on (t = 0 s, the screen cold)",
                path.display()
            ),
            ClockStart::Continued(t) => format!(
                "simulated clock: continuing at t = {t:.3} s since power-on from {}",
                path.display()
            ),
        }
    }
}

/// Reads a clock file: `None` if it does not exist; a file that is not a
/// clock file or holds a time that is not finite and ≥ 0 is an error
/// naming the file.
pub fn load(path: &Path) -> Result<Option<f64>> {
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(Error::io(path, e)),
    };
    if text.len() > 4096 {
        return Err(Error::parse(path, "larger than 4 KiB: not a clock file"));
    }
    let f: ClockFile = serde_json::from_str(&text)
        .map_err(|e| Error::parse(path, format!("not a simulated clock file: {e}")))?;
    if f.format != FORMAT {
        return Err(Error::parse(
            path,
            format!("format `{}` is not `{FORMAT}`", f.format),
        ));
    }
    let t = f.seconds_since_power_on;
    if !(t.is_finite() && t >= 0.0) {
        return Err(Error::parse(
            path,
            format!("seconds_since_power_on {t} is not a finite number ≥ 0"),
        ));
    }
    Ok(Some(t))
}

/// Writes `seconds` atomically: a temporary file beside `path`, then a
/// rename over it.
pub fn save(path: &Path, seconds: f64) -> Result<()> {
    let text = serde_json::to_string(&ClockFile {
        format: FORMAT.into(),
        seconds_since_power_on: seconds,
    })
    .map_err(|e| Error::Other(format!("{}: {e}", path.display())))?;
    let name = path
        .file_name()
        .ok_or_else(|| Error::parse(path, "not a file name"))?;
    let tmp = path.with_file_name(format!(".{}.tmp", name.to_string_lossy()));
    std::fs::write(&tmp, text + "\n").map_err(|e| Error::io(&tmp, e))?;
    std::fs::rename(&tmp, path).map_err(|e| Error::io(path, e))
}

/// A facility's clock tied to its file: loaded on [`SimClock::attach`],
/// saved by [`SimClock::save`] and when dropped (an error return, or the
/// end of the command).
pub struct SimClock {
    facility: SimFacility,
    path: PathBuf,
    /// How the clock started.
    pub start: ClockStart,
}

impl SimClock {
    /// Loads `path` into `facility`'s clock (missing: time 0) and says how
    /// it started on stderr.
    pub fn attach(facility: &SimFacility, path: &Path) -> Result<SimClock> {
        let start = match load(path)? {
            Some(t) => {
                facility
                    .set_now(t)
                    .map_err(|e| Error::parse(path, e.to_string()))?;
                ClockStart::Continued(t)
            }
            None => {
                facility.set_now(0.0)?;
                ClockStart::PowerOn
            }
        };
        eprintln!("optistim: {}", start.describe(path));
        Ok(SimClock {
            facility: facility.clone(),
            path: path.to_path_buf(),
            start,
        })
    }

    /// Saves the facility's current time.
    pub fn save(&self) -> Result<()> {
        save(&self.path, self.facility.now())
    }

    /// Saves the clock, then exits with status 130, on Ctrl-C, for a
    /// command that has no Ctrl-C handler of its own.
    pub fn save_on_interrupt(&self) -> Result<()> {
        let (facility, path) = (self.facility.clone(), self.path.clone());
        ctrlc::set_handler(move || {
            if let Err(e) = save(&path, facility.now()) {
                eprintln!("optistim: {e}");
            }
            std::process::exit(130);
        })
        .map_err(|e| Error::Other(format!("installing the Ctrl-C handler: {e}")))
    }
}

impl Drop for SimClock {
    fn drop(&mut self) {
        if let Err(e) = self.save() {
            eprintln!("optistim: saving the simulated clock: {e}");
        }
    }
}
