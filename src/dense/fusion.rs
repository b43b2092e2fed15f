//! The dense pass's fusion loop: each chosen frame loaded, masked, counted against the
//! truth masks, pictured, and fused into the volume and the keyframe cloud.

use std::path::PathBuf;
use std::time::Instant;

use super::cloud::CloudBuilder;
use super::free_space::{Evidence, NeighbourWindow, PosedDepth};
use super::inputs::{check_interrupt, frame_depth, sequence_frame, FrameLookup};
use super::mask_layers::{MapRelease, MaskLayers};
use super::masks::MaskSource;
use super::outputs::save_png;
use super::report::DenseStages;
use super::truth::{count_truth, unknown_instances, TruthCounter, TruthFrame};
use super::tsdf::{FrameInput, TsdfVolume};
use super::{frames_bar, render, Chosen, DenseConfig, DenseInputs};
use crate::eval::stats::MedianSample;
use crate::geometry::se3::Se3;
use crate::io::image_files::DepthImage;
use crate::io::run_dir::{names, RunDir};
use crate::io::IoError;

/// What [`fuse_frames`] did.
pub(super) struct Fused {
    pub frames: usize,
    pub keyframes_in_cloud: usize,
    pub masked: u64,
    pub pixels: u64,
    /// Pixels with depth within `max_depth`, and those masked.
    pub fusable: u64,
    pub fusable_masked: u64,
    pub integration_ms: MedianSample,
    /// Masked pixels the static map explained, fused after all.
    pub released: u64,
    /// The per-frame stages' times (loading to cloud frames).
    pub stages: DenseStages,
}

/// Seconds since `start`, added to `total`.
fn add_since(total: &mut f64, start: Instant) {
    *total += start.elapsed().as_secs_f64();
}

/// What [`fuse_frames`] reads beside the fusion of the frame before: the frames'
/// poses and depth (for placing the detected objects, too) and the free-space window.
pub(super) struct FrameSources<'a> {
    pub lookup: &'a FrameLookup<'a>,
    pub window: Option<&'a mut NeighbourWindow<'a>>,
}

/// The frames [`fuse_frames`] fuses, in order, each with the frames it stands for
/// ([`super::tsdf::FrameInput::weight`]); `count` of them (for the progress bar).
pub(super) struct FusedFrames<I> {
    pub count: usize,
    pub frames: I,
}

/// Where [`fuse_frames`] takes masks from and puts the frames.
pub(super) struct FrameSinks<'a> {
    pub mask_source: &'a mut MaskSource,
    pub volume: Option<&'a mut TsdfVolume>,
    pub cloud: Option<&'a mut CloudBuilder>,
    pub truth: &'a mut Option<TruthCounter>,
}

/// What each frame's side outputs need: the mask pictures' folder (when asked for)
/// and the truth masks' instances of unknown class.
struct Extras {
    pictures: Option<PathBuf>,
    unknown: Vec<bool>,
}

/// One loaded frame to fuse: its time, pose, whether it is a keyframe, the frames it
/// stands for, depth and colour.
struct Loaded {
    timestamp: f64,
    pose: Se3,
    is_keyframe: bool,
    weight: f32,
    depth: DepthImage,
    rgb: image::RgbImage,
}

