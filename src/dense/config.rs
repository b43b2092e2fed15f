//! The `[dense]` section: what the dense pass fuses, how the movers are masked, what
//! it writes, and the settings of each part built from it.

use serde::{Deserialize, Serialize};

use super::cloud::CloudSettings;
use super::free_space::FreeSpaceSettings;
use super::masks::MaskSettings;
use super::segments::SegmentSettings;
use super::tsdf::TsdfSettings;
use crate::checks::{self, BadValue};
use crate::detect::{DetectorConfig, Model, Models, Source};
use crate::io::ply::PlyEncoding;

/// `[dense] detect_model`: the model of the dense pass's own detections.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DenseModel {
    /// The tracking pass's `[detector]` as it is.
    Tracking,
    /// YOLOv4-tiny.
    Yolov4Tiny,
    /// YOLOX-nano.
    YoloxNano,
    /// DEIMv2-femto.
    Deimv2Femto,
}

impl DenseModel {
    /// The model, `None` for the tracking pass's.
    pub fn model(self) -> Option<Model> {
        match self {
            DenseModel::Tracking => None,
            DenseModel::Yolov4Tiny => Some(Model::Yolov4Tiny),
            DenseModel::YoloxNano => Some(Model::YoloxNano),
            DenseModel::Deimv2Femto => Some(Model::Deimv2Femto),
        }
    }
}

/// Which frames go into the TSDF.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FrameChoice {
    /// Every tracked frame.
    All,
    /// Keyframes only.
    Keyframes,
}

/// How the dense map is fused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Fusion {
    /// A TSDF with space carving, meshed by marching cubes; the keyframes' point cloud
    /// loses what the TSDF has since seen through (`cloud_free_space`).
    Tsdf,
    /// ORB-SLAM2's dense point cloud (the paper's Fig. 9): the keyframes' clouds
    /// joined and voxel-downsampled, no TSDF and no carving, so a mover the masks miss
    /// stays in the map wherever it stood.
    Points,
    /// Both: the TSDF mesh, and the keyframes' cloud without carving (the demo shows
    /// each).
    Both,
}

/// `[dense]`: the dense map, in its parts. The file spells the keys flat (`voxel`,
/// `mask_border`, ...; [`DenseFile`]); each part here is what one step of the pass
/// reads.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(from = "DenseFile", into = "DenseFile")]
pub struct DenseConfig {
    /// Run the dense pass after tracking (`dopslam run`).
    pub enabled: bool,
    /// TSDF mesh (default), ORB-SLAM2-style point cloud without carving, or both.
    pub fusion: Fusion,
    /// Which frames are fused.
    pub frames: DenseFrames,
    /// The TSDF volume.
    pub tsdf: DenseTsdf,
    /// The keyframes' point cloud.
    pub cloud: DenseCloud,
    /// The dense pass's own detections.
    pub detections: DenseDetections,
    /// How the movers are masked.
    pub masks: DenseMasks,
    /// What the dense pass writes.
    pub outputs: DenseOutputs,
}

/// Which frames are fused (`[dense]` keys `frames`, `frame_step`,
/// `frame_min_translation`, `frame_min_rotation`, `frame_max_gap`, `frame_still_gap`).
#[derive(Debug, Clone, PartialEq)]
pub struct DenseFrames {
    /// Frames fused into the TSDF: all tracked frames or keyframes only.
    pub which: FrameChoice,
    /// Fuse every n-th chosen frame.
    pub step: usize,
    /// Of those, a frame is fused when the camera moved at least this far since the
    /// last fused frame (metres), or turned at least [`Self::min_rotation`], or
    /// [`Self::max_gap`] frames have passed; keyframes always are. A frame from
    /// nearly the same place adds little the last one did not (0 and 0: every frame).
    pub min_translation: f64,
    /// Degrees (see [`Self::min_translation`]).
    pub min_rotation: f64,
    /// At most this many of the chosen frames from one fused frame to the next.
    pub max_gap: usize,
    /// While the camera stands still (it moved under a quarter of
    /// [`Self::min_translation`] and turned under a quarter of [`Self::min_rotation`]
    /// over the last [`Self::max_gap`] frames), this gap instead: the view does not
    /// change, the scene does, and each frame shows background the movers hid in the
    /// last (0: [`Self::max_gap`] throughout).
    pub still_gap: usize,
}

