//! Loop detection and correction (ORB-SLAM §VII, ORB-SLAM2's `LoopClosing`) over the
//! keyframes in the order they were made. Stages 1 and 2 ([`PlaceRecognition`], in
//! [`super::place_recognition`]) run
//! beside the tracking pass (`system::stages::Recognition`); stages 3 and 4
//! ([`LoopCloser`]) in the global pass, or during the tracking pass with
//! `[global.loops] during_tracking` (`system::loops`), no loop within `gap` keyframes
//! after the last:
//! 1. **Candidates**: database hits not covisible with the keyframe, scoring at least the
//!    lowest score of its covisible keyframes, sharing at least 80 % of the best hit's
//!    words; grouped with their covisible keyframes, groups within 75 % of the best
//!    accumulated score kept.
//! 2. **Consistency**: a candidate's group must overlap the groups of
//!    `min_consistency` consecutive keyframes.
//! 3. **Geometry**: keypoints matched through the vocabulary, their static map points
//!    give 3-D-3-D pairs; RANSAC on Horn's closed form finds
//!    \(T_{kc}\) (candidate camera to keyframe camera) with at least `min_inliers`
//!    pairs reprojecting within \(\chi^2_{0.95}(2)\,\sigma^2\) in both images; then the
//!    candidate's covisible points projected with \(T_{kc} T_{cw}\) must match at
//!    least `min_guided_matches` keypoints.
//! 4. **Correction**: the keyframe and its covisible keyframes move with
//!    \(T'_{kw} = T_{kc} T_{cw}\), their points with them; duplicated points are fused,
//!    the loop edge joins the essential graph, which is optimised.
//!    A loop between two map segments (tracking stayed lost in between) first moves
//!    the keyframe's whole segment rigidly onto the loop and merges it into the
//!    matched keyframe's.
//!
//! Points whose moving probability is above the removal threshold take no part. Every
//! candidate is reported with the stage where it stopped.

use std::collections::{HashMap, HashSet};

use nalgebra::Point3;
use serde::{Deserialize, Serialize};

use super::candidates::{Candidate, LoopKeys, LoopOutcome, LoopPair, LoopReject};
use super::essential_graph;
use super::loop_confirmation::Disagreement;
use super::place_recognition::{Found, LoopConfig, PlaceRecognition, Words};
use super::rigid_motion::RigidMotion;
use super::word_matching::{match_by_words, static_point, Worded};
use super::LoopInputs;
use crate::geometry::se3::{self, Se3};
use crate::map::{KeyFrameKey, Map, MapPointKey};
use crate::mapping::fusion;
use crate::optim::pose_graph::GraphReport;
use crate::optim::ransac::{ransac, Rounds, SkipRepeats};
use crate::random::Rng;

/// The seed of stage 3's RANSAC: the same samples in every run, so that a run's loops
/// do not depend on the clock.
const LOOP_RANSAC_SEED: u64 = 7;

/// Loop closing as the tracking pass hands it over: what place recognition found,
/// and the closer (with the loops it closed during the pass, when it did).
pub struct LoopState {
    /// Place recognition's database, words and findings.
    pub recognition: PlaceRecognition,
    /// The closer.
    pub closer: LoopCloser,
}

/// What verification reads beside the map: every keyframe's words, and what place
/// recognition found for the keyframes after the one verified.
#[derive(Clone, Copy)]
struct Look<'a> {
    words: &'a Words,
    upcoming: &'a [Found],
}

/// A loop that passed stage 3: the corrected pose \(T_{kc} T_{cw}\), the figures, and
/// the candidate's group with its static points.
struct Verified {
    corrected: Se3,
    inliers: usize,
    guided_matches: usize,
    loop_group: Vec<KeyFrameKey>,
    loop_points: Vec<MapPointKey>,
}

/// A loop that was closed.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ClosedLoop {
    #[serde(flatten)]
    /// The two keyframes.
    pub pair: LoopPair,
    /// Inliers of the rigid motion.
    pub inliers: usize,
    /// Matches after the guided search.
    pub guided_matches: usize,
    /// How far the keyframe moved: metres and degrees.
    pub correction_m: f64,
    /// How far the keyframe turned, degrees.
    pub correction_deg: f64,
    /// Map points fused across the loop.
    pub fused_points: usize,
    /// What the essential-graph optimisation did.
    pub essential_graph: GraphReport,
    /// When the two keyframes were in different map segments: the keyframe's segment,
    /// moved rigidly onto the loop and merged into the matched keyframe's.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub merged: Option<SegmentMerge>,
    /// Closed during the tracking pass (`[global.loops] during_tracking`), not after it.
    #[serde(default)]
    pub during_tracking: bool,
}

/// A map segment merged into another by a loop.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct SegmentMerge {
    /// The segment moved.
    pub segment: usize,
    /// The segment it was merged into.
    pub into: usize,
}

