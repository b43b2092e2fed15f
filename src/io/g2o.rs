//! g2o's 3-D pose-graph text format, as the standard benchmark graphs (sphere, garage,
//! torus, cubicle) ship it:
//!
//! ```text
//! VERTEX_SE3:QUAT id x y z qx qy qz qw            # world_from_vertex
//! EDGE_SE3:QUAT a b x y z qx qy qz qw I11 I12 .. I66  # T_a^{-1} T_b, upper triangle of the information
//! FIX id
//! ```
//!
//! The information matrix is in g2o's order (translation, then rotation). Other lines
//! (2-D types, comments) are refused with the line named, so a wrong file never gives
//! a silently partial graph.

use std::fmt::Write as _;
use std::path::Path;

use nalgebra::Matrix6;

use super::errors::read_text;
use super::file_list::{content_lines, parse_numbers, split_fields};
use super::trajectory::write_translation_quaternion;
use super::IoError;
use crate::geometry::se3::{self, Se3};

/// An edge as the file has it.
#[derive(Debug, Clone, PartialEq)]
pub struct G2oEdge {
    /// The first vertex's id.
    pub from: u64,
    /// The second vertex's id.
    pub to: u64,
    /// \(T_{from}^{-1} T_{to}\).
    pub measurement: Se3,
    /// Information in g2o's order (translation, rotation).
    pub information: Matrix6<f64>,
}

/// A 3-D pose graph as the file has it.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct G2oGraph {
    /// `(id, world_from_vertex)` in file order.
    pub vertices: Vec<(u64, Se3)>,
    /// The edges.
    pub edges: Vec<G2oEdge>,
    /// The ids held fixed.
    pub fixed: Vec<u64>,
}

/// The numbers after a record's tag, exactly `count` of them.
fn numbers(path: &Path, line: usize, fields: &[&str], count: usize) -> Result<Vec<f64>, IoError> {
    let format = match fields[0] {
        "VERTEX_SE3:QUAT" => "VERTEX_SE3:QUAT id x y z qx qy qz qw",
        _ => "EDGE_SE3:QUAT a b x y z qx qy qz qw and 21 information entries",
    };
    parse_numbers(path, line, &fields[1..].join(" "), count - 1, format)
}

fn pose(path: &Path, line: usize, v: &[f64]) -> Result<Se3, IoError> {
    let q = [v[3], v[4], v[5], v[6]];
    let norm = q.iter().map(|x| x * x).sum::<f64>().sqrt();
    if (norm - 1.0).abs() > 1e-3 {
        return Err(IoError::parse(
            path,
            line,
            format!("quaternion norm {norm:.6}, not 1"),
        ));
    }
    Ok(se3::from_translation_quaternion(
        nalgebra::Vector3::new(v[0], v[1], v[2]),
        q,
    ))
}

impl G2oGraph {
    /// Reads a `.g2o` file.
    pub fn read(path: &Path) -> Result<Self, IoError> {
        let text = read_text(path)?;
        let mut graph = Self::default();
        let mut seen = std::collections::HashSet::new();
        for (line, content) in content_lines(&text) {
            let fields: Vec<&str> = split_fields(content).collect();
            let id = |s: &str| {
                s.parse::<u64>()
                    .map_err(|_| IoError::parse(path, line, format!("{s:?} is not a vertex id")))
            };
            match fields.first().copied() {
                None => {}
                Some("VERTEX_SE3:QUAT") => {
                    let v = numbers(path, line, &fields, 9)?;
                    let vertex = id(fields[1])?;
                    if !seen.insert(vertex) {
                        return Err(IoError::parse(path, line, format!("vertex {vertex} twice")));
                    }
                    graph.vertices.push((vertex, pose(path, line, &v[1..])?));
                }
                Some("EDGE_SE3:QUAT") => {
                    let v = numbers(path, line, &fields, 31)?;
                    let (from, to) = (id(fields[1])?, id(fields[2])?);
                    let mut information = Matrix6::zeros();
                    let mut k = 9;
                    for r in 0..6 {
                        for c in r..6 {
                            information[(r, c)] = v[k];
                            information[(c, r)] = v[k];
                            k += 1;
                        }
                    }
                    // Positive definite: Cholesky succeeds (a zero, negated or
                    // indefinite information makes the optimisation meaningless).
                    if information.cholesky().is_none() {
                        return Err(IoError::parse(
                            path,
                            line,
                            format!("the information matrix of edge {from}-{to} is not positive definite"),
                        ));
                    }
                    graph.edges.push(G2oEdge {
                        from,
                        to,
                        measurement: pose(path, line, &v[2..])?,
                        information,
                    });
                }
                Some("FIX") => {
                    for f in &fields[1..] {
                        graph.fixed.push(id(f)?);
                    }
                }
                Some(other) => {
                    return Err(IoError::parse(
                        path,
                        line,
                        format!("{other}: only VERTEX_SE3:QUAT, EDGE_SE3:QUAT and FIX are read"),
                    ))
                }
            }
        }
        if graph.vertices.is_empty() {
            return Err(IoError::invalid(
                path,
                "no VERTEX_SE3:QUAT line: not a 3-D pose graph",
            ));
        }
        for e in &graph.edges {
            for v in [e.from, e.to] {
                if !seen.contains(&v) {
                    return Err(IoError::invalid(
                        path,
                        format!("an edge names vertex {v}, which the file does not define"),
                    ));
                }
            }
        }
        Ok(graph)
    }

