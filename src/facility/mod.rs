//! Facility driver: states in, display LUT, screen, serial sync, frame log.

pub mod trajectory;
pub mod udp;
