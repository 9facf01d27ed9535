//! CSV tables (LUT, geometry, trajectories, spectra) read with the `csv`
//! crate, which handles quoting, CRLF and a UTF-8 byte-order mark. This adds
//! what every table here shares: `#` comment lines and blank lines skipped,
//! cells trimmed, and the line each row starts on, for error messages.

use std::path::Path;

use crate::error::{Error, Result};

/// One row of a table: the line it starts on (from 1) and its cells.
#[derive(Debug)]
pub struct Row {
    pub line: usize,
    pub cells: csv::StringRecord,
}

impl Row {
    /// The cells joined by commas (a header as written, without spaces).
    pub fn joined(&self) -> String {
        self.cells.iter().collect::<Vec<_>>().join(",")
    }

    /// The number of cells.
    pub fn len(&self) -> usize {
        self.cells.len()
    }

    /// Whether the row has no cells.
    pub fn is_empty(&self) -> bool {
        self.cells.is_empty()
    }
}

/// The rows of `bytes` with `delimiter`; `path` names the file in errors.
/// Rows may have any number of cells: each table checks its own.
pub fn rows<'a>(
    path: &'a Path,
    bytes: &'a [u8],
    delimiter: u8,
) -> impl Iterator<Item = Result<Row>> + 'a {
    let reader = csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .delimiter(delimiter)
        .trim(csv::Trim::All)
        .from_reader(bytes);
    // Lines are counted from the record's byte offset: the reader's own
    // count skips blank CRLF lines, and after a CRLF its offset points at
    // the LF, which is skipped here.
    let mut counted = (0usize, 1usize);
    let mut line_at = move |mut byte: usize| {
        while bytes.get(byte).is_some_and(|&b| b == b'\r' || b == b'\n') {
            byte += 1;
        }
        let (from, line) = counted;
        let newlines = bytes[from.min(byte)..byte]
            .iter()
            .filter(|&&b| b == b'\n')
            .count();
        counted = (byte, line + newlines);
        counted.1
    };
    reader
        .into_records()
        .filter_map(move |record| match record {
            Ok(cells) => {
                let byte = cells.position().map_or(0, |p| p.byte() as usize);
                let line = line_at(byte.min(bytes.len()));
                let blank = cells.iter().all(str::is_empty);
                let comment = cells.get(0).is_some_and(|c| c.starts_with('#'));
                (!blank && !comment).then_some(Ok(Row { line, cells }))
            }
            Err(e) => Some(Err(read_error(path, &e))),
        })
}

/// A reader error as one line naming the file and line.
fn read_error(path: &Path, e: &csv::Error) -> Error {
    let line = e.position().map_or(0, |p| p.line());
    let what = match e.kind() {
        csv::ErrorKind::Utf8 { .. } => "not UTF-8 text".to_string(),
        _ => e.to_string(),
    };
    Error::parse(path, format!("line {line}: {what}"))
}

/// The delimiter of a table that may use commas, semicolons, tabs or
/// spaces (instrument software writes all four): the first of those found
/// on the first line that is not blank or a comment.
pub fn sniff_delimiter(bytes: &[u8]) -> u8 {
    let first = bytes
        .split(|&b| b == b'\n')
        .map(|l| l.trim_ascii())
        .find(|l| !l.is_empty() && !l.starts_with(b"#"))
        .unwrap_or_default();
    [b',', b';', b'\t']
        .into_iter()
        .find(|d| first.contains(d))
        .unwrap_or(b' ')
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(text: &str) -> Vec<(usize, Vec<String>)> {
        rows(Path::new("t.csv"), text.as_bytes(), b',')
            .map(|r| {
                let r = r.unwrap();
                (r.line, r.cells.iter().map(String::from).collect())
            })
            .collect()
    }

    #[test]
    fn comments_blanks_bom_crlf_and_quotes() {
        let text = "\u{feff}a, b\r\n# note\r\n\r\n  \r\n1,\"2,5\"\r\n  # indented note\n3 , 4\n";
        let got = read(text);
        let want = vec![
            (1, vec!["a".to_string(), "b".into()]),
            (5, vec!["1".into(), "2,5".into()]),
            (7, vec!["3".into(), "4".into()]),
        ];
        assert_eq!(got, want);
    }

    #[test]
    fn invalid_utf8_names_file_and_line() {
        let bytes = b"a,b\n1,2\n3,\xff\n";
        let e = rows(Path::new("t.csv"), bytes, b',')
            .find_map(|r| r.err())
            .unwrap()
            .to_string();
        assert!(
            e.contains("t.csv") && e.contains("line 3") && e.contains("UTF-8"),
            "{e}"
        );
    }

    proptest::proptest! {
        /// Any mix of data, blank and comment lines with LF or CRLF ends:
        /// the data rows come back with the line they are on.
        #[test]
        fn rows_keep_their_line_numbers(
            lines in proptest::collection::vec((0usize..5, proptest::bool::ANY), 0..40)
        ) {
            const KINDS: [&str; 5] = ["1,2", "", "   ", "# c,d", "\"x,y\",3"];
            let mut text = String::new();
            let mut want = Vec::new();
            for (i, (kind, crlf)) in lines.iter().enumerate() {
                text.push_str(KINDS[*kind]);
                text.push_str(if *crlf { "\r\n" } else { "\n" });
                if *kind == 0 || *kind == 4 {
                    want.push(i + 1);
                }
            }
            let got: Vec<usize> = read(&text).into_iter().map(|(l, _)| l).collect();
            proptest::prop_assert_eq!(got, want);
        }
    }

    #[test]
    fn delimiter_is_sniffed_from_the_first_data_line() {
        assert_eq!(sniff_delimiter(b"# a,b\n400;1\n"), b';');
        assert_eq!(sniff_delimiter(b"400\t1\n"), b'\t');
        assert_eq!(sniff_delimiter(b"400  1\n"), b' ');
        assert_eq!(sniff_delimiter(b"\n400,1\n"), b',');
    }
}
