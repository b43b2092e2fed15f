//! The dense pass: fuse only static depth, with the final poses, into a TSDF (meshed
//! by marching cubes) and a point cloud, and write them as PLY and OBJ.
//!
//! It reads a finished run's folder, so `dopslam fuse RUN_DIR` re-fuses without
//! tracking again: `trajectory.txt` (the final poses), `keyframes.txt`, the keyframe
//! detections in `detections/` and the dynamic keypoints per frame in
//! `dynamic_keypoints.json`; the frames come from the sequence. Masks: [`masks`].
//! Outputs: `dense_mesh.ply`, `dense_mesh.obj`, `dense_points.ply`, `dense.json`,
//! and pictures `dense_perspective.png`, `dense_top.png`.

pub mod cloud;
pub mod compare;
pub mod config;
pub mod comparison;
pub mod disparity;
pub mod free_space;
pub mod marching_cubes;
pub mod masks;
pub mod more_detections;
pub mod neighbours;
pub mod render;
pub mod segments;
pub mod tsdf;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use serde::Serialize;

use crate::detect::FrameDetections;
use crate::dop::{DopConfig, Mode};
use crate::geometry::camera::PinholeCamera;
use crate::geometry::se3::Se3;
use crate::io::atomic::write_atomic;
use crate::io::run_dir::{names, RunDir};
use crate::io::image_files::DepthImage;
use crate::io::ply::{write_obj, write_ply};
use crate::io::sequence::{FrameImages, Sequence};
use crate::io::trajectory::TrajectoryFormat;
use crate::io::{IoError, Trajectory};
use cloud::CloudBuilder;
use disparity::{stereo_depth, StereoDepth};
use free_space::NeighbourWindow;
use masks::{FrameKeypoints, MaskSettings, MaskSource};
use segments::SegmentSettings;
use tsdf::{FrameInput, TsdfVolume};

pub use config::{DenseConfig, FrameChoice, Fusion};

/// Pixels fused against a synthetic sequence's ground-truth masks.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct FusedTruth {
    pub frames: usize,
    /// Pixels with depth on movers, and those fused anyway.
    pub mover_pixels: u64,
    pub mover_pixels_fused: u64,
    /// Pixels with depth on the static scene, and those fused.
    pub static_pixels: u64,
    pub static_pixels_fused: u64,
    /// Share of mover pixels kept out, and of static pixels fused.
    pub dynamic_removed: f64,
    pub static_kept: f64,
    /// Of the mover pixels, those on movers of no COCO class (which no detector
    /// knows; from `masks/instances.txt`), those fused anyway, and the share kept out
    /// (`None` without such movers).
    pub unknown_mover_pixels: u64,
    pub unknown_mover_pixels_fused: u64,
    pub unknown_removed: Option<f64>,
}

impl FusedTruth {
    /// The shares, once every frame is counted.
    fn finish(mut self) -> Self {
        let share = |part: u64, whole: u64| part as f64 / whole.max(1) as f64;
        self.dynamic_removed = 1.0 - share(self.mover_pixels_fused, self.mover_pixels);
        self.static_kept = share(self.static_pixels_fused, self.static_pixels);
        self.unknown_removed = (self.unknown_mover_pixels > 0)
            .then(|| 1.0 - share(self.unknown_mover_pixels_fused, self.unknown_mover_pixels));
        self
    }
}

/// Which instance ids of the truth masks are movers no detector knows (a class that is
/// not a COCO name), by id.
fn unknown_instances(masks: &Path) -> Result<Vec<bool>, IoError> {
    let mut unknown = Vec::new();
    for (id, class) in crate::io::image_files::read_instance_classes(masks)?.unwrap_or_default() {
        let id = id as usize;
        if unknown.len() <= id {
            unknown.resize(id + 1, false);
        }
        unknown[id] = crate::detect::coco::class_id(&class).is_none();
    }
    Ok(unknown)
}

