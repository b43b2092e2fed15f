#!/usr/bin/env python3
"""Dense-map benchmark: dopslam's TSDF against Open3D 0.20's VoxelBlockGrid (CPU) on
the same frames and poses, side by side.

    python3 tools/bench_dense.py SEQUENCE [--poses TRAJ] [--frames N] [--threads 2] [--plain]

By default dopslam fuses with its default settings, which do more than Open3D's
integration: space carving, a first pass that allocates every frame's blocks (so the
earlier frames carve too), an image margin. `--plain` turns those off, to compare the
integration itself like for like.

SEQUENCE is a TUM-layout folder (e.g. written by `dopslam synth`); the poses are its
groundtruth.txt unless --poses names a trajectory (TUM format). Both systems fuse
every frame at 1 cm voxels, 4 cm truncation, 4 m depth, no masks; the script prints
per-frame integration time (median, mean), meshing time, peak memory of each process,
the surface agreement (mean and 95th percentile distance from each mesh's vertices to
the other mesh's vertices, in voxels), and checks that Open3D reads every PLY/OBJ that
dopslam writes (vertex and face counts equal). Needs Open3D 0.20 (Debian:
libusb-1.0-0 libgomp1 libgl1): `data/venv/bin/pip install open3d==0.20.0`, then run
this script with data/venv/bin/python.
"""
import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time


def read_list(path):
    rows = []
    with open(path) as f:
        for line in f:
            if line.strip() and not line.startswith("#"):
                rows.append(line.split())
    return rows


def open3d_run(folder, poses, frames, args, out):
    """Runs Open3D in this process; returns timings and the mesh path."""
    import numpy as np
    import open3d as o3d
    import open3d.core as o3c

    calib = {}
    with open(os.path.join(folder, "calibration.yaml")) as f:
        for line in f:
            if ":" in line:
                k, v = line.split(":", 1)
                calib[k.strip()] = v.strip()
    fx, fy = float(calib["Camera.fx"]), float(calib["Camera.fy"])
    cx, cy = float(calib["Camera.cx"]), float(calib["Camera.cy"])
    depth_scale = float(calib.get("DepthMapFactor", 5000))
    device = o3c.Device("CPU:0")
    intrinsic = o3c.Tensor([[fx, 0, cx], [0, fy, cy], [0, 0, 1]], o3c.float64)
    vbg = o3d.t.geometry.VoxelBlockGrid(
        attr_names=("tsdf", "weight", "color"),
        attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
        attr_channels=((1), (1), (3)),
        voxel_size=args.voxel,
        block_resolution=8,
        block_count=100000,
        device=device,
    )
    times = []
    for stamp, rgb, depth in frames:
        pose = poses.get(stamp)
        if pose is None:
            continue
        t, q = pose[:3], pose[3:]
        x, y, z, w = q
        rotation = np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
            ]
        )
        world_from_camera = np.eye(4)
        world_from_camera[:3, :3] = rotation
        world_from_camera[:3, 3] = t
        extrinsic = o3c.Tensor(np.linalg.inv(world_from_camera), o3c.float64)
        d = o3d.t.io.read_image(os.path.join(folder, depth)).to(device)
        c = o3d.t.io.read_image(os.path.join(folder, rgb)).to(device)
        start = time.perf_counter()
        coords = vbg.compute_unique_block_coordinates(
            d, intrinsic, extrinsic, depth_scale, args.max_depth, args.truncation / args.voxel
        )
        vbg.integrate(
            coords, d, c, intrinsic, intrinsic, extrinsic, depth_scale, args.max_depth,
            args.truncation / args.voxel,
        )
        times.append((time.perf_counter() - start) * 1e3)
    start = time.perf_counter()
    mesh = vbg.extract_triangle_mesh().to_legacy()
    mesh_ms = (time.perf_counter() - start) * 1e3
    path = os.path.join(out, "open3d_mesh.ply")
    o3d.io.write_triangle_mesh(path, mesh)
    return times, mesh_ms, path


