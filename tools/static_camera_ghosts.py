#!/usr/bin/env python3
"""Ghosts of movers in a dense map made from a static camera (issue 80's real-people
goal; `../shared/data/real/ist/confusao`): the camera stands still, so the far end of
each pixel's depths over the sequence is the static background, and a map vertex
clearly in front of it (more than MARGIN metres in front of the nearest background in
a WINDOW x WINDOW pixel window, so that a static object's edge, whose vertex may
project a pixel off onto the wall behind it, does not count) stands where a mover
stood. Also the share of the background's pixels the map covers (a vertex within
MARGIN of the background at that pixel), and the share of the background within
MAX_DEPTH (the dense pass's range) the mesh's surface covers: its triangles sampled
finely enough that every pixel they cover is reached (a 1 cm mesh's vertices alone
leave gaps between them beyond about 2 m, where a pixel is smaller than a voxel).

The far end of a pixel's depths also catches a static surface's noise and mixed pixels
(an edge that flickers between a desk and the wall behind it). So each vertex in front
is also checked against its pixel's depths: `in_front_rare` counts those seen at their
own depth (within MARGIN / 2) in under half of the frames with depth there, which is
what a mover's ghost is; a surface seen there in most frames is static.

`--percentile P` takes the P-th percentile of each pixel's depths as its background
instead of the far end (100, the default). A thin static object (a chair's leg, a
desk's edge) flickers to the floor or the wall behind it in a few frames, so the far
end puts it in front of its own background; the 95th percentile ignores the farthest
5 % of a pixel's depths and still sees the background wherever the movers leave it
free in more than 5 % of the frames (docs/design.md, "The real people's measure").

    data/venv/bin/python tools/static_camera_ghosts.py SEQUENCE RUN_DIR [MESH.ply ...]
        [--settings S.yaml] [--margin 0.15] [--window 5] [--percentile 100]
        [--max-depth 4.0] [--json]

SEQUENCE: a TUM-layout folder (depth.txt, depth PNGs at 5000 per metre unless the
settings' DepthMapFactor says otherwise); RUN_DIR: a run on it (its trajectory's first
pose is the camera's, the world frame); the meshes (default RUN_DIR/dense_mesh.ply)
are binary PLY files as dopslam writes them. The camera's fx, fy, cx, cy come from
--settings (an ORB-SLAM2 settings file). Needs numpy and Pillow (data/venv:
`data/venv/bin/pip install pillow`).
"""
import argparse
import json
import os
import re
import struct
import sys
import warnings

try:
    import numpy as np
    from PIL import Image
except ImportError as e:
    sys.exit(f"static_camera_ghosts.py needs numpy and Pillow ({e}): data/venv/bin/pip install pillow")


def settings(path):
    text = open(path).read()
    value = lambda key, default=None: float(re.search(rf"^{key}:\s*([-0-9.eE+]+)", text, re.M).group(1)) \
        if re.search(rf"^{key}:", text, re.M) else default
    return (value("Camera.fx"), value("Camera.fy"), value("Camera.cx"), value("Camera.cy"),
            value("DepthMapFactor", 5000.0))


def tum_list(path):
    """(timestamp, file) of each line of a TUM list (rgb.txt, depth.txt)."""
    if not os.path.isfile(path):
        sys.exit(f"{path}: missing (a TUM-layout sequence has rgb.txt and depth.txt)")
    rows = [line.split() for line in open(path) if line.strip() and not line.startswith("#")]
    return [(float(r[0]), r[1]) for r in rows]


def depths(sequence, factor):
    return np.stack([np.asarray(Image.open(os.path.join(sequence, name)), dtype=np.float32) / factor
                     for _, name in tum_list(os.path.join(sequence, "depth.txt"))])


def read_ply_vertices(path):
    with open(path, "rb") as f:
        header = b""
        while not header.endswith(b"end_header\n"):
            header += f.readline()
        text = header.decode("ascii")
        count = int(re.search(r"element vertex (\d+)", text).group(1))
        props = re.findall(r"property (\w+) (\w+)\n", text.split("element vertex")[1].split("element")[0])
        sizes = {"float": 4, "uchar": 1, "double": 8, "int": 4}
        stride = sum(sizes[t] for t, _ in props)
        data = np.frombuffer(f.read(count * stride), dtype=np.uint8).reshape(count, stride)
        xyz = np.frombuffer(data[:, :12].tobytes(), dtype="<f4").reshape(count, 3)
        faces = np.zeros((0, 3), dtype=np.int64)
        found = re.search(r"element face (\d+)\nproperty list uchar int", text)
        if found:
            n = int(found.group(1))
            rows = np.frombuffer(f.read(n * 13), dtype=np.uint8).reshape(n, 13)
            if not (rows[:, 0] == 3).all():
                raise SystemExit(f"{path}: a face that is not a triangle")
            faces = np.frombuffer(rows[:, 1:].tobytes(), dtype="<i4").reshape(n, 3).astype(np.int64)
    return xyz.astype(np.float64), faces


