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

    /// The triangles' total area.
    pub fn surface_area(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| self.vertex(i as usize));
                (b - a).cross(&(c - a)).norm() / 2.0
            })
            .sum()
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
    /// triangles) and `min_area <= 0` keep everything. [`Pieces`] does the same for a
    /// mesh that comes triangle by triangle.
    pub fn without_small_pieces(mut self, min_area: f64) -> (Mesh, Pruned) {
        let mut pieces = Pieces::default();
        pieces.add_vertices(self.vertices.len());
        for &t in &self.triangles {
            pieces.join(t);
        }
        let mut areas = pieces.into_areas();
        for &t in &self.triangles {
            areas.add(t, triangle_area(t.map(|i| self.vertices[i as usize])));
        }
        let kept = areas.keep(min_area);
        if kept.pruned == Pruned::default() {
            return (self, kept.pruned);
        }
        // In place: a second mesh beside this one would double the peak.
        let flags: Vec<bool> = kept.index.iter().map(|&i| i != u32::MAX).collect();
        retain_flagged(&mut self.vertices, &flags);
        retain_flagged(&mut self.colours, &flags);
        retain_flagged(&mut self.normals, &flags);
        self.triangles.retain(|&t| kept.triangle(t).is_some());
        for t in &mut self.triangles {
            *t = t.map(|i| kept.index[i as usize]);
        }
        (self, kept.pruned)
    }
}

/// The area of the triangle with corners `corners` (m²): \(\tfrac12 \lVert (b - a)
/// \times (c - a) \rVert\), in double precision.
pub fn triangle_area(corners: [[f32; 3]; 3]) -> f64 {
    let [a, b, c] = corners.map(|[x, y, z]| Vector3::new(x as f64, y as f64, z as f64));
    (b - a).cross(&(c - a)).norm() / 2.0
}

/// The connected pieces of a mesh's triangles (triangles that share a vertex belong to
/// one piece), built as vertices and triangles come, without the mesh: 6 bytes a
/// vertex. [`Pieces::into_areas`] then sums each piece's area, triangle by triangle in
/// the same order, and [`PieceAreas::keep`] drops the small pieces.
#[derive(Default)]
pub struct Pieces {
    sets: petgraph::unionfind::UnionFind<u32>,
    /// Whether each vertex is in a triangle.
    used: Vec<bool>,
    triangles: usize,
}

impl Pieces {
    /// `n` more vertices, each in a piece of its own until a triangle joins it.
    pub fn add_vertices(&mut self, n: usize) {
        for _ in 0..n {
            self.sets.new_set();
        }
        self.used.resize(self.used.len() + n, false);
    }

    /// Joins the pieces of the triangle `t`'s corners.
    pub fn join(&mut self, [a, b, c]: [u32; 3]) {
        self.sets.union(a, b);
        self.sets.union(a, c);
        for i in [a, b, c] {
            self.used[i as usize] = true;
        }
        self.triangles += 1;
    }

    /// Every triangle joined: each vertex's piece, with no area yet.
    pub fn into_areas(self) -> PieceAreas {
        let n = self.used.len();
        PieceAreas {
            pieces: self.sets.into_labeling(),
            used: self.used,
            area: vec![0.0; n],
            triangles: self.triangles,
        }
    }
}

/// Each vertex's piece (its root vertex) and the area of each piece so far.
pub struct PieceAreas {
    pieces: Vec<u32>,
    used: Vec<bool>,
    /// By root vertex: the area of its piece (m²).
    area: Vec<f64>,
    triangles: usize,
}

impl PieceAreas {
    /// Adds the triangle `t` (joined before) of area `area` (m²) to its piece.
    pub fn add(&mut self, t: [u32; 3], area: f64) {
        self.area[self.pieces[t[0] as usize] as usize] += area;
    }

    /// The vertices in pieces of at least `min_area` (m²), each numbered anew in
    /// order; vertices in no triangle go too. No triangle or `min_area <= 0`: all.
    pub fn keep(self, min_area: f64) -> KeptVertices {
        let Self {
            mut pieces,
            used,
            area,
            triangles,
        } = self;
        if triangles == 0 || min_area <= 0.0 {
            return KeptVertices {
                index: (0..pieces.len() as u32).collect(),
                pruned: Pruned::default(),
            };
        }
        let (mut kept, mut dropped_pieces) = (0u32, 0);
        // In place: each vertex's root becomes its new number.
        for (v, slot) in pieces.iter_mut().enumerate() {
            let root = *slot as usize;
            let small = area[root] < min_area;
            dropped_pieces += usize::from(used[v] && root == v && small);
            *slot = if used[v] && !small { kept } else { u32::MAX };
            kept += u32::from(*slot != u32::MAX);
        }
        let pruned = Pruned {
            pieces: dropped_pieces,
            vertices: pieces.len() - kept as usize,
        };
        KeptVertices {
            index: pieces,
            pruned,
        }
    }
}

/// The vertices [`PieceAreas::keep`] keeps, and what went.
pub struct KeptVertices {
    /// One a vertex: its number among those kept, or `u32::MAX` when it goes.
    pub index: Vec<u32>,
    /// What went.
    pub pruned: Pruned,
}

impl KeptVertices {
    /// The number of vertices kept.
    pub fn len(&self) -> usize {
        self.index.len() - self.pruned.vertices
    }

    /// Whether no vertex is kept.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The triangle `t` renumbered, or `None` when it went (its piece is one).
    pub fn triangle(&self, t: [u32; 3]) -> Option<[u32; 3]> {
        let first = self.index[t[0] as usize];
        (first != u32::MAX).then(|| t.map(|i| self.index[i as usize]))
    }
}

/// Keeps the items of `items` whose flag is set (an empty `items` stays empty).
fn retain_flagged<T>(items: &mut Vec<T>, flags: &[bool]) {
    let mut flags = flags.iter();
    items.retain(|_| flags.next().copied().unwrap_or(false));
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
