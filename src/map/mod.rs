//! The sparse map: keyframes and map points in arenas with typed keys (`slotmap`), so
//! that removing an entity is safe and a key of one kind can never index the other.

use nalgebra::Vector3;
use slotmap::{new_key_type, SlotMap};

use crate::features::{Descriptor, KeyPoint};
use crate::geometry::se3::Se3;

new_key_type! {
    /// A keyframe in the map.
    pub struct KeyFrameKey;
    /// A map point in the map.
    pub struct MapPointKey;
}

/// A 3-D point seen by keyframes.
#[derive(Debug, Clone)]
pub struct MapPoint {
    pub position: Vector3<f64>,
    /// The representative descriptor (the one of the first observation).
    pub descriptor: Descriptor,
    /// Mean viewing direction (unit vector from the cameras to the point).
    pub normal: Vector3<f64>,
    /// Distances within which the point can be matched (scale invariance range).
    pub min_distance: f64,
    pub max_distance: f64,
    /// Keyframes that see the point and the keypoint index in each.
    pub observations: Vec<(KeyFrameKey, usize)>,
}

/// A keyframe: a frame kept in the map.
#[derive(Debug, Clone)]
pub struct KeyFrame {
    pub frame_index: usize,
    pub timestamp: f64,
    pub camera_from_world: Se3,
    pub keypoints: Vec<KeyPoint>,
    pub descriptors: Vec<Descriptor>,
    pub depth: Vec<f32>,
    pub right_u: Vec<f32>,
    /// The map point each keypoint observes.
    pub map_points: Vec<Option<MapPointKey>>,
}

impl KeyFrame {
    pub fn world_from_camera(&self) -> Se3 {
        self.camera_from_world.inverse()
    }

    /// The camera centre in the world frame.
    pub fn centre(&self) -> Vector3<f64> {
        self.camera_from_world.inverse().translation.vector
    }
}

/// The map.
#[derive(Debug, Default)]
pub struct Map {
    pub keyframes: SlotMap<KeyFrameKey, KeyFrame>,
    pub points: SlotMap<MapPointKey, MapPoint>,
    /// Keyframes in insertion order.
    pub keyframe_order: Vec<KeyFrameKey>,
}

impl Map {
    pub fn add_keyframe(&mut self, keyframe: KeyFrame) -> KeyFrameKey {
        let key = self.keyframes.insert(keyframe);
        self.keyframe_order.push(key);
        key
    }

    /// Removes a map point and its observations from every keyframe.
    pub fn remove_point(&mut self, key: MapPointKey) {
        if let Some(point) = self.points.remove(key) {
            for (kf, index) in point.observations {
                if let Some(keyframe) = self.keyframes.get_mut(kf) {
                    if keyframe.map_points[index] == Some(key) {
                        keyframe.map_points[index] = None;
                    }
                }
            }
        }
    }

    /// The keyframes that share the most map points with `points`, best first, at most
    /// `limit` (the covisible neighbourhood of a frame).
    pub fn covisible_keyframes(
        &self,
        points: impl Iterator<Item = MapPointKey>,
        limit: usize,
    ) -> Vec<KeyFrameKey> {
        let mut counts: std::collections::HashMap<KeyFrameKey, usize> = Default::default();
        for key in points {
            if let Some(point) = self.points.get(key) {
                for (kf, _) in &point.observations {
                    *counts.entry(*kf).or_default() += 1;
                }
            }
        }
        let mut ranked: Vec<(KeyFrameKey, usize)> = counts.into_iter().collect();
        let order: std::collections::HashMap<KeyFrameKey, usize> = self
            .keyframe_order
            .iter()
            .enumerate()
            .map(|(i, k)| (*k, i))
            .collect();
        ranked.sort_by(|a, b| b.1.cmp(&a.1).then(order[&b.0].cmp(&order[&a.0])));
        ranked.into_iter().take(limit).map(|(k, _)| k).collect()
    }

    /// The map as an ASCII PLY point cloud.
    pub fn to_ply(&self) -> String {
        let mut out = format!(
            "ply\nformat ascii 1.0\ncomment dopslam sparse map\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nend_header\n",
            self.points.len()
        );
        for point in self.points.values() {
            let p = point.position;
            out += &format!("{} {} {}\n", p.x, p.y, p.z);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn keyframe(n: usize) -> KeyFrame {
        KeyFrame {
            frame_index: 0,
            timestamp: 0.0,
            camera_from_world: Se3::identity(),
            keypoints: vec![],
            descriptors: vec![],
            depth: vec![],
            right_u: vec![],
            map_points: vec![None; n],
        }
    }

    #[test]
    fn removing_a_point_clears_its_observations_and_its_key() {
        let mut map = Map::default();
        let a = map.add_keyframe(keyframe(3));
        let b = map.add_keyframe(keyframe(3));
        let point = map.points.insert(MapPoint {
            position: Vector3::zeros(),
            descriptor: [0; 4],
            normal: Vector3::z(),
            min_distance: 0.0,
            max_distance: 10.0,
            observations: vec![(a, 1), (b, 2)],
        });
        map.keyframes[a].map_points[1] = Some(point);
        map.keyframes[b].map_points[2] = Some(point);
        assert_eq!(map.covisible_keyframes([point].into_iter(), 5).len(), 2);
        map.remove_point(point);
        assert!(map.points.get(point).is_none());
        assert_eq!(map.keyframes[a].map_points[1], None);
        assert_eq!(map.keyframes[b].map_points[2], None);
        // A new point may reuse the slot, but the old key stays dead.
        let other = map.points.insert(map_point_like());
        assert_ne!(other, point);
        assert!(map.points.get(point).is_none());
    }

    fn map_point_like() -> MapPoint {
        MapPoint {
            position: Vector3::zeros(),
            descriptor: [0; 4],
            normal: Vector3::z(),
            min_distance: 0.0,
            max_distance: 1.0,
            observations: vec![],
        }
    }
}
