//! Screen output: the [`Display`] trait the render loop presents frames
//! through, an in-memory [`SimDisplay`] for tests and dry runs, and the
//! real full-screen X11 [`WindowDisplay`].
//!
//! Frames are row-major `width × height` `u32` pixels `0x00RRGGBB` (grey
//! drive levels from [`lut::encode_grey`](super::lut::encode_grey)); one
//! frame-buffer pixel is one screen pixel, never scaled.
//!
//! # WindowDisplay on X11
//!
//! minifb has no full-screen API, `WindowOptions::topmost` does nothing on
//! Linux and window positions are wrong without a window manager, so:
//!
//! * the window covers one **monitor** of `$DISPLAY`'s default X screen: a
//!   RandR 1.5 monitor (`XRRGetMonitors`, active ones, in the server's
//!   order), chosen by index or name ([`MonitorSelect`]). Without RandR 1.5
//!   monitors (extension missing, server too old, libXrandr not loadable,
//!   no active monitor) the whole X screen is the only monitor, index 0,
//!   and a warning says so;
//! * its size is that monitor's size, which must equal the requested
//!   resolution (`screen.resolution`);
//! * it is borderless, 1:1 (`Scale::X1`, `ScaleMode::UpperLeft`), moved to
//!   the monitor's origin, and `_NET_WM_STATE_FULLSCREEN` and
//!   `_NET_WM_STATE_ABOVE` are requested from the window manager with the
//!   EWMH client message (harmless when there is none, as under Xvfb);
//! * its position relative to the root window (`XTranslateCoordinates`) and
//!   its size are then checked: a window that did not land exactly on the
//!   monitor is an error, never a silently shifted frame;
//! * `present` calls `update_with_buffer`, then `XSync` on minifb's own
//!   connection (from its raw display handle), so the image has been
//!   processed by the X server when the presented timestamp is taken. The
//!   panel scans it out at its next refresh; that latency is the monitor's.
//!
//! The X screen must have depth 24 (Xvfb: `-screen 0 WxHx24`; depth 16
//! crashes minifb). minifb connects to `$DISPLAY`'s default screen (select
//! another X screen with `DISPLAY=:0.1`).

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::error::{Error, Result};

/// A screen that shows frames.
pub trait Display {
    /// Shows `frame` (`width × height` pixels `0x00RRGGBB`) and returns the
    /// instant it was handed to the display server.
    fn present(&mut self, frame: &[u32]) -> Result<Instant>;
    /// False once the window was closed (or the simulated fault hit).
    fn is_open(&self) -> bool;
    /// `(width, height)` in pixels.
    fn size(&self) -> (usize, usize);
}

fn check_frame(frame: &[u32], (w, h): (usize, usize)) -> Result<()> {
    if frame.len() != w * h {
        return Err(Error::invalid(
            "frame",
            format!("{} pixels for a {w}×{h} display", frame.len()),
        ));
    }
    Ok(())
}

/// Writes a frame as an 8-bit RGB PNG.
pub fn save_png(frame: &[u32], (w, h): (usize, usize), path: impl AsRef<Path>) -> Result<()> {
    let path = path.as_ref();
    check_frame(frame, (w, h))?;
    let mut img = image::RgbImage::new(w as u32, h as u32);
    for (p, &v) in img.pixels_mut().zip(frame) {
        *p = image::Rgb([(v >> 16) as u8, (v >> 8) as u8, v as u8]);
    }
    img.save(path)
        .map_err(|e| Error::parse(path, format!("cannot write PNG: {e}")))
}

/// A presented frame kept by [`SimDisplay`].
#[derive(Debug, Clone, PartialEq)]
pub struct SimFrame {
    /// 0-based index of the `present` call.
    pub index: u64,
    /// Pixels.
    pub pixels: Vec<u32>,
    /// Presented timestamp.
    pub at: Instant,
}

