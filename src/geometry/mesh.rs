//! A coloured triangle mesh, or a point cloud when it has no triangles.

use nalgebra::Vector3;

/// Vertices (metres, world frame) with optional per-vertex colours and normals, and
/// triangles as vertex indices, counter-clockwise seen from outside.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Mesh {
    /// Positions in metres (world frame).
    pub vertices: Vec<[f32; 3]>,
    /// Empty, or one per vertex.
    pub colours: Vec<[u8; 3]>,
    /// Empty, or one unit normal per vertex.
    pub normals: Vec<[f32; 3]>,
    /// Triangles as vertex indices; empty for a point cloud.
    pub triangles: Vec<[u32; 3]>,
}

impl Mesh {
    /// A point cloud.
    pub fn points(vertices: Vec<[f32; 3]>) -> Self {
        Self {
            vertices,
            ..Self::default()
        }
    }

    /// Whether there is no vertex.
    pub fn is_empty(&self) -> bool {
        self.vertices.is_empty()
    }

    /// The number of vertices.
    pub fn len(&self) -> usize {
        self.vertices.len()
    }

    /// The vertex `i` as a vector.
    pub fn vertex(&self, i: usize) -> Vector3<f64> {
        let [x, y, z] = self.vertices[i];
        Vector3::new(x as f64, y as f64, z as f64)
    }

    /// Checks that colours, normals and triangles refer to the vertices.
    pub fn validate(&self) -> Result<(), String> {
        let n = self.vertices.len();
        if !self.colours.is_empty() && self.colours.len() != n {
            return Err(format!("{} colours for {n} vertices", self.colours.len()));
        }
        if !self.normals.is_empty() && self.normals.len() != n {
            return Err(format!("{} normals for {n} vertices", self.normals.len()));
        }
        if let Some(t) = self
            .triangles
            .iter()
            .find(|t| t.iter().any(|&i| i as usize >= n))
        {
            return Err(format!("triangle {t:?} refers past the {n} vertices"));
        }
        if let Some(v) = self
            .vertices
            .iter()
            .find(|v| v.iter().any(|c| !c.is_finite()))
        {
            return Err(format!("vertex {v:?} is not finite"));
        }
        Ok(())
    }

    /// Area-weighted samples on the triangles, about one per `spacing`² of surface,
    /// at least one per triangle's area share (deterministic: a regular pattern in
    /// barycentric coordinates).
    pub fn sample_surface(&self, spacing: f64) -> Vec<Vector3<f64>> {
        let mut samples = Vec::new();
        for t in &self.triangles {
            let [a, b, c] = t.map(|i| self.vertex(i as usize));
            let area = (b - a).cross(&(c - a)).norm() / 2.0;
            // n subdivisions per side give n² sub-triangles of area/n² each.
            let n = ((area / (spacing * spacing)).sqrt().ceil() as usize).max(1);
            for i in 0..n {
                for j in 0..n - i {
                    let (u, v) = (
                        (i as f64 + 1.0 / 3.0) / n as f64,
                        (j as f64 + 1.0 / 3.0) / n as f64,
                    );
                    samples.push(a + (b - a) * u + (c - a) * v);
                    if i + j + 1 < n {
                        let (u, v) = (
                            (i as f64 + 2.0 / 3.0) / n as f64,
                            (j as f64 + 2.0 / 3.0) / n as f64,
                        );
                        samples.push(a + (b - a) * u + (c - a) * v);
                    }
                }
            }
        }
        samples
    }
}

/// What [`Mesh::without_small_pieces`] took away.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Pruned {
    /// Pieces (connected sets of triangles) removed.
    pub pieces: usize,
    /// Vertices removed with them.
    pub vertices: usize,
}

impl Mesh {
    /// The mesh without its small pieces: triangles that share a vertex belong to one
    /// piece, and a piece whose area \(\sum_t \tfrac12 \lVert (b - a) \times (c - a)
    /// \rVert\) over its triangles is below `min_area` (m²) is dropped with its
    /// vertices, as Open3D's `cluster_connected_triangles` and a size filter do. The
    /// vertices kept keep their order, colours and normals. A point cloud (no
    /// triangles) and `min_area <= 0` keep everything.
    pub fn without_small_pieces(mut self, min_area: f64) -> (Mesh, Pruned) {
        if self.triangles.is_empty() || min_area <= 0.0 {
            return (self, Pruned::default());
        }
        let keep = self.in_large_pieces(min_area);
        // In place: a second mesh beside this one would double the peak.
        let mut index = vec![u32::MAX; keep.flags.len()];
        let mut kept = 0u32;
        for (v, _) in keep.flags.iter().enumerate().filter(|(_, &k)| k) {
            index[v] = kept;
            kept += 1;
        }
        retain_flagged(&mut self.vertices, &keep.flags);
        retain_flagged(&mut self.colours, &keep.flags);
        retain_flagged(&mut self.normals, &keep.flags);
        self.triangles.retain(|t| index[t[0] as usize] != u32::MAX);
        for t in &mut self.triangles {
            *t = t.map(|i| index[i as usize]);
        }
        let pruned = Pruned {
            pieces: keep.pieces_dropped,
            vertices: keep.flags.len() - kept as usize,
        };
        (self, pruned)
    }

