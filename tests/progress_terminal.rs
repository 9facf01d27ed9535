//! Progress bars: drawn on a terminal (a real pseudo-terminal as the
//! child's stderr), absent from redirected output, which carries no escape
//! sequence and no carriage return (`bench`, `run`).

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::Duration;

use serialport::{SerialPort, TTYPort};

/// The benchmark Moon at 160×160 px: a sweep of a few settings in a second.
fn small_scene(dir: &Path) -> PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("configs/moon_bench.toml")).unwrap();
    let data = root.join("data");
    let text = text
        .replace("[1024, 1024]", "[160, 160]")
        .replace("../data", data.to_str().unwrap());
    let path = dir.join("scene.toml");
    std::fs::write(&path, text).unwrap();
    path
}

fn bench(scene: &Path) -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_optistim"));
    cmd.arg("bench").arg("--scene").arg(scene).args([
        "--phases",
        "40,100",
        "--densities",
        "0.5,1",
        "--repeats",
        "3",
    ]);
    cmd
}

/// No escape sequence, no carriage return, no bar in `out`.
fn assert_plain(what: &str, out: &Output) {
    // `run` exits 4 when its verdict is `fail` (a busy machine may miss
    // deadlines): a verdict, not an error.
    let verdict_fail = what == "run" && out.status.code() == Some(4);
    assert!(
        out.status.success() || verdict_fail,
        "{what}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    for (stream, bytes) in [("stdout", &out.stdout), ("stderr", &out.stderr)] {
        let text = String::from_utf8_lossy(bytes);
        assert!(!bytes.contains(&0x1b), "{what} {stream} has ESC: {text}");
        assert!(!bytes.contains(&b'\r'), "{what} {stream} has CR: {text}");
        assert!(!text.contains("ETA"), "{what} {stream} has a bar: {text}");
    }
}

#[test]
fn redirected_bench_and_run_write_no_bar_and_no_escapes() {
    let dir = tempfile::tempdir().unwrap();
    let out = bench(&small_scene(dir.path())).output().unwrap();
    assert_plain("bench", &out);
    // The table itself is there: 2 phases × 2 interiors × 2 densities.
    let rows = String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter(|l| l.starts_with("| 40 ") || l.starts_with("| 100 "))
        .count();
    assert_eq!(rows, 8);

    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let out = Command::new(env!("CARGO_BIN_EXE_optistim"))
        .current_dir(root)
        .args(["run", "configs/facility.toml", "--frames", "12", "--log"])
        .arg(dir.path().join("frames.jsonl"))
        .arg("--summary")
        .arg(dir.path().join("summary.json"))
        .output()
        .unwrap();
    assert_plain("run", &out);
    assert!(String::from_utf8_lossy(&out.stdout).contains("frames 12"));
}

#[test]
fn bench_on_a_terminal_draws_its_bar() {
    let dir = tempfile::tempdir().unwrap();
    let scene = small_scene(dir.path());
    let (mut master, slave) = TTYPort::pair().expect("pty pair");
    master.set_timeout(Duration::from_millis(100)).unwrap();
    let tty = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(slave.name().expect("slave name"))
        .unwrap();
    let mut child = bench(&scene)
        .stdout(Stdio::null())
        .stderr(Stdio::from(tty))
        .spawn()
        .unwrap();
    // Read while the child writes, so a full pty buffer never blocks it.
    let mut seen = Vec::new();
    let mut buf = [0u8; 4096];
    let deadline = std::time::Instant::now() + Duration::from_secs(60);
    loop {
        match master.read(&mut buf) {
            Ok(n) => seen.extend_from_slice(&buf[..n]),
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
            Err(_) => break,
        }
        if child.try_wait().unwrap().is_some() || std::time::Instant::now() > deadline {
            break;
        }
    }
    let status = child.wait().unwrap();
    while let Ok(n) = master.read(&mut buf) {
        if n == 0 {
            break;
        }
        seen.extend_from_slice(&buf[..n]);
    }
    assert!(status.success());
    let text = String::from_utf8_lossy(&seen);
    assert!(text.contains("bench ["), "no bar on the terminal: {text:?}");
    assert!(text.contains("/10"), "no step count of 10: {text:?}");
}
