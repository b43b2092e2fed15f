//! The sparse map: keyframes and map points in arenas with typed keys (`slotmap`), so
//! that removing an entity is safe and a key of one kind can never index the other.

pub mod file;
pub mod record;
pub mod visibility;

use nalgebra::Vector3;
use slotmap::{new_key_type, SlotMap};

use crate::features::Descriptor;
use crate::frame::Frame;
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
    /// World position in metres.
    pub position: Vector3<f64>,
    /// The representative descriptor (the one of the first observation).
    pub descriptor: Descriptor,
    /// Mean viewing direction (unit vector from the cameras to the point).
    pub normal: Vector3<f64>,
    /// Distances within which the point can be matched (scale invariance range).
    pub min_distance: f64,
    /// The farthest of those distances.
    pub max_distance: f64,
    /// Keyframes that see the point and the keypoint index in each.
    pub observations: Vec<(KeyFrameKey, usize)>,
    /// Frames in whose frustum tracking predicted the point, and frames where it was
    /// matched as an inlier: their ratio culls points that are rarely re-found.
    pub visible: u32,
    /// Frames where the point was matched as an inlier.
    pub found: u32,
    /// Sequence number ([`KeyFrame::id`]) of the keyframe that created the point.
    pub first_keyframe_id: usize,
    /// Moving probability \(P(X)\) of the DOP model (0.5 until a detection speaks).
    pub moving: f32,
    /// The DOP model's geometric check: runs of frames where the point was consistent
    /// with the pose, or not.
    pub consistency: crate::dop::consistency::Consistency,
}

impl MapPoint {
    /// A point first seen by keyframe `first_keyframe_id`; no observations yet.
    pub fn new(
        position: Vector3<f64>,
        descriptor: Descriptor,
        normal: Vector3<f64>,
        (min_distance, max_distance): (f64, f64),
        first_keyframe_id: usize,
    ) -> Self {
        Self {
            position,
            descriptor,
            normal,
            min_distance,
            max_distance,
            observations: Vec::new(),
            visible: 1,
            found: 1,
            first_keyframe_id,
            moving: 0.5,
            consistency: Default::default(),
        }
    }

    /// \(found / visible\): how often the point is matched when it should be seen.
    pub fn found_ratio(&self) -> f64 {
        self.found as f64 / self.visible.max(1) as f64
    }
}

/// A set of map keys with foldhash's fast fixed-seed hasher: the local-map search
/// hashes some ten thousand keys a frame, where SipHash's resistance to flooding buys
/// nothing; the seed is fixed, so nothing depends on a per-process random state.
pub type KeySet<K> = std::collections::HashSet<K, foldhash::fast::FixedState>;

/// A map from map keys with the hasher of [`KeySet`].
pub type KeyMap<K, V> = std::collections::HashMap<K, V, foldhash::fast::FixedState>;

/// What the map holds, in bytes ([`Map::footprint`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MapFootprint {
    /// The keyframes: features, depth, grid, observations, edges.
    pub keyframes: usize,
    /// The map points with their observation lists.
    pub points: usize,
}

/// A keyframe: a frame kept in the map.
#[derive(Debug, Clone)]
pub struct KeyFrame {
    /// Insertion sequence number (0 for the map's first keyframe).
    pub id: usize,
    /// The frame's features, depth and keypoint grid.
    pub frame: Frame,
    /// \(T_{cw}\): the keyframe's pose.
    pub camera_from_world: Se3,
    /// The map point each keypoint observes.
    pub map_points: Vec<Option<MapPointKey>>,
    /// Covisibility edges: keyframes sharing at least 15 points (or the best one),
    /// with the number shared, most first.
    pub connections: Vec<(KeyFrameKey, usize)>,
    /// Spanning tree: the keyframe this one was attached to, and those attached to it.
    pub parent: Option<KeyFrameKey>,
    /// The keyframes attached to this one in the spanning tree.
    pub children: Vec<KeyFrameKey>,
    /// The detector's boxes, once they come back from the detection thread.
    pub detections: Option<Vec<crate::detect::Detection>>,
    /// The map segment: tracking that stays lost starts a new one (0 for the first),
    /// unrelated to the others until a loop merges them.
    pub segment: usize,
    /// The recording that made it ([`Map::recordings`]): the current one, or one whose
    /// map was loaded (`dopslam run --map`), whose frame indices are not this
    /// sequence's.
    pub recording: u32,
}

