//! What the map keeps of a tracked frame that is not (only) a keyframe: its pose
//! relative to its reference keyframe and the map points it saw. The tracking pass
//! writes one [`FrameRecord`] per frame into [`FrameRecords`], which keeps their
//! observations on disk (they grow with the frames, not with the map); the global
//! pass corrects them on the final map, and the final trajectory is read from them.

use std::borrow::Cow;
use std::path::Path;

use super::{KeyFrameKey, MapPointKey};
use crate::geometry::se3::{self, Se3, POSE_BYTES};
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

/// Bytes of a pose on disk: the rotation matrix (column order) and the translation.
/// Bytes of a record on disk without its observations: timestamp, segment, which of
/// the optional parts it has, keyframe key, tracked pose, reference key and pose,
/// where its observations are and how many.
const RECORD_BYTES: usize = 8 + 8 + 1 + 8 + POSE_BYTES + 8 + POSE_BYTES + 8 + 4;
/// Records read or changed at a time from disk ([`FrameRecords::update`]).
pub const RECORD_CHUNK: usize = 4096;

/// The tracked frames' records in frame order (held in memory when made by
/// `Default`). With spill files ([`FrameRecords::spilling_into`]) each record goes to
/// disk as it is pushed, its observations to one file and the rest (poses, keys:
/// [`RECORD_BYTES`]) to a slot of another, so that memory holds only the newest
/// record whatever the number of frames; they are read back through
/// [`FrameRecords::iter`], [`FrameRecords::observations`], and changed in place
/// through [`FrameRecords::update`] and [`FrameRecords::change_observations`]. The
/// files are removed with the records.
#[derive(Debug, Default)]
pub struct FrameRecords {
    held: Vec<FrameRecord>,
    file: Option<SpillFile>,
    /// The records without their observations, one slot a frame.
    heads: Option<SpillFile>,
    len: usize,
    /// The newest record (its observations on disk with spill files).
    last: Option<FrameRecord>,
}

impl FrameRecords {
    /// Records that go to new spill files in `dir` (a run's folder).
    pub fn spilling_into(dir: &Path) -> Result<Self, IoError> {
        Ok(Self {
            file: Some(SpillFile::create(dir, "frames", 1)?),
            heads: Some(SpillFile::create(dir, "frame-poses", RECORD_BYTES)?),
            ..Self::default()
        })
    }

    /// Adds the next frame's record (to disk, with spill files).
    pub fn push(&mut self, mut record: FrameRecord) -> Result<(), IoError> {
        if let (Some(file), Some(heads)) = (self.file.as_mut(), self.heads.as_mut()) {
            let at = file.append(&encode(&record.observations))?;
            record.spilled = Some(Spilled {
                at,
                count: record.observations.len() as u32,
            });
            record.observations = Vec::new();
            heads.write(None, &record.head_bytes())?;
            self.last = Some(record);
        } else {
            self.held.push(record);
        }
        // Counted once written: after a failed write the records stay whole.
        self.len += 1;
        Ok(())
    }

    /// How many records there are.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether there is none.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The newest record.
    pub fn last(&self) -> Option<&FrameRecord> {
        match &self.heads {
            Some(_) => self.last.as_ref(),
            None => self.held.last(),
        }
    }

    /// The records `start..start + n` (fewer at the end), read from disk.
    pub fn read_chunk(&self, start: usize, n: usize) -> Result<Vec<FrameRecord>, IoError> {
        let Some(heads) = &self.heads else {
            return Ok(self.held[start..(start + n).min(self.len)].to_vec());
        };
        let n = n.min(self.len.saturating_sub(start));
        let mut bytes = vec![0u8; n * RECORD_BYTES];
        heads.read_at((start * RECORD_BYTES) as u64, &mut bytes)?;
        Ok(bytes
            .chunks_exact(RECORD_BYTES)
            .map(FrameRecord::from_head_bytes)
            .collect())
    }

