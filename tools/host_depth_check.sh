#!/usr/bin/env bash
# Depth frames from the host listed on the GPU (issue 34 item 1): `drive_check.sh` on a drive's
# ground-truth depth maps (`--depth gt`), before and after a change, GPU against CPU.
#
#   tools/host_depth_check.sh LENGTH_M DENSER...
#
# e.g. tools/host_depth_check.sh 10 /tmp/denser-before target/release/denser
exec "$(dirname "$0")/drive_check.sh" gt "$@"