impl KeyFrame {
    /// A keyframe made from `frame`, observing no points yet (its id is given when it
    /// is added to the map).
    pub fn new(frame: Frame, camera_from_world: Se3) -> Self {
        let n = frame.len();
        Self {
            id: 0,
            frame,
            camera_from_world,
            map_points: vec![None; n],
            connections: Vec::new(),
            parent: None,
            children: Vec::new(),
            detections: None,
            segment: 0,
            recording: 0,
        }
    }

    /// \(T_{wc} = T_{cw}^{-1}\).
    pub fn world_from_camera(&self) -> Se3 {
        self.camera_from_world.inverse()
    }

    /// The map points the keyframe observes (a copy, so the map can change meanwhile).
    pub fn observed_points(&self) -> Vec<MapPointKey> {
        self.map_points.iter().flatten().copied().collect()
    }

    /// The camera centre in the world frame.
    pub fn centre(&self) -> Vector3<f64> {
        self.camera_from_world.inverse().translation.vector
    }

    /// The covisibility weight to `other` (0 when not connected).
    pub fn weight_to(&self, other: KeyFrameKey) -> usize {
        self.connections
            .iter()
            .find(|(k, _)| *k == other)
            .map_or(0, |(_, w)| *w)
    }

    /// Up to `n` best covisible keyframes.
    pub fn best_covisible(&self, n: usize) -> Vec<KeyFrameKey> {
        self.connections.iter().take(n).map(|(k, _)| *k).collect()
    }
}

/// Covisibility edges need at least this many shared points (ORB-SLAM's 15).
const MIN_COVISIBILITY: usize = 15;

/// The map shared by tracking and local mapping.
pub type SharedMap = std::sync::Arc<std::sync::RwLock<Map>>;

/// The map. Its fields are its own: it is read through [`Map::keyframes`],
/// [`Map::points`] and the like, and written only through its methods, grouped by what
/// they change (observations and connections, poses and positions, segments,
/// detection waits, the DOP state of points, culling's counters), so that a point's
/// observations and its keyframes' map points always agree.
#[derive(Debug, Default)]
pub struct Map {
    keyframes: SlotMap<KeyFrameKey, KeyFrame>,
    points: SlotMap<MapPointKey, MapPoint>,
    /// Keyframes in insertion order.
    keyframe_order: Vec<KeyFrameKey>,
    /// Keyframes ever inserted (the next keyframe's id).
    keyframes_created: usize,
    /// Culled keyframes: their parent at removal and \(T_{cp}\) (camera from parent),
    /// so frames tracked against them keep a pose that follows later corrections.
    culled: std::collections::HashMap<KeyFrameKey, (KeyFrameKey, Se3)>,
    /// Keyframes (ids) whose detection has not come back (real-time mode). The points
    /// they made may sit on a person the detector is about to report: tracking keeps
    /// them out of the pose while enough others remain, and local BA leaves them out
    /// (both only those within the wait zones, when there are any).
    awaiting_detection: std::collections::HashSet<usize>,
    /// The latest detection's dynamic boxes, widened, when only the new points near
    /// them wait (DOP with `[tracking] wait_near_boxes_only`); `None`: every new point
    /// waits (the rule is off, or no detection came back yet).
    wait_zones: Option<Vec<crate::dop::boxes::ObjectBox>>,
    /// The recordings whose keyframes the map holds (their sequences' names), the
    /// current one last: new keyframes are the last one's.
    recordings: Vec<String>,
}

/// Reads.
impl Map {
    /// The keyframes, by key.
    pub fn keyframes(&self) -> &SlotMap<KeyFrameKey, KeyFrame> {
        &self.keyframes
    }

    /// The map points, by key.
    pub fn points(&self) -> &SlotMap<MapPointKey, MapPoint> {
        &self.points
    }

