//! Reading datasets and trajectories, writing outputs atomically.

pub mod atomic;
pub mod data_dir;
pub mod errors;
pub mod file_list;
pub mod g2o;
pub mod image_files;
pub mod kitti;
pub mod orbslam_settings;
pub mod output;
pub mod ply;
pub mod ply_stream;
pub mod recording;
pub mod run_dir;
pub mod sequence;
pub mod trajectory;
pub mod tum;

pub use errors::IoError;
pub use trajectory::Trajectory;
