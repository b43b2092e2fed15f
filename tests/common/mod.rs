//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

/// The real reference data beside the checkout (`../shared/data`), or where
/// `DOPSLAM_SHARED_DATA` points. `None` (with a message saying why the test skips)
/// when it is absent.
pub fn shared_data(test: &str) -> Option<PathBuf> {
    let path = std::env::var_os("DOPSLAM_SHARED_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data"));
    if path.join("README.md").exists() {
        Some(path)
    } else {
        eprintln!(
            "skipping {test}: the shared reference data is not at {} (set DOPSLAM_SHARED_DATA)",
            path.display()
        );
        None
    }
}

/// A fresh, empty temporary folder for one test.
pub fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("dopslam-it-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}
