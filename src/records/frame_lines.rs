//! `report.json`'s `frames`: one [`FrameLine`] per frame. A run writes them to a spill
//! file in its folder as the frames come ([`FrameLines::spilling_into`]), so that no
//! pass holds a line per frame, and `report.json` is written from that file as a
//! stream. A report read back from disk holds its lines in memory.

use std::io::BufReader;
use std::path::Path;

use serde::{Deserialize, Deserializer, Serialize, Serializer};

use super::report::FrameLine;
use crate::io::spill::SpillFile;
use crate::io::IoError;

/// The lines of a run's frames, in frame order: held, or in a spill file (one JSON
/// value each, written as the frames come; the file goes with them).
#[derive(Debug, Default)]
pub struct FrameLines {
    held: Vec<FrameLine>,
    spill: Option<SpillFile>,
    len: usize,
}

impl FrameLines {
    /// Lines written to a new spill file in `dir` (a run's folder) as they come.
    pub fn spilling_into(dir: &Path) -> Result<Self, IoError> {
        Ok(Self {
            held: Vec::new(),
            spill: Some(SpillFile::create(dir, "lines", 1)?),
            len: 0,
        })
    }

    /// Adds the next frame's line.
    pub fn push(&mut self, line: FrameLine) -> Result<(), IoError> {
        match self.spill.as_mut() {
            None => self.held.push(line),
            Some(spill) => {
                let mut bytes = serde_json::to_vec(&line).expect("a frame line serialises");
                bytes.push(b'\n');
                spill.append(&bytes)?;
            }
        }
        // Counted once written: after a failed write the lines stay whole.
        self.len += 1;
        Ok(())
    }

    /// How many lines there are.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether there is none.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The lines in order, read from the spill file as they are taken.
    pub fn iter(&self) -> Box<dyn Iterator<Item = Result<FrameLine, IoError>> + '_> {
        let Some(spill) = self.spill.as_ref() else {
            return Box::new(self.held.iter().cloned().map(Ok));
        };
        let reader = BufReader::with_capacity(1 << 16, spill.reader());
        let lines = serde_json::Deserializer::from_reader(reader).into_iter::<FrameLine>();
        Box::new(lines.map(|line| line.map_err(|e| IoError::invalid(spill.path(), e.to_string()))))
    }

    /// All lines in memory (a short run's, or a test's).
    pub fn to_vec(&self) -> Result<Vec<FrameLine>, IoError> {
        self.iter().collect()
    }

    /// `visit` on every line in order.
    pub fn try_for_each(&self, mut visit: impl FnMut(&FrameLine)) -> Result<(), IoError> {
        self.iter().try_for_each(|line| line.map(|l| visit(&l)))
    }

    /// The bytes held in memory (the lines in a spill file not counted).
    pub fn heap_bytes(&self) -> usize {
        self.held.capacity() * std::mem::size_of::<FrameLine>()
    }
}

impl From<Vec<FrameLine>> for FrameLines {
    fn from(held: Vec<FrameLine>) -> Self {
        Self {
            len: held.len(),
            held,
            spill: None,
        }
    }
}

impl Serialize for FrameLines {
    /// A JSON array, each line read from the spill file as it is written out.
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        use serde::ser::{Error, SerializeSeq};
        let mut seq = serializer.serialize_seq(Some(self.len))?;
        for line in self.iter() {
            seq.serialize_element(&line.map_err(S::Error::custom)?)?;
        }
        seq.end()
    }
}

impl<'de> Deserialize<'de> for FrameLines {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        Vec::<FrameLine>::deserialize(deserializer).map(Self::from)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(index: usize) -> FrameLine {
        let text = format!(
            r#"{{"index": {index}, "timestamp": {}, "state": "ok", "segment": 0,
            "keypoints": {}, "matches": 400, "inliers": 399, "keyframe": false,
            "dynamic_keypoints": 1, "dynamic_map_points": 0, "geometric_raised": 0,
            "geometric_lowered": 0, "rigidity_outliers": 0, "matching_ms": {},
            "optimisation_ms": 0.5, "dop_ms": 0.25, "extraction_ms": {},
            "tracking_ms": {}}}"#,
            index as f64 * 0.1 + 1e-9,
            1000 + index,
            0.1 * index as f64 + 0.123456789,
            3.0 + index as f64 / 7.0,
            9.0 / (index + 1) as f64,
        );
        serde_json::from_str(&text).unwrap()
    }

    #[test]
    fn spilled_lines_write_the_same_report_as_held_ones_and_hold_nothing() {
        let dir = std::env::temp_dir().join(format!("dopslam-lines-{}", std::process::id()));
        let mut spilled = FrameLines::spilling_into(&dir).unwrap();
        let mut held = FrameLines::default();
        for i in 0..300 {
            spilled.push(line(i)).unwrap();
            held.push(line(i)).unwrap();
        }
        assert_eq!(spilled.heap_bytes(), 0);
        assert!(held.heap_bytes() >= 300 * std::mem::size_of::<FrameLine>());
        let text = |lines: &FrameLines| serde_json::to_string_pretty(lines).unwrap();
        assert_eq!(text(&spilled), text(&held));
        let back: FrameLines = serde_json::from_str(&text(&spilled)).unwrap();
        assert_eq!(back.len(), 300);
        assert_eq!(text(&back), text(&held));
        let lines = spilled.to_vec().unwrap();
        assert_eq!(lines[299].tracking.index, 299);
        assert_eq!(lines[17].extraction_ms, line(17).extraction_ms);
        drop(spilled);
        let left = std::fs::read_dir(&dir).unwrap().count();
        std::fs::remove_dir(&dir).unwrap();
        assert_eq!(left, 0, "the spill file goes with the lines");
    }
}
