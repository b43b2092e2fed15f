//! Movers: people walking back and forth across the camera's view, seated people who
//! leave, and objects of a "static" class (a chair, a box) pushed around. A person is a
//! textured box of a person's size or a real cut-out on a camera-facing billboard. Each
//! has an instance id (1, 2, …; 0 is the static scene in the masks) and a COCO class.

use std::path::PathBuf;
use std::sync::Arc;

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::scene::{Cuboid, Scene, Shape};
use super::sprite::{Billboard, Sprite};
use crate::checks::{self, BadValue};
use crate::detect::coco;
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
    /// A standing person's RGBA cut-out: people become camera-facing billboards of it
    /// instead of textured boxes.
    pub sprite: Option<PathBuf>,
    /// Distance of each person's path (m), overriding `distance` + 0.8 m per person:
    /// e.g. `[0.9, 2.2]` for a close pass that fills half the image.
    pub distances: Vec<f64>,
    /// A walker stops this long (s) in the middle of the path and at each end before
    /// turning back; 0 walks without stopping.
    pub pause: f64,
    /// Cut-outs walk with a gait (legs opening and closing once per `stride` metres,
    /// a vertical bob) and face their walking direction.
    pub gait: bool,
    /// Metres per step.
    pub stride: f64,
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
            sprite: None,
            distances: Vec::new(),
            pause: 0.0,
            gait: false,
            stride: 1.4,
        }
    }
}

/// Seated people: they sit still (swaying slightly) for a while, then stand up and
/// walk out of the view; with a very long `sit_seconds` they never leave.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SeatedConfig {
    /// Seated people.
    pub count: usize,
    /// How long each sits before leaving (s).
    pub sit_seconds: f64,
    /// Distance in front of the mean camera position (m).
    pub distance: f64,
    /// Amplitude of the seated sway (m).
    pub sway: f64,
    /// Height of a seated person (m).
    pub seated_height: f64,
    /// A seated person's RGBA cut-out, shown while seated (the standing one from
    /// `people.sprite`, if any, once they get up).
    pub sprite: Option<PathBuf>,
}

impl Default for SeatedConfig {
    fn default() -> Self {
        Self {
            count: 0,
            sit_seconds: 10.0,
            distance: 1.6,
            sway: 0.02,
            seated_height: 1.25,
            sprite: None,
        }
    }
}

/// Objects of a class the detector calls static (a chair, a suitcase) that are pushed
/// back and forth in view: the DOP model must notice that they move.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ObjectsConfig {
    /// Objects.
    pub count: usize,
    /// COCO class name.
    pub class: String,
    /// Size in metres: width, height, depth.
    pub size: [f64; 3],
    /// Speed in m/s.
    pub speed: f64,
    /// Distance in front of the mean camera position (m).
    pub distance: f64,
    /// Half length of the path (m).
    pub span: f64,
    /// Seconds the object stands still in the middle and at each end of its path.
    pub pause: f64,
    /// Height of the object's bottom above the floor (m): 0 stands on it, 1.3 floats
    /// at head height like a balloon.
    pub lift: f64,
}

impl Default for ObjectsConfig {
    fn default() -> Self {
        Self {
            count: 0,
            class: "chair".into(),
            size: [0.5, 0.9, 0.5],
            speed: 0.3,
            distance: 1.4,
            span: 0.8,
            pause: 0.0,
            lift: 0.0,
        }
    }
}

impl ObjectsConfig {
    /// Checks the section `key` (`objects`, or `unknown` for movers of no COCO class:
    /// `known` says which the class must be).
    pub fn validate(&self, key: &str, known: bool) -> Result<(), BadValue> {
        let class_key = format!("{key}.class");
        match (coco::class_id(&self.class).is_some(), known) {
            (false, true) => {
                return Err(BadValue::new(
                    class_key,
                    format!("{:?} is not a COCO class name", self.class),
                ))
            }
            (true, false) => {
                return Err(BadValue::new(
                    class_key,
                    format!(
                        "{:?} is a COCO class (a detector knows it); movers no detector knows go here, others under [objects]",
                        self.class
                    ),
                ))
            }
            _ => {}
        }
        if self.size.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
            return Err(BadValue::new(
                format!("{key}.size"),
                format!("must be positive, got {:?}", self.size),
            ));
        }
        checks::each(
            key,
            checks::positive,
            &[("speed", self.speed), ("span", self.span)],
        )?;
        checks::each(
            key,
            checks::non_negative,
            &[
                ("distance", self.distance),
                ("pause", self.pause),
                ("lift", self.lift),
            ],
        )?;
        Ok(())
    }
}

