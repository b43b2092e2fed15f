//! Reading datasets and trajectories, writing outputs atomically.

pub mod atomic;
pub mod data_dir;
pub mod errors;
pub mod file_list;
pub mod g2o;
pub mod image_files;
pub mod json_array;
pub mod kitti;
pub mod orbslam_settings;
pub mod output;
pub mod ply;
pub mod ply_stream;
pub mod recording;
pub mod run_dir;

pub mod sequence;
pub mod spill;
pub mod trajectory;
pub mod tum;

pub use errors::IoError;
pub use trajectory::Trajectory;

/// FNV-1a (64 bits, hex) of `bytes`: the fingerprints of a sequence, of a batch run's
/// inputs and of a kept dense state.
pub fn content_hash(bytes: &[u8]) -> String {
    let hash = bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| {
        (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)
    });
    format!("{hash:016x}")
}