/// In-memory display: records frames (the last `keep`, or all), can dump
/// them as PNG, and can simulate the window being closed.
#[derive(Debug, Clone)]
pub struct SimDisplay {
    width: usize,
    height: usize,
    keep: Option<usize>,
    frames: VecDeque<SimFrame>,
    presented: u64,
    close_after: Option<u64>,
    open: bool,
}

impl SimDisplay {
    /// Keeps the last `keep` frames (0 keeps none).
    pub fn new(width: usize, height: usize, keep: usize) -> SimDisplay {
        SimDisplay {
            width,
            height,
            keep: Some(keep),
            frames: VecDeque::new(),
            presented: 0,
            close_after: None,
            open: true,
        }
    }

    /// Keeps every frame.
    pub fn keep_all(width: usize, height: usize) -> SimDisplay {
        SimDisplay {
            keep: None,
            ..SimDisplay::new(width, height, 0)
        }
    }

    /// Fault injection: the display closes after `n` more successful presents.
    pub fn close_after(mut self, n: u64) -> SimDisplay {
        self.close_after = Some(self.presented + n);
        if n == 0 {
            self.open = false;
        }
        self
    }

    /// Closes now (like a user closing the window).
    pub fn close(&mut self) {
        self.open = false;
    }

    /// Kept frames, oldest first.
    pub fn frames(&self) -> impl Iterator<Item = &SimFrame> {
        self.frames.iter()
    }

    /// The most recent frame.
    pub fn last(&self) -> Option<&SimFrame> {
        self.frames.back()
    }

    /// Successful presents so far.
    pub fn presented(&self) -> u64 {
        self.presented
    }

    /// Writes the kept frames as `frame_<index>.png` into `dir`.
    pub fn dump_png(&self, dir: impl AsRef<Path>) -> Result<Vec<PathBuf>> {
        let dir = dir.as_ref();
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        self.frames
            .iter()
            .map(|f| {
                let p = dir.join(format!("frame_{:06}.png", f.index));
                save_png(&f.pixels, (self.width, self.height), &p)?;
                Ok(p)
            })
            .collect()
    }
}

impl Display for SimDisplay {
    fn present(&mut self, frame: &[u32]) -> Result<Instant> {
        if !self.open {
            return Err(Error::Other("display closed".into()));
        }
        check_frame(frame, (self.width, self.height))?;
        let at = Instant::now();
        if self.keep != Some(0) {
            // Reuse the oldest kept frame's memory once the window is full:
            // a fresh screen-sized allocation per frame costs page faults.
            let recycled = match self.keep {
                Some(k) if self.frames.len() >= k => self.frames.pop_front(),
                _ => None,
            };
            let pixels = match recycled {
                Some(mut old) => {
                    old.pixels.clear();
                    old.pixels.extend_from_slice(frame);
                    old.pixels
                }
                None => frame.to_vec(),
            };
            self.frames.push_back(SimFrame {
                index: self.presented,
                pixels,
                at,
            });
        }
        self.presented += 1;
        if self.close_after == Some(self.presented) {
            self.open = false;
        }
        Ok(at)
    }

    fn is_open(&self) -> bool {
        self.open
    }

    fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }
}

/// Which monitor the window covers (`screen.monitor`): an index into the
/// monitor list ([`x_monitors`]) or a RandR monitor name such as `"DP-1"`.
/// The name `"primary"`, unless a monitor is called so, means the monitor
/// RandR marks primary (the one of the primary output, `xrandr --primary`).
#[derive(Debug, Clone, PartialEq, Eq, serde::Deserialize)]
#[serde(
    untagged,
    expecting = "a monitor index (integer ≥ 0) or a RandR monitor name (string)"
)]
pub enum MonitorSelect {
    /// Position in the list, 0-based.
    Index(usize),
    /// RandR monitor name.
    Name(String),
}

impl Default for MonitorSelect {
    fn default() -> Self {
        MonitorSelect::Index(0)
    }
}

