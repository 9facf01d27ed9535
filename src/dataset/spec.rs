//! The dataset spec (TOML, docs/DATASETS.md) and the pure function from
//! (spec, item index) to the item: its poses, noise seed and directory.

use std::path::{Path, PathBuf};

use glam::{DMat3, DQuat, DVec3};
use serde::Deserialize;
use sha2::{Digest, Sha256};

use crate::error::{toml_message, Error, Result};
use crate::facility::trajectory::Trajectory;
use crate::scene::{Scene, State};

/// Most items one spec may list.
pub const MAX_ITEMS: usize = 10_000_000;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SpecFile {
    dataset: DatasetTable,
    poses: PosesTable,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct DatasetTable {
    scene: PathBuf,
    count: Option<usize>,
    seed: u64,
    out: PathBuf,
    outputs: Vec<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PosesTable {
    trajectory: Option<PathBuf>,
    distance: Option<[f64; 2]>,
    phase_deg: Option<[f64; 2]>,
    #[serde(default)]
    roll_deg: Option<[f64; 2]>,
    #[serde(default)]
    jitter_deg: f64,
    #[serde(default)]
    random_body_attitude: bool,
}

/// Where the poses of the items come from.
#[derive(Clone, Debug)]
pub enum Poses {
    /// Item i is row i of a trajectory file.
    Trajectory(Vec<State>),
    /// Item i is drawn from these ranges with the seed and i.
    Sampled(Sampling),
}

/// Ranges the poses are drawn from (angles in radians).
#[derive(Clone, Copy, Debug)]
pub struct Sampling {
    /// Camera range from the body centre [m].
    pub distance: [f64; 2],
    /// Phase angle (Sun–body–camera) [rad].
    pub phase: [f64; 2],
    /// Roll about the boresight [rad].
    pub roll: [f64; 2],
    /// Largest pointing error: the boresight tilts off the body centre by
    /// an angle uniform in [0, jitter] [rad].
    pub jitter: f64,
    /// Draw the body's attitude uniformly over all rotations.
    pub random_body_attitude: bool,
}

/// What each item holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Outputs {
    /// radiance.tiff, electrons.tiff, dn.png, render.json.
    pub image: bool,
    /// The label files (src/labels).
    pub labels: bool,
}

/// A checked dataset spec.
#[derive(Clone, Debug)]
pub struct Spec {
    /// The spec file.
    pub path: PathBuf,
    /// The scene every item starts from.
    pub scene: Scene,
    /// The scene's epoch text.
    pub epoch: Option<String>,
    /// Items.
    pub count: usize,
    /// Seed of the poses and noise.
    pub seed: u64,
    /// Output directory.
    pub out: PathBuf,
    /// Files per item.
    pub outputs: Outputs,
    /// Pose source.
    pub poses: Poses,
    /// SHA-256 (hex) of the spec, scene and trajectory texts: an item
    /// records it, and is only reused under the same hash.
    pub hash: String,
}

/// One item: everything that is a function of (spec, index).
#[derive(Clone, Debug, PartialEq)]
pub struct Item {
    /// Index in 0..count.
    pub index: usize,
    /// Poses.
    pub state: State,
    /// Seed of the item's detector noise.
    pub noise_seed: u64,
    /// Directory name under `out/items/`.
    pub name: String,
}

fn invalid(path: &Path, key: &str, message: impl std::fmt::Display) -> Error {
    Error::parse(path, format!("`{key}`: {message}"))
}

/// `[lo, hi]` finite with lo ≤ hi, inside [min, max].
fn range(path: &Path, key: &str, r: [f64; 2], min: f64, max: f64) -> Result<[f64; 2]> {
    if !(r[0].is_finite() && r[1].is_finite()) || r[0] > r[1] || r[0] < min || r[1] > max {
        return Err(invalid(
            path,
            key,
            format!(
                "[{}, {}] must be finite, low ≤ high, within [{min}, {max}]",
                r[0], r[1]
            ),
        ));
    }
    Ok(r)
}

impl Spec {
    /// Reads and checks a spec file; relative paths resolve against its
    /// directory; `out` overrides `dataset.out`.
    pub fn from_file(path: &Path, out: Option<&Path>) -> Result<Spec> {
        let text = crate::infile::read_text_bounded(path, crate::infile::CONFIG_LIMIT)?;
        Spec::from_toml(&text, path, out)
    }

    /// Parses spec text; `path` names it in errors and anchors paths.
    pub fn from_toml(text: &str, path: &Path, out: Option<&Path>) -> Result<Spec> {
        let file: SpecFile =
            toml::from_str(text).map_err(|e| Error::parse(path, toml_message(text, &e)))?;
        let base = path.parent().unwrap_or(Path::new("."));
        let d = &file.dataset;
        let outputs = parse_outputs(path, &d.outputs)?;
        let scene_path = base.join(&d.scene);
        let scene = Scene::from_file(&scene_path).map_err(|e| invalid(path, "dataset.scene", e))?;
        let epoch = crate::scene::epoch_text(&scene_path)?;
        let mut hasher = Sha256::new();
        hasher.update(text.as_bytes());
        hasher.update(std::fs::read(&scene_path).map_err(|e| Error::io(&scene_path, e))?);
        if let Some(lens) = &scene.camera.distortion {
            // The lens file is part of what an item depends on.
            hasher.update(format!("{:?}", lens.intrinsics).as_bytes());
        }
        let poses = parse_poses(path, base, &file.poses, &scene, &mut hasher)?;
        let count = match (&poses, d.count) {
            (Poses::Trajectory(s), None) => s.len(),
            (Poses::Trajectory(s), Some(c)) if c > s.len() => {
                return Err(invalid(
                    path,
                    "dataset.count",
                    format!("{c} items but the trajectory has {} states", s.len()),
                ))
            }
            (_, Some(c)) => c,
            (Poses::Sampled(_), None) => {
                return Err(invalid(
                    path,
                    "dataset.count",
                    "required with sampled poses",
                ))
            }
        };
        if count == 0 || count > MAX_ITEMS {
            return Err(invalid(
                path,
                "dataset.count",
                format!("{count} must be within [1, {MAX_ITEMS}]"),
            ));
        }
        Ok(Spec {
            path: path.to_path_buf(),
            scene,
            epoch,
            count,
            seed: d.seed,
            out: out.map_or_else(|| base.join(&d.out), Path::to_path_buf),
            outputs,
            poses,
            hash: hex(&hasher.finalize()),
        })
    }

    /// Item `index` (< count): a pure function of the spec and the index.
    pub fn item(&self, index: usize) -> Item {
        let state = match &self.poses {
            Poses::Trajectory(states) => states[index],
            Poses::Sampled(s) => sample_state(s, &self.scene.state, self.seed, index),
        };
        Item {
            index,
            state,
            noise_seed: mix(self.seed ^ mix(index as u64 ^ NOISE_STREAM)),
            name: format!("{index:07}"),
        }
    }
}

fn parse_outputs(path: &Path, names: &[String]) -> Result<Outputs> {
    let mut o = Outputs {
        image: false,
        labels: false,
    };
    for n in names {
        match n.as_str() {
            "image" => o.image = true,
            "labels" => o.labels = true,
            other => {
                return Err(invalid(
                    path,
                    "dataset.outputs",
                    format!(
                        "unknown output `{}` (known: image, labels)",
                        crate::error::abbreviate(other, 40)
                    ),
                ))
            }
        }
    }
    if !(o.image || o.labels) {
        return Err(invalid(
            path,
            "dataset.outputs",
            "name at least one of image, labels",
        ));
    }
    Ok(o)
}

fn parse_poses(
    path: &Path,
    base: &Path,
    p: &PosesTable,
    scene: &Scene,
    hasher: &mut Sha256,
) -> Result<Poses> {
    let sampled = p.distance.is_some() || p.phase_deg.is_some() || p.roll_deg.is_some();
    if let Some(t) = &p.trajectory {
        if sampled || p.jitter_deg != 0.0 || p.random_body_attitude {
            return Err(invalid(
                path,
                "poses.trajectory",
                "give either a trajectory or sampled ranges, not both",
            ));
        }
        let tpath = base.join(t);
        let text = crate::infile::read_text_bounded(&tpath, crate::infile::DATA_LIMIT)?;
        hasher.update(text.as_bytes());
        let traj = Trajectory::parse(&text, &tpath)?;
        let states = traj
            .states
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let st = State {
                    body_position: s.body_position.unwrap_or(scene.state.body_position),
                    body_attitude: s.body_attitude.unwrap_or(scene.state.body_attitude),
                    camera_position: s.camera_position,
                    camera_attitude: s.camera_attitude,
                    sun_position: s.sun_position,
                    occulter: scene.state.occulter,
                };
                st.check(
                    scene.body.radius,
                    &format!("{}: state {i}", tpath.display()),
                )?;
                Ok(st)
            })
            .collect::<Result<Vec<_>>>()?;
        return Ok(Poses::Trajectory(states));
    }
    let (Some(distance), Some(phase)) = (p.distance, p.phase_deg) else {
        return Err(invalid(
            path,
            "poses",
            "give `trajectory`, or both `distance` and `phase_deg`",
        ));
    };
    let radius = scene.body.radius;
    let sun_range = (scene.state.sun_position - scene.state.body_position).length();
    let distance = range(
        path,
        "poses.distance",
        distance,
        radius * (1.0 + 1e-9),
        sun_range * 0.5,
    )?;
    let phase = range(path, "poses.phase_deg", phase, 0.0, 180.0)?;
    let roll = range(
        path,
        "poses.roll_deg",
        p.roll_deg.unwrap_or([0.0, 360.0]),
        -360.0,
        360.0,
    )?;
    let jitter = range(path, "poses.jitter_deg", [p.jitter_deg; 2], 0.0, 90.0)?[0];
    Ok(Poses::Sampled(Sampling {
        distance,
        phase: phase.map(f64::to_radians),
        roll: roll.map(f64::to_radians),
        jitter: jitter.to_radians(),
        random_body_attitude: p.random_body_attitude,
    }))
}

