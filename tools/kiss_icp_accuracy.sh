#!/usr/bin/env bash
# How much accuracy a map loses when its poses come from KISS-ICP instead of the truth (issue 38
# item 4; record: docs/bench/kiss_icp.md).
#
#   tools/kiss_icp_accuracy.sh [DENSER_BIN] [WORKDIR]
#
# DENSER_BIN defaults to target/release/denser, WORKDIR to /tmp/kiss (its drive/, scans/, run_*/,
# true/, kiss_anchored/ and kiss_fitted/ are replaced). Env: LENGTH_M (150), SEED (8), PYTHON (python3);
# KISS_ICP_* variables reach KISS-ICP (tools/kiss_icp_poses.sh). Needs kiss-icp (a user tool:
# `pip install kiss-icp==1.3.0`) and numpy.
#
# 1. `denser synth --lidar-only` writes a drive in the KITTI layout (poses = world_from_cam0,
#    calib.txt's Tr = cam0_from_velo).
# 2. WORKDIR/scans is a folder of scans: scans/ links to velodyne/*.bin, times.txt copied.
# 3. True poses: `reconstruct` of the folder with the KITTI poses and Tr as the extrinsic.
# 4. tools/kiss_icp_poses.sh gives the LiDAR's poses in its first scan's frame; they are put in the
#    world frame two ways: anchored (world_from_velo_i = world_from_cam0_0 · Tr · kiss_i, the first
#    scan at its true pose: what a user who knows only the start would get) and fitted (the rigid
#    transform that best fits the KISS positions to the true ones, Horn/Umeyama without scale:
#    the map's own error, without a global offset). Trajectory error: ATE RMSE of the positions
#    (both ways), drift = final position error anchored, and its share of the path length.
# 5. `reconstruct` with each; every run is scored against the drive's LiDAR scans merged with the
#    TRUE poses (`--gt` the KITTI sequence folder). Each run reads its own folder (WORKDIR/run_*:
#    scans/ linked, times.txt, trajectory.txt, extrinsic.txt for the true poses) rather than
#    `--poses`/`--extrinsic`, because `reconstruct --gt SEQUENCE` also merges the ground truth with
#    the file `--poses` names (denser 0.2.0 at the time of the record).
# Prints a Markdown table of the reports' accuracy and the run times.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
bin=$(readlink -f "${1:-$root/target/release/denser}")
work=${2:-/tmp/kiss}
length=${LENGTH_M:-150}
seed=${SEED:-8}
python=${PYTHON:-python3}
[ -x "$bin" ] || { echo "kiss_icp_accuracy: $bin: no denser binary (cargo build --release, or pass its path)" >&2; exit 1; }
mkdir -p "$work"
work=$(readlink -f "$work")
now() { date +%s.%N; }
secs() { "$python" -c "import sys; print(f'{float(sys.argv[2]) - float(sys.argv[1]):.1f}')" "$1" "$2"; }
exec 3>&2
run() {
  echo "+ $*" >&3
  "$@"
}
# A folder of scans for one run: WORKDIR/scans' scans with this trajectory (and extrinsic).
run_folder() {
  local dir=$work/run_$1
  mkdir -p "$dir"
  ln -s "$work/scans/scans" "$dir/scans"
  cp "$work/scans/times.txt" "$dir/"
  cp "$2" "$dir/trajectory.txt"
  [ $# -lt 3 ] || cp "$3" "$dir/extrinsic.txt"
}

rm -rf "$work/drive" "$work/scans" "$work"/run_* "$work/true" "$work/kiss_anchored" "$work/kiss_fitted"
run "$bin" --log warn synth --out "$work/drive" --length-m "$length" --lidar-only --seed "$seed" >&2
seq=$work/drive/sequences/00
mkdir -p "$work/scans/scans"
for f in "$seq"/velodyne/*.bin; do ln -s "$f" "$work/scans/scans/"; done
cp "$seq/times.txt" "$work/scans/"
# Tr (cam0_from_velo) as a 4×4 extrinsic: body = cam0, sensor = velo.
"$python" - "$seq/calib.txt" "$work/tr_4x4.txt" <<'EOF'
import sys
for line in open(sys.argv[1]):
    if line.startswith("Tr:"):
        v = line.split()[1:]
        rows = [v[0:4], v[4:8], v[8:12], ["0", "0", "0", "1"]]
        open(sys.argv[2], "w").write("".join(" ".join(r) + "\n" for r in rows))
        break
else:
    sys.exit(f"{sys.argv[1]}: no Tr line")
EOF

t0=$(now)
run_folder true "$work/drive/poses/00.txt" "$work/tr_4x4.txt"
run "$bin" reconstruct "$work/run_true" --gt "$seq" --out "$work/true" >"$work/true.log" 2>&1
t1=$(now)
run "$root/tools/kiss_icp_poses.sh" "$work/scans" "$work/scans/trajectory_kiss.txt" >"$work/kiss_icp.log" 2>&1
t2=$(now)

"$python" - "$work/drive/poses/00.txt" "$work/tr_4x4.txt" "$work/scans/trajectory_kiss.txt" "$work" <<'EOF'
import json, sys
import numpy as np
cam_poses, tr, kiss, work = sys.argv[1:]
def load(path):
    a = np.loadtxt(path, ndmin=2).reshape(-1, 3, 4)
    t = np.tile(np.eye(4), (len(a), 1, 1))
    t[:, :3] = a
    return t
truth = load(cam_poses) @ np.loadtxt(tr)  # world_from_velo
k = load(kiss)
assert len(k) == len(truth), (len(k), len(truth))
anchored = truth[0] @ k
# best rigid fit of the KISS positions onto the true ones (Horn / Umeyama, no scale)
p, q = k[:, :3, 3], truth[:, :3, 3]
pm, qm = p.mean(0), q.mean(0)
u, _, vt = np.linalg.svd((q - qm).T @ (p - pm))
d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
fit = np.eye(4)
fit[:3, :3] = u @ d @ vt
fit[:3, 3] = qm - fit[:3, :3] @ pm
fitted = fit @ k
def save(path, t):
    np.savetxt(path, t[:, :3].reshape(-1, 12), fmt="%.17g")
save(f"{work}/scans/trajectory_kiss_anchored.txt", anchored)
save(f"{work}/scans/trajectory_kiss_fitted.txt", fitted)
err_a = np.linalg.norm(anchored[:, :3, 3] - q, axis=1)
err_f = np.linalg.norm(fitted[:, :3, 3] - q, axis=1)
length = float(np.linalg.norm(np.diff(q, axis=0), axis=1).sum())
r = anchored[-1, :3, :3].T @ truth[-1, :3, :3]
rot_deg = float(np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1))))
stats = {
    "scans": len(k),
    "path_length_m": length,
    "ate_rmse_anchored_m": float(np.sqrt((err_a**2).mean())),
    "ate_rmse_fitted_m": float(np.sqrt((err_f**2).mean())),
    "ate_max_anchored_m": float(err_a.max()),
    "final_drift_m": float(err_a[-1]),
    "final_drift_percent": float(100 * err_a[-1] / length),
    "final_rotation_error_deg": rot_deg,
}
json.dump(stats, open(f"{work}/trajectory_error.json", "w"), indent=1)
EOF

run_folder kiss_anchored "$work/scans/trajectory_kiss_anchored.txt"
run_folder kiss_fitted "$work/scans/trajectory_kiss_fitted.txt"
t3=$(now)
run "$bin" reconstruct "$work/run_kiss_anchored" --gt "$seq" --out "$work/kiss_anchored" >"$work/kiss_anchored.log" 2>&1
t4=$(now)
run "$bin" reconstruct "$work/run_kiss_fitted" --gt "$seq" --out "$work/kiss_fitted" >"$work/kiss_fitted.log" 2>&1
t5=$(now)

"$python" - "$work" "$(secs "$t0" "$t1")" "$(secs "$t1" "$t2")" "$(secs "$t3" "$t4")" "$(secs "$t4" "$t5")" <<'EOF'
import json, sys
work, t_true, t_kiss, t_anch, t_fit = sys.argv[1:]
te = json.load(open(f"{work}/trajectory_error.json"))
print(f"{te['scans']} scans over {te['path_length_m']:.1f} m; KISS-ICP {t_kiss} s")
print(f"KISS-ICP trajectory: ATE RMSE {te['ate_rmse_anchored_m']:.3f} m anchored at scan 0, "
      f"{te['ate_rmse_fitted_m']:.3f} m best-fit; final drift {te['final_drift_m']:.3f} m "
      f"({te['final_drift_percent']:.2f} % of the path), {te['final_rotation_error_deg']:.2f}°")
print()
print("| poses | raw median m | raw p75 m | reg. median m | reg. p75 m | reg. completeness median m | reconstruct s |")
print("|---|---:|---:|---:|---:|---:|---:|")
for name, label, t in (("true", "true", t_true), ("kiss_anchored", "KISS-ICP, anchored", t_anch),
                       ("kiss_fitted", "KISS-ICP, best-fit", t_fit)):
    s = {x["label"]: x for x in json.load(open(f"{work}/{name}/report.json"))["surfaces"]}
    raw, reg = s["raw"]["accuracy"], s["regularized"]["accuracy"]
    print(f"| {label} | {raw['median_m']:.4f} | {raw['p75_m']:.4f} | {reg['median_m']:.4f} | "
          f"{reg['p75_m']:.4f} | {s['regularized']['completeness']['median_m']:.4f} | {t} |")
EOF
