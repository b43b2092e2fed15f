//! The static transforms of a recording (`/tf_static`): where the depth camera sits in
//! the colour camera's frame.

use std::collections::HashMap;

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};

use super::messages::{self, Transform};
use super::{Catalog, Store};
use crate::io::IoError;

/// The message types that carry transforms (ROS 2 and ROS 1 spellings).
const TF_TYPES: [&str; 2] = ["tf2_msgs/TFMessage", "tf/tfMessage"];

/// Every transform of the `/tf_static` topics.
pub fn static_transforms(
    path: &std::path::Path,
    catalog: &Catalog,
    store: &dyn Store,
) -> Result<Vec<Transform>, IoError> {
    let mut all = Vec::new();
    let topics = catalog
        .topics
        .iter()
        .filter(|t| t.name.ends_with("tf_static") && TF_TYPES.contains(&t.msg_type.as_str()));
    for topic in topics {
        for entry in &topic.messages {
            let data = store.read(entry.at)?;
            let decoded = messages::transforms(&data, catalog.wire)
                .map_err(|e| IoError::invalid(path, format!("topic {}: {e}", topic.name)))?;
            all.extend(decoded);
        }
    }
    Ok(all)
}

fn isometry(t: &Transform) -> Isometry3<f64> {
    let [x, y, z, w] = t.rotation;
    let [tx, ty, tz] = t.translation;
    Isometry3::from_parts(
        Translation3::new(tx, ty, tz),
        UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z)),
    )
}

/// `target_from_source`: \(T_{ts} = T_{rt}^{-1} T_{rs}\) through the root \(r\) the
/// two frames share in the tree of `transforms`; `None` when they share none.
pub fn between(transforms: &[Transform], target: &str, source: &str) -> Option<Isometry3<f64>> {
    let parents: HashMap<&str, &Transform> =
        transforms.iter().map(|t| (t.child.as_str(), t)).collect();
    // root_from_frame, and the root, by walking up (a cycle stops after 64 steps).
    let up = |frame: &str| -> (String, Isometry3<f64>) {
        let (mut at, mut root_from) = (frame.to_owned(), Isometry3::identity());
        for _ in 0..64 {
            let Some(t) = parents.get(at.as_str()) else {
                break;
            };
            root_from = isometry(t) * root_from;
            at = t.parent.clone();
        }
        (at, root_from)
    };
    let (root_t, root_from_target) = up(target);
    let (root_s, root_from_source) = up(source);
    (root_t == root_s).then(|| root_from_target.inverse() * root_from_source)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn t(parent: &str, child: &str, x: f64) -> Transform {
        Transform {
            parent: parent.into(),
            child: child.into(),
            translation: [x, 0.0, 0.0],
            rotation: [0.0, 0.0, 0.0, 1.0],
        }
    }

    #[test]
    fn two_frames_under_one_root_and_two_apart() {
        // librealsense: ref -> Depth identity, ref -> Color at -25 mm.
        let tree = [
            t("ref_1", "Depth", 0.0),
            t("ref_1", "Color", -0.025),
            t("other", "Lonely", 1.0),
        ];
        let colour_from_depth = between(&tree, "Color", "Depth").unwrap();
        assert!((colour_from_depth.translation.vector.x - 0.025).abs() < 1e-12);
        assert!(between(&tree, "Color", "Lonely").is_none());
        assert_eq!(
            between(&tree, "Depth", "Depth"),
            Some(Isometry3::identity())
        );
    }
}
