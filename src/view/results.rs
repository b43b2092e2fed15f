//! A finished run folder, logged: what the run left (the final trajectory, the ground
//! truth aligned to it, the loops, the dense mesh and cloud; [`log_results`]) and,
//! for `dopslam view`, the tracking pass replayed from the files it wrote
//! ([`replay_frames`]): poses, keyframes, events, the removed keypoints, the detector's
//! boxes, and the images when the sequence is at hand.

use std::collections::BTreeMap;

use nalgebra::Vector3;

use super::entry::{centres, At, Entry, Level};
use super::log::LogHandle;
use super::ViewError;
use crate::detect::{cache_file, read_cache_file};
use crate::eval::associate::{associate, AssociationRule};
use crate::geometry::alignment::{umeyama, AlignmentKind};
use crate::geometry::se3::Se3;
use crate::io::run_dir::RunDir;
use crate::io::sequence::{FrameImages, Sequence};
use crate::io::trajectory::Trajectory;
use crate::records::{FrameLines, RunReport};
use crate::tracking::FrameStats;

/// The tracking pass's trajectory is drawn again every this many frames.
pub const TRAJECTORY_EVERY: usize = 10;

/// Camera centres in one piece of the tracking path
/// (`world/trajectory/tracking/<piece>`, [`PathPieces`]).
pub const PATH_PIECE: usize = 300;

/// The tracking path as the recording draws it: in pieces of [`PATH_PIECE`] centres,
/// the growing one drawn again every [`TRAJECTORY_EVERY`] frames and a full one left
/// as it was last drawn, so that the memory and the recording grow with the frames,
/// not with their square.
#[derive(Debug, Default)]
pub struct PathPieces {
    piece: usize,
    centres: Vec<Vector3<f64>>,
}

impl PathPieces {
    /// Adds a camera centre; when the piece is full, the entry that draws it whole,
    /// before the next piece starts where it ended (so the pieces join).
    pub fn push(&mut self, centre: Vector3<f64>) -> Option<Entry> {
        let full = (self.centres.len() > PATH_PIECE).then(|| {
            let drawn = self.entry();
            let last = *self.centres.last().expect("a full piece");
            self.centres.clear();
            self.centres.push(last);
            self.piece += 1;
            drawn
        });
        self.centres.push(centre);
        full
    }

    /// The entry that draws the growing piece.
    pub fn entry(&self) -> Entry {
        Entry::Trajectory {
            name: "tracking",
            piece: Some(self.piece),
            centres: self.centres.clone(),
        }
    }
}

/// What happened at one frame, for the events: its state, whether it made a keyframe,
/// why it was lost.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameFacts<'a> {
    /// The frame's index.
    pub index: usize,
    /// `ok`, `lost`, `not_initialised`.
    pub state: &'a str,
    /// Whether it became a keyframe.
    pub keyframe: bool,
    /// Why it was lost, if it was.
    pub lost: Option<String>,
}

/// The events of a frame after one in state `previous`: keyframe inserted, tracking
/// lost (with why), relocalised.
pub fn frame_events(previous: Option<&str>, facts: &FrameFacts<'_>) -> Vec<(Level, String)> {
    let mut events = Vec::new();
    match (previous, facts.state) {
        (Some("ok"), "lost") => {
            let why = facts.lost.as_deref().unwrap_or("no reason given");
            events.push((Level::Warning, format!("tracking lost ({why})")));
        }
        (Some("lost"), "ok") => events.push((Level::Info, "relocalised".to_string())),
        (Some("not_initialised") | None, "ok") => {
            events.push((Level::Info, "tracking started".to_string()))
        }
        _ => {}
    }
    if facts.keyframe {
        events.push((Level::Info, "keyframe inserted".to_string()));
    }
    events
}

/// The events of frame `index` as one entry (one text per frame and entity: a second
/// one at the same time would hide the first), a warning when one of them is.
pub fn events_entry(index: usize, events: Vec<(Level, String)>) -> Option<Entry> {
    if events.is_empty() {
        return None;
    }
    let level = if events.iter().any(|(l, _)| *l == Level::Warning) {
        Level::Warning
    } else {
        Level::Info
    };
    let texts: Vec<String> = events.into_iter().map(|(_, t)| t).collect();
    Some(Entry::Event {
        level,
        text: format!("frame {index}: {}", texts.join("; ")),
        about_loops: false,
    })
}

