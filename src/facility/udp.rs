//! Closed-loop state input: a non-blocking UDP receiver that accepts states
//! from one configured sender and hands the render loop the newest one.
//!
//! # Datagram format
//!
//! One datagram carries exactly one state, UTF-8, optionally ending in a
//! newline, in either form:
//!
//! * **CSV**: one line with all 18 fields in the fixed order of
//!   [`COLUMNS`](super::trajectory::COLUMNS):
//!   `t,cam_x,cam_y,cam_z,cam_qw,cam_qx,cam_qy,cam_qz,sun_x,sun_y,sun_z,body_x,body_y,body_z,body_qw,body_qx,body_qy,body_qz`
//!   (no header; the body fields may be empty, as whole groups).
//! * **JSON** (recognised by a leading `{`): see
//!   [`StateJson`](super::trajectory::StateJson), e.g.
//!   `{"t":1.0,"camera_position":[0,0,-1e7],"camera_attitude":[1,0,0,0],"sun_position":[1.5e11,0,0]}`.
//!
//! Units and conventions as in [`trajectory`](super::trajectory).
//!
//! # Acceptance
//!
//! * Datagrams from any address other than the configured sender are
//!   dropped (`foreign`). A sender port of 0 accepts any port of that IP.
//! * Malformed datagrams (bad UTF-8, wrong field count, non-number,
//!   non-finite, zero-norm quaternion, several lines) are dropped
//!   (`malformed`) and the reason is kept in [`UdpStateReceiver::last_rejection`].
//! * A state whose `t` is not strictly after the last accepted `t` is dropped
//!   (`stale`).
//! * [`UdpStateReceiver::latest`] drains everything queued; when several
//!   valid states arrived since the previous call the newest wins and the
//!   others count as `superseded` (they were accepted, just never rendered).

use std::net::{SocketAddr, UdpSocket};
use std::time::Instant;

use crate::error::{Error, Result};

use super::trajectory::State;

/// Counters of the receiver, since it was bound.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct UdpStats {
    /// Valid, in-order states.
    pub accepted: u64,
    /// Accepted states replaced by a newer one before being handed out.
    pub superseded: u64,
    /// States whose `t` was not after the last accepted one.
    pub stale: u64,
    /// Datagrams that failed to parse or validate.
    pub malformed: u64,
    /// Datagrams from another address than the configured sender.
    pub foreign: u64,
    /// Socket errors other than "no more data".
    pub socket_errors: u64,
}

impl UdpStats {
    /// Every datagram seen (accepted or not).
    pub fn total(&self) -> u64 {
        self.accepted + self.stale + self.malformed + self.foreign
    }

    /// Every datagram not accepted.
    pub fn dropped(&self) -> u64 {
        self.stale + self.malformed + self.foreign
    }
}

/// The `drops` column (the last) of the row of a /proc/net/udp table whose
/// `inode` column (the tenth) is `inode`.
fn drops_of_inode(table: &str, inode: &str) -> Option<u64> {
    table.lines().skip(1).find_map(|row| {
        let cols: Vec<&str> = row.split_whitespace().collect();
        (cols.len() >= 13 && cols[9] == inode).then(|| cols.last()?.parse().ok())?
    })
}

/// Parses one datagram payload (CSV or JSON form); the error is a reason.
pub fn parse_datagram(bytes: &[u8]) -> std::result::Result<State, String> {
    let text = std::str::from_utf8(bytes).map_err(|e| format!("not UTF-8: {e}"))?;
    let text = text.trim();
    if text.is_empty() {
        return Err("empty datagram".into());
    }
    let parsed = if text.starts_with('{') {
        State::from_json(text)
    } else {
        if text.contains('\n') {
            return Err("more than one line in a datagram".into());
        }
        State::from_csv_line(text)
    };
    parsed.map_err(|e| e.to_string())
}

/// Non-blocking UDP state receiver.
#[derive(Debug)]
pub struct UdpStateReceiver {
    socket: UdpSocket,
    sender: SocketAddr,
    last_t: Option<f64>,
    stats: UdpStats,
    last_rejection: Option<String>,
    buf: Vec<u8>,
    errors_logged: super::throttle::Throttle,
}

impl UdpStateReceiver {
    /// Binds `bind` and accepts datagrams only from `sender`.
    pub fn bind(bind: SocketAddr, sender: SocketAddr) -> Result<UdpStateReceiver> {
        let io = |e| Error::io(format!("udp://{bind}"), e);
        let socket = UdpSocket::bind(bind).map_err(io)?;
        socket.set_nonblocking(true).map_err(io)?;
        Ok(UdpStateReceiver {
            socket,
            sender,
            last_t: None,
            stats: UdpStats::default(),
            last_rejection: None,
            buf: vec![0; 65536],
            errors_logged: Default::default(),
        })
    }

