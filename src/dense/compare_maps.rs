//! `dopslam compare-maps` and `run --compare-no-dop`: judge maps, write the table
//! (`compare.md`, `compare.json`), each map coloured by its distance to the reference
//! (`NAME_distance.ply`, blue 0 to red at twice `ghost_distance`, with the distance
//! as a `scalar` property for CloudCompare), and the maps side by side with their
//! ghosts in red (`compare_top.png`, `compare_perspective.png`).

use std::path::{Path, PathBuf};

use serde::Serialize;

use super::map_figures::{
    distance_colour, judge, static_accuracy, table, CompareSettings, Judged, MapFigures,
    StaticReference,
};
use super::render::{self, Viewpoint};
use super::save_png;
use crate::geometry::mesh::Mesh;
use crate::geometry::se3::Se3;
use crate::io::atomic::write_atomic;
use crate::io::ply::{read_ply, write_ply, PlyEncoding};
use crate::io::IoError;
use crate::io::Trajectory;
use nalgebra::{Matrix3, Vector3};

/// A comparison's result.
#[derive(Debug, Serialize)]
pub struct Comparison {
    /// The maps' names.
    pub names: Vec<String>,
    /// The static reference.
    pub reference: PathBuf,
    /// The movers' reference, when there is one.
    pub movers: Option<PathBuf>,
    /// The thresholds used.
    pub settings: CompareSettings,
    /// The figures, one per map.
    pub maps: Vec<MapFigures>,
    /// The files written.
    pub outputs: Vec<PathBuf>,
}

impl Comparison {
    /// The figures as a Markdown table.
    pub fn table(&self) -> String {
        let figures: Vec<&MapFigures> = self.maps.iter().collect();
        table(&self.names, &figures)
    }
}

/// What to compare.
pub struct CompareInputs<'a> {
    /// Maps with their names; with two or more, the last is the baseline for SA.
    pub maps: &'a [(String, PathBuf)],
    /// Per map, a transform into the reference's frame (`reference_from_map`), e.g.
    /// the SE(3) alignment of its run's trajectory to the ground truth.
    pub alignments: &'a [Option<Se3>],
    /// The static reference (PLY).
    pub reference: &'a Path,
    /// The movers' surfaces, to count ghosts (PLY).
    pub movers: Option<&'a Path>,
    /// Camera poses (`world_from_camera`) to orient the pictures.
    pub cameras: Option<&'a [crate::geometry::se3::Se3]>,
    /// The thresholds.
    pub settings: CompareSettings,
    /// The output folder.
    pub out: &'a Path,
}

/// The most samples drawn on the reference surface for completion and recall (each
/// is looked up in every map's k-d tree): at the default 2 cm, 4000 m² of surface.
pub const MAX_REFERENCE_SAMPLES: f64 = 1e7;

/// The spacing the reference is sampled at: `asked`, or wider where the surface at
/// `asked` would give more than [`MAX_REFERENCE_SAMPLES`] (a street's static scene,
/// hundreds of metres, would take hours and gigabytes at 2 cm).
pub fn sample_spacing(reference: &Mesh, asked: f64) -> f64 {
    let area = reference.surface_area();
    asked.max((area / MAX_REFERENCE_SAMPLES).sqrt())
}

/// Judges the maps and writes the outputs (see the module doc).
pub fn compare_maps(inputs: &CompareInputs) -> Result<Comparison, IoError> {
    let reference_mesh = read_ply(inputs.reference)?;
    if reference_mesh.is_empty() {
        return Err(IoError::invalid(
            inputs.reference,
            "the reference has no vertices",
        ));
    }
    let mut settings = inputs.settings;
    settings.sample_spacing = sample_spacing(&reference_mesh, settings.sample_spacing);
    let reference = StaticReference::new(&reference_mesh, settings.sample_spacing)
        .map_err(|m| IoError::invalid(inputs.reference, m))?;
    let movers = match inputs.movers {
        Some(path) => Some(read_ply(path)?.vertices),
        None => None,
    };
    let mut judged = Vec::new();
    let mut meshes = Vec::new();
    for (k, (name, path)) in inputs.maps.iter().enumerate() {
        let mut mesh = read_ply(path)?;
        if let Some(Some(pose)) = inputs.alignments.get(k) {
            transform(&mut mesh, pose);
        }
        if mesh.is_empty() {
            return Err(IoError::invalid(path, "the map has no vertices"));
        }
        judged.push(judge(&mesh, &reference, movers.as_deref(), &settings));
        meshes.push((name.clone(), mesh));
    }
    if judged.len() >= 2 {
        let baseline = judged.len() - 1;
        for i in 0..baseline {
            let sa = static_accuracy(&judged[i].samples, &judged[baseline].samples);
            judged[i].figures.static_accuracy = Some(sa);
        }
    }
    let names: Vec<String> = meshes.iter().map(|(n, _)| n.clone()).collect();
    let mut outputs = write_distance_maps(inputs, &meshes, &judged)?;
    outputs.extend(write_pictures(inputs, &reference_mesh, &meshes, &judged)?);
    let comparison = Comparison {
        names,
        reference: inputs.reference.to_path_buf(),
        movers: inputs.movers.map(Path::to_path_buf),
        settings,
        maps: judged.into_iter().map(|j| j.figures).collect(),
        outputs,
    };
    let json = serde_json::to_string_pretty(&comparison).expect("comparison serialises");
    write_atomic(&inputs.out.join("compare.json"), json.as_bytes())?;
    let md = format!(
        "# Dense maps compared\n\nReference: `{}`{}; sampled every {:.3} m for completion and recall\n\n{}\nPictures: left to right as the columns; ghosts (farther than {} m from the reference) in red.\n",
        inputs.reference.display(),
        inputs
            .movers
            .map(|m| format!("; movers' ground truth: `{}`", m.display()))
            .unwrap_or_default(),
        settings.sample_spacing,
        comparison.table(),
        inputs.settings.ghost_distance
    );
    write_atomic(&inputs.out.join("compare.md"), md.as_bytes())?;
    Ok(comparison)
}

