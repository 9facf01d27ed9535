//! Counter-based random numbers for the simulated facility: the detector
//! models' generator (`crate::sensor::rng`), re-exported under its old path.

pub use crate::sensor::rng::Rng;
