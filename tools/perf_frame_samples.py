#!/usr/bin/env python3
"""Counts the samples of `perf script` outputs whose call stack holds given frames.

    perf record -g --call-graph dwarf,16384 -F 499 -o P.data denser reconstruct ...
    perf script -i P.data -F comm,tid,ip,sym > P.txt
    tools/perf_frame_samples.py P.txt [P2.txt ...]

Each sample is one thread's; at -F 499 a sample stands for about 2 ms of that thread's CPU.
The frames counted are the LiDAR scan path's host steps (issue 34, docs/bench/gpu.md).
"""
import re
import sys

FRAMES = {
    "rays (all threads)": r"fusion::lidar::(rays|sent_rays|LidarPlan::with_returns|LidarPlan::rays_only)\b"
    r"|^(rays|sent_rays|rays_only|with_returns)$",
    "record_rays": r"record_rays",
    "dispatch_order": r"dispatch_order",
    "fuse_then_list": r"fuse_then_list",
    "with_listed_blocks": r"with_listed_blocks",
    "finish_lidar_listing": r"finish_lidar_listing",
    "Reconstructor::fuse_lidar (main)": r"Reconstructor::fuse_lidar\b",
    "make_chunk (staging made once)": r"make_chunk",
    "make_resident_inner": r"make_resident_inner",
    "table upload": r"DeviceTable::upload",
    "collect (late)": r"resident::late::<impl denser::gpu::resident::ResidentMap>::collect\b",
    "learn_insertions": r"learn_insertions",
}


def samples(path):
    """Each sample's thread id and its frames' symbols, innermost first."""
    out, cur = [], None
    for line in open(path, errors="replace"):
        if not line.strip():
            if cur:
                out.append(cur)
            cur = None
        elif not line[0].isspace():
            cur = (line.split()[-1], [])
        elif cur is not None:
            parts = line.strip().split(" ", 1)
            cur[1].append(parts[1] if len(parts) > 1 else parts[0])
    if cur:
        out.append(cur)
    return out


for path in sys.argv[1:]:
    s = samples(path)
    counts = []
    for name, pattern in FRAMES.items():
        rx = re.compile(pattern)
        n = sum(1 for _, frames in s if any(rx.search(f) for f in frames))
        counts.append(f"{name}={n}")
    print(path, len(s), " ".join(counts))
