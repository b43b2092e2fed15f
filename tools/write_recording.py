#!/usr/bin/env python3
"""Writes a TUM-layout RGB-D folder (e.g. `dopslam synth`'s) as a recording, with the
independent writers of the `rosbags` package: a ROS 1 bag (as TUM publishes its
sequences) or a ROS 2 bag (SQLite 3 or MCAP storage, CDR messages).

The tests and tools/bench_recordings.sh make their fixtures with it; dopslam itself
never runs it. Topics follow TUM's bags: /camera/rgb/image_color,
/camera/depth/image, /camera/rgb/camera_info, /camera/depth/camera_info.

    write_recording.py SEQ OUT.bag --format ros1 [--compression bz2|lz4]
    write_recording.py SEQ OUT_DIR --format ros2-sqlite|ros2-mcap
      [--rgb rgb8|bgr8|png|jpeg] [--depth 32FC1|16UC1|compressedDepth] [--frames N]
      [--repeat K]  (each frame written K times with new stamps: a large recording)
      [--shuffle]  (messages written out of stamp order)  [--no-depth]
      [--ground-truth]  (groundtruth.txt as PoseStamped on /ground_truth)
    write_recording.py SEQ OUT --format ... --stereo
      (the stereo pair of SEQ/kitti/sequences/00 as mono8 /stereo/left|right/image_rect
      with their camera_info, the right one's P holding -fx * baseline)
      [--corrupt-frame K]  (frame K's JPEG zeroed after its first 20 bytes)  [--rgb 8UC3]  (an encoding no
      reader takes for colour)

Depth: 32FC1 in metres (the folder's raw value times float32(1/5000), so a reader
that divides as dopslam does gets the same floats); 16UC1 and compressedDepth keep the
folder's raw values (5000 per metre: read them with [dataset] depth_scale = 5000).
"""
import argparse
import io
import sys
from pathlib import Path

import numpy as np
from PIL import Image


def read_list(path):
    rows = []
    for line in Path(path).read_text().splitlines():
        if line.strip() and not line.startswith('#'):
            stamp, name = line.split()[:2]
            rows.append((stamp, name))
    return rows


def read_settings(path):
    """The numeric keys of an ORB-SLAM2 settings file (`Camera.fx: 535.4`)."""
    values = {}
    for line in Path(path).read_text().splitlines():
        if ':' in line and not line.startswith('%'):
            key, value = line.split(':', 1)
            try:
                values[key.strip()] = float(value)
            except ValueError:
                pass
    return values


def split_stamp(text):
    sec, _, frac = text.partition('.')
    return int(sec), int((frac + '000000000')[:9])


def shuffled(events):
    """The events with each frame's four messages swapped with the next frame's."""
    out = []
    for start in range(0, len(events), 8):
        block = events[start:start + 8]
        out.extend(block[4:] + block[:4])
    return out


