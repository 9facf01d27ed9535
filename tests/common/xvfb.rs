//! Real-X-server helpers of the window tests: a private Xvfb, root-window
//! screenshots with ImageMagick's `import`, and the skip-or-fail rule: without
//! Xvfb or `import` a test prints why and passes, unless
//! `OPTISTIM_REQUIRE_XVFB=1` (set by .ci/run), in which case it fails.

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

use optistim::error::Result;
use optistim::facility::display::{WindowDisplay, WindowOptions};

pub const IMPORT: &str = "/usr/bin/import";

/// A running Xvfb, killed on drop.
pub struct Xvfb {
    child: Child,
    /// `":N"`.
    pub display: String,
}

impl Drop for Xvfb {
    fn drop(&mut self) {
        // SIGTERM, so Xvfb removes its socket and lock file (SIGKILL leaves
        // them, and stale ones pile up over the display numbers).
        let _ = Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status();
        let end = Instant::now() + Duration::from_secs(3);
        while Instant::now() < end {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// `$DISPLAY` is process-wide and minifb reads it: tests of one binary that
/// use X take this lock for their whole duration.
pub fn x_lock() -> MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}

fn find_xvfb() -> Option<&'static str> {
    ["/usr/bin/Xvfb", "/usr/local/bin/Xvfb"]
        .into_iter()
        .find(|p| Path::new(p).exists())
}

/// Skips (returns true) or fails, as `OPTISTIM_REQUIRE_XVFB` says.
pub fn skip(test: &str, why: &str) -> bool {
    if std::env::var("OPTISTIM_REQUIRE_XVFB").as_deref() == Ok("1") {
        panic!("OPTISTIM_REQUIRE_XVFB=1 but {why}");
    }
    println!("SKIPPED {test}: {why}");
    true
}

/// Starts Xvfb with one `w×h` depth-24 screen (and `extra` arguments) on a
/// free display number and points `$DISPLAY` at it. `None` when the test
/// is to be skipped (see [`skip`]).
pub fn start(test: &str, (w, h): (usize, usize), extra: &[&str]) -> Option<Xvfb> {
    let Some(bin) = find_xvfb() else {
        skip(test, "Xvfb not installed (apt-get install xvfb)");
        return None;
    };
    if !Path::new(IMPORT).exists() {
        skip(
            test,
            "/usr/bin/import not installed (apt-get install imagemagick)",
        );
        return None;
    }
    for n in 91..200usize {
        // A stale socket would pass for readiness below: skip it too.
        if Path::new(&format!("/tmp/.X11-unix/X{n}")).exists()
            || Path::new(&format!("/tmp/.X{n}-lock")).exists()
        {
            continue;
        }
        let Ok(child) = Command::new(bin)
            .arg(format!(":{n}"))
            .args(["-screen", "0", &format!("{w}x{h}x24"), "-nolisten", "tcp"])
            .args(extra)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
        else {
            break;
        };
        let mut x = Xvfb {
            child,
            display: format!(":{n}"),
        };
        let sock = format!("/tmp/.X11-unix/X{n}");
        let end = Instant::now() + Duration::from_secs(10);
        while Instant::now() < end {
            if let Ok(Some(_)) = x.child.try_wait() {
                break; // died (display taken meanwhile?): try the next number
            }
            if Path::new(&sock).exists() {
                std::thread::sleep(Duration::from_millis(200));
                std::env::set_var("DISPLAY", &x.display);
                return Some(x);
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
    skip(test, "could not start Xvfb");
    None
}

/// Opens the window, retrying once: creating a window against a fresh Xvfb
/// very rarely fails.
pub fn open_window(opts: &WindowOptions) -> WindowDisplay {
    match WindowDisplay::open(opts) {
        Ok(w) => w,
        Err(e) => {
            eprintln!("first window creation failed ({e}); retrying once");
            std::thread::sleep(Duration::from_millis(500));
            WindowDisplay::open(opts).expect("window on Xvfb")
        }
    }
}

/// Like [`open_window`] for an open that must fail: retries once only if
/// the first error is not the expected kind (`accept`).
pub fn open_window_err(opts: &WindowOptions, accept: impl Fn(&str) -> bool) -> String {
    let first: Result<WindowDisplay> = WindowDisplay::open(opts);
    let e = match first {
        Ok(w) => panic!("window opened but should not: {w:?}"),
        Err(e) => e.to_string(),
    };
    if accept(&e) {
        return e;
    }
    eprintln!("unexpected error ({e}); retrying once");
    std::thread::sleep(Duration::from_millis(500));
    match WindowDisplay::open(opts) {
        Ok(w) => panic!("window opened but should not: {w:?}"),
        Err(e) => e.to_string(),
    }
}

/// Screenshot of the whole root window of `display`.
pub fn screenshot_root(display: &str) -> image::RgbImage {
    let dir = tempfile::tempdir().unwrap();
    let shot = dir.path().join("root.png");
    let out = Command::new(IMPORT)
        .args(["-display", display, "-window", "root"])
        .arg(&shot)
        .output()
        .expect("run import");
    assert!(
        out.status.success(),
        "import failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    image::open(&shot).expect("screenshot PNG").to_rgb8()
}

/// `0x00RRGGBB` → `[r, g, b]`.
pub fn rgb(v: u32) -> [u8; 3] {
    [(v >> 16) as u8, (v >> 8) as u8, v as u8]
}

/// A differing pixel: `(x, y, got, want)`.
pub type PixelDiff = (usize, usize, [u8; 3], [u8; 3]);

/// Pixels of the `w×h` rectangle at `(x0, y0)` of `img` that differ from
/// `frame` (row-major `w×h`): count and the first `(x, y, got, want)`.
pub fn diff_rect(
    img: &image::RgbImage,
    (x0, y0): (usize, usize),
    (w, h): (usize, usize),
    frame: &[u32],
) -> (usize, Option<PixelDiff>) {
    assert_eq!(frame.len(), w * h);
    let mut bad = 0;
    let mut first = None;
    for y in 0..h {
        for x in 0..w {
            let got = img.get_pixel((x0 + x) as u32, (y0 + y) as u32).0;
            let want = rgb(frame[y * w + x]);
            if got != want {
                bad += 1;
                first.get_or_insert((x, y, got, want));
            }
        }
    }
    (bad, first)
}
