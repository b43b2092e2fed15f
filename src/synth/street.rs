//! A street canyon along the camera path, for stereo sequences in the KITTI layout:
//! a road `camera_height` below the cameras (slabs that follow the path's height),
//! buildings on both sides set back from the path, cars parked at the kerbs (class "car", yet static: where masking every car
//! hurts), cars driving along the road in the other lane, and pedestrians crossing
//! ahead or walking on the pavements.
//!
//! Everything is an axis-aligned box (the scene's ray caster); the path's horizontal
//! heading picks which axis a building's or car's length runs along.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::movers::{standing_corner, up_axis, Appearance, Behaviour, Mover};
use super::scene::{Cuboid, Scene};
use crate::checks::{self, BadValue};
use crate::geometry::se3::Se3;
use crate::random::Rng;

/// The street section of a synth config; `enabled = false` keeps the room.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StreetConfig {
    /// Render a street instead of the room.
    pub enabled: bool,
    /// Height of the cameras above the road (KITTI: 1.65 m).
    pub camera_height: f64,
    /// Buildings keep at least this far from every camera position (m).
    pub half_width: f64,
    /// Path length between building plots on each side (m).
    pub building_spacing: f64,
    /// Building height range (m).
    pub building_height: [f64; 2],
    /// Path length between parking spots on each side (m), and the share taken.
    pub parking_spacing: f64,
    /// The share of spots taken.
    pub parked_share: f64,
    /// Lateral distance of parked cars' centres from the path (m).
    pub parking_offset: f64,
    /// Cars driving back and forth along the other lane, and their speed (m/s).
    pub moving_cars: usize,
    /// Their speed (m/s).
    pub car_speed: f64,
    /// Pedestrians crossing ahead of the path or walking along the pavements.
    pub pedestrians: usize,
    /// Their speed (m/s).
    pub pedestrian_speed: f64,
    /// Only what lies within this distance of the camera is rendered (m).
    pub render_range: f64,
    /// Path length covered by each slab of road (m); the road follows the path's
    /// height slab by slab.
    pub road_spacing: f64,
}

impl Default for StreetConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            camera_height: 1.65,
            half_width: 7.0,
            building_spacing: 14.0,
            building_height: [6.0, 18.0],
            parking_spacing: 6.5,
            parked_share: 0.6,
            parking_offset: 3.6,
            moving_cars: 3,
            car_speed: 8.0,
            pedestrians: 4,
            pedestrian_speed: 1.4,
            render_range: 70.0,
            road_spacing: 4.0,
        }
    }
}

impl StreetConfig {
    /// Checks each value's range; the error names the key.
    pub fn validate(&self) -> Result<(), BadValue> {
        checks::each("street", checks::positive, &[
            ("camera_height", self.camera_height),
            ("half_width", self.half_width),
            ("building_spacing", self.building_spacing),
            ("parking_spacing", self.parking_spacing),
            ("car_speed", self.car_speed),
            ("pedestrian_speed", self.pedestrian_speed),
            ("render_range", self.render_range),
            ("road_spacing", self.road_spacing),
        ])?;
        checks::unit_interval("street.parked_share", self.parked_share)?;
        if self.parking_offset >= self.half_width {
            return Err(BadValue::new(
                "street.parking_offset",
                format!(
                    "({}) must be less than street.half_width ({}): cars park in front of the buildings",
                    self.parking_offset, self.half_width
                ),
            ));
        }
        Ok(())
    }
}

/// How deep the road slabs (and the buildings' footings) reach below the road (m).
const ROAD_THICKNESS: f64 = 3.0;

/// A point along the path: position, horizontal heading and the horizontal left.
struct PathPoint {
    position: Vector3<f64>,
    heading: Vector3<f64>,
    left: Vector3<f64>,
}

