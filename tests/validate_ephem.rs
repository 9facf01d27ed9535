//! Analytic ephemerides and time scales against JPL DE421.
//!
//! Reference numbers were computed once, offline, with Skyfield 1.x and the
//! DE421 kernel of the PyPI package `skyfield-data` (`de421.bsp`):
//! `ts.utc(...)`, `eph['sun'|'moon'|'earth'].at(t).position.km`, giving
//! geometric (no light time) ICRF ≈ J2000 vectors, km.
#![allow(clippy::needless_range_loop)]

use glam::DVec3;
use optistim::validate::ephem::{self, Utc};

struct Ref {
    utc: &'static str,
    jd_tt: f64,
    sun_geo_km: [f64; 3],
    moon_geo_km: [f64; 3],
}

const REFS: [Ref; 2] = [
    Ref {
        utc: "2004-08-19T23:42:43.134",
        jd_tt: 2453237.4887421066,
        sun_geo_km: [-127300880.60566588, 75134829.42873205, 32574216.351575132],
        moon_geo_km: [-371879.2684908211, -89061.75030979514, -25755.765368130058],
    },
    Ref {
        utc: "2004-10-28T02:05:10.920",
        jd_tt: 2453306.5876748147,
        sun_geo_km: [-121835174.63327982, -78086431.71795848, -33853454.39085555],
        moon_geo_km: [323012.87625080347, 202531.95939551294, 89416.24592161924],
    },
];

#[test]
fn utc_to_tt() {
    for r in &REFS {
        let t = Utc::parse(r.utc).unwrap();
        assert_eq!(t.tai_minus_utc(), 32.0);
        // 1e-8 day = 0.9 ms.
        assert!(
            (t.jd_tt() - r.jd_tt).abs() < 1e-8,
            "{} {}",
            t.jd_tt(),
            r.jd_tt
        );
    }
    assert_eq!(
        Utc::parse("2017-01-01T00:00:00").unwrap().tai_minus_utc(),
        37.0
    );
    assert_eq!(
        Utc::parse("2005-12-31T23:59:59").unwrap().tai_minus_utc(),
        32.0
    );
    assert_eq!(
        Utc::parse("2004-232T23:42:43.134").unwrap(),
        Utc::parse("2004-08-19T23:42:43.134").unwrap()
    );
    // The last half-minute before a leap second is still on the old offset.
    assert_eq!(
        Utc::parse("2005-12-31T23:59:40").unwrap().tai_minus_utc(),
        32.0
    );
    assert_eq!(
        Utc::parse("2006-01-01T00:00:00").unwrap().tai_minus_utc(),
        33.0
    );
    assert!(Utc::parse("2005-02-30T00:00:00").is_err());
    assert!(Utc::parse("2004-13-01T00:00:00").is_err());
    assert!(Utc::parse("yesterday").is_err());
    // J2000.0 epoch: 2000-01-01T11:58:55.816 UTC = 12:00 TT.
    assert!(
        (Utc::parse("2000-01-01T11:58:55.816").unwrap().jd_tt() - ephem::JD_J2000).abs() < 1e-9
    );
}

#[test]
fn sun_and_moon_vs_de421() {
    for r in &REFS {
        let jd = r.jd_tt;
        let sun = ephem::sun_geocentric_j2000(jd);
        let moon = ephem::moon_geocentric_j2000(jd);
        let sun_ref = DVec3::from_array(r.sun_geo_km) * 1e3;
        let moon_ref = DVec3::from_array(r.moon_geo_km) * 1e3;
        // Meeus low accuracy: 0.01 deg documented; measured 0.003 deg.
        let a = sun.angle_between(sun_ref).to_degrees();
        assert!(a < 0.01, "sun direction error {a} deg");
        // Radius: ~1e-4 relative (no planetary/lunar perturbations).
        assert!((sun.length() / sun_ref.length() - 1.0).abs() < 1e-4);
        // Almanac low precision Moon: ~0.3 deg, i.e. ~2000 km; measured < 900 km.
        let d = (moon - moon_ref).length() / 1e3;
        assert!(d < 2500.0, "moon position error {d} km");
        // What matters for shading: the Sun seen from the Moon.
        let s = ephem::sun_from_moon_j2000(jd)
            .angle_between(sun_ref - moon_ref)
            .to_degrees();
        assert!(s < 0.005, "selenocentric sun direction error {s} deg");
        println!(
            "{}: sun {a:.4} deg, moon {d:.0} km, sun from moon {s:.4} deg",
            r.utc
        );
    }
}

#[test]
fn moon_rotation_model_sanity() {
    // At J2000 the pole is near (269.99, 66.54) minus/plus the E1 terms and
    // W advances 13.176358 deg/day; the body->J2000 matrix is a rotation
    // whose z column is the pole.
    let jd = 2453237.4887421066;
    let (a0, d0, w) = ephem::moon_rotation_elements_deg(jd);
    assert!((a0 - 269.99).abs() < 4.0 && (d0 - 66.54).abs() < 2.0 && (0.0..360.0).contains(&w));
    let m = ephem::moon_body_to_j2000(jd);
    assert!((m.determinant() - 1.0).abs() < 1e-12);
    let pole = m * DVec3::Z;
    let (ra, dec) = ephem::unit_to_radec(pole);
    assert!((ra - a0).abs() < 1e-9 && (dec - d0).abs() < 1e-9);
    // The prime meridian node: x axis at angle W from the node Q = z_J2000 x pole.
    let node = DVec3::Z.cross(pole).normalize();
    let x = m * DVec3::X;
    let ang = node.angle_between(x).to_degrees();
    let signed = if node.cross(x).dot(pole) >= 0.0 {
        ang
    } else {
        360.0 - ang
    };
    assert!((signed - w).abs() < 1e-6, "{signed} vs {w}");
    // One sidereal month later (27.321661 d) W advances by ~360 deg.
    let (_, _, w2) = ephem::moon_rotation_elements_deg(jd + 27.321661);
    let dw = (w2 - w).rem_euclid(360.0);
    assert!(!(1.0..=359.0).contains(&dw), "{dw}");
}
