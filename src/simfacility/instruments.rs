//! The simulated facility's screen and camera held together with its
//! virtual clock, lent to a calibration routine as its [`Instruments`]
//! (the wait after each patch advances the clock instead of sleeping).

use crate::calibration::dark::DarkBank;
use crate::calibration::Instruments;
use crate::instruments::SpotMeter;

use super::{SimCamera, SimFacility, SimScreen};

/// The simulated screen, camera and clock of one facility.
pub struct SimInstruments {
    display: SimScreen,
    camera: SimCamera,
    wait: Box<dyn FnMut(f64)>,
}

impl SimInstruments {
    /// Handles on `sim`'s screen and camera, and a wait that advances its
    /// clock.
    pub fn new(sim: &SimFacility) -> Self {
        let clock = sim.clone();
        SimInstruments {
            display: sim.display(),
            camera: sim.camera(),
            wait: Box::new(move |s| clock.advance(s)),
        }
    }

    /// The routine's instruments: these, `meter` (none for a routine
    /// without one, such as the flat field) and the campaign's `darks`.
    pub fn lend<'a>(
        &'a mut self,
        meter: Option<&'a mut dyn SpotMeter>,
        darks: &'a mut DarkBank,
    ) -> Instruments<'a> {
        Instruments {
            display: &mut self.display,
            camera: &mut self.camera,
            meter,
            darks,
            wait: self.wait.as_mut(),
        }
    }
}
