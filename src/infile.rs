//! Input files read with a size bound: a path to `/dev/zero`, a FIFO or a
//! runaway file gives an error naming the file and the limit instead of
//! reading until memory runs out.

pub mod csv_table;

use std::io::Read;
use std::path::Path;

use crate::error::{Error, Result};

/// Bound for configuration and scene files (TOML), bytes.
pub const CONFIG_LIMIT: u64 = 16 << 20;
/// Bound for calibration tables (LUT, geometry, spectra), bytes.
pub const TABLE_LIMIT: u64 = 256 << 20;
/// Bound for trajectories, logs and flight images, bytes.
pub const DATA_LIMIT: u64 = 2 << 30;

/// The whole of `path`, at most `limit` bytes; more is an error.
pub fn read_bounded(path: &Path, limit: u64) -> Result<Vec<u8>> {
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let too_big = || {
        Error::parse(
            path,
            format!("larger than the {} MiB this input may have", limit >> 20),
        )
    };
    let meta = file.metadata().map_err(|e| Error::io(path, e))?;
    if meta.is_dir() {
        return Err(Error::parse(path, "is a directory, not a file"));
    }
    if meta.is_file() && meta.len() > limit {
        return Err(too_big());
    }
    let mut bytes = Vec::new();
    file.take(limit + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| Error::io(path, e))?;
    if bytes.len() as u64 > limit {
        return Err(too_big());
    }
    Ok(bytes)
}

/// [`read_bounded`] as UTF-8 text (a leading byte-order mark removed).
pub fn read_text_bounded(path: &Path, limit: u64) -> Result<String> {
    let bytes = read_bounded(path, limit)?;
    let text = String::from_utf8(bytes).map_err(|e| {
        Error::parse(
            path,
            format!(
                "not UTF-8 text (invalid byte at offset {})",
                e.utf8_error().valid_up_to()
            ),
        )
    })?;
    Ok(match text.strip_prefix('\u{feff}') {
        Some(rest) => rest.to_string(),
        None => text,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn endless_and_oversized_inputs_are_refused() {
        let e = read_bounded(Path::new("/dev/zero"), 1 << 20)
            .unwrap_err()
            .to_string();
        assert!(e.contains("/dev/zero") && e.contains("1 MiB"), "{e}");
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("big.csv");
        std::fs::write(&p, vec![b'x'; (2 << 20) + 1]).unwrap();
        assert!(read_bounded(&p, 2 << 20).is_err());
        assert_eq!(read_bounded(&p, 3 << 20).unwrap().len(), (2 << 20) + 1);
        assert!(read_bounded(dir.path(), 1 << 20)
            .unwrap_err()
            .to_string()
            .contains("directory"));
    }

    #[test]
    fn text_drops_a_bom_and_names_bad_bytes() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.csv");
        std::fs::write(&p, b"\xef\xbb\xbfa,b\n").unwrap();
        assert_eq!(read_text_bounded(&p, 1024).unwrap(), "a,b\n");
        std::fs::write(&p, b"ab\xffc").unwrap();
        let e = read_text_bounded(&p, 1024).unwrap_err().to_string();
        assert!(e.contains("offset 2"), "{e}");
    }
}
