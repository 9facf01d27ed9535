//! `optistim dataset`: many rendered and labelled frames from one spec,
//! sharded over processes. [`spec`] reads the spec and makes item i a pure
//! function of (spec, i); [`shard`] says which items this process owns
//! (flag, Slurm or Kubernetes variables); [`run`] renders, resumes and
//! merges. docs/DATASETS.md documents the spec and the files.

pub mod run;
pub mod shard;
pub mod spec;

pub use run::{merge, render_shard, verify, ShardReport};
pub use shard::{resolve as resolve_shard, Shard};
pub use spec::{Item, Spec};