    /// The keyframes in insertion order (culled ones left out).
    pub fn keyframe_order(&self) -> &[KeyFrameKey] {
        &self.keyframe_order
    }

    /// How many keyframes were ever inserted (the next keyframe's id).
    pub fn keyframes_created(&self) -> usize {
        self.keyframes_created
    }

    /// The recordings whose keyframes the map holds, the current one last (empty
    /// before [`Map::begin_recording`]).
    pub fn recordings(&self) -> &[String] {
        &self.recordings
    }

    /// The current recording's number (new keyframes carry it).
    pub fn current_recording(&self) -> u32 {
        self.recordings.len().saturating_sub(1) as u32
    }

    /// Whether keyframe `key` was made by the current recording (not loaded).
    pub fn is_current(&self, key: KeyFrameKey) -> bool {
        self.keyframes
            .get(key)
            .is_some_and(|kf| kf.recording == self.current_recording())
    }

    /// The bytes the keyframes and the points hold (their structs and arrays, by
    /// capacity; not the allocator's own overhead), for the memory report.
    pub fn footprint(&self) -> MapFootprint {
        use std::mem::size_of;
        let keyframes = self
            .keyframes
            .values()
            .map(|kf| {
                size_of::<KeyFrame>()
                    + kf.frame.heap_bytes()
                    + kf.map_points.capacity() * size_of::<Option<MapPointKey>>()
                    + kf.connections.capacity() * size_of::<(KeyFrameKey, usize)>()
                    + kf.children.capacity() * size_of::<KeyFrameKey>()
            })
            .sum();
        let points = self
            .points
            .values()
            .map(|p| {
                size_of::<MapPoint>()
                    + p.observations.capacity() * size_of::<(KeyFrameKey, usize)>()
            })
            .sum();
        MapFootprint { keyframes, points }
    }

    /// The segments the map's keyframes use (a new segment is numbered from here).
    pub fn segments_used(&self) -> usize {
        self.keyframes
            .values()
            .map(|kf| kf.segment + 1)
            .max()
            .unwrap_or(0)
    }
}

/// Test fixtures write what they need directly.
#[cfg(test)]
impl Map {
    pub(crate) fn point_mut(&mut self, key: MapPointKey) -> &mut MapPoint {
        &mut self.points[key]
    }

    pub(crate) fn keyframe_mut(&mut self, key: KeyFrameKey) -> &mut KeyFrame {
        &mut self.keyframes[key]
    }
}

/// Writes other than observations and connections, grouped by what they change.
impl Map {
    /// Every keyframe's frame, to rewrite its measurements (the global pass's
    /// disparity correction); poses, points and observations stay as they are.
    pub fn keyframe_frames_mut(&mut self) -> impl Iterator<Item = &mut crate::frame::Frame> {
        self.keyframes.values_mut().map(|k| &mut k.frame)
    }

    /// Inserts a point that no keyframe observes yet ([`Map::add_observation`] adds
    /// them).
    pub fn insert_point(&mut self, point: MapPoint) -> MapPointKey {
        debug_assert!(
            point.observations.is_empty(),
            "observations come through add_observation"
        );
        self.points.insert(point)
    }

    /// Poses: keyframe `key` at \(T_{cw}\) = `camera_from_world` (after an
    /// optimisation or a loop's correction); nothing when the keyframe is gone.
    pub fn set_keyframe_pose(&mut self, key: KeyFrameKey, camera_from_world: Se3) {
        if let Some(kf) = self.keyframes.get_mut(key) {
            kf.camera_from_world = camera_from_world;
        }
    }

    /// Poses and positions: the whole map moved rigidly by `world_change` (\(X' = S
    /// X\): every keyframe's pose becomes \(T_{cw} S^{-1}\), every point and its
    /// viewing direction move with it). Relative poses (culled keyframes', frames')
    /// are unchanged.
    pub fn transform_world(&mut self, world_change: &Se3) {
        let inverse = world_change.inverse();
        for kf in self.keyframes.values_mut() {
            kf.camera_from_world *= inverse;
        }
        for p in self.points.values_mut() {
            p.position = (world_change * nalgebra::Point3::from(p.position)).coords;
            p.normal = world_change.rotation * p.normal;
        }
    }

