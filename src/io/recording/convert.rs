//! `dopslam convert REC --to tum|kitti OUT`: a sequence (a recording, usually) written
//! in the layout every other tool reads:
//!
//! - TUM RGB-D: `rgb/` PNGs, `depth/` 16-bit PNGs at 5000 per metre, `rgb.txt`,
//!   `depth.txt` and an ORB-SLAM2 `calibration.yaml`;
//! - KITTI odometry (a rectified stereo pair): `image_0/`, `image_1/` grey PNGs,
//!   `times.txt` and `calib.txt` (\(P_1[0,3] = -f_x b\)).
//!
//! The folder is written under a temporary name beside `OUT` and renamed when complete,
//! so an interrupted conversion leaves no half folder that looks whole; `OUT` must not
//! exist (or be an empty folder): nothing is overwritten.

use std::path::{Path, PathBuf};

use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;

use crate::io::image_files::depth_to_png16;
use crate::io::orbslam_settings::{Calibration, OrbSettings, OrbSlamSettings};
use crate::io::sequence::{FrameImages, SensorKind, Sequence};
use crate::io::IoError;

/// The depth scale of the TUM layout: raw units per metre.
const TUM_DEPTH_SCALE: f64 = 5000.0;

/// The layouts a sequence converts to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layout {
    /// TUM RGB-D, for RGB-D sequences.
    Tum,
    /// KITTI odometry, for stereo pairs.
    Kitti,
}

impl Layout {
    fn folders(self) -> [&'static str; 2] {
        match self {
            Layout::Tum => ["rgb", "depth"],
            Layout::Kitti => ["image_0", "image_1"],
        }
    }

    fn sensor(self) -> SensorKind {
        match self {
            Layout::Tum => SensorKind::Rgbd,
            Layout::Kitti => SensorKind::Stereo,
        }
    }
}

/// Checks that `out` can be written: absent or an empty folder, its parent writable.
/// Returns the temporary folder (with the layout's image folders) the conversion
/// writes into.
pub fn prepare(out: &Path, layout: Layout) -> Result<PathBuf, IoError> {
    if out.exists() {
        let empty = out.is_dir()
            && std::fs::read_dir(out)
                .map(|mut d| d.next().is_none())
                .unwrap_or(false);
        if !empty {
            return Err(IoError::invalid(
                out,
                "exists and is not an empty folder: give a new output folder",
            ));
        }
    }
    let name = out
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "converted".into());
    let parent = out
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let partial = parent.join(format!(".{name}.partial-{}", std::process::id()));
    // A new folder, never one that is there already: only what this conversion made is
    // removed when it fails.
    let folders = std::iter::once(partial.clone()).chain(layout.folders().map(|f| partial.join(f)));
    for dir in folders {
        std::fs::create_dir(&dir).map_err(|source| IoError::Write { path: dir, source })?;
    }
    Ok(partial)
}

/// Writes frames `0..frames` of `sequence` in `layout` at `out` (see the module doc);
/// returns the number of frames written.
pub fn convert(
    sequence: &dyn Sequence,
    out: &Path,
    frames: usize,
    layout: Layout,
    progress: bool,
) -> Result<usize, IoError> {
    if sequence.sensor() != layout.sensor() {
        let (what, other) = match layout {
            Layout::Tum => ("stereo pairs", "--to kitti"),
            Layout::Kitti => ("RGB-D frames", "--to tum"),
        };
        return Err(IoError::invalid(
            out,
            format!("{} holds {what}: convert it {other}", sequence.name()),
        ));
    }
    let partial = prepare(out, layout)?;
    let result = write_frames(sequence, &partial, frames, layout, progress).and_then(|stamps| {
        write_lists(sequence.calibration(), &partial, &stamps, layout)?;
        if out.exists() {
            std::fs::remove_dir(out).map_err(|source| IoError::Write {
                path: out.to_path_buf(),
                source,
            })?;
        }
        std::fs::rename(&partial, out).map_err(|source| IoError::Write {
            path: out.to_path_buf(),
            source,
        })?;
        Ok(stamps.len())
    });
    if result.is_err() {
        // Only the temporary folder this conversion made goes.
        let _ = std::fs::remove_dir_all(&partial);
    }
    result
}