/// What a mover looks like.
#[derive(Debug, Clone, PartialEq)]
pub enum Appearance {
    /// A textured box.
    Box,
    /// A cut-out on a billboard; a seated person may have a second cut-out.
    Sprite {
        /// The standing cut-out.
        standing: Option<Arc<Sprite>>,
        /// The seated one.
        seated: Option<Arc<Sprite>>,
    },
}

/// How a mover moves.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Behaviour {
    /// Back and forth between `start` and `end` forever, stopping `pause` seconds in
    /// the middle and at each end; with `gait`, cut-outs step once per `stride` metres.
    Walk {
        /// Seconds stopped.
        pause: f64,
        /// Metres per step, with a gait.
        gait: Option<f64>,
    },
    /// Seated at `start` (lower box, slight sway) until `sit_seconds`, then walks once to
    /// `end` at full height and stays there.
    Seated {
        /// Seconds seated.
        sit_seconds: f64,
        /// The box's height while seated, metres.
        seated_height: f64,
        /// The sway's amplitude, metres.
        sway: f64,
    },
}

/// A moving object.
#[derive(Debug, Clone, PartialEq)]
pub struct Mover {
    /// The instance id in the masks.
    pub instance: u16,
    /// The class name.
    pub class: String,
    /// The COCO class id; `None` for a mover no detector knows.
    pub class_id: Option<u32>,
    /// The box's minimum corner at the two ends of its path.
    pub start: Vector3<f64>,
    /// The other end.
    pub end: Vector3<f64>,
    /// The box's size, metres.
    pub size: Vector3<f64>,
    /// Metres per second.
    pub speed: f64,
    /// Time offset in seconds along the back-and-forth walk.
    pub phase: f64,
    /// How it moves.
    pub behaviour: Behaviour,
    /// The world axis that points up, and its sign.
    pub up: (usize, f64),
    /// A box or a cut-out.
    pub appearance: Appearance,
}

impl Mover {
    /// The box swept by the mover over its whole path.
    pub fn swept_box(&self) -> Cuboid {
        let end = self.end + self.size;
        Cuboid {
            min: self.start.inf(&self.end),
            max: (self.start + self.size).sup(&end),
            texture: 0,
        }
    }

    /// Whether a seated mover is still seated at time `t`.
    pub fn seated_at(&self, t: f64) -> bool {
        matches!(self.behaviour, Behaviour::Seated { sit_seconds, .. } if t < sit_seconds)
    }

    /// The mover's geometry at time `t` seen from a camera at `camera`: its box, or a
    /// billboard standing on the box's bottom face, as tall as the box, facing the camera.
    pub fn shape_at(&self, t: f64, camera: &Vector3<f64>) -> Shape {
        let cuboid = self.cuboid_at(t);
        let Appearance::Sprite { standing, seated } = &self.appearance else {
            return Shape::Box(cuboid);
        };
        let sprite = if self.seated_at(t) {
            seated.as_ref().or(standing.as_ref())
        } else {
            standing.as_ref().or(seated.as_ref())
        };
        let Some(sprite) = sprite else {
            return Shape::Box(cuboid);
        };
        let (axis, sign) = self.up;
        let mut up = Vector3::zeros();
        up[axis] = sign;
        let mut base = (cuboid.min + cuboid.max) * 0.5;
        base[axis] = if sign > 0.0 {
            cuboid.min[axis]
        } else {
            cuboid.max[axis]
        };
        let height = cuboid.max[axis] - cuboid.min[axis];
        let mut board = Billboard::facing(base, up, height, camera, sprite.clone());
        if let (
            Behaviour::Walk {
                gait: Some(stride), ..
            },
            false,
        ) = (self.behaviour, self.seated_at(t))
        {
            let (walked, direction) = self.walked(t);
            let phase = std::f64::consts::TAU * walked / stride;
            board.gait.open = if direction == 0.0 {
                0.0
            } else {
                0.12 * phase.sin().abs()
            };
            board.gait.mirrored = direction * (self.end - self.start).dot(&board.right) < 0.0;
            // The body rises as the legs pass each other: a 2 cm bob.
            board.base += up * 0.02 * (1.0 - phase.sin().abs()) * direction.abs();
        }
        Shape::Billboard(board)
    }

