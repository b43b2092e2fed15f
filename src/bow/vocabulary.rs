//! A hierarchical vocabulary of binary descriptors (DBoW2's scheme, Gálvez-López and
//! Tardós 2012): a tree of branching `k` and depth `L` built by k-medians on the
//! Hamming space (k-means++ seeding, cluster centres by bitwise majority), leaves are
//! words with an IDF weight \(\log(N / n_i)\) (\(N\) training images, \(n_i\) those
//! holding word \(i\)). An image's bag of words is the TF-IDF vector
//! \(v_i = \tfrac{n_{id}}{n_d}\,\mathrm{idf}_i\), L1-normalised; two images score
//! \(s(v, w) = 1 - \tfrac12 \lVert v - w \rVert_1 \in [0, 1]\).
//!
//! Stored in a compact binary file (`DOPVOC01`, then `k`, `L` and per node its parent,
//! its 32-byte centre and its weight, little endian) that loads in milliseconds.

use std::collections::BTreeMap;
use std::path::Path;

use rayon::prelude::*;

use crate::features::{hamming, Descriptor};
use crate::io::IoError;
use crate::random::Rng;

const MAGIC: &[u8; 8] = b"DOPVOC01";
const NODE_BYTES: usize = 4 + 32 + 4;

/// A sparse bag of words: `(word, weight)` sorted by word, L1-normalised.
pub type BowVector = Vec<(u32, f64)>;

/// Features grouped by their tree node at a coarser level (for guided matching):
/// `(node, feature indices)` sorted by node.
pub type FeatureVector = Vec<(u32, Vec<u32>)>;

#[derive(Debug, Clone, PartialEq)]
struct Node {
    parent: u32,
    centre: Descriptor,
    /// IDF weight for a leaf (0 for inner nodes).
    weight: f32,
    children: Vec<u32>,
    /// The word index for a leaf.
    word: u32,
    depth: u8,
}

impl Node {
    fn root() -> Self {
        Self {
            parent: u32::MAX,
            centre: [0; 4],
            weight: 0.0,
            children: Vec::new(),
            word: u32::MAX,
            depth: 0,
        }
    }
}

/// A trained vocabulary.
#[derive(Debug, Clone, PartialEq)]
pub struct Vocabulary {
    /// Children per node (k).
    pub branching: usize,
    /// Levels below the root (L); the words are the leaves.
    pub depth: usize,
    nodes: Vec<Node>,
    /// Node index of each word.
    words: Vec<u32>,
}

/// How a vocabulary is trained.
#[derive(Debug, Clone, Copy)]
pub struct TrainOptions {
    /// Children per node (k).
    pub branching: usize,
    /// Levels below the root (L).
    pub depth: usize,
    /// k-medians iterations per split.
    pub iterations: usize,
    /// The seed of the k-medians++ initial centres.
    pub seed: u64,
}

impl Default for TrainOptions {
    /// 10 branches, 4 levels: up to 10^4 words.
    fn default() -> Self {
        Self {
            branching: 10,
            depth: 4,
            iterations: 10,
            seed: 1,
        }
    }
}

/// The bitwise majority of descriptors (ties go to 0, as DBoW2's).
fn majority(descriptors: &[Descriptor], members: &[u32]) -> Descriptor {
    let mut counts = [0u32; 256];
    for &m in members {
        let d = &descriptors[m as usize];
        for (k, count) in counts.iter_mut().enumerate() {
            *count += ((d[k / 64] >> (k % 64)) & 1) as u32;
        }
    }
    let mut centre = [0u64; 4];
    for (k, &count) in counts.iter().enumerate() {
        if 2 * count > members.len() as u32 {
            centre[k / 64] |= 1 << (k % 64);
        }
    }
    centre
}

