//! Measuring instruments of a screen calibration, behind one trait per seam
//! with real and simulated implementations side by side (as
//! [`Display`](crate::facility::display::Display) and
//! [`SyncPort`](crate::facility::serial::SyncPort) are):
//!
//! | trait | real | simulated |
//! |---|---|---|
//! | [`SpotMeter`] | a photometer, radiometer or spectroradiometer on a serial port, speaking a configurable line protocol | the simulated facility's meter (in process, or over a pseudo-terminal) |
//! | [`Camera`] | the facility camera, through its acquisition software (`files`) or a capture command (`command`) | the simulated facility's camera |
//!
//! | module | owns |
//! |---|---|
//! | [`config`] | the `[calibrate.meter]` / `[calibrate.camera]` tables, their checks, `open_spot_meter` / `open_camera` for the real kinds |
//! | [`spot_meter`] | the serial meter and its line protocol (also spoken by the simulated meter) |
//! | [`camera`] | the `files` and `command` backends |
//! | [`frame`] | frame files (PNG, TIFF, FITS) and the statistics a calibration takes of frames |
//! | [`intrinsics`] | the camera intrinsics file (OpenCV K and distortion), pixel ↔ direction |
//!
//! The keys, the reply spec and the formats are described in
//! docs/INSTRUMENTS.md.
//!
//! Units: a spot meter reading is the instrument's value times its
//! configured unit scale (for a radiometer, W m⁻² sr⁻¹ in its own band); a
//! spectrum is W m⁻² sr⁻¹ nm⁻¹ against wavelength in nm. Camera frames are in
//! DN as the camera delivers them, before any dark subtraction.

use crate::error::Result;

pub mod camera;
pub mod config;
pub mod frame;
pub mod intrinsics;
pub mod spot_meter;

/// One spot-meter measurement.
#[derive(Debug, Clone, PartialEq)]
pub struct SpotReading {
    /// The scalar reading, in the meter's configured unit after its scale
    /// (a spectroradiometer gives the integral of its spectrum here).
    pub value: f64,
    /// A spectroradiometer's spectrum: `(wavelength_nm, W m⁻² sr⁻¹ nm⁻¹)`,
    /// wavelengths strictly increasing. `None` for a scalar instrument.
    pub spectrum: Option<Vec<(f64, f64)>>,
}

/// An instrument that measures the screen's radiance in a spot.
pub trait SpotMeter: Send {
    /// Takes one reading of whatever the screen shows now (after the
    /// instrument's own settle time). Errors name the instrument and say
    /// what went wrong (timeout, malformed reply, unplugged).
    fn measure(&mut self) -> Result<SpotReading>;
    /// One line naming the instrument (model, port, protocol) for the
    /// calibration files' provenance.
    fn describe(&self) -> String;
}

/// Whether light reaches the detector during a capture.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Shutter {
    /// A normal frame of what the screen shows.
    #[default]
    Open,
    /// A dark frame: no light on the detector (shutter closed, camera
    /// capped), bias and dark current only, at the request's exposure.
    Closed,
}

/// What the calibration asks the camera for.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct CaptureRequest {
    /// Pattern name, unique within a campaign (e.g. `level_0128_r1`): the
    /// `files` backend waits for a file of this name, errors quote it.
    pub pattern: String,
    /// Exposure time, s.
    pub exposure_s: f64,
    /// Open for a frame of the screen, closed for a dark frame.
    pub shutter: Shutter,
}

impl CaptureRequest {
    /// A frame of what the screen shows.
    pub fn light(pattern: impl Into<String>, exposure_s: f64) -> CaptureRequest {
        CaptureRequest {
            pattern: pattern.into(),
            exposure_s,
            shutter: Shutter::Open,
        }
    }

    /// A dark frame (no light on the detector) at this exposure.
    pub fn dark(pattern: impl Into<String>, exposure_s: f64) -> CaptureRequest {
        CaptureRequest {
            pattern: pattern.into(),
            exposure_s,
            shutter: Shutter::Closed,
        }
    }
}

/// One frame from the camera, in DN, row-major, top row first.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraFrame {
    pub width: usize,
    pub height: usize,
    /// DN per pixel as delivered (no dark subtraction).
    pub data: Vec<f32>,
    /// Exposure the frame was taken with, s.
    pub exposure_s: f64,
    /// DN at or above which a pixel is saturated.
    pub saturation_dn: f32,
}

/// The facility camera, looking at the screen through the collimator.
pub trait Camera: Send {
    /// Takes one frame of what the screen shows now.
    fn capture(&mut self, request: &CaptureRequest) -> Result<CameraFrame>;
    /// One line naming the camera and backend for provenance.
    fn describe(&self) -> String;
}
