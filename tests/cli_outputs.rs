//! Outputs are never replaced silently: `run` without `--log`/`--summary`
//! gives every run a directory of its own (twice in a row: two
//! directories, one run each); a given log is extended only with
//! `--append` and a given summary replaced only with `--overwrite`;
//! `render --out` and `plot-log` refuse an earlier result unless
//! `--overwrite`.

use std::path::Path;
use std::process::{Command, Output};

use optistim::facility::log::read_records;

fn optistim(args: &[&str], extra: &[&Path]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_optistim"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .args(args)
        .args(extra)
        .output()
        .unwrap()
}

/// Exit 0 or 4 (a `fail` verdict from a missed deadline on a busy
/// machine): the run happened.
fn ran(out: &Output) -> bool {
    matches!(out.status.code(), Some(0 | 4))
}

#[test]
fn runs_twice_in_a_row_get_a_directory_each() {
    let tmp = tempfile::tempdir().unwrap();
    let runs = tmp.path().join("runs");
    let args = [
        "run",
        "configs/facility.toml",
        "--frames",
        "2",
        "--runs-dir",
    ];
    for _ in 0..2 {
        let out = optistim(&args, &[&runs]);
        assert!(ran(&out), "{}", String::from_utf8_lossy(&out.stderr));
    }
    let mut dirs: Vec<_> = std::fs::read_dir(&runs)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    dirs.sort();
    assert_eq!(dirs.len(), 2, "{dirs:?}");
    let mut ids = Vec::new();
    for d in &dirs {
        let records = read_records(d.join("frames.jsonl")).unwrap();
        assert_eq!(records.len(), 2, "{}: one run of two frames", d.display());
        assert!(records.iter().all(|r| r.run == records[0].run));
        let s: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(d.join("run_summary.json")).unwrap())
                .unwrap();
        assert_eq!(s["run"], records[0].run.as_str());
        ids.push(records[0].run.clone());
        // YYYYMMDDTHHMMSSZ, maybe with -N.
        let name = d.file_name().unwrap().to_string_lossy().into_owned();
        assert!(
            name.len() >= 16 && &name[8..9] == "T" && &name[15..16] == "Z",
            "{name}"
        );
    }
    assert_ne!(ids[0], ids[1]);
}

#[test]
fn a_given_log_or_summary_is_kept_unless_told() {
    let tmp = tempfile::tempdir().unwrap();
    let (log, summary) = (tmp.path().join("f.jsonl"), tmp.path().join("s.json"));
    let run = ["run", "configs/facility.toml", "--frames", "1", "--log"];
    let out = optistim(&run, &[&log, Path::new("--summary"), &summary]);
    assert!(ran(&out), "{}", String::from_utf8_lossy(&out.stderr));
    let (log_before, summary_before) = (
        std::fs::read(&log).unwrap(),
        std::fs::read(&summary).unwrap(),
    );
    let other = tmp.path().join("other.json");
    let out = optistim(&run, &[&log, Path::new("--summary"), &other]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("f.jsonl") && err.contains("--append"), "{err}");
    let out = optistim(
        &["run", "configs/facility.toml", "--frames", "1", "--summary"],
        &[&summary, Path::new("--log"), &tmp.path().join("g.jsonl")],
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("s.json") && err.contains("--overwrite"),
        "{err}"
    );
    assert_eq!(std::fs::read(&log).unwrap(), log_before, "log untouched");
    assert_eq!(std::fs::read(&summary).unwrap(), summary_before);
    assert!(
        !tmp.path().join("g.jsonl").exists(),
        "refused before the run"
    );

    // Told: the log gains a second run after the first, whole.
    let out = optistim(
        &run,
        &[&log, Path::new("--append"), Path::new("--summary"), &other],
    );
    assert!(ran(&out), "{}", String::from_utf8_lossy(&out.stderr));
    let after = std::fs::read(&log).unwrap();
    assert!(after.starts_with(&log_before));
    let records = read_records(&log).unwrap();
    assert_eq!(records.len(), 2);
    assert_ne!(records[0].run, records[1].run);
}

#[test]
fn render_refuses_an_earlier_result_unless_overwriting() {
    let tmp = tempfile::tempdir().unwrap();
    let out_dir = tmp.path().join("r");
    let render = ["render", "configs/examples/moon_lambert.toml", "--out"];
    assert!(optistim(&render, &[&out_dir]).status.success());
    let first = std::fs::read(out_dir.join("summary.json")).unwrap();
    let out = optistim(&render, &[&out_dir]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("radiance.tiff") && err.contains("--overwrite"),
        "{err}"
    );
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert_eq!(std::fs::read(out_dir.join("summary.json")).unwrap(), first);
    let out = optistim(&render, &[&out_dir, Path::new("--overwrite")]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}
