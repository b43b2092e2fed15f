//! PLY files (Stanford triangle format) through the `ply-rs-bw` crate, and OBJ files
//! with vertex colours, for meshes and point clouds.
//!
//! Written: `x y z` (float), then `nx ny nz` (float) and `red green blue` (uchar) when
//! the mesh has them, an optional float `scalar` property per vertex (e.g. a distance,
//! as CloudCompare's scalar fields), and `face` with `vertex_indices` (uchar count,
//! int indices): the layout MeshLab, Open3D and CloudCompare read. Read: any PLY with
//! vertex `x y z` (float or double), colours in uchar (or float 0-1), faces of three
//! or more indices (polygons fanned into triangles).

use std::io::{BufReader, Write};
use std::path::Path;

use ply_rs_bw::parser::Parser;
use ply_rs_bw::ply::{
    Addable, ElementDef, Encoding, Header, Ply, PropertyAccess, PropertyAccessResult, PropertyDef,
    PropertyType, ScalarType,
};
use ply_rs_bw::writer::Writer;

use super::atomic::write_atomic_with;
use super::IoError;
use crate::geometry::mesh::Mesh;

/// One PLY element, vertex or face, as read or written.
#[derive(Debug, Clone, Default)]
struct Record {
    position: [f64; 3],
    normal: [f32; 3],
    colour: [u8; 3],
    scalar: f32,
    indices: Vec<i64>,
}

impl Record {
    fn axis(name: &str) -> Option<(usize, bool)> {
        match name {
            "x" => Some((0, false)),
            "y" => Some((1, false)),
            "z" => Some((2, false)),
            "nx" => Some((0, true)),
            "ny" => Some((1, true)),
            "nz" => Some((2, true)),
            _ => None,
        }
    }

    fn channel(name: &str) -> Option<usize> {
        match name {
            "red" | "r" | "diffuse_red" => Some(0),
            "green" | "g" | "diffuse_green" => Some(1),
            "blue" | "b" | "diffuse_blue" => Some(2),
            _ => None,
        }
    }

    fn set_number(&mut self, name: &str, value: f64) -> PropertyAccessResult {
        if let Some((i, normal)) = Self::axis(name) {
            if normal {
                self.normal[i] = value as f32;
            } else {
                self.position[i] = value;
            }
        } else if name == "scalar" {
            self.scalar = value as f32;
        } else {
            return PropertyAccessResult::Ignored;
        }
        PropertyAccessResult::Set
    }

    fn set_indices(
        &mut self,
        name: &str,
        values: impl Iterator<Item = i64>,
    ) -> PropertyAccessResult {
        if name == "vertex_indices" || name == "vertex_index" {
            self.indices = values.collect();
            PropertyAccessResult::Set
        } else {
            PropertyAccessResult::Ignored
        }
    }
}

impl PropertyAccess for Record {
    fn new() -> Self {
        Self::default()
    }
    fn set_float(&mut self, name: &str, value: f32) -> PropertyAccessResult {
        if let Some(c) = Self::channel(name) {
            self.colour[c] = (value.clamp(0.0, 1.0) * 255.0).round() as u8;
            return PropertyAccessResult::Set;
        }
        self.set_number(name, value as f64)
    }
    fn set_double(&mut self, name: &str, value: f64) -> PropertyAccessResult {
        self.set_number(name, value)
    }
    fn set_uchar(&mut self, name: &str, value: u8) -> PropertyAccessResult {
        match Self::channel(name) {
            Some(c) => {
                self.colour[c] = value;
                PropertyAccessResult::Set
            }
            None => self.set_number(name, value as f64),
        }
    }
    fn set_int(&mut self, name: &str, value: i32) -> PropertyAccessResult {
        self.set_number(name, value as f64)
    }
    fn set_list_int(&mut self, name: &str, value: Vec<i32>) -> PropertyAccessResult {
        self.set_indices(name, value.into_iter().map(i64::from))
    }
    fn set_list_uint(&mut self, name: &str, value: Vec<u32>) -> PropertyAccessResult {
        self.set_indices(name, value.into_iter().map(i64::from))
    }
    fn set_list_uchar(&mut self, name: &str, value: Vec<u8>) -> PropertyAccessResult {
        self.set_indices(name, value.into_iter().map(i64::from))
    }
    fn set_list_ushort(&mut self, name: &str, value: Vec<u16>) -> PropertyAccessResult {
        self.set_indices(name, value.into_iter().map(i64::from))
    }
    fn get_float(&self, name: &str) -> Option<f32> {
        match Self::axis(name) {
            Some((i, true)) => Some(self.normal[i]),
            Some((i, false)) => Some(self.position[i] as f32),
            None => (name == "scalar").then_some(self.scalar),
        }
    }
    fn get_uchar(&self, name: &str) -> Option<u8> {
        Self::channel(name).map(|c| self.colour[c])
    }
    fn get_list_int(&self, _name: &str) -> Option<&[i32]> {
        None
    }
}

