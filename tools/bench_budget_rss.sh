#!/usr/bin/env bash
# Peak RSS of the whole job against --memory-budget B (issue "A map survives its users", item 6):
# on a synthetic LiDAR drive of LENGTH metres along the KITTI 00 trajectory, `reconstruct --map`
# with its evaluation and surfaces, a swept `regularize` (with the peak of its scratch state under
# sweeps/, polled, against the map's size), `merge` of the drive's two halves, and `export` to
# every format. Peak RSS from /usr/bin/time (`%M`), one run each.
#
# Usage: tools/bench_budget_rss.sh [DENSER_BIN] [WORKDIR] [LENGTH_M] [BUDGET_MIB]
#   defaults: target/release/denser, a fresh temporary folder, 300, 128.
# The KITTI 00 poses come from ../shared/data (KITTI_POSES overrides); the drive and the maps are
# made in WORKDIR unless there already.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
bin=$(readlink -f "${1:-$root/target/release/denser}")
work=${2:-$(mktemp -d)}
length=${3:-300}
budget=${4:-128}
poses=${KITTI_POSES:-$root/../shared/data/kitti_odom_poses_evo/KITTI_00_gt.txt}
mkdir -p "$work"
cd "$work"
echo "machine: $(nproc) cores; $(uname -sr); $("$bin" --version); drive ${length} m; budget ${budget} MiB (bound $((budget + 64)) MiB)"
drive=d$length
if [ ! -d "$drive/sequences/00" ]; then
  "$bin" --log warn synth --out "$drive" --length-m "$length" --trajectory "$poses" --lidar-only >/dev/null
fi
frames=$(ls "$drive/sequences/00/velodyne" | wc -l)
B="${budget}MiB"

# run LABEL COMMAND...: one line "LABEL peak_MiB seconds" (the command's output in LABEL.log).
run() {
  local label=$1
  shift
  /usr/bin/time -f "%M %e" -o "$label.time" "$bin" "$@" >"$label.log" 2>&1 || {
    echo "$label failed:"
    tail -5 "$label.log"
    exit 1
  }
  read -r kib secs <"$label.time"
  printf '%-28s %8.1f MiB %8.1f s\n' "$label" "$(echo "$kib / 1024" | bc -l)" "$secs"
}

rm -rf map out halves_a halves_b merged exports
run "reconstruct --map (eval)" reconstruct "$drive/sequences/00" --depth lidar --map map --out out \
  --memory-budget "$B" --device cpu
grep -E "^(pager|peak RSS)" "reconstruct --map (eval).log" || true
echo "evaluation scratch on disk (peak): $(grep -A1 'evaluation scratch on disk' out/report.json | tail -1 | tr -d ' ,') bytes"
map_bytes=$(du -sb map/chunks | cut -f1)

# A swept pass (a new λ): the scratch state's peak, polled.
"$bin" --log warn regularize map --lambda 0.7 --memory-budget "$B" --device cpu >regularize.log 2>&1 &
pid=$!
peak=0
start=$(date +%s.%N)
while kill -0 "$pid" 2>/dev/null; do
  # du complains (and fails) when a state file is replaced under it: take its figure anyway.
  s=$( (du -sb map/sweeps 2>/dev/null || true) | cut -f1 | head -1)
  if [ -n "$s" ] && [ "$s" -gt "$peak" ]; then peak=$s; fi
  sleep 0.2
done
wait "$pid"
grep -E "peak RSS|sweep state" regularize.log | tail -1
echo "swept pass: sweeps/ peak $peak bytes (polled) against the map's chunk files $map_bytes bytes ($(echo "$peak / $map_bytes" | bc -l | cut -c1-5)×), $(echo "$(date +%s.%N) - $start" | bc | cut -c1-6) s"

# Merge: the drive's halves fused apart.
half=$((frames / 2))
"$bin" --log warn reconstruct "$drive/sequences/00" --depth lidar --map halves_a --out ha --last "$half" \
  --memory-budget "$B" --skip-regularize --no-eval --device cpu >/dev/null
"$bin" --log warn reconstruct "$drive/sequences/00" --depth lidar --map halves_b --out hb --first "$half" \
  --memory-budget "$B" --skip-regularize --no-eval --device cpu >/dev/null
run "merge (two halves)" merge halves_a halves_b --out merged --memory-budget "$B"
run "regularize (merged)" regularize merged --memory-budget "$B" --device cpu

mkdir -p exports
run "export --mesh" export map --mesh exports/m.ply --memory-budget "$B"
run "export --points .ply" export map --points exports/p.ply --memory-budget "$B"
run "export --points .las" export map --points exports/p.las --memory-budget "$B"
run "export --points .laz" export map --points exports/p.laz --memory-budget "$B"
run "export --points .copc.laz" export map --points exports/p.copc.laz --memory-budget "$B"
run "export --tiles" export map --tiles exports/tiles --memory-budget "$B"
