#!/usr/bin/env bash
# Quick start, step 2: runs the whole test suite (cargo's tests, then the batch on a
# real Slurm: tools/test_slurm.sh). Installs what the tests need first
# (the same idempotent steps as tools/setup.sh, without the demo).
set -euo pipefail
cd "$(dirname "$0")/.."
# Always the idempotent set-up: a machine with Rust but without the Debian packages,
# ONNX Runtime or the detector gets them too (it skips what is there).
bash tools/setup.sh --no-demo
command -v cargo >/dev/null 2>&1 || export PATH="$HOME/.cargo/bin:$PATH"
source tools/system_packages.sh
cargo test --release "${CARGO_FEATURES[@]}"
# The batch on a real one-node Slurm cluster (DOPSLAM_SKIP_SLURM=1 skips it, saying so).
bash tools/test_slurm.sh ./target/release/dopslam
