//! Screen calibration routines, after the facility on the data flow: they
//! drive the screen and read the instruments to produce the files `run`
//! reads (display LUT, flat field, geometry).

pub mod geometric;
