//! Marching cubes (Lorensen and Cline 1987) over a sparse TSDF volume, to a welded,
//! coloured triangle mesh.
//!
//! The case table is built at first use rather than typed in: for each of the 256
//! sign patterns of a cube's corners, every face contributes segments between its
//! crossed edges (on a face with four crossings the inside corners are cut off
//! separately, a rule that neighbouring cubes share, so the mesh is closed); the
//! segments chain into loops, each loop is fanned into triangles and oriented so
//! that its normal points from the inside (\(F < 0\)) to the outside. On an edge
//! from corner \(a\) to \(b\) the vertex sits where the linear interpolation of the
//! field crosses zero, \(p = p_a + \frac{F_a}{F_a - F_b}(p_b - p_a)\).
//! A cube is meshed only when all 8 corners were observed.

use std::sync::OnceLock;

use nalgebra::Vector3;
use rayon::prelude::*;

use super::tsdf::{voxel_index, FxMap, TsdfVolume, BLOCK};
use crate::geometry::mesh::Mesh;

/// Corner `c` of the unit cube: bit 0 x, bit 1 y, bit 2 z.
fn corner(c: usize) -> [usize; 3] {
    [c & 1, (c >> 1) & 1, (c >> 2) & 1]
}

/// The least distance, in voxels, of a vertex from the corners of its edge.
const CORNER_GAP: f32 = 1e-3;

/// The 12 edges as corner pairs: 4 along x, 4 along y, 4 along z.
const EDGES: [(usize, usize); 12] = [
    (0, 1),
    (2, 3),
    (4, 5),
    (6, 7),
    (0, 2),
    (1, 3),
    (4, 6),
    (5, 7),
    (0, 4),
    (1, 5),
    (2, 6),
    (3, 7),
];

/// The 6 faces as corner cycles (consecutive corners share an edge).
const FACES: [[usize; 4]; 6] = [
    [0, 2, 6, 4],
    [1, 3, 7, 5],
    [0, 1, 5, 4],
    [2, 3, 7, 6],
    [0, 1, 3, 2],
    [4, 5, 7, 6],
];

fn edge_between(a: usize, b: usize) -> usize {
    let (a, b) = (a.min(b), a.max(b));
    EDGES
        .iter()
        .position(|&e| e == (a, b))
        .expect("adjacent corners")
}

/// A face's corners in counter-clockwise order seen from outside the cube.
fn face_outside_ccw(face: [usize; 4]) -> [usize; 4] {
    let p = |c: usize| {
        let k = corner(c);
        Vector3::new(k[0] as f64, k[1] as f64, k[2] as f64)
    };
    let axis = (0..3)
        .find(|&a| face.iter().all(|&c| corner(c)[a] == corner(face[0])[a]))
        .expect("a face has a constant axis");
    let mut outward = Vector3::zeros();
    outward[axis] = if corner(face[0])[axis] == 1 {
        1.0
    } else {
        -1.0
    };
    let turn = (p(face[1]) - p(face[0])).cross(&(p(face[2]) - p(face[1])));
    if turn.dot(&outward) > 0.0 {
        face
    } else {
        [face[3], face[2], face[1], face[0]]
    }
}

