//! Relocalisation after a loss (ORB-SLAM §V-A): keyframes ranked by how many of a
//! sample of the frame's descriptors match their points; for the best few, brute-force
//! matches, EPnP in RANSAC, pose-only optimisation, and when that leaves fewer than
//! [`RELOCALISATION_ACCEPT`] inliers a projection search of the keyframe's points for
//! more. Any segment's keyframes are searched: the camera may come back to an older
//! segment, which becomes the active one again.

use std::time::Instant;

use super::search::live_points;
use super::{Timing, TrackInput, Tracker};
use crate::features::{hamming, TH_LOW};
use crate::frame::matching::{brute_force, search_by_projection};
use crate::frame::Frame;
use crate::map::{KeyFrameKey, Map};
use crate::optim::pnp::{epnp_ransac, Correspondence, Ransac};
use crate::optim::robust::CHI2_MONO;
use crate::tracking::params::*;
use crate::tracking::report::{PoseEstimate, Reject};

impl Tracker {
    /// Relocalises `frame` against the best-ranked keyframes; the one that accepts it
    /// becomes the reference (and its segment the active one).
    pub(super) fn relocalise(
        &mut self,
        input: TrackInput,
        timing: &mut Timing,
    ) -> Result<PoseEstimate, Reject> {
        let TrackInput { map, frame, .. } = input;
        let start = Instant::now();
        let ranked = rank_keyframes(map, frame);
        timing.matching += start.elapsed().as_secs_f64() * 1e3;
        for key in ranked.into_iter().take(RELOCALISATION_CANDIDATES) {
            if let Some(found) = self.relocalise_against(input, key, timing) {
                self.segment = map.keyframes()[key].segment;
                self.reference = Some(key);
                return Ok(found);
            }
        }
        Err(Reject::NotRelocalised)
    }

    /// EPnP RANSAC against one keyframe, optimised, with a projection search for more
    /// matches when the inliers fall short.
    fn relocalise_against(
        &self,
        input: TrackInput,
        key: KeyFrameKey,
        timing: &mut Timing,
    ) -> Option<PoseEstimate> {
        let TrackInput { map, frame, .. } = input;
        let start = Instant::now();
        let kf = &map.keyframes()[key];
        let (keys, descriptors) = live_points(map, kf);
        let matches = brute_force(frame, &descriptors, RELOCALISATION_MATCH_RATIO);
        timing.matching += start.elapsed().as_secs_f64() * 1e3;
        if matches.len() < MIN_BRUTE_FORCE_MATCHES {
            return None;
        }
        let start = Instant::now();
        let fx2 = self.camera.fx * self.camera.fx;
        let correspondences: Vec<Correspondence> = matches
            .iter()
            .map(|&(q, i)| {
                let k = &frame.keypoints[i];
                Correspondence {
                    world: map.points()[keys[q]].position,
                    normalised: nalgebra::Vector2::new(
                        (k.x as f64 - self.camera.cx) / self.camera.fx,
                        (k.y as f64 - self.camera.cy) / self.camera.fy,
                    ),
                }
            })
            .collect();
        let thresholds: Vec<f64> = matches
            .iter()
            .map(|&(_, i)| CHI2_MONO * self.pyramid.sigma2[frame.keypoints[i].level as usize] / fx2)
            .collect();
        let (pose, inliers) = epnp_ransac(&correspondences, &thresholds, &Ransac::default())?;
        timing.optimisation += start.elapsed().as_secs_f64() * 1e3;
        let mut points = vec![None; frame.len()];
        for (&(q, i), inlier) in matches.iter().zip(&inliers) {
            if *inlier {
                points[i] = Some(keys[q]);
            }
        }
        let mut estimate = self.optimise(input, &pose, &points, timing);
        if estimate.inliers < MIN_SEARCH_INLIERS {
            return None;
        }
        if estimate.inliers < RELOCALISATION_ACCEPT {
            let start = Instant::now();
            let mut points = estimate.matches;
            let mut taken: Vec<bool> = points.iter().map(|p| p.is_some()).collect();
            let (query_keys, queries) =
                self.projector()
                    .keyframe_queries(map, key, &points, &estimate.camera_from_world);
            for (q, i) in search_by_projection(
                frame,
                &queries,
                &mut taken,
                RELOCALISATION_SEARCH_RATIO,
                false,
            ) {
                points[i] = Some(query_keys[q]);
            }
            timing.matching += start.elapsed().as_secs_f64() * 1e3;
            estimate = self.optimise(input, &estimate.camera_from_world, &points, timing);
        }
        (estimate.inliers >= RELOCALISATION_ACCEPT).then_some(estimate)
    }
}

/// Every keyframe ranked by how many of a sample of the frame's descriptors match one
/// of its points' descriptors (ties: the newest first).
fn rank_keyframes(map: &Map, frame: &Frame) -> Vec<KeyFrameKey> {
    let sample: Vec<usize> = (0..frame.len())
        .step_by(RELOCALISATION_SAMPLE_STEP)
        .collect();
    let mut ranked: Vec<(usize, usize, KeyFrameKey)> = map
        .keyframe_order()
        .iter()
        .map(|&key| {
            let kf = &map.keyframes()[key];
            let descriptors: Vec<_> = kf
                .map_points
                .iter()
                .zip(&kf.frame.descriptors)
                .filter(|(p, _)| p.is_some())
                .map(|(_, d)| d)
                .collect();
            let hits = sample
                .iter()
                .filter(|&&i| {
                    descriptors
                        .iter()
                        .any(|d| hamming(&frame.descriptors[i], d) <= TH_LOW)
                })
                .count();
            (hits, kf.id, key)
        })
        .collect();
    ranked.sort_by(|a, b| b.0.cmp(&a.0).then(b.1.cmp(&a.1)));
    ranked.into_iter().map(|(_, _, key)| key).collect()
}
