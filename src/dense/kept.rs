//! A dense pass's fused state kept for a later `dopslam fuse` (`[dense] keep_state`,
//! `--keep-state`): the volume's and the cloud's spill files, linked into
//! `dense_state/` once fusion is done, with their tables and `state.json`
//! ([`DenseState`]): which settings and inputs made them, and what fusion reported.
//!
//! A later pass over the same run whose fingerprint is the same (every setting that
//! changes what is fused, the run's files, the sequence's frames) takes the state
//! instead of fusing again: only the mesh, the cloud and the files are made, with its
//! own output settings (`mesh_min_piece_area`, the cloud's outlier and normal
//! neighbours and carving, `obj`, `ply_encoding`, `pictures`). The kept files are read
//! and never written, so a state serves any number of such passes.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::cloud::CloudBuilder;
use super::cloud_voxels::KeptCloud;
use super::inputs::DenseInputs;
use super::outputs::Maps;
use super::tsdf::{KeptVolume, TsdfVolume};
use super::{DenseConfig, DenseReport, Fusion};
use crate::io::atomic::write_atomic;
use crate::io::run_dir::{names, RunDir};
use crate::io::{content_hash, IoError};

/// The layout version of `dense_state/`.
pub const FORMAT: u32 = 1;
/// The state's description inside `dense_state/`.
const STATE: &str = "state.json";

/// What made a fused state: a hash (FNV-1a, 64 bits, hex) of each part. Equal parts,
/// equal volume and cloud.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Fingerprint {
    /// The `[dense]` settings but for the outputs' and the memory budgets', the
    /// masking, the camera, the DOP model, the moving classes, the stereo depth and the
    /// detector.
    pub settings: String,
    /// The run's files the pass reads: the trajectory, keyframes, detections (the
    /// run's and the dense pass's own) and dynamic keypoints.
    pub run: String,
    /// The sequence's frames: their number and timestamps.
    pub sequence: String,
}

impl Fingerprint {
    /// The parts that differ from `other`'s, by name.
    pub fn differences(&self, other: &Fingerprint) -> Vec<&'static str> {
        let mut parts = Vec::new();
        for (name, same) in [
            ("settings", self.settings == other.settings),
            ("run files", self.run == other.run),
            ("sequence frames", self.sequence == other.sequence),
        ] {
            if !same {
                parts.push(name);
            }
        }
        parts
    }
}

/// `dense_state/state.json`: a kept fused state.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct DenseState {
    /// [`FORMAT`].
    pub format: u32,
    /// What made it.
    pub fingerprint: Fingerprint,
    /// The volume's files (none when no TSDF was fused).
    pub volume: Option<KeptVolume>,
    /// The cloud's files (none when no cloud was made).
    pub cloud: Option<KeptCloud>,
    /// What the pass that kept it reported of its fusion (frames, masks, truth, times
    /// and memory up to the end of fusion).
    pub fusion: DenseReport,
}

/// What a later pass finds in its output folder.
pub enum Found {
    /// No kept state.
    Nothing,
    /// A state made otherwise: the parts of the fingerprint that differ, or what is
    /// missing from it.
    Other(String),
    /// A state to reuse: the maps and the fusion's report.
    Same(Box<(Maps, DenseReport)>),
}

/// [`content_hash`] of the byte strings `parts`, each preceded by its length.
fn hash<'a>(parts: impl IntoIterator<Item = &'a [u8]>) -> String {
    let mut bytes = Vec::new();
    for part in parts {
        bytes.extend((part.len() as u64).to_le_bytes());
        bytes.extend_from_slice(part);
    }
    content_hash(&bytes)
}

/// A memory budget of `mb` megabytes in bytes (0: no limit).
pub(super) fn budget_bytes(mb: f64) -> usize {
    if mb > 0.0 {
        (mb * 1e6) as usize
    } else {
        usize::MAX
    }
}

/// The fingerprint of a pass over `inputs` with `config`.
pub fn fingerprint(inputs: &DenseInputs, config: &DenseConfig) -> Result<Fingerprint, IoError> {
    let mut fused = config.clone();
    // What does not change the volume or the cloud's sums.
    let defaults = DenseConfig::default();
    let pictures = fused.outputs.mask_pictures_every;
    fused.enabled = true;
    fused.outputs = defaults.outputs;
    fused.outputs.mask_pictures_every = pictures;
    (fused.tsdf.memory_mb, fused.cloud.memory_mb) = (0.0, 0.0);
    fused.cloud.outlier_neighbours = defaults.cloud.outlier_neighbours;
    fused.cloud.outlier_std = defaults.cloud.outlier_std;
    fused.cloud.normal_neighbours = defaults.cloud.normal_neighbours;
    fused.cloud.free_space = defaults.cloud.free_space;
    let settings = [
        json(&fused),
        json(&inputs.masking),
        json(&inputs.camera),
        json(inputs.dop),
        json(inputs.dynamic_classes),
        format!("{:?}", inputs.stereo),
        format!("{:?}", inputs.detector.as_ref().map(|d| &d.1)),
    ];
    let run = RunDir::new(inputs.run_dir);
    let out = RunDir::new(inputs.out_dir);
    let mut files = vec![run.trajectory(), run.keyframes(), run.dynamic_keypoints()];
    for dir in [run.detections(), out.dense_detections()] {
        files.push(dir.clone());
        files.extend(listed(&dir)?);
    }
    let contents: Vec<Vec<u8>> = files
        .iter()
        .map(|f| read_if_there(f))
        .collect::<Result<_, _>>()?;
    let sequence = inputs.sequence;
    let stamps: Vec<u8> = (0..sequence.len())
        .flat_map(|i| sequence.timestamp(i).to_le_bytes())
        .collect();
    Ok(Fingerprint {
        settings: hash(settings.iter().map(|s| s.as_bytes())),
        // Named within their folders: the same run however its path is spelled.
        run: hash(
            files
                .iter()
                .map(|f| {
                    let within = f
                        .strip_prefix(inputs.run_dir)
                        .or(f.strip_prefix(inputs.out_dir));
                    within.unwrap_or(f).as_os_str().as_encoded_bytes()
                })
                .chain(contents.iter().map(Vec::as_slice)),
        ),
        sequence: hash([stamps.as_slice()]),
    })
}