/// Loop closing across keyframes: verification and correction of what place
/// recognition found, during the tracking pass ([`Self::screen`] and
/// [`Self::close_ready`], as ORB-SLAM2's loop closing thread does) or after it
/// ([`Self::close_found`]).
pub struct LoopCloser {
    inputs: LoopInputs,
    config: LoopConfig,
    last_loop: Option<usize>,
    /// The loops closed, keyframe and match.
    pub loops: Vec<(KeyFrameKey, KeyFrameKey)>,
    /// Every candidate that reached consistency checking.
    pub candidates: Vec<Candidate>,
    /// The loops closed, as reported.
    pub closed: Vec<ClosedLoop>,
    /// Whether the loops closed now are closed during the tracking pass.
    during_tracking: bool,
    /// A loop verified by [`Self::screen`] waits at the head of place recognition's
    /// findings.
    ready: bool,
    /// The time spent closing loops during the tracking pass, milliseconds.
    pub during_tracking_ms: f64,
    rng: Rng,
}

impl LoopCloser {
    /// A closer with place recognition's `config`.
    pub fn new(inputs: LoopInputs, config: LoopConfig) -> Self {
        Self {
            inputs,
            config,
            last_loop: None,
            loops: Vec::new(),
            candidates: Vec::new(),
            closed: Vec::new(),
            during_tracking: false,
            ready: false,
            during_tracking_ms: 0.0,
            rng: Rng::new(LOOP_RANSAC_SEED),
        }
    }

    /// Whether `key` comes within `gap` keyframes after the last loop closed.
    fn recent(&self, map: &Map, key: KeyFrameKey) -> bool {
        let id = map.keyframes().get(key).map_or(0, |kf| kf.id);
        self.last_loop
            .is_some_and(|last| id < last + self.config.gap)
    }

    /// Verifies and corrects, in order, everything place recognition found
    /// (keyframes within `gap` after a loop closed here are passed).
    pub fn close_found(&mut self, map: &mut Map, recognition: &mut PlaceRecognition) {
        (self.during_tracking, self.ready) = (false, false);
        let found = std::mem::take(&mut recognition.found);
        self.close_first(map, &recognition.words, &found, found.len());
    }

    /// How many of the keyframes place recognition found have every confirmation
    /// they can get: the next `confirmations` keyframes that found the place within
    /// `4 gap` keyframes, or recognition has gone past that window.
    fn settled(&self, map: &Map, recognition: &PlaceRecognition) -> usize {
        let found = &recognition.found;
        let newest = recognition.newest_id.unwrap_or(0);
        let id = |k: KeyFrameKey| map.keyframes().get(k).map(|kf| kf.id);
        (0..found.len())
            .take_while(|&i| {
                let Some(first) = id(found[i].0) else {
                    return true;
                };
                let within = first + 4 * self.config.gap;
                let later = found[i + 1..]
                    .iter()
                    .filter(|(k, _)| id(*k).is_some_and(|later| later <= within))
                    .count();
                newest > within || later >= self.config.confirmations
            })
            .count()
    }

    /// Whether a loop verified by [`Self::screen`] waits for [`Self::close_ready`].
    pub fn is_ready(&self) -> bool {
        self.ready
    }

    /// During the tracking pass, under the map's read lock (beside tracking, as
    /// place recognition runs): stage 3 for the keyframes that are settled (their
    /// confirmations are in), in order. Those with no loop leave with their
    /// candidates recorded; the first with a loop that verifies waits for
    /// [`Self::close_ready`], and so do the ones after it. Returns whether a loop waits.
    pub fn screen(&mut self, map: &Map, recognition: &mut PlaceRecognition) -> bool {
        if self.ready {
            return true;
        }
        let count = self.settled(map, recognition);
        if count == 0 {
            return false;
        }
        let found = std::mem::take(&mut recognition.found);
        let mut done = 0;
        for (i, (key, candidates)) in found.iter().enumerate().take(count) {
            if map.keyframes().contains_key(*key) && !self.pass_too_soon(map, &found[i]) {
                let look = Look {
                    words: &recognition.words,
                    upcoming: &found[i + 1..],
                };
                let before = self.candidates.len();
                if self.any_verifies(map, *key, candidates, look) {
                    // Verified again, and recorded, when the loop is closed.
                    self.candidates.truncate(before);
                    self.ready = true;
                    break;
                }
            }
            done = i + 1;
        }
        recognition.found = found[done..].to_vec();
        self.ready
    }

    /// Under the map's write lock (local mapping idle): verifies the loop that
    /// [`Self::screen`] found once more on the map as it is now, and closes it.
    /// Returns how many loops were closed (0 or 1).
    pub fn close_ready(&mut self, map: &mut Map, recognition: &mut PlaceRecognition) -> usize {
        if !std::mem::take(&mut self.ready) {
            return 0;
        }
        self.during_tracking = true;
        let before = self.closed.len();
        let found = std::mem::take(&mut recognition.found);
        self.close_first(map, &recognition.words, &found, 1);
        recognition.found = found.into_iter().skip(1).collect();
        self.closed.len() - before
    }

    /// Whether `entry`'s keyframe comes too soon after the last loop: then its
    /// candidates are recorded as passed.
    fn pass_too_soon(&mut self, map: &Map, entry: &Found) -> bool {
        let (key, candidates) = entry;
        if !self.recent(map, *key) {
            return false;
        }
        for &(c, score) in candidates {
            if map.keyframes().contains_key(c) {
                let gap = self.config.gap;
                let reject = LoopReject::TooSoon { gap };
                let keys = LoopKeys {
                    keyframe: *key,
                    matched: c,
                };
                self.record(map, keys, score, LoopOutcome::Rejected(reject));
            }
        }
        true
    }