/// The triangles (as edge triples) of sign pattern `case` (bit c set: corner c inside).
///
/// On each face (corners counter-clockwise seen from outside) every run of inside
/// corners gives a directed segment from the crossed edge after the run to the one
/// before it, so that the inside lies on its left; a face with four crossings has two
/// runs of one corner (inside corners cut off separately). A face shared by two
/// cubes is seen from opposite sides, so its segment runs one way in each: the
/// surface is closed and consistently oriented. The segments chain into loops, fanned
/// into triangles, wound so that their normals point to the outside (\(F > 0\)).
fn triangles_of(case: usize) -> Vec<[u8; 3]> {
    let inside = |c: usize| case >> c & 1 == 1;
    // next[e] = the edge that the segment starting at edge e ends at.
    let mut next = [usize::MAX; 12];
    for face in FACES {
        let f = face_outside_ccw(face);
        let edge = |k: usize| edge_between(f[k % 4], f[(k + 1) % 4]);
        for k in 0..4 {
            // Corner k ends a run of inside corners when the next corner is outside.
            if inside(f[k]) && !inside(f[(k + 1) % 4]) {
                let mut start = k;
                while inside(f[(start + 3) % 4]) && (start + 3) % 4 != k {
                    start = (start + 3) % 4;
                }
                // From the edge after the run to the edge before it.
                next[edge(k)] = edge(start + 3);
            }
        }
    }
    let mut triangles = Vec::new();
    let mut used = [false; 12];
    for first in 0..12 {
        if next[first] == usize::MAX || used[first] {
            continue;
        }
        let mut chain = Vec::new();
        let mut e = first;
        while !used[e] {
            used[e] = true;
            chain.push(e);
            e = next[e];
        }
        // The fan's apex: one whose chords do not run along a cube face (a chord in
        // a face would be drawn by the neighbouring cube too). One always exists.
        let n = chain.len();
        let on_face = |a: usize, b: usize| {
            FACES.iter().any(|f| {
                let has = |e: usize| (0..4).any(|k| edge_between(f[k], f[(k + 1) % 4]) == e);
                has(a) && has(b)
            })
        };
        let apex = (0..n)
            .find(|&a| {
                (0..n)
                    .filter(|&j| j != a && j != (a + 1) % n && j != (a + n - 1) % n)
                    .all(|j| !on_face(chain[a], chain[j]))
            })
            .unwrap_or(0);
        chain.rotate_left(apex);
        for k in 1..n - 1 {
            // Reversed: the segments turn with the inside on their left, seen from
            // outside, so the loop's own normal points inside.
            triangles.push([chain[0] as u8, chain[k + 1] as u8, chain[k] as u8]);
        }
    }
    triangles
}

/// The case table, built once.
fn table() -> &'static Vec<Vec<[u8; 3]>> {
    static TABLE: OnceLock<Vec<Vec<[u8; 3]>>> = OnceLock::new();
    TABLE.get_or_init(|| (0..256).map(triangles_of).collect())
}

/// A voxel's value: field, whether it has a colour, colour.
type Sample = (f32, bool, [u8; 3]);

/// Vertices keyed by (lower corner's global voxel coordinate, edge axis).
type EdgeKey = ([i64; 3], u8);

/// One block's triangles with vertices keyed by their edge.
struct Piece {
    vertices: Vec<(EdgeKey, [f32; 3], [u8; 3])>,
    triangles: Vec<[u32; 3]>,
}

/// The mesh of the zero level set of `volume`, whole in memory (for small volumes and
/// tests; the dense pass streams it: [`extract_with`]); an error only from its spill
/// file.
pub fn extract(volume: &mut TsdfVolume) -> Result<Mesh, crate::io::IoError> {
    let mut mesh = Mesh::default();
    extract_with(volume, |batch| {
        mesh.vertices.extend_from_slice(&batch.vertices);
        mesh.colours.extend_from_slice(&batch.colours);
        mesh.triangles.extend_from_slice(&batch.triangles);
        Ok(())
    })?;
    Ok(mesh)
}

/// A batch of the mesh as it is welded: the vertices new in it (numbered on from the
/// batches before), its triangles (numbers in the whole mesh) and their areas (m²).
#[derive(Debug, Default)]
pub struct MeshBatch {
    /// Positions (metres, world frame) of the vertices new in this batch.
    pub vertices: Vec<[f32; 3]>,
    /// Their colours.
    pub colours: Vec<[u8; 3]>,
    /// Triangles as vertex numbers in the whole mesh.
    pub triangles: Vec<[u32; 3]>,
    /// Each triangle's area, [`crate::geometry::mesh::triangle_area`].
    pub areas: Vec<f64>,
}

/// The mesh of the zero level set of `volume`, handed to `sink` batch by batch (the
/// same vertices and triangles, in the same order, as one mesh of all): no step holds
/// the whole mesh. An error from the volume's spill file or from `sink`.
pub fn extract_with(
    volume: &mut TsdfVolume,
    sink: impl FnMut(MeshBatch) -> Result<(), crate::io::IoError>,
) -> Result<(), crate::io::IoError> {
    extract_in_batches(volume, WELD_BATCH, sink)
}