def stereo(args, header, RawImage, CameraInfo, Roi, ros1):
    """The messages of a synth folder's KITTI stereo pair: (stamp ns, topic, message)."""
    kitti = args.seq / 'kitti' / 'sequences' / '00'
    times = [float(t) for t in (kitti / 'times.txt').read_text().split()]
    if args.frames:
        times = times[:args.frames]
    calib = {line.split(':')[0]: [float(v) for v in line.split(':')[1].split()]
             for line in (kitti / 'calib.txt').read_text().splitlines() if ':' in line}
    first = Image.open(kitti / 'image_0' / '000000.png')
    width, height = first.size

    def info(stamp_ns, p):
        matrices = dict(d=np.zeros(5), k=np.array([p[0], 0, p[2], 0, p[5], p[6], 0, 0, 1.0]),
                        r=np.eye(3).flatten(), p=np.array(p))
        if ros1:
            matrices = {k.upper(): v for k, v in matrices.items()}
        return CameraInfo(header=header(stamp_ns, 'camera'), height=height, width=width,
                          distortion_model='plumb_bob', binning_x=0, binning_y=0,
                          roi=Roi(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False), **matrices)

    events = []
    for index, t in enumerate(times):
        ns = int(round(t * 1e9))
        for side, folder, p in (('left', 'image_0', calib['P0']), ('right', 'image_1', calib['P1'])):
            grey = np.asarray(Image.open(kitti / folder / f'{index:06d}.png').convert('L'))
            events.append((ns, f'/stereo/{side}/image_rect', RawImage(
                header=header(ns, side), height=height, width=width, encoding='mono8', is_bigendian=0,
                step=width, data=np.ascontiguousarray(grey).reshape(-1))))
            events.append((ns, f'/stereo/{side}/camera_info', info(ns, p)))
    topics = [('/stereo/left/image_rect', 'sensor_msgs/msg/Image'), ('/stereo/right/image_rect', 'sensor_msgs/msg/Image'),
              ('/stereo/left/camera_info', 'sensor_msgs/msg/CameraInfo'),
              ('/stereo/right/camera_info', 'sensor_msgs/msg/CameraInfo')]
    return events, topics


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('seq', type=Path)
    parser.add_argument('out', type=Path)
    parser.add_argument('--format', choices=['ros1', 'ros2-sqlite', 'ros2-mcap'], required=True)
    parser.add_argument('--compression', choices=['none', 'bz2', 'lz4', 'zstd-file', 'zstd-message'], default='none',
                        help='bz2, lz4: ROS 1 chunks; zstd-file, zstd-message: rosbag2 compression modes')
    parser.add_argument('--split', type=int, default=1,
                        help='ROS 2 SQLite: split the bag into N files, as rosbag2 --max-bag-size does')
    parser.add_argument('--rgb', choices=['rgb8', 'bgr8', 'png', 'jpeg', '8UC3'], default='rgb8')
    parser.add_argument('--depth', choices=['32FC1', '16UC1', 'compressedDepth'], default='32FC1')
    parser.add_argument('--frames', type=int, default=0)
    parser.add_argument('--repeat', type=int, default=1)
    parser.add_argument('--shuffle', action='store_true')
    parser.add_argument('--no-depth', action='store_true')
    parser.add_argument('--corrupt-frame', type=int, default=-1)
    parser.add_argument('--stereo', action='store_true')
    parser.add_argument('--ground-truth', action='store_true',
                        help='also groundtruth.txt as geometry_msgs/PoseStamped on /ground_truth')
    args = parser.parse_args()

    from rosbags.typesys import Stores, get_typestore
    ros1 = args.format == 'ros1'
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    T = store.types
    Header, Time = T['std_msgs/msg/Header'], T['builtin_interfaces/msg/Time']
    RawImage, Compressed = T['sensor_msgs/msg/Image'], T['sensor_msgs/msg/CompressedImage']
    CameraInfo, Roi = T['sensor_msgs/msg/CameraInfo'], T['sensor_msgs/msg/RegionOfInterest']

    seq = args.seq
    cal = read_settings(seq / 'calibration.yaml')
    width, height = int(cal['Camera.width']), int(cal['Camera.height'])
    rgb_rows, depth_rows = read_list(seq / 'rgb.txt'), read_list(seq / 'depth.txt')
    if args.frames:
        rgb_rows, depth_rows = rgb_rows[:args.frames], depth_rows[:args.frames]
    period = 1.0 / cal.get('Camera.fps', 30.0)
    span_ns = int(round((len(rgb_rows) * period) * 1e9))

    def header(stamp_ns, frame):
        sec, nsec = divmod(stamp_ns, 1_000_000_000)
        kwargs = dict(stamp=Time(sec=sec, nanosec=nsec), frame_id=frame)
        if ros1:
            kwargs['seq'] = 0
        return Header(**kwargs)

    def info(stamp_ns, frame):
        fx, fy, cx, cy = (cal[f'Camera.{k}'] for k in ('fx', 'fy', 'cx', 'cy'))
        d = np.array([cal.get(f'Camera.{k}', 0.0) for k in ('k1', 'k2', 'p1', 'p2', 'k3')])
        matrices = dict(d=d, k=np.array([fx, 0, cx, 0, fy, cy, 0, 0, 1.0]), r=np.eye(3).flatten(),
                        p=np.array([fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1.0, 0]))
        if ros1:  # ROS 1 spells them D, K, R, P
            matrices = {k.upper(): v for k, v in matrices.items()}
        return CameraInfo(
            header=header(stamp_ns, frame), height=height, width=width, distortion_model='plumb_bob',
            binning_x=0, binning_y=0, roi=Roi(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
            **matrices)

    def colour(stamp_ns, path, index):
        rgb = np.asarray(Image.open(seq / path).convert('RGB'))
        if args.rgb in ('png', 'jpeg'):
            buf = io.BytesIO()
            Image.fromarray(rgb).save(buf, format=args.rgb.upper(), quality=95)
            data = buf.getvalue()
            if index == args.corrupt_frame:
                data = data[:20] + bytes(len(data) - 20)  # the header kept, the rest zeros
            return COMPRESSED, Compressed(header=header(stamp_ns, 'rgb'), format=args.rgb,
                                          data=np.frombuffer(data, np.uint8))
        if args.rgb == 'bgr8':
            rgb = rgb[:, :, ::-1]
        # '8UC3' writes the same bytes under an encoding that names no colour order.
        return IMAGE, RawImage(header=header(stamp_ns, 'rgb'), height=height, width=width, encoding=args.rgb,
                               is_bigendian=0, step=width * 3, data=np.ascontiguousarray(rgb).reshape(-1))

    def depth(stamp_ns, path):
        raw = np.asarray(Image.open(seq / path)).astype(np.uint16)
        if args.depth == 'compressedDepth':
            buf = io.BytesIO()
            Image.fromarray(raw).save(buf, format='PNG')
            config = np.array([0], '<i4').tobytes() + np.array([0.0, 0.0], '<f4').tobytes()
            return COMPRESSED, Compressed(header=header(stamp_ns, 'depth'), format='16UC1; compressedDepth png',
                                          data=np.frombuffer(config + buf.getvalue(), np.uint8))
        if args.depth == '16UC1':
            data = raw.astype('<u2')
            step = width * 2
        else:
            metres = raw.astype(np.float32) * np.float32(1.0 / 5000.0)
            metres[raw == 0] = np.nan
            data = metres.astype('<f4')
            step = width * 4
        return IMAGE, RawImage(header=header(stamp_ns, 'depth'), height=height, width=width, encoding=args.depth,
                               is_bigendian=0, step=step, data=np.frombuffer(data.tobytes(), np.uint8))

    IMAGE, COMPRESSED = 'sensor_msgs/msg/Image', 'sensor_msgs/msg/CompressedImage'
    kinds = {'rgb': COMPRESSED if args.rgb in ('png', 'jpeg') else IMAGE,
             'depth': COMPRESSED if args.depth == 'compressedDepth' else IMAGE}
    topics = [('/camera/rgb/image_color', kinds['rgb']), ('/camera/depth/image', kinds['depth']),
              ('/camera/rgb/camera_info', 'sensor_msgs/msg/CameraInfo'),
              ('/camera/depth/camera_info', 'sensor_msgs/msg/CameraInfo')]

    PoseStamped, Pose = T['geometry_msgs/msg/PoseStamped'], T['geometry_msgs/msg/Pose']
    Point, Quaternion = T['geometry_msgs/msg/Point'], T['geometry_msgs/msg/Quaternion']
    truth = []
    if args.ground_truth:
        topics.append(('/ground_truth', 'geometry_msgs/msg/PoseStamped'))
        for line in (seq / 'groundtruth.txt').read_text().splitlines():
            if line.strip() and not line.startswith('#'):
                stamp, *v = line.split()
                truth.append((stamp, [float(x) for x in v]))

    def pose(stamp_ns, v):
        return PoseStamped(header=header(stamp_ns, 'world'), pose=Pose(
            position=Point(x=v[0], y=v[1], z=v[2]), orientation=Quaternion(x=v[3], y=v[4], z=v[5], w=v[6])))

    if args.stereo:
        stereo_events, topics = stereo(args, header, RawImage, CameraInfo, Roi, ros1)

    if ros1:
        from rosbags.rosbag1 import Writer
        writer = Writer(args.out)
        if args.compression != 'none':
            writer.set_compression(getattr(Writer.CompressionFormat, args.compression.upper()))
        serialise = store.serialize_ros1
        add = lambda topic, kind: writer.add_connection(topic, kind, typestore=store)  # noqa: E731
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer
        plugin = StoragePlugin.MCAP if args.format == 'ros2-mcap' else StoragePlugin.SQLITE3
        writer = Writer(args.out, version=9, storage_plugin=plugin)
        if args.compression.startswith('zstd'):
            from rosbags.rosbag2.writer import CompressionFormat, CompressionMode
            mode = CompressionMode.FILE if args.compression == 'zstd-file' else CompressionMode.MESSAGE
            writer.set_compression(mode, CompressionFormat.ZSTD)
        serialise = store.serialize_cdr
        add = lambda topic, kind: writer.add_connection(topic, kind, typestore=store)  # noqa: E731

    written = 0
    with writer:
        conns = {topic: add(topic, kind) for topic, kind in topics}
        if args.stereo:
            for ns, topic, msg in stereo_events:
                writer.write(conns[topic], ns, serialise(msg, dict(topics)[topic]))
                written += 1
        for repeat in range(0 if args.stereo else args.repeat):
            shift = repeat * span_ns
            events = []
            for index, (stamp, path) in enumerate(rgb_rows):
                ns = sum(a * b for a, b in zip(split_stamp(stamp), (1_000_000_000, 1))) + shift
                events.append((ns, 0, '/camera/rgb/image_color', lambda ns=ns, p=path, i=index: colour(ns, p, i)))
                events.append((ns, 2, '/camera/rgb/camera_info', lambda ns=ns: (None, info(ns, 'rgb'))))
            for stamp, path in ([] if args.no_depth else depth_rows):
                ns = sum(a * b for a, b in zip(split_stamp(stamp), (1_000_000_000, 1))) + shift
                events.append((ns, 1, '/camera/depth/image', lambda ns=ns, p=path: depth(ns, p)))
                events.append((ns, 3, '/camera/depth/camera_info', lambda ns=ns: (None, info(ns, 'depth'))))
            for stamp, v in truth if repeat == 0 else []:
                ns = sum(a * b for a, b in zip(split_stamp(stamp), (1_000_000_000, 1)))
                events.append((ns, 4, '/ground_truth', lambda ns=ns, v=v: (None, pose(ns, v))))
            events.sort(key=lambda e: (e[0], e[1]))
            if args.shuffle:  # each frame's messages after the next frame's: stamps out of order
                events = shuffled(events)
            for ns, _, topic, make in events:
                _, msg = make()
                kind = dict(topics)[topic]
                writer.write(conns[topic], ns, serialise(msg, kind))
                written += 1
    if args.split > 1:
        split(args.out, args.split)
    print(f'wrote {written} messages to {args.out}', file=sys.stderr)


def split(bag, parts):
    """Splits a ROS 2 SQLite bag into `parts` files as rosbag2's size or duration
    splitting leaves them: each file with every topic and a run of the messages in time
    order, metadata.yaml listing the files in order."""
    import shutil
    import sqlite3
    from ruamel.yaml import YAML
    yaml = YAML()
    meta_path = bag / 'metadata.yaml'
    meta = yaml.load(meta_path.read_text())
    info = meta['rosbag2_bagfile_information']
    [whole] = info['relative_file_paths']
    with sqlite3.connect(bag / whole) as db:
        stamps = [row[0] for row in db.execute('SELECT timestamp FROM messages ORDER BY timestamp, id')]
    bounds = [stamps[len(stamps) * k // parts] for k in range(parts)] + [stamps[-1] + 1]
    names, files = [], []
    for k in range(parts):
        name = whole.replace('.db3', f'_{k}.db3')
        shutil.copy(bag / whole, bag / name)
        with sqlite3.connect(bag / name) as db:
            db.execute('DELETE FROM messages WHERE timestamp < ? OR timestamp >= ?', (bounds[k], bounds[k + 1]))
            count = db.execute('SELECT COUNT(*) FROM messages').fetchone()[0]
            first, last = db.execute('SELECT MIN(timestamp), MAX(timestamp) FROM messages').fetchone()
        db.close()
        with sqlite3.connect(bag / name) as db:
            db.execute('VACUUM')
        names.append(name)
        files.append({'path': name, 'starting_time': {'nanoseconds_since_epoch': first},
                      'duration': {'nanoseconds': last - first}, 'message_count': count})
    (bag / whole).unlink()
    info['relative_file_paths'] = names
    info['files'] = files
    with open(meta_path, 'w') as out:
        yaml.dump(meta, out)


if __name__ == '__main__':
    main()
