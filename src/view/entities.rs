//! The entity paths of a run's recording, and how each [`Entry`] becomes Rerun's
//! archetypes. The world is the run's world frame; the camera's pinhole is Rerun's
//! default RDF (x right, y down, z forward), as the run's cameras.
//!
//! | entity | what |
//! |---|---|
//! | `world/camera` | the tracking pass's pose (`Transform3D`) |
//! | `world/camera/image` | pinhole, image (JPEG, scaled by `rerun_image_scale`) |
//! | `world/camera/image/keypoints` | kept keypoints, coloured by moving probability (green 0, yellow 0.5, red 1) |
//! | `world/camera/image/removed` | keypoints removed before pose estimation (magenta) |
//! | `world/camera/image/detections` | the detector's boxes with class and score |
//! | `world/camera/image/depth` | depth (with `rerun_depth`) |
//! | `world/map/static`, `world/map/moving` | the local map at keyframes |
//! | `world/keyframes` | keyframe centres |
//! | `world/trajectory/{final,truth}`, `world/trajectory/tracking/<piece>` | trajectories (blue, green, grey; a baseline's red); the tracking path in pieces of 300 centres |
//! | `world/loops` | closed loops' edges |
//! | `world/dense/mesh`, `world/dense/cloud` | the dense map |
//! | `events`, `events/loops` | keyframes, tracking lost and relocalised; loops closed |
//!
//! A prefix goes after `world/`: `no_dop` for `--compare-no-dop`'s baseline;
//! `recordings/<k>_<sequence>` for each recording of a merged map (`dopslam view` of a
//! `dopslam merge` folder: its trajectories, ground truth and own dense map, each
//! recording in its own colour) and `merged` for the merged map itself.

#[cfg(feature = "rerun")]
pub use with_rerun::{open_stream, Stream};
#[cfg(not(feature = "rerun"))]
pub use without_rerun::{open_stream, Stream};

#[cfg(feature = "rerun")]
use super::entry::{At, Entry, Level, Message};

/// Timestamps above this many seconds (1973) are Unix times; below, durations.
pub const UNIX_TIME_AFTER: f64 = 1e8;

/// The entity path of `rest` under `prefix` (`world/...`), or of the events.
pub fn path(prefix: &str, rest: &str) -> String {
    match (prefix.is_empty(), rest == EVENTS) {
        (true, true) => EVENTS.to_string(),
        (false, true) => format!("{prefix}/{EVENTS}"),
        (true, false) => format!("world/{rest}"),
        (false, false) => format!("world/{prefix}/{rest}"),
    }
}

/// The camera's pose and pinhole.
pub const CAMERA: &str = "camera";
/// The frame's image.
pub const IMAGE: &str = "camera/image";
/// Its keypoints kept.
pub const KEYPOINTS: &str = "camera/image/keypoints";
/// Its keypoints removed as dynamic.
pub const REMOVED: &str = "camera/image/removed";
/// The detector's boxes.
pub const DETECTIONS: &str = "camera/image/detections";
/// The frame's depth.
pub const DEPTH: &str = "camera/image/depth";
/// The static map points.
pub const MAP_STATIC: &str = "map/static";
/// The moving map points.
pub const MAP_MOVING: &str = "map/moving";
/// The keyframes' centres.
pub const KEYFRAMES: &str = "keyframes";
/// The trajectories (tracking, final).
pub const TRAJECTORY: &str = "trajectory";
/// The loops closed.
pub const LOOPS: &str = "loops";
/// The TSDF mesh.
pub const MESH: &str = "dense/mesh";
/// The point cloud.
pub const CLOUD: &str = "dense/cloud";
/// Losses, relocalisations, loops and the run's summary.
pub const EVENTS: &str = "events";

/// The colour of a keypoint of moving probability `p`: green (static) through yellow
/// (unknown, 0.5) to red (dynamic): \(r = \min(1, 2p)\), \(g = \min(1, 2(1-p))\).
pub fn probability_colour(p: f32) -> [u8; 3] {
    let p = if p.is_finite() {
        p.clamp(0.0, 1.0)
    } else {
        0.5
    };
    let r = (2.0 * p).min(1.0);
    let g = (2.0 * (1.0 - p)).min(1.0);
    [(r * 255.0).round() as u8, (g * 255.0).round() as u8, 0]
}

