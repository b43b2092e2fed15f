#!/usr/bin/env bash
# RUSTC_WORKSPACE_WRAPPER of tools/test.sh: dopslam's own crates (never its
# dependencies) are compiled by clippy's driver, which runs clippy's lints while it
# compiles, with warnings as errors (as `cargo clippy --all-targets -- -D warnings`).
# So the test build lints the code, and no separate `cargo clippy` build of every
# dependency (metadata only, about 8 minutes on 2 cores) is needed. Cargo calls it as
# `clippy_rustc.sh RUSTC ARGS...`.
set -euo pipefail
exec "${CLIPPY_DRIVER:-clippy-driver}" "$@" -D warnings
