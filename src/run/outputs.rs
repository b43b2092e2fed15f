//! The outputs of the tracking and global passes, written atomically into the run
//! folder ([`RunDir`] names every file): `trajectory.txt` (TUM format, every tracked
//! frame), `trajectory_tracking.txt` (before the global pass), `keyframes.txt`,
//! `map.ply` (the sparse map), `segments.txt`, `dynamic_keypoints.json` (DOP) and
//! `report.json` (per-frame state, matches, inliers and times; totals, lost spans,
//! coverage, ATE when the sequence has ground truth).

use std::path::Path;

use super::error::{RunError, StopReason};
use super::options::RunOptions;
use crate::dop::Mode;
use crate::dynamics::DetectionTotals;
use crate::eval::report::{evaluate, EvalOptions, EvalReport};
use crate::eval::stats::MedianSample;
use crate::global::GlobalReport;
use crate::io::atomic::write_atomic_with;
use crate::io::run_dir::RunDir;
use crate::io::sequence::Sequence;
use crate::io::trajectory::TrajectoryFormat;
use crate::io::Trajectory;
use crate::map::record::FrameRecords;
use crate::map::Map;
use crate::mapping::MappingStats;
use crate::records::report::{final_segment, FrameLine, RunReport, RunTotals, SegmentSpans};
use crate::records::FrameLines;
use crate::records::RunSetup;
use crate::tracking::TrackingState;

/// Before any work (after the set-up): the paths are UTF-8 (the report names them),
/// the output and debug folders can be written and are not inside the input sequence,
/// no other run writes into the output folder (the lock returned is held for the run),
/// and an earlier run's outputs there move into a folder of their own under
/// `previous/` (nothing is deleted).
pub fn prepare(out: &Path, options: &RunOptions) -> Result<crate::io::output::DirLock, RunError> {
    use crate::io::output;
    // The sequence, and the folder of the map the run loads: neither is written.
    let map_dir = options.base_map.as_ref().and_then(|b| b.run_folder());
    let inputs: Vec<&Path> = options
        .sequence_dir
        .as_deref()
        .into_iter()
        .chain(map_dir)
        .collect();
    if let Some(dir) = inputs.first().filter(|d| d.to_str().is_none()) {
        return Err(RunError::Input(format!(
            "the sequence path {} is not valid UTF-8, which report.json cannot name: link it under a UTF-8 name (ln -s) and run that",
            dir.display()
        )));
    }
    output::prepare_dir(out, "output", &inputs)?;
    if let Some(debug) = &options.debug_frames {
        output::prepare_dir(debug, "debug frames", &inputs)?;
    }
    output::check_inputs_clear(out, &inputs)?;
    let lock = output::DirLock::take(out)?;
    let (moved, to) = output::move_previous_outputs(out, &[])?;
    if let (Some(to), true) = (to, options.progress) {
        eprintln!(
            "{} held an earlier run's outputs: moved into {} ({}); earlier runs stay in previous/",
            out.display(),
            to.display(),
            moved.join(", ")
        );
    }
    Ok(lock)
}

/// Every tracked frame's pose: relative to its reference keyframe, placed on that
/// keyframe's current pose (so frames follow the keyframes' corrections).
pub fn trajectory_of(map: &Map, records: &FrameRecords) -> Result<Trajectory, RunError> {
    let mut trajectory = Trajectory::default();
    for record in records.iter() {
        let record = record?;
        if let Some(pose) = record.camera_from_world_on(|key| map.keyframe_pose(key)) {
            trajectory.push(record.timestamp, pose.inverse());
        }
    }
    Ok(trajectory)
}

/// The trajectory of the tracking pass, written before the global pass moves the map.
pub fn write_tracking_trajectory(
    run: &RunDir,
    map: &Map,
    records: &FrameRecords,
) -> Result<Trajectory, RunError> {
    let tracking = trajectory_of(map, records)?;
    tracking.write(&run.tracking_trajectory(), TrajectoryFormat::Tum)?;
    Ok(tracking)
}

/// Each DOP frame's dynamic keypoints, for the dense pass's masks.
pub fn write_dynamic_keypoints(
    run: &RunDir,
    keypoints: &super::observers::DynamicKeypoints,
) -> Result<(), RunError> {
    let path = run.dynamic_keypoints();
    Ok(write_atomic_with(&path, |out| keypoints.write_json(out))?)
}

