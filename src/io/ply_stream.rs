//! A point cloud written to a PLY file piece by piece, so that no step holds the whole
//! cloud: the pieces' rows go to a temporary body file beside the target; `finish`
//! writes the header (which must count the rows) and then the body, atomically, as
//! [`super::ply::write_ply`] does for a cloud held whole. An unfinished stream leaves
//! the file before it as it was, and no temporary file.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use ply_rs_bw::ply::{ElementDef, Header};

use super::atomic::write_atomic_with;
use super::ply::{header, vertex_properties, write_header, write_vertices, PlyEncoding};
use super::IoError;
use crate::geometry::mesh::Mesh;

/// The properties of a stream's rows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PointRows {
    /// Each point has a normal.
    pub normals: bool,
    /// Each point has a colour.
    pub colours: bool,
}

/// A point cloud file being written.
pub struct PlyPointStream {
    path: PathBuf,
    body_path: PathBuf,
    body: Option<BufWriter<File>>,
    rows: PointRows,
    vertex: ElementDef,
    header: Header,
    count: usize,
}

impl PlyPointStream {
    /// A stream into `path` (not touched before [`PlyPointStream::finish`]) of rows
    /// with `rows`' properties.
    pub fn create(
        path: &Path,
        rows: PointRows,
        encoding: PlyEncoding,
        comment: &str,
    ) -> Result<Self, IoError> {
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned());
        let body_path = path.with_file_name(format!(
            ".{}.body{}",
            name.unwrap_or_default(),
            std::process::id()
        ));
        let body = File::create(&body_path).map_err(|source| IoError::Write {
            path: body_path.clone(),
            source,
        })?;
        let vertex = vertex_properties(rows.normals, rows.colours, false);
        Ok(Self {
            path: path.to_path_buf(),
            header: header(encoding, comment, &vertex),
            body_path,
            body: Some(BufWriter::with_capacity(1 << 20, body)),
            rows,
            vertex,
            count: 0,
        })
    }

    /// Appends `piece`'s points (with normals and colours as the stream's rows).
    pub fn push(&mut self, piece: &Mesh) -> Result<(), IoError> {
        let err = |m: String| IoError::invalid(&self.path, m);
        piece.validate().map_err(err)?;
        let has = |v: usize| v == piece.len();
        if has(piece.normals.len()) != self.rows.normals
            || has(piece.colours.len()) != self.rows.colours
        {
            return Err(err(format!(
                "a piece of {} points with {} normals and {} colours, rows {:?}",
                piece.len(),
                piece.normals.len(),
                piece.colours.len(),
                self.rows
            )));
        }
        let body = self.body.as_mut().expect("open until finished");
        write_vertices(body, piece, None, &self.vertex, &self.header).map_err(|source| {
            IoError::Write {
                path: self.body_path.clone(),
                source,
            }
        })?;
        self.count += piece.len();
        Ok(())
    }

    /// Points pushed so far.
    pub fn len(&self) -> usize {
        self.count
    }

    /// Whether no point was pushed.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// Writes the file: the header, then the rows pushed; the temporary body goes.
    pub fn finish(mut self) -> Result<(), IoError> {
        let body = self.body.take().expect("open until finished");
        let written = body.into_inner().map_err(|e| IoError::Write {
            path: self.body_path.clone(),
            source: e.into_error(),
        })?;
        drop(written);
        let mut header = self.header.clone();
        if let Some(vertex) = header.elements.get_mut("vertex") {
            vertex.count = self.count;
        }
        let body_path = self.body_path.clone();
        write_atomic_with(&self.path, |out| {
            write_header(out, &header)?;
            let mut body = File::open(&body_path)?;
            std::io::copy(&mut body, out)?;
            Ok(())
        })
    }
}

impl Drop for PlyPointStream {
    fn drop(&mut self) {
        // Ours alone (created by this stream); the target file is never touched here.
        let _ = std::fs::remove_file(&self.body_path);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::ply::{read_ply, write_ply};

    fn piece(start: usize, n: usize) -> Mesh {
        let mut piece = Mesh::points((start..start + n).map(|i| [i as f32, 0.5, -1.0]).collect());
        piece.colours = (start..start + n).map(|i| [i as u8, 2, 3]).collect();
        piece.normals = vec![[0.0, 0.0, 1.0]; n];
        piece
    }

    #[test]
    fn a_streamed_cloud_is_the_file_of_the_whole_cloud() {
        let dir = std::env::temp_dir().join(format!("dopslam-plystream-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let rows = PointRows {
            normals: true,
            colours: true,
        };
        for encoding in [PlyEncoding::Binary, PlyEncoding::Ascii] {
            let (streamed, whole) = (dir.join("streamed.ply"), dir.join("whole.ply"));
            std::fs::write(&streamed, b"the earlier file").unwrap();
            let mut stream = PlyPointStream::create(&streamed, rows, encoding, "c").unwrap();
            stream.push(&piece(0, 70_000)).unwrap();
            stream.push(&piece(70_000, 3)).unwrap();
            assert!(stream.push(&Mesh::points(vec![[0.0; 3]])).is_err());
            assert_eq!(std::fs::read(&streamed).unwrap(), b"the earlier file");
            assert_eq!(stream.len(), 70_003);
            stream.finish().unwrap();
            write_ply(&whole, &piece(0, 70_003), None, encoding, "c").unwrap();
            assert_eq!(
                std::fs::read(&streamed).unwrap(),
                std::fs::read(&whole).unwrap()
            );
            assert_eq!(read_ply(&streamed).unwrap().len(), 70_003);
        }
        // An unfinished stream leaves the earlier file and no temporary one.
        let earlier = dir.join("streamed.ply");
        let before = std::fs::read(&earlier).unwrap();
        let mut stream = PlyPointStream::create(&earlier, rows, PlyEncoding::Binary, "c").unwrap();
        stream.push(&piece(0, 10)).unwrap();
        drop(stream);
        assert_eq!(std::fs::read(&earlier).unwrap(), before);
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 2);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
