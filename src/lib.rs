//! dopslam: dynamic-object-probability SLAM for RGB-D and stereo sequences.
//!
//! The crate follows the data flow of the system (Ai et al. 2021):
//! sequences in (`io`), geometry helpers (`geometry`), configuration (`config`),
//! and evaluation against ground truth (`eval`). Lower layers never import higher
//! ones: `geometry` knows nothing of datasets, `io` nothing of evaluation.
//!
//! No `unwrap` in library code (clippy's `unwrap_used` is denied outside tests): what
//! comes from input returns an error; the remaining `expect`s state invariants (a
//! poisoned lock, a buffer sized just above).

#![cfg_attr(not(test), deny(clippy::unwrap_used))]

pub mod batch;
pub mod bow;
pub mod checks;
pub mod config;
pub mod demo;
pub mod dense;
pub mod detect;
pub mod dop;
pub mod dynamics;
pub mod eval;
pub mod features;
pub mod frame;
pub mod geometry;
pub mod global;
pub mod interrupt;
pub mod io;
pub mod map;
pub mod mapping;
pub mod memory;
pub mod optim;
pub mod pacing;
pub mod random;
pub mod run;
pub mod synth;
pub mod system;
pub mod threads;
pub mod tracking;
pub mod view;
