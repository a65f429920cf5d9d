//! The one error type of the house, classified by whose fault it is (the README's "Commands" exit codes):
//! bad input — a dataset, config key, `--set` value, edit spec or argument that is wrong — exits 2
//! with a message naming the file and field or key; everything else — a write that failed (full
//! disk, permissions), a run that diverged, an internal failure — exits 1. The CLI asks
//! [`DataError::is_bad_input`] of every `DataError` in an error chain.

use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum DataError {
    /// Bad input: a file that is missing, unreadable, or malformed as a whole.
    #[error("{}: {msg}", path.display())]
    File { path: PathBuf, msg: String },
    /// Bad input: one field (a JSON key, an npz array, a frame entry, an image channel, a config
    /// key) of a file is wrong.
    #[error("{}: {field}: {msg}", path.display())]
    Field { path: PathBuf, field: String, msg: String },
    /// Bad input not tied to one file (a command-line value, a `--set` key, an empty split).
    #[error("{0}")]
    Invalid(String),
    /// Not the input's fault: writing or creating `path` failed (full disk, permissions, …).
    #[error("{}: {msg}", path.display())]
    Io { path: PathBuf, msg: String },
    /// Not the input's fault: the computation failed (a diverged run, an internal error).
    #[error("{0}")]
    Failed(String),
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
    /// A failed write, directory creation or rename (exit code 1).
    pub fn io(path: impl AsRef<Path>, msg: impl Into<String>) -> Self {
        DataError::Io {
            path: path.as_ref().to_path_buf(),
            msg: msg.into(),
        }
    }
    /// A failure that is not the input's fault (exit code 1).
    pub fn failed(msg: impl Into<String>) -> Self {
        DataError::Failed(msg.into())
    }

    /// Whether the user's input is at fault (exit code 2) rather than the machine or the
    /// computation (exit code 1).
    pub fn is_bad_input(&self) -> bool {
        matches!(
            self,
            DataError::File { .. } | DataError::Field { .. } | DataError::Invalid(_)
        )
    }
}

pub type Result<T, E = DataError> = std::result::Result<T, E>;
