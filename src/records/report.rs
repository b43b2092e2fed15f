//! What `report.json` holds: the run's totals, segments, per-frame lines.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::setup::RunSetup;
use crate::dense::DenseReport;
use crate::dop::Mode;
use crate::dynamics::DetectionTotals;
use crate::eval::report::EvalReport;
use crate::eval::truth::TruthCounts;
use crate::global::GlobalReport;
use crate::mapping::MappingStats;
use crate::tracking::{FrameStats, TrackingState};

/// Totals of a run.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RunTotals {
    /// Frames read.
    pub frames: usize,
    /// Frames tracked.
    pub tracked: usize,
    /// Frames lost.
    pub lost: usize,
    /// Frames before the map started.
    pub not_initialised: usize,
    /// Tracked frames over all frames, in %.
    pub coverage_percent: f64,
    /// Inclusive frame index ranges where tracking was lost.
    pub lost_spans: Vec<(usize, usize)>,
    /// The map segments: tracking that stays lost starts a new one
    /// (`[tracking] new_map_after_seconds`); a loop merges segments in the global pass.
    pub segments: Vec<SegmentSpan>,
    /// Tracked frames in the largest segment after the merges, over all frames, in %:
    /// the part of the run in one frame of reference.
    pub largest_segment_percent: f64,
    /// Keyframes at the end.
    pub keyframes: usize,
    /// Map points at the end.
    pub map_points: usize,
    /// Tracking time per frame (ORB extraction + tracking), as ORB-SLAM2 prints it.
    pub median_tracking_ms: f64,
    /// The mean of the same.
    pub mean_tracking_ms: f64,
    /// Median ORB extraction time.
    pub median_extraction_ms: f64,
    /// Median matching time.
    pub median_matching_ms: f64,
    /// Median pose-optimisation time.
    pub median_optimisation_ms: f64,
    /// The DOP model per frame (propagation and expansion; 0 without it).
    pub median_dop_ms: f64,
    /// The process's peak resident memory so far (MiB, Linux): after tracking and the
    /// global pass; the dense pass reports its own.
    pub peak_memory_mib: Option<f64>,
}

/// A map segment of a run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SegmentSpan {
    /// The segment's number.
    pub segment: usize,
    /// First and last frame tracked in it, and how many were.
    pub first_frame: usize,
    /// The last frame tracked in it.
    pub last_frame: usize,
    /// Frames tracked in it.
    pub tracked_frames: usize,
    /// The segment a loop merged it into (in the global pass), following later merges.
    pub merged_into: Option<usize>,
}

/// The segments the tracked frames were in, gathered frame by frame
/// ([`SegmentSpans::add`]) as the frames' lines are read.
#[derive(Debug, Default)]
pub struct SegmentSpans {
    spans: Vec<SegmentSpan>,
}

impl SegmentSpans {
    /// Adds a frame (only a tracked one counts).
    pub fn add(&mut self, t: &FrameStats) {
        if t.state != TrackingState::Ok {
            return;
        }
        match self.spans.iter_mut().find(|s| s.segment == t.segment) {
            Some(span) => {
                span.last_frame = t.index;
                span.tracked_frames += 1;
            }
            None => self.spans.push(SegmentSpan {
                segment: t.segment,
                first_frame: t.index,
                last_frame: t.index,
                tracked_frames: 1,
                merged_into: None,
            }),
        }
    }

    /// The spans, and the share of all `frames` in the largest after `merges`
    /// (segment, into).
    pub fn finish(self, merges: &[(usize, usize)], frames: usize) -> (Vec<SegmentSpan>, f64) {
        let mut spans = self.spans;
        let root = |s| final_segment(merges, s);
        let mut merged: std::collections::BTreeMap<usize, usize> = Default::default();
        for span in &mut spans {
            let r = root(span.segment);
            span.merged_into = (r != span.segment).then_some(r);
            *merged.entry(r).or_default() += span.tracked_frames;
        }
        let largest = merged.values().max().copied().unwrap_or(0);
        (spans, 100.0 * largest as f64 / frames.max(1) as f64)
    }
}

