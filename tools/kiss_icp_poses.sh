#!/usr/bin/env bash
# Poses for a folder of scans that has none, from KISS-ICP (a LiDAR odometry), for
# `denser reconstruct` (issue 38 item 4; docs/bench/kiss_icp.md measures the accuracy).
#
#   tools/kiss_icp_poses.sh SCANS_FOLDER [OUT_TRAJECTORY]
#
# Runs `kiss_icp_pipeline` on SCANS_FOLDER/scans and writes OUT_TRAJECTORY (default
# SCANS_FOLDER/trajectory_kiss.txt): a KITTI trajectory (a 3×4 matrix per line), one pose per scan
# in denser's scan order, each the pose of the LiDAR (world_from_sensor) in KISS-ICP's world, which
# is the first scan's sensor frame (the first pose is the identity). Then prints the command:
#
#   denser reconstruct SCANS_FOLDER --poses OUT_TRAJECTORY
#
# A user tool: KISS-ICP is not installed by tools/setup.sh and no test needs it. Install it with
# `pip install kiss-icp==1.3.0` (the version measured). Its generic loader reads one format per
# folder: KITTI `.bin` (f32 x y z reflectance) with numpy alone; `.pcd` / `.ply` need open3d,
# trimesh or pyntcloud (`pip install "kiss-icp[all]"`, which brings open3d); it does not read
# `.las` / `.laz` (denser does): convert those scans first. KISS-ICP's settings come from its
# `KISS_ICP_*` environment variables (pydantic-settings), e.g.
# `KISS_ICP_DATA='{"max_range": 80}' KISS_ICP_MAPPING='{"voxel_size": 0.5}'`; KISS_ICP_OUT_DIR is
# set here (a temporary folder). KISS-ICP de-skews a scan only when its file carries per-point times
# (a PCD field `t`/`time`/`timestamp`… read through open3d); denser does not de-skew.
#
# No extrinsic: the poses are the sensor's. If SCANS_FOLDER/extrinsic.txt exists, denser applies
# it by default (world_from_body · body_from_sensor), which would be wrong here: this script then
# writes an identity extrinsic next to OUT_TRAJECTORY and prints `--extrinsic` with it.
#
# Env: PYTHON (default python3), KISS_ICP_PIPELINE (default kiss_icp_pipeline).
set -euo pipefail

usage() {
  sed -n '2,10p' "$0" >&2
  exit 2
}
[ $# -ge 1 ] && [ $# -le 2 ] || usage
case $1 in -h | --help) usage ;; esac

folder=${1%/}
out=${2:-$folder/trajectory_kiss.txt}
python=${PYTHON:-python3}
pipeline=${KISS_ICP_PIPELINE:-kiss_icp_pipeline}
kiss_version=1.3.0

die() {
  echo "kiss_icp_poses: $*" >&2
  exit 1
}

[ -d "$folder/scans" ] || die "$folder/scans: no such folder (a folder of scans holds its scans in scans/)"
command -v "$python" >/dev/null 2>&1 || die "$python not found (set PYTHON)"
if ! have=$("$python" -c 'from importlib.metadata import version; import kiss_icp; print(version("kiss-icp"))' 2>/dev/null); then
  die "KISS-ICP is not installed for $python: pip install kiss-icp==$kiss_version"
fi
command -v "$pipeline" >/dev/null 2>&1 \
  || die "$pipeline not on PATH although kiss_icp $have is installed (pip's script folder missing from PATH?)"
[ "$have" = "$kiss_version" ] || echo "kiss_icp_poses: warning: kiss-icp $have, measured with $kiss_version" >&2

# The scans in denser's order and in KISS-ICP's (natsort), which must name the same files.
"$python" - "$folder/scans" <<'EOF' || exit 1
import os, re, sys
import natsort
scans = sys.argv[1]
names = [n for n in os.listdir(scans) if os.path.isfile(os.path.join(scans, n))]
# denser (src/io/scans.rs): these extensions, any case
ours = [n for n in names if os.path.splitext(n)[1][1:].lower() in ("pcd", "ply", "las", "laz", "bin")]
# KISS-ICP 1.3 (datasets/generic.py): names ending in a supported extension, case-sensitive
kiss_ext = ("bin", "pcd", "ply", "xyz", "obj", "ctm", "off", "stl")
theirs = [n for n in names if any(n.endswith(e) for e in kiss_ext)]
def fail(msg):
    print(f"kiss_icp_poses: {scans}: {msg}", file=sys.stderr)
    sys.exit(1)
