//! Recordings as sensors and `rosbag record` write them, read as a [`Sequence`]: ROS 1
//! bags (`.bag`), ROS 2 bags (a folder with `metadata.yaml`, SQLite `.db3` or `.mcap`
//! storage), single `.db3` / `.mcap` files, and Azure Kinect `.mkv` recordings
//! ([`kinect`]).
//!
//! Opening a recording scans it once into a [`Catalog`]: each topic's messages with
//! their header stamps and where they lie ([`Location`]); no image is kept. Frames
//! then load one at a time from the [`Store`], so a recording of any size streams.
//! The topics are chosen as described in [`topics`], the calibration comes from the
//! colour stream's `sensor_msgs/CameraInfo` (or the recording's own, [`RecordedCameras`]).

pub mod convert;
pub mod frames;
pub mod kinect;
pub mod mapped;
pub mod matroska;
mod mcap_chunks;
pub mod messages;
pub mod realsense;
pub mod register;
pub mod ros1;
pub mod ros2;
pub mod tf;
pub mod topics;

use std::borrow::Cow;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

pub use messages::Wire;
pub use topics::TopicChoice;

use super::orbslam_settings::Calibration;
use super::sequence::{Frame, FrameImages, SensorKind, Sequence};
use super::{IoError, Trajectory};
use crate::geometry::camera::PinholeCamera;

/// Where a message lies in its store: two numbers whose meaning is the store's (a ROS 1
/// chunk's byte position and an offset in it; an MCAP chunk and a message's ordinal in
/// it; a SQLite row id).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Location(pub u64, pub u64);

/// One message of a topic: its stamp (the `std_msgs/Header` stamp, else the time it was
/// recorded) and where it lies.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Entry {
    /// The header stamp (else the receive time), seconds.
    pub stamp: f64,
    /// Where the message lies.
    pub at: Location,
}

/// A topic of a recording with its messages in stamp order.
#[derive(Debug, Clone)]
pub struct Topic {
    /// The topic's name.
    pub name: String,
    /// The message type in ROS 1 spelling (`sensor_msgs/Image`, also for ROS 2's
    /// `sensor_msgs/msg/Image`).
    pub msg_type: String,
    /// Its messages, in time order.
    pub messages: Vec<Entry>,
}

impl Topic {
    /// Messages per second over its stamps' span; `None` with fewer than two messages
    /// or no span.
    pub fn rate(&self) -> Option<f64> {
        let (first, last) = (self.messages.first()?, self.messages.last()?);
        let span = last.stamp - first.stamp;
        (self.messages.len() > 1 && span > 0.0).then(|| (self.messages.len() - 1) as f64 / span)
    }
}

/// The message types read for frames and calibration.
pub const IMAGE: &str = "sensor_msgs/Image";
/// `sensor_msgs/CompressedImage`.
pub const COMPRESSED: &str = "sensor_msgs/CompressedImage";
/// `sensor_msgs/CameraInfo`.
pub const CAMERA_INFO: &str = "sensor_msgs/CameraInfo";

fn has_header(msg_type: &str) -> bool {
    [IMAGE, COMPRESSED, CAMERA_INFO].contains(&msg_type)
}

/// The cameras a recording carries in its own format (an Azure Kinect's
/// `calibration.json`), where a bag has `CameraInfo` topics and `/tf_static`.
#[derive(Debug, Clone)]
pub struct RecordedCameras {
    /// Where in the recording they are (`the calibration.json attachment`).
    pub from: String,
    /// The colour camera, for the colour images' size.
    pub colour: PinholeCamera,
    /// The depth camera, for the depth images' size.
    pub depth: PinholeCamera,
    /// \(T_{colour,depth}\): a depth-camera point into the colour camera.
    pub colour_from_depth: nalgebra::Isometry3<f64>,
    /// What the reader found, for `dopslam info`.
    pub notes: Vec<String>,
}

/// What a scan of a recording found.
#[derive(Debug, Clone)]
pub struct Catalog {
    /// How its messages are encoded.
    pub wire: Wire,
    /// Its topics.
    pub topics: Vec<Topic>,
    /// The store's topic or connection ids to indices into `topics` (ROS 1 bags may have
    /// several connections for one topic).
    ids: HashMap<u64, usize>,
    /// Said once to the user: no index, cut short, stamps out of order.
    pub warnings: Vec<String>,
    /// Messages of our types whose header could not be decoded, by topic.
    undecodable: HashMap<usize, usize>,
    /// The recording's own cameras, when it carries them outside its topics.
    pub recorded: Option<RecordedCameras>,
}

