//! The real spot meter: a photometer, radiometer or spectroradiometer on a
//! serial port, speaking the line protocol of its `[calibrate.meter]` table;
//! and the protocol itself ([`parse_reply`], [`reply_complete`],
//! [`format_reply`], [`serve`]) shared with the simulated meter, which speaks
//! it over a pseudo-terminal.
//!
//! # One reading
//!
//! 1. wait `settle` (the screen and the instrument settle after a change);
//! 2. discard stale input, send `command`;
//! 3. read until the reply is complete ([`reply_complete`]) or `timeout`;
//! 4. parse it ([`parse_reply`]) and scale by `unit_scale`.
//!
//! A timeout or a malformed reply is retried up to `retries` times. After a
//! timeout the retry first discards whatever arrives during one more
//! `timeout` (the late reply of the abandoned command), so a slow reply is
//! not taken for the retry's; so does the next reading after one that
//! failed by a timeout. A read or write error (the adapter unplugged)
//! closes the port and fails this reading; the next reading re-opens the
//! port's path.

use std::io::{Read, Write};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use serialport::{ClearBuffer, SerialPort};

use super::config::{abbreviate, ReplyFormat, ReplySpec, SpotMeterConfig};
use super::{SpotMeter, SpotReading};
use crate::error::{Error, Result};

/// Longest reply accepted, bytes: beyond it the reply is garbage.
pub const MAX_REPLY_BYTES: usize = 1 << 20;
/// Most spectrum records in one reply.
pub const MAX_SPECTRUM_POINTS: usize = 100_000;
/// Longest reply quoted in an error, characters.
const QUOTE: usize = 80;

/// Parses a complete reply into the instrument's own values (not yet
/// multiplied by `unit_scale`; see [`SpotReading::scaled`]). Errors are
/// one line saying what is wrong, quoting at most 80 characters of the
/// reply.
pub fn parse_reply(spec: &ReplySpec, reply: &str) -> Result<SpotReading> {
    let body = reply.trim_start();
    if let Some(ep) = &spec.error_prefix {
        if body.starts_with(ep.as_str()) {
            return Err(malformed("the instrument reports an error", reply));
        }
    }
    let Some(rest) = body.strip_prefix(spec.prefix.as_str()) else {
        return Err(malformed(
            &format!("expected the reply to start with `{}`", spec.prefix),
            reply,
        ));
    };
    match spec.format {
        ReplyFormat::Scalar => parse_scalar(spec, rest, reply),
        ReplyFormat::Spectrum => parse_spectrum(spec, rest, reply),
    }
}

fn malformed(what: &str, reply: &str) -> Error {
    Error::Other(format!(
        "malformed reply: {what}; reply `{}`",
        abbreviate(reply, QUOTE)
    ))
}

fn parse_number(token: &str) -> Option<f64> {
    let v: f64 = token.parse().ok()?;
    v.is_finite().then_some(v)
}

fn parse_scalar(spec: &ReplySpec, rest: &str, reply: &str) -> Result<SpotReading> {
    let line = rest.split(['\r', '\n']).next().unwrap_or("");
    let token = line
        .split(|c: char| c.is_whitespace() || c == ',' || c == ';')
        .filter(|t| !t.is_empty())
        .nth(spec.field);
    let Some(token) = token else {
        return Err(malformed(
            &format!("no field {} after the prefix", spec.field),
            reply,
        ));
    };
    let Some(value) = parse_number(token) else {
        return Err(malformed(
            &format!("field {} is not a finite number", spec.field),
            reply,
        ));
    };
    Ok(SpotReading {
        value,
        spectrum: None,
    })
}

fn parse_spectrum(spec: &ReplySpec, rest: &str, reply: &str) -> Result<SpotReading> {
    let end = spec.end.as_deref().unwrap_or("");
    let mut points: Vec<(f64, f64)> = Vec::new();
    let mut ended = false;
    for line in rest.split(['\r', '\n']) {
        if line.trim() == end {
            ended = true;
            break;
        }
        for record in line.split(';').map(str::trim).filter(|r| !r.is_empty()) {
            if points.len() == MAX_SPECTRUM_POINTS {
                return Err(malformed(
                    &format!("more than {MAX_SPECTRUM_POINTS} records"),
                    reply,
                ));
            }
            let (w, v) = parse_pair(spec, record, points.len(), reply)?;
            if points.last().is_some_and(|p| p.0 >= w) {
                return Err(malformed(
                    &format!(
                        "record {}: wavelengths must increase strictly",
                        points.len()
                    ),
                    reply,
                ));
            }
            points.push((w, v));
        }
    }
    if !ended {
        return Err(malformed(&format!("no terminator line `{end}`"), reply));
    }
    if points.len() < 2 {
        return Err(malformed("a spectrum needs at least two records", reply));
    }
    Ok(SpotReading {
        value: trapezoid(&points),
        spectrum: Some(points),
    })
}

