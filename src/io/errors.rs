//! Errors of the readers and writers: each names the file, and the line where one applies.

use std::path::PathBuf;
use thiserror::Error;

/// Why a file cannot be read or written; each names the file, and the line where one applies.
#[derive(Debug, Error)]
pub enum IoError {
    #[error("cannot read {path}: {source}")]
    /// The file cannot be read.
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    #[error("cannot write {path}: {source}")]
    /// The file cannot be written.
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    #[error("{path}:{line}: {message}")]
    /// A line of the file cannot be parsed.
    Parse {
        /// The file.
        path: PathBuf,
        /// The line, from 1.
        line: usize,
        /// What is wrong.
        message: String,
    },
    #[error("{path}: {message}")]
    /// The file says something without meaning.
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    #[error("{path}: not found ({what})")]
    /// The file or folder does not exist.
    Missing {
        /// The file.
        path: PathBuf,
        /// What it should be.
        what: String,
    },
    #[error("cannot decode image {path}: {message}")]
    /// The image cannot be decoded.
    Image {
        /// The file.
        path: PathBuf,
        /// The decoder's message.
        message: String,
    },
}

impl IoError {
    /// A parse error at `line` of `path`.
    pub fn parse(path: impl Into<PathBuf>, line: usize, message: impl Into<String>) -> Self {
        Self::Parse {
            path: path.into(),
            line,
            message: message.into(),
        }
    }

    /// `path` cannot be read.
    pub fn read(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Read {
            path: path.into(),
            source,
        }
    }

    /// `path` says something without meaning.
    pub fn invalid(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Self::Invalid {
            path: path.into(),
            message: message.into(),
        }
    }
}

/// `Ok` when `path` exists; else `Missing` (with `what`), or, for a symbolic link that
/// leads back to itself, an error that says it is a loop (not "not found").
pub fn check_exists(path: &std::path::Path, what: &str) -> Result<(), IoError> {
    match std::fs::metadata(path) {
        Ok(_) => Ok(()),
        Err(e) if e.raw_os_error() == Some(libc::ELOOP) => Err(IoError::Invalid {
            path: path.to_path_buf(),
            message: "a loop of symbolic links (it leads back to itself)".into(),
        }),
        Err(_) => Err(IoError::Missing {
            path: path.to_path_buf(),
            what: what.into(),
        }),
    }
}

/// Reads a whole text file, naming it in the error.
pub fn read_text(path: &std::path::Path) -> Result<String, IoError> {
    check_exists(path, "no such file")?;
    std::fs::read_to_string(path).map_err(|source| IoError::Read {
        path: path.to_path_buf(),
        source,
    })
}
