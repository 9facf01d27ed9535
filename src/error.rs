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

/// Library result.
pub type Result<T, E = Error> = std::result::Result<T, E>;

#[cfg(test)]
mod tests {
    use super::*;

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
