//! The ground-truth scorer of a synthetic sequence (its `masks/` and
//! `detections_oracle/`), a [`FrameObserver`]: each tracked frame's keypoints against
//! the mover mask (which were called dynamic, which took part in the pose), and each
//! detected keyframe's dynamic boxes against the people in it. Sequences without masks
//! score nothing.

use std::path::PathBuf;

use super::observers::{FrameObserver, FrameView};
use crate::dynamics::Applied;
use crate::eval::truth::{
    ground_truth_mask, ground_truth_people, Classification, Recall, TruthCounts,
};
use crate::io::IoError;

/// Scores a run against the ground truth of its sequence folder.
#[derive(Default)]
pub struct TruthScorer {
    sequence_dir: Option<PathBuf>,
    /// The last frame's counts, until they go to its report line.
    latest: Option<TruthCounts>,
    /// Moving keypoints called moving, against the truth (DOP and mask boxes).
    pub classification: Option<Classification>,
    /// The detector's recall of people, when the sequence has person masks.
    pub person_recall: Option<Recall>,
}

impl TruthScorer {
    /// A scorer of the sequence at `sequence_dir` (no truth: nothing scored).
    pub fn new(sequence_dir: Option<PathBuf>) -> Self {
        Self {
            sequence_dir,
            ..Self::default()
        }
    }
}

impl FrameObserver for TruthScorer {
    fn on_frame(&mut self, view: &FrameView) -> Result<(), IoError> {
        let dir = self.sequence_dir.as_deref();
        let counts = view.tracked().and_then(|frame| {
            let mask = ground_truth_mask(dir, view.timestamp)?;
            let positions: Vec<(f32, f32)> = frame.keypoints.iter().map(|k| (k.x, k.y)).collect();
            let called: Vec<bool> = match view.dop {
                Some(dop) => frame.moving.iter().map(|p| dop.removed(*p)).collect(),
                None => vec![false; positions.len()],
            };
            let in_pose: Vec<u32> = view
                .record
                .observations
                .iter()
                .map(|o| o.keypoint)
                .collect();
            Some(TruthCounts::new(&mask, &positions, &called, &in_pose))
        });
        if let (Some(counts), Some(_)) = (&counts, view.dop) {
            self.classification
                .get_or_insert_with(Classification::default)
                .add(counts);
        }
        self.latest = counts;
        Ok(())
    }

    fn annotate(&mut self, line: &mut crate::records::FrameLine) {
        line.truth = self.latest.take();
    }

    fn on_applied(&mut self, applied: &[Applied]) {
        let dir = self.sequence_dir.as_deref();
        for done in applied {
            match done {
                Applied::Boxes { timestamp, boxes } => {
                    if let Some((people, image_area)) = ground_truth_people(dir, *timestamp) {
                        self.person_recall
                            .get_or_insert_with(Recall::default)
                            .add(*timestamp, &people, boxes, image_area);
                    }
                }
                Applied::Keypoints {
                    timestamp,
                    positions,
                    in_box,
                } => {
                    if let Some(mask) = ground_truth_mask(dir, *timestamp) {
                        self.classification
                            .get_or_insert_with(Classification::default)
                            .add(&TruthCounts::new(&mask, positions, in_box, &[]));
                    }
                }
                Applied::Detected { .. } => {}
            }
        }
    }
}
