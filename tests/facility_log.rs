//! Frame log durability: a process that aborts (no destructors, no flush at
//! exit) loses no record written before the crash, and a later run appends
//! to — never truncates — the existing log.

use std::process::Command;
use std::time::{Duration, Instant};

use optistim::facility::log::{read_records, FrameLog, FrameRecord};

const CHILD_ENV: &str = "OPTISTIM_LOG_CRASH_CHILD";

fn record(log: &FrameLog, frame: u64, start: Instant) -> FrameRecord {
    let presented = start + Duration::from_millis(10 * frame + 5);
    FrameRecord {
        frame,
        state_t: frame as f64,
        t_state_received: Some(log.since_start(start + Duration::from_millis(10 * frame))),
        t_render_start: log.since_start(start + Duration::from_millis(10 * frame + 1)),
        t_render_end: log.since_start(start + Duration::from_millis(10 * frame + 3)),
        t_convert_end: log.since_start(start + Duration::from_millis(10 * frame + 4)),
        t_presented: log.since_start(presented),
        deadline: log.since_start(start + Duration::from_millis(10 * frame + 8)),
        k: 1.0,
        lut_sha256: "0".repeat(64),
        ..Default::default()
    }
}

/// Child half: writes frames then aborts mid-run. Does nothing unless the
/// parent test started this binary with the environment variable set.
#[test]
fn crash_child() {
    let Ok(path) = std::env::var(CHILD_ENV) else {
        return;
    };
    let start = Instant::now();
    let mut log = FrameLog::open(&path, start).unwrap();
    for f in 0..5 {
        let r = record(&log, f, start);
        log.write(r).unwrap();
    }
    std::process::abort();
}

#[test]
fn records_survive_a_crash_and_logs_are_appended() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("frames.jsonl");

    // First run: a normal one with two frames.
    let start = Instant::now();
    let mut log = FrameLog::open(&path, start).unwrap();
    for f in 100..102 {
        let r = record(&log, f, start);
        log.write(r).unwrap();
    }
    let first_run = log.run().to_string();
    drop(log);
    let before = std::fs::read(&path).unwrap();

    // Second run crashes after five frames.
    let status = Command::new(std::env::current_exe().unwrap())
        .args(["--exact", "crash_child", "--nocapture", "--test-threads=1"])
        .env(CHILD_ENV, &path)
        .status()
        .unwrap();
    assert!(!status.success(), "child should have aborted");

    let after = std::fs::read(&path).unwrap();
    assert!(after.starts_with(&before), "existing log was modified");
    let recs = read_records(&path).unwrap();
    let frames: Vec<u64> = recs.iter().map(|r| r.frame).collect();
    assert_eq!(frames, vec![100, 101, 0, 1, 2, 3, 4]);
    assert!(recs[..2].iter().all(|r| r.run == first_run));
    assert!(recs[2..]
        .iter()
        .all(|r| r.run != first_run && r.run == recs[2].run));
    assert!(
        recs.iter().all(|r| !r.missed),
        "presented 3 ms before deadline"
    );
    assert!((recs[3].t_presented - recs[3].t_state_received.unwrap() - 0.005).abs() < 1e-9);
}

/// A record torn by a full disk: the next run starts a new line, so no
/// later record is glued onto it and every whole record reads back.
#[test]
fn a_torn_record_does_not_swallow_the_next_run() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("frames.jsonl");
    let start = Instant::now();
    let mut log = FrameLog::open(&path, start).unwrap();
    for f in 0..2 {
        let r = record(&log, f, start);
        log.write(r).unwrap();
    }
    drop(log);
    let whole = std::fs::read_to_string(&path).unwrap();
    let torn = &whole.lines().next().unwrap()[..40];
    std::fs::write(&path, format!("{whole}{torn}")).unwrap();

    let mut log = FrameLog::open(&path, start).unwrap();
    for f in 7..9 {
        let r = record(&log, f, start);
        log.write(r).unwrap();
    }
    drop(log);
    let text = std::fs::read_to_string(&path).unwrap();
    assert_eq!(
        text.lines().nth(2),
        Some(torn),
        "the torn record on its own line"
    );
    let frames: Vec<u64> = read_records(&path)
        .unwrap()
        .iter()
        .map(|r| r.frame)
        .collect();
    assert_eq!(frames, vec![0, 1, 7, 8]);
}
