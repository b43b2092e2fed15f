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
    /// Height of a person (m); the floor is put this far below the camera plus 0.05 m.
    pub height: f64,
}

impl Default for PeopleConfig {
    fn default() -> Self {
        Self {
            count: 0,
            speed: 0.8,
            distance: 1.8,
            span: 1.8,
            height: 1.75,
        }
    }
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
}

impl Mover {
    /// The box at time `t` seconds: walking from `start` to `end` and back.
    pub fn cuboid_at(&self, t: f64) -> Cuboid {
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

/// Places the floor `height + 0.05` m below the mean camera position, and `count` people
/// on paths across the mean viewing direction, the first at `distance`, each next one
/// 0.8 m farther, walking in alternating directions.
pub fn place_people(config: &PeopleConfig, poses: &[Se3], scene: &mut Scene) -> Vec<Mover> {
    if poses.is_empty() {
        return Vec::new();
    }
    let (up, sign) = up_axis(poses);
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
    let lateral = up_vector.cross(&forward);
    let floor = centre[up] - sign * (config.height + 0.05);
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
            }
        })
        .collect()
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
        };
        assert!((mover.cuboid_at(1.0).min.x - 1.0).abs() < 1e-12);
        assert!((mover.cuboid_at(3.0).min.x - 1.0).abs() < 1e-12);
        assert!((mover.cuboid_at(4.0).min.x).abs() < 1e-12);
    }
}
