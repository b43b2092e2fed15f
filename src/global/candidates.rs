//! Loop candidates and what became of them ([`LoopOutcome`]): written by place
//! recognition (stage 2) and loop closing (stages 3 and 4), reported in `report.json`.

use serde::{Deserialize, Serialize};

use crate::map::{KeyFrameKey, Map};

/// The keyframe that looks for a loop and the one it matched: ids (insertion numbers)
/// and timestamps.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub struct LoopPair {
    /// The keyframe's id.
    pub keyframe: usize,
    /// The matched keyframe's id.
    pub matched: usize,
    /// The keyframe's time, seconds.
    pub keyframe_time: f64,
    /// The matched keyframe's time, seconds.
    pub matched_time: f64,
}

/// The keyframe that looks for a loop and the keyframe it matched, as map keys.
#[derive(Debug, Clone, Copy)]
pub struct LoopKeys {
    /// The keyframe that looks for a loop.
    pub keyframe: KeyFrameKey,
    /// The keyframe it matched.
    pub matched: KeyFrameKey,
}

impl LoopPair {
    pub(super) fn of(map: &Map, keys: LoopKeys) -> Self {
        let (a, b) = (
            &map.keyframes()[keys.keyframe],
            &map.keyframes()[keys.matched],
        );
        Self {
            keyframe: a.id,
            matched: b.id,
            keyframe_time: a.frame.timestamp,
            matched_time: b.frame.timestamp,
        }
    }
}

/// A candidate and what became of it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Candidate {
    #[serde(flatten)]
    /// The two keyframes.
    pub pair: LoopPair,
    /// The place-recognition score of the match.
    pub score: f64,
    /// Whether the loop was closed.
    pub accepted: bool,
    /// Why it was accepted or where it stopped, as a sentence ([`LoopOutcome`]'s).
    pub outcome: String,
}

impl Candidate {
    /// The candidate `pair` at `score` and what became of it.
    pub fn new(pair: LoopPair, score: f64, outcome: LoopOutcome) -> Self {
        Self {
            pair,
            score,
            accepted: matches!(outcome, LoopOutcome::Accepted { .. }),
            outcome: outcome.to_string(),
        }
    }
}

/// What became of a loop candidate: accepted, or the stage that rejected it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LoopOutcome {
    /// The loop was closed.
    Accepted {
        /// Inliers of the rigid motion.
        inliers: usize,
        /// Matches after the guided search.
        guided_matches: usize,
    },
    /// Where it stopped.
    Rejected(LoopReject),
}

/// Where a loop candidate stopped, in the order of the stages.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LoopReject {
    /// Stage 2: its group overlapped the groups of too few consecutive keyframes.
    Inconsistent {
        /// Keyframes in a row that overlapped.
        count: usize,
        /// Keyframes needed.
        needed: usize,
    },
    /// Its keyframe came too soon after the last loop closed.
    TooSoon {
        /// Keyframes to wait after a loop.
        gap: usize,
    },
    /// Stage 3: too few vocabulary matches with static points.
    FewMatches {
        /// How many there were.
        found: usize,
        /// How many are needed.
        needed: usize,
    },
    /// Stage 3: RANSAC found no rigid motion.
    NoRigidMotion,
    /// Stage 3: the rigid motion has too few inliers.
    FewInliers {
        /// How many there were.
        found: usize,
        /// How many are needed.
        needed: usize,
    },
    /// Stage 3: too few matches after the guided search.
    FewGuidedMatches {
        /// Inliers of the rigid motion.
        inliers: usize,
        /// Matches after the guided search.
        found: usize,
        /// Matches needed.
        needed: usize,
    },
    /// Stage 3: the next keyframes that found the place verified loops of their own,
    /// and each places the keyframe elsewhere ([`super::loop_confirmation`]).
    Contradicted {
        /// Later loops verified.
        checked: usize,
        /// The closest of their placements: centimetres apart.
        cm: u32,
        /// And tenths of a degree.
        decidegrees: u32,
    },
}

impl std::fmt::Display for LoopOutcome {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            LoopOutcome::Accepted {
                inliers,
                guided_matches,
            } => write!(
                f,
                "accepted: {inliers} inliers, {guided_matches} matches after guided search"
            ),
            LoopOutcome::Rejected(reject) => reject.fmt(f),
        }
    }
}

impl std::fmt::Display for LoopReject {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            LoopReject::Inconsistent { count, needed } => {
                write!(
                    f,
                    "seen by {count} consecutive keyframes of {needed} needed"
                )
            }
            LoopReject::TooSoon { gap } => write!(f, "within {gap} keyframes of the last loop"),
            LoopReject::FewMatches { found, needed } => {
                write!(
                    f,
                    "{found} vocabulary matches with static points, {needed} needed"
                )
            }
            LoopReject::NoRigidMotion => write!(f, "no rigid motion fits the 3-D matches"),
            LoopReject::FewInliers { found, needed } => {
                write!(f, "{found} RANSAC inliers, {needed} needed")
            }
            LoopReject::FewGuidedMatches {
                inliers,
                found,
                needed,
            } => write!(
                f,
                "{inliers} inliers, but {found} matches after guided search, {needed} needed"
            ),
            LoopReject::Contradicted {
                checked,
                cm,
                decidegrees,
            } => write!(
                f,
                "contradicted: the loops of the next {checked} keyframes place it {:.2} m / {:.1} deg away or more",
                cm as f64 / 100.0,
                decidegrees as f64 / 10.0
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{LoopOutcome, LoopReject};

    #[test]
    fn outcomes_read_as_the_report_writes_them() {
        let rejected = LoopOutcome::Rejected(LoopReject::FewGuidedMatches {
            inliers: 31,
            found: 12,
            needed: 40,
        });
        assert_eq!(
            rejected.to_string(),
            "31 inliers, but 12 matches after guided search, 40 needed"
        );
        let accepted = LoopOutcome::Accepted {
            inliers: 31,
            guided_matches: 80,
        };
        assert_eq!(
            serde_json::to_value(super::Candidate::new(
                super::LoopPair {
                    keyframe: 9,
                    matched: 1,
                    keyframe_time: 2.0,
                    matched_time: 0.5
                },
                0.2,
                accepted
            ))
            .unwrap()["outcome"],
            "accepted: 31 inliers, 80 matches after guided search"
        );
    }
}
