#!/usr/bin/env bash
# Wall time of a regularization pass run by 1, 2 and 4 shards (`regularize --shard i/N`, all
# started at once, then the committing `regularize`), with the map on disk and on an S3 server
# (moto on the loopback address), and of `merge`; per-chunk costs for the estimate in
# docs/bench/scaleout.md. Usage (release binary):
#
#   cargo build --release && tools/bench_scaleout.sh [LENGTH_M] [ITERATIONS] [REGION_CHUNKS]
#
# Prints one line per run: where, shards, wall seconds (shards + commit), the commit's seconds.
set -euo pipefail
cd "$(dirname "$0")/.."
BIN="$PWD/target/release/denser"
LEN="${1:-200}"
IT="${2:-100}"
RC="${3:-2}"
WORK="$(mktemp -d)"
PORT=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
moto_server -H 127.0.0.1 -p "$PORT" >/dev/null 2>&1 &
MOTO=$!
trap 'kill $MOTO 2>/dev/null; rm -rf "$WORK"' EXIT
export AWS_ENDPOINT_URL="http://127.0.0.1:$PORT" AWS_ACCESS_KEY_ID=bench AWS_SECRET_ACCESS_KEY=bench \
  AWS_REGION=us-east-1 AWS_ALLOW_HTTP=true
for _ in $(seq 100); do curl -s -o /dev/null "$AWS_ENDPOINT_URL" && break; sleep 0.2; done
curl -s -X PUT "$AWS_ENDPOINT_URL/bench" >/dev/null
cd "$WORK"
echo "machine: $(nproc) cores, $(uname -r); load: $(uptime | sed 's/.*load average: //')"
"$BIN" synth --out drive --length-m "$LEN" --frame-spacing-m 2 --lidar-only >/dev/null
fuse() {
  /usr/bin/time -f "%e s wall, %M KiB peak" "$BIN" reconstruct drive/sequences/00 --depth lidar \
    --map "$1" --out out --memory-budget 1GiB --skip-regularize --no-eval 2>&1 | tail -1
}
echo "fuse to disk: $(fuse disk)"
echo "fuse to S3:   $(fuse s3://bench/city)"
"$BIN" inspect disk | sed 's/^/  /'
lambda=0.70
for where in disk s3://bench/city; do
  for n in 1 2 4; do
    lambda=$(python3 -c "print(round($lambda + 0.01, 2))")
    flags=(--lambda "$lambda" --iterations "$IT" --region-chunks "$RC" --memory-budget 1GiB --device cpu)
    t0=$(date +%s.%N)
    pids=()
    for ((i = 0; i < n; i++)); do
      "$BIN" regularize "$where" --shard "$i/$n" "${flags[@]}" >"shard_$i.txt" 2>&1 &
      pids+=($!)
    done
    for p in "${pids[@]}"; do wait "$p"; done
    t1=$(date +%s.%N)
    "$BIN" regularize "$where" "${flags[@]}" >final.txt 2>&1
    t2=$(date +%s.%N)
    python3 -c "print(f'regularize {\"$where\":<18} {$n} shards: {($t2-$t0):7.1f} s wall (shards {($t1-$t0):7.1f} s, commit {($t2-$t1):5.1f} s); load {open(\"/proc/loadavg\").read().split()[0]}')"
    grep -h "regularization pass" final.txt | sed 's/^/    /'
  done
done
"$BIN" reconstruct drive/sequences/00 --depth lidar --map half_a --out o --last $(( LEN / 4 )) \
  --memory-budget 1GiB --skip-regularize --no-eval >/dev/null 2>&1
"$BIN" reconstruct drive/sequences/00 --depth lidar --map half_b --out o --first $(( LEN / 4 )) \
  --memory-budget 1GiB --skip-regularize --no-eval >/dev/null 2>&1
echo "one process, paper settings (100 iterations, regions of 2 chunks): $(/usr/bin/time -f '%e s wall, %U s user, %S s sys, %M KiB peak' "$BIN" regularize disk --lambda 0.9 --iterations 100 --region-chunks 2 --device cpu 2>&1 | tail -1)"
echo "export mesh: $(/usr/bin/time -f '%e s wall, %U s user, %M KiB peak' "$BIN" export disk --mesh m.ply 2>&1 | tail -1)"
echo "merge: $(/usr/bin/time -f '%e s wall, %M KiB peak' "$BIN" merge half_a half_b --out merged 2>&1 | tr '\n' ' ')"