/// k-medians of `members` with k-means++ seeding; the clusters (possibly fewer than `k`).
fn cluster(
    descriptors: &[Descriptor],
    members: &[u32],
    k: usize,
    iterations: usize,
    rng: &mut Rng,
) -> Vec<(Descriptor, Vec<u32>)> {
    if members.len() <= k {
        return members
            .iter()
            .map(|&m| (descriptors[m as usize], vec![m]))
            .collect();
    }
    let mut centres =
        vec![descriptors[members[(rng.next_u64() % members.len() as u64) as usize] as usize]];
    let mut nearest: Vec<f64> = members
        .iter()
        .map(|&m| hamming(&descriptors[m as usize], &centres[0]) as f64)
        .collect();
    while centres.len() < k {
        let total: f64 = nearest.iter().map(|d| d * d).sum();
        if total == 0.0 {
            break;
        }
        let mut target = rng.uniform() * total;
        let mut chosen = members.len() - 1;
        for (i, d) in nearest.iter().enumerate() {
            target -= d * d;
            if target <= 0.0 {
                chosen = i;
                break;
            }
        }
        let c = descriptors[members[chosen] as usize];
        for (n, &m) in nearest.iter_mut().zip(members) {
            *n = n.min(hamming(&descriptors[m as usize], &c) as f64);
        }
        centres.push(c);
    }
    let mut assignment = vec![usize::MAX; members.len()];
    for _ in 0..iterations.max(1) {
        let next: Vec<usize> = members
            .par_iter()
            .map(|&m| {
                let d = &descriptors[m as usize];
                (0..centres.len())
                    .min_by_key(|&c| hamming(d, &centres[c]))
                    .expect("at least one centre")
            })
            .collect();
        if next == assignment {
            break;
        }
        assignment = next;
        for (c, centre) in centres.iter_mut().enumerate() {
            let group: Vec<u32> = members
                .iter()
                .zip(&assignment)
                .filter(|(_, a)| **a == c)
                .map(|(m, _)| *m)
                .collect();
            if !group.is_empty() {
                *centre = majority(descriptors, &group);
            }
        }
    }
    let mut groups: Vec<(Descriptor, Vec<u32>)> =
        centres.into_iter().map(|c| (c, Vec::new())).collect();
    for (&m, &a) in members.iter().zip(&assignment) {
        groups[a].1.push(m);
    }
    groups.retain(|(_, g)| !g.is_empty());
    groups
}

fn read_u32(bytes: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"))
}

impl Vocabulary {
    /// Trains a vocabulary on the descriptors of `images` (one list per image).
    pub fn train(images: &[Vec<Descriptor>], options: &TrainOptions) -> Self {
        let descriptors: Vec<Descriptor> = images.iter().flatten().copied().collect();
        let mut rng = Rng::new(options.seed);
        let mut nodes = vec![Node::root()];
        // Breadth-first splits: (node, members).
        let mut queue = std::collections::VecDeque::from([(
            0u32,
            (0..descriptors.len() as u32).collect::<Vec<_>>(),
        )]);
        while let Some((parent, members)) = queue.pop_front() {
            let depth = nodes[parent as usize].depth;
            if depth as usize >= options.depth || members.is_empty() {
                continue;
            }
            for (centre, group) in cluster(
                &descriptors,
                &members,
                options.branching,
                options.iterations,
                &mut rng,
            ) {
                let id = nodes.len() as u32;
                nodes.push(Node {
                    parent,
                    centre,
                    weight: 0.0,
                    children: Vec::new(),
                    word: u32::MAX,
                    depth: depth + 1,
                });
                nodes[parent as usize].children.push(id);
                queue.push_back((id, group));
            }
        }
        let mut vocabulary = Self::from_nodes(options.branching, options.depth, nodes);
        // IDF: log(N / n_i) over the training images.
        let mut holding = vec![0usize; vocabulary.words.len()];
        for image in images {
            let mut seen: Vec<u32> = image.iter().map(|d| vocabulary.word_of(d).0).collect();
            seen.sort_unstable();
            seen.dedup();
            for w in seen {
                holding[w as usize] += 1;
            }
        }
        let n = images.len().max(1) as f64;
        for (w, &count) in holding.iter().enumerate() {
            let node = vocabulary.words[w] as usize;
            vocabulary.nodes[node].weight = if count == 0 {
                0.0
            } else {
                (n / count as f64).ln() as f32
            };
        }
        vocabulary
    }

    /// Numbers the leaves as words (in node order).
    fn from_nodes(branching: usize, depth: usize, mut nodes: Vec<Node>) -> Self {
        let mut words = Vec::new();
        for (i, node) in nodes.iter_mut().enumerate() {
            if i > 0 && node.children.is_empty() {
                node.word = words.len() as u32;
                words.push(i as u32);
            }
        }
        Self {
            branching,
            depth,
            nodes,
            words,
        }
    }

    /// The number of words (leaves).
    pub fn len(&self) -> usize {
        self.words.len()
    }

    /// Whether the vocabulary has no word.
    pub fn is_empty(&self) -> bool {
        self.words.is_empty()
    }

