#!/usr/bin/env python3
"""Side-by-side peer benchmark: scikit-image's `denoise_tv_chambolle` on the dense 128^3 float32
volume that `cargo bench --bench core -- tv_dense_128` regularizes with denser's solver. Never a
dependency of denser.

The volume (same formula as `dense_tv_volume` in benches/core.rs): a sphere of radius 40 voxels
centred in the cube, f = clamp((r - 40) / 10, -1, 1) (a normalised TSDF with mu = 10 voxels),
plus uniform noise in [-0.1, 0.1) from a splitmix64 hash of the voxel's linear index.

Both minimise the same energy: skimage's ROF problem is
    min_u 1/2 sum (u - f)^2 + weight * sum |grad u|
(forward differences, zero across the volume's faces, isotropic norm), which divided by `weight`
is denser's  sum |grad u| + (lambda/2) sum w (u - f)^2  with w = 1 on every voxel (all in Omega)
and lambda = 1/weight. The algorithms differ: skimage runs Chambolle's 2004 dual projection
(tau = 1/6), denser Chambolle-Pock primal-dual (sigma = 1/2, tau = 1/6, theta = 1), so 50
iterations of each reach different energies; both energies are printed, computed here by the
same formula, next to the throughput.

Setup:  pip install scikit-image==0.26.0 numpy
Usage:  python3 tools/bench_skimage_tv.py [--passes N] [--iterations 50] [--lambda 0.8]
Prints one JSON line: median seconds per solve, voxel-iterations per second, energy before/after.
"""
import argparse
import json
import time

import numpy as np
import skimage
from skimage.restoration import denoise_tv_chambolle

N = 128


def splitmix64(x: np.ndarray) -> np.ndarray:
    with np.errstate(over="ignore"):
        z = x + np.uint64(0x9E3779B97F4A7C15)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        return z ^ (z >> np.uint64(31))


def volume() -> np.ndarray:
    """f[z, y, x] as float32 (x fastest, as denser's blocks)."""
    z, y, x = np.meshgrid(np.arange(N), np.arange(N), np.arange(N), indexing="ij")
    c = (N - 1) / 2.0
    r = np.sqrt((x - c) ** 2 + (y - c) ** 2 + (z - c) ** 2)
    f = np.clip((r - 40.0) / 10.0, -1.0, 1.0)
    index = (x + N * (y + N * z)).astype(np.uint64)
    noise = (splitmix64(index) >> np.uint64(40)).astype(np.float64) / float(1 << 24)
    return (f + 0.2 * (noise - 0.5)).astype(np.float32)


def energy(u: np.ndarray, f: np.ndarray, lam: float) -> float:
    u = u.astype(np.float64)
    g = np.zeros((3,) + u.shape)
    for ax in range(3):
        sl = [slice(None)] * 3
        sl[ax] = slice(0, -1)
        g[(ax,) + tuple(sl)] = np.diff(u, axis=ax)
    tv = np.sqrt((g ** 2).sum(axis=0)).sum()
    return float(tv + 0.5 * lam * ((u - f.astype(np.float64)) ** 2).sum())


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--passes", type=int, default=5)
    parser.add_argument("--iterations", type=int, default=50)
    parser.add_argument("--lambda", dest="lam", type=float, default=0.8)
    args = parser.parse_args()
    f = volume()
    times, u = [], None
    for _ in range(args.passes):
        t = time.perf_counter()
        # eps = 0: never stop early, run exactly max_num_iter iterations.
        u = denoise_tv_chambolle(f, weight=1.0 / args.lam, eps=0.0, max_num_iter=args.iterations)
        times.append(time.perf_counter() - t)
    times.sort()
    median = times[len(times) // 2]
    print(json.dumps({
        "peer": "scikit-image " + skimage.__version__ + " denoise_tv_chambolle",
        "voxels": int(f.size), "iterations": args.iterations, "lambda": args.lam,
        "weight": 1.0 / args.lam, "dtype": str(u.dtype), "passes": args.passes,
        "median_s": median, "m_voxel_iterations_per_s": f.size * args.iterations / median / 1e6,
        "energy_before": energy(f, f, args.lam), "energy_after": energy(u, f, args.lam),
    }))


if __name__ == "__main__":
    main()
