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
//! * the size is the native resolution of the chosen X screen
//!   (`XDisplayWidth`/`XDisplayHeight` on a connection of our own);
//! * the window is borderless, 1:1 (`Scale::X1`, `ScaleMode::UpperLeft`),
//!   moved to (0, 0), and `_NET_WM_STATE_FULLSCREEN` and
//!   `_NET_WM_STATE_ABOVE` are requested from the window manager with the
//!   EWMH client message (harmless when there is none, as under Xvfb);
//! * `present` calls `update_with_buffer`, then `XSync` on minifb's own
//!   connection (from its raw display handle), so the image has been
//!   processed by the X server when the presented timestamp is taken. The
//!   panel scans it out at its next refresh; that latency is the monitor's.
//!
//! The X screen must have depth 24 (Xvfb: `-screen 0 WxHx24`; depth 16
//! crashes minifb). minifb connects to `$DISPLAY`, so `monitor` must be
//! that display's default screen (select another with `DISPLAY=:0.1`).

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

/// Options of [`WindowDisplay::open`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct WindowOptions {
    /// X screen number (must be `$DISPLAY`'s default screen).
    pub monitor: usize,
    /// Window title (also how tools find the window).
    pub title: String,
}

impl Default for WindowOptions {
    fn default() -> Self {
        WindowOptions {
            monitor: 0,
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
                std::env::var("DISPLAY").unwrap_or_default()
            )));
        }
        Ok(XConn { xlib, dpy })
    }

    /// Native size of X screen `monitor`, which must be the default screen.
    fn screen_size(&self, monitor: usize) -> Result<(usize, usize)> {
        let x = self.xlib;
        // SAFETY: queries on a live connection.
        unsafe {
            let count = (x.XScreenCount)(self.dpy);
            if monitor as i64 >= count as i64 {
                return Err(Error::invalid(
                    "screen.monitor",
                    format!("X screen {monitor} does not exist ({count} screens)"),
                ));
            }
            let default = (x.XDefaultScreen)(self.dpy) as usize;
            if default != monitor {
                return Err(Error::invalid(
                    "screen.monitor",
                    format!(
                        "X screen {monitor} is not the default screen {default} of $DISPLAY; \
                         run with DISPLAY=<host>:<n>.{monitor}"
                    ),
                ));
            }
            let w = (x.XDisplayWidth)(self.dpy, monitor as i32);
            let h = (x.XDisplayHeight)(self.dpy, monitor as i32);
            Ok((w as usize, h as usize))
        }
    }

    /// Asks the window manager (if any) for full screen and always-on-top,
    /// and moves the window to the screen origin.
    fn request_fullscreen(&self, window: u64, monitor: usize) {
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
            let root = (x.XRootWindow)(dpy, monitor as i32);
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
                root,
                xlib::False,
                xlib::SubstructureRedirectMask | xlib::SubstructureNotifyMask,
                &mut ev,
            );
            (x.XMoveWindow)(dpy, window, 0, 0);
            (x.XRaiseWindow)(dpy, window);
            (x.XSync)(dpy, xlib::False);
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

/// Native resolution of X screen `monitor` on `$DISPLAY`.
pub fn x_screen_size(monitor: usize) -> Result<(usize, usize)> {
    let xlib =
        x11_dl::xlib::Xlib::open().map_err(|e| Error::Other(format!("cannot load libX11: {e}")))?;
    let conn = XConn::open(&xlib)?;
    let size = conn.screen_size(monitor);
    drop(conn);
    size
}

/// Full-screen borderless X11 window (see the module docs).
pub struct WindowDisplay {
    window: minifb::Window,
    xlib: x11_dl::xlib::Xlib,
    /// minifb's own connection (valid while `window` lives).
    dpy: *mut x11_dl::xlib::Display,
    width: usize,
    height: usize,
}

impl std::fmt::Debug for WindowDisplay {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WindowDisplay")
            .field("width", &self.width)
            .field("height", &self.height)
            .finish()
    }
}

impl WindowDisplay {
    /// Opens the full-screen window on `$DISPLAY`.
    pub fn open(opts: &WindowOptions) -> Result<WindowDisplay> {
        use raw_window_handle::{HasDisplayHandle, RawDisplayHandle};
        let xlib = x11_dl::xlib::Xlib::open()
            .map_err(|e| Error::Other(format!("cannot load libX11: {e}")))?;
        // Our connection stays open until minifb's exists: an X server that
        // resets when its last client leaves (Xvfb's default) would
        // otherwise refuse minifb's connection while resetting.
        let own = XConn::open(&xlib)?;
        let (w, h) = own.screen_size(opts.monitor)?;
        let window = minifb::Window::new(
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
        own.request_fullscreen(window.get_window_handle() as u64, opts.monitor);
        drop(own);
        Ok(WindowDisplay {
            window,
            xlib,
            dpy,
            width: w,
            height: h,
        })
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
