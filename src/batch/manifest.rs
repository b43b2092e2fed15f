//! The batch manifest (`dopslam batch MANIFEST.toml`): which sequences, in which modes,
//! how many times, with which overrides, and within which budget. Unknown keys are
//! refused by name; relative paths are taken from the manifest's folder.
//!
//! ```toml
//! [batch]
//! modes = ["dop", "no-dop", "mask-boxes"]
//! repetitions = 3
//!
//! [[sequence]]                      # a synthetic preset, generated once per seed
//! preset = "walking_xyz"            # a shipped preset (configs/synth/) or a path
//! seeds = [1, 2]
//!
//! [[sequence]]                      # recorded folders in the TUM/Bonn or KITTI layout
//! glob = "/data/tum/rgbd_dataset_freiburg3_walking_*"
//! settings = "/data/tum/TUM3.yaml"   # calibration (ORB-SLAM2 settings file)
//! depth_scale = 5000.0
//! ```

use std::path::{Path, PathBuf};

use serde::Deserialize;

use thiserror::Error;

use crate::checks::{self, BadValue};
use crate::config::{Config, ConfigError, ConfigProblem};
use crate::detect::Source;
use crate::dop::Mode;

/// A manifest that cannot be read or planned; the error names the file and the key or
/// `[[sequence]]` entry.
#[derive(Debug, Error)]
pub enum ManifestError {
    #[error("cannot read manifest {}: {source}", path.display())]
    /// The file cannot be read.
    Read {
        /// The manifest.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    #[error("manifest {}: {problem}", path.display())]
    /// The manifest says something the batch cannot do.
    Invalid {
        /// The manifest.
        path: PathBuf,
        /// What.
        problem: Box<ManifestProblem>,
    },
}

/// What is wrong in a manifest.
#[derive(Debug, Error)]
pub enum ManifestProblem {
    /// Not TOML, an unknown key, a value of the wrong type, or a `[batch]` value out
    /// of its range (as a config's).
    #[error(transparent)]
    Text(#[from] ConfigProblem),
    #[error("no [[sequence]] entry")]
    /// The manifest names no sequence.
    NoSequence,
    /// The `[[sequence]]` entry numbered `entry` (from 1).
    #[error("[[sequence]] #{entry}: {problem}")]
    Entry {
        /// The entry's number, from 1.
        entry: usize,
        /// What is wrong in it.
        problem: EntryProblem,
    },
    #[error("two sequences are named {0:?}: give them distinct `name`s")]
    /// Two sequences share a name.
    SameName(String),
    #[error("sequence {sequence}: {problem}")]
    /// A sequence's `map_from` that cannot be followed.
    MapFrom {
        /// The sequence.
        sequence: String,
        /// What is wrong.
        problem: String,
    },
    #[error("sequence name {0:?}: use letters, digits, '-', '_' and '.' only")]
    /// A name unfit for a folder.
    UnsafeName(String),
    /// The batch's config file (`[batch] config`).
    #[error(transparent)]
    Config(#[from] ConfigError),
}

impl From<BadValue> for ManifestProblem {
    fn from(bad: BadValue) -> Self {
        Self::Text(bad.into())
    }
}

/// What is wrong in one `[[sequence]]` entry.
#[derive(Debug, Error)]
pub enum EntryProblem {
    #[error("give exactly one of path, glob or preset")]
    /// None or several of `path`, `glob` and `preset`.
    Source,
    #[error("seeds and synth_frames are for presets")]
    /// `seeds` or `synth_frames` without a preset.
    SeedsWithoutPreset,
    #[error("repetitions and modes must not be empty")]
    /// Empty `repetitions` or `modes`.
    Empty,
    #[error(transparent)]
    /// A value out of its range.
    Value(#[from] BadValue),
    /// Its config file or ORB-SLAM2 settings file.
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error("glob {pattern:?}: {source}")]
    /// The glob pattern is malformed.
    Glob {
        /// The pattern.
        pattern: String,
        /// glob's message.
        source: glob::PatternError,
    },
    #[error("glob {} matches no sequence folder or recording", .0.display())]
    /// The glob matches nothing.
    NoMatch(PathBuf),
    #[error("preset {} does not exist", .0.display())]
    /// The preset's file does not exist.
    NoPresetFile(PathBuf),
    #[error("give one of map and map_from, not both")]
    /// Both `map` and `map_from`.
    TwoMaps,
    #[error("map_frozen needs a map to load: give map or map_from")]
    /// `map_frozen` without a map.
    FrozenWithoutMap,
    #[error("no preset named {name:?} (looked for {file})")]
    /// No preset has the name.
    NoPreset {
        /// The name.
        name: String,
        /// The file looked for.
        file: String,
    },
}

/// The `[batch]` table: what every sequence gets unless it says otherwise.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BatchSettings {
    /// Output folder (the command line's `--out` wins; default `outputs/batch/<manifest name>`).
    pub out: Option<PathBuf>,
    /// The modes every sequence runs in.
    pub modes: Vec<Mode>,
    /// Runs per sequence and mode (real-time runs differ: papers report the median of 5-10).
    pub repetitions: usize,
    /// A `dopslam` config (TOML) for every run; default: the built-in defaults.
    pub config: Option<PathBuf>,
    /// Where keyframe detections come from (`dopslam run --detections`); `no-dop` runs
    /// never use a detector.
    pub detections: Option<Source>,
    /// `dopslam run --deterministic` (local mapping inline: repeatable, slower).
    pub deterministic: bool,
    /// `dopslam run --pace`: real-time runs take frames as fast as tracking goes
    /// (`free`, the default) or at the recording's rate (`recording`, a live run).
    pub pace: crate::pacing::Pace,
    /// Run the dense map (and, on synthetic sequences, compare it with the static scene).
    pub dense: bool,
    /// Run the global pass.
    pub global: bool,
    /// Track only the first N frames of each sequence.
    pub frames: Option<usize>,
    /// Runs at a time; default: as many as the core and memory budgets allow.
    pub jobs: Option<usize>,
    /// Cores one run may use (tracking, local mapping, detection): the core budget is
    /// the machine's cores divided by this.
    pub cores_per_run: usize,
    /// Memory one run is allowed, GiB: the memory budget is the available memory
    /// divided by this.
    pub memory_per_run_gib: f64,
    /// The RPE delta in seconds (reported per second, as TUM's tables give it).
    pub rpe_seconds: f64,
}

impl Default for BatchSettings {
    fn default() -> Self {
        Self {
            out: None,
            modes: Mode::ALL.to_vec(),
            repetitions: 1,
            config: None,
            detections: None,
            deterministic: false,
            pace: crate::pacing::Pace::Free,
            dense: true,
            global: true,
            frames: None,
            jobs: None,
            cores_per_run: 2,
            memory_per_run_gib: 3.0,
            rpe_seconds: 1.0,
        }
    }
}

/// One `[[sequence]]` entry: exactly one of `path`, `glob` or `preset`, and overrides.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SequenceEntry {
    /// The name in tables (default: the folder's or the preset's name, with `-s<seed>`).
    pub name: Option<String>,
    /// A sequence folder (TUM/Bonn RGB-D or KITTI stereo layout) or a recording (ROS 1
    /// `.bag`, ROS 2 bag folder, `.mcap`, `.db3`, `.mkv`).
    pub path: Option<PathBuf>,
    /// A glob of sequence folders or recordings (`*`, `?`, `[...]`; `lab/*.bag`), each
    /// its own sequence.
    pub glob: Option<String>,
    /// A `dopslam synth` preset: a name under `configs/synth/` or a path to a TOML.
    pub preset: Option<String>,
    /// Seeds of the preset, one sequence each (default: the preset's own seed).
    pub seeds: Vec<u64>,
    /// Frames to generate (default: the preset's).
    pub synth_frames: Option<usize>,
    /// Calibration: an ORB-SLAM2 settings file (`dopslam run --settings`).
    pub settings: Option<PathBuf>,
    /// The depth images' scale (TUM: 5000 per metre).
    pub depth_scale: Option<f64>,
    /// A recording's colour, depth, camera-info and ground-truth topics (`[dataset]`'s
    /// keys).
    pub rgb_topic: Option<String>,
    /// The recording's depth topic.
    pub depth_topic: Option<String>,
    /// The recording's camera-info topic.
    pub camera_info_topic: Option<String>,
    /// The recording's ground-truth pose topic.
    pub ground_truth_topic: Option<String>,
    /// A TUM trajectory as the recording's ground truth (relative to the manifest).
    pub ground_truth_file: Option<PathBuf>,
    /// A `dopslam` config for this sequence's runs (instead of `[batch] config`).
    pub config: Option<PathBuf>,
    /// Its modes (else the batch's).
    pub modes: Option<Vec<Mode>>,
    /// Its repetitions (else the batch's).
    pub repetitions: Option<usize>,
    /// Frames per run (else the batch's).
    pub frames: Option<usize>,
    /// The detections' source (else the batch's).
    pub detections: Option<Source>,
    /// The dense map for this sequence's runs (instead of `[batch] dense`).
    pub dense: Option<bool>,
    /// A finished run folder whose map (`slam_map.bin`) this sequence's runs load
    /// (`dopslam run --map`): tracked in its world frame.
    pub map: Option<PathBuf>,
    /// The batch sequence whose runs' maps this sequence's runs load: run `r<k>` in
    /// mode M loads the map of that sequence's run `r<k>` in mode M, once it finished.
    pub map_from: Option<String>,
    /// Localise only in the loaded map (`--map-frozen`).
    pub map_frozen: bool,
}

impl SequenceEntry {
    fn validate(&self) -> Result<(), EntryProblem> {
        let sources = [
            self.path.is_some(),
            self.glob.is_some(),
            self.preset.is_some(),
        ];
        if sources.iter().filter(|&&x| x).count() != 1 {
            return Err(EntryProblem::Source);
        }
        if self.preset.is_none() && (!self.seeds.is_empty() || self.synth_frames.is_some()) {
            return Err(EntryProblem::SeedsWithoutPreset);
        }
        if self.repetitions == Some(0) || self.modes.as_ref().is_some_and(Vec::is_empty) {
            return Err(EntryProblem::Empty);
        }
        if let Some(scale) = self.depth_scale {
            checks::positive("depth_scale", scale)?;
        }
        if self.map.is_some() && self.map_from.is_some() {
            return Err(EntryProblem::TwoMaps);
        }
        if self.map_frozen && self.map.is_none() && self.map_from.is_none() {
            return Err(EntryProblem::FrozenWithoutMap);
        }
        Ok(())
    }
}

/// The whole manifest.
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    #[serde(default)]
    /// `[batch]`.
    pub batch: BatchSettings,
    #[serde(default, rename = "sequence")]
    /// The `[[sequence]]` entries.
    pub sequences: Vec<SequenceEntry>,
    /// The folder relative paths are taken from (the manifest's).
    #[serde(skip)]
    pub base: PathBuf,
}