/// What the passes computed, for [`write`].
pub struct Computed<'a> {
    /// Held from the set's first file (`dynamic_keypoints.json`) to its last: a second
    /// Ctrl-C between them waits for the whole set.
    pub writing: crate::interrupt::Writing,
    /// The sequence.
    pub sequence: &'a dyn Sequence,
    /// Its folder or recording.
    pub sequence_path: Option<&'a Path>,
    /// What the run was set up with.
    pub setup: RunSetup,
    /// DOP, mask boxes or none.
    pub mode: Mode,
    /// The map after the global pass.
    pub map: Map,
    /// What local mapping did.
    pub mapping: MappingStats,
    /// What detection did.
    pub detection: DetectionTotals,
    /// One report line per frame (in a spill file).
    pub lines: FrameLines,
    /// One record per frame (the trajectory).
    pub records: FrameRecords,
    /// Why the run stopped early, if it did.
    pub stopped: Option<StopReason>,
    /// The global pass's report and the tracking pass's trajectory, when it ran.
    pub global: Option<(GlobalReport, Trajectory)>,
    /// The header to write the map under (`slam_map.bin`; its disparity offset is
    /// the run's, set here); `None`: no map is written.
    pub map_header: Option<crate::map::file::MapHeader>,
    /// The map the run was tracked in (`--map`), when there was one.
    pub loaded: Option<crate::records::LoadedMap>,
}

/// Writes trajectory, keyframes, map, segments and report; evaluates against ground
/// truth (also the tracking pass's trajectory, when the global pass ran after it).
pub fn write(run: &RunDir, computed: Computed) -> Result<RunReport, RunError> {
    // A second Ctrl-C waits until the set is written (the guard came with `computed`,
    // from before its first file).
    let Computed {
        writing: _writing,
        sequence,
        sequence_path,
        setup,
        mode,
        map,
        mapping,
        detection,
        lines,
        records,
        stopped,
        global,
        map_header,
        loaded,
    } = computed;
    let map = &map;
    let trajectory = trajectory_of(map, &records)?;
    trajectory.write(&run.trajectory(), TrajectoryFormat::Tum)?;
    write_keyframes_and_map(run, map)?;
    let merges: Vec<(usize, usize)> = global
        .iter()
        .flat_map(|(g, _)| g.loops.iter().filter_map(|l| l.merged))
        .map(|m| (m.segment, m.into))
        .collect();
    let tally = tally_lines(run, &lines, &merges)?;
    let placed_at_frame = tally.placed_at_frame;
    let totals = tally.totals(map, &merges, trajectory.len());
    let ate_of = |trajectory: &Trajectory| ate(sequence, trajectory);
    let ate = ate_of(&trajectory);
    let (global, ate_tracking) = match global {
        Some((report, tracking)) => (Some(report), ate_of(&tracking)),
        None => (None, None),
    };
    let mut report = RunReport {
        schema: crate::records::SCHEMA,
        sequence: sequence.name().to_string(),
        setup,
        sequence_path: sequence_path.map(|p| p.canonicalize().unwrap_or_else(|_| p.to_path_buf())),
        mode,
        totals,
        ate,
        ate_tracking,
        mapping,
        detection,
        global,
        frames: lines,
        stopped: stopped.map(|reason| reason.to_string()),
        dense: None,
        times: None,
        slam_map: None,
    };
    let loaded = loaded.map(|loaded| crate::records::LoadedMap {
        placed_at_frame,
        ..loaded
    });
    report.slam_map = slam_map_of(run, map, map_header, loaded, &report)?;
    write_report(run, &report)?;
    Ok(report)
}

/// `report.json` (again at the run's end, with the dense pass and the times).
pub fn write_report(run: &RunDir, report: &RunReport) -> Result<(), RunError> {
    write_atomic_with(&run.report(), |out| {
        serde_json::to_writer_pretty(out, report).map_err(std::io::Error::other)
    })?;
    Ok(())
}

/// What the run did with saved maps: the one it loaded (`loaded`, with the first
/// frame placed in it set) and `slam_map.bin`, written under `header` (the run's disparity
/// offset set) when there is one and this recording made a keyframe or was placed in
/// the loaded map.
fn slam_map_of(
    run: &RunDir,
    map: &Map,
    header: Option<crate::map::file::MapHeader>,
    loaded: Option<crate::records::LoadedMap>,
    report: &RunReport,
) -> Result<Option<crate::records::SlamMapReport>, RunError> {
    // A recording placed in a loaded map may make no keyframe (tracked there as a
    // revisit): the map it leaves is still the one a later recording continues.
    let made_keyframes = map.keyframe_order().iter().any(|k| map.is_current(*k));
    let placed = loaded.as_ref().is_some_and(|l| l.placed_at_frame.is_some());
    let saved = match header {
        Some(mut header) if made_keyframes || placed => {
            let start = std::time::Instant::now();
            header.disparity_offset_px = report.disparity_offset_px();
            let file = run.slam_map();
            crate::map::file::write_map(&file, map, &header)?;
            Some(crate::records::SavedMap {
                bytes: std::fs::metadata(&file).map_or(0, |m| m.len()),
                file,
                recordings: map.recordings().to_vec(),
                keyframes: map.keyframes().len(),
                points: map.points().len(),
                write_s: start.elapsed().as_secs_f64(),
            })
        }
        _ => None,
    };
    Ok((loaded.is_some() || saved.is_some())
        .then_some(crate::records::SlamMapReport { loaded, saved }))
}

