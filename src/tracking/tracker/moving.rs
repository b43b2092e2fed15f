//! The DOP model on the tracker's frames: each tracked frame's moving probabilities
//! (propagation from its map points or the last frame's keypoints, expansion, the
//! followed objects' boxes), the last frame's refresh after a detection, and the
//! keypoint budget that makes up for the keypoints movers take. What takes part in the
//! pose, and the model's state over the run, come from [`crate::dynamics`] with each
//! frame ([`Participation`]).

use super::Tracker;
use crate::dop::DopConfig;
use crate::dynamics::frames::{propagate_and_expand, Participation};
use crate::features::{hamming, TH_LOW};
use crate::frame::Frame;
use crate::geometry::se3::Se3;
use crate::map::{Map, MapPointKey};

impl Tracker {
    /// The keypoint budget for the next frame: `n_features` over the static share
    /// \(\phi\) of the last frame's keypoints (those the DOP model did not remove), so
    /// that movers taking keypoints do not leave the pose fewer static ones
    /// ([`crate::features::orb::OrbExtractor::with_budget`] clamps it).
    pub fn feature_budget(&self, n_features: usize, dop: Option<&DopConfig>) -> usize {
        let (Some(last), Some(dop)) = (&self.last, dop) else {
            return n_features;
        };
        let total = last.frame.moving.len();
        let dynamic = last
            .frame
            .moving
            .iter()
            .filter(|p| dop.removed(**p))
            .count();
        let share = (total - dynamic) as f64 / total.max(1) as f64;
        (n_features as f64 / share.max(0.01)).round() as usize
    }

    /// After detections updated the map: the last frame's keypoints take their map
    /// points' probabilities (the others keep theirs), then expansion runs again, so the
    /// next frame propagates what the detections said.
    pub fn refresh_moving(&mut self, map: &Map, gate: &Participation) {
        let (Some(dop), Some(last)) = (gate.dop, self.last.as_mut()) else {
            return;
        };
        let from_map: Vec<Option<f32>> = last
            .points
            .iter()
            .map(|k| k.and_then(|k| map.points.get(k)).map(|p| p.moving))
            .collect();
        let kept: Vec<Option<f32>> = last
            .frame
            .moving
            .iter()
            .zip(&from_map)
            .map(|(p, m)| (m.is_none() && *p != dop.p_init).then_some(*p))
            .collect();
        let followed = gate.followed.map(|f| (f, &last.camera_from_world));
        last.frame.moving = propagate_and_expand(dop, &last.frame, &from_map, &kept, followed);
    }

    /// The DOP model's probabilities for a tracked frame at `camera_from_world`
    /// (propagation from its map points, else from the last frame's keypoints, else
    /// P_init; then expansion and the followed objects' boxes).
    pub(super) fn moving_probabilities(
        &self,
        dop: &DopConfig,
        followed: Option<&crate::dop::tracks::FollowedObjects>,
        map: &Map,
        frame: &Frame,
        camera_from_world: &Se3,
        points: &[Option<MapPointKey>],
    ) -> Vec<f32> {
        let from_map: Vec<Option<f32>> = points
            .iter()
            .map(|k| k.and_then(|k| map.points.get(k)).map(|p| p.moving))
            .collect();
        let from_last: Vec<Option<f32>> = match (&self.last, dop.propagation) {
            (Some(last), true) => (0..frame.len())
                .map(|i| {
                    if from_map[i].is_some() {
                        return None;
                    }
                    let k = &frame.keypoints[i];
                    let candidates = last.frame.features_in_area(
                        k.x,
                        k.y,
                        20.0,
                        k.level.saturating_sub(1),
                        k.level + 1,
                    );
                    candidates
                        .into_iter()
                        .map(|j| {
                            (
                                hamming(&frame.descriptors[i], &last.frame.descriptors[j]),
                                j,
                            )
                        })
                        .filter(|(d, _)| *d <= TH_LOW)
                        .min()
                        .map(|(_, j)| last.frame.moving[j])
                })
                .collect(),
            _ => vec![None; frame.len()],
        };
        let followed = followed.map(|f| (f, camera_from_world));
        propagate_and_expand(dop, frame, &from_map, &from_last, followed)
    }
}
