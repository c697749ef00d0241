#!/usr/bin/env bash
# The GPU tier's host share, builds side by side (issue 34): a synthetic drive fused on the GPU
# by each build in turn, ROUNDS rounds, printing each run's "GPU tier per frame" line (the
# fusing thread's own CPU time per depth frame or LiDAR scan), its traffic per frame, wall time,
# peak RSS and output digests (the same bytes for every build?). Quote the median of the rounds
# and the per-round ratios: the machines are shared and noisy.
#
#   tools/host_share_rounds.sh gt|lidar LENGTH_M ROUNDS DENSER...
#
# e.g. tools/host_share_rounds.sh gt 30 3 /tmp/denser-before target/release/denser
set -u
depth=$1
length=$2
rounds=$3
shift 3
work=$(mktemp -d)
echo "# host_share_rounds $(date -u +%FT%TZ) on $(hostname), $(nproc) cores; ${length} m drive, --depth $depth, $rounds rounds"
"$1" synth --out "$work/drive" --length-m "$length" --seed 3 2>&1 | grep -v INFO
for bin in "$@"; do
    echo "## $bin: $("$bin" --version 2>&1)"
done
for r in $(seq "$rounds"); do
    for bin in "$@"; do
        echo "### round $r: $bin ($(date -u +%T))"
        rm -rf "$work/out"
        /usr/bin/time -f "wall %e s, peak RSS %M KiB" "$bin" reconstruct \
            "$work/drive/sequences/00" --depth "$depth" --device gpu --no-eval \
            --out "$work/out" 2>&1 | grep -E "GPU tier per frame|GPU traffic per (depth|LiDAR)|wall"
        (cd "$work/out" && md5sum ./*.ply | tr '\n' ' ' && echo)
    done
done
rm -rf "$work"
