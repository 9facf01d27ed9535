//! Trajectories given by epoch: the camera's Moon-centred position and
//! attitude per line, the Sun and the Moon's orientation from an
//! [`Ephemeris`] (SPICE kernels) at each line's epoch.
//!
//! # CSV format
//!
//! | column | unit | required |
//! |---|---|---|
//! | `epoch` | ISO UTC text (or with a ` TDB` suffix), strictly increasing | yes |
//! | `cam_x_km, cam_y_km, cam_z_km` | km, camera relative to the Moon's centre, J2000 axes | yes |
//! | `cam_qw, cam_qx, cam_qy, cam_qz` | scalar-first quaternion, camera → J2000 | yes |
//!
//! The world frame is J2000 axes with the Moon at the origin (as a scene
//! with `state.epoch`); a state's `t` is TDB seconds after the first line.
//! Blank lines and `#` lines are ignored; every error names the file, the
//! line and the column.

use std::path::Path;

use glam::{DQuat, DVec3};

use super::trajectory::{quat_from_wxyz, vec3_checked, State, Trajectory};
use crate::ephemeris::{parse_epoch, Ephemeris, Epoch};
use crate::error::{Error, Result};

/// The columns, in the order a row's values are kept.
pub const EPOCH_COLUMNS: [&str; 8] = [
    "epoch", "cam_x_km", "cam_y_km", "cam_z_km", "cam_qw", "cam_qx", "cam_qy", "cam_qz",
];

/// Whether a CSV header names an `epoch` column (an epoch trajectory).
pub fn is_epoch_header(text: &str) -> bool {
    crate::infile::csv_table::rows(Path::new(""), text.as_bytes(), b',')
        .next()
        .and_then(|header| header.ok())
        .is_some_and(|h| h.cells.iter().any(|c| c == "epoch"))
}

/// Reads an epoch trajectory file.
pub fn load(path: &Path, eph: &dyn Ephemeris) -> Result<Trajectory> {
    let text = crate::infile::read_text_bounded(path, crate::infile::DATA_LIMIT)?;
    parse(&text, path, eph)
}

/// Parses epoch-trajectory CSV text; `path` names it in errors.
pub fn parse(text: &str, path: &Path, eph: &dyn Ephemeris) -> Result<Trajectory> {
    let err = |line: usize, msg: String| Error::parse(path, format!("line {line}: {msg}"));
    let mut rows = crate::infile::csv_table::rows(path, text.as_bytes(), b',');
    let header = rows
        .next()
        .transpose()?
        .ok_or_else(|| Error::parse(path, "empty file: no header line"))?;
    let map = column_map(&header.cells).map_err(|m| err(header.line, m))?;
    let mut first: Option<Epoch> = None;
    let mut states: Vec<State> = Vec::new();
    for row in rows {
        let row = row?;
        let line_no = row.line;
        let cells: Vec<&str> = row.cells.iter().collect();
        if cells.len() != map.len() {
            let msg = format!("expected {} fields, found {}", map.len(), cells.len());
            return Err(err(line_no, msg));
        }
        let mut row = [""; 8];
        for (cell, &idx) in cells.iter().zip(&map) {
            row[idx] = cell;
        }
        let state = row_state(&row, &mut first, eph).map_err(|e| match e {
            Error::Invalid { field, message } => {
                err(line_no, format!("column `{field}`: {message}"))
            }
            other => err(line_no, other.to_string()),
        })?;
        if let Some(prev) = states.last() {
            if state.t <= prev.t {
                return Err(err(
                    line_no,
                    "column `epoch`: not after the previous line's".into(),
                ));
            }
        }
        states.push(state);
    }
    if states.is_empty() {
        return Err(Error::parse(path, "no states after the header"));
    }
    Ok(Trajectory {
        path: path.to_path_buf(),
        states,
    })
}

/// Header position → index in [`EPOCH_COLUMNS`]; all columns required once.
fn column_map(header: &csv::StringRecord) -> std::result::Result<Vec<usize>, String> {
    let mut map = Vec::new();
    let mut seen = [false; 8];
    for name in header.iter() {
        let idx = EPOCH_COLUMNS
            .iter()
            .position(|c| *c == name)
            .ok_or_else(|| {
                let known = EPOCH_COLUMNS.join(", ");
                format!(
                    "unknown column `{}` (known: {known})",
                    crate::error::abbreviate(name, 40)
                )
            })?;
        if std::mem::replace(&mut seen[idx], true) {
            return Err(format!("duplicate column `{name}`"));
        }
        map.push(idx);
    }
    match EPOCH_COLUMNS.iter().zip(seen).find(|(_, s)| !s) {
        Some((name, _)) => Err(format!("missing required column `{name}`")),
        None => Ok(map),
    }
}

/// One row (cells in [`EPOCH_COLUMNS`] order) to a state; `first` is the
/// trajectory's first epoch (set by the first row).
fn row_state(row: &[&str; 8], first: &mut Option<Epoch>, eph: &dyn Ephemeris) -> Result<State> {
    let t = parse_epoch(row[0], "epoch")?;
    let mut v = [0.0; 7];
    for (i, x) in v.iter_mut().enumerate() {
        let name = EPOCH_COLUMNS[i + 1];
        *x = row[i + 1].parse().map_err(|_| {
            Error::invalid(
                name,
                format!(
                    "not a number: `{}`",
                    crate::error::abbreviate(row[i + 1], 40)
                ),
            )
        })?;
    }
    let camera = vec3_checked([v[0], v[1], v[2]], "cam_x_km")? * 1e3;
    let attitude = quat_from_wxyz([v[3], v[4], v[5], v[6]], "cam_qw")?;
    let start = *first.get_or_insert(t);
    let at = |e: Error| Error::invalid("epoch", format!("`{}`: {e}", row[0]));
    let body = DQuat::from_mat3(&eph.moon_to_j2000(t).map_err(at)?).normalize();
    Ok(State {
        t: (t - start).to_seconds(),
        camera_position: camera,
        camera_attitude: attitude,
        sun_position: eph.sun_from_moon(t).map_err(at)?,
        body_position: Some(DVec3::ZERO),
        body_attitude: Some(body),
    })
}
