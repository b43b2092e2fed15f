//! One dense static map of several recordings of one place (`dopslam merge`): runs
//! tracked in one map's world frame (`dopslam run --map`) fused into one volume and
//! one cloud, each recording with its own masks; then every recording's frames once
//! more as free space only (every pixel masked: the volume carves in front of it and
//! fuses nothing, [`super::tsdf`]). What any recording saw through is carved,
//! whichever recording fused a surface there: a person who sat through the whole of
//! one recording and was gone in another, a bag put down in one.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::inputs::{for_each_group, load_group, read_run, sequence_frame, DenseInputs};
use super::outputs::{finish_report, write_maps, CameraPaths};
use super::tsdf::{FrameInput, TsdfVolume};
use super::{
    allocate_blocks, dense_detections, frame_choice, fuse_into, mask_source, new_maps, DenseConfig,
    DenseReport, FusedTruth, Fusing, TruthCounter,
};
use crate::io::run_dir::RunDir;
use crate::io::IoError;

/// `merge.json`: what each recording gave and what the merge did.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MergeReport {
    /// The layout version.
    pub schema: u32,
    /// Each recording, in the order fused.
    pub recordings: Vec<MergedRecording>,
    /// The free-space pass over every recording, seconds.
    pub carve_s: f64,
    /// The merged maps' figures (also in `dense.json`).
    pub dense: DenseReport,
}

/// What one recording gave to a merged map.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MergedRecording {
    /// Its run folder (absolute).
    pub run: PathBuf,
    /// Frames fused with its own masks.
    pub frames_fused: usize,
    /// Pixels its masks kept out.
    pub masked_percent: f64,
    /// Its keyframes in the cloud.
    pub keyframes_in_cloud: usize,
    /// Frames that carved the merged volume as free space.
    pub carving_frames: usize,
    /// On a synthetic sequence: its movers kept out and static pixels fused.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub truth: Option<FusedTruth>,
    /// Fusing it, seconds.
    pub fuse_s: f64,
}

/// Merges `recordings` (each a finished run with its sequence; their trajectories in
/// one frame) into the dense map written to `out_dir` with `dense.json` and
/// `merge.json`. Each recording's own side files (its dense pass's detections) go to
/// its `out_dir`.
pub fn merge(
    recordings: &[DenseInputs],
    out_dir: &Path,
    config: &DenseConfig,
) -> Result<MergeReport, IoError> {
    config
        .validate()
        .map_err(|m| IoError::invalid(out_dir, m.to_string()))?;
    let Some(first) = recordings.first() else {
        return Err(IoError::invalid(out_dir, "no recording to merge"));
    };
    let started = Instant::now();
    crate::memory::start_sampling();
    let mut maps = new_maps(first.camera, out_dir, config)?;
    let mut read = Vec::with_capacity(recordings.len());
    for inputs in recordings {
        let run_dir = RunDir::new(inputs.run_dir);
        let run = read_run(&run_dir, inputs.sequence, inputs.masking, out_dir)?;
        let frames = frame_choice::choose_frames(&run.table, config)?;
        if config.fuses_tsdf() && config.tsdf.carve && config.tsdf.allocate_first {
            let chosen = frames.fused(&run.table).map(|c| c.map(|c| c.0));
            allocate_blocks(&mut maps.volume, inputs, frames.fused, chosen)?;
        }
        read.push((run, frames));
    }
    let (parts, cameras) = fuse_each(recordings, &mut read, config, &mut maps)?;
    let start = Instant::now();
    if config.fuses_tsdf() && config.tsdf.carve {
        for (inputs, (run, frames)) in recordings.iter().zip(&read) {
            let chosen = frames.fused(&run.table).map(|c| c.map(|c| c.0));
            carve(&mut maps.volume, inputs, frames.fused, chosen)?;
        }
    }
    let carve_s = start.elapsed().as_secs_f64();
    let out = RunDir::new(out_dir);
    let mut dense = DenseReport {
        masking: Some(first.masking),
        frames_fused: parts.iter().map(|p| p.frames_fused).sum(),
        keyframes_in_cloud: parts.iter().map(|p| p.keyframes_in_cloud).sum(),
        masked_percent: parts
            .iter()
            .map(|p| p.masked_percent * p.frames_fused as f64)
            .sum::<f64>()
            / parts.iter().map(|p| p.frames_fused).sum::<usize>().max(1) as f64,
        tsdf_blocks: maps.volume.blocks.len(),
        tsdf_memory_mb: maps.volume.memory_bytes() as f64 / 1e6,
        ..DenseReport::default()
    };
    write_maps(&out, first.masking, config, maps, &cameras, &mut dense)?;
    let dense = finish_report(&out, dense, started, None)?;
    let report = MergeReport {
        schema: crate::io::run_dir::SCHEMA,
        recordings: parts,
        carve_s,
        dense,
    };
    let json = serde_json::to_string_pretty(&report).expect("the report serialises");
    let path = out.file(crate::io::run_dir::names::MERGE_REPORT);
    crate::io::atomic::write_atomic(&path, json.as_bytes())?;
    Ok(report)
}

