//! Which topics of a recording make the frames, and the calibration they carry.
//!
//! Without options: the colour stream is the `Image` / `CompressedImage` topic whose
//! first message has a colour encoding (names with `color`, `colour` or `rgb` first,
//! 8-bit grey infrared last); the depth stream the one with a depth encoding (`16UC1`,
//! `32FC1`, `compressedDepth`; names with `registered` or `aligned` first); the camera
//! info the `CameraInfo` topic sharing the longest name prefix with the colour topic.
//! Where two topics tie, the choice is the user's: the error lists them.

use std::path::Path;

use super::messages::{self, Wire};
use super::register::Registration;
use super::{tf, Catalog, Store, Topic, CAMERA_INFO, COMPRESSED, IMAGE};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};

use crate::geometry::camera::PinholeCamera;
use crate::geometry::se3::Se3;
use crate::io::orbslam_settings::Calibration;
use crate::io::IoError;
use crate::io::Trajectory;

/// The topics the user named (`[dataset] rgb_topic`, `depth_topic`, `camera_info_topic`,
/// `ground_truth_topic`, the same options of the command line and batch manifests).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TopicChoice {
    /// The colour topic.
    pub rgb: Option<String>,
    /// The depth topic.
    pub depth: Option<String>,
    /// The camera-info topic.
    pub camera_info: Option<String>,
    /// A pose topic read as the ground truth; never chosen unnamed.
    pub ground_truth: Option<String>,
}

/// The topics chosen.
#[derive(Debug, Clone, PartialEq)]
pub struct Chosen {
    /// The colour image; of a stereo pair, the left image.
    pub colour: String,
    /// The depth image; of a stereo pair, the right image.
    pub depth: String,
    /// The colour (left) camera's info.
    pub camera_info: Option<String>,
    /// A rectified stereo pair (no depth topic, a `left` and a `right` image topic):
    /// the right camera's info, whose projection holds the baseline.
    pub stereo: Option<Option<String>>,
}

/// What a stream of images holds, from its first message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Content {
    Colour,
    Grey,
    Depth,
    Other,
}

fn content(topic: &Topic, store: &dyn Store, wire: Wire) -> Result<Content, IoError> {
    let data = store.read(topic.messages[0].at)?;
    Ok(match topic.msg_type.as_str() {
        IMAGE => match messages::image(&data, wire).map(|i| i.encoding) {
            Ok(e) if ["rgb8", "bgr8", "rgba8", "bgra8"].contains(&e.as_str()) => Content::Colour,
            Ok(e) if e == "mono8" => Content::Grey,
            Ok(e) if ["16UC1", "32FC1", "mono16"].contains(&e.as_str()) => Content::Depth,
            _ => Content::Other,
        },
        COMPRESSED => match messages::compressed(&data, wire).map(|c| c.format) {
            Ok(f) if f.contains("compressedDepth") => Content::Depth,
            Ok(_) => Content::Colour,
            Err(_) => Content::Other,
        },
        _ => Content::Other,
    })
}

/// The list of topics for an error: name, type and message count.
pub fn listing(catalog: &Catalog) -> String {
    let mut lines: Vec<String> = catalog
        .topics
        .iter()
        .map(|t| format!("{} ({}, {} messages)", t.name, t.msg_type, t.messages.len()))
        .collect();
    lines.sort();
    let listed = if lines.is_empty() {
        "it has no messages it can read".to_owned()
    } else {
        format!("its topics: {}", lines.join(", "))
    };
    // What the reader read past says why a topic may be missing (cut short, a
    // serialisation not read).
    if catalog.warnings.is_empty() {
        listed
    } else {
        format!("{listed}; and {}", catalog.warnings.join("; "))
    }
}

/// A topic named by the user: it must exist and have one of `types`.
fn named<'a>(
    path: &Path,
    catalog: &'a Catalog,
    name: &str,
    types: &[&str],
    key: &str,
) -> Result<&'a Topic, IoError> {
    let topic = catalog
        .topic(name)
        .filter(|t| !t.messages.is_empty())
        .ok_or_else(|| {
            IoError::invalid(
                path,
                format!(
                    "{key} {name}: no such topic with messages; {}",
                    listing(catalog)
                ),
            )
        })?;
    if !types.contains(&topic.msg_type.as_str()) {
        return Err(IoError::invalid(
            path,
            format!(
                "{key} {name} carries {}, not {}",
                topic.msg_type,
                types.join(" or ")
            ),
        ));
    }
    Ok(topic)
}

