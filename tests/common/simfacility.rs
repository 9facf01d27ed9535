//! The simulated facility's test fixtures: a small facility written as
//! TOML text (one base, each test naming only the keys it changes), the
//! bundled configuration, a uniform screen, and `optistim run` on the
//! simulated facility.

use std::path::{Path, PathBuf};
use std::process::Command;

use optistim::facility::display::Display;
use optistim::facility::lut::encode_grey;
use optistim::simfacility::{SimFacility, SimFacilityConfig};

/// The bundled simulated facility, `configs/simfacility.toml`.
pub fn bundled_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/simfacility.toml")
}

/// The bundled facility with each `(old, new)` text of `edits` replaced
/// (each `old` must stand in the file exactly once), its relative paths
/// resolved against `configs/`.
pub fn bundled_edited(edits: &[(&str, &str)]) -> SimFacility {
    let path = bundled_path();
    let mut text = std::fs::read_to_string(&path).unwrap();
    for (old, new) in edits {
        assert_eq!(text.matches(old).count(), 1, "{old} in the bundled file");
        text = text.replace(old, new);
    }
    let mut cfg = SimFacilityConfig::parse(&text, &path).unwrap();
    cfg.resolve_paths(path.parent().unwrap());
    SimFacility::new(cfg).unwrap()
}

/// The measured LCD white spectrum the bundled screen uses.
pub fn lcd_white_spectrum() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("data/display/lcd_white_apple_studio_display.csv")
}

/// A simulated-facility configuration as TOML sections of `key = value`
/// lines; `with` replaces a key where the section has it and adds it
/// otherwise, so a test states only what differs from `small()`.
#[derive(Clone)]
pub struct SimToml {
    /// (section name, "" for the top level; its (key, value) lines).
    sections: Vec<(String, Vec<(String, String)>)>,
}

impl SimToml {
    /// A 64×48 screen (0.1 mm, 60 Hz, γ 2.2, white 2 W m⁻² sr⁻¹, black
    /// 0.01, flat 380–780 nm spectrum) behind an ideal 0.5 m collimator
    /// (τ 0.8), a 40×30 camera at 4000 px (gain 0.05 DN/e⁻, full well
    /// 1e9 e⁻, 16 bits), a flat meter on the screen's centre; seed 7.
    pub fn small() -> Self {
        let mut t = SimToml {
            sections: Vec::new(),
        };
        t = t.with("", "seed = 7");
        t = t.with(
            "screen",
            "resolution = [64, 48]\nrefresh_hz = 60.0\npixel_pitch = 1.0e-4\ngamma = 2.2\n\
             max_radiance = 2.0\nblack_level = 0.01\nspectrum = \"flat\"",
        );
        t = t.with("collimator", "focal_length = 0.5\ntransmission = 0.8");
        t = t.with(
            "camera",
            "resolution = [40, 30]\nfx = 4000.0\nfy = 4000.0\ncx = 20.0\ncy = 15.0\n\
             focal_length = 0.05\nf_number = 4.0\nband_nm = [450.0, 820.0]\n\
             sun_spectrum = \"blackbody\"\nexposure = 0.01\ngain = 0.05\nfull_well = 1.0e9\nbits = 16",
        );
        t.with(
            "meter",
            "response = \"flat\"\nspot_center_px = [32.0, 24.0]\nspot_radius_px = 5.0",
        )
    }

    /// `small()` without shot noise, the one noise its defaults turn on:
    /// no noise and no non-uniformity.
    pub fn quiet() -> Self {
        Self::small().with("camera", "shot_noise = false")
    }

    /// The same with `seed`.
    pub fn seed(self, seed: u64) -> Self {
        self.with("", &format!("seed = {seed}"))
    }

    /// Sets each `key = value` line of `lines` in `section` (blank lines
    /// skipped): replaced where the key is there, added at the end if not.
    pub fn with(mut self, section: &str, lines: &str) -> Self {
        for line in lines.lines().map(str::trim).filter(|l| !l.is_empty()) {
            let (key, value) = line
                .split_once('=')
                .unwrap_or_else(|| panic!("not a `key = value` line: {line}"));
            let (key, value) = (key.trim().to_string(), value.trim().to_string());
            let keys = self.section(section);
            match keys.iter_mut().find(|(k, _)| *k == key) {
                Some(kv) => kv.1 = value,
                None => keys.push((key, value)),
            }
        }
        self
    }

    fn section(&mut self, name: &str) -> &mut Vec<(String, String)> {
        let at = match self.sections.iter().position(|(n, _)| n == name) {
            Some(at) => at,
            None => {
                self.sections.push((name.to_string(), Vec::new()));
                self.sections.len() - 1
            }
        };
        &mut self.sections[at].1
    }

    /// The TOML text: the top-level keys first, then each section.
    pub fn text(&self) -> String {
        let mut out = String::new();
        let mut ordered: Vec<_> = self.sections.iter().collect();
        ordered.sort_by_key(|(name, _)| !name.is_empty());
        for (name, keys) in ordered {
            if !name.is_empty() {
                out.push_str(&format!("[{name}]\n"));
            }
            for (k, v) in keys {
                out.push_str(&format!("{k} = {v}\n"));
            }
        }
        out
    }

    /// The facility, or the one-line error of its configuration (read as
    /// `test.toml`).
    pub fn try_facility(&self) -> optistim::Result<SimFacility> {
        SimFacilityConfig::parse(&self.text(), "test.toml").and_then(SimFacility::new)
    }

    /// The facility (the test's configuration is valid).
    pub fn facility(&self) -> SimFacility {
        self.try_facility().unwrap()
    }
}

/// Shows drive level `level` on the whole screen of `f`.
pub fn show_uniform(f: &SimFacility, level: u32) {
    let mut d = f.display();
    let (w, h) = d.size();
    d.present(&vec![encode_grey(level, 8); w * h]).unwrap();
}

/// A `w` × `h` screen frame, black but for a Gaussian blob (σ = 2 screen
/// px, radiance above black ∝ the Gaussian through the γ 2.2 drive)
/// centred on the pixel corner (du, dv), within 7 px of it.
pub fn gaussian_dot_frame(w: usize, h: usize, (du, dv): (usize, usize)) -> Vec<u32> {
    let mut frame = vec![encode_grey(0, 8); w * h];
    for y in dv - 7..dv + 7 {
        for x in du - 7..du + 7 {
            let r2 = (x as f64 + 0.5 - du as f64).powi(2) + (y as f64 + 0.5 - dv as f64).powi(2);
            let g = (-r2 / 8.0).exp();
            frame[y * w + x] = encode_grey((255.0 * g.powf(1.0 / 2.2)).round() as u32, 8);
        }
    }
    frame
}

/// `optistim run configs/facility.toml --frames N` on the bundled
/// simulated facility, capturing every `capture_every`-th frame, from the
/// crate's root; the test adds the output paths.
pub fn run_on_sim_facility(frames: u64, capture_every: u64) -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_optistim"));
    cmd.current_dir(env!("CARGO_MANIFEST_DIR"))
        .args(["run", "configs/facility.toml", "--frames"])
        .arg(frames.to_string())
        .args(SIM_FACILITY_ARGS)
        .arg("--capture-every")
        .arg(capture_every.to_string());
    cmd
}

/// The flags that put `optistim run` on the bundled simulated facility.
pub const SIM_FACILITY_ARGS: [&str; 4] = [
    "--display",
    "sim-facility",
    "--sim-facility",
    "configs/simfacility.toml",
];