impl std::fmt::Display for MonitorSelect {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            MonitorSelect::Index(i) => write!(f, "{i}"),
            MonitorSelect::Name(n) => write!(f, "{n:?}"),
        }
    }
}

/// One monitor: a rectangle of the X screen, in root-window pixels.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MonitorInfo {
    /// RandR name (`"screen"` for the whole-screen fallback).
    pub name: String,
    /// Origin on the root window.
    pub x: i32,
    /// Origin on the root window.
    pub y: i32,
    /// Pixels.
    pub width: usize,
    /// Pixels.
    pub height: usize,
    /// Marked primary by RandR (always true for the fallback).
    pub primary: bool,
}

impl std::fmt::Display for MonitorInfo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{:?} {}×{}+{}+{}{}",
            self.name,
            self.width,
            self.height,
            self.x,
            self.y,
            if self.primary { " (primary)" } else { "" }
        )
    }
}

/// The monitors of `$DISPLAY`'s default X screen.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MonitorList {
    /// In `XRRGetMonitors` order (active monitors only).
    pub monitors: Vec<MonitorInfo>,
    /// Why RandR monitors were not used, when the list is the whole-screen
    /// fallback.
    pub fallback: Option<String>,
}

impl MonitorList {
    /// `0: "OPS" 600×900+0+0, 1: …`, for error messages.
    pub fn describe(&self) -> String {
        let list: Vec<String> = self
            .monitors
            .iter()
            .enumerate()
            .map(|(i, m)| format!("{i}: {m}"))
            .collect();
        match &self.fallback {
            None => list.join(", "),
            Some(why) => format!("{} (no RandR monitors: {why})", list.join(", ")),
        }
    }

    /// The monitor `sel` names.
    pub fn select(&self, sel: &MonitorSelect) -> Result<&MonitorInfo> {
        let found = match sel {
            MonitorSelect::Index(i) => self.monitors.get(*i),
            MonitorSelect::Name(n) => {
                self.monitors
                    .iter()
                    .find(|m| &m.name == n)
                    .or_else(|| match n.as_str() {
                        "primary" => self.monitors.iter().find(|m| m.primary),
                        _ => None,
                    })
            }
        };
        found.ok_or_else(|| {
            let what = match sel {
                MonitorSelect::Index(i) => format!("there is no monitor {i}"),
                MonitorSelect::Name(n) if n == "primary" => {
                    "no monitor is named or marked \"primary\"".to_string()
                }
                MonitorSelect::Name(n) => format!("there is no monitor named {n:?}"),
            };
            Error::invalid(
                "screen.monitor",
                format!(
                    "{what} on X display {:?}; monitors found: {}",
                    display_name(),
                    self.describe()
                ),
            )
        })
    }
}

fn display_name() -> String {
    std::env::var("DISPLAY").unwrap_or_default()
}

/// Options of [`WindowDisplay::open`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct WindowOptions {
    /// Monitor of `$DISPLAY`'s default X screen.
    pub monitor: MonitorSelect,
    /// Required `(width, height)` (`screen.resolution`): the monitor must
    /// have exactly this size. `None` takes the monitor's size.
    pub resolution: Option<(usize, usize)>,
    /// Window title (also how tools find the window).
    pub title: String,
}

impl Default for WindowOptions {
    fn default() -> Self {
        WindowOptions {
            monitor: MonitorSelect::default(),
            resolution: None,
            title: "optistim".into(),
        }
    }
}

/// An Xlib connection of our own, closed on drop.
struct XConn<'a> {
    xlib: &'a x11_dl::xlib::Xlib,
    dpy: *mut x11_dl::xlib::Display,
}

