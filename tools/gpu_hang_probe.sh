#!/usr/bin/env bash
# Finds which GPU test or run stops making progress on a hardware GPU: the GPU tests one at a
# time under a time limit (the last "test … " line without a result is the one), then one
# `reconstruct` of a short drive per build, each under a time limit.
#   GPU_TESTS=BIN tools/gpu_hang_probe.sh BEFORE AFTER OUT
set -uo pipefail
before=$1 after=$2 out=$3
work=$(mktemp -d)
for n in before after; do eval "gunzip -c \$$n > $work/$n"; chmod +x "$work/$n"; done
gunzip -c "$GPU_TESTS" >"$work/tests"; chmod +x "$work/tests"
(cd "$work" && timeout 80 ./tests --test-threads 1 >"$out/tests.log" 2>&1; echo "tests rc=$?" >>"$out/tests.log")
"$work/after" synth --length-m 30 --seed 1 --out "$work/d" >/dev/null 2>&1
for run in "after gpu" "before gpu" "after cpu"; do
    set -- $run
    echo "### $1 --device $2" >>"$out/runs.log"
    timeout 35 "$work/$1" reconstruct "$work/d/sequences/00" --depth gt --device "$2" --no-eval \
        --out "$work/o-$1-$2" >>"$out/runs.log" 2>&1
    echo "rc=$?" >>"$out/runs.log"
done
