//! The fused pixels counted against a synthetic sequence's ground-truth masks
//! (`masks/` of the sequence, `dense.json`'s `truth`).

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::mask_layers::MaskLayer;
use super::tsdf::FrameInput;
use crate::io::IoError;

/// How many of the leaks [`FusedTruth::leaks`] keeps (the largest).
const LEAKS_KEPT: usize = 20;

/// Pixels fused against a synthetic sequence's ground-truth masks.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
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
    /// Where movers got in: runs of consecutive fused frames in which one mover had
    /// pixels fused, the largest first (at most 20), to find the frames to look at.
    pub leaks: Vec<Leak>,
    /// Each mask source's pixels against the truth: how many of them lie on movers
    /// (its precision), and what it masked alone.
    #[serde(default)]
    pub sources: Vec<SourceFigures>,
}

/// One mask source ([`MaskLayer`]) against the truth masks, over the pixels with depth
/// of the fused frames.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct SourceFigures {
    /// The source's name (`objects`, `discs`, `free_space`, `segments`, `dilation`,
    /// `map_agrees`: marked by a source, then fused because the static map explained
    /// its depth).
    pub source: String,
    /// Pixels it marked.
    pub pixels: u64,
    /// Those on movers.
    pub mover_pixels: u64,
    /// The share of its pixels on movers (for `map_agrees`: the share it let in).
    pub precision: f64,
    /// Its pixels over all pixels with depth, %.
    pub percent_of_pixels: f64,
    /// Pixels it marked and no other source did (all of its pixels for `map_agrees`).
    pub only_pixels: u64,
    /// Those on movers.
    pub only_mover_pixels: u64,
}

/// Per source ([`MaskLayer::ALL`]'s order): pixels, on movers, alone, alone on movers.
#[derive(Debug, Default)]
struct SourceCounts {
    counts: [[u64; 4]; MaskLayer::ALL.len()],
    pixels: u64,
}

impl SourceCounts {
    fn add(&mut self, sources: u8, mover: bool) {
        self.pixels += 1;
        let masked = sources & !MaskLayer::MapAgrees.bit();
        for (k, layer) in MaskLayer::ALL.iter().enumerate() {
            let bit = layer.bit();
            if sources & bit == 0 {
                continue;
            }
            let alone = masked == bit || *layer == MaskLayer::MapAgrees;
            let c = &mut self.counts[k];
            c[0] += 1;
            c[1] += mover as u64;
            c[2] += alone as u64;
            c[3] += (alone && mover) as u64;
        }
    }

    fn figures(&self) -> Vec<SourceFigures> {
        MaskLayer::ALL
            .iter()
            .zip(&self.counts)
            .map(|(layer, c)| SourceFigures {
                source: layer.name().into(),
                pixels: c[0],
                mover_pixels: c[1],
                precision: c[1] as f64 / c[0].max(1) as f64,
                percent_of_pixels: 100.0 * c[0] as f64 / self.pixels.max(1) as f64,
                only_pixels: c[2],
                only_mover_pixels: c[3],
            })
            .collect()
    }
}

/// The count of a dense pass against the truth masks as it goes: the figures so far
/// and the leaks still open at the last frame counted (one per instance).
#[derive(Debug, Default)]
pub struct TruthCounter {
    figures: FusedTruth,
    open: Vec<Leak>,
    sources: SourceCounts,
}

/// A run of consecutive fused frames in which one mover had pixels fused.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Leak {
    /// The mover's instance id in the truth masks.
    pub instance: u16,
    /// The first frame's timestamp.
    pub first: f64,
    /// The last frame's timestamp.
    pub last: f64,
    /// Frames in the run.
    pub frames: usize,
    /// The mover's pixels with depth in these frames.
    pub pixels: u64,
    /// Those fused.
    pub pixels_fused: u64,
}

impl TruthCounter {
    /// The figures with their shares, once every frame is counted.
    pub(super) fn finish(self) -> FusedTruth {
        let Self {
            figures: mut truth,
            mut open,
            sources,
        } = self;
        truth.sources = sources.figures();
        let share = |part: u64, whole: u64| part as f64 / whole.max(1) as f64;
        truth.dynamic_removed = 1.0 - share(truth.mover_pixels_fused, truth.mover_pixels);
        truth.static_kept = share(truth.static_pixels_fused, truth.static_pixels);
        truth.unknown_removed = (truth.unknown_mover_pixels > 0)
            .then(|| 1.0 - share(truth.unknown_mover_pixels_fused, truth.unknown_mover_pixels));
        truth.leaks.append(&mut open);
        keep_largest(&mut truth.leaks);
        truth
    }

