//! Epochs and ephemerides: an epoch (UTC or TDB text) → the Sun and Moon
//! positions and the Moon's orientation, in J2000 (ICRF) axes, metres.
//!
//! [`Ephemeris`] is the seam: [`Spice`] reads JPL SPK and binary PCK
//! kernels with `anise` (DE421 and `moon_pa_de421_1900-2050.bpc`, fetched
//! by `tools/fetch_kernels.sh`); the low-precision analytic one lives in
//! `validate::ephem` (it needs no files).
//!
//! The Moon's body frame is the Mean Earth/polar axis frame (`MOON_ME`),
//! the frame of the lunar maps. The kernels give the principal-axes frame
//! (`MOON_PA_DE421`, BPC frame 31006); ME is PA turned by the constant
//! rotation of `moon_080317.tf` (frame 31007), built in here because anise
//! does not read text frame kernels. Leap seconds come from hifitime's
//! table, which has the 2017-01-01 leap second that `naif0011.tls` (2015)
//! lacks, so after 2017 CSPICE with that file is 1 s behind;
//! before 1972 SPICE assumes TAI − UTC = 9 s where hifitime takes 0 s, so
//! UTC epochs before 1972 are 9 s later than CSPICE's `str2et` makes them.

use std::path::{Path, PathBuf};

pub use anise::prelude::Epoch;
use anise::prelude::{Almanac, Frame};
use glam::{DMat3, DVec3};

use crate::error::{abbreviate, Error, Result};

/// NAIF ids.
pub const SUN: i32 = 10;
pub const EARTH: i32 = 399;
pub const MOON: i32 = 301;
/// J2000 frame id.
const J2000: i32 = 1;
/// `MOON_PA_DE421`: the principal-axes frame of the lunar BPC.
pub const MOON_PA_DE421: i32 = 31006;

/// `TKFRAME_31007_ANGLES` of `moon_080317.tf`: MOON_ME_DE421 relative to
/// MOON_PA_DE421, arcseconds, about axes (3, 2, 1).
const ME_FROM_PA_ARCSEC: [f64; 3] = [67.92, 78.56, 0.30];

/// File names `tools/fetch_kernels.sh` writes, loaded by [`Spice::from_dir`].
pub const KERNEL_FILES: [&str; 2] = ["de421.bsp", "moon_pa_de421_1900-2050.bpc"];

/// Sun and Moon geometry at an epoch.
pub trait Ephemeris {
    /// A short name for reports.
    fn name(&self) -> &'static str;
    /// Moon centre relative to the Earth centre, J2000, m (geometric).
    fn moon_from_earth(&self, t: Epoch) -> Result<DVec3>;
    /// Sun centre relative to the Moon centre, J2000, m (geometric).
    fn sun_from_moon(&self, t: Epoch) -> Result<DVec3>;
    /// Rotation of Moon body-fixed (Mean Earth/polar axis) vectors into J2000.
    fn moon_to_j2000(&self, t: Epoch) -> Result<DMat3>;
}

/// Parses an epoch: ISO `YYYY-MM-DDThh:mm:ss[.fff]`, UTC unless followed by
/// a time scale (` UTC`, ` TDB`, ` TT`, ` TAI`); `field` names it in errors.
pub fn parse_epoch(text: &str, field: &str) -> Result<Epoch> {
    let t = text.trim();
    let bad = |why: &str| {
        Error::invalid(
            field,
            format!(
                "`{}`: {why} (expected e.g. `2004-08-19T23:42:43.134` or `... TDB`)",
                abbreviate(t, 60)
            ),
        )
    };
    // hifitime also reads `JD ...`/`SEC ...`; a scene takes calendar text only.
    let looks_iso = t.len() >= 19
        && t.len() <= 64
        && t.as_bytes()[..4].iter().all(u8::is_ascii_digit)
        && t.as_bytes()[4] == b'-';
    if !looks_iso {
        return Err(bad("not an ISO calendar epoch"));
    }
    let epoch = Epoch::from_gregorian_str(t).map_err(|e| bad(&e.to_string()))?;
    let year = epoch.year();
    if !(1000..=3000).contains(&year) {
        return Err(bad("year outside 1000-3000"));
    }
    Ok(epoch)
}

/// Row-major 3×3 to glam's column-major matrix.
fn from_rows(r: [[f64; 3]; 3]) -> DMat3 {
    DMat3::from_cols_array_2d(&r).transpose()
}

/// SPICE's frame rotation `[θ]_axis` (axis 1, 2 or 3): the matrix taking
/// vectors to a frame turned by θ about that axis.
pub fn frame_rotation(angle_rad: f64, axis: usize) -> DMat3 {
    let (s, c) = angle_rad.sin_cos();
    match axis {
        1 => from_rows([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]]),
        2 => from_rows([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]]),
        _ => from_rows([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]]),
    }
}

/// MOON_ME → MOON_PA: `[a1]_3 [a2]_2 [a3]_1` with the angles of
/// `moon_080317.tf` (SPICE's TK frame convention; checked against CSPICE's
/// `pxform` in `tests/ephemeris_spice.rs`).
pub fn moon_me_to_pa() -> DMat3 {
    let a = ME_FROM_PA_ARCSEC.map(|s| (s / 3600.0).to_radians());
    frame_rotation(a[0], 3) * frame_rotation(a[1], 2) * frame_rotation(a[2], 1)
}

