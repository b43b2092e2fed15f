//! librealsense's own recording layout (`rs.recorder`, the RealSense Viewer): streams
//! under `/device_0/sensor_N/<Stream>_M/`, each image topic beside an `image/metadata`
//! topic of `std_msgs/String` (`Frame number=..;timestamp=<ms>;..`), the depth unit in
//! `/device_0/sensor_N/option/Depth_Units/value`.
//!
//! The images' header stamps are when the recorder received them; the metadata's
//! `timestamp` is the device's clock that librealsense's playback gives frames, and that
//! pairs colour with depth. Both are replaced here, frame by frame.

use super::messages;
use super::{Catalog, Store};
use crate::io::IoError;

const STRING: &str = "std_msgs/String";

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
    let topic = catalog
        .topics
        .iter()
        .find(|t| t.name.ends_with("/option/Depth_Units/value") && t.msg_type == STRING);
    let Some(entry) = topic.and_then(|t| t.messages.first()) else {
        return Ok(None);
    };
    let text = messages::string(&store.read(entry.at)?, catalog.wire).unwrap_or_default();
    Ok(text
        .trim()
        .parse::<f64>()
        .ok()
        .filter(|u| *u > 0.0 && u.is_finite())
        .map(|u| 1.0 / u))
}