fn parse_pair(spec: &ReplySpec, record: &str, index: usize, reply: &str) -> Result<(f64, f64)> {
    let bad = |what: &str| {
        malformed(
            &format!("record {index} `{}`: {what}", abbreviate(record, 24)),
            reply,
        )
    };
    let Some((w, v)) = record.split_once(spec.pair_separator.as_str()) else {
        return Err(bad(&format!(
            "expected `wavelength{}value`",
            spec.pair_separator
        )));
    };
    let (Some(w), Some(v)) = (parse_number(w.trim()), parse_number(v.trim())) else {
        return Err(bad("not two finite numbers"));
    };
    if !(w > 0.0 && w < 1e6) {
        return Err(bad("wavelength must be in (0, 1e6) nm"));
    }
    Ok((w, v))
}

fn trapezoid(points: &[(f64, f64)]) -> f64 {
    points
        .windows(2)
        .map(|p| 0.5 * (p[0].1 + p[1].1) * (p[1].0 - p[0].0))
        .sum()
}

/// Whether `received` holds a whole reply: for a scalar, a line end after
/// some text; for a spectrum, a line equal to the terminator. An error
/// reply (`error_prefix`) is complete at its first line end.
pub fn reply_complete(spec: &ReplySpec, received: &str) -> bool {
    let body = received.trim_start();
    let first_line_done = body.contains(['\r', '\n']);
    let is_error = spec
        .error_prefix
        .as_deref()
        .is_some_and(|p| body.starts_with(p));
    match spec.format {
        ReplyFormat::Scalar => first_line_done,
        ReplyFormat::Spectrum if is_error => first_line_done,
        ReplyFormat::Spectrum => {
            let end = spec.end.as_deref().unwrap_or("");
            // Only whole lines count: the last piece may still be arriving.
            let mut lines: Vec<&str> = body.split(['\r', '\n']).collect();
            lines.pop();
            lines.iter().any(|l| l.trim() == end)
        }
    }
}

/// The reply an instrument speaking `spec` gives for `reading` (instrument
/// units, before `unit_scale`): what the simulated meter sends.
pub fn format_reply(spec: &ReplySpec, reading: &SpotReading) -> String {
    match (&spec.format, &reading.spectrum) {
        (ReplyFormat::Spectrum, Some(points)) => {
            let mut s = format!("{}\r\n", spec.prefix);
            for (w, v) in points {
                s.push_str(&format!("{w:e}{}{v:e}\r\n", spec.pair_separator));
            }
            s.push_str(spec.end.as_deref().unwrap_or(""));
            s.push_str("\r\n");
            s
        }
        _ => {
            let filler = "- ".repeat(spec.field);
            format!("{} {filler}{:e}\r\n", spec.prefix, reading.value)
        }
    }
}

impl SpotReading {
    /// The reading with its value and spectrum multiplied by `k`.
    pub fn scaled(mut self, k: f64) -> SpotReading {
        self.value *= k;
        if let Some(s) = &mut self.spectrum {
            for p in s.iter_mut() {
                p.1 *= k;
            }
        }
        self
    }
}