    /// Positions: point `key` at `position` (world); nothing when the point is gone.
    /// Its normal and distances follow with [`Map::update_point`].
    pub fn set_point_position(&mut self, key: MapPointKey, position: Vector3<f64>) {
        if let Some(p) = self.points.get_mut(key) {
            p.position = position;
        }
    }

    /// Segments: keyframe `key` now belongs to `segment` (a loop merged its segment).
    pub fn set_keyframe_segment(&mut self, key: KeyFrameKey, segment: usize) {
        if let Some(kf) = self.keyframes.get_mut(key) {
            kf.segment = segment;
        }
    }

    /// Detection waits: keyframe `keyframe_id`'s detection is on its way.
    pub fn await_detection(&mut self, keyframe_id: usize) {
        self.awaiting_detection.insert(keyframe_id);
    }

    /// Detection waits: keyframe `keyframe_id`'s detection came back (or never will).
    pub fn detection_came_back(&mut self, keyframe_id: usize) {
        self.awaiting_detection.remove(&keyframe_id);
    }

    /// Detection waits: from now on only the new points within `zones` (image boxes
    /// of the keyframe that made them) wait, in tracking and in local BA alike;
    /// `None`: all of them.
    pub fn set_wait_zones(&mut self, zones: Option<Vec<crate::dop::boxes::ObjectBox>>) {
        self.wait_zones = zones;
    }

    /// Detections: what the detector found in keyframe `key`.
    pub fn set_detections(&mut self, key: KeyFrameKey, detections: Vec<crate::detect::Detection>) {
        if let Some(kf) = self.keyframes.get_mut(key) {
            kf.detections = Some(detections);
        }
    }

    /// The DOP state of point `key`: its moving probability and its geometric
    /// consistency, to update together.
    pub fn point_dop_mut(
        &mut self,
        key: MapPointKey,
    ) -> Option<(&mut f32, &mut crate::dop::consistency::Consistency)> {
        self.points
            .get_mut(key)
            .map(|p| (&mut p.moving, &mut p.consistency))
    }
}

impl Map {
    /// A new recording (sequence `name`) starts adding keyframes to the map: a run's
    /// own, or one that continues a loaded map. The points' runs of consistent frames
    /// (the DOP model's geometric check) were counted on the earlier recording's
    /// clock: they start again; the moving probabilities stay.
    pub fn begin_recording(&mut self, name: &str) {
        self.recordings.push(name.to_string());
        for point in self.points.values_mut() {
            point.consistency = Default::default();
        }
    }

    /// Culling's counters after a frame: the points predicted `visible` in it, and
    /// those `found` there as inliers of its pose (a point is culled when found in too
    /// few of the frames that should see it).
    pub fn count_visibility(&mut self, visible: &[MapPointKey], found: &[Option<MapPointKey>]) {
        for key in visible {
            if let Some(p) = self.points.get_mut(*key) {
                p.visible += 1;
            }
        }
        for key in found.iter().flatten() {
            if let Some(p) = self.points.get_mut(*key) {
                p.found += 1;
            }
        }
    }

    /// Whether `point` was made by a keyframe whose detection has not come back, and
    /// does not lie clear of the wait zones ([`Map::set_wait_zones`]).
    pub fn awaits_detection(&self, point: &MapPoint) -> bool {
        self.keyframe_awaits_detection(point) && !self.clear_of_wait_zones(point)
    }

    /// Whether `point` was made by a keyframe whose detection has not come back,
    /// wherever it lies.
    pub fn keyframe_awaits_detection(&self, point: &MapPoint) -> bool {
        self.awaiting_detection.contains(&point.first_keyframe_id)
    }

