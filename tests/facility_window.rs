//! WindowDisplay on a real X server (Xvfb): the presented frame must appear
//! on the root window pixel for pixel.
//!
//! Needs `Xvfb` and ImageMagick's `import` (Debian packages `xvfb`,
//! `imagemagick`). Without them the test prints why and passes, unless
//! `OPTISTIM_REQUIRE_XVFB=1`, in which case it fails.

use std::time::Instant;

use optistim::facility::display::{Display, MonitorSelect, WindowOptions};
use optistim::facility::frame_id::{Corner, FrameIdCode};

#[path = "common/xvfb.rs"]
mod xvfb;

const W: usize = 640;
const H: usize = 480;

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
    let _x = xvfb::x_lock();
    let Some(x) = xvfb::start("facility_window", (W, H), &[]) else {
        return;
    };
    // One monitor covering the screen: RandR's, or the whole-screen fallback.
    let mut win = xvfb::open_window(&WindowOptions::default());
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

    let img = xvfb::screenshot_root(&x.display);
    assert_eq!((img.width() as usize, img.height() as usize), (W, H));
    let (bad, first) = xvfb::diff_rect(&img, (0, 0), (W, H), &frame);
    assert_eq!(
        bad, 0,
        "{bad} pixels differ; first (x, y, got, want) = {first:?}"
    );

    // The frame-id block is readable from the screenshot too.
    let code = FrameIdCode::new(true, Corner::BottomLeft, 24, 4, 8, (W, H)).unwrap();
    let id = code.decode_image(|x, y| img.get_pixel(x as u32, y as u32).0[1] as f64);
    assert_eq!(id, Ok(0x00C0_FFEE));
}

/// Without the RandR extension the whole X screen is monitor 0.
#[test]
fn without_randr_the_screen_is_monitor_0() {
    let _x = xvfb::x_lock();
    let Some(x) = xvfb::start("facility_window", (W, H), &["-extension", "RANDR"]) else {
        return;
    };
    let list = optistim::facility::display::x_monitors().unwrap();
    assert!(list.fallback.is_some(), "{list:?}");
    assert_eq!(list.monitors.len(), 1);
    let m = &list.monitors[0];
    assert_eq!((m.x, m.y, m.width, m.height), (0, 0, W, H));

    let e = xvfb::open_window_err(
        &WindowOptions {
            monitor: MonitorSelect::Index(1),
            ..WindowOptions::default()
        },
        |e| e.contains("screen.monitor"),
    );
    assert!(e.contains("no monitor 1") && e.contains("RandR"), "{e}");

    let mut win = xvfb::open_window(&WindowOptions {
        monitor: MonitorSelect::Index(0),
        resolution: Some((W, H)),
        ..WindowOptions::default()
    });
    let frame = pattern();
    win.present(&frame).unwrap();
    let img = xvfb::screenshot_root(&x.display);
    let (bad, first) = xvfb::diff_rect(&img, (0, 0), (W, H), &frame);
    assert_eq!(bad, 0, "{bad} pixels differ; first = {first:?}");
}
