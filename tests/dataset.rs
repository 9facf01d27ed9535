//! `optistim dataset`: four shards give the same bytes as one run; a
//! killed shard (missing, corrupt or half-written items) resumes; the
//! Slurm and Kubernetes variables select the shard; bad specs and shards
//! are one-line errors; sampled poses stay inside their ranges.

mod common;
use common::file_tree as tree;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use glam::DVec3;
use optistim::dataset::{resolve_shard, Shard, Spec};
use optistim::fuzzing::{mutate, Rng};
use proptest::prelude::*;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The example spec with its scene path made absolute, written to `dir`.
fn spec_in(dir: &Path, extra_poses: &str) -> PathBuf {
    let text = std::fs::read_to_string(root().join("configs/dataset/moon.toml"))
        .unwrap()
        .replace(
            "\"moon_scene.toml\"",
            &format!("{:?}", root().join("configs/dataset/moon_scene.toml")),
        )
        + extra_poses;
    let path = dir.join("spec.toml");
    std::fs::write(&path, text).unwrap();
    path
}

fn optistim(args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_optistim"));
    cmd.args(args).env("OPTISTIM_LOG", "warn");
    for k in [
        "SLURM_ARRAY_TASK_ID",
        "SLURM_ARRAY_TASK_COUNT",
        "SLURM_ARRAY_TASK_MIN",
        "JOB_COMPLETION_INDEX",
        "OPTISTIM_SHARD_COUNT",
    ] {
        cmd.env_remove(k);
    }
    for (k, v) in env {
        cmd.env(k, v);
    }
    cmd.output().unwrap()
}

fn run_ok(args: &[&str], env: &[(&str, &str)]) -> String {
    let out = optistim(args, env);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{args:?} failed: {stderr}");
    String::from_utf8(out.stdout).unwrap()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn four_shards_equal_one_run_byte_for_byte() {
    let tmp = tempfile::tempdir().unwrap();
    let spec = spec_in(tmp.path(), "");
    let whole = tmp.path().join("whole");
    let sharded = tmp.path().join("sharded");
    run_ok(
        &["dataset", s(&spec), "--out", s(&whole), "--jobs", "2"],
        &[],
    );
    run_ok(&["dataset", s(&spec), "--out", s(&whole), "--merge"], &[]);
    for i in 0..4 {
        let shard = format!("{i}/4");
        // One job per shard: the bytes must not depend on the job count.
        let line = run_ok(
            &[
                "dataset",
                s(&spec),
                "--out",
                s(&sharded),
                "--shard",
                &shard,
                "--jobs",
                "1",
            ],
            &[],
        );
        assert!(line.contains("2 items, 2 rendered"), "{line}");
    }
    run_ok(&["dataset", s(&spec), "--out", s(&sharded), "--merge"], &[]);
    let (a, b) = (tree(&whole), tree(&sharded));
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
    // 8 items × 14 files, the manifest and the merged COCO file.
    assert_eq!(a.len(), 8 * 14 + 2);
    for (name, bytes) in &a {
        assert!(bytes == &b[name], "{name} differs between the runs");
    }
    // The manifest's hashes are those of the files (computed here).
    let manifest: serde_json::Value = serde_json::from_slice(&a["manifest.json"]).unwrap();
    use sha2::Digest;
    for item in manifest["items"].as_array().unwrap() {
        let dir = item["dir"].as_str().unwrap();
        for (f, h) in item["files"].as_object().unwrap() {
            let bytes = &a[&format!("{dir}/{f}")];
            let hex: String = sha2::Sha256::digest(bytes)
                .iter()
                .map(|b| format!("{b:02x}"))
                .collect();
            assert_eq!(h.as_str().unwrap(), hex, "{dir}/{f}");
        }
    }
    let coco: serde_json::Value = serde_json::from_slice(&a["coco.json"]).unwrap();
    assert_eq!(coco["images"].as_array().unwrap().len(), 8);
}

#[test]
fn a_killed_shard_resumes_from_what_verifies() {
    let tmp = tempfile::tempdir().unwrap();
    let spec = spec_in(tmp.path(), "");
    let out = tmp.path().join("out");
    let reference = tmp.path().join("reference");
    run_ok(&["dataset", s(&spec), "--out", s(&reference)], &[]);
    run_ok(
        &["dataset", s(&spec), "--out", s(&reference), "--merge"],
        &[],
    );
    run_ok(&["dataset", s(&spec), "--out", s(&out)], &[]);
    let items = out.join("items");
    // A kill's leftovers: items gone, one with a corrupt image, one
    // with a file missing, and a half-written temporary directory.
    std::fs::remove_dir_all(items.join("0000002")).unwrap();
    // A file where an item's directory belongs.
    std::fs::remove_dir_all(items.join("0000001")).unwrap();
    std::fs::write(items.join("0000001"), b"junk").unwrap();
    let mut dn = std::fs::read(items.join("0000004/dn.png")).unwrap();
    let last = dn.len() - 20;
    dn[last] ^= 0xff;
    std::fs::write(items.join("0000004/dn.png"), dn).unwrap();
    std::fs::remove_file(items.join("0000006/depth.tiff")).unwrap();
    std::fs::create_dir(items.join(".0000002.tmp.424242")).unwrap();
    std::fs::write(items.join(".0000002.tmp.424242/dn.png"), b"half").unwrap();
    // Merging now fails and names the first missing item.
    let merge = optistim(&["dataset", s(&spec), "--out", s(&out), "--merge"], &[]);
    let err = String::from_utf8_lossy(&merge.stderr);
    assert!(!merge.status.success());
    assert!(
        err.contains("4 of 8 items missing") && err.contains("first: 1, 2, 4, 6"),
        "{err}"
    );
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    let line = run_ok(&["dataset", s(&spec), "--out", s(&out)], &[]);
    assert!(
        line.contains("8 items, 4 rendered, 4 verified and kept"),
        "{line}"
    );
    assert!(!items.join(".0000002.tmp.424242").exists());
    run_ok(&["dataset", s(&spec), "--out", s(&out), "--merge"], &[]);
    assert_eq!(tree(&out), tree(&reference));
}

/// An environment of the given variables.
fn var<'a>(pairs: &'a [(&'a str, &'a str)]) -> impl Fn(&str) -> Option<String> + 'a {
    move |k: &str| {
        pairs
            .iter()
            .find(|(n, _)| *n == k)
            .map(|(_, v)| v.to_string())
    }
}