/// Fuses the `chosen` frames in order, masked: into the volume (when given) and, the
/// keyframes, into the cloud (when given); counts the fused pixels against the truth
/// masks. Each frame is loaded and its free-space evidence gathered beside the
/// masking and fusion of the frame before it (`rayon::join`): the evidence reads the
/// frames around, never the volume, and what follows it reads the volume as the
/// frames before left it, as in a loop one frame at a time.
pub(super) fn fuse_frames(
    inputs: &DenseInputs,
    config: &DenseConfig,
    chosen: FusedFrames<impl Iterator<Item = Result<(Chosen, f32), IoError>>>,
    sources: FrameSources,
    mut sinks: FrameSinks,
) -> Result<Fused, IoError> {
    let progress = frames_bar("fuse  ", chosen.count, inputs.progress);
    let extras = extras(inputs, config)?;
    let mut fused = Fused {
        frames: 0,
        keyframes_in_cloud: 0,
        masked: 0,
        pixels: 0,
        integration_ms: MedianSample::default(),
        released: 0,
        fusable: 0,
        fusable_masked: 0,
        stages: DenseStages::default(),
    };
    let FrameSources { lookup, mut window } = sources;
    let mut pending: Option<Prepared> = None;
    for (step, next) in chosen.frames.map(Some).chain([None]).enumerate() {
        let next = next.transpose()?;
        // The objects the next frame's masks need, placed before it is loaded: a
        // stereo pair matched for them is not matched again.
        if let Some(((index, ..), _)) = next {
            let start = Instant::now();
            let t = inputs.sequence.timestamp(index);
            sinks
                .mask_source
                .place_through(t, &|t| lookup.pose(t), &|t| lookup.depth(t))?;
            add_since(&mut fused.stages.inputs_s, start);
        }
        let window = window.as_deref_mut();
        let (prepared, finished) = rayon::join(
            || {
                next.map(|(c, weight)| prepare(inputs, lookup, (c, weight), window))
                    .transpose()
            },
            || {
                pending.take().map(|p| {
                    progress.inc(1);
                    fuse_frame(inputs, config, &extras, &mut sinks, p, &mut fused)
                })
            },
        );
        finished.transpose()?;
        pending = prepared?;
        // The blocks and chunks that go to their spill files, and the frames' buffers,
        // leave free pages the allocator would keep in its heaps (a fifth of the peak
        // on a long loop: docs/design.md): handed back every few frames.
        if (step + 1) % RELEASE_EVERY == 0 {
            crate::memory::release_freed_memory();
        }
        if let Some(p) = &pending {
            fused.stages.loading_s += p.loading_s;
            fused.stages.free_space_s += p.free_space_s;
        }
    }
    progress.finish_and_clear();
    Ok(fused)
}

/// Frames fused between two hand-backs of the allocator's free pages.
const RELEASE_EVERY: usize = 16;

/// A frame loaded, with its free-space evidence, and the seconds each took.
struct Prepared {
    frame: Loaded,
    evidence: Option<Evidence>,
    loading_s: f64,
    free_space_s: f64,
}

/// Loads the `chosen` frame (a stereo pair's depth from `lookup` when placing the
/// objects matched it) and gathers its free-space evidence from the `window` (when
/// there is one).
fn prepare(
    inputs: &DenseInputs,
    lookup: &FrameLookup,
    chosen: (Chosen, f32),
    window: Option<&mut NeighbourWindow>,
) -> Result<Prepared, IoError> {
    let ((index, pose, is_keyframe), weight) = chosen;
    check_interrupt(inputs)?;
    let start = Instant::now();
    let (timestamp, depth, rgb) = sequence_frame(inputs, index, lookup.take_matched(index))?;
    let loading_s = start.elapsed().as_secs_f64();
    let start = Instant::now();
    let posed = PosedDepth {
        timestamp,
        depth: &depth,
        camera_from_world: &pose,
    };
    let evidence = match window {
        Some(window) => Some(window.evidence(&inputs.camera, posed, |i| frame_depth(inputs, i))?),
        None => None,
    };
    Ok(Prepared {
        frame: Loaded {
            timestamp,
            pose,
            is_keyframe,
            weight,
            depth,
            rgb,
        },
        evidence,
        loading_s,
        free_space_s: start.elapsed().as_secs_f64(),
    })
}

/// The mask pictures' folder, made when pictures are asked for, and the truth masks'
/// unknown instances.
fn extras(inputs: &DenseInputs, config: &DenseConfig) -> Result<Extras, IoError> {
    let pictures = match config.outputs.mask_pictures_every {
        0 => None,
        _ => {
            let dir = RunDir::new(inputs.out_dir).file(names::MASK_PICTURES);
            std::fs::create_dir_all(&dir).map_err(|source| IoError::Write {
                path: dir.clone(),
                source,
            })?;
            Some(dir)
        }
    };
    let unknown = match &inputs.truth_masks {
        Some(dir) => unknown_instances(dir)?,
        None => Vec::new(),
    };
    Ok(Extras { pictures, unknown })
}

