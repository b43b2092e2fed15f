//! Even spreading of keypoints over a level (ORB-SLAM2's quadtree, §III-A of the
//! ORB-SLAM paper): the region is split into quadrants, largest nodes first, until
//! there are as many nodes as wanted keypoints or no node holds more than one; each
//! node then keeps its strongest keypoint.

use std::collections::BinaryHeap;

/// A node: its rectangle and the indices of the points inside.
struct Node {
    x0: f32,
    y0: f32,
    x1: f32,
    y1: f32,
    points: Vec<usize>,
}

impl Node {
    fn area(&self) -> f32 {
        (self.x1 - self.x0) * (self.y1 - self.y0)
    }

    fn split(self, positions: &[(f32, f32)]) -> Vec<Node> {
        let (mx, my) = ((self.x0 + self.x1) * 0.5, (self.y0 + self.y1) * 0.5);
        let mut children = [
            (self.x0, self.y0, mx, my),
            (mx, self.y0, self.x1, my),
            (self.x0, my, mx, self.y1),
            (mx, my, self.x1, self.y1),
        ]
        .map(|(x0, y0, x1, y1)| Node {
            x0,
            y0,
            x1,
            y1,
            points: Vec::new(),
        });
        for i in self.points {
            let (x, y) = positions[i];
            let child = (x >= mx) as usize + 2 * (y >= my) as usize;
            children[child].points.push(i);
        }
        children
            .into_iter()
            .filter(|c| !c.points.is_empty())
            .collect()
    }
}

/// Picks at most `wanted` of the points (`positions` with `responses`) spread over the
/// rectangle `[x0, x1) × [y0, y1)`; returns their indices.
pub fn spread(
    positions: &[(f32, f32)],
    responses: &[f32],
    rect: (f32, f32, f32, f32),
    wanted: usize,
) -> Vec<usize> {
    if positions.is_empty() || wanted == 0 {
        return Vec::new();
    }
    let (x0, y0, x1, y1) = rect;
    // Start with square-ish root nodes side by side, as many as the aspect ratio says.
    let roots = ((x1 - x0) / (y1 - y0).max(1.0)).round().max(1.0) as usize;
    let step = (x1 - x0) / roots as f32;
    let mut finished: Vec<Node> = Vec::new();
    let mut heap: BinaryHeap<(u64, usize)> = BinaryHeap::new();
    let mut nodes: Vec<Option<Node>> = Vec::new();
    let mut live = 0usize;
    let push = |node: Node,
                heap: &mut BinaryHeap<(u64, usize)>,
                nodes: &mut Vec<Option<Node>>,
                finished: &mut Vec<Node>| {
        if node.points.len() == 1 || node.area() < 1.0 {
            finished.push(node);
        } else {
            // Larger areas first; among equal areas, fuller nodes first.
            let key = ((node.area() as u64) << 20) | node.points.len().min(0xFFFFF) as u64;
            heap.push((key, nodes.len()));
            nodes.push(Some(node));
        }
    };
    let mut root_nodes: Vec<Node> = (0..roots)
        .map(|r| Node {
            x0: x0 + r as f32 * step,
            y0,
            x1: x0 + (r + 1) as f32 * step,
            y1,
            points: Vec::new(),
        })
        .collect();
    for (i, &(x, _)) in positions.iter().enumerate() {
        let r = (((x - x0) / step) as usize).min(roots - 1);
        root_nodes[r].points.push(i);
    }
    for node in root_nodes.into_iter().filter(|n| !n.points.is_empty()) {
        live += 1;
        push(node, &mut heap, &mut nodes, &mut finished);
    }
    while live < wanted {
        let Some((_, index)) = heap.pop() else { break };
        let node = nodes[index].take().expect("each node is split once");
        let children = node.split(positions);
        live += children.len() - 1;
        for child in children {
            push(child, &mut heap, &mut nodes, &mut finished);
        }
    }
    finished.extend(nodes.into_iter().flatten());
    let best = |node: &Node| {
        *node
            .points
            .iter()
            .max_by(|&&a, &&b| responses[a].total_cmp(&responses[b]).then(b.cmp(&a)))
            .expect("nodes are never empty")
    };
    let mut chosen: Vec<usize> = finished.iter().map(best).collect();
    if chosen.len() > wanted {
        chosen.sort_by(|&a, &b| responses[b].total_cmp(&responses[a]).then(a.cmp(&b)));
        chosen.truncate(wanted);
    }
    chosen.sort_unstable();
    chosen
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::Rng;

    #[test]
    fn a_dense_cluster_does_not_take_the_whole_budget() {
        let mut rng = Rng::new(3);
        // 900 strong points in one corner, 100 weak ones spread over the rest.
        let mut positions = Vec::new();
        let mut responses = Vec::new();
        for _ in 0..900 {
            positions.push((rng.range(0.0, 40.0) as f32, rng.range(0.0, 40.0) as f32));
            responses.push(100.0);
        }
        for _ in 0..100 {
            positions.push((rng.range(0.0, 400.0) as f32, rng.range(0.0, 300.0) as f32));
            responses.push(10.0);
        }
        let chosen = spread(&positions, &responses, (0.0, 0.0, 400.0, 300.0), 150);
        assert!(chosen.len() <= 150 && chosen.len() > 100);
        let outside = chosen
            .iter()
            .filter(|&&i| positions[i].0 > 40.0 || positions[i].1 > 40.0)
            .count();
        // Most of the spread-out points survive; the cluster is thinned.
        assert!(outside > 70, "{outside}");
    }

    #[test]
    fn fewer_points_than_wanted_are_all_kept() {
        let positions = vec![(1.0, 1.0), (50.0, 50.0), (90.0, 10.0)];
        let chosen = spread(&positions, &[1.0, 2.0, 3.0], (0.0, 0.0, 100.0, 100.0), 10);
        assert_eq!(chosen, vec![0, 1, 2]);
        assert!(spread(&positions, &[1.0, 2.0, 3.0], (0.0, 0.0, 100.0, 100.0), 0).is_empty());
    }
}