    /// Along a walk at time `t`: the distance walked so far (m) and the direction of
    /// motion (+1 towards `end`, -1 back, 0 stopped), and the position along the path
    /// in [0, 1].
    fn walk_state(&self, t: f64) -> (f64, f64, f64) {
        let Behaviour::Walk { pause, .. } = self.behaviour else {
            return (0.0, 0.0, 0.0);
        };
        let length = (self.end - self.start).norm().max(1e-9);
        let half = length / 2.0 / self.speed;
        // One leg: walk half, stop, walk half, stop (then the next leg goes back).
        let leg = 2.0 * (half + pause);
        let period = 2.0 * leg;
        let time = ((t + self.phase) % period + period) % period;
        let (legs_done, in_leg) = ((time / leg).floor(), time % leg);
        let moving = |x: f64| x.min(half) + (x - half - pause).clamp(0.0, half);
        let along_leg = moving(in_leg) * self.speed;
        let stopped = (in_leg > half && in_leg < half + pause) || in_leg > 2.0 * half + pause;
        let full_period_walks = ((t + self.phase) / period).floor() * 2.0 * length;
        let walked = full_period_walks + legs_done * length + along_leg;
        let (along, direction) = if legs_done == 0.0 {
            (along_leg, 1.0)
        } else {
            (length - along_leg, -1.0)
        };
        (
            walked,
            if stopped { 0.0 } else { direction },
            along / length,
        )
    }

    /// The distance walked by time `t` and the direction of motion.
    fn walked(&self, t: f64) -> (f64, f64) {
        let (walked, direction, _) = self.walk_state(t);
        (walked, direction)
    }

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
        let (_, _, along) = self.walk_state(t);
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
pub fn place_people(
    config: &PeopleConfig,
    appearance: &Appearance,
    poses: &[Se3],
    scene: &mut Scene,
) -> Vec<Mover> {
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
            let distance = config
                .distances
                .get(i)
                .copied()
                .unwrap_or(config.distance + 0.8 * i as f64);
            let middle = centre + forward * distance;
            let (mut a, mut b) = (
                middle - lateral * config.span,
                middle + lateral * config.span,
            );
            if i % 2 == 1 {
                std::mem::swap(&mut a, &mut b);
            }
            // Box corners: the floor level along `up`, centred on the path otherwise.
            let corner = |p: Vector3<f64>| standing_corner(p, &size, up, sign, floor);
            Mover {
                instance: i as u16 + 1,
                class: "person".into(),
                class_id: Some(0),
                start: corner(a),
                end: corner(b),
                size,
                speed: config.speed,
                phase: 1.7 * i as f64,
                behaviour: Behaviour::Walk {
                    pause: config.pause,
                    gait: config.gait.then_some(config.stride),
                },
                up: (up, sign),
                appearance: appearance.clone(),
            }
        })
        .collect()
}

/// Adds a table of `[length, width, height]` metres to the scene's furniture, centred
/// under the mean camera position and standing on the floor, its length along the mean
/// viewing direction. Call after [`place_people`] (which sets the floor).
pub fn place_table(size: [f64; 3], poses: &[Se3], scene: &mut Scene) {
    let Some(at) = placement(poses, scene, 1) else {
        return;
    };
    let half = at.forward.abs() * size[0] * 0.5 + at.lateral.abs() * size[1] * 0.5;
    let (mut min, mut max) = (at.centre - half, at.centre + half);
    min[at.up] = at.floor.min(at.floor + at.sign * size[2]);
    max[at.up] = at.floor.max(at.floor + at.sign * size[2]);
    scene.furniture.push(Cuboid {
        min,
        max,
        texture: 2 + scene.furniture.len() as u32,
    });
}

/// Places `count` seated people `distance` in front of the mean camera position, spread
/// sideways 0.9 m apart; each leaves sideways (4 m) after `sit_seconds`. Instance ids
/// continue after `first_instance - 1`. Call after [`place_people`] (which sets the floor).
pub fn place_seated(
    config: &SeatedConfig,
    appearance: &Appearance,
    height: f64,
    poses: &[Se3],
    scene: &Scene,
    first_instance: u16,
) -> Vec<Mover> {
    let Some(p) = placement(poses, scene, config.count) else {
        return Vec::new();
    };
    let (up, sign, floor) = (p.up, p.sign, p.floor);
    let mut size = Vector3::repeat(0.5);
    size[up] = height;
    (0..config.count)
        .map(|i| {
            let offset = (i as f64 - (config.count as f64 - 1.0) / 2.0) * 0.9;
            let seat = p.centre + p.forward * config.distance + p.lateral * offset;
            let exit = seat + p.lateral * if offset >= 0.0 { 4.0 } else { -4.0 };
            let corner = |p: Vector3<f64>| standing_corner(p, &size, up, sign, floor);
            Mover {
                instance: first_instance + i as u16,
                class: "person".into(),
                class_id: Some(0),
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
                appearance: appearance.clone(),
            }
        })
        .collect()
}

