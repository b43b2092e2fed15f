//! A keyframe database with an inverted index (DBoW2's / ORB-SLAM's): per word, the
//! entries holding it, so a query touches only the entries that share a word with it.

use super::vocabulary::{BowVector, Vocabulary};

/// Entries are identified by the caller's `T` (a keyframe key).
#[derive(Debug, Clone)]
pub struct Database<T: Copy> {
    /// Per word: (entry, weight).
    inverted: Vec<Vec<(u32, f64)>>,
    entries: Vec<T>,
}

/// One query result.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit<T> {
    /// The entry's identifier (a keyframe).
    pub id: T,
    /// The L1 similarity of the two bags of words, in [0, 1].
    pub score: f64,
    /// Words shared with the query.
    pub common: usize,
}

impl<T: Copy> Database<T> {
    /// An empty database over `vocabulary`'s words.
    pub fn new(vocabulary: &Vocabulary) -> Self {
        Self {
            inverted: vec![Vec::new(); vocabulary.len()],
            entries: Vec::new(),
        }
    }

    /// The entries added.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether no entry was added.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// Adds an entry (only its words' inverted lists keep its weights).
    pub fn add(&mut self, id: T, bow: &BowVector) {
        let index = self.entries.len() as u32;
        for &(word, weight) in bow {
            if let Some(list) = self.inverted.get_mut(word as usize) {
                list.push((index, weight));
            }
        }
        self.entries.push(id);
    }

    /// Every entry sharing a word with `bow` and accepted by `keep`, with its L1 score
    /// (accumulated over the shared words only:
    /// \(s = -\tfrac12 \sum_{i \in v \cap w} (|v_i - w_i| - |v_i| - |w_i|)\)), best first.
    pub fn query(&self, bow: &BowVector, keep: impl Fn(T) -> bool) -> Vec<Hit<T>> {
        let mut score = vec![0.0f64; self.entries.len()];
        let mut common = vec![0usize; self.entries.len()];
        for &(word, v) in bow {
            for &(entry, w) in self
                .inverted
                .get(word as usize)
                .map_or(&[][..], |l| l.as_slice())
            {
                score[entry as usize] += (v - w).abs() - v.abs() - w.abs();
                common[entry as usize] += 1;
            }
        }
        let mut hits: Vec<Hit<T>> = self
            .entries
            .iter()
            .enumerate()
            .filter(|(i, id)| common[*i] > 0 && keep(**id))
            .map(|(i, id)| Hit {
                id: *id,
                score: -0.5 * score[i],
                common: common[i],
            })
            .collect();
        hits.sort_by(|a, b| b.score.total_cmp(&a.score));
        hits
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bow::vocabulary::tests::{images, small_vocabulary};

    #[test]
    fn inverted_index_scores_equal_full_scores() {
        let (training, queries) = images(6, 2, 7);
        let vocabulary = small_vocabulary(&training);
        let mut database = Database::new(&vocabulary);
        let bows: Vec<BowVector> = training.iter().map(|i| vocabulary.transform(i).0).collect();
        for (i, b) in bows.iter().enumerate() {
            database.add(i, b);
        }
        let (query, _) = vocabulary.transform(&queries[2]);
        let hits = database.query(&query, |id| id != 5);
        assert!(hits.iter().all(|h| h.id != 5));
        assert_eq!(hits[0].id / 2, 2);
        for h in &hits {
            assert!((h.score - Vocabulary::score(&query, &bows[h.id])).abs() < 1e-12);
        }
    }
}
