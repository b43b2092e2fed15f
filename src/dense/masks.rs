//! Per-frame dynamic masks for fusion, from what the tracking pass learnt.
//!
//! With the DOP model (`Mode::Dop`) a frame's mask is the union of
//! 1. the dynamic objects of the detected keyframes nearest before and after it
//!    (within `track_seconds`); an object followed from the one to the other (the same
//!    [`Object::track`]) is placed once, between the two as far as the frame's time
//!    lies between theirs (`objects_at`: a walker moves on between detections, and
//!    two boxes, one where they were and one where they will be, hold as much static
//!    scene as person). Each is a box refined by depth as in the paper's
//!    Algorithm 1: the box's object depth \(z_{obj}\) is the dominant depth of its
//!    central region (from the keyframe's depth map; with `mask_foreground_share`, the
//!    default, the nearest depth mode holding that share of the whole box: the mover
//!    in front of what it hides, also when it fills little of its box; a person
//!    behind another takes its depth from what the front one's box leaves, see
//!    `box_depths`), the object is placed in the
//!    world with the keyframe's final pose (a box whose centre stands behind its
//!    foreground, a second time at the centre's depth: `centre_behind`; box edges
//!    near the image's border on it: `snap_to_border`), projected into the frame
//!    with the frame's pose, and a pixel inside the projected box belongs to it when
//!    \(z_{obj} - \delta_z \le d \le z_{obj} + \delta_{behind}\) (`mask_depth_behind`:
//!    the far leg) (objects the detector missed on a keyframe are
//!    predicted there by [`ObjectTracks`], as in the tracking pass);
//! 2. discs of `keypoint_radius` pixels around the frame's keypoints in a removed
//!    (dynamic) state, with depth within \(\delta_z / 2\) of the keypoint's;
//! 3. with `segments`, the depth segments grown from the dynamic keypoints outside
//!    every object's box ([`super::segments`]): movers no detector knows. A kept
//!    segment is followed: its centre, placed in the world, seeds the next frames'
//!    growth for `follow_seconds` after a keypoint last supported it (a box set down
//!    for a while stays out of the map);
//! 4. with the free-space evidence of the frames around ([`super::free_space`]), the
//!    pixels they saw through, which also seed segments (kept when a tenth of a
//!    segment was seen moving); discs leave out the pixels they saw in place, except
//!    inside an object's box in front of what lies behind it;
//!
//! then dilated by `border` pixels (the ring the dilation adds leaves out pixels seen
//! in place). `Mode::MaskBoxes` (`--mask-boxes`) masks whole
//! dynamic boxes of the nearest keyframe; `Mode::Off` (`--no-dop`) fuses all.

use super::detection_feed::DetectionFeed;
use super::free_space::{Evidence, PosedDepth};
pub use super::keypoint_feed::FrameKeypoints;
use super::keypoint_feed::KeypointFeed;
pub use super::mask_layers::{dilate, MaskLayer, MaskLayers};
use super::segments::{grow_segments, Seed, SegmentSettings};
use crate::detect::FrameDetections;
use crate::dop::boxes::{foreground_depth, object_depth, Keypoint, ObjectBox};
use crate::dop::tracks::{Object, ObjectTracks};
use crate::dop::{DopConfig, Mode};
use crate::dynamics::keyframes::object_boxes;
use crate::geometry::camera::{ImageSize, PinholeCamera};
use crate::geometry::se3::Se3;
use crate::io::image_files::DepthImage;
use crate::io::IoError;

/// Settings of the masks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MaskSettings {
    /// Mask dilation, pixels.
    pub border: u32,
    /// The disc radius around a dynamic keypoint, pixels.
    pub keypoint_radius: u32,
    /// The objects' depth: [`foreground_depth`] of the box's pixels with this share;
    /// 0: [`object_depth`] (the dominant depth of its centre).
    pub foreground_share: f32,
    /// How fast a track's predicted box grows, m/s (`mask_track_margin_speed`; its
    /// margin was made at `[dop] track_max_speed`).
    pub track_margin_speed: f32,
    /// How far behind its depth an object's mask reaches, metres (in front: `delta_z`).
    pub depth_behind: f32,
    /// How far behind it reaches at the pixels the frames around did not see still
    /// (with free-space evidence), metres.
    pub depth_behind_not_still: f32,
    /// No disc around a dynamic keypoint inside an object's box but behind it.
    pub skip_behind_objects: bool,
    /// A disc only around a dynamic keypoint with at least this many other dynamic
    /// keypoints within `4 * keypoint_radius` pixels (0: every one).
    pub disc_neighbours: usize,
    /// With free-space evidence, discs and segments only around the dynamic keypoints
    /// with a pixel seen moving within `keypoint_radius` of them (and only those count
    /// as a disc's neighbours).
    pub keypoints_seen_moving: bool,
    /// Grow depth segments from the dynamic keypoints outside every object's box, and
    /// follow them for this many seconds after a keypoint last supported them.
    pub segments: Option<(SegmentSettings, f64)>,
}

/// A segment kept in an earlier frame: its centre in the world, and when a dynamic
/// keypoint last supported it.
#[derive(Debug, Clone, Copy)]
struct FollowedSegment {
    centre: nalgebra::Vector3<f64>,
    since: f64,
}

/// One detected keyframe: its dynamic boxes (pixels) and objects (world).
#[derive(Debug, Clone)]
pub struct KeyframeObjects {
    /// The keyframe's time.
    pub timestamp: f64,
    /// Its boxes.
    pub boxes: Vec<ObjectBox>,
    /// The followed objects seen from it (once placed, see [`MaskSource::place_through`]).
    pub objects: Vec<Object>,
    /// Each box's class: followed, moving on its own.
    classes: Vec<BoxClass>,
}

/// What a detected box's class tells.
#[derive(Debug, Clone, Copy)]
struct BoxClass {
    /// The DOP model follows it ([`DopConfig::follows`]).
    followed: bool,
    /// It moves on its own (`never_static_classes`: people): masked whatever the
    /// free-space evidence says. The others (a car, a truck, a false alarm of one on a
    /// table) are masked where evidence is gathered only when it saw them move.
    self_moving: bool,
}

/// A frame's final `camera_from_world` by its timestamp, and its depth map.
pub type PoseAt<'a> = &'a dyn Fn(f64) -> Result<Option<Se3>, IoError>;
/// The depth of the frame at a time, if there is one.
pub type DepthAt<'a> = &'a dyn Fn(f64) -> Option<DepthImage>;

/// What the masks are made for: the masking mode, the camera, the DOP model's settings
/// and the classes that move.
#[derive(Clone, Copy)]
pub struct MaskContext<'a> {
    /// DOP, mask boxes or none.
    pub masking: Mode,
    /// The undistorted camera.
    pub camera: PinholeCamera,
    /// The DOP model's settings.
    pub dop: &'a DopConfig,
    /// The COCO classes that move.
    pub dynamic_classes: &'a [String],
}

/// Detected frames let go together ([`MaskSource::let_go_before`]).
const LET_GO_BATCH: usize = 64;

/// Everything the masks are made from.
pub struct MaskSource {
    /// DOP, mask boxes or none.
    pub masking: Mode,
    /// The mask settings.
    pub settings: MaskSettings,
    camera: PinholeCamera,
    dop: DopConfig,
    /// The detected frames read so far, in time order; those no later frame needs
    /// are let go ([`Self::let_go_before`]).
    keyframes: Vec<KeyframeObjects>,
    /// The detected frames not read yet.
    detections: DetectionFeed,
    /// The COCO classes that move.
    dynamic_classes: Vec<String>,
    /// How many of `keyframes` have their objects placed, and the tracks that
    /// followed them.
    placed: usize,
    tracks: ObjectTracks,
    /// The frames' dynamic keypoints, taken as the masked frames come.
    keypoints: KeypointFeed,
    /// The segments kept in the latest masked frame.
    followed: Vec<FollowedSegment>,
}

impl MaskSource {
    /// Builds the detected frames' objects from their `detections`: `pose_at(t)`
    /// gives a frame's final `camera_from_world`, `depth_at(t)` its depth map (frames
    /// missing either keep their pixel boxes only); `keypoints` are the frames'
    /// dynamic keypoints. [`Self::unplaced`] and [`Self::place_through`] do the same
    /// as the frames come, as the dense pass does: this, every frame placed first, is
    /// what the tests hold that to.
    #[cfg(test)]
    pub fn new(
        context: MaskContext,
        settings: MaskSettings,
        detections: impl Into<DetectionFeed>,
        keypoints: impl Into<KeypointFeed>,
        pose_at: PoseAt,
        depth_at: DepthAt,
    ) -> Result<Self, IoError> {
        let mut source = Self::unplaced(context, settings, detections, keypoints);
        source.place_through(f64::INFINITY, pose_at, depth_at)?;
        Ok(source)
    }

    /// The masks of the detected frames of `detections`, read and placed by
    /// [`Self::place_through`] before a frame near them is masked.
    pub fn unplaced(
        context: MaskContext,
        settings: MaskSettings,
        detections: impl Into<DetectionFeed>,
        keypoints: impl Into<KeypointFeed>,
    ) -> Self {
        let MaskContext {
            masking,
            camera,
            dop,
            dynamic_classes,
        } = context;
        Self {
            masking,
            settings,
            camera,
            dop: dop.clone(),
            keyframes: Vec::new(),
            detections: detections.into(),
            dynamic_classes: dynamic_classes.to_vec(),
            placed: 0,
            tracks: ObjectTracks::default(),
            keypoints: keypoints.into(),
            followed: Vec::new(),
        }
    }

