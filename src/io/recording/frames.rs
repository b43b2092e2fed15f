//! Frames of a recording: colour and depth messages paired by stamp (TUM's rule), and
//! decoded into the images a [`crate::io::sequence::Frame`] holds.
//!
//! Encodings: colour `rgb8`, `bgr8`, `rgba8`, `bgra8`, `mono8` and compressed JPEG or
//! PNG; depth `16UC1` / `mono16` (raw units, divided by the depth scale), `32FC1`
//! (metres; NaN and non-positive values are no depth) and `compressedDepth` PNG
//! (`16UC1`, or `32FC1` quantised as \(z = a / (q - b)\) with \(a, b\) from its
//! 12-byte header).

use std::path::Path;

use image::{GrayImage, RgbImage};

use super::messages::{self, Wire};
use super::register::Registration;
use super::topics::Chosen;
use super::{Catalog, Entry, Store, COMPRESSED};
use crate::io::file_list::associate_greedy;
use crate::io::image_files::{grey_from_rgb, DepthImage};
use crate::io::IoError;

/// One frame: its colour and depth messages and whether each is compressed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FramePair {
    /// The colour message.
    pub colour: Entry,
    /// The depth message.
    pub depth: Entry,
    /// Whether the colour is compressed.
    pub colour_compressed: bool,
    /// Whether the depth is compressed.
    pub depth_compressed: bool,
}

/// Pairs the chosen colour and depth topics' messages by stamp.
pub fn pair(
    path: &Path,
    catalog: &Catalog,
    chosen: &Chosen,
    max_difference: f64,
) -> Result<Vec<FramePair>, IoError> {
    let colour = catalog.topic(&chosen.colour).expect("chosen topics exist");
    let depth = catalog.topic(&chosen.depth).expect("chosen topics exist");
    let stamps = |t: &super::Topic| t.messages.iter().map(|m| m.stamp).collect::<Vec<_>>();
    let pairs = associate_greedy(&stamps(colour), &stamps(depth), 0.0, max_difference);
    if pairs.is_empty() {
        return Err(IoError::invalid(
            path,
            format!(
                "none of the {} colour images ({}, stamps {:.3}-{:.3}) has a depth image ({}, {} messages, stamps {:.3}-{:.3}) within {max_difference} s: are the two stamped by different clocks? (raise [dataset] max_difference)",
                colour.messages.len(), colour.name, colour.messages[0].stamp, colour.messages.last().expect("non-empty").stamp,
                depth.name, depth.messages.len(), depth.messages[0].stamp, depth.messages.last().expect("non-empty").stamp
            ),
        ));
    }
    Ok(pairs
        .into_iter()
        .map(|(i, j)| FramePair {
            colour: colour.messages[i],
            depth: depth.messages[j],
            colour_compressed: colour.msg_type == COMPRESSED,
            depth_compressed: depth.msg_type == COMPRESSED,
        })
        .collect())
}

/// Decodes a frame's messages read back from the store.
pub struct Reader<'a> {
    /// The recording.
    pub path: &'a Path,
    /// Its messages.
    pub store: &'a dyn Store,
    /// How messages are encoded (ROS 1 or CDR).
    pub wire: Wire,
    /// Applied to each depth image when the depth is in its own camera.
    pub registration: Option<&'a Registration>,
}

