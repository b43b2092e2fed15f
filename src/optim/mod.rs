//! Nonlinear least squares for SLAM: robust kernels and the pose-only optimisation of
//! tracking. Knows nothing of ORB or detectors: it sees points, pixels and weights.

pub mod block_sparse;
pub mod local_ba;
pub mod pnp;
pub mod pose_graph;
pub mod pose_only;
pub mod ransac;
pub mod robust;
pub mod stereo_projection;