/// The segment that `segment` ended in after `merges` (segment, into), in order.
pub fn final_segment(merges: &[(usize, usize)], mut segment: usize) -> usize {
    // Each merge moves a segment into another; following them takes at most one step
    // per merge.
    for _ in 0..=merges.len() {
        match merges.iter().find(|(from, _)| *from == segment) {
            Some((_, into)) => segment = *into,
            None => break,
        }
    }
    segment
}

/// One frame's line in the report.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FrameLine {
    #[serde(flatten)]
    /// The tracker's line.
    pub tracking: FrameStats,
    /// ORB extraction, milliseconds.
    pub extraction_ms: f64,
    /// Extraction and tracking, milliseconds.
    pub tracking_ms: f64,
    /// Against the ground-truth masks of a synthetic sequence (absent elsewhere).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub truth: Option<TruthCounts>,
}

/// What `report.json` holds.
#[derive(Debug, Serialize, Deserialize)]
pub struct RunReport {
    /// The layout version ([`super::SCHEMA`]).
    pub schema: u32,
    /// The sequence's name.
    pub sequence: String,
    /// What the run was set up with.
    pub setup: RunSetup,
    /// The sequence folder, when known (for `dopslam fuse`).
    pub sequence_path: Option<PathBuf>,
    /// How moving objects were treated.
    pub mode: Mode,
    /// Frame counts and timings.
    pub totals: RunTotals,
    /// ATE of `trajectory.txt` (after the global pass, when it ran).
    pub ate: Option<EvalReport>,
    /// ATE of `trajectory_tracking.txt` (the tracking pass alone), when the global pass ran.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ate_tracking: Option<EvalReport>,
    /// What local mapping did.
    pub mapping: MappingStats,
    /// What detection did.
    pub detection: DetectionTotals,
    /// The global pass: loops, candidates, full BA.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub global: Option<GlobalReport>,
    /// One line per frame (in a spill file while the run that makes them goes on).
    pub frames: super::FrameLines,
    /// Why the run stopped before the last frame, if it did: the error's sentence.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stopped: Option<String>,
    /// The dense pass, when it ran (written once it has).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dense: Option<DenseReport>,
    /// Where the run's time went, against the recording's duration (written at the
    /// run's end).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub times: Option<RunTimes>,
    /// The map the run loaded (`--map`) and the one it saved.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub slam_map: Option<super::SlamMapReport>,
}

/// The wall time of a run's stages against the recording's duration, and the memory
/// each held at its peak.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct RunTimes {
    /// The recording's duration over the frames read, seconds (`None` when their
    /// timestamps span no time).
    pub recording_s: Option<f64>,
    /// Each stage that ran, in order.
    pub stages: Vec<StageTime>,
    /// The whole run (the stages and what lies between them), seconds.
    pub total_s: f64,
    /// `total_s` over `recording_s`: below 1 the run keeps up with the recording.
    pub real_time_factor: Option<f64>,
    /// The process's peak resident memory over the whole run, MiB (Linux).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub peak_memory_mib: Option<f64>,
}

/// One stage's wall time and peak memory.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StageTime {
    /// `tracking`, `global`, `outputs` or `dense`.
    pub stage: String,
    /// Wall time, seconds.
    pub seconds: f64,
    /// `seconds` over the recording's duration.
    pub real_time_factor: Option<f64>,
    /// The peak resident memory while the stage ran, MiB, sampled every 10 ms (what
    /// the stages before it left resident included; `None` where the system cannot
    /// tell, [`crate::memory::stage_peak_mib`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub peak_memory_mib: Option<f64>,
}

/// A stage as it ended: its name, wall time and peak memory.
#[derive(Debug, Clone, Copy)]
pub struct Lap {
    /// The stage's name.
    pub stage: &'static str,
    /// Its wall time, seconds.
    pub seconds: f64,
    /// Its peak resident memory, MiB.
    pub peak_memory_mib: Option<f64>,
}