/// What the dense pass did.
#[derive(Debug, Clone, Default, Serialize)]
pub struct DenseReport {
    pub masking: Option<Mode>,
    pub frames_fused: usize,
    /// Tracked frames left out because they are in a map segment that no loop merged
    /// with the largest one.
    pub other_segment_frames: usize,
    pub keyframes_in_cloud: usize,
    /// Share of pixels masked as dynamic over the fused frames, %.
    pub masked_percent: f64,
    pub tsdf_blocks: usize,
    pub tsdf_memory_mb: f64,
    pub mesh_vertices: usize,
    pub mesh_triangles: usize,
    pub cloud_points: usize,
    /// Cloud voxels dropped as seen through (see `DenseConfig::cloud_free_space`).
    pub cloud_seen_through: usize,
    /// The dense pass's own detections (`detect_every`).
    pub extra_detections: Option<more_detections::ExtraDetections>,
    /// Milliseconds: TSDF integration per frame (median), marching cubes, cloud.
    pub median_integration_ms: f64,
    pub marching_cubes_ms: f64,
    pub cloud_ms: f64,
    pub total_s: f64,
    /// The process's peak resident memory at the end of the pass (MiB, Linux).
    pub peak_memory_mib: Option<f64>,
    pub truth: Option<FusedTruth>,
    pub outputs: Vec<PathBuf>,
}

/// Where the dense pass finds its inputs.
pub struct DenseInputs<'a> {
    pub sequence: &'a dyn Sequence,
    pub camera: PinholeCamera,
    /// The run folder (inputs).
    pub run_dir: &'a Path,
    /// Where the dense outputs go (usually the run folder).
    pub out_dir: &'a Path,
    pub masking: Mode,
    pub dop: &'a DopConfig,
    pub dynamic_classes: &'a [String],
    /// A synthetic sequence's `masks/` folder, to count what was fused.
    pub truth_masks: Option<PathBuf>,
    pub progress: bool,
    /// How stereo pairs become depth (stereo sequences only).
    pub stereo: Option<StereoDepth>,
    /// The detector for `detect_every` (DOP masks only).
    pub detector: Option<(std::sync::Mutex<Box<dyn crate::detect::Detector>>, String)>,
}

/// A frame's depth and colour: an RGB-D frame's own, or a stereo pair's SGBM depth
/// and its left image in grey.
fn depth_and_colour(
    images: FrameImages,
    stereo: Option<&StereoDepth>,
    what: &Path,
) -> Result<(DepthImage, image::RgbImage), IoError> {
    match images {
        FrameImages::Rgbd { rgb, depth } => Ok((depth, rgb)),
        FrameImages::Stereo { left, right } => {
            let stereo = stereo.ok_or_else(|| {
                IoError::invalid(what, "a stereo frame, but no stereo calibration was given")
            })?;
            let depth =
                stereo_depth(&left, &right, stereo).map_err(|m| IoError::invalid(what, m))?;
            Ok((depth, image::DynamicImage::ImageLuma8(left).to_rgb8()))
        }
    }
}

/// Timestamps as keys (microseconds, as the file names carry them).
fn key(t: f64) -> i64 {
    (t * 1e6).round() as i64
}

/// The timestamps of the frames in the largest segment of the run's `segments.txt`
/// ([`RunDir::segments`]: each tracked frame's timestamp and map segment after the
/// loops' merges), when it lists more than one (`None`: fuse every frame; also for runs
/// written before the file existed). Segments that no loop merged have unrelated
/// frames of reference, so only the largest is fused.
fn largest_segment(run: &RunDir) -> Result<Option<std::collections::HashSet<i64>>, IoError> {
    let path = run.segments();
    let Ok(text) = std::fs::read_to_string(&path) else {
        return Ok(None);
    };
    let mut frames: HashMap<usize, Vec<i64>> = HashMap::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let mut fields = line.split_whitespace();
        let parsed = match (fields.next(), fields.next(), fields.next()) {
            (Some(t), Some(s), None) => t.parse::<f64>().ok().zip(s.parse::<usize>().ok()),
            _ => None,
        };
        let Some((t, segment)) = parsed else {
            return Err(IoError::invalid(
                &path,
                format!("line {}: expected `timestamp segment`, got {line:?}", n + 1),
            ));
        };
        frames.entry(segment).or_default().push(key(t));
    }
    if frames.len() < 2 {
        return Ok(None);
    }
    // The most frames; ties go to the older segment.
    let largest = frames
        .into_iter()
        .max_by(|a, b| a.1.len().cmp(&b.1.len()).then(b.0.cmp(&a.0)))
        .map(|(_, times)| times.into_iter().collect());
    Ok(largest)
}

