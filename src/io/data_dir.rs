//! The runtime data directory: one folder that holds what `dopslam` loads at run time
//! and does not compile in, found wherever the binary runs.
//!
//! ```text
//! DATA/ort/libonnxruntime.so            ONNX Runtime (keyframe detector)
//! DATA/models/yolov4-tiny-320x256.onnx  the default detector (and the others)
//! DATA/vocabulary.dbow                  the place-recognition vocabulary (loop closing)
//! ```
//!
//! The folder is looked for in this order (the first that applies wins):
//! 1. an explicit path in the config (`[detector] model_path`, `ort_library`,
//!    `[global] vocabulary`) names that one file, wherever the data directory is;
//! 2. `DOPSLAM_DATA`: when set, the only data directory looked at;
//! 3. the directory `tools/setup.sh` installed into, recorded in
//!    `$XDG_DATA_HOME/dopslam/data-dir` (default `~/.local/share/dopslam/data-dir`);
//! 4. `./data` under the working directory (a checkout used in place).
//!
//! `dopslam doctor` prints what was found where.

use std::path::{Path, PathBuf};

/// The environment variable that names the data directory.
pub const ENV: &str = "DOPSLAM_DATA";
/// The ONNX Runtime library, under the data directory.
pub const ORT_LIBRARY: &str = "ort/libonnxruntime.so";
/// The place-recognition vocabulary, under the data directory.
pub const VOCABULARY: &str = "vocabulary.dbow";
/// What to run when something is missing.
pub const INSTALL_HINT: &str = "run `bash tools/setup.sh` in the dopslam checkout (it installs ONNX Runtime and the detectors and records where), or set DOPSLAM_DATA to a folder holding ort/, models/ and vocabulary.dbow; `dopslam doctor` shows what was looked for where";

/// Why a data directory was chosen.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DataOrigin {
    /// `DOPSLAM_DATA` names it.
    Environment,
    /// `tools/setup.sh` recorded it in this file.
    Installed {
        /// The record file.
        record: PathBuf,
    },
    /// `./data` under the working directory.
    WorkingDirectory,
}

impl std::fmt::Display for DataOrigin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DataOrigin::Environment => write!(f, "{ENV}"),
            DataOrigin::Installed { record } => {
                write!(
                    f,
                    "installed by tools/setup.sh (recorded in {})",
                    record.display()
                )
            }
            DataOrigin::WorkingDirectory => write!(f, "./data of the working directory"),
        }
    }
}

/// The data directory in use.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DataDir {
    /// The folder.
    pub path: PathBuf,
    /// Why it was chosen.
    pub origin: DataOrigin,
}

impl DataDir {
    /// The data directory of this process (see the module's order).
    pub fn locate() -> Self {
        if let Some(dir) = std::env::var_os(ENV).filter(|v| !v.is_empty()) {
            return Self {
                path: PathBuf::from(dir),
                origin: DataOrigin::Environment,
            };
        }
        if let Some((record, path)) = install_record().and_then(|record| {
            let path = read_record(&record)?;
            Some((record, path))
        }) {
            return Self {
                path,
                origin: DataOrigin::Installed { record },
            };
        }
        Self {
            path: PathBuf::from("data"),
            origin: DataOrigin::WorkingDirectory,
        }
    }

    /// A file under the data directory.
    pub fn file(&self, relative: impl AsRef<Path>) -> PathBuf {
        self.path.join(relative)
    }
}

/// The file where `tools/setup.sh` records the data directory it installed into:
/// `$XDG_DATA_HOME/dopslam/data-dir`, else `$HOME/.local/share/dopslam/data-dir`.
pub fn install_record() -> Option<PathBuf> {
    let base = std::env::var_os("XDG_DATA_HOME")
        .filter(|v| !v.is_empty())
        .map(PathBuf::from)
        .or_else(|| {
            std::env::var_os("HOME")
                .filter(|v| !v.is_empty())
                .map(|home| PathBuf::from(home).join(".local/share"))
        })?;
    Some(base.join("dopslam").join("data-dir"))
}

/// The directory a record names, when the record exists and the directory does.
fn read_record(record: &Path) -> Option<PathBuf> {
    let text = std::fs::read_to_string(record).ok()?;
    let path = PathBuf::from(text.trim_end_matches(['\n', '\r']));
    (path.is_absolute() && path.is_dir()).then_some(path)
}

/// A file the config names explicitly, else `relative` under the data directory.
pub fn resolve(explicit: Option<&Path>, relative: &str) -> PathBuf {
    match explicit {
        Some(path) => path.to_path_buf(),
        None => DataDir::locate().file(relative),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_record_names_an_existing_absolute_directory_only() {
        let dir = std::env::temp_dir().join(format!("dopslam-record-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let record = dir.join("data-dir");
        std::fs::write(&record, format!("{}\n", dir.display())).unwrap();
        assert_eq!(read_record(&record), Some(dir.clone()));
        std::fs::write(&record, "relative/data\n").unwrap();
        assert_eq!(read_record(&record), None);
        std::fs::write(&record, format!("{}\n", dir.join("gone").display())).unwrap();
        assert_eq!(read_record(&record), None);
        assert_eq!(read_record(&dir.join("no-record")), None);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn an_explicit_path_wins() {
        let explicit = PathBuf::from("/somewhere/my.onnx");
        assert_eq!(resolve(Some(&explicit), "models/x.onnx"), explicit);
        assert!(resolve(None, VOCABULARY).ends_with(VOCABULARY));
    }
}
