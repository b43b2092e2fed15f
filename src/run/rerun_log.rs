//! The tracking pass seen by the run's Rerun recording ([`crate::view`]): each frame's
//! pose, image, keypoints by DOP state and events, the local map at keyframes, and the
//! detector's boxes when they arrive. It only sends typed entries: the logging thread
//! does the rest.

use nalgebra::Vector3;

use super::observers::{FrameObserver, FrameView};
use crate::dynamics::Applied;
use crate::io::IoError;
use crate::view::results::{events_entry, frame_events, FrameFacts, PathPieces, TRAJECTORY_EVERY};
use crate::view::{At, Entry, LogHandle};

/// Logs the tracking pass (see the module doc).
pub struct RerunLog {
    log: LogHandle,
    /// The last frame's time: detections arriving are logged there.
    at: At,
    previous: Option<&'static str>,
    path: PathPieces,
    keyframes: Vec<Vector3<f64>>,
}

impl RerunLog {
    /// A recorder logging into `log`.
    pub fn new(log: LogHandle) -> Self {
        Self {
            log,
            at: At::Always,
            previous: None,
            path: PathPieces::default(),
            keyframes: Vec::new(),
        }
    }

    fn log(&self, entry: Entry) {
        self.log.log("", self.at, entry);
    }

    /// Keypoints kept (with their moving probability) and removed.
    fn log_keypoints(&self, view: &FrameView) {
        let Some(frame) = view.frame else {
            return;
        };
        let (mut kept, mut removed) = (Vec::new(), Vec::new());
        for (k, &p) in frame.keypoints.iter().zip(&frame.moving) {
            if view.dop.is_some_and(|d| d.removed(p)) {
                removed.push([k.x, k.y]);
            } else {
                kept.push(([k.x, k.y], p));
            }
        }
        self.log(Entry::Keypoints { kept, removed });
    }
}

impl FrameObserver for RerunLog {
    fn on_frame(&mut self, view: &FrameView) -> Result<(), IoError> {
        let (report, record) = (view.stats, view.record);
        self.at = At::Frame {
            index: view.index,
            seconds: view.timestamp,
        };
        if let Some(camera_from_world) = record.camera_from_world {
            let world_from_camera = camera_from_world.inverse();
            self.log(Entry::Camera { world_from_camera });
            if let Some(full) = self.path.push(world_from_camera.translation.vector) {
                self.log(full);
            }
            if report.keyframe {
                self.keyframes.push(world_from_camera.translation.vector);
                self.log(Entry::Keyframes(self.keyframes.clone()));
            }
        }
        if view.index.is_multiple_of(TRAJECTORY_EVERY) {
            self.log(self.path.entry());
        }
        let state = report.state.as_str();
        let facts = FrameFacts {
            index: view.index,
            state,
            keyframe: report.keyframe,
            lost: report.lost.and_then(|r| {
                serde_json::to_value(r)
                    .ok()?
                    .get("reason")?
                    .as_str()
                    .map(String::from)
            }),
        };
        if let Some(entry) = events_entry(view.index, frame_events(self.previous, &facts)) {
            self.log(entry);
        }
        self.previous = Some(state);
        self.log_keypoints(view);
        if let Some(picture) = view.picture {
            self.log(Entry::Image(picture.clone().into_colour()));
        }
        if let Some(depth) = view.depth {
            self.log(Entry::Depth {
                metres: depth.metres.clone(),
                width: depth.width,
                height: depth.height,
            });
        }
        if let Some(map) = view.recent_map {
            self.log(Entry::MapPoints {
                fixed: map.fixed.clone(),
                moving: map.moving.clone(),
            });
        }
        Ok(())
    }

    /// The boxes of the detections that arrived, at the current frame: several
    /// keyframes' detections arriving together are one entry (each label names its
    /// keyframe).
    fn on_applied(&mut self, applied: &[Applied]) {
        let mut arrived = Vec::new();
        let mut any = false;
        for done in applied {
            if let Applied::Detected { frame, detections } = done {
                any = true;
                arrived.extend(detections.iter().map(|d| (*frame, d.clone())));
            }
        }
        if any {
            self.log(Entry::Boxes(arrived));
        }
    }

    fn finish(&mut self) {
        self.log(self.path.entry());
    }
}
