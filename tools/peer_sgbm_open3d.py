#!/usr/bin/env python3
"""End-to-end peer of `denser reconstruct --depth stereo`: what a user of this field would run
instead. OpenCV StereoSGBM (MODE_SGBM_3WAY) on every rectified pair of a KITTI-layout drive,
disparity -> depth, Open3D's VoxelBlockGrid TSDF integration, marching cubes, and an evaluation
against the drive's LiDAR scans (distance from each mesh vertex to the nearest ground-truth point,
and back). Never a dependency of denser.

Input: a KITTI odometry sequence folder as `denser synth` writes it (or KITTI's own):
image_0/image_1 (grey, rectified), image_2 (colour, same camera as image_0 in a synthetic drive),
calib.txt (P0, P1, Tr), velodyne/*.bin, and poses in ../../poses/NN.txt (world_from_cam0).

Parameters, chosen to match `denser reconstruct`'s defaults:
- SGBM: 128 disparities from 0, blockSize 5, P1 = 8*5^2, P2 = 32*5^2 (OpenCV's documented
  recommendation for grey), uniquenessRatio 10, speckleWindowSize 100, speckleRange 2,
  disp12MaxDiff 1, preFilterCap 63 (as tools/bench_opencv_sgbm.py).
- Depth z = fx * B / d for d > 0, kept up to --depth-max (denser: 40 m for depth maps), handed
  to Open3D in millimetres (uint16; Open3D integrates u16 depth with u8 colour).
- TSDF: voxel 0.10 m, 8^3-voxel blocks, truncation 10 voxels = 1.0 m (denser's default at 10 cm),
  colour from image_2.
- Evaluation: Open3D KD-tree distances (accuracy: mesh vertex -> LiDAR, completeness:
  LiDAR -> mesh vertex), medians and 75th percentiles. The scans are merged in the world frame
  (world_from_cam0 * Tr * p), all points of every frame's scan, as `denser reconstruct` merges them.

Timing: wall clock per stage (image reading is part of "stereo", as denser's "input and stereo"),
and the whole run divided by the number of frames. cv2 and Open3D use all cores by default.

Setup:  pip install opencv-python-headless open3d==0.20.0 numpy   (Debian libusb-1.0-0 for open3d)
Usage:  python3 tools/peer_sgbm_open3d.py SEQ [--out DIR] [--first N] [--last N] [--no-eval]
Prints one JSON line; with --out, writes DIR/mesh_peer.ply so `denser evaluate --mesh
peer=DIR/mesh_peer.ply --gt SEQ` can score it exactly as denser scores its own.
"""
import argparse
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import open3d as o3d
import open3d.core as o3c


def read_calib(seq: Path):
    rows = {}
    for line in (seq / "calib.txt").read_text().splitlines():
        if ":" in line:
            key, vals = line.split(":", 1)
            rows[key.strip()] = np.array([float(x) for x in vals.split()])
    for key in ("P0", "P1"):
        if key not in rows or rows[key].size != 12:
            sys.exit(f"{seq / 'calib.txt'}: missing or malformed {key} (12 numbers)")
    p0, p1 = rows["P0"].reshape(3, 4), rows["P1"].reshape(3, 4)
    fx = p0[0, 0]
    baseline_m = -p1[0, 3] / p1[0, 0]
    if not baseline_m > 0:
        sys.exit(f"{seq / 'calib.txt'}: P1 gives a baseline of {baseline_m} m (expected > 0)")
    velo_from = np.eye(4)
    if "Tr" in rows:
        velo_from[:3, :] = rows["Tr"].reshape(3, 4)
    return p0[:, :3], fx, baseline_m, velo_from


def read_poses(seq: Path):
    path = seq.parent.parent / "poses" / f"{seq.name}.txt"
    if not path.is_file():
        sys.exit(f"{path}: no poses file (world_from_cam0, 12 numbers per line)")
    poses = []
    for line in path.read_text().splitlines():
        if line.strip():
            m = np.eye(4)
            m[:3, :] = np.array([float(x) for x in line.split()]).reshape(3, 4)
            poses.append(m)
    return poses


def sgbm():
    block = 5
    return cv2.StereoSGBM_create(
        minDisparity=0, numDisparities=128, blockSize=block,
        P1=8 * block * block, P2=32 * block * block, disp12MaxDiff=1, preFilterCap=63,
        uniquenessRatio=10, speckleWindowSize=100, speckleRange=2, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)