#[cfg(not(feature = "rerun"))]
mod without_rerun {
    use super::super::entry::{Message, Target};
    use super::super::{OutputConfig, ViewError};

    /// Stands where the recording would be: never made (see [`super::super::Logger::open`]).
    pub struct Stream;

    /// Without the `rerun` feature: an error saying so.
    pub fn open_stream(_target: &Target, _name: &'static str) -> Result<Stream, ViewError> {
        Err(ViewError::NotBuilt)
    }

    impl Stream {
        /// Never reached (no stream is made): an error saying so.
        pub fn log(&self, _message: &Message, _config: &OutputConfig) -> Result<(), ViewError> {
            Err(ViewError::NotBuilt)
        }

        /// Nothing to close.
        pub fn close(self) -> Result<bool, ViewError> {
            Ok(true)
        }
    }
}

#[cfg(feature = "rerun")]
mod with_rerun {
    use super::*;
    use crate::view::entry::Target;
    use crate::view::{OutputConfig, ViewError};
    use rerun::{
        Boxes2D, Color, DepthImage, EncodedImage, LineStrips3D, Mesh3D, Pinhole, Points2D,
        Points3D, RecordingStream, TextLog, Transform3D,
    };

    /// A Rerun recording stream.
    pub struct Stream {
        stream: RecordingStream,
        /// Whether it streams to a viewer (not a file).
        viewer: bool,
    }

    /// Opens the stream to `target` under the application id `name`.
    pub fn open_stream(target: &Target, name: &'static str) -> Result<Stream, ViewError> {
        let builder = rerun::RecordingStreamBuilder::new(name);
        let stream = match target {
            Target::File(path) => builder.save(path).map_err(|e| ViewError::Create {
                path: path.clone(),
                error: e.to_string(),
            })?,
            Target::Connect(address) => {
                builder
                    .connect_grpc_opts(address.clone())
                    .map_err(|e| ViewError::Connect {
                        address: address.clone(),
                        message: e.to_string(),
                    })?
            }
        };
        let viewer = matches!(target, Target::Connect(_));
        Ok(Stream { stream, viewer })
    }

    fn colours(list: &[[u8; 3]]) -> Vec<Color> {
        list.iter()
            .map(|c| Color::from_rgb(c[0], c[1], c[2]))
            .collect()
    }

    fn vec3(v: &nalgebra::Vector3<f64>) -> [f32; 3] {
        [v.x as f32, v.y as f32, v.z as f32]
    }

    impl Stream {
        /// Logs one message (images scaled and compressed here, off the tracking thread).
        pub fn log(&self, message: &Message, config: &OutputConfig) -> Result<(), ViewError> {
            let stream = &self.stream;
            match message.at {
                At::Frame { index, seconds } => {
                    stream.set_time_sequence("frame", index as i64);
                    // TUM's stamps are Unix times (shown as dates), KITTI's and most
                    // recordings' own clocks start near 0 (shown as durations).
                    if seconds > UNIX_TIME_AFTER {
                        stream.set_timestamp_secs_since_epoch("time", seconds);
                    } else {
                        stream.set_duration_secs("time", seconds);
                    }
                }
                At::Always => {}
            }
            let logged = self.log_entry(message, config);
            logged.map_err(|e| ViewError::Sdk {
                stage: "log to",
                message: e.to_string(),
            })
        }

        fn send<A: rerun::AsComponents>(
            &self,
            at: At,
            path: String,
            value: &A,
        ) -> rerun::RecordingStreamResult<()> {
            match at {
                At::Always => self.stream.log_static(path, value),
                At::Frame { .. } => self.stream.log(path, value),
            }
        }

        /// Each entry to the method of its group (every variant named: a new one
        /// must be given a group).
        fn log_entry(
            &self,
            message: &Message,
            config: &OutputConfig,
        ) -> rerun::RecordingStreamResult<()> {
            match &message.entry {
                Entry::Pinhole { .. }
                | Entry::Camera { .. }
                | Entry::Image(_)
                | Entry::Depth { .. } => self.log_camera(message, config),
                Entry::Keypoints { .. } | Entry::Boxes(_) => self.log_pixels(message, config),
                Entry::MapPoints { .. }
                | Entry::Keyframes(_)
                | Entry::Trajectory { .. }
                | Entry::Event { .. }
                | Entry::LoopEdges(_)
                | Entry::Mesh { .. }
                | Entry::Cloud { .. } => self.log_world(message),
            }
        }

