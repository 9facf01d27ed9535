//! Serial sync: the command line sent to the camera trigger/sync box for
//! each frame, and the ports that carry it without ever blocking the render
//! loop (a real serial device with automatic reconnection, and a simulator
//! with fault injection).
//!
//! # Command template
//!
//! A template is literal text with placeholders, e.g.
//! `"FRAME {id} {t} {exposure_us}\n"` (in TOML write `\n` inside a basic
//! string). Placeholders:
//!
//! | placeholder | value |
//! |---|---|
//! | `{id}` | frame id, decimal |
//! | `{t}` | state time, s, 6 decimals |
//! | `{exposure_us}` | camera exposure, µs, integer |
//! | `{{`, `}}` | literal `{`, `}` |
//!
//! Anything else in braces is an error naming the placeholder.
//!
//! # Never blocking
//!
//! [`SerialPortSync`] owns the device in two background threads: a writer
//! that takes lines from a bounded queue and writes them as soon as they
//! arrive, and a reader that splits incoming bytes into acknowledgement
//! lines. [`SyncPort::send`] only enqueues (or reports the device gone or the
//! queue full); [`SyncPort::wait_ack`] waits at most its timeout. A read or
//! write error other than a timeout (on Linux: `EIO`/`BrokenPipe` when a USB
//! adapter is unplugged or a pty master closes) marks the device gone: it is
//! logged and counted, commands are dropped (not queued: a late trigger is
//! worse than none), and the device path is re-opened every
//! `reconnect_interval` (1 s by default) until it works again.

use std::collections::VecDeque;
use std::io::{Read, Write};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use serde::Serialize;

use crate::error::{Error, Result};
use crate::instruments::spot_meter::is_timeout;
use crate::placeholders::{self, Part};

/// A field of the frame command.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Field {
    Id,
    T,
    ExposureUs,
}

/// The template's placeholders, in the order the errors list them.
const FIELDS: [(&str, Field); 3] = [
    ("id", Field::Id),
    ("t", Field::T),
    ("exposure_us", Field::ExposureUs),
];

/// A parsed command template (see the module docs).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CommandTemplate {
    segments: Vec<Part<Field>>,
}

/// Values substituted into a [`CommandTemplate`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameCommand {
    /// Frame id.
    pub id: u64,
    /// State time, s.
    pub t: f64,
    /// Exposure, µs.
    pub exposure_us: u64,
}

impl CommandTemplate {
    /// Parses a template; unknown or unclosed placeholders are errors.
    pub fn parse(template: &str) -> Result<CommandTemplate> {
        let segments = placeholders::parse(template, &FIELDS)
            .map_err(|e| Error::invalid("sync.template", e))?;
        Ok(CommandTemplate { segments })
    }

    /// The command line for one frame.
    pub fn render(&self, cmd: &FrameCommand) -> String {
        let mut out = String::new();
        for s in &self.segments {
            match s {
                Part::Lit(l) => out.push_str(l),
                Part::Field(Field::Id) => out.push_str(&cmd.id.to_string()),
                Part::Field(Field::T) => out.push_str(&format!("{:.6}", cmd.t)),
                Part::Field(Field::ExposureUs) => out.push_str(&cmd.exposure_us.to_string()),
            }
        }
        out
    }
}

/// Result of [`SyncPort::send`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum SendOutcome {
    /// Handed to the writer (real port) or delivered (simulator).
    Queued,
    /// The device is gone; the line was dropped.
    DeviceGone,
    /// The writer is behind; the line was dropped.
    QueueFull,
    /// No sync by choice (`--serial none`): nothing sent, nothing missed.
    Disabled,
}

/// Counters of a sync port.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct SyncStats {
    /// Lines accepted by `send`.
    pub queued: u64,
    /// Lines fully written to the device.
    pub written: u64,
    /// Lines dropped because the device was gone.
    pub dropped_gone: u64,
    /// Lines dropped because the queue was full.
    pub dropped_full: u64,
    /// Write errors (each marks the device gone).
    pub write_errors: u64,
    /// Read errors (each marks the device gone).
    pub read_errors: u64,
    /// Failed (re)open attempts.
    pub open_failures: u64,
    /// Successful opens after the first.
    pub reconnects: u64,
    /// Acknowledgement lines received.
    pub acks: u64,
}

