#!/usr/bin/env python3
"""Side-by-side peer benchmark: OpenCV's StereoSGBM on the pairs `denser stereo` is measured on
(docs/bench/stereo.md). Never a dependency of denser.

Pairs (both from ../shared/data, or --data DIR):
- KITTI odometry 00 frame 0 (1241x376, grey), 128 disparities from 0. Its ground truth is the
  frame's Velodyne scan projected into the left camera (nearest pixel, nearest point wins,
  d = fx * B / z), as `denser::depth::ground_truth::disparity_from_points` and the test
  `kitti_frame0_tgv_beats_sgm` build it.
- Middlebury 2014 Motorcycle, quarter size (741x497), ndisp from calib.txt (70) from 0, ground
  truth disp0GT.pfm (inf = unknown), non-occlusion mask mask0nocc.png (255 = non-occluded).

OpenCV's modes: MODE_SGBM_3WAY (5 directions in 2 passes: left-to-right, top-left, top,
top-right going down, then right-to-left; rows split into stripes run in parallel) and
MODE_SGBM (5 directions in one pass; MODE_HH would be 8). --block sets blockSize. Parameters: blockSize 5 (grey, so P1 = 8*5^2 and
P2 = 32*5^2, OpenCV's documented recommendation), uniquenessRatio 10, speckleWindowSize 100,
speckleRange 2, disp12MaxDiff 1, preFilterCap 63. Disparities below minDisparity (invalid)
count as missing.

Timing: `compute()` only (images decoded and in memory), median of --runs after one warm-up
(wall, and process CPU time: user + system of all threads), with cv2.setNumThreads(--threads)
(-1, the default: not called, so all cores; 0: sequential). Scores (same definitions as
`denser stereo-eval`, src/depth/metrics.rs): bad-1/2/3 over all ground-truth pixels with a
missing prediction counting as bad, D1 (> 3 px and > 5 %), EPE over pixels with a prediction,
density. With --write DIR the disparities (and KITTI's LiDAR ground truth) are written as PFM
so that `denser stereo-eval` can score them too.

Setup:  pip install opencv-python-headless numpy
Usage:  python3 tools/bench_opencv_sgbm.py [--runs 21] [--threads -1] [--write DIR]
Prints one JSON line per (pair, mode).
"""
import argparse
import json
import os
import statistics
import sys
import time

import cv2
import numpy as np


def read_pfm(path):
    with open(path, "rb") as f:
        kind = f.readline().strip()
        if kind != b"Pf":
            sys.exit(f"{path}: not a grey PFM (header {kind!r})")
        w, h = map(int, f.readline().split())
        scale = float(f.readline())
        data = np.fromfile(f, dtype="<f4" if scale < 0 else ">f4", count=w * h)
    if data.size != w * h:
        sys.exit(f"{path}: truncated ({data.size} of {w * h} values)")
    return np.flipud(data.reshape(h, w)).astype(np.float32)


def write_pfm(path, img):
    h, w = img.shape
    with open(path, "wb") as f:
        f.write(b"Pf\n%d %d\n-1.0\n" % (w, h))
        np.flipud(img).astype("<f4").tofile(f)


def read_grey(path):
    img = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
    if img is None:
        sys.exit(f"{path}: cannot read the image")
    return img


def kitti_calib(path):
    rows = {}
    with open(path) as f:
        for line in f:
            key, _, vals = line.partition(":")
            if vals.strip():
                rows[key.strip()] = np.array([float(v) for v in vals.split()])
    p0, p1 = rows["P0"].reshape(3, 4), rows["P1"].reshape(3, 4)
    tr = np.vstack([rows["Tr"].reshape(3, 4), [0, 0, 0, 1]])
    fx, cx, cy, fy = p0[0, 0], p0[0, 2], p0[1, 2], p0[1, 1]
    baseline_m = -(p1[0, 3] - p0[0, 3]) / fx
    return fx, fy, cx, cy, baseline_m, tr


def kitti_ground_truth(seq, w, h):
    fx, fy, cx, cy, b, cam_from_velo = kitti_calib(os.path.join(seq, "calib.txt"))
    velo = np.fromfile(os.path.join(seq, "velodyne", "000000.bin"), dtype="<f4").reshape(-1, 4)
    pts = np.c_[velo[:, :3].astype(np.float64), np.ones(len(velo))] @ cam_from_velo.T
    pts = pts[(pts[:, 2] > 1e-9) & np.isfinite(pts).all(axis=1)]
    u = np.round(fx * pts[:, 0] / pts[:, 2] + cx)
    v = np.round(fy * pts[:, 1] / pts[:, 2] + cy)
    keep = (u >= 0) & (v >= 0) & (u < w) & (v < h)
    u, v, z = u[keep].astype(int), v[keep].astype(int), pts[keep, 2]
    depth = np.full((h, w), np.inf)
    np.minimum.at(depth, (v, u), z)
    gt = np.full((h, w), np.nan, dtype=np.float32)
    ok = np.isfinite(depth)
    gt[ok] = (fx * b / depth[ok]).astype(np.float32)
    return gt