        /// The camera: its pinhole, pose, image and depth.
        fn log_camera(
            &self,
            message: &Message,
            config: &OutputConfig,
        ) -> rerun::RecordingStreamResult<()> {
            let (prefix, at) = (message.prefix.as_ref(), message.at);
            let scale = config.rerun_image_scale as f32;
            let at_path = |rest: &str| path(prefix, rest);
            match &message.entry {
                Entry::Pinhole {
                    fx,
                    fy,
                    cx,
                    cy,
                    width,
                    height,
                } => {
                    let s = f64::from(scale);
                    let pinhole = Pinhole::from_focal_length_and_resolution(
                        [(fx * s) as f32, (fy * s) as f32],
                        [
                            (*width as f32 * scale).round(),
                            (*height as f32 * scale).round(),
                        ],
                    )
                    .with_principal_point([(cx * s) as f32, (cy * s) as f32]);
                    self.send(at, at_path(IMAGE), &pinhole)
                }
                Entry::Camera { world_from_camera } => {
                    let r = world_from_camera.rotation.matrix();
                    let columns: [[f32; 3]; 3] =
                        std::array::from_fn(|c| std::array::from_fn(|row| r[(row, c)] as f32));
                    let transform = Transform3D::from_translation_mat3x3(
                        vec3(&world_from_camera.translation.vector),
                        rerun::datatypes::Mat3x3::from(columns),
                    );
                    self.send(at, at_path(CAMERA), &transform)
                }
                Entry::Image(rgb) => {
                    let jpeg = encode_jpeg(rgb, scale, config.rerun_jpeg_quality);
                    let image = EncodedImage::from_file_contents(jpeg)
                        .with_media_type(rerun::MediaType::JPEG);
                    self.send(at, at_path(IMAGE), &image)
                }
                Entry::Depth {
                    metres,
                    width,
                    height,
                } => {
                    let (data, size) = scale_depth(metres, *width, *height, scale);
                    let bytes: Vec<u8> = data.iter().flat_map(|d| d.to_le_bytes()).collect();
                    let depth = DepthImage::from_data_type_and_bytes(
                        bytes,
                        [size.0, size.1],
                        rerun::datatypes::ChannelDatatype::F32,
                    )
                    .with_meter(1.0);
                    self.send(at, at_path(DEPTH), &depth)
                }
                _ => unreachable!("log_entry sends only these here"),
            }
        }

        /// What is drawn on the image: keypoints and boxes (scaled with it).
        fn log_pixels(
            &self,
            message: &Message,
            config: &OutputConfig,
        ) -> rerun::RecordingStreamResult<()> {
            let (prefix, at) = (message.prefix.as_ref(), message.at);
            let scale = config.rerun_image_scale as f32;
            let at_path = |rest: &str| path(prefix, rest);
            match &message.entry {
                Entry::Keypoints { kept, removed } => {
                    let positions = kept.iter().map(|(p, _)| [p[0] * scale, p[1] * scale]);
                    let colours: Vec<Color> = kept
                        .iter()
                        .map(|(_, m)| {
                            let c = probability_colour(*m);
                            Color::from_rgb(c[0], c[1], c[2])
                        })
                        .collect();
                    let points = Points2D::new(positions)
                        .with_colors(colours)
                        .with_radii([2.0]);
                    self.send(at, at_path(KEYPOINTS), &points)?;
                    let removed =
                        Points2D::new(removed.iter().map(|p| [p[0] * scale, p[1] * scale]))
                            .with_colors([Color::from_rgb(255, 0, 255)])
                            .with_radii([3.5]);
                    self.send(at, at_path(REMOVED), &removed)
                }
                Entry::Boxes(detections) => {
                    let mins = detections
                        .iter()
                        .map(|(_, d)| [d.bbox[0] * scale, d.bbox[1] * scale]);
                    let sizes = detections.iter().map(|(_, d)| {
                        [
                            (d.bbox[2] - d.bbox[0]) * scale,
                            (d.bbox[3] - d.bbox[1]) * scale,
                        ]
                    });
                    let labels = detections
                        .iter()
                        .map(|(keyframe, d)| format!("{} {:.2} (kf {keyframe})", d.class, d.score));
                    let boxes = Boxes2D::from_mins_and_sizes(mins, sizes).with_labels(labels);
                    self.send(at, at_path(DETECTIONS), &boxes)
                }
                _ => unreachable!("log_entry sends only these here"),
            }
        }

