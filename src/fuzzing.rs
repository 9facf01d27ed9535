//! Fuzzing entry points: every parser of user input behind one function
//! that takes arbitrary bytes, the real files that seed mutation, and a
//! small deterministic mutator. Used by the property tests
//! (`tests/fuzz_parsers.rs`, a modest case count in `cargo test`) and by
//! the long-run harness (`cargo run --release --example fuzz_parsers`),
//! which runs on stable Rust with no extra tooling.
//!
//! The contract checked: a parser returns `Ok` or an error; it never
//! panics, never hangs and never allocates beyond a stated bound.

use std::path::Path;

/// The parsers exercised.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Target {
    FacilityToml,
    SceneToml,
    Trajectory,
    EpochTrajectory,
    Lut,
    Geometry,
    Spectrum,
    Pds3Label,
    Pds3Image,
    UdpDatagram,
    SyncTemplate,
    SimClock,
    DarkModel,
    Responsivity,
    SimFacilityToml,
    CalibrateToml,
    DatasetSpec,
    StarCatalogue,
}

impl Target {
    /// Every target.
    pub const ALL: [Target; 18] = [
        Target::FacilityToml,
        Target::SceneToml,
        Target::Trajectory,
        Target::EpochTrajectory,
        Target::Lut,
        Target::Geometry,
        Target::Spectrum,
        Target::Pds3Label,
        Target::Pds3Image,
        Target::UdpDatagram,
        Target::SyncTemplate,
        Target::SimClock,
        Target::DarkModel,
        Target::Responsivity,
        Target::SimFacilityToml,
        Target::CalibrateToml,
        Target::DatasetSpec,
        Target::StarCatalogue,
    ];