impl Catalog {
    /// An empty catalog of `wire`-encoded messages.
    pub fn new(wire: Wire) -> Self {
        Self {
            wire,
            topics: Vec::new(),
            ids: HashMap::new(),
            warnings: Vec::new(),
            undecodable: HashMap::new(),
            recorded: None,
        }
    }

    /// Declares the store's topic `id`.
    pub fn add_topic(&mut self, id: impl Into<u64>, name: &str, msg_type: &str) {
        let msg_type = msg_type.replacen("/msg/", "/", 1);
        let index = match self.topics.iter().position(|t| t.name == name) {
            Some(i) => i,
            None => {
                self.topics.push(Topic {
                    name: name.to_owned(),
                    msg_type,
                    messages: Vec::new(),
                });
                self.topics.len() - 1
            }
        };
        self.ids.insert(id.into(), index);
    }

    /// Adds a message of topic `id` whose stamp the store knows already (an Azure
    /// Kinect block's time).
    pub fn add_entry(&mut self, id: impl Into<u64>, entry: Entry) {
        if let Some(&index) = self.ids.get(&id.into()) {
            self.topics[index].messages.push(entry);
        }
    }

    /// Adds a message of topic `id`; `received` (seconds) stands in for a missing or
    /// zero header stamp.
    pub fn add_message(&mut self, id: impl Into<u64>, at: Location, data: &[u8], received: f64) {
        let Some(&index) = self.ids.get(&id.into()) else {
            return;
        };
        let topic = &mut self.topics[index];
        let stamp = if has_header(&topic.msg_type) {
            match messages::stamp(data, self.wire) {
                Ok(stamp) if stamp > 0.0 => stamp,
                Ok(_) => received,
                Err(_) => {
                    *self.undecodable.entry(index).or_default() += 1;
                    return;
                }
            }
        } else {
            received
        };
        topic.messages.push(Entry { stamp, at });
    }

    /// Sorts each topic by stamp (saying where they were out of order). Topics without
    /// messages stay: errors list them.
    pub fn finish(mut self) -> Self {
        for (index, count) in &self.undecodable {
            self.warnings.push(format!(
                "{count} messages of topic {} could not be decoded as {} and are skipped",
                self.topics[*index].name, self.topics[*index].msg_type
            ));
        }
        for topic in &mut self.topics {
            let out_of_order = topic
                .messages
                .windows(2)
                .filter(|w| w[1].stamp < w[0].stamp)
                .count();
            if out_of_order > 0 {
                self.warnings.push(format!(
                    "topic {}: {out_of_order} messages come before an earlier stamp; they are read in stamp order",
                    topic.name
                ));
                topic.messages.sort_by(|a, b| a.stamp.total_cmp(&b.stamp));
            }
        }
        self
    }

    /// The topic named `name`.
    pub fn topic(&self, name: &str) -> Option<&Topic> {
        self.topics.iter().find(|t| t.name == name)
    }
}

/// Reads a message's bytes back from where the scan found it.
pub trait Store: Send + Sync {
    /// The bytes of the message at `at`: borrowed where the store holds them as they
    /// are (a message stored uncompressed in a memory-mapped file, [`mapped`]), else
    /// its own copy.
    fn read(&self, at: Location) -> Result<Cow<'_, [u8]>, IoError>;
}

/// How to read a recording (from `[dataset]` and the command line).
#[derive(Debug, Clone, Default)]
pub struct RecordingOptions {
    /// The topics to read.
    pub topics: TopicChoice,
    /// Raw 16-bit depth units per metre; `None`: 1000 (millimetres, REP 118).
    pub depth_scale: Option<f64>,
    /// Tolerance in seconds for pairing colour and depth stamps.
    pub max_difference: f64,
    /// A TUM trajectory file as the ground truth (for a recording without a pose topic).
    pub ground_truth_file: Option<PathBuf>,
}

