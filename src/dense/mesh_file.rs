//! The dense mesh kept on disk while it is made and written (issue 83: no step holds
//! the whole mesh). Marching cubes hands it over batch by batch
//! ([`super::marching_cubes::extract_with`]): the vertices (position and colour, 15
//! bytes) and the triangles (vertex numbers and area, 20 bytes) are appended to two
//! spill files in the output folder, and only the pieces' bookkeeping stays in memory
//! ([`Pieces`]: 6 bytes a vertex). The small pieces are then dropped
//! ([`MeshOnDisk::prune`]: each vertex's new number, 4 bytes), and the files (PLY,
//! OBJ) are written from the spill files piece by piece, the same bytes as the whole
//! mesh written by [`crate::io::ply::write_ply`] and [`crate::io::ply::write_obj`].
//! The spill files go with the mesh.

use std::io::Write;
use std::path::Path;

use super::cloud::Sample;
use super::marching_cubes::{extract_with, MeshBatch};
use super::tsdf::TsdfVolume;
use crate::geometry::mesh::{KeptVertices, Mesh, Pieces, Pruned};
use crate::io::atomic::write_atomic_with;
use crate::io::ply::{write_obj_faces, write_obj_head, write_obj_vertices};
use crate::io::ply::{PlyEncoding, PlyMeshRows};
use crate::io::spill::SpillFile;
use crate::io::IoError;

/// Bytes of a vertex's record: position (3 × f32) and colour (3 × u8).
const VERTEX: usize = 15;
/// Bytes of a triangle's record: vertex numbers (3 × u32) and area (f64).
const TRIANGLE: usize = 20;
/// Records read back at a time.
const READ: usize = 1 << 16;

/// A mesh made by marching cubes, its vertices and triangles in spill files.
pub struct MeshOnDisk {
    vertices: SpillFile,
    triangles: SpillFile,
    pieces: Pieces,
}

impl MeshOnDisk {
    /// Meshes `volume` into spill files in `dir`.
    pub fn extract(volume: &mut TsdfVolume, dir: &Path) -> Result<Self, IoError> {
        let mut mesh = Self {
            vertices: SpillFile::create(dir, "mesh-vertices", VERTEX)?,
            triangles: SpillFile::create(dir, "mesh-triangles", TRIANGLE)?,
            pieces: Pieces::default(),
        };
        extract_with(volume, |batch| mesh.append(batch))?;
        Ok(mesh)
    }

    fn append(&mut self, batch: MeshBatch) -> Result<(), IoError> {
        let mut bytes = Vec::with_capacity(batch.vertices.len() * VERTEX);
        for (position, colour) in batch.vertices.iter().zip(&batch.colours) {
            for c in position {
                bytes.extend_from_slice(&c.to_le_bytes());
            }
            bytes.extend_from_slice(colour);
        }
        self.vertices.append(&bytes)?;
        self.pieces.add_vertices(batch.vertices.len());
        bytes.clear();
        for (&t, area) in batch.triangles.iter().zip(&batch.areas) {
            self.pieces.join(t);
            for i in t {
                bytes.extend_from_slice(&i.to_le_bytes());
            }
            bytes.extend_from_slice(&area.to_le_bytes());
        }
        self.triangles.append(&bytes)?;
        Ok(())
    }

    /// The mesh without its pieces of less than `min_area` (m²), as
    /// [`Mesh::without_small_pieces`] gives it.
    pub fn prune(self, min_area: f64) -> Result<PrunedMesh, IoError> {
        let mut areas = self.pieces.into_areas();
        each_piece(&self.triangles, TRIANGLE, |bytes| {
            for record in bytes.chunks_exact(TRIANGLE) {
                let (t, area) = triangle(record);
                areas.add(t, area);
            }
            Ok(())
        })?;
        let kept = areas.keep(min_area);
        let mut triangles_kept = 0;
        each_piece(&self.triangles, TRIANGLE, |bytes| {
            let records = bytes.chunks_exact(TRIANGLE);
            triangles_kept += records
                .filter(|record| kept.triangle(triangle(record).0).is_some())
                .count();
            Ok(())
        })?;
        Ok(PrunedMesh {
            vertices: self.vertices,
            triangles: self.triangles,
            kept,
            triangles_kept,
        })
    }
}