    /// Whether `point`'s keypoint in its first keyframe lies clear of every wait zone
    /// (false when there are none: every new point waits).
    pub fn clear_of_wait_zones(&self, point: &MapPoint) -> bool {
        let Some(zones) = self.wait_zones.as_deref() else {
            return false;
        };
        let keypoint = point.observations.first().and_then(|&(key, i)| {
            let kf = self.keyframes.get(key)?;
            kf.frame.keypoints.get(i).map(|k| (k.x, k.y))
        });
        keypoint.is_some_and(|(x, y)| !crate::dop::boxes::in_dynamic_box(zones, x, y))
    }

    /// Inserts a keyframe, giving it the next id.
    pub fn add_keyframe(&mut self, mut keyframe: KeyFrame) -> KeyFrameKey {
        keyframe.id = self.keyframes_created;
        keyframe.recording = self.current_recording();
        self.keyframes_created += 1;
        let key = self.keyframes.insert(keyframe);
        self.keyframe_order.push(key);
        key
    }

    /// The current camera-from-world pose of a keyframe, following the spanning tree
    /// through culled keyframes (\(T_{cw} = T_{cp} T_{pw}\)).
    pub fn keyframe_pose(&self, mut key: KeyFrameKey) -> Option<Se3> {
        let mut camera_from_key = Se3::identity();
        loop {
            if let Some(kf) = self.keyframes.get(key) {
                return Some(camera_from_key * kf.camera_from_world);
            }
            let (parent, camera_from_parent) = self.culled.get(&key)?;
            camera_from_key *= camera_from_parent;
            key = *parent;
        }
    }

    /// The oldest keyframe of each segment still in the map: each holds its segment's
    /// gauge in optimisations, as segments that no loop has merged share no frame.
    pub fn segment_anchors(&self) -> std::collections::HashSet<KeyFrameKey> {
        let mut seen = std::collections::HashSet::new();
        self.keyframe_order
            .iter()
            .copied()
            .filter(|k| {
                self.keyframes
                    .get(*k)
                    .is_some_and(|kf| seen.insert(kf.segment))
            })
            .collect()
    }

    /// The newest keyframe of `segment`.
    pub fn newest_of_segment(&self, segment: usize) -> Option<KeyFrameKey> {
        self.keyframe_order.iter().rev().copied().find(|k| {
            self.keyframes
                .get(*k)
                .is_some_and(|kf| kf.segment == segment)
        })
    }

    /// Records that keypoint `index` of `keyframe` observes `point`.
    pub fn add_observation(&mut self, point: MapPointKey, keyframe: KeyFrameKey, index: usize) {
        let (Some(p), Some(kf)) = (self.points.get_mut(point), self.keyframes.get_mut(keyframe))
        else {
            return;
        };
        if kf.map_points[index].is_none() && !p.observations.iter().any(|(k, _)| *k == keyframe) {
            kf.map_points[index] = Some(point);
            p.observations.push((keyframe, index));
        }
    }

    /// Removes one observation; the point goes when no keyframe sees it any more.
    pub fn remove_observation(&mut self, keyframe: KeyFrameKey, index: usize) {
        let Some(point) = self
            .keyframes
            .get_mut(keyframe)
            .and_then(|kf| kf.map_points[index].take())
        else {
            return;
        };
        if let Some(p) = self.points.get_mut(point) {
            p.observations
                .retain(|(k, i)| !(*k == keyframe && *i == index));
            if p.observations.is_empty() {
                self.points.remove(point);
            }
        }
    }

    /// Merges `old` into `new` (a duplicate found by fusion): the keyframes that saw
    /// `old` see `new` instead, unless they already do; the counters add up.
    pub fn replace_point(&mut self, old: MapPointKey, new: MapPointKey) {
        if old == new || !self.points.contains_key(new) {
            return;
        }
        let Some(removed) = self.points.remove(old) else {
            return;
        };
        for (kf, index) in removed.observations {
            let Some(keyframe) = self.keyframes.get_mut(kf) else {
                continue;
            };
            keyframe.map_points[index] = None;
            self.add_observation(new, kf, index);
        }
        let p = &mut self.points[new];
        p.visible += removed.visible;
        p.found += removed.found;
    }

