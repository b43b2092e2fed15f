#!/usr/bin/env bash
# Quick start, step 2: runs the whole test suite. Installs what the tests need first
# (the same idempotent steps as tools/setup.sh, without the demo).
set -euo pipefail
cd "$(dirname "$0")/.."
command -v cargo >/dev/null 2>&1 || export PATH="$HOME/.cargo/bin:$PATH"
if ! command -v cargo >/dev/null 2>&1; then
    bash tools/setup.sh --no-demo
fi
source tools/system_packages.sh
cargo test --release "${CARGO_FEATURES[@]}"