    /// Which vertices are in a piece of at least `min_area` (m²), and how many pieces
    /// are not.
    fn in_large_pieces(&self, min_area: f64) -> Kept {
        let mut pieces = petgraph::unionfind::UnionFind::<u32>::new(self.vertices.len());
        // Vertices in no triangle go too.
        let mut used = vec![false; self.vertices.len()];
        for &[a, b, c] in &self.triangles {
            pieces.union(a, b);
            pieces.union(a, c);
            for i in [a, b, c] {
                used[i as usize] = true;
            }
        }
        let mut area = vec![0.0; self.vertices.len()];
        for t in &self.triangles {
            let [a, b, c] = t.map(|i| self.vertex(i as usize));
            area[pieces.find(t[0]) as usize] += (b - a).cross(&(c - a)).norm() / 2.0;
        }
        let dropped = |root: u32| area[root as usize] < min_area;
        let pieces_dropped = (0..self.vertices.len() as u32)
            .filter(|&v| used[v as usize] && pieces.find(v) == v && dropped(v))
            .count();
        let flags = (0..self.vertices.len())
            .map(|v| used[v] && !dropped(pieces.find(v as u32)))
            .collect();
        Kept {
            flags,
            pieces_dropped,
        }
    }
}

/// Keeps the items of `items` whose flag is set (an empty `items` stays empty).
fn retain_flagged<T>(items: &mut Vec<T>, flags: &[bool]) {
    let mut flags = flags.iter();
    items.retain(|_| flags.next().copied().unwrap_or(false));
}

/// The vertices [`Mesh::without_small_pieces`] keeps.
struct Kept {
    /// One a vertex: in a piece large enough.
    flags: Vec<bool>,
    /// Pieces (with a triangle) too small.
    pieces_dropped: usize,
}

/// A unit square at z = 0, two triangles (for tests).
#[cfg(test)]
pub fn unit_square() -> Mesh {
    Mesh {
        vertices: vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
        ],
        triangles: vec![[0, 1, 2], [0, 2, 3]],
        ..Mesh::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_cover_a_square_evenly_inside_it() {
        let mesh = unit_square();
        let samples = mesh.sample_surface(0.1);
        // 1 m² at 0.1 m spacing: about 100 samples, each inside the square.
        assert!((90..=130).contains(&samples.len()), "{}", samples.len());
        assert!(samples
            .iter()
            .all(|p| (0.0..=1.0).contains(&p.x) && (0.0..=1.0).contains(&p.y) && p.z == 0.0));
        assert!(mesh.validate().is_ok());
        let broken = Mesh {
            triangles: vec![[0, 1, 7]],
            ..mesh
        };
        assert!(broken.validate().is_err());
    }

    #[test]
    fn small_pieces_go_and_the_rest_keeps_its_colours() {
        let mut mesh = unit_square();
        mesh.colours = vec![[1, 1, 1]; 4];
        // A separate triangle of 0.005 m², and a vertex in no triangle.
        mesh.vertices.extend([
            [5.0, 0.0, 0.0],
            [5.1, 0.0, 0.0],
            [5.0, 0.1, 0.0],
            [9.0, 9.0, 9.0],
        ]);
        mesh.colours.extend([[2, 2, 2]; 4]);
        mesh.triangles.push([4, 5, 6]);
        // The square's triangles after the small one: indices must be renumbered.
        mesh.triangles.rotate_right(1);
        let (kept, pruned) = mesh.clone().without_small_pieces(0.01);
        assert_eq!(
            pruned,
            Pruned {
                pieces: 1,
                vertices: 4
            }
        );
        assert_eq!(kept.vertices, unit_square().vertices);
        assert_eq!(kept.colours, vec![[1, 1, 1]; 4]);
        assert_eq!(kept.triangles, unit_square().triangles);
        assert!(kept.validate().is_ok());
        // Below the small piece's area everything in a triangle stays.
        let (kept, pruned) = mesh.clone().without_small_pieces(0.004);
        assert_eq!(
            (kept.triangles.len(), pruned.pieces, pruned.vertices),
            (3, 0, 1)
        );
        assert_eq!(mesh.clone().without_small_pieces(0.0).0, mesh);
    }
}
