//! Crash-safe measurement log of a calibration campaign: every measurement
//! is appended to a JSON-lines file as it is taken (and fsync'd), so a
//! campaign stopped by a crash, an instrument fault or Ctrl-C resumes where
//! it stopped (`--resume`) instead of starting again.
//!
//! Format: the first line is `{"campaign": "<fingerprint>", "routine":
//! "<name>"}`; every further line is one measurement, an object with at
//! least `"pattern": "<name>"`. The fingerprint is the SHA-256 of the
//! `[calibrate]` table, the routine and the display's size and bits, so a
//! checkpoint from a different campaign is refused. A torn last line (the
//! process died while writing it) is dropped; a malformed earlier line is an
//! error naming the line.

use std::collections::HashMap;
use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;
use serde::Serialize;

use crate::error::{Error, Result};

/// An open checkpoint file.
#[derive(Debug)]
pub struct Checkpoint {
    path: PathBuf,
    file: File,
    done: HashMap<String, serde_json::Value>,
}

#[derive(Serialize, serde::Deserialize)]
struct Header {
    campaign: String,
    routine: String,
}

impl Checkpoint {
    /// Opens `path` for campaign `fingerprint` of `routine`. Without
    /// `resume` an existing file is refused (it may hold hours of
    /// measurements); with `resume` its measurements are loaded and new
    /// ones appended.
    pub fn open(path: &Path, fingerprint: &str, routine: &str, resume: bool) -> Result<Checkpoint> {
        let mut exists = path.exists();
        if exists && !resume && holds_no_measurement(path)? {
            // A campaign that stopped before its first measurement (a bad
            // input, say) has nothing to resume: start it again.
            std::fs::remove_file(path).map_err(|e| Error::io(path, e))?;
            exists = false;
        }
        if exists && !resume {
            return Err(Error::Other(format!(
                "{}: a checkpoint of an earlier campaign exists: pass --resume to continue it, \
                 or move it away to start again",
                path.display()
            )));
        }
        let mut done = HashMap::new();
        if exists {
            let text = crate::infile::read_text_bounded(path, crate::infile::TABLE_LIMIT)?;
            let keep = parse(path, &text, fingerprint, routine, &mut done)?;
            if keep < text.len() {
                // Drop the torn tail so appends start on a line of their own.
                let f = OpenOptions::new()
                    .write(true)
                    .open(path)
                    .map_err(|e| Error::io(path, e))?;
                f.set_len(keep as u64).map_err(|e| Error::io(path, e))?;
            }
        }
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        }
        let mut file = OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
            .map_err(|e| Error::io(path, e))?;
        let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
        if len == 0 {
            let header = Header {
                campaign: fingerprint.to_string(),
                routine: routine.to_string(),
            };
            let line = serde_json::to_string(&header).map_err(|e| Error::Other(e.to_string()))?;
            writeln!(file, "{line}").map_err(|e| Error::io(path, e))?;
            file.sync_data().map_err(|e| Error::io(path, e))?;
        }
        Ok(Checkpoint {
            path: path.to_path_buf(),
            file,
            done,
        })
    }

    /// The stored measurement of `pattern`, if taken before.
    pub fn get<T: DeserializeOwned>(&self, pattern: &str) -> Result<Option<T>> {
        match self.done.get(pattern) {
            None => Ok(None),
            Some(v) => serde_json::from_value(v.clone()).map(Some).map_err(|e| {
                Error::parse(
                    &self.path,
                    format!("measurement `{pattern}` has an unexpected shape: {e}"),
                )
            }),
        }
    }

    /// Number of measurements stored.
    pub fn len(&self) -> usize {
        self.done.len()
    }

    /// True when nothing is stored.
    pub fn is_empty(&self) -> bool {
        self.done.is_empty()
    }

    /// Appends one measurement (an object serialised with a `pattern`
    /// field) and forces it to disk before returning.
    pub fn record<T: Serialize>(&mut self, pattern: &str, value: &T) -> Result<()> {
        let mut v = serde_json::to_value(value).map_err(|e| Error::Other(e.to_string()))?;
        match &mut v {
            serde_json::Value::Object(m) => {
                m.insert("pattern".into(), pattern.into());
            }
            _ => return Err(Error::Other("checkpoint records must be objects".into())),
        }
        let line = serde_json::to_string(&v).map_err(|e| Error::Other(e.to_string()))?;
        writeln!(self.file, "{line}").map_err(|e| Error::io(&self.path, e))?;
        self.file
            .sync_data()
            .map_err(|e| Error::io(&self.path, e))?;
        self.done.insert(pattern.to_string(), v);
        Ok(())
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// Loads the measurements of `text` into `done`; returns the byte length
/// of the good part (everything but a torn last line).
fn parse(
    path: &Path,
    text: &str,
    fingerprint: &str,
    routine: &str,
    done: &mut HashMap<String, serde_json::Value>,
) -> Result<usize> {
    let mut offset = 0;
    let mut header_seen = false;
    let lines: Vec<&str> = text.split_inclusive('\n').collect();
    for (i, raw) in lines.iter().enumerate() {
        let last = i + 1 == lines.len();
        let line = raw.trim_end();
        let torn = |what: &str| -> Result<usize> {
            if last && !raw.ends_with('\n') {
                Ok(offset)
            } else {
                Err(Error::parse(path, format!("line {}: {what}", i + 1)))
            }
        };
        if line.is_empty() {
            offset += raw.len();
            continue;
        }
        let v: serde_json::Value = match serde_json::from_str(line) {
            Ok(v) => v,
            Err(e) => return torn(&format!("not JSON: {e}")),
        };
        if !header_seen {
            let h: Header = match serde_json::from_value(v) {
                Ok(h) => h,
                Err(_) => return torn("expected the campaign header line"),
            };
            if h.campaign != fingerprint || h.routine != routine {
                return Err(Error::parse(
                    path,
                    format!(
                        "checkpoint of a different campaign ({} {}…, this one is {} {}…): \
                         the [calibrate] settings or the display changed; move it away to start again",
                        crate::instruments::config::abbreviate(&h.routine, 40),
                        h.campaign.chars().take(12).collect::<String>(),
                        routine,
                        fingerprint.chars().take(12).collect::<String>()
                    ),
                ));
            }
            header_seen = true;
        } else {
            match v.get("pattern").and_then(|p| p.as_str()) {
                Some(p) => {
                    done.insert(p.to_string(), v.clone());
                }
                None => return torn("a measurement without `pattern`"),
            }
        }
        offset += raw.len();
    }
    Ok(offset)
}

/// The campaign fingerprint: SHA-256 of the canonical `[calibrate]` table,
/// the routine and the display.
pub fn fingerprint(
    calibrate: &toml::Value,
    routine: &str,
    screen: (usize, usize),
    bits: u32,
) -> String {
    let canon = format!(
        "{}\n{routine}\n{}x{}\n{bits}",
        serde_json::to_string(calibrate).unwrap_or_default(),
        screen.0,
        screen.1
    );
    crate::facility::lut::sha256_hex(canon.as_bytes())
}

/// True when the checkpoint at `path` holds at most its header line.
fn holds_no_measurement(path: &Path) -> Result<bool> {
    let text = crate::infile::read_text_bounded(path, crate::infile::TABLE_LIMIT)?;
    Ok(text.lines().filter(|l| !l.trim().is_empty()).count() <= 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Serialize, serde::Deserialize, PartialEq, Debug)]
    struct M {
        dn: f64,
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(128))]
        /// Any file content: Ok or a named error, never a panic.
        #[test]
        fn parse_never_panics(text in "(\\{\"campaign\":\"[a-zé]{0,14}\",\"routine\":\"r\"\\}\n)?[ -~é\n]{0,200}") {
            let mut done = HashMap::new();
            let _ = parse(Path::new("c.jsonl"), &text, "abc", "r", &mut done);
        }
    }

    #[test]
    fn resume_reads_back_tolerates_a_torn_line_and_refuses_other_campaigns() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("c.jsonl");
        {
            let mut c = Checkpoint::open(&p, "abc", "radiometric", false).unwrap();
            c.record("a", &M { dn: 1.5 }).unwrap();
            c.record("b", &M { dn: 2.5 }).unwrap();
        }
        // A torn last line, as left by a crash mid-write.
        let mut f = OpenOptions::new().append(true).open(&p).unwrap();
        write!(f, "{{\"pattern\":\"c\",\"dn\":").unwrap();
        drop(f);
        assert!(Checkpoint::open(&p, "abc", "radiometric", false).is_err());
        {
            let mut c = Checkpoint::open(&p, "abc", "radiometric", true).unwrap();
            assert_eq!(c.len(), 2);
            assert_eq!(c.get::<M>("b").unwrap(), Some(M { dn: 2.5 }));
            assert_eq!(c.get::<M>("c").unwrap(), None);
            c.record("c", &M { dn: 3.5 }).unwrap();
        }
        let c = Checkpoint::open(&p, "abc", "radiometric", true).unwrap();
        assert_eq!(c.get::<M>("c").unwrap(), Some(M { dn: 3.5 }));
        let e = Checkpoint::open(&p, "xyz", "radiometric", true)
            .unwrap_err()
            .to_string();
        assert!(e.contains("different campaign"), "{e}");
        // A malformed line that is not the last one is an error naming it.
        std::fs::write(
            &p,
            "{\"campaign\":\"abc\",\"routine\":\"r\"}\nnope\n{\"pattern\":\"a\"}\n",
        )
        .unwrap();
        let e = Checkpoint::open(&p, "abc", "r", true)
            .unwrap_err()
            .to_string();
        assert!(e.contains("line 2"), "{e}");
    }
}
