//! What the dense pass did (`dense.json`, and `report.json`'s `dense`).

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::more_detections::ExtraDetections;
use super::truth::FusedTruth;
use crate::dop::Mode;

/// What the dense pass did.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct DenseReport {
    /// The layout version (`crate::io::run_dir::SCHEMA`; 0 until written).
    pub schema: u32,
    /// How movers were masked (none without a dense pass).
    pub masking: Option<Mode>,
    /// Frames fused into the TSDF.
    pub frames_fused: usize,
    /// Tracked frames left out because they are in a map segment that no loop merged
    /// with the largest one.
    pub other_segment_frames: usize,
    /// Keyframes in the point cloud.
    pub keyframes_in_cloud: usize,
    /// Share of pixels masked as dynamic over the fused frames, %.
    pub masked_percent: f64,
    /// TSDF blocks allocated.
    pub tsdf_blocks: usize,
    /// Their memory, MB.
    pub tsdf_memory_mb: f64,
    /// Mesh vertices.
    pub mesh_vertices: usize,
    /// Mesh triangles.
    pub mesh_triangles: usize,
    /// Pieces of the mesh dropped as smaller than `mesh_min_piece_area`.
    pub mesh_pieces_dropped: usize,
    /// Their vertices (not in `mesh_vertices`).
    pub mesh_vertices_dropped: usize,
    /// Cloud points.
    pub cloud_points: usize,
    /// Cloud voxels dropped as seen through (see `DenseConfig::cloud_free_space`).
    pub cloud_seen_through: usize,
    /// The dense pass's own detections (`detect_every`).
    pub extra_detections: Option<ExtraDetections>,
    /// Stereo: pixels added to every SGBM disparity (the rig's offset the run found).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub disparity_offset_px: Option<f64>,
    /// Milliseconds: TSDF integration per frame (median), marching cubes, cloud.
    pub median_integration_ms: f64,
    /// Marching cubes, milliseconds.
    pub marching_cubes_ms: f64,
    /// The cloud, milliseconds.
    pub cloud_ms: f64,
    /// The whole pass, seconds.
    pub total_s: f64,
    /// The process's peak resident memory at the end of the pass (MiB, Linux).
    pub peak_memory_mib: Option<f64>,
    /// Against the synthetic truth masks.
    pub truth: Option<FusedTruth>,
    /// The files written.
    pub outputs: Vec<PathBuf>,
}
