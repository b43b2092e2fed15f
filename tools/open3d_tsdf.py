#!/usr/bin/env python3
"""Integrate a TUM-layout RGB-D sequence (e.g. one written by `dopslam synth`) into an
Open3D TSDF volume with its ground-truth poses, and judge the mesh against the exact
static geometry (`static_scene.ply`) when the folder has one.

Checks that outside tools take synth output unchanged, and shows what moving people do
to a dense map: with `--mask-movers` the synth instance masks remove mover pixels first
(the clean map the DOP pipeline aims for); without it, the people leave ghosts.

    pip install open3d            # (Debian also needs libusb-1.0-0 libgl1 libgomp1)
    python3 tools/open3d_tsdf.py outputs/walking_xyz --out outputs/walking_xyz/tsdf.ply
    python3 tools/open3d_tsdf.py outputs/walking_xyz --mask-movers --out outputs/clean.ply

Prints the mesh size and, against static_scene.ply, the fraction of mesh vertices more
than --ghost-distance from any static surface (ghosts and noise) and their median error.
"""
import argparse
import os
import sys

import numpy as np


def read_pairs(folder):
    path = os.path.join(folder, "associations.txt")
    pairs = []
    with open(path) as f:
        for line in f:
            if line.strip() and not line.startswith("#"):
                t, rgb, _, depth = line.split()[:4]
                pairs.append((float(t), rgb, depth))
    return pairs


def read_groundtruth(folder):
    poses = {}
    with open(os.path.join(folder, "groundtruth.txt")) as f:
        for line in f:
            if line.strip() and not line.startswith("#"):
                v = [float(x) for x in line.split()]
                poses[round(v[0], 6)] = v[1:]
    return poses


def world_from_camera(v):
    tx, ty, tz, qx, qy, qz, qw = v
    r = np.array([
        [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
        [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
        [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)],
    ])
    m = np.eye(4)
    m[:3, :3] = r
    m[:3, 3] = [tx, ty, tz]
    return m


def read_intrinsics(folder):
    values = {}
    with open(os.path.join(folder, "calibration.yaml")) as f:
        for line in f:
            if ":" in line and line.strip().startswith("Camera."):
                key, value = line.split(":", 1)
                try:
                    values[key.strip()] = float(value.split("#")[0])
                except ValueError:
                    pass
    return values


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder")
    parser.add_argument("--out", help="mesh PLY to write")
    parser.add_argument("--voxel", type=float, default=0.02, help="voxel size (m)")
    parser.add_argument("--max-depth", type=float, default=4.0)
    parser.add_argument("--max-resolution", type=int, default=384)
    parser.add_argument("--every", type=int, default=1, help="use every n-th frame")
    parser.add_argument("--mask-movers", action="store_true",
                        help="drop mover pixels using the synth masks")
    parser.add_argument("--ghost-distance", type=float, default=0.05)
    args = parser.parse_args()
    try:
        import open3d as o3d
    except ImportError as e:
        sys.exit(f"open3d is not installed ({e}); pip install open3d")

    folder = args.folder
    c = read_intrinsics(folder)
    width, height = int(c.get("Camera.width", 640)), int(c.get("Camera.height", 480))
    intrinsic = o3d.camera.PinholeCameraIntrinsic(
        width, height, c["Camera.fx"], c["Camera.fy"], c["Camera.cx"], c["Camera.cy"])
    gt = read_groundtruth(folder)
    # A uniform volume around what the cameras can see (Open3D 0.20's scalable volume
    # extracted empty meshes here). Its side is capped at --max-resolution voxels.
    positions = np.array([v[:3] for v in gt.values()])
    lo = positions.min(axis=0) - args.max_depth
    hi = positions.max(axis=0) + args.max_depth
    reference = os.path.join(folder, "static_scene.ply")
    if os.path.exists(reference):
        room = np.asarray(o3d.io.read_triangle_mesh(reference).vertices)
        lo, hi = np.maximum(lo, room.min(axis=0) - 0.1), np.minimum(hi, room.max(axis=0) + 0.1)
    length = float((hi - lo).max())
    resolution = min(int(np.ceil(length / args.voxel)), args.max_resolution)
    print(f"volume: {length:.2f} m cube, {resolution}^3 voxels of {length / resolution * 100:.1f} cm")
    volume = o3d.pipelines.integration.UniformTSDFVolume(
        length=length, resolution=resolution, sdf_trunc=4 * length / resolution,
        color_type=o3d.pipelines.integration.TSDFVolumeColorType.RGB8, origin=lo)
    pairs = read_pairs(folder)[:: args.every]
    for i, (t, rgb_name, depth_name) in enumerate(pairs):
        color = o3d.io.read_image(os.path.join(folder, rgb_name))
        depth = np.asarray(o3d.io.read_image(os.path.join(folder, depth_name))).copy()
        if args.mask_movers:
            mask_path = os.path.join(folder, "masks", os.path.basename(rgb_name))
            mask = np.asarray(o3d.io.read_image(mask_path))
            depth[mask > 0] = 0
        rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
            color, o3d.geometry.Image(depth), depth_scale=5000.0,
            depth_trunc=args.max_depth, convert_rgb_to_intensity=False)
        # Open3D wants the extrinsic camera_from_world.
        extrinsic = np.linalg.inv(world_from_camera(gt[round(t, 6)]))
        volume.integrate(rgbd, intrinsic, extrinsic)
        if i % 100 == 0:
            print(f"integrated {i + 1}/{len(pairs)} frames", file=sys.stderr)
    mesh = volume.extract_triangle_mesh()
    print(f"mesh: {len(mesh.vertices)} vertices, {len(mesh.triangles)} triangles")
    if args.out:
        o3d.io.write_triangle_mesh(args.out, mesh)
        print(f"wrote {args.out}")
    if os.path.exists(reference) and len(mesh.vertices):
        scene_mesh = o3d.io.read_triangle_mesh(reference)
        raycast = o3d.t.geometry.RaycastingScene()
        raycast.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(scene_mesh))
        points = o3d.core.Tensor(np.asarray(mesh.vertices), dtype=o3d.core.Dtype.Float32)
        distance = raycast.compute_distance(points).numpy()
        far = distance > args.ghost_distance
        print(f"vertices within {args.ghost_distance} m of the static scene: "
              f"{100 * (1 - far.mean()):.2f} %; off it (ghosts, noise): {far.sum()} "
              f"({100 * far.mean():.2f} %); median distance {np.median(distance) * 1000:.1f} mm")


if __name__ == "__main__":
    main()
