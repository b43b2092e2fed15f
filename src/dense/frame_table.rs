//! The run's frames as the dense pass reads them, on disk: one fixed slot per frame of
//! the sequence in a spill file of the output folder (removed when the pass ends),
//! holding the frame's final pose from `trajectory.txt` bit for bit and whether it lies
//! in the largest map segment of `segments.txt`. Both files are read line by line, so the pass holds no list
//! of frames: choosing the frames ([`super::frame_choice`]), placing the detected
//! objects and the free-space neighbours read the slots they need, and a time comes
//! to its frame by a binary search over the sequence's own timestamps
//! ([`TimeOrder`]). The keyframes' times are held: they grow with the map.

use std::collections::{HashMap, HashSet};
use std::path::Path;

use crate::geometry::se3::{self, Se3, POSE_BYTES};
use crate::io::run_dir::RunDir;
use crate::io::sequence::Sequence;
use crate::io::spill::SpillFile;
use crate::io::trajectory::{for_each_tum, TrajectoryFormat};
use crate::io::{IoError, Trajectory};

/// Timestamps as keys (microseconds, as the file names carry them).
pub(super) fn key(t: f64) -> i64 {
    (t * 1e6).round() as i64
}

/// A slot: flags, then `world_from_camera` ([`se3::write_bytes`]).
const SLOT: usize = 1 + POSE_BYTES;
/// The frame has a pose in `trajectory.txt`.
const POSED: u8 = 1;
/// The frame lies in the largest map segment of `segments.txt`.
const IN_LARGEST: u8 = 2;

/// The frames of a sequence in time order: the sequence's own order when its
/// timestamps do not decrease (recordings' do), else a sorted list of its indices
/// (ties in index order).
pub(super) enum TimeOrder {
    /// Index order is time order.
    Sorted,
    /// The indices by time.
    Permuted(Vec<u32>),
}

impl TimeOrder {
    /// The time order of `sequence`'s frames.
    pub fn of(sequence: &dyn Sequence) -> Self {
        let n = sequence.len();
        let sorted = (1..n).all(|i| {
            sequence
                .timestamp(i - 1)
                .total_cmp(&sequence.timestamp(i))
                .is_le()
        });
        if sorted {
            return Self::Sorted;
        }
        let mut indices: Vec<u32> = (0..n as u32).collect();
        indices.sort_by(|&a, &b| {
            let (a, b) = (
                sequence.timestamp(a as usize),
                sequence.timestamp(b as usize),
            );
            a.total_cmp(&b)
        });
        Self::Permuted(indices)
    }

    /// The index of the frame `rank`-th in time.
    pub fn index(&self, rank: usize) -> usize {
        match self {
            Self::Sorted => rank,
            Self::Permuted(indices) => indices[rank] as usize,
        }
    }

    /// The number of frames before the first one for which `after(timestamp)` holds
    /// (`after` false, then true, along time).
    fn rank_where(&self, sequence: &dyn Sequence, after: impl Fn(f64) -> bool) -> usize {
        let (mut low, mut high) = (0, sequence.len());
        while low < high {
            let middle = low + (high - low) / 2;
            match after(sequence.timestamp(self.index(middle))) {
                true => high = middle,
                false => low = middle + 1,
            }
        }
        low
    }
}

/// The run's frames on disk (see the module doc).
pub(super) struct FrameTable<'a> {
    sequence: &'a dyn Sequence,
    order: TimeOrder,
    file: SpillFile,
    /// `segments.txt` lists more than one segment: only the largest one's frames are
    /// posed.
    segmented: bool,
    keyframe_times: HashSet<i64>,
    /// Posed frames of the other segments, left out.
    pub other_segment_frames: usize,
}

