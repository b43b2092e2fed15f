#!/usr/bin/env bash
# Quick start, step 2: runs the whole test suite (cargo's tests, then the batch on a
# real Slurm: tools/test_slurm.sh). Installs what the tests need first
# (the same idempotent steps as tools/setup.sh, without the demo).
set -euo pipefail
cd "$(dirname "$0")/.."
# Always the idempotent set-up: a machine with Rust but without the Debian packages,
# ONNX Runtime or the detector gets them too (it skips what is there). It builds
# nothing: `cargo test` below builds the binary the tests run, and a `cargo build`
# before it would compile about 60 crates twice (the dev-dependencies turn on features
# of crates the Rerun SDK shares, so the test build cannot reuse the plain one's).
bash tools/setup.sh --no-demo --no-build
command -v cargo >/dev/null 2>&1 || export PATH="$HOME/.cargo/bin:$PATH"
source tools/system_packages.sh
# The tests write their synthetic sequences under one temporary folder of this run,
# removed when the run ends, however it ends (each test also removes its own).
TMPDIR=$(mktemp -d "${TMPDIR:-/tmp}/dopslam-tests.XXXXXX")
export TMPDIR
trap 'rm -rf "$TMPDIR"' EXIT
# The independent writers the recording tests use (tests/recordings.rs: the Python
# rosbags package writes ROS 1 and ROS 2 bags, pyrealsense2 RealSense recordings), in the
# venv setup.sh made, and Debian's ffmpeg Azure Kinect recordings; with them installed,
# a test that cannot find them fails instead of skipping. pyrealsense2's wheel links
# libusb-1.0 (Debian libusb-1.0-0), a need of the tests only. rerun-sdk (with its
# dataframe API) reads the runs' Rerun recordings back (tests/rerun.rs): the same version
# as the `rerun` crate (Cargo.toml). ffmpeg's libraries come with OpenCV's packages
# already. Slurm and munge for tools/test_slurm.sh. They download while cargo compiles
# (below): the build needs none of them, and they wait on the network, it on the CPU.
install_test_tools() {
    local test_apt=()
    local pkg
    local packages=(libusb-1.0-0 ffmpeg)
    [ "${DOPSLAM_SKIP_SLURM:-0}" = 1 ] || packages+=(slurm-wlm munge)
    for pkg in "${packages[@]}"; do
        dpkg -s "$pkg" >/dev/null 2>&1 || test_apt+=("$pkg")
    done
    if [ ${#test_apt[@]} -gt 0 ] && [ "$(id -u)" = 0 ]; then
        apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${test_apt[@]}" >/dev/null
    fi
    { [ -x data/venv/bin/python ] || python3 -m venv data/venv; }
    data/venv/bin/pip install -q "rosbags==0.11.*" "pyrealsense2==2.59.*" "rerun-sdk[datafusion]==0.36.3" pillow numpy
    # librealsense before 2.56 wrote ROS 1 bags: its Python package beside the venv's,
    # for the test that reads such a recording.
    [ -d data/pyrealsense2-2.55/pyrealsense2 ] \
        || data/venv/bin/pip install -q --target data/pyrealsense2-2.55 "pyrealsense2==2.55.1.6486"
}
install_test_tools >"$TMPDIR/test-tools.log" 2>&1 &
test_tools=$!
export DOPSLAM_REQUIRE_RECORDING_WRITERS=1
free_mib=$(df -Pm "$TMPDIR" | awk 'NR == 2 { print $4 }')
if [ "${free_mib:-0}" -lt 2048 ]; then
  echo "warning: ${free_mib} MiB free under $TMPDIR; the tests write up to about 0.5 GiB there at a time" >&2
fi
# The code's shape first (seconds): rustfmt, the structure bars of tools/spine_bar.py.
for component in rustfmt clippy; do
  tool=${component/rustfmt/fmt}
  cargo "$tool" --version >/dev/null 2>&1 || rustup component add "$component" \
    || { echo "cargo $tool is missing and rustup could not add $component" >&2; exit 1; }
done
cargo fmt --check || { echo "the code is not rustfmt-clean: run cargo fmt" >&2; exit 1; }
python3 tools/spine_bar.py
# Clippy with warnings as errors (the library denies `unwrap`; see src/lib.rs), in the
# test build itself: dopslam's own crates go through clippy's driver
# (tools/clippy_rustc.sh), the dependencies are the release build's.
export RUSTC_WORKSPACE_WRAPPER="$PWD/tools/clippy_rustc.sh"
cargo test --release --all-targets --no-run "${CARGO_FEATURES[@]}"
wait "$test_tools" || { cat "$TMPDIR/test-tools.log" >&2; echo "installing the tests' tools failed (above)" >&2; exit 1; }
# The tests on real images (tests/real_kitti.rs, the IST recording, ...) skip without
# the shared data, quietly (cargo hides a passing test's output): say so here, so that a
# clone elsewhere is not taken for a full check (a fresh clone in /tmp once passed while
# the real KITTI 01 test failed beside the data).
shared_data=${DOPSLAM_SHARED_DATA:-$PWD/../shared/data}
if [ ! -f "$shared_data/README.md" ]; then
  echo "note: no shared data at $shared_data (set DOPSLAM_SHARED_DATA): the tests on real images skip and check nothing" >&2
fi
cargo test --release "${CARGO_FEATURES[@]}"
# The batch on a real one-node Slurm cluster (DOPSLAM_SKIP_SLURM=1 skips it, saying so).
bash tools/test_slurm.sh ./target/release/dopslam
