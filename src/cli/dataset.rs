//! `optistim dataset SPEC`: render this process's shard of a dataset, or
//! `--merge` the shards into the manifest.

use std::path::PathBuf;

use anyhow::{Context, Result};

use optistim::dataset::{self, Spec};

/// Arguments of `optistim dataset`.
#[derive(clap::Args)]
pub struct DatasetArgs {
    /// Dataset spec (TOML, docs/DATASETS.md).
    pub spec: PathBuf,
    /// Render shard INDEX of COUNT (items i with i mod COUNT = INDEX).
    /// Without it: SLURM_ARRAY_TASK_ID/SLURM_ARRAY_TASK_COUNT, or
    /// JOB_COMPLETION_INDEX/OPTISTIM_SHARD_COUNT, or all items.
    #[arg(long, value_name = "INDEX/COUNT")]
    pub shard: Option<String>,
    /// Check that every item is present and verifies; write manifest.json
    /// (and coco.json with labels). Renders nothing.
    #[arg(long)]
    pub merge: bool,
    /// Output directory (replaces the spec's `dataset.out`).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Items rendered at once, one core each (default: the cores).
    #[arg(long)]
    pub jobs: Option<usize>,
    /// Seconds between progress lines.
    #[arg(long, default_value_t = 10.0)]
    pub progress_every: f64,
}

/// Runs the command; prints one verdict line on stdout.
pub fn dataset(args: &DatasetArgs) -> Result<()> {
    let spec = Spec::from_file(&args.spec, args.out.as_deref())?;
    if args.merge {
        if args.shard.is_some() {
            anyhow::bail!("--merge takes no --shard: it checks every item");
        }
        let n = dataset::merge(&spec)?;
        println!(
            "dataset {}: merged {n} items into {}: complete",
            args.spec.display(),
            spec.out.join("manifest.json").display()
        );
        return Ok(());
    }
    let shard = dataset::resolve_shard(args.shard.as_deref(), |k| std::env::var(k).ok())?;
    let jobs = args
        .jobs
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    if jobs == 0 || jobs > 4096 {
        anyhow::bail!("invalid `--jobs`: {jobs} must be within [1, 4096]");
    }
    if !(args.progress_every.is_finite() && args.progress_every >= 0.0) {
        anyhow::bail!("invalid `--progress-every`: must be finite and ≥ 0");
    }
    let start = std::time::Instant::now();
    let report = dataset::render_shard(&spec, shard, jobs, args.progress_every)
        .with_context(|| format!("dataset {}", args.spec.display()))?;
    let secs = start.elapsed().as_secs_f64();
    println!(
        "dataset {}: shard {}/{}: {} items, {} rendered, {} verified and kept, {:.2} s ({:.3} items/s with {jobs} jobs): done",
        args.spec.display(),
        shard.index,
        shard.count,
        report.items,
        report.rendered,
        report.reused,
        secs,
        report.rendered as f64 / secs.max(1e-9),
    );
    Ok(())
}