        /// The world: map points, keyframes, trajectories, events, loops, the dense map.
        fn log_world(&self, message: &Message) -> rerun::RecordingStreamResult<()> {
            let (prefix, at) = (message.prefix.as_ref(), message.at);
            let at_path = |rest: &str| path(prefix, rest);
            match &message.entry {
                Entry::MapPoints { fixed, moving } => {
                    let fixed_points = Points3D::new(fixed.iter().map(vec3))
                        .with_colors([Color::from_rgb(200, 200, 200)])
                        .with_radii([0.01]);
                    self.send(at, at_path(MAP_STATIC), &fixed_points)?;
                    let moving_points = Points3D::new(moving.iter().map(vec3))
                        .with_colors([Color::from_rgb(255, 40, 40)])
                        .with_radii([0.02]);
                    self.send(at, at_path(MAP_MOVING), &moving_points)
                }
                Entry::Keyframes(centres) => {
                    let points = Points3D::new(centres.iter().map(vec3))
                        .with_colors([Color::from_rgb(60, 120, 255)])
                        .with_radii([0.03]);
                    self.send(at, at_path(KEYFRAMES), &points)
                }
                Entry::Trajectory {
                    name,
                    piece,
                    centres,
                } => {
                    let colour = trajectory_colour(name, prefix);
                    let strip = LineStrips3D::new([centres.iter().map(vec3).collect::<Vec<_>>()])
                        .with_colors([colour]);
                    self.send(at, at_path(&trajectory_entity(name, *piece)), &strip)
                }
                Entry::Event {
                    level,
                    text,
                    about_loops,
                } => {
                    let level = match level {
                        Level::Info => rerun::TextLogLevel::INFO,
                        Level::Warning => rerun::TextLogLevel::WARN,
                    };
                    let log = TextLog::new(text.as_str()).with_level(level);
                    let entity = if *about_loops {
                        format!("{}/loops", at_path(EVENTS))
                    } else {
                        at_path(EVENTS)
                    };
                    self.send(at, entity, &log)
                }
                Entry::LoopEdges(edges) => {
                    let strips = edges.iter().map(|(a, b)| vec![vec3(a), vec3(b)]);
                    let lines =
                        LineStrips3D::new(strips).with_colors([Color::from_rgb(255, 160, 0)]);
                    self.send(at, at_path(LOOPS), &lines)
                }
                Entry::Mesh {
                    vertices,
                    triangles,
                    colours: vertex_colours,
                } => {
                    let mut mesh = Mesh3D::new(vertices.iter().copied()).with_triangle_indices(
                        triangles.iter().map(|t| rerun::datatypes::UVec3D::from(*t)),
                    );
                    if !vertex_colours.is_empty() {
                        mesh = mesh.with_vertex_colors(colours(vertex_colours));
                    }
                    self.send(at, at_path(MESH), &mesh)
                }
                Entry::Cloud {
                    points,
                    colours: point_colours,
                } => {
                    let mut cloud = Points3D::new(points.iter().copied()).with_radii([0.005]);
                    if !point_colours.is_empty() {
                        cloud = cloud.with_colors(colours(point_colours));
                    }
                    self.send(at, at_path(CLOUD), &cloud)
                }
                _ => unreachable!("log_entry sends only these here"),
            }
        }

