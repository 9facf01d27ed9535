//! # optistim
//!
//! A radiometrically exact renderer of planets and moons, and the driver of a
//! hardware-in-the-loop optical facility for vision-based navigation.
//!
//! The modules follow the data flow of one frame:
//!
//! | module | owns |
//! |---|---|
//! | [`scene`] | what is out there: camera, body, Sun, poses; the TOML scene file |
//! | [`ephemeris`] | epochs → Sun and Moon positions and the Moon's orientation, from SPICE kernels |
//! | [`radiometry`] | how light is made and reflected: solar spectra, reflectance models, band integrals |
//! | [`render_settings`] | the renderer's settings (the `[render]` table), read by the scene file, the renderer and the governor |
//! | [`render`] | the paper's method: surface caps, their power coefficients PF_i, gridding onto pixels, the detector chain |
//! | [`facility`] | the real-time loop: states in, display LUT, screen, serial sync, frame log |
//! | [`instruments`] | the calibration's spot meter and camera, real and simulated, behind traits |
//! | [`calibration`] | `optistim calibrate`: the screen's LUT, flat field, geometry and verification, measured through the instruments |
//! | [`simfacility`] | a seeded physics model of screen, collimator, camera and spot meter: the truth to rehearse calibration and `run` on |
//! | [`utc`] | UTC calendar stamps for reports and run directories |
//! | [`validate`] | comparison with real flight images (PDS3/AMIE, SSIM) |
//! | [`figures`] | small PNG figures for reports: curves with residuals, heatmaps, quivers |
//!
//! Support modules: [`error`] (the error type), [`infile`] (size-bounded
//! input reads), [`outfile`] (outputs that never clobber), [`progress`]
//! (progress bars, only on a terminal), [`memo`] (per-camera tables built
//! once per process), [`fuzzing`]
//! (every parser behind one entry point, for the property tests and the
//! long-run fuzz harness).
//!
//! Conventions (SI units, OpenCV camera frame, scalar-first quaternions,
//! pixel centres at +0.5) are described in `docs/CONVENTIONS.md`.

// `!(x > 0.0)` is used on purpose: it is also true for NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod calibration;
pub mod dataset;
pub mod ephemeris;
pub mod error;
pub mod expose;
pub mod facility;
pub mod fidelity;
pub mod figures;
pub mod fuzzing;
pub mod infile;
pub mod instruments;
pub mod labels;
pub mod memo;
pub mod optics;
pub mod outfile;
pub mod placeholders;
pub mod planner;
pub mod progress;
pub mod radiometry;
pub mod render;
pub mod render_settings;
pub mod scene;
pub mod sensor;
pub mod simfacility;
pub mod stars;
pub mod utc;
pub mod validate;

pub use error::{Error, Result};

/// `n` copies of `value` with every page resident: written once here, so
/// a real-time loop never takes a first-touch page fault in it (a
/// zero-filled allocation is mapped lazily, page by page, as it is first
/// written, which made the facility's memory creep while the body drifted
/// over untouched parts of the screen).
pub fn resident_vec<T: Copy>(value: T, n: usize) -> Vec<T> {
    let mut v = Vec::with_capacity(n);
    advise_huge_pages(&v);
    // Opaque to the optimiser: the writes below cannot become a lazily
    // mapped zeroed allocation.
    std::hint::black_box(&mut v);
    v.resize(n, value);
    v
}

/// Ask the kernel to back `v`'s allocation with 2 MiB pages where it can:
/// a footprint's texture reads jump between map rows (8 KiB apart for a
/// 2k map), so with 4 KiB pages a frame touches thousands of pages. The
/// gain measured on the benchmark machine (~5 %) was within its noise.
fn advise_huge_pages<T>(v: &Vec<T>) {
    #[cfg(target_os = "linux")]
    {
        const HUGE: usize = 2 << 20;
        let bytes = v.capacity() * std::mem::size_of::<T>();
        let start = v.as_ptr() as usize;
        let aligned = start.div_ceil(HUGE) * HUGE;
        let end = (start + bytes) / HUGE * HUGE;
        if end > aligned {
            // SAFETY: the range lies inside `v`'s allocation; the advice
            // changes only how it is backed, never its contents.
            unsafe {
                libc::madvise(
                    aligned as *mut libc::c_void,
                    end - aligned,
                    libc::MADV_HUGEPAGE,
                );
            }
        }
    }
}
