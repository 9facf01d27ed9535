//! Star catalogues: the bundled Hipparcos stars (V ≤ 7.5,
//! `data/stars/hipparcos_v7.5.csv`) or a user's CSV file of the same
//! format, range-checked row by row, and proper motion to an epoch.
//!
//! A file has an optional leading `id` column, then `ra_deg`, `dec_deg`
//! (ICRS), `pm_ra_mas_per_yr` (μα* = μα cos δ), `pm_dec_mas_per_yr`,
//! `v_mag` and `b_v`, and an optional trailing `parallax_mas`, named in a
//! header line; `#` lines are comments.

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
/// The optional column after [`COLUMNS`]: the annual parallax [mas].
pub const PARALLAX_COLUMN: &str = "parallax_mas";
/// Largest parallax accepted [mas] (Proxima Centauri: 768). Hipparcos
/// lists small negative parallaxes for distant stars (its errors):
/// accepted down to −[`MAX_PARALLAX`] and used as 0.
pub const MAX_PARALLAX: f64 = 1000.0;
/// The astronomical unit [m], the baseline of a parallax.
pub const AU: f64 = 1.495_978_707e11;
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
    /// Annual parallax [rad] (0 where the catalogue gives none or a
    /// negative one).
    pub parallax: f64,
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

    /// The direction `years` after the catalogue epoch seen from
    /// `observer` [m], the observer's position from the Sun (taken for the
    /// solar-system barycentre, ≤ 0.01 AU away: ≤ 1 % of the parallax):
    /// the star sits at 1 AU / parallax along its barycentric direction.
    pub fn direction_from(&self, years: f64, observer: DVec3) -> DVec3 {
        let barycentric = self.direction_after(years);
        if self.parallax == 0.0 {
            return barycentric;
        }
        (barycentric - observer * (self.parallax / AU)).normalize()
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
    let has_parallax = names.len() == COLUMNS.len() + 1 && names.last() == Some(&PARALLAX_COLUMN);
    if names[..names.len() - usize::from(has_parallax)] != COLUMNS {
        return Err(err(
            header.line,
            format!(
                "header `{}`: expected `[id,]{}[,{PARALLAX_COLUMN}]`",
                header.joined(),
                COLUMNS.join(",")
            ),
        ));
    }
    let width = COLUMNS.len() + usize::from(has_id) + usize::from(has_parallax);
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
        let parallax_mas = if has_parallax {
            parse_parallax(&row.cells[width - 1]).map_err(|why| err(row.line, why))?
        } else {
            0.0
        };
        let [ra, dec, pm_ra, pm_dec, v_mag, b_v] = values;
        stars.push(Star {
            id,
            ra: ra.to_radians(),
            dec: dec.to_radians(),
            pm_ra: pm_ra * MAS_TO_RAD,
            pm_dec: pm_dec * MAS_TO_RAD,
            v_mag,
            b_v,
            parallax: parallax_mas.max(0.0) * MAS_TO_RAD,
        });
    }
    if stars.is_empty() {
        return Err(Error::parse(path, "no stars after the header"));
    }
    Ok(stars)
}

/// A `parallax_mas` cell [mas], range-checked.
fn parse_parallax(text: &str) -> std::result::Result<f64, String> {
    match text.parse::<f64>() {
        Ok(p) if p.is_finite() && p.abs() <= MAX_PARALLAX => Ok(p),
        Ok(p) if p.is_finite() => Err(format!(
            "{PARALLAX_COLUMN} {p} is outside [-{MAX_PARALLAX}, {MAX_PARALLAX}]"
        )),
        _ => Err(format!("{PARALLAX_COLUMN} `{text}` is not a finite number")),
    }
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
        // Sirius's parallax 379.2 mas, α Cen A's (HIP 71683) 754.8 mas
        // (Hipparcos new reduction, rounded).
        assert!((sirius.parallax / MAS_TO_RAD - 379.2).abs() < 1.0);
        let alpha_cen = cat.stars.iter().find(|s| s.id == 71683).unwrap();
        assert!((alpha_cen.parallax / MAS_TO_RAD - 754.8).abs() < 2.0);
    }

    #[test]
    fn parallax_shifts_a_star_by_its_closed_form() {
        // A star along +x at 1 AU / p, seen from 1 AU along +y: it appears
        // atan(p) toward −y; seen from along its own direction, unmoved.
        let p_mas = 768.0;
        let star = Star {
            id: 1,
            ra: 0.0,
            dec: 0.0,
            pm_ra: 0.0,
            pm_dec: 0.0,
            v_mag: 11.0,
            b_v: 1.8,
            parallax: p_mas * MAS_TO_RAD,
        };
        let seen = star.direction_from(0.0, DVec3::new(0.0, AU, 0.0));
        let expected = (p_mas * MAS_TO_RAD).atan();
        // atan2 of |cross| and dot: acos loses ~1e-8 rad near 0.
        let shift = DVec3::X.cross(seen).length().atan2(DVec3::X.dot(seen));
        assert!(
            (shift - expected).abs() < 1e-6 * expected,
            "{shift} vs {expected}"
        );
        assert!(seen.y < 0.0 && seen.z.abs() < 1e-15);
        let along = star.direction_from(0.0, DVec3::new(5.0 * AU, 0.0, 0.0));
        assert!(DVec3::X.cross(along).length() < 1e-15);
    }

    #[test]
    fn parallax_column_is_optional_and_range_checked() {
        let head = "id,ra_deg,dec_deg,pm_ra_mas_per_yr,pm_dec_mas_per_yr,v_mag,b_v";
        let path = Path::new("cat.csv");
        let with = |row: &str| format!("{head},parallax_mas\n{row}\n");
        let stars = parse(path, with("7,10,20,0,0,5,0.6,100").as_bytes()).unwrap();
        assert!((stars[0].parallax - 100.0 * MAS_TO_RAD).abs() < 1e-20);
        let negative = parse(path, with("7,10,20,0,0,5,0.6,-0.5").as_bytes()).unwrap();
        assert_eq!(
            negative[0].parallax, 0.0,
            "a negative parallax is used as 0"
        );
        let without = parse(path, format!("{head}\n7,10,20,0,0,5,0.6\n").as_bytes()).unwrap();
        assert_eq!(without[0].parallax, 0.0);
        for bad in ["2000", "nan", "x"] {
            let e = parse(path, with(&format!("7,10,20,0,0,5,0.6,{bad}")).as_bytes())
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("cat.csv") && e.contains("line 2") && e.contains("parallax_mas"),
                "{e}"
            );
            assert_eq!(e.lines().count(), 1, "{e}");
        }
        let short = parse(path, with("7,10,20,0,0,5,0.6").as_bytes()).unwrap_err();
        assert!(short.to_string().contains("cells"), "{short}");
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
            parallax: 0.0,
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
