#!/usr/bin/env python3
"""How two binary PLY files that denser wrote differ: vertex and face counts, the largest
vertex displacement (in metres), the largest colour step, and whether the faces are equal.
Used by tools/gpu_check.sh where two meshes are not byte-identical (two devices or builds).
Reads only denser's layout (formats: src/io/ply.rs): float x y z, optional uchar red green
blue, then faces as a uchar count 3 and three int indices.

    tools/ply_diff.py A.ply B.ply [VOXEL_M]

With VOXEL_M, the displacement is also given in voxels. Exit status 0 when the files are the
same mesh up to those numbers (same counts and faces), 1 otherwise. Needs numpy.
"""
import sys

import numpy as np


def read(path):
    with open(path, "rb") as f:
        data = f.read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    vertices = faces = 0
    color = False
    for line in header:
        w = line.split()
        if w[:2] == ["element", "vertex"]:
            vertices = int(w[2])
        elif w[:2] == ["element", "face"]:
            faces = int(w[2])
        elif w[:3] == ["property", "uchar", "red"]:
            color = True
    vtype = [("xyz", "<f4", 3)] + ([("rgb", "u1", 3)] if color else [])
    v = np.frombuffer(data, dtype=np.dtype(vtype), count=vertices, offset=end)
    off = end + v.nbytes
    f = np.frombuffer(data, dtype=np.dtype([("n", "u1"), ("i", "<i4", 3)]), count=faces, offset=off)
    return v, f


def main():
    a, b = sys.argv[1], sys.argv[2]
    voxel = float(sys.argv[3]) if len(sys.argv) > 3 else None
    (va, fa), (vb, fb) = read(a), read(b)
    same_counts = len(va) == len(vb) and len(fa) == len(fb)
    line = f"vertices {len(va)} / {len(vb)}, faces {len(fa)} / {len(fb)}"
    same = same_counts
    if same_counts:
        d = np.abs(va["xyz"].astype(np.float64) - vb["xyz"].astype(np.float64))
        moved = int(np.count_nonzero(d.max(axis=1)))
        line += f"; {moved} vertices moved, at most {d.max() if d.size else 0:.3g} m"
        if voxel:
            line += f" ({(d.max() if d.size else 0) / voxel:.3g} voxel)"
        if "rgb" in va.dtype.names and "rgb" in vb.dtype.names:
            c = np.abs(va["rgb"].astype(int) - vb["rgb"].astype(int))
            line += f"; colour at most {c.max() if c.size else 0} steps apart"
        faces_equal = bool(np.array_equal(fa["i"], fb["i"]))
        line += "; faces " + ("equal" if faces_equal else "DIFFERENT")
        same = faces_equal
    print(line)
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