/// [`extract_with`] in batches of `size` blocks.
fn extract_in_batches(
    volume: &mut TsdfVolume,
    size: usize,
    mut sink: impl FnMut(MeshBatch) -> Result<(), crate::io::IoError>,
) -> Result<(), crate::io::IoError> {
    let table = table();
    let mut welded = Welded::default();
    // Blocks in batches, each welded as it comes (in the blocks' order, as one batch
    // of all would): the pieces of a whole volume, before welding, took several times
    // the mesh's memory (real figures in docs/design.md). A volume with a budget
    // brings each batch's blocks (and their neighbours) into memory first, after
    // sending those it holds to its spill file: meshing then holds one batch's blocks
    // beside the batch of the mesh, not the budget's.
    let total = volume.coords.len();
    for first in (0..total).step_by(size.max(1)) {
        let last = first.saturating_add(size.max(1)).min(total);
        volume.spill_resident()?;
        volume.load_for_meshing(first, last)?;
        let volume = &*volume;
        let pieces: Vec<Piece> = volume.coords[first..last]
            .par_iter()
            .map(|&coord| block_piece(volume, table, coord))
            .collect();
        let mut batch = MeshBatch::default();
        for (number, piece) in (first as u32..).zip(pieces) {
            welded.add(piece, Order { volume, number }, &mut batch);
        }
        welded.forget_before(last as u32);
        sink(batch)?;
    }
    Ok(())
}

/// Blocks meshed in parallel before their pieces are welded.
const WELD_BATCH: usize = 4096;

/// The triangles of the cubes whose lower corner lies in the block at `coord` (cubes
/// reach into the neighbouring blocks).
fn block_piece(volume: &TsdfVolume, table: &[Vec<[u8; 3]>], coord: [i32; 3]) -> Piece {
    let voxel = volume.settings.voxel;
    let mut piece = Piece {
        vertices: Vec::new(),
        triangles: Vec::new(),
    };
    let mut local: FxMap<EdgeKey, u32> = FxMap::default();
    let base = coord.map(|c| c as i64 * BLOCK as i64);
    for z in 0..BLOCK as i64 {
        for y in 0..BLOCK as i64 {
            for x in 0..BLOCK as i64 {
                let origin = [base[0] + x, base[1] + y, base[2] + z];
                let Some((values, case)) = cube_samples(volume, origin) else {
                    continue;
                };
                if table[case].is_empty() {
                    continue;
                }
                let mut vertex_of = |e: u8| -> u32 {
                    let key = edge_key(origin, e);
                    if let Some(&i) = local.get(&key) {
                        return i;
                    }
                    let (position, colour) = edge_vertex(&values, origin, e, voxel);
                    let index = piece.vertices.len() as u32;
                    piece.vertices.push((key, position, colour));
                    local.insert(key, index);
                    index
                };
                for tri in &table[case] {
                    let t = tri.map(&mut vertex_of);
                    if t[0] != t[1] && t[1] != t[2] && t[0] != t[2] {
                        piece.triangles.push(t);
                    }
                }
            }
        }
    }
    piece
}

/// The samples at the 8 corners of the cube with lower corner `origin` (global voxel
/// coordinates) and its case (bit c set where corner c is inside, SDF < 0); `None`
/// where a corner has no observation.
fn cube_samples(volume: &TsdfVolume, origin: [i64; 3]) -> Option<([Sample; 8], usize)> {
    let sample = |g: [i64; 3]| -> Option<Sample> {
        let b = BLOCK as i64;
        let block = [g[0].div_euclid(b), g[1].div_euclid(b), g[2].div_euclid(b)];
        let local = [g[0].rem_euclid(b), g[1].rem_euclid(b), g[2].rem_euclid(b)];
        let blk = volume.block([block[0] as i32, block[1] as i32, block[2] as i32])?;
        let i = voxel_index(local[0] as usize, local[1] as usize, local[2] as usize);
        (blk.weight[i] > 0.0).then(|| (blk.sdf[i], blk.colour_weight[i] > 0, blk.colour[i]))
    };
    let mut values: [Sample; 8] = [(0.0, false, [0; 3]); 8];
    let mut case = 0;
    for (c, value) in values.iter_mut().enumerate() {
        let k = corner(c);
        *value = sample([
            origin[0] + k[0] as i64,
            origin[1] + k[1] as i64,
            origin[2] + k[2] as i64,
        ])?;
        if value.0 < 0.0 {
            case |= 1 << c;
        }
    }
    Some((values, case))
}

