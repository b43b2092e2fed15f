//! The detected frames' boxes as the masks reach them: the run's keyframe detections
//! (`detections/`) and the dense pass's own (`detections_dense/`), one file a frame,
//! read through once to check them and to index them by time, then read again one
//! frame at a time, in time order ([`DetectionFeed::take_next`]). A frame in both folders
//! is one frame: the keyframe's boxes, joined by the dense pass's that overlap none of
//! its boxes of their class. So the dense pass holds an index entry of 24 bytes a
//! detected frame, not its boxes.

use std::collections::{HashSet, VecDeque};
use std::path::{Path, PathBuf};

use super::frame_table::key;
use crate::detect::{cache_file, read_cache_file, Detection, FrameDetections};
use crate::io::IoError;

/// A detected frame in the index: its time, the folder its file lies in, and its
/// detections themselves when they are given whole or its file's name is not the one
/// the cache gives its time.
#[derive(Debug)]
struct Entry {
    timestamp: f64,
    folder: usize,
    held: Option<Box<FrameDetections>>,
}

/// The detected frames, in time order (see the module doc).
#[derive(Debug, Default)]
pub struct DetectionFeed {
    folders: Vec<PathBuf>,
    index: VecDeque<Entry>,
}

/// Frames given whole, held (for tests: the dense pass reads its cache folders).
#[cfg(test)]
impl From<Vec<FrameDetections>> for DetectionFeed {
    fn from(frames: Vec<FrameDetections>) -> Self {
        let mut feed = Self::default();
        feed.index.extend(frames.into_iter().map(|frame| Entry {
            timestamp: frame.timestamp,
            folder: usize::MAX,
            held: Some(Box::new(frame)),
        }));
        feed.sort();
        feed
    }
}

impl DetectionFeed {
    /// Adds the frames of the cache folder `dir` (none when it does not exist), each
    /// file read to check it: a malformed one is an error naming it. Frames already
    /// taken by [`DetectionFeed::take_next`] are not taken again.
    pub fn add_folder(&mut self, dir: &Path) -> Result<(), IoError> {
        let Ok(entries) = std::fs::read_dir(dir) else {
            return Ok(());
        };
        let folder = self.folders.len();
        self.folders.push(dir.to_path_buf());
        for entry in entries.flatten() {
            let path = entry.path();
            if path.extension().is_none_or(|e| e != "json") {
                continue;
            }
            let frame =
                read_cache_file(&path).map_err(|e| IoError::invalid(&path, e.to_string()))?;
            let named = path == cache_file(dir, frame.timestamp);
            self.index.push_back(Entry {
                timestamp: frame.timestamp,
                folder,
                held: (!named).then(|| Box::new(frame)),
            });
        }
        self.sort();
        Ok(())
    }

    /// The index in time order; a time's frames in the order their folders came.
    fn sort(&mut self) {
        self.index.make_contiguous().sort_by(|a, b| {
            a.timestamp
                .total_cmp(&b.timestamp)
                .then(a.folder.cmp(&b.folder))
        });
    }

    /// The times of the frames not taken yet, as keys ([`key`]).
    pub fn keys(&self) -> HashSet<i64> {
        self.index.iter().map(|e| key(e.timestamp)).collect()
    }

    /// The frames not taken yet.
    pub fn len(&self) -> usize {
        self.index.len()
    }

    /// Whether every frame was taken.
    pub fn is_empty(&self) -> bool {
        self.index.is_empty()
    }

    /// The next frame in time: the first file of its time, joined by the others of
    /// that time ([`join`]).
    pub fn take_next(&mut self) -> Result<Option<FrameDetections>, IoError> {
        let Some(first) = self.index.pop_front() else {
            return Ok(None);
        };
        let mut frame = self.load(first)?;
        let k = key(frame.timestamp);
        while let Some(entry) = self.index.pop_front() {
            if key(entry.timestamp) != k {
                self.index.push_front(entry);
                break;
            }
            let more = self.load(entry)?;
            join(&mut frame.detections, more.detections);
        }
        Ok(Some(frame))
    }