impl Reader<'_> {
    fn bad(&self, entry: &Entry, what: &str, message: impl std::fmt::Display) -> IoError {
        IoError::Image {
            path: self.path.to_path_buf(),
            message: format!("the {what} image stamped {:.6}: {message}", entry.stamp),
        }
    }

    /// The grey image of one camera of a stereo pair: `mono8` as it is, other
    /// encodings through [`grey_from_rgb`], compressed ones through the decoder's own.
    pub fn grey(&self, entry: &Entry, compressed: bool) -> Result<GrayImage, IoError> {
        let data = self.store.read(entry.at)?;
        let bad = |m: String| self.bad(entry, "stereo", m);
        if compressed {
            let c = messages::compressed(&data, self.wire).map_err(bad)?;
            let image = image::load_from_memory(c.data)
                .map_err(|e| bad(format!("{} data: {e}", c.format)))?;
            return Ok(image.into_luma8());
        }
        let raw = messages::image(&data, self.wire).map_err(bad)?;
        if raw.encoding == "mono8" {
            let (w, h, step) = (raw.width as usize, raw.height as usize, raw.step as usize);
            if step < w {
                return Err(bad(format!(
                    "step {step} is shorter than a row of {w} pixels of mono8"
                )));
            }
            let grey: Vec<u8> = raw
                .data
                .chunks(step)
                .take(h)
                .flat_map(|row| &row[..w])
                .copied()
                .collect();
            return Ok(GrayImage::from_raw(raw.width, raw.height, grey)
                .expect("rows of the announced size"));
        }
        Ok(grey_from_rgb(&rgb_from_raw(&raw).map_err(bad)?))
    }

    /// The colour image of a frame.
    pub fn colour(&self, entry: &Entry, compressed: bool) -> Result<RgbImage, IoError> {
        let data = self.store.read(entry.at)?;
        let bad = |m: String| self.bad(entry, "colour", m);
        if compressed {
            let c = messages::compressed(&data, self.wire).map_err(bad)?;
            let image = image::load_from_memory(c.data)
                .map_err(|e| bad(format!("{} data: {e}", c.format)))?;
            return Ok(image.into_rgb8());
        }
        let raw = messages::image(&data, self.wire).map_err(bad)?;
        rgb_from_raw(&raw).map_err(bad)
    }

    /// The depth image of a frame in metres, in the colour camera.
    pub fn depth(
        &self,
        entry: &Entry,
        compressed: bool,
        depth_scale: f64,
    ) -> Result<DepthImage, IoError> {
        let depth = self.raw_depth(entry, compressed, depth_scale)?;
        let Some(registration) = self.registration else {
            return Ok(depth);
        };
        registration.apply(&depth).ok_or_else(|| {
            let size = format!("{}x{}", depth.width, depth.height);
            self.bad(
                entry,
                "depth",
                format!("{size}, not the size its camera info gives"),
            )
        })
    }

    /// The depth image of a frame in metres, in its own camera.
    fn raw_depth(
        &self,
        entry: &Entry,
        compressed: bool,
        depth_scale: f64,
    ) -> Result<DepthImage, IoError> {
        let data = self.store.read(entry.at)?;
        let bad = |m: String| self.bad(entry, "depth", m);
        if compressed {
            let c = messages::compressed(&data, self.wire).map_err(bad)?;
            return compressed_depth(&c, depth_scale).map_err(bad);
        }
        let raw = messages::image(&data, self.wire).map_err(bad)?;
        let (w, h, step) = (raw.width as usize, raw.height as usize, raw.step as usize);
        let bytes = match raw.encoding.as_str() {
            "16UC1" | "mono16" => 2,
            "32FC1" => 4,
            other => {
                return Err(bad(format!(
                    "encoding {other:?} is not a depth encoding read here (16UC1, mono16, 32FC1)"
                )))
            }
        };
        if step < w * bytes {
            return Err(bad(format!(
                "step {step} is shorter than a row of {w} pixels of {}",
                raw.encoding
            )));
        }
        let scale = (1.0 / depth_scale) as f32;
        // Appended row by row ([`append_row`]), each pixel tested by comparisons only
        // (`z > 0 && z < inf`, which NaN fails): `is_finite` stopped the vectorisation
        // (56 % of reading an MCAP bag went there).
        let depth = |m: f32| if m > 0.0 && m < f32::INFINITY { m } else { 0.0 };
        let mut metres = Vec::with_capacity(w * h);
        for row in raw.data.chunks(step).take(h) {
            let row = &row[..w * bytes];
            let out = &mut metres;
            match (bytes, raw.big_endian) {
                (2, false) => append_row(out, row, |p| depth(u16::from_le_bytes(p) as f32 * scale)),
                (2, true) => append_row(out, row, |p| depth(u16::from_be_bytes(p) as f32 * scale)),
                (_, false) => append_row(out, row, |p| depth(f32::from_le_bytes(p))),
                (_, true) => append_row(out, row, |p| depth(f32::from_be_bytes(p))),
            }
        }
        Ok(DepthImage {
            width: raw.width,
            height: raw.height,
            metres,
        })
    }
}

/// Appends the `N`-byte pixels of `row`, each converted by `pixel` (an `extend` of known
/// length, which the compiler vectorises: no test of the capacity per pixel, and no
/// zeroing of the image first).
fn append_row<const N: usize, T>(out: &mut Vec<T>, row: &[u8], pixel: impl Fn([u8; N]) -> T) {
    out.extend(row.as_chunks::<N>().0.iter().map(|&p| pixel(p)));
}