#[test]
fn scheduler_variables_select_the_shard() {
    let shard = |index, count| Shard { index, count };
    assert_eq!(resolve_shard(None, var(&[])).unwrap(), Shard::ALL);
    let slurm = [
        ("SLURM_ARRAY_TASK_ID", "2"),
        ("SLURM_ARRAY_TASK_COUNT", "4"),
    ];
    assert_eq!(resolve_shard(None, var(&slurm)).unwrap(), shard(2, 4));
    // An array 1-4 (`--array=1-4`): ids count from SLURM_ARRAY_TASK_MIN.
    let from_one = [
        ("SLURM_ARRAY_TASK_ID", "4"),
        ("SLURM_ARRAY_TASK_COUNT", "4"),
        ("SLURM_ARRAY_TASK_MIN", "1"),
    ];
    assert_eq!(resolve_shard(None, var(&from_one)).unwrap(), shard(3, 4));
    let k8s = [("JOB_COMPLETION_INDEX", "0"), ("OPTISTIM_SHARD_COUNT", "3")];
    assert_eq!(resolve_shard(None, var(&k8s)).unwrap(), shard(0, 3));
    // The flag agrees with the variables: fine; contradicts: an error.
    assert_eq!(
        resolve_shard(Some("2/4"), var(&slurm)).unwrap(),
        shard(2, 4)
    );
    let err = resolve_shard(Some("1/4"), var(&slurm))
        .unwrap_err()
        .to_string();
    assert!(err.contains("contradicts"), "{err}");
    let both = [
        ("SLURM_ARRAY_TASK_ID", "0"),
        ("SLURM_ARRAY_TASK_COUNT", "2"),
        ("JOB_COMPLETION_INDEX", "1"),
        ("OPTISTIM_SHARD_COUNT", "2"),
    ];
    assert!(resolve_shard(None, var(&both)).is_err());
    for bad in [
        &[("SLURM_ARRAY_TASK_ID", "1")][..],
        &[("OPTISTIM_SHARD_COUNT", "4")],
        &[("JOB_COMPLETION_INDEX", "4"), ("OPTISTIM_SHARD_COUNT", "4")],
        &[
            ("SLURM_ARRAY_TASK_ID", "x"),
            ("SLURM_ARRAY_TASK_COUNT", "4"),
        ],
        &[
            ("SLURM_ARRAY_TASK_ID", "0"),
            ("SLURM_ARRAY_TASK_COUNT", "0"),
        ],
    ] {
        assert!(resolve_shard(None, var(bad)).is_err(), "{bad:?} accepted");
    }
    for flag in ["4/4", "-1/4", "0/0", "1", "a/b", "1/2/3"] {
        assert!(
            resolve_shard(Some(flag), var(&[])).is_err(),
            "{flag} accepted"
        );
    }
    // Every item belongs to exactly one of n shards.
    for n in 1..6 {
        for i in 0..20 {
            assert_eq!((0..n).filter(|&k| shard(k, n).owns(i)).count(), 1);
        }
    }
}