/// The frames' final poses (`camera_from_world`) by timestamp.
fn poses_by_time(trajectory: &Trajectory) -> HashMap<i64, Se3> {
    trajectory
        .timestamps
        .iter()
        .zip(&trajectory.poses)
        .map(|(&t, pose)| (key(t), pose.inverse()))
        .collect()
}

/// Reads the keyframe detections a run cached (`detections/*.json`).
pub fn read_detections(dir: &Path) -> Result<Vec<FrameDetections>, IoError> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Ok(Vec::new());
    };
    let mut frames = Vec::new();
    for entry in entries.flatten() {
        let path = entry.path();
        if path.extension().is_some_and(|e| e == "json") {
            let frame = crate::detect::read_cache_file(&path)
                .map_err(|e| IoError::invalid(&path, e.to_string()))?;
            frames.push(frame);
        }
    }
    Ok(frames)
}

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

/// Reads `dynamic_keypoints.json` (empty when the run had no DOP model).
pub fn read_keypoints(path: &Path) -> Result<Vec<FrameKeypoints>, IoError> {
    if !path.exists() {
        return Ok(Vec::new());
    }
    let text = crate::io::errors::read_text(path)?;
    serde_json::from_str(&text).map_err(|e| IoError::invalid(path, format!("malformed: {e}")))
}

