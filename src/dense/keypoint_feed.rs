//! The frames' dynamic keypoints as the masks take them, in time order: read from
//! `dynamic_keypoints.json` one frame at a time as the dense pass comes to it
//! ([`KeypointFeed::from_file`]), so that the pass holds one frame's keypoints
//! whatever the length of the run; or held (a test's, or a file out of time order).

use std::path::Path;

use crate::io::json_array::JsonArrayItems;
use crate::io::IoError;

/// Dynamic keypoints of one frame: `(x, y, depth)` (one entry of
/// `dynamic_keypoints.json`).
#[derive(Debug, Clone, Default, serde::Serialize, serde::Deserialize)]
pub struct FrameKeypoints {
    /// The frame's time.
    pub timestamp: f64,
    /// Its dynamic keypoints `(x, y, depth)`.
    pub points: Vec<[f32; 3]>,
}

/// Two timestamps closer than this are the same frame's (seconds).
const SAME_FRAME: f64 = 1e-6;

/// The frames' dynamic keypoints, taken in time order ([`KeypointFeed::advance_to`]).
pub struct KeypointFeed {
    rest: Box<dyn Iterator<Item = FrameKeypoints> + Send>,
    current: Option<FrameKeypoints>,
}

impl Default for KeypointFeed {
    fn default() -> Self {
        Self::from(Vec::new())
    }
}

impl From<Vec<FrameKeypoints>> for KeypointFeed {
    /// Held keypoints, sorted by time here.
    fn from(mut keypoints: Vec<FrameKeypoints>) -> Self {
        keypoints.sort_by(|a, b| a.timestamp.total_cmp(&b.timestamp));
        Self {
            rest: Box::new(keypoints.into_iter()),
            current: None,
        }
    }
}

impl KeypointFeed {
    /// The keypoints of `dynamic_keypoints.json` at `path` (none when it is missing: a
    /// run without the DOP model). The file is read through once here, so that an
    /// entry that does not parse is an error before any frame is fused; then again
    /// as the frames come. A file whose frames are out of time order is held, sorted.
    pub fn from_file(path: &Path) -> Result<Self, IoError> {
        if !path.exists() {
            return Ok(Self::default());
        }
        let mut previous = f64::NEG_INFINITY;
        let mut in_order = true;
        for frame in JsonArrayItems::<FrameKeypoints>::open(path)? {
            let t = frame?.timestamp;
            in_order &= t >= previous;
            previous = t;
        }
        if !in_order {
            let held = JsonArrayItems::open(path)?.collect::<Result<Vec<_>, _>>()?;
            return Ok(Self::from(held));
        }
        // Read whole once already: the file is this run's, and changes under a dense
        // pass only if something else writes into the run folder.
        let items = JsonArrayItems::<FrameKeypoints>::open(path)?.map_while(Result::ok);
        Ok(Self {
            rest: Box::new(items),
            current: None,
        })
    }

    /// Moves on to the frame at `timestamp`: the frames before it are let go.
    pub fn advance_to(&mut self, timestamp: f64) {
        while self
            .current
            .as_ref()
            .is_none_or(|k| k.timestamp < timestamp - SAME_FRAME)
        {
            match self.rest.next() {
                Some(next) => self.current = Some(next),
                None => {
                    // Only frames before `timestamp` were left.
                    self.current = None;
                    return;
                }
            }
        }
    }

    /// The dynamic keypoints of the frame at `timestamp` (none if it has no entry),
    /// after [`Self::advance_to`] it.
    pub fn at(&self, timestamp: f64) -> &[[f32; 3]] {
        self.current
            .as_ref()
            .filter(|k| (k.timestamp - timestamp).abs() < SAME_FRAME)
            .map_or(&[], |k| &k.points)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(t: f64, n: usize) -> FrameKeypoints {
        FrameKeypoints {
            timestamp: t,
            points: (0..n).map(|i| [i as f32, t as f32, 1.5]).collect(),
        }
    }

    #[test]
    fn the_feed_gives_each_frame_its_keypoints_from_the_file_as_the_frames_come() {
        let dir = std::env::temp_dir().join(format!("dopslam-feed-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let frames: Vec<FrameKeypoints> = (0..40).map(|i| frame(i as f64 * 0.1, i % 5)).collect();
        let path = dir.join("dynamic_keypoints.json");
        std::fs::write(&path, serde_json::to_string(&frames).unwrap()).unwrap();
        let mut shuffled = frames.clone();
        shuffled.swap(3, 30);
        let unsorted = dir.join("unsorted.json");
        std::fs::write(&unsorted, serde_json::to_string(&shuffled).unwrap()).unwrap();
        for mut feed in [
            KeypointFeed::from_file(&path).unwrap(),
            KeypointFeed::from_file(&unsorted).unwrap(),
            KeypointFeed::from(shuffled.clone()),
        ] {
            // Every third frame, and times between frames, which have none.
            for i in (0..40).step_by(3) {
                let t = i as f64 * 0.1;
                feed.advance_to(t - 0.05);
                assert!(feed.at(t - 0.05).is_empty());
                feed.advance_to(t);
                assert_eq!(feed.at(t), &frames[i].points[..], "frame {i}");
            }
            feed.advance_to(100.0);
            assert!(feed.at(100.0).is_empty());
        }
        assert!(KeypointFeed::from_file(&dir.join("missing.json")).is_ok());
        std::fs::write(&path, r#"[{"timestamp": 1.0, "points": [[1, 2]]}]"#).unwrap();
        let bad = KeypointFeed::from_file(&path).err().unwrap().to_string();
        assert!(
            bad.contains("dynamic_keypoints.json") && bad.contains("malformed"),
            "{bad}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
