//! What the map keeps of a tracked frame that is not (only) a keyframe: its pose
//! relative to its reference keyframe and the map points it saw. The tracking pass
//! writes one [`FrameRecord`] per frame into [`FrameRecords`], which keeps their
//! observations on disk (they grow with the frames, not with the map); the global
//! pass corrects them on the final map, and the final trajectory is read from them.

use std::borrow::Cow;
use std::path::Path;

use super::{KeyFrameKey, MapPointKey};
use crate::geometry::se3::Se3;
use crate::io::spill::SpillFile;
use crate::io::IoError;

/// One frame's hand-off from the tracking pass to the global pass.
#[derive(Debug, Clone, Default)]
pub struct FrameRecord {
    /// Seconds (the sequence's clock).
    pub timestamp: f64,
    /// The map segment the frame was tracked in.
    pub segment: usize,
    /// The keyframe made from this frame, if one was (the key it had then).
    pub keyframe: Option<KeyFrameKey>,
    /// The tracked pose, \(T_{cw}\) (none for a lost frame).
    pub camera_from_world: Option<Se3>,
    /// The reference keyframe and the pose relative to it, \(T_{cr}\): the final
    /// trajectory is \(T_{cr} T_{rw}\) with the reference's corrected pose.
    pub reference: Option<(KeyFrameKey, Se3)>,
    /// The keypoints whose map points took part in the final pose as inliers, with
    /// what the global pass needs to estimate the pose again on the final map (and the
    /// keypoint indices, for scoring against ground-truth masks).
    pub observations: Vec<FrameObservation>,
    /// Where [`FrameRecords`] put the observations on disk (then `observations` is
    /// empty).
    pub spilled: Option<Spilled>,
}

/// A record's observations in the spill file: where, and how many.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Spilled {
    /// Byte offset.
    pub at: u64,
    /// Observations.
    pub count: u32,
}

impl FrameRecord {
    /// The record of the frame at `timestamp`, before tracking in `segment`.
    pub fn start(timestamp: f64, segment: usize) -> Self {
        Self {
            timestamp,
            segment,
            ..Self::default()
        }
    }

    /// The bytes it holds (its struct and its observations, by capacity).
    pub fn heap_bytes(&self) -> usize {
        std::mem::size_of::<Self>()
            + self.observations.capacity() * std::mem::size_of::<FrameObservation>()
    }

    /// How many observations it has, held or on disk.
    pub fn observation_count(&self) -> usize {
        self.spilled
            .map_or(self.observations.len(), |s| s.count as usize)
    }

    /// Whether a keyframe was made from this frame.
    pub fn is_keyframe(&self) -> bool {
        self.keyframe.is_some()
    }

    /// The frame's pose placed on its reference keyframe's pose as `keyframe_pose`
    /// gives it now (so frames follow the keyframes' corrections), else the tracked
    /// pose: \(T_{cw} = T_{cr} T_{rw}\).
    pub fn camera_from_world_on(
        &self,
        keyframe_pose: impl Fn(KeyFrameKey) -> Option<Se3>,
    ) -> Option<Se3> {
        self.reference
            .and_then(|(key, camera_from_reference)| {
                Some(camera_from_reference * keyframe_pose(key)?)
            })
            .or(self.camera_from_world)
    }
}

/// One keypoint of a tracked frame and the map point it saw (undistorted level-0
/// pixel, virtual right coordinate, negative without depth).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameObservation {
    /// The map point.
    pub point: MapPointKey,
    /// The keypoint's index in the frame.
    pub keypoint: u32,
    /// Column (undistorted level-0 pixels).
    pub x: f32,
    /// Row.
    pub y: f32,
    /// Virtual right-image column; negative without depth.
    pub right_u: f32,
    /// The keypoint's pyramid level.
    pub level: u8,
}

/// Bytes of one observation on disk: the point's key (`KeyData::as_ffi`), the keypoint
/// index, x, y, right column, level.
const OBSERVATION_BYTES: usize = 8 + 4 + 4 + 4 + 4 + 1;