/// `NAME_distance.ply` per map: its points coloured by their distance to the
/// reference, the distance as a scalar. Returns the paths written.
fn write_distance_maps(
    inputs: &CompareInputs,
    meshes: &[(String, Mesh)],
    maps: &[Judged],
) -> Result<Vec<PathBuf>, IoError> {
    let mut outputs = Vec::new();
    let full = (inputs.settings.ghost_distance * 2.0) as f32;
    for ((name, mesh), figures) in meshes.iter().zip(maps) {
        let coloured = Mesh {
            colours: figures
                .samples
                .distances
                .iter()
                .map(|&d| distance_colour(d, full))
                .collect(),
            ..mesh.clone()
        };
        let path = inputs.out.join(format!("{}_distance.ply", file_stem(name)));
        write_ply(
            &path,
            &coloured,
            Some(&figures.samples.distances),
            PlyEncoding::Binary,
            "dopslam compare-maps: colour = distance to the reference (blue 0, red >= 2x ghost distance); scalar = distance in metres",
        )?;
        outputs.push(path);
    }
    Ok(outputs)
}

/// `compare_top.png` and `compare_perspective.png`: the maps side by side, ghosts in
/// red, seen from the run's cameras (else from above the reference). Returns the paths
/// written.
fn write_pictures(
    inputs: &CompareInputs,
    reference_mesh: &Mesh,
    meshes: &[(String, Mesh)],
    maps: &[Judged],
) -> Result<Vec<PathBuf>, IoError> {
    let mut outputs = Vec::new();
    let view = match inputs.cameras {
        Some(cameras) => Viewpoint::from_cameras(cameras),
        None => Viewpoint::from_points(&reference_mesh.vertices),
    };
    if let Some(view) = view {
        let ghost = |(mesh, judged): (&Mesh, &Judged)| -> Vec<[u8; 3]> {
            let flags: Vec<bool> = judged
                .samples
                .distances
                .iter()
                .map(|&d| d as f64 > inputs.settings.ghost_distance)
                .collect();
            render::with_ghosts(mesh, &flags)
        };
        let coloured: Vec<Vec<[u8; 3]>> =
            meshes.iter().map(|(_, m)| m).zip(maps).map(ghost).collect();
        let camera = render::picture_camera();
        let mut top = None::<image::RgbImage>;
        let mut perspective = None::<image::RgbImage>;
        for (((name, mesh), colours), judged) in meshes.iter().zip(&coloured).zip(maps) {
            let figures = &judged.figures;
            let caption = match figures.mover_points {
                Some(movers) => format!("{name}: {movers} mover points"),
                None => format!("{name}: {} ghost points", figures.ghost_points),
            };
            let mut t = render::top(&mesh.vertices, colours, &view, 600);
            let mut p =
                render::perspective(&mesh.vertices, colours, &view.camera_from_world, &camera);
            render::label(&mut t, &caption);
            render::label(&mut p, &caption);
            top = Some(match top {
                Some(left) => render::side_by_side(&left, &t),
                None => t,
            });
            perspective = Some(match perspective {
                Some(left) => render::side_by_side(&left, &p),
                None => p,
            });
        }
        for (name, picture) in [
            ("compare_top.png", top),
            ("compare_perspective.png", perspective),
        ] {
            if let Some(picture) = picture {
                let path = inputs.out.join(name);
                save_png(&path, &picture)?;
                outputs.push(path);
            }
        }
    }
    Ok(outputs)
}

