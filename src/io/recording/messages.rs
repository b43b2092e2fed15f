//! The three ROS message types a recording's camera streams use, decoded from their
//! wire bytes: `sensor_msgs/Image`, `sensor_msgs/CompressedImage` and
//! `sensor_msgs/CameraInfo`, in ROS 1 serialisation (little-endian, packed, strings
//! and arrays prefixed by a `u32` length) or in ROS 2's CDR (a 4-byte encapsulation
//! header, then fields aligned to their own size from the header's end, strings with
//! their terminating NUL counted).

/// How a message's bytes are laid out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wire {
    /// ROS 1: packed little-endian.
    Ros1,
    /// ROS 2: CDR (the encapsulation header says the byte order).
    Cdr,
}

/// What went wrong decoding a message: the field and why.
pub type DecodeError = String;

/// A cursor over one message's bytes.
struct Cursor<'a> {
    data: &'a [u8],
    pos: usize,
    /// Where CDR alignment counts from (after the encapsulation header).
    origin: usize,
    wire: Wire,
    little: bool,
}

impl<'a> Cursor<'a> {
    fn new(data: &'a [u8], wire: Wire) -> Result<Self, DecodeError> {
        match wire {
            Wire::Ros1 => Ok(Self {
                data,
                pos: 0,
                origin: 0,
                wire,
                little: true,
            }),
            Wire::Cdr => {
                if data.len() < 4 {
                    return Err(format!("{} bytes: too short for a CDR message", data.len()));
                }
                // Encapsulation kind: 0x0000/0x0002 big-endian, 0x0001/0x0003 little.
                let little = data[1] & 1 == 1;
                Ok(Self {
                    data,
                    pos: 4,
                    origin: 4,
                    wire,
                    little,
                })
            }
        }
    }

    fn align(&mut self, size: usize) {
        if self.wire == Wire::Cdr {
            let offset = self.pos - self.origin;
            self.pos += (size - offset % size) % size;
        }
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], DecodeError> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.data.len());
        let Some(end) = end else {
            return Err(format!(
                "{what}: needs {n} bytes at offset {} but the message has {}",
                self.pos,
                self.data.len()
            ));
        };
        let bytes = &self.data[self.pos..end];
        self.pos = end;
        Ok(bytes)
    }

    fn u8(&mut self, what: &str) -> Result<u8, DecodeError> {
        Ok(self.take(1, what)?[0])
    }

    fn u32(&mut self, what: &str) -> Result<u32, DecodeError> {
        self.align(4);
        let b: [u8; 4] = self.take(4, what)?.try_into().expect("4 bytes");
        Ok(if self.little {
            u32::from_le_bytes(b)
        } else {
            u32::from_be_bytes(b)
        })
    }

    fn f64(&mut self, what: &str) -> Result<f64, DecodeError> {
        self.align(8);
        let b: [u8; 8] = self.take(8, what)?.try_into().expect("8 bytes");
        Ok(if self.little {
            f64::from_le_bytes(b)
        } else {
            f64::from_be_bytes(b)
        })
    }

    fn bytes(&mut self, what: &str) -> Result<&'a [u8], DecodeError> {
        let n = self.u32(what)? as usize;
        self.take(n, what)
    }

    fn string(&mut self, what: &str) -> Result<String, DecodeError> {
        let mut bytes = self.bytes(what)?;
        if self.wire == Wire::Cdr {
            bytes = bytes.strip_suffix(&[0]).unwrap_or(bytes);
        }
        Ok(String::from_utf8_lossy(bytes).into_owned())
    }

    fn f64s<const N: usize>(&mut self, what: &str) -> Result<[f64; N], DecodeError> {
        let mut out = [0.0; N];
        for v in &mut out {
            *v = self.f64(what)?;
        }
        Ok(out)
    }

    /// `std_msgs/Header`: the stamp in seconds (ROS 1 has a `seq` before it).
    fn header(&mut self) -> Result<f64, DecodeError> {
        Ok(self.header_and_frame()?.0)
    }

    /// `std_msgs/Header`: the stamp in seconds and the frame id.
    fn header_and_frame(&mut self) -> Result<(f64, String), DecodeError> {
        if self.wire == Wire::Ros1 {
            self.u32("header.seq")?;
        }
        let sec = self.u32("header.stamp.sec")?;
        let nsec = self.u32("header.stamp.nsec")?;
        let frame = self.string("header.frame_id")?;
        Ok((sec as f64 + nsec as f64 / 1e9, frame))
    }
}