/// The TSDF volume (`[dense]` keys `voxel`, `truncation`, `max_depth`, `max_weight`, `carve`, `far_carves`, `image_margin`, `allocate_first`, `tsdf_memory_mb`).
#[derive(Debug, Clone, PartialEq)]
pub struct DenseTsdf {
    /// Voxel edge, metres.
    pub voxel: f64,
    /// TSDF truncation, metres.
    pub truncation: f64,
    /// Depths beyond this are not fused, metres.
    pub max_depth: f64,
    /// Weight cap: lower forgets faster (carving of what left).
    pub max_weight: f32,
    /// Carve free space along rays (erases surfaces that later proved empty).
    pub carve: bool,
    /// A depth beyond `max_depth` still carves its ray up to `max_depth`.
    pub far_carves: bool,
    /// Pixels this close to the image border fuse no surface into the TSDF (they still
    /// carve): a person cut by the border to a sliver is found by no detector.
    pub image_margin: u32,
    /// Allocate every fused frame's blocks before fusing any (a first pass that reads
    /// the depth of every frame once more: for stereo, SGBM twice), so that carving
    /// also counts the free space seen before a mover came (see
    /// [`TsdfVolume::allocate`]).
    pub allocate_first: bool,
    /// The most block voxels held in memory, MB: beyond it the blocks the camera left
    /// longest ago go to a spill file in the output folder (removed at the end) and
    /// come back when needed, with the same result ([`TsdfVolume::spill_to`]); 0: no
    /// limit.
    pub memory_mb: f64,
}

/// The keyframes' point cloud (`[dense]` keys `cloud_voxel`, `cloud_stride`, `outlier_neighbours`, `outlier_std`, `normal_neighbours`, `cloud_free_space`, `cloud_memory_mb`).
#[derive(Debug, Clone, PartialEq)]
pub struct DenseCloud {
    /// Voxel edge, metres.
    pub voxel: f64,
    /// The cloud's pixel stride.
    pub stride: usize,
    /// Neighbours for outlier removal (0: off).
    pub outlier_neighbours: usize,
    /// The outlier threshold, standard deviations.
    pub outlier_std: f64,
    /// Neighbours for normals (0: none).
    pub normal_neighbours: usize,
    /// Cloud points the fused TSDF has since seen as free space are dropped (a mover
    /// missed by the masks that later left): \(F\) above this, in truncation units
    /// (1 or more: off; needs the mesh).
    pub free_space: f32,
    /// The most voxel sums held in memory (as frames are added, and as the cloud is
    /// carved and written), MB: beyond it the chunks least recently used go to a spill
    /// file in the output folder (removed at the end), with the same cloud
    /// ([`super::cloud::CloudBuilder::spill_to`]); 0: no limit.
    pub memory_mb: f64,
}

/// The dense pass's own detections (`[dense]` keys `detect_every`, `detect_model`, `detect_tiles`).
#[derive(Debug, Clone, PartialEq)]
pub struct DenseDetections {
    /// With the DOP model, also detect on every n-th fused frame for the masks (0: the
    /// keyframes' detections only; see [`super::more_detections`]).
    pub every: usize,
    /// The model of those detections, when the run's detector is ONNX: the dense
    /// pass is offline and can afford a better one than the tracking pass's.
    pub model: DenseModel,
    /// ... run on the whole image and on `detect_tiles` x `detect_tiles` overlapping
    /// tiles of it ([`crate::detect::tiles`]); 1: the whole image only.
    pub tiles: u32,
}

