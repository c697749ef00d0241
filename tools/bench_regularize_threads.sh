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
bin=$(readlink -f "${1:-target/release/denser}")
work=${2:-$(mktemp -d)}
rounds=${3:-3}
shift $(( $# > 3 ? 3 : $# ))
threads=("$@")
[ ${#threads[@]} -gt 0 ] || threads=(1 2)
mkdir -p "$work"
cd "$work"
if [ ! -f map/manifest.dmf ]; then
  "$bin" --log warn synth --out drive --length-m 150 --lidar-only --seed 8 >/dev/null
  "$bin" --log warn reconstruct drive/sequences/00 --depth lidar --map map --out rec \
    --skip-regularize --no-eval >/dev/null
  "$bin" --log warn regularize map --memory-budget 512MiB >/dev/null
fi
"$bin" --log warn inspect map | head -3
echo "machine: $(nproc) cores; $(uname -sr); $("$bin" --version)"
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
