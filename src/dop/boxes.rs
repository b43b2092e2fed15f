//! The detector's verdict \(S_t(x)\) per keypoint, with boxes refined to their objects
//! by depth (the paper's Algorithm 1; this reading is a reconstruction, see
//! `dop-model.md` §6):
//! 1. a box's object depth \(z_{obj}\) is the mode of the keypoint depths in its
//!    central region (histogram of `delta_z / 2` bins, the mean of the fullest bin);
//! 2. a keypoint inside a box belongs to its object when \(|z - z_{obj}| \le \delta_z\),
//!    else it is the box's background;
//! 3. inside overlapping boxes it goes to the box whose \(z_{obj}\) is nearest its
//!    depth; \(S = 1\) when that box is of a dynamic class (static-class boxes take part
//!    so that a chair in front of a person keeps its points);
//! 4. without depth, \(S = 1\) inside a dynamic box's central region, else unknown.

use super::DopConfig;

/// A detected box in image pixels and whether its class is dynamic.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObjectBox {
    /// `[x1, y1, x2, y2]` in pixels.
    pub bbox: [f32; 4],
    /// Whether the box's class moves (a person), else static (a parked car).
    pub dynamic: bool,
    /// The object's depth when known (a box predicted from a followed object); else
    /// it is estimated from the keypoints in the box's centre.
    pub depth: Option<f32>,
    /// Its object has been followed moving ([`super::tracks`]): points on it are not
    /// verified static.
    pub moved: bool,
}

impl ObjectBox {
    /// Whether `(x, y)` lies in the box.
    pub fn contains(&self, x: f32, y: f32) -> bool {
        let [x1, y1, x2, y2] = self.bbox;
        x >= x1 && x < x2 && y >= y1 && y < y2
    }

    /// The box grown on every side by `share` of its width (left and right) and height
    /// (top and bottom), plus `px` pixels.
    pub fn widened(&self, share: f32, px: f32) -> Self {
        let [x1, y1, x2, y2] = self.bbox;
        let (wide, high) = (share * (x2 - x1) + px, share * (y2 - y1) + px);
        Self {
            bbox: [x1 - wide, y1 - high, x2 + wide, y2 + high],
            ..*self
        }
    }

    /// Whether `(x, y)` lies in the central `fraction` of the box (each side).
    pub fn central(&self, x: f32, y: f32, fraction: f32) -> bool {
        let [x1, y1, x2, y2] = self.bbox;
        let (cx, cy) = ((x1 + x2) / 2.0, (y1 + y2) / 2.0);
        let (hw, hh) = ((x2 - x1) * fraction / 2.0, (y2 - y1) * fraction / 2.0);
        (x - cx).abs() <= hw && (y - cy).abs() <= hh
    }
}

/// The naive verdict (`--mask-boxes`): whether `(x, y)` lies inside any dynamic box.
pub fn in_dynamic_box(boxes: &[ObjectBox], x: f32, y: f32) -> bool {
    boxes.iter().any(|b| b.dynamic && b.contains(x, y))
}

/// Whether `(x, y)` lies inside the box of an object followed moving.
pub fn in_moved_box(boxes: &[ObjectBox], x: f32, y: f32) -> bool {
    boxes
        .iter()
        .any(|b| b.dynamic && b.moved && b.contains(x, y))
}

/// A keypoint: pixel position and depth in metres (0 when unknown).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Keypoint {
    /// Column, pixels.
    pub x: f32,
    /// Row, pixels.
    pub y: f32,
    /// Depth in metres; 0 when unknown.
    pub depth: f32,
}

/// Depth bins: each bin's count and sum of depths, by bin index.
type DepthBins = std::collections::BTreeMap<i64, (usize, f32)>;