/// Where a sequence comes from.
#[derive(Debug, Clone, PartialEq)]
pub enum SequenceSource {
    /// A recorded folder or recording.
    Folder(PathBuf),
    /// A preset file and the seed to generate it with.
    Synthetic {
        /// The preset's file.
        preset: PathBuf,
        /// Its seed (else the preset's).
        seed: Option<u64>,
        /// Frames to generate (else the preset's).
        frames: Option<usize>,
    },
}

/// One sequence of the batch with everything its runs need.
#[derive(Debug, Clone)]
pub struct PlannedSequence {
    /// Its unique name.
    pub name: String,
    /// Where its frames come from.
    pub source: SequenceSource,
    /// The config its runs use (overrides applied).
    pub config: Config,
    /// Its modes.
    pub modes: Vec<Mode>,
    /// Its repetitions.
    pub repetitions: usize,
    /// Frames per run (else all).
    pub frames: Option<usize>,
    /// The map its runs load, if any.
    pub map: Option<MapSource>,
}

/// The map a sequence's runs load (`dopslam run --map`).
#[derive(Debug, Clone, PartialEq)]
pub struct MapSource {
    /// A run folder outside the batch, or a sequence of the batch.
    pub from: MapFrom,
    /// `--map-frozen`.
    pub frozen: bool,
}