    /// Stage 3 for the candidates until one verifies (the others recorded).
    fn any_verifies(
        &mut self,
        map: &Map,
        key: KeyFrameKey,
        candidates: &[(KeyFrameKey, f64)],
        look: Look,
    ) -> bool {
        for &(matched, score) in candidates {
            if !map.keyframes().contains_key(matched) {
                continue;
            }
            let keys = LoopKeys {
                keyframe: key,
                matched,
            };
            match self.check(map, keys, look) {
                Ok(_) => return true,
                Err(reject) => self.record(map, keys, score, LoopOutcome::Rejected(reject)),
            }
        }
        false
    }

    /// Stages 3 and 4 for the first `count` keyframes of `found`, in order.
    fn close_first(&mut self, map: &mut Map, words: &Words, found: &[Found], count: usize) {
        for (i, entry) in found.iter().enumerate().take(count) {
            let key = entry.0;
            if !map.keyframes().contains_key(key) || self.pass_too_soon(map, entry) {
                continue;
            }
            let look = Look {
                words,
                upcoming: &found[i + 1..],
            };
            self.verify(map, key, &entry.1, look);
        }
    }

    /// Stages 3 and 4 for the candidates until one closes a loop.
    fn verify(
        &mut self,
        map: &mut Map,
        key: KeyFrameKey,
        candidates: &[(KeyFrameKey, f64)],
        look: Look,
    ) {
        for &(matched, score) in candidates {
            if !map.keyframes().contains_key(matched) {
                continue;
            }
            let keys = LoopKeys {
                keyframe: key,
                matched,
            };
            if self.verify_and_correct(map, keys, score, look) {
                break;
            }
        }
    }

    /// Every candidate with its outcome, by keyframe; the time place recognition took.
    pub fn finish(
        mut self,
        recognition: PlaceRecognition,
    ) -> (Vec<ClosedLoop>, Vec<Candidate>, f64) {
        let mut candidates = recognition.rejected;
        candidates.append(&mut self.candidates);
        candidates.sort_by_key(|c| c.pair.keyframe);
        (self.closed, candidates, recognition.milliseconds)
    }

    fn record(&mut self, map: &Map, keys: LoopKeys, score: f64, outcome: LoopOutcome) {
        let pair = LoopPair::of(map, keys);
        self.candidates.push(Candidate::new(pair, score, outcome));
    }

    /// Stages 3 and 4 for one candidate; `true` when the loop was closed.
    fn verify_and_correct(
        &mut self,
        map: &mut Map,
        keys: LoopKeys,
        score: f64,
        look: Look,
    ) -> bool {
        let verified = match self.check(map, keys, look) {
            Ok(verified) => verified,
            Err(reject) => {
                self.record(map, keys, score, LoopOutcome::Rejected(reject));
                return false;
            }
        };
        let outcome = LoopOutcome::Accepted {
            inliers: verified.inliers,
            guided_matches: verified.guided_matches,
        };
        self.record(map, keys, score, outcome);
        self.correct_loop(map, keys, verified);
        true
    }

    /// Stage 3 for one candidate: its geometry, then the next keyframes' loops.
    fn check(&mut self, map: &Map, keys: LoopKeys, look: Look) -> Result<Verified, LoopReject> {
        self.verify_geometry(map, keys.keyframe, keys.matched, look.words)
            .and_then(|v| {
                self.confirm(map, keys.keyframe, &v.corrected, look)
                    .map(|()| v)
            })
    }

    /// The loop placing `key` at `corrected`, against the loops of the next keyframes
    /// that found the place (up to `confirmations`, within `4 gap` keyframes), each
    /// verified on its own without closing it ([`loop_confirmation`]): `Err` when some
    /// verified and none agrees.
    fn confirm(
        &mut self,
        map: &Map,
        key: KeyFrameKey,
        corrected: &Se3,
        look: Look,
    ) -> Result<(), LoopReject> {
        let config = &self.config;
        let (wanted, id) = (config.confirmations, map.keyframes()[key].id);
        let within = id + 4 * config.gap;
        let later: Vec<&Found> = look
            .upcoming
            .iter()
            .filter(|(k, _)| map.keyframes().get(*k).is_some_and(|kf| kf.id <= within))
            .take(wanted)
            .collect();
        let mut closest: Option<Disagreement> = None;
        let mut checked = 0;
        for (later_key, candidates) in later {
            let placed = candidates
                .iter()
                .filter(|(c, _)| map.keyframes().contains_key(*c))
                .find_map(|(c, _)| self.verify_geometry(map, *later_key, *c, look.words).ok());
            let Some(placed) = placed else {
                continue;
            };
            checked += 1;
            let pose = |k: KeyFrameKey| map.keyframes()[k].camera_from_world;
            let d =
                Disagreement::between(&pose(key), corrected, &pose(*later_key), &placed.corrected);
            if d.agrees() {
                return Ok(());
            }
            if closest.is_none_or(|c| d.degrees < c.degrees) {
                closest = Some(d);
            }
        }
        match closest {
            None => Ok(()),
            Some(d) => Err(LoopReject::Contradicted {
                checked,
                cm: (d.metres * 100.0).round() as u32,
                decidegrees: (d.degrees * 10.0).round() as u32,
            }),
        }
    }