/// The key of edge `e` of the cube at `origin`: its lower corner and its axis, shared
/// by the cubes around the edge.
fn edge_key(origin: [i64; 3], e: u8) -> EdgeKey {
    let (a, b) = EDGES[e as usize];
    let (ka, kb) = (corner(a), corner(b));
    let axis = (0..3).find(|&i| ka[i] != kb[i]).expect("an axis");
    let lower = [
        origin[0] + ka[0].min(kb[0]) as i64,
        origin[1] + ka[1].min(kb[1]) as i64,
        origin[2] + ka[2].min(kb[2]) as i64,
    ];
    (lower, axis as u8)
}

/// The vertex on edge `e` of the cube at `origin`: where the SDF crosses zero along
/// the edge (linear interpolation, \(t = f_a / (f_a - f_b)\)), in metres, and its
/// colour.
fn edge_vertex(values: &[Sample; 8], origin: [i64; 3], e: u8, voxel: f64) -> ([f32; 3], [u8; 3]) {
    let (a, b) = EDGES[e as usize];
    let (ka, kb) = (corner(a), corner(b));
    let (fa, fb) = (values[a].0, values[b].0);
    // Kept off the corners: a corner whose value is exactly 0 would give each of its
    // crossed edges a vertex at the same place (duplicates that some readers merge,
    // degenerate triangles).
    let t = (fa / (fa - fb)).clamp(CORNER_GAP, 1.0 - CORNER_GAP);
    let position = [0, 1, 2].map(|i| {
        let pa = (origin[i] + ka[i] as i64) as f64;
        let pb = (origin[i] + kb[i] as i64) as f64;
        ((pa + t as f64 * (pb - pa)) * voxel) as f32
    });
    // A corner seen only as free space has no colour.
    let colour = if values[a].1 == values[b].1 {
        [0, 1, 2].map(|i| {
            let (ca, cb) = (values[a].2[i] as f32, values[b].2[i] as f32);
            (ca + t * (cb - ca)).round() as u8
        })
    } else if values[a].1 {
        values[a].2
    } else {
        values[b].2
    };
    (position, colour)
}

/// The blocks' pieces joined so far, sharing vertices on the edges between blocks.
#[derive(Default)]
struct Welded {
    /// Vertices so far.
    count: u32,
    /// The number of each vertex on an edge between blocks (a quarter of the
    /// vertices: the others belong to one block's piece alone), by its edge, with the
    /// number of the last block whose piece can meet it: it goes once that block is
    /// welded, so the index holds the blocks' frontier, not the route.
    index: FxMap<EdgeKey, (u32, u32)>,
}

/// A block's place in the meshing order: its `number` among `volume`'s blocks.
#[derive(Clone, Copy)]
struct Order<'a> {
    volume: &'a TsdfVolume,
    number: u32,
}

impl Order<'_> {
    /// The last block (in meshing order) whose cubes can have the edge `key`: the
    /// four cubes around an edge along axis \(a\) have their lower corners at the
    /// edge's lower corner less 0 or 1 on each other axis.
    fn last_to_meet(&self, key: &EdgeKey) -> u32 {
        let (lower, axis) = key;
        let (b, c) = match axis {
            0 => (1, 2),
            1 => (0, 2),
            _ => (0, 1),
        };
        let mut last = self.number;
        for k in 0..4 {
            let mut cube = *lower;
            cube[b] -= k & 1;
            cube[c] -= k >> 1;
            let block = cube.map(|c| c.div_euclid(BLOCK as i64) as i32);
            if let Some(n) = self.volume.block_number(block) {
                last = last.max(n);
            }
        }
        last
    }
}

/// Whether the edge `key` can be shared by the cubes of two blocks: the four cubes
/// around an edge along axis \(a\) have their lower corners at the edge's lower corner
/// less 0 or 1 on each other axis, so they fall into more than one block exactly when
/// the edge lies on a block face across one of those axes.
fn on_block_boundary(key: &EdgeKey) -> bool {
    let (lower, axis) = key;
    (0..3).any(|i| i != *axis as usize && lower[i].rem_euclid(BLOCK as i64) == 0)
}