    /// A detected frame's boxes of moving classes, as the masks use them.
    fn boxes_of(&self, frame: FrameDetections) -> KeyframeObjects {
        let (boxes, classes): (Vec<ObjectBox>, Vec<BoxClass>) =
            object_boxes(&frame.detections, &self.dynamic_classes)
                .into_iter()
                .zip(&frame.detections)
                .filter(|(b, _)| b.dynamic)
                .map(|(b, d)| {
                    let class = BoxClass {
                        followed: self.dop.follows(&d.class),
                        self_moving: self.dop.moves_on_its_own(&d.class),
                    };
                    (snap_to_border(b, &self.camera), class)
                })
                .unzip();
        KeyframeObjects {
            timestamp: frame.timestamp,
            boxes,
            objects: Vec::new(),
            classes,
        }
    }

    /// Reads the detected frames up to and including the first one at or after
    /// `ahead`.
    fn read_through(&mut self, ahead: f64) -> Result<(), IoError> {
        while self.keyframes.last().is_none_or(|k| k.timestamp < ahead) {
            let Some(frame) = self.detections.take_next()? else {
                break;
            };
            let objects = self.boxes_of(frame);
            self.keyframes.push(objects);
        }
        Ok(())
    }

    /// Places the objects of the detected frames up to and including the first one at
    /// or after `timestamp` plus `track_seconds` (in time order, followed from one to
    /// the next), with their poses and depth maps; a frame without a box needs no depth
    /// map. Looking that far ahead, a person the detector missed on some frames and
    /// found again is known on both sides of the gap before a frame in it is masked
    /// ([`fill_gaps`]).
    pub fn place_through(
        &mut self,
        timestamp: f64,
        pose_at: PoseAt,
        depth_at: DepthAt,
    ) -> Result<(), IoError> {
        let track_seconds = self.dop.track_seconds as f64;
        let ahead = timestamp + track_seconds;
        self.read_through(ahead)?;
        let through = self.keyframes.partition_point(|k| k.timestamp < ahead) + 1;
        while self.placed < through.min(self.keyframes.len()) {
            let index = self.placed;
            self.placed += 1;
            let frame = &mut self.keyframes[index];
            if self.masking != Mode::Dop {
                continue;
            }
            let Some(pose) = pose_at(frame.timestamp)? else {
                continue;
            };
            let placed = if frame.boxes.is_empty() {
                Vec::new()
            } else {
                let Some(depth) = depth_at(frame.timestamp) else {
                    continue;
                };
                place_objects(
                    &frame.boxes,
                    &frame.classes,
                    &depth_samples(&depth, 4),
                    &self.settings,
                    &self.dop,
                    &self.camera,
                    &pose.inverse(),
                )
            };
            frame.objects = follow_objects(&mut self.tracks, frame.timestamp, placed, &self.dop);
            let speed = self.dop.track_max_speed as f64;
            fill_gaps(&mut self.keyframes[..=index], track_seconds, speed);
        }
        Ok(())
    }

    /// The mask of the frame at `timestamp` (`true`: dynamic), or `None` when
    /// nothing in it is dynamic: [`Self::layers`] without the sources.
    pub fn mask(
        &mut self,
        timestamp: f64,
        depth: &DepthImage,
        camera_from_world: &Se3,
        evidence: Option<&Evidence>,
    ) -> Option<Vec<bool>> {
        self.layers(timestamp, depth, camera_from_world, evidence)
            .map(|layers| layers.dynamic)
    }

    /// The mask of the frame at `timestamp` with the source of each masked pixel, or
    /// `None` when nothing in it is dynamic. Frames come in time order (segments are
    /// followed from one to the next).
    ///
    /// With `evidence` ([`super::free_space`], DOP only), pixels seen through by the
    /// neighbour frames are masked too, and the discs and the dilation leave out the
    /// pixels seen still.
    pub fn layers(
        &mut self,
        timestamp: f64,
        depth: &DepthImage,
        camera_from_world: &Se3,
        evidence: Option<&Evidence>,
    ) -> Option<MaskLayers> {
        if self.masking == Mode::Off {
            return None;
        }
        self.keypoints.advance_to(timestamp);
        self.let_go_before(timestamp);
        let size = ImageSize::from((depth.width, depth.height));
        let mut sources = vec![0u8; depth.metres.len()];
        let evidence = evidence.filter(|_| self.masking == Mode::Dop);
        let near = self.near_keyframes(timestamp);
        let any = match self.masking {
            Mode::Off => false,
            Mode::MaskBoxes => {
                let nearest = near.iter().min_by(|a, b| {
                    (a.timestamp - timestamp)
                        .abs()
                        .total_cmp(&(b.timestamp - timestamp).abs())
                });
                let mut any = false;
                for b in nearest.iter().flat_map(|k| &k.boxes) {
                    any |= fill_box(&mut sources, MaskLayer::Objects, size, b.bbox, |_, _| true);
                }
                any
            }
            Mode::Dop => {
                let frame = PosedDepth {
                    timestamp,
                    depth,
                    camera_from_world,
                };
                self.dop_layers(&mut sources, frame, &near, evidence)
            }
        };
        any.then(|| MaskLayers::dilated(sources, size, self.settings.border, evidence))
    }

    /// Lets the detected frames go that no frame masked from `timestamp` on needs:
    /// placed, over a second older than `track_seconds` before it (the masks take the
    /// detected frames within that: [`Self::near_keyframes`]) and than twice that
    /// before the newest placed frame (the gaps a detection fills reach that far back:
    /// [`fill_gaps`]). So the detected frames held span a few seconds, not the run.
    fn let_go_before(&mut self, timestamp: f64) {
        let Some(newest) = self
            .placed
            .checked_sub(1)
            .map(|i| self.keyframes[i].timestamp)
        else {
            return;
        };
        let track_seconds = self.dop.track_seconds as f64;
        let before = (timestamp - track_seconds).min(newest - 2.0 * track_seconds) - 1.0;
        let old = self.keyframes[..self.placed].partition_point(|k| k.timestamp < before);
        // In batches, so that the frames left move once per batch.
        if old >= LET_GO_BATCH || (old > 0 && 2 * old >= self.keyframes.len()) {
            self.keyframes.drain(..old);
            self.placed -= old;
        }
    }

    /// The detected keyframes nearest before and after `timestamp`, within
    /// `track_seconds`.
    fn near_keyframes(&self, timestamp: f64) -> Vec<KeyframeObjects> {
        let after = self.keyframes.partition_point(|k| k.timestamp < timestamp);
        debug_assert!(
            self.masking != Mode::Dop
                || self.keyframes.is_empty()
                || self.placed > after.min(self.keyframes.len() - 1),
            "the objects near {timestamp} s are placed (place_through) before it is masked"
        );
        [after.checked_sub(1), Some(after)]
            .into_iter()
            .flatten()
            .filter_map(|i| self.keyframes.get(i))
            .filter(|k| (k.timestamp - timestamp).abs() <= self.dop.track_seconds as f64)
            .cloned()
            .collect()
    }

    /// The DOP mask's sources in `sources`: the near keyframes' objects, the discs
    /// around dynamic keypoints, the pixels seen moving and the segments; whether any
    /// pixel was masked.
    fn dop_layers(
        &mut self,
        sources: &mut [u8],
        frame: PosedDepth,
        near: &[KeyframeObjects],
        evidence: Option<&Evidence>,
    ) -> bool {
        let PosedDepth {
            timestamp,
            depth,
            camera_from_world,
        } = frame;
        let (w, h) = (depth.width as usize, depth.height as usize);
        let speed = self.dop.track_max_speed as f64;
        let objects: Vec<ObjectBox> = objects_at(near, timestamp, speed)
            .iter()
            .filter_map(|object| {
                let object = &self.with_mask_margin(object);
                let b = object.to_box(&self.camera, camera_from_world)?;
                let moves =
                    object.self_moving || evidence.is_none_or(|e| self.seen_moving(e, depth, &b));
                moves.then_some(b)
            })
            .collect();
        let mut any = self.object_masks(sources, depth, &objects, evidence);
        let keypoints = self.shown_keypoints(timestamp, evidence, (w, h));
        let keypoints = keypoints.as_ref();
        let keep = disc_keep(depth, &objects, evidence, self.dop.delta_z);
        any |= self.keypoint_discs(sources, depth, keypoints, &objects, &keep);
        if let Some(e) = evidence {
            for (m, &moving) in sources.iter_mut().zip(&e.moving) {
                *m |= MaskLayer::FreeSpace.bit() * moving as u8;
                any |= moving;
            }
        }
        if self.settings.segments.is_some() {
            let seeds = seeds_of(keypoints, &objects, evidence, (w, h), timestamp);
            let moving = evidence.map(|e| e.moving.as_slice());
            any |= self.segment_masks(sources, frame, seeds, moving, &objects);
        }
        any
    }

    /// `object` with the margin of a prediction grown at `mask_track_margin_speed`
    /// instead of `track_max_speed`.
    fn with_mask_margin(&self, object: &Object) -> Object {
        let made_at = self.dop.track_max_speed.max(f32::MIN_POSITIVE);
        let share = f64::from(self.settings.track_margin_speed / made_at);
        Object {
            margin: object.margin * share,
            ..*object
        }
    }

    /// Whether the evidence saw [`OBJECT_MOVING_SHARE`] of box `b`'s body move.
    fn seen_moving(&self, evidence: &Evidence, depth: &DepthImage, b: &ObjectBox) -> bool {
        let (front, behind) = (self.dop.delta_z, self.settings.depth_behind);
        let z = b.depth.unwrap_or(0.0);
        let w = depth.width as usize;
        let (columns, rows) = box_pixels(b.bbox, ImageSize::from((depth.width, depth.height)));
        let (mut pixels, mut moving) = (0usize, 0usize);
        for v in rows {
            for i in v * w + columns.start..v * w + columns.end {
                let d = depth.metres[i];
                if d > 0.0 && d >= z - front && d <= z + behind {
                    pixels += 1;
                    moving += evidence.moving[i] as usize;
                }
            }
        }
        moving > 0 && moving as f32 >= OBJECT_MOVING_SHARE * pixels as f32
    }

