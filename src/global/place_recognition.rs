//! Stages 1 and 2 of loop closing (ORB-SLAM §VII-A, B): place recognition through
//! the vocabulary and the consistency of candidates over consecutive keyframes. They
//! run on each keyframe beside the tracking pass; [`super::loop_closing`] verifies and
//! corrects what they found in the global pass.

use std::collections::{HashMap, HashSet};

use serde::Serialize;

use super::candidates::{Candidate, LoopKeys, LoopOutcome, LoopPair, LoopReject};
use crate::bow::{BowVector, Database, FeatureVector, Hit, Vocabulary};
use crate::map::{KeyFrameKey, Map};

/// Loop-closing parameters (ORB-SLAM2's values by default).
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LoopConfig {
    /// Look for loops (needs the vocabulary); `dopslam run --no-loops` turns it off and
    /// the global pass keeps full BA and the frames' refinement.
    pub enabled: bool,
    /// Keyframes in a row whose groups must overlap a candidate's (ORB-SLAM2: 3).
    pub min_consistency: usize,
    /// No loop is searched within this many keyframes after the last one.
    pub gap: usize,
    /// Rigid-motion inliers a loop needs.
    pub min_inliers: usize,
    /// Matches after the guided search a loop needs.
    pub min_guided_matches: usize,
    /// Covisibility edges of at least this weight join the essential graph.
    pub covisibility_weight: usize,
    /// RANSAC hypotheses for the rigid motion.
    pub ransac_iterations: usize,
    /// Lowe's ratio for matching through the vocabulary.
    pub ratio: f32,
    /// A verified loop is checked against the loops of up to this many of the next
    /// keyframes that found the place (within `4 gap` keyframes), each verified on
    /// its own: when all of those that verify place the keyframe elsewhere, the loop
    /// is not closed ([`super::loop_confirmation`]; 0: off).
    pub confirmations: usize,
    /// Close loops during the tracking pass, as soon as a loop's confirmations are in,
    /// so that the frames after it are tracked in the map the loop joined; `false` (the
    /// default: on a street driven again it cost accuracy, `docs/design.md`): every
    /// loop is closed in the global pass, after tracking.
    pub during_tracking: bool,
}

impl Default for LoopConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            min_consistency: 3,
            gap: 10,
            min_inliers: 20,
            min_guided_matches: 40,
            covisibility_weight: 100,
            ransac_iterations: 300,
            ratio: 0.75,
            confirmations: 3,
            during_tracking: false,
        }
    }
}

/// A keyframe that place recognition found consistent candidates for, with them and
/// their scores.
pub type Found = (KeyFrameKey, Vec<(KeyFrameKey, f64)>);

/// Each keyframe's words (bag of words and direct index).
pub type Words = HashMap<KeyFrameKey, (BowVector, FeatureVector)>;

/// Stages 1 and 2 (place recognition and consistency), apart from the correction:
/// run on each keyframe as local mapping finishes it during the tracking pass (in its
/// own thread or inline, `system::stages::Recognition`).
pub struct PlaceRecognition {
    pub(super) config: LoopConfig,
    database: Database<KeyFrameKey>,
    pub(super) words: Words,
    /// The id of the newest keyframe searched.
    pub newest_id: Option<usize>,
    /// Groups of the previous keyframe's candidates and how many keyframes in a row
    /// each has been seen.
    groups: Vec<(HashSet<KeyFrameKey>, usize)>,
    /// Each keyframe searched that has consistent candidates, in order, with them and
    /// their scores.
    pub found: Vec<Found>,
    /// Candidates that failed the consistency check.
    pub rejected: Vec<Candidate>,
    /// Time spent, milliseconds.
    pub milliseconds: f64,
}

impl PlaceRecognition {
    /// Place recognition over `vocabulary`'s words with `config`.
    pub fn new(vocabulary: &Vocabulary, config: LoopConfig) -> Self {
        Self {
            config,
            database: Database::new(vocabulary),
            words: HashMap::new(),
            newest_id: None,
            groups: Vec::new(),
            found: Vec::new(),
            rejected: Vec::new(),
            milliseconds: 0.0,
        }
    }

    /// Its config.
    pub fn config(&self) -> &LoopConfig {
        &self.config
    }

    /// The words of every keyframe already in `map` (a loaded one), in the database
    /// without a search: later keyframes can find them.
    pub fn seed(&mut self, vocabulary: &Vocabulary, map: &Map) {
        use rayon::prelude::*;
        let start = std::time::Instant::now();
        let keys = map.keyframe_order();
        let words: Vec<_> = keys
            .par_iter()
            .map(|k| vocabulary.transform(&map.keyframes()[*k].frame.descriptors))
            .collect();
        for (key, words) in keys.iter().zip(words) {
            self.database.add(*key, &words.0);
            self.words.insert(*key, words);
        }
        self.milliseconds += start.elapsed().as_secs_f64() * 1e3;
    }