    /// Recomputes a point's normal (mean viewing direction), its scale-invariance
    /// distances (from its reference keyframe, the first that still observes it, and the
    /// level there) and its descriptor: the observed descriptor with the least median
    /// Hamming distance to the others.
    pub fn update_point(&mut self, point: MapPointKey, scale_factors: &[f64]) {
        let Some(p) = self.points.get(point) else {
            return;
        };
        let mut normal = Vector3::zeros();
        let mut descriptors = Vec::new();
        let mut reference: Option<(f64, usize)> = None;
        for (kf, index) in &p.observations {
            let Some(keyframe) = self.keyframes.get(*kf) else {
                continue;
            };
            let offset = p.position - keyframe.centre();
            let distance = offset.norm();
            normal += offset / distance.max(1e-9);
            descriptors.push(keyframe.frame.descriptors[*index]);
            if reference.is_none() {
                reference = Some((distance, keyframe.frame.keypoints[*index].level as usize));
            }
        }
        let Some((distance, level)) = reference else {
            return;
        };
        let mut distances = vec![0u32; descriptors.len()];
        let best = (0..descriptors.len())
            .min_by_key(|&i| {
                for (d, o) in distances.iter_mut().zip(&descriptors) {
                    *d = crate::features::hamming(&descriptors[i], o);
                }
                let middle = (distances.len() - 1) / 2;
                *distances.select_nth_unstable(middle).1
            })
            .map(|i| descriptors[i]);
        let max_distance = distance * scale_factors[level];
        let p = &mut self.points[point];
        if normal.norm() > 0.0 {
            p.normal = normal.normalize();
        }
        p.max_distance = max_distance;
        p.min_distance = max_distance / scale_factors[scale_factors.len() - 1];
        if let Some(d) = best {
            p.descriptor = d;
        }
    }

    /// Rebuilds `keyframe`'s covisibility edges (both directions) from the points it
    /// sees and attaches it to the spanning tree under its best covisible keyframe.
    pub fn update_connections(&mut self, keyframe: KeyFrameKey) {
        let Some(kf) = self.keyframes.get(keyframe) else {
            return;
        };
        let mut counts: std::collections::BTreeMap<KeyFrameKey, usize> = Default::default();
        for point in kf.map_points.iter().flatten() {
            if let Some(p) = self.points.get(*point) {
                for (other, _) in &p.observations {
                    if *other != keyframe {
                        *counts.entry(*other).or_default() += 1;
                    }
                }
            }
        }
        let mut ranked: Vec<(KeyFrameKey, usize)> = counts.into_iter().collect();
        ranked.sort_by(|a, b| {
            b.1.cmp(&a.1)
                .then(self.keyframes[b.0].id.cmp(&self.keyframes[a.0].id))
        });
        let best = ranked.first().copied();
        ranked.retain(|(_, w)| *w >= MIN_COVISIBILITY);
        if ranked.is_empty() {
            ranked.extend(best);
        }
        for (other, weight) in &ranked {
            let o = &mut self.keyframes[*other];
            o.connections.retain(|(k, _)| *k != keyframe);
            o.connections.push((keyframe, *weight));
            o.connections.sort_by_key(|c| std::cmp::Reverse(c.1));
        }
        let is_first = self.keyframe_order.first() == Some(&keyframe);
        let id = self.keyframes[keyframe].id;
        // The parent is older, so the tree has no cycles even when local mapping runs
        // behind tracking and newer keyframes already share points with this one.
        let parent = ranked
            .iter()
            .find(|(k, _)| self.keyframes[*k].id < id)
            .map(|(k, _)| *k);
        let kf = &mut self.keyframes[keyframe];
        kf.connections = ranked;
        if kf.parent.is_none() && !is_first {
            if let Some(parent) = parent {
                kf.parent = Some(parent);
                self.keyframes[parent].children.push(keyframe);
            }
        }
    }