impl RunTimes {
    /// The times of the stages' `laps` and of the whole run, `total_s`, against a
    /// recording of `recording_s`; `peak_memory_mib`, the whole run's.
    pub fn new(
        recording_s: Option<f64>,
        laps: &[Lap],
        total_s: f64,
        peak_memory_mib: Option<f64>,
    ) -> Self {
        let factor = |seconds: f64| recording_s.map(|r| seconds / r);
        Self {
            recording_s,
            stages: laps
                .iter()
                .map(|lap| StageTime {
                    stage: lap.stage.into(),
                    seconds: lap.seconds,
                    real_time_factor: factor(lap.seconds),
                    peak_memory_mib: lap.peak_memory_mib,
                })
                .collect(),
            total_s,
            real_time_factor: factor(total_s),
            peak_memory_mib,
        }
    }

    /// Lines for the console: each stage's seconds and the run's factor, and each
    /// stage's peak memory where it is known.
    pub fn summary(&self) -> String {
        let stages: Vec<String> = self
            .stages
            .iter()
            .map(|s| format!("{} {:.1} s", s.stage, s.seconds))
            .collect();
        let factor = match (self.real_time_factor, self.recording_s) {
            (Some(f), Some(r)) => format!(": {f:.2} x the recording's {r:.1} s"),
            _ => String::new(),
        };
        let mut summary = format!(
            "wall time: {}; the run {:.1} s{factor}",
            stages.join(", "),
            self.total_s
        );
        let peaks: Vec<String> = self
            .stages
            .iter()
            .filter_map(|s| Some(format!("{} {:.0}", s.stage, s.peak_memory_mib?)))
            .collect();
        if let Some(run) = self.peak_memory_mib.filter(|_| !peaks.is_empty()) {
            summary += &format!(
                "\npeak memory (MiB): {}; the run {run:.0}",
                peaks.join(", ")
            );
        }
        summary
    }
}

impl RunReport {
    /// The fingerprint of the sequence's first frame (`dopslam fuse` checks that it
    /// fuses the sequence the run tracked).
    pub fn first_frame_hash(&self) -> Option<&str> {
        self.setup.first_frame_hash.as_deref()
    }

    /// The rig's disparity offset in the run's disparities, pixels: what tracking added
    /// to its matches and what the global pass took out after it (0 when neither).
    pub fn disparity_offset_px(&self) -> f64 {
        let tracking = self.setup.disparity_offset.as_ref().map(|o| o.offset_px);
        let global = self
            .global
            .as_ref()
            .and_then(|g| g.disparity_offset.as_ref());
        tracking.unwrap_or(0.0) + global.map_or(0.0, |o| o.offset_px)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn run_times_give_each_stage_and_the_run_against_the_recording() {
        let lap = |stage, seconds, peak_memory_mib| Lap {
            stage,
            seconds,
            peak_memory_mib,
        };
        let laps = [
            lap("tracking", 45.0, Some(900.4)),
            lap("dense", 15.0, Some(1500.0)),
        ];
        let times = RunTimes::new(Some(30.0), &laps, 63.0, Some(1500.0));
        let factors: Vec<Option<f64>> = times.stages.iter().map(|s| s.real_time_factor).collect();
        assert_eq!(factors, vec![Some(1.5), Some(0.5)]);
        assert_eq!(times.real_time_factor, Some(2.1));
        assert_eq!(
            times.summary(),
            "wall time: tracking 45.0 s, dense 15.0 s; the run 63.0 s: 2.10 x the recording's 30.0 s\n\
             peak memory (MiB): tracking 900, dense 1500; the run 1500"
        );
        let unknown = RunTimes::new(None, &[lap("tracking", 1.0, None)], 1.0, Some(80.0));
        assert_eq!(unknown.real_time_factor, None);
        assert_eq!(
            unknown.summary(),
            "wall time: tracking 1.0 s; the run 1.0 s"
        );
    }
}