/// Where a loaded map comes from.
#[derive(Debug, Clone, PartialEq)]
pub enum MapFrom {
    /// A finished run folder (absolute).
    Run(PathBuf),
    /// The batch sequence of this index: each run loads its run of the same mode and
    /// repetition.
    Sequence(usize),
}

impl Manifest {
    /// Reads and checks the manifest at `path`.
    pub fn load(path: &Path) -> Result<Self, ManifestError> {
        let text = std::fs::read_to_string(path).map_err(|source| ManifestError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        let invalid = |problem| ManifestError::Invalid {
            path: path.to_path_buf(),
            problem: Box::new(problem),
        };
        let mut manifest: Manifest =
            toml::from_str(&text).map_err(|e| invalid(ConfigProblem::Syntax(e).into()))?;
        manifest.base = path.parent().map(Path::to_path_buf).unwrap_or_default();
        manifest.validate().map_err(invalid)?;
        Ok(manifest)
    }

    /// A path from the manifest, relative to its folder unless absolute.
    pub fn resolve(&self, path: &Path) -> PathBuf {
        if path.is_absolute() {
            path.to_path_buf()
        } else {
            self.base.join(path)
        }
    }

    fn validate(&self) -> Result<(), ManifestProblem> {
        let b = &self.batch;
        if b.modes.is_empty() {
            return Err(BadValue::new("batch.modes", "is empty").into());
        }
        checks::at_least_one("batch.repetitions", b.repetitions as u64)?;
        checks::at_least_one("batch.cores_per_run", b.cores_per_run as u64)?;
        checks::positive("batch.memory_per_run_gib", b.memory_per_run_gib)?;
        if let Some(jobs) = b.jobs {
            checks::at_least_one("batch.jobs", jobs as u64)?;
        }
        checks::positive("batch.rpe_seconds", b.rpe_seconds)?;
        if self.sequences.is_empty() {
            return Err(ManifestProblem::NoSequence);
        }
        for (i, s) in self.sequences.iter().enumerate() {
            s.validate().map_err(|problem| ManifestProblem::Entry {
                entry: i + 1,
                problem,
            })?;
        }
        Ok(())
    }

    /// The sequences with their configs: globs expanded, presets found, one entry
    /// per seed, names unique. Errors name the entry and what is wrong.
    pub fn plan(&self) -> Result<Vec<PlannedSequence>, ManifestProblem> {
        let base_config = self.load_config(self.batch.config.as_deref())?;
        let mut planned = Vec::new();
        // Each planned sequence's entry, for its map once every name is known.
        let mut entries = Vec::new();
        for (i, entry) in self.sequences.iter().enumerate() {
            let context = |problem| ManifestProblem::Entry {
                entry: i + 1,
                problem,
            };
            let config = self.entry_config(entry, &base_config).map_err(context)?;
            let sources = self.entry_sources(entry).map_err(context)?;
            let several = sources.len() > 1;
            for (k, (default_name, source)) in sources.into_iter().enumerate() {
                let name = match (&entry.name, several) {
                    (Some(n), false) => n.clone(),
                    (Some(n), true) => format!("{n}-{}", k + 1),
                    (None, _) => default_name,
                };
                planned.push(PlannedSequence {
                    name,
                    source,
                    config: config.clone(),
                    modes: entry
                        .modes
                        .clone()
                        .unwrap_or_else(|| self.batch.modes.clone()),
                    repetitions: entry.repetitions.unwrap_or(self.batch.repetitions),
                    frames: entry.frames.or(self.batch.frames),
                    map: None,
                });
                entries.push(entry);
            }
        }
        let mut names: Vec<&str> = planned.iter().map(|p| p.name.as_str()).collect();
        names.sort_unstable();
        if let Some(w) = names.windows(2).find(|w| w[0] == w[1]) {
            return Err(ManifestProblem::SameName(w[0].to_string()));
        }
        if let Some(bad) = planned.iter().find(|p| !safe_name(&p.name)) {
            return Err(ManifestProblem::UnsafeName(bad.name.clone()));
        }
        self.plan_maps(&mut planned, &entries)?;
        Ok(planned)
    }

    /// Each sequence's map: a run folder, or a sequence of the batch that runs every
    /// mode and repetition it does, with no circle of sequences loading each other's.
    fn plan_maps(
        &self,
        planned: &mut [PlannedSequence],
        entries: &[&SequenceEntry],
    ) -> Result<(), ManifestProblem> {
        for k in 0..planned.len() {
            let entry = entries[k];
            let from = match (&entry.map, &entry.map_from) {
                (Some(run), _) => MapFrom::Run(absolute(&self.resolve(run))),
                (None, Some(name)) => {
                    let missing = || ManifestProblem::MapFrom {
                        sequence: planned[k].name.clone(),
                        problem: format!("map_from {name:?} names no other sequence of the batch"),
                    };
                    let reference = planned.iter().position(|p| &p.name == name);
                    let reference = reference.filter(|&r| r != k).ok_or_else(missing)?;
                    check_reference(&planned[k], &planned[reference])?;
                    MapFrom::Sequence(reference)
                }
                (None, None) => continue,
            };
            planned[k].map = Some(MapSource {
                from,
                frozen: entry.map_frozen,
            });
        }
        for k in 0..planned.len() {
            if let Some(MapFrom::Sequence(r)) = planned[k].map.as_ref().map(|m| &m.from) {
                if planned[*r].map.as_ref().is_some_and(|m| m.frozen) {
                    return Err(ManifestProblem::MapFrom {
                        sequence: planned[k].name.clone(),
                        problem: format!(
                            "map_from {:?}, whose runs are frozen (map_frozen: localisation only) and save no map",
                            planned[*r].name
                        ),
                    });
                }
            }
            if root_sequence(planned, k).is_none() {
                return Err(ManifestProblem::MapFrom {
                    sequence: planned[k].name.clone(),
                    problem: "its map_from leads back to itself: one sequence of a group must load no batch sequence's map".into(),
                });
            }
        }
        Ok(())
    }

    /// The config of one `[[sequence]]` entry: its own file or the batch's, then its
    /// ORB-SLAM2 settings and options.
    fn entry_config(
        &self,
        entry: &SequenceEntry,
        base_config: &Config,
    ) -> Result<Config, EntryProblem> {
        let mut config = match &entry.config {
            Some(path) => self.load_config(Some(path))?,
            None => base_config.clone(),
        };
        if let Some(settings) = &entry.settings {
            let path = absolute(&self.resolve(settings));
            config.apply_orbslam_settings(&path)?;
        }
        if entry.depth_scale.is_some() {
            config.dataset.depth_scale = entry.depth_scale;
        }
        config
            .dataset
            .override_topics(&crate::io::recording::TopicChoice {
                rgb: entry.rgb_topic.clone(),
                depth: entry.depth_topic.clone(),
                camera_info: entry.camera_info_topic.clone(),
                ground_truth: entry.ground_truth_topic.clone(),
            });
        if let Some(file) = &entry.ground_truth_file {
            config.dataset.ground_truth_file = Some(absolute(&self.resolve(file)));
        }
        if let Some(source) = entry.detections.or(self.batch.detections) {
            config.detector.source = source;
        }
        config.dense.enabled = entry.dense.unwrap_or(self.batch.dense);
        config.global.enabled = self.batch.global;
        Ok(config)
    }

    /// The sequences of one `[[sequence]]` entry with their default names: its folder
    /// or recording, the matches of its glob, or its preset once per seed.
    fn entry_sources(
        &self,
        entry: &SequenceEntry,
    ) -> Result<Vec<(String, SequenceSource)>, EntryProblem> {
        let sources = if let Some(path) = &entry.path {
            let path = absolute(&self.resolve(path));
            vec![(folder_name(&path), SequenceSource::Folder(path))]
        } else if let Some(pattern) = &entry.glob {
            let pattern = self.resolve(Path::new(pattern));
            let folders = glob_sequences(&pattern)?;
            if folders.is_empty() {
                return Err(EntryProblem::NoMatch(pattern));
            }
            folders
                .into_iter()
                .map(|p| (folder_name(&p), SequenceSource::Folder(p)))
                .collect()
        } else {
            let preset = self.find_preset(entry.preset.as_deref().unwrap_or_default());
            let preset = preset?;
            let stem = folder_name(&preset);
            let seeds: Vec<Option<u64>> = if entry.seeds.is_empty() {
                vec![None]
            } else {
                entry.seeds.iter().map(|&s| Some(s)).collect()
            };
            seeds
                .into_iter()
                .map(|seed| {
                    let name = match seed {
                        Some(s) => format!("{stem}-s{s}"),
                        None => stem.clone(),
                    };
                    let source = SequenceSource::Synthetic {
                        preset: preset.clone(),
                        seed,
                        frames: entry.synth_frames,
                    };
                    (name, source)
                })
                .collect()
        };
        Ok(sources)
    }

    fn load_config(&self, path: Option<&Path>) -> Result<Config, ConfigError> {
        match path {
            Some(path) => {
                let mut config = Config::load(&self.resolve(path))?;
                // The runs read it from their own folders: keep its paths reachable.
                if let Some(settings) = &config.dataset.settings {
                    config.dataset.settings = Some(absolute(settings));
                }
                Ok(config)
            }
            None => Ok(Config::default()),
        }
    }

    /// A preset by path (relative to the manifest) or by name (`configs/synth/NAME.toml`
    /// under the current folder, else under the source tree dopslam was built from).
    fn find_preset(&self, preset: &str) -> Result<PathBuf, EntryProblem> {
        let as_path = self.resolve(Path::new(preset));
        if preset.ends_with(".toml") || preset.contains('/') {
            return if as_path.is_file() {
                Ok(absolute(&as_path))
            } else {
                Err(EntryProblem::NoPresetFile(as_path))
            };
        }
        let file = format!("configs/synth/{preset}.toml");
        [
            PathBuf::from(&file),
            Path::new(env!("CARGO_MANIFEST_DIR")).join(&file),
        ]
        .into_iter()
        .find(|p| p.is_file())
        .map(|p| absolute(&p))
        .ok_or_else(|| EntryProblem::NoPreset {
            name: preset.to_string(),
            file,
        })
    }
}

/// `sequence`'s runs can load `reference`'s maps: every mode and repetition they run,
/// it runs.
fn check_reference(
    sequence: &PlannedSequence,
    reference: &PlannedSequence,
) -> Result<(), ManifestProblem> {
    let problem = |what: String| ManifestProblem::MapFrom {
        sequence: sequence.name.clone(),
        problem: format!("map_from {:?} {what}", reference.name),
    };
    if let Some(mode) = sequence.modes.iter().find(|m| !reference.modes.contains(m)) {
        return Err(problem(format!(
            "has no {} runs, whose maps this sequence's {0} runs would load",
            mode.name()
        )));
    }
    if sequence.repetitions > reference.repetitions {
        return Err(problem(format!(
            "runs {} repetitions, this sequence {}: each run loads the map of the run of its own repetition",
            reference.repetitions, sequence.repetitions
        )));
    }
    Ok(())
}

/// The sequence at the head of `k`'s `map_from` chain (`k` itself when it loads no
/// batch sequence's map); `None` on a circle.
pub fn root_sequence(planned: &[PlannedSequence], k: usize) -> Option<usize> {
    let mut at = k;
    for _ in 0..=planned.len() {
        match planned[at].map.as_ref().map(|m| &m.from) {
            Some(MapFrom::Sequence(next)) => at = *next,
            _ => return Some(at),
        }
    }
    None
}

/// A path made absolute against the current folder (runs happen in other folders).
pub fn absolute(path: &Path) -> PathBuf {
    std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf())
}