/// How the movers are masked (`[dense]` keys `mask_border`, `keypoint_radius`, `mask_foreground_share`, `mask_depth_behind`, `mask_depth_behind_not_still`, `mask_track_margin_speed`, `mask_discs_behind_objects`, `mask_disc_neighbours`, `mask_keypoints_seen_moving`, `mask_segments`, `mask_segment_radius`, `mask_segment_radius_metres`, `mask_segment_edge_share`, `mask_segment_support`, `mask_segment_follow_seconds`, `mask_free_space_seconds`, `mask_free_space_far_seconds`, `mask_free_space_stride`, `mask_free_space_no_return`, `mask_free_space_tolerance_growth`, `mask_map_min_weight`, `mask_map_band`, `mask_map_release_bodies`).
#[derive(Debug, Clone, PartialEq)]
pub struct DenseMasks {
    /// Mask dilation, pixels.
    pub border: u32,
    /// The disc radius around a dynamic keypoint, pixels.
    pub keypoint_radius: u32,
    /// The depth an object's mask is cut at: the nearest depth mode holding at least
    /// this share of its box's pixels (the mover stands in front of what it hides);
    /// 0: the dominant depth of the box's centre, as the tracking pass refines boxes.
    pub foreground_share: f32,
    /// How far behind its depth an object's mask reaches, metres (in front it reaches
    /// the DOP model's `delta_z`): a walker's far leg and feet lie up to half a metre
    /// behind the front of their body.
    pub depth_behind: f32,
    /// How far behind its depth an object's mask reaches at the pixels the frames
    /// around did not see still (free-space evidence, DOP only), metres; below
    /// `depth_behind`: no farther. A person partly hidden behind another in one box
    /// stands up to a metre or more behind the front one, where the static scene
    /// behind a walker is seen still from the frames around.
    pub depth_behind_not_still: f32,
    /// A followed person the detector missed on a detected frame is masked with the
    /// box their track predicts there, grown on every side by this speed (m/s) times
    /// the time since they were seen (the tracking pass's boxes grow at `[dop]
    /// track_max_speed`). The prediction already moves with the person's velocity;
    /// the margin only covers its error. Gaps between two detections of a person
    /// need none ([`super::masks`]).
    pub track_margin_speed: f32,
    /// Discs also around dynamic keypoints inside a detected mover's box but behind
    /// it (false: none there; more static pixels fused, but a second mover behind the
    /// first loses its discs).
    pub discs_behind_objects: bool,
    /// A disc only around a dynamic keypoint with at least this many other dynamic
    /// keypoints within four disc radii (0: around every one): the geometric check's
    /// lone false alarms on the static scene get none, a mover's keypoints come in
    /// groups.
    pub disc_neighbours: usize,
    /// With free-space evidence: discs and segments only around the dynamic keypoints
    /// with a pixel seen moving within the disc's radius. The tracking pass's dynamic
    /// keypoints include static ones (a box's or a propagated probability); the
    /// neighbours' free space tells them apart where it can see.
    pub keypoints_seen_moving: bool,
    /// Grow a depth segment from the dynamic keypoints outside every detected mover's
    /// box (movers no detector knows, see [`segments`]): a region is kept when at least
    /// `mask_segment_edge_share` of its border is a depth edge to something farther,
    /// it holds `mask_segment_support` keypoints or more, and it grows at most
    /// `mask_segment_radius` pixels from its seed, or as far as
    /// `mask_segment_radius_metres` reaches at the seed's depth where that is farther.
    pub segments: bool,
    /// The segment's reach from its seed, pixels.
    pub segment_radius: u32,
    /// The segment's reach at the seed's depth, metres.
    pub segment_radius_metres: f32,
    /// The share of its border that must be a depth edge.
    pub segment_edge_share: f32,
    /// The keypoints a segment needs.
    pub segment_support: usize,
    /// A kept segment seeds the next frames' growth for this many seconds after a
    /// dynamic keypoint last supported it (0: no following).
    pub segment_follow_seconds: f64,
    /// Free-space evidence ([`free_space`]): each fused frame's pixels are checked
    /// against the frames this many seconds (and half as many) before and after it;
    /// pixels those frames saw through are masked (movers, also those no detector
    /// found), and discs and dilation leave out pixels they saw still. 0: off.
    pub free_space_seconds: f64,
    /// Far neighbours added to the free-space evidence (when it is on): the frames
    /// this many seconds (and half as many) before and after each fused frame. A mover
    /// that stands still longer than the near window (a box set down, a person who
    /// waits) was seen elsewhere then, and its place seen through. 0: none.
    pub free_space_far_seconds: f64,
    /// The free-space evidence judges every `free_space_stride`-th pixel of every
    /// such row against the neighbours; the pixels between copy those around them
    /// where they lie at the same depth and agree, and are judged themselves where
    /// they do not (1: every pixel judged).
    pub free_space_stride: usize,
    /// A neighbour frame with no depth at all within 2 pixels of where a pixel's
    /// point projects, the point lying within this many metres of that frame,
    /// returned nothing from it: weaker evidence than seeing through that the point
    /// was gone (a walker's legs before a floor beyond the sensor's range; a dark or
    /// shiny static surface returns nothing either), see
    /// [`crate::dense::free_space`]. 0: off.
    pub free_space_no_return: f32,
    /// How fast the free-space test's depth tolerance grows with the depth:
    /// \(\tau(z) = 0.03\,\mathrm{m} + g z^2\) (per metre). A neighbour's depth within
    /// \(\tau\) of a point is the same surface; beyond it, seen through.
    pub free_space_tolerance_growth: f32,
    /// A masked pixel whose depth lies on the static map fused so far, where the map
    /// has at least this weight (frames), is fused after all (`dense.json`'s
    /// `map_agrees`): the wall behind a person's box, the floor around a disc. A mover
    /// stands in front of the map, or where the map has nothing yet. 0: off.
    pub map_min_weight: f32,
    /// How far in front of the map's surface (metres) a masked pixel's depth may lie
    /// and still be on it: the sensor's noise (a Kinect's or Xtion's is 2-3 cm at
    /// 3.5 m). A mover's foot that close to the floor is fused with it. Taken as the
    /// truncation where it is wider (the field says nothing farther out).
    pub map_band: f32,
    /// The map also releases a detected object's body pixels that the free-space
    /// evidence saw still (the floor at a walker's feet, a desk beside them at their
    /// depth); a body in front of the map, or seen moving, stays masked.
    pub map_release_bodies: bool,
}