/// A face record for writing (indices as i32, borrowed by the writer).
#[derive(Debug, Clone, Default)]
struct Face(Vec<i32>);

/// PLY encodings offered to users.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PlyEncoding {
    #[default]
    /// Binary, little-endian.
    Binary,
    /// ASCII.
    Ascii,
}

/// The vertex element's properties: position, then normals, colours and the scalar
/// field when the mesh has them.
fn vertex_element(mesh: &Mesh, with_scalar: bool) -> ElementDef {
    vertex_properties(
        !mesh.normals.is_empty(),
        !mesh.colours.is_empty(),
        with_scalar,
    )
}

/// The vertex element: position, then normals, colours and the scalar field as asked.
pub(super) fn vertex_properties(normals: bool, colours: bool, with_scalar: bool) -> ElementDef {
    let float = PropertyType::Scalar(ScalarType::Float);
    let uchar = PropertyType::Scalar(ScalarType::UChar);
    let mut vertex = ElementDef::new("vertex".to_string());
    for name in ["x", "y", "z"] {
        vertex
            .properties
            .add(PropertyDef::new(name.into(), float.clone()));
    }
    if normals {
        for name in ["nx", "ny", "nz"] {
            vertex
                .properties
                .add(PropertyDef::new(name.into(), float.clone()));
        }
    }
    if colours {
        for name in ["red", "green", "blue"] {
            vertex
                .properties
                .add(PropertyDef::new(name.into(), uchar.clone()));
        }
    }
    if with_scalar {
        vertex
            .properties
            .add(PropertyDef::new("scalar".into(), float.clone()));
    }
    vertex
}

/// Writes `mesh` (and an optional per-vertex `scalar` field) to `path` atomically.
pub fn write_ply(
    path: &Path,
    mesh: &Mesh,
    scalar: Option<&[f32]>,
    encoding: PlyEncoding,
    comment: &str,
) -> Result<(), IoError> {
    mesh.validate().map_err(|m| IoError::invalid(path, m))?;
    let mut vertex = vertex_element(mesh, scalar.is_some());
    vertex.count = mesh.len();
    let rows = PlyMeshRows::new(encoding, comment, vertex, mesh.triangles.len());
    let write = |out: &mut dyn Write| -> std::io::Result<()> {
        rows.header(out)?;
        write_vertices(out, mesh, scalar, &rows.vertex, &rows.header)?;
        rows.faces(out, &mesh.triangles)
    };
    write_atomic_with(path, write)
}

/// A mesh file's parts written piece by piece, the counts known first (for a mesh no
/// step holds whole): the header, then every vertex, then every face; the same bytes
/// as [`write_ply`] of the whole mesh.
pub struct PlyMeshRows {
    header: Header,
    vertex: ElementDef,
    face: ElementDef,
}

impl PlyMeshRows {
    /// The rows of a coloured mesh of `vertices` and `triangles`.
    pub fn coloured(
        encoding: PlyEncoding,
        comment: &str,
        vertices: usize,
        triangles: usize,
    ) -> Self {
        let mut vertex = vertex_properties(false, true, false);
        vertex.count = vertices;
        Self::new(encoding, comment, vertex, triangles)
    }

    fn new(encoding: PlyEncoding, comment: &str, vertex: ElementDef, triangles: usize) -> Self {
        let mut header = header(encoding, comment, &vertex);
        let mut face = ElementDef::new("face".to_string());
        face.properties.add(PropertyDef::new(
            "vertex_indices".into(),
            PropertyType::List(ScalarType::UChar, ScalarType::Int),
        ));
        face.count = triangles;
        if triangles > 0 {
            header.elements.add(face.clone());
        }
        Self {
            header,
            vertex,
            face,
        }
    }

    /// Writes the header.
    pub fn header(&self, out: &mut dyn Write) -> std::io::Result<()> {
        write_header(out, &self.header)
    }

    /// Writes `piece`'s vertices (positions and colours) as the next vertex rows.
    pub fn vertices(&self, out: &mut dyn Write, piece: &Mesh) -> std::io::Result<()> {
        write_vertices(out, piece, None, &self.vertex, &self.header)
    }