/// The vertex numbers and the area in a triangle's record.
fn triangle(record: &[u8]) -> ([u32; 3], f64) {
    let word = |k: usize| u32::from_le_bytes(record[4 * k..4 * k + 4].try_into().expect("4"));
    let area = f64::from_le_bytes(record[12..20].try_into().expect("8"));
    ([word(0), word(1), word(2)], area)
}

/// The position and colour in a vertex's record.
fn vertex(record: &[u8]) -> ([f32; 3], [u8; 3]) {
    let float = |k: usize| f32::from_le_bytes(record[4 * k..4 * k + 4].try_into().expect("4"));
    (
        [float(0), float(1), float(2)],
        [record[12], record[13], record[14]],
    )
}

/// Hands `each` the records of `record` bytes in `file`, [`READ`] at a time.
fn each_piece(
    file: &SpillFile,
    record: usize,
    mut each: impl FnMut(&[u8]) -> Result<(), IoError>,
) -> Result<(), IoError> {
    let count = file.bytes() as usize / record;
    let mut bytes = vec![0; READ * record];
    for first in (0..count).step_by(READ) {
        let n = READ.min(count - first);
        file.read_at((first * record) as u64, &mut bytes[..n * record])?;
        each(&bytes[..n * record])?;
    }
    Ok(())
}

/// The mesh without its small pieces, still on disk, ready to be written.
pub struct PrunedMesh {
    vertices: SpillFile,
    triangles: SpillFile,
    kept: KeptVertices,
    triangles_kept: usize,
}

impl PrunedMesh {
    /// The vertices kept.
    pub fn len(&self) -> usize {
        self.kept.len()
    }

    /// Whether no vertex is kept.
    pub fn is_empty(&self) -> bool {
        self.kept.is_empty()
    }

    /// The triangles kept.
    pub fn triangles(&self) -> usize {
        self.triangles_kept
    }

    /// What went with the small pieces.
    pub fn pruned(&self) -> Pruned {
        self.kept.pruned
    }

    /// Hands `each` the vertices kept (positions and colours), piece by piece in order.
    fn each_vertices(
        &self,
        mut each: impl FnMut(&Mesh) -> Result<(), IoError>,
    ) -> Result<(), IoError> {
        let mut piece = Mesh::default();
        let mut number = 0;
        each_piece(&self.vertices, VERTEX, |bytes| {
            piece.vertices.clear();
            piece.colours.clear();
            for record in bytes.chunks_exact(VERTEX) {
                if self.kept.index[number] != u32::MAX {
                    let (position, colour) = vertex(record);
                    piece.vertices.push(position);
                    piece.colours.push(colour);
                }
                number += 1;
            }
            each(&piece)
        })
    }

    /// Hands `each` the triangles kept (numbered among the vertices kept), piece by
    /// piece in order.
    fn each_triangles(
        &self,
        mut each: impl FnMut(&[[u32; 3]]) -> Result<(), IoError>,
    ) -> Result<(), IoError> {
        let mut piece = Vec::new();
        each_piece(&self.triangles, TRIANGLE, |bytes| {
            piece.clear();
            let kept = bytes.chunks_exact(TRIANGLE);
            piece.extend(kept.filter_map(|record| self.kept.triangle(triangle(record).0)));
            each(&piece)
        })
    }