/// The stamp of a message with a `std_msgs/Header` first (every type here).
pub fn stamp(data: &[u8], wire: Wire) -> Result<f64, DecodeError> {
    Cursor::new(data, wire)?.header()
}

/// A `std_msgs/String`'s text (librealsense keeps stream info and options in them).
pub fn string(data: &[u8], wire: Wire) -> Result<String, DecodeError> {
    Cursor::new(data, wire)?.string("data")
}

/// One `geometry_msgs/TransformStamped`: the pose of `child` in `parent`, i.e.
/// \(p_{parent} = R(q)\, p_{child} + t\).
#[derive(Debug, Clone, PartialEq)]
pub struct Transform {
    /// The parent frame.
    pub parent: String,
    /// The child frame.
    pub child: String,
    /// The translation, metres.
    pub translation: [f64; 3],
    /// \((x, y, z, w)\).
    pub rotation: [f64; 4],
}

/// Decodes a `tf2_msgs/TFMessage` (ROS 1 `tf/tfMessage` has the same layout).
pub fn transforms(data: &[u8], wire: Wire) -> Result<Vec<Transform>, DecodeError> {
    let mut c = Cursor::new(data, wire)?;
    let n = c.u32("transforms")? as usize;
    if n > 10_000 {
        return Err(format!("transforms: {n} entries (at most 10000 expected)"));
    }
    (0..n)
        .map(|_| {
            let (_, parent) = c.header_and_frame()?;
            let child = c.string("child_frame_id")?;
            let translation = c.f64s::<3>("transform.translation")?;
            let rotation = c.f64s::<4>("transform.rotation")?;
            Ok(Transform {
                parent,
                child,
                translation,
                rotation,
            })
        })
        .collect()
}

/// Decodes a `geometry_msgs/Transform`: the translation and the rotation \((x, y, z, w)\).
pub fn transform(data: &[u8], wire: Wire) -> Result<([f64; 3], [f64; 4]), DecodeError> {
    let mut c = Cursor::new(data, wire)?;
    Ok((c.f64s::<3>("translation")?, c.f64s::<4>("rotation")?))
}

/// Decodes a `std_msgs/Float32`.
pub fn float32(data: &[u8], wire: Wire) -> Result<f32, DecodeError> {
    let mut c = Cursor::new(data, wire)?;
    let bits = c.u32("data")?;
    Ok(f32::from_bits(bits))
}

/// The pose types a ground-truth topic may carry.
pub const POSE_TYPES: [&str; 3] = [
    "geometry_msgs/PoseStamped",
    "nav_msgs/Odometry",
    "geometry_msgs/TransformStamped",
];

/// A stamped pose: the stamp, the position and the orientation \((x, y, z, w)\).
pub type StampedPose = (f64, [f64; 3], [f64; 4]);

/// Decodes one of [`POSE_TYPES`] (in ROS 1 spelling) into its stamped pose; for an
/// `Odometry` the pose without its covariance.
pub fn stamped_pose(data: &[u8], wire: Wire, msg_type: &str) -> Result<StampedPose, DecodeError> {
    let mut c = Cursor::new(data, wire)?;
    let stamp = c.header()?;
    match msg_type {
        "geometry_msgs/PoseStamped" => {}
        "nav_msgs/Odometry" | "geometry_msgs/TransformStamped" => {
            c.string("child_frame_id")?;
        }
        other => {
            return Err(format!(
                "{other} is not a pose type ({})",
                POSE_TYPES.join(", ")
            ))
        }
    }
    let position = c.f64s::<3>("position")?;
    let orientation = c.f64s::<4>("orientation")?;
    Ok((stamp, position, orientation))
}

