#!/usr/bin/env bash
# Depth frames from the host listed on the GPU (issue 34 item 1): for each build given, a
# synthetic drive reconstructed from its ground-truth depth maps (`--depth gt`) with
# `--device gpu` and, as the oracle, `--device cpu`; prints each GPU run's host time per frame
# (the "GPU tier per frame" line: listing blocks is the host's share of planning), its GPU
# traffic per depth frame, wall time and peak RSS, and every run's output digests (the same
# bytes before and after a change, and GPU the same as CPU?). Counts are device-independent
# (lavapipe is enough); kernel and wall times count only on a hardware GPU.
#
#   tools/host_depth_check.sh LENGTH_M DENSER...
#
# e.g. tools/host_depth_check.sh 10 /tmp/denser-before target/release/denser
set -u
length=$1
shift
work=$(mktemp -d)
first=$1
echo "# host_depth_check $(date -u +%FT%TZ) on $(hostname), $(nproc) cores; ${length} m drive"
"$first" synth --out "$work/drive" --length-m "$length" --seed 3 2>&1 | grep -v INFO
for bin in "$@"; do
    echo "## $bin ($("$bin" --version 2>&1))"
    for device in gpu cpu; do
        out="$work/out"
        rm -rf "$out"
        echo "### --depth gt --device $device ($(date -u +%T))"
        /usr/bin/time -f "wall %e s, peak RSS %M KiB" "$bin" reconstruct \
            "$work/drive/sequences/00" --depth gt --device "$device" --no-eval \
            --out "$out" 2>&1 | grep -v INFO | grep -E "GPU tier|per depth frame|wall|fused"
        (cd "$out" && md5sum ./*.ply)
    done
done
rm -rf "$work"