    /// The bound address (useful when binding port 0).
    pub fn local_addr(&self) -> Result<SocketAddr> {
        self.socket
            .local_addr()
            .map_err(|e| Error::io("udp socket", e))
    }

    /// Datagrams the kernel dropped because the socket's receive buffer
    /// was full: the `drops` column of this socket's row in /proc/net/udp
    /// (or udp6), found by the socket's inode. `None` where the OS does not
    /// tell.
    pub fn kernel_drops(&self) -> Option<u64> {
        use std::os::fd::AsRawFd;
        let link = std::fs::read_link(format!("/proc/self/fd/{}", self.socket.as_raw_fd())).ok()?;
        let inode = link
            .to_str()?
            .strip_prefix("socket:[")?
            .strip_suffix(']')?
            .to_owned();
        ["/proc/net/udp", "/proc/net/udp6"]
            .iter()
            .filter_map(|p| std::fs::read_to_string(p).ok())
            .find_map(|table| drops_of_inode(&table, &inode))
    }

    /// Counters so far.
    pub fn stats(&self) -> UdpStats {
        self.stats
    }

    /// Reason the most recent datagram was rejected, if any was.
    pub fn last_rejection(&self) -> Option<&str> {
        self.last_rejection.as_deref()
    }

    /// `t` of the last accepted state.
    pub fn last_t(&self) -> Option<f64> {
        self.last_t
    }

    fn is_sender(&self, from: SocketAddr) -> bool {
        from.ip() == self.sender.ip()
            && (self.sender.port() == 0 || from.port() == self.sender.port())
    }

    /// Drains the socket without blocking and returns the newest valid
    /// in-order state received since the previous call, with the instant it
    /// was read. `None` when nothing new was accepted.
    pub fn latest(&mut self) -> Option<(State, Instant)> {
        let mut newest: Option<(State, Instant)> = None;
        loop {
            let (n, from) = match self.socket.recv_from(&mut self.buf) {
                Ok(x) => x,
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => break,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                Err(e) => {
                    // E.g. ICMP port unreachable reported on Linux: not fatal.
                    self.stats.socket_errors += 1;
                    if let Some(more) = self.errors_logged.hit(Instant::now()) {
                        tracing::warn!(more, "udp receive error: {e}");
                    }
                    if self.stats.socket_errors.is_multiple_of(1000) {
                        break;
                    }
                    continue;
                }
            };
            let received = Instant::now();
            if !self.is_sender(from) {
                self.stats.foreign += 1;
                self.last_rejection = Some(format!("foreign sender {from}"));
                continue;
            }
            let state = match parse_datagram(&self.buf[..n]) {
                Ok(s) => s,
                Err(reason) => {
                    self.stats.malformed += 1;
                    tracing::debug!("malformed state datagram: {reason}");
                    self.last_rejection = Some(reason);
                    continue;
                }
            };
            if let Some(last) = self.last_t {
                if state.t <= last {
                    self.stats.stale += 1;
                    self.last_rejection = Some(format!(
                        "stale state t = {} (last accepted {last})",
                        state.t
                    ));
                    continue;
                }
            }
            self.stats.accepted += 1;
            self.last_t = Some(state.t);
            if newest.replace((state, received)).is_some() {
                self.stats.superseded += 1;
            }
        }
        newest
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parse_datagram_forms_and_rejections() {
        let csv = "1,0,0,-1e7,1,0,0,0,1.5e11,0,0,,,,,,,\n";
        let s = parse_datagram(csv.as_bytes()).unwrap();
        assert_eq!(s.camera_position.z, -1e7);
        let json = r#"{"t":2,"camera_position":[0,0,1],"camera_attitude":[0,0,0,2],"sun_position":[1,0,0],"body_position":null}"#;
        let s = parse_datagram(json.as_bytes()).unwrap();
        assert_eq!(s.camera_attitude.z, 1.0);
        assert!(parse_datagram(b"").is_err());
        assert!(parse_datagram(&[0xff, 0xfe]).unwrap_err().contains("UTF-8"));
        assert!(parse_datagram(b"1,2,3").unwrap_err().contains("18"));
        assert!(parse_datagram(format!("{csv}{csv}").as_bytes())
            .unwrap_err()
            .contains("more than one line"));
        let inf = "1,0,0,inf,1,0,0,0,1.5e11,0,0,,,,,,,";
        assert!(parse_datagram(inf.as_bytes())
            .unwrap_err()
            .contains("cam_z"));
    }

    #[test]
    fn sender_port_zero_accepts_any_port_of_that_ip() {
        let r = UdpStateReceiver::bind(
            "127.0.0.1:0".parse().unwrap(),
            "127.0.0.1:0".parse().unwrap(),
        )
        .unwrap();
        assert!(r.is_sender("127.0.0.1:5555".parse().unwrap()));
        assert!(!r.is_sender("127.0.0.2:5555".parse().unwrap()));
    }
}