impl<'a> XConn<'a> {
    fn open(xlib: &'a x11_dl::xlib::Xlib) -> Result<XConn<'a>> {
        // SAFETY: XOpenDisplay with NULL uses $DISPLAY; the result is checked.
        let dpy = unsafe { (xlib.XOpenDisplay)(std::ptr::null()) };
        if dpy.is_null() {
            return Err(Error::Other(format!(
                "cannot open X display {:?}",
                display_name()
            )));
        }
        Ok(XConn { xlib, dpy })
    }

    /// Native size of X screen `screen`, which must be the default screen.
    fn screen_size(&self, screen: usize) -> Result<(usize, usize)> {
        let x = self.xlib;
        // SAFETY: queries on a live connection.
        unsafe {
            let count = (x.XScreenCount)(self.dpy);
            if screen as i64 >= count as i64 {
                return Err(Error::Other(format!(
                    "X screen {screen} does not exist ({count} screens)"
                )));
            }
            let default = (x.XDefaultScreen)(self.dpy) as usize;
            if default != screen {
                return Err(Error::Other(format!(
                    "X screen {screen} is not the default screen {default} of $DISPLAY; \
                     run with DISPLAY=<host>:<n>.{screen}"
                )));
            }
            let w = (x.XDisplayWidth)(self.dpy, screen as i32);
            let h = (x.XDisplayHeight)(self.dpy, screen as i32);
            Ok((w as usize, h as usize))
        }
    }

    fn root(&self) -> x11_dl::xlib::Window {
        // SAFETY: query on a live connection.
        unsafe { (self.xlib.XDefaultRootWindow)(self.dpy) }
    }

    /// RandR 1.5 monitors of the default screen, or why there are none.
    fn randr_monitors(&self) -> std::result::Result<Vec<MonitorInfo>, String> {
        let xrr = x11_dl::xrandr::Xrandr::open()
            .map_err(|e| format!("cannot load libXrandr.so.2: {e}"))?;
        let x = self.xlib;
        // SAFETY: Xlib/Xrandr calls on a live connection; the extension is
        // checked before use, and the monitor array and atom names are read
        // within their counts and freed once.
        unsafe {
            let (mut ev, mut err) = (0, 0);
            if (xrr.XRRQueryExtension)(self.dpy, &mut ev, &mut err) == 0 {
                return Err("the X server has no RandR extension".into());
            }
            let (mut major, mut minor) = (0, 0);
            if (xrr.XRRQueryVersion)(self.dpy, &mut major, &mut minor) == 0 {
                return Err("RandR version query failed".into());
            }
            if (major, minor) < (1, 5) {
                return Err(format!("the X server has RandR {major}.{minor} < 1.5"));
            }
            let mut n = 0;
            let mons = (xrr.XRRGetMonitors)(self.dpy, self.root(), x11_dl::xlib::True, &mut n);
            if mons.is_null() {
                return Err("XRRGetMonitors failed".into());
            }
            let list = std::slice::from_raw_parts(mons, n.max(0) as usize)
                .iter()
                .enumerate()
                .map(|(i, m)| {
                    let p = (x.XGetAtomName)(self.dpy, m.name);
                    let name = if p.is_null() {
                        format!("monitor{i}")
                    } else {
                        let s = std::ffi::CStr::from_ptr(p).to_string_lossy().into_owned();
                        (x.XFree)(p as *mut _);
                        s
                    };
                    MonitorInfo {
                        name,
                        x: m.x,
                        y: m.y,
                        width: m.width.max(0) as usize,
                        height: m.height.max(0) as usize,
                        primary: m.primary != 0,
                    }
                })
                .collect();
            (xrr.XRRFreeMonitors)(mons);
            Ok(list)
        }
    }

    /// RandR monitors, or the whole default screen as monitor 0.
    fn monitors(&self) -> Result<MonitorList> {
        let why = match self.randr_monitors() {
            Ok(list) if !list.is_empty() => {
                return Ok(MonitorList {
                    monitors: list,
                    fallback: None,
                })
            }
            Ok(_) => "RandR reports no active monitor".to_string(),
            Err(why) => why,
        };
        // SAFETY: query on a live connection.
        let screen = unsafe { (self.xlib.XDefaultScreen)(self.dpy) } as usize;
        let (width, height) = self.screen_size(screen)?;
        Ok(MonitorList {
            monitors: vec![MonitorInfo {
                name: "screen".into(),
                x: 0,
                y: 0,
                width,
                height,
                primary: true,
            }],
            fallback: Some(why),
        })
    }

    /// Asks the window manager (if any) for full screen and always-on-top.
    fn request_fullscreen(&self, window: u64) {
        use x11_dl::xlib;
        let x = self.xlib;
        let dpy = self.dpy;
        // SAFETY: Xlib calls on a live connection; the event is zero-initialised
        // and every field the protocol reads is set.
        unsafe {
            let atom = |name: &[u8]| (x.XInternAtom)(dpy, name.as_ptr() as *const _, xlib::False);
            let state = atom(b"_NET_WM_STATE\0");
            let full = atom(b"_NET_WM_STATE_FULLSCREEN\0");
            let above = atom(b"_NET_WM_STATE_ABOVE\0");
            let mut ev: xlib::XEvent = std::mem::zeroed();
            ev.client_message.type_ = xlib::ClientMessage;
            ev.client_message.window = window;
            ev.client_message.message_type = state;
            ev.client_message.format = 32;
            let l = ev.client_message.data.as_longs_mut();
            l[0] = 1; // _NET_WM_STATE_ADD
            l[1] = full as _;
            l[2] = above as _;
            l[3] = 1; // source: normal application
            (x.XSendEvent)(
                dpy,
                self.root(),
                xlib::False,
                xlib::SubstructureRedirectMask | xlib::SubstructureNotifyMask,
                &mut ev,
            );
            (x.XRaiseWindow)(dpy, window);
            (x.XSync)(dpy, xlib::False);
        }
    }

    /// Root-window position of the window's top-left pixel and its size.
    fn placement(&self, window: u64) -> Option<(i32, i32, usize, usize)> {
        use x11_dl::xlib;
        let x = self.xlib;
        // SAFETY: queries on a live connection; the outputs are locals.
        unsafe {
            (x.XSync)(self.dpy, xlib::False);
            let (mut rx, mut ry, mut child) = (0, 0, 0);
            let ok = (x.XTranslateCoordinates)(
                self.dpy,
                window,
                self.root(),
                0,
                0,
                &mut rx,
                &mut ry,
                &mut child,
            );
            let mut attr: xlib::XWindowAttributes = std::mem::zeroed();
            if ok == 0 || (x.XGetWindowAttributes)(self.dpy, window, &mut attr) == 0 {
                return None;
            }
            Some((rx, ry, attr.width as usize, attr.height as usize))
        }
    }

    /// Waits (a window manager acts asynchronously) until the window covers
    /// exactly `mon`, or fails.
    fn check_placement(&self, window: u64, mon: &MonitorInfo) -> Result<()> {
        let want = (mon.x, mon.y, mon.width, mon.height);
        let end = Instant::now() + std::time::Duration::from_secs(2);
        loop {
            let got = self.placement(window);
            if got == Some(want) {
                return Ok(());
            }
            if Instant::now() >= end {
                let got = got.map_or("unknown".into(), |(x, y, w, h)| format!("{w}×{h}+{x}+{y}"));
                return Err(Error::Other(format!(
                    "the window did not land on monitor {mon} (screen.monitor): it is at {got} \
                     on the root window; a window manager may have moved it"
                )));
            }
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
    }
}

impl Drop for XConn<'_> {
    fn drop(&mut self) {
        // SAFETY: closing the connection we opened.
        unsafe {
            (self.xlib.XCloseDisplay)(self.dpy);
        }
    }
}

fn load_xlib() -> Result<x11_dl::xlib::Xlib> {
    x11_dl::xlib::Xlib::open().map_err(|e| Error::Other(format!("cannot load libX11: {e}")))
}

/// The monitors of `$DISPLAY`'s default X screen, as [`WindowDisplay`]
/// numbers them.
pub fn x_monitors() -> Result<MonitorList> {
    let xlib = load_xlib()?;
    let conn = XConn::open(&xlib)?;
    let list = conn.monitors();
    drop(conn);
    list
}

/// Full-screen borderless X11 window on one monitor (see the module docs).
pub struct WindowDisplay {
    window: minifb::Window,
    xlib: x11_dl::xlib::Xlib,
    /// minifb's own connection (valid while `window` lives).
    dpy: *mut x11_dl::xlib::Display,
    monitor: MonitorInfo,
    width: usize,
    height: usize,
}

impl std::fmt::Debug for WindowDisplay {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WindowDisplay")
            .field("monitor", &self.monitor)
            .field("width", &self.width)
            .field("height", &self.height)
            .finish()
    }
}

