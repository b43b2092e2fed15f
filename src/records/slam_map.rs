//! `report.json`'s `slam_map`: the map a run loaded (`--map`) and the map it saved
//! (`slam_map.bin`).

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

/// What a run did with saved maps.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct SlamMapReport {
    /// The map the run tracked in (`--map`), when there was one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub loaded: Option<LoadedMap>,
    /// The map the run left (`slam_map.bin`), when it wrote one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub saved: Option<SavedMap>,
}

/// The map a run was tracked in.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LoadedMap {
    /// Its file.
    pub file: PathBuf,
    /// Localisation only (`--map-frozen`).
    pub frozen: bool,
    /// The recordings it holds.
    pub recordings: Vec<String>,
    /// Its keyframes.
    pub keyframes: usize,
    /// Its map points.
    pub points: usize,
    /// The file's size.
    pub bytes: u64,
    /// The time to read it, seconds.
    pub load_s: f64,
    /// The first frame placed in it by relocalisation (`None`: none was).
    pub placed_at_frame: Option<usize>,
}

/// The map a run saved.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SavedMap {
    /// Its file.
    pub file: PathBuf,
    /// The recordings it holds, this run's last.
    pub recordings: Vec<String>,
    /// Its keyframes.
    pub keyframes: usize,
    /// Its map points.
    pub points: usize,
    /// The file's size.
    pub bytes: u64,
    /// The time to write it, seconds.
    pub write_s: f64,
}