def score(pred, gt, mask=None):
    scored = np.isfinite(gt)
    if mask is not None:
        scored &= mask
    g = gt[scored].astype(np.float64)
    p = pred[scored].astype(np.float64)
    has = np.isfinite(p)
    err = np.where(has, np.abs(p - g), np.inf)
    n = max(len(g), 1)
    return {
        "bad1_pct": 100.0 * np.sum(err > 1) / n,
        "bad2_pct": 100.0 * np.sum(err > 2) / n,
        "bad3_pct": 100.0 * np.sum(err > 3) / n,
        "d1_pct": 100.0 * np.sum((err > 3) & (err > 0.05 * np.abs(g))) / n,
        "epe_px": float(np.mean(err[has])) if has.any() else float("nan"),
        "density_pct": 100.0 * np.sum(has) / n,
        "gt_pixels": int(len(g)),
    }


def matcher(mode, num_disparities, block):
    return cv2.StereoSGBM_create(
        minDisparity=0,
        numDisparities=num_disparities,
        blockSize=block,
        P1=8 * block * block,
        P2=32 * block * block,
        disp12MaxDiff=1,
        preFilterCap=63,
        uniquenessRatio=10,
        speckleWindowSize=100,
        speckleRange=2,
        mode=mode,
    )


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data"))
    ap.add_argument("--runs", type=int, default=21)
    ap.add_argument("--threads", type=int, default=-1, help="-1: OpenCV's default (all cores), 0: sequential")
    ap.add_argument("--block", type=int, default=5)
    ap.add_argument("--write", default=None, help="folder for the PFM outputs")
    a = ap.parse_args()
    if a.threads >= 0:
        cv2.setNumThreads(a.threads)
    seq = os.path.join(a.data, "kitti_odom00_frames000-005", "sequences", "00")
    mb = os.path.join(a.data, "middlebury2014_motorcycle_Q_sttr", "trainingQ", "Motorcycle")
    pairs = []
    left, right = read_grey(os.path.join(seq, "image_0", "000000.png")), read_grey(os.path.join(seq, "image_1", "000000.png"))
    pairs.append(("kitti00_0", left, right, 128, kitti_ground_truth(seq, left.shape[1], left.shape[0]), None))
    with open(os.path.join(mb, "calib.txt")) as f:
        ndisp = int(next(l for l in f if l.startswith("ndisp=")).split("=")[1])
    mask = cv2.imread(os.path.join(mb, "mask0nocc.png"), cv2.IMREAD_GRAYSCALE) == 255
    pairs.append(("motorcycle_q", read_grey(os.path.join(mb, "im0.png")), read_grey(os.path.join(mb, "im1.png")),
                  ndisp, read_pfm(os.path.join(mb, "disp0GT.pfm")), mask))
    if a.write:
        os.makedirs(a.write, exist_ok=True)
        write_pfm(os.path.join(a.write, "kitti00_0_gt.pfm"), pairs[0][4])
    for name, l, r, nd, gt, m in pairs:
        # OpenCV needs a multiple of 16.
        nd16 = (nd + 15) // 16 * 16
        for mode_name, mode in [("sgbm_3way", cv2.STEREO_SGBM_MODE_SGBM_3WAY), ("sgbm", cv2.STEREO_SGBM_MODE_SGBM)]:
            sg = matcher(mode, nd16, a.block)
            raw = sg.compute(l, r)
            times, cpu = [], []
            for _ in range(a.runs):
                t, c = time.perf_counter(), time.process_time()
                raw = sg.compute(l, r)
                times.append(time.perf_counter() - t)
                cpu.append(time.process_time() - c)
            disp = raw.astype(np.float32) / 16.0
            disp[raw < 0] = np.nan
            if a.write:
                write_pfm(os.path.join(a.write, f"{name}_{mode_name}.pfm"), disp)
            line = {
                "pair": name,
                "mode": mode_name,
                "size": f"{l.shape[1]}x{l.shape[0]}",
                "num_disparities": nd16,
                "threads": cv2.getNumThreads(),
                "median_ms": 1e3 * statistics.median(times),
                "min_ms": 1e3 * min(times),
                "cpu_median_ms": 1e3 * statistics.median(cpu),
                "runs": a.runs,
                "opencv": cv2.__version__,
                "all": score(disp, gt),
            }
            if m is not None:
                line["nonocc"] = score(disp, gt, m)
            print(json.dumps(line))


if __name__ == "__main__":
    main()