/// A frame-sync channel that never blocks the render loop.
pub trait SyncPort: Send {
    /// Sends one command line (already rendered, including its terminator).
    fn send(&mut self, line: &str) -> Result<SendOutcome>;
    /// Next acknowledgement line (without terminator), waiting at most
    /// `timeout`; `None` if none arrived.
    fn wait_ack(&mut self, timeout: Duration) -> Result<Option<String>>;
    /// Whether the device is currently usable.
    fn is_connected(&self) -> bool;
    /// Counters.
    fn stats(&self) -> SyncStats;
    /// Discards acknowledgements already received; returns how many.
    fn clear_acks(&mut self) -> usize {
        let mut n = 0;
        while let Ok(Some(_)) = self.wait_ack(Duration::ZERO) {
            n += 1;
        }
        n
    }
}

/// How to open and keep a serial device.
#[derive(Debug, Clone, PartialEq)]
pub struct SerialOptions {
    /// Device path (may be a symlink, re-resolved on every reconnect).
    pub path: PathBuf,
    /// Baud rate.
    pub baud: u32,
    /// Set DTR after opening (errors such as ENOTTY on ptys are ignored).
    pub dtr: Option<bool>,
    /// Set RTS after opening (errors ignored likewise).
    pub rts: Option<bool>,
    /// Open with exclusive access (TIOCEXCL + flock).
    pub exclusive: bool,
    /// Pause between reconnection attempts.
    pub reconnect_interval: Duration,
    /// Bounded queue length of the writer.
    pub queue: usize,
    /// Read poll / write timeout of the device.
    pub io_timeout: Duration,
}

impl SerialOptions {
    /// Defaults for `path` at `baud`.
    pub fn new(path: impl Into<PathBuf>, baud: u32) -> SerialOptions {
        SerialOptions {
            path: path.into(),
            baud,
            dtr: None,
            rts: None,
            exclusive: true,
            reconnect_interval: Duration::from_secs(1),
            queue: 64,
            io_timeout: Duration::from_millis(20),
        }
    }
}

struct Shared {
    connected: AtomicBool,
    /// Set by the reader when the device failed under it.
    reader_failed: AtomicBool,
    stop: AtomicBool,
    stats: Mutex<SyncStats>,
}

impl Shared {
    fn bump(&self, f: impl FnOnce(&mut SyncStats)) {
        if let Ok(mut s) = self.stats.lock() {
            f(&mut s);
        }
    }
}

/// Real serial device with background writer/reader and reconnection.
pub struct SerialPortSync {
    tx: Option<SyncSender<Vec<u8>>>,
    acks: Receiver<String>,
    shared: Arc<Shared>,
    threads: Vec<JoinHandle<()>>,
}

impl std::fmt::Debug for SerialPortSync {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SerialPortSync")
            .field("connected", &self.is_connected())
            .finish()
    }
}

fn open_port(o: &SerialOptions) -> std::result::Result<Box<dyn serialport::SerialPort>, String> {
    let path = o.path.to_string_lossy().into_owned();
    let mut port = serialport::new(path, o.baud)
        .timeout(o.io_timeout)
        .exclusive(o.exclusive)
        .open()
        .map_err(|e| e.to_string())?;
    // Modem lines: ignore failures (ENOTTY on ptys, unsupported adapters).
    if let Some(level) = o.dtr {
        if let Err(e) = port.write_data_terminal_ready(level) {
            tracing::debug!("DTR not set on {}: {e}", o.path.display());
        }
    }
    if let Some(level) = o.rts {
        if let Err(e) = port.write_request_to_send(level) {
            tracing::debug!("RTS not set on {}: {e}", o.path.display());
        }
    }
    Ok(port)
}

