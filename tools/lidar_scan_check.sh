#!/usr/bin/env bash
# LiDAR scans fused on the GPU (issue 34 items 2 and 3): `drive_check.sh` on a drive's
# simulated LiDAR (`--depth lidar`), before and after a change, GPU against CPU.
#
#   tools/lidar_scan_check.sh LENGTH_M DENSER...
#
# e.g. tools/lidar_scan_check.sh 10 /tmp/denser-before target/release/denser
exec "$(dirname "$0")/drive_check.sh" lidar "$@"