#[test]
fn the_binary_reads_slurm_and_kubernetes_variables() {
    let tmp = tempfile::tempdir().unwrap();
    let spec = spec_in(tmp.path(), "");
    let slurm = tmp.path().join("slurm");
    let env = [
        ("SLURM_ARRAY_TASK_ID", "1"),
        ("SLURM_ARRAY_TASK_COUNT", "4"),
    ];
    let line = run_ok(&["dataset", s(&spec), "--out", s(&slurm)], &env);
    assert!(line.contains("shard 1/4: 2 items"), "{line}");
    let names: Vec<String> = std::fs::read_dir(slurm.join("items"))
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect::<std::collections::BTreeSet<_>>()
        .into_iter()
        .collect();
    assert_eq!(names, ["0000001", "0000005"]);
    let k8s = tmp.path().join("k8s");
    let env = [("JOB_COMPLETION_INDEX", "2"), ("OPTISTIM_SHARD_COUNT", "3")];
    let line = run_ok(&["dataset", s(&spec), "--out", s(&k8s)], &env);
    assert!(line.contains("shard 2/3: 2 items"), "{line}");
    // A flag contradicting the variables is refused before any work.
    let out = optistim(
        &["dataset", s(&spec), "--out", s(&k8s), "--shard", "0/3"],
        &env,
    );
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("contradicts") && err.trim().lines().count() == 1,
        "{err}"
    );
}

#[test]
fn bad_specs_are_one_line_errors_naming_the_key() {
    let tmp = tempfile::tempdir().unwrap();
    let cases: [(&str, &str, &str); 7] = [
        ("count = 8", "count = 8\ncolour = 3", "colour"),
        (
            "phase_deg = [10.0, 120.0]",
            "phase_deg = [120.0, 10.0]",
            "poses.phase_deg",
        ),
        (
            "phase_deg = [10.0, 120.0]",
            "phase_deg = [10.0, 190.0]",
            "poses.phase_deg",
        ),
        (
            "distance = [4.0e7, 9.0e7]",
            "distance = [1.0e6, 9.0e7]",
            "poses.distance",
        ),
        ("count = 8", "count = 0", "dataset.count"),
        ("jitter_deg = 0.5", "jitter_deg = nan", "poses.jitter_deg"),
        (
            "[\"image\", \"labels\"]",
            "[\"image\", \"depth\"]",
            "dataset.outputs",
        ),
    ];
    let base = std::fs::read_to_string(spec_in(tmp.path(), "")).unwrap();
    for (from, to, key) in cases {
        assert!(base.contains(from), "{from}");
        let path = tmp.path().join("bad.toml");
        std::fs::write(&path, base.replace(from, to)).unwrap();
        let out = optistim(
            &["dataset", s(&path), "--out", s(&tmp.path().join("o"))],
            &[],
        );
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{to} accepted");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(err.contains("bad.toml") && err.contains(key), "{to}: {err}");
    }
    let spec = spec_in(tmp.path(), "");
    let out = optistim(&["dataset", s(&spec), "--shard", "8/8"], &[]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("--shard"), "{err}");
    assert!(!tmp.path().join("items").exists());
}

