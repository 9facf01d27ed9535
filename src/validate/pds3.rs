//! PDS3 labels and attached images: a parser for the ODL label syntax
//! (`KEY = VALUE`, units in `<...>`, quoted strings spanning lines,
//! sequences `(a, b)` and sets `{a, b}`, `OBJECT`/`GROUP` nesting, `/* */`
//! comments, `END`), typed accessors that name the file and key in every
//! error, and a reader for the `IMAGE` object of an attached-label file.
//!
//! Only attached labels (label and data in one file, pointers in bytes or
//! records) are supported; that is what the SMART-1 AMIE EDR products use.

use std::path::{Path, PathBuf};

use super::raster::Raster;
use crate::error::{Error, Result};

/// One label value.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    /// An unquoted token (number, symbol, date) with its optional unit
    /// (the text between `<` and `>`, e.g. `KM`, `DEG`, `BYTES`).
    Scalar { text: String, unit: Option<String> },
    /// A `"quoted"` string, kept verbatim (line breaks included).
    Quoted(String),
    /// A `'symbol'` literal.
    Symbol(String),
    /// A sequence `(a, b, ...)` or a set `{a, b, ...}`, with an optional unit
    /// written after the closing bracket.
    Sequence {
        items: Vec<Value>,
        unit: Option<String>,
    },
}

impl Value {
    /// Text of a scalar, quoted string or symbol (quoted strings with their
    /// whitespace runs, line breaks included, collapsed to single spaces).
    pub fn as_text(&self) -> Option<String> {
        match self {
            Value::Scalar { text, .. } | Value::Symbol(text) => Some(text.clone()),
            Value::Quoted(s) => Some(s.split_whitespace().collect::<Vec<_>>().join(" ")),
            Value::Sequence { .. } => None,
        }
    }

    /// Short description for error messages, e.g. `string "N/A"`.
    pub fn describe(&self) -> String {
        match self {
            Value::Scalar { text, .. } => format!("`{text}`"),
            Value::Quoted(s) => format!(
                "string \"{}\"",
                s.split_whitespace().collect::<Vec<_>>().join(" ")
            ),
            Value::Symbol(s) => format!("symbol '{s}'"),
            Value::Sequence { items, .. } => format!("a sequence of {} items", items.len()),
        }
    }
}

/// A group of statements: the label itself, an `OBJECT` or a `GROUP`.
#[derive(Debug, Clone, PartialEq)]
pub struct Group {
    /// File the label was read from (used in error messages).
    pub path: PathBuf,
    /// `ROOT` for the label, else the object's name (e.g. `IMAGE`).
    pub name: String,
    /// `KEY = VALUE` statements, in file order.
    pub entries: Vec<(String, Value)>,
    /// Nested `OBJECT`s and `GROUP`s, in file order.
    pub children: Vec<Group>,
}

/// A parsed PDS3 label.
#[derive(Debug, Clone, PartialEq)]
pub struct Label {
    /// Top-level statements and objects.
    pub root: Group,
    /// Number of bytes from the start of the file to just after `END`.
    pub label_len: usize,
}

impl Group {
    fn err(&self, key: &str, msg: impl std::fmt::Display) -> Error {
        let place = if self.name == "ROOT" {
            String::new()
        } else {
            format!("OBJECT {}: ", self.name)
        };
        Error::parse(&self.path, format!("{place}`{key}`: {msg}"))
    }

    /// The value of `key` (first occurrence), or `None`.
    pub fn find(&self, key: &str) -> Option<&Value> {
        self.entries
            .iter()
            .find(|(k, _)| k.eq_ignore_ascii_case(key))
            .map(|(_, v)| v)
    }

    /// The value of `key`; error naming the file and key when missing.
    pub fn get(&self, key: &str) -> Result<&Value> {
        self.find(key).ok_or_else(|| self.err(key, "missing key"))
    }

    /// The nested `OBJECT`/`GROUP` named `name`.
    pub fn object(&self, name: &str) -> Result<&Group> {
        self.children
            .iter()
            .find(|g| g.name.eq_ignore_ascii_case(name))
            .ok_or_else(|| Error::parse(&self.path, format!("missing OBJECT `{name}`")))
    }

    /// String value of `key` (quoted strings have whitespace runs collapsed).
    pub fn string(&self, key: &str) -> Result<String> {
        self.get(key)?
            .as_text()
            .ok_or_else(|| self.err(key, "expected a string, found a sequence"))
    }

