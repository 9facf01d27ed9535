//! Star catalogues: the bundled Hipparcos stars (V ≤ 7.5,
//! `data/stars/hipparcos_v7.5.csv`) or a user's CSV file of the same
//! format, range-checked row by row, and proper motion to an epoch.
//!
//! A file has an optional leading `id` column, then `ra_deg`, `dec_deg`
//! (ICRS), `pm_ra_mas_per_yr` (μα* = μα cos δ), `pm_dec_mas_per_yr`,
//! `v_mag` and `b_v`, named in a header line; `#` lines are comments.

use std::path::Path;
use std::sync::{Arc, OnceLock};

use glam::DVec3;

use crate::error::{Error, Result};
use crate::infile::csv_table;

/// The bundled catalogue's text.
const BUNDLED_CSV: &str = include_str!("../../data/stars/hipparcos_v7.5.csv");
/// Epoch of the Hipparcos positions (Julian year).
pub const HIPPARCOS_EPOCH_YEAR: f64 = 1991.25;
/// The columns after the optional `id`.
pub const COLUMNS: [&str; 6] = [
    "ra_deg",
    "dec_deg",
    "pm_ra_mas_per_yr",
    "pm_dec_mas_per_yr",
    "v_mag",
    "b_v",
];
/// Largest proper motion accepted [mas/yr] (Barnard's star: 10 400).
pub const MAX_PROPER_MOTION: f64 = 20_000.0;
/// Accepted V magnitudes (Sirius −1.46; the faintest a camera could see).
pub const V_RANGE: (f64, f64) = (-2.0, 30.0);
/// Accepted B−V colours: the blackbody temperature formula
/// ([`super::photometry::temperature_from_b_v`]) holds over it.
pub const B_V_RANGE: (f64, f64) = (-0.5, 5.0);

const MAS_TO_RAD: f64 = std::f64::consts::PI / (180.0 * 3600.0 * 1000.0);

/// One star at its catalogue epoch.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Star {
    /// Catalogue number (the HIP number for the bundled catalogue; the
    /// row's ordinal when the file has no `id` column).
    pub id: u64,
    /// Right ascension and declination [rad], ICRS.
    pub ra: f64,
    pub dec: f64,
    /// Proper motion μα* = μα cos δ and μδ [rad/yr].
    pub pm_ra: f64,
    pub pm_dec: f64,
    /// Johnson V magnitude.
    pub v_mag: f64,
    /// Johnson B−V colour.
    pub b_v: f64,
}

impl Star {
    /// Unit direction (ICRS axes) at the catalogue epoch.
    pub fn direction(&self) -> DVec3 {
        let (sa, ca) = self.ra.sin_cos();
        let (sd, cd) = self.dec.sin_cos();
        DVec3::new(cd * ca, cd * sa, sd)
    }

    /// Unit direction `years` after the catalogue epoch: the proper motion
    /// as a displacement along the local east and north unit vectors
    /// (no cos δ division, so it holds at the poles too).
    pub fn direction_after(&self, years: f64) -> DVec3 {
        let (sa, ca) = self.ra.sin_cos();
        let (sd, cd) = self.dec.sin_cos();
        let east = DVec3::new(-sa, ca, 0.0);
        let north = DVec3::new(-sd * ca, -sd * sa, cd);
        (self.direction() + years * (self.pm_ra * east + self.pm_dec * north)).normalize()
    }
}

/// Stars with the epoch of their positions.
#[derive(Clone, Debug)]
pub struct Catalogue {
    pub stars: Vec<Star>,
    /// Julian year of the positions.
    pub epoch_year: f64,
}

impl Catalogue {
    /// The bundled Hipparcos catalogue (parsed once per process).
    pub fn bundled() -> Arc<Catalogue> {
        static BUNDLED: OnceLock<Arc<Catalogue>> = OnceLock::new();
        BUNDLED
            .get_or_init(|| {
                let stars = parse(Path::new("bundled"), BUNDLED_CSV.as_bytes())
                    .expect("the bundled catalogue parses (tested)");
                Arc::new(Catalogue {
                    stars,
                    epoch_year: HIPPARCOS_EPOCH_YEAR,
                })
            })
            .clone()
    }

    /// A user's catalogue file whose positions are at `epoch_year`.
    pub fn from_file(path: &Path, epoch_year: f64) -> Result<Catalogue> {
        let bytes = crate::infile::read_bounded(path, crate::infile::TABLE_LIMIT)?;
        Ok(Catalogue {
            stars: parse(path, &bytes)?,
            epoch_year,
        })
    }
}

