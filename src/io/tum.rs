//! The TUM RGB-D layout (also used by the Bonn RGB-D Dynamic dataset and by
//! `dopslam synth`): `rgb.txt`, `depth.txt`, optional `groundtruth.txt`, images under
//! `rgb/` and `depth/`, 16-bit depth with a scale of 5000 per metre.
//!
//! Colour and depth are paired either by an ORB-SLAM-style association file
//! (`t_rgb rgb/… t_depth depth/…`) or by TUM's greedy nearest-timestamp rule with a
//! tolerance (0.02 s, as `associate.py`).

use std::path::{Path, PathBuf};

use super::file_list::{associate_greedy, read_file_list};
use super::image_files::{read_depth, read_rgb, DepthImage};
use super::orbslam_settings::{Calibration, OrbSlamSettings};
use super::sequence::{Frame, FrameImages, SensorKind, Sequence};
use super::{IoError, Trajectory};
use crate::geometry::camera::PinholeCamera;

/// How to open a TUM-layout folder.
#[derive(Debug, Clone)]
pub struct TumOptions {
    /// Raw depth units per metre; `None` takes the calibration file's, else 5000.
    pub depth_scale: Option<f64>,
    /// The association tolerance in seconds for pairing rgb.txt with depth.txt.
    pub max_difference: f64,
    /// An ORB-SLAM-style association file to use instead of pairing by timestamp.
    pub association_file: Option<PathBuf>,
}

impl Default for TumOptions {
    fn default() -> Self {
        Self {
            depth_scale: None,
            max_difference: 0.02,
            association_file: None,
        }
    }
}

/// One paired RGB-D frame of the index.
#[derive(Debug, Clone, PartialEq)]
pub struct RgbdEntry {
    /// The colour image's time, seconds.
    pub rgb_timestamp: f64,
    /// Its file.
    pub rgb_path: PathBuf,
    /// The depth map's time, seconds.
    pub depth_timestamp: f64,
    /// Its file.
    pub depth_path: PathBuf,
}

/// A TUM-layout RGB-D sequence; frames load lazily.
#[derive(Debug)]
pub struct TumSequence {
    name: String,
    root: PathBuf,
    entries: Vec<RgbdEntry>,
    depth_scale: f64,
    ground_truth: Option<Trajectory>,
    calibration: Option<Calibration>,
    /// How many rgb.txt and depth.txt lines there were (for reporting the pairing).
    pub listed: (usize, usize),
}

/// The file names a calibration may have in a sequence folder (synth writes the first).
const CALIBRATION_FILES: [&str; 2] = ["calibration.yaml", "camera.yaml"];

/// The intrinsics TUM publishes for the freiburg1/2/3 sensors, chosen by folder name
/// (fr1 and fr2 are distorted; their ORB-SLAM2 settings files carry the coefficients).
pub fn tum_calibration_for_name(name: &str) -> Option<Calibration> {
    let camera = if name.contains("freiburg1") || name.contains("fr1") {
        PinholeCamera {
            fx: 517.306408,
            fy: 516.469215,
            cx: 318.643040,
            cy: 255.313989,
            width: 640,
            height: 480,
            distortion: [0.262383, -0.953104, -0.005358, 0.002628, 1.163314],
            rational: [0.0; 3],
        }
    } else if name.contains("freiburg2") || name.contains("fr2") {
        PinholeCamera {
            fx: 520.908620,
            fy: 521.007327,
            cx: 325.141442,
            cy: 249.701764,
            width: 640,
            height: 480,
            distortion: [0.231222, -0.784899, -0.003257, -0.000105, 0.917205],
            rational: [0.0; 3],
        }
    } else if name.contains("freiburg3") || name.contains("fr3") {
        PinholeCamera::tum_fr3()
    } else {
        return None;
    };
    Some(Calibration {
        camera,
        bf: Some(40.0),
        depth_scale: Some(5000.0),
        th_depth: Some(40.0),
        fps: Some(30.0),
    })
}