    /// Stage 3 for one candidate: the vocabulary matches, the rigid motion by RANSAC,
    /// the guided search with the corrected pose \(T_{kc} T_{cw}\).
    fn verify_geometry(
        &mut self,
        map: &Map,
        key: KeyFrameKey,
        candidate: KeyFrameKey,
        words: &Words,
    ) -> Result<Verified, LoopReject> {
        let config = &self.config;
        let (min_inliers, min_guided) = (config.min_inliers, config.min_guided_matches);
        let matches = {
            let (a, b) = (&map.keyframes()[key], &map.keyframes()[candidate]);
            match_by_words(
                map,
                Worded {
                    keyframe: a,
                    words: &words[&key].1,
                },
                Worded {
                    keyframe: b,
                    words: &words[&candidate].1,
                },
                config.ratio,
                self.inputs.removal_threshold,
            )
        };
        if matches.len() < min_inliers {
            return Err(LoopReject::FewMatches {
                found: matches.len(),
                needed: min_inliers,
            });
        }
        let (keyframe_from_candidate, inliers) = self
            .ransac(map, key, candidate, &matches)
            .ok_or(LoopReject::NoRigidMotion)?;
        if inliers < min_inliers {
            return Err(LoopReject::FewInliers {
                found: inliers,
                needed: min_inliers,
            });
        }
        // Guided search: the candidate's covisible points projected with the corrected pose.
        let corrected = keyframe_from_candidate * map.keyframes()[candidate].camera_from_world;
        let loop_group: Vec<KeyFrameKey> = std::iter::once(candidate)
            .chain(map.keyframes()[candidate].best_covisible(usize::MAX))
            .filter(|k| map.keyframes().contains_key(*k))
            .collect();
        let loop_points = self.static_points(map, &loop_group);
        let guided = fusion::search_from(
            map,
            key,
            &corrected,
            &loop_points,
            &self.inputs.camera,
            &self.inputs.pyramid,
            self.inputs.size,
        );
        if guided.len() < min_guided {
            return Err(LoopReject::FewGuidedMatches {
                inliers,
                found: guided.len(),
                needed: min_guided,
            });
        }
        Ok(Verified {
            corrected,
            inliers,
            guided_matches: guided.len(),
            loop_group,
            loop_points,
        })
    }

    /// Stage 4 for a verified loop: segments merged when the loop joins two, the
    /// correction carried, the loop recorded.
    fn correct_loop(&mut self, map: &mut Map, keys: LoopKeys, verified: Verified) {
        let LoopKeys {
            keyframe: key,
            matched: candidate,
        } = keys;
        let Verified {
            corrected,
            inliers,
            guided_matches,
            loop_group,
            loop_points,
        } = verified;
        let original = map.keyframes()[key].camera_from_world;
        let moved = se3::log(&(corrected * original.inverse()));
        let merged = merge_segments(map, keys, &corrected, &self.inputs.pyramid.factors);
        let (fused, report) =
            self.correct(map, key, candidate, corrected, &loop_group, &loop_points);
        let pair = LoopPair::of(map, keys);
        self.closed.push(ClosedLoop {
            pair,
            inliers,
            guided_matches,
            correction_m: (corrected.inverse().translation.vector
                - original.inverse().translation.vector)
                .norm(),
            correction_deg: moved.fixed_rows::<3>(3).norm().to_degrees(),
            fused_points: fused,
            essential_graph: report,
            merged,
            during_tracking: self.during_tracking,
        });
        self.last_loop = Some(pair.keyframe);
    }

    fn static_points(&self, map: &Map, keyframes: &[KeyFrameKey]) -> Vec<MapPointKey> {
        let mut seen = HashSet::new();
        let mut points = Vec::new();
        for k in keyframes {
            let kf = &map.keyframes()[*k];
            for i in 0..kf.map_points.len() {
                if let Some(p) = static_point(map, kf, i, self.inputs.removal_threshold) {
                    if seen.insert(p) {
                        points.push(p);
                    }
                }
            }
        }
        points
    }

    /// RANSAC ([`crate::optim::ransac`]) over Horn's closed form: \(T_{kc}\) with
    /// \(P_k = T_{kc} P_c\) for the camera-frame points, inliers reprojecting within the
    /// gate in both images; refitted twice on the inliers.
    fn ransac(
        &mut self,
        map: &Map,
        key: KeyFrameKey,
        candidate: KeyFrameKey,
        matches: &[(usize, usize)],
    ) -> Option<(Se3, usize)> {
        let estimator = RigidMotion::new(
            map,
            LoopKeys {
                keyframe: key,
                matched: candidate,
            },
            matches,
            &self.inputs,
        );
        let rounds = Rounds {
            iterations: self.config.ransac_iterations,
            min_inliers: 0,
            refits: 2,
        };
        let (t, inliers) = ransac(&estimator, &mut SkipRepeats(&mut self.rng), rounds)?;
        Some((t, inliers.len()))
    }

