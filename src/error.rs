//! Error type shared by the library: every variant names the file, line or
//! field that caused it, so a user can fix the input without reading code.

use std::path::PathBuf;

/// Library error.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A configuration, trajectory or calibration file could not be read.
    /// The I/O error is in the message and deliberately not a `source`:
    /// error chains (`{:#}`) would print its text twice.
    #[error("{path}: {cause}")]
    Io {
        path: PathBuf,
        cause: std::io::Error,
    },
    /// A file was read but its content is invalid.
    #[error("{path}: {message}")]
    Parse { path: PathBuf, message: String },
    /// A field has a value outside its domain.
    #[error("invalid `{field}`: {message}")]
    Invalid { field: String, message: String },
    /// Anything else, with context.
    #[error("{0}")]
    Other(String),
}

impl Error {
    /// Invalid value of the named field.
    pub fn invalid(field: impl Into<String>, message: impl Into<String>) -> Self {
        Error::Invalid {
            field: field.into(),
            message: message.into(),
        }
    }

    /// Parse failure in the named file.
    pub fn parse(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Error::Parse {
            path: path.into(),
            message: message.into(),
        }
    }

    /// I/O failure on the named file.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            cause: source,
        }
    }
}

/// `text` cut to at most `max` characters (with `…`), so a 1 MB cell in
/// a bad file gives a one-line message.
pub fn abbreviate(text: &str, max: usize) -> String {
    if text.chars().count() <= max {
        return text.to_string();
    }
    let mut out: String = text.chars().take(max.saturating_sub(1)).collect();
    out.push('…');
    out
}

/// One-line message of a TOML error: the line it is on, that line's text
/// (which names the key) and what is wrong, abbreviated (the toml crate's
/// own text spans several lines with a source excerpt).
pub fn toml_message(text: &str, e: &toml::de::Error) -> String {
    let msg = abbreviate(&e.message().replace('\n', " "), 400);
    let Some(span) = e.span() else {
        return msg;
    };
    let start = span.start.min(text.len());
    if !text.is_char_boundary(start) {
        return msg;
    }
    let line_no = text.as_bytes()[..start]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1;
    let line_start = text[..start].rfind('\n').map_or(0, |i| i + 1);
    let line_end = text[start..].find('\n').map_or(text.len(), |i| start + i);
    // The line around the error's start: up to 40 characters before it
    // (the key) and 60 after (the value).
    let before: String = text[line_start..start].chars().rev().take(40).collect();
    let before: String = before.chars().rev().collect();
    let after: String = text[start..line_end].chars().take(60).collect();
    let cut_left = if before.len() < start - line_start {
        "…"
    } else {
        ""
    };
    let cut_right = if after.len() < line_end - start {
        "…"
    } else {
        ""
    };
    let source = format!("{cut_left}{before}{after}{cut_right}");
    let source = source.trim();
    if source.is_empty() {
        format!("line {line_no}: {msg}")
    } else {
        format!("line {line_no} (`{source}`): {msg}")
    }
}

/// Library result.
pub type Result<T, E = Error> = std::result::Result<T, E>;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn toml_errors_are_one_line_naming_the_line_and_key() {
        #[derive(serde::Deserialize, Debug)]
        #[allow(dead_code)]
        struct T {
            radius: f64,
        }
        let text = "# a comment\n\nradius = \"big\"\n";
        let e = toml::from_str::<T>(text).unwrap_err();
        assert!(
            e.to_string().contains('\n'),
            "the crate's own text is multi-line"
        );
        let m = toml_message(text, &e);
        assert!(!m.contains('\n'), "{m}");
        assert!(m.starts_with("line 3 "), "{m}");
        assert!(m.contains("radius"), "{m}");
        // A very long line is cut around the error.
        let long = format!("radius = \"{}\"", "x".repeat(5000));
        let e = toml::from_str::<T>(&long).unwrap_err();
        let m = toml_message(&long, &e);
        assert!(m.len() < 700, "{} chars", m.len());
        assert!(m.contains("radius"), "{m}");
    }

    #[test]
    fn io_errors_state_their_cause_once() {
        let e = Error::io(
            "x/y.csv",
            std::io::Error::from(std::io::ErrorKind::NotFound),
        );
        let chain = format!("{:#}", anyhow::Error::from(e));
        assert_eq!(chain.matches("not found").count(), 1, "{chain}");
        assert!(chain.starts_with("x/y.csv: "), "{chain}");
    }

    #[test]
    fn abbreviation_keeps_short_text_and_cuts_long() {
        assert_eq!(abbreviate("abc", 5), "abc");
        let long = "x".repeat(1_000_000);
        let a = abbreviate(&long, 80);
        assert_eq!(a.chars().count(), 80);
        assert!(a.ends_with('…'));
    }
}
