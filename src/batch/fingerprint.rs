//! What decides a batch run's result, recorded in its `run.json`, so that a batch
//! never takes a run made with other settings for one of its own: the sequence folder,
//! the frames, the mode, how it ran (deterministic or real time, the pace), the
//! effective config (the `config.toml` the run is given), the content of the ORB-SLAM2
//! settings file it names, the detector's files and the `dopslam` binary. Each is a
//! value or an FNV-1a hash of the content ([`crate::run::content_hash`]), under a name, so that a
//! difference can be said by name ("frames 10 -> 30", "config changed").
//!
//! The sequence counts by what it holds ([`sequence_files`]): the content of its text
//! files (its own calibration, the association and timestamp lists, the ground truth),
//! and each other file's name, size and modification time (the frames; a recording
//! file likewise). Not checked: a frame rewritten in place with the same size and its
//! old modification time restored, which only a hash of every image would see.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use crate::config::Config;
use crate::pacing::Pace;
use crate::run::content_hash;

pub use crate::records::RunInputs;

/// The hash of a file's content, `missing` when it cannot be read.
fn file_hash(path: &Path) -> String {
    std::fs::read(path).map_or_else(|_| "missing".into(), |bytes| content_hash(&bytes))
}

/// Text files up to this size count by their content; larger ones as frames do.
const TEXT_BYTES: u64 = 8 << 20;

/// How deep below a sequence folder its files are looked for (TUM's `rgb/`, KITTI's
/// `image_0/`, a ROS 2 bag folder's storage files).
const DEPTH: usize = 3;

/// The sequence's files by kind: `sequence calibration` (its own calibration:
/// `calibration.yaml`, KITTI's `calib.txt`, the recorder's YAML files), `sequence
/// lists` (the other text files: association and timestamp lists, ground truth), each a
/// hash of the content; and `sequence frames`, a hash of every other file's relative
/// path, size and modification time. A single file (a recording) is a `sequence
/// frames` of its own size and time.
pub fn sequence_files(path: &Path) -> Vec<(&'static str, String)> {
    let mut kinds: [(&'static str, Vec<String>); 3] = [
        ("sequence calibration", Vec::new()),
        ("sequence lists", Vec::new()),
        ("sequence frames", Vec::new()),
    ];
    let mut files = Vec::new();
    if path.is_dir() {
        collect_files(path, path, DEPTH, &mut files);
    } else {
        files.push((path.to_path_buf(), PathBuf::new()));
    }
    files.sort();
    for (file, relative) in files {
        let Ok(meta) = std::fs::metadata(&file) else {
            continue;
        };
        let name = relative.to_string_lossy().into_owned();
        let extension = file.extension().and_then(|e| e.to_str()).unwrap_or("");
        let text = ["txt", "yaml", "yml", "json", "csv", "toml"].contains(&extension)
            && meta.len() <= TEXT_BYTES;
        let (kind, value) = if text {
            let calibration = extension.starts_with("y") || name.ends_with("calib.txt");
            (usize::from(!calibration), file_hash(&file))
        } else {
            let time = meta
                .modified()
                .ok()
                .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok());
            (
                2,
                format!("{} {}", meta.len(), time.map_or(0, |t| t.as_nanos())),
            )
        };
        kinds[kind].1.push(format!("{name}\t{value}"));
    }
    kinds
        .into_iter()
        .filter(|(_, lines)| !lines.is_empty())
        .map(|(key, lines)| (key, content_hash(lines.join("\n").as_bytes())))
        .collect()
}

/// The regular files below `dir` (down to `depth` folders), each with its path
/// relative to `root`; symbolic links to folders are not followed.
fn collect_files(root: &Path, dir: &Path, depth: usize, out: &mut Vec<(PathBuf, PathBuf)>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        let Ok(kind) = entry.file_type() else {
            continue;
        };
        if kind.is_dir() && depth > 0 {
            collect_files(root, &path, depth - 1, out);
        } else if path.is_file() {
            let relative = path.strip_prefix(root).unwrap_or(&path).to_path_buf();
            out.push((path, relative));
        }
    }
}