/// Moves a mesh by `pose` (points and normals).
pub fn transform(mesh: &mut Mesh, pose: &Se3) {
    for v in &mut mesh.vertices {
        let p = pose * nalgebra::Point3::from(v.map(f64::from));
        *v = [p.x as f32, p.y as f32, p.z as f32];
    }
    for n in &mut mesh.normals {
        let m = pose.rotation * nalgebra::Vector3::from(n.map(f64::from));
        *n = [m.x as f32, m.y as f32, m.z as f32];
    }
}

/// The rigid transform that best maps a run's poses onto the ground truth's
/// (`reference_from_estimate`), from whole poses rather than positions alone so that a
/// camera that barely moves still fixes the rotation: with poses matched by time
/// (nearest within 20 ms), \(R = \mathrm{proj}_{SO(3)} \sum_i R^{gt}_i (R^{est}_i)^T\)
/// (the chordal mean) and \(t = \overline{t^{gt}_i - R\, t^{est}_i}\).
pub fn pose_alignment(estimate: &Trajectory, reference: &Trajectory) -> Option<Se3> {
    let mut order: Vec<usize> = (0..reference.len()).collect();
    order.sort_by(|&a, &b| reference.timestamps[a].total_cmp(&reference.timestamps[b]));
    let times: Vec<f64> = order.iter().map(|&i| reference.timestamps[i]).collect();
    let mut pairs = Vec::new();
    for (t, est) in estimate.timestamps.iter().zip(&estimate.poses) {
        let k = times.partition_point(|&r| r < *t);
        let best = [k.checked_sub(1), Some(k)]
            .into_iter()
            .flatten()
            .filter(|&k| k < times.len())
            .min_by(|&a, &b| (times[a] - t).abs().total_cmp(&(times[b] - t).abs()))?;
        if (times[best] - t).abs() <= 0.02 {
            pairs.push((est, &reference.poses[order[best]]));
        }
    }
    if pairs.len() < 3 {
        return None;
    }
    let sum: Matrix3<f64> = pairs
        .iter()
        .map(|(est, gt)| gt.rotation.matrix() * est.rotation.matrix().transpose())
        .sum();
    let svd = sum.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut fix = Matrix3::identity();
    fix[(2, 2)] = (u * v_t).determinant().signum();
    let rotation = u * fix * v_t;
    let translation = pairs
        .iter()
        .map(|(est, gt)| gt.translation.vector - rotation * est.translation.vector)
        .sum::<Vector3<f64>>()
        / pairs.len() as f64;
    Some(crate::geometry::se3::from_parts(translation, rotation))
}

/// A name safe as a file stem.
fn file_stem(name: &str) -> String {
    name.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::se3;
    use proptest::prelude::*;

    /// A square of `side` metres in two triangles.
    fn square(side: f32) -> Mesh {
        Mesh {
            triangles: vec![[0, 1, 2], [0, 2, 3]],
            ..Mesh::points(vec![
                [0.0, 0.0, 0.0],
                [side, 0.0, 0.0],
                [side, side, 0.0],
                [0.0, side, 0.0],
            ])
        }
    }

    #[test]
    fn a_street_sized_reference_is_sampled_wider_and_a_room_as_asked() {
        assert!((square(10.0).surface_area() - 100.0).abs() < 1e-9);
        assert_eq!(sample_spacing(&square(10.0), 0.02), 0.02);
        // 1 km² at 2 cm would be 2.5e9 samples: 10 million at 31.6 cm.
        let wide = sample_spacing(&square(1000.0), 0.02);
        assert!((wide - 0.1_f64.sqrt()).abs() < 1e-9, "{wide}");
        let count = square(1000.0).sample_surface(wide).len() as f64;
        assert!(count <= 1.01 * MAX_REFERENCE_SAMPLES, "{count}");
    }

    proptest! {
        /// A trajectory moved by any rigid transform, even one that stands still,
        /// aligns back onto the original.
        #[test]
        fn pose_alignment_recovers_a_rigid_motion(xi in se3::tests::tangent(3.0, 3.0), still in any::<bool>()) {
            let moved = se3::exp(&xi);
            let (mut reference, mut estimate) = (Trajectory::default(), Trajectory::default());
            for k in 0..20 {
                let t = k as f64 * 0.1;
                let step = if still { 1e-4 } else { 0.1 };
                let pose = se3::exp(&nalgebra::Vector6::new(step * k as f64, 0.0, 0.02 * t, 0.01 * k as f64, 0.3 * t, 0.0));
                reference.push(t, moved * pose);
                estimate.push(t + 0.001, pose);
            }
            let found = pose_alignment(&estimate, &reference).unwrap();
            let error = se3::log(&(found.inverse() * moved)).norm();
            prop_assert!(error < 1e-9, "error {}", error);
        }
    }
}