/// The camera's range and phase and its pointing error, from the poses.
fn geometry(spec: &Spec, i: usize) -> (f64, f64, f64) {
    let st = spec.item(i).state;
    let to_cam = st.camera_position - st.body_position;
    let to_sun = st.sun_position - st.body_position;
    let boresight = st.camera_attitude * DVec3::Z;
    (
        to_cam.length(),
        to_cam.angle_between(to_sun).to_degrees(),
        boresight.angle_between(-to_cam).to_degrees(),
    )
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    #[test]
    fn sampled_poses_stay_in_their_ranges(
        seed in any::<u64>(),
        d0 in 2.0e6f64..1.0e9, dspan in 0.0f64..1.0e9,
        p0 in 0.0f64..180.0, pspan in 0.0f64..180.0,
        jitter in 0.0f64..10.0,
    ) {
        let tmp = tempfile::tempdir().unwrap();
        let p1 = (p0 + pspan).min(180.0);
        let text = std::fs::read_to_string(spec_in(tmp.path(), "")).unwrap()
            .replace("seed = 2026", &format!("seed = {}", seed >> 1))
            .replace("[4.0e7, 9.0e7]", &format!("[{d0:e}, {:e}]", d0 + dspan))
            .replace("[10.0, 120.0]", &format!("[{p0}, {p1}]"))
            .replace("jitter_deg = 0.5", &format!("jitter_deg = {jitter}"));
        let path = tmp.path().join("p.toml");
        let spec = Spec::from_toml(&text, &path, None).unwrap();
        let again = Spec::from_toml(&text, &path, None).unwrap();
        for i in 0..spec.count {
            prop_assert_eq!(spec.item(i), again.item(i));
            let (range, phase, off) = geometry(&spec, i);
            prop_assert!(range >= d0 * (1.0 - 1e-12) && range <= (d0 + dspan) * (1.0 + 1e-12));
            prop_assert!(phase >= p0 - 1e-6 && phase <= p1 + 1e-6, "{} not in [{}, {}]", phase, p0, p1);
            prop_assert!(off <= jitter + 1e-6);
            prop_assert!(spec.item(i).state.check(1737.4e3, "item").is_ok());
        }
    }

    #[test]
    fn mutated_specs_never_panic(seed in any::<u64>()) {
        let tmp = tempfile::tempdir().unwrap();
        let text = std::fs::read_to_string(spec_in(tmp.path(), "")).unwrap();
        let mut rng = Rng::new(seed);
        let bytes = mutate(text.as_bytes(), &mut rng);
        let text = String::from_utf8_lossy(&bytes);
        if let Ok(spec) = Spec::from_toml(&text, &tmp.path().join("m.toml"), None) {
            prop_assert!(spec.count >= 1);
            let _ = spec.item(spec.count - 1);
        }
    }
}

#[test]
fn trajectory_rows_are_the_items() {
    let tmp = tempfile::tempdir().unwrap();
    let csv = root().join("configs/moon_approach.csv");
    let base = std::fs::read_to_string(spec_in(tmp.path(), "")).unwrap();
    let poses_at = base.find("[poses]").unwrap();
    let head = base[..poses_at].replace("count = 8\n", "");
    let text = format!("{head}[poses]\ntrajectory = {csv:?}\n");
    let path = tmp.path().join("t.toml");
    let spec = Spec::from_toml(&text, &path, None).unwrap();
    // Columns t, cam_x, cam_y, cam_z, ... read here by hand.
    let rows: Vec<Vec<f64>> = std::fs::read_to_string(&csv)
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!(spec.count, rows.len());
    for i in [0, 7, rows.len() - 1] {
        let st = spec.item(i).state;
        assert_eq!(
            st.camera_position,
            DVec3::new(rows[i][1], rows[i][2], rows[i][3])
        );
        assert_eq!(
            st.sun_position,
            DVec3::new(rows[i][8], rows[i][9], rows[i][10])
        );
    }
    // More items than rows, and both pose sources, are errors.
    let more = text.replace("seed =", &format!("count = {}\nseed =", rows.len() + 1));
    let err = Spec::from_toml(&more, &path, None).unwrap_err().to_string();
    assert!(err.contains("dataset.count"), "{err}");
    let both = format!("{text}phase_deg = [10.0, 20.0]\n");
    let err = Spec::from_toml(&both, &path, None).unwrap_err().to_string();
    assert!(err.contains("poses.trajectory"), "{err}");
}
