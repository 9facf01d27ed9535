//! What the benchmark examples share: their positional arguments (each
//! with a default), the process's CPU time, and medians.
#![allow(dead_code)]

use std::path::PathBuf;
use std::str::FromStr;

/// The command line's positional arguments, read in order; a missing one
/// takes its default.
pub struct Positional(std::iter::Skip<std::env::Args>);

impl Positional {
    /// The arguments after the program's name.
    pub fn from_env() -> Self {
        Positional(std::env::args().skip(1))
    }

    /// The next argument as a path, or `default`.
    pub fn path(&mut self, default: &str) -> PathBuf {
        PathBuf::from(self.0.next().unwrap_or_else(|| default.into()))
    }

    /// The next argument parsed as a `T`, or `default`; the error names
    /// the argument (`name`, as the usage line spells it).
    pub fn value<T>(&mut self, name: &str, default: T) -> anyhow::Result<T>
    where
        T: FromStr,
        T::Err: std::fmt::Display,
    {
        match self.0.next() {
            None => Ok(default),
            Some(s) => s
                .parse()
                .map_err(|e| anyhow::anyhow!("{name}: {e} (got `{s}`)")),
        }
    }
}

/// The process's CPU time, all threads [ms]: steadier than wall time on
/// a loaded machine.
pub fn cpu_ms() -> f64 {
    let mut t = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes the timespec it is given.
    unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut t) };
    t.tv_sec as f64 * 1e3 + t.tv_nsec as f64 * 1e-6
}

/// The upper median of `v` (the middle element after sorting).
pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}