/// Points every `spacing` metres of path length (horizontal headings from the poses'
/// viewing directions).
fn along_path(poses: &[Se3], up: (usize, f64), spacing: f64) -> Vec<PathPoint> {
    let mut up_vector = Vector3::zeros();
    up_vector[up.0] = up.1;
    let mut points = Vec::new();
    let mut next = 0.0;
    let mut travelled = 0.0;
    for (i, pose) in poses.iter().enumerate() {
        if i > 0 {
            travelled += (pose.translation.vector - poses[i - 1].translation.vector).norm();
        }
        if travelled + 1e-9 < next {
            continue;
        }
        next = travelled + spacing;
        let mut heading = pose.rotation.matrix().column(2).into_owned();
        heading[up.0] = 0.0;
        let Some(heading) = heading.try_normalize(1e-9) else {
            continue;
        };
        points.push(PathPoint {
            position: pose.translation.vector,
            left: up_vector.cross(&heading),
            heading,
        });
    }
    points
}

/// An axis-aligned box centred on `centre` horizontally, standing on `floor`, with its
/// `length` along the horizontal axis closest to `heading`.
fn standing_box(
    centre: Vector3<f64>,
    heading: &Vector3<f64>,
    (length, width, height): (f64, f64, f64),
    up: (usize, f64),
    floor: f64,
) -> (Vector3<f64>, Vector3<f64>) {
    let horizontal: Vec<usize> = (0..3).filter(|&a| a != up.0).collect();
    let along = if heading[horizontal[0]].abs() >= heading[horizontal[1]].abs() {
        horizontal[0]
    } else {
        horizontal[1]
    };
    let across = horizontal[0] + horizontal[1] - along;
    let mut size = Vector3::zeros();
    size[along] = length;
    size[across] = width;
    size[up.0] = height;
    (standing_corner(centre, &size, up.0, up.1, floor), size)
}

/// Whether the box at `min` of `size` keeps `clearance` metres from every camera.
fn clear_of(
    cameras: &[Vector3<f64>],
    min: Vector3<f64>,
    size: Vector3<f64>,
    clearance: f64,
) -> bool {
    let cuboid = Cuboid {
        min,
        max: min + size,
        texture: 0,
    };
    cuboid.clear_of(cameras, clearance)
}

/// The street scene and its movers along `poses`; movers' instance ids start at 1 and
/// `appearance` dresses the pedestrians.
pub fn build_street(
    config: &StreetConfig,
    poses: &[Se3],
    appearance: &Appearance,
    seed: u64,
) -> (Scene, Vec<Mover>) {
    let street = Street {
        config,
        poses,
        up: up_axis(poses),
        cameras: poses.iter().map(|p| p.translation.vector).collect(),
    };
    let mut scene = street.room();
    let mut rng = Rng::new(seed ^ 0x57EE7);
    street.add_buildings(&mut scene, &mut rng);
    let mut movers = street.parked_cars(&mut rng);
    let points = along_path(poses, street.up, 1.0);
    if points.is_empty() {
        return (scene, movers);
    }
    street.add_moving_cars(&points, &mut movers, &mut rng);
    street.add_pedestrians(&points, appearance, &mut movers, &mut rng);
    let driving: Vec<Cuboid> = movers
        .iter()
        .filter(|m| m.start != m.end)
        .map(Mover::swept_box)
        .collect();
    scene.make_room_for(&driving, street.up.0, 0.3);
    street.add_road(&mut scene);
    (scene, movers)
}

/// What every part of the street is placed by: the config, the camera path, its up
/// axis (index, sign) and the cameras' centres.
struct Street<'a> {
    config: &'a StreetConfig,
    poses: &'a [Se3],
    up: (usize, f64),
    cameras: Vec<Vector3<f64>>,
}