/// A loaded map's part of a run's inputs (key `map`): the run folder, frozen or not,
/// and the map file's length and CRC-32 ([`crate::map::file::checksum`], from its
/// trailer without reading the rest); `no slam_map.bin` when the run has none (yet).
pub fn map_input(run: &Path, frozen: bool) -> String {
    let path = crate::io::run_dir::RunDir::new(run).slam_map();
    let what = match crate::map::file::checksum(&path) {
        Ok((length, crc)) => format!("{length} bytes, crc {crc:08x}"),
        Err(_) => "no slam_map.bin".into(),
    };
    let mode = if frozen { "frozen" } else { "continued" };
    format!("{} ({mode}): {what}", run.display())
}

/// Makes the inputs of runs, hashing each file it reads once.
pub struct Fingerprinter {
    files: Mutex<HashMap<PathBuf, String>>,
    sequences: Mutex<HashMap<PathBuf, Vec<(&'static str, String)>>>,
    program: String,
}

/// How a batch runs its runs (the same for all of them).
#[derive(Debug, Clone, Copy)]
pub struct Execution {
    /// Runs with `--deterministic`.
    pub deterministic: bool,
    /// How frames are paced.
    pub pace: Pace,
}

impl Fingerprinter {
    /// For runs started with `program`: its version and the hash of its file.
    pub fn new(program: &Path) -> Self {
        Self {
            files: Mutex::new(HashMap::new()),
            sequences: Mutex::new(HashMap::new()),
            program: format!("{} {}", env!("CARGO_PKG_VERSION"), file_hash(program)),
        }
    }

    /// [`file_hash`], each file read once.
    fn file(&self, path: &Path) -> String {
        let mut files = self.files.lock().expect("fingerprint cache poisoned");
        files
            .entry(path.to_path_buf())
            .or_insert_with(|| file_hash(path))
            .clone()
    }

    /// [`sequence_files`], each sequence read once.
    fn sequence(&self, path: &Path) -> Vec<(&'static str, String)> {
        let mut sequences = self.sequences.lock().expect("fingerprint cache poisoned");
        sequences
            .entry(path.to_path_buf())
            .or_insert_with(|| sequence_files(path))
            .clone()
    }