    /// Extends the open leaks with one frame's mover pixels, `(instance, pixels,
    /// fused)`: a mover with none fused closes its leak.
    fn count_leaks(&mut self, timestamp: f64, movers: &[(u16, u64, u64)]) {
        let mut still_open = Vec::with_capacity(self.open.len());
        for &(instance, pixels, pixels_fused) in movers.iter().filter(|m| m.2 > 0) {
            let mut leak = match self.open.iter().position(|l| l.instance == instance) {
                Some(i) => self.open.swap_remove(i),
                None => Leak {
                    instance,
                    first: timestamp,
                    last: timestamp,
                    frames: 0,
                    pixels: 0,
                    pixels_fused: 0,
                },
            };
            leak.last = timestamp;
            leak.frames += 1;
            leak.pixels += pixels;
            leak.pixels_fused += pixels_fused;
            still_open.push(leak);
        }
        self.figures.leaks.append(&mut self.open);
        // The closed leaks that can no longer be among the largest go (a stable sort:
        // the same as sorting them all at the end).
        if self.figures.leaks.len() > 2 * LEAKS_KEPT {
            keep_largest(&mut self.figures.leaks);
        }
        self.open = still_open;
    }
}

/// The [`LEAKS_KEPT`] largest `leaks` (the most pixels fused; the earlier first), in
/// that order.
fn keep_largest(leaks: &mut Vec<Leak>) {
    leaks.sort_by(|a, b| {
        b.pixels_fused
            .cmp(&a.pixels_fused)
            .then(a.first.total_cmp(&b.first))
    });
    leaks.truncate(LEAKS_KEPT);
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

/// A frame's instance ids in the truth masks (0: static) and, per pixel, the sources
/// of its mask ([`MaskLayer`] bits; none without masks).
pub(super) struct TruthFrame<'a> {
    pub timestamp: f64,
    pub ids: &'a [u16],
    pub sources: Option<&'a [u8]>,
}

/// Counts the fused and masked pixels of `frame` against its instance ids
/// (`unknown[id]`: a mover no detector knows), and each mask source's pixels.
pub(super) fn count_truth(
    counter: &mut TruthCounter,
    frame: TruthFrame,
    unknown: &[bool],
    input: &FrameInput,
    max_depth: f64,
) {
    let TruthFrame {
        timestamp,
        ids,
        sources,
    } = frame;
    let truth = &mut counter.figures;
    truth.frames += 1;
    // (instance, pixels, fused) of this frame's movers.
    let mut movers: Vec<(u16, u64, u64)> = Vec::new();
    for (i, &id) in ids.iter().enumerate() {
        let d = input.depth.metres.get(i).copied().unwrap_or(0.0) as f64;
        if d <= 0.0 || d > max_depth {
            continue;
        }
        let fused = !input.dynamic.is_some_and(|m| m[i]);
        counter.sources.add(sources.map_or(0, |s| s[i]), id > 0);
        if id > 0 {
            truth.mover_pixels += 1;
            truth.mover_pixels_fused += fused as u64;
            match movers.iter_mut().find(|m| m.0 == id) {
                Some(m) => {
                    m.1 += 1;
                    m.2 += fused as u64;
                }
                None => movers.push((id, 1, fused as u64)),
            }
            if unknown.get(id as usize).copied().unwrap_or(false) {
                truth.unknown_mover_pixels += 1;
                truth.unknown_mover_pixels_fused += fused as u64;
            }
        } else {
            truth.static_pixels += 1;
            truth.static_pixels_fused += fused as u64;
        }
    }
    counter.count_leaks(timestamp, &movers);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn leaks_are_runs_of_frames_per_mover_largest_first() {
        let mut truth = TruthCounter::default();
        // Mover 1 leaks in frames 0-1, not in 2, again in 3; mover 2 only in frame 1.
        truth.count_leaks(0.0, &[(1, 10, 2)]);
        truth.count_leaks(0.1, &[(1, 10, 3), (2, 50, 40)]);
        truth.count_leaks(0.2, &[(1, 10, 0), (2, 50, 0)]);
        truth.count_leaks(0.3, &[(1, 10, 1)]);
        let leaks = truth.finish().leaks;
        let got: Vec<_> = leaks
            .iter()
            .map(|l| {
                (
                    l.instance,
                    l.first,
                    l.last,
                    l.frames,
                    l.pixels,
                    l.pixels_fused,
                )
            })
            .collect();
        assert_eq!(
            got,
            vec![
                (2, 0.1, 0.1, 1, 50, 40),
                (1, 0.0, 0.1, 2, 20, 5),
                (1, 0.3, 0.3, 1, 10, 1)
            ]
        );
    }

    /// A long run's many leaks, kept few as they close, give the largest ones a sort
    /// of them all gives (ties in the order they closed).
    #[test]
    fn the_largest_leaks_of_a_long_run_are_those_of_all_of_them() {
        let mut truth = TruthCounter::default();
        let mut closed = Vec::new();
        for k in 0..500u64 {
            let t = k as f64 * 0.1;
            // One leak a frame, closed the next; sizes repeat, so ties abound.
            let fused = (k * 37) % 23;
            truth.count_leaks(t, &[((k % 7) as u16, 100, fused + 1)]);
            truth.count_leaks(t + 0.05, &[]);
            closed.push((t, fused + 1));
            assert!(truth.figures.leaks.len() <= 2 * LEAKS_KEPT + 1);
        }
        closed.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.total_cmp(&b.0)));
        let kept: Vec<(f64, u64)> = truth
            .finish()
            .leaks
            .iter()
            .map(|l| (l.first, l.pixels_fused))
            .collect();
        assert_eq!(kept, closed[..LEAKS_KEPT]);
    }
}
