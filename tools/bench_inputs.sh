#!/usr/bin/env bash
# Reading what users record, measured (issue 38): the same synthetic LiDAR drive as the KITTI
# layout, a ROS 2 bag (MCAP with zstd chunks, and SQLite3) and a folder of KITTI .bin scans with a
# TUM trajectory, each surveyed by `inspect-input` (bags: one pass over every message) and fused
# by `reconstruct --map` within a memory budget smaller than the bag. Prints one line per run:
# wall seconds, peak RSS, input seconds (reading + decoding scans, from map_report.json).
#
#   tools/bench_inputs.sh [BIN] [LENGTH_M] [BUDGET] [WORKDIR]
#   defaults: target/release/denser 300 256MiB /tmp/denser-bench-inputs
# Needs python3 with rosbags, pypcd4, plyfile, pillow, numpy (tools/setup.sh installs them).
set -euo pipefail
cd "$(dirname "$0")/.."
bin=$(realpath "${1:-target/release/denser}")
length_m=${2:-300}
budget=${3:-256MiB}
work=${4:-/tmp/denser-bench-inputs}
rm -rf "$work"
mkdir -p "$work"
echo "# $(date -u +%FT%TZ) $(uname -n) $(nproc) cores; $("$bin" --version); git $(git rev-parse --short HEAD)"
"$bin" --log warn synth --out "$work/drive" --length-m "$length_m" --lidar-only --seed 8 >/dev/null
seq="$work/drive/sequences/00"
python3 tools/make_input_fixtures.py "$seq" "$work/fx" --only bag_mcap,bag_sqlite,scans_bin
scans=$(ls "$seq/velodyne" | wc -l)
echo "# drive: ${length_m} m, ${scans} scans, $(du -sh "$seq/velodyne" | cut -f1) of .bin; bag_mcap $(du -sh "$work/fx/bag_mcap" | cut -f1), bag_sqlite $(du -sh "$work/fx/bag_sqlite" | cut -f1)"
echo "# load average before: $(cut -d' ' -f1-3 /proc/loadavg)"
printf '%-12s %-22s %8s %10s %9s %9s\n' input step wall_s peak_MiB input_s MB/s
run() { # name step bytes command...
  local name=$1 step=$2 bytes=$3; shift 3
  local log="$work/$name-$step.time"
  /usr/bin/time -v "$@" >"$work/$name-$step.out" 2>"$log"
  local wall rss
  wall=$(awk -F': ' '/Elapsed \(wall clock\)/ {n=split($2,a,":"); s=0; for(i=1;i<=n;i++) s=s*60+a[i]; print s}' "$log")
  rss=$(awk -F': ' '/Maximum resident set size/ {printf "%.0f", $2/1024}' "$log")
  local input_s="-"
  if [ -f "$work/out-$name/map_report.json" ] && [ "$step" = reconstruct ]; then
    input_s=$(python3 -c "import json,sys;print('%.2f'%json.load(open(sys.argv[1]))['timings']['input_s'])" "$work/out-$name/map_report.json")
  fi
  local rate="-"
  rate=$(python3 -c "print('%.0f'%($bytes/1e6/$wall) if $wall > 0.05 else '-')")
  printf '%-12s %-22s %8s %10s %9s %9s\n' "$name" "$step" "$wall" "$rss" "$input_s" "$rate"
}
for name in kitti bag_mcap bag_sqlite scans_bin; do
  case $name in
    kitti) in=$seq; bytes=$(du -sb "$seq/velodyne" | cut -f1) ;;
    scans_bin) in=$work/fx/scans_bin; bytes=$(du -sb "$in/scans" | cut -f1) ;;
    *) in=$work/fx/$name; bytes=$(du -sb "$in" | cut -f1) ;;
  esac
  run "$name" inspect-input "$bytes" "$bin" --log warn inspect-input "$in"
  run "$name" reconstruct "$bytes" "$bin" --log warn reconstruct "$in" --no-eval --map "$work/map-$name" \
    --memory-budget "$budget" --skip-regularize --out "$work/out-$name"
done
# The maps must hold the same blocks (the bag's and the folder's poses are the KITTI poses).
for name in bag_mcap bag_sqlite scans_bin; do
  a=$("$bin" --log warn inspect "$work/map-kitti" --json | python3 -c "import json,sys;d=json.load(sys.stdin)['summary'];print(d['blocks'], d['observed_voxels'])")
  b=$("$bin" --log warn inspect "$work/map-$name" --json | python3 -c "import json,sys;d=json.load(sys.stdin)['summary'];print(d['blocks'], d['observed_voxels'])")
  echo "# blocks, observed voxels: kitti $a, $name $b"
done
echo "# load average at the end: $(cut -d' ' -f1-3 /proc/loadavg)"