/// An RGB image of a raw colour or grey `sensor_msgs/Image` (`rgb8`, `bgr8`, `rgba8`,
/// `bgra8`, `mono8`).
fn rgb_from_raw(raw: &messages::RawImage) -> Result<RgbImage, String> {
    let channels = match raw.encoding.as_str() {
        "rgb8" | "bgr8" => 3,
        "rgba8" | "bgra8" => 4,
        "mono8" => 1,
        other => {
            return Err(format!(
                "encoding {other:?} is not a colour encoding read here (rgb8, bgr8, rgba8, bgra8, mono8)"
            ))
        }
    };
    let (w, h, step) = (raw.width as usize, raw.height as usize, raw.step as usize);
    if step < w * channels {
        return Err(format!(
            "step {step} is shorter than a row of {w} pixels of {}",
            raw.encoding
        ));
    }
    let swap = raw.encoding.starts_with("bgr");
    let mut rgb = Vec::with_capacity(w * h);
    for row in raw.data.chunks(step).take(h) {
        let row = &row[..w * channels];
        match (channels, swap) {
            (3, false) => rgb.extend_from_slice(row.as_chunks::<3>().0),
            (1, _) => append_row(&mut rgb, row, |[g]: [u8; 1]| [g; 3]),
            (3, true) => append_row(&mut rgb, row, |[b, g, r]: [u8; 3]| [r, g, b]),
            (_, false) => append_row(&mut rgb, row, |[r, g, b, _]: [u8; 4]| [r, g, b]),
            (_, true) => append_row(&mut rgb, row, |[b, g, r, _]: [u8; 4]| [r, g, b]),
        }
    }
    let rgb = rgb.into_flattened();
    Ok(RgbImage::from_raw(raw.width, raw.height, rgb).expect("rows of the announced size"))
}

/// Decodes `compressed_depth_image_transport`'s format: a 12-byte header (`i32`
/// format, two `f32` quantisation parameters) and a 16-bit PNG.
fn compressed_depth(c: &messages::CompressedImage, depth_scale: f64) -> Result<DepthImage, String> {
    if !c.format.contains("png") {
        return Err(format!(
            "format {:?}: only PNG compressedDepth is read (not RVL)",
            c.format
        ));
    }
    let (header, png) = c
        .data
        .split_at_checked(12)
        .ok_or("compressedDepth data shorter than its 12-byte header")?;
    let a = f32::from_le_bytes(header[4..8].try_into().expect("4 bytes"));
    let b = f32::from_le_bytes(header[8..12].try_into().expect("4 bytes"));
    let image = image::load_from_memory_with_format(png, image::ImageFormat::Png)
        .map_err(|e| format!("compressedDepth PNG: {e}"))?;
    let image::DynamicImage::ImageLuma16(raw) = image else {
        return Err(format!(
            "compressedDepth PNG is {:?}, not 16-bit grey",
            image.color()
        ));
    };
    let float = c.format.starts_with("32FC1");
    let scale = (1.0 / depth_scale) as f32;
    let metres = raw
        .as_raw()
        .iter()
        .map(|&q| match (q, float) {
            (0, _) => 0.0,
            (q, true) => {
                let z = a / (q as f32 - b);
                if z.is_finite() && z > 0.0 {
                    z
                } else {
                    0.0
                }
            }
            (q, false) => q as f32 * scale,
        })
        .collect();
    Ok(DepthImage {
        width: raw.width(),
        height: raw.height(),
        metres,
    })
}

/// What `dopslam info` says about a recording.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Description {
    /// Every topic: name, type, messages, rate in Hz.
    pub topics: Vec<(String, String, usize, f64)>,
    /// The colour (or left) topic chosen.
    pub colour: String,
    /// The depth (or right) topic chosen.
    pub depth: String,
    /// The camera-info topic chosen.
    pub camera_info: Option<String>,
    /// A stereo pair: `colour` is the left image topic, `depth` the right one.
    pub stereo: bool,
    /// Frames paired.
    pub frames: usize,
    /// What may be wrong.
    pub warnings: Vec<String>,
    /// What the reader did beyond the plain topics (device clock stamps).
    pub notes: Vec<String>,
    /// Whether the depth was recorded in the colour camera already.
    pub registered: bool,
    /// Raw 16-bit depth units per metre in use.
    pub depth_scale: f64,
    /// Where the cameras come from when not from topics (`calibration.json`).
    pub cameras_from: Option<String>,
    /// Where the transform that registers the depth came from.
    pub registered_by: Option<String>,
}

impl Description {
    /// The description of `chosen` among `catalog`'s topics, with `frames` paired.
    pub fn new(catalog: &Catalog, chosen: &Chosen, frames: usize) -> Self {
        let topics = catalog
            .topics
            .iter()
            .map(|t| {
                let rate = t.rate().unwrap_or(0.0);
                (t.name.clone(), t.msg_type.clone(), t.messages.len(), rate)
            })
            .collect();
        Self {
            topics,
            colour: chosen.colour.clone(),
            depth: chosen.depth.clone(),
            camera_info: chosen.camera_info.clone(),
            stereo: chosen.stereo.is_some(),
            frames,
            warnings: catalog.warnings.clone(),
            notes: Vec::new(),
            registered: true,
            depth_scale: 1000.0,
            cameras_from: None,
            registered_by: None,
        }
    }
}
