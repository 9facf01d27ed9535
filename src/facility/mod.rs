//! Facility driver: states in, display LUT, screen, serial sync, frame log.

pub mod config;
pub mod display;
pub mod dither;
pub mod frame_id;
pub mod log;
pub mod lut;
pub mod serial;
pub mod trajectory;
pub mod udp;