/// Fuses a finished run (see the module doc).
pub fn fuse_run(inputs: &DenseInputs, config: &DenseConfig) -> Result<DenseReport, IoError> {
    config
        .validate()
        .map_err(|m| IoError::invalid(inputs.run_dir, m))?;
    let started = Instant::now();
    let (run, out) = (RunDir::new(inputs.run_dir), RunDir::new(inputs.out_dir));
    let trajectory = Trajectory::read(&run.trajectory(), TrajectoryFormat::Tum)?;
    let keyframes =
        Trajectory::read(&run.keyframes(), TrajectoryFormat::Tum).unwrap_or_default();
    let mut poses = poses_by_time(&trajectory);
    let mut other_segment_frames = 0;
    if let Some(keep) = largest_segment(&run)? {
        let before = poses.len();
        poses.retain(|t, _| keep.contains(t));
        other_segment_frames = before - poses.len();
    }
    let keyframe_times: std::collections::HashSet<i64> =
        keyframes.timestamps.iter().map(|&t| key(t)).collect();
    let sequence = inputs.sequence;
    let index_of: HashMap<i64, usize> = (0..sequence.len())
        .map(|i| (key(sequence.timestamp(i)), i))
        .collect();
    let load_depth =
        |t: f64| -> Option<DepthImage> { frame_depth(inputs, *index_of.get(&key(t))?).ok() };
    let (mut detections, keypoints) = if inputs.masking == Mode::Off {
        (Vec::new(), Vec::new())
    } else {
        (
            read_detections(&run.detections())?,
            read_keypoints(&run.dynamic_keypoints())?,
        )
    };
    // The frames to fuse, in sequence order (keyframes only for a point cloud alone).
    let every_frame = config.frames == FrameChoice::All && config.fusion != Fusion::Points;
    let chosen: Vec<(usize, Se3, bool)> = (0..sequence.len())
        .filter_map(|i| {
            let k = key(sequence.timestamp(i));
            let pose = *poses.get(&k)?;
            let is_keyframe = keyframe_times.contains(&k);
            (every_frame || is_keyframe).then_some((i, pose, is_keyframe))
        })
        .step_by(config.frame_step)
        .collect();
    let extra_detections = match (&inputs.detector, inputs.masking) {
        (Some((detector, describe)), Mode::Dop) if config.detect_every > 0 => {
            let fused: Vec<usize> = chosen.iter().map(|c| c.0).collect();
            let mut detector = detector.lock().expect("detector lock poisoned");
            Some(more_detections::add(
                sequence,
                (detector.as_mut(), describe),
                (&fused, config.detect_every),
                &out.dense_detections(),
                &mut detections,
                inputs.progress,
            )?)
        }
        _ => None,
    };
    let mut mask_source = MaskSource::new(
        inputs.masking,
        MaskSettings {
            border: config.mask_border,
            keypoint_radius: config.keypoint_radius,
            foreground_share: config.mask_foreground_share,
            skip_behind_objects: !config.mask_discs_behind_objects,
            disc_neighbours: config.mask_disc_neighbours,
            segments: config.mask_segments.then(|| {
                let settings = SegmentSettings {
                    radius: config.mask_segment_radius,
                    radius_metres: config.mask_segment_radius_metres,
                    edge_share: config.mask_segment_edge_share,
                    support: config.mask_segment_support,
                    ..SegmentSettings::default()
                };
                (settings, config.mask_segment_follow_seconds)
            }),
        },
        inputs.camera,
        inputs.dop,
        inputs.dynamic_classes,
        detections,
        keypoints,
        &|t| poses.get(&key(t)).copied(),
        &load_depth,
    );
    let fuse_tsdf = config.fuses_tsdf();
    let cloud_on = config.cloud || config.fusion != Fusion::Tsdf;
    let mut volume = TsdfVolume::new(config.tsdf(), inputs.camera);
    if fuse_tsdf && config.carve && config.allocate_first {
        allocate_blocks(&mut volume, inputs, &chosen)?;
    }
    let mut cloud = CloudBuilder::new(config.cloud_settings(), inputs.camera);
    let mut report = DenseReport {
        masking: Some(inputs.masking),
        other_segment_frames,
        extra_detections,
        ..DenseReport::default()
    };
    let mut truth = inputs.truth_masks.as_ref().map(|_| FusedTruth::default());
    let mut window = (inputs.masking == Mode::Dop && config.mask_free_space_seconds > 0.0)
        .then(|| {
            let posed = (0..sequence.len())
                .filter_map(|i| {
                    let t = sequence.timestamp(i);
                    Some((t, i, *poses.get(&key(t))?))
                })
                .collect();
            NeighbourWindow::new(config.free_space_settings(), posed)
        });
    let fused = fuse_frames(
        inputs,
        config,
        &chosen,
        (&mut mask_source, window.as_mut()),
        (fuse_tsdf.then_some(&mut volume), cloud_on.then_some(&mut cloud)),
        &mut truth,
    )?;
    (report.frames_fused, report.keyframes_in_cloud) = (fused.frames, fused.keyframes_in_cloud);
    let (masked, pixels, mut integration_ms) = (fused.masked, fused.pixels, fused.integration_ms);
    report.masked_percent = 100.0 * masked as f64 / pixels.max(1) as f64;
    report.median_integration_ms = crate::eval::stats::median(&mut integration_ms);
    report.tsdf_blocks = volume.blocks.len();
    report.tsdf_memory_mb = volume.memory_bytes() as f64 / 1e6;
    let maps = Maps {
        volume,
        cloud: cloud_on.then_some(cloud),
    };
    write_maps(&out, inputs.masking, config, maps, &trajectory, &mut report)?;
    report.truth = truth.map(FusedTruth::finish);
    report.total_s = started.elapsed().as_secs_f64();
    report.peak_memory_mib = crate::memory::peak_resident_mib();
    let json = serde_json::to_string_pretty(&report).expect("report serialises");
    write_atomic(&out.dense_report(), json.as_bytes())?;
    // A request that came while the files were written: they were finished whole, and
    // the command still ends as interrupted.
    interrupted(out.root(), "asked while the dense map was written: it was finished whole")?;
    Ok(report)
}

/// The fused volume and the keyframe cloud (when one is made).
struct Maps {
    volume: TsdfVolume,
    cloud: Option<CloudBuilder>,
}

