#!/usr/bin/env bash
# Runs every fuzz target of tools/fuzz for SECONDS each (default 600), one after the
# other, on a nightly toolchain with cargo-fuzz (installed here when missing). The
# seeds in tools/fuzz/corpus/TARGET are read; new inputs go to outputs/fuzz/TARGET
# (git-ignored). A crash stops the script with libFuzzer's report and the input under
# tools/fuzz/artifacts/TARGET/: add it to tests/bad_input.rs as a regression test.
#
# No single allocation may exceed 1100 MB (-malloc_limit_mb: a chunk may announce
# up to 1 GiB decompressed, see docs/recordings.md); one larger is a crash, as a panic is.
# The container readers (ros1_bag, mcap, ros2_sqlite, matroska) read inputs up to
# 256 KiB; their seeds come from tools/fuzz/make_recording_seeds.py. A minute each:
#
#   bash tools/fuzz.sh 60 ros1_bag mcap ros2_sqlite matroska
#
#   bash tools/fuzz.sh [SECONDS] [TARGET...]
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-600}
shift || true
command -v cargo >/dev/null 2>&1 || export PATH="$HOME/.cargo/bin:$PATH"
rustup toolchain list | grep -q nightly || rustup toolchain install nightly --profile minimal
command -v cargo-fuzz >/dev/null 2>&1 || cargo install cargo-fuzz
targets=("$@")
if [ ${#targets[@]} -eq 0 ]; then
    mapfile -t targets < <(cargo +nightly fuzz list --fuzz-dir tools/fuzz)
fi
# Build every target once, then run the binaries: editing the sources meanwhile does
# not trigger a sanitizer rebuild before each target.
cargo +nightly fuzz build --fuzz-dir tools/fuzz 2>&1 | tail -n 2
bin=tools/fuzz/target/$(rustc -vV | sed -n 's/^host: //p')/release
for target in "${targets[@]}"; do
    echo "== $target: ${seconds} s"
    mkdir -p "outputs/fuzz/$target" "tools/fuzz/artifacts/$target"
    case "$target" in
        ros1_bag|mcap|ros2_sqlite|matroska) max_len=262144 ;;
        *) max_len=65536 ;;
    esac
    "$bin/$target" "outputs/fuzz/$target" "tools/fuzz/corpus/$target" \
        -max_total_time="$seconds" -rss_limit_mb=2048 -malloc_limit_mb=1100 -max_len=$max_len \
        -artifact_prefix="tools/fuzz/artifacts/$target/" 2>&1 | tail -n 3
done
