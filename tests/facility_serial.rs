//! SerialPortSync against a real pseudo-terminal pair. The driver opens the
//! slave through a symlink, like a udev name of a real adapter; unplugging is
//! simulated by closing the master, replugging by pointing the symlink to a
//! new pty.
#![cfg(unix)]

use std::io::{Read, Write};
use std::path::Path;
use std::time::{Duration, Instant};

use optistim::facility::serial::{SendOutcome, SerialOptions, SerialPortSync, SyncPort};
use serialport::{SerialPort, TTYPort};

fn new_pair(link: &Path) -> (TTYPort, TTYPort) {
    let (mut master, slave) = TTYPort::pair().expect("pty pair");
    master.set_timeout(Duration::from_millis(50)).unwrap();
    let name = slave.name().expect("slave name");
    let tmp = link.with_extension("new");
    let _ = std::fs::remove_file(&tmp);
    std::os::unix::fs::symlink(&name, &tmp).unwrap();
    std::fs::rename(&tmp, link).unwrap(); // atomic repoint
    (master, slave)
}

/// Reads from the master until `want` bytes arrived or 3 s passed.
fn read_exact_within(master: &mut TTYPort, want: usize) -> Vec<u8> {
    let mut got = Vec::new();
    let end = Instant::now() + Duration::from_secs(3);
    let mut buf = [0u8; 256];
    while got.len() < want && Instant::now() < end {
        match master.read(&mut buf) {
            Ok(n) => got.extend_from_slice(&buf[..n]),
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
            Err(e) => panic!("master read: {e}"),
        }
    }
    got
}

#[test]
fn commands_acks_unplug_and_reconnect_over_a_pty() {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("ttySYNC");
    let (mut master, _slave) = new_pair(&link);

    let mut opts = SerialOptions::new(&link, 115_200);
    opts.reconnect_interval = Duration::from_millis(200);
    opts.dtr = Some(true); // ENOTTY on a pty: must be ignored
    opts.rts = Some(true);
    let mut port = SerialPortSync::open(opts).unwrap();
    assert!(
        port.wait_connected(Duration::from_secs(3)),
        "never connected"
    );

    // Command bytes arrive at the master, unchanged.
    let line = "FRAME 1 0.040000 2500\n";
    assert_eq!(port.send(line).unwrap(), SendOutcome::Queued);
    assert_eq!(read_exact_within(&mut master, line.len()), line.as_bytes());

    // An ack written by the master is read (CR LF terminated).
    master.write_all(b"ACK 1\r\n").unwrap();
    assert_eq!(
        port.wait_ack(Duration::from_secs(3)).unwrap().as_deref(),
        Some("ACK 1")
    );
    assert_eq!(port.wait_ack(Duration::from_millis(50)).unwrap(), None);

    // Unplug: the master goes away. Sends must never block.
    drop(master);
    let t0 = Instant::now();
    let mut outcomes = Vec::new();
    while Instant::now() - t0 < Duration::from_millis(600) {
        let s = Instant::now();
        outcomes.push(port.send("FRAME 2 0.08 2500\n").unwrap());
        assert!(s.elapsed() < Duration::from_millis(20), "send blocked");
        assert_eq!(port.wait_ack(Duration::from_millis(5)).unwrap(), None);
    }
    assert!(!port.is_connected(), "unplug not detected");
    assert!(outcomes.contains(&SendOutcome::DeviceGone));
    let st = port.stats();
    assert!(st.read_errors + st.write_errors >= 1, "{st:?}");
    assert!(st.dropped_gone >= 1, "{st:?}");
    assert_eq!(st.reconnects, 0);

    // Replug: a new pty behind the same path. The driver re-opens it.
    let (mut master2, _slave2) = new_pair(&link);
    assert!(port.wait_connected(Duration::from_secs(3)), "no reconnect");
    assert_eq!(port.stats().reconnects, 1);
    let line = "FRAME 3 0.120000 2500\n";
    assert_eq!(port.send(line).unwrap(), SendOutcome::Queued);
    assert_eq!(read_exact_within(&mut master2, line.len()), line.as_bytes());
    master2.write_all(b"ACK 3\n").unwrap();
    assert_eq!(
        port.wait_ack(Duration::from_secs(3)).unwrap().as_deref(),
        Some("ACK 3")
    );
    // The writer thread counts a line after its write returns, which may be
    // after the master has read it: give the count a moment on a busy machine.
    let t0 = Instant::now();
    while port.stats().written < 2 && t0.elapsed() < Duration::from_secs(2) {
        std::thread::sleep(Duration::from_millis(5));
    }
    let st = port.stats();
    assert_eq!(st.written, 2, "{st:?}");
    assert_eq!(st.acks, 2, "{st:?}");
}
