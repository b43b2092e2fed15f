#!/usr/bin/env python3
"""Writes a `dopslam synth` folder rendered with a 640x576 `[depth_camera]` as an Azure
Kinect recording, as `k4arecorder` lays it out: a Matroska file muxed by ffmpeg (Debian's)
with a `COLOR` track (BGRA, NV12, YUY2 or MJPEG) and a `DEPTH` track (16-bit big-endian millimetres,
in the depth camera's own geometry, NFOV unbinned), the device calibration as the
`calibration.json` attachment (each camera normalised to its whole sensor, as the
device stores it), and the `K4A_*` tags (`K4A_START_OFFSET_NS` puts the stamps on the
folder's clock).

ffmpeg writes raw video in Matroska's VFW mode but leaves the BITMAPINFOHEADER's
FOURCC at 0 (with a negative height for top-down rows); k4arecorder writes `BGRA` and
`b16g` there, so this script sets those 8 bytes of each raw track's codec private data
and nothing else. The tests (tests/recordings.rs) make their fixtures with it; dopslam
never runs it.

    write_kinect.py SEQ OUT.mkv [--colour bgra|mjpeg|nv12|yuy2] [--frames N]
"""
import argparse
import json
import struct
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

from write_recording import read_list, read_settings  # the folder's lists and settings, as there

DEPTH_SENSOR, DEPTH_CROP = 1024, (192, 180)  # NFOV unbinned: 640x576 of the 1024x1024 sensor


def camera(location, cal, binned, crop, sensor, translation):
    """A calibration.json camera: intrinsics normalised by the binned size, 0 at the
    first pixel's corner, in the SDK's parameter order."""
    cx = (cal['Camera.cx'] + 0.5 + crop[0]) / binned[0]
    cy = (cal['Camera.cy'] + 0.5 + crop[1]) / binned[1]
    fx, fy = cal['Camera.fx'] / binned[0], cal['Camera.fy'] / binned[1]
    k1, k2, p1, p2, k3 = (cal.get(f'Camera.{k}', 0.0) for k in ('k1', 'k2', 'p1', 'p2', 'k3'))
    return {
        'Intrinsics': {
            'ModelParameterCount': 14,
            'ModelParameters': [cx, cy, fx, fy, k1, k2, k3, 0.0, 0.0, 0.0, 0.0, 0.0, p2, p1],
            'ModelType': 'CALIBRATION_LensDistortionModelBrownConrady',
        },
        'Location': location,
        'MetricRadius': 1.7,
        'Purpose': 'CALIBRATION_CameraPurposeDepth' if 'D0' in location else 'CALIBRATION_CameraPurposePhotoVideo',
        'Rt': {'Rotation': [1, 0, 0, 0, 1, 0, 0, 0, 1], 'Translation': list(translation)},
        'SensorHeight': sensor[1],
        'SensorWidth': sensor[0],
    }