/// Each recording fused into `maps` with its own masks (`read`: its run and chosen
/// frames): what each gave, and their trajectories one after the other.
fn fuse_each(
    recordings: &[DenseInputs],
    read: &mut [(super::inputs::RunInputs, frame_choice::ChosenFrames)],
    config: &DenseConfig,
    maps: &mut super::outputs::Maps,
) -> Result<(Vec<MergedRecording>, CameraPaths), IoError> {
    let carves = config.fuses_tsdf() && config.tsdf.carve;
    let mut parts = Vec::with_capacity(recordings.len());
    let mut cameras = CameraPaths::default();
    for (inputs, (run, frames)) in recordings.iter().zip(read) {
        let start = Instant::now();
        let out = RunDir::new(inputs.out_dir);
        dense_detections(
            inputs,
            config,
            frames.candidates(&run.table),
            &out,
            &mut run.detections,
        )?;
        let mut masks = mask_source(inputs, config, run);
        let mut report = DenseReport::default();
        let fusing = Fusing {
            frames,
            mask_source: &mut masks,
            table: &run.table,
        };
        let truth = fuse_into(inputs, config, fusing, &mut report, maps)?;
        parts.push(MergedRecording {
            run: crate::io::output::resolved(inputs.run_dir),
            frames_fused: report.frames_fused,
            masked_percent: report.masked_percent,
            keyframes_in_cloud: report.keyframes_in_cloud,
            carving_frames: if carves { frames.fused } else { 0 },
            truth: truth.map(TruthCounter::finish),
            fuse_s: start.elapsed().as_secs_f64(),
        });
        cameras.0.append(&mut run.cameras.0);
    }
    Ok((parts, cameras))
}

/// The `count` `chosen` frames of a recording integrated as free space only: every
/// pixel masked, so each carves the volume in front of its depth and fuses nothing.
fn carve(
    volume: &mut TsdfVolume,
    inputs: &DenseInputs,
    count: usize,
    chosen: impl Iterator<Item = Result<super::Chosen, IoError>>,
) -> Result<(), IoError> {
    let progress = super::frames_bar("carve ", count, inputs.progress);
    for_each_group(chosen, |group| {
        let frames = load_group(inputs, group, |inputs, i| sequence_frame(inputs, i, None))?;
        for (&(_, pose, _), frame) in group.iter().zip(frames) {
            let (_, depth, colour) = frame?;
            let masked = vec![true; depth.metres.len()];
            volume.integrate(&FrameInput {
                depth: &depth,
                colour: &colour,
                dynamic: Some(&masked),
                camera_from_world: &pose,
                weight: 1.0,
            })?;
            progress.inc(1);
        }
        Ok(())
    })?;
    progress.finish_and_clear();
    Ok(())
}
