//! `optistim run` as a service manager or `timeout` stops it: SIGTERM (and
//! SIGINT, Ctrl-C) end the run cleanly, with every frame logged as a whole
//! JSON line and the summary written, saying it was interrupted (verdict
//! `fail`, exit status 4).
#![cfg(unix)]

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn run_and_signal(signal: i32, dir: &Path) {
    let log = dir.join("frames.jsonl");
    let summary = dir.join("summary.json");
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut child = Command::new(env!("CARGO_BIN_EXE_optistim"))
        .arg("run")
        .arg(manifest.join("configs/facility.toml"))
        .arg("--log")
        .arg(&log)
        .arg("--summary")
        .arg(&summary)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start optistim run");
    // Wait for the loop to have logged a few frames, then signal it.
    let start = Instant::now();
    while std::fs::read_to_string(&log).map_or(0, |t| t.lines().count()) < 5 {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "no frames logged"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    // SAFETY: plain kill(2) on our own child's pid.
    assert_eq!(unsafe { libc::kill(child.id() as i32, signal) }, 0);
    let status = child.wait().expect("wait");
    // Stopped before its 300 frames: the verdict is `fail`, exit status 4.
    assert_eq!(
        status.code(),
        Some(4),
        "exit status after signal {signal}: {status}"
    );

    let text = std::fs::read_to_string(&log).unwrap();
    assert!(text.ends_with('\n'), "the last record is whole");
    let frames = text.lines().count();
    assert!((5..300).contains(&frames), "{frames} frames: stopped early");
    for line in text.lines() {
        serde_json::from_str::<serde_json::Value>(line).expect("each line is JSON");
    }
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&summary).expect("summary written")).unwrap();
    assert_eq!(s["interrupted"], true, "{s}");
    assert_eq!(s["frames_planned"], 300, "{s}");
    assert_eq!(s["frames"], frames as u64, "{s}");
    assert_eq!(s["verdict"], "fail", "{s}");
    let reason = format!("interrupted after {frames} of 300 planned frames");
    assert!(
        s["reasons"]
            .as_array()
            .unwrap()
            .iter()
            .any(|r| r == reason.as_str()),
        "{s}"
    );
}

#[test]
fn sigterm_stops_the_run_like_ctrl_c() {
    let dir = tempfile::tempdir().unwrap();
    run_and_signal(libc::SIGTERM, dir.path());
}

#[test]
fn sigint_stops_the_run() {
    let dir = tempfile::tempdir().unwrap();
    run_and_signal(libc::SIGINT, dir.path());
}