impl Street<'_> {
    /// The road's height under a path point: the road follows the path's height (KITTI
    /// 00 climbs 11 m in its first 1000 frames), and everything stands on the road under
    /// its own path point.
    fn floor_under(&self, p: &Vector3<f64>) -> f64 {
        p[self.up.0] - self.up.1 * self.config.camera_height
    }

    /// The "room": ground well below the lowest road, a far sky above, distant facades
    /// all round; the road itself is slabs along the path ([`Street::add_road`]).
    fn room(&self) -> Scene {
        let (config, up) = (self.config, self.up);
        let (mut lo, mut hi) = (
            Vector3::repeat(f64::INFINITY),
            Vector3::repeat(f64::NEG_INFINITY),
        );
        for c in &self.cameras {
            lo = lo.inf(c);
            hi = hi.sup(c);
        }
        let margin = config.half_width + 25.0;
        let (mut min, mut max) = (lo.add_scalar(-margin), hi.add_scalar(margin));
        let (low, high) = if up.1 > 0.0 { (lo, hi) } else { (hi, lo) };
        let ground = low[up.0] - up.1 * (config.camera_height + ROAD_THICKNESS);
        let sky = high[up.0] + up.1 * 30.0;
        (min[up.0], max[up.0]) = (ground.min(sky), ground.max(sky));
        Scene {
            room: Cuboid {
                min,
                max,
                texture: 1,
            },
            furniture: Vec::new(),
            look: super::scene::Look::Blocks,
        }
    }

    /// A building on each side of every `building_spacing` metres of path, where it
    /// keeps clear of the cameras.
    fn add_buildings(&self, scene: &mut Scene, rng: &mut Rng) {
        let (config, up) = (self.config, self.up);
        for point in along_path(self.poses, up, config.building_spacing) {
            for side in [-1.0, 1.0] {
                let depth = rng.range(6.0, 10.0);
                let setback = config.half_width + depth / 2.0 + rng.range(0.0, 3.0);
                let centre = point.position + point.left * side * setback;
                let dims = (
                    rng.range(0.8, 1.1) * config.building_spacing,
                    depth,
                    rng.range(config.building_height[0], config.building_height[1]),
                );
                // Sunk below the road so that no slope shows a gap under it.
                let (min, size) = standing_box(
                    centre,
                    &point.heading,
                    (dims.0, dims.1, dims.2 + ROAD_THICKNESS),
                    up,
                    self.floor_under(&point.position) - up.1 * ROAD_THICKNESS,
                );
                if clear_of(&self.cameras, min, size, config.half_width) {
                    let texture = 2 + scene.furniture.len() as u32;
                    scene.furniture.push(Cuboid {
                        min,
                        max: min + size,
                        texture,
                    });
                }
            }
        }
    }

    /// A car box from `start` to `end` (equal for a parked car: a mover that never
    /// moves, so that masks and oracle boxes call it a car).
    fn car(
        &self,
        (start, end): (Vector3<f64>, Vector3<f64>),
        size: Vector3<f64>,
        speed: f64,
        phase: f64,
        instance: u16,
    ) -> Mover {
        Mover {
            instance,
            class: "car".into(),
            class_id: Some(2),
            start,
            end,
            size,
            speed,
            phase,
            behaviour: Behaviour::Walk {
                pause: 0.0,
                gait: None,
            },
            up: self.up,
            appearance: Appearance::Box,
        }
    }

    /// Parked cars along both kerbs, each spot taken with probability `parked_share`.
    fn parked_cars(&self, rng: &mut Rng) -> Vec<Mover> {
        let (config, up) = (self.config, self.up);
        let mut movers = Vec::new();
        for point in along_path(self.poses, up, config.parking_spacing) {
            for side in [-1.0, 1.0] {
                if rng.uniform() >= config.parked_share {
                    continue;
                }
                let centre = point.position + point.left * side * config.parking_offset;
                let floor = self.floor_under(&point.position);
                let (min, size) = standing_box(centre, &point.heading, (4.3, 1.8, 1.5), up, floor);
                if !clear_of(&self.cameras, min, size, config.parking_offset - 1.2) {
                    continue;
                }
                let instance = movers.len() as u16 + 1;
                movers.push(self.car((min, min), size, 1.0, 0.0, instance));
            }
        }
        movers
    }

    /// `moving_cars` cars in the other lane: 1.8 m to the left, 30 m each way along the
    /// heading, where that straight line keeps clear of the (possibly curving) camera
    /// path; up to 20 tries each.
    fn add_moving_cars(&self, points: &[PathPoint], movers: &mut Vec<Mover>, rng: &mut Rng) {
        for i in 0..self.config.moving_cars {
            for _attempt in 0..20 {
                let point = pick(points, rng);
                let centre = point.position + point.left * 1.8;
                let floor = self.floor_under(&point.position);
                let (min, size) =
                    standing_box(centre, &point.heading, (4.3, 1.8, 1.5), self.up, floor);
                let (start, end) = (min - point.heading * 30.0, min + point.heading * 30.0);
                let clear = (0..=30).all(|k| {
                    let at = start.lerp(&end, k as f64 / 30.0);
                    clear_of(&self.cameras, at, size, 1.2)
                });
                if clear {
                    let instance = movers.len() as u16 + 1;
                    let phase = 2.9 * i as f64;
                    movers.push(self.car(
                        (start, end),
                        size,
                        self.config.car_speed,
                        phase,
                        instance,
                    ));
                    break;
                }
            }
        }
    }

    /// `pedestrians` people: every other one crosses the road 12 m ahead of where the
    /// camera passes, the others walk along the far kerb.
    fn add_pedestrians(
        &self,
        points: &[PathPoint],
        appearance: &Appearance,
        movers: &mut Vec<Mover>,
        rng: &mut Rng,
    ) {
        let (config, up) = (self.config, self.up);
        for i in 0..config.pedestrians {
            let point = pick(points, rng);
            let (start, end) = if i % 2 == 0 {
                let ahead = point.position + point.heading * 12.0;
                (ahead + point.left * 5.0, ahead - point.left * 5.0)
            } else {
                let kerb = point.position - point.left * (config.parking_offset + 1.6);
                (kerb - point.heading * 6.0, kerb + point.heading * 6.0)
            };
            let mut size = Vector3::repeat(0.45);
            size[up.0] = 1.75;
            let floor = self.floor_under(&point.position);
            let corner = |p: Vector3<f64>| standing_corner(p, &size, up.0, up.1, floor);
            movers.push(Mover {
                instance: movers.len() as u16 + 1,
                class: "person".into(),
                class_id: Some(0),
                start: corner(start),
                end: corner(end),
                size,
                speed: config.pedestrian_speed,
                phase: 1.3 * i as f64,
                behaviour: Behaviour::Walk {
                    pause: 0.0,
                    gait: Some(1.4),
                },
                up,
                appearance: appearance.clone(),
            });
        }
    }

    /// The road: a slab under every few metres of path, its top `camera_height` below
    /// the cameras there, wide enough to reach the buildings.
    fn add_road(&self, scene: &mut Scene) {
        let (config, up) = (self.config, self.up);
        let reach = config.half_width + 12.0;
        for point in along_path(self.poses, up, config.road_spacing) {
            let top = self.floor_under(&point.position);
            let (min, size) = standing_box(
                point.position,
                &point.heading,
                (config.road_spacing * 1.5, 2.0 * reach, ROAD_THICKNESS),
                up,
                top - up.1 * ROAD_THICKNESS,
            );
            scene.furniture.push(Cuboid {
                min,
                max: min + size,
                texture: 1,
            });
        }
    }
}