/// SPK and binary PCK kernels read with anise.
pub struct Spice {
    almanac: Almanac,
    files: Vec<PathBuf>,
}

impl Spice {
    /// Loads SPK (`.bsp`) and binary PCK (`.bpc`) files; text kernels are
    /// refused (see the module doc for what replaces them).
    pub fn load(paths: &[PathBuf]) -> Result<Spice> {
        if paths.is_empty() {
            return Err(Error::Other("no SPICE kernels given".into()));
        }
        let mut almanac = Almanac::default();
        for p in paths {
            almanac = load_kernel(almanac, p)?;
        }
        Ok(Spice {
            almanac,
            files: paths.to_vec(),
        })
    }

    /// Loads [`KERNEL_FILES`] from `dir` (as written by `tools/fetch_kernels.sh`).
    pub fn from_dir(dir: &Path) -> Result<Spice> {
        let paths: Vec<PathBuf> = KERNEL_FILES.iter().map(|f| dir.join(f)).collect();
        Spice::load(&paths)
    }

    /// The kernel files loaded.
    pub fn files(&self) -> &[PathBuf] {
        &self.files
    }

    /// Geometric position of NAIF body `target` relative to `observer`,
    /// J2000, m. Errors name the bodies and the kernels' coverage.
    pub fn position(&self, target: i32, observer: i32, t: Epoch) -> Result<DVec3> {
        for id in [target, observer] {
            self.check_spk_coverage(id, t)?;
        }
        let s = self
            .almanac
            .translate_geometric(Frame::new(target, J2000), Frame::new(observer, J2000), t)
            .map_err(|e| {
                Error::Other(format!(
                    "SPK: no path from body {observer} to body {target} at {t}: {e}"
                ))
            })?;
        let r = s.radius_km;
        Ok(DVec3::new(r[0], r[1], r[2]) * 1e3)
    }

    /// Rotation of MOON_PA_DE421 vectors into J2000, from the BPC.
    pub fn moon_pa_to_j2000(&self, t: Epoch) -> Result<DMat3> {
        let (start, end) = self.almanac.bpc_domain(MOON_PA_DE421).map_err(|_| {
            Error::Other(format!(
                "no binary PCK with frame {MOON_PA_DE421} (MOON_PA_DE421) among {}",
                self.list()
            ))
        })?;
        if t < start || t > end {
            return Err(Error::Other(format!(
                "epoch {t} outside the Moon orientation kernel's coverage {start} .. {end}"
            )));
        }
        let dcm = self
            .almanac
            .rotation_to_parent(Frame::new(MOON, MOON_PA_DE421), t)
            .map_err(|e| Error::Other(format!("BPC frame {MOON_PA_DE421} at {t}: {e}")))?;
        // anise gives J2000 → PA; the body-to-world rotation is its transpose.
        let m = dcm.rot_mat;
        let j2000_to_pa = from_rows([
            [m[(0, 0)], m[(0, 1)], m[(0, 2)]],
            [m[(1, 0)], m[(1, 1)], m[(1, 2)]],
            [m[(2, 0)], m[(2, 1)], m[(2, 2)]],
        ]);
        Ok(j2000_to_pa.transpose())
    }

    fn check_spk_coverage(&self, id: i32, t: Epoch) -> Result<()> {
        if id == 0 {
            return Ok(()); // the solar-system barycentre is every chain's root
        }
        let (start, end) = self.almanac.spk_domain(id).map_err(|_| {
            Error::Other(format!(
                "no SPK segment for body {id} among {}",
                self.list()
            ))
        })?;
        if t < start || t > end {
            return Err(Error::Other(format!(
                "epoch {t} outside the SPK coverage of body {id}: {start} .. {end}"
            )));
        }
        Ok(())
    }

    fn list(&self) -> String {
        let names: Vec<String> = self.files.iter().map(|p| p.display().to_string()).collect();
        names.join(", ")
    }
}

impl Ephemeris for Spice {
    fn name(&self) -> &'static str {
        "SPICE kernels (anise)"
    }

    fn moon_from_earth(&self, t: Epoch) -> Result<DVec3> {
        self.position(MOON, EARTH, t)
    }

    fn sun_from_moon(&self, t: Epoch) -> Result<DVec3> {
        self.position(SUN, MOON, t)
    }

    fn moon_to_j2000(&self, t: Epoch) -> Result<DMat3> {
        Ok(self.moon_pa_to_j2000(t)? * moon_me_to_pa())
    }
}

/// Loads one binary kernel, refusing text kernels and non-DAF files with a
/// message naming the file.
fn load_kernel(almanac: Almanac, path: &Path) -> Result<Almanac> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let head = &bytes[..bytes.len().min(8)];
    if head != b"DAF/SPK " && head != b"DAF/PCK " {
        let what = if bytes.starts_with(b"KPL/") {
            "a text kernel: only SPK (.bsp) and binary PCK (.bpc) files are read"
        } else {
            "not a DAF/SPK or DAF/PCK file"
        };
        return Err(Error::parse(path, what));
    }
    almanac
        .load_from_bytes(bytes.as_slice().into())
        .map_err(|e| Error::parse(path, format!("cannot read the kernel: {e}")))
}
