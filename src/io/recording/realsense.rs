//! librealsense's own recording layout (`rs.recorder`, the RealSense Viewer): streams
//! under `/device_0/sensor_N/<Stream>_M/`, each image topic beside an `image/metadata`
//! topic of `std_msgs/String` (`Frame number=..;timestamp=<ms>;..`), the depth unit in
//! `/device_0/sensor_N/option/Depth_Units/value`.
//!
//! librealsense before 2.56 wrote ROS 1 bags: images in `sensor_msgs/Image` stamped by
//! the device's clock already, camera infos under `<Stream>_M/info/camera_info` without
//! a frame, the depth unit as a `std_msgs/Float32`, and each stream's extrinsics as a
//! `geometry_msgs/Transform` on `<Stream>_M/tf/<k>`: \(T_{s,k}\), a point of the
//! reference stream \(k\) into stream \(s\), so that
//! \(T_{colour,depth} = T_{colour,k}\, T_{depth,k}^{-1}\).
//!
//! The images' header stamps are when the recorder received them; the metadata's
//! `timestamp` is the device's clock that librealsense's playback gives frames, and that
//! pairs colour with depth. Both are replaced here, frame by frame.

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};

use super::messages;
use super::{Catalog, Location, Store};
use crate::io::IoError;

const STRING: &str = "std_msgs/String";
const FLOAT32: &str = "std_msgs/Float32";
const TRANSFORM: &str = "geometry_msgs/Transform";

/// The value of `key` in librealsense's `key=value;key=value` text.
fn field<'a>(text: &'a str, key: &str) -> Option<&'a str> {
    text.split(';').find_map(|kv| {
        kv.split_once('=')
            .filter(|(k, _)| k.trim() == key)
            .map(|(_, v)| v.trim())
    })
}

/// Gives each librealsense image topic its frames' device stamps (when the metadata
/// topic has one message per image); returns what it did, for the user.
pub fn device_stamps(catalog: &mut Catalog, store: &dyn Store) -> Result<Vec<String>, IoError> {
    let mut said = Vec::new();
    for i in 0..catalog.topics.len() {
        let Some((prefix, _)) = catalog.topics[i].name.split_once("/image/data") else {
            continue;
        };
        let metadata = format!("{prefix}/image/metadata");
        let Some(meta) = catalog
            .topics
            .iter()
            .find(|t| t.name == metadata && t.msg_type == STRING)
        else {
            continue;
        };
        if meta.messages.len() != catalog.topics[i].messages.len() {
            said.push(format!(
                "{metadata}: {} messages for {} images: the images keep their header stamps",
                meta.messages.len(),
                catalog.topics[i].messages.len()
            ));
            continue;
        }
        let mut stamps = Vec::with_capacity(meta.messages.len());
        for entry in &meta.messages {
            let text = messages::string(&store.read(entry.at)?, catalog.wire).unwrap_or_default();
            match field(&text, "timestamp").and_then(|v| v.parse::<f64>().ok()) {
                Some(ms) => stamps.push(ms * 1e-3),
                None => break,
            }
        }
        if stamps.len() == meta.messages.len() {
            let topic = &mut catalog.topics[i];
            for (entry, stamp) in topic.messages.iter_mut().zip(stamps) {
                entry.stamp = stamp;
            }
            topic.messages.sort_by(|a, b| a.stamp.total_cmp(&b.stamp));
            said.push(format!(
                "{}: stamped by the device's clock ({metadata})",
                topic.name
            ));
        }
    }
    Ok(said)
}

/// Raw depth units per metre from `Depth_Units` (metres per unit), when recorded.
pub fn depth_scale(catalog: &Catalog, store: &dyn Store) -> Result<Option<f64>, IoError> {
    let topic = catalog.topics.iter().find(|t| {
        t.name.ends_with("/option/Depth_Units/value")
            && [STRING, FLOAT32].contains(&t.msg_type.as_str())
    });
    let Some((entry, msg_type)) = topic.and_then(|t| t.messages.first().map(|m| (m, &t.msg_type)))
    else {
        return Ok(None);
    };
    let data = store.read(entry.at)?;
    // A Float32 unit read as the decimal it was written as (its shortest round-trip
    // text): 0.001f32 is 0.001, 1000 per metre, not 999.99995.
    let text = if msg_type == FLOAT32 {
        messages::float32(&data, catalog.wire)
            .ok()
            .map(|u| u.to_string())
    } else {
        messages::string(&data, catalog.wire).ok()
    };
    Ok(text
        .and_then(|t| t.trim().parse::<f64>().ok())
        .filter(|u| *u > 0.0 && u.is_finite())
        .map(|u| 1.0 / u))
}

/// \(T_{colour,depth}\) from the `tf/<k>` topics beside two image topics
/// (`.../<Stream>_M/image/data`) of a librealsense ROS 1 bag, when both streams have one
/// for the same reference \(k\).
pub fn stream_extrinsics(
    catalog: &Catalog,
    store: &dyn Store,
    colour: &str,
    depth: &str,
) -> Result<Option<Isometry3<f64>>, IoError> {
    let tf_of = |image: &str| -> Vec<(String, Location)> {
        let Some((stream, _)) = image.split_once("/image/data") else {
            return Vec::new();
        };
        let prefix = format!("{stream}/tf/");
        catalog
            .topics
            .iter()
            .filter(|t| t.msg_type == TRANSFORM && t.name.starts_with(&prefix))
            .filter_map(|t| Some((t.name[prefix.len()..].to_owned(), t.messages.first()?.at)))
            .collect()
    };
    let (colour_tf, depth_tf) = (tf_of(colour), tf_of(depth));
    let Some((c_at, d_at)) = colour_tf
        .iter()
        .find_map(|(k, c)| depth_tf.iter().find(|(j, _)| j == k).map(|(_, d)| (*c, *d)))
    else {
        return Ok(None);
    };
    let pose = |at: Location| -> Result<Option<Isometry3<f64>>, IoError> {
        let data = store.read(at)?;
        let Ok(([x, y, z], [qx, qy, qz, qw])) = messages::transform(&data, catalog.wire) else {
            return Ok(None);
        };
        let q = Quaternion::new(qw, qx, qy, qz);
        if q.norm() < 1e-9 || ![x, y, z].iter().all(|v| v.is_finite()) {
            return Ok(None);
        }
        Ok(Some(Isometry3::from_parts(
            Translation3::new(x, y, z),
            UnitQuaternion::from_quaternion(q),
        )))
    };
    Ok(match (pose(c_at)?, pose(d_at)?) {
        (Some(colour_from_k), Some(depth_from_k)) => Some(colour_from_k * depth_from_k.inverse()),
        _ => None,
    })
}
