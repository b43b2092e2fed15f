//! The KITTI odometry stereo layout: `sequences/NN/{image_0,image_1}/NNNNNN.png`,
//! `calib.txt` (projection matrices `P0:` … `P3:`), `times.txt`, and ground truth in
//! `poses/NN.txt` two levels up (or given explicitly).

use std::path::{Path, PathBuf};

use image::GrayImage;

use super::errors::read_text;
use super::file_list::split_fields;
use super::image_files::read_gray;
use super::orbslam_settings::Calibration;
use super::sequence::{Frame, FrameImages, SensorKind, Sequence};
use super::trajectory::read_times;
use super::{IoError, Trajectory};
use crate::geometry::camera::PinholeCamera;

/// A KITTI odometry stereo sequence; frames load lazily.
#[derive(Debug)]
pub struct KittiSequence {
    name: String,
    root: PathBuf,
    times: Vec<f64>,
    calibration: Calibration,
    ground_truth: Option<Trajectory>,
}

/// Reads `calib.txt`: fx, fy, cx, cy from `P0`, and `bf = -P1[0,3]`.
pub fn read_kitti_calibration(
    path: &Path,
    width: u32,
    height: u32,
) -> Result<Calibration, IoError> {
    let text = read_text(path)?;
    let mut p0 = None;
    let mut p1 = None;
    for (index, line) in text.lines().enumerate() {
        let Some((key, rest)) = line.split_once(':') else {
            continue;
        };
        let key = key.trim();
        let values: Result<Vec<f64>, _> = split_fields(rest).map(str::parse::<f64>).collect();
        let values = values
            .map_err(|_| IoError::parse(path, index + 1, format!("{key}: expected 12 numbers")))?;
        if values.len() != 12 && (key == "P0" || key == "P1") {
            return Err(IoError::parse(
                path,
                index + 1,
                format!("{key}: expected 12 numbers, found {}", values.len()),
            ));
        }
        match key {
            "P0" => p0 = Some(values),
            "P1" => p1 = Some(values),
            _ => {}
        }
    }
    let p0 =
        p0.ok_or_else(|| IoError::invalid(path, "missing the line P0: (left camera projection)"))?;
    let p1 =
        p1.ok_or_else(|| IoError::invalid(path, "missing the line P1: (right camera projection)"))?;
    let camera = PinholeCamera {
        fx: p0[0],
        fy: p0[5],
        cx: p0[2],
        cy: p0[6],
        width,
        height,
        distortion: [0.0; 5],
        rational: [0.0; 3],
    };
    camera
        .validate()
        .map_err(|message| IoError::invalid(path, message.to_string()))?;
    let bf = -p1[3];
    if bf <= 0.0 {
        return Err(IoError::invalid(
            path,
            format!("P1 gives a non-positive baseline times fx ({bf})"),
        ));
    }
    Ok(Calibration {
        camera,
        bf: Some(bf),
        depth_scale: None,
        th_depth: Some(35.0),
        fps: Some(10.0),
    })
}

/// A rectified stereo pair in grey; `Err` naming the right image when the two differ
/// in size.
pub fn read_pair(left: &Path, right: &Path) -> Result<(GrayImage, GrayImage), IoError> {
    let (left_image, right_image) = (read_gray(left)?, read_gray(right)?);
    if left_image.dimensions() != right_image.dimensions() {
        return Err(IoError::invalid(
            right,
            format!(
                "is {}x{} but its left image {} is {}x{}: a rectified pair has one size",
                right_image.width(),
                right_image.height(),
                left.display(),
                left_image.width(),
                left_image.height()
            ),
        ));
    }
    Ok((left_image, right_image))
}

/// How many `.png` files a folder holds.
fn count_pngs(dir: &Path) -> Result<usize, IoError> {
    let entries = std::fs::read_dir(dir).map_err(|_| IoError::Missing {
        path: dir.to_path_buf(),
        what: "image folder (KITTI layout: image_0/ left, image_1/ right, NNNNNN.png)".into(),
    })?;
    Ok(entries
        .filter_map(Result::ok)
        .filter(|e| e.path().extension().is_some_and(|x| x == "png"))
        .count())
}