def median(values):
    s = sorted(values)
    return s[len(s) // 2] if s else float("nan")


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sequence")
    parser.add_argument("--poses", help="TUM trajectory (default: SEQUENCE/groundtruth.txt)")
    parser.add_argument("--frames", type=int, default=0, help="first N frames only (0: all)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--voxel", type=float, default=0.01)
    parser.add_argument("--truncation", type=float, default=0.04)
    parser.add_argument("--max-depth", type=float, default=4.0)
    parser.add_argument("--dopslam", default="target/release/dopslam")
    parser.add_argument("--out", default="outputs/bench_dense")
    parser.add_argument("--plain", action="store_true",
                        help="dopslam as Open3D integrates: no carving, no allocation pass, no image margin "
                             "(like for like; the default measures dopslam's default fusion)")
    parser.add_argument("--open3d-only", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    os.makedirs(args.out, exist_ok=True)
    folder = args.sequence
    poses_path = args.poses or os.path.join(folder, "groundtruth.txt")
    poses = {}
    for row in read_list(poses_path):
        poses[f"{float(row[0]):.6f}"] = [float(v) for v in row[1:8]]
    frames = [(f"{float(r[0]):.6f}", r[1], r[3]) for r in read_list(os.path.join(folder, "associations.txt"))]
    if args.frames:
        frames = frames[: args.frames]

    if args.open3d_only:
        times, mesh_ms, path = open3d_run(folder, poses, frames, args, args.out)
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        print(json.dumps({"times": times, "mesh_ms": mesh_ms, "mesh": path, "peak_mb": peak}))
        return

    env = dict(os.environ, OMP_NUM_THREADS=str(args.threads), RAYON_NUM_THREADS=str(args.threads))
    # Open3D in its own process (its peak memory apart from ours).
    o3d_out = subprocess.run(
        [sys.executable, __file__, folder, "--poses", poses_path, "--frames", str(args.frames),
         "--voxel", str(args.voxel), "--truncation", str(args.truncation),
         "--max-depth", str(args.max_depth), "--out", args.out, "--open3d-only"],
        env=env, check=True, capture_output=True, text=True,
    )
    o3d_result = json.loads(o3d_out.stdout.strip().splitlines()[-1])

    # dopslam: a run folder whose trajectory is these poses, fused by `dopslam fuse`.
    run = os.path.join(args.out, "dopslam_run")
    os.makedirs(run, exist_ok=True)
    chosen = {stamp for stamp, _, _ in frames}
    with open(os.path.join(run, "trajectory.txt"), "w") as f:
        for stamp in sorted(chosen):
            if stamp in poses:
                f.write(stamp + " " + " ".join(f"{v:.9f}" for v in poses[stamp]) + "\n")
    with open(os.path.join(run, "keyframes.txt"), "w") as f:
        for k, stamp in enumerate(sorted(chosen)):
            if stamp in poses and k % 10 == 0:
                f.write(stamp + " " + " ".join(f"{v:.9f}" for v in poses[stamp]) + "\n")
    with open(os.path.join(run, "report.json"), "w") as f:
        json.dump({"sequence_path": os.path.abspath(folder), "mode": "off"}, f)
    config = os.path.join(run, "dense.toml")
    with open(config, "w") as f:
        f.write(f"[dense]\nvoxel = {args.voxel}\ntruncation = {args.truncation}\nmax_depth = {args.max_depth}\n"
                "pictures = false\n")
        if args.plain:
            f.write("carve = false\nallocate_first = false\nimage_margin = 0\n")
    start = time.perf_counter()
    subprocess.run(
        ["/usr/bin/time", "-v", args.dopslam, "fuse", run, "--no-dop", "--config", config],
        env=env, check=True, capture_output=True, text=True,
    )
    ours = json.load(open(os.path.join(run, "dense.json")))
    timed = subprocess.run(
        ["/usr/bin/time", "-f", "%M", args.dopslam, "fuse", run, "--no-dop", "--config", config],
        env=env, check=True, capture_output=True, text=True,
    )
    our_peak = float(timed.stderr.strip().splitlines()[-1]) / 1024
    wall = time.perf_counter() - start

    import numpy as np
    import open3d as o3d

    ours_mesh = o3d.io.read_triangle_mesh(os.path.join(run, "dense_mesh.ply"))
    theirs = o3d.io.read_triangle_mesh(o3d_result["mesh"])
    a, b = np.asarray(ours_mesh.vertices), np.asarray(theirs.vertices)

    def distances(source, target):
        tree = o3d.geometry.KDTreeFlann(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(target)))
        step = max(1, len(source) // 50000)
        out = []
        for p in source[::step]:
            _, _, d2 = tree.search_knn_vector_3d(p, 1)
            out.append(np.sqrt(d2[0]))
        return np.array(out)

    ab, ba = distances(a, b), distances(b, a)
    print(f"frames: {len(o3d_result['times'])} ({folder}), voxel {args.voxel} m, truncation {args.truncation} m, "
          f"{args.threads} threads")
    print("| | dopslam | Open3D 0.20 VoxelBlockGrid (CPU) |")
    print("|---|---|---|")
    print(f"| integration per frame, median (ms) | {ours['median_integration_ms']:.1f} | {median(o3d_result['times']):.1f} |")
    print(f"| marching cubes (ms) | {ours['marching_cubes_ms']:.0f} | {o3d_result['mesh_ms']:.0f} |")
    print(f"| mesh vertices / triangles | {len(a)} / {len(ours_mesh.triangles)} | {len(b)} / {len(theirs.triangles)} |")
    print(f"| peak memory of the process (MB) | {our_peak:.0f} | {o3d_result['peak_mb']:.0f} |")
    print(f"surface agreement: dopslam -> Open3D mean {ab.mean() / args.voxel:.2f} voxels (p95 {np.percentile(ab, 95) / args.voxel:.2f}), "
          f"Open3D -> dopslam mean {ba.mean() / args.voxel:.2f} voxels (p95 {np.percentile(ba, 95) / args.voxel:.2f})")
    print(f"speed-up (median integration): {median(o3d_result['times']) / ours['median_integration_ms']:.2f}x")
    # Open3D reads what dopslam writes.
    ok = True
    for name in ["dense_mesh.ply", "dense_mesh.obj", "dense_points.ply"]:
        path = os.path.join(run, name)
        if not os.path.exists(path):
            continue
        if name == "dense_points.ply":
            pc = o3d.io.read_point_cloud(path)
            good = len(pc.points) == ours["cloud_points"] and pc.has_colors() and pc.has_normals()
            print(f"Open3D reads {name}: {len(pc.points)} points (dopslam wrote {ours['cloud_points']}), colours {pc.has_colors()}, normals {pc.has_normals()}")
        else:
            m = o3d.io.read_triangle_mesh(path)
            good = len(m.vertices) == ours["mesh_vertices"] and len(m.triangles) == ours["mesh_triangles"] and m.has_vertex_colors()
            print(f"Open3D reads {name}: {len(m.vertices)} vertices / {len(m.triangles)} triangles (dopslam wrote {ours['mesh_vertices']} / {ours['mesh_triangles']}), colours {m.has_vertex_colors()}")
        ok &= good
    print("all files read back equal" if ok else "MISMATCH in files read back")
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
