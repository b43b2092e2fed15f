//! Local mapping (ORB-SLAM §VI, ORB-SLAM2 §III-D): for each new keyframe, in order,
//! 1. update its points (normal, descriptor, distances) and covisibility edges;
//! 2. cull recent map points that tracking rarely re-finds or no second keyframe sees;
//! 3. triangulate new points with its best covisible keyframes;
//! 4. fuse duplicates with its first and second covisible neighbours;
//! 5. run local bundle adjustment over its covisible window;
//! 6. cull redundant covisible keyframes.
//!
//! [`LocalMapping`] runs this beside tracking in its own thread (the real-time mode:
//! tracking never waits for it), or inline after each keyframe in `--deterministic`
//! mode so that results repeat exactly. Both modes run the same code on the shared
//! map; heavy searches take the read lock and the solver runs with no lock at all.

pub mod culling;
pub mod fusion;
pub mod triangulation;
pub mod window_ba;

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::features::ScalePyramid;
use crate::geometry::camera::ImageSize;
use crate::geometry::stereo_camera::StereoCamera;
use crate::map::{KeyFrameKey, MapPoint, MapPointKey, SharedMap};

/// Local mapping parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MappingConfig {
    /// Covisible keyframes searched for triangulation and fusion (ORB-SLAM2: 10).
    pub neighbours: usize,
    /// Triangulate new points from the covisible keyframes.
    pub triangulation: bool,
    /// Fuse duplicate points.
    pub fusion: bool,
    /// Run local BA.
    pub local_ba: bool,
    /// Free keyframes in local BA: the new one and its best covisible ones.
    pub local_ba_keyframes: usize,
    /// Cull points that are rarely re-found.
    pub cull_points: bool,
    /// Cull redundant keyframes.
    pub cull_keyframes: bool,
    /// Fraction of a keyframe's close points seen by three others that makes it redundant.
    pub redundancy: f64,
}

impl Default for MappingConfig {
    fn default() -> Self {
        Self {
            neighbours: 10,
            triangulation: true,
            fusion: true,
            local_ba: true,
            local_ba_keyframes: 10,
            cull_points: true,
            cull_keyframes: true,
            redundancy: 0.9,
        }
    }
}

/// What local mapping did over a run.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MappingStats {
    /// Keyframes processed.
    pub keyframes_processed: usize,
    /// Points triangulated.
    pub points_triangulated: usize,
    /// Points culled.
    pub points_culled: usize,
    /// Points fused into others.
    pub fusions: usize,
    /// Observations local BA dropped as outliers.
    pub ba_outliers_removed: usize,
    /// Keyframes culled as redundant.
    pub keyframes_culled: usize,
    /// Keyframes whose local BA was skipped because more were waiting.
    pub ba_skipped: usize,
    /// Milliseconds spent in local mapping in total and in local BA.
    pub total_ms: f64,
    /// Milliseconds in local BA.
    pub ba_ms: f64,
}

/// The local mapper: processes keyframes one by one on the shared map.
pub struct LocalMapper {
    /// Its settings.
    pub config: MappingConfig,
    camera: StereoCamera,
    pyramid: ScalePyramid,
    size: (f32, f32),
    /// RGB-D close/far limit in metres.
    close_depth: f32,
    recent: Vec<MapPointKey>,
    /// Keyframes handed over and not yet processed (this one included), in the
    /// threaded mode: with more waiting, local BA and keyframe culling are skipped, as
    /// ORB-SLAM2 does, so that mapping keeps up.
    pending: Option<Arc<AtomicUsize>>,
    /// Keypoints with a moving probability above this make no new points (1: none
    /// excluded; the DOP model sets its removal threshold).
    pub removal_threshold: f32,
    /// What it did so far.
    pub stats: MappingStats,
    /// Called with each keyframe once it is processed (loop detection takes it from
    /// here, as ORB-SLAM2's local mapping hands keyframes to loop closing).
    pub then: Option<Box<dyn FnMut(KeyFrameKey) + Send>>,
}

impl LocalMapper {
    /// A mapper with `config` for `camera` and `pyramid`.
    pub fn new(
        config: MappingConfig,
        camera: StereoCamera,
        pyramid: ScalePyramid,
        size: impl Into<ImageSize>,
        close_depth: f32,
    ) -> Self {
        let ImageSize { width, height } = size.into();
        Self {
            config,
            camera,
            pyramid,
            size: (width as f32, height as f32),
            close_depth,
            recent: Vec::new(),
            pending: None,
            removal_threshold: 1.0,
            stats: MappingStats::default(),
            then: None,
        }
    }

    /// Beside tracking: the count of keyframes handed over and not yet processed.
    pub fn set_pending(&mut self, pending: Arc<AtomicUsize>) {
        self.pending = Some(pending);
    }

    fn more_waiting(&self) -> bool {
        self.pending
            .as_ref()
            .is_some_and(|p| p.load(Ordering::SeqCst) > 1)
    }