/// Logs what the run folder holds after the run (under `prefix`): the final
/// trajectory, `truth` aligned to it (SE(3), as `dopslam eval`), the loops (of the run
/// itself: a baseline's, under a prefix, are left out) and the dense map. Each part that is absent is left out; a file that cannot be read is an
/// error naming it.
pub fn log_results(
    log: &LogHandle,
    run: &RunDir,
    prefix: &str,
    truth: Option<&Trajectory>,
) -> Result<(), ViewError> {
    let final_path = run.trajectory();
    let estimate = if final_path.exists() {
        Some(Trajectory::read_tum(&final_path)?)
    } else {
        None
    };
    if let Some(estimate) = &estimate {
        log.log(
            prefix.to_string(),
            At::Always,
            Entry::Trajectory {
                name: "final",
                piece: None,
                centres: centres(&estimate.poses),
            },
        );
        if let Some(aligned) = truth.and_then(|t| aligned_truth(t, estimate)) {
            log.log(
                prefix.to_string(),
                At::Always,
                Entry::Trajectory {
                    name: "truth",
                    piece: None,
                    centres: aligned,
                },
            );
        }
    }
    // The loops of the run itself (a baseline's would fill the run's events).
    if run.report().exists() && prefix.is_empty() {
        let report = crate::records::read_report(run)?;
        log_loops(log, &report, estimate.as_ref());
    }
    log_dense(log, run, prefix)
}

/// The ground-truth centres moved into the estimate's world (SE(3) Umeyama over the
/// poses paired by time, TUM's 20 ms); `None` when fewer than three pair.
fn aligned_truth(truth: &Trajectory, estimate: &Trajectory) -> Option<Vec<Vector3<f64>>> {
    let pairs = associate(truth, estimate, AssociationRule::TumGreedy, 0.02, 0.0).pairs;
    if pairs.len() < 3 {
        return None;
    }
    let source: Vec<Vector3<f64>> = pairs
        .iter()
        .map(|&(t, _)| truth.poses[t].translation.vector)
        .collect();
    let target: Vec<Vector3<f64>> = pairs
        .iter()
        .map(|&(_, e)| estimate.poses[e].translation.vector)
        .collect();
    let estimate_from_truth = umeyama(&source, &target, AlignmentKind::Se3).ok()?;
    Some(
        truth
            .poses
            .iter()
            .map(|p| estimate_from_truth.transform_point(&p.translation.vector))
            .collect(),
    )
}

/// The loops: an event at each candidate's keyframe (detected, with the outcome of
/// its checks) and at each closed loop's, joined per frame; and the edges between the
/// two keyframes' final centres of the closed ones.
fn log_loops(log: &LogHandle, report: &RunReport, estimate: Option<&Trajectory>) {
    let Some(global) = &report.global else {
        return;
    };
    let frames = frame_times(&report.frames);
    let mut texts: BTreeMap<usize, (f64, Vec<String>)> = BTreeMap::new();
    let mut say = |at: f64, text: String| {
        let index = nearest_frame(&frames, at);
        texts.entry(index).or_insert((at, Vec::new())).1.push(text);
    };
    for candidate in &global.candidates {
        let (at, matched) = (candidate.pair.keyframe_time, candidate.pair.matched_time);
        let frame = nearest_frame(&frames, matched);
        say(
            at,
            format!(
                "loop candidate with the keyframe of frame {frame}: {}",
                candidate.outcome
            ),
        );
    }
    let mut edges = Vec::new();
    for found in &global.loops {
        let (at, matched) = (found.pair.keyframe_time, found.pair.matched_time);
        let correction = found.correction_m;
        let frame = nearest_frame(&frames, matched);
        say(
            at,
            format!(
                "loop closed with the keyframe of frame {frame} (keyframe moved {correction:.3} m)"
            ),
        );
        if let Some(estimate) = estimate {
            if let (Some(a), Some(b)) = (centre_at(estimate, at), centre_at(estimate, matched)) {
                edges.push((a, b));
            }
        }
    }
    for (index, (seconds, lines)) in texts {
        let entry = Entry::Event {
            level: Level::Info,
            text: format!("frame {index}: {}", lines.join("; ")),
            about_loops: true,
        };
        log.log("", At::Frame { index, seconds }, entry);
    }
    if !edges.is_empty() {
        log.log("", At::Always, Entry::LoopEdges(edges));
    }
}