/// A `sensor_msgs/Image`.
#[derive(Debug, Clone, PartialEq)]
pub struct RawImage<'a> {
    /// The header stamp, seconds.
    pub stamp: f64,
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// `rgb8`, `bgr8`, `mono8`, `16UC1`, `32FC1`, ….
    pub encoding: String,
    /// Whether multi-byte values are big-endian.
    pub big_endian: bool,
    /// Bytes per row.
    pub step: u32,
    /// The pixels.
    pub data: &'a [u8],
}

/// Decodes a `sensor_msgs/Image`.
pub fn image(data: &[u8], wire: Wire) -> Result<RawImage<'_>, DecodeError> {
    let mut c = Cursor::new(data, wire)?;
    let stamp = c.header()?;
    let height = c.u32("height")?;
    let width = c.u32("width")?;
    let encoding = c.string("encoding")?;
    let big_endian = c.u8("is_bigendian")? != 0;
    let step = c.u32("step")?;
    let data = c.bytes("data")?;
    if (step as u64) * (height as u64) > data.len() as u64 {
        return Err(format!(
            "data: {} bytes, but {height} rows of {step} bytes were announced",
            data.len()
        ));
    }
    Ok(RawImage {
        stamp,
        width,
        height,
        encoding,
        big_endian,
        step,
        data,
    })
}

/// A `sensor_msgs/CompressedImage`.
#[derive(Debug, Clone, PartialEq)]
pub struct CompressedImage<'a> {
    /// The header stamp, seconds.
    pub stamp: f64,
    /// `jpeg`, `png`, or `16UC1; compressedDepth png` and the like.
    pub format: String,
    /// The compressed bytes.
    pub data: &'a [u8],
}

/// Decodes a `sensor_msgs/CompressedImage`.
pub fn compressed(data: &[u8], wire: Wire) -> Result<CompressedImage<'_>, DecodeError> {
    let mut c = Cursor::new(data, wire)?;
    let stamp = c.header()?;
    let format = c.string("format")?;
    let data = c.bytes("data")?;
    Ok(CompressedImage {
        stamp,
        format,
        data,
    })
}

/// A `sensor_msgs/CameraInfo` (the region of interest and binning are not used).
#[derive(Debug, Clone, PartialEq)]
pub struct CameraInfo {
    /// The header stamp, seconds.
    pub stamp: f64,
    /// The camera's frame (in `/tf_static`).
    pub frame: String,
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// `plumb_bob`, `rational_polynomial`, `equidistant`, or empty.
    pub distortion_model: String,
    /// The distortion coefficients.
    pub d: Vec<f64>,
    /// The intrinsic matrix, row-major: \(K = [f_x, 0, c_x; 0, f_y, c_y; 0, 0, 1]\).
    pub k: [f64; 9],
    /// The projection matrix of the rectified camera, row-major 3x4; for the right
    /// camera of a stereo pair \(P_{03} = -f_x b\).
    pub p: [f64; 12],
}

