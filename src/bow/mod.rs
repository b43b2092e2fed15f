//! Place recognition by bags of binary words: a hierarchical vocabulary
//! ([`vocabulary`]) and a keyframe database with an inverted index ([`database`]).
//! Knows descriptors only, nothing of maps or poses.

pub mod database;
pub mod vocabulary;

pub use database::{Database, Hit};
pub use vocabulary::{BowVector, FeatureVector, TrainOptions, Vocabulary};