/// The stars of a catalogue file's bytes; `path` names it in errors.
pub fn parse(path: &Path, bytes: &[u8]) -> Result<Vec<Star>> {
    let err = |line: usize, what: String| Error::parse(path, format!("line {line}: {what}"));
    if bytes.last().is_some_and(|&b| b != b'\n') {
        let lines = bytes.iter().filter(|&&b| b == b'\n').count() + 1;
        return Err(err(
            lines,
            "the file ends mid-line (truncated?): the last line needs its newline".into(),
        ));
    }
    let mut rows = csv_table::rows(path, bytes, b',');
    let header = rows
        .next()
        .ok_or_else(|| Error::parse(path, "no header line and no stars"))??;
    let has_id = header.cells.get(0) == Some("id");
    let names: Vec<&str> = header.cells.iter().skip(usize::from(has_id)).collect();
    if names != COLUMNS {
        return Err(err(
            header.line,
            format!(
                "header `{}`: expected `[id,]{}`",
                header.joined(),
                COLUMNS.join(",")
            ),
        ));
    }
    let width = COLUMNS.len() + usize::from(has_id);
    let mut stars = Vec::new();
    for row in rows {
        let row = row?;
        if row.len() != width {
            return Err(err(
                row.line,
                format!("{} cells, expected {width} (truncated?)", row.len()),
            ));
        }
        let id = if has_id {
            let text = &row.cells[0];
            text.parse::<u64>()
                .map_err(|_| err(row.line, format!("id `{text}` is not a whole number")))?
        } else {
            stars.len() as u64 + 1
        };
        let cells = row.cells.iter().skip(usize::from(has_id));
        let mut values = [0.0; 6];
        for ((value, text), name) in values.iter_mut().zip(cells).zip(COLUMNS) {
            *value = text
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| err(row.line, format!("{name} `{text}` is not a finite number")))?;
        }
        check_ranges(&values).map_err(|why| err(row.line, why))?;
        let [ra, dec, pm_ra, pm_dec, v_mag, b_v] = values;
        stars.push(Star {
            id,
            ra: ra.to_radians(),
            dec: dec.to_radians(),
            pm_ra: pm_ra * MAS_TO_RAD,
            pm_dec: pm_dec * MAS_TO_RAD,
            v_mag,
            b_v,
        });
    }
    if stars.is_empty() {
        return Err(Error::parse(path, "no stars after the header"));
    }
    Ok(stars)
}

/// The first value of a row outside its range, as a message.
fn check_ranges(v: &[f64; 6]) -> std::result::Result<(), String> {
    let within = |x: f64, lo: f64, hi: f64| (lo..=hi).contains(&x);
    let checks = [
        (within(v[0], 0.0, 360.0), "ra_deg", "[0, 360]"),
        (within(v[1], -90.0, 90.0), "dec_deg", "[-90, 90]"),
        (
            v[2].abs() <= MAX_PROPER_MOTION,
            "pm_ra_mas_per_yr",
            "[-20000, 20000]",
        ),
        (
            v[3].abs() <= MAX_PROPER_MOTION,
            "pm_dec_mas_per_yr",
            "[-20000, 20000]",
        ),
        (within(v[4], V_RANGE.0, V_RANGE.1), "v_mag", "[-2, 30]"),
        (within(v[5], B_V_RANGE.0, B_V_RANGE.1), "b_v", "[-0.5, 5]"),
    ];
    match checks.iter().position(|c| !c.0) {
        Some(k) => Err(format!(
            "{} {} is outside {}",
            checks[k].1, v[k], checks[k].2
        )),
        None => Ok(()),
    }
}

/// Julian year (TT) of an epoch.
pub fn julian_year(epoch: crate::ephemeris::Epoch) -> f64 {
    2000.0 + (epoch.to_jde_tt_days() - 2_451_545.0) / 365.25
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bundled_catalogue_holds_the_hipparcos_stars_to_7_5() {
        let cat = Catalogue::bundled();
        assert_eq!(cat.stars.len(), 25_688);
        // Sirius (HIP 32349): V −1.44, RA 101.2886°, Dec −16.7131°,
        // μα* −546 mas/yr (published values, rounded).
        let sirius = cat.stars.iter().find(|s| s.id == 32349).unwrap();
        assert!((sirius.v_mag + 1.44).abs() < 0.02);
        assert!((sirius.ra.to_degrees() - 101.2886).abs() < 1e-3);
        assert!((sirius.dec.to_degrees() + 16.7131).abs() < 1e-3);
        assert!((sirius.pm_ra / MAS_TO_RAD + 546.0).abs() < 1.0);
    }

    #[test]
    fn proper_motion_moves_a_star_by_mu_times_t() {
        // 1000 mas/yr east and 500 north for 100 years: an arc of
        // 100 × √(1000² + 500²) mas.
        let star = Star {
            id: 1,
            ra: 1.0,
            dec: 0.5,
            pm_ra: 1000.0 * MAS_TO_RAD,
            pm_dec: 500.0 * MAS_TO_RAD,
            v_mag: 5.0,
            b_v: 0.6,
        };
        let arc = star.direction().angle_between(star.direction_after(100.0));
        let expected = 100.0 * (1000f64.powi(2) + 500f64.powi(2)).sqrt() * MAS_TO_RAD;
        assert!(
            (arc - expected).abs() < 1e-6 * expected,
            "{arc} vs {expected}"
        );
        let later = star.direction_after(100.0);
        assert!(later.z.asin() > star.dec, "north proper motion raises dec");
    }
}
