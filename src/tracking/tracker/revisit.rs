//! Revisits: a frame tracked mostly on points an earlier visit made (ORB-SLAM2 tracks
//! a place it maps again in the map it has). On a revisit the keyframe decision weighs
//! the frame against the old keyframe that shares most of its matches, and the next
//! frame's local map reaches further ([`super::projection::local_keyframes`]).
//! `docs/design.md`, "Revisits tracked in the earlier visit's map".

use crate::map::{KeyFrameKey, KeyMap, Map, MapPointKey};
use crate::tracking::params::{REVISIT_KEYFRAMES, REVISIT_MIN_OBSERVATIONS};

/// Whether keyframe `id` is old: more than [`REVISIT_KEYFRAMES`] older than `newest`,
/// the newest keyframe the tracker made (every keyframe is, when it made none: a map
/// loaded to track in).
fn is_old(id: usize, newest: Option<usize>) -> bool {
    newest.is_none_or(|newest| id + REVISIT_KEYFRAMES < newest)
}

/// Whether a frame tracked with `matches` is on a revisit: more than half of its
/// matched points were made by old keyframes ([`is_old`]).
pub(super) fn is_revisit(
    map: &Map,
    newest: Option<usize>,
    matches: &[Option<MapPointKey>],
) -> bool {
    let (mut matched, mut old) = (0, 0);
    for point in matches
        .iter()
        .flatten()
        .filter_map(|k| map.points().get(*k))
    {
        matched += 1;
        old += usize::from(is_old(point.first_keyframe_id, newest));
    }
    old * 2 > matched
}

/// On a revisit, the points the keyframe decision weighs the frame against: those of
/// the old keyframe that shares most of the frame's matches `points` (ORB-SLAM2's
/// reference keyframe, `pKFmax`; ties to the newer), seen by at least
/// [`REVISIT_MIN_OBSERVATIONS`] keyframes (ORB-SLAM2's `nMinObs`); `None` when no old
/// keyframe shares a match.
pub(super) fn revisited_points(
    map: &Map,
    newest: Option<usize>,
    points: &[Option<MapPointKey>],
) -> Option<Vec<Option<MapPointKey>>> {
    let mut votes: KeyMap<KeyFrameKey, usize> = KeyMap::default();
    for point in points.iter().flatten().filter_map(|k| map.points().get(*k)) {
        for (kf, _) in &point.observations {
            if map
                .keyframes()
                .get(*kf)
                .is_some_and(|kf| is_old(kf.id, newest))
            {
                *votes.entry(*kf).or_default() += 1;
            }
        }
    }
    let id = |k: KeyFrameKey| map.keyframes()[k].id;
    let (best, _) = votes
        .into_iter()
        .max_by(|a, b| a.1.cmp(&b.1).then(id(a.0).cmp(&id(b.0))))?;
    let seen_enough = |k: &MapPointKey| {
        map.points()
            .get(*k)
            .is_some_and(|p| p.observations.len() >= REVISIT_MIN_OBSERVATIONS)
    };
    let kept = map.keyframes()[best].map_points.iter();
    Some(kept.map(|p| p.filter(seen_enough)).collect())
}
