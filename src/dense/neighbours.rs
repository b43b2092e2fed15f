//! Nearest-neighbour queries on point sets (a kiddo k-d tree).

use std::num::NonZeroUsize;

use kiddo::{ImmutableKdTree, SquaredEuclidean};

/// A k-d tree over points; items are indices into the slice it was built from.
pub struct PointIndex {
    tree: Option<ImmutableKdTree<f32, 3>>,
}

impl PointIndex {
    /// The index over `points`.
    pub fn new(points: &[[f32; 3]]) -> Self {
        Self {
            tree: (!points.is_empty())
                .then(|| ImmutableKdTree::new_from_slice(points).ok())
                .flatten(),
        }
    }

    /// The distance from `query` to its nearest point (infinite for an empty set).
    pub fn nearest_distance(&self, query: &[f32; 3]) -> f32 {
        match &self.tree {
            Some(tree) => tree
                .query(query)
                .nearest_one::<SquaredEuclidean<f32>>()
                .execute()
                .distance
                .sqrt(),
            None => f32::INFINITY,
        }
    }

    /// Nearest distances of many queries (in parallel).
    pub fn nearest_distances(&self, queries: &[[f32; 3]]) -> Vec<f32> {
        use rayon::prelude::*;
        queries
            .par_iter()
            .map(|q| self.nearest_distance(q))
            .collect()
    }

    /// The `k` nearest points as `(index, distance)`, nearest first.
    pub fn nearest(&self, query: &[f32; 3], k: usize) -> Vec<(u32, f32)> {
        let (Some(tree), Some(k)) = (&self.tree, NonZeroUsize::new(k)) else {
            return Vec::new();
        };
        tree.query(query)
            .nearest_n::<SquaredEuclidean<f32>>(k)
            .execute()
            .into_iter()
            .map(|r| (r.item, r.distance.sqrt()))
            .collect()
    }
}
