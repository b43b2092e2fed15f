#!/usr/bin/env python3
"""How far a dense map's vertices lie from a synthetic sequence's true static scene.

    data/venv/bin/python tools/mesh_accuracy.py SEQ/static_scene.ply RUN/dense_mesh.ply [MORE.ply ...]

The accuracy half of `dopslam compare-maps --reference`, for scenes too large for it:
compare-maps also samples the whole reference surface to measure completion, which on
a street of hundreds of metres takes tens of minutes and gigabytes. Here each vertex's
exact distance to the nearest reference triangle is computed (numpy, in chunks). The
maps must lie in the reference's frame: a `dopslam synth` sequence's world is its first
camera, as a run's trajectory is, so a run's maps need no alignment (the run's drift
adds to the distances). Prints, per map: the median, mean and 90th percentile distance,
the share within 10 cm and beyond 30 cm (ghosts of movers count too).
"""
import sys

import numpy as np

PLY_TYPES = {"float": "<f4", "double": "<f8", "uchar": "u1", "uint8": "u1", "int": "<i4",
             "uint": "<u4", "short": "<i2", "ushort": "<u2"}


def read_header(f):
    header = []
    while True:
        line = f.readline().decode().strip()
        header.append(line)
        if line == "end_header":
            return header


def count(header, element):
    return int(next(h for h in header if h.startswith(f"element {element}")).split()[2])


def read_ply(path):
    """Vertices (n x 3) and, for an ASCII mesh, its triangles (m x 3)."""
    with open(path, "rb") as f:
        header = read_header(f)
        vertices = count(header, "vertex")
        if "format ascii 1.0" in header:
            v = np.array([[float(x) for x in f.readline().split()[:3]] for _ in range(vertices)])
            faces = [f.readline().split()[1:4] for _ in range(count(header, "face"))]
            return v, np.array(faces, dtype=int)
        properties, in_vertex = [], False
        for h in header:
            if h.startswith("element"):
                in_vertex = h.startswith("element vertex")
            elif h.startswith("property") and in_vertex:
                properties.append(h.split())
        dtype = np.dtype([(p[2], PLY_TYPES[p[1]]) for p in properties])
        a = np.frombuffer(f.read(vertices * dtype.itemsize), dtype=dtype)
        return np.stack([a["x"], a["y"], a["z"]], 1).astype(np.float64), None


def segment_distance(p, a, b):
    ab = b - a
    t = ((p[:, None, :] - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12)
    closest = a + np.clip(t, 0, 1)[..., None] * ab
    return np.linalg.norm(p[:, None, :] - closest, axis=-1)


def distances(points, a, b, c, chunk=4000):
    """Each point's distance to the nearest triangle (a[i], b[i], c[i])."""
    n = np.cross(b - a, c - a)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    out = []
    for i in range(0, len(points), chunk):
        p = points[i:i + chunk]
        height = ((p[:, None, :] - a) * n).sum(-1)
        foot = p[:, None, :] - height[..., None] * n
        side = lambda u, v: (np.cross(v - u, foot - u) * n).sum(-1) >= 0
        inside = side(a, b) & side(b, c) & side(c, a)
        edges = np.minimum(np.minimum(segment_distance(p, a, b), segment_distance(p, b, c)),
                           segment_distance(p, c, a))
        out.append(np.where(inside, np.abs(height), edges).min(1))
    return np.concatenate(out)


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    reference, faces = read_ply(sys.argv[1])
    if faces is None:
        sys.exit(f"{sys.argv[1]}: not an ASCII mesh (dopslam synth's static_scene.ply is one)")
    a, b, c = (reference[faces[:, k]] for k in range(3))
    for path in sys.argv[2:]:
        d = distances(read_ply(path)[0], a, b, c)
        print(f"{path}: {len(d)} vertices; distance to the true scene median "
              f"{np.median(d) * 100:.1f} cm, mean {d.mean() * 100:.1f} cm, 90th percentile "
              f"{np.percentile(d, 90) * 100:.1f} cm; within 10 cm {100 * (d <= 0.1).mean():.1f} %, "
              f"beyond 30 cm {100 * (d > 0.3).mean():.2f} %")


if __name__ == "__main__":
    main()