/// A part of the settings' fingerprint.
fn json<T: Serialize + ?Sized>(value: &T) -> String {
    serde_json::to_string(value).expect("settings serialise")
}

/// The files in `dir`, sorted (none when it does not exist).
fn listed(dir: &Path) -> Result<Vec<PathBuf>, IoError> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Ok(Vec::new());
    };
    let mut files = Vec::new();
    for entry in entries {
        files.push(entry.map_err(|e| IoError::read(dir, e))?.path());
    }
    files.sort();
    Ok(files)
}

/// A file's bytes; none for a file that is not there, or a folder.
fn read_if_there(path: &Path) -> Result<Vec<u8>, IoError> {
    if !path.is_file() {
        return Ok(Vec::new());
    }
    std::fs::read(path).map_err(|e| IoError::read(path, e))
}

/// What a pass keeps: the maps it fused (every voxel and sum spilled), what made them
/// and what fusion reported.
pub struct Keeping<'a> {
    /// The maps.
    pub maps: &'a Maps,
    /// Whether the maps' volume was fused (a mesh was asked for).
    pub volume: bool,
    /// What made them.
    pub fingerprint: &'a Fingerprint,
    /// What fusion reported.
    pub fusion: &'a DenseReport,
}

/// Keeps `keeping` as `out`'s `dense_state/`: written beside it first, then put in
/// place of the state there was (the output folder's own, made by an earlier pass).
pub fn keep(out: &RunDir, keeping: &Keeping) -> Result<(), IoError> {
    let Keeping {
        maps,
        volume,
        fingerprint,
        fusion,
    } = keeping;
    let dir = out.file(names::DENSE_STATE);
    let new = out.file(&format!(
        ".{}-{}.tmp",
        names::DENSE_STATE,
        std::process::id()
    ));
    let made = |source| IoError::Write {
        path: new.clone(),
        source,
    };
    std::fs::create_dir_all(&new).map_err(made)?;
    let state = DenseState {
        format: FORMAT,
        fingerprint: (*fingerprint).clone(),
        volume: volume.then(|| maps.volume.keep(&new)).transpose()?,
        cloud: maps.cloud.as_ref().map(|c| c.keep(&new)).transpose()?,
        fusion: (*fusion).clone(),
    };
    let json = serde_json::to_string_pretty(&state).expect("state serialises");
    write_atomic(&new.join(STATE), json.as_bytes())?;
    if dir.join(STATE).is_file() {
        std::fs::remove_dir_all(&dir).map_err(|source| IoError::Write {
            path: dir.clone(),
            source,
        })?;
    }
    std::fs::rename(&new, &dir).map_err(|source| IoError::Write { path: dir, source })
}

/// Cuts the kept files of `out`'s state back to what their tables refer to: the cloud's
/// spill file, linked when it was kept, grew as the cloud was carved after.
pub fn trim(out: &RunDir) -> Result<(), IoError> {
    let dir = out.file(names::DENSE_STATE);
    let state = read_state(&dir)?;
    let files = [
        (super::tsdf::KEPT_VOXELS, state.volume.map(|v| v.bytes)),
        (super::cloud_voxels::KEPT_SUMS, state.cloud.map(|c| c.bytes)),
    ];
    for (name, bytes) in files {
        let (path, Some(bytes)) = (dir.join(name), bytes) else {
            continue;
        };
        let file = std::fs::OpenOptions::new().write(true).open(&path);
        file.and_then(|f| f.set_len(bytes))
            .map_err(|source| IoError::Write { path, source })?;
    }
    Ok(())
}

fn read_state(dir: &Path) -> Result<DenseState, IoError> {
    let path = dir.join(STATE);
    let text = crate::io::errors::read_text(&path)?;
    let state: DenseState =
        serde_json::from_str(&text).map_err(|e| IoError::invalid(&path, e.to_string()))?;
    if state.format != FORMAT {
        return Err(IoError::invalid(
            &path,
            format!("layout {} where this build reads {FORMAT}", state.format),
        ));
    }
    Ok(state)
}

