#!/usr/bin/env bash
# A synthetic drive fused on the GPU against the CPU (issue 34): for each build given, the drive
# reconstructed from its ground-truth depth maps (`gt`: a depth frame from the host, listed on
# the device) or its simulated LiDAR (`lidar`) with `--device gpu` and, as the oracle,
# `--device cpu`; prints each GPU run's "GPU tier" lines (the host's time per frame: listing
# blocks is the host's share of planning), its GPU traffic per depth frame or LiDAR scan
# (uploads, readbacks, submits, waits, buffers and bind groups created), the kernels compiled,
# wall time and peak RSS, and every run's output digests (the same bytes before and after a
# change, and GPU the same as CPU?). Counts are device-independent (lavapipe is enough); kernel
# and wall times count only on a hardware GPU. `host_depth_check.sh` and `lidar_scan_check.sh`
# run it for each input.
#
#   tools/drive_check.sh gt|lidar LENGTH_M DENSER...
#
# e.g. tools/drive_check.sh lidar 10 /tmp/denser-before target/release/denser
set -u
depth=$1
length=$2
shift 2
work=$(mktemp -d)
first=$1
echo "# drive_check $(date -u +%FT%TZ) on $(hostname), $(nproc) cores; ${length} m drive, --depth $depth"
"$first" synth --out "$work/drive" --length-m "$length" --seed 3 2>&1 | grep -v INFO
for bin in "$@"; do
    echo "## $bin ($("$bin" --version 2>&1))"
    for device in gpu cpu; do
        out="$work/out"
        rm -rf "$out"
        echo "### --depth $depth --device $device ($(date -u +%T))"
        /usr/bin/time -f "wall %e s, peak RSS %M KiB" "$bin" reconstruct \
            "$work/drive/sequences/00" --depth "$depth" --device "$device" --no-eval \
            --out "$out" 2>&1 | grep -v INFO | grep -E "GPU tier|GPU traffic|GPU kernels|wall|fused"
        (cd "$out" && md5sum ./*.ply)
    done
done
rm -rf "$work"
