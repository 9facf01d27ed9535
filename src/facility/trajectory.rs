//! Facility states: the pose of camera, Sun and (optionally) body at one
//! instant, and the CSV trajectory file that lists them for open-loop runs.
//!
//! # CSV trajectory format
//!
//! One header line naming the columns, then one state per line. Columns are
//! found by header name, in any order:
//!
//! | column | unit | required |
//! |---|---|---|
//! | `t` | s | yes |
//! | `cam_x, cam_y, cam_z` | m, world frame | yes |
//! | `cam_qw, cam_qx, cam_qy, cam_qz` | scalar-first quaternion, camera → world | yes |
//! | `sun_x, sun_y, sun_z` | m, world frame | yes |
//! | `body_x, body_y, body_z` | m, world frame | no (all three or none) |
//! | `body_qw, body_qx, body_qy, body_qz` | scalar-first quaternion, body → world | no (all four or none) |
//!
//! An unknown or duplicated column name is an error. Optional columns may be
//! left empty on a line: an empty group means "not given" (`None`); a group
//! that is only partly filled is an error. Blank lines and lines starting with
//! `#` are ignored. `t` must be strictly increasing. Quaternions are
//! normalised; zero-norm or non-finite values are rejected. Every error names
//! the file, the line and the column.

use std::path::{Path, PathBuf};

use glam::{DQuat, DVec3};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// Pose of everything the renderer needs at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct State {
    /// State time, s.
    pub t: f64,
    /// Camera position in the world frame, m.
    pub camera_position: DVec3,
    /// Rotation of camera-frame vectors into the world frame (unit).
    pub camera_attitude: DQuat,
    /// Sun position in the world frame, m.
    pub sun_position: DVec3,
    /// Body position in the world frame, m (`None`: scene default).
    pub body_position: Option<DVec3>,
    /// Rotation of body-frame vectors into the world frame (`None`: scene default).
    pub body_attitude: Option<DQuat>,
}

/// All column names, in the fixed order used by the UDP CSV datagrams.
pub const COLUMNS: [&str; 18] = [
    "t", "cam_x", "cam_y", "cam_z", "cam_qw", "cam_qx", "cam_qy", "cam_qz", "sun_x", "sun_y",
    "sun_z", "body_x", "body_y", "body_z", "body_qw", "body_qx", "body_qy", "body_qz",
];

/// Number of columns that must always be present (`t` … `sun_z`).
pub const REQUIRED_COLUMNS: usize = 11;

/// Converts a scalar-first quaternion `[w, x, y, z]` into a unit [`DQuat`].
///
/// Rejects non-finite components and (near-)zero norm; `field` names the
/// offending value in the error.
pub fn quat_from_wxyz(q: [f64; 4], field: &str) -> Result<DQuat> {
    let shown = || format!("[{:e}, {:e}, {:e}, {:e}]", q[0], q[1], q[2], q[3]);
    if q.iter().any(|c| !c.is_finite()) {
        return Err(Error::invalid(
            field,
            format!("non-finite quaternion {}", shown()),
        ));
    }
    // Scaled first, so a 1e200 component neither overflows the sum of
    // squares nor is mistaken for a zero norm.
    let big = q.iter().fold(0.0f64, |m, c| m.max(c.abs()));
    if big == 0.0 {
        return Err(Error::invalid(
            field,
            format!("quaternion {} has zero norm", shown()),
        ));
    }
    let norm = big * q.iter().map(|c| (c / big) * (c / big)).sum::<f64>().sqrt();
    if norm <= 1e-12 {
        return Err(Error::invalid(
            field,
            format!("quaternion {} has a norm below 1e-12", shown()),
        ));
    }
    Ok(DQuat::from_xyzw(
        q[1] / norm,
        q[2] / norm,
        q[3] / norm,
        q[0] / norm,
    ))
}

/// Checks a 3-vector for finiteness.
pub fn vec3_checked(v: [f64; 3], field: &str) -> Result<DVec3> {
    if v.iter().any(|c| !c.is_finite()) {
        return Err(Error::invalid(
            field,
            format!("non-finite vector [{:e}, {:e}, {:e}]", v[0], v[1], v[2]),
        ));
    }
    Ok(DVec3::from_array(v))
}

