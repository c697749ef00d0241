# Sourced by tools/bench_export_threads.sh and tools/bench_regularize_threads.sh: reads their
# arguments [DENSER_BIN] [WORKDIR] [ROUNDS] [THREADS...] into `bin`, `work`, `rounds` and
# `threads` (defaults: target/release/denser, a fresh temporary folder, 3, threads 1 and 2),
# enters WORKDIR and makes the issue-40 map there unless it holds it already (do not modify it,
# or results are not comparable): `synth --length-m 150 --lidar-only --seed 8`, `reconstruct
# --depth lidar --map` with --skip-regularize, then `regularize` (100 iterations, 512 MiB).
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
