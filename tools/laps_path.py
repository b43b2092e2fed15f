#!/usr/bin/env python3
"""Writes a KITTI pose file that drives a recorded path several times (for
tools/bench_memory.sh's `laps`: three laps of KITTI 00, 11 km).

Each lap is the recorded path, pose for pose. Between laps a joining drive, all of
it at 10 Hz with speeds that change smoothly: it brakes straight on from the lap's
end, makes a U-turn to the left, drives back to beside the lap's start in a parallel
lane, makes a second U-turn and speeds up into the lap's first pose at the lap's own
starting speed. So the camera never jumps and the laps are the same path (the same
places seen again: what a run has to keep bounded).

    python3 tools/laps_path.py KITTI_POSES OUT [--laps 3] [--radius 5]

Prints the number of frames written and the length of the whole drive.
"""

import argparse
import sys

import numpy as np

RAMP = 20  # frames to change speed
TURN_DEG_PER_FRAME = 2.5  # about KITTI 00's own turns


def read_poses(path):
    rows = np.loadtxt(path, ndmin=2)
    if rows.shape[1] != 12:
        sys.exit(f"{path}: expected 12 numbers a line (KITTI poses), found {rows.shape[1]}")
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :] = rows.reshape(-1, 3, 4)
    return poses


def axis_angle(axis, angle):
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def pose(rotation, position):
    out = np.eye(4)
    out[:3, :3] = rotation
    out[:3, 3] = position
    return out


def horizontal(vector, up):
    flat = vector - up * (vector @ up)
    return flat / np.linalg.norm(flat)


def speeds(frames, start, end):
    """Per-frame step lengths easing from start to end over `frames` frames."""
    k = (np.arange(frames) + 0.5) / frames
    return start + (end - start) * (3 * k**2 - 2 * k**3)


def straight(start, direction, steps, rotation):
    along = np.cumsum(steps)
    return [pose(rotation, start + direction * s) for s in along], start + direction * along[-1]


def u_turn(start, rotation, up, radius, step):
    """A left U-turn from `start` (camera `rotation`) at `step` metres a frame."""
    forward = horizontal(rotation[:, 2], up)
    left = np.cross(up, forward)
    centre = start + radius * left
    frames = int(np.ceil(np.pi * radius / step))
    out = []
    for i in range(1, frames + 1):
        theta = np.pi * i / frames
        position = centre - radius * left * np.cos(theta) + radius * forward * np.sin(theta)
        out.append(pose(axis_angle(up, theta) @ rotation, position))
    return out


def slerp_rotations(a, b, frames):
    """Rotations from a to b (exclusive of a), by the axis-angle of a^T b."""
    relative = a.T @ b
    angle = np.arccos(np.clip((np.trace(relative) - 1) / 2, -1, 1))
    if angle < 1e-9:
        return [a] * frames
    axis = np.array([relative[2, 1] - relative[1, 2], relative[0, 2] - relative[2, 0],
                     relative[1, 0] - relative[0, 1]]) / (2 * np.sin(angle))
    return [a @ axis_angle(axis, angle * (i + 1) / frames) for i in range(frames)]


def join(end, first, up, radius, cruise):
    """The poses from after `end` (a lap's last pose, moving at end_speed) to before
    `first`: brake, U-turn, drive back, U-turn, speed up."""
    end_pose, end_speed = end
    first_pose, first_speed = first
    turn_step = radius * np.radians(TURN_DEG_PER_FRAME)
    forward_end = horizontal(end_pose[:3, 2], up)
    brake, at = straight(end_pose[:3, 3], forward_end, speeds(RAMP, end_speed, turn_step), end_pose[:3, :3])
    first_turn = u_turn(at, end_pose[:3, :3], up, radius, turn_step)
    # The second U-turn ends RAMP frames of speeding up before the first pose.
    forward_first = horizontal(first_pose[:3, 2], up)
    speed_up = speeds(RAMP, turn_step, first_speed)
    turn_end = first_pose[:3, 3] - forward_first * speed_up.sum()
    turn_start = turn_end + 2 * radius * np.cross(up, forward_first)
    turned = axis_angle(up, np.pi) @ first_pose[:3, :3]
    back_from, back_to = first_turn[-1][:3, 3], turn_start
    length = np.linalg.norm(back_to - back_from)
    ramps = np.concatenate([speeds(RAMP, turn_step, cruise), speeds(RAMP, cruise, turn_step)])
    cruising = max(int(np.ceil((length - ramps.sum()) / cruise)), 0)
    steps = np.concatenate([ramps[:RAMP], np.full(cruising, cruise), ramps[RAMP:]])
    steps *= length / steps.sum()
    rotations = slerp_rotations(first_turn[-1][:3, :3], turned, len(steps))
    along = np.cumsum(steps) / length
    back = [pose(r, back_from + (back_to - back_from) * a) for r, a in zip(rotations, along)]
    second_turn = u_turn(turn_start, turned, up, radius, turn_step)
    into, _ = straight(turn_end, forward_first, speed_up, first_pose[:3, :3])
    return brake + first_turn + back + second_turn + into[:-1]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("poses")
    parser.add_argument("out")
    parser.add_argument("--laps", type=int, default=3)
    parser.add_argument("--radius", type=float, default=5.0, help="U-turn radius (m)")
    parser.add_argument("--cruise", type=float, default=0.8, help="metres a frame driving back")
    args = parser.parse_args()
    if args.laps < 1:
        sys.exit("--laps: at least 1")
    lap = read_poses(args.poses)
    # KITTI camera frames: y down; the path's up is the mean of the cameras' -y.
    up = -lap[:, :3, 1].mean(axis=0)
    up /= np.linalg.norm(up)
    step = lambda a, b: float(np.linalg.norm(lap[b, :3, 3] - lap[a, :3, 3]))
    between = join((lap[-1], step(-2, -1)), (lap[0], step(0, 1)), up, args.radius, args.cruise)
    drive = list(lap)
    for _ in range(args.laps - 1):
        drive += between + list(lap)
    drive = np.array(drive)
    jumps = np.linalg.norm(np.diff(drive[:, :3, 3], axis=0), axis=1)
    with open(args.out, "w") as f:
        for p in drive:
            f.write(" ".join(f"{v:.9g}" for v in p[:3, :].reshape(-1)) + "\n")
    print(f"{len(drive)} frames, {jumps.sum() / 1000:.2f} km, largest step {jumps.max():.2f} m, "
          f"{len(between)} frames between laps")


if __name__ == "__main__":
    main()
