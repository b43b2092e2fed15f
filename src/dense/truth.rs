//! The fused pixels counted against a synthetic sequence's ground-truth masks
//! (`masks/` of the sequence, `dense.json`'s `truth`).

use std::path::Path;

use serde::Serialize;

use super::tsdf::FrameInput;
use crate::io::IoError;

/// Pixels fused against a synthetic sequence's ground-truth masks.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct FusedTruth {
    /// Frames counted.
    pub frames: usize,
    /// Pixels with depth on movers, and those fused anyway.
    pub mover_pixels: u64,
    /// Mover pixels fused.
    pub mover_pixels_fused: u64,
    /// Pixels with depth on the static scene, and those fused.
    pub static_pixels: u64,
    /// Static pixels fused.
    pub static_pixels_fused: u64,
    /// Share of mover pixels kept out, and of static pixels fused.
    pub dynamic_removed: f64,
    /// Share of static pixels fused.
    pub static_kept: f64,
    /// Of the mover pixels, those on movers of no COCO class (which no detector
    /// knows; from `masks/instances.txt`), those fused anyway, and the share kept out
    /// (`None` without such movers).
    pub unknown_mover_pixels: u64,
    /// Those fused.
    pub unknown_mover_pixels_fused: u64,
    /// The share kept out.
    pub unknown_removed: Option<f64>,
}

impl FusedTruth {
    /// The shares, once every frame is counted.
    pub(super) fn finish(mut self) -> Self {
        let share = |part: u64, whole: u64| part as f64 / whole.max(1) as f64;
        self.dynamic_removed = 1.0 - share(self.mover_pixels_fused, self.mover_pixels);
        self.static_kept = share(self.static_pixels_fused, self.static_pixels);
        self.unknown_removed = (self.unknown_mover_pixels > 0)
            .then(|| 1.0 - share(self.unknown_mover_pixels_fused, self.unknown_mover_pixels));
        self
    }
}

/// Which instance ids of the truth masks are movers no detector knows (a class that is
/// not a COCO name), by id.
pub(super) fn unknown_instances(masks: &Path) -> Result<Vec<bool>, IoError> {
    let mut unknown = Vec::new();
    for (id, class) in crate::io::image_files::read_instance_classes(masks)?.unwrap_or_default() {
        let id = id as usize;
        if unknown.len() <= id {
            unknown.resize(id + 1, false);
        }
        unknown[id] = crate::detect::coco::class_id(&class).is_none();
    }
    Ok(unknown)
}

/// Counts fused and masked pixels against instance ids (0: static; `unknown[id]`: a
/// mover no detector knows).
pub(super) fn count_truth(
    truth: &mut FusedTruth,
    ids: &[u16],
    unknown: &[bool],
    input: &FrameInput,
    max_depth: f64,
) {
    truth.frames += 1;
    for (i, &id) in ids.iter().enumerate() {
        let d = input.depth.metres.get(i).copied().unwrap_or(0.0) as f64;
        if d <= 0.0 || d > max_depth {
            continue;
        }
        let fused = !input.dynamic.is_some_and(|m| m[i]);
        if id > 0 {
            truth.mover_pixels += 1;
            truth.mover_pixels_fused += fused as u64;
            if unknown.get(id as usize).copied().unwrap_or(false) {
                truth.unknown_mover_pixels += 1;
                truth.unknown_mover_pixels_fused += fused as u64;
            }
        } else {
            truth.static_pixels += 1;
            truth.static_pixels_fused += fused as u64;
        }
    }
}
