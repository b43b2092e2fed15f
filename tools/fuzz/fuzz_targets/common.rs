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

/// Opens the recording at `path` as a run does and decodes its first frames: every
/// container reader's path from the file's bytes to a frame.
pub fn open_recording(path: &std::path::Path) {
    use dopslam::io::sequence::Sequence;
    let options = dopslam::io::recording::RecordingOptions::default();
    if let Ok(recording) = dopslam::io::recording::RecordingSequence::open(path, &options) {
        for index in 0..recording.len().min(3) {
            let _ = recording.load(index);
        }
    }
}
