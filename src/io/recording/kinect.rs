//! Azure Kinect recordings (`k4arecorder`'s `.mkv`): the `COLOR` track (`MJPG`, `NV12`,
//! `YUY2` or `BGRA`) and the `DEPTH` track (`b16g`: 16-bit big-endian millimetres, in
//! the depth camera's own geometry), the device calibration from the
//! `calibration.json` attachment, stamps by the device's clock.
//!
//! Each frame is handed to the recording reader as the ROS message a bag would hold
//! (depth as a big-endian `16UC1` `sensor_msgs/Image`, `BGRA` as `bgra8`, `MJPG` as a
//! JPEG `CompressedImage`, `NV12` and `YUY2` converted to `rgb8`), so pairing,
//! decoding, depth registration and their errors are the bags' own.
//!
//! **Calibration.** `calibration.json` gives each camera's intrinsics for its whole
//! sensor, normalised by the sensor's size with \((0, 0)\) at the corner of the first
//! pixel, and its pose `Rt` as \(T_{c,w}\) (a point of the common frame into the
//! camera; metres). A recording's images are a binned and cropped part of the sensor,
//! so, as the SDK's `transformation_get_mode_specific_camera_calibration` does, with
//! the binned size \((W_b, H_b)\) and the crop's offset \((o_x, o_y)\):
//! \(f_x = \hat f_x W_b\), \(c_x = \hat c_x W_b - o_x - \tfrac12\) (and the same in
//! \(y\)). Depth modes: 320x288 (binned 512, crop 96x90), 640x576 (1024, 192x180),
//! 512x512 (512, none), 1024x1024 (1024, none). Colour: the 4:3 sensor binned to the
//! image's width, cropped in \(y\) to its height (a 16:9 calibration of early devices
//! is first brought to 4:3). The depth moves into the colour camera by
//! \(T_{colour,depth} = T_{colour,w}\, T_{depth,w}^{-1}\). The lenses are the SDK's
//! Brown-Conrady model, OpenCV's rational model (see
//! [`crate::geometry::camera::PinholeCamera::distort`]).

use std::borrow::Cow;
use std::fs::File;
use std::path::Path;

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde_json::Value;

use super::matroska::{self, Block, Scan, Track};
use super::{Catalog, Entry, Location, RecordedCameras, Store, Wire, COMPRESSED, IMAGE};
use crate::geometry::camera::ImageSize;
use crate::geometry::camera::PinholeCamera;
use crate::io::IoError;

/// How a track's frames become messages.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Format {
    Depth16,
    Bgra,
    Jpeg,
    Nv12,
    Yuy2,
}

impl Format {
    fn of(track: &Track) -> Option<Self> {
        if track.codec == "V_MJPEG" {
            return Some(Self::Jpeg);
        }
        match &track.fourcc()? {
            b"b16g" => Some(Self::Depth16),
            b"BGRA" => Some(Self::Bgra),
            b"MJPG" => Some(Self::Jpeg),
            b"NV12" => Some(Self::Nv12),
            b"YUY2" => Some(Self::Yuy2),
            _ => None,
        }
    }
}

/// How a read track's frames become messages: their layout and size.
#[derive(Debug, Clone, Copy)]
struct Layout {
    format: Format,
    width: u32,
    height: u32,
}

/// The frames of an Azure Kinect recording, read one at a time.
struct KinectStore {
    path: std::path::PathBuf,
    file: File,
    /// The tracks read.
    layouts: Vec<Layout>,
    /// Each frame's block, its track's index in `layouts`, and its stamp.
    frames: Vec<(Block, usize, f64)>,
}

/// A ROS 1 `std_msgs/Header` with `stamp` (seconds) and an empty frame.
fn header(out: &mut Vec<u8>, stamp: f64) {
    let sec = stamp.floor();
    let nsec = ((stamp - sec) * 1e9).round().min(999_999_999.0);
    for v in [0u32, sec as u32, nsec as u32, 0] {
        out.extend(v.to_le_bytes());
    }
}

