//! The stereo rig's disparity offset, estimated from the map and taken out (stereo
//! only; beyond ORB-SLAM2, which trusts the rectification).
//!
//! A real rig's rectification leaves a constant error \(\delta\) in every disparity:
//! the true disparity is \(d = d_{obs} + \delta\), so the depth \(bf / d_{obs}\) is too
//! far by a share \(z\delta / bf\) of itself, which grows with the distance, and the
//! whole trajectory's scale follows the near points' depths (real KITTI 01: the path
//! 3 % too long; `docs/design.md`, "The rig's disparity offset").
//!
//! The map holds a second measurement of every point's depth that no disparity enters:
//! its position triangulated from the bearings of the keyframes that see it, with their
//! poses. Those poses carry the scale \(s\) the disparities gave them, so a point's
//! disparity as the bearings place it, \(y = bf / z_{mv}\), relates to its observed one,
//! \(x = bf / z_{obs}\), by
//! \[ y = \frac{x + \delta}{s} = a x + b, \qquad \delta = b / a. \]
//! A robust line through the pairs \((x, y)\) of the points whose rays span at least
//! [`MIN_PARALLAX_DEG`] gives \(\delta\). Every keyframe's and frame's disparity is then
//! corrected (depth \(bf / (d_{obs} + \delta)\), right column \(u - d_{obs} - \delta\)), and the
//! full BA and the frames' refinement that follow fit poses and points to them.

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use crate::eval::stats::median;
use crate::frame::stereo::offset_disparity;
use crate::geometry::stereo_camera::StereoCamera;
use crate::map::record::FrameRecord;
use crate::map::Map;
use crate::optim::robust::huber_weight;

/// A point's rays must span at least this angle (degrees) for its triangulated depth to
/// be a measurement.
pub const MIN_PARALLAX_DEG: f64 = 2.0;
/// Fewest (disparity, triangulated disparity) pairs an estimate needs.
pub const MIN_PAIRS: usize = 200;
/// Only observations at pyramid levels up to this one give pairs: a coarse level's
/// keypoint position is that much coarser, and on both real KITTI clips the estimate
/// grows with the level (`docs/design.md`, "The rig's disparity offset").
pub const MAX_LEVEL: u8 = 2;
/// The Huber threshold of the line fit, pixels of disparity.
const HUBER_PX: f64 = 0.5;

/// What the estimate found (in `report.json`, `global.disparity_offset`).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct OffsetReport {
    /// The offset \(\delta\) taken out, pixels (added to every observed disparity).
    pub offset_px: f64,
    /// Each round's estimate, pixels.
    pub rounds: Vec<f64>,
    /// Pairs in the last round's fit.
    pub pairs: usize,
    /// The pose scale the last fit saw, \(1/a\).
    pub scale: f64,
}

impl OffsetReport {
    /// One line for the console: what was found and whether it was taken out.
    pub fn summary(&self) -> String {
        let found = format!("stereo disparity offset: {}", self.estimates());
        if self.offset_px == 0.0 {
            format!("{found}; none taken out (below [global] disparity_offset_min_px)")
        } else {
            format!(
                "{found}; {:.3} px taken out of every disparity",
                self.offset_px
            )
        }
    }

    /// The rounds' estimates and the pairs: "estimates 1.266, 0.039 px from 11684 pairs".
    pub fn estimates(&self) -> String {
        let rounds: Vec<String> = self.rounds.iter().map(|r| format!("{r:.3}")).collect();
        format!(
            "estimates {} px from {} pairs",
            rounds.join(", "),
            self.pairs
        )
    }
}

/// One observation's pair: the observed disparity and the one its triangulated point
/// gives.
type Pair = (f64, f64);

/// The midpoint triangulation of rays from `centres` along unit `rays`:
/// \(\min_X \sum_i \lVert (I - r_i r_i^T)(X - c_i) \rVert^2\).
fn triangulate(centres: &[Vector3<f64>], rays: &[Vector3<f64>]) -> Option<Vector3<f64>> {
    let mut a = Matrix3::zeros();
    let mut b = Vector3::zeros();
    for (c, r) in centres.iter().zip(rays) {
        let p = Matrix3::identity() - r * r.transpose();
        a += p;
        b += p * c;
    }
    a.lu().solve(&b)
}

/// The widest angle between two of `rays` (unit vectors), radians.
fn parallax(rays: &[Vector3<f64>]) -> f64 {
    let mut min_cos: f64 = 1.0;
    for (i, r) in rays.iter().enumerate() {
        for s in &rays[i + 1..] {
            min_cos = min_cos.min(r.dot(s));
        }
    }
    min_cos.clamp(-1.0, 1.0).acos()
}