    /// Stage 4: moves the keyframe's covisible neighbourhood and its points onto the
    /// loop, fuses duplicates, links the loop and optimises the essential graph.
    fn correct(
        &mut self,
        map: &mut Map,
        key: KeyFrameKey,
        candidate: KeyFrameKey,
        corrected: Se3,
        loop_group: &[KeyFrameKey],
        loop_points: &[MapPointKey],
    ) -> (usize, GraphReport) {
        let scale_factors = self.inputs.pyramid.factors.clone();
        let neighbourhood: Vec<KeyFrameKey> = std::iter::once(key)
            .chain(map.keyframes()[key].connections.iter().map(|(k, _)| *k))
            .filter(|k| map.keyframes().contains_key(*k) && !loop_group.contains(k))
            .collect();
        let before_links: HashMap<KeyFrameKey, HashSet<KeyFrameKey>> = neighbourhood
            .iter()
            .map(|k| {
                (
                    *k,
                    map.keyframes()[*k]
                        .connections
                        .iter()
                        .map(|(c, _)| *c)
                        .collect(),
                )
            })
            .collect();
        let (uncorrected, placed_by) =
            carry_correction(map, key, &corrected, &neighbourhood, loop_group);
        for p in placed_by.keys() {
            map.update_point(*p, &scale_factors);
        }
        // Fuse the loop group's points into the corrected neighbourhood.
        let mut fused = 0;
        for &n in &neighbourhood {
            let found = fusion::search(
                map,
                n,
                loop_points,
                &self.inputs.camera,
                &self.inputs.pyramid,
                self.inputs.size,
            );
            fused += fusion::apply(map, &found);
        }
        for &n in &neighbourhood {
            map.update_connections(n);
        }
        // New links between the neighbourhood and the rest are loop edges.
        for &n in &neighbourhood {
            let Some(kf) = map.keyframes().get(n) else {
                continue;
            };
            for (c, _) in &kf.connections {
                if !before_links[&n].contains(c) && !neighbourhood.contains(c) {
                    self.loops.push((n, *c));
                }
            }
        }
        self.loops.push((key, candidate));
        let report = essential_graph::optimise(
            map,
            &self.loops,
            &uncorrected,
            &placed_by,
            candidate,
            self.config.covisibility_weight,
        );
        let all: Vec<MapPointKey> = map.points().keys().collect();
        for p in all {
            map.update_point(p, &scale_factors);
        }
        (fused, report)
    }
}

/// Moves the keyframes a loop correction carries with `key` (its pose \(T_{kw}\) becomes
/// `corrected` \(T'_{kw}\)): first its covisible `neighbourhood`, then every later
/// keyframe of its segment outside the loop group whose spanning-tree parent was
/// carried, all by the same \(M = T_{kw}^{-1} T'_{kw}\) ([`move_rigidly`]). Online,
/// keyframes after a loop are tracked on the corrected map; offline they already exist,
/// and left in place they would start the essential graph with the whole correction on
/// one edge (a kink that on a 4.5 km street left the optimisation unconverged and the
/// map bent). A later keyframe tracked against an older part of the map (a revisit:
/// its parent is older than the loop and was not carried) stays with that part: moved
/// with the loop, it and the old points it sees would be torn from their place (three
/// laps of one street ended 300 m off). Returns the poses before the move and the
/// keyframe that placed each point.
fn carry_correction(
    map: &mut Map,
    key: KeyFrameKey,
    corrected: &Se3,
    neighbourhood: &[KeyFrameKey],
    loop_group: &[KeyFrameKey],
) -> (HashMap<KeyFrameKey, Se3>, HashMap<MapPointKey, KeyFrameKey>) {
    let m = map.keyframes()[key].world_from_camera() * corrected;
    let (id, segment) = (map.keyframes()[key].id, map.keyframes()[key].segment);
    let mut carried: Vec<KeyFrameKey> = neighbourhood.to_vec();
    let mut member: HashSet<KeyFrameKey> = carried.iter().copied().collect();
    // Keyframe order is id order and a parent is older than its children: one pass.
    for &k in map.keyframe_order() {
        let Some(kf) = map.keyframes().get(k) else {
            continue;
        };
        let follows = kf.parent.is_some_and(|p| member.contains(&p));
        let later = kf.id > id && kf.segment == segment && !loop_group.contains(&k);
        if later && follows && member.insert(k) {
            carried.push(k);
        }
    }
    let moved = Moved {
        keyframes: &carried,
        all_points_of: neighbourhood.len(),
    };
    move_rigidly(map, moved, &m)
}

/// Keyframes moved together: every point the first `all_points_of` see moves with
/// them; of the points the others see, those one of them found first.
#[derive(Clone, Copy)]
struct Moved<'k> {
    keyframes: &'k [KeyFrameKey],
    all_points_of: usize,
}

/// Moves the keyframes rigidly, \(T'_{nw} = T_{nw} M\), and their points as
/// [`Moved`] says, \(X' = M^{-1} X\), each once (a point an older, unmoved keyframe
/// found first stays with it). Returns the poses before the move and, per moved
/// point, the keyframe it moved with.
fn move_rigidly(
    map: &mut Map,
    moved: Moved,
    m: &Se3,
) -> (HashMap<KeyFrameKey, Se3>, HashMap<MapPointKey, KeyFrameKey>) {
    let keyframes = moved.keyframes;
    let m_inverse = m.inverse();
    let mut before = HashMap::new();
    for &n in keyframes {
        let old = map.keyframes()[n].camera_from_world;
        before.insert(n, old);
        map.set_keyframe_pose(n, se3::normalised(&(old * m)));
    }
    let mut placed_by = HashMap::new();
    for (i, &n) in keyframes.iter().enumerate() {
        for p in map.keyframes()[n].observed_points() {
            let Some(point) = map.points().get(p) else {
                continue;
            };
            let found_first = point.observations.first().map(|o| o.0) == Some(n);
            if placed_by.contains_key(&p) || (i >= moved.all_points_of && !found_first) {
                continue;
            }
            let position = (m_inverse * Point3::from(point.position)).coords;
            map.set_point_position(p, position);
            placed_by.insert(p, n);
        }
    }
    (before, placed_by)
}