/// Observations as [`FrameRecords`] writes them to disk.
fn encode(observations: &[FrameObservation]) -> Vec<u8> {
    let mut bytes = Vec::with_capacity(observations.len() * OBSERVATION_BYTES);
    observations.iter().for_each(|o| o.write_to(&mut bytes));
    bytes
}

impl FrameObservation {
    fn write_to(&self, out: &mut Vec<u8>) {
        use slotmap::Key;
        out.extend_from_slice(&self.point.data().as_ffi().to_le_bytes());
        out.extend_from_slice(&self.keypoint.to_le_bytes());
        for value in [self.x, self.y, self.right_u] {
            out.extend_from_slice(&value.to_le_bytes());
        }
        out.push(self.level);
    }

    fn read_from(bytes: &[u8]) -> Self {
        let word = |at: usize| -> [u8; 4] { bytes[at..at + 4].try_into().expect("4 bytes") };
        let key: [u8; 8] = bytes[..8].try_into().expect("8 bytes");
        Self {
            point: slotmap::KeyData::from_ffi(u64::from_le_bytes(key)).into(),
            keypoint: u32::from_le_bytes(word(8)),
            x: f32::from_le_bytes(word(12)),
            y: f32::from_le_bytes(word(16)),
            right_u: f32::from_le_bytes(word(20)),
            level: bytes[24],
        }
    }
}

/// The tracked frames' records in frame order (their observations held in memory when
/// made by `Default`). With a spill file
/// ([`FrameRecords::spilling_into`]) each record's observations go to disk as it is
/// pushed, so memory holds only the poses (about 150 bytes a frame, where the
/// observations take 10-15 kB on the renders); they are read back, and changed in place, through
/// [`FrameRecords::observations`] and [`FrameRecords::change_observations`]. The file
/// is removed with the records.
#[derive(Debug, Default)]
pub struct FrameRecords {
    records: Vec<FrameRecord>,
    file: Option<SpillFile>,
}

impl FrameRecords {
    /// Records whose observations go to a new spill file in `dir` (a run's folder).
    pub fn spilling_into(dir: &Path) -> Result<Self, IoError> {
        Ok(Self {
            records: Vec::new(),
            file: Some(SpillFile::create(dir, "frames", 1)?),
        })
    }

    /// Adds the next frame's record (its observations to disk, with a spill file).
    pub fn push(&mut self, mut record: FrameRecord) -> Result<(), IoError> {
        if let Some(file) = self.file.as_mut() {
            let at = file.append(&encode(&record.observations))?;
            record.spilled = Some(Spilled {
                at,
                count: record.observations.len() as u32,
            });
            record.observations = Vec::new();
        }
        self.records.push(record);
        Ok(())
    }

    /// The observations of `record` (one of these records).
    pub fn observations<'a>(
        &self,
        record: &'a FrameRecord,
    ) -> Result<Cow<'a, [FrameObservation]>, IoError> {
        self.reader().observations(record)
    }

    /// Reads the observations on disk.
    pub fn reader(&self) -> ObservationReader<'_> {
        ObservationReader {
            file: self.file.as_ref(),
        }
    }

    /// `change` applied to every observation of every record, held or on disk.
    pub fn change_observations(
        &mut self,
        mut change: impl FnMut(&mut FrameObservation),
    ) -> Result<(), IoError> {
        for i in 0..self.records.len() {
            let Some(spilled) = self.records[i].spilled else {
                self.records[i]
                    .observations
                    .iter_mut()
                    .for_each(&mut change);
                continue;
            };
            let mut observations = self.observations(&self.records[i])?.into_owned();
            observations.iter_mut().for_each(&mut change);
            if let Some(file) = self.file.as_mut() {
                file.overwrite(spilled.at, &encode(&observations))?;
            }
        }
        Ok(())
    }

    /// The records and the reader of their observations, apart (to change the records
    /// while reading).
    pub fn split_mut(&mut self) -> (&mut [FrameRecord], ObservationReader<'_>) {
        (
            &mut self.records,
            ObservationReader {
                file: self.file.as_ref(),
            },
        )
    }

    /// The bytes the records hold in memory (their observations on disk not counted).
    pub fn heap_bytes(&self) -> usize {
        self.records
            .iter()
            .map(FrameRecord::heap_bytes)
            .sum::<usize>()
            + (self.records.capacity() - self.records.len()) * std::mem::size_of::<FrameRecord>()
    }
}

