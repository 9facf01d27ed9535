//! Facility driver: states in, display LUT, screen, serial sync, frame log.
//!
//! | module | owns |
//! |---|---|
//! | [`acceptance`] | the `[acceptance]` rules and a run's verdict |
//! | [`trajectory`] | the [`State`](trajectory::State) type and open-loop CSV trajectories |
//! | [`epoch_trajectory`] | trajectories given by epoch, Sun and Moon from SPICE kernels |
//! | [`udp`] | closed-loop states over UDP (newest wins, stale/malformed counted) |
//! | [`lut`] | display radiance LUT (PCHIP, inverse, SHA-256) and flat field |
//! | [`geometry`] | geometric calibration file (screen pixel → camera direction) and the pre-warp |
//! | [`governor`] | the frame-time governor: render fidelity rungs, their cost and error, the choice per frame |
//! | [`dither`] | target radiance → drive levels in the body's ROI (k, τ, flat field, dithering) |
//! | [`frame_uncertainty`] | a frame's radiometric uncertainty from the LUT's per-level budget |
//! | [`frame_id`] | frame number drawn as a binary block in a corner, and its decoder |
//! | [`display`] | the [`Display`](display::Display) trait, simulated and full-screen X11 displays |
//! | [`serial`] | per-frame sync command over a serial port that never blocks the loop |
//! | [`log`] | write-through JSON-lines frame log and run summary |
//! | [`timing`] | timing figure of a frame log (`optistim plot-log`) |
//! | [`throttle`] | repeated warnings logged once per interval, with a count |
//! | [`config`] | the facility TOML file |
//! | [`driver`] | the real-time loop of `optistim run` tying these together: the screen model, the render thread, the presenter |
//!
//! Per frame, the loop is expected to: take a state ([`udp`] or
//! [`trajectory`]), render the body's ROI, [`dither::Converter::convert`] it
//! into the frame buffer, draw the [`frame_id`] block (after the conversion,
//! which may clear the previous ROI), `present` it, send the sync line, and
//! write the [`log`] record.

pub mod acceptance;
pub mod config;
pub mod display;
pub mod dither;
pub mod driver;
pub mod epoch_trajectory;
pub mod frame_id;
pub mod frame_uncertainty;
pub mod geometry;
pub mod governor;
pub mod log;
pub mod lut;
pub mod serial;
pub mod throttle;
pub mod timing;
pub mod trajectory;
pub mod udp;