def first_pose(run_dir):
    for line in open(os.path.join(run_dir, "trajectory.txt")):
        if line.strip() and not line.startswith("#"):
            v = [float(x) for x in line.split()]
            tx, ty, tz, qx, qy, qz, qw = v[1:8]
            r = np.array([
                [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
                [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
                [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)],
            ])
            return r, np.array([tx, ty, tz])
    raise SystemExit(f"{run_dir}/trajectory.txt holds no pose")


def background(stack, percentile):
    """Each pixel's background: the `percentile`-th percentile of its depths (0: none)."""
    if percentile >= 100:
        return stack.max(axis=0)
    valid = np.where(stack > 0, stack, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # pixels that never had depth
        far = np.nanpercentile(valid, percentile, axis=0, method="higher")
    return np.nan_to_num(far).astype(stack.dtype)


def nearest_in_window(far, window):
    """Each pixel's nearest background in its window x window window (inf: none; pixels
    that never had depth are no background)."""
    h, w = far.shape
    k = window // 2
    padded = np.pad(np.where(far > 0, far, np.inf), k, mode="edge")
    return np.min([padded[dy:dy + h, dx:dx + w] for dy in range(window) for dx in range(window)], axis=0)


def project(points, camera, pose, shape):
    """Each point's depth, pixel (u, v) and whether it lies in the image."""
    fx, fy, cx, cy = camera
    r, t = pose
    p = (points - t) @ r  # world -> camera (camera_from_world = R^T (x - t))
    h, w = shape
    z = p[:, 2]
    ok = z > 0.05
    u = np.round(fx * p[:, 0] / np.where(ok, z, 1) + cx).astype(int)
    v = np.round(fy * p[:, 1] / np.where(ok, z, 1) + cy).astype(int)
    return z, u, v, ok & (u >= 0) & (u < w) & (v >= 0) & (v < h)


def surface_covered(mesh, camera, pose, far, margin, max_depth):
    """The share (%) of the pixels whose background lies within max_depth that the
    mesh's surface covers (within margin of the background there)."""
    vertices, faces = mesh
    covered = np.zeros(far.shape, dtype=bool)
    n = 5  # samples a triangle side: 2 mm apart on a 1 cm mesh
    weights = np.array([(i / n, j / n, 1 - (i + j) / n) for i in range(n + 1) for j in range(n + 1 - i)])
    for start in range(0, len(faces), 50000):
        corners = vertices[faces[start:start + 50000]]
        points = np.einsum("sj,kjc->ksc", weights, corners).reshape(-1, 3)
        z, u, v, inside = project(points, camera, pose, far.shape)
        z, u, v = z[inside], u[inside], v[inside]
        near = np.abs(z - far[v, u]) <= margin
        covered[v[near], u[near]] = True
    in_range = (far > 0) & (far <= max_depth)
    return 100.0 * (covered & in_range).sum() / max(in_range.sum(), 1)


def judge(mesh, stack, camera, pose, margin, window, percentile=100, max_depth=4.0):
    far = background(stack, percentile)
    h, w = far.shape
    z, u, v, inside = project(mesh[0], camera, pose, far.shape)
    nearest = nearest_in_window(far, window)
    bg = np.where(inside, nearest[np.clip(v, 0, h - 1), np.clip(u, 0, w - 1)], 0.0)
    valid = inside & np.isfinite(bg) & (bg > 0)
    ghost = valid & (z < bg - margin)
    covered = np.zeros_like(far, dtype=bool)
    near_bg = inside & (np.abs(z - far[np.clip(v, 0, h - 1), np.clip(u, 0, w - 1)]) <= margin)
    covered[v[near_bg], u[near_bg]] = True
    history = stack[:, v[ghost], u[ghost]]
    seen_there = (np.abs(history - z[ghost][None]) <= margin / 2).sum(axis=0)
    rare = int((seen_there < 0.5 * (history > 0).sum(axis=0)).sum())
    return dict(percentile=percentile, vertices=int(len(mesh[0])), judged=int(valid.sum()),
                in_front=int(ghost.sum()),
                in_front_percent=100.0 * ghost.sum() / max(valid.sum(), 1),
                in_front_rare=rare, in_front_rare_percent=100.0 * rare / max(valid.sum(), 1),
                background_covered_percent=100.0 * covered.sum() / max((far > 0).sum(), 1),
                surface_covered_percent=surface_covered(mesh, camera, pose, far, margin, max_depth))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sequence")
    parser.add_argument("run_dir")
    parser.add_argument("meshes", nargs="*")
    parser.add_argument("--settings", required=True)
    parser.add_argument("--margin", type=float, default=0.15)
    parser.add_argument("--window", type=int, default=5)
    parser.add_argument("--percentile", type=float, default=100.0,
                        help="each pixel's background: this percentile of its depths (100: the far end)")
    parser.add_argument("--max-depth", type=float, default=4.0,
                        help="the surface coverage counts the background within this range (the dense pass's max_depth)")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    if not 50.0 <= args.percentile <= 100.0:
        sys.exit(f"--percentile {args.percentile}: must lie within 50-100 (a mover may cover a pixel in up to half the frames)")
    fx, fy, cx, cy, factor = settings(args.settings)
    stack = depths(args.sequence, factor)
    pose = first_pose(args.run_dir)
    meshes = args.meshes or [os.path.join(args.run_dir, "dense_mesh.ply")]
    rows = {m: judge(read_ply_vertices(m), stack, (fx, fy, cx, cy), pose, args.margin, args.window,
                     args.percentile, args.max_depth)
            for m in meshes}
    if args.json:
        print(json.dumps(rows))
        return
    for m, r in rows.items():
        where = "far end" if args.percentile >= 100 else f"{args.percentile:g}th percentile"
        print(f"{m}: {r['in_front']} of {r['judged']} vertices ({r['in_front_percent']:.3f} %) more than "
              f"{args.margin} m in front of the background (each pixel's {where}) ({r['in_front_rare']}, {r['in_front_rare_percent']:.2f} %, "
              f"seen there in under half of the frames); the map covers "
              f"{r['background_covered_percent']:.1f} % of the background's pixels (vertices); its surface covers "
              f"{r['surface_covered_percent']:.1f} % of those within {args.max_depth} m")


if __name__ == "__main__":
    main()