/// Plays the instrument on `port` (e.g. a pty master): every time the bytes
/// received end with `command`, sends `format_reply(spec, measure())`.
/// Returns when `stop` is set (checked every 50 ms) or the port fails.
pub fn serve(
    port: &mut dyn SerialPort,
    command: &str,
    spec: &ReplySpec,
    stop: &AtomicBool,
    mut measure: impl FnMut() -> SpotReading,
) -> std::io::Result<()> {
    port.set_timeout(Duration::from_millis(50))?;
    let mut got: Vec<u8> = Vec::new();
    let mut buf = [0u8; 256];
    while !stop.load(Ordering::Relaxed) {
        match port.read(&mut buf) {
            Ok(0) => return Ok(()),
            Ok(n) => got.extend_from_slice(&buf[..n]),
            Err(e) if is_timeout(&e) => continue,
            Err(e) => return Err(e),
        }
        if got.ends_with(command.as_bytes()) {
            got.clear();
            port.write_all(format_reply(spec, &measure()).as_bytes())?;
        } else if got.len() > 4096 {
            got.drain(..got.len() - command.len());
        }
    }
    Ok(())
}

/// Whether a serial read or write error only means "nothing yet" (the
/// port's timeout, or an interrupted call): the caller tries again.
pub(crate) fn is_timeout(e: &std::io::Error) -> bool {
    matches!(
        e.kind(),
        std::io::ErrorKind::TimedOut
            | std::io::ErrorKind::WouldBlock
            | std::io::ErrorKind::Interrupted
    )
}

/// How one attempt failed.
enum Attempt {
    /// No complete reply within the timeout (what arrived, possibly empty).
    Timeout(String),
    /// A complete reply that does not parse.
    Garbage(String),
    /// The device failed (unplugged): not retried.
    Gone(String),
}

/// A spot meter on a serial port (see the module docs).
pub struct SerialSpotMeter {
    cfg: SpotMeterConfig,
    path: PathBuf,
    port: Option<Box<dyn SerialPort>>,
    /// The last reading ended in a timeout: its reply may still come.
    late_reply_pending: bool,
}

impl SerialSpotMeter {
    /// Opens the meter's port (a validated `serial` config).
    pub fn open(cfg: SpotMeterConfig) -> Result<SerialSpotMeter> {
        let Some(path) = cfg.port.clone() else {
            return Err(Error::invalid(
                "calibrate.meter.port",
                "missing: a serial meter needs a port",
            ));
        };
        let mut m = SerialSpotMeter {
            cfg,
            path,
            port: None,
            late_reply_pending: false,
        };
        m.connect()?;
        Ok(m)
    }

    fn connect(&mut self) -> Result<()> {
        let path = self.path.to_string_lossy().into_owned();
        let port = serialport::new(path.as_str(), self.cfg.baud)
            .timeout(Duration::from_millis(50))
            .open()
            .map_err(|e| self.error(&format!("cannot open {path}: {e}")))?;
        self.port = Some(port);
        Ok(())
    }

    fn error(&self, what: &str) -> Error {
        Error::Other(format!("spot meter `{}`: {what}", self.cfg.name))
    }

    fn command_quoted(&self) -> String {
        abbreviate(&self.cfg.command, 40)
    }

    /// Sends the command and reads one reply.
    fn attempt(&mut self) -> std::result::Result<SpotReading, Attempt> {
        let timeout = Duration::from_secs_f64(self.cfg.timeout);
        let Some(port) = self.port.as_mut() else {
            return Err(Attempt::Gone("not connected".into()));
        };
        // Stale bytes (a late reply) must not be read as this reply.
        let _ = port.clear(ClearBuffer::Input);
        let sent = port
            .write_all(self.cfg.command.as_bytes())
            .and_then(|_| port.flush());
        if let Err(e) = sent {
            return Err(Attempt::Gone(format!("write failed: {e}")));
        }
        let got = read_reply(port.as_mut(), &self.cfg.reply, timeout)?;
        parse_reply(&self.cfg.reply, &got).map_err(|_| Attempt::Garbage(got))
    }

    /// Reads and discards whatever arrives within `period` (the late reply
    /// of an abandoned command).
    fn discard_for(&mut self, period: Duration) -> std::result::Result<(), Attempt> {
        let Some(port) = self.port.as_mut() else {
            return Err(Attempt::Gone("not connected".into()));
        };
        let end = Instant::now() + period;
        let mut buf = [0u8; 4096];
        while let Some(left) = end.checked_duration_since(Instant::now()) {
            let _ = port.set_timeout(left.min(Duration::from_millis(50)));
            match port.read(&mut buf) {
                Ok(0) => return Err(Attempt::Gone("end of file".into())),
                Ok(_) => {}
                Err(e) if is_timeout(&e) => {}
                Err(e) => return Err(Attempt::Gone(format!("read failed: {e}"))),
            }
        }
        Ok(())
    }
}