    /// The depth segments grown from the frame's keypoint `seeds` and from the segments
    /// followed from earlier frames; remembers the kept ones for the next frame, except
    /// those mostly inside a detected mover's box (the detector follows those).
    fn segment_masks(
        &mut self,
        sources: &mut [u8],
        frame: PosedDepth,
        mut seeds: Vec<Seed>,
        moving: Option<&[bool]>,
        objects: &[ObjectBox],
    ) -> bool {
        let PosedDepth {
            timestamp,
            depth,
            camera_from_world,
        } = frame;
        let Some((settings, follow_seconds)) = self.settings.segments else {
            return false;
        };
        let camera = &self.camera;
        seeds.extend(
            self.followed
                .iter()
                .filter(|f| timestamp - f.since <= follow_seconds)
                .filter_map(|f| {
                    let p = camera_from_world * nalgebra::Point3::from(f.centre);
                    let pixel = (p.z > 0.0).then(|| camera.project(&p.coords))?;
                    Some(Seed {
                        x: pixel.x as f32,
                        y: pixel.y as f32,
                        followed: true,
                        since: f.since,
                    })
                }),
        );
        let segments = grow_segments(depth, &seeds, moving, &settings, camera.fx as f32);
        let world_from_camera = camera_from_world.inverse();
        let w = depth.width as usize;
        let in_boxes = |i: &usize| {
            let (x, y) = ((i % w) as f32, (i / w) as f32);
            objects.iter().any(|b| b.contains(x, y))
        };
        self.followed = segments
            .iter()
            .filter(|segment| {
                2 * segment.pixels.iter().filter(|i| in_boxes(i)).count() < segment.pixels.len()
            })
            .map(|segment| {
                let sum: nalgebra::Vector3<f64> = segment
                    .pixels
                    .iter()
                    .map(|&i| {
                        let pixel = nalgebra::Vector2::new((i % w) as f64, (i / w) as f64);
                        camera.unproject(&pixel, depth.metres[i] as f64)
                    })
                    .sum();
                let centre = sum / segment.pixels.len().max(1) as f64;
                FollowedSegment {
                    centre: (world_from_camera * nalgebra::Point3::from(centre)).coords,
                    since: segment.since,
                }
            })
            .collect();
        for segment in &segments {
            for &i in &segment.pixels {
                sources[i] |= MaskLayer::Segments.bit();
            }
        }
        !segments.is_empty()
    }

    /// Each object's box, cut at its depth: the pixels from `delta_z` in front of it to
    /// `mask_depth_behind` behind it, and those without depth; within `delta_z` of it
    /// (and without depth) as [`MaskLayer::Objects`], farther behind as
    /// [`MaskLayer::ObjectBand`], which with `evidence` also takes the pixels up to
    /// `mask_depth_behind_not_still` behind it that the frames around did not see
    /// still (a person partly hidden behind the one the box is cut at).
    fn object_masks(
        &self,
        sources: &mut [u8],
        depth: &DepthImage,
        objects: &[ObjectBox],
        evidence: Option<&Evidence>,
    ) -> bool {
        let size = ImageSize::from((depth.width, depth.height));
        let w = size.width as usize;
        let mut any = false;
        let (front, behind) = (self.dop.delta_z, self.settings.depth_behind);
        // The body reaches `delta_z` behind the depth too, or less when the band does.
        let body = front.min(behind);
        let not_still = |u: usize, v: usize| evidence.is_some_and(|e| !e.still[v * w + u]);
        let farther = self.settings.depth_behind_not_still;
        for b in objects {
            let z = b.depth.unwrap_or(0.0);
            any |= fill_box(sources, MaskLayer::Objects, size, b.bbox, |u, v| {
                let d = depth.at(u as u32, v as u32);
                d == 0.0 || (d >= z - front && d <= z + body)
            });
            any |= fill_box(sources, MaskLayer::ObjectBand, size, b.bbox, |u, v| {
                let d = depth.at(u as u32, v as u32);
                d > z + body && (d <= z + behind || (d <= z + farther && not_still(u, v)))
            });
        }
        any
    }

    /// Discs around the frame's dynamic keypoints (depth within `delta_z / 2` of the
    /// keypoint's), except keypoints inside a detected mover's box but more than
    /// `delta_z` behind it: the background the mover stands in front of, which the
    /// object's mask already judged (with `skip_behind_objects`); only the pixels
    /// `keep(u, v)` allows.
    fn keypoint_discs(
        &self,
        sources: &mut [u8],
        depth: &DepthImage,
        keypoints: &[[f32; 3]],
        objects: &[ObjectBox],
        keep: &dyn Fn(usize, usize) -> bool,
    ) -> bool {
        let size = ImageSize::from((depth.width, depth.height));
        let behind = |x: f32, y: f32, z: f32| {
            self.settings.skip_behind_objects
                && z > 0.0
                && objects.iter().any(|b| {
                    b.contains(x, y) && b.depth.is_some_and(|bz| z - bz > self.dop.delta_z)
                })
        };
        let r = self.settings.keypoint_radius as f32;
        let reach = 4.0 * r;
        let supported = |p: &[f32; 3]| {
            let n = self.settings.disc_neighbours;
            n == 0
                || keypoints
                    .iter()
                    .filter(|q| (q[0] - p[0]).abs() <= reach && (q[1] - p[1]).abs() <= reach)
                    .nth(n)
                    .is_some()
        };
        let mut any = false;
        for &[x, y, z] in keypoints
            .iter()
            .filter(|p| !behind(p[0], p[1], p[2]) && supported(p))
        {
            let bbox = [x - r, y - r, x + r + 1.0, y + r + 1.0];
            any |= fill_box(sources, MaskLayer::Discs, size, bbox, |u, v| {
                let (du, dv) = (u as f32 - x, v as f32 - y);
                let d = depth.at(u as u32, v as u32);
                du * du + dv * dv <= r * r
                    && (z <= 0.0 || d == 0.0 || (d - z).abs() <= self.dop.delta_z / 2.0)
                    && keep(u, v)
            });
        }
        any
    }

    /// The dynamic keypoints of the frame at `timestamp` that draw discs and seed
    /// segments: with `keypoints_seen_moving` and `evidence`, those with a pixel seen
    /// moving within `keypoint_radius`; otherwise all.
    fn shown_keypoints(
        &self,
        timestamp: f64,
        evidence: Option<&Evidence>,
        size: (usize, usize),
    ) -> std::borrow::Cow<'_, [[f32; 3]]> {
        let keypoints = self.frame_keypoints(timestamp);
        let radius = self.settings.keypoint_radius as f32;
        match evidence.filter(|_| self.settings.keypoints_seen_moving) {
            Some(e) => keypoints
                .iter()
                .filter(|p| moving_within(e, size, p, radius))
                .copied()
                .collect(),
            None => keypoints.into(),
        }
    }

    /// The dynamic keypoints of the frame at `timestamp` (none if it has no entry),
    /// once [`Self::layers`] moved the feed on to it.
    fn frame_keypoints(&self, timestamp: f64) -> &[[f32; 3]] {
        self.keypoints.at(timestamp)
    }
}

/// The objects at time `t` of the detected frames `near` it (the one before, the one
/// at or after; [`MaskSource::near_keyframes`]): an object of a track seen in both is
/// placed between its two places ([`between`], margins growing at `speed`); the
/// others as their frame saw them.
fn objects_at(near: &[KeyframeObjects], t: f64, speed: f64) -> Vec<Object> {
    let [before, after] = near else {
        return near
            .iter()
            .flat_map(|k| k.objects.iter().copied())
            .collect();
    };
    let when = Between {
        t0: before.timestamp,
        t1: after.timestamp,
        t,
        speed,
    };
    let partner = |o: &Object| {
        o.track
            .and_then(|id| after.objects.iter().find(|a| a.track == Some(id)))
    };
    let mut objects: Vec<Object> = before
        .objects
        .iter()
        .map(|o| partner(o).map_or(*o, |a| between(o, a, &when)))
        .collect();
    let paired = |a: &&Object| {
        a.track
            .is_some_and(|id| before.objects.iter().any(|o| o.track == Some(id)))
    };
    objects.extend(after.objects.iter().filter(|a| !paired(a)).copied());
    objects
}

/// The share of an object's body pixels (its box's pixels from `delta_z` in front of
/// its depth to `mask_depth_behind` behind it) that the free-space evidence must see
/// moving for an object of a class that does not move on its own to be masked: 2 %. A
/// parked car, or a table taken for a truck, is seen still, as the static scene it is.
const OBJECT_MOVING_SHARE: f32 = 0.02;

/// With `frames` placed through the last: each track detected on the last frame, and
/// before that on an earlier frame within `2 * track_seconds`, is placed on the frames
/// between as [`between`] the two detections (margins growing at `speed`). Those
/// frames held the tracks' predictions from the first detection alone, whose margins
/// grow with the time since it (at `track_max_speed`, a metre in two thirds of a
/// second: most of the image for a person near the camera).
fn fill_gaps(frames: &mut [KeyframeObjects], track_seconds: f64, speed: f64) {
    let Some((last, earlier)) = frames.split_last_mut() else {
        return;
    };
    for to in last.objects.iter().filter(|o| !o.predicted()) {
        let Some(id) = to.track else {
            continue;
        };
        let detected = |o: &&Object| o.track == Some(id) && !o.predicted();
        let Some((i, from)) = earlier
            .iter()
            .enumerate()
            .rev()
            .take_while(|(_, k)| last.timestamp - k.timestamp <= 2.0 * track_seconds)
            .find_map(|(i, k)| Some((i, *k.objects.iter().find(detected)?)))
        else {
            continue;
        };
        let (t0, t1) = (earlier[i].timestamp, last.timestamp);
        for k in &mut earlier[i + 1..] {
            let when = Between {
                t0,
                t1,
                t: k.timestamp,
                speed,
            };
            for o in k.objects.iter_mut().filter(|o| o.track == Some(id)) {
                *o = between(&from, to, &when);
            }
        }
    }
}

