//! WindowDisplay on one RandR monitor of a wide X screen (Xvfb): two
//! monitors are defined in-process with XRRSetMonitor, the window is opened
//! on one of them by name and by index, and the root-window screenshot must
//! show the presented frame exactly on that monitor's rectangle and nothing
//! elsewhere. Skip-or-fail rule as in facility_window.rs.

use optistim::facility::display::{x_monitors, Display, MonitorInfo, MonitorSelect, WindowOptions};
use optistim::facility::frame_id::{Corner, FrameIdCode};
use x11_dl::{xlib, xrandr};

#[path = "common/xvfb.rs"]
mod xvfb;

const SCREEN: (usize, usize) = (1600, 900);

/// The monitors this test defines: name, x, y, width, height, primary.
const OPS: (&str, i32, i32, usize, usize, bool) = ("OPS", 0, 0, 600, 900, false);
const FAC: (&str, i32, i32, usize, usize, bool) = ("FAC", 600, 100, 1000, 700, true);

/// A connection that defined the monitors; it stays open for the test, as
/// Xvfb forgets them when it resets after its last client leaves.
struct Monitors {
    xlib: xlib::Xlib,
    xrr: xrandr::Xrandr,
    dpy: *mut xlib::Display,
}

impl Monitors {
    fn define(mons: &[(&str, i32, i32, usize, usize, bool)]) -> Monitors {
        let xlib = xlib::Xlib::open().expect("libX11");
        let xrr = xrandr::Xrandr::open().expect("libXrandr.so.2");
        // SAFETY: plain Xlib/Xrandr calls on a connection checked non-null;
        // each XRRMonitorInfo comes from XRRAllocateMonitor and is freed once.
        unsafe {
            let dpy = (xlib.XOpenDisplay)(std::ptr::null());
            assert!(!dpy.is_null(), "cannot open $DISPLAY");
            let (mut major, mut minor) = (0, 0);
            (xrr.XRRQueryVersion)(dpy, &mut major, &mut minor);
            assert!(
                (major, minor) >= (1, 5),
                "Xvfb has RandR {major}.{minor}, monitors need 1.5"
            );
            let root = (xlib.XDefaultRootWindow)(dpy);
            for &(name, x, y, w, h, primary) in mons {
                let m = (xrr.XRRAllocateMonitor)(dpy, 0);
                let cname = std::ffi::CString::new(name).unwrap();
                (*m).name = (xlib.XInternAtom)(dpy, cname.as_ptr(), xlib::False);
                (*m).primary = primary as i32;
                (*m).x = x;
                (*m).y = y;
                (*m).width = w as i32;
                (*m).height = h as i32;
                // 0.25 mm pixels; the size in mm plays no part here.
                (*m).mwidth = w as i32 / 4;
                (*m).mheight = h as i32 / 4;
                (xrr.XRRSetMonitor)(dpy, root, m);
                (xlib.XFree)(m as *mut _);
            }
            (xlib.XSync)(dpy, xlib::False);
            Monitors { xlib, xrr, dpy }
        }
    }

    /// Monitor names in XRRGetMonitors order (active ones), queried here
    /// rather than through optistim.
    fn names(&self) -> Vec<String> {
        // SAFETY: as in `define`; the array is read within its count.
        unsafe {
            let root = (self.xlib.XDefaultRootWindow)(self.dpy);
            let mut n = 0;
            let m = (self.xrr.XRRGetMonitors)(self.dpy, root, xlib::True, &mut n);
            assert!(!m.is_null());
            let names = std::slice::from_raw_parts(m, n as usize)
                .iter()
                .map(|mi| {
                    let p = (self.xlib.XGetAtomName)(self.dpy, mi.name);
                    let s = std::ffi::CStr::from_ptr(p).to_string_lossy().into_owned();
                    (self.xlib.XFree)(p as *mut _);
                    s
                })
                .collect();
            (self.xrr.XRRFreeMonitors)(m);
            names
        }
    }
}

impl Drop for Monitors {
    fn drop(&mut self) {
        // SAFETY: closing the connection opened in `define`.
        unsafe {
            (self.xlib.XCloseDisplay)(self.dpy);
        }
    }
}

/// Xvfb with a black root (`-br`, so anything outside the window is 0) and
/// the two monitors.
fn setup(test: &str) -> Option<(xvfb::Xvfb, Monitors)> {
    let x = xvfb::start(test, SCREEN, &["-br"])?;
    let m = Monitors::define(&[OPS, FAC]);
    Some((x, m))
}

fn geometry(m: &MonitorInfo) -> (i32, i32, usize, usize) {
    (m.x, m.y, m.width, m.height)
}

/// Gradient in all three channels (distinct per pixel row/column, offset by
/// `seed` so consecutive frames differ) plus the frame-id block.
fn pattern((w, h): (usize, usize), seed: u32, id: u64) -> Vec<u32> {
    let mut f: Vec<u32> = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let r = (x * 255 / (w - 1)) as u32;
            let g = (y * 255 / (h - 1)) as u32;
            let b = (((x ^ y) as u32) + seed) & 0xff;
            // Never black, so a frame pixel is told from the root background.
            (r << 16) | (g << 8) | b.max(1)
        })
        .collect();
    let code = FrameIdCode::new(true, Corner::TopRight, 24, 4, 8, (w, h)).unwrap();
    code.encode(&mut f, id).unwrap();
    f
}