    /// The file's text (full precision).
    pub fn to_text(&self) -> String {
        let mut text = String::new();
        let pose = write_translation_quaternion;
        for (id, p) in &self.vertices {
            let _ = write!(text, "VERTEX_SE3:QUAT {id} ");
            pose(&mut text, p);
            text.push('\n');
        }
        for e in &self.edges {
            let _ = write!(text, "EDGE_SE3:QUAT {} {} ", e.from, e.to);
            pose(&mut text, &e.measurement);
            for r in 0..6 {
                for c in r..6 {
                    let _ = write!(text, " {}", e.information[(r, c)]);
                }
            }
            text.push('\n');
        }
        for id in &self.fixed {
            let _ = writeln!(text, "FIX {id}");
        }
        text
    }

    /// Writes the file atomically.
    pub fn write(&self, path: &Path) -> Result<(), IoError> {
        super::atomic::write_atomic(path, self.to_text().as_bytes())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector6;

    #[test]
    fn writes_and_reads_back_the_same_graph() {
        let dir = std::env::temp_dir().join(format!("dopslam-g2o-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("graph.g2o");
        let a = se3::exp(&Vector6::new(0.1, 0.2, 0.3, 0.01, -0.2, 0.3));
        let b = se3::exp(&Vector6::new(-1.0, 0.5, 2.0, 0.4, 0.1, -0.3));
        let mut information = Matrix6::identity() * 100.0;
        information[(0, 4)] = 3.0;
        information[(4, 0)] = 3.0;
        let graph = G2oGraph {
            vertices: vec![(7, a), (9, b)],
            edges: vec![G2oEdge {
                from: 7,
                to: 9,
                measurement: a.inverse() * b,
                information,
            }],
            fixed: vec![7],
        };
        graph.write(&path).unwrap();
        let back = G2oGraph::read(&path).unwrap();
        assert_eq!(back.vertices.len(), 2);
        assert_eq!(back.fixed, vec![7]);
        assert_eq!(back.edges[0].information, information);
        let d = se3::log(&(back.edges[0].measurement.inverse() * graph.edges[0].measurement));
        assert!(d.norm() < 1e-12);
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn names_the_line_of_a_bad_record() {
        let dir = std::env::temp_dir().join(format!("dopslam-g2o-bad-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("bad.g2o");
        std::fs::write(
            &path,
            "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE2 1 0 0 0\n",
        )
        .unwrap();
        let e = G2oGraph::read(&path).unwrap_err().to_string();
        assert!(e.contains(":2:") && e.contains("VERTEX_SE2"), "{e}");
        std::fs::write(&path, "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nEDGE_SE3:QUAT 0 5 0 0 0 0 0 0 1 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1\n").unwrap();
        let e = G2oGraph::read(&path).unwrap_err().to_string();
        assert!(e.contains("vertex 5"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