fn string(out: &mut Vec<u8>, s: &[u8]) {
    out.extend((s.len() as u32).to_le_bytes());
    out.extend(s);
}

/// A ROS 1 `sensor_msgs/Image` up to its data, whose length is `len` (the data is to
/// be appended; the capacity is there).
fn image_header(
    stamp: f64,
    size: impl Into<ImageSize>,
    encoding: &str,
    big: bool,
    step: u32,
    len: usize,
) -> Vec<u8> {
    let ImageSize {
        width: w,
        height: h,
    } = size.into();
    let mut out = Vec::with_capacity(len + 64);
    header(&mut out, stamp);
    out.extend(h.to_le_bytes());
    out.extend(w.to_le_bytes());
    string(&mut out, encoding.as_bytes());
    out.push(u8::from(big));
    out.extend(step.to_le_bytes());
    out.extend((len as u32).to_le_bytes());
    out
}

/// BT.601 limited-range YCbCr to RGB, as libyuv (and so the SDK's playback) converts.
fn rgb(y: u8, u: u8, v: u8) -> [u8; 3] {
    let (y, u, v) = (
        1.164 * (y as f32 - 16.0),
        u as f32 - 128.0,
        v as f32 - 128.0,
    );
    let c = |x: f32| x.round().clamp(0.0, 255.0) as u8;
    [
        c(y + 1.596 * v),
        c(y - 0.813 * v - 0.391 * u),
        c(y + 2.018 * u),
    ]
}

/// `NV12` (a Y plane, then interleaved U, V at half resolution) or `YUY2` (Y0 U Y1 V
/// per two pixels) to packed RGB; `None` when the frame is short.
fn rgb_of_yuv(format: Format, w: usize, h: usize, data: &[u8]) -> Option<Vec<u8>> {
    let mut out = Vec::with_capacity(w * h * 3);
    match format {
        Format::Nv12 => {
            let (luma, chroma) = data.split_at_checked(w * h)?;
            if chroma.len() < w.div_ceil(2) * 2 * h.div_ceil(2) {
                return None;
            }
            for v in 0..h {
                for u in 0..w {
                    let c = (v / 2) * w.div_ceil(2) * 2 + (u / 2) * 2;
                    out.extend(rgb(luma[v * w + u], chroma[c], chroma[c + 1]));
                }
            }
        }
        _ => {
            if data.len() < w.div_ceil(2) * 4 * h {
                return None;
            }
            for v in 0..h {
                for u in 0..w {
                    let p = v * w.div_ceil(2) * 4 + (u / 2) * 4;
                    let y = data[p + if u % 2 == 0 { 0 } else { 2 }];
                    out.extend(rgb(y, data[p + 1], data[p + 3]));
                }
            }
        }
    }
    Some(out)
}

impl Store for KinectStore {
    fn read(&self, at: Location) -> Result<Cow<'_, [u8]>, IoError> {
        self.message(at).map(Cow::Owned)
    }
}