    /// Short name for reports.
    pub fn name(self) -> &'static str {
        match self {
            Target::FacilityToml => "facility_toml",
            Target::SceneToml => "scene_toml",
            Target::Trajectory => "trajectory_csv",
            Target::EpochTrajectory => "epoch_trajectory_csv",
            Target::Lut => "lut_csv",
            Target::Geometry => "geometry_csv",
            Target::Spectrum => "spectrum_csv",
            Target::Pds3Label => "pds3_label",
            Target::Pds3Image => "pds3_image",
            Target::UdpDatagram => "udp_datagram",
            Target::SyncTemplate => "sync_template",
            Target::SimClock => "sim_clock_json",
            Target::DarkModel => "dark_model_toml",
            Target::Responsivity => "responsivity_toml",
            Target::SimFacilityToml => "simfacility_toml",
            Target::CalibrateToml => "calibrate_toml",
            Target::DatasetSpec => "dataset_spec",
            Target::StarCatalogue => "star_catalogue_csv",
        }
    }

    /// Real inputs to start mutation from (the bundled files).
    pub fn seeds(self) -> Vec<Vec<u8>> {
        let s = |b: &[u8]| b.to_vec();
        match self {
            Target::FacilityToml => vec![
                s(include_bytes!("../configs/facility.toml")),
                s(include_bytes!("../configs/facility_warped.toml")),
            ],
            // The bundled scenes' maps are not beside the scratch file, so
            // a self-contained scene seeds the checks past the maps.
            Target::SceneToml => vec![
                s(SCENE_SEED.as_bytes()),
                s(include_bytes!("../configs/moon.toml")),
                s(relief_scene_seed().as_bytes()),
            ],
            Target::Trajectory => vec![head(include_bytes!("../configs/moon_approach.csv"), 12)],
            Target::EpochTrajectory => vec![s(EPOCH_TRAJECTORY_SEED.as_bytes())],
            Target::Lut => vec![
                s(include_bytes!("../calib/example_lut.csv")),
                s(LUT_UNCERTAINTY_SEED.as_bytes()),
            ],
            Target::Geometry => vec![s(GEOMETRY_SEED.as_bytes())],
            Target::Spectrum => vec![head(include_bytes!("../data/solar/astm_e490_am0.csv"), 40)],
            // The label records (what the label parser reads) of both
            // AMIE files; for the image reader a 16×16 copy of one, so a
            // mutation costs microseconds, not a 0.5 MB image.
            Target::Pds3Label => vec![
                s(&AMIE_041028[..AMIE_LABEL_BYTES]),
                s(&AMIE_040819[..AMIE_LABEL_BYTES]),
            ],
            Target::Pds3Image => vec![small_amie()],
            Target::UdpDatagram => vec![
                s(b"1.5,0,0,-4e8,1,0,0,0,1.3e11,0,-7.5e10,0,0,0,0.5,0.5,0.5,-0.5\n"),
                s(br#"{"t":1.0,"camera_position":[0,0,-1e7],"camera_attitude":[1,0,0,0],"sun_position":[1.5e11,0,0]}"#),
            ],
            Target::SyncTemplate => vec![s(b"FRAME {id} {t} {exposure_us}\n")],
            Target::SimClock => vec![s(
                br#"{"format": "optistim-simclock-1", "seconds_since_power_on": 3600.0}"#,
            )],
            Target::DarkModel => vec![s(DARK_MODEL_SEED.as_bytes())],
            Target::Responsivity => vec![s(RESPONSIVITY_SEED.as_bytes())],
            Target::SimFacilityToml => vec![s(include_bytes!("../configs/simfacility.toml"))],
            Target::CalibrateToml => vec![s(include_bytes!("../configs/facility_calibrate.toml"))],
            Target::DatasetSpec => vec![s(DATASET_SEED.as_bytes())],
            Target::StarCatalogue => vec![head(
                include_bytes!("../data/stars/hipparcos_v7.5.csv"),
                20,
            )],
        }
    }

    /// Feeds `bytes` to the parser; `scratch` is a directory for the
    /// parsers that read files. Returns whether the input was accepted.
    pub fn run(self, bytes: &[u8], scratch: &Path) -> bool {
        use crate::facility as f;
        let text = String::from_utf8_lossy(bytes);
        let name = Path::new("fuzz.input");
        match self {
            Target::FacilityToml => f::config::FacilityConfig::parse(&text, name).is_ok(),
            // The relief seed's DEM, written beside the scene.
            Target::SceneToml => {
                write_seed_dem(scratch)
                    && crate::scene::Scene::from_toml(&text, &scratch.join("scene.toml")).is_ok()
            }
            Target::Trajectory => f::trajectory::Trajectory::parse(&text, name).is_ok(),
            // The analytic ephemeris: the parser's checks, no kernels needed.
            Target::EpochTrajectory => {
                let eph = crate::validate::ephem::Analytic;
                f::epoch_trajectory::parse(&text, name, &eph).is_ok()
            }
            Target::Lut => f::lut::DisplayLut::from_csv_bytes(bytes, name, 8).is_ok(),
            Target::Geometry => {
                f::geometry::GeometryCalibration::from_csv_bytes(bytes, name, (64, 32)).is_ok()
            }
            Target::Spectrum => {
                crate::radiometry::spectrum::Table::from_csv_bytes(bytes, name).is_ok()
            }
            Target::Pds3Label => crate::validate::pds3::Label::parse(bytes, name).is_ok(),
            Target::Pds3Image => crate::validate::pds3::parse_image(bytes, name).is_ok(),
            Target::UdpDatagram => f::udp::parse_datagram(bytes).is_ok(),
            Target::SyncTemplate => f::serial::CommandTemplate::parse(&text).is_ok(),
            Target::SimClock => {
                let path = scratch.join("clock.json");
                std::fs::write(&path, bytes).is_ok()
                    && crate::simfacility::clock::load(&path).is_ok()
            }
            Target::DarkModel => dark_model(bytes, scratch),
            Target::Responsivity => {
                crate::calibration::responsivity::CameraResponsivity::parse(&text, name).is_ok()
            }
            Target::SimFacilityToml => {
                crate::simfacility::config::SimFacilityConfig::parse(&text, name).is_ok()
            }
            Target::CalibrateToml => {
                crate::calibration::config::CalibrateConfig::parse(&text, name, 8).is_ok()
            }
            // The spec names `scene.toml` beside it: the self-contained seed scene.
            Target::DatasetSpec => {
                let scene = scratch.join("scene.toml");
                (scene.is_file() || std::fs::write(&scene, SCENE_SEED).is_ok())
                    && crate::dataset::Spec::from_toml(&text, &scratch.join("spec.toml"), None)
                        .is_ok_and(|s| s.item(s.count - 1).index + 1 == s.count)
            }
            Target::StarCatalogue => crate::stars::catalogue::parse(name, bytes).is_ok(),
        }
    }
}