def merged_lidar(seq: Path, poses, velo_cam0, frames):
    chunks = []
    for i in frames:
        path = seq / "velodyne" / f"{i:06}.bin"
        if not path.is_file():
            continue
        raw = np.fromfile(path, dtype="<f4")
        if raw.size % 4:
            sys.exit(f"{path}: truncated scan ({raw.size} floats, not a multiple of 4)")
        pts = raw.reshape(-1, 4)[:, :3].astype(np.float64)
        world_from_velo = poses[i] @ velo_cam0
        chunks.append(pts @ world_from_velo[:3, :3].T + world_from_velo[:3, 3])
    return np.concatenate(chunks) if chunks else np.zeros((0, 3))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("seq", type=Path, help="KITTI-layout sequence folder (sequences/NN)")
    ap.add_argument("--out", type=Path, help="write mesh_peer.ply here")
    ap.add_argument("--first", type=int, default=0)
    ap.add_argument("--last", type=int, help="one past the last frame (default: all)")
    ap.add_argument("--voxel-size", type=float, default=0.10)
    ap.add_argument("--depth-max", type=float, default=40.0)
    ap.add_argument("--no-eval", action="store_true")
    args = ap.parse_args()
    seq = args.seq
    for sub in ("image_0", "image_1", "image_2"):
        if not (seq / sub).is_dir():
            sys.exit(f"{seq / sub}: missing (a stereo drive needs image_0, image_1 and image_2)")
    k, fx, baseline_m, velo_cam0 = read_calib(seq)
    poses = read_poses(seq)
    last = len(poses) if args.last is None else min(args.last, len(poses))
    frames = [i for i in range(args.first, last) if (seq / "image_0" / f"{i:06}.png").is_file()]
    if not frames:
        sys.exit(f"{seq}: no frames in [{args.first}, {last})")

    intr = o3c.Tensor(k, dtype=o3c.Dtype.Float64)
    trunc_mult = 10.0
    vbg = o3d.t.geometry.VoxelBlockGrid(
        attr_names=("tsdf", "weight", "color"), attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
        attr_channels=((1), (1), (3)), voxel_size=args.voxel_size, block_resolution=8,
        block_count=200000, device=o3c.Device("CPU:0"))
    matcher = sgbm()
    t_stereo = t_fuse = 0.0
    t0 = time.perf_counter()
    for i in frames:
        t = time.perf_counter()
        left = cv2.imread(str(seq / "image_0" / f"{i:06}.png"), cv2.IMREAD_GRAYSCALE)
        right = cv2.imread(str(seq / "image_1" / f"{i:06}.png"), cv2.IMREAD_GRAYSCALE)
        if left is None or right is None:
            sys.exit(f"{seq}: frame {i:06}: unreadable image_0/image_1 PNG")
        disp = matcher.compute(left, right).astype(np.float32) / 16.0  # fixed point, 4 fraction bits
        depth_m = np.zeros_like(disp)
        ok = disp > 0
        depth_m[ok] = fx * baseline_m / disp[ok]
        depth_m[depth_m > args.depth_max] = 0.0
        depth_mm = np.rint(depth_m * 1000.0).astype(np.uint16)  # Open3D takes u16 depth with u8 colour
        color = o3d.t.io.read_image(str(seq / "image_2" / f"{i:06}.png"))
        t_stereo += time.perf_counter() - t

        t = time.perf_counter()
        depth_img = o3d.t.geometry.Image(o3c.Tensor(depth_mm))
        extr = o3c.Tensor(np.linalg.inv(poses[i]), dtype=o3c.Dtype.Float64)
        coords = vbg.compute_unique_block_coordinates(depth_img, intr, extr, 1000.0, args.depth_max, trunc_mult)
        vbg.integrate(coords, depth_img, color, intr, intr, extr, 1000.0, args.depth_max, trunc_mult)
        t_fuse += time.perf_counter() - t

    t = time.perf_counter()
    mesh = vbg.extract_triangle_mesh().to_legacy()
    t_mesh = time.perf_counter() - t
    t_reconstruct = time.perf_counter() - t0
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        o3d.io.write_triangle_mesh(str(args.out / "mesh_peer.ply"), mesh)

    result = {
        "peer": f"opencv {cv2.__version__} SGBM_3WAY + open3d {o3d.__version__} VoxelBlockGrid",
        "sequence": str(seq), "frames": len(frames), "image": f"{left.shape[1]}x{left.shape[0]}",
        "voxel_size_m": args.voxel_size, "truncation_m": trunc_mult * args.voxel_size,
        "depth_max_m": args.depth_max, "blocks": int(vbg.hashmap().size()),
        "mesh_vertices": len(mesh.vertices), "mesh_triangles": len(mesh.triangles),
        "stereo_s": round(t_stereo, 3), "fusion_s": round(t_fuse, 3), "mesh_s": round(t_mesh, 3),
        "reconstruct_s_per_frame": round(t_reconstruct / len(frames), 4),
    }
    if not args.no_eval:
        t = time.perf_counter()
        gt = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(
            merged_lidar(seq, poses, velo_cam0, frames)))
        verts = o3d.geometry.PointCloud(mesh.vertices)
        acc = np.asarray(verts.compute_point_cloud_distance(gt))
        comp = np.asarray(gt.compute_point_cloud_distance(verts))
        t_eval = time.perf_counter() - t
        result.update({
            "gt_points": len(gt.points), "eval_s": round(t_eval, 3),
            "accuracy_median_m": float(np.median(acc)), "accuracy_p75_m": float(np.percentile(acc, 75)),
            "completeness_median_m": float(np.median(comp)),
            "total_s_per_frame": round((t_reconstruct + t_eval) / len(frames), 4),
        })
    print(json.dumps(result))


if __name__ == "__main__":
    main()