/// Decodes a `sensor_msgs/CameraInfo`.
pub fn camera_info(data: &[u8], wire: Wire) -> Result<CameraInfo, DecodeError> {
    let mut c = Cursor::new(data, wire)?;
    let (stamp, frame) = c.header_and_frame()?;
    let height = c.u32("height")?;
    let width = c.u32("width")?;
    let distortion_model = c.string("distortion_model")?;
    let n = c.u32("D")? as usize;
    if n > 64 {
        return Err(format!(
            "D: {n} distortion coefficients (at most 64 expected)"
        ));
    }
    let d = (0..n).map(|_| c.f64("D")).collect::<Result<Vec<_>, _>>()?;
    let k = c.f64s::<9>("K")?;
    let _r = c.f64s::<9>("R")?;
    let p = c.f64s::<12>("P")?;
    Ok(CameraInfo {
        stamp,
        frame,
        width,
        height,
        distortion_model,
        d,
        k,
        p,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Builds ROS 1 or CDR bytes field by field, as a writer would.
    struct Writer {
        out: Vec<u8>,
        wire: Wire,
    }

    impl Writer {
        fn new(wire: Wire) -> Self {
            let out = if wire == Wire::Cdr {
                vec![0, 1, 0, 0]
            } else {
                Vec::new()
            };
            Self { out, wire }
        }
        fn align(&mut self, n: usize) {
            if self.wire == Wire::Cdr {
                while !(self.out.len() - 4).is_multiple_of(n) {
                    self.out.push(0);
                }
            }
        }
        fn u32(&mut self, v: u32) {
            self.align(4);
            self.out.extend(v.to_le_bytes());
        }
        fn f64(&mut self, v: f64) {
            self.align(8);
            self.out.extend(v.to_le_bytes());
        }
        fn string(&mut self, s: &str) {
            let nul = usize::from(self.wire == Wire::Cdr);
            self.u32((s.len() + nul) as u32);
            self.out.extend(s.as_bytes());
            self.out.extend(std::iter::repeat_n(0, nul));
        }
        fn header(&mut self, sec: u32, nsec: u32) {
            if self.wire == Wire::Ros1 {
                self.u32(7);
            }
            self.u32(sec);
            self.u32(nsec);
            self.string("camera");
        }
    }

    #[test]
    fn an_image_decodes_in_both_wires() {
        for wire in [Wire::Ros1, Wire::Cdr] {
            let mut w = Writer::new(wire);
            w.header(1_305_031_102, 175_304_000);
            w.u32(2);
            w.u32(3);
            w.string("mono8");
            w.out.push(0);
            w.u32(3);
            w.u32(6);
            w.out.extend([1, 2, 3, 4, 5, 6]);
            let image = image(&w.out, wire).unwrap();
            assert!((image.stamp - 1_305_031_102.175304).abs() < 1e-6);
            assert_eq!((image.width, image.height, image.step), (3, 2, 3));
            assert_eq!(image.encoding, "mono8");
            assert_eq!(image.data, &[1, 2, 3, 4, 5, 6]);
            // Cut anywhere: an error naming the field, never a panic.
            for cut in 0..w.out.len() {
                assert!(
                    super::image(&w.out[..cut], wire).is_err(),
                    "{wire:?} cut at {cut}"
                );
            }
        }
    }

    #[test]
    fn camera_info_aligns_its_doubles_in_cdr() {
        for wire in [Wire::Ros1, Wire::Cdr] {
            let mut w = Writer::new(wire);
            w.header(5, 0);
            w.u32(480);
            w.u32(640);
            w.string("plumb_bob");
            w.u32(5);
            for d in [0.1, -0.2, 0.0, 0.0, 0.3] {
                w.f64(d);
            }
            let k = [525.0, 0.0, 319.5, 0.0, 526.0, 239.5, 0.0, 0.0, 1.0];
            for v in k.iter().chain(&[0.0; 9]).chain(&[0.0; 12]) {
                w.f64(*v);
            }
            let info = camera_info(&w.out, wire).unwrap();
            assert_eq!((info.width, info.height), (640, 480));
            assert_eq!(info.k, k);
            assert_eq!(info.d, vec![0.1, -0.2, 0.0, 0.0, 0.3]);
            assert_eq!(info.distortion_model, "plumb_bob");
        }
    }

    #[test]
    fn an_absurd_length_is_an_error() {
        let mut w = Writer::new(Wire::Ros1);
        w.header(1, 2);
        w.u32(u32::MAX);
        assert!(compressed(&w.out, Wire::Ros1)
            .unwrap_err()
            .contains("format"));
    }
}