    /// Removes a keyframe (redundant-keyframe culling): its observations, its
    /// covisibility edges, and its place in the spanning tree, whose children move to
    /// the candidate parent (its own parent or an already moved sibling) they share
    /// the most points with.
    pub fn remove_keyframe(&mut self, keyframe: KeyFrameKey) {
        let Some(kf) = self.keyframes.get(keyframe) else {
            return;
        };
        let (parent, children) = (kf.parent, kf.children.clone());
        let Some(parent) = parent else {
            return; // the root stays
        };
        for index in 0..kf.map_points.len() {
            self.remove_observation(keyframe, index);
        }
        let mut candidates = vec![parent];
        for child in &children {
            let Some(c) = self.keyframes.get(*child) else {
                continue;
            };
            let new_parent = candidates
                .iter()
                .copied()
                .max_by_key(|k| c.weight_to(*k))
                .unwrap_or(parent);
            self.keyframes[*child].parent = Some(new_parent);
            self.keyframes[new_parent].children.push(*child);
            candidates.push(*child);
        }
        let camera_from_parent =
            self.keyframes[keyframe].camera_from_world * self.keyframes[parent].world_from_camera();
        self.culled.insert(keyframe, (parent, camera_from_parent));
        let removed = self.keyframes.remove(keyframe).expect("present");
        self.keyframes[parent].children.retain(|k| *k != keyframe);
        for (other, _) in removed.connections {
            if let Some(o) = self.keyframes.get_mut(other) {
                o.connections.retain(|(k, _)| *k != keyframe);
            }
        }
        self.keyframe_order.retain(|k| *k != keyframe);
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
        let mut counts: KeyMap<KeyFrameKey, usize> = Default::default();
        for key in points {
            if let Some(point) = self.points.get(key) {
                for (kf, _) in &point.observations {
                    *counts.entry(*kf).or_default() += 1;
                }
            }
        }
        let mut ranked: Vec<(KeyFrameKey, usize)> = counts.into_iter().collect();
        // Ties go to the newer keyframe: ids follow `keyframe_order` (both are the
        // insertion order, kept by the map file), so no per-call index of every keyframe.
        let id = |k: KeyFrameKey| self.keyframes.get(k).map_or(0, |kf| kf.id);
        ranked.sort_by(|a, b| b.1.cmp(&a.1).then(id(b.0).cmp(&id(a.0))));
        ranked.into_iter().take(limit).map(|(k, _)| k).collect()
    }