/// Writes the mesh (marching cubes over the volume, when it was fused), the point
/// cloud (carved by the volume when asked) and the pictures into `out`.
fn write_maps(
    out: &RunDir,
    masking: Mode,
    config: &DenseConfig,
    maps: Maps,
    trajectory: &Trajectory,
    report: &mut DenseReport,
) -> Result<(), IoError> {
    let comment = format!(
        "dopslam dense map, masking {:?}, voxel {} m",
        masking, config.voxel
    );
    let Maps { volume, cloud } = maps;
    // Everything is computed before anything is written: an interrupt until then
    // leaves the earlier dense map as it was.
    let mesh = config.fuses_tsdf().then(|| {
        let start = Instant::now();
        let mesh = marching_cubes::extract(&volume);
        report.marching_cubes_ms = start.elapsed().as_secs_f64() * 1e3;
        report.mesh_vertices = mesh.len();
        report.mesh_triangles = mesh.triangles.len();
        mesh
    });
    let points = cloud.map(|cloud| {
        let start = Instant::now();
        let (carved, limit) = (config.cloud_carved(), config.cloud_free_space);
        let (points, dropped) = cloud.finish(|p| carved && volume.seen_through(p, limit));
        report.cloud_ms = start.elapsed().as_secs_f64() * 1e3;
        report.cloud_points = points.len();
        report.cloud_seen_through = dropped;
        points
    });
    drop(volume);
    interrupted(out.root(), "the dense map was not written; the earlier one is as it was")?;
    if let Some(mesh) = &mesh {
        let path = out.file(names::DENSE_MESH_PLY);
        write_ply(&path, mesh, None, config.ply_encoding, &comment)?;
        report.outputs.push(path);
        if config.obj {
            let path = out.file(names::DENSE_MESH_OBJ);
            write_obj(&path, mesh, &comment)?;
            report.outputs.push(path);
        }
    }
    if let Some(points) = &points {
        let path = out.file(names::DENSE_POINTS);
        write_ply(&path, points, None, config.ply_encoding, &comment)?;
        report.outputs.push(path);
    }
    if let (true, Some(map)) = (config.pictures, mesh.as_ref().or(points.as_ref())) {
        write_pictures(out, map, trajectory, report)?;
    }
    Ok(())
}

/// The dense map's pictures (perspective and top view) from the cameras' side.
fn write_pictures(
    out: &RunDir,
    map: &crate::geometry::mesh::Mesh,
    trajectory: &Trajectory,
    report: &mut DenseReport,
) -> Result<(), IoError> {
    let Some(view) = render::Viewpoint::from_cameras(&trajectory.poses) else {
        return Ok(());
    };
    let colours = render::with_ghosts(map, &[]);
    let pictures = [
        (
            names::DENSE_PERSPECTIVE,
            render::perspective(
                &map.vertices,
                &colours,
                &view.camera_from_world,
                &render::picture_camera(),
            ),
        ),
        (
            names::DENSE_TOP,
            render::top(&map.vertices, &colours, &view, 800),
        ),
    ];
    for (name, picture) in pictures {
        let path = out.file(name);
        save_png(&path, &picture)?;
        report.outputs.push(path);
    }
    Ok(())
}

/// What [`fuse_frames`] did.
struct Fused {
    frames: usize,
    keyframes_in_cloud: usize,
    masked: u64,
    pixels: u64,
    integration_ms: Vec<f64>,
}