/// A path point drawn uniformly from `points` (not empty).
fn pick<'p>(points: &'p [PathPoint], rng: &mut Rng) -> &'p PathPoint {
    &points[(rng.next_u64() % points.len() as u64) as usize]
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix3;

    #[test]
    fn the_road_follows_a_climbing_path_camera_height_below_every_camera() {
        // KITTI's convention: the camera looks along +z with y down; the path climbs
        // 4 m over 200 m (2 %), as KITTI 00's first kilometre does 11 m.
        let poses: Vec<Se3> = (0..200)
            .map(|i| {
                let z = i as f64;
                crate::geometry::se3::from_parts(
                    Vector3::new(0.0, -0.02 * z, z),
                    Matrix3::identity(),
                )
            })
            .collect();
        let config = StreetConfig {
            enabled: true,
            ..StreetConfig::default()
        };
        let (scene, movers) = build_street(&config, &poses, &Appearance::Box, 1);
        assert!(!movers.is_empty());
        let down = Vector3::y();
        for pose in poses.iter().step_by(7) {
            let camera = pose.translation.vector;
            let hit = scene.cast(&camera, &down).expect("road below the camera");
            // Slabs 4 m apart on a 2 % slope: steps of 8 cm.
            assert!(
                (hit.t - config.camera_height).abs() < 0.12,
                "road {} m below the camera at z = {}",
                hit.t,
                camera.z
            );
        }
    }
}
