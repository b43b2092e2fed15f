#!/usr/bin/env python3
"""Writes a `dopslam synth` folder rendered with a `[depth_camera]` as a genuine
RealSense recording, with librealsense's own recorder (`pyrealsense2`:
`rs.recorder(path, rs.software_device())`), without a camera: the colour stream from
rgb/, the depth stream (Z16, 1 mm units) from depth_camera/ in the depth camera's own
geometry, both streams' intrinsics, and the depth-to-colour extrinsics.

librealsense 2.56 and later write a ROS 2 SQLite file (OUT must end in .db3); earlier
versions write a ROS 1 bag (run it with pyrealsense2 2.55 first on PYTHONPATH, OUT.bag),
as users' older recordings are. The tests (tests/recordings.rs) make their fixtures with
it; dopslam never runs it.

    write_realsense.py SEQ OUT.db3 [--frames N]
"""
import argparse
import sys
from pathlib import Path

import numpy as np
from PIL import Image

from write_recording import read_list, read_settings  # the folder's lists and settings, as there


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('seq', type=Path)
    parser.add_argument('out', type=Path)
    parser.add_argument('--frames', type=int, default=0)
    args = parser.parse_args()
    import pyrealsense2 as rs

    colour_cal, depth_cal = read_settings(args.seq / 'calibration.yaml'), read_settings(args.seq / 'depth_camera.yaml')

    def intrinsics(cal):
        i = rs.intrinsics()
        i.width, i.height = int(cal['Camera.width']), int(cal['Camera.height'])
        i.fx, i.fy, i.ppx, i.ppy = cal['Camera.fx'], cal['Camera.fy'], cal['Camera.cx'], cal['Camera.cy']
        i.model = rs.distortion.brown_conrady
        i.coeffs = [cal.get(f'Camera.{k}', 0.0) for k in ('k1', 'k2', 'p1', 'p2', 'k3')]
        return i

    def stream(kind, uid, fmt, bpp, intr):
        s = rs.video_stream()
        s.type, s.index, s.uid = kind, 0, uid
        s.width, s.height, s.fps, s.bpp, s.fmt = intr.width, intr.height, 30, bpp, fmt
        s.intrinsics = intr
        return s

    device = rs.software_device()
    depth_sensor, colour_sensor = device.add_sensor('Depth'), device.add_sensor('Color')
    depth_intr, colour_intr = intrinsics(depth_cal), intrinsics(colour_cal)
    depth_profile = depth_sensor.add_video_stream(stream(rs.stream.depth, 0, rs.format.z16, 2, depth_intr))
    colour_profile = colour_sensor.add_video_stream(stream(rs.stream.color, 1, rs.format.rgb8, 3, colour_intr))
    extrinsics = rs.extrinsics()  # colour_from_depth: p_colour = R p_depth + t
    extrinsics.rotation = [1, 0, 0, 0, 1, 0, 0, 0, 1]
    extrinsics.translation = [depth_cal[f'ColourFromDepth.{a}'] for a in ('tx', 'ty', 'tz')]
    depth_profile.register_extrinsics_to(colour_profile, extrinsics)
    depth_sensor.add_read_only_option(rs.option.depth_units, 0.001)

    recorder = rs.recorder(str(args.out), device)
    depth_sensor.open(depth_profile)
    colour_sensor.open(colour_profile)
    queue = rs.frame_queue(100)
    depth_sensor.start(queue)
    colour_sensor.start(queue)
    rows = read_list(args.seq / 'rgb.txt')
    if args.frames:
        rows = rows[:args.frames]
    for number, (stamp, path) in enumerate(rows):
        name = Path(path).name
        raw = np.asarray(Image.open(args.seq / 'depth_camera' / name)).astype(np.float64)
        millimetres = np.round(raw / 5.0).astype(np.uint16)  # 5000 per metre -> 1 mm units
        rgb = np.asarray(Image.open(args.seq / path).convert('RGB'))
        for sensor, profile, image, bpp in ((depth_sensor, depth_profile, millimetres, 2),
                                            (colour_sensor, colour_profile, rgb, 3)):
            frame = rs.software_video_frame()
            frame.pixels = np.ascontiguousarray(image).tobytes()
            frame.stride, frame.bpp = image.shape[1] * bpp, bpp
            frame.timestamp = float(stamp) * 1000.0
            frame.domain = rs.timestamp_domain.system_time
            frame.frame_number = number
            frame.profile = profile.as_video_stream_profile()
            sensor.on_video_frame(frame)
    for sensor in (depth_sensor, colour_sensor):
        sensor.stop()
        sensor.close()
    del recorder
    print(f'wrote {len(rows)} frames to {args.out}', file=sys.stderr)


if __name__ == '__main__':
    main()