/// What the dense pass writes (`[dense]` keys `mesh`, `obj`, `mesh_min_piece_area`, `cloud`, `pictures`, `mask_pictures_every`, `ply_encoding`, `keep_state`).
#[derive(Debug, Clone, PartialEq)]
pub struct DenseOutputs {
    /// The mesh (PLY).
    pub mesh: bool,
    /// The mesh as OBJ too.
    pub obj: bool,
    /// Pieces of the mesh (triangles connected to each other) with less surface than
    /// this, m², are dropped: a mover's fragment fused where no mask caught it floats
    /// apart from the scene, as do specks of depth noise. 0: keep every piece.
    pub mesh_min_piece_area: f64,
    /// The point cloud.
    pub cloud: bool,
    /// Pictures of the map.
    pub pictures: bool,
    /// Every n-th fused frame's mask as a picture in `mask_pictures/` (0: none): the
    /// colour frame beside its mask, against the ground truth of a synthetic sequence
    /// (green: mover masked, red: static masked, yellow: mover fused).
    pub mask_pictures_every: usize,
    /// PLY encoding: binary (little endian) or ascii.
    pub ply_encoding: PlyEncoding,
    /// Keep the fused volume and cloud in `dense_state/` ([`super::kept`]) for a
    /// later `dopslam fuse` with other output settings to reuse (GBs on long routes).
    pub keep_state: bool,
}