impl WindowDisplay {
    /// Opens the full-screen window on the chosen monitor of `$DISPLAY`.
    pub fn open(opts: &WindowOptions) -> Result<WindowDisplay> {
        use raw_window_handle::{HasDisplayHandle, RawDisplayHandle};
        let xlib = load_xlib()?;
        // Our connection stays open until minifb's exists: an X server that
        // resets when its last client leaves (Xvfb's default) would
        // otherwise refuse minifb's connection while resetting.
        let own = XConn::open(&xlib)?;
        let list = own.monitors()?;
        if let Some(why) = &list.fallback {
            tracing::warn!(
                "no RandR 1.5 monitors ({why}): the whole X screen is monitor 0, {}",
                list.monitors[0]
            );
        }
        let mon = list.select(&opts.monitor)?.clone();
        let (w, h) = (mon.width, mon.height);
        if let Some((rw, rh)) = opts.resolution {
            if (rw, rh) != (w, h) {
                return Err(Error::invalid(
                    "screen.resolution",
                    format!(
                        "{rw}×{rh}, but screen.monitor = {} is monitor {mon}; monitors found: {}",
                        opts.monitor,
                        list.describe()
                    ),
                ));
            }
        }
        let mut window = minifb::Window::new(
            &opts.title,
            w,
            h,
            minifb::WindowOptions {
                borderless: true,
                title: false,
                resize: false,
                scale: minifb::Scale::X1,
                scale_mode: minifb::ScaleMode::UpperLeft,
                topmost: true,
                ..Default::default()
            },
        )
        .map_err(|e| Error::Other(format!("cannot create the {w}×{h} window: {e:?}")))?;
        let dpy = match window.display_handle().map(|d| d.as_raw()) {
            Ok(RawDisplayHandle::Xlib(x)) => x
                .display
                .map(|p| p.as_ptr() as *mut x11_dl::xlib::Display)
                .ok_or_else(|| Error::Other("minifb gave no Xlib display".into()))?,
            _ => return Err(Error::Other("minifb window is not an Xlib window".into())),
        };
        // Move before the full-screen request: a window manager makes a
        // window full screen on the monitor it is on.
        window.set_position(mon.x as isize, mon.y as isize);
        // SAFETY: `dpy` is minifb's live connection, used on this thread.
        unsafe {
            (xlib.XSync)(dpy, x11_dl::xlib::False);
        }
        let handle = window.get_window_handle() as u64;
        own.request_fullscreen(handle);
        own.check_placement(handle, &mon)?;
        drop(own);
        tracing::info!("display window on monitor {mon}");
        Ok(WindowDisplay {
            window,
            xlib,
            dpy,
            monitor: mon,
            width: w,
            height: h,
        })
    }