    /// The word of a descriptor (greedy descent) and its ancestor at depth
    /// `feature_depth` (the node used to group features for matching).
    pub fn word_of_at(&self, d: &Descriptor, feature_depth: usize) -> (u32, u32) {
        let mut node = 0usize;
        let mut at_depth = 0u32;
        while !self.nodes[node].children.is_empty() {
            node = *self.nodes[node]
                .children
                .iter()
                .min_by_key(|&&c| hamming(d, &self.nodes[c as usize].centre))
                .expect("children") as usize;
            if self.nodes[node].depth as usize == feature_depth {
                at_depth = node as u32;
            }
        }
        if at_depth == 0 {
            at_depth = node as u32;
        }
        (self.nodes[node].word, at_depth)
    }

    /// The word of a descriptor.
    pub fn word_of(&self, d: &Descriptor) -> (u32, u32) {
        self.word_of_at(d, self.depth.saturating_sub(2).max(1))
    }

    /// The bag of words of an image and its features grouped by node two levels above
    /// the leaves (DBoW2's `transform(features, bow, fv, levelsup = 2)`).
    pub fn transform(&self, descriptors: &[Descriptor]) -> (BowVector, FeatureVector) {
        let mut bow: BTreeMap<u32, f64> = BTreeMap::new();
        let mut groups: BTreeMap<u32, Vec<u32>> = BTreeMap::new();
        for (i, d) in descriptors.iter().enumerate() {
            let (word, node) = self.word_of(d);
            let weight = self.nodes[self.words[word as usize] as usize].weight as f64;
            if weight > 0.0 {
                *bow.entry(word).or_default() += weight;
            }
            groups.entry(node).or_default().push(i as u32);
        }
        let total: f64 = bow.values().sum();
        let bow = bow
            .into_iter()
            .map(|(w, v)| (w, if total > 0.0 { v / total } else { 0.0 }))
            .collect();
        (bow, groups.into_iter().collect())
    }

    /// DBoW2's L1 score \(1 - \tfrac12 \lVert v - w \rVert_1\) of two normalised vectors.
    pub fn score(a: &BowVector, b: &BowVector) -> f64 {
        let (mut i, mut j, mut s) = (0, 0, 0.0);
        while i < a.len() && j < b.len() {
            match a[i].0.cmp(&b[j].0) {
                std::cmp::Ordering::Less => i += 1,
                std::cmp::Ordering::Greater => j += 1,
                std::cmp::Ordering::Equal => {
                    let (x, y) = (a[i].1, b[j].1);
                    s += (x - y).abs() - x.abs() - y.abs();
                    i += 1;
                    j += 1;
                }
            }
        }
        -0.5 * s
    }

