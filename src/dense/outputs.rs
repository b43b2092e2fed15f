//! The dense pass's outputs: the mesh (PLY, OBJ), the point cloud (PLY) and the
//! pictures, each computed before any file is written.

use std::path::{Path, PathBuf};
use std::time::Instant;

use super::cloud::{CloudBuilder, WrittenCloud};
use super::mesh_file::{MeshOnDisk, PrunedMesh};
use super::tsdf::TsdfVolume;
use super::{render, DenseConfig, DenseReport};
use crate::dop::Mode;
use crate::io::atomic::write_atomic;
use crate::io::ply_stream::PlyPointStream;
use crate::io::run_dir::{names, RunDir};
use crate::io::IoError;

/// The most mesh vertices or cloud points the pictures are drawn from (a sample spread
/// over the whole map).
const PICTURE_POINTS: usize = 2_000_000;

/// The fused volume and the keyframe cloud (when one is made).
pub struct Maps {
    /// The volume (empty when no mesh is made).
    pub volume: TsdfVolume,
    /// The cloud's sums.
    pub cloud: Option<CloudBuilder>,
}

impl Maps {
    /// With budgets: every voxel and sum goes to its spill file, with no spare arrays
    /// left (the mesh is made next, one batch of blocks at a time).
    pub fn spill_everything(&mut self) -> Result<(), IoError> {
        if let Some(cloud) = self.cloud.as_mut() {
            cloud.spill_everything()?;
        }
        self.volume.spill_everything()
    }
}

/// The trajectory files (TUM) whose cameras the pictures look from, one recording's
/// after another's: read twice as the pictures are made, never held.
#[derive(Debug, Clone, Default)]
pub(super) struct CameraPaths(pub Vec<PathBuf>);

impl CameraPaths {
    /// The pictures' viewpoint ([`render::Viewpoint::from_cameras`]) over every pose of
    /// the files; `None` without any.
    pub fn viewpoint(&self) -> Result<Option<render::Viewpoint>, IoError> {
        render::Viewpoint::from_camera_reads(|each| {
            for path in &self.0 {
                crate::io::trajectory::for_each_tum(path, |_, pose| {
                    each(&pose);
                    Ok(())
                })?;
            }
            Ok(())
        })
    }
}

/// Writes the mesh (marching cubes over the volume, when it was fused), the point
/// cloud (carved by the volume when asked) and the pictures into `out`.
pub(super) fn write_maps(
    out: &RunDir,
    masking: Mode,
    config: &DenseConfig,
    maps: Maps,
    cameras: &CameraPaths,
    report: &mut DenseReport,
) -> Result<(), IoError> {
    let comment = format!(
        "dopslam dense map, masking {:?}, voxel {} m",
        masking, config.tsdf.voxel
    );
    // The frames' buffers are gone, and with budgets the cloud's sums and the
    // volume's voxels wait in their spill files: their pages go back before the mesh
    // is made, which brings one batch of blocks back at a time.
    let mut maps = maps;
    maps.spill_everything()?;
    let Maps { mut volume, cloud } = maps;
    crate::memory::release_freed_memory();
    // The mesh's part starts here: what the budgets held until now is fusion's.
    crate::memory::part_peak_mib();
    // Everything is computed before anything is written: an interrupt until then
    // leaves the earlier dense map as it was.
    let mesh = match config.fuses_tsdf() {
        true => Some(make_mesh(out, config, &mut volume, report)?),
        false => None,
    };
    let points = match cloud {
        Some(cloud) => Some(write_cloud(out, config, cloud, volume, &comment, report)?),
        None => {
            report.tsdf_spill = volume.spill_counts()?;
            drop(volume);
            None
        }
    };
    interrupted(
        out.root(),
        "the dense map was not written; the earlier one is as it was",
    )?;
    let start = Instant::now();
    let (stream, sample) = match points {
        Some(points) => (Some(points.stream), Some(points.sample)),
        None => (None, None),
    };
    write_files(out, config, mesh.as_ref(), stream, &comment, report)?;
    if config.outputs.pictures {
        let map = match &mesh {
            Some(mesh) => Some(mesh.sample(PICTURE_POINTS)?),
            None => sample,
        };
        if let Some(map) = map {
            write_pictures(out, &map, cameras, report)?;
        }
    }
    report.stages.writing_s = start.elapsed().as_secs_f64();
    report.memory.writing_mib = crate::memory::part_peak_mib();
    Ok(())
}

/// The mesh of `volume`, made on disk beside `out`'s files, without its small pieces.
fn make_mesh(
    out: &RunDir,
    config: &DenseConfig,
    volume: &mut TsdfVolume,
    report: &mut DenseReport,
) -> Result<PrunedMesh, IoError> {
    let start = Instant::now();
    let mesh = MeshOnDisk::extract(volume, out.root())?;
    let mesh = mesh.prune(config.outputs.mesh_min_piece_area)?;
    report.marching_cubes_ms = start.elapsed().as_secs_f64() * 1e3;
    report.stages.mesh_s = report.marching_cubes_ms / 1e3;
    let dropped = mesh.pruned();
    report.mesh_pieces_dropped = dropped.pieces;
    report.mesh_vertices_dropped = dropped.vertices;
    report.mesh_vertices = mesh.len();
    report.mesh_triangles = mesh.triangles();
    report.memory.mesh_mib = crate::memory::part_peak_mib();
    Ok(mesh)
}

