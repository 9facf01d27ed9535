//! Rate limiting of warnings that can repeat every frame (no state, a sync
//! line not sent): the first is logged at once, the rest as a count at most
//! once per interval, so a lost device or a silent simulator does not flood
//! the log at the refresh rate.

use std::time::{Duration, Instant};

/// How often a repeated warning is summarised.
pub const SUMMARY_INTERVAL: Duration = Duration::from_secs(5);

/// One repeated warning's state.
#[derive(Debug)]
pub struct Throttle {
    interval: Duration,
    last_logged: Option<Instant>,
    suppressed: u64,
}

impl Default for Throttle {
    fn default() -> Self {
        Throttle::new(SUMMARY_INTERVAL)
    }
}

impl Throttle {
    /// A throttle that logs at most once per `interval`.
    pub fn new(interval: Duration) -> Throttle {
        Throttle {
            interval,
            last_logged: None,
            suppressed: 0,
        }
    }

    /// Records one occurrence at `now`. `Some(n)` means log it now, saying
    /// that `n` more occurred since the last one logged (0 for the first);
    /// `None` means stay quiet.
    pub fn hit(&mut self, now: Instant) -> Option<u64> {
        match self.last_logged {
            Some(t) if now.saturating_duration_since(t) < self.interval => {
                self.suppressed += 1;
                None
            }
            _ => {
                self.last_logged = Some(now);
                Some(std::mem::take(&mut self.suppressed))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 60 occurrences a second for 12 s log 3 times (0, 5, 10 s), and the
    /// counts add up to every occurrence.
    #[test]
    fn sixty_a_second_log_once_per_interval_with_counts() {
        let start = Instant::now();
        let mut t = Throttle::new(Duration::from_secs(5));
        let mut logged = Vec::new();
        for i in 0..720u64 {
            let now = start + Duration::from_nanos(i * 1_000_000_000 / 60);
            if let Some(n) = t.hit(now) {
                logged.push((i, n));
            }
        }
        assert_eq!(
            logged.iter().map(|l| l.0).collect::<Vec<_>>(),
            [0, 300, 600]
        );
        assert_eq!(
            logged.iter().map(|l| l.1).collect::<Vec<_>>(),
            [0, 299, 299]
        );
        let total: u64 =
            logged.len() as u64 + logged.iter().map(|l| l.1).sum::<u64>() + t.suppressed;
        assert_eq!(total, 720);
    }
}
