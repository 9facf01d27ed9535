//! Time scales and low-precision analytic ephemerides, enough to rebuild the
//! geometry of an AMIE image from its label without SPICE kernels:
//!
//! - UTC text → Julian date, UTC → TT by hifitime (calendar and the IERS
//!   leap seconds; TDB is taken equal to TT, the difference is below 2 ms).
//! - Geocentric Sun, J2000 equator: the low-accuracy solar theory of
//!   J. Meeus, *Astronomical Algorithms* (2nd ed., 1998), ch. 25 (geometric
//!   longitude good to ~0.01°, radius to ~1e-5 au), referred to the J2000
//!   equinox with Meeus' `-0.01397°/yr` correction. No aberration is applied:
//!   for illumination the geometric direction is the right one (the Sun's
//!   aberration of 20" is below the accuracy of the label values anyway).
//! - Geocentric Moon, J2000 equator: the low-precision formulae of the
//!   *Astronomical Almanac* (section D, "Low-precision formulae for the
//!   Moon's coordinates"), ~0.3° in longitude, ~0.2° in latitude, ~0.003° in
//!   parallax, i.e. ~2000 km. At the Sun's distance that moves the Sun's
//!   selenocentric direction by < 0.001°.
//! - Moon orientation: the IAU WGCCRE 2009 rotation model (Archinal et al.,
//!   *Celest. Mech. Dyn. Astr.* 109, 101–135, 2011, table 2; identical to
//!   NAIF's `pck00010.tpc` `BODY301_*`), pole α0, δ0 and prime meridian W
//!   with the 13 nutation/libration arguments E1..E13. It realises the Mean
//!   Earth/polar axis frame to ~150 m on the surface.
//! - Greenwich mean sidereal time (IAU 1982, Meeus eq. 12.4), only to check
//!   the label's Earth-fixed spacecraft vector.

use glam::{DMat3, DVec3};

use crate::ephemeris::{Ephemeris, Epoch};
use crate::error::{Error, Result};

/// Julian date of J2000.0 (2000-01-01T12:00 TT).
pub const JD_J2000: f64 = 2_451_545.0;
/// Astronomical unit, m (IAU 2012).
pub const AU_M: f64 = 149_597_870_700.0;
/// Mean obliquity of the ecliptic at J2000, degrees (IAU 1980 value used by
/// Meeus and by SPICE's `ECLIPJ2000`).
pub const OBLIQUITY_J2000_DEG: f64 = 23.439_291_1;
/// Earth equatorial radius used by the Almanac's lunar parallax, m.
pub const EARTH_RADIUS_AA_M: f64 = 6_378_140.0;

/// A UTC calendar instant; its time scales come from hifitime.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Utc {
    pub year: i32,
    pub month: u32,
    pub day: u32,
    pub hour: u32,
    pub minute: u32,
    pub second: f64,
    epoch: Epoch,
}

impl Utc {
    /// Parses `YYYY-MM-DDThh:mm:ss[.fff][Z]` (also `YYYY-DDDThh:mm:ss`, day of year).
    pub fn parse(text: &str) -> Result<Utc> {
        let bad = |m: &str| Error::invalid("time", format!("`{text}`: {m}"));
        let t = text.trim().trim_end_matches('Z');
        let (date, time) = t
            .split_once('T')
            .ok_or_else(|| bad("expected `T` between date and time"))?;
        let d: Vec<&str> = date.split('-').collect();
        let (year, month, day) = match d.as_slice() {
            [y, m, dd] => (
                y.parse::<i32>().map_err(|_| bad("bad year"))?,
                m.parse::<u32>().map_err(|_| bad("bad month"))?,
                dd.parse::<u32>().map_err(|_| bad("bad day"))?,
            ),
            [y, doy] => {
                let y: i32 = y.parse().map_err(|_| bad("bad year"))?;
                let doy: u32 = doy.parse().map_err(|_| bad("bad day of year"))?;
                let leap = (y % 4 == 0 && y % 100 != 0) || y % 400 == 0;
                let lens = [
                    31,
                    if leap { 29 } else { 28 },
                    31,
                    30,
                    31,
                    30,
                    31,
                    31,
                    30,
                    31,
                    30,
                    31,
                ];
                let mut rem = doy;
                let mut m = 1;
                for l in lens {
                    if rem <= l {
                        break;
                    }
                    rem -= l;
                    m += 1;
                }
                if doy == 0 || m > 12 {
                    return Err(bad("day of year out of range"));
                }
                (y, m, rem)
            }
            _ => return Err(bad("expected YYYY-MM-DD")),
        };
        let tp: Vec<&str> = time.split(':').collect();
        if tp.len() != 3 {
            return Err(bad("expected hh:mm:ss"));
        }
        let hour: u32 = tp[0].parse().map_err(|_| bad("bad hour"))?;
        let minute: u32 = tp[1].parse().map_err(|_| bad("bad minute"))?;
        let second: f64 = tp[2].parse().map_err(|_| bad("bad second"))?;
        if !(1..=12).contains(&month)
            || !(1..=31).contains(&day)
            || hour > 23
            || minute > 59
            || !(0.0..61.0).contains(&second)
        {
            return Err(bad("field out of range"));
        }
        let whole = second.floor();
        let nanos = ((second - whole) * 1e9).round().min(999_999_999.0) as u32;
        let epoch = Epoch::maybe_from_gregorian_utc(
            year,
            month as u8,
            day as u8,
            hour as u8,
            minute as u8,
            whole as u8,
            nanos,
        )
        .map_err(|_| bad("not a date in the calendar"))?;
        Ok(Utc {
            year,
            month,
            day,
            hour,
            minute,
            second,
            epoch,
        })
    }