    /// Number and optional unit of `key`.
    pub fn f64_with_unit(&self, key: &str) -> Result<(f64, Option<String>)> {
        match self.get(key)? {
            Value::Scalar { text, unit } => {
                let v = parse_number(text)
                    .ok_or_else(|| self.err(key, format!("`{text}` is not a number")))?;
                Ok((v, unit.clone()))
            }
            other => Err(self.err(
                key,
                format!("expected a number, found {}", other.describe()),
            )),
        }
    }

    /// Number of `key`, whose unit must be `unit` (case-insensitive) or absent.
    pub fn f64_in(&self, key: &str, unit: &str) -> Result<f64> {
        let (v, u) = self.f64_with_unit(key)?;
        match u {
            Some(u) if !u.eq_ignore_ascii_case(unit) => {
                Err(self.err(key, format!("unit <{u}>, expected <{unit}>")))
            }
            _ => Ok(v),
        }
    }

    /// Number of `key`, any unit ignored.
    pub fn f64(&self, key: &str) -> Result<f64> {
        Ok(self.f64_with_unit(key)?.0)
    }

    /// Integer value of `key`.
    pub fn i64(&self, key: &str) -> Result<i64> {
        match self.get(key)? {
            Value::Scalar { text, .. } => text
                .parse::<i64>()
                .map_err(|_| self.err(key, format!("`{text}` is not an integer"))),
            other => Err(self.err(
                key,
                format!("expected an integer, found {}", other.describe()),
            )),
        }
    }

    /// Numbers of the sequence `key` (flattened one level), with the
    /// sequence's unit if any.
    pub fn f64_seq(&self, key: &str) -> Result<(Vec<f64>, Option<String>)> {
        match self.get(key)? {
            Value::Sequence { items, unit } => {
                let mut out = Vec::with_capacity(items.len());
                for (i, it) in items.iter().enumerate() {
                    match it {
                        Value::Scalar { text, .. } => {
                            out.push(parse_number(text).ok_or_else(|| {
                                self.err(key, format!("item {i}: `{text}` is not a number"))
                            })?)
                        }
                        other => {
                            return Err(self.err(
                                key,
                                format!("item {i}: expected a number, found {}", other.describe()),
                            ))
                        }
                    }
                }
                Ok((out, unit.clone()))
            }
            other => Err(self.err(
                key,
                format!("expected a sequence, found {}", other.describe()),
            )),
        }
    }

    /// Sequence `key` of exactly `n` numbers.
    pub fn f64_array<const N: usize>(&self, key: &str) -> Result<[f64; N]> {
        let (v, _) = self.f64_seq(key)?;
        v.as_slice()
            .try_into()
            .map_err(|_| self.err(key, format!("expected {N} numbers, found {}", v.len())))
    }
}

impl Label {
    /// Reads and parses the label at the start of `path`.
    pub fn read(path: impl AsRef<Path>) -> Result<Label> {
        let path = path.as_ref();
        let bytes = crate::infile::read_bounded(path, crate::infile::DATA_LIMIT)?;
        Self::parse(&bytes, path)
    }

    /// Parses the label at the start of `bytes` (the file may continue with
    /// binary data after `END`); `path` is used in error messages.
    pub fn parse(bytes: &[u8], path: impl AsRef<Path>) -> Result<Label> {
        Parser {
            b: bytes,
            i: 0,
            path: path.as_ref().to_path_buf(),
            depth: 0,
        }
        .label()
    }

    /// Top-level accessor shortcuts (see [`Group`]).
    pub fn get(&self, key: &str) -> Result<&Value> {
        self.root.get(key)
    }

    /// The file the label came from.
    pub fn path(&self) -> &Path {
        &self.root.path
    }

    /// 0-based byte offset of the object `^name` points to, e.g.
    /// `^IMAGE = 36865 <BYTES>` gives 36864 and `^IMAGE = 37` (records) gives
    /// `36 * RECORD_BYTES`. Detached pointers (`("FILE", n)`) are refused.
    pub fn pointer(&self, name: &str) -> Result<u64> {
        let key = format!("^{name}");
        let root = &self.root;
        match root.get(&key)? {
            Value::Scalar { text, unit } => {
                let n: u64 = text
                    .parse()
                    .map_err(|_| root.err(&key, format!("`{text}` is not a positive integer")))?;
                if n == 0 {
                    return Err(root.err(&key, "pointers are 1-based; 0 is invalid"));
                }
                match unit.as_deref() {
                    Some(u) if u.eq_ignore_ascii_case("BYTES") => Ok(n - 1),
                    None => {
                        let rb = root.i64("RECORD_BYTES")?;
                        if rb <= 0 {
                            return Err(root.err("RECORD_BYTES", "must be positive"));
                        }
                        (n - 1).checked_mul(rb as u64).ok_or_else(|| {
                            root.err(&key, format!("{n} records of {rb} bytes overflow"))
                        })
                    }
                    Some(u) => Err(root.err(&key, format!("unsupported pointer unit <{u}>"))),
                }
            }
            other => Err(root.err(
                &key,
                format!(
                    "detached or malformed pointer {} is not supported",
                    other.describe()
                ),
            )),
        }
    }
}