    /// Writes the mesh to `path` as PLY (atomically).
    pub fn write_ply(
        &self,
        path: &Path,
        encoding: PlyEncoding,
        comment: &str,
    ) -> Result<(), IoError> {
        let rows = PlyMeshRows::coloured(encoding, comment, self.len(), self.triangles());
        write_atomic_with(path, |out| {
            rows.header(out)?;
            self.each_vertices(|piece| rows.vertices(out, piece).map_err(failed(path)))
                .map_err(std::io::Error::other)?;
            self.each_triangles(|piece| rows.faces(out, piece).map_err(failed(path)))
                .map_err(std::io::Error::other)
        })
    }

    /// Writes the mesh to `path` as OBJ (atomically).
    pub fn write_obj(&self, path: &Path, comment: &str) -> Result<(), IoError> {
        write_atomic_with(path, |out: &mut dyn Write| {
            write_obj_head(out, comment, self.len(), self.triangles())?;
            self.each_vertices(|piece| write_obj_vertices(out, piece).map_err(failed(path)))
                .map_err(std::io::Error::other)?;
            self.each_triangles(|piece| write_obj_faces(out, piece).map_err(failed(path)))
                .map_err(std::io::Error::other)
        })
    }

    /// An evenly spread sample of at most `max` vertices kept (for the pictures).
    pub fn sample(&self, max: usize) -> Result<Mesh, IoError> {
        let mut sample = Sample::new(max);
        self.each_vertices(|piece| {
            sample.add(piece);
            Ok(())
        })?;
        Ok(sample.mesh)
    }
}

/// A failed write of `path`.
fn failed(path: &Path) -> impl Fn(std::io::Error) -> IoError + '_ {
    move |source| IoError::Write {
        path: path.to_path_buf(),
        source,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dense::marching_cubes::extract;
    use crate::dense::marching_cubes::tests::random_field;
    use crate::io::ply::{write_obj, write_ply};

    #[test]
    fn a_mesh_made_on_disk_writes_the_files_of_the_whole_mesh() {
        let dir = std::env::temp_dir().join(format!("dopslam-mesh-file-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut volume = random_field(3, 5);
        let whole = extract(&mut volume).unwrap();
        let min_area = 0.5;
        let (pruned_whole, pruned) = whole.clone().without_small_pieces(min_area);
        assert!(pruned.pieces > 0 && pruned_whole.len() > 1000, "{pruned:?}");
        let on_disk = MeshOnDisk::extract(&mut volume, &dir).unwrap();
        assert_eq!(on_disk.vertices.bytes() as usize / VERTEX, whole.len());
        let mesh = on_disk.prune(min_area).unwrap();
        assert_eq!(mesh.pruned(), pruned);
        assert_eq!(
            (mesh.len(), mesh.triangles()),
            (pruned_whole.len(), pruned_whole.triangles.len())
        );
        let bytes = |name: &str| std::fs::read(dir.join(name)).unwrap();
        for encoding in [PlyEncoding::Binary, PlyEncoding::Ascii] {
            write_ply(&dir.join("whole.ply"), &pruned_whole, None, encoding, "c").unwrap();
            mesh.write_ply(&dir.join("disk.ply"), encoding, "c")
                .unwrap();
            assert!(bytes("whole.ply") == bytes("disk.ply"), "{encoding:?}");
        }
        write_obj(&dir.join("whole.obj"), &pruned_whole, "c").unwrap();
        mesh.write_obj(&dir.join("disk.obj"), "c").unwrap();
        assert!(bytes("whole.obj") == bytes("disk.obj"));
        let sample = mesh.sample(100).unwrap();
        assert!((51..=100).contains(&sample.len()), "{}", sample.len());
        assert!(sample
            .vertices
            .iter()
            .all(|v| pruned_whole.vertices.contains(v)));
        drop(mesh);
        // Only the files written are left: the spill files went with the mesh.
        let mut left: Vec<String> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        left.sort();
        assert_eq!(left, ["disk.obj", "disk.ply", "whole.obj", "whole.ply"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