/// Stream constants: the pose and noise draws of an item never share
/// random numbers.
const POSE_STREAM: u64 = 0x706f_7365;
const NOISE_STREAM: u64 = 0x006e_6f69_7365;

/// SplitMix64's finaliser: a bijective mix of 64 bits.
pub fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Uniform draws in [0, 1) from (seed, index).
struct Draws(u64);

impl Draws {
    fn next(&mut self) -> f64 {
        self.0 = mix(self.0);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    fn within(&mut self, r: [f64; 2]) -> f64 {
        r[0] + (r[1] - r[0]) * self.next()
    }
}

/// The sampled poses of item `index`: the Sun and body as in the scene;
/// the camera at a drawn range and phase, at a drawn azimuth about the
/// Sun line, pointing at the body with a drawn roll and pointing error.
fn sample_state(s: &Sampling, base: &State, seed: u64, index: usize) -> State {
    let mut d = Draws(mix(seed ^ mix(index as u64 ^ POSE_STREAM)));
    let to_sun = (base.sun_position - base.body_position).normalize();
    let (e1, e2) = to_sun.any_orthonormal_pair();
    let phase = d.within(s.phase);
    let azimuth = std::f64::consts::TAU * d.next();
    let dir = phase.cos() * to_sun + phase.sin() * (azimuth.cos() * e1 + azimuth.sin() * e2);
    let camera_position = base.body_position + d.within(s.distance) * dir;
    let z = -dir;
    let (a, b) = z.any_orthonormal_pair();
    let roll = d.within(s.roll);
    let x = roll.cos() * a + roll.sin() * b;
    let pointing = DQuat::from_mat3(&DMat3::from_cols(x, z.cross(x), z)).normalize();
    let tilt_axis = d.next() * std::f64::consts::TAU;
    let tilt = s.jitter * d.next();
    let jitter = DQuat::from_axis_angle(DVec3::new(tilt_axis.cos(), tilt_axis.sin(), 0.0), tilt);
    let body_attitude = if s.random_body_attitude {
        uniform_rotation(&mut d)
    } else {
        base.body_attitude
    };
    State {
        camera_position,
        camera_attitude: (pointing * jitter).normalize(),
        body_attitude,
        ..*base
    }
}

/// Shoemake's uniform random rotation.
fn uniform_rotation(d: &mut Draws) -> DQuat {
    let (u1, u2, u3) = (d.next(), d.next(), d.next());
    let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
    let (t2, t3) = (std::f64::consts::TAU * u2, std::f64::consts::TAU * u3);
    DQuat::from_xyzw(a * t2.sin(), a * t2.cos(), b * t3.sin(), b * t3.cos()).normalize()
}

/// Lower-case hex of bytes.
pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}