/// A loop between map segments: moves the keyframe's whole segment rigidly so that the
/// keyframe lands on `corrected` ([`move_rigidly`] with \(M = T_{kw}^{-1} T'_{kw}\))
/// and gives its keyframes the matched keyframe's segment. `None` (nothing moved)
/// within one segment.
fn merge_segments(
    map: &mut Map,
    keys: LoopKeys,
    corrected: &Se3,
    scale_factors: &[f64],
) -> Option<SegmentMerge> {
    let LoopKeys {
        keyframe: key,
        matched: candidate,
    } = keys;
    let (segment, into) = (
        map.keyframes()[key].segment,
        map.keyframes()[candidate].segment,
    );
    if segment == into {
        return None;
    }
    let m = map.keyframes()[key].world_from_camera() * corrected;
    let members: Vec<KeyFrameKey> = map
        .keyframe_order()
        .iter()
        .copied()
        .filter(|k| {
            map.keyframes()
                .get(*k)
                .is_some_and(|kf| kf.segment == segment)
        })
        .collect();
    let whole = Moved {
        keyframes: &members,
        all_points_of: members.len(),
    };
    let (_, moved) = move_rigidly(map, whole, &m);
    for &k in &members {
        map.set_keyframe_segment(k, into);
    }
    // Normals turn with the segment.
    for p in moved.into_keys() {
        map.update_point(p, scale_factors);
    }
    Some(SegmentMerge { segment, into })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::Frame;
    use crate::map::{KeyFrame, MapPoint};
    use nalgebra::Vector3;
    use nalgebra::{Rotation3, Translation3};

    fn keyframe(segment: usize, camera_from_world: Se3) -> KeyFrame {
        let frame = Frame::from_parts(
            0,
            0.0,
            vec![crate::features::KeyPoint::default(); 4],
            vec![[0; 4]; 4],
            vec![0.0; 4],
            vec![-1.0; 4],
            (640, 480),
        );
        let mut kf = KeyFrame::new(frame, camera_from_world);
        kf.segment = segment;
        kf
    }

    fn keys(keyframe: KeyFrameKey, matched: KeyFrameKey) -> LoopKeys {
        LoopKeys { keyframe, matched }
    }

    fn pose(t: [f64; 3], axis_angle: [f64; 3]) -> Se3 {
        Se3::from_parts(
            Translation3::new(t[0], t[1], t[2]),
            Rotation3::from_scaled_axis(Vector3::from(axis_angle)),
        )
    }

    fn observed_point(map: &mut Map, keyframe: KeyFrameKey, position: [f64; 3]) -> MapPointKey {
        let p = map.insert_point(MapPoint::new(
            Vector3::from(position),
            [0; 4],
            Vector3::z(),
            (0.1, 10.0),
            0,
        ));
        map.add_observation(p, keyframe, 0);
        p
    }

    #[test]
    fn a_loop_correction_carries_the_later_keyframes_of_its_segment_and_their_points() {
        let mut map = Map::default();
        // A path of keyframes 0..8 in segment 0, each attached to the one before, then
        // one in segment 1, then a revisit of keyframe 1's place (attached to it) and
        // one after it.
        let mut k: Vec<KeyFrameKey> = Vec::new();
        for i in 0..8 {
            let step = i as f64;
            let mut kf = keyframe(
                0,
                pose([-0.5 * step, 0.0, 0.1 * step], [0.0, 0.05 * step, 0.0]),
            );
            kf.parent = k.last().copied();
            k.push(map.add_keyframe(kf));
        }
        let other = map.add_keyframe(keyframe(1, pose([2.0, 0.0, 0.0], [0.0, 0.3, 0.0])));
        let mut revisit = keyframe(0, pose([-0.4, 0.0, 0.1], [0.0, 0.06, 0.0]));
        revisit.parent = Some(k[1]);
        let revisit = map.add_keyframe(revisit);
        let mut after_revisit = keyframe(0, pose([-0.9, 0.0, 0.2], [0.0, 0.1, 0.0]));
        after_revisit.parent = Some(revisit);
        let after_revisit = map.add_keyframe(after_revisit);
        let early = observed_point(&mut map, k[1], [0.0, 0.0, 2.0]);
        map.add_observation(early, k[7], 1);
        map.add_observation(early, revisit, 1);
        let late = observed_point(&mut map, k[7], [0.3, 0.2, 2.5]);
        let elsewhere = observed_point(&mut map, other, [0.1, 0.1, 1.0]);
        let revisited = observed_point(&mut map, after_revisit, [-0.2, 0.1, 3.0]);
        let before: Vec<Se3> = map
            .keyframes()
            .values()
            .map(|kf| kf.camera_from_world)
            .collect();
        let positions =
            |map: &Map| [early, late, elsewhere, revisited].map(|p| map.points()[p].position);
        let (points_before, late_in_camera) = (
            positions(&map),
            map.keyframes()[k[7]].camera_from_world * Point3::from(map.points()[late].position),
        );
        let four_from_seven =
            map.keyframes()[k[4]].camera_from_world * map.keyframes()[k[7]].world_from_camera();
        // A large correction, like the 70 m / 41 degree one on the street.
        let corrected = pose([30.0, -2.0, 60.0], [0.1, 0.7, 0.0]) * before[4];

        let (uncorrected, placed_by) =
            carry_correction(&mut map, k[4], &corrected, &[k[4], k[3], k[5]], &[k[0]]);

        let moved: HashSet<KeyFrameKey> = uncorrected.keys().copied().collect();
        assert_eq!(moved, HashSet::from([k[3], k[4], k[5], k[6], k[7]]));
        let unmoved = [k[0], k[1], k[2], other, revisit, after_revisit];
        for (kf, index) in unmoved.into_iter().zip([0, 1, 2, 8, 9, 10]) {
            assert_eq!(map.keyframes()[kf].camera_from_world, before[index]);
        }
        assert!(
            se3::log(&(map.keyframes()[k[4]].camera_from_world * corrected.inverse())).norm()
                < 1e-9
        );
        // The later part keeps its shape and its points stay put in its cameras.
        let after =
            map.keyframes()[k[4]].camera_from_world * map.keyframes()[k[7]].world_from_camera();
        assert!(se3::log(&(after * four_from_seven.inverse())).norm() < 1e-9);
        let late_after =
            map.keyframes()[k[7]].camera_from_world * Point3::from(map.points()[late].position);
        assert!((late_after - late_in_camera).norm() < 1e-9);
        assert_eq!(placed_by.get(&late), Some(&k[7]));
        // The point keyframe 1 found stays with it though keyframe 7 sees it too; the
        // revisit's points stay with the revisit.
        let points_after = positions(&map);
        for i in [0, 2, 3] {
            assert_eq!(points_after[i], points_before[i]);
        }
        assert!((points_after[1] - points_before[1]).norm() > 10.0);
        assert!(!placed_by.contains_key(&early));
    }

    /// Keyframes on a 200-step circle whose tracking drifted 0.3 degrees of yaw a step,
    /// each linked to the one before (parent and covisibility), and the poses that close
    /// the loop from keyframe 150 onto keyframe 0 without drift.
    fn drifted_circle(map: &mut Map) -> (Vec<KeyFrameKey>, Vec<Se3>) {
        let (mut keys, mut truth) = (Vec::new(), Vec::new());
        let step = pose([0.0, 0.0, 2.0], [0.0, std::f64::consts::TAU / 200.0, 0.0]);
        let drift = pose([0.0, 0.0, 0.0], [0.0, 0.3f64.to_radians(), 0.0]);
        let (mut world_from_true, mut world_from_tracked) = (Se3::identity(), Se3::identity());
        for _ in 0..200 {
            let mut kf = keyframe(0, world_from_tracked.inverse());
            kf.parent = keys.last().copied();
            let key = map.add_keyframe(kf);
            if let Some(&previous) = keys.last() {
                map.keyframe_mut(key).connections.push((previous, 200));
            }
            keys.push(key);
            truth.push(world_from_true.inverse());
            world_from_true *= step;
            world_from_tracked = world_from_tracked * step * drift;
        }
        (keys, truth)
    }

    #[test]
    fn a_large_loop_correction_with_the_later_keyframes_carried_converges() {
        let mut map = Map::default();
        let (k, truth) = drifted_circle(&mut map);
        let loop_error = |map: &Map| {
            se3::log(
                &(map.keyframes()[k[150]].camera_from_world
                    * map.keyframes()[k[0]].world_from_camera()
                    * (truth[150] * truth[0].inverse()).inverse()),
            )
            .norm()
        };
        let drifted = loop_error(&map);
        // Keyframe 150 lands where the truth puts it relative to keyframe 0: a 45 degree
        // correction, with 49 keyframes after it.
        let corrected = truth[150] * truth[0].inverse() * map.keyframes()[k[0]].camera_from_world;
        let (uncorrected, placed_by) = carry_correction(
            &mut map,
            k[150],
            &corrected,
            &[k[150], k[149], k[151]],
            &[k[0]],
        );
        let report = essential_graph::optimise(
            &mut map,
            &[(k[150], k[0])],
            &uncorrected,
            &placed_by,
            k[0],
            100,
        );
        assert!(report.converged, "{report:?}");
        assert!(report.final_cost < 1e-5 * report.initial_cost, "{report:?}");
        // The loop nearly holds (its edge weighs as one of the 150 it closes).
        assert!(
            loop_error(&map) < 0.02 * drifted,
            "{} from {drifted}",
            loop_error(&map)
        );
    }

    #[test]
    fn a_loop_between_segments_moves_the_later_one_rigidly_and_merges_it() {
        let mut map = Map::default();
        let a = map.add_keyframe(keyframe(0, Se3::identity()));
        let b = map.add_keyframe(keyframe(1, pose([0.3, 0.0, 0.1], [0.0, 0.4, 0.0])));
        let c = map.add_keyframe(keyframe(1, pose([0.5, -0.2, 0.0], [0.1, 0.5, 0.0])));
        let p = observed_point(&mut map, c, [0.2, 0.1, 2.0]);
        let q = observed_point(&mut map, a, [-0.4, 0.0, 3.0]);
        let in_c = |map: &Map| {
            map.keyframes()[c].camera_from_world * Point3::from(map.points()[p].position)
        };
        let (before_c, before_q) = (in_c(&map), map.points()[q].position);
        let b_from_c =
            map.keyframes()[b].camera_from_world * map.keyframes()[c].world_from_camera();
        let corrected = pose([-1.0, 0.2, 0.3], [0.0, -1.2, 0.1]);

        let merge = merge_segments(&mut map, keys(b, a), &corrected, &[1.0; 8]);

        assert_eq!(
            merge,
            Some(SegmentMerge {
                segment: 1,
                into: 0
            })
        );
        let landed = map.keyframes()[b].camera_from_world * corrected.inverse();
        assert!(se3::log(&landed).norm() < 1e-9);
        // The segment's own geometry is unchanged: relative poses, points in its cameras.
        let after = map.keyframes()[b].camera_from_world * map.keyframes()[c].world_from_camera();
        assert!(se3::log(&(after * b_from_c.inverse())).norm() < 1e-9);
        assert!((in_c(&map) - before_c).norm() < 1e-9);
        // The other segment stays where it was.
        assert_eq!(map.points()[q].position, before_q);
        assert!(map.keyframes().values().all(|kf| kf.segment == 0));
        assert_eq!(
            map.segment_anchors().into_iter().collect::<Vec<_>>(),
            vec![a]
        );
        // Within one segment there is nothing to merge.
        assert_eq!(
            merge_segments(&mut map, keys(c, a), &corrected, &[1.0; 8]),
            None
        );
    }

    /// A closer over keyframes with ids 0..60 and place recognition that found
    /// keyframes `found` (by id, one candidate each: keyframe 0) and searched up to
    /// `newest`.
    fn screened(found: &[usize], newest: usize) -> (Map, LoopCloser, PlaceRecognition) {
        use crate::bow::vocabulary::TrainOptions;
        use crate::bow::Vocabulary;
        let mut map = Map::default();
        let keys: Vec<KeyFrameKey> = (0..60)
            .map(|i| map.add_keyframe(keyframe(0, pose([i as f64, 0.0, 0.0], [0.0; 3]))))
            .collect();
        let training = vec![vec![[0u64; 4], [u64::MAX; 4]]; 2];
        let options = TrainOptions {
            depth: 1,
            ..TrainOptions::default()
        };
        let vocabulary = Vocabulary::train(&training, &options);
        let config = LoopConfig::default();
        let mut recognition = PlaceRecognition::new(&vocabulary, config.clone());
        recognition.found = found
            .iter()
            .map(|&id| (keys[id], vec![(keys[0], 1.0)]))
            .collect();
        recognition.newest_id = Some(newest);
        let inputs = LoopInputs {
            camera: crate::geometry::stereo_camera::StereoCamera {
                fx: 500.0,
                fy: 500.0,
                cx: 320.0,
                cy: 240.0,
                bf: 40.0,
            },
            pyramid: crate::features::ScalePyramid::new(8, 1.2),
            size: (640.0, 480.0),
            removal_threshold: 1.0,
        };
        (map, LoopCloser::new(inputs, config), recognition)
    }

    #[test]
    fn a_found_keyframe_is_settled_once_its_confirmations_are_in_or_their_window_passed() {
        // Defaults: 3 confirmations within 4 x 10 keyframes.
        assert_eq!(LoopConfig::default().confirmations, 3);
        assert_eq!(LoopConfig::default().gap, 10);
        // Keyframe 10 has three later finds within 50; 11 has two, and recognition is
        // at 31: it waits, and so does everything after it.
        let (map, closer, recognition) = screened(&[10, 11, 12, 30], 31);
        assert_eq!(closer.settled(&map, &recognition), 1);
        // Recognition at 52: 11's window (to 51) has passed, 12's (to 52) has not.
        let (map, closer, recognition) = screened(&[10, 11, 12, 30], 52);
        assert_eq!(closer.settled(&map, &recognition), 2);
        // Nothing found: nothing settled.
        let (map, closer, recognition) = screened(&[], 59);
        assert_eq!(closer.settled(&map, &recognition), 0);
    }

    #[test]
    fn screening_drops_the_settled_keyframes_whose_loops_fail_and_keeps_the_rest() {
        // The keyframes share no words and observe no points: every loop fails at
        // stage 3, so nothing waits to be closed; the settled keyframes leave with
        // their candidates recorded, the last one waits for its confirmations.
        let (map, mut closer, mut recognition) = screened(&[10, 11, 12, 30], 31);
        for (key, _) in &recognition.found {
            let words = (Default::default(), Default::default());
            recognition.words.insert(*key, words);
        }
        let first = map.keyframe_order()[0];
        recognition
            .words
            .insert(first, (Default::default(), Default::default()));
        assert!(!closer.screen(&map, &mut recognition));
        assert!(!closer.is_ready());
        let left: Vec<usize> = recognition
            .found
            .iter()
            .map(|(k, _)| map.keyframes()[*k].id)
            .collect();
        assert_eq!(left, vec![11, 12, 30]);
        assert_eq!(closer.candidates.len(), 1);
        assert!(!closer.candidates[0].accepted);
        let expected = LoopOutcome::Rejected(LoopReject::FewMatches {
            found: 0,
            needed: 20,
        });
        assert_eq!(closer.candidates[0].outcome, expected.to_string());
        // Nothing is closed without a loop waiting.
        let mut map = map;
        assert_eq!(closer.close_ready(&mut map, &mut recognition), 0);
        assert_eq!(recognition.found.len(), 3);
    }
}
