#!/usr/bin/env python3
"""Reads a dopslam Rerun recording (.rrd) back with the Python `rerun-sdk` and prints
what it holds as JSON: the entity paths (temporal and static), the frames with a
camera pose, each frame's kept and removed keypoint counts, the events, and the
number of points of the static entities.

It goes through rerun-sdk's dataframe API (a local server holding the file as a
dataset), independently of dopslam's writer. Used by tests/rerun.rs:

    data/venv/bin/python tools/read_rerun.py RUN.rrd
"""

import json
import sys

import rerun as rr


# What a run logs per frame (the rest, trajectories and the dense map, is static).
TEMPORAL = ["/world/camera/**", "/world/map/**", "/world/keyframes", "/world/trajectory/tracking/**", "/events/**"]


def entity_of(column):
    """`/world/camera:Transform3D:translation` -> `world/camera`."""
    return column.split(":")[0].lstrip("/")


def counts(table, column):
    """Per frame index, the number of instances in `column` (its last row wins)."""
    out = {}
    if column not in table:
        return out
    for index, value in zip(table["frame"], table[column]):
        if value is not None:
            out[int(index)] = len(value)
    return out


def columns_of(frame):
    """A pyarrow table as {column: list of Python values} (None where null)."""
    return {name: frame.column(name).to_pylist() for name in frame.column_names}


def main():
    path = sys.argv[1]
    with rr.server.Server(host="127.0.0.1", datasets={"run": [path]}) as server:
        dataset = server.client().get_dataset("run")
        # The per-frame entities only: a static column (the dense mesh) would be
        # repeated on every row.
        # A recording with no frames (a merged map's: static entities only) has no
        # frame index.
        try:
            temporal = columns_of(dataset.filter_contents(TEMPORAL).reader(index="frame").to_arrow_table())
        except ValueError:
            temporal = {"frame": []}
        static = columns_of(dataset.reader(index=None).to_arrow_table())
    columns = [c for c in temporal if ":" in c]
    static_columns = [c for c in static if ":" in c and not c.startswith("property:")]
    poses = set()
    for column in columns:
        if entity_of(column) == "world/camera" and "Transform3D" in column:
            for index, value in zip(temporal["frame"], temporal[column]):
                if value is not None:
                    poses.add(int(index))
    events = []
    for column in columns:
        if entity_of(column).startswith("events") and column.endswith(":text"):
            for value in temporal[column]:
                if value is not None:
                    events.extend(str(v) for v in value)
    static_sizes = {}
    for column in static_columns:
        if column.endswith(":positions") or column.endswith(":vertex_positions") or column.endswith(":strips"):
            value = static[column][0] if static[column] else None
            if value is not None:
                static_sizes[entity_of(column)] = sum(len(v) for v in value) if column.endswith(":strips") else len(value)
    print(json.dumps({
        "version": rr.__version__,
        "entities": sorted({entity_of(c) for c in columns}),
        "static_entities": sorted({entity_of(c) for c in static_columns}),
        "pose_frames": sorted(poses),
        "kept": counts(temporal, "/world/camera/image/keypoints:Points2D:positions"),
        "removed": counts(temporal, "/world/camera/image/removed:Points2D:positions"),
        "images": len(counts(temporal, "/world/camera/image:EncodedImage:blob")),
        "events": events,
        "static_sizes": static_sizes,
    }))


if __name__ == "__main__":
    main()