def set_fourccs(path, fourccs):
    """Sets the FOURCC (and a positive height) of each VFW track's BITMAPINFOHEADER, in
    track order: CodecPrivate (ID 0x63A2) of 40 bytes (size 0xA8)."""
    data = bytearray(path.read_bytes())
    at = 0
    for fourcc in fourccs:
        at = data.find(b'\x63\xa2\xa8\x28\x00\x00\x00', at)
        assert at >= 0, 'a VFW track without its BITMAPINFOHEADER'
        header = at + 3
        height = struct.unpack_from('<i', data, header + 8)[0]
        struct.pack_into('<i', data, header + 8, abs(height))
        data[header + 16:header + 20] = fourcc
        at = header + 40
    path.write_bytes(bytes(data))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('seq', type=Path)
    parser.add_argument('out', type=Path)
    parser.add_argument('--colour', choices=['bgra', 'mjpeg', 'nv12', 'yuy2'], default='bgra')
    parser.add_argument('--frames', type=int, default=0)
    args = parser.parse_args()
    colour_cal = read_settings(args.seq / 'calibration.yaml')
    depth_cal = read_settings(args.seq / 'depth_camera.yaml')
    (w, h) = int(colour_cal['Camera.width']), int(colour_cal['Camera.height'])
    (dw, dh) = int(depth_cal['Camera.width']), int(depth_cal['Camera.height'])
    assert (dw, dh) == (640, 576), 'the depth camera must be 640x576 (NFOV unbinned)'
    rows = read_list(args.seq / 'rgb.txt')
    if args.frames:
        rows = rows[:args.frames]
    stamps = [float(stamp) for stamp, _ in rows]
    fps = round((len(stamps) - 1) / (stamps[-1] - stamps[0])) if len(stamps) > 1 else 30
    # The depth camera is the device's frame; the colour camera sits at ColourFromDepth.
    offset = [depth_cal[f'ColourFromDepth.{a}'] for a in ('tx', 'ty', 'tz')]
    calibration = {'CalibrationInformation': {'Cameras': [
        camera('CALIBRATION_CameraLocationD0', depth_cal, (DEPTH_SENSOR, DEPTH_SENSOR), DEPTH_CROP,
               (DEPTH_SENSOR, DEPTH_SENSOR), (0.0, 0.0, 0.0)),
        camera('CALIBRATION_CameraLocationPV0', colour_cal, (w, w * 3 // 4), (0, (w * 3 // 4 - h) // 2),
               (4096, 3072), offset),
    ]}}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        with open(tmp / 'colour.raw', 'wb') as colour, open(tmp / 'depth.raw', 'wb') as depth:
            for _, path in rows:
                rgb = np.asarray(Image.open(args.seq / path).convert('RGB'))
                bgra = np.dstack([rgb[..., 2], rgb[..., 1], rgb[..., 0], np.full(rgb.shape[:2], 255, np.uint8)])
                colour.write(np.ascontiguousarray(bgra).tobytes())
                raw = np.asarray(Image.open(args.seq / 'depth_camera' / Path(path).name)).astype(np.float64)
                depth.write(np.round(raw / 5.0).astype('>u2').tobytes())  # 5000 per metre -> mm
        (tmp / 'calibration.json').write_text(json.dumps(calibration, indent=1))
        # Colour as k4arecorder stores each mode: raw BGRA, NV12 or YUY2 (ffmpeg's BT.601
        # limited range, as the device's), or JPEG.
        pix_fmt = {'bgra': 'bgra', 'mjpeg': 'yuvj444p', 'nv12': 'nv12', 'yuy2': 'yuyv422'}[args.colour]
        colour_codec = ['-c:v:0', 'mjpeg', '-q:v:0', '2'] if args.colour == 'mjpeg' else ['-c:v:0', 'rawvideo']
        mode = {'bgra': 'BGRA', 'mjpeg': 'MJPG', 'nv12': 'NV12', 'yuy2': 'YUY2'}[args.colour]
        command = [
            'ffmpeg', '-loglevel', 'error', '-y',
            '-f', 'rawvideo', '-pix_fmt', 'bgra', '-s', f'{w}x{h}', '-r', str(fps), '-i', str(tmp / 'colour.raw'),
            '-f', 'rawvideo', '-pix_fmt', 'gray16be', '-s', f'{dw}x{dh}', '-r', str(fps), '-i', str(tmp / 'depth.raw'),
            '-map', '0', '-map', '1', *colour_codec, '-c:v:1', 'rawvideo', '-allow_raw_vfw', '1',
            '-pix_fmt:v:0', pix_fmt,
            '-metadata:s:v:0', 'title=COLOR', '-metadata:s:v:0', f'K4A_COLOR_MODE={mode}_{h}P',
            '-metadata:s:v:1', 'title=DEPTH', '-metadata:s:v:1', 'K4A_DEPTH_MODE=NFOV_UNBINNED',
            '-attach', str(tmp / 'calibration.json'),
            '-metadata:s:t:0', 'mimetype=application/octet-stream',
            '-metadata:s:t:0', 'K4A_CALIBRATION_FILE=calibration.json',
            '-metadata', f'K4A_START_OFFSET_NS={round(stamps[0] * 1e9)}',
            '-metadata', 'title=Azure Kinect',
            str(args.out),
        ]
        subprocess.run(command, check=True)
    # ffmpeg stores NV12 and YUY2 as V_UNCOMPRESSED with their FOURCC already.
    raw_colour = [b'BGRA'] if args.colour == 'bgra' else []
    set_fourccs(args.out, raw_colour + [b'b16g'])
    print(f'wrote {len(rows)} frames to {args.out}', file=sys.stderr)


if __name__ == '__main__':
    main()
