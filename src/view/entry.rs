//! The typed entries of a run's recording: what is logged, when, and where it goes.

use std::borrow::Cow;
use std::path::PathBuf;

use nalgebra::Vector3;

use crate::detect::Detection;
use crate::geometry::se3::Se3;

/// When an entry holds: a frame of the sequence (index and timestamp, seconds), or
/// always (static: calibration, the final trajectory, the dense map).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum At {
    /// Frame `index`, at `seconds` (the sequence's clock).
    Frame {
        /// The frame's index.
        index: usize,
        /// Its time.
        seconds: f64,
    },
    /// Static.
    Always,
}

/// The level of an event.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Level {
    /// A fact.
    Info,
    /// A problem.
    Warning,
}

/// One thing to log, in the run's own types.
#[derive(Debug, Clone)]
pub enum Entry {
    /// The camera's pinhole (the full-size image's intrinsics, pixels).
    Pinhole {
        /// Focal length x, pixels.
        fx: f64,
        /// Focal length y, pixels.
        fy: f64,
        /// Principal point x.
        cx: f64,
        /// Principal point y.
        cy: f64,
        /// Image width.
        width: u32,
        /// Image height.
        height: u32,
    },
    /// The camera's pose.
    Camera {
        /// \(T_{wc}\).
        world_from_camera: Se3,
    },
    /// The frame's colour (or grey) image, full size: scaled and JPEG-compressed on
    /// the logging thread.
    Image(image::RgbImage),
    /// The frame's depth in metres (0: none), full size.
    Depth {
        /// Depth per pixel, metres (0: none).
        metres: Vec<f32>,
        /// Width.
        width: u32,
        /// Height.
        height: u32,
    },
    /// Keypoints (full-size pixels) with their moving probability, and the ones
    /// removed before pose estimation.
    Keypoints {
        /// Kept keypoints with their moving probability.
        kept: Vec<([f32; 2], f32)>,
        /// Removed keypoints.
        removed: Vec<[f32; 2]>,
    },
    /// The detector's boxes, each with the frame of the keyframe it was found on,
    /// logged when they arrived.
    Boxes(Vec<(usize, Detection)>),
    /// The local map: static points and points flagged moving.
    MapPoints {
        /// Static points.
        fixed: Vec<Vector3<f64>>,
        /// Moving points.
        moving: Vec<Vector3<f64>>,
    },
    /// Camera centres of the keyframes so far.
    Keyframes(Vec<Vector3<f64>>),
    /// A trajectory (camera centres) under `name` (`tracking`, `final`, `truth`).
    Trajectory {
        /// `tracking` or `final`.
        name: &'static str,
        /// The piece of a path drawn in pieces (`world/trajectory/<name>/<piece>`;
        /// [`super::results::PathPieces`]), `None` for a path drawn whole.
        piece: Option<usize>,
        /// The camera centres.
        centres: Vec<Vector3<f64>>,
    },
    /// Something that happened in tracking (keyframe, lost, relocalised), or to loops
    /// (`about_loops`: candidates and closures, logged under `events/loops`, so that
    /// they do not hide the tracking events of their keyframe's frame).
    Event {
        /// Info or warning.
        level: Level,
        /// The sentence.
        text: String,
        /// Whether it is about loops (shown with them).
        about_loops: bool,
    },
    /// The closed loops' edges, each between two camera centres.
    LoopEdges(Vec<(Vector3<f64>, Vector3<f64>)>),
    /// A dense mesh: vertices, triangles, optional colours.
    Mesh {
        /// Positions, metres.
        vertices: Vec<[f32; 3]>,
        /// Vertex indices.
        triangles: Vec<[u32; 3]>,
        /// Per-vertex colours.
        colours: Vec<[u8; 3]>,
    },
    /// A dense point cloud with optional colours.
    Cloud {
        /// Positions, metres.
        points: Vec<[f32; 3]>,
        /// Per-point colours.
        colours: Vec<[u8; 3]>,
    },
}

impl Entry {
    /// Images go first when the logging thread falls behind.
    pub fn droppable(&self) -> bool {
        matches!(self, Entry::Image(_) | Entry::Depth { .. })
    }
}

/// One entry under an entity path prefix (`""` for the run, `no_dop` for the baseline
/// of `--compare-no-dop`, `recordings/<k>_<sequence>` for a merged map's recordings),
/// at a time.
#[derive(Debug, Clone)]
pub struct Message {
    /// The entity path prefix.
    pub prefix: Cow<'static, str>,
    /// When.
    pub at: At,
    /// What.
    pub entry: Entry,
}

/// Where the recording goes.
#[derive(Debug, Clone, PartialEq)]
pub enum Target {
    /// An `.rrd` file (made new: an existing file is not overwritten).
    File(PathBuf),
    /// A running viewer's address (`rerun+http://HOST:PORT/proxy`, or `HOST:PORT`).
    Connect(String),
}

/// How long a streamed recording waits for a viewer that takes nothing before it gives
/// up on it: without progress, for room in the queue and for the last entries; and for
/// the SDK's flush at the end.
pub const VIEWER_PATIENCE: std::time::Duration = std::time::Duration::from_secs(5);

impl Target {
    /// The file's path or the viewer's address, as a user names it.
    pub fn name(&self) -> String {
        match self {
            Self::File(path) => path.display().to_string(),
            Self::Connect(address) => address.clone(),
        }
    }
}

/// Camera centres of poses.
pub fn centres<'a>(poses: impl IntoIterator<Item = &'a Se3>) -> Vec<Vector3<f64>> {
    poses.into_iter().map(|p| p.translation.vector).collect()
}
