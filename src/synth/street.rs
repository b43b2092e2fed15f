//! A street canyon along the camera path, for stereo sequences in the KITTI layout:
//! a road `camera_height` below the cameras (slabs that follow the path's height),
//! buildings on both sides set back from the path, cars parked at the kerbs (class "car", yet static: where masking every car
//! hurts), cars driving along the road in the other lane, and pedestrians crossing
//! ahead or walking on the pavements; or, with `layout = "highway"`, a highway
//! ([`super::outdoor`]: sky, trees, lane lines, traffic both ways, some of it at the
//! camera's own speed).
//!
//! Everything is an axis-aligned box (the scene's ray caster); the path's horizontal
//! heading picks which axis a building's or car's length runs along.

use std::sync::Arc;

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::movers::{standing_corner, up_axis, Appearance, Behaviour, Mover};
use super::outdoor::{HighwayLook, LaneFrame, FOLLOWING_LANE, ONCOMING_LANES, ROAD, TREES};
use super::scene::{Cuboid, Look, Scene};
use crate::checks::{self, BadValue};
use crate::geometry::se3::Se3;
use crate::random::Rng;

/// What kind of road the street is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum StreetLayout {
    /// A town street: buildings of speckled blocks on both sides, parked cars, cars in
    /// the other lane, pedestrians.
    #[default]
    Canyon,
    /// A highway ([`super::outdoor`]): sky, clumps of trees instead of buildings (a
    /// third of their size, set back `half_width` on the right and 9 m more on the
    /// left, beyond the oncoming carriageway, and at least 0.6 `half_width` from every
    /// camera), asphalt with lane lines, `moving_cars` oncoming at `car_speed` and
    /// `following_cars` in the lane to the left.
    Highway,
}

/// The street section of a synth config; `enabled = false` keeps the room.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StreetConfig {
    /// Render a street instead of the room.
    pub enabled: bool,
    /// A town street (`canyon`) or a `highway`.
    pub layout: StreetLayout,
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
    /// Highway only: cars in the lane left of the camera's, driving its way; every
    /// third at the camera's own mean speed (the hardest mover: still in the image),
    /// the others 8 or 16 % faster.
    pub following_cars: usize,
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
            layout: StreetLayout::Canyon,
            camera_height: 1.65,
            half_width: 7.0,
            building_spacing: 14.0,
            building_height: [6.0, 18.0],
            parking_spacing: 6.5,
            parked_share: 0.6,
            parking_offset: 3.6,
            moving_cars: 3,
            car_speed: 8.0,
            following_cars: 0,
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
        checks::each(
            "street",
            checks::positive,
            &[
                ("camera_height", self.camera_height),
                ("half_width", self.half_width),
                ("building_spacing", self.building_spacing),
                ("parking_spacing", self.parking_spacing),
                ("car_speed", self.car_speed),
                ("pedestrian_speed", self.pedestrian_speed),
                ("render_range", self.render_range),
                ("road_spacing", self.road_spacing),
            ],
        )?;
        checks::unit_interval("street.parked_share", self.parked_share)?;
        if self.following_cars > 0 && self.layout != StreetLayout::Highway {
            return Err(BadValue::new(
                "street.following_cars",
                "needs street.layout = \"highway\"",
            ));
        }
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
    /// Path length from the first pose (m).
    along: f64,
}

/// The path point of one pose: its horizontal heading (the viewing direction without
/// its `up` part) and left; `None` for a camera looking straight up or down.
fn path_point(pose: &Se3, up: (usize, f64), along: f64) -> Option<PathPoint> {
    let mut up_vector = Vector3::zeros();
    up_vector[up.0] = up.1;
    let mut heading = pose.rotation.matrix().column(2).into_owned();
    heading[up.0] = 0.0;
    let heading = heading.try_normalize(1e-9)?;
    Some(PathPoint {
        position: pose.translation.vector,
        left: up_vector.cross(&heading),
        heading,
        along,
    })
}

