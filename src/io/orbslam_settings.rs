//! ORB-SLAM2 settings files (OpenCV FileStorage YAML, `%YAML:1.0`), so users can
//! reuse their calibration: `Camera.fx/fy/cx/cy/k1/k2/p1/p2/k3`, `Camera.width/height`,
//! `Camera.bf`, `Camera.fps`, `DepthMapFactor`, `ThDepth`, `ORBextractor.*`.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::errors::{read_text, IoError};
use crate::geometry::camera::PinholeCamera;

/// A camera calibration: intrinsics plus what RGB-D and stereo need.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Calibration {
    /// The camera (`Camera.fx`, …).
    pub camera: PinholeCamera,
    /// Stereo baseline times fx, in pixel·metres (`Camera.bf`); for RGB-D the virtual baseline.
    pub bf: Option<f64>,
    /// Raw depth units per metre (`DepthMapFactor`, 5000 for TUM).
    pub depth_scale: Option<f64>,
    /// Close/far threshold in baselines (`ThDepth`).
    pub th_depth: Option<f64>,
    /// `Camera.fps`.
    pub fps: Option<f64>,
}

/// The ORB extractor settings of an ORB-SLAM2 file (absent keys stay `None`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct OrbSettings {
    /// `ORBextractor.nFeatures`.
    pub n_features: Option<usize>,
    /// `ORBextractor.scaleFactor`.
    pub scale_factor: Option<f64>,
    /// `ORBextractor.nLevels`.
    pub n_levels: Option<usize>,
    /// `ORBextractor.iniThFAST`.
    pub ini_th_fast: Option<u8>,
    /// `ORBextractor.minThFAST`.
    pub min_th_fast: Option<u8>,
}

/// Everything dopslam reads from an ORB-SLAM2 settings file.
#[derive(Debug, Clone, PartialEq)]
pub struct OrbSlamSettings {
    /// The camera and depth values.
    pub calibration: Calibration,
    /// The ORB values.
    pub orb: OrbSettings,
    /// Every scalar key of the file, in file order.
    pub keys: Vec<String>,
}

/// The keys of an ORB-SLAM2 (RGB-D or stereo) settings file that set something here.
pub const APPLIED_KEYS: [&str; 20] = [
    "Camera.fx",
    "Camera.fy",
    "Camera.cx",
    "Camera.cy",
    "Camera.k1",
    "Camera.k2",
    "Camera.p1",
    "Camera.p2",
    "Camera.k3",
    "Camera.width",
    "Camera.height",
    "Camera.fps",
    "Camera.bf",
    "ThDepth",
    "DepthMapFactor",
    "ORBextractor.nFeatures",
    "ORBextractor.scaleFactor",
    "ORBextractor.nLevels",
    "ORBextractor.iniThFAST",
    "ORBextractor.minThFAST",
];

/// Whether an ORB-SLAM2 key is known to have no meaning here: the viewer's, and
/// `Camera.RGB` (ORB-SLAM2's channel order of images in memory after `cv::imread`;
/// dopslam reads image files in the order they store).
pub fn has_no_meaning_here(key: &str) -> bool {
    key.starts_with("Viewer.") || key == "Camera.RGB"
}

impl OrbSlamSettings {
    /// The file's keys sorted into those applied, those known to have no meaning here,
    /// and unknown ones.
    pub fn sort_keys(&self) -> (Vec<String>, Vec<String>, Vec<String>) {
        let (mut applied, mut no_meaning, mut unknown) = (Vec::new(), Vec::new(), Vec::new());
        for key in &self.keys {
            if APPLIED_KEYS.contains(&key.as_str()) {
                applied.push(key.clone());
            } else if has_no_meaning_here(key) {
                no_meaning.push(key.clone());
            } else {
                unknown.push(key.clone());
            }
        }
        (applied, no_meaning, unknown)
    }
}

/// The scalar `key: value` lines of an OpenCV YAML file: value and line number by key.
type ScalarMap = BTreeMap<String, (String, usize)>;

/// Reads the scalar `key: value` lines of an OpenCV YAML file, and every top-level
/// key in file order. Matrices
/// (`!!opencv-matrix` blocks) and nested maps are skipped; a key given twice is an
/// error naming both lines.
fn read_scalars(path: &Path) -> Result<(ScalarMap, Vec<String>), IoError> {
    let text = read_text(path)?;
    let mut scalars: BTreeMap<String, (String, usize)> = BTreeMap::new();
    let mut keys = Vec::new();
    let mut seen: BTreeMap<String, usize> = BTreeMap::new();
    for (index, raw) in text.lines().enumerate() {
        let line = raw.split('#').next().unwrap_or_default();
        if line.trim().is_empty()
            || line.starts_with('%')
            || line.trim() == "---"
            || line.starts_with([' ', '\t'])
        {
            continue;
        }
        let Some((key, value)) = line.split_once(':') else {
            return Err(IoError::parse(
                path,
                index + 1,
                format!("expected `key: value`, found {:?}", line.trim()),
            ));
        };
        let key = key.trim().to_owned();
        if let Some(first) = seen.insert(key.clone(), index + 1) {
            return Err(IoError::parse(
                path,
                index + 1,
                format!("{key} is given twice (first on line {first}); keep one"),
            ));
        }
        keys.push(key.clone());
        let value = value.trim();
        if value.is_empty() || value.starts_with("!!") {
            continue;
        }
        scalars.insert(key, (value.trim_matches('"').to_owned(), index + 1));
    }
    Ok((scalars, keys))
}