/// Presents a frame on the window opened with `sel` and checks the root
/// window: the monitor rectangle equals the frame, the rest is black.
fn show_and_check(display: &str, sel: MonitorSelect, seed: u32, id: u64) {
    let (_, x0, y0, w, h, _) = FAC;
    let mut win = xvfb::open_window(&WindowOptions {
        monitor: sel.clone(),
        resolution: Some((w, h)),
        ..WindowOptions::default()
    });
    assert_eq!(win.size(), (w, h), "{sel}");
    assert_eq!(geometry(win.monitor()), (x0, y0, w, h), "{sel}");
    assert_eq!(win.monitor().name, "FAC");
    let frame = pattern((w, h), seed, id);
    win.present(&frame).unwrap();

    let img = xvfb::screenshot_root(display);
    assert_eq!((img.width() as usize, img.height() as usize), SCREEN);
    let (bad, first) = xvfb::diff_rect(&img, (x0 as usize, y0 as usize), (w, h), &frame);
    assert_eq!(
        bad, 0,
        "monitor {sel}: {bad} of the monitor's pixels differ from the frame; \
         first (x, y, got, want) = {first:?}"
    );
    let inside = |x: usize, y: usize| {
        (x0 as usize..x0 as usize + w).contains(&x) && (y0 as usize..y0 as usize + h).contains(&y)
    };
    let spilled: Vec<(u32, u32)> = img
        .enumerate_pixels()
        .filter(|(x, y, p)| !inside(*x as usize, *y as usize) && p.0 != [0, 0, 0])
        .map(|(x, y, _)| (x, y))
        .collect();
    assert!(
        spilled.is_empty(),
        "monitor {sel}: {} non-black pixels outside the monitor, first {:?}",
        spilled.len(),
        spilled.first()
    );
    let code = FrameIdCode::new(true, Corner::TopRight, 24, 4, 8, (w, h)).unwrap();
    let read = code.decode_image(|x, y| {
        img.get_pixel((x0 as usize + x) as u32, (y0 as usize + y) as u32)
            .0[1] as f64
    });
    assert_eq!(read, Ok(id), "frame id read back from the monitor");
}

#[test]
fn frame_covers_exactly_the_chosen_monitor() {
    let _x = xvfb::x_lock();
    let Some((x, mons)) = setup("facility_window_monitors") else {
        return;
    };
    let names = mons.names();
    let fac_index = names.iter().position(|n| n == "FAC").expect("FAC defined");
    assert!(names.iter().any(|n| n == "OPS"), "{names:?}");

    // optistim's list: same order as XRRGetMonitors, the geometry defined.
    let list = x_monitors().unwrap();
    assert_eq!(list.fallback, None);
    let listed: Vec<&str> = list.monitors.iter().map(|m| m.name.as_str()).collect();
    assert_eq!(listed, names);
    for (name, x0, y0, w, h, primary) in [OPS, FAC] {
        let m = list.monitors.iter().find(|m| m.name == name).unwrap();
        assert_eq!(geometry(m), (x0, y0, w, h), "{name}");
        assert_eq!(m.primary, primary, "{name}");
    }

    show_and_check(
        &x.display,
        MonitorSelect::Name("FAC".into()),
        0,
        0x00C0_FFEE,
    );
    show_and_check(&x.display, MonitorSelect::Index(fac_index), 77, 0x0012_3456);
    // FAC is the monitor marked primary.
    show_and_check(
        &x.display,
        MonitorSelect::Name("primary".into()),
        150,
        0x00AB_CDEF,
    );
}

#[test]
fn wrong_resolution_or_unknown_monitor_is_an_error() {
    let _x = xvfb::x_lock();
    let Some((_x, _mons)) = setup("facility_window_monitors") else {
        return;
    };
    let listed = |e: &str| {
        e.contains("\"OPS\" 600×900+0+0") && e.contains("\"FAC\" 1000×700+600+100 (primary)")
    };

    let e = xvfb::open_window_err(
        &WindowOptions {
            monitor: MonitorSelect::Name("FAC".into()),
            resolution: Some((1920, 1080)),
            ..WindowOptions::default()
        },
        |e| e.contains("screen.resolution"),
    );
    assert!(
        e.contains("screen.resolution") && e.contains("1920×1080") && listed(&e),
        "{e}"
    );

    let e = xvfb::open_window_err(
        &WindowOptions {
            monitor: MonitorSelect::Name("HDMI-9".into()),
            resolution: Some((1000, 700)),
            ..WindowOptions::default()
        },
        |e| e.contains("screen.monitor"),
    );
    assert!(
        e.contains("screen.monitor") && e.contains("\"HDMI-9\"") && listed(&e),
        "{e}"
    );

    let e = xvfb::open_window_err(
        &WindowOptions {
            monitor: MonitorSelect::Index(7),
            ..WindowOptions::default()
        },
        |e| e.contains("screen.monitor"),
    );
    assert!(e.contains("no monitor 7") && listed(&e), "{e}");
}