/// Reads spilled observations while the records are borrowed mutably
/// ([`FrameRecords::split_mut`]).
#[derive(Debug, Clone, Copy)]
pub struct ObservationReader<'a> {
    file: Option<&'a SpillFile>,
}

impl ObservationReader<'_> {
    /// The observations of `record`.
    pub fn observations<'r>(
        &self,
        record: &'r FrameRecord,
    ) -> Result<Cow<'r, [FrameObservation]>, IoError> {
        let (Some(spilled), Some(file)) = (record.spilled, self.file) else {
            return Ok(Cow::Borrowed(&record.observations));
        };
        let mut bytes = vec![0u8; spilled.count as usize * OBSERVATION_BYTES];
        file.read_at(spilled.at, &mut bytes)?;
        Ok(Cow::Owned(
            bytes
                .chunks_exact(OBSERVATION_BYTES)
                .map(FrameObservation::read_from)
                .collect(),
        ))
    }
}

impl std::ops::Deref for FrameRecords {
    type Target = [FrameRecord];
    fn deref(&self) -> &[FrameRecord] {
        &self.records
    }
}

impl std::ops::DerefMut for FrameRecords {
    fn deref_mut(&mut self) -> &mut [FrameRecord] {
        &mut self.records
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use slotmap::SlotMap;

    fn records_with(points: &[MapPointKey], frames: usize) -> Vec<FrameRecord> {
        (0..frames)
            .map(|f| FrameRecord {
                timestamp: f as f64 * 0.1,
                observations: (0..f * 3)
                    .map(|i| FrameObservation {
                        point: points[(f + i) % points.len()],
                        keypoint: i as u32,
                        x: 10.0 + i as f32 * 0.37,
                        y: 200.0 - f as f32 * 1.1,
                        right_u: if i % 2 == 0 { -1.0 } else { 3.5 + i as f32 },
                        level: (i % 8) as u8,
                    })
                    .collect(),
                ..FrameRecord::default()
            })
            .collect()
    }

    #[test]
    fn spilled_observations_come_back_and_change_like_held_ones() {
        let mut keys: SlotMap<MapPointKey, ()> = SlotMap::with_key();
        let points: Vec<MapPointKey> = (0..7).map(|_| keys.insert(())).collect();
        keys.remove(points[2]);
        let points: Vec<MapPointKey> = points.into_iter().chain([keys.insert(())]).collect();
        let dir = std::env::temp_dir().join(format!("dopslam-records-{}", std::process::id()));
        let originals = records_with(&points, 6);
        let mut held = FrameRecords::default();
        let mut spilled = FrameRecords::spilling_into(&dir).unwrap();
        for record in originals.clone() {
            held.push(record.clone()).unwrap();
            spilled.push(record).unwrap();
        }
        assert!(spilled.iter().all(|r| r.observations.is_empty()));
        assert!(spilled.heap_bytes() < held.heap_bytes());
        for (i, original) in originals.iter().enumerate() {
            assert_eq!(spilled[i].observation_count(), original.observations.len());
            assert_eq!(
                *spilled.observations(&spilled[i]).unwrap(),
                *original.observations
            );
        }
        let shift = |o: &mut FrameObservation| {
            if o.right_u >= 0.0 {
                o.right_u -= 0.25;
            }
        };
        held.change_observations(shift).unwrap();
        spilled.change_observations(shift).unwrap();
        for i in 0..originals.len() {
            assert_eq!(
                spilled.observations(&spilled[i]).unwrap(),
                held.observations(&held[i]).unwrap()
            );
        }
        assert_ne!(held[5].observations, originals[5].observations);
        drop(spilled);
        let left = std::fs::read_dir(&dir).unwrap().count();
        std::fs::remove_dir(&dir).unwrap();
        assert_eq!(left, 0, "the spill file goes with the records");
    }
}