impl KinectStore {
    /// The message of frame `at.0`, made from its block.
    fn message(&self, at: Location) -> Result<Vec<u8>, IoError> {
        let Some(&(block, track, stamp)) = self.frames.get(at.0 as usize) else {
            return Err(IoError::invalid(&self.path, format!("no frame {}", at.0)));
        };
        let Layout {
            format,
            width: w,
            height: h,
        } = self.layouts[track];
        let read_error = |e| IoError::read(&self.path, e);
        let raw = |encoding, big, step| {
            // Read straight into the message (a frame is megabytes: no second copy).
            let mut out = image_header(stamp, (w, h), encoding, big, step, block.len as usize);
            let start = out.len();
            out.resize(start + block.len as usize, 0);
            matroska::read_block_into(&self.file, &block, &mut out[start..]).map_err(read_error)?;
            Ok(out)
        };
        let data = || matroska::read_block(&self.file, &block).map_err(read_error);
        match format {
            Format::Depth16 => raw("16UC1", true, w * 2),
            Format::Bgra => raw("bgra8", false, w * 4),
            Format::Jpeg => {
                let data = data()?;
                let mut out = Vec::with_capacity(data.len() + 32);
                header(&mut out, stamp);
                string(&mut out, b"jpeg");
                string(&mut out, &data);
                Ok(out)
            }
            Format::Nv12 | Format::Yuy2 => {
                let pixels =
                    rgb_of_yuv(format, w as usize, h as usize, &data()?).ok_or_else(|| {
                        IoError::Image {
                            path: self.path.clone(),
                            message: format!(
                                "the frame at byte {} is {} bytes, short for {w}x{h} {format:?}",
                                block.offset, block.len
                            ),
                        }
                    })?;
                let mut out = image_header(stamp, (w, h), "rgb8", false, w * 3, pixels.len());
                out.extend_from_slice(&pixels);
                Ok(out)
            }
        }
    }
}

/// Opens an Azure Kinect recording: its `COLOR` and `DEPTH` tracks as topics of a
/// [`Catalog`] whose cameras come from `calibration.json`.
pub fn open(path: &Path) -> Result<(Box<dyn Store>, Catalog), IoError> {
    let scan = matroska::scan(path)?;
    let mut catalog = Catalog::new(Wire::Ros1);
    catalog.warnings.extend(scan.warnings.iter().cloned());
    // The device clock: the SDK adds the start offset to every block's time.
    let offset_ns = scan
        .tag(0, "K4A_START_OFFSET_NS")
        .and_then(|v| v.trim().parse::<i64>().ok())
        .unwrap_or(0);
    let (mut layouts, mut frames, mut skipped) = (Vec::new(), Vec::new(), Vec::new());
    for track in &scan.tracks {
        let format = Format::of(track);
        let wanted = match (track.name.as_str(), format) {
            ("COLOR", Some(f)) => f != Format::Depth16,
            ("DEPTH", Some(f)) => f == Format::Depth16,
            ("COLOR" | "DEPTH", None) => {
                return Err(IoError::invalid(
                    path,
                    format!(
                        "track {}: codec {} ({}) is not read (MJPG, NV12, YUY2, BGRA colour; b16g depth)",
                        track.name,
                        track.codec,
                        track.fourcc().map_or_else(|| "no FOURCC".into(), |f| printable(&f))
                    ),
                ))
            }
            _ => false,
        };
        if !wanted || track.encoded {
            skipped.push(track.name.clone());
            continue;
        }
        let format = format.expect("wanted tracks have one");
        let msg_type = if format == Format::Jpeg {
            COMPRESSED
        } else {
            IMAGE
        };
        catalog.add_topic(track.number, &track.name, msg_type);
        layouts.push(Layout {
            format,
            width: track.width,
            height: track.height,
        });
        for block in scan.blocks.iter().filter(|b| b.track == track.number) {
            let stamp = (block.time_ns + offset_ns).max(0) as f64 * 1e-9;
            let at = Location(frames.len() as u64, 0);
            catalog.add_entry(track.number, Entry { stamp, at });
            frames.push((*block, layouts.len() - 1, stamp));
        }
    }
    catalog.recorded = Some(cameras(path, &scan, &skipped)?);
    let file = File::open(path).map_err(|e| IoError::read(path, e))?;
    Ok((
        Box::new(KinectStore {
            path: path.to_path_buf(),
            file,
            layouts,
            frames,
        }),
        catalog,
    ))
}

