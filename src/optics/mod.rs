//! The camera's optics between the scene's radiance and the sensor: the
//! point spread function ([`psf`]) and the lens distortion applied to an
//! ideal pinhole image ([`distortion`]). Both act on images the renderer
//! has already made, so the radiometry stays the renderer's and these only
//! move light between pixels.

pub mod distortion;
pub mod lens_table;
pub mod psf;
