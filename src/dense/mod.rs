//! The dense pass: fuse only static depth, with the final poses, into a TSDF (meshed
//! by marching cubes) and a point cloud, and write them as PLY and OBJ.
//!
//! It reads a finished run's folder, so `dopslam fuse RUN_DIR` re-fuses without
//! tracking again: `trajectory.txt` (the final poses), `keyframes.txt`, the keyframe
//! detections in `detections/` and the dynamic keypoints per frame in
//! `dynamic_keypoints.json`; the frames come from the sequence. Masks: [`masks`].
//! Outputs: `dense_mesh.ply`, `dense_mesh.obj`, `dense_points.ply`, `dense.json`,
//! and pictures `dense_perspective.png`, `dense_top.png`.
//!
//! [`fuse_run`] reads like the run: [`inputs`] (what the run folder and the sequence
//! hold), [`more_detections`] (the pass's own detections), [`masks`], [`tsdf`] and
//! [`cloud`] (fusion), [`outputs`] (the files), [`truth`] (the count against a
//! synthetic sequence's masks); [`config`] is the `[dense]` section.

pub mod cloud;
pub mod cloud_voxels;
pub mod compare_maps;
pub mod config;
pub mod detection_feed;
pub mod disparity;
mod frame_choice;
mod frame_table;
pub mod free_space;
mod fusion;
pub mod inputs;
pub mod kept;
pub mod keypoint_feed;
pub mod map_figures;
mod maps;
pub mod marching_cubes;
pub mod mask_layers;
pub mod masks;
pub mod merge;
pub mod mesh_file;
pub mod more_detections;
pub mod neighbours;
pub mod outputs;
pub mod render;
pub mod report;
pub mod segments;
pub mod truth;
pub mod tsdf;

use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};

use crate::dop::Mode;
use crate::geometry::se3::Se3;
use crate::io::run_dir::RunDir;
use crate::io::IoError;
use detection_feed::DetectionFeed;
use frame_table::key;
use inputs::RunInputs;
use maps::{allocate_blocks, fuse, fuse_into, new_maps, Fusing};
use masks::{MaskContext, MaskSource};
use outputs::{interrupted, write_maps};

pub use config::{DenseConfig, FrameChoice, Fusion};
pub use inputs::{read_keypoints, DenseInputs};
pub use outputs::save_png;
pub use report::DenseReport;
pub use truth::{FusedTruth, TruthCounter};

/// A progress bar over `len` frames labelled `label` (hidden unless `shown`).
pub fn frames_bar(label: &str, len: usize, shown: bool) -> ProgressBar {
    let bar = if shown {
        ProgressBar::new(len as u64)
    } else {
        ProgressBar::hidden()
    };
    bar.set_style(
        ProgressStyle::with_template(&format!(
            "{label}{{bar:40}} {{pos}}/{{len}} frames ({{per_sec}}, {{eta}} left)"
        ))
        .expect("valid template"),
    );
    bar
}