/// Each report frame's index and time.
fn frame_times(frames: &FrameLines) -> Vec<(usize, f64)> {
    frames
        .iter()
        .map_while(Result::ok)
        .map(|f| (f.tracking.index, f.tracking.timestamp))
        .collect()
}

/// The index of the frame (index, time) nearest `seconds` (0 without frames).
fn nearest_frame(frames: &[(usize, f64)], seconds: f64) -> usize {
    frames
        .iter()
        .min_by(|a, b| (a.1 - seconds).abs().total_cmp(&(b.1 - seconds).abs()))
        .map_or(0, |f| f.0)
}

/// The centre of the pose nearest `seconds` (within 20 ms).
fn centre_at(trajectory: &Trajectory, seconds: f64) -> Option<Vector3<f64>> {
    let (i, t) = trajectory
        .timestamps
        .iter()
        .enumerate()
        .min_by(|a, b| (a.1 - seconds).abs().total_cmp(&(b.1 - seconds).abs()))?;
    ((t - seconds).abs() <= 0.02).then(|| trajectory.poses[i].translation.vector)
}

/// The dense mesh and cloud, decimated to `rerun_max_points` (every n-th triangle or
/// point).
pub fn log_dense(log: &LogHandle, run: &RunDir, prefix: &str) -> Result<(), ViewError> {
    let limit = log.config.rerun_max_points;
    let mesh_path = run.file(crate::io::run_dir::names::DENSE_MESH_PLY);
    if mesh_path.exists() {
        let mesh = crate::io::ply::read_ply(&mesh_path)?;
        let step = mesh.triangles.len().div_ceil(limit).max(1);
        let kept: Vec<[u32; 3]> = mesh.triangles.iter().step_by(step).copied().collect();
        log.log(prefix.to_string(), At::Always, compact_mesh(&mesh, kept));
    }
    let cloud_path = run.file(crate::io::run_dir::names::DENSE_POINTS);
    if cloud_path.exists() {
        let cloud = crate::io::ply::read_ply(&cloud_path)?;
        let step = cloud.vertices.len().div_ceil(limit).max(1);
        let colours = if cloud.colours.len() == cloud.vertices.len() {
            cloud.colours.iter().step_by(step).copied().collect()
        } else {
            Vec::new()
        };
        log.log(
            prefix.to_string(),
            At::Always,
            Entry::Cloud {
                points: cloud.vertices.iter().step_by(step).copied().collect(),
                colours,
            },
        );
    }
    Ok(())
}

/// The mesh of `triangles` (of `mesh`) with only the vertices they use, renumbered.
fn compact_mesh(mesh: &crate::geometry::mesh::Mesh, triangles: Vec<[u32; 3]>) -> Entry {
    let mut new_index = vec![u32::MAX; mesh.vertices.len()];
    let (mut vertices, mut colours) = (Vec::new(), Vec::new());
    let coloured = mesh.colours.len() == mesh.vertices.len();
    let triangles = triangles
        .into_iter()
        .map(|t| {
            t.map(|v| {
                let slot = &mut new_index[v as usize];
                if *slot == u32::MAX {
                    *slot = vertices.len() as u32;
                    vertices.push(mesh.vertices[v as usize]);
                    if coloured {
                        colours.push(mesh.colours[v as usize]);
                    }
                }
                *slot
            })
        })
        .collect();
    Entry::Mesh {
        vertices,
        triangles,
        colours,
    }
}

/// What the replay logged.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Replayed {
    /// Frames replayed.
    pub frames: usize,
    /// Poses logged.
    pub poses: usize,
    /// Images logged.
    pub images: usize,
    /// Keyframes whose boxes were logged.
    pub keyframe_boxes: usize,
}

