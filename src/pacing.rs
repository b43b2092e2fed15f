//! Frames at the recording's rate: in real-time mode a recorded sequence can be played
//! back as its camera delivered it (`dopslam run --pace recording`), so that the
//! detector and local mapping have the wall-clock time per frame that they would have
//! live (ORB-SLAM2's examples wait for each frame's timestamp the same way). Played as
//! fast as the tracker goes (the default), they get less: a detector that keeps up with
//! a 30 Hz camera may fall a keyframe or two behind.
//!
//! Frame \(i\) with timestamp \(t_i\) is handed over no earlier than
//! \(w_0 + (t_i - t_0)\), with \(w_0\) the wall-clock time of the first frame. A
//! tracker slower than the camera is never held back: frames that came due while it
//! was busy are taken at once, as a live camera's queued frames are.

use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

/// How real-time mode hands recorded frames to the tracker.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Pace {
    /// At the recording's rate, as the camera delivered them: a live run.
    Recording,
    /// As fast as the tracker goes (the default: the detector and local mapping get
    /// less wall-clock time per frame than live, and runs take half the time; on the
    /// cut-out presets accuracy was the same, README).
    #[default]
    Free,
}

/// The longest wait between two frames: a gap in the timestamps longer than this (a
/// recording paused, a clock that jumped) is played as this long.
pub const MAX_GAP: Duration = Duration::from_secs(1);

/// Waits for each frame's time.
#[derive(Debug)]
pub struct Pacer {
    pace: Pace,
    /// The first frame's wall-clock time and timestamp (moved on over long gaps).
    origin: Option<(Instant, f64)>,
    last: Option<f64>,
}

impl Pacer {
    /// A pacer that releases frames as `pace` says.
    pub fn new(pace: Pace) -> Self {
        Self {
            pace,
            origin: None,
            last: None,
        }
    }

    /// Sleeps until the frame with `timestamp` (seconds) is due, at most [`MAX_GAP`]
    /// after the last frame's time, and in slices that a Ctrl-C or SIGTERM ends.
    pub fn wait_for(&mut self, timestamp: f64) {
        if self.pace == Pace::Free {
            return;
        }
        let (start, first) = self.origin.get_or_insert((Instant::now(), timestamp));
        if let Some(last) = self.last {
            let gap = timestamp - last;
            if gap.is_finite() && gap > MAX_GAP.as_secs_f64() {
                *first += gap - MAX_GAP.as_secs_f64();
            }
        }
        self.last = Some(timestamp);
        let (start, first) = (*start, *first);
        while let Some(rest) = due_in(start.elapsed(), timestamp - first) {
            if crate::interrupt::requested() {
                return;
            }
            std::thread::sleep(rest.min(Duration::from_millis(50)));
        }
    }
}

/// How long to wait when `elapsed` wall-clock time has passed since the first frame and
/// the frame is `offset` seconds after it in the recording; `None` when it is due.
fn due_in(elapsed: Duration, offset: f64) -> Option<Duration> {
    if !(offset.is_finite() && offset > 0.0) {
        return None;
    }
    Duration::from_secs_f64(offset)
        .checked_sub(elapsed)
        .filter(|d| !d.is_zero())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_gap_in_the_timestamps_waits_at_most_max_gap() {
        let mut pacer = Pacer::new(Pace::Recording);
        pacer.wait_for(100.0);
        let start = Instant::now();
        pacer.wait_for(100_000.0);
        let waited = start.elapsed();
        assert!(waited <= MAX_GAP + Duration::from_millis(300), "{waited:?}");
        assert!(waited >= MAX_GAP - Duration::from_millis(100), "{waited:?}");
        // The frames after the gap keep their own spacing.
        let start = Instant::now();
        pacer.wait_for(100_000.05);
        assert!(start.elapsed() < Duration::from_millis(200));
    }

    #[test]
    fn a_frame_waits_for_its_time_and_a_late_one_does_not() {
        let ms = Duration::from_millis;
        assert_eq!(due_in(ms(10), 0.033), Some(ms(23)));
        assert_eq!(due_in(ms(40), 0.033), None);
        assert_eq!(due_in(ms(0), 0.0), None);
        // Timestamps that go back, or are not numbers, never block.
        assert_eq!(due_in(ms(0), -1.0), None);
        assert_eq!(due_in(ms(0), f64::NAN), None);
    }

    #[test]
    fn recording_pace_takes_the_recording_s_time_and_free_does_not() {
        let timestamps = [100.0, 100.02, 100.04, 100.06];
        let played = |pace| {
            let mut pacer = Pacer::new(pace);
            let start = Instant::now();
            for t in timestamps {
                pacer.wait_for(t);
            }
            start.elapsed()
        };
        assert!(played(Pace::Recording) >= Duration::from_millis(60));
        assert!(played(Pace::Free) < Duration::from_millis(20));
    }
}