/// The colour and depth cameras of the recording's `calibration.json`, for its images'
/// sizes.
fn cameras(path: &Path, scan: &Scan, skipped: &[String]) -> Result<RecordedCameras, IoError> {
    let bad = |m: String| IoError::invalid(path, format!("calibration.json: {m}"));
    let named = scan
        .tag(0, "K4A_CALIBRATION_FILE")
        .unwrap_or("calibration.json");
    let Some((_, json)) = scan.attachments.iter().find(|(n, _)| n == named) else {
        return Err(IoError::invalid(
            path,
            format!("no {named} attachment: not an Azure Kinect recording (k4arecorder attaches the device calibration)"),
        ));
    };
    let json: Value = serde_json::from_slice(json).map_err(|e| bad(e.to_string()))?;
    let size = |name: &str| {
        scan.tracks
            .iter()
            .find(|t| t.name == name)
            .map(|t| (t.width, t.height))
            .ok_or_else(|| {
                IoError::invalid(
                    path,
                    format!("no {name} track (tracks: {})", track_names(scan)),
                )
            })
    };
    let (depth_size, colour_size) = (size("DEPTH")?, size("COLOR")?);
    let (depth, depth_pose) = camera(&json, "CALIBRATION_CameraLocationD0").map_err(bad)?;
    let (colour, colour_pose) = camera(&json, "CALIBRATION_CameraLocationPV0").map_err(bad)?;
    let depth = depth_mode(&depth, depth_size).map_err(bad)?;
    let colour = colour_mode(colour, colour_size).map_err(bad)?;
    let mut notes = vec![format!(
        "Azure Kinect recording: cameras from {named} (depth {}x{}, colour {}x{}), stamps by the device clock",
        depth_size.0, depth_size.1, colour_size.0, colour_size.1
    )];
    if !skipped.is_empty() {
        notes.push(format!("tracks not read: {}", skipped.join(", ")));
    }
    Ok(RecordedCameras {
        from: format!("the {named} attachment"),
        colour,
        depth,
        colour_from_depth: colour_pose * depth_pose.inverse(),
        notes,
    })
}

fn track_names(scan: &Scan) -> String {
    let names: Vec<&str> = scan.tracks.iter().map(|t| t.name.as_str()).collect();
    names.join(", ")
}

/// A camera of `calibration.json` for its whole sensor: intrinsics normalised by the
/// sensor's size (0 at the first pixel's corner), the sensor's size.
#[derive(Debug, Clone, Copy)]
struct SensorCamera {
    /// `cx, cy, fx, fy` normalised.
    centre_focal: [f64; 4],
    distortion: [f64; 5],
    rational: [f64; 3],
    sensor: (f64, f64),
}

fn numbers(v: &Value, key: &str, n: usize) -> Result<Vec<f64>, String> {
    let list = v
        .get(key)
        .and_then(Value::as_array)
        .ok_or_else(|| format!("{key} is missing"))?;
    let out: Vec<f64> = list.iter().filter_map(Value::as_f64).collect();
    if out.len() < n || out.len() != list.len() {
        return Err(format!("{key} has {} numbers, {n} expected", out.len()));
    }
    Ok(out)
}