/// The histogram of the valid (positive) `depths` in `bin`-wide bins, and how many were
/// valid; `None` without any.
fn depth_histogram(depths: &[f32], bin: f32) -> Option<(DepthBins, usize)> {
    let mut bins = DepthBins::new();
    let mut valid = 0;
    for &z in depths.iter().filter(|z| **z > 0.0) {
        let entry = bins.entry((z / bin).floor() as i64).or_default();
        entry.0 += 1;
        entry.1 += z;
        valid += 1;
    }
    (valid > 0).then_some((bins, valid))
}

/// The dominant depth of `depths` (the mean of the fullest `bin`-wide histogram bin;
/// ties go to the nearer bin).
pub fn dominant_depth(depths: &[f32], bin: f32) -> Option<f32> {
    let (bins, _) = depth_histogram(depths, bin)?;
    let (_, (count, sum)) =
        bins.iter()
            .fold(None::<(i64, (usize, f32))>, |best, (k, v)| match best {
                Some(b) if b.1 .0 >= v.0 => Some(b),
                _ => Some((*k, *v)),
            })?;
    Some(sum / count as f32)
}

/// The foreground depth of `depths` (bins `bin` wide): the mean of the nearest two
/// neighbouring bins that together hold at least `min_share` of the valid depths. In a
/// mover's box the mover stands in front of what it hides, so this is the mover's
/// depth also where the background fills most of the box (a person cut by the image
/// border, partly hidden, or seen through the gaps of its own outline), where the
/// dominant depth is the wall's.
pub fn foreground_depth(depths: &[f32], bin: f32, min_share: f32) -> Option<f32> {
    let (bins, valid) = depth_histogram(depths, bin)?;
    let needed = ((min_share * valid as f32).ceil() as usize).max(1);
    bins.iter().find_map(|(k, &(count, sum))| {
        let (next_count, next_sum) = bins.get(&(k + 1)).copied().unwrap_or_default();
        let total = count + next_count;
        (total >= needed).then(|| (sum + next_sum) / total as f32)
    })
}

/// The object depth of a box from its keypoints: the dominant depth of those in its
/// central region.
pub fn object_depth(config: &DopConfig, keypoints: &[Keypoint], b: &ObjectBox) -> Option<f32> {
    let central: Vec<f32> = keypoints
        .iter()
        .filter(|k| b.central(k.x, k.y, config.central_fraction))
        .map(|k| k.depth)
        .collect();
    dominant_depth(&central, config.delta_z / 2.0)
}