/// `keyframes.txt` (this recording's keyframes) and `map.ply` (the whole sparse map).
fn write_keyframes_and_map(run: &RunDir, map: &Map) -> Result<(), RunError> {
    let mut keyframes = Trajectory::default();
    for key in map.keyframe_order().iter().filter(|k| map.is_current(**k)) {
        let kf = &map.keyframes()[*key];
        keyframes.push(kf.frame.timestamp, kf.world_from_camera());
    }
    keyframes.write(&run.keyframes(), TrajectoryFormat::Tum)?;
    crate::io::ply::write_ply(
        &run.sparse_map(),
        &map.to_mesh(),
        None,
        crate::io::ply::PlyEncoding::Binary,
        "dopslam sparse map",
    )?;
    Ok(())
}

/// Reads the frames' `lines` once: their totals' counts, spans and timing columns,
/// and `segments.txt` ([`crate::io::run_dir::write_segments`]: each tracked frame's
/// map segment after the loops' `merges`), written as the lines are read.
fn tally_lines(
    run: &RunDir,
    lines: &FrameLines,
    merges: &[(usize, usize)],
) -> Result<LineTally, RunError> {
    let mut tally = LineTally::default();
    let tracked = lines.iter().filter_map(|line| match line {
        Err(e) => Some(Err(std::io::Error::other(e))),
        Ok(line) => {
            tally.add(&line);
            let t = &line.tracking;
            (t.state == TrackingState::Ok)
                .then(|| Ok((t.timestamp, final_segment(merges, t.segment))))
        }
    });
    crate::io::run_dir::write_segments(&run.segments(), tracked)?;
    Ok(tally)
}

/// What one reading of the frames' lines gathers for the run's totals (the timing
/// columns' medians from bounded samples: exact up to
/// [`crate::eval::stats::MEDIAN_SAMPLE_CAP`] frames).
#[derive(Default)]
struct LineTally {
    frames: usize,
    lost: usize,
    not_initialised: usize,
    lost_spans: Vec<(usize, usize)>,
    segments: SegmentSpans,
    /// The first frame tracked (placed in a loaded map).
    placed_at_frame: Option<usize>,
    tracking_ms_sum: f64,
    tracking_ms: MedianSample,
    extraction_ms: MedianSample,
    matching_ms: MedianSample,
    optimisation_ms: MedianSample,
    dop_ms: MedianSample,
}

impl LineTally {
    fn add(&mut self, line: &FrameLine) {
        let t = &line.tracking;
        self.frames += 1;
        match t.state {
            TrackingState::Lost => {
                self.lost += 1;
                match self.lost_spans.last_mut() {
                    Some(span) if span.1 + 1 == t.index => span.1 = t.index,
                    _ => self.lost_spans.push((t.index, t.index)),
                }
            }
            TrackingState::NotInitialised => self.not_initialised += 1,
            TrackingState::Ok => {
                self.placed_at_frame.get_or_insert(t.index);
            }
        }
        self.segments.add(t);
        self.tracking_ms_sum += line.tracking_ms;
        self.tracking_ms.push(line.tracking_ms);
        self.extraction_ms.push(line.extraction_ms);
        self.matching_ms.push(t.matching_ms);
        self.optimisation_ms.push(t.optimisation_ms);
        self.dop_ms.push(t.dop_ms);
    }

    /// The run's totals, with the map's sizes, the loops' `merges` and the frames in
    /// the trajectory (`tracked`).
    fn totals(self, map: &Map, merges: &[(usize, usize)], tracked: usize) -> RunTotals {
        let frames = self.frames;
        let (segments, largest_segment_percent) = self.segments.finish(merges, frames);
        let mean_tracking_ms = self.tracking_ms_sum / frames.max(1) as f64;
        RunTotals {
            frames,
            tracked,
            lost: self.lost,
            not_initialised: self.not_initialised,
            coverage_percent: 100.0 * tracked as f64 / frames.max(1) as f64,
            lost_spans: self.lost_spans,
            segments,
            largest_segment_percent,
            keyframes: map.keyframes().len(),
            map_points: map.points().len(),
            median_tracking_ms: self.tracking_ms.median(),
            mean_tracking_ms,
            median_extraction_ms: self.extraction_ms.median(),
            median_matching_ms: self.matching_ms.median(),
            median_optimisation_ms: self.optimisation_ms.median(),
            median_dop_ms: self.dop_ms.median(),
            peak_memory_mib: crate::memory::peak_resident_mib(),
        }
    }
}

/// ATE of `trajectory` against the sequence's ground truth, when it has some.
fn ate(sequence: &dyn Sequence, trajectory: &Trajectory) -> Option<EvalReport> {
    match sequence.ground_truth() {
        Some(gt) if trajectory.len() >= 3 => evaluate(
            gt,
            trajectory,
            &EvalOptions {
                min_coverage: 0.0,
                ..EvalOptions::default()
            },
        )
        .ok(),
        _ => None,
    }
}