/// A time `t` between two of a track's frames, at `t0` and `t1`, and how fast a
/// margin grows away from them (m/s).
struct Between {
    t0: f64,
    t1: f64,
    t: f64,
    speed: f64,
}

/// A track's object at `when.t`, seen as `a` at `t0` and `b` at `t1`: as far from `a`
/// to `b` as the time (a walk straight at an even pace; size and margin mixed alike),
/// its margin grown by `speed` times the time to the nearer of the two (a walker
/// turns: over a gap of a second and a half, a straight line from the one place to
/// the other misses them).
fn between(a: &Object, b: &Object, when: &Between) -> Object {
    let span = when.t1 - when.t0;
    let s = if span > 0.0 {
        ((when.t - when.t0) / span).clamp(0.0, 1.0)
    } else {
        1.0
    };
    let nearer = (when.t - when.t0).min(when.t1 - when.t).max(0.0);
    let mix = |x: f64, y: f64| x + (y - x) * s;
    Object {
        centre: a.centre + (b.centre - a.centre) * s,
        size: (mix(a.size.0, b.size.0), mix(a.size.1, b.size.1)),
        margin: mix(a.margin, b.margin) + when.speed * nearer,
        moved: a.moved || b.moved,
        self_moving: a.self_moving || b.self_moving,
        track: b.track,
    }
}

/// Whether a pixel within `radius` of keypoint `p` was seen moving.
fn moving_within(evidence: &Evidence, size: (usize, usize), p: &[f32; 3], radius: f32) -> bool {
    let (w, h) = size;
    let (x, y) = (p[0].round() as i64, p[1].round() as i64);
    let r = radius.ceil() as i64;
    let r2 = radius * radius;
    (-r..=r).any(|dv| {
        let v = y + dv;
        v >= 0
            && (v as usize) < h
            && (-r..=r).any(|du| {
                let u = x + du;
                u >= 0
                    && (u as usize) < w
                    && (du * du + dv * dv) as f32 <= r2
                    && evidence.moving[v as usize * w + u as usize]
            })
    })
}

/// Which disc pixels `(u, v)` to mask: all without `evidence`; with it, none that the
/// neighbours saw still, except inside an object's box and more than `delta_z` in
/// front of what lies behind it there (a second mover, hidden in part and paused, may
/// have no other mask than its discs).
fn disc_keep<'a>(
    depth: &'a DepthImage,
    objects: &'a [ObjectBox],
    evidence: Option<&'a Evidence>,
    delta_z: f32,
) -> impl Fn(usize, usize) -> bool + 'a {
    let backs: Vec<f32> = match evidence {
        Some(_) => objects.iter().map(|b| box_background(depth, b)).collect(),
        None => Vec::new(),
    };
    let w = depth.width as usize;
    move |u, v| {
        let Some(e) = evidence else { return true };
        let i = v * w + u;
        let (x, y, d) = (u as f32, v as f32, depth.metres[i]);
        let in_front =
            |(b, back): (&ObjectBox, &f32)| b.contains(x, y) && d > 0.0 && d < back - delta_z;
        !e.still[i] || objects.iter().zip(&backs).any(in_front)
    }
}

/// A box edge this share of the image's height or less from the image's border is
/// taken to the border (16 px of 480).
const BORDER_SNAP: f32 = 1.0 / 30.0;

/// `b` with its edges near the image's border ([`BORDER_SNAP`]) on it: a detector
/// draws the box of an object cut by the border a few pixels short of it, and those
/// rows of the object would be fused.
fn snap_to_border(mut b: ObjectBox, camera: &PinholeCamera) -> ObjectBox {
    let (w, h) = (camera.width as f32, camera.height as f32);
    let snap = BORDER_SNAP * h;
    let [x1, y1, x2, y2] = &mut b.bbox;
    for (low, high, size) in [(x1, x2, w), (y1, y2, h)] {
        if *low <= snap {
            *low = 0.0;
        }
        if *high >= size - snap {
            *high = size;
        }
    }
    b
}

/// What lies behind a box's object: the 90th percentile of the depths in the box
/// (every 4th pixel each way; 0 without any).
fn box_background(depth: &DepthImage, b: &ObjectBox) -> f32 {
    let (w, h) = (depth.width as usize, depth.height as usize);
    let clip = |value: f32, limit: usize| (value.max(0.0) as usize).min(limit);
    let [x1, y1, x2, y2] = b.bbox;
    let mut depths: Vec<f32> = (clip(y1, h)..clip(y2, h))
        .step_by(4)
        .flat_map(|v| {
            (clip(x1, w)..clip(x2, w))
                .step_by(4)
                .map(move |u| v * w + u)
        })
        .map(|i| depth.metres[i])
        .filter(|&d| d > 0.0)
        .collect();
    far_depth(&mut depths)
}

/// Grid step (pixels) of the seeds taken from the free-space evidence.
const MOVING_SEED_STEP: usize = 8;

/// The pixels seen moving on a grid of [`MOVING_SEED_STEP`]: seeds of depth segments,
/// so that a mover whose free space shows only at its trailing edge (a flat face
/// sliding sideways stays at the same depth) is masked over its whole segment.
fn moving_seeds(evidence: &Evidence, w: usize, h: usize) -> Vec<(f32, f32)> {
    (0..h)
        .step_by(MOVING_SEED_STEP)
        .flat_map(|v| (0..w).step_by(MOVING_SEED_STEP).map(move |u| (u, v)))
        .filter(|&(u, v)| evidence.moving[v * w + u])
        .map(|(u, v)| (u as f32, v as f32))
        .collect()
}

/// The segments' seeds at `timestamp`: the frame's dynamic keypoints outside the
/// boxes, and the pixels seen moving (inside a box too: a second mover partly hidden
/// behind a detected one).
fn seeds_of(
    keypoints: &[[f32; 3]],
    objects: &[ObjectBox],
    evidence: Option<&Evidence>,
    size: (usize, usize),
    timestamp: f64,
) -> Vec<Seed> {
    let outside = keypoints
        .iter()
        .filter(|p| !objects.iter().any(|b| b.contains(p[0], p[1])))
        .map(|p| (p[0], p[1]));
    outside
        .chain(evidence.map_or(Vec::new(), |e| moving_seeds(e, size.0, size.1)))
        .map(|(x, y)| Seed {
            x,
            y,
            followed: false,
            since: timestamp,
        })
        .collect()
}

/// The dynamic `boxes` of a detected frame placed in the world at their object depth
/// ([`box_depths`] with `mask_foreground_share`, else the model's), each with whether
/// its class is followed (and [`Object::self_moving`] set from `classes`); boxes
/// without depth are left out. A box whose centre lies behind its foreground
/// ([`centre_behind`]) is placed a second time, at its centre's depth (not followed:
/// only the frames around this one see it).
fn place_objects(
    boxes: &[ObjectBox],
    classes: &[BoxClass],
    samples: &[Keypoint],
    settings: &MaskSettings,
    dop: &DopConfig,
    camera: &PinholeCamera,
    world_from_camera: &Se3,
) -> Vec<(Object, bool)> {
    let depths: Vec<Option<f32>> = if settings.foreground_share > 0.0 {
        box_depths(boxes, samples, dop, settings.foreground_share)
    } else {
        boxes
            .iter()
            .map(|b| object_depth(dop, samples, b))
            .collect()
    };
    boxes
        .iter()
        .zip(classes)
        .zip(depths)
        .flat_map(|((b, class), z)| {
            let behind = z.and_then(|z| centre_behind(b, z, samples, dop, camera));
            let place = |z: f32| Object {
                self_moving: class.self_moving,
                ..Object::from_box(b.bbox, z, camera, world_from_camera)
            };
            [
                z.map(|z| (place(z), class.followed)),
                behind.map(|c| (place(c), false)),
            ]
        })
        .flatten()
        .collect()
}

/// The largest share of the image a box placed at its centre's depth too
/// ([`centre_behind`]) may cover: a box around most of the image (a person close to the
/// camera, a false alarm) is centred on whatever lies behind.
const CENTRE_MAX_AREA: f32 = 0.25;

/// The depth \(z_c\) of a box's centre ([`object_depth`]) where it lies behind the
/// box's object depth \(z\), holds more of the box than \(z\) does (samples within
/// \(\delta_z\) of each), and lies in front of what the box leaves behind:
/// \(z + \delta_z / 2 < z_c \le z_{90} - \delta_z / 2\), \(z_{90}\) the 90th percentile
/// of the samples in the box. Then the foreground is something small in front of the
/// mover (a box on the floor, a desk's edge, the floor a loose box reaches down to) and
/// the mover is what the box is centred on and mostly made of; its mask must reach
/// both depths. A box of legs centred on the wall between them fails the last test
/// (the wall is what lies behind); a close person in front of a desk fails the second.
fn centre_behind(
    b: &ObjectBox,
    z: f32,
    samples: &[Keypoint],
    dop: &DopConfig,
    camera: &PinholeCamera,
) -> Option<f32> {
    let [x1, y1, x2, y2] = b.bbox;
    if (x2 - x1) * (y2 - y1) > CENTRE_MAX_AREA * (camera.width * camera.height) as f32 {
        return None;
    }
    let half = dop.delta_z / 2.0;
    let centre = object_depth(dop, samples, b).filter(|&c| c > z + half)?;
    let mut inside: Vec<f32> = samples
        .iter()
        .filter(|k| b.contains(k.x, k.y))
        .map(|k| k.depth)
        .collect();
    let held = |at: f32| held_near(inside.iter().copied(), at, dop.delta_z);
    if held(centre) <= held(z) {
        return None;
    }
    (centre <= far_depth(&mut inside) - half).then_some(centre)
}

