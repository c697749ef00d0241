#!/usr/bin/env bash
# `regularize` of a stored map on 1 and N threads (issue 40): wall time, CPU time and peak RSS of
# a new 100-iteration pass with RAYON_NUM_THREADS set, in alternating rounds, each on a fresh copy
# of the map; then a byte comparison of the regularized maps (chunk files and manifest) across
# thread counts. Prints one line per run and a median per thread count.
#
#   tools/bench_regularize_threads.sh [DENSER_BIN] [WORKDIR] [ROUNDS] [THREADS...]
#
# Defaults: target/release/denser, a fresh temporary folder, 3 rounds, threads 1 and 2. The map is
# the one of tools/bench_export_threads.sh (reused when WORKDIR holds it): `synth --length-m 150
# --lidar-only --seed 8`, `reconstruct --depth lidar --map --skip-regularize`, `regularize`
# (512 MiB); each run adds a pass with another λ (0.7), as `regularize` of an archived map does.
set -euo pipefail
# shellcheck source=tools/bench_threads_setup.sh
source "$(dirname "$(readlink -f "$0")")/bench_threads_setup.sh"
declare -A times
for r in $(seq 1 "$rounds"); do
  for t in "${threads[@]}"; do
    rm -rf "reg_${t}"
    cp -r map "reg_${t}"
    s=$( { /usr/bin/time -f "%e %U %S %M" env RAYON_NUM_THREADS="$t" "$bin" --log warn \
      regularize "reg_${t}" --lambda 0.7 --memory-budget 512MiB >/dev/null; } 2>&1 | tail -1)
    read -r wall user sys rss <<<"$s"
    echo "round $r threads $t: wall $wall s, user $user s, sys $sys s, peak RSS $(( rss / 1024 )) MiB"
    times[$t]+="$wall "
  done
done
for t in "${threads[@]}"; do
  med=$(printf '%s\n' ${times[$t]} | sort -g | awk '{a[NR]=$1} END {print a[int((NR+1)/2)]}')
  echo "median threads $t: $med s"
done
first=${threads[0]}
for t in "${threads[@]:1}"; do
  diff -r "reg_${first}/chunks" "reg_${t}/chunks" >/dev/null &&
    cmp "reg_${first}/manifest.dmf" "reg_${t}/manifest.dmf" &&
    echo "regularized maps of $first and $t threads: identical"
done
