//! Radiometry: how sunlight reaches a surface point and how much of it is
//! scattered toward the camera.
//!
//! - [`fastmath`]: inverse trigonometry for the per-pixel loop;
//! - [`geometry`]: the photometric angles of one scattering event;
//! - [`lime`]: LIME, the real Moon's disk reflectance, which Moon renders
//!   are compared with;
//! - [`reflectance`]: the reflection models (BRDFs) named in scene files;
//! - [`spectrum`]: solar spectra, detector response tables and band integrals.

pub mod fastmath;
pub mod geometry;
pub mod lime;
pub mod reflectance;
pub mod spectrum;

pub use geometry::ScatteringGeometry;