/// \(S_t(x)\) per keypoint: `Some(true)` on a dynamic object, `Some(false)` static or
/// background, `None` unknown (no depth, outside a dynamic box's centre).
pub fn verdicts(
    config: &DopConfig,
    keypoints: &[Keypoint],
    boxes: &[ObjectBox],
) -> Vec<Option<bool>> {
    let object_depths: Vec<Option<f32>> = boxes
        .iter()
        .map(|b| b.depth.or_else(|| object_depth(config, keypoints, b)))
        .collect();
    keypoints
        .iter()
        .map(|k| {
            let inside: Vec<usize> = (0..boxes.len())
                .filter(|&b| boxes[b].contains(k.x, k.y))
                .collect();
            if inside.is_empty() {
                return Some(false);
            }
            if !config.refine_boxes {
                return Some(inside.iter().any(|&b| boxes[b].dynamic));
            }
            if k.depth <= 0.0 {
                let central = inside.iter().any(|&b| {
                    boxes[b].dynamic && boxes[b].central(k.x, k.y, config.central_fraction)
                });
                return central.then_some(true);
            }
            // The box whose object depth is nearest, if within delta_z.
            let nearest = inside
                .iter()
                .filter_map(|&b| object_depths[b].map(|z| (b, (z - k.depth).abs())))
                .filter(|(_, d)| *d <= config.delta_z)
                .min_by(|a, b| a.1.total_cmp(&b.1));
            match nearest {
                Some((b, _)) => Some(boxes[b].dynamic),
                // A dynamic box whose object depth is unknown keeps the naive verdict.
                None => Some(
                    inside
                        .iter()
                        .any(|&b| boxes[b].dynamic && object_depths[b].is_none()),
                ),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_foreground_depth_is_the_nearest_substantial_mode() {
        // 70 % wall at 4 m, 25 % person at 1.5 m, 5 % noise at 0.5 m.
        let mut depths = vec![4.0f32; 70];
        depths.extend(vec![1.5f32; 25]);
        depths.extend(vec![0.5f32; 5]);
        depths.extend(vec![0.0f32; 30]);
        assert_eq!(dominant_depth(&depths, 0.2), Some(4.0));
        let z = foreground_depth(&depths, 0.2, 0.15).unwrap();
        assert!((z - 1.5).abs() < 1e-6, "{z}");
        // A person split over two bins is one mode.
        let split = [vec![1.39f32; 10], vec![1.41f32; 10], vec![4.0f32; 80]].concat();
        let z = foreground_depth(&split, 0.2, 0.15).unwrap();
        assert!((z - 1.40).abs() < 1e-3, "{z}");
        assert_eq!(foreground_depth(&[0.0, 0.0], 0.2, 0.15), None);
    }

    fn kp(x: f32, y: f32, depth: f32) -> Keypoint {
        Keypoint { x, y, depth }
    }

    #[test]
    fn dominant_depth_is_the_fullest_bin() {
        let z = dominant_depth(&[2.0, 2.05, 2.1, 4.0, 4.02, 0.0], 0.2).unwrap();
        assert!((z - 2.05).abs() < 1e-6);
        assert_eq!(dominant_depth(&[0.0], 0.2), None);
    }

    #[test]
    fn the_wall_behind_a_person_stays_static() {
        let config = DopConfig::default();
        let person = ObjectBox {
            bbox: [100.0, 100.0, 200.0, 300.0],
            dynamic: true,
            depth: None,
            moved: false,
        };
        let keypoints = [
            kp(150.0, 200.0, 2.0), // on the person (centre)
            kp(140.0, 180.0, 2.1), // on the person
            kp(105.0, 110.0, 4.0), // wall behind, inside the box
            kp(150.0, 200.5, 0.0), // no depth, centre of the box
            kp(102.0, 295.0, 0.0), // no depth, box corner
            kp(300.0, 200.0, 4.0), // outside every box
        ];
        let s = verdicts(&config, &keypoints, &[person]);
        assert_eq!(
            s,
            vec![
                Some(true),
                Some(true),
                Some(false),
                Some(true),
                None,
                Some(false)
            ]
        );
        // Without refinement every keypoint in the box is dynamic.
        let naive = verdicts(
            &DopConfig {
                refine_boxes: false,
                ..config
            },
            &keypoints,
            &[person],
        );
        assert_eq!(naive[2], Some(true));
    }

    #[test]
    fn overlapping_boxes_give_a_keypoint_to_the_nearest_object() {
        let config = DopConfig::default();
        // A chair (static) at 1.5 m in front of a person at 3 m; boxes overlap.
        let chair = ObjectBox {
            bbox: [0.0, 100.0, 100.0, 200.0],
            dynamic: false,
            depth: None,
            moved: false,
        };
        let person = ObjectBox {
            bbox: [50.0, 0.0, 150.0, 200.0],
            dynamic: true,
            depth: None,
            moved: false,
        };
        let keypoints = [
            kp(50.0, 150.0, 1.5), // chair centre
            kp(40.0, 140.0, 1.55),
            kp(100.0, 100.0, 3.0), // person centre
            kp(90.0, 90.0, 3.05),
            kp(75.0, 150.0, 1.5), // in both boxes, chair depth
            kp(75.0, 160.0, 3.0), // in both boxes, person depth
            kp(100.0, 120.0, 3.02),
        ];
        let s = verdicts(&config, &keypoints, &[chair, person]);
        assert_eq!(s[4], Some(false), "the chair in front keeps its point");
        assert_eq!(s[5], Some(true));
        assert_eq!(&s[..4], &[Some(false), Some(false), Some(true), Some(true)]);
    }
}