/// How many of `depths` lie within `tolerance` of `z`.
fn held_near(depths: impl Iterator<Item = f32>, z: f32, tolerance: f32) -> usize {
    depths.filter(|d| (d - z).abs() <= tolerance).count()
}

/// A box lying at least this share of its area inside another box is taken for a part
/// of that box's object (a tile's box of part of a person), and one holding that share
/// of another for a box around it (a group, a false alarm on the whole image): neither
/// hides the other.
const NESTED: f32 = 0.8;

/// A box whose foreground holds more than this share of it is that object's own box:
/// a person behind another is hidden in part, so most of its box is not the front one.
const FRONT_SHARE: f32 = 0.3;

/// The object depth of each box: the [`foreground_depth`] (bins \(\delta_z / 2\) wide,
/// the nearest holding `share`) of the depth `samples` in it, except where a person
/// stands behind another and the one in front is its box's foreground too.
///
/// So the boxes take their depths in order of how much of their samples their
/// foreground holds (within \(\delta_z\) of it): the box the front person fills first.
/// A later box whose foreground holds at most [`FRONT_SHARE`] of it takes its
/// foreground from the samples the earlier boxes it overlaps leave (those not inside
/// one of them within \(\delta_z\) of its depth; boxes [`nested`] in it or it in them
/// take none), if that depth \(z'\)
/// - agrees within \(\delta_z\) with the dominant depth of the box's own centre
///   ([`object_depth`]): the person behind is what the box is centred on;
/// - lies in front of what the box leaves behind: \(z' \le z_{90} - \delta_z / 2\),
///   \(z_{90}\) the 90th percentile of the samples left. A box of a close person's
///   legs, centred on the wall between them, would otherwise take the wall's depth
///   and mask the wall (cutout_xyz: 2.3 % of the static pixels).
///
/// Otherwise it keeps its foreground.
fn box_depths(
    boxes: &[ObjectBox],
    samples: &[Keypoint],
    dop: &DopConfig,
    share: f32,
) -> Vec<Option<f32>> {
    let delta_z = dop.delta_z;
    let inside: Vec<Vec<&Keypoint>> = boxes
        .iter()
        .map(|b| samples.iter().filter(|k| b.contains(k.x, k.y)).collect())
        .collect();
    let depths_of = |points: &[&Keypoint]| points.iter().map(|k| k.depth).collect::<Vec<f32>>();
    let first: Vec<Option<f32>> = inside
        .iter()
        .map(|points| foreground_depth(&depths_of(points), delta_z / 2.0, share))
        .collect();
    let held: Vec<f32> = (0..boxes.len())
        .map(|i| {
            let near = |z: f32| held_near(inside[i].iter().map(|k| k.depth), z, delta_z);
            first[i].map_or(0, near) as f32 / inside[i].len().max(1) as f32
        })
        .collect();
    let mut order: Vec<usize> = (0..boxes.len()).collect();
    order.sort_by(|&a, &b| held[b].total_cmp(&held[a]).then(a.cmp(&b)));
    let mut depths = first;
    for (n, &i) in order.iter().enumerate() {
        let earlier: Vec<(&ObjectBox, f32)> = order[..n]
            .iter()
            .filter_map(|&j| Some((&boxes[j], depths[j]?)))
            .filter(|(b, _)| overlap_share(&boxes[i].bbox, &b.bbox) > 0.0)
            .filter(|(b, _)| !nested(&boxes[i].bbox, &b.bbox))
            .collect();
        if held[i] > FRONT_SHARE || earlier.is_empty() {
            continue;
        }
        let left: Vec<&Keypoint> = inside[i]
            .iter()
            .copied()
            .filter(|k| {
                !earlier
                    .iter()
                    .any(|(b, z)| b.contains(k.x, k.y) && (k.depth - z).abs() <= delta_z)
            })
            .collect();
        let centre = object_depth(dop, samples, &boxes[i]);
        let mut left = depths_of(&left);
        let back = far_depth(&mut left);
        if let Some(z) = foreground_depth(&left, delta_z / 2.0, share)
            .filter(|z| centre.is_some_and(|c| (c - z).abs() <= delta_z))
            .filter(|z| *z <= back - delta_z / 2.0)
        {
            depths[i] = Some(z);
        }
    }
    depths
}

/// The 90th percentile of `depths` (reordered; 0 when empty): what lies behind.
fn far_depth(depths: &mut [f32]) -> f32 {
    if depths.is_empty() {
        return 0.0;
    }
    let k = (depths.len() - 1) * 9 / 10;
    *depths.select_nth_unstable_by(k, f32::total_cmp).1
}

/// Whether one of two boxes lies [`NESTED`] inside the other.
fn nested(a: &[f32; 4], b: &[f32; 4]) -> bool {
    overlap_share(a, b) >= NESTED || overlap_share(b, a) >= NESTED
}

/// The share of box `a`'s area that lies inside box `b`.
fn overlap_share(a: &[f32; 4], b: &[f32; 4]) -> f32 {
    use crate::detect::yolo::{area, intersection};
    area(&intersection(a, b)) / area(a).max(f32::MIN_POSITIVE)
}

/// A detected frame's objects at `t`: those of the followed classes go through
/// `tracks` (which add the followed objects the detector missed), the others stay as
/// detected.
fn follow_objects(
    tracks: &mut ObjectTracks,
    t: f64,
    placed: Vec<(Object, bool)>,
    dop: &DopConfig,
) -> Vec<Object> {
    let (tracked, others): (Vec<_>, Vec<_>) = placed.into_iter().partition(|(_, f)| *f);
    let mut objects: Vec<Object> = tracked.into_iter().map(|(o, _)| o).collect();
    let missed = tracks.update(t, &mut objects, dop);
    objects.extend(others.into_iter().map(|(o, _)| o));
    objects.extend(missed);
    objects
}

/// Every `step`-th pixel with depth, as keypoints for [`object_depth`].
fn depth_samples(depth: &DepthImage, step: usize) -> Vec<Keypoint> {
    let (w, h) = (depth.width as usize, depth.height as usize);
    let mut samples = Vec::with_capacity(w * h / (step * step));
    for v in (0..h).step_by(step) {
        for u in (0..w).step_by(step) {
            let z = depth.metres[v * w + u];
            if z > 0.0 {
                samples.push(Keypoint {
                    x: u as f32,
                    y: v as f32,
                    depth: z,
                });
            }
        }
    }
    samples
}

/// Marks the pixels of `bbox` (clipped) for which `keep(u, v)` as masked by `layer`
/// in `sources` (an image of `size`); whether any was.
fn fill_box(
    sources: &mut [u8],
    layer: MaskLayer,
    size: ImageSize,
    bbox: [f32; 4],
    keep: impl Fn(usize, usize) -> bool,
) -> bool {
    let w = size.width as usize;
    let (columns, rows) = box_pixels(bbox, size);
    let mut any = false;
    for v in rows {
        for u in columns.clone() {
            if keep(u, v) {
                sources[v * w + u] |= layer.bit();
                any = true;
            }
        }
    }
    any
}

/// The columns and rows of the pixels that `bbox` touches (outward to whole pixels),
/// clipped to an image of `size`.
fn box_pixels(bbox: [f32; 4], size: ImageSize) -> (std::ops::Range<usize>, std::ops::Range<usize>) {
    let (w, h) = (size.width as usize, size.height as usize);
    let clip = |value: f32, limit: usize| (value.max(0.0) as usize).min(limit);
    let (x1, y1) = (clip(bbox[0].floor(), w), clip(bbox[1].floor(), h));
    let (x2, y2) = (clip(bbox[2].ceil(), w), clip(bbox[3].ceil(), h));
    (x1..x2, y1..y2)
}