/// Reads until `reply_complete` or `timeout`; what arrived, lossily decoded.
fn read_reply(
    port: &mut dyn SerialPort,
    spec: &ReplySpec,
    timeout: Duration,
) -> std::result::Result<String, Attempt> {
    let deadline = Instant::now() + timeout;
    let mut got: Vec<u8> = Vec::new();
    let mut buf = [0u8; 4096];
    loop {
        let text = String::from_utf8_lossy(&got);
        if reply_complete(spec, &text) {
            return Ok(text.into_owned());
        }
        if got.len() > MAX_REPLY_BYTES {
            return Err(Attempt::Garbage(text.into_owned()));
        }
        let Some(left) = deadline.checked_duration_since(Instant::now()) else {
            return Err(Attempt::Timeout(text.into_owned()));
        };
        let _ = port.set_timeout(left.min(Duration::from_millis(50)));
        match port.read(&mut buf) {
            Ok(0) => return Err(Attempt::Gone("end of file".into())),
            Ok(n) => got.extend_from_slice(&buf[..n]),
            Err(e) if is_timeout(&e) => {}
            Err(e) => return Err(Attempt::Gone(format!("read failed: {e}"))),
        }
    }
}

impl SpotMeter for SerialSpotMeter {
    fn measure(&mut self) -> Result<SpotReading> {
        if self.port.is_none() {
            self.connect()?;
        }
        std::thread::sleep(Duration::from_secs_f64(self.cfg.settle));
        let timeout = Duration::from_secs_f64(self.cfg.timeout);
        let mut last = Attempt::Timeout(String::new());
        for attempt in 0..=self.cfg.retries {
            let after_timeout = matches!(last, Attempt::Timeout(_))
                && (attempt > 0 || std::mem::take(&mut self.late_reply_pending));
            if after_timeout {
                if let Err(gone) = self.discard_for(timeout) {
                    last = gone;
                    break;
                }
            }
            if attempt > 0 {
                tracing::warn!(
                    "spot meter `{}`: retry {attempt} of {}",
                    self.cfg.name,
                    self.cfg.retries
                );
            }
            match self.attempt() {
                Ok(r) => return Ok(r.scaled(self.cfg.unit_scale)),
                Err(Attempt::Gone(why)) => {
                    last = Attempt::Gone(why);
                    break;
                }
                Err(a) => last = a,
            }
        }
        self.late_reply_pending = matches!(last, Attempt::Timeout(_));
        Err(self.failure(last))
    }

    fn describe(&self) -> String {
        format!(
            "{} (serial {} at {} baud, command `{}`, {} reply)",
            self.cfg.name,
            self.path.display(),
            self.cfg.baud,
            self.command_quoted(),
            match self.cfg.reply.format {
                ReplyFormat::Scalar => "scalar",
                ReplyFormat::Spectrum => "spectrum",
            }
        )
    }
}

impl SerialSpotMeter {
    /// The error for a reading that failed after its attempts.
    fn failure(&mut self, last: Attempt) -> Error {
        let tries = self.cfg.retries + 1;
        let cmd = self.command_quoted();
        match last {
            Attempt::Timeout(got) if got.is_empty() => self.error(&format!(
                "no reply to command `{cmd}` within {} s ({tries} attempts)",
                self.cfg.timeout
            )),
            Attempt::Timeout(got) => self.error(&format!(
                "incomplete reply to command `{cmd}` within {} s ({tries} attempts): `{}`",
                self.cfg.timeout,
                abbreviate(&got, QUOTE)
            )),
            Attempt::Garbage(got) => {
                let why = parse_reply(&self.cfg.reply, &got)
                    .err()
                    .map(|e| e.to_string())
                    .unwrap_or_else(|| "reply too long".into());
                let why = why.split("; reply").next().unwrap_or("").to_string();
                self.error(&format!(
                    "{why} (command `{cmd}`, {tries} attempts); reply `{}`",
                    abbreviate(&got, QUOTE)
                ))
            }
            Attempt::Gone(why) => {
                self.port = None;
                self.error(&format!(
                    "device {} gone ({why}) during command `{cmd}`; unplugged? The next reading re-opens it",
                    self.path.display()
                ))
            }
        }
    }
}
