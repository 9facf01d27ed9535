//! Outputs are never replaced silently: `run` without `--log`/`--summary`
//! gives every run a directory of its own (twice in a row: two
//! directories, one run each); a given log is extended only with
//! `--append` and a given summary replaced only with `--overwrite`;
//! `render --out` and `plot-log` refuse an earlier result unless
//! `--overwrite`.

use std::path::Path;
use std::process::{Command, Output};

use optistim::facility::log::read_records;

mod common;
use common::simfacility::SIM_FACILITY_ARGS;

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

fn frame_names(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with("frame_") && n.ends_with(".png"))
        .collect();
    names.sort();
    names
}

/// `run --dump DIR` (and `--captures DIR` below) twice: the second run is
/// refused before it starts, naming an earlier frame and `--overwrite`,
/// and the first run's frames are untouched; with `--overwrite` the
/// earlier frames are removed and the directory holds the new run's only.
fn frames_dir_is_kept_unless_told(flag: &str, extra: &[&str]) {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("frames");
    let runs = tmp.path().join("runs");
    let run = |frames: &str, overwrite: bool| {
        let mut args = vec!["run", "configs/facility.toml", "--frames", frames];
        args.extend(extra);
        if overwrite {
            args.push("--overwrite");
        }
        args.extend([flag]);
        optistim(&args, &[&dir, Path::new("--runs-dir"), &runs])
    };
    let first = run("3", false);
    assert!(ran(&first), "{}", String::from_utf8_lossy(&first.stderr));
    let before = frame_names(&dir);
    assert!(before.len() >= 2, "{before:?}");
    let stamp = std::fs::read(dir.join(&before[0])).unwrap();
    let again = run("1", false);
    assert!(!ran(&again), "{flag}: a second run was accepted");
    let err = String::from_utf8_lossy(&again.stderr);
    assert!(
        err.contains(&before[0]) && err.contains("--overwrite") && err.trim().lines().count() == 1,
        "{err}"
    );
    assert_eq!(frame_names(&dir), before);
    assert_eq!(std::fs::read(dir.join(&before[0])).unwrap(), stamp);
    let replaced = run("1", true);
    assert!(
        ran(&replaced),
        "{}",
        String::from_utf8_lossy(&replaced.stderr)
    );
    assert_eq!(frame_names(&dir), ["frame_000000.png"]);
}

#[test]
fn dump_refuses_earlier_frames_unless_overwriting() {
    frames_dir_is_kept_unless_told("--dump", &[]);
}

#[test]
fn captures_refuse_earlier_frames_unless_overwriting() {
    frames_dir_is_kept_unless_told("--captures", &SIM_FACILITY_ARGS);
}

#[test]
fn validate_refuses_an_earlier_result_unless_overwriting() {
    let tmp = tempfile::tempdir().unwrap();
    let out_dir = tmp.path().join("val");
    std::fs::create_dir(&out_dir).unwrap();
    std::fs::write(out_dir.join("report.json"), b"earlier").unwrap();
    let out = optistim(
        &[
            "validate",
            "amie",
            "data/amie/AMI_EE3_040819_00208_00030.IMG",
            "--out",
        ],
        &[&out_dir],
    );
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("report.json")
            && err.contains("--overwrite")
            && err.trim().lines().count() == 1,
        "{err}"
    );
    assert_eq!(
        std::fs::read(out_dir.join("report.json")).unwrap(),
        b"earlier"
    );
}

/// A bad `--caps-per-pixel` is a one-line error naming the flag (not the
/// scene key it overrides), before anything is rendered or validated.
#[test]
fn caps_per_pixel_flag_errors_name_the_flag() {
    let tmp = tempfile::tempdir().unwrap();
    let out_dir = tmp.path().join("out");
    let out_arg = out_dir.to_str().unwrap();
    for bad in ["nan", "0", "-1", "65", "1e9", "inf", "four"] {
        for cmd in [
            vec!["render", "configs/moon.toml", "--out", out_arg],
            vec![
                "validate",
                "amie",
                "data/amie/missing.img",
                "--out",
                out_arg,
            ],
        ] {
            let flag = format!("--caps-per-pixel={bad}");
            let mut args = cmd.clone();
            args.push(&flag);
            let out = optistim(&args, &[]);
            let err = String::from_utf8_lossy(&out.stderr);
            assert!(!out.status.success(), "{args:?} succeeded");
            assert!(err.contains("--caps-per-pixel"), "{args:?}: {err}");
            assert!(!err.contains("render.caps_per_pixel"), "{args:?}: {err}");
        }
    }
    assert!(!out_dir.exists(), "nothing is written for a bad flag");
}

/// A bad `--relief-height-scale` is a one-line error naming the flag,
/// before anything is validated.
#[test]
fn relief_height_scale_flag_errors_name_the_flag() {
    let tmp = tempfile::tempdir().unwrap();
    let out_dir = tmp.path().join("out");
    let out_arg = out_dir.to_str().unwrap();
    for bad in ["nan", "0", "-1", "10.5", "inf", "two"] {
        let flag = format!("--relief-height-scale={bad}");
        let args = [
            "validate",
            "amie",
            "data/amie/missing.img",
            "--relief",
            "shadows",
            "--out",
            out_arg,
            &flag,
        ];
        let out = optistim(&args, &[]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?} succeeded");
        assert!(err.contains("--relief-height-scale"), "{args:?}: {err}");
    }
    assert!(!out_dir.exists(), "nothing is written for a bad flag");
}