/// The keypoints of a tracked frame in a removed (dynamic) state, `(x, y, depth)`.
pub fn dynamic_keypoints(frame: &crate::frame::Frame, dop: &DopConfig) -> FrameKeypoints {
    FrameKeypoints {
        timestamp: frame.timestamp,
        points: frame
            .keypoints
            .iter()
            .zip(&frame.moving)
            .zip(&frame.depth)
            .filter(|((_, p), _)| dop.removed(**p))
            .map(|((k, _), z)| [k.x, k.y, *z])
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::detect::Detection;
    use nalgebra::Vector3;

    /// A wall at 3 m with a person-sized slab at 1.5 m in the middle.
    fn scene() -> (PinholeCamera, DepthImage) {
        let camera = PinholeCamera::tum_fr3();
        let mut depth = DepthImage::new(camera.width, camera.height);
        for v in 0..camera.height {
            for u in 0..camera.width {
                let person = (250..390).contains(&u) && (100..460).contains(&v);
                depth.metres[(v * camera.width + u) as usize] = if person { 1.5 } else { 3.0 };
            }
        }
        (camera, depth)
    }

    /// A DOP mask source over [`scene`] (identity poses, its depth on every keyframe).
    fn scene_source(
        settings: MaskSettings,
        frames: Vec<FrameDetections>,
        keypoints: Vec<FrameKeypoints>,
    ) -> MaskSource {
        scene_source_of(&["person".to_string()], settings, frames, keypoints)
    }

    /// [`scene_source`] with the `dynamic_classes` given.
    fn scene_source_of(
        dynamic_classes: &[String],
        settings: MaskSettings,
        frames: Vec<FrameDetections>,
        keypoints: Vec<FrameKeypoints>,
    ) -> MaskSource {
        let (camera, depth) = scene();
        MaskSource::new(
            MaskContext {
                masking: Mode::Dop,
                camera,
                dop: &DopConfig::default(),
                dynamic_classes,
            },
            settings,
            frames,
            keypoints,
            &|_| Ok(Some(Se3::identity())),
            &|_| Some(depth.clone()),
        )
        .expect("held detections")
    }

    /// The DOP mask at t = 1 of [`scene`] with one person detected in `bbox` at t = 1,
    /// the frame's dynamic `keypoints`, and `settings`.
    fn person_mask(bbox: [f32; 4], keypoints: &[[f32; 3]], settings: MaskSettings) -> Vec<bool> {
        let (_, depth) = scene();
        let frames = vec![FrameDetections {
            timestamp: 1.0,
            detections: vec![Detection {
                class: "person".into(),
                class_id: 0,
                score: 0.9,
                bbox,
                instance: None,
            }],
        }];
        let keypoints = vec![FrameKeypoints {
            timestamp: 1.0,
            points: keypoints.to_vec(),
        }];
        let mut source = scene_source(settings, frames, keypoints);
        source
            .mask(1.0, &depth, &Se3::identity(), None)
            .expect("a mask")
    }

    fn at(mask: &[bool], u: u32, v: u32) -> bool {
        mask[(v * PinholeCamera::tum_fr3().width + u) as usize]
    }

    /// A person cut by the image border fills little of its box: the box's dominant
    /// depth is the wall's, which masks the wall and not the person; its foreground
    /// depth is the person's.
    #[test]
    fn a_box_the_wall_fills_is_cut_at_its_foreground_depth() {
        // The person (250..390) fills about a sixth of this box.
        let mask_with = |foreground_share| {
            let settings = MaskSettings {
                border: 0,
                keypoint_radius: 0,
                foreground_share,
                track_margin_speed: 0.4,
                depth_behind: 0.4,
                depth_behind_not_still: 0.4,
                skip_behind_objects: false,
                disc_neighbours: 0,
                keypoints_seen_moving: false,
                segments: None,
            };
            person_mask([250.0, 80.0, 640.0, 480.0], &[], settings)
        };
        let dominant = mask_with(0.0);
        assert!(
            at(&dominant, 500, 300) && !at(&dominant, 320, 300),
            "the wall's depth"
        );
        let foreground = mask_with(0.1);
        assert!(at(&foreground, 320, 300), "the person");
        assert!(
            !at(&foreground, 500, 300),
            "the wall inside the box stays static"
        );
    }

    /// Discs of radius 5 around every dynamic keypoint, no border, no segments.
    fn disc_settings() -> MaskSettings {
        MaskSettings {
            border: 0,
            keypoint_radius: 5,
            foreground_share: 0.1,
            track_margin_speed: 0.4,
            depth_behind: 0.4,
            depth_behind_not_still: 0.4,
            skip_behind_objects: true,
            disc_neighbours: 0,
            keypoints_seen_moving: false,
            segments: None,
        }
    }

    /// A dynamic keypoint on the wall inside a detected person's box, behind the
    /// person: its disc is drawn unless discs behind objects are off; one outside any
    /// box keeps its disc either way.
    #[test]
    fn discs_behind_a_detected_mover_can_be_left_out() {
        let mask_with = |skip_behind_objects| {
            let settings = MaskSettings {
                skip_behind_objects,
                ..disc_settings()
            };
            let keypoints = [[240.0, 300.0, 3.0], [100.0, 300.0, 3.0]];
            person_mask([230.0, 80.0, 410.0, 470.0], &keypoints, settings)
        };
        let drawn = mask_with(false);
        assert!(at(&drawn, 240, 300) && at(&drawn, 100, 300));
        let skipped = mask_with(true);
        assert!(!at(&skipped, 240, 300), "behind the person");
        assert!(at(&skipped, 100, 300), "outside any box");
        assert!(at(&skipped, 320, 300), "the person");
    }

    /// With `keypoints_seen_moving`, a dynamic keypoint draws its disc only where the
    /// free-space evidence saw a pixel move within the disc's radius: the one on the
    /// slab (a few pixels beside it seen moving) keeps its disc, the one on the wall
    /// (seen moving nowhere) loses it.
    #[test]
    fn discs_only_around_keypoints_seen_moving() {
        let (camera, depth) = scene();
        let (w, h) = (camera.width as usize, camera.height as usize);
        let mut moving = vec![false; w * h];
        for (u, v) in [(303, 262), (304, 262), (303, 263)] {
            moving[v * w + u] = true;
        }
        let evidence = Evidence {
            moving,
            still: vec![false; w * h],
        };
        let mask_with = |keypoints_seen_moving| {
            let settings = MaskSettings {
                keypoints_seen_moving,
                ..disc_settings()
            };
            let keypoints = vec![FrameKeypoints {
                timestamp: 1.0,
                points: vec![[300.0, 260.0, 1.5], [60.0, 60.0, 3.0]],
            }];
            let mut source = scene_source(settings, vec![], keypoints);
            let identity = Se3::identity();
            source
                .mask(1.0, &depth, &identity, Some(&evidence))
                .expect("a mask")
        };
        let every = mask_with(false);
        assert!(at(&every, 300, 256) && at(&every, 60, 60), "both discs");
        let gated = mask_with(true);
        assert!(at(&gated, 300, 256), "the slab's disc");
        assert!(!at(&gated, 60, 60), "no disc on the wall");
        assert!(at(&gated, 303, 262), "the pixel seen moving");
    }

    /// A mover no detector knows (the slab of [`scene`], no detection): two dynamic
    /// keypoints on it at t = 1 mask its whole depth segment; the segment is followed
    /// to t = 2 without keypoints, and let go 3 s after its last support. A lone
    /// dynamic keypoint on the wall gets no disc with `disc_neighbours`.
    #[test]
    fn a_mover_without_a_box_is_masked_by_its_segment_and_followed() {
        let (_, depth) = scene();
        let settings = MaskSettings {
            border: 0,
            keypoint_radius: 5,
            foreground_share: 0.1,
            track_margin_speed: 0.4,
            depth_behind: 0.4,
            depth_behind_not_still: 0.4,
            skip_behind_objects: true,
            disc_neighbours: 2,
            keypoints_seen_moving: false,
            // The slab is 360 pixels tall.
            segments: Some((
                SegmentSettings {
                    radius: 240,
                    ..SegmentSettings::default()
                },
                3.0,
            )),
        };
        let keypoints = vec![FrameKeypoints {
            timestamp: 1.0,
            points: vec![[300.0, 260.0, 1.5], [340.0, 300.0, 1.5], [60.0, 60.0, 3.0]],
        }];
        let mut source = scene_source(settings, vec![], keypoints);
        let identity = Se3::identity();
        // (slab pixels masked, other pixels masked)
        let count = |m: &[bool]| {
            let slab = |i: usize| depth.metres[i] < 2.0;
            let masked = |i: &usize| m[*i];
            let on = (0..m.len()).filter(|&i| slab(i)).filter(masked).count();
            (
                on,
                (0..m.len()).filter(|&i| !slab(i)).filter(masked).count(),
            )
        };
        let first = source.mask(1.0, &depth, &identity, None).expect("a mask");
        let (on, off) = count(&first);
        assert!(
            on >= 140 * 360 * 99 / 100 && off == 0,
            "the slab only: {on}, {off}"
        );
        assert!(!at(&first, 60, 60), "no disc around the lone keypoint");
        let followed = source.mask(2.0, &depth, &identity, None).expect("followed");
        let (followed_on, followed_off) = count(&followed);
        assert!(followed_on >= on && followed_off == 0);
        assert!(
            source.mask(4.5, &depth, &identity, None).is_none(),
            "let go"
        );
    }

    /// Objects' masks alone: no border, no foreground share, discs around every
    /// keypoint, no segments.
    fn object_settings() -> MaskSettings {
        MaskSettings {
            border: 0,
            keypoint_radius: 8,
            foreground_share: 0.0,
            track_margin_speed: 0.4,
            depth_behind: 0.4,
            depth_behind_not_still: 0.4,
            skip_behind_objects: false,
            disc_neighbours: 0,
            keypoints_seen_moving: false,
            segments: None,
        }
    }

    /// A detected frame holding `objects`.
    fn detected_frame(timestamp: f64, objects: Vec<Object>) -> KeyframeObjects {
        KeyframeObjects {
            timestamp,
            boxes: Vec::new(),
            objects,
            classes: Vec::new(),
        }
    }

    /// An object of track `track` at `x` metres (2 m in front of the camera).
    fn walker(track: u32, x: f64) -> Object {
        Object {
            centre: Vector3::new(x, 0.0, 2.0),
            size: (0.5, 1.7),
            margin: 0.0,
            moved: true,
            self_moving: true,
            track: Some(track),
        }
    }

    /// Between two detections of the same person, the person is placed once, as far
    /// along as the time; someone seen on one side only stays where they were seen.
    #[test]
    fn a_person_seen_before_and_after_a_frame_is_placed_between_once() {
        let before = detected_frame(1.0, vec![walker(1, 0.0), walker(2, -1.0)]);
        let after = detected_frame(1.4, vec![walker(1, 0.4), walker(3, 1.0)]);
        let objects = objects_at(&[before, after], 1.1, 1.5);
        assert_eq!(objects.len(), 3, "{objects:?}");
        let x = |track: u32| {
            objects
                .iter()
                .find(|o| o.track == Some(track))
                .map(|o| o.centre.x)
        };
        assert!((x(1).unwrap() - 0.1).abs() < 1e-9, "{objects:?}");
        let margin = |track: u32| {
            objects
                .iter()
                .find(|o| o.track == Some(track))
                .unwrap()
                .margin
        };
        assert!(
            (margin(1) - 0.15).abs() < 1e-9,
            "0.1 s from the nearer detection"
        );
        assert_eq!(margin(2), 0.0);
        assert_eq!(x(2), Some(-1.0));
        assert_eq!(x(3), Some(1.0));
    }

    /// A person missed on the frames between two detections is placed between them
    /// there, with a margin for the time to the nearer detection; one never seen again
    /// keeps the prediction.
    #[test]
    fn the_gap_between_two_detections_of_a_person_is_filled_in() {
        let predicted = |track: u32, x: f64| Object {
            margin: 0.6,
            ..walker(track, x)
        };
        let mut frames = vec![
            detected_frame(0.0, vec![walker(1, 0.0), walker(2, 3.0)]),
            detected_frame(0.4, vec![predicted(1, 0.1), predicted(2, 3.0)]),
            detected_frame(0.8, vec![walker(1, 0.8), predicted(2, 3.0)]),
        ];
        fill_gaps(&mut frames, 1.0, 0.5);
        let gap = &frames[1].objects;
        assert!((gap[0].centre.x - 0.4).abs() < 1e-9, "{gap:?}");
        assert!(
            (gap[0].margin - 0.2).abs() < 1e-9,
            "0.4 s from either detection"
        );
        assert!(gap[1].predicted(), "track 2 was not seen again");
        // Detections farther apart than twice track_seconds leave the gap alone.
        let mut far = vec![
            detected_frame(0.0, vec![walker(1, 0.0)]),
            detected_frame(0.4, vec![predicted(1, 0.1)]),
            detected_frame(2.5, vec![walker(1, 2.0)]),
        ];
        fill_gaps(&mut far, 1.0, 0.5);
        assert!(far[1].objects[0].predicted());
    }

    /// A detected object of a class that does not move on its own (a truck: here a
    /// false alarm on the slab) is masked only where the frames around saw it move; a
    /// person is masked either way.
    #[test]
    fn an_object_seen_still_is_fused_unless_it_moves_on_its_own() {
        let (camera, depth) = scene();
        let n = depth.metres.len();
        let still = Evidence {
            moving: vec![false; n],
            still: vec![true; n],
        };
        // The frames around saw a strip of the slab's edge move (7 of its 140 columns).
        let mut moving = Evidence {
            moving: vec![false; n],
            still: vec![true; n],
        };
        for v in 100..460 {
            for u in 250..257 {
                moving.moving[(v * camera.width + u) as usize] = true;
            }
        }
        let object_at_centre = |class: &str, evidence: &Evidence| {
            let frames = vec![FrameDetections {
                timestamp: 1.0,
                detections: vec![Detection {
                    class: class.into(),
                    class_id: 0,
                    score: 0.9,
                    bbox: [230.0, 80.0, 410.0, 470.0],
                    instance: None,
                }],
            }];
            let classes = ["person".to_string(), "truck".to_string()];
            let mut source = scene_source_of(&classes, object_settings(), frames, vec![]);
            source
                .layers(1.0, &depth, &Se3::identity(), Some(evidence))
                .is_some_and(|m| {
                    m.sources[(300 * camera.width + 320) as usize] & MaskLayer::Objects.bit() != 0
                })
        };
        assert!(!object_at_centre("truck", &still), "a truck seen still");
        assert!(object_at_centre("truck", &moving), "a truck seen moving");
        assert!(object_at_centre("person", &still), "a person seen still");
    }

    #[test]
    fn dop_masks_the_object_not_its_background_and_reaches_frames_between_keyframes() {
        let (camera, depth) = scene();
        let detection = Detection {
            class: "person".into(),
            class_id: 0,
            score: 0.9,
            bbox: [230.0, 80.0, 410.0, 470.0],
            instance: None,
        };
        let frames = vec![FrameDetections {
            timestamp: 1.0,
            detections: vec![detection],
        }];
        let settings = object_settings();
        let identity = Se3::identity();
        let mut source = scene_source(settings, frames.clone(), vec![]);
        // A frame 0.2 s later, camera moved 10 cm to the right: the person shifts left.
        let moved = crate::geometry::se3::from_parts(
            Vector3::new(-0.1, 0.0, 0.0),
            nalgebra::Matrix3::identity(),
        );
        for (pose, shift) in [(identity, 0i32), (moved, -36)] {
            let mask = source.mask(1.2, &depth, &pose, None).expect("a mask");
            let at = |u: i32, v: i32| mask[(v as u32 * camera.width + (u + shift) as u32) as usize];
            assert!(at(320, 300), "the person's centre");
            assert!(!at(240, 300), "the wall inside the box stays static");
            assert!(!at(100, 300), "outside the box");
        }
        // Far from any keyframe nothing is masked; --no-dop masks nothing.
        assert!(source.mask(5.0, &depth, &identity, None).is_none());
        let mut boxes = MaskSource::new(
            MaskContext {
                masking: Mode::MaskBoxes,
                camera,
                dop: &DopConfig::default(),
                dynamic_classes: &["person".to_string()],
            },
            settings,
            frames,
            vec![],
            &|_| Ok(None),
            &|_| None,
        )
        .expect("held detections");
        let mask = boxes.mask(1.0, &depth, &identity, None).expect("a mask");
        assert!(mask[(300 * camera.width + 240) as usize], "a whole box");
    }

    /// A DOP mask source over [`scene`] with [`object_settings`], its detected frames
    /// read and placed as the frames come ([`MaskSource::place_through`]).
    fn lazy_source(frames: Vec<FrameDetections>) -> MaskSource {
        let context = MaskContext {
            masking: Mode::Dop,
            camera: scene().0,
            dop: &DopConfig::default(),
            dynamic_classes: &["person".to_string()],
        };
        MaskSource::unplaced(context, object_settings(), frames, vec![])
    }

    #[test]
    fn objects_placed_as_frames_come_mask_as_those_placed_first() {
        let (_, depth) = scene();
        let person = |t: f64, x: f32| FrameDetections {
            timestamp: t,
            detections: vec![Detection {
                class: "person".into(),
                class_id: 0,
                score: 0.9,
                bbox: [x, 80.0, x + 180.0, 470.0],
                instance: None,
            }],
        };
        let empty = |t: f64| FrameDetections {
            timestamp: t,
            detections: vec![],
        };
        let frames = vec![
            person(1.0, 230.0),
            empty(1.4),
            person(1.8, 260.0),
            person(2.6, 300.0),
        ];
        let settings = object_settings();
        let mut first = scene_source(settings, frames.clone(), vec![]);
        let mut lazy = lazy_source(frames);
        let asked = std::cell::RefCell::new(Vec::new());
        let depth_at = |t: f64| {
            asked.borrow_mut().push(t);
            Some(depth.clone())
        };
        let identity = Se3::identity();
        for t in [0.9, 1.0, 1.2, 1.5, 1.8, 2.0, 2.5] {
            lazy.place_through(t, &|_| Ok(Some(Se3::identity())), &depth_at)
                .unwrap();
            assert_eq!(
                lazy.mask(t, &depth, &identity, None),
                first.mask(t, &depth, &identity, None),
                "at {t} s"
            );
            // Placed up to the first detected frame at or after t + track_seconds (1 s):
            // each boxed frame's depth asked once, the frame without a box never.
            let through = [1.0, 1.4, 1.8, 2.6]
                .into_iter()
                .find(|&d| d >= t + 1.0)
                .unwrap_or(2.6);
            let boxed: Vec<f64> = [1.0, 1.8, 2.6]
                .into_iter()
                .filter(|&d| d <= through)
                .collect();
            assert_eq!(*asked.borrow(), boxed, "at {t} s");
        }
    }

    /// Over a long walk, the frames masked one after another, placing as they come and
    /// letting the old detected frames go, get the masks a source that placed every
    /// frame first and let none go gives; and hold a few seconds of detected frames.
    #[test]
    fn old_detected_frames_let_go_change_no_mask() {
        let (_, depth) = scene();
        // A person detected every 0.4 s for 40 s, walking to and fro; missed from 10 to
        // 11.2 s (a gap to fill) and absent from 20 to 24 s.
        let frames: Vec<FrameDetections> = (0..100)
            .map(|i| 0.4 * i as f64)
            .map(|t| {
                let x = 120.0 + (60.0 * t as f32) % 300.0;
                let seen = !(10.0..11.3).contains(&t) && !(20.0..24.0).contains(&t);
                FrameDetections {
                    timestamp: t,
                    detections: [x]
                        .into_iter()
                        .filter(|_| seen)
                        .map(|x| Detection {
                            class: "person".into(),
                            class_id: 0,
                            score: 0.9,
                            bbox: [x, 80.0, x + 180.0, 470.0],
                            instance: None,
                        })
                        .collect(),
                }
            })
            .collect();
        let settings = object_settings();
        let mut lazy = lazy_source(frames.clone());
        let (identity, mut most_held) = (Se3::identity(), 0);
        for t in (0..80).map(|i| 0.5 * i as f64 + 0.05) {
            lazy.place_through(t, &|_| Ok(Some(identity)), &|_| Some(depth.clone()))
                .unwrap();
            let mask = lazy.mask(t, &depth, &identity, None);
            // Every frame placed before any is masked (or let go).
            let mut first = scene_source(settings, frames.clone(), vec![]);
            assert_eq!(mask, first.mask(t, &depth, &identity, None), "at {t} s");
            most_held = most_held.max(lazy.keyframes.len());
        }
        // Read as the frames come, let go once passed: some 5 s of them (1 s ahead,
        // 2 s of gaps and 1 s of margin behind), up to twice that between two batches
        // let go (17 here).
        assert!(most_held <= 25, "{most_held} of 100 held");
        assert!(
            lazy.keyframes.len() < 20,
            "{} held at the end",
            lazy.keyframes.len()
        );
    }

    /// Depth samples on a 2-pixel grid of a 400 x 300 image: `depth_at(u, v)`.
    fn grid_samples(depth_at: impl Fn(f32, f32) -> f32) -> Vec<Keypoint> {
        (0..150)
            .flat_map(|v| (0..200).map(move |u| (2.0 * u as f32, 2.0 * v as f32)))
            .map(|(x, y)| Keypoint {
                x,
                y,
                depth: depth_at(x, y),
            })
            .collect()
    }

    fn person_box(bbox: [f32; 4]) -> ObjectBox {
        ObjectBox {
            bbox,
            dynamic: true,
            depth: None,
            moved: false,
        }
    }

    /// Person A (2 m) stands in front of part of person B (3 m) before a wall (5 m):
    /// A is the foreground of both boxes. B takes its depth from what A leaves; a box
    /// of part of A and a box around the whole image keep A's.
    #[test]
    fn a_person_behind_another_takes_its_own_depth() {
        let samples = grid_samples(|x, _| match x {
            x if (100.0..200.0).contains(&x) => 2.0,
            x if (200.0..260.0).contains(&x) => 3.0,
            _ => 5.0,
        });
        let boxes = [
            person_box([175.0, 0.0, 300.0, 300.0]),
            person_box([100.0, 0.0, 200.0, 300.0]),
            person_box([120.0, 0.0, 180.0, 150.0]),
            person_box([0.0, 0.0, 400.0, 300.0]),
        ];
        let share = |points: &[Keypoint], b: &ObjectBox| {
            let inside: Vec<f32> = points
                .iter()
                .filter(|k| b.contains(k.x, k.y))
                .map(|k| k.depth)
                .collect();
            foreground_depth(&inside, 0.2, 0.1)
        };
        // Each box alone: A is everyone's foreground.
        for b in &boxes {
            assert!((share(&samples, b).unwrap() - 2.0).abs() < 1e-3);
        }
        let dop = DopConfig {
            delta_z: 0.4,
            ..DopConfig::default()
        };
        let depths = box_depths(&boxes, &samples, &dop, 0.1);
        let close = |z: Option<f32>, want: f32| z.is_some_and(|z| (z - want).abs() < 1e-3);
        assert!(close(depths[0], 3.0), "B: {:?}", depths[0]);
        assert!(close(depths[1], 2.0), "A: {:?}", depths[1]);
        assert!(close(depths[2], 2.0), "part of A: {:?}", depths[2]);
        assert!(close(depths[3], 2.0), "a box around all: {:?}", depths[3]);
    }

    /// A person (3 m) before a wall (5 m) whose box reaches down over a crate on the
    /// floor in front of it (2 m): the crate is the box's foreground, the person its
    /// centre, and the box is placed at both. A box of two legs (2 m) centred on the
    /// wall between them is placed at the legs only.
    #[test]
    fn a_box_centred_behind_its_foreground_is_placed_at_its_centre_too() {
        let camera = PinholeCamera::tum_fr3();
        let dop = DopConfig {
            delta_z: 0.4,
            ..DopConfig::default()
        };
        let b = person_box([100.0, 0.0, 300.0, 300.0]);
        let crate_before_person = grid_samples(|x, y| match (x, y) {
            (_, y) if y >= 240.0 && (100.0..300.0).contains(&x) => 2.0,
            (x, _) if (150.0..250.0).contains(&x) => 3.0,
            _ => 5.0,
        });
        let z = box_depths(&[b], &crate_before_person, &dop, 0.1)[0].expect("a depth");
        assert!((z - 2.0).abs() < 1e-3, "the crate is the foreground: {z}");
        let centre = centre_behind(&b, z, &crate_before_person, &dop, &camera);
        assert!(centre.is_some_and(|c| (c - 3.0).abs() < 1e-3), "{centre:?}");
        let legs = grid_samples(|x, _| match x {
            x if (100.0..140.0).contains(&x) || (260.0..300.0).contains(&x) => 2.0,
            _ => 5.0,
        });
        assert_eq!(centre_behind(&b, 2.0, &legs, &dop, &camera), None);
        // The same box around most of the image is not placed at its centre.
        let whole = person_box([50.0, 0.0, 350.0, 300.0]);
        let z = box_depths(&[whole], &crate_before_person, &dop, 0.1)[0].expect("a depth");
        assert_eq!(
            centre_behind(&whole, z, &crate_before_person, &dop, &camera),
            None
        );
    }

    /// Edges within 16 px of the border of a 640 x 480 image go to it; the others stay.
    #[test]
    fn box_edges_near_the_border_go_to_it() {
        let camera = PinholeCamera::tum_fr3();
        let snapped = |bbox| snap_to_border(person_box(bbox), &camera).bbox;
        assert_eq!(snapped([9.0, 15.0, 630.0, 470.0]), [0.0, 0.0, 640.0, 480.0]);
        assert_eq!(
            snapped([17.0, 20.0, 620.0, 460.0]),
            [17.0, 20.0, 620.0, 460.0]
        );
    }

    /// An object's mask reaches `depth_behind` behind its depth and `delta_z` in front;
    /// with free-space evidence, `depth_behind_not_still` behind it where the frames
    /// around did not see the pixel still.
    #[test]
    fn an_object_mask_reaches_its_far_leg_behind_it() {
        let (camera, mut depth) = scene();
        let w = camera.width as usize;
        let mut fill = |us: std::ops::Range<usize>, vs: std::ops::Range<usize>, z: f32| {
            for v in vs {
                for u in us.clone() {
                    depth.metres[v * w + u] = z;
                }
            }
        };
        // The far leg, 0.5 m behind the body, in the slab's lower left; in the box's
        // upper right, 1 m behind the body, another person half hidden (not seen
        // still) above a crate (seen still).
        fill(250..300, 300..460, 2.0);
        fill(390..400, 100..300, 2.5);
        let crate_rows = 200..300;
        let mut evidence = Evidence {
            moving: vec![false; depth.metres.len()],
            still: vec![false; depth.metres.len()],
        };
        for v in crate_rows {
            evidence.still[v * w + 395] = true;
        }
        let object = ObjectBox {
            depth: Some(1.5),
            ..person_box([240.0, 90.0, 400.0, 470.0])
        };
        let mask_with = |depth_behind, depth_behind_not_still, evidence| {
            let settings = MaskSettings {
                border: 0,
                keypoint_radius: 0,
                foreground_share: 0.1,
                track_margin_speed: 0.4,
                depth_behind,
                depth_behind_not_still,
                skip_behind_objects: false,
                disc_neighbours: 0,
                keypoints_seen_moving: false,
                segments: None,
            };
            let source = scene_source(settings, Vec::new(), Vec::new());
            let mut sources = vec![0u8; depth.metres.len()];
            source.object_masks(&mut sources, &depth, &[object], evidence);
            sources
        };
        let (narrow, wide) = (mask_with(0.4, 0.4, None), mask_with(0.6, 0.6, None));
        let farther = mask_with(0.6, 1.2, Some(&evidence));
        let layer = |sources: &[u8], u: u32, v: u32| sources[v as usize * w + u as usize];
        let body = MaskLayer::Objects.bit();
        let band = MaskLayer::ObjectBand.bit();
        assert!(
            layer(&narrow, 300, 200) == body && layer(&wide, 300, 200) == body,
            "the body"
        );
        assert!(
            layer(&narrow, 260, 400) == 0 && layer(&wide, 260, 400) == band,
            "the far leg, in the band"
        );
        assert_eq!(layer(&wide, 245, 200), 0, "the wall in the box");
        for (sources, (u, v), expected, what) in [
            (&wide, (395, 150), 0, "the person behind, beyond the band"),
            (
                &farther,
                (395, 150),
                band,
                "the person behind, not seen still",
            ),
            (&farther, (395, 250), 0, "the crate behind, seen still"),
            (&farther, (245, 200), 0, "the wall, beyond the farther band"),
        ] {
            assert_eq!(layer(sources, u, v), expected, "{what}");
        }
        assert_eq!(
            mask_with(0.6, 1.2, None),
            wide,
            "no evidence: no farther band"
        );
    }

    /// A box of a close person's legs (1 m) before a wall (3 m), beside the person's
    /// own box, is centred on the wall between the legs: with nothing behind the wall,
    /// it keeps the legs' depth rather than take the wall's.
    #[test]
    fn a_box_between_legs_keeps_the_legs_depth() {
        let legs = |x: f32| (100.0..130.0).contains(&x) || (170.0..200.0).contains(&x);
        let samples = grid_samples(|x, _| if legs(x) { 1.0 } else { 3.0 });
        let boxes = [
            person_box([90.0, 0.0, 210.0, 300.0]),
            person_box([120.0, 150.0, 260.0, 300.0]),
        ];
        let dop = DopConfig {
            delta_z: 0.4,
            ..DopConfig::default()
        };
        let depths = box_depths(&boxes, &samples, &dop, 0.1);
        for (i, z) in depths.iter().enumerate() {
            assert!(z.is_some_and(|z| (z - 1.0).abs() < 1e-3), "box {i}: {z:?}");
        }
    }
}