impl Welded {
    /// Adds `piece` (of the block at `order`) to `batch`: its triangles, its vertices
    /// on edges met before taken from there, the others numbered on.
    fn add(&mut self, piece: Piece, order: Order, batch: &mut MeshBatch) {
        let Self { count, index } = self;
        let mut push = |position: &[f32; 3], colour: &[u8; 3]| {
            batch.vertices.push(*position);
            batch.colours.push(*colour);
            *count += 1;
            *count - 1
        };
        let map: Vec<u32> = piece
            .vertices
            .iter()
            .map(|(key, position, colour)| {
                if !on_block_boundary(key) {
                    return push(position, colour);
                }
                if let Some(&(number, _)) = index.get(key) {
                    return number;
                }
                let number = push(position, colour);
                let last = order.last_to_meet(key);
                if last > order.number {
                    index.insert(*key, (number, last));
                }
                number
            })
            .collect();
        for t in &piece.triangles {
            batch.triangles.push(t.map(|i| map[i as usize]));
            let corners = t.map(|i| piece.vertices[i as usize].1);
            batch
                .areas
                .push(crate::geometry::mesh::triangle_area(corners));
        }
    }

    /// Forgets the vertices that no block from `number` on can meet.
    fn forget_before(&mut self, number: u32) {
        self.index.retain(|_, &mut (_, last)| last >= number);
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::dense::tsdf::{TsdfSettings, TsdfVolume};
    use std::collections::HashMap;

    /// Every undirected edge of `mesh` is shared by exactly two triangles, once each way.
    fn assert_closed(mesh: &Mesh) {
        let mut directed: HashMap<(u32, u32), usize> = HashMap::new();
        for t in &mesh.triangles {
            for k in 0..3 {
                *directed.entry((t[k], t[(k + 1) % 3])).or_default() += 1;
            }
        }
        for (&(a, b), &n) in &directed {
            assert_eq!(n, 1, "edge ({a}, {b}) used {n} times one way");
            assert!(
                directed.contains_key(&(b, a)),
                "edge ({a}, {b}) at {:?} is a border",
                mesh.vertices[a as usize]
            );
        }
    }

    /// Random signs on a grid of `side`³ blocks (0.1 m voxels), positive on its outer
    /// layer, the blocks made in a shuffled order: many pieces, large and small, and
    /// many edges between blocks met far apart in the blocks' order.
    pub(crate) fn random_field(side: i32, seed: u64) -> TsdfVolume {
        let settings = TsdfSettings {
            voxel: 0.1,
            ..TsdfSettings::default()
        };
        let mut volume =
            TsdfVolume::new(settings, crate::geometry::camera::PinholeCamera::tum_fr3());
        let mut rng = crate::random::Rng::new(seed);
        let n = side * BLOCK as i32;
        let mut coords: Vec<[i32; 3]> = (0..side * side * side)
            .map(|k| [k % side, k / side % side, k / (side * side)])
            .collect();
        for k in (1..coords.len()).rev() {
            coords.swap(k, (rng.uniform() * (k + 1) as f64) as usize % (k + 1));
        }
        for [bx, by, bz] in coords {
            let block = volume.block_mut([bx, by, bz]).unwrap();
            for i in 0..BLOCK * BLOCK * BLOCK {
                let local = [i % BLOCK, i / BLOCK % BLOCK, i / (BLOCK * BLOCK)];
                let g = [0, 1, 2].map(|k| [bx, by, bz][k] * BLOCK as i32 + local[k] as i32);
                let border = g.iter().any(|&c| c == 0 || c == n - 1);
                let i = voxel_index(local[0], local[1], local[2]);
                block.sdf[i] = if border {
                    0.5
                } else {
                    rng.uniform() as f32 - 0.5
                };
                block.weight[i] = 1.0;
                block.colour[i] = [local[0] as u8 * 30, local[1] as u8 * 30, 90];
                block.colour_weight[i] = 1;
            }
        }
        volume
    }

    #[test]
    fn a_fully_observed_random_field_gives_a_closed_surface() {
        let mesh = extract(&mut random_field(3, 7)).unwrap();
        assert!(mesh.triangles.len() > 1000);
        assert_closed(&mesh);
    }

    /// The weld forgets the vertices no later block can meet: batches of any size give
    /// the same mesh, vertex for vertex, as one batch of every block.
    #[test]
    fn batches_of_any_size_weld_the_same_mesh() {
        let mut volume = random_field(4, 11);
        let whole = |volume: &mut TsdfVolume, size: usize| {
            let mut mesh = Mesh::default();
            let mut areas = Vec::new();
            extract_in_batches(volume, size, |batch| {
                mesh.vertices.extend_from_slice(&batch.vertices);
                mesh.colours.extend_from_slice(&batch.colours);
                mesh.triangles.extend_from_slice(&batch.triangles);
                areas.extend_from_slice(&batch.areas);
                Ok(())
            })
            .unwrap();
            (mesh, areas)
        };
        let (all, areas) = whole(&mut volume, usize::MAX);
        assert!(all.triangles.len() > 5000);
        assert_closed(&all);
        for (t, area) in all.triangles.iter().zip(&areas) {
            let corners = t.map(|i| all.vertices[i as usize]);
            assert_eq!(*area, crate::geometry::mesh::triangle_area(corners));
        }
        for size in [1, 5, 17] {
            assert!(
                whole(&mut volume, size) == (all.clone(), areas.clone()),
                "{size}"
            );
        }
    }

    /// A field that is exactly 0 at some voxels (depth that falls on the lattice) gives
    /// no two vertices at one place.
    #[test]
    fn zeros_on_the_lattice_give_no_duplicate_vertices() {
        let settings = TsdfSettings {
            voxel: 0.1,
            ..TsdfSettings::default()
        };
        let mut volume =
            TsdfVolume::new(settings, crate::geometry::camera::PinholeCamera::tum_fr3());
        for (bx, by) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            let block = volume.block_mut([bx, by, 0]).unwrap();
            for z in 0..BLOCK {
                for y in 0..BLOCK {
                    for x in 0..BLOCK {
                        let i = voxel_index(x, y, z);
                        // A plane z = 4 with a bump: zero on and around the bump's rim.
                        let bump = i32::from((x + y) % 3 == 0);
                        block.sdf[i] = (z as i32 - 4 - bump).clamp(-1, 1) as f32 * 0.5;
                        block.weight[i] = 1.0;
                    }
                }
            }
        }
        let mesh = extract(&mut volume).unwrap();
        assert!(mesh.triangles.len() > 100);
        let mut positions: Vec<[u32; 3]> =
            mesh.vertices.iter().map(|v| v.map(f32::to_bits)).collect();
        let n = positions.len();
        positions.sort_unstable();
        positions.dedup();
        assert_eq!(positions.len(), n, "duplicate vertices");
    }

