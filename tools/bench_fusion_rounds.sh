#!/usr/bin/env bash
# Depth fusion against Open3D in alternating rounds (issue 14, item 1): on a shared, noisy
# machine one run's median can move by 20 % between seconds, so each round measures the two
# denser builds and the peer back to back, and the summary takes the median over the rounds
# of each round's ratio to the peer.
#
# Usage: BEFORE=path/to/denser AFTER=path/to/denser STREET=drive/sequences/00 \
#          [ROUNDS=10] tools/bench_fusion_rounds.sh
#        tools/bench_fusion_rounds.sh --summary RAW   (the summary of raw lines kept earlier)
# Raw lines: `round tool frames voxel ms_per_frame` (tool: before, after, open3d; frames: rgbd =
# the shared RGB-D frames, `denser bench --passes 5`; street = the drive's 1241x375 depth maps,
# `denser bench --rgbd STREET --passes 3 --max-depth-m 40`), then the summary.
# Needs Open3D for tools/bench_open3d.py (`pip install open3d==0.20.0 numpy`).
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)

summary() {
  python3 - "$1" <<'EOF'
import statistics, sys
rows = [l.split() for l in open(sys.argv[1]) if l[:1].isdigit()]
ms = {}
for r, tool, frames, voxel, t in rows:
    key = (int(r), tool, frames, voxel)
    if key in ms:
        sys.exit(f"two figures for {key}: the raw lines are not one run's")
    ms[key] = float(t)
rounds = sorted({k[0] for k in ms})
print("| frames | voxel | before | after | Open3D | before ÷ Open3D | after ÷ Open3D (range) |")
print("|---|---|---|---|---|---|---|")
for frames in ("rgbd", "street"):
    for voxel in ("10cm", "5cm"):
        col = lambda tool: [ms[(r, tool, frames, voxel)] for r in rounds if (r, tool, frames, voxel) in ms]
        ratio = lambda tool: [ms[(r, tool, frames, voxel)] / ms[(r, "open3d", frames, voxel)]
                              for r in rounds
                              if (r, tool, frames, voxel) in ms and (r, "open3d", frames, voxel) in ms]
        after, before = ratio("after"), ratio("before")
        if not after or not before:
            continue
        print(f"| {frames} | {voxel} | {statistics.median(col('before')):.2f} | "
              f"{statistics.median(col('after')):.2f} | {statistics.median(col('open3d')):.2f} | "
              f"{statistics.median(before):.2f}× | {statistics.median(after):.2f}× "
              f"({min(after):.2f}–{max(after):.2f}, {len(after)} rounds) |")
print("(ms per frame: medians over the rounds of each run's median; ratios: the median over the rounds of each round's ratio)")
EOF
}

if [[ "${1:-}" == "--summary" ]]; then
  summary "$2"
  exit 0
fi

: "${BEFORE:?path of the denser build before}" "${AFTER:?path of the denser build after}"
: "${STREET:?the sequences/00 folder of a denser synth drive}"
rounds=${ROUNDS:-10}
raw=$(mktemp)
trap 'rm -f "$raw"' EXIT
build() { # tool -> the path of its denser build
  if [[ $1 == after ]]; then echo "$AFTER"; else echo "$BEFORE"; fi
}
denser_rows() { # round tool frames: `denser bench` table rows -> raw lines
  awk -v r="$1" -v b="$2" -v f="$3" -F'|' '/ cm /{gsub(/ /,"",$2); gsub(/ /,"",$4); print r, b, f, $2, $4}'
}
open3d_rows() { # round frames: bench_open3d.py JSON lines -> raw lines
  R="$1" F="$2" python3 -c '
import json, os, sys
for j in map(json.loads, sys.stdin):
    cm = round(j["voxel_size_m"] * 100)
    print(os.environ["R"], "open3d", os.environ["F"], f"{cm}cm", j["median_ms_per_frame"])'
}
for r in $(seq 1 "$rounds"); do
  for tool in before after; do
    "$(build "$tool")" bench --passes 5 2>/dev/null | denser_rows "$r" "$tool" rgbd
  done
  python3 "$here/bench_open3d.py" --passes 5 2>/dev/null | grep '^{' | open3d_rows "$r" rgbd
  for tool in before after; do
    "$(build "$tool")" bench --rgbd "$STREET" --passes 3 --max-depth-m 40 2>/dev/null \
      | denser_rows "$r" "$tool" street
  done
  python3 "$here/bench_open3d.py" --kitti "$STREET" --passes 3 --depth-max 40 2>/dev/null | grep '^{' | open3d_rows "$r" street
done | tee "$raw"
summary "$raw"
