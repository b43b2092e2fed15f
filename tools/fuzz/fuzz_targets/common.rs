//! The readers take paths: each input goes to a file of this process's own first.

use std::path::PathBuf;

/// Writes `data` to this process's scratch file named `name` and returns its path.
pub fn scratch(name: &str, data: &[u8]) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("dopslam-fuzz-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("a scratch folder in the temp dir");
    let path = dir.join(name);
    std::fs::write(&path, data).expect("the scratch file is writable");
    path
}