/// Whether `path` looks like a recording rather than a sequence folder.
pub fn is_recording(path: &Path) -> bool {
    if path.is_dir() {
        // A folder is a ROS 2 bag by what it holds, whatever its name (a TUM folder
        // may be called `x.bag`): its metadata, or storage files and no image lists.
        let lists = ["rgb.txt", "associations.txt", "image_0"];
        return path.join("metadata.yaml").is_file()
            || (!lists.iter().any(|l| path.join(l).exists()) && ros2::has_storage_files(path));
    }
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
    matches!(ext, "bag" | "mcap" | "db3" | "mkv")
}

/// Opens the store of a recording by its kind.
fn open_store(path: &Path) -> Result<(Box<dyn Store>, Catalog), IoError> {
    super::errors::check_exists(path, "recording")?;
    let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
    if path.is_dir() {
        return ros2::open_bag_folder(path);
    }
    match ext {
        "bag" => {
            let (bag, catalog) = ros1::Ros1Bag::open(path)?;
            Ok((Box::new(bag), catalog))
        }
        "mcap" => ros2::open_mcap(path),
        "db3" => ros2::open_sqlite(path),
        "mkv" => kinect::open(path),
        _ => Err(IoError::invalid(
            path,
            "not a recording (.bag, .mcap, .db3, .mkv or a ROS 2 bag folder)",
        )),
    }
}

/// A recording read as a sequence of RGB-D frames.
pub struct RecordingSequence {
    name: String,
    path: PathBuf,
    store: Box<dyn Store>,
    wire: Wire,
    /// Colour and depth, or left and right of a stereo pair.
    frames: Vec<frames::FramePair>,
    sensor: SensorKind,
    calibration: Option<Calibration>,
    depth_scale: f64,
    /// How depth reaches the colour camera, when it is recorded in its own.
    registration: Option<register::Registration>,
    ground_truth: Option<Trajectory>,
    /// What the scan and the topic choice said, for `dopslam info` and the run's log.
    pub description: frames::Description,
}

impl std::fmt::Debug for RecordingSequence {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RecordingSequence")
            .field("path", &self.path)
            .field("frames", &self.frames.len())
            .finish()
    }
}

impl RecordingSequence {
    /// Opens a recording: scans it, chooses the topics, pairs colour and depth.
    pub fn open(path: &Path, options: &RecordingOptions) -> Result<Self, IoError> {
        let (store, catalog) = open_store(path)?;
        let mut catalog = catalog.finish();
        let device_stamps = realsense::device_stamps(&mut catalog, store.as_ref())?;
        let choice = topics::choose(path, &catalog, store.as_ref(), &options.topics)?;
        let registration = match &catalog.recorded {
            Some(c) => Some((
                register::Registration::new(&c.depth, &c.colour, c.colour_from_depth),
                c.from.clone(),
            )),
            None => topics::registration(path, &catalog, store.as_ref(), &choice)?,
        };
        let (registration, registered_by) = registration.unzip();
        let recorded_scale = realsense::depth_scale(&catalog, store.as_ref())?;
        let ground_truth = match (&options.topics.ground_truth, &options.ground_truth_file) {
            (Some(topic), Some(file)) => {
                return Err(IoError::invalid(
                    file,
                    format!("the ground truth is given twice, as this file and as topic {topic}: choose one"),
                ))
            }
            (Some(topic), None) => Some(topics::ground_truth(path, &catalog, store.as_ref(), topic)?),
            (None, Some(file)) => Some(Trajectory::read_tum(file)?),
            (None, None) => None,
        };
        let depth_scale = options.depth_scale.or(recorded_scale).unwrap_or(1000.0);
        if !(depth_scale.is_finite() && depth_scale > 0.0) {
            return Err(IoError::invalid(
                path,
                format!("depth scale must be positive, got {depth_scale}"),
            ));
        }
        let frames = frames::pair(path, &catalog, &choice, options.max_difference)?;
        let calibration = calibration(path, &catalog, store.as_ref(), &choice)?;
        let sensor = if choice.stereo.is_some() {
            SensorKind::Stereo
        } else {
            SensorKind::Rgbd
        };
        let name = path
            .file_stem()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "recording".into());
        let mut description = frames::Description::new(&catalog, &choice, frames.len());
        description.notes = device_stamps;
        if let Some(recorded) = &catalog.recorded {
            description.notes.extend(recorded.notes.iter().cloned());
            description.cameras_from = Some(recorded.from.clone());
        }
        description.registered = registration.is_none();
        description.registered_by = registered_by;
        description.depth_scale = depth_scale;
        Ok(Self {
            name,
            path: path.to_path_buf(),
            store,
            wire: catalog.wire,
            frames,
            calibration,
            depth_scale,
            sensor,
            registration,
            ground_truth,
            description,
        })
    }

    fn reader(&self) -> frames::Reader<'_> {
        frames::Reader {
            path: &self.path,
            store: self.store.as_ref(),
            wire: self.wire,
            registration: self.registration.as_ref(),
        }
    }

    /// The recording's path.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// The calibration of the chosen topics: the colour camera's info (or the recording's