    /// Runs the six steps for keyframe `key`.
    pub fn process(&mut self, map: &SharedMap, key: KeyFrameKey) {
        let start = Instant::now();
        let factors = self.pyramid.factors.clone();
        let id = {
            let mut m = map.write().expect("map lock poisoned");
            let Some(kf) = m.keyframes().get(key) else {
                return;
            };
            let id = kf.id;
            let points: Vec<MapPointKey> = kf.map_points.iter().flatten().copied().collect();
            for p in points {
                if m.points().get(p).is_some_and(|p| p.first_keyframe_id == id) {
                    self.recent.push(p);
                }
                // Fusion updates every point of the keyframe at its end anyway.
                if !self.config.fusion {
                    m.update_point(p, &factors);
                }
            }
            m.update_connections(key);
            if self.config.cull_points {
                self.stats.points_culled += culling::cull_points(&mut m, &mut self.recent, id);
            }
            id
        };
        if self.config.triangulation {
            self.triangulate(map, key, id);
        }
        if self.config.fusion {
            self.fuse(map, key);
        }
        if self.more_waiting() {
            self.stats.ba_skipped += 1;
        } else if self.config.local_ba {
            let ba_start = Instant::now();
            let window = {
                let m = map.read().expect("map lock poisoned");
                window_ba::Window::build(
                    &m,
                    key,
                    self.config.local_ba_keyframes,
                    &self.pyramid,
                    self.removal_threshold,
                )
            };
            if let Some(mut window) = window {
                let report = window.solve(&self.camera);
                let mut m = map.write().expect("map lock poisoned");
                self.stats.ba_outliers_removed += window.apply(&mut m, &report, &factors);
            }
            self.stats.ba_ms += ba_start.elapsed().as_secs_f64() * 1e3;
        }
        if self.config.cull_keyframes && !self.more_waiting() {
            let mut m = map.write().expect("map lock poisoned");
            let neighbours: Vec<KeyFrameKey> = m.keyframes()[key]
                .connections
                .iter()
                .map(|(k, _)| *k)
                .collect();
            for k in neighbours {
                // Keyframes newer than this one may be in use by tracking.
                let older = m
                    .keyframes()
                    .get(k)
                    .is_some_and(|kf| kf.id > 0 && kf.id < id);
                if older && culling::is_redundant(&m, k, self.close_depth, self.config.redundancy) {
                    m.remove_keyframe(k);
                    self.stats.keyframes_culled += 1;
                }
            }
        }
        self.stats.keyframes_processed += 1;
        self.stats.total_ms += start.elapsed().as_secs_f64() * 1e3;
        if let Some(then) = self.then.as_mut() {
            then(key);
        }
    }

    /// Step 3: new points with the best covisible keyframes.
    fn triangulate(&mut self, map: &SharedMap, key: KeyFrameKey, id: usize) {
        let found: Vec<(KeyFrameKey, Vec<triangulation::NewPoint>)> = {
            let m = map.read().expect("map lock poisoned");
            let kf = &m.keyframes()[key];
            kf.best_covisible(self.config.neighbours)
                .into_iter()
                .filter_map(|other| {
                    let o = m.keyframes().get(other)?;
                    let points = triangulation::triangulate_pair(
                        kf,
                        o,
                        &self.camera,
                        &self.pyramid,
                        self.close_depth,
                        self.removal_threshold,
                    );
                    Some((other, points))
                })
                .collect()
        };
        let mut m = map.write().expect("map lock poisoned");
        for (other, points) in found {
            for p in points {
                let free = |k: KeyFrameKey, i: usize| {
                    m.keyframes()
                        .get(k)
                        .is_some_and(|kf| kf.map_points[i].is_none())
                };
                if !free(key, p.index1) || !free(other, p.index2) {
                    continue;
                }
                let descriptor = m.keyframes()[key].frame.descriptors[p.index1];
                let point = m.insert_point(MapPoint::new(
                    p.position,
                    descriptor,
                    nalgebra::Vector3::z(),
                    (0.0, 0.0),
                    id,
                ));
                m.add_observation(point, key, p.index1);
                m.add_observation(point, other, p.index2);
                m.update_point(point, &self.pyramid.factors);
                self.recent.push(point);
                self.stats.points_triangulated += 1;
            }
        }
    }

    /// Step 4: the keyframe's points into its neighbours and theirs into it.
    fn fuse(&mut self, map: &SharedMap, key: KeyFrameKey) {
        let fusions = {
            let m = map.read().expect("map lock poisoned");
            let kf = &m.keyframes()[key];
            let mut targets = Vec::new();
            for k in kf.best_covisible(self.config.neighbours) {
                if !targets.contains(&k) {
                    targets.push(k);
                }
                for second in m.keyframes()[k].best_covisible(5) {
                    if second != key && !targets.contains(&second) {
                        targets.push(second);
                    }
                }
            }
            let own: Vec<MapPointKey> = kf.map_points.iter().flatten().copied().collect();
            let mut fusions = Vec::new();
            let mut theirs = Vec::new();
            let mut seen = std::collections::HashSet::new();
            for t in &targets {
                fusions.extend(fusion::search(
                    &m,
                    *t,
                    &own,
                    &self.camera,
                    &self.pyramid,
                    self.size,
                ));
                for p in m.keyframes()[*t].map_points.iter().flatten() {
                    if seen.insert(*p) {
                        theirs.push(*p);
                    }
                }
            }
            fusions.extend(fusion::search(
                &m,
                key,
                &theirs,
                &self.camera,
                &self.pyramid,
                self.size,
            ));
            fusions
        };
        let mut m = map.write().expect("map lock poisoned");
        self.stats.fusions += fusion::apply(&mut m, &fusions);
        for p in m.keyframes()[key].observed_points() {
            m.update_point(p, &self.pyramid.factors);
        }
        m.update_connections(key);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_config_round_trips_through_toml() {
        let config = MappingConfig::default();
        let text = toml::to_string(&config).unwrap();
        assert_eq!(toml::from_str::<MappingConfig>(&text).unwrap(), config);
        assert!(toml::from_str::<MappingConfig>("neighbors = 3").is_err());
    }
}