impl OrbSlamSettings {
    /// Reads an ORB-SLAM2 settings file. `Camera.fx`, `fy`, `cx`, `cy` are required;
    /// the image size defaults to 640x480 when absent.
    pub fn read(path: &Path) -> Result<Self, IoError> {
        let (scalars, keys) = read_scalars(path)?;
        let file = Scalars { path, scalars };
        let calibration = file.calibration()?;
        let orb = OrbSettings {
            n_features: file
                .count("ORBextractor.nFeatures", 1e6)?
                .map(|v| v as usize),
            scale_factor: file.number("ORBextractor.scaleFactor")?,
            n_levels: file
                .count("ORBextractor.nLevels", 32.0)?
                .map(|v| v as usize),
            ini_th_fast: file
                .count("ORBextractor.iniThFAST", 255.0)?
                .map(|v| v as u8),
            min_th_fast: file
                .count("ORBextractor.minThFAST", 255.0)?
                .map(|v| v as u8),
        };
        Ok(Self {
            calibration,
            orb,
            keys,
        })
    }

    /// Writes an ORB-SLAM2-style settings file for a calibration (used by `synth`, so
    /// ORB-SLAM2 itself can run the generated sequences).
    pub fn to_yaml(calibration: &Calibration, orb: &OrbSettings) -> String {
        let c = &calibration.camera;
        let mut out = String::from("%YAML:1.0\n\n# Written by dopslam\n");
        let mut line = |key: &str, value: String| out.push_str(&format!("{key}: {value}\n"));
        for (key, value) in [
            ("Camera.fx", c.fx),
            ("Camera.fy", c.fy),
            ("Camera.cx", c.cx),
            ("Camera.cy", c.cy),
        ] {
            line(key, format!("{value:?}"));
        }
        for (key, value) in [
            "Camera.k1",
            "Camera.k2",
            "Camera.p1",
            "Camera.p2",
            "Camera.k3",
        ]
        .iter()
        .zip(c.distortion)
        {
            line(key, format!("{value:?}"));
        }
        if !c.rational.iter().all(|&k| k == 0.0) {
            for (key, value) in ["Camera.k4", "Camera.k5", "Camera.k6"]
                .iter()
                .zip(c.rational)
            {
                line(key, format!("{value:?}"));
            }
        }
        line("Camera.width", c.width.to_string());
        line("Camera.height", c.height.to_string());
        line(
            "Camera.fps",
            format!("{:?}", calibration.fps.unwrap_or(30.0)),
        );
        if let Some(bf) = calibration.bf {
            line("Camera.bf", format!("{bf:?}"));
        }
        line("Camera.RGB", "1".into());
        if let Some(th) = calibration.th_depth {
            line("ThDepth", format!("{th:?}"));
        }
        if let Some(scale) = calibration.depth_scale {
            line("DepthMapFactor", format!("{scale:?}"));
        }
        line(
            "ORBextractor.nFeatures",
            orb.n_features.unwrap_or(1000).to_string(),
        );
        line(
            "ORBextractor.scaleFactor",
            format!("{:?}", orb.scale_factor.unwrap_or(1.2)),
        );
        line(
            "ORBextractor.nLevels",
            orb.n_levels.unwrap_or(8).to_string(),
        );
        line(
            "ORBextractor.iniThFAST",
            orb.ini_th_fast.unwrap_or(20).to_string(),
        );
        line(
            "ORBextractor.minThFAST",
            orb.min_th_fast.unwrap_or(7).to_string(),
        );
        out
    }
}

/// A settings file's scalar keys (value and line), read as numbers with errors that
/// name the file, the key and the line.
struct Scalars<'a> {
    path: &'a Path,
    scalars: ScalarMap,
}

