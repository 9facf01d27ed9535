//! Output files that never clobber what they should not: a summary or
//! report is replaced atomically (temporary file + rename) only when the
//! path is absent or a regular file, so a symlink, a device node such as
//! `/dev/null` or a directory at that path is refused with a message
//! instead of being replaced (as root a rename over `/dev/null` makes it a
//! regular file). An earlier result is replaced only when the command was
//! told so ([`check_no_earlier`], `--overwrite`).

use std::io::Write;
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

/// What `path` is, when it is something an output must not replace.
fn unsafe_kind(meta: &std::fs::Metadata) -> Option<&'static str> {
    let t = meta.file_type();
    if t.is_symlink() {
        Some("a symbolic link")
    } else if t.is_dir() {
        Some("a directory")
    } else if !t.is_file() {
        Some("not a regular file (a device, FIFO or socket)")
    } else {
        None
    }
}

/// Ok when `path` is absent or a regular file (not followed through a
/// symlink); otherwise an error naming the path and what it is.
pub fn check_replaceable(path: &Path) -> Result<()> {
    match std::fs::symlink_metadata(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(Error::io(path, e)),
        Ok(meta) => match unsafe_kind(&meta) {
            None => Ok(()),
            Some(kind) => Err(Error::invalid(
                path.display().to_string(),
                format!("refusing to replace it: it is {kind}"),
            )),
        },
    }
}

/// Ok when `path` is absent or, following symlinks, a regular file: what
/// an append-only log may write through.
pub fn check_appendable(path: &Path) -> Result<()> {
    match std::fs::metadata(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(Error::io(path, e)),
        Ok(meta) if meta.is_file() => Ok(()),
        Ok(meta) => Err(Error::invalid(
            path.display().to_string(),
            format!(
                "refusing to write to it: it is {}",
                unsafe_kind(&meta).unwrap_or("not a regular file")
            ),
        )),
    }
}

/// Ok when `overwrite` is set or none of `paths` exists; else an error
/// naming the first earlier result found, so a command refuses before it
/// does its work.
pub fn check_no_earlier(paths: &[PathBuf], overwrite: bool) -> Result<()> {
    if overwrite {
        return Ok(());
    }
    match paths.iter().find(|p| std::fs::symlink_metadata(p).is_ok()) {
        None => Ok(()),
        Some(p) => Err(Error::invalid(
            p.display().to_string(),
            "exists (an earlier result): refusing to replace it without --overwrite",
        )),
    }
}

/// The files in `dir` named `prefix…suffix` (empty when `dir` is absent).
pub fn files_like(dir: &Path, prefix: &str, suffix: &str) -> Result<Vec<PathBuf>> {
    let entries = match std::fs::read_dir(dir) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(Error::io(dir, e)),
        Ok(entries) => entries,
    };
    let mut found = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|e| Error::io(dir, e))?;
        let name = entry.file_name();
        let name = name.to_string_lossy();
        if name.starts_with(prefix) && name.ends_with(suffix) {
            found.push(entry.path());
        }
    }
    found.sort();
    Ok(found)
}

/// A directory of numbered frames (`prefix…suffix`) for this command:
/// earlier frames there are refused ([`check_no_earlier`]) unless
/// `overwrite`, and with it removed first, so the directory then holds
/// this command's frames only, never a mix of two runs.
pub fn claim_frames_dir(dir: &Path, prefix: &str, suffix: &str, overwrite: bool) -> Result<()> {
    let earlier = files_like(dir, prefix, suffix)?;
    check_no_earlier(&earlier, overwrite)?;
    for p in &earlier {
        check_replaceable(p)?;
        std::fs::remove_file(p).map_err(|e| Error::io(p, e))?;
    }
    Ok(())
}

/// Temporary sibling of `path`, unique to this process.
fn temporary_for(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.{}.tmp", std::process::id()))
}

