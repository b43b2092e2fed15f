//! The maps a dense pass fuses into: made empty ([`new_maps`]), their blocks
//! allocated from every chosen frame first ([`allocate_blocks`]), then the frames
//! fused with their masks ([`fuse_into`]); [`fuse`] does the three for one run, and
//! [`super::merge`] runs them over several recordings into one map.

use std::time::Instant;

use super::cloud::CloudBuilder;
use super::frame_table::FrameTable;
use super::free_space::NeighbourWindow;
use super::fusion::{fuse_frames, FrameSinks, FrameSources, FusedFrames};
use super::inputs::{for_each_group, frame_depth, load_group, FrameLookup};
use super::masks::MaskSource;
use super::outputs::Maps;
use super::tsdf::TsdfVolume;
use super::{
    frame_choice, frames_bar, kept, Chosen, DenseConfig, DenseInputs, DenseReport, Fusion,
    TruthCounter,
};
use crate::dop::Mode;
use crate::io::IoError;

/// What a recording's frames are fused with: the chosen frames (each weighted by the
/// frames it stands for), their masks' source, and the frames' final poses (the
/// free-space evidence of the frames around, too).
pub(super) struct Fusing<'a> {
    pub frames: &'a frame_choice::ChosenFrames,
    pub mask_source: &'a mut MaskSource,
    pub table: &'a FrameTable<'a>,
}

/// Fuses a run's frames (`fusing`): the TSDF volume and the keyframe cloud as
/// `config` asks, the fused pixels counted against the truth masks; the per-frame
/// figures go into `report`.
pub(super) fn fuse(
    inputs: &DenseInputs,
    config: &DenseConfig,
    fusing: Fusing,
    report: &mut DenseReport,
) -> Result<(Maps, Option<TruthCounter>), IoError> {
    let mut maps = new_maps(inputs.camera, inputs.out_dir, config)?;
    if config.fuses_tsdf() && config.tsdf.carve && config.tsdf.allocate_first {
        let start = Instant::now();
        let chosen = fusing.frames.fused(fusing.table).map(|c| c.map(|c| c.0));
        allocate_blocks(&mut maps.volume, inputs, fusing.frames.fused, chosen)?;
        report.stages.allocation_s = start.elapsed().as_secs_f64();
    }
    let truth = fuse_into(inputs, config, fusing, report, &mut maps)?;
    report.tsdf_blocks = maps.volume.blocks.len();
    report.tsdf_memory_mb = maps.volume.memory_bytes() as f64 / 1e6;
    Ok((maps, truth))
}

/// An empty volume and cloud for `camera` as `config` asks, with their budgets' spill
/// files in `out_dir` (a pass that keeps its state spills without a budget too).
pub(super) fn new_maps(
    camera: crate::geometry::camera::PinholeCamera,
    out_dir: &std::path::Path,
    config: &DenseConfig,
) -> Result<Maps, IoError> {
    let cloud_on = config.outputs.cloud || config.fusion != Fusion::Tsdf;
    let mut volume = TsdfVolume::new(config.tsdf(), camera);
    let keep = config.outputs.keep_state;
    if config.fuses_tsdf() && (config.tsdf.memory_mb > 0.0 || keep) {
        volume.spill_to(out_dir, kept::budget_bytes(config.tsdf.memory_mb))?;
    }
    let mut cloud = CloudBuilder::new(config.cloud_settings(), camera);
    if cloud_on && (config.cloud.memory_mb > 0.0 || keep) {
        cloud.spill_to(out_dir, kept::budget_bytes(config.cloud.memory_mb))?;
    }
    Ok(Maps {
        volume,
        cloud: cloud_on.then_some(cloud),
    })
}

/// [`fuse`] into `maps` (empty, or holding other recordings of the place:
/// [`super::merge`]).
pub(super) fn fuse_into(
    inputs: &DenseInputs,
    config: &DenseConfig,
    fusing: Fusing,
    report: &mut DenseReport,
    maps: &mut Maps,
) -> Result<Option<TruthCounter>, IoError> {
    let Fusing {
        frames,
        mask_source,
        table,
    } = fusing;
    let mut truth = inputs.truth_masks.as_ref().map(|_| TruthCounter::default());
    let free_space = inputs.masking == Mode::Dop && config.masks.free_space_seconds > 0.0;
    let mut window = free_space.then(|| NeighbourWindow::new(config.free_space_settings(), table));
    let lookup = FrameLookup::new(inputs, table);
    let sources = FrameSources {
        lookup: &lookup,
        window: window.as_mut(),
    };
    let sinks = FrameSinks {
        mask_source,
        volume: config.fuses_tsdf().then_some(&mut maps.volume),
        cloud: maps.cloud.as_mut(),
        truth: &mut truth,
    };
    let chosen = FusedFrames {
        count: frames.fused,
        frames: frames.fused(table),
    };
    let fused = fuse_frames(inputs, config, chosen, sources, sinks)?;
    report.memory.fusion_mib = crate::memory::part_peak_mib();
    (report.frames_fused, report.keyframes_in_cloud) = (fused.frames, fused.keyframes_in_cloud);
    report.released_on_map = fused.released;
    report.stages.frames_from(&fused.stages);
    report.masked_percent = 100.0 * fused.masked as f64 / fused.pixels.max(1) as f64;
    report.masked_fusable_percent =
        100.0 * fused.fusable_masked as f64 / fused.fusable.max(1) as f64;
    report.median_integration_ms = fused.integration_ms.median();
    Ok(truth)
}

/// The first pass of `allocate_first`: the `count` `chosen` frames' blocks, without
/// masks (blocks where masked movers stood only take free-space observations).
pub(super) fn allocate_blocks(
    volume: &mut TsdfVolume,
    inputs: &DenseInputs,
    count: usize,
    chosen: impl Iterator<Item = Result<Chosen, IoError>>,
) -> Result<(), IoError> {
    let progress = frames_bar("blocks ", count, inputs.progress);
    for_each_group(chosen, |group| {
        let depths = load_group(inputs, group, frame_depth)?;
        for (&(_, pose, _), depth) in group.iter().zip(depths) {
            volume.allocate(&depth?, &pose);
            progress.inc(1);
        }
        Ok(())
    })?;
    progress.finish_and_clear();
    Ok(())
}