    #[test]
    fn every_case_is_closed_within_the_cube() {
        let table = table();
        assert!(table[0].is_empty() && table[255].is_empty());
        for (case, triangles) in table.iter().enumerate().take(255).skip(1) {
            assert!(!triangles.is_empty(), "case {case} has no triangle");
            // Each crossed edge carries a vertex.
            let crossed = EDGES
                .iter()
                .enumerate()
                .filter(|(_, &(a, b))| (case >> a & 1) != (case >> b & 1))
                .count();
            let used: std::collections::HashSet<u8> = triangles.iter().flatten().copied().collect();
            assert_eq!(used.len(), crossed, "case {case}");
        }
    }
}
#[cfg(test)]
mod cases {
    use super::*;

    /// Within a cube, no directed edge is used twice.
    #[test]
    fn each_case_is_a_manifold_patch() {
        for case in 0..256usize {
            let t = triangles_of(case);
            let mut seen = std::collections::HashMap::new();
            for tri in &t {
                for k in 0..3 {
                    *seen.entry((tri[k], tri[(k + 1) % 3])).or_insert(0) += 1;
                }
            }
            for (e, n) in &seen {
                assert_eq!(*n, 1, "case {case:08b} edge {e:?} twice: {t:?}");
            }
        }
    }
}