fn folder_name(path: &Path) -> String {
    path.file_stem()
        .map_or_else(|| "sequence".into(), |s| s.to_string_lossy().into_owned())
}

fn safe_name(name: &str) -> bool {
    !name.is_empty()
        && !name.starts_with('.')
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
}

/// The folders and recordings a glob pattern matches, sorted.
fn glob_sequences(pattern: &Path) -> Result<Vec<PathBuf>, EntryProblem> {
    let text = pattern.to_string_lossy();
    let paths = glob::glob(&text).map_err(|source| EntryProblem::Glob {
        pattern: text.to_string(),
        source,
    })?;
    let mut folders: Vec<PathBuf> = paths
        .filter_map(Result::ok)
        .filter(|p| p.is_dir() || crate::io::recording::is_recording(p))
        .map(|p| absolute(&p))
        .collect();
    folders.sort();
    Ok(folders)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<Manifest, String> {
        let manifest: Manifest = toml::from_str(text).map_err(|e| e.to_string())?;
        manifest.validate().map_err(|e| e.to_string())?;
        Ok(manifest)
    }

    #[test]
    fn defaults_and_overrides() {
        let m = parse(
            "[batch]\nrepetitions = 3\n[[sequence]]\npreset = \"static_room\"\nseeds = [1, 2]\n\
             [[sequence]]\npath = \"/tmp\"\nmodes = [\"no-dop\"]\ndepth_scale = 1000.0\n",
        )
        .unwrap();
        assert_eq!(m.batch.modes, Mode::ALL.to_vec());
        let plan = m.plan().unwrap();
        let names: Vec<&str> = plan.iter().map(|p| p.name.as_str()).collect();
        assert_eq!(names, ["static_room-s1", "static_room-s2", "tmp"]);
        assert_eq!(plan[0].repetitions, 3);
        assert_eq!(plan[2].modes, [Mode::Off]);
        assert_eq!(plan[2].config.dataset.depth_scale, Some(1000.0));
    }

    #[test]
    fn refuses_what_is_wrong_by_name() {
        let unknown = parse("[batch]\nrepetition = 3\n").unwrap_err();
        assert!(unknown.contains("repetition"), "{unknown}");
        let two = parse("[[sequence]]\npath = \"a\"\npreset = \"b\"\n").unwrap_err();
        assert!(two.contains("exactly one"), "{two}");
        let none = parse("[batch]\nrepetitions = 2\n").unwrap_err();
        assert!(none.contains("no [[sequence]]"), "{none}");
        let mode = parse("[batch]\nmodes = [\"dynaslam\"]\n").unwrap_err();
        assert!(mode.contains("dynaslam"), "{mode}");
        let missing = parse("[[sequence]]\npreset = \"no_such_preset\"\n")
            .unwrap()
            .plan()
            .unwrap_err()
            .to_string();
        assert!(missing.contains("no_such_preset"), "{missing}");
        let twice = parse("[[sequence]]\npath = \"/tmp\"\n[[sequence]]\npath = \"/tmp\"\n")
            .unwrap()
            .plan()
            .unwrap_err();
        assert!(
            matches!(&twice, ManifestProblem::SameName(name) if name == "tmp"),
            "{twice}"
        );
    }

    /// `map_from` chains are followed to their head; what cannot be followed is
    /// refused by sequence and by what is wrong.
    #[test]
    fn map_from_chains_and_what_they_refuse() {
        let room = "preset = \"static_room\"\n";
        let entries = |extra: [&str; 3]| {
            format!(
                "[batch]\nmodes = [\"dop\"]\n[[sequence]]\n{room}name = \"a\"\n{}\n\
                 [[sequence]]\n{room}name = \"b\"\n{}\n[[sequence]]\n{room}name = \"c\"\n{}\n",
                extra[0], extra[1], extra[2]
            )
        };
        let plan = |extra| parse(&entries(extra)).and_then(|m| m.plan().map_err(|e| e.to_string()));
        let planned = plan([
            "",
            "map_from = \"a\"",
            "map_from = \"b\"\nmap_frozen = true",
        ])
        .unwrap();
        assert_eq!(planned[1].map.as_ref().unwrap().from, MapFrom::Sequence(0));
        assert!(planned[2].map.as_ref().unwrap().frozen);
        assert_eq!(root_sequence(&planned, 2), Some(0));
        assert_eq!(root_sequence(&planned, 0), Some(0));
        let refused = [
            (["", "map_from = \"x\"", ""], "names no other sequence"),
            (["", "map_from = \"b\"", ""], "names no other sequence"),
            (
                ["map_from = \"c\"", "map_from = \"a\"", "map_from = \"b\""],
                "leads back",
            ),
            (
                [
                    "",
                    "map_from = \"a\"\nmap_frozen = true",
                    "map_from = \"b\"",
                ],
                "save no map",
            ),
            (
                ["", "map_from = \"a\"\nmodes = [\"no-dop\"]", ""],
                "has no no-dop runs",
            ),
            (
                ["", "map_from = \"a\"\nrepetitions = 2", ""],
                "runs 1 repetitions",
            ),
            (["", "map_from = \"a\"\nmap = \"/tmp\"", ""], "not both"),
            (["map_frozen = true", "", ""], "needs a map"),
        ];
        for (extra, said) in refused {
            let error = plan(extra).unwrap_err();
            assert!(error.contains(said), "{extra:?}: {error}");
        }
    }

    /// The shipped manifests (`configs/batch/`) load and plan: their presets exist, and
    /// their `map_from` chains can be followed.
    #[test]
    fn the_shipped_manifests_plan() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/batch");
        let mut planned = 0;
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            let manifest = Manifest::load(&path).unwrap_or_else(|e| panic!("{e}"));
            let plan = manifest.plan();
            let plan = plan.unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            planned += plan.len();
            if path.ends_with("sessions.toml") {
                let maps = plan.iter().filter(|p| p.map.is_some()).count();
                assert_eq!(maps, 3, "{}", path.display());
            }
        }
        assert!(planned > 0);
    }

    #[test]
    fn a_planned_config_survives_the_file_the_runs_read() {
        let m =
            parse("[[sequence]]\npath = \"/tmp\"\ndepth_scale = 1000.0\ndetections = \"oracle\"\n")
                .unwrap();
        let config = m.plan().unwrap().remove(0).config;
        let text = toml::to_string(&config).unwrap();
        assert_eq!(Config::from_toml(&text).unwrap(), config);
    }

    #[test]
    fn a_glob_takes_recordings_and_their_topics() {
        let dir = std::env::temp_dir().join(format!("dopslam-glob-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("folder")).unwrap();
        for file in ["a.bag", "b.mcap", "c.mkv", "notes.txt"] {
            std::fs::write(dir.join(file), "x").unwrap();
        }
        let pattern = dir.join("*").to_string_lossy().into_owned();
        let m = parse(&format!(
            "[[sequence]]\nglob = {pattern:?}\nrgb_topic = \"/cam/rgb\"\nground_truth_topic = \"/mocap\"\nground_truth_file = \"gt.txt\"\n"
        ))
        .unwrap();
        let planned = m.plan().unwrap();
        let names: Vec<&str> = planned.iter().map(|p| p.name.as_str()).collect();
        assert_eq!(
            names,
            ["a", "b", "c", "folder"],
            "the text file is no sequence"
        );
        let dataset = &planned[0].config.dataset;
        assert_eq!(dataset.rgb_topic.as_deref(), Some("/cam/rgb"));
        assert_eq!(dataset.ground_truth_topic.as_deref(), Some("/mocap"));
        let file = dataset.ground_truth_file.as_ref().unwrap();
        assert!(file.is_absolute() && file.ends_with("gt.txt"), "{file:?}");
        std::fs::remove_dir_all(dir).unwrap();
    }
}