/// Places `count` objects `lift` above the floor, `distance` in front of the mean camera
/// position, each pushed back and forth sideways along its own path (0.7 m farther
/// each), standing still `pause` seconds in the middle and at each end. Call after
/// [`place_people`] (which sets the floor).
pub fn place_objects(
    config: &ObjectsConfig,
    poses: &[Se3],
    scene: &Scene,
    first_instance: u16,
) -> Vec<Mover> {
    let Some(p) = placement(poses, scene, config.count) else {
        return Vec::new();
    };
    let (up, sign, floor) = (p.up, p.sign, p.floor);
    let class_id = coco::class_id(&config.class);
    // Width across the path, height along up, depth along the viewing direction.
    let mut size = Vector3::zeros();
    size[(up + 1) % 3] = config.size[0];
    size[up] = config.size[1];
    size[(up + 2) % 3] = config.size[2];
    (0..config.count)
        .map(|i| {
            let middle = p.centre + p.forward * (config.distance + 0.7 * i as f64);
            let corner = |p: Vector3<f64>| {
                let mut c = standing_corner(p, &size, up, sign, floor);
                c[up] += sign * config.lift;
                c
            };
            Mover {
                instance: first_instance + i as u16,
                class: config.class.clone(),
                class_id,
                start: corner(middle - p.lateral * config.span),
                end: corner(middle + p.lateral * config.span),
                size,
                speed: config.speed,
                phase: 0.9 * i as f64,
                behaviour: Behaviour::Walk {
                    pause: config.pause,
                    gait: None,
                },
                up: (up, sign),
                appearance: Appearance::Box,
            }
        })
        .collect()
}

/// Where movers go: the up axis and its sign, the mean camera position, the horizontal
/// viewing directions, and the floor level.
struct Placement {
    up: usize,
    sign: f64,
    centre: Vector3<f64>,
    forward: Vector3<f64>,
    lateral: Vector3<f64>,
    floor: f64,
}

/// The placement frame of `count` movers along the camera poses (`None` when there is
/// nothing to place).
fn placement(poses: &[Se3], scene: &Scene, count: usize) -> Option<Placement> {
    if poses.is_empty() || count == 0 {
        return None;
    }
    let (up, sign) = up_axis(poses);
    let (centre, forward, lateral) = viewing_frame(poses, up, sign);
    Some(Placement {
        up,
        sign,
        centre,
        forward,
        lateral,
        floor: floor_level(scene, up, sign),
    })
}

/// The floor's coordinate along the up axis (the room's face below the cameras).
fn floor_level(scene: &Scene, up: usize, sign: f64) -> f64 {
    if sign > 0.0 {
        scene.room.min[up]
    } else {
        scene.room.max[up]
    }
}

/// The minimum corner of a box of `size` centred on `p` across the floor and standing
/// on the floor.
pub(super) fn standing_corner(
    p: Vector3<f64>,
    size: &Vector3<f64>,
    up: usize,
    sign: f64,
    floor: f64,
) -> Vector3<f64> {
    let mut c = p - size * 0.5;
    c[up] = if sign > 0.0 { floor } else { floor - size[up] };
    c
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
            class: "person".into(),
            class_id: Some(0),
            start: Vector3::zeros(),
            end: Vector3::new(2.0, 0.0, 0.0),
            size: Vector3::repeat(0.4),
            speed: 1.0,
            phase: 0.0,
            behaviour: Behaviour::Walk {
                pause: 0.0,
                gait: None,
            },
            up: (1, -1.0),
            appearance: Appearance::Box,
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
            ..mover.clone()
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
        // With 0.5 s stops: half way (1 s), stopped until 1.5 s, at the end at 2.5 s,
        // stopped until 3 s, then back.
        let pausing = Mover {
            behaviour: Behaviour::Walk {
                pause: 0.5,
                gait: Some(1.4),
            },
            ..mover.clone()
        };
        for (t, x, direction) in [
            (0.5, 0.5, 1.0),
            (1.2, 1.0, 0.0),
            (2.0, 1.5, 1.0),
            (2.7, 2.0, 0.0),
            (3.5, 1.5, -1.0),
        ] {
            assert!((pausing.cuboid_at(t).min.x - x).abs() < 1e-9, "t = {t}");
            assert_eq!(pausing.walked(t).1, direction, "t = {t}");
        }
        assert!((pausing.walked(3.5).0 - 2.5).abs() < 1e-9);
    }
}
