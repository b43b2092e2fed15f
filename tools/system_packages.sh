#!/usr/bin/env bash
# The Debian packages dopslam needs, installed when missing (as root; idempotent), and
# the cargo features this machine can build (sourced: sets CARGO_FEATURES).
#
# A C toolchain and pkg-config for -sys crates; SQLite (ROS 2 bags' .db3) and zstd (their
# compression, Debian's library instead of a bundled build); python3 and pip fetch the ONNX Runtime
# wheel; DejaVu Sans labels the batch plots (PNG); OpenCV (libopencv-dev, with
# clang/libclang-dev for the opencv crate's bindings) gives the dense depth of stereo
# pairs (StereoSGBM). apt runs only when something is missing (about 1 min for OpenCV).
need_apt=()
for pkg in build-essential pkg-config python3 python3-pip python3-venv unzip curl ca-certificates fonts-dejavu-core libsqlite3-dev libzstd-dev libopencv-dev clang libclang-dev; do
    dpkg -s "$pkg" >/dev/null 2>&1 || need_apt+=("$pkg")
done
if [ ${#need_apt[@]} -gt 0 ]; then
    if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
        printf '\033[1m[setup]\033[0m installing %s\n' "${need_apt[*]}"
        { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need_apt[@]}" >/dev/null; } \
            || printf '\033[1m[setup]\033[0m warning: apt-get could not install %s\n' "${need_apt[*]}"
    else
        printf '\033[1m[setup]\033[0m warning: missing Debian packages %s (run as root on Debian to install them)\n' "${need_apt[*]}"
    fi
fi
# Without OpenCV, build without the opencv feature: stereo still tracks, but its dense
# map is refused with a message saying what to install.
CARGO_FEATURES=()
if ! pkg-config --exists opencv4 2>/dev/null || ! command -v clang >/dev/null 2>&1; then
    printf '\033[1m[setup]\033[0m warning: OpenCV (libopencv-dev) or clang not found: building without the opencv feature (no dense map for stereo)\n'
    CARGO_FEATURES=(--no-default-features --features rerun)
fi