impl State {
    /// Builds a state from the 18 values in [`COLUMNS`] order; `None` marks an
    /// absent optional value. Errors name the column (as the field).
    pub fn from_values(v: &[Option<f64>; 18]) -> Result<State> {
        for (i, name) in COLUMNS.iter().enumerate().take(REQUIRED_COLUMNS) {
            match v[i] {
                None => return Err(Error::invalid(*name, "missing value")),
                Some(x) if !x.is_finite() => {
                    return Err(Error::invalid(*name, format!("non-finite value {x}")))
                }
                Some(_) => {}
            }
        }
        for (i, name) in COLUMNS.iter().enumerate().skip(REQUIRED_COLUMNS) {
            if let Some(x) = v[i] {
                if !x.is_finite() {
                    return Err(Error::invalid(*name, format!("non-finite value {x}")));
                }
            }
        }
        let g = |i: usize| v[i].unwrap_or(f64::NAN);
        let group = |range: std::ops::Range<usize>| -> Result<bool> {
            let given = range.clone().filter(|&i| v[i].is_some()).count();
            if given != 0 && given != range.len() {
                let missing: Vec<&str> = range
                    .filter(|&i| v[i].is_none())
                    .map(|i| COLUMNS[i])
                    .collect();
                return Err(Error::invalid(
                    missing[0],
                    format!("partly given group: missing {}", missing.join(", ")),
                ));
            }
            Ok(given != 0)
        };
        let body_pos = group(11..14)?;
        let body_att = group(14..18)?;
        Ok(State {
            t: g(0),
            camera_position: vec3_checked([g(1), g(2), g(3)], "cam_x")?,
            camera_attitude: quat_from_wxyz([g(4), g(5), g(6), g(7)], "cam_qw")?,
            sun_position: vec3_checked([g(8), g(9), g(10)], "sun_x")?,
            body_position: if body_pos {
                Some(vec3_checked([g(11), g(12), g(13)], "body_x")?)
            } else {
                None
            },
            body_attitude: if body_att {
                Some(quat_from_wxyz([g(14), g(15), g(16), g(17)], "body_qw")?)
            } else {
                None
            },
        })
    }

    /// Parses one CSV line with all 18 fields in the fixed [`COLUMNS`] order
    /// (optional body fields may be empty). Errors name the column.
    pub fn from_csv_line(line: &str) -> Result<State> {
        // One datagram, one unquoted line: split directly rather than build
        // a CSV reader (and its buffer) at the sender's rate.
        let cells: Vec<&str> = line.trim().split(',').collect();
        if cells.len() != COLUMNS.len() {
            return Err(Error::invalid(
                "csv",
                format!("expected {} fields, found {}", COLUMNS.len(), cells.len()),
            ));
        }
        let mut values = [None; 18];
        for (i, cell) in cells.iter().enumerate() {
            values[i] = parse_cell(cell).map_err(|m| Error::invalid(COLUMNS[i], m))?;
        }
        State::from_values(&values)
    }

    /// Parses the JSON form (see [`StateJson`]).
    pub fn from_json(text: &str) -> Result<State> {
        let j: StateJson =
            serde_json::from_str(text).map_err(|e| Error::invalid("json", e.to_string()))?;
        j.to_state()
    }

    /// JSON form of this state (round-trips through [`State::from_json`]).
    pub fn to_json(&self) -> String {
        let q = |q: DQuat| [q.w, q.x, q.y, q.z];
        let j = StateJson {
            t: self.t,
            camera_position: self.camera_position.to_array(),
            camera_attitude: q(self.camera_attitude),
            sun_position: self.sun_position.to_array(),
            body_position: self.body_position.map(|p| p.to_array()),
            body_attitude: self.body_attitude.map(q),
        };
        serde_json::to_string(&j).expect("plain numbers serialise")
    }

    /// CSV line in the fixed [`COLUMNS`] order (no newline).
    pub fn to_csv_line(&self) -> String {
        let mut out: Vec<String> = vec![self.t.to_string()];
        out.extend(
            self.camera_position
                .to_array()
                .iter()
                .map(|x| x.to_string()),
        );
        let q = self.camera_attitude;
        out.extend([q.w, q.x, q.y, q.z].iter().map(|x| x.to_string()));
        out.extend(self.sun_position.to_array().iter().map(|x| x.to_string()));
        match self.body_position {
            Some(p) => out.extend(p.to_array().iter().map(|x| x.to_string())),
            None => out.extend(std::iter::repeat_n(String::new(), 3)),
        }
        match self.body_attitude {
            Some(q) => out.extend([q.w, q.x, q.y, q.z].iter().map(|x| x.to_string())),
            None => out.extend(std::iter::repeat_n(String::new(), 4)),
        }
        out.join(",")
    }
}