/// The pairs \((x, y)\) of every static point seen by keyframes whose rays span at
/// least [`MIN_PARALLAX_DEG`], one per observation with a stereo depth at a level up to
/// [`MAX_LEVEL`] (every observation's ray enters the triangulation).
fn pairs(map: &Map, camera: &StereoCamera, removal_threshold: f32) -> Vec<Pair> {
    let mut out = Vec::new();
    let min_parallax = MIN_PARALLAX_DEG.to_radians();
    for point in map.points().values() {
        if point.moving > removal_threshold || point.observations.len() < 2 {
            continue;
        }
        let seen: Vec<_> = point
            .observations
            .iter()
            .filter_map(|&(k, i)| map.keyframes().get(k).map(|kf| (kf, i)))
            .collect();
        let (mut centres, mut rays) = (Vec::new(), Vec::new());
        for (kf, i) in &seen {
            let kp = &kf.frame.keypoints[*i];
            let ray_c = Vector3::new(
                (kp.x as f64 - camera.cx) / camera.fx,
                (kp.y as f64 - camera.cy) / camera.fy,
                1.0,
            );
            let world_from_camera = kf.world_from_camera();
            centres.push(world_from_camera.translation.vector);
            rays.push((world_from_camera.rotation * ray_c).normalize());
        }
        if parallax(&rays) < min_parallax {
            continue;
        }
        let Some(x_world) = triangulate(&centres, &rays) else {
            continue;
        };
        for (kf, i) in seen {
            if kf.frame.keypoints[i].level > MAX_LEVEL {
                continue;
            }
            let depth = kf.frame.depth[i];
            let z = (kf.camera_from_world * nalgebra::Point3::from(x_world)).z;
            if depth > 0.0 && z > 0.0 {
                out.push((camera.bf / depth as f64, camera.bf / z));
            }
        }
    }
    out
}

/// The robust line \(y = a x + b\) through `pairs` (Huber, iteratively reweighted
/// least squares from \(a = 1\), \(b\) the median of \(y - x\)).
fn fit_line(pairs: &[Pair]) -> Option<(f64, f64)> {
    if pairs.is_empty() {
        return None;
    }
    let mut gaps: Vec<f64> = pairs.iter().map(|(x, y)| y - x).collect();
    let (mut a, mut b) = (1.0, median(&mut gaps));
    for _ in 0..20 {
        let (mut sw, mut sx, mut sy, mut sxx, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for &(x, y) in pairs {
            let w = huber_weight((y - a * x - b).powi(2), HUBER_PX);
            sw += w;
            sx += w * x;
            sy += w * y;
            sxx += w * x * x;
            sxy += w * x * y;
        }
        let det = sw * sxx - sx * sx;
        if det.abs() < 1e-12 {
            return None;
        }
        a = (sw * sxy - sx * sy) / det;
        b = (sxx * sy - sx * sxy) / det;
    }
    (a > 0.0).then_some((a, b))
}

/// One estimate from the map.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    /// The offset \(\delta = b / a\), pixels.
    pub offset_px: f64,
    /// Pairs in the fit.
    pub pairs: usize,
    /// The pose scale the fit saw, \(1/a\).
    pub scale: f64,
}

/// The offset \(\delta\) the map shows; `None` with fewer than [`MIN_PAIRS`] pairs.
pub fn estimate(map: &Map, camera: &StereoCamera, removal_threshold: f32) -> Option<Estimate> {
    let pairs = pairs(map, camera, removal_threshold);
    if pairs.len() < MIN_PAIRS {
        return None;
    }
    let (a, b) = fit_line(&pairs)?;
    Some(Estimate {
        offset_px: b / a,
        pairs: pairs.len(),
        scale: 1.0 / a,
    })
}

/// Adds `offset` to every stereo disparity of the map's keyframes and of the tracked
/// `frames`' observations: depths \(bf / (d + \delta)\), right columns \(u - d - \delta\).
pub fn correct(map: &mut Map, frames: &mut [&mut FrameRecord], bf: f64, offset: f64) {
    for frame in map.keyframe_frames_mut() {
        for (i, kp) in frame.keypoints.iter().enumerate() {
            if frame.depth[i] <= 0.0 {
                continue;
            }
            let d = offset_disparity(bf / frame.depth[i] as f64, offset);
            frame.depth[i] = (bf / d) as f32;
            if frame.right_u[i] >= 0.0 {
                frame.right_u[i] = kp.x - d as f32;
            }
        }
    }
    for record in frames.iter_mut() {
        for o in &mut record.observations {
            if o.right_u >= 0.0 {
                o.right_u = o.x - offset_disparity((o.x - o.right_u) as f64, offset) as f32;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::Rng;

    #[test]
    fn the_line_recovers_offset_and_scale_through_outliers() {
        let mut rng = Rng::new(3);
        let (delta, scale) = (1.3, 1.03);
        let pairs: Vec<Pair> = (0..2000)
            .map(|i| {
                let x = rng.range(0.5, 60.0);
                let noise = if i % 10 == 0 {
                    rng.range(-20.0, 20.0)
                } else {
                    rng.range(-0.3, 0.3)
                };
                (x, (x + delta) / scale + noise)
            })
            .collect();
        let (a, b) = fit_line(&pairs).unwrap();
        assert!((b / a - delta).abs() < 0.05, "{}", b / a);
        assert!((1.0 / a - scale).abs() < 0.005, "{}", 1.0 / a);
    }

    #[test]
    fn rays_meet_where_they_were_cast_from() {
        let target = Vector3::new(1.0, -2.0, 30.0);
        let centres = [
            Vector3::zeros(),
            Vector3::new(0.0, 0.0, 5.0),
            Vector3::new(0.5, 0.0, 10.0),
        ];
        let rays: Vec<_> = centres.iter().map(|c| (target - c).normalize()).collect();
        let x = triangulate(&centres, &rays).unwrap();
        assert!((x - target).norm() < 1e-9);
        assert!(parallax(&rays) > 0.0);
    }
}
