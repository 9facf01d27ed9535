//! Validation against real flight images.