impl SerialPortSync {
    /// Starts the background threads. The first open is attempted at once;
    /// if it fails the port starts disconnected and keeps retrying (the
    /// error is logged, not returned: a missing sync box must not stop a
    /// run). Returns an error only if the threads cannot be spawned.
    pub fn open(opts: SerialOptions) -> Result<SerialPortSync> {
        let shared = Arc::new(Shared {
            connected: AtomicBool::new(false),
            reader_failed: AtomicBool::new(false),
            stop: AtomicBool::new(false),
            stats: Mutex::new(SyncStats::default()),
        });
        let (tx, rx) = mpsc::sync_channel::<Vec<u8>>(opts.queue.max(1));
        let (ack_tx, ack_rx) = mpsc::channel::<String>();
        let (port_tx, port_rx) = mpsc::channel::<Box<dyn serialport::SerialPort>>();
        let spawn_err = |e: std::io::Error| Error::io(&opts.path, e);
        let writer = {
            let shared = shared.clone();
            let opts = opts.clone();
            std::thread::Builder::new()
                .name("optistim-sync-writer".into())
                .spawn(move || writer_loop(opts, shared, rx, port_tx))
                .map_err(spawn_err)?
        };
        let reader = {
            let shared = shared.clone();
            std::thread::Builder::new()
                .name("optistim-sync-reader".into())
                .spawn(move || reader_loop(shared, port_rx, ack_tx))
                .map_err(spawn_err)?
        };
        Ok(SerialPortSync {
            tx: Some(tx),
            acks: ack_rx,
            shared,
            threads: vec![writer, reader],
        })
    }