fn parse_number(text: &str) -> Option<f64> {
    // PDS3 also allows radix integers `16#FF#`; accept them for completeness.
    if let Some((radix, rest)) = text.split_once('#') {
        let digits = rest.strip_suffix('#')?;
        let r: u32 = radix.parse().ok()?;
        return i64::from_str_radix(digits, r).ok().map(|v| v as f64);
    }
    text.parse::<f64>().ok()
}

struct Parser<'a> {
    b: &'a [u8],
    i: usize,
    path: PathBuf,
    /// Open `(`/`{` around the value being parsed (bounded: the parser
    /// recurses once per level).
    depth: usize,
}

/// Deepest sequence/set nesting accepted; real labels use two.
const MAX_NESTING: usize = 32;

impl Parser<'_> {
    fn line(&self) -> usize {
        1 + self.b[..self.i.min(self.b.len())]
            .iter()
            .filter(|&&c| c == b'\n')
            .count()
    }

    fn fail(&self, msg: impl std::fmt::Display) -> Error {
        Error::parse(&self.path, format!("line {}: {msg}", self.line()))
    }

    fn peek(&self) -> Option<u8> {
        self.b.get(self.i).copied()
    }

    /// Skips whitespace and `/* */` comments.
    fn skip_ws(&mut self) -> Result<()> {
        loop {
            match self.peek() {
                Some(c) if c.is_ascii_whitespace() => self.i += 1,
                Some(b'/') if self.b.get(self.i + 1) == Some(&b'*') => {
                    let start = self.i;
                    let end = self.b[self.i + 2..].windows(2).position(|w| w == b"*/");
                    match end {
                        Some(p) => self.i += 2 + p + 2,
                        None => {
                            self.i = start;
                            return Err(self.fail("unterminated comment `/*` (truncated label?)"));
                        }
                    }
                }
                _ => return Ok(()),
            }
        }
    }

    /// Skips spaces and tabs only (a unit must be on the value's line).
    fn skip_blanks(&mut self) {
        while matches!(self.peek(), Some(b' ' | b'\t')) {
            self.i += 1;
        }
    }

    fn identifier(&mut self) -> Result<String> {
        let start = self.i;
        while let Some(c) = self.peek() {
            if c.is_ascii_alphanumeric() || matches!(c, b'_' | b':' | b'^') {
                self.i += 1;
            } else {
                break;
            }
        }
        if self.i == start {
            return Err(match self.peek() {
                None => self.fail("unexpected end of file before `END` (truncated label?)"),
                Some(c) if !c.is_ascii() || (c.is_ascii_control() && !c.is_ascii_whitespace()) => {
                    self.fail("binary data before `END` (not a PDS3 label, or truncated)")
                }
                Some(c) => self.fail(format!("expected a keyword, found `{}`", c as char)),
            });
        }
        Ok(String::from_utf8_lossy(&self.b[start..self.i]).into_owned())
    }

    fn unit(&mut self) -> Result<Option<String>> {
        self.skip_blanks();
        if self.peek() != Some(b'<') {
            return Ok(None);
        }
        let start = self.i + 1;
        match self.b[start..]
            .iter()
            .position(|&c| c == b'>' || c == b'\n')
        {
            Some(p) if self.b[start + p] == b'>' => {
                self.i = start + p + 1;
                Ok(Some(
                    String::from_utf8_lossy(&self.b[start..start + p])
                        .trim()
                        .to_string(),
                ))
            }
            _ => Err(self.fail("unterminated unit `<`")),
        }
    }

    fn value(&mut self) -> Result<Value> {
        self.skip_ws()?;
        match self.peek() {
            None => Err(self.fail("unexpected end of file: missing value (truncated label?)")),
            Some(q @ (b'"' | b'\'')) => {
                let start = self.i + 1;
                match self.b[start..].iter().position(|&c| c == q) {
                    Some(p) => {
                        self.i = start + p + 1;
                        let s =
                            String::from_utf8_lossy(&self.b[start..start + p]).replace('\r', "");
                        Ok(if q == b'"' {
                            Value::Quoted(s)
                        } else {
                            Value::Symbol(s)
                        })
                    }
                    None => Err(self.fail("unterminated quoted string (truncated label?)")),
                }
            }
            Some(open @ (b'(' | b'{')) => {
                let close = if open == b'(' { b')' } else { b'}' };
                if self.depth >= MAX_NESTING {
                    return Err(
                        self.fail(format!("sequences nested deeper than {MAX_NESTING} levels"))
                    );
                }
                self.i += 1;
                self.depth += 1;
                let mut items = Vec::new();
                loop {
                    self.skip_ws()?;
                    match self.peek() {
                        Some(c) if c == close => {
                            self.i += 1;
                            break;
                        }
                        None => return Err(self.fail("unterminated sequence (truncated label?)")),
                        _ => {}
                    }
                    items.push(self.value()?);
                    self.skip_ws()?;
                    match self.peek() {
                        Some(b',') => self.i += 1,
                        Some(c) if c == close => {}
                        None => return Err(self.fail("unterminated sequence (truncated label?)")),
                        Some(c) => {
                            return Err(self.fail(format!(
                                "expected `,` or `{}` in sequence, found `{}`",
                                close as char, c as char
                            )))
                        }
                    }
                }
                self.depth -= 1;
                let unit = self.unit()?;
                Ok(Value::Sequence { items, unit })
            }
            Some(_) => {
                let start = self.i;
                while let Some(c) = self.peek() {
                    if c.is_ascii_whitespace()
                        || matches!(c, b',' | b')' | b'}' | b'<' | b'(' | b'{' | b'=')
                    {
                        break;
                    }
                    if c == b'/' && self.b.get(self.i + 1) == Some(&b'*') {
                        break;
                    }
                    if !c.is_ascii() || c.is_ascii_control() {
                        return Err(self.fail("binary data inside a value (not a PDS3 label?)"));
                    }
                    self.i += 1;
                }
                if self.i == start {
                    return Err(self.fail(format!(
                        "expected a value, found `{}`",
                        self.b[start] as char
                    )));
                }
                let text = String::from_utf8_lossy(&self.b[start..self.i]).into_owned();
                let unit = self.unit()?;
                Ok(Value::Scalar { text, unit })
            }
        }
    }

    fn label(mut self) -> Result<Label> {
        // A PDS3 label starts with PDS_VERSION_ID = PDS3 (optionally after
        // comments / an SFDU header, which these products do not have).
        self.skip_ws()?;
        let first = self.identifier().map_err(|_| {
            Error::parse(
                &self.path,
                "not a PDS3 file: it does not start with `PDS_VERSION_ID`",
            )
        })?;
        if !first.eq_ignore_ascii_case("PDS_VERSION_ID") {
            return Err(Error::parse(
                &self.path,
                format!("not a PDS3 file: first keyword is `{first}`, expected `PDS_VERSION_ID`"),
            ));
        }
        self.skip_ws()?;
        if self.peek() != Some(b'=') {
            return Err(self.fail("expected `=` after `PDS_VERSION_ID`"));
        }
        self.i += 1;
        let version = self.value()?;
        if version.as_text().as_deref() != Some("PDS3") {
            return Err(Error::parse(
                &self.path,
                format!("not a PDS3 file: PDS_VERSION_ID = {version:?}"),
            ));
        }
        let new_group = |name: &str, path: &PathBuf| Group {
            path: path.clone(),
            name: name.to_string(),
            entries: vec![],
            children: vec![],
        };
        let mut stack = vec![new_group("ROOT", &self.path)];
        stack[0].entries.push(("PDS_VERSION_ID".into(), version));
        loop {
            self.skip_ws()?;
            let key = self.identifier()?;
            let upper = key.to_ascii_uppercase();
            if upper == "END" {
                // `END` must be a whole statement, not e.g. `END = 3`.
                let save = self.i;
                self.skip_blanks();
                if self.peek() != Some(b'=') {
                    self.i = save;
                    if stack.len() > 1 {
                        let open = stack.last().map(|g| g.name.clone()).unwrap_or_default();
                        return Err(
                            self.fail(format!("`END` inside OBJECT `{open}` (missing END_OBJECT)"))
                        );
                    }
                    // Consume the rest of the END line.
                    while let Some(c) = self.peek() {
                        self.i += 1;
                        if c == b'\n' {
                            break;
                        }
                    }
                    let root = stack.pop().expect("root group");
                    return Ok(Label {
                        root,
                        label_len: self.i,
                    });
                }
                self.i = save;
            }
            self.skip_ws()?;
            let closes = upper == "END_OBJECT" || upper == "END_GROUP";
            if closes && self.peek() != Some(b'=') {
                // `END_OBJECT` may appear without `= NAME`.
                if stack.len() < 2 {
                    return Err(self.fail(format!("`{key}` without a matching OBJECT/GROUP")));
                }
                let g = stack.pop().expect("non-root group");
                stack.last_mut().expect("parent").children.push(g);
                continue;
            }
            match self.peek() {
                Some(b'=') => self.i += 1,
                None => {
                    return Err(self.fail(format!(
                        "unexpected end of file after `{key}` (truncated label?)"
                    )))
                }
                Some(c) => {
                    return Err(
                        self.fail(format!("expected `=` after `{key}`, found `{}`", c as char))
                    )
                }
            }
            let value = self.value()?;
            match upper.as_str() {
                "OBJECT" | "GROUP" => {
                    let name = value
                        .as_text()
                        .ok_or_else(|| self.fail(format!("{key} name must be a word")))?;
                    stack.push(new_group(&name, &self.path));
                }
                "END_OBJECT" | "END_GROUP" => {
                    if stack.len() < 2 {
                        return Err(self.fail(format!("`{key}` without a matching OBJECT/GROUP")));
                    }
                    let g = stack.pop().expect("non-root group");
                    if let Some(name) = value.as_text() {
                        if !name.eq_ignore_ascii_case(&g.name) {
                            return Err(
                                self.fail(format!("`{key} = {name}` closes OBJECT `{}`", g.name))
                            );
                        }
                    }
                    stack.last_mut().expect("parent").children.push(g);
                }
                _ => stack.last_mut().expect("group").entries.push((key, value)),
            }
        }
    }
}