/// The camera at `location` (`CALIBRATION_CameraLocationD0`, `...PV0`) and its pose
/// \(T_{c,w}\).
fn camera(json: &Value, location: &str) -> Result<(SensorCamera, Isometry3<f64>), String> {
    let cameras = json
        .pointer("/CalibrationInformation/Cameras")
        .and_then(Value::as_array)
        .ok_or("CalibrationInformation.Cameras is missing")?;
    let camera = cameras
        .iter()
        .find(|c| c.get("Location").and_then(Value::as_str) == Some(location))
        .ok_or_else(|| format!("no camera at {location}"))?;
    let intrinsics = camera
        .get("Intrinsics")
        .ok_or_else(|| format!("{location}: Intrinsics is missing"))?;
    let model = intrinsics
        .get("ModelType")
        .and_then(Value::as_str)
        .unwrap_or("");
    if model != "CALIBRATION_LensDistortionModelBrownConrady" {
        return Err(format!(
            "{location}: lens model {model:?} is not read (CALIBRATION_LensDistortionModelBrownConrady, as every retail device has)"
        ));
    }
    let p = numbers(intrinsics, "ModelParameters", 14).map_err(|e| format!("{location}: {e}"))?;
    let rt = camera
        .get("Rt")
        .ok_or_else(|| format!("{location}: Rt is missing"))?;
    let r = numbers(rt, "Rotation", 9).map_err(|e| format!("{location}: {e}"))?;
    let t = numbers(rt, "Translation", 3).map_err(|e| format!("{location}: {e}"))?;
    let sensor = ["SensorWidth", "SensorHeight"]
        .map(|k| camera.get(k).and_then(Value::as_f64).unwrap_or(0.0));
    if sensor.iter().any(|s| *s <= 0.0) || p[2] <= 0.0 || p[3] <= 0.0 {
        return Err(format!(
            "{location}: the sensor size or focal length is not positive"
        ));
    }
    let rotation = Rotation3::from_matrix(&Matrix3::from_row_slice(&r[..9]));
    let pose = Isometry3::from_parts(
        Translation3::from(Vector3::new(t[0], t[1], t[2])),
        UnitQuaternion::from_rotation_matrix(&rotation),
    );
    // cx, cy, fx, fy, k1..k6, codx, cody, p2, p1 (the SDK's order).
    let sensor_camera = SensorCamera {
        centre_focal: [p[0], p[1], p[2], p[3]],
        distortion: [p[4], p[5], p[13], p[12], p[6]],
        rational: [p[7], p[8], p[9]],
        sensor: (sensor[0], sensor[1]),
    };
    Ok((sensor_camera, pose))
}

/// The camera of an image binned to `binned` and cropped at `offset` of the sensor,
/// `size` pixels.
fn mode(
    c: &SensorCamera,
    binned: (f64, f64),
    offset: (f64, f64),
    size: (u32, u32),
) -> PinholeCamera {
    let [cx, cy, fx, fy] = c.centre_focal;
    PinholeCamera {
        fx: fx * binned.0,
        fy: fy * binned.1,
        cx: cx * binned.0 - offset.0 - 0.5,
        cy: cy * binned.1 - offset.1 - 0.5,
        width: size.0,
        height: size.1,
        distortion: c.distortion,
        rational: c.rational,
    }
}

/// The depth camera of a recording whose depth images are `size`.
fn depth_mode(c: &SensorCamera, size: (u32, u32)) -> Result<PinholeCamera, String> {
    if c.sensor != (1024.0, 1024.0) {
        return Err(format!(
            "the depth sensor is {}x{}, 1024x1024 expected",
            c.sensor.0, c.sensor.1
        ));
    }
    let (binned, offset) = match size {
        (320, 288) => (512.0, (96.0, 90.0)),
        (640, 576) => (1024.0, (192.0, 180.0)),
        (512, 512) => (512.0, (0.0, 0.0)),
        (1024, 1024) => (1024.0, (0.0, 0.0)),
        (w, h) => return Err(format!("depth images of {w}x{h} are no Azure Kinect depth mode (320x288, 640x576, 512x512, 1024x1024)")),
    };
    Ok(mode(c, (binned, binned), offset, size))
}

