//! The one error type for bad input. The CLI maps any `DataError` in an error chain to exit code 2
//! (DESIGN.md: "2 bad input, with a message naming what and where"); everything else exits 1.

use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum DataError {
    /// A file that is missing, unreadable, or malformed as a whole.
    #[error("{}: {msg}", path.display())]
    File { path: PathBuf, msg: String },
    /// One field (a JSON key, an npz array, a frame entry, an image channel) of a file is wrong.
    #[error("{}: {field}: {msg}", path.display())]
    Field { path: PathBuf, field: String, msg: String },
    /// Bad input not tied to one file (a command-line value, an empty split).
    #[error("{0}")]
    Invalid(String),
}

impl DataError {
    pub fn file(path: impl AsRef<Path>, msg: impl Into<String>) -> Self {
        DataError::File {
            path: path.as_ref().to_path_buf(),
            msg: msg.into(),
        }
    }
    pub fn field(path: impl AsRef<Path>, field: impl Into<String>, msg: impl Into<String>) -> Self {
        DataError::Field {
            path: path.as_ref().to_path_buf(),
            field: field.into(),
            msg: msg.into(),
        }
    }
    pub fn invalid(msg: impl Into<String>) -> Self {
        DataError::Invalid(msg.into())
    }
}

pub type Result<T, E = DataError> = std::result::Result<T, E>;
