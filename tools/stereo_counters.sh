#!/usr/bin/env bash
# The GPU traffic of one stereo pair (device-independent counts: bytes up and down, submits,
# waits, buffers, bind groups, dispatches) for each build given, SGM and TGV-tensor, and the
# disparity files' digests (the same bytes before and after a change?). Runs on lavapipe.
#
#   tools/stereo_counters.sh LEFT RIGHT DENSER...
#
# e.g. tools/stereo_counters.sh ../shared/data/kitti_odom00_frames000-005/sequences/00/image_{0,1}/000000.png /tmp/denser-before target/release/denser
set -u
left=$1 right=$2
shift 2
work=$(mktemp -d)
echo "# stereo_counters $(date -u +%FT%TZ) on $(hostname), $(nproc) cores; $left"
for bin in "$@"; do
    echo "## $bin ($("$bin" --version 2>&1))"
    for method in sgm tgv-tensor; do
        for dev in gpu cpu; do
            "$bin" stereo "$left" "$right" --method "$method" --device "$dev" --out "$work/d.pfm" 2>&1 |
                grep -E "GPU traffic|matched in" | sed "s/^/$method, $dev: /"
            echo "$method, $dev: PFM md5 $(md5sum <"$work/d.pfm" | cut -d' ' -f1)"
        done
    done
done
rm -rf "$work"