    /// The monitor the window covers.
    pub fn monitor(&self) -> &MonitorInfo {
        &self.monitor
    }
}

impl Display for WindowDisplay {
    fn present(&mut self, frame: &[u32]) -> Result<Instant> {
        check_frame(frame, (self.width, self.height))?;
        if !self.window.is_open() {
            return Err(Error::Other("display window closed".into()));
        }
        self.window
            .update_with_buffer(frame, self.width, self.height)
            .map_err(|e| Error::Other(format!("present failed: {e}")))?;
        // SAFETY: `dpy` is minifb's live connection, used on this thread.
        unsafe {
            (self.xlib.XSync)(self.dpy, x11_dl::xlib::False);
        }
        Ok(Instant::now())
    }

    fn is_open(&self) -> bool {
        self.window.is_open()
    }

    fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sim_keeps_last_n_and_closes_on_fault() {
        let mut d = SimDisplay::new(3, 2, 2).close_after(3);
        for v in 0..3u32 {
            let t = d.present(&[v; 6]).unwrap();
            assert!(t <= Instant::now());
        }
        assert!(!d.is_open());
        assert!(d.present(&[0; 6]).is_err());
        let kept: Vec<(u64, u32)> = d.frames().map(|f| (f.index, f.pixels[0])).collect();
        assert_eq!(kept, vec![(1, 1), (2, 2)]);
        assert_eq!(d.presented(), 3);
        let mut e = SimDisplay::keep_all(3, 2);
        assert!(e.present(&[0; 5]).is_err(), "wrong size rejected");
        for _ in 0..5 {
            e.present(&[0; 6]).unwrap();
        }
        assert_eq!(e.frames().count(), 5);
    }

