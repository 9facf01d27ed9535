//! `optistim plot-log`: the timing figure of a frame log written by
//! `optistim run` ([`optistim::facility::timing`]).

use std::path::PathBuf;

use anyhow::{bail, Context, Result};

use optistim::facility::log::read_records;
use optistim::facility::timing::{runs, write_timing_figure, RunTiming};

/// Arguments of `optistim plot-log`.
#[derive(clap::Args)]
pub struct PlotLogArgs {
    /// Frame log (JSON lines) of `optistim run --log`.
    pub log: PathBuf,
    /// Output directory for `timing.png` (default: the log's directory).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Replace an earlier `timing.png`.
    #[arg(long)]
    pub overwrite: bool,
    /// Run id to plot (a log may hold several runs); default: the last.
    #[arg(long)]
    pub run: Option<String>,
}

/// `optistim plot-log`.
pub fn plot_log(args: &PlotLogArgs) -> Result<()> {
    let records = read_records(&args.log)?;
    let ids = runs(&records);
    let run = match (&args.run, ids.last()) {
        (Some(r), _) if ids.contains(r) => r.clone(),
        (Some(r), _) => bail!(
            "{}: no run `{r}` (runs: {})",
            args.log.display(),
            ids.join(", ")
        ),
        (None, Some(last)) => last.clone(),
        (None, None) => bail!("{}: no complete frame record", args.log.display()),
    };
    let out = args.out.clone().unwrap_or_else(|| {
        args.log
            .parent()
            .filter(|d| !d.as_os_str().is_empty())
            .map_or_else(|| PathBuf::from("."), PathBuf::from)
    });
    let path = out.join("timing.png");
    optistim::outfile::check_no_earlier(std::slice::from_ref(&path), args.overwrite)?;
    let timing = RunTiming::of_run(&records, &run);
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    write_timing_figure(&path, &timing)?;
    let l = timing.latency_ms;
    tracing::info!(
        runs_in_log = ids.len(),
        frames = timing.frames,
        missed = timing.missed,
        p50_ms = l.p50.map(|v| format!("{v:.2}")),
        p99_ms = l.p99.map(|v| format!("{v:.2}")),
        "run {run}: wrote {}",
        path.display()
    );
    Ok(())
}