/// The tracking pass replayed from the run folder: each frame of `report.json` at its
/// index and time, with the pose of `trajectory_tracking.txt`, its events, the removed
/// keypoints (`dynamic_keypoints.json`), the boxes of the detection cache at their
/// keyframe, and the image when `sequence` is given.
pub fn replay_frames(
    log: &LogHandle,
    run: &RunDir,
    report: &RunReport,
    sequence: Option<&dyn Sequence>,
) -> Result<Replayed, ViewError> {
    let tracking_path = run.tracking_trajectory();
    let tracking = if tracking_path.exists() {
        Trajectory::read_tum(&tracking_path)?
    } else {
        Trajectory::read_tum(&run.trajectory())?
    };
    let pose_at: BTreeMap<u64, usize> = tracking
        .timestamps
        .iter()
        .enumerate()
        .map(|(i, t)| (time_key(*t), i))
        .collect();
    let removed = read_removed(run)?;
    let mut replay = Replay {
        log,
        replayed: Replayed::default(),
        previous: None,
        path: PathPieces::default(),
        keyframes: Vec::new(),
    };
    let lines = report.frames.to_vec()?;
    let last = lines.last().map(|f| f.tracking.index);
    for frame in lines.iter().map(|f| &f.tracking) {
        let at = At::Frame {
            index: frame.index,
            seconds: frame.timestamp,
        };
        let pose = pose_at
            .get(&time_key(frame.timestamp))
            .map(|&i| tracking.poses[i]);
        replay.pose_and_events(frame, at, pose, Some(frame.index) == last);
        if let Some(points) = removed.get(&time_key(frame.timestamp)) {
            let entry = Entry::Keypoints {
                kept: Vec::new(),
                removed: points.clone(),
            };
            log.log("", at, entry);
        }
        if frame.keyframe {
            replay.replayed.keyframe_boxes += log_cached_boxes(log, run, frame, at)?;
        }
        if let Some(sequence) = sequence {
            replay.replayed.images += log_image(log, sequence, frame.index, at)?;
        }
    }
    Ok(replay.replayed)
}

/// The state of a replay: the path and keyframes so far, the last frame's state.
struct Replay<'a> {
    log: &'a LogHandle,
    replayed: Replayed,
    previous: Option<String>,
    path: PathPieces,
    keyframes: Vec<Vector3<f64>>,
}

impl Replay<'_> {
    /// A frame's pose (when tracked), keyframes, trajectory so far (every
    /// [`TRAJECTORY_EVERY`] frames and at the `last`) and events.
    fn pose_and_events(&mut self, frame: &FrameStats, at: At, pose: Option<Se3>, last: bool) {
        let log = self.log;
        self.replayed.frames += 1;
        if let Some(pose) = pose {
            log.log(
                "",
                at,
                Entry::Camera {
                    world_from_camera: pose,
                },
            );
            self.replayed.poses += 1;
            if let Some(full) = self.path.push(pose.translation.vector) {
                log.log("", at, full);
            }
            if frame.keyframe {
                self.keyframes.push(pose.translation.vector);
                log.log("", at, Entry::Keyframes(self.keyframes.clone()));
            }
        }
        if frame.index.is_multiple_of(TRAJECTORY_EVERY) || last {
            log.log("", at, self.path.entry());
        }
        let facts = FrameFacts {
            index: frame.index,
            state: frame.state.as_str(),
            keyframe: frame.keyframe,
            lost: frame.lost.map(|reject| {
                let value = serde_json::to_value(reject).unwrap_or_default();
                let reason = value.get("reason").and_then(|r| r.as_str());
                reason.unwrap_or("?").to_string()
            }),
        };
        if let Some(entry) =
            events_entry(frame.index, frame_events(self.previous.as_deref(), &facts))
        {
            log.log("", at, entry);
        }
        self.previous = Some(frame.state.as_str().to_string());
    }
}

/// A timestamp as a map key (microseconds, as the files write them).
fn time_key(seconds: f64) -> u64 {
    (seconds * 1e6).round().max(0.0) as u64
}

/// The removed keypoints of each frame, by time (empty without the file), read as the
/// dense pass reads them.
fn read_removed(run: &RunDir) -> Result<BTreeMap<u64, Vec<[f32; 2]>>, ViewError> {
    let frames = crate::dense::inputs::read_keypoints(&run.dynamic_keypoints())?;
    Ok(frames
        .into_iter()
        .map(|f| {
            (
                time_key(f.timestamp),
                f.points.iter().map(|p| [p[0], p[1]]).collect(),
            )
        })
        .collect())
}

/// The cached boxes of the keyframe `frame`, when the cache has its file: 1 if logged.
fn log_cached_boxes(
    log: &LogHandle,
    run: &RunDir,
    frame: &FrameStats,
    at: At,
) -> Result<usize, ViewError> {
    let file = cache_file(&run.detections(), frame.timestamp);
    if !file.exists() {
        return Ok(0);
    }
    let cached = read_cache_file(&file)?;
    let boxes = cached
        .detections
        .into_iter()
        .map(|d| (frame.index, d))
        .collect();
    log.log("", at, Entry::Boxes(boxes));
    Ok(1)
}