/// The cloud carved by the `volume` (dropped before the cloud's neighbour searches),
/// its rows streamed to `out`'s cloud file (finished with the other files).
fn write_cloud(
    out: &RunDir,
    config: &DenseConfig,
    cloud: CloudBuilder,
    mut volume: TsdfVolume,
    comment: &str,
    report: &mut DenseReport,
) -> Result<WrittenCloud, IoError> {
    // The carving only queries the volume: with a budget, its voxels wait in the
    // spill file meanwhile.
    volume.spill_everything()?;
    crate::memory::release_freed_memory();
    let start = Instant::now();
    let (carving, limit) = (config.cloud_carved(), config.cloud.free_space);
    let (carved, dropped) = cloud.carve(|means| match carving {
        true => volume.seen_through_each(means, limit),
        false => vec![false; means.len()],
    })?;
    report.tsdf_spill = volume.spill_counts()?;
    drop(volume);
    crate::memory::release_freed_memory();
    let path = out.file(names::DENSE_POINTS);
    let encoding = config.outputs.ply_encoding;
    let points = carved.write(&path, encoding, comment, PICTURE_POINTS)?;
    report.cloud_ms = start.elapsed().as_secs_f64() * 1e3;
    report.stages.cloud_s = report.cloud_ms / 1e3;
    report.cloud_points = points.stream.len();
    report.cloud_seen_through = dropped;
    report.cloud_spill = points.spill;
    report.memory.cloud_mib = crate::memory::part_peak_mib();
    // The positions and their k-d tree are gone: their pages go back before the
    // files are written.
    crate::memory::release_freed_memory();
    Ok(points)
}

/// The `mesh` (PLY, and OBJ when asked) and the cloud `points` (PLY, its rows
/// streamed already) into `out`.
fn write_files(
    out: &RunDir,
    config: &DenseConfig,
    mesh: Option<&PrunedMesh>,
    points: Option<PlyPointStream>,
    comment: &str,
    report: &mut DenseReport,
) -> Result<(), IoError> {
    if let Some(mesh) = mesh {
        let path = out.file(names::DENSE_MESH_PLY);
        mesh.write_ply(&path, config.outputs.ply_encoding, comment)?;
        report.outputs.push(path);
        if config.outputs.obj {
            let path = out.file(names::DENSE_MESH_OBJ);
            mesh.write_obj(&path, comment)?;
            report.outputs.push(path);
        }
    }
    if let Some(points) = points {
        points.finish()?;
        report.outputs.push(out.file(names::DENSE_POINTS));
    }
    Ok(())
}

/// The dense map's pictures (perspective and top view) from the cameras' side.
fn write_pictures(
    out: &RunDir,
    map: &crate::geometry::mesh::Mesh,
    cameras: &CameraPaths,
    report: &mut DenseReport,
) -> Result<(), IoError> {
    let Some(view) = cameras.viewpoint()? else {
        return Ok(());
    };
    let colours = render::with_ghosts(map, &[]);
    let pictures = [
        (
            names::DENSE_PERSPECTIVE,
            render::perspective(
                &map.vertices,
                &colours,
                &view.camera_from_world,
                &render::picture_camera(),
            ),
        ),
        (
            names::DENSE_TOP,
            render::top(&map.vertices, &colours, &view, 800),
        ),
    ];
    for (name, picture) in pictures {
        let path = out.file(name);
        save_png(&path, &picture)?;
        report.outputs.push(path);
    }
    Ok(())
}

/// Writes a PNG atomically.
pub fn save_png(path: &Path, picture: &image::RgbImage) -> Result<(), IoError> {
    let mut bytes = Vec::new();
    picture
        .write_to(
            &mut std::io::Cursor::new(&mut bytes),
            image::ImageFormat::Png,
        )
        .map_err(|e| IoError::Write {
            path: path.to_path_buf(),
            source: std::io::Error::other(e),
        })?;
    write_atomic(path, &bytes)
}

/// `Err` naming `dir` and saying `what` once an interrupt was asked for.
pub(super) fn interrupted(dir: &Path, what: &str) -> Result<(), IoError> {
    if crate::interrupt::requested() {
        return Err(IoError::invalid(
            dir,
            format!("{}: {what}", crate::interrupt::MESSAGE),
        ));
    }
    Ok(())
}

/// Sets `report`'s totals (the time since `started`, of the `recording`'s seconds, and
/// the peak memory) and writes it as `dense.json`.
pub(super) fn finish_report(
    out: &RunDir,
    mut report: DenseReport,
    started: Instant,
    recording: Option<f64>,
) -> Result<DenseReport, IoError> {
    report.total_s = started.elapsed().as_secs_f64();
    report.real_time_factor = recording.map(|recording| report.total_s / recording);
    report.peak_memory_mib = crate::memory::peak_resident_mib();
    report.schema = crate::io::run_dir::SCHEMA;
    let json = serde_json::to_string_pretty(&report).expect("report serialises");
    write_atomic(&out.dense_report(), json.as_bytes())?;
    // A request that came while the files were written: they were finished whole, and
    // the command still ends as interrupted.
    interrupted(
        out.root(),
        "asked while the dense map was written: it was finished whole",
    )?;
    Ok(report)
}