    /// The binary file's bytes.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut bytes = Vec::with_capacity(20 + self.nodes.len() * NODE_BYTES);
        bytes.extend_from_slice(MAGIC);
        bytes.extend_from_slice(&(self.branching as u32).to_le_bytes());
        bytes.extend_from_slice(&(self.depth as u32).to_le_bytes());
        bytes.extend_from_slice(&((self.nodes.len() - 1) as u32).to_le_bytes());
        // Parents come before children (breadth-first order), so a reader can link
        // each node as it goes.
        for node in &self.nodes[1..] {
            bytes.extend_from_slice(&node.parent.to_le_bytes());
            for word in node.centre {
                bytes.extend_from_slice(&word.to_le_bytes());
            }
            bytes.extend_from_slice(&node.weight.to_le_bytes());
        }
        bytes
    }

    /// Reads the binary file's bytes; `Err` says what is wrong.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, String> {
        if bytes.len() < 20 || &bytes[..8] != MAGIC {
            return Err("not a dopslam vocabulary (no DOPVOC01 header)".into());
        }
        let branching = read_u32(bytes, 8) as usize;
        let depth = read_u32(bytes, 12) as usize;
        let count = read_u32(bytes, 16) as usize;
        if branching < 2 || depth < 1 {
            return Err(format!(
                "a vocabulary needs branching k >= 2 and depth L >= 1; the header says k = {branching}, L = {depth}"
            ));
        }
        if bytes.len() != 20 + count * NODE_BYTES {
            return Err(format!(
                "{} bytes, but {count} nodes need {}: the file is truncated or corrupt",
                bytes.len(),
                20 + count * NODE_BYTES
            ));
        }
        let mut nodes = Vec::with_capacity(count + 1);
        nodes.push(Node::root());
        for i in 0..count {
            let at = 20 + i * NODE_BYTES;
            let parent = read_u32(bytes, at);
            if parent as usize >= nodes.len() {
                return Err(format!(
                    "node {} names parent {parent}, not before it",
                    i + 1
                ));
            }
            let mut centre = [0u64; 4];
            for (k, c) in centre.iter_mut().enumerate() {
                *c = u64::from_le_bytes(
                    bytes[at + 4 + 8 * k..at + 12 + 8 * k]
                        .try_into()
                        .expect("8 bytes"),
                );
            }
            let weight = f32::from_le_bytes(bytes[at + 36..at + 40].try_into().expect("4 bytes"));
            let depth = nodes[parent as usize].depth + 1;
            nodes[parent as usize].children.push((i + 1) as u32);
            nodes.push(Node {
                parent,
                centre,
                weight,
                children: Vec::new(),
                word: u32::MAX,
                depth,
            });
        }
        let vocabulary = Self::from_nodes(branching, depth, nodes);
        if vocabulary.len() < 2 {
            return Err(format!(
                "{} word(s): a vocabulary that can tell places apart needs more (train it on images with texture)",
                vocabulary.len()
            ));
        }
        Ok(vocabulary)
    }

    /// Reads a vocabulary file.
    pub fn read(path: &Path) -> Result<Self, IoError> {
        let bytes = std::fs::read(path).map_err(|source| IoError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_bytes(&bytes).map_err(|message| IoError::invalid(path, message))
    }

    /// Writes the vocabulary atomically.
    pub fn write(&self, path: &Path) -> Result<(), IoError> {
        crate::io::atomic::write_atomic(path, &self.to_bytes())
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// `places` random prototype descriptor sets; each image is a place's set with a few
    /// bits flipped per descriptor.
    pub fn images(
        places: usize,
        per_place: usize,
        seed: u64,
    ) -> (Vec<Vec<Descriptor>>, Vec<Vec<Descriptor>>) {
        let mut rng = Rng::new(seed);
        let prototypes: Vec<Vec<Descriptor>> = (0..places)
            .map(|_| {
                (0..200)
                    .map(|_| {
                        [
                            rng.next_u64(),
                            rng.next_u64(),
                            rng.next_u64(),
                            rng.next_u64(),
                        ]
                    })
                    .collect()
            })
            .collect();
        let view = |rng: &mut Rng, place: &Vec<Descriptor>| -> Vec<Descriptor> {
            let mut seen = Vec::new();
            for d in place {
                if rng.uniform() < 0.8 {
                    let mut d = *d;
                    for _ in 0..8 {
                        let bit = rng.next_u64() % 256;
                        d[(bit / 64) as usize] ^= 1 << (bit % 64);
                    }
                    seen.push(d);
                }
            }
            seen
        };
        let training = prototypes
            .iter()
            .flat_map(|p| {
                (0..per_place)
                    .map(|_| view(&mut rng, p))
                    .collect::<Vec<_>>()
            })
            .collect();
        let queries = prototypes.iter().map(|p| view(&mut rng, p)).collect();
        (training, queries)
    }

    /// A three-level vocabulary of `training`.
    pub fn small_vocabulary(training: &[Vec<Descriptor>]) -> Vocabulary {
        Vocabulary::train(
            training,
            &TrainOptions {
                depth: 3,
                ..TrainOptions::default()
            },
        )
    }

    #[test]
    fn a_revisited_place_scores_its_own_images_first() {
        let (training, queries) = images(12, 2, 3);
        let vocabulary = small_vocabulary(&training);
        assert!(vocabulary.len() > 300, "{} words", vocabulary.len());
        let database: Vec<BowVector> = training.iter().map(|i| vocabulary.transform(i).0).collect();
        for (place, query) in queries.iter().enumerate() {
            let (bow, _) = vocabulary.transform(query);
            let best = (0..database.len())
                .max_by(|&a, &b| {
                    Vocabulary::score(&bow, &database[a])
                        .total_cmp(&Vocabulary::score(&bow, &database[b]))
                })
                .unwrap();
            assert_eq!(best / 2, place);
            let own = Vocabulary::score(&bow, &database[best]);
            assert!((0.0..=1.0).contains(&own) && own > 0.2, "{own}");
        }
        let (bow, _) = vocabulary.transform(&queries[0]);
        assert!((Vocabulary::score(&bow, &bow) - 1.0).abs() < 1e-9);
    }

    #[test]
    fn the_binary_file_reads_back_the_same_vocabulary() {
        let (training, _) = images(4, 2, 5);
        let vocabulary = small_vocabulary(&training);
        let back = Vocabulary::from_bytes(&vocabulary.to_bytes()).unwrap();
        assert_eq!(back, vocabulary);
        let mut bytes = vocabulary.to_bytes();
        bytes.truncate(bytes.len() - 3);
        assert!(Vocabulary::from_bytes(&bytes)
            .unwrap_err()
            .contains("truncated"));
        assert!(Vocabulary::from_bytes(b"hello world, this is no vocabulary").is_err());
    }
}