/// A dark model file read beside two 4×4 16-bit dark frames written into
/// `scratch` (the seed's `d1.png` and `d2.png`).
fn dark_model(bytes: &[u8], scratch: &Path) -> bool {
    for (name, level) in [("d1.png", 100u16), ("d2.png", 120)] {
        let img = image::ImageBuffer::<image::Luma<u16>, _>::from_pixel(4, 4, image::Luma([level]));
        if img.save(scratch.join(name)).is_err() {
            return false;
        }
    }
    let path = scratch.join("dark.toml");
    std::fs::write(&path, bytes).is_ok()
        && crate::calibration::dark::DarkBank::from_file(&path, "cam").is_ok()
}

/// A LUT with its per-level expanded uncertainty column.
const LUT_UNCERTAINTY_SEED: &str = "drive_level,radiance_w_m2_sr,uncertainty_k2_percent\n\
0,0.001,8.0\n64,0.05,3.0\n128,0.25,1.5\n192,0.6,1.2\n255,1.1,1.2\n";

/// A dark model of two exposures.
const DARK_MODEL_SEED: &str = "camera = \"cam\"\nresolution = [4, 4]\nsaturation_dn = 65535.0\n\
[[frame]]\nexposure_s = 0.001\npath = \"d1.png\"\n\
[[frame]]\nexposure_s = 0.01\npath = \"d2.png\"\n";

/// A camera responsivity file as `sim-lab` writes it.
const RESPONSIVITY_SEED: &str = "responsivity_dn_per_s_per_w_m2_sr = 1.25e6\n\
uncertainty_k2_percent = 0.5\nregion_px = [40, 40, 48, 48]\n";
/// A dataset spec over [`SCENE_SEED`] (written beside it as `scene.toml`).
const DATASET_SEED: &str = r#"[dataset]
scene = "scene.toml"
count = 8
seed = 2026
out = "out"
outputs = ["image", "labels"]

[poses]
distance = [4.0e7, 9.0e7]
phase_deg = [10.0, 120.0]
roll_deg = [0.0, 360.0]
jitter_deg = 0.5
random_body_attitude = true
"#;

/// A scene that reads no file, with a sensor chain (its keys mutate too).
const SCENE_SEED: &str = r#"[camera]
resolution = [64, 48]
pixel_pitch = 13.3e-6
fov_deg = 6.0
f_number = 2.5
exposure = 2.0e-5
full_well = 1.0e5
bits = 12
band = [450e-9, 820e-9]

[camera.sensor]
seed = 3
dark_current = 20.0
read_noise = 5.0
nonlinearity = 0.01
row_noise = 1.5
shot_noise = true

[sun]
spectrum = "blackbody"
temperature = 5772.0

[body]
radius = 1737.4e3
reflectance = { model = "hapke", w = 0.3, b = 0.2, c = 0.5, theta_bar = 0.35, h_s = 0.06, b_s0 = 1.0 }

