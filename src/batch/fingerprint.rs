//! What decides a batch run's result, recorded in its `run.json`, so that a batch
//! never takes a run made with other settings for one of its own: the sequence folder,
//! the frames, the mode, how it ran (deterministic or real time, the pace), the
//! effective config (the `config.toml` the run is given), the content of the ORB-SLAM2
//! settings file it names, the detector's files and the `dopslam` binary. Each is a
//! value or an FNV-1a hash of the content ([`crate::run::content_hash`]), under a name, so that a
//! difference can be said by name ("frames 10 -> 30", "config changed").

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use crate::config::Config;
use crate::pacing::Pace;
use crate::run::content_hash;

/// The named inputs of one run (see the module doc).
pub type RunInputs = BTreeMap<String, String>;

/// The hash of a file's content, `missing` when it cannot be read.
fn file_hash(path: &Path) -> String {
    std::fs::read(path).map_or_else(|_| "missing".into(), |bytes| content_hash(&bytes))
}

/// Makes the inputs of runs, hashing each file it reads once.
pub struct Fingerprinter {
    files: Mutex<HashMap<PathBuf, String>>,
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

    /// The inputs of a run of `sequence_dir` (its first `frames`) in `mode`
    /// (`mode_flag`) with `config`, the config as its `config.toml` holds it.
    pub fn inputs(
        &self,
        (sequence_dir, frames): (&Path, Option<usize>),
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
        Fingerprinter::new(&program).inputs((Path::new("/seq"), frames), "--dop", config, execution)
    }

    #[test]
    fn a_change_of_frames_or_config_is_named() {
        let config = Config::default();
        let before = inputs_of(Some(10), &config);
        assert!(differences(&before, &inputs_of(Some(10), &config)).is_empty());
        assert_eq!(differences(&before, &inputs_of(Some(30), &config)), ["frames 10 -> 30"]);
        let mut other = config.clone();
        other.orb.n_features = 1500;
        assert_eq!(differences(&before, &inputs_of(Some(10), &other)), ["config changed"]);
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
}
