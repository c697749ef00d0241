#!/usr/bin/env bash
# LiDAR scans fused on the GPU (issue 34 items 2 and 3): for each build given, a synthetic
# drive reconstructed from its simulated LiDAR (`--depth lidar`) with `--device gpu` and, as the
# oracle, `--device cpu`; prints each GPU run's "GPU tier" and traffic lines (per LiDAR scan:
# uploads, readbacks, submits, waits, buffers and bind groups created), the kernels compiled,
# wall time and peak RSS, and every run's output digests (the same bytes before and after a
# change, and GPU the same as CPU?). Counts are device-independent (lavapipe is enough); kernel
# and wall times count only on a hardware GPU.
#
#   tools/lidar_scan_check.sh LENGTH_M DENSER...
#
# e.g. tools/lidar_scan_check.sh 10 /tmp/denser-before target/release/denser
set -u
length=$1
shift
work=$(mktemp -d)
first=$1
echo "# lidar_scan_check $(date -u +%FT%TZ) on $(hostname), $(nproc) cores; ${length} m drive"
"$first" synth --out "$work/drive" --length-m "$length" --seed 3 2>&1 | grep -v INFO
for bin in "$@"; do
    echo "## $bin ($("$bin" --version 2>&1))"
    for device in gpu cpu; do
        out="$work/out"
        rm -rf "$out"
        echo "### --depth lidar --device $device ($(date -u +%T))"
        /usr/bin/time -f "wall %e s, peak RSS %M KiB" "$bin" reconstruct \
            "$work/drive/sequences/00" --depth lidar --device "$device" --no-eval \
            --out "$out" 2>&1 | grep -v INFO | grep -E "GPU tier|GPU traffic|GPU kernels|wall|fused"
        (cd "$out" && md5sum ./*.ply)
    done
done
rm -rf "$work"