/// The best-ranked topic among `candidates` (lower rank first); an error when none, or
/// when two share the best rank.
fn best(
    path: &Path,
    catalog: &Catalog,
    mut candidates: Vec<(u8, &Topic)>,
    what: &str,
    key: &str,
) -> Result<String, IoError> {
    candidates.sort_by_key(|(rank, t)| (*rank, t.name.clone()));
    match candidates.as_slice() {
        [] => Err(IoError::invalid(
            path,
            format!("no {what} topic found; {}", listing(catalog)),
        )),
        [(r0, a), (r1, b), ..] if r0 == r1 => Err(IoError::invalid(
            path,
            format!(
                "two {what} topics, {} and {}: name one with {key}",
                a.name, b.name
            ),
        )),
        [(_, first), ..] => Ok(first.name.clone()),
    }
}

fn contains_any(name: &str, words: &[&str]) -> bool {
    let lower = name.to_ascii_lowercase();
    words.iter().any(|w| lower.contains(w))
}

/// Topics with their rank (lowest first).
type Ranked<'a> = Vec<(u8, &'a Topic)>;

/// The recording's image topics with messages, by content: colour (and grey) and
/// depth, each ranked (0 first: a name that says what it carries; grey last).
fn image_topics<'a>(
    catalog: &'a Catalog,
    store: &dyn Store,
) -> Result<(Ranked<'a>, Ranked<'a>), IoError> {
    let images = [IMAGE, COMPRESSED];
    let mut colour = Vec::new();
    let mut depth = Vec::new();
    for topic in catalog
        .topics
        .iter()
        .filter(|t| !t.messages.is_empty() && images.contains(&t.msg_type.as_str()))
    {
        match content(topic, store, catalog.wire)? {
            Content::Colour => colour.push((
                u8::from(!contains_any(&topic.name, &["color", "colour", "rgb"])),
                topic,
            )),
            Content::Grey => colour.push((2, topic)),
            Content::Depth => depth.push((
                u8::from(!contains_any(&topic.name, &["registered", "aligned"])),
                topic,
            )),
            Content::Other => {}
        }
    }
    Ok((colour, depth))
}

/// Chooses the colour, depth and camera-info topics.
pub fn choose(
    path: &Path,
    catalog: &Catalog,
    store: &dyn Store,
    choice: &TopicChoice,
) -> Result<Chosen, IoError> {
    let images = [IMAGE, COMPRESSED];
    let (colour, depth) = image_topics(catalog, store)?;
    if choice.depth.is_none() && depth.is_empty() {
        if let Some(pair) = stereo_pair(catalog, &colour, choice) {
            return Ok(pair);
        }
    }
    let colour = match &choice.rgb {
        Some(name) => named(path, catalog, name, &images, "rgb_topic")?
            .name
            .clone(),
        None => best(
            path,
            catalog,
            colour,
            "colour image",
            "--rgb-topic ([dataset] rgb_topic)",
        )?,
    };
    let depth = match &choice.depth {
        Some(name) => {
            let topic = named(path, catalog, name, &images, "depth_topic")?;
            if matches!(
                content(topic, store, catalog.wire)?,
                Content::Colour | Content::Grey
            ) {
                return Err(IoError::invalid(
                    path,
                    format!("depth_topic {name} carries colour or grey images, not depth (16UC1, 32FC1, mono16 or compressedDepth)"),
                ));
            }
            topic.name.clone()
        }
        None if depth.is_empty() => return Err(monocular(path, catalog)),
        None => best(
            path,
            catalog,
            depth,
            "depth image",
            "--depth-topic ([dataset] depth_topic)",
        )?,
    };
    let camera_info = match &choice.camera_info {
        Some(name) => Some(
            named(path, catalog, name, &[CAMERA_INFO], "camera_info_topic")?
                .name
                .clone(),
        ),
        None => nearest_info(catalog, &colour),
    };
    Ok(Chosen {
        colour,
        depth,
        camera_info,
        stereo: None,
    })
}

/// The error for a recording with neither a depth topic nor a stereo pair.
fn monocular(path: &Path, catalog: &Catalog) -> IoError {
    IoError::invalid(
        path,
        format!(
            "no depth image topic found, and no stereo pair (two image topics named .../left/... and .../right/...): monocular input is not supported, dopslam needs RGB-D or a rectified stereo pair; {}",
            listing(catalog)
        ),
    )
}