/// The colour camera of a recording whose colour images are `size`: the 4:3 sensor
/// binned to the width, cropped to the height.
fn colour_mode(mut c: SensorCamera, size: (u32, u32)) -> Result<PinholeCamera, String> {
    let (sw, sh) = c.sensor;
    if (sw * 9.0 / 16.0 - sh).abs() < 1.0 {
        // An early 16:9 calibration: the same sensor seen as 4:3, 384 rows higher.
        let [cx, cy, fx, fy] = c.centre_focal;
        let h43 = sw * 3.0 / 4.0;
        c.centre_focal = [cx, (cy * sh + (h43 - sh) / 2.0) / h43, fx, fy * sh / h43];
        c.sensor = (sw, h43);
    } else if (sw * 3.0 / 4.0 - sh).abs() >= 1.0 {
        return Err(format!(
            "the colour sensor is {sw}x{sh}, neither 4:3 nor 16:9"
        ));
    }
    let (w, h) = (size.0 as f64, size.1 as f64);
    let binned_h = w * 3.0 / 4.0;
    if h > binned_h {
        return Err(format!(
            "colour images of {}x{} are taller than 4:3",
            size.0, size.1
        ));
    }
    Ok(mode(&c, (w, binned_h), (0.0, (binned_h - h) / 2.0), size))
}

/// A FourCC as text: printable ASCII as it is, any other byte as `\xNN` (a FourCC of
/// zeros would print raw NUL bytes).
fn printable(code: &[u8]) -> String {
    code.iter()
        .map(|&b| {
            if b.is_ascii_graphic() || b == b' ' {
                (b as char).to_string()
            } else {
                format!("\\x{b:02x}")
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_fourcc_of_zeros_prints_as_escapes() {
        assert_eq!(printable(b"MJPG"), "MJPG");
        assert_eq!(printable(&[0, 0, 0, 0]), "\\x00\\x00\\x00\\x00");
    }

    #[test]
    fn grey_yuv_is_grey_in_both_layouts() {
        // Y = 126, U = V = 128: grey 128 (limited range), in 2x2 NV12 and YUY2.
        let nv12 = [126, 126, 126, 126, 128, 128];
        let yuy2 = [126, 128, 126, 128, 126, 128, 126, 128];
        for (format, data) in [(Format::Nv12, &nv12[..]), (Format::Yuy2, &yuy2[..])] {
            let out = rgb_of_yuv(format, 2, 2, data).unwrap();
            assert!(out.iter().all(|&c| c == 128), "{format:?}: {out:?}");
            assert!(
                rgb_of_yuv(format, 2, 2, &data[..3]).is_none(),
                "short frame"
            );
        }
        // Pure red in BT.601 limited range: Y 81, U 90, V 240.
        let red = rgb(81, 90, 240);
        assert!(red[0] >= 250 && red[1] <= 3 && red[2] <= 3, "{red:?}");
    }

    #[test]
    fn mode_specific_intrinsics_follow_the_sdk() {
        let sensor = SensorCamera {
            centre_focal: [0.5, 0.5, 0.49, 0.49],
            distortion: [0.0; 5],
            rational: [0.0; 3],
            sensor: (1024.0, 1024.0),
        };
        // NFOV unbinned: cx = 0.5 * 1024 - 192 - 0.5.
        let d = depth_mode(&sensor, (640, 576)).unwrap();
        assert_eq!((d.cx, d.cy, d.fx), (319.5, 331.5, 0.49 * 1024.0));
        assert!(depth_mode(&sensor, (640, 480)).is_err());
        // 720p colour from a 4096x3072 sensor: binned 1280x960, 120 rows cropped.
        let colour = SensorCamera {
            sensor: (4096.0, 3072.0),
            ..sensor
        };
        let c = colour_mode(colour, (1280, 720)).unwrap();
        assert_eq!((c.cx, c.cy, c.fy), (639.5, 359.5, 0.49 * 960.0));
        // A 16:9 calibration of the same lens gives the same camera.
        let legacy = SensorCamera {
            sensor: (4096.0, 2304.0),
            centre_focal: [0.5, 0.5, 0.49, 0.49 * 3072.0 / 2304.0],
            ..sensor
        };
        let l = colour_mode(legacy, (1280, 720)).unwrap();
        assert!(
            (l.cy - c.cy).abs() < 1e-9 && (l.fy - c.fy).abs() < 1e-9,
            "{l:?}"
        );
    }
}
