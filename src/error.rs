//! Error type shared by the library: every variant names the file, line or
//! field that caused it, so a user can fix the input without reading code.

use std::path::PathBuf;

/// Library error.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A configuration, trajectory or calibration file could not be read.
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
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
            source,
        }
    }
}

/// Library result.
pub type Result<T, E = Error> = std::result::Result<T, E>;
