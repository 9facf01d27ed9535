//! The simulated spot meter served over a real pseudo-terminal: a thread on
//! the master end answers every command with the simulated facility's
//! reading in the reply format of a `[calibrate.meter]` table
//! ([`serve`]), so a campaign on the simulated facility runs the real
//! [`SerialSpotMeter`](crate::instruments::spot_meter::SerialSpotMeter)
//! (settle, timeout, retries, parsing) against it. The meter opens
//! [`PtyMeter::path`], the slave's device name.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;

use serialport::{SerialPort, TTYPort};

use super::SimFacility;
use crate::error::{Error, Result};
use crate::instruments::config::{MeterKind, ReplySpec, SpotMeterConfig};
use crate::instruments::spot_meter::serve;

/// The serving thread and the pty pair. Stops and joins on drop.
pub struct PtyMeter {
    path: PathBuf,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<std::io::Result<()>>>,
    /// Kept open so the slave end stays valid between the meter's opens.
    _slave: TTYPort,
}

impl PtyMeter {
    /// Starts serving `facility`'s meter: each time the bytes received end
    /// with `command`, the reply to one reading is sent, its value (and
    /// spectrum) divided by `unit_scale` (the real meter multiplies it
    /// back).
    pub fn start(
        facility: &SimFacility,
        command: &str,
        reply: &ReplySpec,
        unit_scale: f64,
    ) -> Result<PtyMeter> {
        if command.is_empty() {
            return Err(Error::invalid("command", "is empty"));
        }
        if !(unit_scale.is_finite() && unit_scale != 0.0) {
            return Err(Error::invalid("unit_scale", "must be finite and non-zero"));
        }
        let (mut master, slave) = TTYPort::pair()
            .map_err(|e| Error::Other(format!("simulated meter: no pseudo-terminal: {e}")))?;
        let path = slave
            .name()
            .map(PathBuf::from)
            .ok_or_else(|| Error::Other("simulated meter: the pty slave has no name".into()))?;
        let stop = Arc::new(AtomicBool::new(false));
        let facility = facility.clone();
        let (command, reply, flag) = (command.to_string(), reply.clone(), stop.clone());
        let thread = std::thread::Builder::new()
            .name("sim-meter-pty".into())
            .spawn(move || {
                serve(&mut master, &command, &reply, &flag, || {
                    facility.read_meter().scaled(1.0 / unit_scale)
                })
            })
            .map_err(|e| Error::Other(format!("simulated meter: cannot start thread: {e}")))?;
        Ok(PtyMeter {
            path,
            stop,
            thread: Some(thread),
            _slave: slave,
        })
    }

    /// Serves the meter a `[calibrate.meter]` table describes (its command,
    /// reply format and unit scale) and returns that table turned into a
    /// serial meter on the pty (`kind = "serial"`, `port` = the slave), to
    /// open with [`open_spot_meter`](crate::instruments::config::open_spot_meter).
    pub fn for_config(
        facility: &SimFacility,
        meter: &SpotMeterConfig,
    ) -> Result<(PtyMeter, SpotMeterConfig)> {
        let pty = PtyMeter::start(facility, &meter.command, &meter.reply, meter.unit_scale)?;
        let mut serial = meter.clone();
        serial.kind = MeterKind::Serial;
        serial.port = Some(pty.path.clone());
        Ok((pty, serial))
    }

    /// The device to open as the meter's `port`.
    pub fn path(&self) -> &std::path::Path {
        &self.path
    }

    /// Stops the thread; returns its I/O error, if it failed.
    pub fn stop(mut self) -> Result<()> {
        self.join()
    }

    fn join(&mut self) -> Result<()> {
        self.stop.store(true, Ordering::Relaxed);
        match self.thread.take().map(|t| t.join()) {
            Some(Ok(Err(e))) => Err(Error::Other(format!("simulated meter pty: {e}"))),
            Some(Err(_)) => Err(Error::Other("simulated meter pty thread panicked".into())),
            _ => Ok(()),
        }
    }
}

impl Drop for PtyMeter {
    fn drop(&mut self) {
        let _ = self.join();
    }
}
