//! Movers: people walking back and forth across the camera's view, as boxes of a
//! person's size (1.75 x 0.5 x 0.3 m) moving at walking speed. Each has an instance id
//! (1, 2, …; 0 is the static scene in the masks) and a COCO class.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::scene::{Cuboid, Scene};
use crate::geometry::se3::Se3;

/// The people section of a synth config.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PeopleConfig {
    /// How many people walk through the view.
    pub count: usize,
    /// Walking speed in m/s.
    pub speed: f64,
    /// Distance of the first walking path in front of the mean camera position (m).
    pub distance: f64,
    /// Half length of each walking path (m).
    pub span: f64,
    /// Height of a person (m).
    pub height: f64,
    /// Height of the mean camera position above the floor (m), like a hand-held camera.
    pub camera_height: f64,
}

impl Default for PeopleConfig {
    fn default() -> Self {
        Self {
            count: 0,
            speed: 0.8,
            distance: 1.8,
            span: 1.8,
            height: 1.75,
            camera_height: 1.2,
        }
    }
}

/// Seated people: they sit still (swaying slightly) for a while, then stand up and
/// walk out of the view; with a very long `sit_seconds` they never leave.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SeatedConfig {
    pub count: usize,
    /// How long each sits before leaving (s).
    pub sit_seconds: f64,
    /// Distance in front of the mean camera position (m).
    pub distance: f64,
    /// Amplitude of the seated sway (m).
    pub sway: f64,
    /// Height of a seated person (m).
    pub seated_height: f64,
}

impl Default for SeatedConfig {
    fn default() -> Self {
        Self {
            count: 0,
            sit_seconds: 10.0,
            distance: 1.6,
            sway: 0.02,
            seated_height: 1.25,
        }
    }
}

/// How a mover moves.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Behaviour {
    /// Back and forth between `start` and `end` forever.
    Walk,
    /// Seated at `start` (lower box, slight sway) until `sit_seconds`, then walks once to
    /// `end` at full height and stays there.
    Seated {
        sit_seconds: f64,
        seated_height: f64,
        sway: f64,
    },
}

/// A moving object.
#[derive(Debug, Clone, PartialEq)]
pub struct Mover {
    pub instance: u16,
    pub class: &'static str,
    pub class_id: u32,
    /// The box's minimum corner at the two ends of its path.
    pub start: Vector3<f64>,
    pub end: Vector3<f64>,
    pub size: Vector3<f64>,
    pub speed: f64,
    /// Time offset in seconds along the back-and-forth walk.
    pub phase: f64,
    pub behaviour: Behaviour,
    /// The world axis that points up, and its sign.
    pub up: (usize, f64),
}

impl Mover {
    /// The box at time `t` seconds.
    pub fn cuboid_at(&self, t: f64) -> Cuboid {
        let texture = 1000 + self.instance as u32;
        if let Behaviour::Seated {
            sit_seconds,
            seated_height,
            sway,
        } = self.behaviour
        {
            let (up, sign) = self.up;
            if t < sit_seconds {
                let mut min = self.start;
                let lateral = (self.end - self.start)
                    .try_normalize(1e-9)
                    .unwrap_or_default();
                min += lateral * sway * (0.7 * t + self.phase).sin();
                let mut max = min + self.size;
                // Keep the feet on the floor: shorten the box from the top.
                if sign > 0.0 {
                    max[up] = min[up] + seated_height;
                } else {
                    min[up] = max[up] - seated_height;
                }
                return Cuboid { min, max, texture };
            }
            let length = (self.end - self.start).norm().max(1e-9);
            let along = ((t - sit_seconds) * self.speed / length).min(1.0);
            let min = self.start.lerp(&self.end, along);
            return Cuboid {
                min,
                max: min + self.size,
                texture,
            };
        }
        let length = (self.end - self.start).norm().max(1e-9);
        let period = 2.0 * length / self.speed;
        let s = ((t + self.phase) % period + period) % period * self.speed;
        let along = if s <= length { s } else { 2.0 * length - s } / length;
        let min = self.start.lerp(&self.end, along);
        Cuboid {
            min,
            max: min + self.size,
            texture: 1000 + self.instance as u32,
        }
    }
}

/// The world axis closest to "up" over the camera poses (camera -y), and its sign.
pub fn up_axis(poses: &[Se3]) -> (usize, f64) {
    let up: Vector3<f64> = poses
        .iter()
        .map(|p| -(p.rotation.matrix().column(1).into_owned()))
        .sum();
    let axis = up.iamax();
    (axis, up[axis].signum())
}