/// The `[dense]` section as the file spells it: flat keys, read into [`DenseConfig`]'s
/// parts.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DenseFile {
    enabled: bool,
    fusion: Fusion,
    voxel: f64,
    truncation: f64,
    max_depth: f64,
    max_weight: f32,
    carve: bool,
    far_carves: bool,
    image_margin: u32,
    allocate_first: bool,
    tsdf_memory_mb: f64,
    frames: FrameChoice,
    frame_step: usize,
    frame_min_translation: f64,
    frame_min_rotation: f64,
    frame_max_gap: usize,
    frame_still_gap: usize,
    mesh: bool,
    obj: bool,
    mesh_min_piece_area: f64,
    cloud: bool,
    pictures: bool,
    cloud_voxel: f64,
    cloud_stride: usize,
    outlier_neighbours: usize,
    outlier_std: f64,
    normal_neighbours: usize,
    cloud_free_space: f32,
    cloud_memory_mb: f64,
    detect_every: usize,
    detect_model: DenseModel,
    detect_tiles: u32,
    mask_border: u32,
    keypoint_radius: u32,
    mask_foreground_share: f32,
    mask_depth_behind: f32,
    mask_depth_behind_not_still: f32,
    mask_track_margin_speed: f32,
    mask_discs_behind_objects: bool,
    mask_disc_neighbours: usize,
    mask_keypoints_seen_moving: bool,
    mask_segments: bool,
    mask_segment_radius: u32,
    mask_segment_radius_metres: f32,
    mask_segment_edge_share: f32,
    mask_segment_support: usize,
    mask_segment_follow_seconds: f64,
    mask_free_space_seconds: f64,
    mask_free_space_far_seconds: f64,
    mask_free_space_stride: usize,
    mask_free_space_no_return: f32,
    mask_free_space_tolerance_growth: f32,
    mask_map_min_weight: f32,
    mask_map_band: f32,
    mask_map_release_bodies: bool,
    mask_pictures_every: usize,
    ply_encoding: PlyEncoding,
    keep_state: bool,
}

impl Default for DenseFile {
    fn default() -> Self {
        DenseConfig::default().into()
    }
}

impl From<DenseFile> for DenseConfig {
    fn from(file: DenseFile) -> Self {
        Self {
            enabled: file.enabled,
            fusion: file.fusion,
            frames: DenseFrames {
                which: file.frames,
                step: file.frame_step,
                min_translation: file.frame_min_translation,
                min_rotation: file.frame_min_rotation,
                max_gap: file.frame_max_gap,
                still_gap: file.frame_still_gap,
            },
            tsdf: DenseTsdf {
                voxel: file.voxel,
                truncation: file.truncation,
                max_depth: file.max_depth,
                max_weight: file.max_weight,
                carve: file.carve,
                far_carves: file.far_carves,
                image_margin: file.image_margin,
                allocate_first: file.allocate_first,
                memory_mb: file.tsdf_memory_mb,
            },
            cloud: DenseCloud {
                voxel: file.cloud_voxel,
                stride: file.cloud_stride,
                outlier_neighbours: file.outlier_neighbours,
                outlier_std: file.outlier_std,
                normal_neighbours: file.normal_neighbours,
                free_space: file.cloud_free_space,
                memory_mb: file.cloud_memory_mb,
            },
            detections: DenseDetections {
                every: file.detect_every,
                model: file.detect_model,
                tiles: file.detect_tiles,
            },
            masks: DenseMasks {
                border: file.mask_border,
                keypoint_radius: file.keypoint_radius,
                foreground_share: file.mask_foreground_share,
                depth_behind: file.mask_depth_behind,
                depth_behind_not_still: file.mask_depth_behind_not_still,
                track_margin_speed: file.mask_track_margin_speed,
                discs_behind_objects: file.mask_discs_behind_objects,
                disc_neighbours: file.mask_disc_neighbours,
                keypoints_seen_moving: file.mask_keypoints_seen_moving,
                segments: file.mask_segments,
                segment_radius: file.mask_segment_radius,
                segment_radius_metres: file.mask_segment_radius_metres,
                segment_edge_share: file.mask_segment_edge_share,
                segment_support: file.mask_segment_support,
                segment_follow_seconds: file.mask_segment_follow_seconds,
                free_space_seconds: file.mask_free_space_seconds,
                free_space_far_seconds: file.mask_free_space_far_seconds,
                free_space_stride: file.mask_free_space_stride,
                free_space_no_return: file.mask_free_space_no_return,
                free_space_tolerance_growth: file.mask_free_space_tolerance_growth,
                map_min_weight: file.mask_map_min_weight,
                map_band: file.mask_map_band,
                map_release_bodies: file.mask_map_release_bodies,
            },
            outputs: DenseOutputs {
                mesh: file.mesh,
                obj: file.obj,
                mesh_min_piece_area: file.mesh_min_piece_area,
                cloud: file.cloud,
                pictures: file.pictures,
                mask_pictures_every: file.mask_pictures_every,
                ply_encoding: file.ply_encoding,
                keep_state: file.keep_state,
            },
        }
    }
}