[state]
body_attitude = [0.5, 0.5, 0.5, -0.5]
camera_position = [0.0, 0.0, -8.2963e7]
camera_attitude = [1.0, 0.0, 0.0, 0.0]
sun_position = [7.48e10, 0.0, -1.29557e11]

[render]
caps_per_pixel = 1.5
node_spacing = 4
pixel_tolerance = 1.0e-3
shadow_edges = false
"#;

/// [`SCENE_SEED`] with a relief block over a DEM written beside it
/// ([`write_seed_dem`]): the shadows' and far limb's keys mutate too.
fn relief_scene_seed() -> String {
    SCENE_SEED.replacen(
        "[state]",
        "shadows = { dem = \"dem.tif\", scale = 1000.0, azimuths = 8, mode = \"always\", \
         displace = true, far_limb = true, cache_dir = \"cache\" }\n\n[state]",
        1,
    )
}

/// Writes the relief seed's DEM (8 × 4 cells, heights 0–1.5 km) into
/// `scratch` unless it is there.
fn write_seed_dem(scratch: &Path) -> bool {
    let path = scratch.join("dem.tif");
    let heights: Vec<f32> = (0..32).map(|k| (k % 7) as f32 * 0.25).collect();
    path.is_file() || crate::render::output::write_f32_tiff(&path, 8, 4, &heights).is_ok()
}

/// Two states of an epoch trajectory.
const EPOCH_TRAJECTORY_SEED: &str =
    "epoch,cam_x_km,cam_y_km,cam_z_km,cam_qw,cam_qx,cam_qy,cam_qz\n\
2004-08-19T23:42:43.134,1000,-2000,300000,1,0,0,0\n\
2004-08-19T23:45:43.134 TDB,1000,-2000,299000,0.5,0.5,0.5,-0.5\n";

/// A 3×3-node geometry lattice over a 64×32 screen.
const GEOMETRY_SEED: &str = "u_px,v_px,tan_x,tan_y\n\
0,0,-0.01,-0.005\n32,0,0,-0.005\n64,0,0.01,-0.005\n\
0,16,-0.01,0\n32,16,0,0\n64,16,0.01,0\n\
0,32,-0.01,0.005\n32,32,0,0.005\n64,32,0.01,0.005\n";

/// The first `n` lines of `bytes`.
const AMIE_041028: &[u8] = include_bytes!("../data/amie/AMI_EE3_041028_00101_00010.IMG");
const AMIE_040819: &[u8] = include_bytes!("../data/amie/AMI_EE3_040819_00208_00030.IMG");
/// LABEL_RECORDS × RECORD_BYTES of the AMIE files.
const AMIE_LABEL_BYTES: usize = 20 * 1024;

/// A valid AMIE file with 16×16 browse and main images: the real label
/// with its sizes, pointer and record count edited in place (same widths),
/// the browse image and every 32nd pixel of the real image.
fn small_amie() -> Vec<u8> {
    let label = String::from_utf8_lossy(&AMIE_041028[..AMIE_LABEL_BYTES]).into_owned();
    let edits = [
        (
            "FILE_RECORDS                   = 548",
            "FILE_RECORDS                   =  22",
        ),
        (
            "^IMAGE                         = 36865",
            "^IMAGE                         = 21505",
        ),
        (
            "LINES                       = 128",
            "LINES                       =  16",
        ),
        (
            "LINE_SAMPLES                = 128",
            "LINE_SAMPLES                =  16",
        ),
        (
            "LINES                       = 512",
            "LINES                       =  16",
        ),
        (
            "LINE_SAMPLES                = 512",
            "LINE_SAMPLES                =  16",
        ),
    ];
    let label = edits
        .iter()
        .fold(label, |l, (from, to)| l.replacen(from, to, 1));
    let mut out = label.into_bytes();
    let record = |out: &mut Vec<u8>, data: &[u8]| {
        out.extend_from_slice(data);
        out.resize(out.len().div_ceil(1024) * 1024, 0);
    };
    let browse: Vec<u8> = (0..256)
        .map(|k| AMIE_041028[20480 + (k / 16) * 8 * 128 + (k % 16) * 8])
        .collect();
    record(&mut out, &browse);
    let image: Vec<u8> = (0..256)
        .flat_map(|k| {
            let at = 36864 + 2 * ((k / 16) * 32 * 512 + (k % 16) * 32);
            [AMIE_041028[at], AMIE_041028[at + 1]]
        })
        .collect();
    record(&mut out, &image);
    out
}