    /// Every record in order (observations on disk stay there), [`RECORD_CHUNK`] read
    /// at a time.
    pub fn iter(&self) -> impl Iterator<Item = Result<FrameRecord, IoError>> + '_ {
        (0..self.len).step_by(RECORD_CHUNK).flat_map(move |start| {
            match self.read_chunk(start, RECORD_CHUNK) {
                Ok(chunk) => chunk.into_iter().map(Ok).collect::<Vec<_>>(),
                Err(e) => vec![Err(e)],
            }
        })
    }

    /// `change` on the records in order, `chunk` at a time, with the reader of their
    /// observations; what it changed goes back to disk.
    pub fn update<E: From<IoError>>(
        &mut self,
        chunk: usize,
        mut change: impl FnMut(&mut [FrameRecord], ObservationReader) -> Result<(), E>,
    ) -> Result<(), E> {
        let chunk = chunk.max(1);
        for start in (0..self.len).step_by(chunk) {
            self.update_range(start, (start + chunk).min(self.len), &mut change)?;
        }
        Ok(())
    }

    /// `change` on the records `start..end`, read into memory, with the reader of
    /// their observations; what it changed goes back to disk.
    pub fn update_range<E: From<IoError>>(
        &mut self,
        start: usize,
        end: usize,
        mut change: impl FnMut(&mut [FrameRecord], ObservationReader) -> Result<(), E>,
    ) -> Result<(), E> {
        let end = end.min(self.len);
        let reader = ObservationReader {
            file: self.file.as_ref(),
        };
        if self.heads.is_none() {
            return change(&mut self.held[start.min(end)..end], reader);
        }
        let mut records = self.read_chunk(start, end.saturating_sub(start))?;
        change(&mut records, reader)?;
        Ok(self.write_chunk(start, records)?)
    }

    /// Writes `records` over the records from `start` on (read by
    /// [`Self::read_chunk`] and changed, their observations where they were).
    pub fn write_chunk(
        &mut self,
        start: usize,
        mut records: Vec<FrameRecord>,
    ) -> Result<(), IoError> {
        let end = start + records.len();
        debug_assert!(end <= self.len);
        let Some(heads) = self.heads.as_mut() else {
            self.held.splice(start..end, records);
            return Ok(());
        };
        let mut written = Vec::with_capacity(records.len() * RECORD_BYTES);
        records.iter().for_each(|r| r.write_head(&mut written));
        heads.overwrite((start * RECORD_BYTES) as u64, &written)?;
        if end == self.len && !records.is_empty() {
            self.last = records.pop();
        }
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
        if self.file.is_none() {
            for record in &mut self.held {
                record.observations.iter_mut().for_each(&mut change);
            }
            return Ok(());
        }
        for start in (0..self.len).step_by(RECORD_CHUNK) {
            for record in self.read_chunk(start, RECORD_CHUNK)? {
                let Some(spilled) = record.spilled else {
                    continue;
                };
                let mut observations = self.observations(&record)?.into_owned();
                observations.iter_mut().for_each(&mut change);
                let file = self.file.as_mut().expect("a spill file");
                file.overwrite(spilled.at, &encode(&observations))?;
            }
        }
        Ok(())
    }

    /// The bytes the records hold in memory (what is on disk not counted).
    pub fn heap_bytes(&self) -> usize {
        self.held.iter().map(FrameRecord::heap_bytes).sum::<usize>()
            + (self.held.capacity() - self.held.len()) * std::mem::size_of::<FrameRecord>()
            + self.last.as_ref().map_or(0, FrameRecord::heap_bytes)
    }
}

impl FrameRecord {
    /// The record without its observations, as [`FrameRecords`] writes it to disk.
    fn head_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(RECORD_BYTES);
        self.write_head(&mut out);
        out
    }

    fn write_head(&self, out: &mut Vec<u8>) {
        use slotmap::Key;
        let start = out.len();
        let key = |k: Option<KeyFrameKey>| k.map_or(0, |k| k.data().as_ffi());
        let flags = u8::from(self.keyframe.is_some())
            | u8::from(self.camera_from_world.is_some()) << 1
            | u8::from(self.reference.is_some()) << 2
            | u8::from(self.spilled.is_some()) << 3;
        out.extend_from_slice(&self.timestamp.to_le_bytes());
        out.extend_from_slice(&(self.segment as u64).to_le_bytes());
        out.push(flags);
        out.extend_from_slice(&key(self.keyframe).to_le_bytes());
        se3::write_bytes(out, self.camera_from_world.as_ref());
        out.extend_from_slice(&key(self.reference.map(|r| r.0)).to_le_bytes());
        se3::write_bytes(out, self.reference.as_ref().map(|r| &r.1));
        let spilled = self.spilled.unwrap_or(Spilled { at: 0, count: 0 });
        out.extend_from_slice(&spilled.at.to_le_bytes());
        out.extend_from_slice(&spilled.count.to_le_bytes());
        debug_assert_eq!(out.len() - start, RECORD_BYTES);
    }

    fn from_head_bytes(bytes: &[u8]) -> Self {
        let mut at = 0;
        let mut take = |n: usize| {
            let part = &bytes[at..at + n];
            at += n;
            part
        };
        let word = |b: &[u8]| u64::from_le_bytes(b.try_into().expect("8 bytes"));
        let timestamp = f64::from_bits(word(take(8)));
        let segment = word(take(8)) as usize;
        let flags = take(1)[0];
        let has = |bit: u8| flags & (1 << bit) != 0;
        let key = |b: &[u8]| -> KeyFrameKey { slotmap::KeyData::from_ffi(word(b)).into() };
        let keyframe = key(take(8));
        let camera_from_world = se3::read_bytes(take(POSE_BYTES));
        let reference_key = key(take(8));
        let reference_pose = se3::read_bytes(take(POSE_BYTES));
        let spilled = Spilled {
            at: word(take(8)),
            count: u32::from_le_bytes(take(4).try_into().expect("4 bytes")),
        };
        Self {
            timestamp,
            segment,
            keyframe: has(0).then_some(keyframe),
            camera_from_world: has(1).then_some(camera_from_world),
            reference: has(2).then_some((reference_key, reference_pose)),
            observations: Vec::new(),
            spilled: has(3).then_some(spilled),
        }
    }
}

