#!/usr/bin/env bash
# Stereo handed to fusion on the device (issue 35 item 3): for each build given, a short
# synthetic drive reconstructed with `--depth stereo --device gpu` (SGM and TGV-tensor) and,
# as the oracle, SGM with `--device cpu`; prints each run's GPU traffic per stereo pair and
# per depth frame, its wall time and peak RSS, and the outputs' digests (the same bytes before
# and after a change, and GPU SGM the same as CPU SGM?). Counts are device-independent
# (lavapipe is enough); times count only on a hardware GPU.
#
#   tools/device_depth_check.sh LENGTH_M DENSER...
#
# e.g. tools/device_depth_check.sh 3 /tmp/denser-before target/release/denser
set -u
length=$1
shift
work=$(mktemp -d)
first=$1
echo "# device_depth_check $(date -u +%FT%TZ) on $(hostname), $(nproc) cores; ${length} m drive"
"$first" synth --out "$work/drive" --length-m "$length" --seed 3 2>&1 | grep -v INFO
for bin in "$@"; do
    echo "## $bin ($("$bin" --version 2>&1))"
    for run in "sgm gpu" "tgv-tensor gpu" "sgm cpu"; do
        set -- $run
        out="$work/out"
        rm -rf "$out"
        echo "### --method $1 --device $2 ($(date -u +%T))"
        /usr/bin/time -f "wall %e s, peak RSS %M KiB" "$bin" reconstruct \
            "$work/drive/sequences/00" --depth stereo --method "$1" --device "$2" --no-eval \
            --out "$out" 2>&1 | grep -v INFO | grep -E "stereo|GPU traffic per|wall|fused"
        (cd "$out" && md5sum ./*.ply)
    done
done
rm -rf "$work"