/// JSON representation of a [`State`]:
/// `{"t":0.0,"camera_position":[x,y,z],"camera_attitude":[w,x,y,z],
/// "sun_position":[x,y,z],"body_position":[x,y,z]|null,"body_attitude":[w,x,y,z]|null}`.
/// The two body fields may be omitted; unknown fields are rejected.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StateJson {
    /// s
    pub t: f64,
    /// m
    pub camera_position: [f64; 3],
    /// scalar-first
    pub camera_attitude: [f64; 4],
    /// m
    pub sun_position: [f64; 3],
    /// m
    #[serde(default)]
    pub body_position: Option<[f64; 3]>,
    /// scalar-first
    #[serde(default)]
    pub body_attitude: Option<[f64; 4]>,
}

impl StateJson {
    /// Validates and converts.
    pub fn to_state(&self) -> Result<State> {
        let mut v = [None; 18];
        v[0] = Some(self.t);
        for i in 0..3 {
            v[1 + i] = Some(self.camera_position[i]);
            v[8 + i] = Some(self.sun_position[i]);
            v[11 + i] = self.body_position.map(|p| p[i]);
        }
        for i in 0..4 {
            v[4 + i] = Some(self.camera_attitude[i]);
            v[14 + i] = self.body_attitude.map(|q| q[i]);
        }
        State::from_values(&v)
    }
}

/// Parses one cell: empty → `None`; otherwise a finite number.
fn parse_cell(cell: &str) -> std::result::Result<Option<f64>, String> {
    let s = cell.trim();
    if s.is_empty() {
        return Ok(None);
    }
    let x: f64 = s
        .parse()
        .map_err(|_| format!("not a number: `{}`", crate::error::abbreviate(s, 40)))?;
    if !x.is_finite() {
        return Err(format!(
            "non-finite value `{}`",
            crate::error::abbreviate(s, 40)
        ));
    }
    Ok(Some(x))
}

/// A time-ordered list of states read from a CSV file.
#[derive(Debug, Clone)]
pub struct Trajectory {
    /// File the states came from.
    pub path: PathBuf,
    /// States, strictly increasing in `t`.
    pub states: Vec<State>,
}

impl Trajectory {
    /// Reads and validates a CSV trajectory file.
    pub fn load(path: impl AsRef<Path>) -> Result<Trajectory> {
        let path = path.as_ref();
        let text = crate::infile::read_text_bounded(path, crate::infile::DATA_LIMIT)?;
        Trajectory::parse(&text, path)
    }