/// An image read from a PDS3 file with an attached label.
#[derive(Debug, Clone)]
pub struct Pds3Image {
    /// The label.
    pub label: Label,
    /// Stored sample values, row by row in file order (first line first).
    pub raw: Vec<u16>,
    /// Physical values `raw * SCALING_FACTOR + OFFSET`, same layout; for
    /// AMIE these are DN = raw / 64.
    pub scaled: Raster,
}

/// Reads the `IMAGE` object of an attached-label PDS3 file: unsigned 8- or
/// 16-bit samples (LSB or MSB), with line prefix/suffix bytes skipped and
/// A byte count that may be absent (0): non-negative and below 2^31.
fn optional_count(img: &Group, key: &str) -> Result<u64> {
    match img.find(key) {
        None => Ok(0),
        Some(_) => {
            let v = img.i64(key)?;
            if (0..1 << 31).contains(&v) {
                Ok(v as u64)
            } else {
                Err(img.err(key, format!("must be in 0 … 2^31, found {v}")))
            }
        }
    }
}

/// `SCALING_FACTOR`/`OFFSET` applied. Checks `FILE_RECORDS * RECORD_BYTES`
/// against the file length for fixed-length records, and that the image
/// lies inside the file.
pub fn read_image(path: impl AsRef<Path>) -> Result<Pds3Image> {
    let path = path.as_ref();
    let bytes = crate::infile::read_bounded(path, crate::infile::DATA_LIMIT)?;
    parse_image(&bytes, path)
}