/// The frame times in `times.txt` at `times_path`: at least one, in time order.
fn ordered_times(times_path: &Path) -> Result<Vec<f64>, IoError> {
    let times = read_times(times_path)?;
    if times.is_empty() {
        return Err(IoError::invalid(times_path, "lists no frame times"));
    }
    if let Some(k) = (1..times.len()).find(|&k| times[k] < times[k - 1]) {
        return Err(IoError::invalid(
            times_path,
            format!(
                "time {} on line {} comes before {} on the line above: KITTI frames are numbered in time order (line k is image k-1), so the order decides which image is which",
                times[k],
                k + 1,
                times[k - 1]
            ),
        ));
    }
    Ok(times)
}

/// The KITTI poses at `path`, one per frame, timed by `times`.
fn ground_truth_for(path: &Path, times: &[f64]) -> Result<Trajectory, IoError> {
    let mut gt = Trajectory::read_kitti(path)?;
    if gt.len() != times.len() {
        return Err(IoError::invalid(
            path,
            format!(
                "holds {} poses but times.txt has {} frames",
                gt.len(),
                times.len()
            ),
        ));
    }
    gt.timestamps = times.to_vec();
    Ok(gt)
}

impl KittiSequence {
    /// Opens a KITTI odometry sequence folder. Ground truth comes from `ground_truth`
    /// when given, else from `../../poses/<name>.txt` when that file exists.
    pub fn open(root: &Path, ground_truth: Option<&Path>) -> Result<Self, IoError> {
        if !root.is_dir() {
            return Err(IoError::Missing {
                path: root.to_path_buf(),
                what: "sequence folder (KITTI layout: image_0/, image_1/, calib.txt, times.txt)"
                    .into(),
            });
        }
        let name = root
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "sequence".into());
        let times_path = root.join("times.txt");
        let times = ordered_times(&times_path)?;
        let (left, right) = (
            count_pngs(&root.join("image_0"))?,
            count_pngs(&root.join("image_1"))?,
        );
        if right < left {
            return Err(IoError::invalid(
                root.join("image_1"),
                format!("holds {right} right images but image_0 holds {left} left ones: every left image needs its right image (NNNNNN.png in both)"),
            ));
        }
        if left < times.len() {
            return Err(IoError::invalid(
                &times_path,
                format!(
                    "lists {} frames but image_0 holds {left} images",
                    times.len()
                ),
            ));
        }
        let first = root.join("image_0").join(format!("{:06}.png", 0));
        let (width, height) = image::image_dimensions(&first).map_err(|e| IoError::Image {
            path: first.clone(),
            message: e.to_string(),
        })?;
        let calibration = read_kitti_calibration(&root.join("calib.txt"), width, height)?;
        let gt_path = ground_truth.map(Path::to_path_buf).or_else(|| {
            let candidate = root
                .parent()?
                .parent()?
                .join("poses")
                .join(format!("{name}.txt"));
            candidate.exists().then_some(candidate)
        });
        let ground_truth = gt_path
            .map(|path| ground_truth_for(&path, &times))
            .transpose()?;
        Ok(Self {
            name,
            root: root.to_path_buf(),
            times,
            calibration,
            ground_truth,
        })
    }
}

impl Sequence for KittiSequence {
    fn name(&self) -> &str {
        &self.name
    }

    fn sensor(&self) -> SensorKind {
        SensorKind::Stereo
    }

    fn len(&self) -> usize {
        self.times.len()
    }

    fn timestamp(&self, index: usize) -> f64 {
        self.times[index]
    }

    fn load(&self, index: usize) -> Result<Frame, IoError> {
        let file = format!("{index:06}.png");
        let (left, right) = read_pair(
            &self.root.join("image_0").join(&file),
            &self.root.join("image_1").join(&file),
        )?;
        Ok(Frame {
            index,
            timestamp: self.times[index],
            images: FrameImages::Stereo { left, right },
        })
    }

    fn ground_truth(&self) -> Option<&Trajectory> {
        self.ground_truth.as_ref()
    }

    fn calibration(&self) -> Option<&Calibration> {
        Some(&self.calibration)
    }
}