impl<'a> FrameTable<'a> {
    /// The frames of `sequence` with the poses, keyframes and segments of the run
    /// folder `run`, in a spill file in `spill_dir`.
    pub fn read(
        run: &RunDir,
        sequence: &'a dyn Sequence,
        spill_dir: &Path,
    ) -> Result<Self, IoError> {
        let keyframes =
            Trajectory::read(&run.keyframes(), TrajectoryFormat::Tum).unwrap_or_default();
        let mut table = Self {
            sequence,
            order: TimeOrder::of(sequence),
            file: SpillFile::create(spill_dir, "dense-frames", SLOT)?,
            segmented: false,
            keyframe_times: keyframes.timestamps.iter().map(|&t| key(t)).collect(),
            other_segment_frames: 0,
        };
        if let Some(last) = sequence.len().checked_sub(1) {
            // Every slot reads as zeros (no pose) until written.
            table.file.write(Some(last as u32), &[0; SLOT])?;
        }
        for_each_tum(&run.trajectory(), |t, world_from_camera| {
            let mut pose = Vec::with_capacity(POSE_BYTES);
            se3::write_bytes(&mut pose, Some(&world_from_camera));
            table.each_frame_at(t, |slot| {
                slot[0] |= POSED;
                slot[1..].copy_from_slice(&pose);
            })
        })?;
        table.mark_largest_segment(&run.segments())?;
        Ok(table)
    }

    /// Marks the frames of the largest segment of `path` (`segments.txt`), when it
    /// lists more than one, and counts the posed frames left out.
    fn mark_largest_segment(&mut self, path: &Path) -> Result<(), IoError> {
        let mut frames: HashMap<usize, usize> = HashMap::new();
        let present = crate::io::run_dir::for_each_segment(path, |_, segment| {
            *frames.entry(segment).or_default() += 1;
            Ok(())
        })?;
        if !present || frames.len() < 2 {
            return Ok(());
        }
        // The most frames; ties go to the older segment.
        let largest = frames
            .into_iter()
            .max_by(|a, b| a.1.cmp(&b.1).then(b.0.cmp(&a.0)))
            .map_or(0, |(segment, _)| segment);
        crate::io::run_dir::for_each_segment(path, |t, segment| match segment == largest {
            true => self.each_frame_at(t, |slot| slot[0] |= IN_LARGEST),
            false => Ok(()),
        })?;
        self.segmented = true;
        for i in 0..self.sequence.len() {
            let flags = self.flags(i)?;
            self.other_segment_frames += usize::from(flags == POSED);
        }
        Ok(())
    }

    /// Changes the slots of the frames whose timestamp has the key of `t` with `change`.
    fn each_frame_at(&mut self, t: f64, change: impl Fn(&mut [u8; SLOT])) -> Result<(), IoError> {
        let k = key(t);
        let first = self.order.rank_where(self.sequence, |s| key(s) >= k);
        let end = self.order.rank_where(self.sequence, |s| key(s) > k);
        for rank in first..end {
            let index = self.order.index(rank);
            let mut slot = [0; SLOT];
            self.file.read(index as u32, &mut slot)?;
            change(&mut slot);
            self.file.write(Some(index as u32), &slot)?;
        }
        Ok(())
    }

    fn flags(&self, index: usize) -> Result<u8, IoError> {
        let mut flags = [0];
        self.file.read_part(index as u32, 0, &mut flags)?;
        Ok(flags[0])
    }

    /// The number of frames of the sequence.
    pub fn len(&self) -> usize {
        self.sequence.len()
    }

    /// Whether frame `index` is a keyframe of the run.
    pub fn is_keyframe(&self, index: usize) -> bool {
        self.keyframe_times
            .contains(&key(self.sequence.timestamp(index)))
    }

    /// Frame `index`'s final `camera_from_world`, when it has one in the fused
    /// segment.
    pub fn pose(&self, index: usize) -> Result<Option<Se3>, IoError> {
        let mut slot = [0; SLOT];
        self.file.read(index as u32, &mut slot)?;
        let wanted = match self.segmented {
            true => POSED | IN_LARGEST,
            false => POSED,
        };
        Ok((slot[0] & wanted == wanted).then(|| se3::read_bytes(&slot[1..]).inverse()))
    }

    /// The frame at time `t` (the last one of that timestamp).
    pub fn index_at(&self, t: f64) -> Option<usize> {
        let k = key(t);
        let end = self.order.rank_where(self.sequence, |s| key(s) > k);
        let index = self.order.index(end.checked_sub(1)?);
        (key(self.sequence.timestamp(index)) == k).then_some(index)
    }