/// Reads spilled observations while the records are borrowed mutably
/// ([`FrameRecords::update`]).
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
    fn spilled_records_come_back_and_change_like_held_ones() {
        let mut keys: SlotMap<MapPointKey, ()> = SlotMap::with_key();
        let points: Vec<MapPointKey> = (0..7).map(|_| keys.insert(())).collect();
        keys.remove(points[2]);
        let points: Vec<MapPointKey> = points.into_iter().chain([keys.insert(())]).collect();
        let mut keyframes: SlotMap<KeyFrameKey, ()> = SlotMap::with_key();
        let keyframe = keyframes.insert(());
        let dir = std::env::temp_dir().join(format!("dopslam-records-{}", std::process::id()));
        let mut originals = records_with(&points, 6);
        let pose = |x: f64| {
            let rotation = nalgebra::Rotation3::from_euler_angles(0.1 * x, -0.2, 0.3 + x);
            Se3::from_parts(nalgebra::Translation3::new(x, -x / 3.0, 1e-7), rotation)
        };
        originals[1].keyframe = Some(keyframe);
        originals[2].camera_from_world = Some(pose(2.0));
        originals[3].reference = Some((keyframe, pose(3.0)));
        originals[4].segment = 3;
        let mut held = FrameRecords::default();
        let mut spilled = FrameRecords::spilling_into(&dir).unwrap();
        for record in originals.clone() {
            held.push(record.clone()).unwrap();
            spilled.push(record).unwrap();
        }
        assert_eq!(spilled.len(), 6);
        assert!(spilled.heap_bytes() < held.heap_bytes());
        // Memory holds the newest record alone, however many were pushed.
        let newest = spilled.heap_bytes();
        assert_eq!(newest, std::mem::size_of::<FrameRecord>());
        let back: Vec<FrameRecord> = spilled.iter().collect::<Result<_, _>>().unwrap();
        for (original, back) in originals.iter().zip(&back) {
            assert_eq!(back.observation_count(), original.observations.len());
            assert_eq!(*spilled.observations(back).unwrap(), *original.observations);
            assert_eq!(back.timestamp.to_bits(), original.timestamp.to_bits());
            assert_eq!(
                (
                    back.segment,
                    back.keyframe,
                    back.camera_from_world,
                    back.reference
                ),
                (
                    original.segment,
                    original.keyframe,
                    original.camera_from_world,
                    original.reference
                )
            );
        }
        let shift = |o: &mut FrameObservation| {
            if o.right_u >= 0.0 {
                o.right_u -= 0.25;
            }
        };
        held.change_observations(shift).unwrap();
        spilled.change_observations(shift).unwrap();
        let moved = |records: &mut FrameRecords| {
            records
                .update(4, |chunk, _| {
                    chunk
                        .iter_mut()
                        .for_each(|r| r.camera_from_world = Some(pose(r.timestamp)));
                    Ok::<(), IoError>(())
                })
                .unwrap()
        };
        moved(&mut held);
        moved(&mut spilled);
        let all = |records: &FrameRecords| -> Vec<FrameRecord> {
            records.iter().collect::<Result<_, _>>().unwrap()
        };
        for (a, b) in all(&held).iter().zip(&all(&spilled)) {
            assert_eq!(
                held.observations(a).unwrap(),
                spilled.observations(b).unwrap()
            );
            assert_eq!(a.camera_from_world, b.camera_from_world);
        }
        assert_eq!(spilled.last().unwrap().camera_from_world, Some(pose(0.5)));
        assert_ne!(
            held.iter().last().unwrap().unwrap().observations,
            originals[5].observations
        );
        drop(spilled);
        let left = std::fs::read_dir(&dir).unwrap().count();
        std::fs::remove_dir(&dir).unwrap();
        assert_eq!(left, 0, "the spill files go with the records");
    }
}
