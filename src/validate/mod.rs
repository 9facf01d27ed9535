//! Validation against real flight images: reading SMART-1 AMIE PDS3 products,
//! rebuilding their geometry from the label, and the image-comparison tools
//! (background removal, NCC alignment, SSIM, comparison figures) used to
//! reproduce the reference paper's validation.
//!
//! | module | owns |
//! |---|---|
//! | [`raster`] | the `f32` image type shared by these tools |
//! | [`pds3`] | PDS3 label parser and attached-image reader |
//! | [`ephem`] | time scales, analytic Sun/Moon ephemerides, IAU Moon rotation |
//! | [`amie`] | AMIE camera model and scene geometry from a label |
//! | [`background`] | AMIE dark level and scattered-light removal |
//! | [`align`] | normalised cross-correlation alignment |
//! | [`ssim`] | structural similarity (Wang et al. 2004) |
//! | [`figure`] | side-by-side comparison PNGs |
//! | [`compare`] | the whole pipeline: render an AMIE image, compare, report |

pub mod align;
pub mod amie;
pub mod background;
pub mod compare;
pub mod ephem;
pub mod figure;
pub mod pds3;
pub mod raster;
pub mod relief_signal;
pub mod ssim;

pub use raster::Raster;