/// Fuses a finished run (see the module doc): reads the run, chooses the frames, adds
/// the dense pass's own detections, makes the masks, fuses, writes; or takes the
/// state an earlier pass kept in the output folder ([`kept`]) when it would fuse the
/// same, and only writes.
pub fn fuse_run(inputs: &DenseInputs, config: &DenseConfig) -> Result<DenseReport, IoError> {
    config
        .validate()
        .map_err(|m| IoError::invalid(inputs.run_dir, m.to_string()))?;
    let started = Instant::now();
    // What came before the pass is not its own peak, and its freed pages go back.
    crate::memory::release_freed_memory();
    crate::memory::start_sampling();
    crate::memory::part_peak_mib();
    let (run, out) = (RunDir::new(inputs.run_dir), RunDir::new(inputs.out_dir));
    let mut read = inputs::read_run(&run, inputs.sequence, inputs.masking, inputs.out_dir)?;
    if let Some(report) = kept::reuse(inputs, config, &read.cameras, started)? {
        return Ok(report);
    }
    let frames = frame_choice::choose_frames(&read.table, config)?;
    let inputs_s = started.elapsed().as_secs_f64();
    let candidates = frames.candidates(&read.table);
    let extra_detections =
        dense_detections(inputs, config, candidates, &out, &mut read.detections)?;
    let detections_s = started.elapsed().as_secs_f64() - inputs_s;
    let start = Instant::now();
    let mut mask_source = mask_source(inputs, config, &mut read);
    let mut report = DenseReport {
        masking: Some(inputs.masking),
        other_segment_frames: read.table.other_segment_frames,
        extra_detections,
        frames_left_still: frames.candidates - frames.fused,
        frames_fused_still: frames.still,
        disparity_offset_px: inputs.stereo.as_ref().map(|s| s.offset),
        sgbm: inputs.stereo.as_ref().map(|s| s.sgbm),
        ..DenseReport::default()
    };
    report.stages.inputs_s = inputs_s + start.elapsed().as_secs_f64();
    report.stages.detections_s = detections_s;
    let fusing = Fusing {
        frames: &frames,
        mask_source: &mut mask_source,
        table: &read.table,
    };
    let (mut maps, truth) = fuse(inputs, config, fusing, &mut report)?;
    report.truth = truth.map(TruthCounter::finish);
    let (first, last) = frames.span.unwrap_or_default();
    let recording = crate::io::sequence::duration_of(inputs.sequence, first, last);
    if config.outputs.keep_state {
        kept::keep_fused(inputs, config, &mut maps, &mut report, started, recording)?;
    }
    write_maps(
        &out,
        inputs.masking,
        config,
        maps,
        &read.cameras,
        &mut report,
    )?;
    if config.outputs.keep_state {
        kept::trim(&out)?;
    }
    outputs::finish_report(&out, report, started, recording)
}

/// A frame to fuse: its index in the sequence, final `camera_from_world`, and whether
/// it is a keyframe (the cloud takes keyframes only).
pub(super) type Chosen = (usize, Se3, bool);

/// The dense pass's own detections ([`more_detections`]) on the `candidates`, added to
/// `detections`, with the DOP masks and a detector.
fn dense_detections(
    inputs: &DenseInputs,
    config: &DenseConfig,
    candidates: impl Iterator<Item = Result<Chosen, IoError>>,
    out: &RunDir,
    detections: &mut DetectionFeed,
) -> Result<Option<more_detections::ExtraDetections>, IoError> {
    let (Some((detector, describe)), Mode::Dop) = (&inputs.detector, inputs.masking) else {
        return Ok(None);
    };
    let every = config.detections.every;
    if every == 0 {
        return Ok(None);
    }
    // The detector's turn comes every `every` frames: only those candidates are listed.
    let mut turns = Vec::new();
    for candidate in candidates {
        let index = candidate?.0;
        if index.is_multiple_of(every) {
            turns.push(index);
        }
    }
    let mut detector = detector.lock().expect("detector lock poisoned");
    more_detections::add(
        inputs.sequence,
        more_detections::Described {
            detector: detector.as_mut(),
            describe,
        },
        &turns,
        more_detections::Schedule {
            every,
            reuse_keyframes: inputs.keyframe_boxes_alike,
        },
        &out.dense_detections(),
        detections,
        inputs.progress,
    )
    .map(Some)
}

/// The masks' source, built from the run's detections and keypoints (taken out of
/// `read`); fusion places the detected objects as it comes near them.
fn mask_source(inputs: &DenseInputs, config: &DenseConfig, read: &mut RunInputs) -> MaskSource {
    MaskSource::unplaced(
        MaskContext {
            masking: inputs.masking,
            camera: inputs.camera,
            dop: inputs.dop,
            dynamic_classes: inputs.dynamic_classes,
        },
        config.mask_settings(),
        std::mem::take(&mut read.detections),
        std::mem::take(&mut read.keypoints),
    )
}