    /// The keyframe's words, its consistent candidates (searched once the database
    /// holds `gap` keyframes), then it joins the database.
    pub fn process(&mut self, vocabulary: &Vocabulary, map: &Map, key: KeyFrameKey) {
        if let Some(kf) = map.keyframes().get(key) {
            let start = std::time::Instant::now();
            let words = vocabulary.transform(&kf.frame.descriptors);
            self.milliseconds += start.elapsed().as_secs_f64() * 1e3;
            self.process_with_words(map, key, words);
        }
    }

    /// [`Self::process`] with the words already computed (outside the map's lock).
    pub fn process_with_words(
        &mut self,
        map: &Map,
        key: KeyFrameKey,
        words: (BowVector, FeatureVector),
    ) {
        let start = std::time::Instant::now();
        if !map.keyframes().contains_key(key) {
            return;
        }
        self.words.insert(key, words);
        self.newest_id = Some(map.keyframes()[key].id);
        let candidates = if self.database.len() >= self.config.gap {
            self.consistent_candidates(map, key)
        } else {
            Vec::new()
        };
        self.database.add(key, &self.words[&key].0);
        if !candidates.is_empty() {
            self.found.push((key, candidates));
        }
        self.milliseconds += start.elapsed().as_secs_f64() * 1e3;
    }

    /// Stages 1 and 2: the candidates consistent over enough keyframes, with scores.
    fn consistent_candidates(&mut self, map: &Map, key: KeyFrameKey) -> Vec<(KeyFrameKey, f64)> {
        let kf = &map.keyframes()[key];
        let bow = &self.words[&key].0;
        let connected: HashSet<KeyFrameKey> = kf.connections.iter().map(|(k, _)| *k).collect();
        let min_score = connected
            .iter()
            .filter_map(|k| self.words.get(k))
            .map(|(b, _)| Vocabulary::score(bow, b))
            .fold(f64::INFINITY, f64::min);
        let min_score = if min_score.is_finite() {
            min_score
        } else {
            0.0
        };
        let hits = self.database.query(bow, |k| {
            k != key && !connected.contains(&k) && map.keyframes().contains_key(k)
        });
        let max_common = hits.iter().map(|h| h.common).max().unwrap_or(0);
        let hits: Vec<_> = hits
            .into_iter()
            .filter(|h| h.score >= min_score && h.common as f64 >= 0.8 * max_common as f64)
            .collect();
        let candidates = best_of_groups(map, &hits);
        // Consistency with the previous keyframes' groups.
        let mut next_groups: Vec<(HashSet<KeyFrameKey>, usize)> = Vec::new();
        let mut enough = Vec::new();
        for &(c, score) in &candidates {
            let mut group: HashSet<KeyFrameKey> = map.keyframes()[c]
                .connections
                .iter()
                .map(|(k, _)| *k)
                .collect();
            group.insert(c);
            let mut count = 1;
            for (previous, n) in &self.groups {
                if previous.iter().any(|k| group.contains(k)) {
                    count = count.max(n + 1);
                }
            }
            if count >= self.config.min_consistency {
                enough.push((c, score));
            } else {
                let reject = LoopReject::Inconsistent {
                    count,
                    needed: self.config.min_consistency,
                };
                self.rejected.push(Candidate::new(
                    LoopPair::of(
                        map,
                        LoopKeys {
                            keyframe: key,
                            matched: c,
                        },
                    ),
                    score,
                    LoopOutcome::Rejected(reject),
                ));
            }
            next_groups.push((group, count));
        }
        self.groups = next_groups;
        enough
    }
}

/// Each hit's score accumulated with its covisible hits' (its 10 best), the best
/// keyframe of each group kept where the group's total reaches 75 % of the best total.
fn best_of_groups(map: &Map, hits: &[Hit<KeyFrameKey>]) -> Vec<(KeyFrameKey, f64)> {
    let scores: HashMap<KeyFrameKey, f64> = hits.iter().map(|h| (h.id, h.score)).collect();
    let mut grouped: Vec<(KeyFrameKey, f64, f64)> = Vec::new();
    for h in hits {
        let (mut best, mut best_score, mut total) = (h.id, h.score, h.score);
        for n in map.keyframes()[h.id].best_covisible(10) {
            if let Some(&s) = scores.get(&n) {
                total += s;
                if s > best_score {
                    (best, best_score) = (n, s);
                }
            }
        }
        grouped.push((best, best_score, total));
    }
    let best_total = grouped.iter().map(|g| g.2).fold(0.0, f64::max);
    let mut candidates: Vec<(KeyFrameKey, f64)> = Vec::new();
    for (k, s, total) in grouped {
        if total >= 0.75 * best_total && !candidates.iter().any(|(c, _)| *c == k) {
            candidates.push((k, s));
        }
    }
    candidates
}
