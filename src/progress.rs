//! Progress bars for long work (bench sweeps, calibration routines,
//! facility runs), drawn on stderr only when stderr is a terminal: a
//! redirected run writes no bar and no escape sequence.

use std::io::IsTerminal;

use indicatif::{ProgressBar, ProgressStyle};

/// A bar of `total` steps named `what` (position, ETA, a message), hidden
/// when stderr is not a terminal.
pub fn bar(total: u64, what: &str) -> ProgressBar {
    if !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    styled(
        ProgressBar::new(total),
        "{prefix} [{bar:30}] {pos}/{len} ETA {eta} {msg}",
        what,
    )
}

/// A counter for work of unknown length (a closed-loop run without
/// `--frames`), hidden when stderr is not a terminal.
pub fn counter(what: &str) -> ProgressBar {
    if !std::io::stderr().is_terminal() {
        return ProgressBar::hidden();
    }
    styled(
        ProgressBar::no_length(),
        "{prefix} {spinner} {pos} {elapsed} {msg}",
        what,
    )
}

fn styled(bar: ProgressBar, template: &str, what: &str) -> ProgressBar {
    let style = ProgressStyle::with_template(template)
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> ");
    bar.set_style(style);
    bar.set_prefix(what.to_string());
    bar
}