impl Scalars<'_> {
    /// The number at `key`, when the file has it.
    fn number(&self, key: &str) -> Result<Option<f64>, IoError> {
        match self.scalars.get(key) {
            None => Ok(None),
            Some((value, line)) => value
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .map(Some)
                .ok_or_else(|| {
                    IoError::parse(
                        self.path,
                        *line,
                        format!("{key} must be a number, found {value:?}"),
                    )
                }),
        }
    }

    /// The number at `key`, which the file must have.
    fn required(&self, key: &str) -> Result<f64, IoError> {
        self.number(key)?.ok_or_else(|| {
            IoError::invalid(
                self.path,
                format!("missing {key} (an ORB-SLAM2 settings file needs Camera.fx, fy, cx, cy)"),
            )
        })
    }

    /// A whole number from 0 to `max` at `key`, when the file has it.
    fn count(&self, key: &str, max: f64) -> Result<Option<f64>, IoError> {
        match self.number(key)? {
            Some(v) if v.fract() != 0.0 || v < 0.0 || v > max => Err(IoError::invalid(
                self.path,
                format!("{key} must be a whole number from 0 to {max}, got {v}"),
            )),
            other => Ok(other),
        }
    }

    /// The camera: ORB-SLAM2's `Camera.*` keys.
    fn camera(&self) -> Result<PinholeCamera, IoError> {
        let or_zero = |key: &str| -> Result<f64, IoError> { Ok(self.number(key)?.unwrap_or(0.0)) };
        let camera = PinholeCamera {
            fx: self.required("Camera.fx")?,
            fy: self.required("Camera.fy")?,
            cx: self.required("Camera.cx")?,
            cy: self.required("Camera.cy")?,
            width: self.number("Camera.width")?.unwrap_or(640.0) as u32,
            height: self.number("Camera.height")?.unwrap_or(480.0) as u32,
            distortion: [
                or_zero("Camera.k1")?,
                or_zero("Camera.k2")?,
                or_zero("Camera.p1")?,
                or_zero("Camera.p2")?,
                or_zero("Camera.k3")?,
            ],
            // Not ORB-SLAM2's: the rational model's denominator, which `dopslam convert`
            // writes for a lens that has one (an Azure Kinect's).
            rational: [
                or_zero("Camera.k4")?,
                or_zero("Camera.k5")?,
                or_zero("Camera.k6")?,
            ],
        };
        camera
            .validate()
            .map_err(|message| IoError::invalid(self.path, message.to_string()))?;
        Ok(camera)
    }

    /// The camera, its baseline, depth scale, `ThDepth` and frame rate, checked.
    fn calibration(&self) -> Result<Calibration, IoError> {
        let calibration = Calibration {
            camera: self.camera()?,
            bf: self.number("Camera.bf")?,
            depth_scale: self.number("DepthMapFactor")?,
            th_depth: self.number("ThDepth")?,
            fps: self.number("Camera.fps")?,
        };
        if let Some(scale) = calibration.depth_scale {
            if scale <= 0.0 {
                return Err(IoError::invalid(
                    self.path,
                    format!("DepthMapFactor must be positive, got {scale}"),
                ));
            }
        }
        for (key, value, valid) in [
            ("Camera.bf", calibration.bf, "positive"),
            ("ThDepth", calibration.th_depth, "positive"),
            ("Camera.fps", calibration.fps, "positive"),
        ] {
            if value.is_some_and(|v| v <= 0.0) {
                return Err(IoError::invalid(
                    self.path,
                    format!("{key} must be {valid}, got {}", value.unwrap_or_default()),
                ));
            }
        }
        Ok(calibration)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn roundtrip_and_errors() {
        let dir = std::env::temp_dir().join(format!("dopslam-yaml-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let calibration = Calibration {
            camera: PinholeCamera::tum_fr3(),
            bf: Some(40.0),
            depth_scale: Some(5000.0),
            th_depth: Some(40.0),
            fps: Some(30.0),
        };
        let orb = OrbSettings {
            n_features: Some(1500),
            ..Default::default()
        };
        let path = dir.join("cam.yaml");
        std::fs::write(&path, OrbSlamSettings::to_yaml(&calibration, &orb)).unwrap();
        let back = OrbSlamSettings::read(&path).unwrap();
        assert_eq!(back.calibration, calibration);
        assert_eq!(back.orb.n_features, Some(1500));
        assert_eq!(back.orb.scale_factor, Some(1.2));

        std::fs::write(&path, "%YAML:1.0\nCamera.fx: 500\nCamera.fy: abc\n").unwrap();
        let message = OrbSlamSettings::read(&path).unwrap_err().to_string();
        assert!(
            message.contains("cam.yaml:3") && message.contains("Camera.fy"),
            "{message}"
        );

        std::fs::write(&path, "%YAML:1.0\nCamera.fx: 500\n").unwrap();
        let message = OrbSlamSettings::read(&path).unwrap_err().to_string();
        assert!(message.contains("missing Camera.fy"), "{message}");
        std::fs::remove_dir_all(dir).unwrap();
    }
}
