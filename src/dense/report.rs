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
    /// Tracked frames not fused because the camera had hardly moved since the last
    /// fused one (`[dense] frame_min_translation`, `frame_min_rotation`).
    #[serde(default)]
    pub frames_left_still: usize,
    /// Frames fused while the camera stood still, every `[dense] frame_still_gap`-th
    /// frame instead of every `frame_max_gap`-th.
    #[serde(default)]
    pub frames_fused_still: usize,
    /// Tracked frames left out because they are in a map segment that no loop merged
    /// with the largest one.
    pub other_segment_frames: usize,
    /// Keyframes in the point cloud.
    pub keyframes_in_cloud: usize,
    /// Share of pixels masked as dynamic over the fused frames, %.
    pub masked_percent: f64,
    /// Share of the pixels the map could take (depth within `max_depth`) masked, %:
    /// what the masks cost the static scene and the movers, not counting pixels no
    /// depth would fuse anyway.
    #[serde(default)]
    pub masked_fusable_percent: f64,
    /// TSDF blocks allocated.
    pub tsdf_blocks: usize,
    /// Their voxels' size, MB (in memory or in the spill file).
    pub tsdf_memory_mb: f64,
    /// What the memory budget (`[dense] tsdf_memory_mb`) made the volume do: blocks
    /// written to the spill file and read back, the file's size, the most voxels in
    /// memory at once.
    #[serde(default)]
    pub tsdf_spill: crate::dense::tsdf::SpillCounts,
    /// What the memory budget (`[dense] cloud_memory_mb`) made the cloud's voxel sums
    /// do while frames were added: chunks written to the spill file and read back, the
    /// file's size, the most sums in memory at once.
    #[serde(default)]
    pub cloud_spill: crate::dense::cloud_voxels::CloudSpillCounts,
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
    /// Stereo: the semi-global matcher's settings the depth was made with
    /// (`[stereo] sgbm_disparities`, `sgbm_block`, `sgbm_downscale`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sgbm: Option<crate::dense::disparity::SgbmSettings>,
    /// Milliseconds: TSDF integration per frame (median), marching cubes, cloud.
    pub median_integration_ms: f64,
    /// Marching cubes, milliseconds.
    pub marching_cubes_ms: f64,
    /// The cloud, milliseconds.
    pub cloud_ms: f64,
    /// The whole pass, seconds.
    pub total_s: f64,
    /// Where that time went.
    #[serde(default)]
    pub stages: DenseStages,
    /// The pass's wall time over the recording's duration (frames fused, first to
    /// last): below 1 keeps up with the recording.
    #[serde(default)]
    pub real_time_factor: Option<f64>,
    /// Masked pixels the static map fused so far explained, fused after all
    /// (`[dense] mask_map_min_weight`).
    #[serde(default)]
    pub released_on_map: u64,
    /// The process's peak resident memory at the end of the pass (MiB, Linux).
    pub peak_memory_mib: Option<f64>,
    /// The peak memory of each part of the pass.
    #[serde(default)]
    pub memory: DenseMemory,
    /// Against the synthetic truth masks.
    pub truth: Option<FusedTruth>,
    /// The files written.
    pub outputs: Vec<PathBuf>,
    /// Where this pass kept its fused state (`[dense] keep_state`), for a later
    /// `dopslam fuse` to reuse.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kept_state: Option<PathBuf>,
    /// This pass reused a kept state instead of fusing: the figures of the frames fused
    /// and masked, `truth`, the stages up to integration and `memory.fusion_mib` are
    /// those of the pass that kept it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reused_state: Option<ReusedState>,
}

/// A kept fused state a pass reused ([`super::kept`]).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ReusedState {
    /// Its folder.
    pub from: PathBuf,
    /// Seconds the pass that kept it took up to the end of fusion.
    pub fusion_s: f64,
}

/// Where the dense pass's time went, seconds of wall time (within each stage rayon
/// uses every core). The stages run one after another, but for two: each frame's
/// loading and free-space evidence run beside the masks, integration and cloud of the
/// frame before it, so those five may sum to more than the time they took together.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct DenseStages {
    /// Reading the run folder, choosing the frames, placing the detected objects (as
    /// fusion comes near them; a stereo pair matched for that is not matched again
    /// when it is fused).
    pub inputs_s: f64,
    /// The dense pass's own detections ([`super::more_detections`]).
    pub detections_s: f64,
    /// The first pass of `allocate_first` (every frame's depth read once more).
    pub allocation_s: f64,
    /// Reading the fused frames (colour and depth; stereo: matching the pairs the
    /// objects' placement did not).
    pub loading_s: f64,
    /// The free-space evidence: the frames around read and every pixel projected.
    pub free_space_s: f64,
    /// The masks, the static map's check included.
    pub masks_s: f64,
    /// Counting against the truth masks and the mask pictures.
    pub truth_s: f64,
    /// TSDF integration.
    pub integration_s: f64,
    /// Keyframes into the point cloud.
    pub cloud_frames_s: f64,
    /// Marching cubes and the small pieces dropped.
    pub mesh_s: f64,
    /// The cloud: voxels, outliers, normals, carving.
    pub cloud_s: f64,
    /// The files and pictures.
    pub writing_s: f64,
}

/// The peak resident memory of each part of the dense pass, MiB, sampled every 10 ms
/// (what was resident before it included; `None` where the system cannot tell,
/// [`crate::memory::part_peak_mib`]).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(default)]
pub struct DenseMemory {
    /// From the pass's start to the last frame fused: the inputs, the pass's own
    /// detections, the volume and the cloud's frames as they grow.
    pub fusion_mib: Option<f64>,
    /// Marching cubes (the volume and the mesh).
    pub mesh_mib: Option<f64>,
    /// The cloud (the volume, the mesh and the cloud).
    pub cloud_mib: Option<f64>,
    /// The files and pictures.
    pub writing_mib: Option<f64>,
}

impl DenseStages {
    /// The per-frame stages (loading to cloud frames) taken from `frames`, and the
    /// objects' placement added to the inputs.
    pub fn frames_from(&mut self, frames: &DenseStages) {
        self.inputs_s += frames.inputs_s;
        self.loading_s = frames.loading_s;
        self.free_space_s = frames.free_space_s;
        self.masks_s = frames.masks_s;
        self.truth_s = frames.truth_s;
        self.integration_s = frames.integration_s;
        self.cloud_frames_s = frames.cloud_frames_s;
    }

    /// The stages by name, in order.
    pub fn named(&self) -> [(&'static str, f64); 12] {
        [
            ("inputs", self.inputs_s),
            ("detections", self.detections_s),
            ("allocation", self.allocation_s),
            ("loading", self.loading_s),
            ("free space", self.free_space_s),
            ("masks", self.masks_s),
            ("truth", self.truth_s),
            ("integration", self.integration_s),
            ("cloud frames", self.cloud_frames_s),
            ("mesh", self.mesh_s),
            ("cloud", self.cloud_s),
            ("writing", self.writing_s),
        ]
    }
}
