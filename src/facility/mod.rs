//! Facility driver: states in, display LUT, screen, serial sync, frame log.