impl From<DenseConfig> for DenseFile {
    fn from(config: DenseConfig) -> Self {
        let DenseConfig {
            enabled,
            fusion,
            frames,
            tsdf,
            cloud,
            detections,
            masks,
            outputs,
        } = config;
        Self {
            enabled,
            fusion,
            frames: frames.which,
            frame_step: frames.step,
            frame_min_translation: frames.min_translation,
            frame_min_rotation: frames.min_rotation,
            frame_max_gap: frames.max_gap,
            frame_still_gap: frames.still_gap,
            voxel: tsdf.voxel,
            truncation: tsdf.truncation,
            max_depth: tsdf.max_depth,
            max_weight: tsdf.max_weight,
            carve: tsdf.carve,
            far_carves: tsdf.far_carves,
            image_margin: tsdf.image_margin,
            allocate_first: tsdf.allocate_first,
            tsdf_memory_mb: tsdf.memory_mb,
            cloud_voxel: cloud.voxel,
            cloud_stride: cloud.stride,
            outlier_neighbours: cloud.outlier_neighbours,
            outlier_std: cloud.outlier_std,
            normal_neighbours: cloud.normal_neighbours,
            cloud_free_space: cloud.free_space,
            cloud_memory_mb: cloud.memory_mb,
            detect_every: detections.every,
            detect_model: detections.model,
            detect_tiles: detections.tiles,
            mask_border: masks.border,
            keypoint_radius: masks.keypoint_radius,
            mask_foreground_share: masks.foreground_share,
            mask_depth_behind: masks.depth_behind,
            mask_depth_behind_not_still: masks.depth_behind_not_still,
            mask_track_margin_speed: masks.track_margin_speed,
            mask_discs_behind_objects: masks.discs_behind_objects,
            mask_disc_neighbours: masks.disc_neighbours,
            mask_keypoints_seen_moving: masks.keypoints_seen_moving,
            mask_segments: masks.segments,
            mask_segment_radius: masks.segment_radius,
            mask_segment_radius_metres: masks.segment_radius_metres,
            mask_segment_edge_share: masks.segment_edge_share,
            mask_segment_support: masks.segment_support,
            mask_segment_follow_seconds: masks.segment_follow_seconds,
            mask_free_space_seconds: masks.free_space_seconds,
            mask_free_space_far_seconds: masks.free_space_far_seconds,
            mask_free_space_stride: masks.free_space_stride,
            mask_free_space_no_return: masks.free_space_no_return,
            mask_free_space_tolerance_growth: masks.free_space_tolerance_growth,
            mask_map_min_weight: masks.map_min_weight,
            mask_map_band: masks.map_band,
            mask_map_release_bodies: masks.map_release_bodies,
            mesh: outputs.mesh,
            obj: outputs.obj,
            mesh_min_piece_area: outputs.mesh_min_piece_area,
            cloud: outputs.cloud,
            pictures: outputs.pictures,
            mask_pictures_every: outputs.mask_pictures_every,
            ply_encoding: outputs.ply_encoding,
            keep_state: outputs.keep_state,
        }
    }
}

impl Default for DenseConfig {
    fn default() -> Self {
        let tsdf = TsdfSettings::default();
        let segments = SegmentSettings::default();
        let free_space = FreeSpaceSettings::default();
        Self {
            enabled: true,
            fusion: Fusion::Tsdf,
            frames: DenseFrames {
                which: FrameChoice::All,
                step: 1,
                min_translation: 0.02,
                min_rotation: 1.0,
                max_gap: 3,
                still_gap: 1,
            },
            tsdf: DenseTsdf {
                voxel: tsdf.voxel,
                truncation: tsdf.truncation,
                max_depth: tsdf.max_depth,
                max_weight: tsdf.max_weight,
                carve: tsdf.carve,
                far_carves: tsdf.far_carves,
                image_margin: tsdf.margin,
                allocate_first: true,
                memory_mb: 512.0,
            },
            cloud: DenseCloud {
                voxel: 0.01,
                stride: 2,
                outlier_neighbours: 16,
                outlier_std: 2.0,
                normal_neighbours: 16,
                free_space: 0.5,
                memory_mb: 256.0,
            },
            detections: DenseDetections {
                every: 5,
                model: DenseModel::Tracking,
                tiles: 1,
            },
            masks: DenseMasks {
                border: 6,
                keypoint_radius: 10,
                foreground_share: 0.10,
                depth_behind: 0.6,
                depth_behind_not_still: 1.2,
                track_margin_speed: 0.75,
                discs_behind_objects: true,
                disc_neighbours: 6,
                keypoints_seen_moving: true,
                segments: true,
                segment_radius: segments.radius,
                segment_radius_metres: segments.radius_metres,
                segment_edge_share: segments.edge_share,
                segment_support: segments.support,
                segment_follow_seconds: 3.0,
                free_space_seconds: free_space.seconds,
                free_space_far_seconds: free_space.far_seconds,
                free_space_stride: free_space.stride,
                free_space_no_return: 4.0,
                free_space_tolerance_growth: free_space.tolerance_growth,
                map_min_weight: 10.0,
                map_band: 0.025,
                map_release_bodies: true,
            },
            outputs: DenseOutputs {
                mesh: true,
                obj: true,
                mesh_min_piece_area: 0.05,
                cloud: true,
                pictures: true,
                mask_pictures_every: 0,
                ply_encoding: PlyEncoding::Binary,
                keep_state: false,
            },
        }
    }
}