/// Replaces `path` with `bytes` atomically, after [`check_replaceable`]:
/// readers see the old file or the whole new one, never a part.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    check_replaceable(path)?;
    let tmp = temporary_for(path);
    let written = std::fs::File::create(&tmp)
        .and_then(|mut f| f.write_all(bytes).and_then(|()| f.sync_all()));
    if let Err(e) = written {
        let _ = std::fs::remove_file(&tmp);
        return Err(Error::io(&tmp, e));
    }
    std::fs::rename(&tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        Error::io(path, e)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_frames_dir_with_earlier_frames_is_refused_or_cleared() {
        let dir = tempfile::tempdir().unwrap();
        let frames = dir.path().join("f");
        // Absent, then empty: claimed.
        claim_frames_dir(&frames, "frame_", ".png", false).unwrap();
        std::fs::create_dir(&frames).unwrap();
        claim_frames_dir(&frames, "frame_", ".png", false).unwrap();
        // Other files do not count and are kept.
        std::fs::write(frames.join("notes.txt"), b"keep").unwrap();
        claim_frames_dir(&frames, "frame_", ".png", false).unwrap();
        for k in [0, 7] {
            std::fs::write(frames.join(format!("frame_{k:06}.png")), b"x").unwrap();
        }
        let e = claim_frames_dir(&frames, "frame_", ".png", false)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("frame_000000.png") && e.contains("--overwrite"),
            "{e}"
        );
        assert_eq!(files_like(&frames, "frame_", ".png").unwrap().len(), 2);
        claim_frames_dir(&frames, "frame_", ".png", true).unwrap();
        assert!(files_like(&frames, "frame_", ".png").unwrap().is_empty());
        assert!(frames.join("notes.txt").exists());
    }

    #[test]
    fn replaces_regular_files_and_refuses_the_rest() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("s.json");
        write_atomic(&file, b"one").unwrap();
        write_atomic(&file, b"two").unwrap();
        assert_eq!(std::fs::read(&file).unwrap(), b"two");

        let link = dir.path().join("link.json");
        std::os::unix::fs::symlink(&file, &link).unwrap();
        let e = write_atomic(&link, b"x").unwrap_err().to_string();
        assert!(
            e.contains("symbolic link") && e.contains("link.json"),
            "{e}"
        );
        assert_eq!(std::fs::read(&file).unwrap(), b"two", "target untouched");

        let e = write_atomic(dir.path(), b"x").unwrap_err().to_string();
        assert!(e.contains("directory"), "{e}");
        let e = write_atomic(Path::new("/dev/null"), b"x")
            .unwrap_err()
            .to_string();
        assert!(e.contains("not a regular file"), "{e}");
        assert!(!std::fs::metadata("/dev/null").unwrap().is_file());
        let leftovers = std::fs::read_dir(dir.path()).unwrap().count();
        assert_eq!(leftovers, 2, "no temporary file left behind");
    }

    #[test]
    fn earlier_results_are_refused_unless_overwriting() {
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (dir.path().join("a.png"), dir.path().join("b.json"));
        let both = [a.clone(), b.clone()];
        check_no_earlier(&both, false).unwrap();
        std::fs::write(&b, "old").unwrap();
        let e = check_no_earlier(&both, false).unwrap_err().to_string();
        assert!(
            e.contains("b.json") && e.contains("--overwrite") && !e.contains('\n'),
            "{e}"
        );
        check_no_earlier(&both, true).unwrap();
    }

    #[test]
    fn appends_through_links_to_regular_files_only() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("log.jsonl");
        check_appendable(&file).unwrap();
        std::fs::write(&file, "").unwrap();
        let link = dir.path().join("link");
        std::os::unix::fs::symlink(&file, &link).unwrap();
        check_appendable(&link).unwrap();
        let e = check_appendable(Path::new("/dev/null"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("/dev/null"), "{e}");
        assert!(check_appendable(dir.path()).is_err());
    }
}