    /// The inputs of a run of `sequence_dir` (its first `frames`) in `mode`
    /// (`mode_flag`) with `config`, the config as its `config.toml` holds it.
    pub fn inputs(
        &self,
        sequence_dir: &Path,
        frames: Option<usize>,
        mode_flag: &str,
        config: &Config,
        execution: Execution,
    ) -> RunInputs {
        let mut inputs = RunInputs::new();
        let mut put = |key: &str, value: String| {
            inputs.insert(key.to_string(), value);
        };
        put("dopslam", self.program.clone());
        put("sequence", sequence_dir.display().to_string());
        for (key, value) in self.sequence(sequence_dir) {
            put(key, value);
        }
        put("frames", frames.map_or("all".into(), |f| f.to_string()));
        put("mode", mode_flag.to_string());
        put(
            "execution",
            match (execution.deterministic, execution.pace) {
                (true, _) => "deterministic".into(),
                (false, Pace::Recording) => "real time, paced as recorded".into(),
                (false, _) => "real time".into(),
            },
        );
        let text = toml::to_string(config).unwrap_or_default();
        put("config", content_hash(text.as_bytes()));
        if let Some(settings) = &config.dataset.settings {
            put("settings file", self.file(settings));
        }
        if config.detector.source == crate::detect::Source::Onnx
            || config.detector.source == crate::detect::Source::Auto
        {
            let files: Vec<String> = config
                .detector
                .onnx_files()
                .iter()
                .map(|(path, _)| self.file(path))
                .collect();
            put("detector files", content_hash(files.join(" ").as_bytes()));
        }
        inputs
    }
}

/// What differs between a run's recorded inputs and today's, by name (`frames 10 ->
/// 30`, `config changed`); empty when nothing does. A record without inputs (an
/// older dopslam's) differs in `inputs not recorded`.
pub fn differences(recorded: &RunInputs, now: &RunInputs) -> Vec<String> {
    if recorded.is_empty() {
        return vec!["inputs not recorded (an older dopslam made it)".into()];
    }
    let shown = ["frames", "mode", "execution", "sequence"];
    let mut keys: Vec<&String> = recorded.keys().chain(now.keys()).collect();
    keys.sort();
    keys.dedup();
    keys.into_iter()
        .filter(|k| recorded.get(*k) != now.get(*k))
        .map(|k| match (recorded.get(k), now.get(k)) {
            (Some(a), Some(b)) if shown.contains(&k.as_str()) => format!("{k} {a} -> {b}"),
            (Some(_), Some(_)) => format!("{k} changed"),
            (None, Some(_)) => format!("{k} added"),
            _ => format!("{k} removed"),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn inputs_of(frames: Option<usize>, config: &Config) -> RunInputs {
        let program = std::env::current_exe().unwrap();
        let execution = Execution {
            deterministic: false,
            pace: Pace::Free,
        };
        Fingerprinter::new(&program).inputs(Path::new("/seq"), frames, "--dop", config, execution)
    }

    #[test]
    fn a_change_of_frames_or_config_is_named() {
        let config = Config::default();
        let before = inputs_of(Some(10), &config);
        assert!(differences(&before, &inputs_of(Some(10), &config)).is_empty());
        assert_eq!(
            differences(&before, &inputs_of(Some(30), &config)),
            ["frames 10 -> 30"]
        );
        let mut other = config.clone();
        other.orb.n_features = 1500;
        assert_eq!(
            differences(&before, &inputs_of(Some(10), &other)),
            ["config changed"]
        );
        assert_eq!(
            differences(&RunInputs::new(), &before),
            ["inputs not recorded (an older dopslam made it)"]
        );
    }

    #[test]
    fn the_settings_file_counts_by_its_content() {
        let dir = std::env::temp_dir().join(format!("dopslam-fingerprint-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let settings = dir.join("cam.yaml");
        std::fs::write(&settings, "Camera.fx: 500\n").unwrap();
        let mut config = Config::default();
        config.dataset.settings = Some(settings.clone());
        let before = inputs_of(None, &config);
        std::fs::write(&settings, "Camera.fx: 520\n").unwrap();
        // A new fingerprinter reads the file again (one batch reads each file once).
        let after = inputs_of(None, &config);
        assert_eq!(differences(&before, &after), ["settings file changed"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// The sequence's own calibration, its lists and its frames each count, by name.
    #[test]
    fn a_sequence_s_calibration_lists_and_frames_count() {
        let dir =
            std::env::temp_dir().join(format!("dopslam-fingerprint-seq-{}", std::process::id()));
        let rgb = dir.join("rgb");
        std::fs::create_dir_all(&rgb).unwrap();
        std::fs::write(dir.join("calibration.yaml"), "Camera.fx: 500\n").unwrap();
        std::fs::write(dir.join("rgb.txt"), "1.0 rgb/1.png\n").unwrap();
        std::fs::write(rgb.join("1.png"), [1u8; 10]).unwrap();
        let inputs = |seq: &Path| {
            let program = std::env::current_exe().unwrap();
            let execution = Execution {
                deterministic: false,
                pace: Pace::Free,
            };
            Fingerprinter::new(&program).inputs(seq, None, "--dop", &Config::default(), execution)
        };
        let mut before = inputs(&dir);
        for (change, named) in [
            (dir.join("calibration.yaml"), "sequence calibration changed"),
            (dir.join("rgb.txt"), "sequence lists changed"),
            (rgb.join("1.png"), "sequence frames changed"),
        ] {
            std::fs::write(&change, [2u8; 11]).unwrap();
            let after = inputs(&dir);
            assert_eq!(differences(&before, &after), [named]);
            before = after;
        }
        // A recording file counts by its size and time.
        let bag = dir.join("a.bag");
        std::fs::write(&bag, [0u8; 10]).unwrap();
        let before = inputs(&bag);
        std::fs::write(&bag, [0u8; 12]).unwrap();
        assert_eq!(
            differences(&before, &inputs(&bag)),
            ["sequence frames changed"]
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