/// Points every `spacing` metres of path length (horizontal headings from the poses'
/// viewing directions).
fn along_path(poses: &[Se3], up: (usize, f64), spacing: f64) -> Vec<PathPoint> {
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
        points.extend(path_point(pose, up, travelled));
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
    fps: f64,
) -> (Scene, Vec<Mover>) {
    let street = Street {
        config,
        poses,
        up: up_axis(poses),
        cameras: poses.iter().map(|p| p.translation.vector).collect(),
    };
    let highway = config.layout == StreetLayout::Highway;
    let mut scene = street.room();
    let mut rng = Rng::new(seed ^ 0x57EE7);
    street.add_buildings(&mut scene, &mut rng);
    let mut movers = street.parked_cars(&mut rng);
    let points = along_path(poses, street.up, 1.0);
    if points.is_empty() {
        return (scene, movers);
    }
    if highway {
        street.add_highway_traffic(&mut movers, fps);
    } else {
        street.add_moving_cars(&points, &mut movers, &mut rng);
    }
    street.add_pedestrians(&points, appearance, &mut movers, &mut rng);
    if !highway {
        // A highway's trees stand beyond its lanes by construction; a diagonal
        // lane's axis-aligned swept box would take them all.
        let driving: Vec<Cuboid> = movers
            .iter()
            .filter(|m| m.start != m.end)
            .map(Mover::swept_box)
            .collect();
        scene.make_room_for(&driving, street.up.0, 0.3);
    }
    let lanes = street.add_road(&mut scene);
    if highway {
        let level = street
            .cameras
            .iter()
            .map(|c| c[street.up.0] * street.up.1)
            .sum::<f64>()
            / street.cameras.len().max(1) as f64
            - config.camera_height;
        scene.look = Look::Highway(Arc::new(HighwayLook {
            up: street.up,
            road_level: level,
            lanes: Arc::new(lanes),
        }));
    }
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
        // A highway's horizon is far: its treeline stands beyond the render range.
        let margin = match config.layout {
            StreetLayout::Canyon => config.half_width + 25.0,
            StreetLayout::Highway => config.half_width + config.render_range,
        };
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
        let highway = config.layout == StreetLayout::Highway;
        for point in along_path(self.poses, up, config.building_spacing) {
            for side in [-1.0, 1.0] {
                // A highway's trees are clumps a third of a building's size (axis-aligned
                // boxes beside a diagonal road reach towards it by their half
                // diagonal), and its left side lies beyond the median and the oncoming
                // lanes.
                let scale = if highway { 0.35 } else { 1.0 };
                let depth = scale * rng.range(6.0, 10.0);
                let beyond = if highway && side > 0.0 { 9.0 } else { 0.0 };
                let setback = config.half_width + beyond + depth / 2.0 + rng.range(0.0, 3.0);
                let centre = point.position + point.left * side * setback;
                let dims = (
                    scale * rng.range(0.8, 1.1) * config.building_spacing,
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
                let clearance = config.half_width * if highway { 0.6 } else { 1.0 };
                if clear_of(&self.cameras, min, size, clearance) {
                    let first = if highway { TREES } else { 2 };
                    let texture = first + scene.furniture.len() as u32;
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
        start: Vector3<f64>,
        end: Vector3<f64>,
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
                movers.push(self.car(min, min, size, 1.0, 0.0, instance));
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
                    movers.push(self.car(start, end, size, self.config.car_speed, phase, instance));
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
    /// the cameras there, wide enough to reach the buildings; the lane frame of each
    /// slab (a highway's slabs have texture [`ROAD`] + their index).
    fn add_road(&self, scene: &mut Scene) -> Vec<LaneFrame> {
        let (config, up) = (self.config, self.up);
        // A highway's verges, median and the land beyond are the road slabs' grass,
        // out to where the trees stand: no step down to the ground shows.
        let reach = match config.layout {
            StreetLayout::Canyon => config.half_width + 12.0,
            StreetLayout::Highway => config.half_width + 40.0,
        };
        let mut lanes = Vec::new();
        for point in self.road_points() {
            let top = self.floor_under(&point.position);
            let (min, size) = standing_box(
                point.position,
                &point.heading,
                (config.road_spacing * 1.5, 2.0 * reach, ROAD_THICKNESS),
                up,
                top - up.1 * ROAD_THICKNESS,
            );
            let texture = match config.layout {
                StreetLayout::Canyon => 1,
                StreetLayout::Highway => ROAD + lanes.len() as u32,
            };
            scene.furniture.push(Cuboid {
                min,
                max: min + size,
                texture,
            });
            lanes.push(LaneFrame {
                origin: point.position,
                heading: point.heading,
                left: point.left,
                along: point.along,
            });
        }
        lanes
    }

    /// Where the road slabs lie: every `road_spacing` metres of path, and on a
    /// highway also straight on for `render_range` metres beyond each end of it (its
    /// last frames look far ahead).
    fn road_points(&self) -> Vec<PathPoint> {
        let (config, up) = (self.config, self.up);
        let mut points = along_path(self.poses, up, config.road_spacing);
        if config.layout != StreetLayout::Highway || points.is_empty() {
            return points;
        }
        let steps = (config.render_range / config.road_spacing).ceil() as usize;
        let extend = |from: &PathPoint, sign: f64| -> Vec<PathPoint> {
            (1..=steps)
                .map(|k| {
                    let distance = sign * k as f64 * config.road_spacing;
                    PathPoint {
                        position: from.position + from.heading * distance,
                        along: from.along + distance,
                        ..*from
                    }
                })
                .collect()
        };
        let before = extend(&points[0], -1.0);
        let after = extend(&points[points.len() - 1], 1.0);
        points.extend(after);
        points.splice(0..0, before.into_iter().rev());
        points
    }

    /// A highway's traffic: `moving_cars` oncoming cars, each passing the camera at its
    /// own time in one of the two oncoming lanes, and `following_cars` in the lane
    /// left of the camera's. Each drives one leg of a straight line along the path's
    /// heading where it meets the camera (it never turns in view), kept only where
    /// that line keeps 1.2 m clear of the camera path.
    fn add_highway_traffic(&self, movers: &mut Vec<Mover>, fps: f64) {
        let (config, n) = (self.config, self.poses.len());
        let duration = (n.max(2) - 1) as f64 / fps;
        let length: f64 = self.cameras.windows(2).map(|w| (w[1] - w[0]).norm()).sum();
        let camera_speed = length / duration;
        let at_frame = |t: f64| {
            let frame = ((t * fps).round() as usize).min(n - 1);
            path_point(&self.poses[frame], self.up, 0.0)
        };
        // An oncoming car is 8 s of driving before and after it meets the camera.
        let window = 8.0;
        for i in 0..config.moving_cars {
            let meet = duration * (i as f64 + 0.5) / config.moving_cars as f64;
            let Some(point) = at_frame(meet) else {
                continue;
            };
            let reach = config.car_speed * window;
            let lane = ONCOMING_LANES[i % 2];
            // At `start` when t + phase = 0, i.e. at t = meet - window.
            let drive = (lane, (reach, -reach), config.car_speed, window - meet);
            self.push_car(movers, &point, drive);
        }
        let Some(first) = at_frame(0.0) else { return };
        for j in 0..config.following_cars {
            let speed = camera_speed * (1.0 + 0.08 * (j % 3) as f64);
            let ahead = 10.0 + 15.0 * j as f64;
            let drive = (
                FOLLOWING_LANE,
                (ahead, ahead + speed * duration + 20.0),
                speed,
                0.0,
            );
            self.push_car(movers, &first, drive);
        }
    }

    /// A car `lateral` metres left of `point`, driving from `along.0` to `along.1`
    /// metres along its heading at `speed`, at the start when `t + phase = 0`; left
    /// out where that line comes within 1.2 m of a camera.
    fn push_car(
        &self,
        movers: &mut Vec<Mover>,
        point: &PathPoint,
        (lateral, along, speed, phase): (f64, (f64, f64), f64, f64),
    ) {
        let floor = self.floor_under(&point.position);
        let centre = point.position + point.left * lateral;
        let (corner, size) = standing_box(centre, &point.heading, (4.3, 1.8, 1.5), self.up, floor);
        let (start, end) = (
            corner + point.heading * along.0,
            corner + point.heading * along.1,
        );
        let clear = (0..=100).all(|k| {
            let at = start.lerp(&end, k as f64 / 100.0);
            clear_of(&self.cameras, at, size, 1.2)
        });
        if clear {
            let instance = movers.len() as u16 + 1;
            movers.push(self.car(start, end, size, speed, phase, instance));
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
        let (scene, movers) = build_street(&config, &poses, &Appearance::Box, 1, 10.0);
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

    #[test]
    fn a_highway_has_sky_lanes_and_traffic_both_ways_one_car_at_the_cameras_speed() {
        // KITTI's convention (y down), 100 frames at 10 Hz along +z at 10 m/s.
        let poses: Vec<Se3> = (0..100)
            .map(|i| {
                let position = Vector3::new(0.0, 0.0, i as f64);
                crate::geometry::se3::from_parts(position, Matrix3::identity())
            })
            .collect();
        let config = StreetConfig {
            enabled: true,
            layout: StreetLayout::Highway,
            half_width: 8.0,
            parked_share: 0.0,
            moving_cars: 4,
            car_speed: 27.0,
            following_cars: 3,
            pedestrians: 0,
            ..StreetConfig::default()
        };
        let (scene, movers) = build_street(&config, &poses, &Appearance::Box, 1, 10.0);
        assert!(matches!(scene.look, Look::Highway(_)));
        let camera = poses[50].translation.vector;
        let sky = scene.cast(&camera, &-Vector3::y()).expect("the sky above");
        assert!(scene.is_emissive(&sky), "{sky:?}");
        assert!(scene.colour(&sky, 0.01).iter().all(|&c| c > 0.85));
        // Down onto the camera's lane: plain asphalt; onto the right edge line: paint;
        // beyond the shoulder: grass. x is right, so the left is -x.
        let colour_at = |lateral: f64| {
            let down = Vector3::new(-lateral, config.camera_height, 0.0);
            let hit = scene.cast(&camera, &down).expect("the road");
            assert!(!scene.is_emissive(&hit));
            scene.colour(&hit, 0.003)
        };
        let (lane, line, verge) = (colour_at(0.0), colour_at(-1.9), colour_at(-6.0));
        assert!((0.2..0.45).contains(&lane[0]), "{lane:?}");
        assert!(line[0] > 0.7, "{line:?}");
        assert!(verge[1] > verge[0] + 0.03, "grass is green: {verge:?}");
        // Every car kept (a straight road), each oncoming one beside the camera when
        // they meet, the first following one 10 m ahead all along.
        assert_eq!(movers.len(), 7);
        let centre = |m: &Mover, t: f64| {
            let c = m.cuboid_at(t);
            (c.min + c.max) / 2.0
        };
        let duration = 9.9;
        for (i, car) in movers[..4].iter().enumerate() {
            let meet = duration * (i as f64 + 0.5) / 4.0;
            let at = centre(car, meet);
            let frame = (meet * 10.0).round();
            let z = at.z;
            assert!(
                (z - frame).abs() < 1.0,
                "car {i} at z {z}, the camera at {frame}"
            );
            assert!((-at.x - ONCOMING_LANES[i % 2]).abs() < 0.1, "{at:?}");
            assert!(centre(car, meet + 0.5).z < at.z - 10.0, "oncoming");
        }
        let follower = &movers[4];
        let speed = follower.speed;
        assert!(
            (speed - 10.0).abs() < 1e-9,
            "the camera's 99 m in 9.9 s: {speed}"
        );
        for t in [0.0, 5.0, 9.9] {
            let ahead = centre(follower, t).z - 10.0 * t;
            assert!((ahead - 10.0).abs() < 0.5, "t {t}: {ahead} m ahead");
            assert!((-centre(follower, t).x - FOLLOWING_LANE).abs() < 0.1);
        }
    }
}