    #[test]
    fn monitor_selection_by_index_name_and_primary() {
        let mon = |name: &str, x, primary| MonitorInfo {
            name: name.into(),
            x,
            y: 0,
            width: 800,
            height: 600,
            primary,
        };
        let list = MonitorList {
            monitors: vec![mon("OPS", 0, false), mon("DP-1", 800, true)],
            fallback: None,
        };
        let pick = |s: MonitorSelect| list.select(&s).map(|m| m.name.clone());
        assert_eq!(pick(MonitorSelect::Index(0)).unwrap(), "OPS");
        assert_eq!(pick(MonitorSelect::Index(1)).unwrap(), "DP-1");
        assert_eq!(pick(MonitorSelect::Name("DP-1".into())).unwrap(), "DP-1");
        assert_eq!(pick(MonitorSelect::Name("primary".into())).unwrap(), "DP-1");
        let e = pick(MonitorSelect::Name("HDMI-1".into()))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("screen.monitor")
                && e.contains("\"HDMI-1\"")
                && e.contains("0: \"OPS\" 800×600+0+0, 1: \"DP-1\" 800×600+800+0 (primary)"),
            "{e}"
        );
        assert!(pick(MonitorSelect::Index(2)).is_err());
        // A monitor really named "primary" wins over the flag.
        let named = MonitorList {
            monitors: vec![mon("A", 0, true), mon("primary", 800, false)],
            fallback: None,
        };
        let p = named
            .select(&MonitorSelect::Name("primary".into()))
            .unwrap();
        assert_eq!(p.x, 800);
        let none = MonitorList {
            monitors: vec![mon("A", 0, false)],
            fallback: None,
        };
        assert!(none.select(&MonitorSelect::Name("primary".into())).is_err());
    }

    #[test]
    fn sim_dumps_png_with_exact_pixels() {
        let dir = tempfile::tempdir().unwrap();
        let mut d = SimDisplay::keep_all(4, 3);
        let frame: Vec<u32> = (0..12)
            .map(|i| 0x0010_2030 * (i + 1))
            .map(|v| v & 0x00FF_FFFF)
            .collect();
        d.present(&frame).unwrap();
        let paths = d.dump_png(dir.path()).unwrap();
        assert_eq!(paths.len(), 1);
        let img = image::open(&paths[0]).unwrap().to_rgb8();
        for (i, p) in img.pixels().enumerate() {
            let v = frame[i];
            assert_eq!(p.0, [(v >> 16) as u8, (v >> 8) as u8, v as u8]);
        }
    }
}