/// The colour (or left) image of frame `index`: 1 if logged.
fn log_image(
    log: &LogHandle,
    sequence: &dyn Sequence,
    index: usize,
    at: At,
) -> Result<usize, ViewError> {
    if index >= sequence.len() {
        return Ok(0);
    }
    let loaded = sequence
        .load(index)
        .map_err(|source| ViewError::Frame { index, source })?;
    let rgb = match loaded.images {
        FrameImages::Rgbd { rgb, .. } => rgb,
        FrameImages::Stereo { left, .. } => image::DynamicImage::ImageLuma8(left).to_rgb8(),
    };
    log.log("", at, Entry::Image(rgb));
    Ok(1)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn facts(index: usize, state: &str, keyframe: bool) -> FrameFacts<'_> {
        FrameFacts {
            index,
            state,
            keyframe,
            lost: Some("few_inliers".into()),
        }
    }

    #[test]
    fn the_path_comes_in_joined_pieces_each_drawn_whole_before_the_next() {
        let mut path = PathPieces::default();
        let mut full = Vec::new();
        for i in 0..2 * PATH_PIECE + 10 {
            full.extend(path.push(Vector3::new(i as f64, 0.0, 0.0)));
        }
        let pieces: Vec<(usize, Vec<Vector3<f64>>)> = full
            .into_iter()
            .chain([path.entry()])
            .map(|e| match e {
                Entry::Trajectory {
                    piece: Some(p),
                    centres,
                    ..
                } => (p, centres),
                other => panic!("{other:?}"),
            })
            .collect();
        assert_eq!(pieces.iter().map(|p| p.0).collect::<Vec<_>>(), [0, 1, 2]);
        assert!(pieces.iter().all(|p| p.1.len() <= PATH_PIECE + 1));
        // Each piece starts where the one before ended, and every centre is drawn.
        for pair in pieces.windows(2) {
            assert_eq!(pair[1].1[0], *pair[0].1.last().unwrap());
        }
        let drawn: usize = pieces.iter().map(|p| p.1.len()).sum::<usize>() - 2;
        assert_eq!(drawn, 2 * PATH_PIECE + 10);
    }

    #[test]
    fn events_follow_state_changes() {
        assert_eq!(frame_events(None, &facts(0, "ok", true)).len(), 2);
        assert!(frame_events(Some("ok"), &facts(5, "ok", false)).is_empty());
        let lost = frame_events(Some("ok"), &facts(6, "lost", false));
        assert_eq!(lost[0].0, Level::Warning);
        assert!(lost[0].1.contains("few_inliers"), "{:?}", lost);
        assert!(frame_events(Some("lost"), &facts(9, "ok", false))[0]
            .1
            .contains("relocalised"));
        assert!(frame_events(Some("lost"), &facts(9, "lost", false)).is_empty());
    }

    #[test]
    fn a_decimated_mesh_keeps_only_its_vertices() {
        let mesh = crate::geometry::mesh::Mesh {
            vertices: vec![
                [0.0; 3],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [5.0; 3],
                [0.0, 0.0, 1.0],
            ],
            colours: vec![[1, 1, 1], [2, 2, 2], [3, 3, 3], [4, 4, 4], [5, 5, 5]],
            normals: Vec::new(),
            triangles: vec![[0, 1, 2], [3, 3, 3], [4, 2, 1]],
        };
        let Entry::Mesh {
            vertices,
            triangles,
            colours,
        } = compact_mesh(&mesh, vec![mesh.triangles[2]])
        else {
            unreachable!()
        };
        assert_eq!(triangles, vec![[0, 1, 2]]);
        assert_eq!(
            vertices,
            vec![[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]
        );
        assert_eq!(colours, vec![[5, 5, 5], [3, 3, 3], [2, 2, 2]]);
    }

    #[test]
    fn nearest_frame_by_time() {
        let frames = [(0, 1.0), (1, 1.1), (2, 1.2)];
        assert_eq!(nearest_frame(&frames, 1.14), 1);
        assert_eq!(nearest_frame(&frames, 9.0), 2);
        assert_eq!(nearest_frame(&[], 9.0), 0);
    }
}