    /// The map points as a point cloud.
    pub fn to_mesh(&self) -> crate::geometry::mesh::Mesh {
        crate::geometry::mesh::Mesh::points(
            self.points
                .values()
                .map(|point| point.position.map(|c| c as f32).into())
                .collect(),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn keyframe(n: usize) -> KeyFrame {
        KeyFrame::new(Frame::blank(n, (640, 480)), Se3::identity())
    }

    fn point() -> MapPoint {
        MapPoint::new(
            Vector3::new(0.0, 0.0, 2.0),
            [0; 4],
            Vector3::z(),
            (0.1, 10.0),
            0,
        )
    }

    /// A map of `keyframes` keyframes of 40 keypoints; points `0..shared[k]` of
    /// keyframe k+1 are also seen by keyframe k (keypoint i sees point i of its row).
    fn chain(shared: &[usize]) -> (Map, Vec<KeyFrameKey>) {
        chain_updated_in(shared, &(0..=shared.len()).collect::<Vec<_>>())
    }

    /// [`chain`] with the connections updated in the given keyframe order.
    fn chain_updated_in(shared: &[usize], order: &[usize]) -> (Map, Vec<KeyFrameKey>) {
        let mut map = Map::default();
        let keys: Vec<KeyFrameKey> = (0..=shared.len())
            .map(|_| map.add_keyframe(keyframe(64)))
            .collect();
        for (k, &n) in shared.iter().enumerate() {
            for i in 0..n {
                let p = map.points.insert(point());
                map.add_observation(p, keys[k], i);
                map.add_observation(p, keys[k + 1], 20 + i);
            }
        }
        for &k in order {
            map.update_connections(keys[k]);
        }
        (map, keys)
    }

    #[test]
    fn removing_a_point_clears_its_observations_and_its_key() {
        let mut map = Map::default();
        let a = map.add_keyframe(keyframe(3));
        let b = map.add_keyframe(keyframe(3));
        let p = map.points.insert(point());
        map.add_observation(p, a, 1);
        map.add_observation(p, b, 2);
        assert_eq!(map.covisible_keyframes([p].into_iter(), 5).len(), 2);
        map.remove_point(p);
        assert!(map.points.get(p).is_none());
        assert_eq!(map.keyframes[a].map_points[1], None);
        assert_eq!(map.keyframes[b].map_points[2], None);
        // A new point may reuse the slot, but the old key stays dead.
        let other = map.points.insert(point());
        assert_ne!(other, p);
        assert!(map.points.get(p).is_none());
    }

    #[test]
    fn connections_need_fifteen_shared_points_or_are_the_best_one() {
        let (map, k) = chain(&[20, 5]);
        assert_eq!(map.keyframes[k[0]].connections, vec![(k[1], 20)]);
        // k1 shares 20 with k0 and 5 with k2: k2's weak edge is its best one, so it
        // is kept (on both sides) although it is below the threshold.
        assert_eq!(map.keyframes[k[1]].connections, vec![(k[0], 20), (k[2], 5)]);
        assert_eq!(map.keyframes[k[2]].connections, vec![(k[1], 5)]);
        assert_eq!(map.keyframes[k[1]].parent, Some(k[0]));
        assert_eq!(map.keyframes[k[2]].parent, Some(k[1]));
        assert_eq!(map.keyframes[k[0]].parent, None);
    }

    #[test]
    fn parents_are_older_whatever_order_mapping_runs_in() {
        // k1 shares most with k2, but k2 is newer: k1 hangs under k0, never under k2,
        // so removing k1 cannot make k2 its own parent.
        let (mut map, k) = chain_updated_in(&[20, 30], &[0, 2, 1]);
        assert_eq!(map.keyframes[k[2]].parent, Some(k[1]));
        assert_eq!(map.keyframes[k[1]].parent, Some(k[0]));
        map.remove_keyframe(k[1]);
        assert_eq!(map.keyframes[k[2]].parent, Some(k[0]));
    }

    #[test]
    fn removing_a_keyframe_reattaches_its_children_and_drops_lone_points() {
        let (mut map, k) = chain(&[20, 18]);
        let points_before = map.points.len();
        map.keyframes[k[1]].camera_from_world = Se3::translation(0.0, 0.0, 1.0);
        map.remove_keyframe(k[1]);
        assert!(!map.keyframes.contains_key(k[1]));
        // Its pose follows its parent's later corrections.
        map.keyframes[k[0]].camera_from_world = Se3::translation(1.0, 0.0, 0.0);
        let pose = map.keyframe_pose(k[1]).unwrap();
        assert!((pose.translation.vector - nalgebra::Vector3::new(1.0, 0.0, 1.0)).norm() < 1e-12);
        assert_eq!(map.keyframe_order, vec![k[0], k[2]]);
        assert_eq!(map.keyframes[k[2]].parent, Some(k[0]));
        assert!(map.keyframes[k[0]].children.contains(&k[2]));
        assert!(map.keyframes[k[0]]
            .connections
            .iter()
            .all(|(o, _)| *o != k[1]));
        // Every point was seen by k1 and one other keyframe: each keeps one observation.
        assert_eq!(map.points.len(), points_before);
        assert!(map.points.values().all(|p| p.observations.len() == 1));
        // The root is never removed.
        map.remove_keyframe(k[0]);
        assert!(map.keyframes.contains_key(k[0]));
    }

    #[test]
    fn replacing_a_point_moves_its_observations() {
        let mut map = Map::default();
        let a = map.add_keyframe(keyframe(3));
        let b = map.add_keyframe(keyframe(3));
        let old = map.points.insert(point());
        let new = map.points.insert(point());
        map.add_observation(old, a, 0);
        map.add_observation(old, b, 1);
        map.add_observation(new, b, 2);
        map.replace_point(old, new);
        assert!(!map.points.contains_key(old));
        assert_eq!(map.keyframes[a].map_points[0], Some(new));
        // b already saw `new`: its observation of `old` is dropped, not duplicated.
        assert_eq!(map.keyframes[b].map_points[1], None);
        assert_eq!(map.points[new].observations.len(), 2);
    }
}