    /// The final `camera_from_world` of the frame at time `t`.
    pub fn pose_at(&self, t: f64) -> Result<Option<Se3>, IoError> {
        match self.index_at(t) {
            Some(index) => self.pose(index),
            None => Ok(None),
        }
    }

    /// The posed frame nearest `time` (the one before it on a tie), when one lies
    /// within `within` seconds: its time, index and `camera_from_world`.
    pub fn nearest_posed(
        &self,
        time: f64,
        within: f64,
    ) -> Result<Option<(f64, usize, Se3)>, IoError> {
        let sequence = self.sequence;
        let rank = self.order.rank_where(sequence, |s| s >= time);
        let posed_at = |rank: usize| -> Result<Option<(f64, usize, Se3)>, IoError> {
            let index = self.order.index(rank);
            let t = sequence.timestamp(index);
            Ok(self.pose(index)?.map(|pose| (t, index, pose)))
        };
        let near =
            |rank: usize| (sequence.timestamp(self.order.index(rank)) - time).abs() <= within;
        // The first posed frame of `ranks` (outwards from `time`), within the reach.
        let first_posed = |ranks: &mut dyn Iterator<Item = usize>| {
            for rank in ranks.take_while(|&r| near(r)) {
                if let Some(found) = posed_at(rank)? {
                    return Ok(Some(found));
                }
            }
            Ok::<_, IoError>(None)
        };
        let before = first_posed(&mut (0..rank).rev())?;
        let after = first_posed(&mut (rank..sequence.len()))?;
        Ok(match (before, after) {
            (Some(b), Some(a)) if (a.0 - time).abs() < (b.0 - time).abs() => Some(a),
            (Some(b), _) => Some(b),
            (None, a) => a,
        })
    }
}