impl DenseConfig {
    /// Checks each value's range; the error names the key.
    pub fn validate(&self) -> Result<(), BadValue> {
        checks::each(
            "dense",
            checks::positive,
            &[
                ("voxel", self.tsdf.voxel),
                ("truncation", self.tsdf.truncation),
                ("max_depth", self.tsdf.max_depth),
                ("max_weight", self.tsdf.max_weight as f64),
                ("cloud_voxel", self.cloud.voxel),
                ("outlier_std", self.cloud.outlier_std),
            ],
        )?;
        if !(self.cloud.free_space.is_finite() && self.cloud.free_space > -1.0) {
            return Err(BadValue::new(
                "dense.cloud_free_space",
                format!("must be a number above -1, got {}", self.cloud.free_space),
            ));
        }
        self.validate_non_negative()?;
        checks::unit_interval(
            "dense.mask_segment_edge_share",
            self.masks.segment_edge_share,
        )?;
        checks::unit_interval("dense.mask_foreground_share", self.masks.foreground_share)?;
        if self.tsdf.truncation < self.tsdf.voxel {
            return Err(BadValue::new(
                "dense.truncation",
                format!(
                    "({}) must be at least one voxel ({})",
                    self.tsdf.truncation, self.tsdf.voxel
                ),
            ));
        }
        if self.tsdf.voxel < 0.002 {
            return Err(BadValue::new(
                "dense.voxel",
                format!(
                    "{} m is below 2 mm: no depth sensor resolves that",
                    self.tsdf.voxel
                ),
            ));
        }
        crate::detect::tiles::check_grid("dense.detect_tiles", self.detections.tiles)?;
        checks::at_least_one("dense.frame_step", self.frames.step as u64)?;
        checks::at_least_one("dense.frame_max_gap", self.frames.max_gap as u64)?;
        checks::at_least_one(
            "dense.mask_free_space_stride",
            self.masks.free_space_stride as u64,
        )?;
        checks::at_least_one("dense.cloud_stride", self.cloud.stride as u64)
    }

    /// The keys that may be 0 but not negative.
    fn validate_non_negative(&self) -> Result<(), BadValue> {
        checks::each(
            "dense",
            checks::non_negative,
            &[
                (
                    "mask_segment_follow_seconds",
                    self.masks.segment_follow_seconds,
                ),
                (
                    "mask_segment_radius_metres",
                    self.masks.segment_radius_metres.into(),
                ),
                ("mask_free_space_seconds", self.masks.free_space_seconds),
                (
                    "mask_free_space_no_return",
                    self.masks.free_space_no_return.into(),
                ),
                (
                    "mask_free_space_tolerance_growth",
                    self.masks.free_space_tolerance_growth.into(),
                ),
                (
                    "mask_free_space_far_seconds",
                    self.masks.free_space_far_seconds,
                ),
                ("mesh_min_piece_area", self.outputs.mesh_min_piece_area),
                ("frame_min_translation", self.frames.min_translation),
                ("frame_min_rotation", self.frames.min_rotation),
                ("mask_map_min_weight", self.masks.map_min_weight.into()),
                ("mask_map_band", self.masks.map_band.into()),
                ("tsdf_memory_mb", self.tsdf.memory_mb),
                ("cloud_memory_mb", self.cloud.memory_mb),
                ("mask_depth_behind", self.masks.depth_behind.into()),
                (
                    "mask_depth_behind_not_still",
                    self.masks.depth_behind_not_still.into(),
                ),
                (
                    "mask_track_margin_speed",
                    self.masks.track_margin_speed.into(),
                ),
            ],
        )
    }