/// Fuses the `chosen` frames in order, masked: into the volume (when given) and, the
/// keyframes, into the cloud (when given); counts the fused pixels against the truth
/// masks.
fn fuse_frames(
    inputs: &DenseInputs,
    config: &DenseConfig,
    chosen: &[(usize, Se3, bool)],
    (mask_source, mut window): (&mut MaskSource, Option<&mut NeighbourWindow>),
    (mut volume, mut cloud): (Option<&mut TsdfVolume>, Option<&mut CloudBuilder>),
    truth: &mut Option<FusedTruth>,
) -> Result<Fused, IoError> {
    let progress = frames_bar("fuse  ", chosen.len(), inputs.progress);
    // The mask pictures' folder, when they are asked for.
    let pictures = match config.mask_pictures_every {
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
    let mut fused = Fused {
        frames: 0,
        keyframes_in_cloud: 0,
        masked: 0,
        pixels: 0,
        integration_ms: Vec::with_capacity(chosen.len()),
    };
    for group in groups(chosen) {
        // Decode a few frames (and match stereo pairs) in parallel; fuse them in order.
        let loaded = load_group(inputs, group, sequence_frame)?;
        for (&(_, pose, is_keyframe), frame) in group.iter().zip(loaded) {
            let (timestamp, depth, rgb) = frame?;
            let evidence = match window.as_deref_mut() {
                Some(window) => Some(window.evidence(
                    &inputs.camera,
                    (timestamp, &depth, &pose),
                    |i| frame_depth(inputs, i),
                )?),
                None => None,
            };
            let mask = mask_source.mask(timestamp, &depth, &pose, evidence.as_ref());
            if let Some(m) = &mask {
                fused.masked += m.iter().filter(|&&x| x).count() as u64;
            }
            fused.pixels += depth.metres.len() as u64;
            let input = FrameInput {
                depth: &depth,
                colour: &rgb,
                dynamic: mask.as_deref(),
                camera_from_world: &pose,
            };
            let ids = inputs.truth_masks.as_ref().and_then(|dir| {
                crate::io::image_files::read_instance_mask(&dir.join(format!("{timestamp:.6}.png")))
            });
            if let (Some(truth), Some(ids)) = (truth.as_mut(), &ids) {
                count_truth(truth, ids.as_raw(), &unknown, &input, config.max_depth);
            }
            if let Some(dir) = pictures
                .as_ref()
                .filter(|_| fused.frames.is_multiple_of(config.mask_pictures_every))
            {
                let truth = ids.as_ref().map(|i| i.as_raw().as_slice());
                let picture = render::mask_picture(&rgb, mask.as_deref(), truth);
                save_png(&dir.join(format!("{timestamp:.6}.png")), &picture)?;
            }
            let start = Instant::now();
            if let Some(volume) = volume.as_deref_mut() {
                volume.integrate(&input);
            }
            fused.integration_ms.push(start.elapsed().as_secs_f64() * 1e3);
            if let (Some(cloud), true) = (cloud.as_deref_mut(), is_keyframe) {
                cloud.add(&input);
                fused.keyframes_in_cloud += 1;
            }
            fused.frames += 1;
            progress.inc(1);
        }
    }
    progress.finish_and_clear();
    Ok(fused)
}

/// The first pass of `allocate_first`: every chosen frame's blocks, without masks
/// (blocks where masked movers stood only take free-space observations).
fn allocate_blocks(
    volume: &mut TsdfVolume,
    inputs: &DenseInputs,
    chosen: &[(usize, Se3, bool)],
) -> Result<(), IoError> {
    let progress = frames_bar("blocks ", chosen.len(), inputs.progress);
    for group in groups(chosen) {
        let depths = load_group(inputs, group, frame_depth)?;
        for (&(_, pose, _), depth) in group.iter().zip(depths) {
            volume.allocate(&depth?, &pose);
            progress.inc(1);
        }
    }
    progress.finish_and_clear();
    Ok(())
}

/// The chosen frames in groups of two per thread: each group is decoded in parallel,
/// then used in order.
fn groups(chosen: &[(usize, Se3, bool)]) -> std::slice::Chunks<'_, (usize, Se3, bool)> {
    chosen.chunks(rayon::current_num_threads().max(1) * 2)
}

/// A group of chosen frames, each loaded by `load` in parallel (after an interrupt
/// check, see [`check_interrupt`]).
fn load_group<T: Send>(
    inputs: &DenseInputs,
    group: &[(usize, Se3, bool)],
    load: impl Fn(&DenseInputs, usize) -> Result<T, IoError> + Sync,
) -> Result<Vec<Result<T, IoError>>, IoError> {
    check_interrupt(inputs)?;
    Ok(group.par_iter().map(|&(i, _, _)| load(inputs, i)).collect())
}