if not ours:
    fail("no scan file (.bin, .pcd, .ply, .las, .laz)")
las = [n for n in ours if n.lower().endswith((".las", ".laz"))]
if las:
    fail(f"KISS-ICP does not read LAS/LAZ ({las[0]} …): convert the scans to .pcd, .ply or KITTI .bin")
if sorted(ours) != sorted(theirs):
    only = sorted(set(ours) ^ set(theirs))
    fail(f"denser and KISS-ICP would read different files (e.g. {only[:3]}): keep only the scans in scans/, with lower-case extensions")
exts = {os.path.splitext(n)[1] for n in ours}
if len(exts) > 1:
    fail(f"mixed formats {sorted(exts)}: KISS-ICP reads every file with the first file's reader")
ext = exts.pop()
if ext != ".bin":
    import importlib.util
    if not any(importlib.util.find_spec(m) for m in ("open3d", "trimesh", "pyntcloud")):
        fail(f'KISS-ICP reads {ext} scans through open3d, trimesh or pyntcloud: pip install "kiss-icp[all]" (or open3d)')
EOF

tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
echo "+ KISS_ICP_OUT_DIR=$tmp $pipeline $folder/scans" >&2
KISS_ICP_OUT_DIR=$tmp "$pipeline" "$folder/scans" >&2
shopt -s nullglob
found=("$tmp"/latest/*_poses_kitti.txt)
[ ${#found[@]} -eq 1 ] || die "KISS-ICP wrote no *_poses_kitti.txt under $tmp/latest"

# KISS-ICP's poses follow its natsort order; write them in denser's (by the number each name
# holds when every name is one, else by name), the order denser matches a KITTI trajectory by.
mkdir -p "$(dirname "$out")"
"$python" - "$folder/scans" "${found[0]}" "$out" <<'EOF'
import os, re, sys
import natsort
import numpy as np
scans, kiss_file, out = sys.argv[1:]
kiss_ext = ("bin", "pcd", "ply", "xyz", "obj", "ctm", "off", "stl")
names = [n for n in os.listdir(scans) if os.path.isfile(os.path.join(scans, n)) and any(n.endswith(e) for e in kiss_ext)]
kiss_order = natsort.natsorted(names)
poses = np.loadtxt(kiss_file, ndmin=2)
if poses.shape != (len(kiss_order), 12):
    sys.exit(f"kiss_icp_poses: {kiss_file}: {poses.shape[0]} poses for {len(kiss_order)} scans")
number = re.compile(r"^[+-]?(inf|infinity|nan|(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?)$", re.I)
stems = {n: os.path.splitext(n)[0] for n in names}
if all(number.match(s) for s in stems.values()):
    ours = sorted(names, key=lambda n: float(stems[n]))
else:
    ours = sorted(names, key=lambda n: os.fsencode(n))
row = {n: i for i, n in enumerate(kiss_order)}
np.savetxt(out, poses[[row[n] for n in ours]], fmt="%.17g")
if ours != kiss_order:
    print("kiss_icp_poses: KISS-ICP read the scans in another order than denser; the poses are written in denser's order", file=sys.stderr)
EOF

n=$(grep -c . "$out")
echo "wrote $out: $n sensor poses (KITTI 3×4, KISS-ICP $have; the first scan's sensor frame is the world)" >&2
if [ -f "$folder/extrinsic.txt" ]; then
  ident=${out%.txt}.identity_extrinsic.txt
  printf '1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n' >"$ident"
  echo "note: $folder/extrinsic.txt would be applied on top of these sensor poses; $ident (the identity) overrides it" >&2
  echo "denser reconstruct $folder --poses $out --extrinsic $ident"
else
  echo "denser reconstruct $folder --poses $out"
fi