        /// Writes what is buffered and closes the stream; whether all was delivered. A
        /// viewer gets [`crate::view::entry::VIEWER_PATIENCE`] to take the rest; one that
        /// takes nothing is left (the SDK's own close would wait for it for ever).
        pub fn close(self) -> Result<bool, ViewError> {
            if self.viewer {
                let flushed = self
                    .stream
                    .flush_with_timeout(crate::view::entry::VIEWER_PATIENCE);
                if flushed.is_err() {
                    std::mem::forget(self.stream);
                    return Ok(false);
                }
            } else {
                self.stream.flush_blocking().map_err(|e| ViewError::Sdk {
                    stage: "finish",
                    message: e.to_string(),
                })?;
            }
            self.stream.disconnect();
            Ok(true)
        }
    }

    /// The image scaled by `scale`, as JPEG of `quality`.
    fn encode_jpeg(rgb: &image::RgbImage, scale: f32, quality: u8) -> Vec<u8> {
        let (w, h) = rgb.dimensions();
        let size = (
            ((w as f32 * scale).round() as u32).max(1),
            ((h as f32 * scale).round() as u32).max(1),
        );
        let scaled;
        let image = if size == (w, h) {
            rgb
        } else {
            // A box filter (each output pixel the mean of those it covers): a
            // fraction of a triangle filter's cost on the logging thread.
            scaled = image::imageops::thumbnail(rgb, size.0, size.1);
            &scaled
        };
        let mut bytes = Vec::new();
        let mut encoder = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, quality);
        encoder
            .encode_image(image)
            .expect("encoding an RGB image into memory cannot fail");
        bytes
    }

    /// The entity of the trajectory `name` (of one `piece` of it, when drawn in pieces).
    fn trajectory_entity(name: &str, piece: Option<usize>) -> String {
        match piece {
            Some(piece) => format!("{TRAJECTORY}/{name}/{piece}"),
            None => format!("{TRAJECTORY}/{name}"),
        }
    }

    /// A trajectory's colour: the truth grey; the run's final green, its tracking
    /// pass blue; a baseline's red; a merged map's recordings each their own.
    fn trajectory_colour(name: &str, prefix: &str) -> Color {
        const RECORDINGS: [(u8, u8, u8); 6] = [
            (40, 200, 80),
            (255, 150, 30),
            (60, 160, 255),
            (200, 80, 220),
            (240, 220, 40),
            (30, 210, 200),
        ];
        let recording = prefix
            .strip_prefix("recordings/")
            .and_then(|rest| rest.split('_').next()?.parse::<usize>().ok());
        match (name, prefix.is_empty(), recording) {
            ("truth", _, _) => Color::from_rgb(120, 120, 120),
            (_, false, Some(k)) => {
                let (r, g, b) = RECORDINGS[k.saturating_sub(1) % RECORDINGS.len()];
                Color::from_rgb(r, g, b)
            }
            (_, false, None) => Color::from_rgb(230, 60, 60),
            ("final", true, _) => Color::from_rgb(40, 200, 80),
            _ => Color::from_rgb(60, 120, 255),
        }
    }

    /// Depth scaled by `scale` (nearest sample: depths are not blended).
    fn scale_depth(metres: &[f32], w: u32, h: u32, scale: f32) -> (Vec<f32>, (u32, u32)) {
        let size = (
            ((w as f32 * scale).round() as u32).max(1),
            ((h as f32 * scale).round() as u32).max(1),
        );
        let mut out = Vec::with_capacity((size.0 * size.1) as usize);
        for v in 0..size.1 {
            let y = ((v as f32 + 0.5) / scale).min(h as f32 - 1.0) as usize;
            for u in 0..size.0 {
                let x = ((u as f32 + 0.5) / scale).min(w as f32 - 1.0) as usize;
                out.push(metres[y * w as usize + x]);
            }
        }
        (out, size)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn probability_ramp_runs_green_yellow_red() {
        assert_eq!(probability_colour(0.0), [0, 255, 0]);
        assert_eq!(probability_colour(0.5), [255, 255, 0]);
        assert_eq!(probability_colour(1.0), [255, 0, 0]);
        assert_eq!(probability_colour(f32::NAN), [255, 255, 0]);
    }

    #[test]
    fn prefixes_go_after_world() {
        assert_eq!(path("", CAMERA), "world/camera");
        assert_eq!(
            path("no_dop", "trajectory/final"),
            "world/no_dop/trajectory/final"
        );
        assert_eq!(path("", EVENTS), "events");
        assert_eq!(path("no_dop", EVENTS), "no_dop/events");
    }
}