/// `Err` once an interrupt was asked for: the dense map is then not written.
fn check_interrupt(inputs: &DenseInputs) -> Result<(), IoError> {
    interrupted(inputs.out_dir, "the dense map was not written")
}

/// `Err` naming `dir` and saying `what` once an interrupt was asked for.
fn interrupted(dir: &Path, what: &str) -> Result<(), IoError> {
    if crate::interrupt::requested() {
        return Err(IoError::invalid(
            dir,
            format!("{}: {what}", crate::interrupt::MESSAGE),
        ));
    }
    Ok(())
}

/// Frame `i`'s depth alone: an RGB-D reader skips the colour image; a stereo pair is
/// matched.
fn frame_depth(inputs: &DenseInputs, i: usize) -> Result<DepthImage, IoError> {
    match inputs.sequence.load_depth(i)? {
        Some(depth) => Ok(depth),
        None => sequence_frame(inputs, i).map(|(_, depth, _)| depth),
    }
}

/// A decoded frame: timestamp, depth and colour.
type LoadedFrame = (f64, DepthImage, image::RgbImage);

/// Frame `i` of the sequence.
fn sequence_frame(inputs: &DenseInputs, i: usize) -> Result<LoadedFrame, IoError> {
    let frame = inputs.sequence.load(i)?;
    let timestamp = frame.timestamp;
    depth_and_colour(frame.images, inputs.stereo.as_ref(), inputs.run_dir)
        .map(|(depth, rgb)| (timestamp, depth, rgb))
}

/// Writes a PNG atomically.
pub fn save_png(path: &Path, picture: &image::RgbImage) -> Result<(), IoError> {
    let mut bytes = Vec::new();
    picture
        .write_to(
            &mut std::io::Cursor::new(&mut bytes),
            image::ImageFormat::Png,
        )
        .map_err(|e| IoError::Write {
            path: path.to_path_buf(),
            source: std::io::Error::other(e),
        })?;
    write_atomic(path, &bytes)
}

/// Counts fused and masked pixels against instance ids (0: static; `unknown[id]`: a
/// mover no detector knows).
fn count_truth(
    truth: &mut FusedTruth,
    ids: &[u16],
    unknown: &[bool],
    input: &FrameInput,
    max_depth: f64,
) {
    truth.frames += 1;
    for (i, &id) in ids.iter().enumerate() {
        let d = input.depth.metres.get(i).copied().unwrap_or(0.0) as f64;
        if d <= 0.0 || d > max_depth {
            continue;
        }
        let fused = !input.dynamic.is_some_and(|m| m[i]);
        if id > 0 {
            truth.mover_pixels += 1;
            truth.mover_pixels_fused += fused as u64;
            if unknown.get(id as usize).copied().unwrap_or(false) {
                truth.unknown_mover_pixels += 1;
                truth.unknown_mover_pixels_fused += fused as u64;
            }
        } else {
            truth.static_pixels += 1;
            truth.static_pixels_fused += fused as u64;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_the_largest_unmerged_segment_is_fused() {
        let dir = std::env::temp_dir().join(format!("dopslam-segments-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let run = RunDir::new(&dir);
        let with = |text: &str| {
            std::fs::write(run.segments(), text).unwrap();
            largest_segment(&run)
        };
        let keep = with("# t s\n1.0 0\n1.1 0\n2.0 1\n2.1 1\n2.2 1\n")
            .unwrap()
            .expect("two segments");
        let expected: std::collections::HashSet<i64> = [2.0, 2.1, 2.2].map(key).into();
        assert_eq!(keep, expected);
        // One segment (or no file): every frame.
        assert_eq!(with("1.0 0\n1.1 0\n").unwrap(), None);
        assert_eq!(largest_segment(&RunDir::new(dir.join("absent"))).unwrap(), None);
        let error = with("1.0 0\n1.1 zero\n").unwrap_err().to_string();
        assert!(
            error.contains("line 2") && error.contains(names::SEGMENTS),
            "{error}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
