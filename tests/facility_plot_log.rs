//! `optistim plot-log`: the timing figure of a real frame log (written by
//! `FrameLog`, with a torn last line) is produced at its size, shows the
//! missed deadlines in red, and its statistics are the log's own.

use std::io::Write;
use std::path::Path;
use std::process::Command;
use std::time::Instant;

use optistim::facility::log::{read_records, FrameLog, FrameRecord};
use optistim::facility::timing::{RunTiming, MISSED_RED, TIMING_FIGURE_SIZE};

/// Frame `k` of 200 at 30 Hz: latency 12 ms + (k mod 7) ms; every 50th
/// frame 40 ms late for its 30 ms deadline; frame 10 a safe frame.
fn record(k: u64) -> FrameRecord {
    let recv = k as f64 / 30.0;
    let latency = if k % 50 == 49 {
        0.040
    } else {
        0.012 + (k % 7) as f64 * 1e-3
    };
    let safe = k == 10;
    FrameRecord {
        frame: k,
        state_t: if safe { f64::NAN } else { recv },
        t_state_received: (!safe).then_some(recv),
        t_render_start: recv,
        t_render_end: recv + 0.005,
        t_convert_end: recv + 0.008,
        t_presented: recv + latency,
        deadline: recv + 0.030,
        safe_frame: safe,
        lut_sha256: "0".repeat(64),
        k: 1.0,
        ..Default::default()
    }
}

fn write_log(path: &Path) {
    // An older run first, then the run to plot, then a torn line.
    let mut old = FrameLog::open(path, Instant::now()).unwrap();
    old.write(record(0)).unwrap();
    drop(old);
    std::thread::sleep(std::time::Duration::from_millis(2));
    let mut log = FrameLog::open(path, Instant::now()).unwrap();
    for k in 0..200 {
        log.write(record(k)).unwrap();
    }
    let mut f = std::fs::OpenOptions::new().append(true).open(path).unwrap();
    f.write_all(b"{\"run\":\"x\",\"frame\":200,\"state_t\":6.6")
        .unwrap();
}

fn red_pixels(img: &image::RgbImage) -> usize {
    let c = MISSED_RED;
    img.pixels().filter(|p| p.0 == [c.0, c.1, c.2]).count()
}

#[test]
fn timing_figure_of_a_log_with_a_torn_line() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("frames.jsonl");
    write_log(&log);
    let out = dir.path().join("figs");
    let res = Command::new(env!("CARGO_BIN_EXE_optistim"))
        .args([
            "plot-log",
            log.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(
        res.status.success(),
        "{}",
        String::from_utf8_lossy(&res.stderr)
    );
    let png = out.join("timing.png");
    if let Some(k) = std::env::var_os("OPTISTIM_KEEP_FIGURES") {
        std::fs::copy(&png, Path::new(&k).join("timing.png")).unwrap();
    }
    let img = image::open(&png).unwrap().to_rgb8();
    assert_eq!((img.width(), img.height()), TIMING_FIGURE_SIZE);
    let dark = img
        .pixels()
        .filter(|p| p.0.iter().all(|&c| c < 100))
        .count();
    assert!(dark > 2000, "only {dark} dark pixels");
    // 4 missed frames drawn as filled red circles.
    assert!(
        red_pixels(&img) >= 4 * 15,
        "{} red pixels",
        red_pixels(&img)
    );

    // The plotted run is the last one, and its statistics are the
    // nearest ranks of the latencies written above.
    let records = read_records(&log).unwrap();
    let run = records.last().unwrap().run.clone();
    let t = RunTiming::of_run(&records, &run);
    assert_eq!((t.frames, t.missed, t.safe_frames), (200, 4, 1));
    assert_eq!(t.late.len(), 4);
    let mut lat: Vec<f64> = (0..200u64)
        .filter(|&k| k != 10)
        .map(|k| {
            if k % 50 == 49 {
                40.0
            } else {
                12.0 + (k % 7) as f64
            }
        })
        .collect();
    lat.sort_by(f64::total_cmp);
    let rank = |p: f64| lat[((p / 100.0 * lat.len() as f64).ceil() as usize) - 1];
    let close = |a: Option<f64>, b: f64| (a.unwrap() - b).abs() < 1e-6;
    assert!(close(t.latency_ms.p50, rank(50.0)), "{:?}", t.latency_ms);
    assert!(close(t.latency_ms.p99, rank(99.0)), "{:?}", t.latency_ms);
}

/// Without `--out` the figure goes next to the log; a second plot refuses
/// to replace it unless `--overwrite`.
#[test]
fn plot_log_writes_next_to_the_log_and_keeps_an_earlier_figure() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("frames.jsonl");
    write_log(&log);
    let plot = |extra: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_optistim"))
            .arg("plot-log")
            .arg(&log)
            .args(extra)
            .output()
            .unwrap()
    };
    assert!(plot(&[]).status.success());
    let png = dir.path().join("timing.png");
    let first = std::fs::read(&png).unwrap();
    let out = plot(&[]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("timing.png") && err.contains("--overwrite"),
        "{err}"
    );
    assert_eq!(std::fs::read(&png).unwrap(), first, "kept");
    // Another run of the same log, replacing the figure when told.
    let records = read_records(&log).unwrap();
    let first_run = records[0].run.clone();
    assert!(plot(&["--run", &first_run, "--overwrite"]).status.success());
    assert_ne!(
        std::fs::read(&png).unwrap(),
        first,
        "the first run's figure"
    );
}

#[test]
fn a_log_without_records_is_a_one_line_error() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("empty.jsonl");
    std::fs::write(&log, "{\"run\":\"x\",\"fra").unwrap();
    let res = Command::new(env!("CARGO_BIN_EXE_optistim"))
        .args(["plot-log", log.to_str().unwrap(), "--out"])
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(!res.status.success());
    let err = String::from_utf8_lossy(&res.stderr);
    assert!(err.contains("empty.jsonl"), "{err}");
    assert!(!dir.path().join("timing.png").exists());
}