    /// Parses CSV text; `path` is only used in error messages.
    pub fn parse(text: &str, path: impl AsRef<Path>) -> Result<Trajectory> {
        let path = path.as_ref();
        let err = |line: usize, msg: String| Error::parse(path, format!("line {line}: {msg}"));
        let mut rows = crate::infile::csv_table::rows(path, text.as_bytes(), b',');
        let header = rows
            .next()
            .transpose()?
            .ok_or_else(|| Error::parse(path, "empty file: no header line"))?;
        let header_line = header.line;
        // Map header position → index in COLUMNS.
        let mut map: Vec<usize> = Vec::new();
        let mut seen = [false; 18];
        for name in header.cells.iter() {
            let idx = COLUMNS.iter().position(|c| *c == name).ok_or_else(|| {
                err(
                    header_line,
                    format!(
                        "unknown column `{}` (known: {})",
                        crate::error::abbreviate(name, 40),
                        COLUMNS.join(", ")
                    ),
                )
            })?;
            if seen[idx] {
                return Err(err(header_line, format!("duplicate column `{name}`")));
            }
            seen[idx] = true;
            map.push(idx);
        }
        for (i, name) in COLUMNS.iter().enumerate().take(REQUIRED_COLUMNS) {
            if !seen[i] {
                return Err(err(
                    header_line,
                    format!("missing required column `{name}`"),
                ));
            }
        }
        let mut states: Vec<State> = Vec::new();
        for row in rows {
            let row = row?;
            let line_no = row.line;
            let cells: Vec<&str> = row.cells.iter().collect();
            if cells.len() != map.len() {
                return Err(err(
                    line_no,
                    format!(
                        "expected {} fields (as in the header), found {}",
                        map.len(),
                        cells.len()
                    ),
                ));
            }
            let mut values = [None; 18];
            for (cell, &idx) in cells.iter().zip(&map) {
                values[idx] = parse_cell(cell)
                    .map_err(|m| err(line_no, format!("column `{}`: {m}", COLUMNS[idx])))?;
            }
            let state = State::from_values(&values).map_err(|e| match e {
                Error::Invalid { field, message } => {
                    err(line_no, format!("column `{field}`: {message}"))
                }
                other => other,
            })?;
            if let Some(prev) = states.last() {
                if state.t <= prev.t {
                    return Err(err(
                        line_no,
                        format!(
                            "column `t`: {} is not after the previous state's t = {}",
                            state.t, prev.t
                        ),
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

    /// Number of states.
    pub fn len(&self) -> usize {
        self.states.len()
    }

    /// Always false for a loaded trajectory (it has at least one state).
    pub fn is_empty(&self) -> bool {
        self.states.is_empty()
    }

    /// The latest state with `state.t <= t`, if any.
    pub fn at_or_before(&self, t: f64) -> Option<&State> {
        let n = self.states.partition_point(|s| s.t <= t);
        n.checked_sub(1).map(|i| &self.states[i])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const HEADER: &str = "t,cam_x,cam_y,cam_z,cam_qw,cam_qx,cam_qy,cam_qz,sun_x,sun_y,sun_z";

    fn msg(e: Error) -> String {
        e.to_string()
    }

    #[test]
    fn parses_required_columns_and_normalises_quaternion() {
        let text = format!("{HEADER}\n0,1,2,3,2,0,0,0,10,20,30\n1.5,1,2,3,0,0,0,3,10,20,30\n");
        let tr = Trajectory::parse(&text, "traj.csv").unwrap();
        assert_eq!(tr.len(), 2);
        let s = &tr.states[1];
        assert_eq!(s.t, 1.5);
        // [w,x,y,z] = [0,0,0,3] → 180° about z, normalised.
        assert!((s.camera_attitude.z - 1.0).abs() < 1e-15);
        assert!(s.camera_attitude.w.abs() < 1e-15);
        // Rotating camera x into world must give -x for 180° about z.
        let v = s.camera_attitude * DVec3::X;
        assert!((v - DVec3::NEG_X).length() < 1e-12);
        assert_eq!(tr.states[0].camera_attitude, DQuat::IDENTITY);
        assert_eq!(s.sun_position, DVec3::new(10.0, 20.0, 30.0));
        assert!(s.body_position.is_none() && s.body_attitude.is_none());
    }

    #[test]
    fn scalar_first_convention_rotates_as_expected() {
        // 90° about +z: w = cos45, z = sin45; camera +x → world +y.
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let q = quat_from_wxyz([h, 0.0, 0.0, h], "q").unwrap();
        assert!((q * DVec3::X - DVec3::Y).length() < 1e-12);
    }

    #[test]
    fn any_column_order_and_optional_body() {
        let text = "sun_z,sun_y,sun_x,body_qz,body_qy,body_qx,body_qw,body_z,body_y,body_x,cam_qz,cam_qy,cam_qx,cam_qw,cam_z,cam_y,cam_x,t\n\
                    3,2,1,0,0,0,1,9,8,7,0,0,0,1,6,5,4,0.25\n\
                    3,2,1,,,,,,,,0,0,0,1,6,5,4,0.5\n";
        let tr = Trajectory::parse(text, "x.csv").unwrap();
        let s = &tr.states[0];
        assert_eq!(s.t, 0.25);
        assert_eq!(s.camera_position, DVec3::new(4.0, 5.0, 6.0));
        assert_eq!(s.sun_position, DVec3::new(1.0, 2.0, 3.0));
        assert_eq!(s.body_position, Some(DVec3::new(7.0, 8.0, 9.0)));
        assert_eq!(s.body_attitude, Some(DQuat::IDENTITY));
        assert_eq!(tr.states[1].body_position, None);
    }

    #[test]
    fn errors_name_file_line_and_column() {
        let e = msg(Trajectory::parse(&format!("{HEADER},bogus\n"), "a.csv").unwrap_err());
        assert!(
            e.contains("a.csv") && e.contains("line 1") && e.contains("bogus"),
            "{e}"
        );

        let text = format!("{HEADER}\n0,1,2,3,1,0,0,0,1,1,1\n1,1,x,3,1,0,0,0,1,1,1\n");
        let e = msg(Trajectory::parse(&text, "b.csv").unwrap_err());
        assert!(
            e.contains("b.csv") && e.contains("line 3") && e.contains("cam_y"),
            "{e}"
        );

        let text = format!("{HEADER}\n0,1,2,3,1,0,0,0,1,1,1\n0,1,2,3,1,0,0,0,1,1,1\n");
        let e = msg(Trajectory::parse(&text, "c.csv").unwrap_err());
        assert!(e.contains("line 3") && e.contains("`t`"), "{e}");

        let text = format!("{HEADER}\n0,1,2,3,0,0,0,0,1,1,1\n");
        let e = msg(Trajectory::parse(&text, "d.csv").unwrap_err());
        assert!(
            e.contains("line 2") && e.contains("cam_qw") && e.contains("zero norm"),
            "{e}"
        );

        let text = format!("{HEADER}\n0,1,2,NaN,1,0,0,0,1,1,1\n");
        let e = msg(Trajectory::parse(&text, "e.csv").unwrap_err());
        assert!(e.contains("cam_z") && e.contains("non-finite"), "{e}");

        let text = format!("{HEADER},body_x,body_y,body_z\n0,1,2,3,1,0,0,0,1,1,1,5,,\n");
        let e = msg(Trajectory::parse(&text, "f.csv").unwrap_err());
        assert!(e.contains("line 2") && e.contains("body_y"), "{e}");

        let text = "t,cam_x\n0,1\n";
        let e = msg(Trajectory::parse(text, "g.csv").unwrap_err());
        assert!(e.contains("missing required column `cam_y`"), "{e}");

        let text = format!("{HEADER},t\n");
        assert!(msg(Trajectory::parse(&text, "h.csv").unwrap_err()).contains("duplicate"));

        let text = format!("{HEADER}\n0,1,2,3,1,0,0,0,1,1\n");
        assert!(msg(Trajectory::parse(&text, "i.csv").unwrap_err()).contains("found 10"));
    }

    /// Messages a person can act on: a huge component is normalised, not
    /// called zero; a 1 MB cell is abbreviated; a BOM is not a column name.
    #[test]
    fn hostile_cells_give_short_exact_messages() {
        let text = format!("{HEADER}\n0,1,2,3,1e200,0,0,1e200,1,1,1\n");
        let t = Trajectory::parse(&text, "a.csv").unwrap();
        let q = t.states[0].camera_attitude;
        let h = std::f64::consts::FRAC_1_SQRT_2;
        assert!((q.w - h).abs() < 1e-15 && (q.z - h).abs() < 1e-15, "{q}");

        let cell = "9".repeat(1_000_000) + "x";
        let text = format!("{HEADER}\n0,1,{cell},3,1,0,0,0,1,1,1\n");
        let e = msg(Trajectory::parse(&text, "b.csv").unwrap_err());
        assert!(
            e.len() < 200 && e.contains("cam_y") && e.contains('…'),
            "{}",
            &e[..200.min(e.len())]
        );
        assert!(!e.contains('"'), "no debug quoting: {e}");

        let text = format!("\u{feff}{HEADER}\n0,1,2,3,1,0,0,0,1,1,1\n");
        assert_eq!(Trajectory::parse(&text, "c.csv").unwrap().len(), 1);
    }

    #[test]
    fn csv_and_json_round_trip() {
        let s = State {
            t: 12.5,
            camera_position: DVec3::new(1.0, -2.0, 3.5e6),
            camera_attitude: quat_from_wxyz([0.5, 0.5, -0.5, 0.5], "q").unwrap(),
            sun_position: DVec3::new(1.5e11, 0.0, 0.0),
            body_position: None,
            body_attitude: Some(quat_from_wxyz([0.0, 1.0, 0.0, 0.0], "q").unwrap()),
        };
        assert_eq!(State::from_csv_line(&s.to_csv_line()).unwrap(), s);
        assert_eq!(State::from_json(&s.to_json()).unwrap(), s);
        assert!(State::from_json(r#"{"t":1,"camera_position":[0,0,0],"camera_attitude":[1,0,0,0],"sun_position":[1,0,0],"extra":1}"#).is_err());
    }

    #[test]
    fn lookup_at_or_before() {
        let text = format!("{HEADER}\n0,1,2,3,1,0,0,0,1,1,1\n2,1,2,3,1,0,0,0,1,1,1\n");
        let tr = Trajectory::parse(&text, "x").unwrap();
        assert!(tr.at_or_before(-0.1).is_none());
        assert_eq!(tr.at_or_before(1.9).unwrap().t, 0.0);
        assert_eq!(tr.at_or_before(2.0).unwrap().t, 2.0);
    }
}