    /// Julian date on the UTC time scale.
    pub fn jd_utc(&self) -> f64 {
        self.epoch.to_jde_utc_days()
    }

    /// TAI − UTC in whole seconds, from hifitime's UTC → TT conversion
    /// (its `leap_seconds()` compares on the TAI scale and so reads one
    /// second high in the last half-minute before a leap second).
    pub fn tai_minus_utc(&self) -> f64 {
        let tt_minus_utc = (self.epoch.to_jde_tt_days() - self.epoch.to_jde_utc_days()) * 86_400.0;
        (tt_minus_utc - 32.184).round()
    }

    /// Julian date on the TT (≈ TDB) scale.
    pub fn jd_tt(&self) -> f64 {
        self.epoch.to_jde_tt_days()
    }
}

fn ecliptic_to_j2000(lon_rad: f64, lat_rad: f64, r: f64) -> DVec3 {
    let eps = OBLIQUITY_J2000_DEG.to_radians();
    let (x, y, z) = (
        r * lat_rad.cos() * lon_rad.cos(),
        r * lat_rad.cos() * lon_rad.sin(),
        r * lat_rad.sin(),
    );
    DVec3::new(
        x,
        y * eps.cos() - z * eps.sin(),
        y * eps.sin() + z * eps.cos(),
    )
}

/// Geocentric position of the Sun (m, J2000 equator and equinox) at `jd_tt`.
/// Meeus ch. 25 low-accuracy theory (see module doc).
pub fn sun_geocentric_j2000(jd_tt: f64) -> DVec3 {
    let t = (jd_tt - JD_J2000) / 36_525.0;
    let l0 = 280.466_46 + 36_000.769_83 * t + 0.000_303_2 * t * t;
    let m = (357.529_11 + 35_999.050_29 * t - 0.000_153_7 * t * t).to_radians();
    let e = 0.016_708_634 - 0.000_042_037 * t - 0.000_000_126_7 * t * t;
    let c = (1.914_602 - 0.004_817 * t - 0.000_014 * t * t) * m.sin()
        + (0.019_993 - 0.000_101 * t) * (2.0 * m).sin()
        + 0.000_289 * (3.0 * m).sin();
    let nu = m + c.to_radians();
    let r_au = 1.000_001_018 * (1.0 - e * e) / (1.0 + e * nu.cos());
    // Mean equinox of date -> J2000 (Meeus 25: -0.01397 deg per year).
    let lon = l0 + c - 0.013_97 * (100.0 * t);
    ecliptic_to_j2000(lon.to_radians(), 0.0, r_au * AU_M)
}