fn head(bytes: &[u8], n: usize) -> Vec<u8> {
    let mut end = 0;
    for _ in 0..n {
        match bytes[end..].iter().position(|&b| b == b'\n') {
            Some(p) => end += p + 1,
            None => return bytes.to_vec(),
        }
    }
    bytes[..end].to_vec()
}

/// Tokens that have broken parsers before: extreme numbers, nesting,
/// encodings, separators.
const TOKENS: &[&str] = &[
    "1e308",
    "-1e308",
    "1e-300",
    "5e-324",
    "nan",
    "inf",
    "-0",
    "0",
    "-1",
    "18446744073709551616",
    "9223372036854775807",
    "4611686018427387904",
    "((((((((((",
    "}}}}",
    "\u{feff}",
    "\r\n",
    "\"",
    "'",
    ",,,,",
    "=",
    "[",
    "]",
    "{",
    "}",
    "<BYTES>",
    "END",
    "OBJECT = IMAGE",
    "\0",
    "é",
    "#",
];

/// xorshift64*: reproducible from a seed, no dependency.
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Rng {
        Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    /// Uniform in `0..n` (n > 0).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n as u64) as usize
    }
}

/// One to four random edits of `input`: byte flips, token insertions and
/// replacements, deletions and duplications of ranges.
pub fn mutate(input: &[u8], rng: &mut Rng) -> Vec<u8> {
    let mut out = input.to_vec();
    for _ in 0..1 + rng.below(4) {
        let len = out.len().max(1);
        let at = rng.below(len).min(out.len());
        match rng.below(6) {
            0 if !out.is_empty() => {
                let i = rng.below(out.len());
                out[i] ^= 1 << rng.below(8);
            }
            1 => {
                let t = TOKENS[rng.below(TOKENS.len())].as_bytes();
                out.splice(at..at, t.iter().copied());
            }
            2 => {
                // Replace a number-like run with a token.
                let end = (at + 1 + rng.below(24)).min(out.len());
                let t = TOKENS[rng.below(TOKENS.len())].as_bytes();
                out.splice(at..end, t.iter().copied());
            }
            3 => {
                let end = (at + rng.below(64)).min(out.len());
                out.drain(at..end);
            }
            4 => {
                let end = (at + rng.below(256)).min(out.len());
                let piece = out[at..end].to_vec();
                out.splice(at..at, piece);
            }
            _ => out.truncate(at),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The small seed is a valid file whose pixels are the real image's
    /// every 32nd (so mutations start from something the reader accepts).
    #[test]
    fn small_amie_is_the_real_image_subsampled() {
        let path =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("data/amie/AMI_EE3_041028_00101_00010.IMG");
        let real = crate::validate::pds3::read_image(&path).unwrap();
        let small = crate::validate::pds3::parse_image(&small_amie(), Path::new("small")).unwrap();
        assert_eq!(small.raw.len(), 256);
        for k in 0..256 {
            let (row, col) = (k / 16, k % 16);
            assert_eq!(
                small.raw[k],
                real.raw[row * 32 * 512 + col * 32],
                "pixel {k}"
            );
        }
        assert!(Target::Pds3Image.run(&small_amie(), Path::new(".")));
        assert!(Target::Pds3Label.run(&AMIE_040819[..AMIE_LABEL_BYTES], Path::new(".")));
    }
}