/// A rectified stereo pair among the image topics: one whose name has `left` (or the
/// one named by `rgb_topic`) and the same name with `right`.
fn stereo_pair(catalog: &Catalog, images: &[(u8, &Topic)], choice: &TopicChoice) -> Option<Chosen> {
    let mut lefts: Vec<&str> = match &choice.rgb {
        Some(name) => vec![name.as_str()],
        None => images
            .iter()
            .map(|(_, t)| t.name.as_str())
            .filter(|n| n.contains("left"))
            .collect(),
    };
    lefts.sort();
    lefts.into_iter().find_map(|left| {
        let right = left.replacen("left", "right", 1);
        // Two distinct topics: a name without `left` maps onto itself.
        let found = right != left && images.iter().any(|(_, t)| t.name == right);
        found.then(|| Chosen {
            colour: left.to_owned(),
            camera_info: choice
                .camera_info
                .clone()
                .or_else(|| nearest_info(catalog, left)),
            stereo: Some(nearest_info(catalog, &right)),
            depth: right,
        })
    })
}

/// The baseline times the focal length (pixel-metres) of a rectified stereo pair from
/// the right camera's projection, \(P_{03} = -f_x b\).
pub fn stereo_bf(
    path: &Path,
    catalog: &Catalog,
    store: &dyn Store,
    right_info: Option<&str>,
) -> Result<f64, IoError> {
    let missing = || {
        IoError::invalid(path, "a stereo pair needs the right camera's sensor_msgs/CameraInfo with its baseline in P (P[3] = -fx * baseline)")
    };
    let (info, _) = camera_of(path, catalog, store, right_info.ok_or_else(missing)?)?;
    let bf = -info.p[3];
    if !(bf.is_finite() && bf > 0.0) {
        return Err(missing());
    }
    Ok(bf)
}

/// The `CameraInfo` topic whose name shares the longest prefix with `image`'s.
fn nearest_info(catalog: &Catalog, image: &str) -> Option<String> {
    let common = |a: &str| {
        a.bytes()
            .zip(image.bytes())
            .take_while(|(x, y)| x == y)
            .count()
    };
    catalog
        .topics
        .iter()
        .filter(|t| t.msg_type == CAMERA_INFO && !t.messages.is_empty())
        .max_by_key(|t| (common(&t.name), std::cmp::Reverse(t.name.clone())))
        .map(|t| t.name.clone())
}

/// The first `CameraInfo` of `topic` and the camera it describes (plumb_bob, or
/// rational_polynomial without its k4-k6).
fn camera_of(
    path: &Path,
    catalog: &Catalog,
    store: &dyn Store,
    topic: &str,
) -> Result<(messages::CameraInfo, PinholeCamera), IoError> {
    let t = catalog.topic(topic).expect("a chosen topic exists");
    let data = store.read(t.messages[0].at)?;
    let bad = |e: String| IoError::invalid(path, format!("camera info topic {topic}: {e}"));
    let info = messages::camera_info(&data, catalog.wire).map_err(bad)?;
    let [fx, _, cx, _, fy, cy, ..] = info.k;
    if !(fx > 0.0 && fy > 0.0 && cx.is_finite() && cy.is_finite()) {
        return Err(bad(format!(
            "K = {:?} is no calibration (uncalibrated camera?): pass --settings or --camera",
            info.k
        )));
    }
    let (mut distortion, mut rational) = ([0.0; 5], [0.0; 3]);
    // librealsense's own recordings name its models ("Brown Conrady", ...).
    let none = info.d.iter().all(|&k| k == 0.0);
    match info.distortion_model.as_str() {
        "plumb_bob" | "rational_polynomial" | "" | "Brown Conrady" | "None" => {
            for (d, v) in distortion.iter_mut().chain(&mut rational).zip(&info.d) {
                *d = *v;
            }
        }
        _ if none => {}
        other => {
            return Err(bad(format!(
                "distortion model {other:?} with coefficients {:?} is not supported (plumb_bob, rational_polynomial, librealsense's Brown Conrady)",
                info.d
            )))
        }
    }
    let (width, height) = (info.width, info.height);
    Ok((
        info,
        PinholeCamera {
            fx,
            fy,
            cx,
            cy,
            width,
            height,
            distortion,
            rational,
        },
    ))
}