/// [`read_image`] on the file's bytes; `path` names it in errors.
pub fn parse_image(bytes: &[u8], path: &Path) -> Result<Pds3Image> {
    let label = Label::parse(bytes, path)?;
    let root = &label.root;

    let record_type = root.string("RECORD_TYPE")?;
    if record_type.eq_ignore_ascii_case("FIXED_LENGTH") {
        let rb = root.i64("RECORD_BYTES")?;
        let nrec = root.i64("FILE_RECORDS")?;
        let expected = rb
            .checked_mul(nrec)
            .filter(|&v| v > 0)
            .ok_or_else(|| root.err("FILE_RECORDS", "invalid record count"))?;
        if expected as u64 != bytes.len() as u64 {
            return Err(Error::parse(path, format!(
                "FILE_RECORDS ({nrec}) x RECORD_BYTES ({rb}) = {expected} bytes, but the file has {} bytes (truncated or padded file)",
                bytes.len()
            )));
        }
        if let Ok(lr) = root.i64("LABEL_RECORDS") {
            let label_bytes = lr.checked_mul(rb).filter(|&v| v >= 0);
            if label_bytes
                .is_none_or(|v| v as u64 > bytes.len() as u64 || v < label.label_len as i64)
            {
                return Err(root.err(
                    "LABEL_RECORDS",
                    format!(
                        "{lr} records of {rb} bytes do not hold the {}-byte label",
                        label.label_len
                    ),
                ));
            }
        }
    }

    let img = root.object("IMAGE")?;
    let lines = img.i64("LINES")?;
    let samples = img.i64("LINE_SAMPLES")?;
    if lines <= 0 || samples <= 0 {
        return Err(img.err("LINES", format!("invalid image size {samples}x{lines}")));
    }
    let bits = img.i64("SAMPLE_BITS")?;
    let stype = img.string("SAMPLE_TYPE")?.to_ascii_uppercase();
    let little = match stype.as_str() {
        "LSB_UNSIGNED_INTEGER" | "PC_UNSIGNED_INTEGER" | "VAX_UNSIGNED_INTEGER" => true,
        "MSB_UNSIGNED_INTEGER"
        | "UNSIGNED_INTEGER"
        | "SUN_UNSIGNED_INTEGER"
        | "MAC_UNSIGNED_INTEGER" => false,
        other => return Err(img.err("SAMPLE_TYPE", format!("unsupported sample type `{other}`"))),
    };
    let bps = match bits {
        8 => 1usize,
        16 => 2usize,
        b => return Err(img.err("SAMPLE_BITS", format!("unsupported {b} bits per sample"))),
    };
    let prefix = optional_count(img, "LINE_PREFIX_BYTES")?;
    let suffix = optional_count(img, "LINE_SUFFIX_BYTES")?;
    let scale = img
        .find("SCALING_FACTOR")
        .map(|_| img.f64("SCALING_FACTOR"))
        .transpose()?
        .unwrap_or(1.0);
    let offset = img
        .find("OFFSET")
        .map(|_| img.f64("OFFSET"))
        .transpose()?
        .unwrap_or(0.0);

    if !(scale.is_finite() && offset.is_finite()) {
        return Err(img.err("SCALING_FACTOR", "SCALING_FACTOR and OFFSET must be finite"));
    }
    let (w, h) = (samples as usize, lines as usize);
    let start = label.pointer("IMAGE")?;
    if start >= bytes.len() as u64 {
        return Err(root.err(
            "^IMAGE",
            format!(
                "byte {start} is past the end of the {}-byte file",
                bytes.len()
            ),
        ));
    }
    // Every size comes from the label: checked, so a value near 2^63 is an
    // error rather than a wrapped slice bound.
    let line_bytes = (w as u64)
        .checked_mul(bps as u64)
        .and_then(|v| v.checked_add(prefix))
        .and_then(|v| v.checked_add(suffix));
    let end = line_bytes
        .and_then(|l| l.checked_mul(h as u64))
        .and_then(|v| v.checked_add(start));
    let (Some(line_bytes), Some(end)) = (line_bytes, end) else {
        return Err(img.err(
            "LINES",
            format!("a {w}x{h} image at byte {start} overflows"),
        ));
    };
    if end > bytes.len() as u64 {
        return Err(Error::parse(path, format!(
            "IMAGE ({w}x{h}, {bits}-bit) at byte {start} needs {end} bytes, the file has {} (truncated?)",
            bytes.len()
        )));
    }
    // Inside the file now, so these fit in usize.
    let (start, line_bytes, prefix) = (start as usize, line_bytes as usize, prefix as usize);
    let mut raw = Vec::with_capacity(w * h);
    for r in 0..h {
        let row =
            &bytes[start + r * line_bytes + prefix..start + r * line_bytes + prefix + w * bps];
        if bps == 1 {
            raw.extend(row.iter().map(|&v| v as u16));
        } else if little {
            raw.extend(
                row.chunks_exact(2)
                    .map(|c| u16::from_le_bytes([c[0], c[1]])),
            );
        } else {
            raw.extend(
                row.chunks_exact(2)
                    .map(|c| u16::from_be_bytes([c[0], c[1]])),
            );
        }
    }
    let data = raw
        .iter()
        .map(|&v| (v as f64 * scale + offset) as f32)
        .collect();
    let scaled = Raster::new(w, h, data)?;
    Ok(Pds3Image { label, raw, scaled })
}
