#!/usr/bin/env python3
"""Writes the seeds of the container readers' fuzz targets (tools/fuzz: ros1_bag, mcap,
ros2_sqlite, matroska) into tools/fuzz/corpus/TARGET/: a two-frame 32x24 TUM folder
written as a recording by tools/write_recording.py (the Python `rosbags` package, an
independent writer) in each compression its reader takes, and an Azure Kinect file by
tools/write_kinect.py (Debian's ffmpeg; skipped, saying so, without it). The seeds are
committed; run this again after a writer changes.

    python3 tools/fuzz/make_recording_seeds.py
"""
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

ROOT = Path(__file__).resolve().parents[2]
CORPUS = ROOT / 'tools/fuzz/corpus'
W, H = 32, 24


def tiny_folder(seq):
    """A TUM folder of two frames with a calibration."""
    (seq / 'rgb').mkdir(parents=True)
    (seq / 'depth').mkdir()
    rng = np.random.default_rng(7)
    rgb_lines, depth_lines = [], []
    for i in range(2):
        stamp = f'{1.0 + i / 30:.6f}'
        Image.fromarray(rng.integers(0, 255, (H, W, 3), np.uint8)).save(seq / f'rgb/{stamp}.png')
        Image.fromarray(rng.integers(4000, 9000, (H, W), np.uint16)).save(seq / f'depth/{stamp}.png')
        rgb_lines.append(f'{stamp} rgb/{stamp}.png')
        depth_lines.append(f'{stamp} depth/{stamp}.png')
    (seq / 'rgb.txt').write_text('\n'.join(rgb_lines) + '\n')
    (seq / 'depth.txt').write_text('\n'.join(depth_lines) + '\n')
    (seq / 'calibration.yaml').write_text(
        f'%YAML:1.0\nCamera.fx: 30.0\nCamera.fy: 30.0\nCamera.cx: 15.5\nCamera.cy: 11.5\n'
        f'Camera.width: {W}\nCamera.height: {H}\nCamera.fps: 30.0\nDepthMapFactor: 5000.0\n')


def kinect_seed(seq, out):
    """An Azure Kinect file of one frame (MJPG colour, the 640x576 depth camera), cut
    after its first 64 KiB: the EBML header, tracks, tags, calibration attachment and
    the first cluster's start (the frames past that add size, not structure)."""
    (seq / 'depth_camera').mkdir()
    for line in (seq / 'rgb.txt').read_text().split():
        if line.endswith('.png'):
            Image.fromarray(np.full((576, 640), 6000, np.uint16)).save(seq / 'depth_camera' / Path(line).name)
    (seq / 'depth_camera.yaml').write_text(
        '%YAML:1.0\nCamera.fx: 504.0\nCamera.fy: 504.0\nCamera.cx: 319.5\nCamera.cy: 287.5\n'
        'Camera.width: 640\nCamera.height: 576\nColourFromDepth.tx: 0.032\nColourFromDepth.ty: 0.0\n'
        'ColourFromDepth.tz: 0.0\n')
    whole = out.with_suffix('.whole.mkv')
    subprocess.run([sys.executable, str(ROOT / 'tools/write_kinect.py'), str(seq), str(whole), '--colour', 'mjpeg',
                    '--frames', '1'], check=True, capture_output=True)
    out.write_bytes(whole.read_bytes()[:65536])
    return out


def write(seq, out, *options):
    subprocess.run([sys.executable, str(ROOT / 'tools/write_recording.py'), str(seq), str(out), *options],
                   check=True, capture_output=True)


def storage_file(folder, suffix):
    return next(p for p in sorted(folder.iterdir()) if p.name.endswith(suffix))


def main():
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        seq = tmp / 'seq'
        tiny_folder(seq)
        seeds = {'ros1_bag': [], 'mcap': [], 'ros2_sqlite': []}
        for compression, rgb, depth in [('none', 'rgb8', '32FC1'), ('lz4', 'png', 'compressedDepth'),
                                        ('bz2', 'bgr8', '16UC1')]:
            out = tmp / f'{compression}.bag'
            write(seq, out, '--format', 'ros1', '--compression', compression, '--rgb', rgb, '--depth', depth)
            seeds['ros1_bag'].append(out)
        for compression in ['none', 'zstd-message']:
            out = tmp / f'mcap-{compression}'
            write(seq, out, '--format', 'ros2-mcap', '--compression', compression)
            seeds['mcap'].append(storage_file(out, '.mcap'))
        out = tmp / 'sqlite'
        write(seq, out, '--format', 'ros2-sqlite')
        seeds['ros2_sqlite'].append(storage_file(out, '.db3'))
        if shutil.which('ffmpeg'):
            seeds['matroska'] = [kinect_seed(seq, tmp / 'kinect.mkv')]
        else:
            print('matroska: no seed (ffmpeg is not installed)', file=sys.stderr)
        for target, files in seeds.items():
            folder = CORPUS / target
            folder.mkdir(parents=True, exist_ok=True)
            for k, path in enumerate(files):
                shutil.copy(path, folder / f'seed-{k}{path.suffix}')
            print(f'{target}: {len(files)} seeds, {sum(p.stat().st_size for p in files)} bytes', file=sys.stderr)


if __name__ == '__main__':
    main()
