#!/usr/bin/env bash
# Export of a stored map on 1 and N threads (issue 40): wall time of `export --mesh`,
# `--points x.copc.laz` and `--tiles` with RAYON_NUM_THREADS set, in alternating rounds, and a
# byte comparison of every output across thread counts. Prints one line per run and a median
# per (format, threads).
#
#   tools/bench_export_threads.sh [DENSER_BIN] [WORKDIR] [ROUNDS] [THREADS...]
#
# Defaults: target/release/denser, a fresh temporary folder, 3 rounds, threads 1 and 2. The map
# (do not modify, or results are not comparable): `synth --length-m 150 --lidar-only --seed 8`,
# `reconstruct --depth lidar --map` with --skip-regularize, then `regularize` (100 iterations,
# 512 MiB), as in the issue's table.
set -euo pipefail
# shellcheck source=tools/bench_threads_setup.sh
source "$(dirname "$(readlink -f "$0")")/bench_threads_setup.sh"
declare -A times
for r in $(seq 1 "$rounds"); do
  for t in "${threads[@]}"; do
    for fmt in mesh copc tiles; do
      case $fmt in
        mesh) args=(--mesh "out_${t}.ply") ;;
        copc) args=(--points "out_${t}.copc.laz") ;;
        tiles) args=(--tiles "out_${t}_tiles") ;;
      esac
      rm -rf "out_${t}_tiles"
      s=$( { /usr/bin/time -f "%e %M" env RAYON_NUM_THREADS="$t" "$bin" --log warn export map \
        "${args[@]}" --memory-budget 512MiB >/dev/null; } 2>&1 | tail -1)
      echo "round $r threads $t $fmt: wall ${s% *} s, peak RSS $(( ${s#* } / 1024 )) MiB"
      times[$fmt,$t]+="${s% *} "
    done
  done
done
for fmt in mesh copc tiles; do
  for t in "${threads[@]}"; do
    med=$(printf '%s\n' ${times[$fmt,$t]} | sort -g | awk '{a[NR]=$1} END {print a[int((NR+1)/2)]}')
    echo "median $fmt threads $t: $med s"
  done
done
first=${threads[0]}
for t in "${threads[@]:1}"; do
  cmp "out_${first}.ply" "out_${t}.ply" && cmp "out_${first}.copc.laz" "out_${t}.copc.laz" &&
    diff -r "out_${first}_tiles" "out_${t}_tiles" >/dev/null &&
    echo "outputs of $first and $t threads: identical"
done
