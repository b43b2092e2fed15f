//! Object detections: the one JSON format shared by the detector cache, the oracle
//! detections that `synth` writes, and detections brought from other detectors.
//!
//! A file per frame holds `{"timestamp": t, "detections": [{"class": "person",
//! "class_id": 0, "score": 0.97, "box": [x1, y1, x2, y2], "instance": 3}]}` with boxes in
//! image pixels (x2, y2 exclusive) and `instance` present only for oracle detections.

pub mod coco;

use serde::{Deserialize, Serialize};

/// One detected object.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Detection {
    /// COCO class name.
    pub class: String,
    /// COCO class index (0 = person).
    pub class_id: u32,
    pub score: f32,
    /// `[x1, y1, x2, y2]` in image pixels.
    #[serde(rename = "box")]
    pub bbox: [f32; 4],
    /// The ground-truth instance id (oracle detections only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub instance: Option<u16>,
}

/// The detections of one frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameDetections {
    pub timestamp: f64,
    pub detections: Vec<Detection>,
}