/// Places the floor `camera_height` below the mean camera position, and `count` people
/// on paths across the mean viewing direction, the first at `distance`, each next one
/// 0.8 m farther, walking in alternating directions.
pub fn place_people(config: &PeopleConfig, poses: &[Se3], scene: &mut Scene) -> Vec<Mover> {
    if poses.is_empty() {
        return Vec::new();
    }
    let (up, sign) = up_axis(poses);
    let (centre, forward, lateral) = viewing_frame(poses, up, sign);
    let floor = centre[up] - sign * config.camera_height;
    if sign > 0.0 {
        scene.room.min[up] = floor;
    } else {
        scene.room.max[up] = floor;
    }
    let mut size = Vector3::repeat(0.4);
    size[up] = config.height;
    (0..config.count)
        .map(|i| {
            let middle = centre + forward * (config.distance + 0.8 * i as f64);
            let (mut a, mut b) = (
                middle - lateral * config.span,
                middle + lateral * config.span,
            );
            if i % 2 == 1 {
                std::mem::swap(&mut a, &mut b);
            }
            // Box corners: the floor level along `up`, centred on the path otherwise.
            let corner = |p: Vector3<f64>| {
                let mut c = p - size * 0.5;
                c[up] = if sign > 0.0 {
                    floor
                } else {
                    floor - config.height
                };
                c
            };
            Mover {
                instance: i as u16 + 1,
                class: "person",
                class_id: 0,
                start: corner(a),
                end: corner(b),
                size,
                speed: config.speed,
                phase: 1.7 * i as f64,
                behaviour: Behaviour::Walk,
                up: (up, sign),
            }
        })
        .collect()
}

/// Places `count` seated people `distance` in front of the mean camera position, spread
/// sideways 0.9 m apart; each leaves sideways (4 m) after `sit_seconds`. Instance ids
/// continue after `first_instance - 1`. Call after [`place_people`] (which sets the floor).
pub fn place_seated(
    config: &SeatedConfig,
    height: f64,
    poses: &[Se3],
    scene: &Scene,
    first_instance: u16,
) -> Vec<Mover> {
    if poses.is_empty() || config.count == 0 {
        return Vec::new();
    }
    let (up, sign) = up_axis(poses);
    let (centre, forward, lateral) = viewing_frame(poses, up, sign);
    let floor = if sign > 0.0 {
        scene.room.min[up]
    } else {
        scene.room.max[up]
    };
    let mut size = Vector3::repeat(0.5);
    size[up] = height;
    (0..config.count)
        .map(|i| {
            let offset = (i as f64 - (config.count as f64 - 1.0) / 2.0) * 0.9;
            let seat = centre + forward * config.distance + lateral * offset;
            let exit = seat + lateral * if offset >= 0.0 { 4.0 } else { -4.0 };
            let corner = |p: Vector3<f64>| {
                let mut c = p - size * 0.5;
                c[up] = if sign > 0.0 { floor } else { floor - height };
                c
            };
            Mover {
                instance: first_instance + i as u16,
                class: "person",
                class_id: 0,
                start: corner(seat),
                end: corner(exit),
                size,
                speed: 0.8,
                phase: 2.3 * i as f64,
                behaviour: Behaviour::Seated {
                    sit_seconds: config.sit_seconds,
                    seated_height: config.seated_height,
                    sway: config.sway,
                },
                up: (up, sign),
            }
        })
        .collect()
}

/// The mean camera position, and the horizontal forward and lateral directions.
fn viewing_frame(
    poses: &[Se3],
    up: usize,
    sign: f64,
) -> (Vector3<f64>, Vector3<f64>, Vector3<f64>) {
    let n = poses.len() as f64;
    let centre: Vector3<f64> = poses
        .iter()
        .map(|p| p.translation.vector)
        .sum::<Vector3<f64>>()
        / n;
    let mut forward: Vector3<f64> = poses
        .iter()
        .map(|p| p.rotation.matrix().column(2).into_owned())
        .sum();
    forward[up] = 0.0;
    let forward = forward.try_normalize(1e-9).unwrap_or_else(|| {
        let mut f = Vector3::zeros();
        f[(up + 1) % 3] = 1.0;
        f
    });
    let mut up_vector = Vector3::zeros();
    up_vector[up] = sign;
    (centre, forward, up_vector.cross(&forward))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn walks_back_and_forth() {
        let mover = Mover {
            instance: 1,
            class: "person",
            class_id: 0,
            start: Vector3::zeros(),
            end: Vector3::new(2.0, 0.0, 0.0),
            size: Vector3::repeat(0.4),
            speed: 1.0,
            phase: 0.0,
            behaviour: Behaviour::Walk,
            up: (1, -1.0),
        };
        assert!((mover.cuboid_at(1.0).min.x - 1.0).abs() < 1e-12);
        assert!((mover.cuboid_at(3.0).min.x - 1.0).abs() < 1e-12);
        assert!((mover.cuboid_at(4.0).min.x).abs() < 1e-12);
        let seated = Mover {
            behaviour: Behaviour::Seated {
                sit_seconds: 5.0,
                seated_height: 1.2,
                sway: 0.0,
            },
            size: Vector3::new(0.5, 1.75, 0.5),
            ..mover
        };
        // Up is -y: the seated box keeps its feet (max y) and is 1.2 m tall.
        let sitting = seated.cuboid_at(1.0);
        assert!(
            (sitting.max.y - 1.75).abs() < 1e-12
                && (sitting.max.y - sitting.min.y - 1.2).abs() < 1e-12
        );
        assert_eq!(seated.cuboid_at(3.0), sitting);
        assert!((seated.cuboid_at(6.0).min.x - 1.0).abs() < 1e-12);
        assert!(
            (seated.cuboid_at(60.0).min.x - 2.0).abs() < 1e-12,
            "stays where it left to"
        );
    }
}