impl TumSequence {
    /// Opens a TUM-layout folder.
    pub fn open(root: &Path, options: &TumOptions) -> Result<Self, IoError> {
        if !root.is_dir() {
            return Err(IoError::Missing {
                path: root.to_path_buf(),
                what: "sequence folder (TUM layout: rgb.txt, depth.txt, rgb/, depth/)".into(),
            });
        }
        let name = root
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "sequence".into());
        let (entries, listed) = match &options.association_file {
            Some(file) => {
                let entries = read_association_file(root, file)?;
                let n = entries.len();
                (entries, (n, n))
            }
            None => pair_by_timestamp(root, options.max_difference)?,
        };
        if entries.is_empty() && listed.0 > 0 && listed.1 > 0 {
            return Err(IoError::invalid(
                root,
                format!(
                    "none of the {} colour images in rgb.txt has a depth map in depth.txt within {} s: the two lists' timestamps do not match (raise [dataset] max_difference, or give an association file)",
                    listed.0, options.max_difference
                ),
            ));
        }
        let gt_path = root.join("groundtruth.txt");
        let ground_truth = if gt_path.exists() {
            Some(Trajectory::read_tum(&gt_path)?)
        } else {
            None
        };
        let calibration = match CALIBRATION_FILES
            .iter()
            .map(|f| root.join(f))
            .find(|p| p.exists())
        {
            Some(path) => Some(OrbSlamSettings::read(&path)?.calibration),
            None => tum_calibration_for_name(&name),
        };
        let depth_scale = options
            .depth_scale
            .or(calibration.as_ref().and_then(|c| c.depth_scale))
            .unwrap_or(5000.0);
        if !(depth_scale.is_finite() && depth_scale > 0.0) {
            return Err(IoError::invalid(
                root,
                format!("depth scale must be positive, got {depth_scale}"),
            ));
        }
        Ok(Self {
            name,
            root: root.to_path_buf(),
            entries,
            depth_scale,
            ground_truth,
            calibration,
            listed,
        })
    }

    /// The paired frames.
    pub fn entries(&self) -> &[RgbdEntry] {
        &self.entries
    }

    /// The sequence's folder.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// Raw depth units per metre.
    pub fn depth_scale(&self) -> f64 {
        self.depth_scale
    }
}

/// Pairs `rgb.txt` and `depth.txt` with TUM's greedy rule.
fn pair_by_timestamp(
    root: &Path,
    max_difference: f64,
) -> Result<(Vec<RgbdEntry>, (usize, usize)), IoError> {
    let rgb = read_file_list(&root.join("rgb.txt"), 1)?;
    let depth = read_file_list(&root.join("depth.txt"), 1)?;
    let rgb_t: Vec<f64> = rgb.iter().map(|e| e.timestamp).collect();
    let depth_t: Vec<f64> = depth.iter().map(|e| e.timestamp).collect();
    let pairs = associate_greedy(&rgb_t, &depth_t, 0.0, max_difference);
    let entries = pairs
        .into_iter()
        .map(|(i, j)| RgbdEntry {
            rgb_timestamp: rgb[i].timestamp,
            rgb_path: root.join(&rgb[i].fields[0]),
            depth_timestamp: depth[j].timestamp,
            depth_path: root.join(&depth[j].fields[0]),
        })
        .collect();
    Ok((entries, (rgb.len(), depth.len())))
}

/// Reads an ORB-SLAM-style association file: `t_rgb rgb_file t_depth depth_file`.
/// Relative image paths are taken from the sequence folder.
pub fn read_association_file(root: &Path, file: &Path) -> Result<Vec<RgbdEntry>, IoError> {
    let list = read_file_list(file, 3)?;
    list.into_iter()
        .map(|entry| {
            let depth_timestamp = entry.fields[1].parse::<f64>().map_err(|_| {
                IoError::parse(
                    file,
                    entry.line,
                    format!(
                        "expected the depth timestamp as the third field, found {:?}",
                        entry.fields[1]
                    ),
                )
            })?;
            Ok(RgbdEntry {
                rgb_timestamp: entry.timestamp,
                rgb_path: root.join(&entry.fields[0]),
                depth_timestamp,
                depth_path: root.join(&entry.fields[2]),
            })
        })
        .collect()
}

impl Sequence for TumSequence {
    fn name(&self) -> &str {
        &self.name
    }

    fn sensor(&self) -> SensorKind {
        SensorKind::Rgbd
    }

    fn len(&self) -> usize {
        self.entries.len()
    }

    fn timestamp(&self, index: usize) -> f64 {
        self.entries[index].rgb_timestamp
    }

    fn load(&self, index: usize) -> Result<Frame, IoError> {
        let entry = &self.entries[index];
        let rgb = read_rgb(&entry.rgb_path)?;
        let depth = read_depth(&entry.depth_path, self.depth_scale)?;
        if (rgb.width(), rgb.height()) != (depth.width, depth.height) {
            return Err(IoError::invalid(
                &entry.depth_path,
                format!(
                    "depth is {}x{} but its colour image is {}x{}",
                    depth.width,
                    depth.height,
                    rgb.width(),
                    rgb.height()
                ),
            ));
        }
        Ok(Frame {
            index,
            timestamp: entry.rgb_timestamp,
            images: FrameImages::Rgbd { rgb, depth },
        })
    }

    fn load_depth(&self, index: usize) -> Result<Option<DepthImage>, IoError> {
        let entry = &self.entries[index];
        read_depth(&entry.depth_path, self.depth_scale).map(Some)
    }

    fn ground_truth(&self) -> Option<&Trajectory> {
        self.ground_truth.as_ref()
    }

    fn calibration(&self) -> Option<&Calibration> {
        self.calibration.as_ref()
    }
}