/// Geocentric position of the Moon (m, J2000 equator and equinox) at `jd_tt`.
/// Astronomical Almanac low-precision formulae (see module doc).
pub fn moon_geocentric_j2000(jd_tt: f64) -> DVec3 {
    let t = (jd_tt - JD_J2000) / 36_525.0;
    let s = |a: f64| a.to_radians().sin();
    let c = |a: f64| a.to_radians().cos();
    let lon = 218.32 + 481_267.881 * t + 6.29 * s(135.0 + 477_198.87 * t)
        - 1.27 * s(259.3 - 413_335.36 * t)
        + 0.66 * s(235.7 + 890_534.22 * t)
        + 0.21 * s(269.9 + 954_397.74 * t)
        - 0.19 * s(357.5 + 35_999.05 * t)
        - 0.11 * s(186.5 + 966_404.03 * t);
    let lat = 5.13 * s(93.3 + 483_202.02 * t) + 0.28 * s(228.2 + 960_400.89 * t)
        - 0.28 * s(318.3 + 6_003.15 * t)
        - 0.17 * s(217.6 - 407_332.21 * t);
    let parallax = 0.9508
        + 0.0518 * c(135.0 + 477_198.87 * t)
        + 0.0095 * c(259.3 - 413_335.36 * t)
        + 0.0078 * c(235.7 + 890_534.22 * t)
        + 0.0028 * c(269.9 + 954_397.74 * t);
    let r = EARTH_RADIUS_AA_M / parallax.to_radians().sin();
    ecliptic_to_j2000(
        (lon - 0.013_97 * (100.0 * t)).to_radians(),
        lat.to_radians(),
        r,
    )
}

/// Position of the Sun relative to the Moon's centre (m, J2000) at `jd_tt`.
pub fn sun_from_moon_j2000(jd_tt: f64) -> DVec3 {
    sun_geocentric_j2000(jd_tt) - moon_geocentric_j2000(jd_tt)
}

/// IAU 2009 rotation elements of the Moon at `jd_tdb`: pole right ascension
/// α0, declination δ0 and prime meridian W, all in degrees.
pub fn moon_rotation_elements_deg(jd_tdb: f64) -> (f64, f64, f64) {
    // Nutation/libration arguments E1..E13: constant (deg) and rate (deg per
    // Julian century), pck00010.tpc BODY3_NUT_PREC_ANGLES.
    const E: [(f64, f64); 13] = [
        (125.045, -1_935.536_452_5),
        (250.089, -3_871.072_905),
        (260.008, 475_263.332_872_5),
        (176.625, 487_269.629_985),
        (357.529, 35_999.050_957_5),
        (311.589, 964_468.499_31),
        (134.963, 477_198.869_325),
        (276.617, 12_006.300_765),
        (34.226, 63_863.513_242_5),
        (15.134, -5_806.609_357_5),
        (119.743, 131.840_64),
        (239.961, 6_003.150_382_5),
        (25.053, 473_327.796_42),
    ];
    const RA: [f64; 13] = [
        -3.8787, -0.1204, 0.0700, -0.0172, 0.0, 0.0072, 0.0, 0.0, 0.0, -0.0052, 0.0, 0.0, 0.0043,
    ];
    const DEC: [f64; 13] = [
        1.5419, 0.0239, -0.0278, 0.0068, 0.0, -0.0029, 0.0009, 0.0, 0.0, 0.0008, 0.0, 0.0, -0.0009,
    ];
    const PM: [f64; 13] = [
        3.5610, 0.1208, -0.0642, 0.0158, 0.0252, -0.0066, -0.0047, -0.0046, 0.0028, 0.0052, 0.0040,
        0.0019, -0.0044,
    ];
    let d = jd_tdb - JD_J2000;
    let t = d / 36_525.0;
    let mut a0 = 269.9949 + 0.0031 * t;
    let mut d0 = 66.5392 + 0.0130 * t;
    let mut w = 38.3213 + 13.176_358_15 * d - 1.4e-12 * d * d;
    for i in 0..13 {
        let e = (E[i].0 + E[i].1 * t).to_radians();
        a0 += RA[i] * e.sin();
        d0 += DEC[i] * e.cos();
        w += PM[i] * e.sin();
    }
    (a0, d0, w.rem_euclid(360.0))
}

/// Rotation matrix taking Moon body-fixed vectors (IAU_MOON: z = north pole,
/// x = prime meridian) to J2000 at `jd_tdb`. The inverse is
/// `Rz(W) · Rx(90° − δ0) · Rz(90° + α0)` (frame rotations).
pub fn moon_body_to_j2000(jd_tdb: f64) -> DMat3 {
    let (a0, d0, w) = moon_rotation_elements_deg(jd_tdb);
    // Active rotations: body -> J2000 = Rz(90+a0) * Rx(90-d0) * Rz(W).
    DMat3::from_rotation_z((90.0 + a0).to_radians())
        * DMat3::from_rotation_x((90.0 - d0).to_radians())
        * DMat3::from_rotation_z(w.to_radians())
}