    fn load(&self, entry: Entry) -> Result<FrameDetections, IoError> {
        if let Some(frame) = entry.held {
            return Ok(*frame);
        }
        let path = cache_file(&self.folders[entry.folder], entry.timestamp);
        read_cache_file(&path).map_err(|e| IoError::invalid(&path, e.to_string()))
    }
}

/// Adds to a frame's `known` boxes those of `more` that overlap none of them of their
/// class (intersection over union at most 0.45).
pub fn join(known: &mut Vec<Detection>, more: Vec<Detection>) {
    for d in more {
        let duplicate = known
            .iter()
            .any(|k| k.class_id == d.class_id && crate::detect::yolo::iou(&k.bbox, &d.bbox) > 0.45);
        if !duplicate {
            known.push(d);
        }
    }
}

/// A frame with a person in each of `boxes` (for tests).
#[cfg(test)]
pub(super) fn frame(timestamp: f64, boxes: &[[f32; 4]]) -> FrameDetections {
    FrameDetections {
        timestamp,
        detections: boxes
            .iter()
            .map(|&bbox| Detection {
                class: "person".into(),
                class_id: 0,
                score: 0.5,
                bbox,
                instance: None,
            })
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every frame left in `feed`, taken.
    fn taken(feed: &mut DetectionFeed) -> Vec<FrameDetections> {
        std::iter::from_fn(|| feed.take_next().unwrap()).collect()
    }

    #[test]
    fn a_keyframe_keeps_its_boxes_and_gains_only_new_ones_in_time_order() {
        let dir = std::env::temp_dir().join(format!("dopslam-feed-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let (keyframes, dense) = (dir.join("detections"), dir.join("detections_dense"));
        let write = |folder: &Path, frame: &FrameDetections| {
            crate::detect::write_cache(folder, frame).unwrap();
        };
        write(&keyframes, &frame(3.0, &[[5.0, 5.0, 9.0, 9.0]]));
        write(&keyframes, &frame(1.0, &[[0.0, 0.0, 10.0, 20.0]]));
        write(
            &dense,
            &frame(1.0, &[[0.5, 0.0, 10.0, 20.0], [100.0, 100.0, 110.0, 120.0]]),
        );
        write(&dense, &frame(2.0, &[[0.0, 0.0, 10.0, 20.0]]));
        // A file named otherwise is read at once and held.
        std::fs::write(
            dense.join("other.json"),
            serde_json::to_string(&frame(2.5, &[])).unwrap(),
        )
        .unwrap();
        std::fs::write(dense.join("detector.txt"), "model\n").unwrap();
        let mut feed = DetectionFeed::default();
        feed.add_folder(&keyframes).unwrap();
        feed.add_folder(&dense).unwrap();
        feed.add_folder(&dir.join("absent")).unwrap();
        assert_eq!(feed.len(), 5);
        let frames = taken(&mut feed);
        let times: Vec<f64> = frames.iter().map(|f| f.timestamp).collect();
        assert_eq!(times, [1.0, 2.0, 2.5, 3.0]);
        // The keyframe's box first, the dense pass's overlapping one left out.
        let boxes: Vec<[f32; 4]> = frames[0].detections.iter().map(|d| d.bbox).collect();
        assert_eq!(
            boxes,
            [[0.0, 0.0, 10.0, 20.0], [100.0, 100.0, 110.0, 120.0]]
        );
        assert!(feed.is_empty() && feed.take_next().unwrap().is_none());
        // A malformed file is named.
        std::fs::write(keyframes.join("4.000000.json"), "{").unwrap();
        let error = DetectionFeed::default().add_folder(&keyframes).unwrap_err();
        assert!(error.to_string().contains("4.000000.json"), "{error}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn frames_given_whole_come_in_time_order() {
        let mut feed = DetectionFeed::from(vec![frame(2.0, &[]), frame(1.0, &[])]);
        let times: Vec<f64> = taken(&mut feed).iter().map(|f| f.timestamp).collect();
        assert_eq!(times, [1.0, 2.0]);
    }
}