/// How the chosen depth reaches the colour camera: `None` when it is registered
/// already (one camera info for both, one frame, or the same intrinsics and no
/// transform or an identity between the frames, as TUM's bags); else the
/// [`Registration`] by the `/tf_static` transform between the two cameras' frames (or,
/// in librealsense's ROS 1 bags, the streams' `tf/<k>` topics), with where the
/// transform came from.
pub fn registration(
    path: &Path,
    catalog: &Catalog,
    store: &dyn Store,
    chosen: &Chosen,
) -> Result<Option<(Registration, String)>, IoError> {
    if chosen.stereo.is_some() {
        return Ok(None);
    }
    let (Some(colour_info), Some(depth_info)) =
        (&chosen.camera_info, nearest_info(catalog, &chosen.depth))
    else {
        return Ok(None);
    };
    if depth_info == *colour_info {
        return Ok(None);
    }
    let (c, colour) = camera_of(path, catalog, store, colour_info)?;
    let (d, depth) = camera_of(path, catalog, store, &depth_info)?;
    let same_intrinsics = (c.width, c.height) == (d.width, d.height)
        && c.k
            .iter()
            .zip(&d.k)
            .all(|(a, b)| (a - b).abs() <= 1e-6 * a.abs().max(1.0))
        && c.d == d.d;
    let identity =
        |t: &Isometry3<f64>| t.translation.vector.norm() < 1e-9 && t.rotation.angle() < 1e-9;
    // librealsense before 2.56: camera infos without frames, extrinsics on tf/<k> topics.
    if let Some(colour_from_depth) =
        super::realsense::stream_extrinsics(catalog, store, &chosen.colour, &chosen.depth)?
    {
        return Ok(
            (!(same_intrinsics && identity(&colour_from_depth))).then(|| {
                let by = "the streams' tf topics (librealsense before 2.56)".to_owned();
                (Registration::new(&depth, &colour, colour_from_depth), by)
            }),
        );
    }
    if c.frame == d.frame {
        return Ok(None);
    }
    let transforms = tf::static_transforms(path, catalog, store)?;
    match tf::between(&transforms, &c.frame, &d.frame) {
        Some(t) if same_intrinsics && identity(&t) => Ok(None),
        Some(colour_from_depth) => Ok(Some((
            Registration::new(&depth, &colour, colour_from_depth),
            "/tf_static".to_owned(),
        ))),
        None if same_intrinsics => Ok(None),
        None => Err(IoError::invalid(
            path,
            format!(
                "depth topic {} is in the depth camera's own geometry ({depth_info}: {}x{}, fx {:.2}; colour {colour_info}: {}x{}, fx {:.2}) and /tf_static has no transform between their frames {:?} and {:?}: record /tf_static, or aligned depth (name it with --depth-topic)",
                chosen.depth, d.width, d.height, d.k[0], c.width, c.height, c.k[0], d.frame, c.frame
            ),
        )),
    }
}

/// The calibration of the first message of the `CameraInfo` topic `info`, with the
/// frame rate of the `images` topic's stamps.
pub fn calibration(
    path: &Path,
    catalog: &Catalog,
    store: &dyn Store,
    info: &str,
    images: &str,
) -> Result<Calibration, IoError> {
    let (_, camera) = camera_of(path, catalog, store, info)?;
    Ok(Calibration {
        camera,
        bf: None,
        depth_scale: None,
        th_depth: None,
        fps: catalog.topic(images).and_then(super::Topic::rate),
    })
}

/// The ground truth from a pose topic (`PoseStamped`, `Odometry` or `TransformStamped`):
/// the pose of the camera (or of the body the topic follows) in the world, by stamp.
pub fn ground_truth(
    path: &Path,
    catalog: &Catalog,
    store: &dyn Store,
    topic: &str,
) -> Result<Trajectory, IoError> {
    let t = named(
        path,
        catalog,
        topic,
        &messages::POSE_TYPES,
        "ground_truth_topic",
    )?;
    let mut trajectory = Trajectory::default();
    for entry in &t.messages {
        let data = store.read(entry.at)?;
        let (stamp, [x, y, z], [qx, qy, qz, qw]) =
            messages::stamped_pose(&data, catalog.wire, &t.msg_type)
                .map_err(|e| IoError::invalid(path, format!("ground_truth_topic {topic}: {e}")))?;
        let rotation = UnitQuaternion::from_quaternion(Quaternion::new(qw, qx, qy, qz));
        if !(rotation.coords.iter().all(|v| v.is_finite())
            && [x, y, z].iter().all(|v| v.is_finite()))
        {
            return Err(IoError::invalid(
                path,
                format!("ground_truth_topic {topic}: a pose at {stamp:.6} is not finite"),
            ));
        }
        let stamp = if stamp > 0.0 { stamp } else { entry.stamp };
        trajectory.push(
            stamp,
            Se3::from_parts(Translation3::new(x, y, z), rotation.to_rotation_matrix()),
        );
    }
    Ok(trajectory)
}
