//! A real Slurm job array renders a dataset: tools/dataset_sbatch.sh,
//! submitted as a 4-task array to the local cluster (tools/slurm_local.sh
//! start), gives after `--merge` the same bytes as one unsharded run.
//! Runs when `sbatch` answers; with OPTISTIM_REQUIRE_SLURM=1 a missing
//! cluster is a failure instead. The Kubernetes manifest's count and
//! completions are checked against each other here too.

mod common;
use common::file_tree as tree;
use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Whether a Slurm controller answers within 10 s.
fn slurm_answers() -> bool {
    Command::new("timeout")
        .args(["10", "sinfo", "-h"])
        .output()
        .is_ok_and(|o| o.status.success())
}

fn optistim(args: &[&str]) {
    let out = Command::new(env!("CARGO_BIN_EXE_optistim"))
        .args(args)
        .env("OPTISTIM_LOG", "warn")
        .env_remove("SLURM_ARRAY_TASK_ID")
        .env_remove("SLURM_ARRAY_TASK_COUNT")
        .env_remove("JOB_COMPLETION_INDEX")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn a_slurm_job_array_equals_the_unsharded_run() {
    let required = std::env::var("OPTISTIM_REQUIRE_SLURM").is_ok_and(|v| v == "1");
    if !slurm_answers() {
        assert!(
            !required,
            "OPTISTIM_REQUIRE_SLURM=1 but no Slurm cluster answers (tools/slurm_local.sh start)"
        );
        eprintln!("no Slurm cluster answers: job-array test not run (tools/slurm_local.sh start)");
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let spec_text = std::fs::read_to_string(root().join("configs/dataset/moon.toml"))
        .unwrap()
        .replace(
            "\"moon_scene.toml\"",
            &format!("{:?}", root().join("configs/dataset/moon_scene.toml")),
        );
    let spec = dir.join("spec.toml");
    std::fs::write(&spec, spec_text).unwrap();
    let (whole, array) = (dir.join("whole"), dir.join("array"));
    let s = |p: &Path| p.to_str().unwrap().to_string();
    optistim(&["dataset", &s(&spec), "--out", &s(&whole)]);
    optistim(&["dataset", &s(&spec), "--out", &s(&whole), "--merge"]);

    // `--wait`: sbatch returns when every task has ended, with the array's
    // worst exit status; `timeout` bounds a cluster that never runs it.
    let sbatch = Command::new("timeout")
        .args(["180", "sbatch", "--wait", "--array=0-3", "--chdir"])
        .arg(dir)
        .arg(format!("--output={}/task_%a.out", dir.display()))
        .arg(root().join("tools/dataset_sbatch.sh"))
        .args([
            s(&spec),
            s(&array),
            env!("CARGO_BIN_EXE_optistim").to_string(),
        ])
        .output()
        .unwrap();
    let log =
        |k: usize| std::fs::read_to_string(dir.join(format!("task_{k}.out"))).unwrap_or_default();
    assert!(
        sbatch.status.success(),
        "sbatch: {} {}; task 0: {}",
        String::from_utf8_lossy(&sbatch.stdout),
        String::from_utf8_lossy(&sbatch.stderr),
        log(0)
    );
    for k in 0..4 {
        assert!(
            log(k).contains(&format!("shard {k}/4: 2 items, 2 rendered")),
            "task {k}: {}",
            log(k)
        );
    }
    optistim(&["dataset", &s(&spec), "--out", &s(&array), "--merge"]);
    let (a, b) = (tree(&whole), tree(&array));
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    for (name, bytes) in &a {
        assert!(bytes == &b[name], "{name} differs");
    }
}

#[test]
fn the_indexed_job_passes_its_completions_as_the_shard_count() {
    let yaml = std::fs::read_to_string(root().join("tools/dataset_indexed_job.yaml")).unwrap();
    let value = |key: &str| -> String {
        let line = yaml
            .lines()
            .find(|l| l.trim_start().starts_with(key))
            .unwrap();
        line.split_once(':')
            .unwrap()
            .1
            .trim()
            .trim_matches('"')
            .to_string()
    };
    assert_eq!(value("completionMode"), "Indexed");
    let completions = value("completions");
    let i = yaml
        .find("name: OPTISTIM_SHARD_COUNT")
        .expect("OPTISTIM_SHARD_COUNT set");
    let count = yaml[i..]
        .lines()
        .nth(1)
        .unwrap()
        .split_once(':')
        .unwrap()
        .1
        .trim()
        .trim_matches('"');
    assert_eq!(count, completions);
    assert_eq!(value("parallelism"), completions);
}
