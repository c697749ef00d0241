#!/usr/bin/env bash
# Runs one fixed map pipeline with two `denser` binaries and compares what each wrote, byte for
# byte: a change that claims "same bytes out" (a refactor, a parallel path) runs it before landing.
#
#   tools/same_bytes.sh BEFORE_BIN AFTER_BIN [WORKDIR]
#
# The pipeline (do not modify, or earlier records are not comparable): a 40 m synthetic LiDAR
# drive (seed 8); `reconstruct --map` in two halves into two maps (8³-block chunks, 96 MiB budget,
# swept regularization, its meshes and evaluation); `regularize` of the first map (another λ, swept
# and with the exact halo) and a sharded pass (`--shard 0/2`, `1/2`, then the committing run);
# `merge` of the two maps; `export` of the merged map to every format (PLY mesh raw and
# regularized, PLY / LAS / LAZ / COPC points, a georeferenced LAS, a 3D Tiles tileset, a boxed
# mesh) and an `export --shard` pass. Maps carry a random identity, so they are compared by what
# they hold: every output above plus `inspect --json` without the identity and timings.
# Prints one line per output and exits 1 if any differ.
set -euo pipefail
before=$(readlink -f "$1")
after=$(readlink -f "$2")
work=${3:-$(mktemp -d)}
mkdir -p "$work"
export RAYON_NUM_THREADS=${RAYON_NUM_THREADS:-2}

"$before" --log warn synth --out "$work/drive" --length-m 40 --lidar-only --seed 8 >/dev/null

pipeline() {
  local bin=$1 out=$2
  rm -rf "$out"
  mkdir -p "$out"
  local common=(--depth lidar --voxel-size 0.1 --chunk-blocks 8 --memory-budget 96MiB --no-eval)
  "$bin" --log warn reconstruct "$work/drive/sequences/00" "${common[@]}" --last 20 --map "$out/a" --out "$out/rec_a"
  "$bin" --log warn reconstruct "$work/drive/sequences/00" "${common[@]}" --first 20 --map "$out/b" --out "$out/rec_b"
  "$bin" --log warn regularize "$out/a" --lambda 0.5 --iterations 40 --memory-budget 64MiB
  "$bin" --log warn export "$out/a" --mesh "$out/a_swept.ply"
  "$bin" --log warn regularize "$out/a" --lambda 0.6 --iterations 30 --sweep-iterations 30 --memory-budget 64MiB
  "$bin" --log warn export "$out/a" --mesh "$out/a_exact.ply"
  "$bin" --log warn regularize "$out/b" --lambda 0.5 --iterations 30 --shard 0/2
  "$bin" --log warn regularize "$out/b" --lambda 0.5 --iterations 30 --shard 1/2
  "$bin" --log warn regularize "$out/b" --lambda 0.5 --iterations 30
  "$bin" --log warn export "$out/b" --mesh "$out/b_sharded.ply"
  "$bin" --log warn merge "$out/a" "$out/b" --out "$out/m"
  "$bin" --log warn regularize "$out/m" --iterations 30 --memory-budget 64MiB
  local m=$out/m
  "$bin" --log warn export "$m" --mesh "$out/m_raw.ply" --raw
  "$bin" --log warn export "$m" --mesh "$out/m_reg.ply"
  "$bin" --log warn export "$m" --points "$out/m_points.ply"
  "$bin" --log warn export "$m" --points "$out/m_points.las"
  "$bin" --log warn export "$m" --points "$out/m_points.laz"
  "$bin" --log warn export "$m" --points "$out/m_points.copc.laz" --memory-budget 64MiB
  "$bin" --log warn export "$m" --points "$out/m_geo.las" --georef EPSG:32632@500000,5335000,100,30
  "$bin" --log warn export "$m" --tiles "$out/m_tiles"
  "$bin" --log warn export "$m" --mesh "$out/m_box.ply" --bbox=-5,-5,-5,5,5,20
  "$bin" --log warn export "$m" --mesh "$out/m_parts.ply" --shard 0/2
  "$bin" --log warn export "$m" --mesh "$out/m_parts.ply" --shard 1/2
  "$bin" --log warn export "$m" --mesh "$out/m_parts.ply"
  for map in a b m; do
    "$bin" --log warn inspect "$out/$map" --json |
      python3 -c 'import json,sys
def strip(v):
    if isinstance(v, dict):
        return {k: strip(x) for k, x in v.items() if "map_id" not in k and "second" not in k and "unix" not in k and k not in ("path", "created_by")}
    if isinstance(v, list):
        return [strip(x) for x in v]
    return v
print(json.dumps(strip(json.load(sys.stdin)), indent=1, sort_keys=True))' >"$out/inspect_$map.json"
  done
}

pipeline "$before" "$work/before"
pipeline "$after" "$work/after"

status=0
while IFS= read -r f; do
  rel=${f#"$work/before/"}
  case "$rel" in
    a/* | b/* | m/* | rec_*/report.* | rec_*/*.json | rec_*/*.md) continue ;; # maps: by inspect; reports: timings
  esac
  if cmp -s "$f" "$work/after/$rel"; then
    echo "same      $rel ($(stat -c %s "$f") bytes)"
  else
    echo "DIFFERENT $rel"
    status=1
  fi
done < <(find "$work/before" -type f | sort)
missing=$(comm -13 <(cd "$work/before" && find . -type f | sort) <(cd "$work/after" && find . -type f | sort) | grep -vE '^\./(a|b|m)/' || true)
if [ -n "$missing" ]; then
  echo "only after: $missing"
  status=1
fi
exit "$status"
