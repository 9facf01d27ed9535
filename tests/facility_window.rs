//! WindowDisplay on a real X server (Xvfb): the presented frame must appear
//! on the root window pixel for pixel.
//!
//! Needs `Xvfb` and ImageMagick's `import` (Debian packages `xvfb`,
//! `imagemagick`). Without them the test prints why and passes, unless
//! `OPTISTIM_REQUIRE_XVFB=1`, in which case it fails.

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use optistim::facility::display::{Display, WindowDisplay, WindowOptions};
use optistim::facility::frame_id::{Corner, FrameIdCode};

const IMPORT: &str = "/usr/bin/import";
const W: usize = 640;
const H: usize = 480;

struct Xvfb(Child);

impl Drop for Xvfb {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn find_xvfb() -> Option<String> {
    for p in ["/usr/bin/Xvfb", "/usr/local/bin/Xvfb"] {
        if Path::new(p).exists() {
            return Some(p.to_string());
        }
    }
    None
}

/// Skips (returns true) or fails, as `OPTISTIM_REQUIRE_XVFB` says.
fn skip(why: &str) -> bool {
    if std::env::var("OPTISTIM_REQUIRE_XVFB").as_deref() == Ok("1") {
        panic!("OPTISTIM_REQUIRE_XVFB=1 but {why}");
    }
    println!("SKIPPED facility_window: {why}");
    true
}

fn start_xvfb(bin: &str) -> Option<(Xvfb, usize)> {
    for n in 91..160usize {
        if Path::new(&format!("/tmp/.X11-unix/X{n}")).exists()
            || Path::new(&format!("/tmp/.X{n}-lock")).exists()
        {
            continue;
        }
        let child = Command::new(bin)
            .arg(format!(":{n}"))
            .args(["-screen", "0", &format!("{W}x{H}x24"), "-nolisten", "tcp"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .ok()?;
        let mut x = Xvfb(child);
        let sock = format!("/tmp/.X11-unix/X{n}");
        let end = Instant::now() + Duration::from_secs(10);
        while Instant::now() < end {
            if let Ok(Some(_)) = x.0.try_wait() {
                break; // died (display taken meanwhile?): try the next number
            }
            if Path::new(&sock).exists() {
                std::thread::sleep(Duration::from_millis(200));
                return Some((x, n));
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
    None
}

fn pattern() -> Vec<u32> {
    // Distinct values in all three channels, to catch channel swaps,
    // offsets and scaling.
    let mut f: Vec<u32> = (0..W * H)
        .map(|i| {
            let (x, y) = (i % W, i / W);
            let r = (x * 255 / (W - 1)) as u32;
            let g = (y * 255 / (H - 1)) as u32;
            let b = ((x ^ y) & 0xff) as u32;
            (r << 16) | (g << 8) | b
        })
        .collect();
    let code = FrameIdCode::new(true, Corner::BottomLeft, 24, 4, 8, (W, H)).unwrap();
    code.encode(&mut f, 0x00C0_FFEE).unwrap();
    f
}

#[test]
fn presented_frame_equals_root_window_pixels() {
    let Some(xvfb_bin) = find_xvfb() else {
        if skip("Xvfb not installed (apt-get install xvfb)") {
            return;
        }
        unreachable!()
    };
    if !Path::new(IMPORT).exists()
        && skip("/usr/bin/import not installed (apt-get install imagemagick)")
    {
        return;
    }
    let Some((_xvfb, n)) = start_xvfb(&xvfb_bin) else {
        if skip("could not start Xvfb") {
            return;
        }
        unreachable!()
    };
    let display = format!(":{n}");
    std::env::set_var("DISPLAY", &display);

    let opts = WindowOptions::default();
    let mut win = match WindowDisplay::open(&opts) {
        Ok(w) => w,
        Err(e) => {
            eprintln!("first window creation failed ({e}); retrying once");
            std::thread::sleep(Duration::from_millis(500));
            WindowDisplay::open(&opts).expect("window on Xvfb")
        }
    };
    assert_eq!(
        win.size(),
        (W, H),
        "size must be the screen's native resolution"
    );
    assert!(win.is_open());

    let frame = pattern();
    let before = Instant::now();
    let at = win.present(&frame).unwrap();
    assert!(at >= before);
    assert!(win.present(&frame[1..]).is_err(), "wrong size is an error");

    let dir = tempfile::tempdir().unwrap();
    let shot = dir.path().join("root.png");
    let out = Command::new(IMPORT)
        .args(["-display", &display, "-window", "root"])
        .arg(&shot)
        .output()
        .expect("run import");
    assert!(
        out.status.success(),
        "import failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let img = image::open(&shot).expect("screenshot PNG").to_rgb8();
    assert_eq!((img.width() as usize, img.height() as usize), (W, H));

    let mut bad = 0usize;
    let mut first = None;
    for (i, p) in img.pixels().enumerate() {
        let v = frame[i];
        let want = [(v >> 16) as u8, (v >> 8) as u8, v as u8];
        if p.0 != want {
            bad += 1;
            first.get_or_insert((i % W, i / W, p.0, want));
        }
    }
    assert_eq!(
        bad, 0,
        "{bad} pixels differ; first (x, y, got, want) = {first:?}"
    );

    // The frame-id block is readable from the screenshot too.
    let code = FrameIdCode::new(true, Corner::BottomLeft, 24, 4, 8, (W, H)).unwrap();
    let id = code.decode_image(|x, y| img.get_pixel(x as u32, y as u32).0[1] as f64);
    assert_eq!(id, Ok(0x00C0_FFEE));
}