    /// Writes `triangles` as the next face rows.
    pub fn faces(&self, mut out: &mut dyn Write, triangles: &[[u32; 3]]) -> std::io::Result<()> {
        for piece in triangles.chunks(PIECE) {
            let faces: Vec<Face> = piece
                .iter()
                .map(|t| Face(t.map(|i| i as i32).to_vec()))
                .collect();
            let writer = Writer::<Face>::new();
            writer.write_payload_of_element(&mut out, &faces, &self.face, &self.header)?;
        }
        Ok(())
    }
}

/// A file's header: `encoding`, `comment`, and the `vertex` element.
pub(super) fn header(encoding: PlyEncoding, comment: &str, vertex: &ElementDef) -> Header {
    let mut header = Ply::<Record>::new().header;
    header.encoding = match encoding {
        PlyEncoding::Binary => Encoding::BinaryLittleEndian,
        PlyEncoding::Ascii => Encoding::Ascii,
    };
    header.comments.push(comment.to_string());
    header.elements.add(vertex.clone());
    header
}

/// Writes `header`.
pub(super) fn write_header(mut out: &mut dyn Write, header: &Header) -> std::io::Result<()> {
    Writer::<Record>::new().write_header(&mut out, header)?;
    Ok(())
}

/// Writes `mesh`'s vertices (and `scalar`) as `vertex` rows of a file with `header`.
pub(super) fn write_vertices(
    mut out: &mut dyn Write,
    mesh: &Mesh,
    scalar: Option<&[f32]>,
    vertex: &ElementDef,
    header: &Header,
) -> std::io::Result<()> {
    // In pieces: the file's bytes and ply-rs's records of a whole mesh would take
    // several times the mesh's own memory.
    let record = |i: usize| Record {
        position: mesh.vertices[i].map(f64::from),
        normal: mesh.normals.get(i).copied().unwrap_or_default(),
        colour: mesh.colours.get(i).copied().unwrap_or_default(),
        scalar: scalar.and_then(|s| s.get(i)).copied().unwrap_or_default(),
        indices: Vec::new(),
    };
    for start in (0..mesh.len()).step_by(PIECE) {
        let records: Vec<Record> = (start..mesh.len().min(start + PIECE)).map(record).collect();
        Writer::<Record>::new().write_payload_of_element(&mut out, &records, vertex, header)?;
    }
    Ok(())
}

/// Vertices or faces written at a time.
const PIECE: usize = 1 << 16;

impl PropertyAccess for Face {
    fn new() -> Self {
        Self::default()
    }
    fn get_list_int(&self, name: &str) -> Option<&[i32]> {
        (name == "vertex_indices").then_some(&self.0[..])
    }
}

/// Reads a PLY mesh or point cloud.
pub fn read_ply(path: &Path) -> Result<Mesh, IoError> {
    let file = std::fs::File::open(path).map_err(|source| match source.kind() {
        std::io::ErrorKind::NotFound => IoError::Missing {
            path: path.to_path_buf(),
            what: "no such PLY file".into(),
        },
        _ => IoError::Read {
            path: path.to_path_buf(),
            source,
        },
    })?;
    let ply = Parser::<Record>::new()
        .read_ply(&mut BufReader::new(file))
        .map_err(|e| IoError::invalid(path, format!("not a readable PLY file: {e}")))?;
    let vertex_def = ply
        .header
        .elements
        .get("vertex")
        .ok_or_else(|| IoError::invalid(path, "the PLY file has no vertex element"))?;
    let has = |name: &str| vertex_def.properties.contains_key(name);
    if !(has("x") && has("y") && has("z")) {
        return Err(IoError::invalid(path, "the vertex element lacks x, y or z"));
    }
    let with_colour = has("red") || has("r") || has("diffuse_red");
    let with_normals = has("nx");
    let empty = Vec::new();
    let records = ply.payload.get("vertex").unwrap_or(&empty);
    let mut mesh = Mesh {
        vertices: records
            .iter()
            .map(|r| r.position.map(|c| c as f32))
            .collect(),
        ..Mesh::default()
    };
    if with_colour {
        mesh.colours = records.iter().map(|r| r.colour).collect();
    }
    if with_normals {
        mesh.normals = records.iter().map(|r| r.normal).collect();
    }
    let n = mesh.len() as i64;
    for (k, face) in ply.payload.get("face").unwrap_or(&empty).iter().enumerate() {
        let f = &face.indices;
        if f.len() < 3 || f.iter().any(|&i| i < 0 || i >= n) {
            return Err(IoError::invalid(
                path,
                format!("face {k} has indices {f:?} (the file has {n} vertices)"),
            ));
        }
        for j in 1..f.len() - 1 {
            mesh.triangles
                .push([f[0] as u32, f[j] as u32, f[j + 1] as u32]);
        }
    }
    mesh.validate().map_err(|m| IoError::invalid(path, m))?;
    Ok(mesh)
}

