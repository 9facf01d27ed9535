//! Real UDP on loopback: only valid, in-order datagrams from the configured
//! sender are accepted, and every rejection is counted in the right bucket.

use std::net::UdpSocket;
use std::time::{Duration, Instant};

use optistim::facility::udp::{UdpStateReceiver, UdpStats};

fn csv_state(t: f64, cam_z: f64) -> String {
    format!("{t},0,0,{cam_z},1,0,0,0,1.5e11,0,0,,,,,,,\n")
}

/// Polls the receiver until the number of datagrams it has seen reaches
/// `expected_total`; returns what `latest` handed out meanwhile.
fn pump(rx: &mut UdpStateReceiver, expected_total: u64) -> Vec<f64> {
    let deadline = Instant::now() + Duration::from_secs(5);
    let mut got = Vec::new();
    while rx.stats().total() < expected_total {
        if let Some((s, _)) = rx.latest() {
            got.push(s.t);
        }
        assert!(
            Instant::now() < deadline,
            "datagram not delivered: {:?}",
            rx.stats()
        );
        std::thread::sleep(Duration::from_millis(1));
    }
    if let Some((s, _)) = rx.latest() {
        got.push(s.t);
    }
    got
}

#[test]
fn accepts_exactly_the_valid_in_order_states() {
    let client = UdpSocket::bind("127.0.0.1:0").unwrap();
    let foreign = UdpSocket::bind("127.0.0.1:0").unwrap();
    let mut rx =
        UdpStateReceiver::bind("127.0.0.1:0".parse().unwrap(), client.local_addr().unwrap())
            .unwrap();
    let to = rx.local_addr().unwrap();
    assert!(rx.latest().is_none());

    // (payload, from foreign socket?, accepted t if accepted)
    let json3 = r#"{"t":3.0,"camera_position":[0,0,-5],"camera_attitude":[1,0,0,0],"sun_position":[1,0,0],"body_position":[1,2,3],"body_attitude":[0,0,1,0]}"#;
    let cases: Vec<(Vec<u8>, bool, Option<f64>)> = [
        (csv_state(1.0, -1.0), false, Some(1.0)),
        (csv_state(2.0, -2.0), false, Some(2.0)),
        (csv_state(1.5, -1.5), false, None),     // out of order
        (csv_state(2.0, -2.0), false, None),     // repeated t
        ("garbage\n".into(), false, None),       // malformed
        ("1,2,3\n".into(), false, None),         // wrong field count
        (csv_state(9.0, f64::NAN), false, None), // non-finite
        ("".into(), false, None),                // empty
        (String::new(), false, None),            // invalid UTF-8, set below
        (csv_state(10.0, -10.0), true, None),    // foreign sender
        (json3.into(), false, Some(3.0)),        // JSON form
        (csv_state(4.0, -4.0), false, Some(4.0)),
    ]
    .into_iter()
    .map(|(p, f, e): (String, bool, Option<f64>)| (p.into_bytes(), f, e))
    .collect();
    let mut cases = cases;
    cases[8].0 = vec![0xff, 0xfe, b'\n']; // invalid UTF-8
    let mut accepted = Vec::new();
    for (i, (payload, from_foreign, expect)) in cases.iter().enumerate() {
        let sock = if *from_foreign { &foreign } else { &client };
        sock.send_to(payload, to).unwrap();
        let got = pump(&mut rx, i as u64 + 1);
        match expect {
            Some(t) => {
                assert_eq!(got, vec![*t], "case {i}: {payload:?}");
                accepted.push(*t);
            }
            None => {
                assert!(got.is_empty(), "case {i} wrongly accepted: {payload:?}");
                assert!(rx.last_rejection().is_some());
            }
        }
    }
    assert_eq!(accepted, vec![1.0, 2.0, 3.0, 4.0]);
    let st = rx.stats();
    assert_eq!(
        st,
        UdpStats {
            accepted: 4,
            superseded: 0,
            stale: 2,
            malformed: 5,
            foreign: 1,
            socket_errors: 0,
        }
    );

    // Several states within one frame: newest wins, others are superseded.
    for t in [5.0, 6.0, 7.0] {
        client.send_to(csv_state(t, -t).as_bytes(), to).unwrap();
    }
    let deadline = Instant::now() + Duration::from_secs(5);
    // Wait until all three are queued, then drain once.
    std::thread::sleep(Duration::from_millis(50));
    let mut last = None;
    while rx.stats().accepted < 7 {
        if let Some(x) = rx.latest() {
            last = Some(x);
        }
        assert!(Instant::now() < deadline);
    }
    let (s, received) = last.unwrap();
    assert_eq!(s.t, 7.0);
    assert_eq!(s.camera_position.z, -7.0);
    assert!(received <= Instant::now());
    // 5 and 6 were handed out only if they arrived in separate drains.
    assert!(rx.stats().superseded <= 2);
}

/// Datagrams sent faster than they are read overflow the socket's receive
/// buffer; the kernel's drop count (Linux) accounts for every datagram that
/// the receiver never saw: seen + dropped by the kernel = sent.
#[test]
fn kernel_drops_account_for_what_the_receive_buffer_lost() {
    let mut rx = UdpStateReceiver::bind(
        "127.0.0.1:0".parse().unwrap(),
        "127.0.0.1:0".parse().unwrap(),
    )
    .unwrap();
    let to = rx.local_addr().unwrap();
    let client = UdpSocket::bind("127.0.0.1:0").unwrap();
    assert_eq!(
        rx.kernel_drops(),
        Some(0),
        "a fresh socket has dropped nothing"
    );
    // ~1 KB each: 20 000 of them are far more than a default receive
    // buffer holds.
    let pad = " ".repeat(900);
    let sent = 20_000u64;
    for i in 0..sent {
        let line = csv_state(i as f64, -1e7);
        client
            .send_to(format!("{}{pad}", line.trim_end()).as_bytes(), to)
            .unwrap();
    }
    // Drain everything still queued.
    let mut quiet = 0;
    while quiet < 50 {
        let before = rx.stats().total();
        rx.latest();
        quiet = if rx.stats().total() == before {
            quiet + 1
        } else {
            0
        };
        std::thread::sleep(Duration::from_millis(1));
    }
    let drops = rx.kernel_drops().expect("Linux reports the drops");
    let seen = rx.stats().total();
    assert!(drops > 0, "nothing dropped: seen {seen}");
    assert_eq!(seen + drops, sent, "seen {seen} + dropped {drops}");
}