/// One frame: its mask (with the free-space evidence), the truth count, the mask
/// picture, then the volume and (a keyframe) the cloud.
fn fuse_frame(
    inputs: &DenseInputs,
    config: &DenseConfig,
    extras: &Extras,
    sinks: &mut FrameSinks,
    prepared: Prepared,
    fused: &mut Fused,
) -> Result<(), IoError> {
    let Prepared {
        frame, evidence, ..
    } = prepared;
    let layers = frame_mask(inputs, config, sinks, &frame, evidence, fused);
    let Loaded {
        timestamp,
        pose,
        is_keyframe,
        weight,
        depth,
        rgb,
    } = frame;
    let max_depth = config.tsdf.max_depth as f32;
    let fusable = |i: usize| depth.metres[i] > 0.0 && depth.metres[i] <= max_depth;
    if let Some(m) = &layers {
        fused.masked += m.masked();
        fused.fusable_masked += (0..m.dynamic.len())
            .filter(|&i| m.dynamic[i] && fusable(i))
            .count() as u64;
    }
    fused.pixels += depth.metres.len() as u64;
    fused.fusable += (0..depth.metres.len()).filter(|&i| fusable(i)).count() as u64;
    let input = FrameInput {
        depth: &depth,
        colour: &rgb,
        dynamic: layers.as_ref().map(|m| m.dynamic.as_slice()),
        camera_from_world: &pose,
        weight,
    };
    let start = Instant::now();
    let sources = layers.as_ref().map(|m| m.sources.as_slice());
    let fusing = Fusing {
        timestamp,
        sources,
        input: &input,
    };
    side_outputs(inputs, config, extras, sinks, fusing, fused.frames)?;
    add_since(&mut fused.stages.truth_s, start);
    let start = Instant::now();
    if let Some(volume) = sinks.volume.as_deref_mut() {
        volume.integrate(&input)?;
    }
    fused
        .integration_ms
        .push(start.elapsed().as_secs_f64() * 1e3);
    add_since(&mut fused.stages.integration_s, start);
    if let (Some(cloud), true) = (sinks.cloud.as_deref_mut(), is_keyframe) {
        let start = Instant::now();
        cloud.add(&input)?;
        fused.keyframes_in_cloud += 1;
        add_since(&mut fused.stages.cloud_frames_s, start);
    }
    fused.frames += 1;
    Ok(())
}

/// The frame's mask: the mask source's layers with the free-space `evidence` of the
/// frames around, and the masked pixels the static map fused so far explains
/// released.
fn frame_mask(
    inputs: &DenseInputs,
    config: &DenseConfig,
    sinks: &mut FrameSinks,
    frame: &Loaded,
    evidence: Option<Evidence>,
    fused: &mut Fused,
) -> Option<MaskLayers> {
    let posed = PosedDepth {
        timestamp: frame.timestamp,
        depth: &frame.depth,
        camera_from_world: &frame.pose,
    };
    let start = Instant::now();
    let mut layers = sinks.mask_source.layers(
        frame.timestamp,
        &frame.depth,
        &frame.pose,
        evidence.as_ref(),
    );
    let still = evidence.as_ref().map(|e| e.still.as_slice());
    let release = MapRelease {
        min_weight: config.masks.map_min_weight,
        bodies_still: still.filter(|_| config.masks.map_release_bodies),
        band: config.masks.map_band,
    };
    let on = release.min_weight > 0.0;
    if let (Some(m), Some(volume), true) = (&mut layers, sinks.volume.as_deref(), on) {
        fused.released += m.release_on_map(posed, &inputs.camera, volume, release);
    }
    add_since(&mut fused.stages.masks_s, start);
    layers
}

/// A frame being fused: its time, its mask's sources and what the volume takes.
struct Fusing<'a> {
    timestamp: f64,
    sources: Option<&'a [u8]>,
    input: &'a FrameInput<'a>,
}

/// The frame's count against the truth masks and its mask picture, when asked for
/// (every `mask_pictures_every`-th of the frames, `fused_before` fused before it).
fn side_outputs(
    inputs: &DenseInputs,
    config: &DenseConfig,
    extras: &Extras,
    sinks: &mut FrameSinks,
    frame: Fusing,
    fused_before: usize,
) -> Result<(), IoError> {
    let Fusing {
        timestamp,
        sources,
        input,
    } = frame;
    let ids = inputs.truth_masks.as_ref().and_then(|dir| {
        crate::io::image_files::read_instance_mask(&dir.join(format!("{timestamp:.6}.png")))
    });
    if let (Some(truth), Some(ids)) = (sinks.truth.as_mut(), &ids) {
        let frame = TruthFrame {
            timestamp,
            ids: ids.as_raw(),
            sources,
        };
        count_truth(truth, frame, &extras.unknown, input, config.tsdf.max_depth);
    }
    if let Some(dir) = extras
        .pictures
        .as_ref()
        .filter(|_| fused_before.is_multiple_of(config.outputs.mask_pictures_every))
    {
        let truth = ids.as_ref().map(|i| i.as_raw().as_slice());
        let picture = render::mask_picture(render::MaskPicture {
            colour: input.colour,
            mask: input.dynamic,
            truth,
            sources,
        });
        save_png(&dir.join(format!("{timestamp:.6}.png")), &picture)?;
    }
    Ok(())
}
