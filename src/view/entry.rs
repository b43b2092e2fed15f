//! The typed entries of a run's recording: what is logged, when, and where it goes.

use std::path::PathBuf;

use nalgebra::Vector3;

use crate::detect::Detection;
use crate::geometry::se3::Se3;

/// When an entry holds: a frame of the sequence (index and timestamp, seconds), or
/// always (static: calibration, the final trajectory, the dense map).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum At {
    Frame { index: usize, seconds: f64 },
    Always,
}

/// The level of an event.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Level {
    Info,
    Warning,
}

/// One thing to log, in the run's own types.
#[derive(Debug, Clone)]
pub enum Entry {
    /// The camera's pinhole (the full-size image's intrinsics, pixels).
    Pinhole {
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        width: u32,
        height: u32,
    },
    /// The camera's pose.
    Camera { world_from_camera: Se3 },
    /// The frame's colour (or grey) image, full size: scaled and JPEG-compressed on
    /// the logging thread.
    Image(image::RgbImage),
    /// The frame's depth in metres (0: none), full size.
    Depth {
        metres: Vec<f32>,
        width: u32,
        height: u32,
    },
    /// Keypoints (full-size pixels) with their moving probability, and the ones
    /// removed before pose estimation.
    Keypoints {
        kept: Vec<([f32; 2], f32)>,
        removed: Vec<[f32; 2]>,
    },
    /// The detector's boxes, each with the frame of the keyframe it was found on,
    /// logged when they arrived.
    Boxes(Vec<(usize, Detection)>),
    /// The local map: static points and points flagged moving.
    MapPoints {
        fixed: Vec<Vector3<f64>>,
        moving: Vec<Vector3<f64>>,
    },
    /// Camera centres of the keyframes so far.
    Keyframes(Vec<Vector3<f64>>),
    /// A trajectory (camera centres) under `name` (`tracking`, `final`, `truth`).
    Trajectory {
        name: &'static str,
        centres: Vec<Vector3<f64>>,
    },
    /// Something that happened in tracking (keyframe, lost, relocalised), or to loops
    /// (`about_loops`: candidates and closures, logged under `events/loops`, so that
    /// they do not hide the tracking events of their keyframe's frame).
    Event {
        level: Level,
        text: String,
        about_loops: bool,
    },
    /// The closed loops' edges, each between two camera centres.
    LoopEdges(Vec<(Vector3<f64>, Vector3<f64>)>),
    /// A dense mesh: vertices, triangles, optional colours.
    Mesh {
        vertices: Vec<[f32; 3]>,
        triangles: Vec<[u32; 3]>,
        colours: Vec<[u8; 3]>,
    },
    /// A dense point cloud with optional colours.
    Cloud {
        points: Vec<[f32; 3]>,
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
/// of `--compare-no-dop`), at a time.
#[derive(Debug, Clone)]
pub struct Message {
    pub prefix: &'static str,
    pub at: At,
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

/// Camera centres of poses.
pub fn centres<'a>(poses: impl IntoIterator<Item = &'a Se3>) -> Vec<Vector3<f64>> {
    poses.into_iter().map(|p| p.translation.vector).collect()
}