    /// Waits up to `timeout` for the device to be connected.
    pub fn wait_connected(&self, timeout: Duration) -> bool {
        let end = Instant::now() + timeout;
        while Instant::now() < end {
            if self.is_connected() {
                return true;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        self.is_connected()
    }
}

fn writer_loop(
    opts: SerialOptions,
    shared: Arc<Shared>,
    rx: Receiver<Vec<u8>>,
    port_tx: mpsc::Sender<Box<dyn serialport::SerialPort>>,
) {
    let mut port: Option<Box<dyn serialport::SerialPort>> = None;
    let mut next_try = Instant::now();
    let mut ever_opened = false;
    let mut logged_failure = false;
    let mut timeouts = super::throttle::Throttle::default();
    let gone = |port: &mut Option<Box<dyn serialport::SerialPort>>, why: &str| {
        if port.take().is_some() {
            tracing::warn!(
                "sync device {} gone: {why}; retrying every {:?}",
                opts.path.display(),
                opts.reconnect_interval
            );
        }
        shared.connected.store(false, Ordering::SeqCst);
    };
    while !shared.stop.load(Ordering::SeqCst) {
        if port.is_some() && shared.reader_failed.swap(false, Ordering::SeqCst) {
            gone(&mut port, "read failed");
            next_try = Instant::now() + opts.reconnect_interval;
        }
        if port.is_none() && Instant::now() >= next_try {
            match open_port(&opts) {
                Ok(p) => {
                    let clone = p.try_clone();
                    match clone {
                        Ok(c) => {
                            let _ = port_tx.send(c);
                            shared.reader_failed.store(false, Ordering::SeqCst);
                            port = Some(p);
                            if ever_opened {
                                shared.bump(|s| s.reconnects += 1);
                            }
                            ever_opened = true;
                            logged_failure = false;
                            tracing::info!("sync device {} connected", opts.path.display());
                            shared.connected.store(true, Ordering::SeqCst);
                        }
                        Err(e) => {
                            shared.bump(|s| s.open_failures += 1);
                            tracing::warn!(
                                "sync device {}: clone failed: {e}",
                                opts.path.display()
                            );
                            next_try = Instant::now() + opts.reconnect_interval;
                        }
                    }
                }
                Err(e) => {
                    shared.bump(|s| s.open_failures += 1);
                    if !logged_failure {
                        tracing::warn!("sync device {}: cannot open: {e}", opts.path.display());
                        logged_failure = true;
                    }
                    next_try = Instant::now() + opts.reconnect_interval;
                }
            }
        }
        match rx.recv_timeout(Duration::from_millis(20)) {
            Ok(line) => match port.as_mut() {
                Some(p) => match p.write_all(&line).and_then(|_| p.flush()) {
                    Ok(()) => shared.bump(|s| s.written += 1),
                    Err(e) if is_timeout(&e) => {
                        shared.bump(|s| s.write_errors += 1);
                        if let Some(more) = timeouts.hit(Instant::now()) {
                            tracing::warn!(more, "sync write timed out: {e}");
                        }
                    }
                    Err(e) => {
                        shared.bump(|s| {
                            s.write_errors += 1;
                            s.dropped_gone += 1;
                        });
                        gone(&mut port, &e.to_string());
                        next_try = Instant::now() + opts.reconnect_interval;
                    }
                },
                None => shared.bump(|s| s.dropped_gone += 1),
            },
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => break,
        }
    }
    shared.connected.store(false, Ordering::SeqCst);
}

fn reader_loop(
    shared: Arc<Shared>,
    port_rx: Receiver<Box<dyn serialport::SerialPort>>,
    ack_tx: mpsc::Sender<String>,
) {
    let mut port: Option<Box<dyn serialport::SerialPort>> = None;
    let mut line: Vec<u8> = Vec::new();
    let mut buf = [0u8; 256];
    while !shared.stop.load(Ordering::SeqCst) {
        // A newer handle (after a reconnect) replaces the old one.
        while let Ok(p) = port_rx.try_recv() {
            port = Some(p);
            line.clear();
        }
        let Some(p) = port.as_mut() else {
            match port_rx.recv_timeout(Duration::from_millis(20)) {
                Ok(p) => {
                    port = Some(p);
                    line.clear();
                }
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => break,
            }
            continue;
        };
        match p.read(&mut buf) {
            Ok(0) => {
                shared.bump(|s| s.read_errors += 1);
                shared.reader_failed.store(true, Ordering::SeqCst);
                port = None;
            }
            Ok(n) => {
                for &b in &buf[..n] {
                    if b == b'\n' || b == b'\r' {
                        if !line.is_empty() {
                            let s = String::from_utf8_lossy(&line).into_owned();
                            line.clear();
                            shared.bump(|st| st.acks += 1);
                            let _ = ack_tx.send(s);
                        }
                    } else if line.len() < 4096 {
                        line.push(b);
                    }
                }
            }
            Err(e) if is_timeout(&e) => {}
            Err(e) => {
                tracing::debug!("sync read failed: {e}");
                shared.bump(|s| s.read_errors += 1);
                shared.reader_failed.store(true, Ordering::SeqCst);
                port = None;
            }
        }
    }
}

impl SyncPort for SerialPortSync {
    fn send(&mut self, line: &str) -> Result<SendOutcome> {
        if !self.is_connected() {
            self.shared.bump(|s| s.dropped_gone += 1);
            return Ok(SendOutcome::DeviceGone);
        }
        let Some(tx) = &self.tx else {
            return Ok(SendOutcome::DeviceGone);
        };
        match tx.try_send(line.as_bytes().to_vec()) {
            Ok(()) => {
                self.shared.bump(|s| s.queued += 1);
                Ok(SendOutcome::Queued)
            }
            Err(TrySendError::Full(_)) => {
                self.shared.bump(|s| s.dropped_full += 1);
                Ok(SendOutcome::QueueFull)
            }
            Err(TrySendError::Disconnected(_)) => {
                self.shared.bump(|s| s.dropped_gone += 1);
                Ok(SendOutcome::DeviceGone)
            }
        }
    }

    fn wait_ack(&mut self, timeout: Duration) -> Result<Option<String>> {
        match self.acks.recv_timeout(timeout) {
            Ok(s) => Ok(Some(s)),
            Err(_) => Ok(None),
        }
    }

    fn is_connected(&self) -> bool {
        self.shared.connected.load(Ordering::SeqCst)
    }

    fn stats(&self) -> SyncStats {
        self.shared.stats.lock().map(|s| *s).unwrap_or_default()
    }
}

impl Drop for SerialPortSync {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::SeqCst);
        self.tx = None;
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

/// One event of a simulated exchange.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Exchange {
    /// A line delivered to the simulated device.
    Sent(String),
    /// A line refused because the device was (simulated) gone.
    Refused(String),
    /// An acknowledgement produced by the device.
    Ack(String),
    /// An acknowledgement the fault injection dropped.
    AckDropped(String),
}

/// Simulated sync device: acknowledges every line with `ACK <line>`
/// (terminator stripped), records the exchange (all of it, or the last
/// entries only for long runs), and injects faults.
#[derive(Debug, Clone, Default)]
pub struct SimSync {
    /// What happened, in order: everything, or the last `history` entries.
    pub exchange: VecDeque<Exchange>,
    /// Most entries kept in `exchange` (None: all).
    pub history: Option<usize>,
    /// Send calls so far (index of the next send).
    pub sends: u64,
    /// Drop the ack of every send whose index is in here.
    pub drop_acks: std::collections::BTreeSet<u64>,
    /// Drop every ack when true.
    pub drop_all_acks: bool,
    /// Device gone for sends with index in `gone.0 .. gone.0 + gone.1`.
    pub gone: Option<(u64, u64)>,
    /// Answer acks at all.
    pub ack: bool,
    pending: VecDeque<String>,
    stats: SyncStats,
}

impl SimSync {
    /// A simulator that acknowledges every line.
    pub fn new() -> SimSync {
        SimSync {
            ack: true,
            ..Default::default()
        }
    }

