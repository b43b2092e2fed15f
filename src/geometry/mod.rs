//! Rigid and similarity transforms, their Lie algebras, camera intrinsics and
//! point-set alignment.
//!
//! Poses are named for the frames they map between: `world_from_camera * p_camera`
//! gives the point in world coordinates.

pub mod alignment;
pub mod camera;
pub mod depth_noise;
pub mod mesh;
pub mod se3;
pub mod sim3;
pub mod so3;
pub mod stereo_camera;

pub use se3::Se3;
pub use sim3::Sim3;
