//! ORB finds enough well-spread keypoints on frames of every synth preset: the test bed's
//! textures are rich enough for tracking at every pyramid level.

use crate::common;

use std::path::Path;

use dopslam::features::{OrbConfig, OrbExtractor};
use dopslam::synth::writer::World;
use dopslam::synth::SynthConfig;

/// The presets' frames, rendered in memory: a few frames spread over a shortened run.
#[test]
fn orb_finds_a_thousand_spread_keypoints_in_every_preset() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/synth");
    let extractor = OrbExtractor::new(&OrbConfig::default());
    let mut presets: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    presets.sort();
    for path in presets {
        let mut config = SynthConfig::load(&path).unwrap();
        // Presets that read cut-outs or a recorded trajectory from the shared data take
        // them from where it is (or skip, saying why, when it is absent).
        let uses_shared = config.people.sprite.is_some()
            || config.seated.sprite.is_some()
            || config.motion.file.is_some();
        if uses_shared {
            let Some(shared) = common::shared_data(&format!("orb on {}", config.name)) else {
                continue;
            };
            // The presets name the shared data beside the checkout, resolved against
            // their own folder (`configs/synth/../../../shared/data/...`): what follows
            // `shared/data` is taken from where the shared data is.
            let relocate = |p: &mut Option<std::path::PathBuf>| {
                if let Some(path) = p {
                    let parts: Vec<_> = path.components().map(|c| c.as_os_str()).collect();
                    if let Some(i) = parts.windows(2).position(|w| w == ["shared", "data"]) {
                        *path = parts[i + 2..].iter().fold(shared.clone(), |p, c| p.join(c));
                    }
                }
            };
            relocate(&mut config.people.sprite);
            relocate(&mut config.seated.sprite);
            relocate(&mut config.motion.file);
        }
        config.sequence.timing = None;
        config.sequence.frames = 240;
        let world = World::new(&config).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        for index in [0, 120, 239] {
            let rgb = world.render(index).rgb;
            let grey = image::DynamicImage::ImageRgb8(rgb).to_luma8();
            let features = extractor.extract(&grey);
            // Spread: the image in cells of 80 x 80 pixels (8 x 6 at 640x480); at least
            // five in six hold keypoints and none more than a tenth of them.
            let columns = grey.width().div_ceil(80) as usize;
            let rows = grey.height().div_ceil(80) as usize;
            let mut cells = vec![0usize; columns * rows];
            for k in &features.keypoints {
                cells[(k.y as usize / 80) * columns + k.x as usize / 80] += 1;
            }
            let occupied = cells.iter().filter(|&&c| c > 0).count();
            let levels: std::collections::BTreeSet<u8> =
                features.keypoints.iter().map(|k| k.level).collect();
            assert_eq!(levels.len(), 8, "{}: keypoints on every level", config.name);
            let busiest = *cells.iter().max().unwrap();
            let total = cells.len();
            println!(
                "{} frame {index}: {} keypoints, {occupied}/{total} cells, busiest {busiest}",
                config.name,
                features.len()
            );
            // A street along a real KITTI path can face a close, plain facade or parked
            // car over part of the view: there, half the cells must hold keypoints.
            let share = if config.street.enabled { 3 } else { 5 };
            assert!(
                features.len() >= 1000
                    && occupied * 6 >= total * share
                    && busiest * 10 <= features.len(),
                "{} frame {index}: {} keypoints, {occupied}/{total} cells occupied, busiest {busiest}",
                config.name,
                features.len()
            );
        }
    }
}