/// Writes `mesh` as a Wavefront OBJ with vertex colours (`v x y z r g b`, colours in
/// 0-1, the extension MeshLab and Open3D read) and vertex normals when present.
pub fn write_obj(path: &Path, mesh: &Mesh, comment: &str) -> Result<(), IoError> {
    mesh.validate().map_err(|m| IoError::invalid(path, m))?;
    let put = |out: &mut dyn Write| -> std::io::Result<()> {
        write_obj_head(out, comment, mesh.len(), mesh.triangles.len())?;
        write_obj_vertices(out, mesh)?;
        for [x, y, z] in &mesh.normals {
            writeln!(out, "vn {x} {y} {z}")?;
        }
        if mesh.normals.is_empty() {
            return write_obj_faces(out, &mesh.triangles);
        }
        for t in &mesh.triangles {
            let [a, b, c] = t.map(|i| i + 1);
            writeln!(out, "f {a}//{a} {b}//{b} {c}//{c}")?;
        }
        Ok(())
    };
    write_atomic_with(path, put)
}

/// An OBJ file's first lines: `comment` and the counts.
pub fn write_obj_head(
    out: &mut dyn Write,
    comment: &str,
    vertices: usize,
    triangles: usize,
) -> std::io::Result<()> {
    writeln!(out, "# {comment}")?;
    writeln!(out, "# {vertices} vertices, {triangles} triangles")
}

/// `piece`'s vertices as OBJ `v` lines (with colours from 0 to 1 when it has them).
pub fn write_obj_vertices(out: &mut dyn Write, piece: &Mesh) -> std::io::Result<()> {
    for (i, [x, y, z]) in piece.vertices.iter().enumerate() {
        match piece.colours.get(i) {
            Some(c) => writeln!(
                out,
                "v {x} {y} {z} {:.4} {:.4} {:.4}",
                c[0] as f32 / 255.0,
                c[1] as f32 / 255.0,
                c[2] as f32 / 255.0
            )?,
            None => writeln!(out, "v {x} {y} {z}")?,
        }
    }
    Ok(())
}

/// `triangles` (vertex numbers from 0) as OBJ `f` lines (numbers from 1).
pub fn write_obj_faces(out: &mut dyn Write, triangles: &[[u32; 3]]) -> std::io::Result<()> {
    for t in triangles {
        let [a, b, c] = t.map(|i| i + 1);
        writeln!(out, "f {a} {b} {c}")?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tetrahedron() -> Mesh {
        Mesh {
            vertices: vec![
                [1.0, 1.0, 1.0],
                [1.0, -1.0, -1.0],
                [-1.0, 1.0, -1.0],
                [-1.0, -1.0, 1.5],
            ],
            colours: vec![[255, 0, 0], [0, 255, 0], [0, 0, 255], [10, 20, 30]],
            normals: vec![],
            triangles: vec![[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]],
        }
    }

    #[test]
    fn ply_round_trips_in_both_encodings() {
        let dir = std::env::temp_dir().join(format!("dopslam-ply-{}", std::process::id()));
        for encoding in [PlyEncoding::Binary, PlyEncoding::Ascii] {
            let path = dir.join(format!("{encoding:?}.ply"));
            let mesh = tetrahedron();
            write_ply(&path, &mesh, Some(&[0.5, 1.0, 2.0, 3.0]), encoding, "test").unwrap();
            let back = read_ply(&path).unwrap();
            assert_eq!(back, mesh, "{encoding:?}");
            let points = Mesh::points(mesh.vertices.clone());
            write_ply(&path, &points, None, encoding, "test").unwrap();
            assert_eq!(read_ply(&path).unwrap(), points);
        }
        let obj = dir.join("t.obj");
        write_obj(&obj, &tetrahedron(), "test").unwrap();
        let text = std::fs::read_to_string(&obj).unwrap();
        assert_eq!(text.lines().filter(|l| l.starts_with("v ")).count(), 4);
        assert!(text.contains("f 1 2 3"));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_file_that_is_not_a_ply_is_refused_by_name() {
        let dir = std::env::temp_dir().join(format!("dopslam-notply-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("map.ply");
        std::fs::write(&path, "solid cube\nfacet normal 0 0 1\n").unwrap();
        let e = read_ply(&path).unwrap_err().to_string();
        assert!(
            e.contains("map.ply") && e.contains("not a readable PLY"),
            "{e}"
        );
        let missing = read_ply(&dir.join("absent.ply")).unwrap_err().to_string();
        assert!(missing.contains("absent.ply"), "{missing}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
