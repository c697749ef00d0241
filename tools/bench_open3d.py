#!/usr/bin/env python3
"""Side-by-side peer benchmark: Open3D's VoxelBlockGrid integrating the same RGB-D frames that
`denser bench` fuses (../shared/data/rgbd_5frames_slambook2), at equal voxel size and truncation
(mu = 8 voxels, Open3D's default trunc_voxel_multiplier). Never a dependency of denser.

Setup:  pip install open3d==0.20.0 numpy   (and Debian libusb-1.0-0 for `import open3d`)
Usage:  python3 tools/bench_open3d.py [DATA_DIR] [--passes N] [--depth-max M]
        python3 tools/bench_open3d.py --kitti SEQ [--passes N] [--depth-max M]
The second form reads a synthetic KITTI-layout drive written by `denser synth` (1242x375 depth in
`depth_gt/`, 16-bit, metres x 256; colour from image_2; intrinsics from P0 of calib.txt; poses
from ../../poses/NN.txt), the frames `denser bench --rgbd SEQ` fuses.
Prints one JSON line per voxel size: median ms per frame (block enumeration + integration).
"""
import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import open3d as o3d
import open3d.core as o3c


def read_pgm16(path: Path) -> np.ndarray:
    data = path.read_bytes()
    parts, pos = [], 0
    while len(parts) < 4:  # magic, width, height, maxval (comments skipped)
        while data[pos:pos + 1].isspace():
            pos += 1
        if data[pos:pos + 1] == b"#":
            pos = data.index(b"\n", pos) + 1
            continue
        end = pos
        while not data[end:end + 1].isspace():
            end += 1
        parts.append(data[pos:end])
        pos = end
    pos += 1
    w, h, maxval = int(parts[1]), int(parts[2]), int(parts[3])
    dtype = ">u2" if maxval > 255 else "u1"
    return np.frombuffer(data, dtype=dtype, count=w * h, offset=pos).reshape(h, w).astype(np.uint16)


def quat_to_matrix(tx, ty, tz, qx, qy, qz, qw):
    n = np.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    qx, qy, qz, qw = qx / n, qy / n, qz / n, qw / n
    r = np.array([
        [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
        [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
        [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)],
    ])
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = r, [tx, ty, tz]
    return m


def slambook_frames(root: Path):
    """The numbered RGB-D folder: depth/N.pgm (mm), color/N.png, pose.txt (tx ty tz qx qy qz qw)."""
    poses = [quat_to_matrix(*map(float, l.split())) for l in (root / "pose.txt").read_text().split("\n") if l.strip()]
    intr = o3c.Tensor([[518.0, 0, 325.5], [0, 519.0, 253.5], [0, 0, 1]], dtype=o3c.Dtype.Float64)
    frames = []
    for i, pose in enumerate(poses, start=1):
        depth = o3d.t.geometry.Image(o3c.Tensor(read_pgm16(root / f"depth/{i}.pgm")))
        color = o3d.t.io.read_image(str(root / f"color/{i}.png"))  # uint8 with uint16 depth
        extr = o3c.Tensor(np.linalg.inv(pose), dtype=o3c.Dtype.Float64)
        frames.append((depth, color, extr))
    return intr, frames, 1000.0


def kitti_frames(seq: Path):
    """A `denser synth` drive: depth_gt/NNNNNN.png (uint16, m x 256), image_2 colour, P0, poses."""
    p0 = next(l for l in (seq / "calib.txt").read_text().splitlines() if l.startswith("P0:"))
    p = np.array([float(x) for x in p0.split()[1:]]).reshape(3, 4)
    intr = o3c.Tensor(p[:, :3], dtype=o3c.Dtype.Float64)
    pose_file = seq.parent.parent / "poses" / f"{seq.name}.txt"
    frames = []
    for i, line in enumerate(pose_file.read_text().splitlines()):
        path = seq / "depth_gt" / f"{i:06}.png"
        if not line.strip() or not path.is_file():
            continue
        pose = np.eye(4)
        pose[:3, :] = np.array([float(x) for x in line.split()]).reshape(3, 4)
        depth = o3d.t.io.read_image(str(path))
        color = o3d.t.io.read_image(str(seq / "image_2" / f"{i:06}.png"))
        extr = o3c.Tensor(np.linalg.inv(pose), dtype=o3c.Dtype.Float64)
        frames.append((depth, color, extr))
    return intr, frames, 256.0


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("data", nargs="?", type=Path,
                        default=Path(__file__).resolve().parents[1] / "../shared/data/rgbd_5frames_slambook2")
    parser.add_argument("--kitti", type=Path, help="a synthetic KITTI-layout sequence (denser synth)")
    parser.add_argument("--passes", type=int, default=10)
    parser.add_argument("--depth-max", type=float, default=10.0, help="metres (denser bench --max-depth-m)")
    args = parser.parse_args()
    passes, depth_max = args.passes, args.depth_max
    if args.kitti:
        intr, frames, depth_scale = kitti_frames(args.kitti)
    else:
        intr, frames, depth_scale = slambook_frames(args.data)
    for voxel in (0.10, 0.05):
        vbg = o3d.t.geometry.VoxelBlockGrid(
            attr_names=("tsdf", "weight", "color"),
            attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
            attr_channels=((1), (1), (3)),
            voxel_size=voxel, block_resolution=8, block_count=100000, device=o3c.Device("CPU:0"))
        times = []
        for p in range(passes):
            for depth, color, extr in frames:
                t = time.perf_counter()
                coords = vbg.compute_unique_block_coordinates(depth, intr, extr, depth_scale, depth_max, 8.0)
                vbg.integrate(coords, depth, color, intr, intr, extr, depth_scale, depth_max, 8.0)
                times.append(time.perf_counter() - t)
        times.sort()
        print(json.dumps({"peer": "open3d " + o3d.__version__, "voxel_size_m": voxel, "truncation_m": 8 * voxel,
                          "depth_max_m": depth_max, "image": f"{depth.columns}x{depth.rows}",
                          "frames": len(times), "median_ms_per_frame": 1e3 * times[len(times) // 2],
                          "blocks": int(vbg.hashmap().size())}))


if __name__ == "__main__":
    main()
