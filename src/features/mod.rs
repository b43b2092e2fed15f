//! ORB features as ORB-SLAM2 uses them (Mur-Artal and Tardós 2017, §III; Rublee et al.
//! 2011): an image pyramid, FAST corners with an initial and a fallback threshold,
//! keypoints spread evenly per level by a quadtree, intensity-centroid orientation and
//! rotated BRIEF descriptors.

pub mod descriptor;
pub mod distribute;
pub mod fast;
pub mod orb;
pub mod pyramid;

pub use descriptor::{hamming, Descriptor, TH_HIGH, TH_LOW};
pub use orb::{KeyPoint, OrbConfig, OrbExtractor, OrbFeatures};
pub use pyramid::ScalePyramid;
