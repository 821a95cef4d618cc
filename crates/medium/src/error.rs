//! Errors of the medium crate: small, matchable, and naming what was wrong.

use std::path::PathBuf;

/// Everything that can go wrong while building a medium or reading or writing a volume.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum MediumError {
    /// A volume file cannot be read or does not match what was declared.
    #[error("{file}: {message}")]
    Volume { file: PathBuf, message: String },
    /// An argument to a constructor is invalid (dims of zero, negative cell size, ...).
    #[error("invalid {what}: {message}")]
    Invalid { what: &'static str, message: String },
    /// Reading or writing a file failed. (The OS error is the message, not a source, so
    /// that an error chain prints it once.)
    #[error("{file}: {error}")]
    Io {
        file: PathBuf,
        error: std::io::Error,
    },
}

impl MediumError {
    pub fn invalid(what: &'static str, message: impl Into<String>) -> Self {
        MediumError::Invalid {
            what,
            message: message.into(),
        }
    }
}