/// own cameras), with the stereo baseline of a pair.
fn calibration(
    path: &Path,
    catalog: &Catalog,
    store: &dyn Store,
    chosen: &topics::Chosen,
) -> Result<Option<Calibration>, IoError> {
    let calibration = match (&chosen.camera_info, &catalog.recorded) {
        (Some(info), _) => Some(topics::calibration(
            path,
            catalog,
            store,
            info,
            &chosen.colour,
        )?),
        (None, Some(recorded)) => Some(Calibration {
            camera: recorded.colour,
            bf: None,
            depth_scale: None,
            th_depth: None,
            fps: catalog.topic(&chosen.colour).and_then(Topic::rate),
        }),
        (None, None) => None,
    };
    Ok(match (&chosen.stereo, calibration) {
        (Some(right_info), Some(mut calibration)) => {
            calibration.bf = Some(topics::stereo_bf(
                path,
                catalog,
                store,
                right_info.as_deref(),
            )?);
            Some(calibration)
        }
        (_, calibration) => calibration,
    })
}

impl Sequence for RecordingSequence {
    fn name(&self) -> &str {
        &self.name
    }

    fn warnings(&self) -> &[String] {
        &self.description.warnings
    }

    fn sensor(&self) -> SensorKind {
        self.sensor
    }

    fn len(&self) -> usize {
        self.frames.len()
    }

    fn timestamp(&self, index: usize) -> f64 {
        self.frames[index].colour.stamp
    }

    fn load(&self, index: usize) -> Result<Frame, IoError> {
        let pair = &self.frames[index];
        let reader = self.reader();
        if self.sensor == SensorKind::Stereo {
            let (left, right) = (
                reader.grey(&pair.colour, pair.colour_compressed)?,
                reader.grey(&pair.depth, pair.depth_compressed)?,
            );
            if left.dimensions() != right.dimensions() {
                let (l, r) = (left.dimensions(), right.dimensions());
                return Err(IoError::invalid(
                    &self.path,
                    format!(
                        "frame {index}: the left image is {}x{}, the right {}x{}",
                        l.0, l.1, r.0, r.1
                    ),
                ));
            }
            return Ok(Frame {
                index,
                timestamp: pair.colour.stamp,
                images: FrameImages::Stereo { left, right },
            });
        }
        let rgb = reader.colour(&pair.colour, pair.colour_compressed)?;
        let depth = reader.depth(&pair.depth, pair.depth_compressed, self.depth_scale)?;
        if (rgb.width(), rgb.height()) != (depth.width, depth.height) {
            return Err(IoError::invalid(
                &self.path,
                format!(
                    "frame {index}: depth is {}x{} but its colour image is {}x{} (is the depth registered to the colour camera?)",
                    depth.width, depth.height, rgb.width(), rgb.height()
                ),
            ));
        }
        Ok(Frame {
            index,
            timestamp: pair.colour.stamp,
            images: FrameImages::Rgbd { rgb, depth },
        })
    }

    fn load_depth(&self, index: usize) -> Result<Option<super::image_files::DepthImage>, IoError> {
        if self.sensor == SensorKind::Stereo {
            return Ok(None);
        }
        let reader = self.reader();
        let pair = &self.frames[index];
        Ok(Some(reader.depth(
            &pair.depth,
            pair.depth_compressed,
            self.depth_scale,
        )?))
    }

    fn ground_truth(&self) -> Option<&Trajectory> {
        self.ground_truth.as_ref()
    }

    fn calibration(&self) -> Option<&Calibration> {
        self.calibration.as_ref()
    }
}