    /// A simulator that keeps only the last `entries` of the exchange, so
    /// its memory stays flat over a run of any length.
    pub fn with_history(entries: usize) -> SimSync {
        SimSync {
            history: Some(entries),
            ..SimSync::new()
        }
    }

    fn record(&mut self, e: Exchange) {
        if let Some(limit) = self.history {
            if self.exchange.len() >= limit {
                self.exchange.pop_front();
            }
            if limit == 0 {
                return;
            }
        }
        self.exchange.push_back(e);
    }

    /// Lines delivered to the device (of those kept).
    pub fn sent_lines(&self) -> Vec<&str> {
        self.exchange
            .iter()
            .filter_map(|e| match e {
                Exchange::Sent(s) => Some(s.as_str()),
                _ => None,
            })
            .collect()
    }

    fn gone_now(&self, idx: u64) -> bool {
        self.gone
            .is_some_and(|(from, n)| idx >= from && idx < from + n)
    }
}

impl SyncPort for SimSync {
    fn send(&mut self, line: &str) -> Result<SendOutcome> {
        let idx = self.sends;
        self.sends += 1;
        if self.gone_now(idx) {
            self.stats.dropped_gone += 1;
            self.record(Exchange::Refused(line.to_string()));
            return Ok(SendOutcome::DeviceGone);
        }
        if idx > 0 && self.gone_now(idx - 1) {
            self.stats.reconnects += 1;
        }
        self.stats.queued += 1;
        self.stats.written += 1;
        self.record(Exchange::Sent(line.to_string()));
        if self.ack {
            let ack = format!("ACK {}", line.trim_end_matches(['\r', '\n']));
            if self.drop_all_acks || self.drop_acks.contains(&idx) {
                self.record(Exchange::AckDropped(ack));
            } else {
                self.stats.acks += 1;
                self.record(Exchange::Ack(ack.clone()));
                self.pending.push_back(ack);
            }
        }
        Ok(SendOutcome::Queued)
    }

    fn wait_ack(&mut self, _timeout: Duration) -> Result<Option<String>> {
        // The simulator answers instantly or never: no waiting needed.
        Ok(self.pending.pop_front())
    }

