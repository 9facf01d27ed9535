//! The serial spot meter against a real pseudo-terminal pair: a simulated
//! instrument thread on the master end answers each command from a script
//! (normal, slow, garbage, silent), the meter opens the slave through a
//! symlink like a udev name; unplugging closes the master, replugging points
//! the symlink at a new pty. Plus property tests of the reply parser.
#![cfg(unix)]

use std::io::{Read, Write};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use optistim::instruments::config::{open_spot_meter, ReplySpec, SpotMeterConfig};
use optistim::instruments::spot_meter::{format_reply, parse_reply, reply_complete};
use optistim::instruments::SpotReading;
use proptest::prelude::*;
use serialport::{SerialPort, TTYPort};

const TIMEOUT_S: f64 = 0.3;

fn new_pair(link: &Path) -> (TTYPort, TTYPort) {
    let (mut master, slave) = TTYPort::pair().expect("pty pair");
    master.set_timeout(Duration::from_millis(20)).unwrap();
    let name = slave.name().expect("slave name");
    let tmp = link.with_extension("new");
    let _ = std::fs::remove_file(&tmp);
    std::os::unix::fs::symlink(&name, &tmp).unwrap();
    std::fs::rename(&tmp, link).unwrap();
    (master, slave)
}

/// What the instrument does with one command.
#[derive(Clone)]
enum Act {
    /// Answer these bytes after this delay.
    Reply(Duration, &'static str),
    /// Never answer.
    Silent,
}
use Act::*;

fn now(s: &'static str) -> Act {
    Reply(Duration::ZERO, s)
}

/// The instrument: for each `MEAS\r\n` received, plays the next act (the
/// last one repeats). Returns the master and the number of commands.
fn instrument(
    mut master: TTYPort,
    script: Vec<Act>,
    stop: Arc<AtomicBool>,
) -> JoinHandle<(TTYPort, usize)> {
    std::thread::spawn(move || {
        let mut got = Vec::new();
        let mut n = 0;
        let mut buf = [0u8; 256];
        while !stop.load(Ordering::Relaxed) {
            match master.read(&mut buf) {
                Ok(k) => got.extend_from_slice(&buf[..k]),
                Err(e) if e.kind() == std::io::ErrorKind::TimedOut => continue,
                Err(_) => break,
            }
            while let Some(i) = find(&got, b"MEAS\r\n") {
                got.drain(..i + 6);
                let act = script[n.min(script.len() - 1)].clone();
                n += 1;
                if let Reply(delay, text) = act {
                    std::thread::sleep(delay);
                    master.write_all(text.as_bytes()).unwrap();
                }
            }
        }
        (master, n)
    })
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

fn config(link: &Path, extra: &str, reply: &str) -> SpotMeterConfig {
    let text = format!(
        "kind = \"serial\"\nname = \"bench photometer\"\nport = \"{}\"\ncommand = \"MEAS\\r\\n\"\n\
         timeout = {TIMEOUT_S}\n{extra}\n[reply]\n{reply}\n",
        link.display()
    );
    let cfg: SpotMeterConfig = toml::from_str(&text).unwrap();
    cfg.validate().unwrap();
    cfg
}

const PHOTOMETER: &str = "prefix = \"OK\"";

/// Runs `script` against a meter of `cfg`, takes `readings` readings.
fn session(
    extra: &str,
    reply: &str,
    script: Vec<Act>,
    readings: usize,
) -> (Vec<Result<SpotReading, String>>, usize, Duration) {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("ttyMETER");
    let (master, _slave) = new_pair(&link);
    let stop = Arc::new(AtomicBool::new(false));
    let inst = instrument(master, script, stop.clone());
    let mut meter = open_spot_meter(&config(&link, extra, reply), dir.path()).unwrap();
    let t0 = Instant::now();
    let out = (0..readings)
        .map(|_| meter.measure().map_err(|e| e.to_string()))
        .collect();
    let elapsed = t0.elapsed();
    stop.store(true, Ordering::Relaxed);
    let (_, n) = inst.join().unwrap();
    (out, n, elapsed)
}

#[test]
fn scalar_replies_are_parsed_and_scaled() {
    let (r, n, _) = session(
        "unit_scale = 2.0\nretries = 0",
        PHOTOMETER,
        vec![now("OK 12.34E+00\r"), now("OK -1.5e-3\r")],
        2,
    );
    assert_eq!(n, 2);
    assert_eq!(r[0].as_ref().unwrap().value, 2.0 * 12.34);
    assert_eq!(r[1].as_ref().unwrap().value, 2.0 * -1.5e-3);
    assert!(r[0].as_ref().unwrap().spectrum.is_none());
    // A radiometer giving status, value, unit: field 1.
    let (r, _, _) = session(
        "retries = 0",
        "prefix = \"R\"\nfield = 1",
        vec![now("R 00, 3.25e-02 W/m2/sr\n")],
        1,
    );
    assert_eq!(r[0].as_ref().unwrap().value, 3.25e-2);
}

#[test]
fn spectrum_reply_gives_spectrum_and_its_integral() {
    let spec = "format = \"spectrum\"\nprefix = \"SPEC\"\nend = \"END\"";
    let reply = "SPEC\r\n400,1.0\r\n500,2.0;600,4.0\r\nEND\r\n";
    let (r, _, _) = session("unit_scale = 0.5\nretries = 0", spec, vec![now(reply)], 1);
    let r = r[0].as_ref().unwrap();
    assert_eq!(
        r.spectrum.as_deref().unwrap(),
        &[(400.0, 0.5), (500.0, 1.0), (600.0, 2.0)]
    );
    // Trapezoids by hand: (1+2)/2·100 + (2+4)/2·100 = 450, × 0.5.
    assert!((r.value - 225.0).abs() < 1e-12, "{}", r.value);
}

#[test]
fn slow_reply_within_timeout_is_read_once() {
    let slow = Duration::from_secs_f64(TIMEOUT_S * 0.5);
    let (r, n, _) = session("retries = 2", PHOTOMETER, vec![Reply(slow, "OK 7.0\r")], 1);
    assert_eq!(r[0].as_ref().unwrap().value, 7.0);
    assert_eq!(n, 1, "no retry for a reply within the timeout");
}

#[test]
fn reply_beyond_timeout_is_retried_and_the_late_one_discarded() {
    let late = Duration::from_secs_f64(TIMEOUT_S * 1.5);
    let (r, n, _) = session(
        "retries = 1",
        PHOTOMETER,
        vec![Reply(late, "OK 1.0\r"), now("OK 2.0\r"), now("OK 3.0\r")],
        2,
    );
    assert_eq!(n, 3);
    assert_eq!(r[0].as_ref().unwrap().value, 2.0, "late reply taken");
    assert_eq!(r[1].as_ref().unwrap().value, 3.0, "replies out of step");
}

#[test]
fn garbage_then_good_is_retried() {
    let (r, n, _) = session(
        "retries = 2",
        PHOTOMETER,
        vec![now("\u{7}#!?\r\n"), now("OK 5.5\r")],
        1,
    );
    assert_eq!(r[0].as_ref().unwrap().value, 5.5);
    assert_eq!(n, 2);
}

#[test]
fn persistent_garbage_error_names_meter_command_and_short_reply() {
    let junk: &'static str = Box::leak(format!("ER {}\r", "x".repeat(500)).into_boxed_str());
    let (r, n, _) = session("retries = 1", PHOTOMETER, vec![now(junk)], 1);
    assert_eq!(n, 2);
    let e = r[0].as_ref().unwrap_err();
    assert!(
        e.contains("bench photometer") && e.contains("MEAS\\r\\n"),
        "{e}"
    );
    let quoted = e.rsplit("reply `").next().unwrap();
    assert!(quoted.starts_with("ER xxx"), "{e}");
    assert!(quoted.chars().count() <= 81, "reply quoted too long: {e}");
    assert!(!e.contains('\n') && !e.contains('\r'), "not one line: {e}");
}

#[test]
fn silence_times_out_with_an_error_naming_the_meter() {
    let (r, n, elapsed) = session("retries = 1", PHOTOMETER, vec![Silent], 1);
    let e = r[0].as_ref().unwrap_err();
    assert!(
        e.contains("bench photometer") && e.contains("no reply"),
        "{e}"
    );
    assert_eq!(n, 2, "one retry");
    // Two timeouts plus the wait for a late reply between them.
    let want = 3.0 * TIMEOUT_S;
    let s = elapsed.as_secs_f64();
    assert!(s >= want && s < want + 1.0, "{s} s");
}

#[test]
fn unplug_fails_the_reading_and_replug_works_again() {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("ttyMETER");
    let (master, slave) = new_pair(&link);
    let stop = Arc::new(AtomicBool::new(false));
    let inst = instrument(master, vec![now("OK 1.0\r")], stop.clone());
    let cfg = config(&link, "retries = 2", PHOTOMETER);
    let mut meter = open_spot_meter(&cfg, dir.path()).unwrap();
    assert_eq!(meter.measure().unwrap().value, 1.0);

    stop.store(true, Ordering::Relaxed);
    let (master, _) = inst.join().unwrap();
    drop(master);
    drop(slave);
    let t0 = Instant::now();
    let e = meter.measure().unwrap_err().to_string();
    assert!(e.contains("bench photometer") && e.contains("gone"), "{e}");
    assert!(
        t0.elapsed() < Duration::from_secs(2),
        "unplug not detected promptly"
    );

    let (master, _slave) = new_pair(&link);
    let stop = Arc::new(AtomicBool::new(false));
    let inst = instrument(master, vec![now("OK 9.0\r")], stop.clone());
    assert_eq!(meter.measure().unwrap().value, 9.0);
    stop.store(true, Ordering::Relaxed);
    assert_eq!(inst.join().unwrap().1, 1);
}

/// `serve`, as the simulated facility uses it, plays the instrument for the
/// real meter: readings the closure makes arrive scaled by `unit_scale`.
#[test]
fn serve_speaks_the_protocol_to_the_real_meter() {
    let cases = [
        ("prefix = \"VAL\"\nfield = 2", None),
        (
            "format = \"spectrum\"\nprefix = \"SPEC\"\nend = \"DONE\"\npair_separator = \" \"",
            Some(vec![(400.0, 1.5), (450.5, 0.25), (700.0, 3.0)]),
        ),
    ];
    for (reply, spectrum) in cases {
        let dir = tempfile::tempdir().unwrap();
        let link = dir.path().join("ttySIM");
        let (mut master, _slave) = new_pair(&link);
        let cfg = config(&link, "unit_scale = 4.0\nretries = 0", reply);
        let stop = Arc::new(AtomicBool::new(false));
        let (spec, stop2, sp) = (cfg.reply.clone(), stop.clone(), spectrum.clone());
        let inst = std::thread::spawn(move || {
            let mut n = 0.0;
            optistim::instruments::spot_meter::serve(&mut master, "MEAS\r\n", &spec, &stop2, || {
                n += 1.0;
                SpotReading {
                    value: 0.125 * n,
                    spectrum: sp.clone(),
                }
            })
        });
        let mut meter = open_spot_meter(&cfg, dir.path()).unwrap();
        for k in 1..=3 {
            let r = meter.measure().unwrap();
            match &spectrum {
                None => assert_eq!(r.value, 4.0 * 0.125 * k as f64),
                Some(s) => {
                    let want: Vec<(f64, f64)> = s.iter().map(|&(w, v)| (w, 4.0 * v)).collect();
                    assert_eq!(r.spectrum.as_ref().unwrap(), &want);
                    // (1.5+0.25)/2·50.5 + (0.25+3)/2·249.5, × 4.
                    let integral = 4.0 * (0.875 * 50.5 + 1.625 * 249.5);
                    assert!((r.value - integral).abs() < 1e-9, "{}", r.value);
                }
            }
        }
        stop.store(true, Ordering::Relaxed);
        inst.join().unwrap().unwrap();
    }
}

#[test]
fn sim_kind_and_missing_port_are_clear_errors() {
    let cfg: SpotMeterConfig = toml::from_str("kind = \"sim\"").unwrap();
    let e = open_spot_meter(&cfg, Path::new("."))
        .err()
        .unwrap()
        .to_string();
    assert!(
        e.contains("calibrate.meter.kind") && e.contains("simulated"),
        "{e}"
    );
    let dir = tempfile::tempdir().unwrap();
    let cfg = config(&dir.path().join("nothing"), "", PHOTOMETER);
    let e = open_spot_meter(&cfg, dir.path()).err().unwrap().to_string();
    assert!(
        e.contains("bench photometer") && e.contains("nothing"),
        "{e}"
    );
}

#[test]
fn malformed_replies_name_what_is_wrong() {
    let sp = spec("format = \"spectrum\"\nprefix = \"S\"\nend = \"END\"\nerror_prefix = \"ERR\"");
    let sc = spec("prefix = \"OK\"\nfield = 1\nerror_prefix = \"ER\"");
    let cases = [
        (&sp, "S\n400,1;400,2\nEND\n", "increase strictly"),
        (&sp, "S\n400,1;500,2\n", "terminator"),
        (&sp, "S\n400,1\nEND\n", "at least two"),
        (&sp, "S\n400;500,2\nEND\n", "record 0"),
        (&sp, "S\n-4,1;500,2\nEND\n", "wavelength"),
        (&sp, "S\n400,nan;500,2\nEND\n", "finite"),
        (&sp, "ERR 12\r", "reports an error"),
        (&sc, "OK 1\r", "no field 1"),
        (&sc, "OK 1 1e999\r", "not a finite number"),
        (&sc, "KO 1 2\r", "start with `OK`"),
        (&sc, "ER 5\r", "reports an error"),
    ];
    for (s, text, want) in cases {
        let e = parse_reply(s, text).unwrap_err().to_string();
        assert!(
            e.contains(want) && e.starts_with("malformed reply"),
            "{text:?}: {e}"
        );
    }
    // A spectrum's error reply ends at its first line, as a scalar's does.
    assert!(reply_complete(&sp, "ERR 12\r"));
}

fn spec(text: &str) -> ReplySpec {
    let s: ReplySpec = toml::from_str(text).unwrap();
    s.validate("reply").unwrap();
    s
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn parse_never_panics(
        text in prop_oneof!["\\PC{0,200}", "[OKER0-9.,;eE+ \r\nND-]{0,120}"],
        field in 0usize..4,
    ) {
        for s in [
            spec(&format!("prefix = \"OK\"\nfield = {field}\nerror_prefix = \"ER\"")),
            spec("format = \"spectrum\"\nend = \"END\"\npair_separator = \" \""),
        ] {
            let _ = reply_complete(&s, &text);
            if let Err(e) = parse_reply(&s, &text) {
                let m = e.to_string();
                prop_assert!(m.starts_with("malformed reply: "), "{}", m);
                prop_assert!(!m.contains('\n'));
            } else {
                let r = parse_reply(&s, &text).unwrap();
                prop_assert!(r.value.is_finite());
            }
        }
    }

    #[test]
    fn scalar_numbers_round_trip(v in -1e30f64..1e30, field in 0usize..3, unit in "[a-zA-Z/]{1,6}") {
        let s = spec(&format!("prefix = \"OK\"\nfield = {field}"));
        let before = "7 ".repeat(field);
        for text in [format!("OK {before}{v} {unit}\r"), format!("  OK,{before}{v:E};{unit}\n")] {
            prop_assert!(reply_complete(&s, &text));
            prop_assert_eq!(parse_reply(&s, &text).unwrap().value, v);
        }
        // A unit glued to the number is not a number.
        let glued = format!("OK {before}{v}{unit}\r");
        prop_assert!(parse_reply(&s, &glued).is_err());
    }

    #[test]
    fn spectra_round_trip(values in prop::collection::vec(0.0f64..1e3, 2..50), w0 in 300.0f64..500.0) {
        let s = spec("format = \"spectrum\"\nprefix = \"S\"\nend = \"END\"");
        let mut text = String::from("S\n");
        let mut want = Vec::new();
        for (i, v) in values.iter().enumerate() {
            let w = w0 + 2.5 * i as f64;
            text.push_str(&format!("{w},{v}{}", if i % 3 == 0 { ";" } else { "\r\n" }));
            want.push((w, *v));
        }
        prop_assert!(!reply_complete(&s, &text));
        text.push_str("\nEND\r\n");
        prop_assert!(reply_complete(&s, &text));
        let r = parse_reply(&s, &text).unwrap();
        let integral: f64 = want.windows(2).map(|p| (p[1].0 - p[0].0) * (p[0].1 + p[1].1) / 2.0).sum();
        prop_assert!((r.value - integral).abs() <= 1e-9 * integral.abs().max(1.0));
        prop_assert_eq!(r.spectrum.unwrap(), want);
        // What the simulated meter sends parses back to the same reading.
        let reading = parse_reply(&s, &text).unwrap();
        prop_assert_eq!(parse_reply(&s, &format_reply(&s, &reading)).unwrap(), reading);
    }
}
