//! Errors of the readers and writers: each names the file, and the line where one applies.

use std::path::PathBuf;
use thiserror::Error;

#[derive(Debug, Error)]
pub enum IoError {
    #[error("cannot read {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot write {path}: {source}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}:{line}: {message}")]
    Parse {
        path: PathBuf,
        line: usize,
        message: String,
    },
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
    #[error("{path}: not found ({what})")]
    Missing { path: PathBuf, what: String },
    #[error("cannot decode image {path}: {message}")]
    Image { path: PathBuf, message: String },
}

impl IoError {
    pub fn parse(path: impl Into<PathBuf>, line: usize, message: impl Into<String>) -> Self {
        Self::Parse {
            path: path.into(),
            line,
            message: message.into(),
        }
    }

    pub fn invalid(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Self::Invalid {
            path: path.into(),
            message: message.into(),
        }
    }
}

/// Reads a whole text file, naming it in the error.
pub fn read_text(path: &std::path::Path) -> Result<String, IoError> {
    if !path.exists() {
        return Err(IoError::Missing {
            path: path.to_path_buf(),
            what: "no such file".into(),
        });
    }
    std::fs::read_to_string(path).map_err(|source| IoError::Read {
        path: path.to_path_buf(),
        source,
    })
}