    fn is_connected(&self) -> bool {
        !self.gone_now(self.sends)
    }

    fn stats(&self) -> SyncStats {
        self.stats
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn template_renders_placeholders_and_escapes() {
        let t = CommandTemplate::parse("FRAME {id} {t} {exposure_us} {{x}}\n").unwrap();
        let s = t.render(&FrameCommand {
            id: 42,
            t: 1.5,
            exposure_us: 2500,
        });
        assert_eq!(s, "FRAME 42 1.500000 2500 {x}\n");
        for bad in ["{exposure}", "{id", "a}b", "{}"] {
            let e = CommandTemplate::parse(bad).unwrap_err().to_string();
            assert!(e.contains("sync.template"), "{bad}: {e}");
        }
        assert!(CommandTemplate::parse("{nope}")
            .unwrap_err()
            .to_string()
            .contains("{nope}"));
    }

    /// A bounded history keeps the last entries and forgets the rest,
    /// while the counters still cover every send.
    #[test]
    fn sim_history_keeps_only_the_last_entries() {
        let mut s = SimSync::with_history(3);
        for i in 0..1000 {
            s.send(&format!("F {i}\n")).unwrap();
            assert_eq!(
                s.wait_ack(Duration::ZERO).unwrap(),
                Some(format!("ACK F {i}"))
            );
        }
        assert_eq!(
            s.exchange.iter().cloned().collect::<Vec<_>>(),
            vec![
                Exchange::Ack("ACK F 998".into()),
                Exchange::Sent("F 999\n".into()),
                Exchange::Ack("ACK F 999".into()),
            ]
        );
        assert_eq!((s.stats().written, s.stats().acks), (1000, 1000));
        let mut silent = SimSync::with_history(0);
        silent.send("F 0\n").unwrap();
        assert!(silent.exchange.is_empty() && silent.stats().written == 1);
    }

    #[test]
    fn sim_records_acks_and_injects_faults() {
        let mut s = SimSync::new();
        s.drop_acks.insert(1);
        s.gone = Some((3, 2));
        let mut outcomes = Vec::new();
        let mut acks = Vec::new();
        for i in 0..6 {
            outcomes.push(s.send(&format!("F {i}\n")).unwrap());
            acks.push(s.wait_ack(Duration::from_millis(1)).unwrap());
        }
        use SendOutcome::*;
        assert_eq!(
            outcomes,
            vec![Queued, Queued, Queued, DeviceGone, DeviceGone, Queued]
        );
        assert_eq!(
            acks,
            vec![
                Some("ACK F 0".into()),
                None,
                Some("ACK F 2".into()),
                None,
                None,
                Some("ACK F 5".into())
            ]
        );
        assert_eq!(s.sent_lines(), vec!["F 0\n", "F 1\n", "F 2\n", "F 5\n"]);
        let st = s.stats();
        assert_eq!(
            (st.written, st.dropped_gone, st.acks, st.reconnects),
            (4, 2, 3, 1)
        );
        assert!(s.exchange.contains(&Exchange::AckDropped("ACK F 1".into())));
    }

    #[test]
    fn missing_device_does_not_block_and_keeps_retrying() {
        let dir = tempfile::tempdir().unwrap();
        let mut o = SerialOptions::new(dir.path().join("no-such-tty"), 115_200);
        o.reconnect_interval = Duration::from_millis(30);
        let mut p = SerialPortSync::open(o).unwrap();
        let t0 = Instant::now();
        for _ in 0..100 {
            assert_eq!(p.send("X\n").unwrap(), SendOutcome::DeviceGone);
        }
        assert!(t0.elapsed() < Duration::from_millis(200));
        assert_eq!(p.wait_ack(Duration::from_millis(10)).unwrap(), None);
        std::thread::sleep(Duration::from_millis(150));
        let st = p.stats();
        assert_eq!(st.dropped_gone, 100);
        assert!(st.open_failures >= 2, "{st:?}");
        assert!(!p.is_connected());
    }
}