    /// The detector of the dense pass's own detections: the run's `tracking` one, with
    /// [`Self::detect_model`] and [`Self::detect_tiles`] when it is ONNX (an oracle or
    /// a cache stays what it is), on every core: nothing else runs while it detects
    /// (the tracking pass's detector shares the cores with tracking, `[detector]
    /// threads`).
    pub fn detector(&self, tracking: &DetectorConfig) -> DetectorConfig {
        let mut detector = tracking.clone();
        if !matches!(tracking.source, Source::Onnx | Source::Auto) {
            return detector;
        }
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        detector.threads = detector.threads.max(cores);
        if let Some(model) = self.detections.model.model() {
            detector.models = Models::One { model, path: None };
        }
        detector.tiles = self.detections.tiles;
        detector
    }

    /// The masks' settings.
    pub fn mask_settings(&self) -> MaskSettings {
        MaskSettings {
            border: self.masks.border,
            keypoint_radius: self.masks.keypoint_radius,
            foreground_share: self.masks.foreground_share,
            depth_behind: self.masks.depth_behind,
            depth_behind_not_still: self.masks.depth_behind_not_still,
            track_margin_speed: self.masks.track_margin_speed,
            skip_behind_objects: !self.masks.discs_behind_objects,
            disc_neighbours: self.masks.disc_neighbours,
            keypoints_seen_moving: self.masks.keypoints_seen_moving,
            segments: self.masks.segments.then(|| {
                let settings = SegmentSettings {
                    radius: self.masks.segment_radius,
                    radius_metres: self.masks.segment_radius_metres,
                    edge_share: self.masks.segment_edge_share,
                    support: self.masks.segment_support,
                    ..SegmentSettings::default()
                };
                (settings, self.masks.segment_follow_seconds)
            }),
        }
    }

    /// The TSDF volume's settings.
    pub fn tsdf(&self) -> TsdfSettings {
        TsdfSettings {
            voxel: self.tsdf.voxel,
            truncation: self.tsdf.truncation,
            max_depth: self.tsdf.max_depth,
            max_weight: self.tsdf.max_weight,
            carve: self.tsdf.carve,
            far_carves: self.tsdf.far_carves,
            margin: self.tsdf.image_margin,
        }
    }

    /// The free-space evidence's settings.
    pub fn free_space_settings(&self) -> FreeSpaceSettings {
        FreeSpaceSettings {
            seconds: self.masks.free_space_seconds,
            far_seconds: self.masks.free_space_far_seconds,
            stride: self.masks.free_space_stride,
            no_return: self.masks.free_space_no_return,
            tolerance_growth: self.masks.free_space_tolerance_growth,
            ..FreeSpaceSettings::default()
        }
    }

    /// Whether the TSDF (and its mesh) is fused.
    pub fn fuses_tsdf(&self) -> bool {
        self.outputs.mesh && self.fusion != Fusion::Points
    }

    /// Whether the cloud is written, and whether it loses what the TSDF saw through.
    pub(super) fn cloud_carved(&self) -> bool {
        self.fusion == Fusion::Tsdf && self.cloud.free_space < 1.0
    }

    /// The point cloud's settings.
    pub fn cloud_settings(&self) -> CloudSettings {
        CloudSettings {
            voxel: self.cloud.voxel,
            stride: self.cloud.stride,
            max_depth: self.tsdf.max_depth,
            outlier_neighbours: self.cloud.outlier_neighbours,
            outlier_std: self.cloud.outlier_std,
            normal_neighbours: self.cloud.normal_neighbours,
            margin: self.tsdf.image_margin,
        }
    }
}