/// Greenwich mean sidereal time, degrees in [0, 360), at `jd_ut1` (UTC is
/// used for UT1; |UT1 − UTC| < 0.9 s, i.e. < 0.004°).
pub fn gmst_deg(jd_ut1: f64) -> f64 {
    let d = jd_ut1 - JD_J2000;
    let t = d / 36_525.0;
    (280.460_618_37 + 360.985_647_366_29 * d + 0.000_387_933 * t * t - t * t * t / 38_710_000.0)
        .rem_euclid(360.0)
}

/// Planetocentric latitude and east longitude (degrees, longitude in
/// [0, 360)) of the direction `v` in a body-fixed frame.
pub fn lat_lon_deg(v: DVec3) -> (f64, f64) {
    let u = v.normalize();
    (
        u.z.clamp(-1.0, 1.0).asin().to_degrees(),
        u.y.atan2(u.x).to_degrees().rem_euclid(360.0),
    )
}

/// Unit vector for right ascension / declination in degrees.
pub fn radec_to_unit(ra_deg: f64, dec_deg: f64) -> DVec3 {
    let (ra, dec) = (ra_deg.to_radians(), dec_deg.to_radians());
    DVec3::new(dec.cos() * ra.cos(), dec.cos() * ra.sin(), dec.sin())
}

/// Right ascension in [0, 360) and declination, degrees, of `v`.
pub fn unit_to_radec(v: DVec3) -> (f64, f64) {
    let u = v.normalize();
    (
        u.y.atan2(u.x).to_degrees().rem_euclid(360.0),
        u.z.clamp(-1.0, 1.0).asin().to_degrees(),
    )
}

/// Rotation taking vectors on the mean equator and equinox of date to
/// J2000, IAU 1976 precession (Lieske et al., *Astron. Astrophys.* 58, 1–16,
/// 1977; Meeus eq. 21.2–21.4): `Rz(−z) Ry(θ) Rz(−ζ)`.
pub fn precession_mean_of_date_to_j2000(jd_tt: f64) -> DMat3 {
    let t = (jd_tt - JD_J2000) / 36_525.0;
    let arcsec = |v: f64| (v / 3600.0).to_radians();
    let zeta = arcsec(2306.2181 * t + 0.30188 * t * t + 0.017998 * t * t * t);
    let z = arcsec(2306.2181 * t + 1.09468 * t * t + 0.018203 * t * t * t);
    let theta = arcsec(2004.3109 * t - 0.42665 * t * t - 0.041833 * t * t * t);
    DMat3::from_rotation_z(-z) * DMat3::from_rotation_y(theta) * DMat3::from_rotation_z(-zeta)
}

/// Rotation taking the label's Earth-fixed vectors (`SMART1:AMIE_SC_EFRF_VECTOR`)
/// to J2000: Greenwich mean sidereal time about the pole of date, then
/// precession to J2000. Nutation (≤ 17″) and polar motion are neglected;
/// UT1 is taken equal to UTC (|UT1 − UTC| < 0.9 s). Checked on both AMIE
/// images against DE421: the geocentric Moon rebuilt as
/// `R · efrf + SC_TARGET_POSITION_VECTOR` is within ~30 km
/// (`tests/validate_pipeline.rs`), against ~900 km for the analytic Moon.
pub fn earth_fixed_to_j2000(jd_utc: f64, jd_tt: f64) -> DMat3 {
    precession_mean_of_date_to_j2000(jd_tt) * DMat3::from_rotation_z(gmst_deg(jd_utc).to_radians())
}

/// The analytic theories above behind the [`Ephemeris`] seam, for
/// comparison with the SPICE kernels (`crate::ephemeris::Spice`).
pub struct Analytic;

impl Ephemeris for Analytic {
    fn name(&self) -> &'static str {
        "analytic (Meeus Sun, Almanac Moon, IAU 2009 rotation)"
    }

    fn moon_from_earth(&self, t: Epoch) -> Result<DVec3> {
        Ok(moon_geocentric_j2000(t.to_jde_tt_days()))
    }

    fn sun_from_moon(&self, t: Epoch) -> Result<DVec3> {
        Ok(sun_from_moon_j2000(t.to_jde_tt_days()))
    }

    fn moon_to_j2000(&self, t: Epoch) -> Result<DMat3> {
        Ok(moon_body_to_j2000(t.to_jde_tt_days()))
    }
}
