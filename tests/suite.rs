//! The integration tests, one binary: each file beside this one is a module of it.
//!
//! One binary instead of one per file: cargo compiles and links the test code once
//! (24 binaries each linked the whole library, about 100 s of a clean build), and the
//! slow tests of different files share the two test threads instead of each file
//! waiting for its own slowest test. `cargo test --release --test suite dop::` runs
//! one file's tests; `cargo test --release --test suite NAME` one test.

mod common;

mod bad_input;
mod batch;
mod calibration;
mod cli;
mod dense;
mod design_signatures;
mod detect;
mod dop;
mod evo_equivalence;
mod global;
mod hostile;
mod layers;
mod layouts;
mod real_kitti;
mod recordings;
mod rerun;
mod sessions;
mod stereo;
mod synth;
mod synth_features;
mod synth_movers;
mod tracking;
mod tum_timing;