impl super::free_space::PosedFrames for FrameTable<'_> {
    fn nearest(&self, time: f64, within: f64) -> Result<Option<(f64, usize, Se3)>, IoError> {
        self.nearest_posed(time, within)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dense::free_space::{PosedFrames, PosedList};
    use crate::io::run_dir::names;
    use crate::io::sequence::{Frame, SensorKind};
    use nalgebra::{Rotation3, Vector3};

    /// Timestamps alone: the table never loads a frame.
    struct Times(Vec<f64>);

    impl Sequence for Times {
        fn name(&self) -> &str {
            "times"
        }
        fn sensor(&self) -> SensorKind {
            SensorKind::Rgbd
        }
        fn len(&self) -> usize {
            self.0.len()
        }
        fn timestamp(&self, index: usize) -> f64 {
            self.0[index]
        }
        fn load(&self, index: usize) -> Result<Frame, IoError> {
            Err(IoError::invalid(
                "times",
                format!("frame {index} has no images"),
            ))
        }
        fn ground_truth(&self) -> Option<&Trajectory> {
            None
        }
        fn calibration(&self) -> Option<&crate::io::orbslam_settings::Calibration> {
            None
        }
    }

    /// A run folder in a new temporary folder `name`.
    fn run_dir(name: &str) -> (std::path::PathBuf, RunDir) {
        let dir = std::env::temp_dir().join(format!("dopslam-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        (dir.clone(), RunDir::new(&dir))
    }

    /// A pose turned and moved by `i`, with digits that a text round trip keeps.
    fn pose(i: usize) -> Se3 {
        let rotation = Rotation3::from_euler_angles(0.1 * i as f64, 0.02, -0.3);
        crate::geometry::se3::from_parts(
            Vector3::new(0.125 * i as f64, -1.5, 2.0),
            *rotation.matrix(),
        )
    }

    #[test]
    fn poses_come_back_from_the_file_and_only_the_largest_segment_is_posed() {
        let (dir, run) = run_dir("frame-table");
        // Frames 0-9 at 10 Hz; frames 2 and 7 were not tracked.
        let times: Vec<f64> = (0..10).map(|i| 1.0 + 0.1 * i as f64).collect();
        let sequence = Times(times.clone());
        let tracked: Vec<usize> = (0..10).filter(|i| ![2, 7].contains(i)).collect();
        let mut trajectory = Trajectory::default();
        for &i in &tracked {
            trajectory.push(times[i], pose(i));
        }
        trajectory
            .write(&run.trajectory(), TrajectoryFormat::Tum)
            .unwrap();
        let written = Trajectory::read(&run.trajectory(), TrajectoryFormat::Tum).unwrap();
        Trajectory {
            timestamps: vec![times[3]],
            poses: vec![pose(3)],
        }
        .write(&run.keyframes(), TrajectoryFormat::Tum)
        .unwrap();
        let table = FrameTable::read(&run, &sequence, &dir).unwrap();
        for (i, &t) in times.iter().enumerate() {
            let expected = tracked
                .iter()
                .position(|&t| t == i)
                .map(|k| written.poses[k].inverse());
            assert_eq!(table.pose(i).unwrap(), expected, "frame {i}");
            assert_eq!(table.pose_at(t).unwrap(), expected);
            assert_eq!(table.index_at(t), Some(i));
        }
        assert!(table.is_keyframe(3) && !table.is_keyframe(4));
        assert_eq!(table.index_at(5.0), None);
        assert_eq!(table.other_segment_frames, 0);
        drop(table);
        // Two segments: frames 0-4 and 5-9; the second has more lines (one of no frame).
        let lines: String = tracked
            .iter()
            .map(|&i| format!("{:.6} {}\n", times[i], usize::from(i >= 5) + 3))
            .collect();
        std::fs::write(run.segments(), format!("# t s\n{lines}9.0 4\n")).unwrap();
        let table = FrameTable::read(&run, &sequence, &dir).unwrap();
        let posed: Vec<usize> = (0..10)
            .filter(|&i| table.pose(i).unwrap().is_some())
            .collect();
        assert_eq!(posed, [5, 6, 8, 9]);
        assert_eq!(table.other_segment_frames, 4);
        drop(table);
        // A malformed line is named; the spill files are gone with their tables.
        std::fs::write(run.segments(), "1.0 0\n1.1 zero\n").unwrap();
        let error = FrameTable::read(&run, &sequence, &dir)
            .err()
            .unwrap()
            .to_string();
        assert!(
            error.contains("line 2") && error.contains(names::SEGMENTS),
            "{error}"
        );
        let left = std::fs::read_dir(&dir).unwrap().flatten();
        assert!(
            left.filter(|e| e.file_name().to_string_lossy().contains("spill"))
                .count()
                == 0
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn the_nearest_posed_frame_is_the_one_a_list_of_them_finds_in_any_time_order() {
        let (dir, run) = run_dir("frame-table-nearest");
        // Uneven times with a gap; every third frame and a stretch are untracked.
        let mut times: Vec<f64> = (0..60)
            .map(|i| 0.05 * i as f64 + 0.001 * (i % 7) as f64)
            .collect();
        times[30..].iter_mut().for_each(|t| *t += 1.0);
        let posed_at = |i: usize| !i.is_multiple_of(3) && !(40..46).contains(&i);
        let mut trajectory = Trajectory::default();
        for (i, &t) in times.iter().enumerate().filter(|(i, _)| posed_at(*i)) {
            trajectory.push(t, pose(i));
        }
        trajectory
            .write(&run.trajectory(), TrajectoryFormat::Tum)
            .unwrap();
        // The same frames, in time order and shuffled.
        let mut shuffled: Vec<usize> = (0..60).collect();
        shuffled.sort_by_key(|&i| (i * 37) % 60);
        for order in [(0..60).collect::<Vec<usize>>(), shuffled] {
            let sequence = Times(order.iter().map(|&i| times[i]).collect());
            let table = FrameTable::read(&run, &sequence, &dir).unwrap();
            let list = PosedList::new(
                (0..60)
                    .filter_map(|i| Some((sequence.0[i], i, table.pose(i).unwrap()?)))
                    .collect(),
            );
            for k in 0..400 {
                let time = -0.2 + 0.0113 * k as f64;
                for within in [0.0, 0.02, 0.06, 0.5, 10.0] {
                    assert_eq!(
                        table.nearest(time, within).unwrap().map(|p| (p.0, p.1)),
                        list.nearest(time, within).unwrap().map(|p| (p.0, p.1)),
                        "time {time}, within {within}"
                    );
                }
            }
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
}
