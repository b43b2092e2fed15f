//! What watches the tracking pass frame by frame without taking part in it: the
//! progress bar, the debug pictures (the paper's Fig. 4), the dynamic keypoints the
//! dense pass masks with, and the ground-truth scorer ([`super::truth`]).

use std::path::PathBuf;

use indicatif::{ProgressBar, ProgressStyle};

use crate::dense::masks::dynamic_keypoints;
use crate::dop::DopConfig;
use crate::dynamics::Applied;
use crate::frame::Frame;
use crate::io::image_files::DepthImage;
use crate::io::spill::SpillFile;
use crate::io::IoError;
use crate::map::record::FrameRecord;
use crate::tracking::input::Picture;
use crate::tracking::{FrameStats, TrackingState};

/// One frame as the system left it.
pub struct FrameView<'a> {
    /// The frame's index.
    pub index: usize,
    /// Seconds.
    pub timestamp: f64,
    /// The frame's report line and its record (pose, reference keyframe).
    pub stats: &'a FrameStats,
    /// The frame's record.
    pub record: &'a FrameRecord,
    /// The frame with its moving probabilities, when tracking kept it.
    pub frame: Option<&'a Frame>,
    /// The DOP model, when on.
    pub dop: Option<&'a DopConfig>,
    /// The frame's picture, when an observer draws on it (debug pictures, the Rerun
    /// recording).
    pub picture: Option<&'a Picture>,
    /// The frame's depth, when the Rerun recording logs it.
    pub depth: Option<&'a DepthImage>,
    /// At a keyframe, when the Rerun recording is on: the recent keyframes' map
    /// points, static and moving ([`crate::system::System::recent_map_points`]).
    pub recent_map: Option<&'a crate::system::RecentMap>,
}

impl FrameView<'_> {
    /// The frame, when it was tracked (state Ok).
    pub fn tracked(&self) -> Option<&Frame> {
        self.frame.filter(|_| self.stats.state == TrackingState::Ok)
    }
}

/// Watches the tracking pass.
pub trait FrameObserver {
    /// After each frame; an error (a file it could not write) stops the pass.
    fn on_frame(&mut self, view: &FrameView) -> Result<(), IoError>;

    /// Adds what it found of the frame it just saw (after [`Self::on_frame`]) to the
    /// frame's report line.
    fn annotate(&mut self, _line: &mut crate::records::FrameLine) {}

    /// After detections were applied to their keyframes.
    fn on_applied(&mut self, _applied: &[Applied]) {}

    /// After the last frame.
    fn finish(&mut self) {}
}

/// The progress bar (hidden without `--progress`).
pub struct Progress {
    bar: ProgressBar,
}

impl Progress {
    /// A bar over `total` frames, drawn when `shown`.
    pub fn new(total: usize, shown: bool) -> Self {
        let bar = if shown {
            ProgressBar::new(total as u64)
        } else {
            ProgressBar::hidden()
        };
        bar.set_style(
            ProgressStyle::with_template(
                "track {bar:40} {pos}/{len} frames {msg} ({per_sec}, {eta} left)",
            )
            .expect("valid template"),
        );
        Self { bar }
    }
}

impl FrameObserver for Progress {
    fn on_frame(&mut self, view: &FrameView) -> Result<(), IoError> {
        self.bar.set_message(format!("{:?}", view.stats.state));
        self.bar.inc(1);
        Ok(())
    }

    fn finish(&mut self) {
        self.bar.finish_and_clear();
    }
}

/// Each frame with its keypoints coloured by DOP state, as PNGs in a folder.
pub struct DebugFrames {
    /// The folder of the pictures.
    pub dir: PathBuf,
}

impl FrameObserver for DebugFrames {
    fn on_frame(&mut self, view: &FrameView) -> Result<(), IoError> {
        let (Some(frame), Some(picture)) = (view.frame, view.picture) else {
            return Ok(());
        };
        let mut picture = picture.clone().into_colour();
        let dop = view.dop.cloned().unwrap_or_default();
        crate::detect::draw::draw_keypoints(&mut picture, frame, &dop);
        let path = self.dir.join(format!("{:06}.png", view.index));
        std::fs::create_dir_all(&self.dir)
            .and_then(|_| picture.save(&path).map_err(std::io::Error::other))
            .map_err(|source| IoError::Write { path, source })
    }
}

/// The dynamic keypoints of every tracked frame (DOP mode), for the dense pass: each
/// frame's goes to a spill file in the run's folder as it comes (one JSON value a
/// line), and `dynamic_keypoints.json` is written from it ([`Self::write_json`]).
pub struct DynamicKeypoints {
    dir: PathBuf,
    spill: Option<SpillFile>,
}

impl DynamicKeypoints {
    /// Keypoints to spill into `dir` (the run's folder) once a DOP frame comes.
    pub fn new(dir: PathBuf) -> Self {
        Self { dir, spill: None }
    }

    /// The frames' keypoints as one JSON array (as `serde_json` writes a list of
    /// them), streamed from the spill file.
    pub fn write_json(&self, out: &mut dyn std::io::Write) -> std::io::Result<()> {
        out.write_all(b"[")?;
        if let Some(spill) = &self.spill {
            let reader = std::io::BufReader::with_capacity(1 << 16, spill.reader());
            for (i, line) in std::io::BufRead::lines(reader).enumerate() {
                if i > 0 {
                    out.write_all(b",")?;
                }
                out.write_all(line?.as_bytes())?;
            }
        }
        out.write_all(b"]")
    }
}

impl FrameObserver for DynamicKeypoints {
    fn on_frame(&mut self, view: &FrameView) -> Result<(), IoError> {
        if let (Some(dop), Some(frame)) = (view.dop, view.tracked()) {
            let spill = match self.spill.as_mut() {
                Some(spill) => spill,
                None => self
                    .spill
                    .insert(SpillFile::create(&self.dir, "keypoints", 1)?),
            };
            let mut line =
                serde_json::to_vec(&dynamic_keypoints(frame, dop)).expect("keypoints serialise");
            line.push(b'\n');
            spill.append(&line)?;
        }
        Ok(())
    }
}