/// The file name of frame `index` stamped `stamp` in `layout`.
fn file_name(layout: Layout, index: usize, stamp: f64) -> String {
    match layout {
        Layout::Tum => format!("{stamp:.6}.png"),
        Layout::Kitti => format!("{index:06}.png"),
    }
}

/// Decodes and writes the frames in parallel; their stamps in frame order.
fn write_frames(
    sequence: &dyn Sequence,
    dir: &Path,
    frames: usize,
    layout: Layout,
    progress: bool,
) -> Result<Vec<f64>, IoError> {
    let bar = if progress {
        ProgressBar::new(frames as u64)
    } else {
        ProgressBar::hidden()
    };
    bar.set_style(
        ProgressStyle::with_template("convert {bar:40} {pos}/{len} frames ({eta} left)")
            .expect("valid template"),
    );
    let [first, second] = layout.folders();
    let stamps = (0..frames)
        .into_par_iter()
        .map(|index| {
            let frame = sequence.load(index)?;
            let name = file_name(layout, index, frame.timestamp);
            let (a, b) = (dir.join(first).join(&name), dir.join(second).join(&name));
            let saved = match frame.images {
                FrameImages::Rgbd { rgb, depth } => {
                    rgb.save(&a).map_err(|e| (a, e)).and_then(|()| {
                        depth_to_png16(&depth, TUM_DEPTH_SCALE)
                            .save(&b)
                            .map_err(|e| (b, e))
                    })
                }
                FrameImages::Stereo { left, right } => left
                    .save(&a)
                    .map_err(|e| (a, e))
                    .and_then(|()| right.save(&b).map_err(|e| (b, e))),
            };
            saved.map_err(|(path, e)| IoError::Write {
                path,
                source: std::io::Error::other(e),
            })?;
            bar.inc(1);
            Ok(frame.timestamp)
        })
        .collect::<Result<Vec<_>, IoError>>();
    bar.finish_and_clear();
    stamps
}

/// The lists and the calibration: `rgb.txt`, `depth.txt` (one stamp for both: the
/// pair's colour stamp) and `calibration.yaml`; or `times.txt` and `calib.txt`.
fn write_lists(
    calibration: Option<&Calibration>,
    dir: &Path,
    stamps: &[f64],
    layout: Layout,
) -> Result<(), IoError> {
    let write = |name: &str, text: &str| {
        let path = dir.join(name);
        std::fs::write(&path, text).map_err(|source| IoError::Write { path, source })
    };
    match layout {
        Layout::Tum => {
            let mut rgb = String::from("# color images\n# timestamp filename\n");
            let mut depth = String::from("# depth maps\n# timestamp filename\n");
            for (index, stamp) in stamps.iter().enumerate() {
                let name = file_name(layout, index, *stamp);
                rgb += &format!("{stamp:.6} rgb/{name}\n");
                depth += &format!("{stamp:.6} depth/{name}\n");
            }
            write("rgb.txt", &rgb)?;
            write("depth.txt", &depth)?;
            if let Some(calibration) = calibration {
                let mut calibration = calibration.clone();
                calibration.depth_scale = Some(TUM_DEPTH_SCALE);
                write(
                    "calibration.yaml",
                    &OrbSlamSettings::to_yaml(&calibration, &OrbSettings::default()),
                )?;
            }
        }
        Layout::Kitti => {
            let times: String = stamps.iter().map(|t| format!("{t:e}\n")).collect();
            write("times.txt", &times)?;
            let Some(c) = calibration else {
                return Err(IoError::invalid(
                    dir,
                    "a stereo pair without a calibration: calib.txt cannot be written",
                ));
            };
            let k = &c.camera;
            let projection = |tx: f64| {
                format!(
                    "{:e} 0 {:e} {:e} 0 {:e} {:e} 0 0 0 1 0",
                    k.fx, k.cx, tx, k.fy, k.cy
                )
            };
            let (left, right) = (projection(0.0), projection(-c.bf.unwrap_or(0.0)));
            write(
                "calib.txt",
                &format!("P0: {left}\nP1: {right}\nP2: {left}\nP3: {right}\n"),
            )?;
        }
    }
    Ok(())
}
