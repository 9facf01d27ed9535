//! Which shard this process renders: `--shard i/n`, else the scheduler's
//! variables. Slurm job arrays: `SLURM_ARRAY_TASK_ID` −
//! `SLURM_ARRAY_TASK_MIN` (0 when unset) of `SLURM_ARRAY_TASK_COUNT`.
//! Kubernetes Indexed Jobs: `JOB_COMPLETION_INDEX` of
//! `OPTISTIM_SHARD_COUNT` (the manifest sets it to the Job's
//! `completions`; Kubernetes does not expose that count to the pod).

use crate::error::{Error, Result};

/// Shard `index` of `count`: the items i with i mod count = index.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shard {
    /// 0-based shard index.
    pub index: usize,
    /// Number of shards.
    pub count: usize,
}

/// Most shards (beyond any scheduler's array size).
pub const MAX_SHARDS: usize = 1 << 20;

impl Shard {
    /// The whole dataset.
    pub const ALL: Shard = Shard { index: 0, count: 1 };

    /// Whether item `i` belongs to this shard.
    pub fn owns(&self, i: usize) -> bool {
        i % self.count == self.index
    }

    fn checked(index: i64, count: i64, source: &str) -> Result<Shard> {
        if count < 1 || count as usize > MAX_SHARDS {
            return Err(Error::invalid(
                source,
                format!("shard count {count} must be within [1, {MAX_SHARDS}]"),
            ));
        }
        if index < 0 || index >= count {
            return Err(Error::invalid(
                source,
                format!("shard index {index} must be within [0, {}]", count - 1),
            ));
        }
        Ok(Shard {
            index: index as usize,
            count: count as usize,
        })
    }

    /// Parses `i/n`.
    pub fn parse(text: &str) -> Result<Shard> {
        let bad = || {
            Error::invalid(
                "--shard",
                format!(
                    "`{}` is not INDEX/COUNT",
                    crate::error::abbreviate(text, 40)
                ),
            )
        };
        let (i, n) = text.split_once('/').ok_or_else(bad)?;
        let i: i64 = i.trim().parse().map_err(|_| bad())?;
        let n: i64 = n.trim().parse().map_err(|_| bad())?;
        Shard::checked(i, n, "--shard")
    }
}

/// The shard from the flag and the environment (`var` looks a variable
/// up): the flag, else Slurm's or Kubernetes' variables, else the whole
/// dataset. A flag and variables that disagree, Slurm and Kubernetes
/// variables that disagree, or an index without a count are errors.
pub fn resolve(flag: Option<&str>, var: impl Fn(&str) -> Option<String>) -> Result<Shard> {
    let flag = flag.map(Shard::parse).transpose()?;
    let slurm = from_slurm(&var)?;
    let k8s = from_kubernetes(&var)?;
    let mut found: Option<(Shard, &str)> = flag.map(|s| (s, "--shard"));
    for (s, name) in [
        (slurm, "SLURM_ARRAY_TASK_ID/COUNT"),
        (k8s, "JOB_COMPLETION_INDEX/OPTISTIM_SHARD_COUNT"),
    ] {
        let Some(s) = s else { continue };
        match found {
            Some((f, fname)) if f != s => {
                return Err(Error::invalid(
                    name,
                    format!(
                        "shard {}/{} contradicts {fname}'s {}/{}",
                        s.index, s.count, f.index, f.count
                    ),
                ))
            }
            Some(_) => {}
            None => found = Some((s, name)),
        }
    }
    Ok(found.map_or(Shard::ALL, |(s, _)| s))
}

fn number(var: &impl Fn(&str) -> Option<String>, name: &str) -> Result<Option<i64>> {
    var(name)
        .map(|v| {
            v.trim().parse::<i64>().map_err(|_| {
                Error::invalid(
                    name,
                    format!("`{}` is not an integer", crate::error::abbreviate(&v, 40)),
                )
            })
        })
        .transpose()
}

fn from_slurm(var: &impl Fn(&str) -> Option<String>) -> Result<Option<Shard>> {
    let id = number(var, "SLURM_ARRAY_TASK_ID")?;
    let count = number(var, "SLURM_ARRAY_TASK_COUNT")?;
    let min = number(var, "SLURM_ARRAY_TASK_MIN")?.unwrap_or(0);
    match (id, count) {
        (None, None) => Ok(None),
        (Some(id), Some(n)) => Shard::checked(id - min, n, "SLURM_ARRAY_TASK_ID").map(Some),
        _ => Err(Error::invalid(
            "SLURM_ARRAY_TASK_ID",
            "set SLURM_ARRAY_TASK_ID and SLURM_ARRAY_TASK_COUNT together",
        )),
    }
}

fn from_kubernetes(var: &impl Fn(&str) -> Option<String>) -> Result<Option<Shard>> {
    let id = number(var, "JOB_COMPLETION_INDEX")?;
    let count = number(var, "OPTISTIM_SHARD_COUNT")?;
    match (id, count) {
        (None, None) => Ok(None),
        (Some(id), Some(n)) => Shard::checked(id, n, "JOB_COMPLETION_INDEX").map(Some),
        _ => Err(Error::invalid(
            "JOB_COMPLETION_INDEX",
            "set JOB_COMPLETION_INDEX and OPTISTIM_SHARD_COUNT together",
        )),
    }
}
