//! dopslam: dynamic-object-probability SLAM for RGB-D and stereo sequences, after Ai et
//! al. (2021): ORB-SLAM2's tracking with a COCO detector on keyframes and a dynamic
//! object probability (DOP) per map point, as an offline two-pass tool with a dense map
//! of the static scene.
//!
//! # A run
//!
//! [`run::run_sequence`] is the tool: a [`run::RunPlan`] resolved once (the set-up of
//! [`run::setup`]: the sequence, its calibration and config; the run folder; the
//! Rerun recording), then [`run::execute`] in four calls: the tracking pass
//! ([`run::tracking_pass`] drives [`system::System`]: the tracker, local mapping,
//! place recognition and the keyframe detector beside it, the DOP state between
//! them), the global pass ([`global::run`]: loops, essential graph, full BA, the frames
//! refined), the outputs ([`run::outputs`]) and the dense pass ([`dense::fuse_run`]:
//! masks, TSDF, mesh and cloud of the static depth only). `docs/design.md` draws the
//! hand-offs between them. What the run writes, and every reader reads back, is typed
//! in [`records`].
//!
//! # Modules, bottom floor first
//!
//! A module imports its own floor and those below, never one above
//! (`tests/layers.rs` checks it):
//!
//! | floor | modules | what |
//! |---|---|---|
//! | 0 | [`random`], [`checks`], [`interrupt`], [`memory`], [`threads`], [`pacing`] | seeded randomness, range checks of settings, stop requests, budgets, pacing |
//! | 1 | [`geometry`] | SE(3)/Sim(3), cameras, alignment, meshes |
//! | 2 | [`io`], [`features`] | TUM/KITTI readers, recordings (ROS bags, MCAP, RealSense), trajectories, images, PLY/OBJ, run folders; ORB |
//! | 3 | [`optim`], [`dop`] | robust kernels, RANSAC, PnP, BA, pose graph; the DOP model (pure) |
//! | 4 | [`frame`], [`detect`], [`eval`] | frames ready for tracking; detectors (ONNX Runtime); ATE/RPE as evo defines them |
//! | 5 | [`map`], [`bow`], [`dynamics`] | keyframes and map points; the vocabulary; the DOP state over a run |
//! | 6 | [`mapping`], [`tracking`] | local mapping; the tracker |
//! | 7 | [`global`], [`dense`], [`records`], [`view`] | the global and dense passes; the files a run writes, typed; the Rerun recording |
//! | 8 | [`config`] | the typed TOML config, ORB-SLAM2 settings applied |
//! | 9 | [`system`] | the online system: the map, the tracker and its helper workers |
//! | 10 | [`run`], [`synth`], [`demo`] | the spine of a run; the synthetic test bed; the demo |
//! | 11 | [`batch`] | batch runs (local, sharded, Slurm) |
//!
//! # Errors
//!
//! No `unwrap` in library code (clippy's `unwrap_used` is denied outside tests): what
//! comes from input returns a typed error that names the file or key and what is wrong
//! ([`io::IoError`], [`checks::BadValue`], [`config::ConfigError`], [`run::RunError`],
//! [`batch::BatchError`]); the remaining `expect`s state invariants (a poisoned lock, a
//! buffer sized just above).

#![cfg_attr(not(test), deny(clippy::unwrap_used))]
#![warn(missing_docs)]

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
pub mod records;
pub mod run;
pub mod synth;
pub mod system;
pub mod threads;
pub mod tracking;
pub mod view;