/// The state kept in `inputs.out_dir` when a pass with `config` would make it (the
/// same [`fingerprint`]) and it holds what `config` makes (the volume for a mesh, the
/// sums for a cloud), opened under `config`'s memory budgets.
pub fn find(inputs: &DenseInputs, config: &DenseConfig) -> Result<Found, IoError> {
    let dir = RunDir::new(inputs.out_dir).file(names::DENSE_STATE);
    if !dir.join(STATE).is_file() {
        return Ok(Found::Nothing);
    }
    let state = read_state(&dir)?;
    let differ = state.fingerprint.differences(&fingerprint(inputs, config)?);
    if !differ.is_empty() {
        return Ok(Found::Other(format!(
            "made with other {}",
            differ.join(", ")
        )));
    }
    let cloud_on = config.outputs.cloud || config.fusion != Fusion::Tsdf;
    let (volume, cloud) = match (config.fuses_tsdf(), state.volume, cloud_on, state.cloud) {
        (true, None, _, _) => return Ok(Found::Other("it has no volume".into())),
        (_, _, true, None) => return Ok(Found::Other("it has no cloud".into())),
        (tsdf, volume, cloud, sums) => (volume.filter(|_| tsdf), sums.filter(|_| cloud)),
    };
    let (settings, camera) = (config.tsdf(), inputs.camera);
    let volume = match volume {
        Some(kept) => {
            let budget = budget_bytes(config.tsdf.memory_mb);
            TsdfVolume::from_kept(settings, camera, &dir, &kept, inputs.out_dir, budget)?
        }
        None => TsdfVolume::new(settings, camera),
    };
    let cloud = match cloud {
        Some(kept) => Some(CloudBuilder::from_kept(
            config.cloud_settings(),
            camera,
            &dir,
            &kept,
            inputs.out_dir,
            budget_bytes(config.cloud.memory_mb),
        )?),
        None => None,
    };
    let maps = Maps { volume, cloud };
    Ok(Found::Same(Box::new((maps, state.fusion))))
}

/// Keeps the fused `maps` ([`keep`]) with the fusion's `report` (its time so
/// far and real-time factor, of the `recording`'s seconds, set first).
pub(super) fn keep_fused(
    inputs: &DenseInputs,
    config: &DenseConfig,
    maps: &mut Maps,
    report: &mut DenseReport,
    started: Instant,
    recording: Option<f64>,
) -> Result<(), IoError> {
    maps.spill_everything()?;
    report.total_s = started.elapsed().as_secs_f64();
    report.real_time_factor = recording.map(|r| report.total_s / r);
    let out = RunDir::new(inputs.out_dir);
    let fingerprint = fingerprint(inputs, config)?;
    let keeping = Keeping {
        maps,
        volume: config.fuses_tsdf(),
        fingerprint: &fingerprint,
        fusion: report,
    };
    keep(&out, &keeping)?;
    report.kept_state = Some(out.file(names::DENSE_STATE));
    Ok(())
}

/// The pass over `inputs` with `config` made from the state kept in its output folder
/// when that is the state it would fuse ([`find`], [`write_reused`]); none otherwise
/// (with a note when a state made otherwise is there).
pub(super) fn reuse(
    inputs: &DenseInputs,
    config: &DenseConfig,
    cameras: &super::outputs::CameraPaths,
    started: Instant,
) -> Result<Option<DenseReport>, IoError> {
    match find(inputs, config)? {
        Found::Same(found) => {
            let (maps, fusion) = *found;
            write_reused(inputs, config, maps, fusion, cameras, started).map(Some)
        }
        Found::Other(why) => {
            let dir = RunDir::new(inputs.out_dir).file(names::DENSE_STATE);
            eprintln!(
                "note: the dense state kept in {} is not this pass's ({why}): fusing again",
                dir.display()
            );
            Ok(None)
        }
        Found::Nothing => Ok(None),
    }
}

/// The pass that takes a kept state: the fusion's report (`fusion`) as it was, the
/// mesh, cloud and files made from `maps` now.
fn write_reused(
    inputs: &DenseInputs,
    config: &DenseConfig,
    maps: Maps,
    fusion: DenseReport,
    cameras: &super::outputs::CameraPaths,
    started: Instant,
) -> Result<DenseReport, IoError> {
    let out = RunDir::new(inputs.out_dir);
    let from = out.file(names::DENSE_STATE);
    if inputs.progress {
        eprintln!(
            "dense state kept in {} reused: the same settings and inputs, not fused again",
            from.display()
        );
    }
    let recording = fusion.real_time_factor.map(|f| fusion.total_s / f);
    let mut report = DenseReport {
        outputs: Vec::new(),
        kept_state: None,
        reused_state: Some(super::report::ReusedState {
            from,
            fusion_s: fusion.total_s,
        }),
        ..fusion
    };
    super::outputs::write_maps(&out, inputs.masking, config, maps, cameras, &mut report)?;
    super::outputs::finish_report(&out, report, started, recording)
}
