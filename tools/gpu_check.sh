#!/usr/bin/env bash
# The GPU tier on a hardware GPU, two builds side by side on one machine: the GPU tests, then
# `reconstruct` of a 60 m synthetic drive's ground-truth depth (fusion per frame, the GPU tier's
# steps, the TV solve, the GPU traffic per stage) and of a 150 m LiDAR drive, with `--device gpu`
# for both builds and `--device cpu` for the second, in alternating rounds, and the depth drive
# paged through a 40 MiB budget (`--map`) with `--device gpu` for both builds; the meshes of the
# two builds are compared byte for byte. Before the drives, the second build's `denser bench` on the
# 60 m drive's depth with `--device gpu` (each kernel's device time from timestamp queries, and
# marching cubes) and `--device cpu`, and its TGV-tensor stereo kernels on one pair; after the
# drives, the second build's stereo on the depth drive's first GPU_CHECK_STEREO_FRAMES frames
# (default 20) with `--device gpu` and `--device cpu`; then the LiDAR drive and five stereo frames
# again with `--kernel-times` (each kernel's device time). The second build's GPU runs log the GPU
# mesher's host phases (debug). Meshes that differ are compared vertex by vertex
# (tools/ply_diff.py, where python3 has numpy). Everything goes to one log (docs/bench/gpu.md
# quotes it).
#
#   [GPU_TESTS=GPU_TEST_BINARY] tools/gpu_check.sh BEFORE_DENSER AFTER_DENSER OUT_DIR [ROUNDS]
#
# GPU_TESTS: the release build of `tests/gpu` (`cargo test --release --test gpu --no-run`), run
# first.
# The binaries may be zstd- or gzip-compressed (`.zst`, `.gz`: unpacked to a temporary folder).
# GPU_CHECK_DEPTH_M and GPU_CHECK_LIDAR_M shorten the drives (60 and 150 m) for a trial run.
# On the lent machines: carry .gl (Debian's libvulkan1, see the device notes) and the binaries.
set -uo pipefail
[ $# -ge 3 ] || { echo "usage: [GPU_TESTS=BIN] $0 BEFORE AFTER OUT [ROUNDS]" >&2; exit 2; }
before=$1 after=$2 out=$3 rounds=${4:-3} tests=${GPU_TESTS:-}
mkdir -p "$out"
work=$(mktemp -d)
log=$out/gpu_check.log
: >"$log"
say() { echo "$*" | tee -a "$log"; }

unpack() { # FILE NAME -> path of an executable
    case $1 in
    *.zst) zstd -dq "$1" -o "$work/$2" ;;
    *.gz) gzip -dc "$1" >"$work/$2" ;;
    *) cp "$1" "$work/$2" ;;
    esac
    chmod +x "$work/$2"
    echo "$work/$2"
}
before=$(unpack "$before" before)
after=$(unpack "$after" after)
[ -n "$tests" ] && tests=$(unpack "$tests" gpu-tests)

say "## machine"
{ nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.max.sm --format=csv 2>&1
  echo "cores: $(nproc)"; uname -r; date -u; } | tee -a "$log"
say "before: $("$before" --version)   after: $("$after" --version)"

if [ -n "$tests" ]; then
    # One test at a time: with four at once (four devices in one process) the binary did not
    # finish on the H100 (docs/bench/gpu.md, run 11).
    say "## GPU tests (after)"
    (cd "$work" && "$tests" --test-threads 1 --nocapture 2>&1) | grep -E "^test |test result|GPU:|SKIPPED|not bit-identical" | tee -a "$log"
fi

say "## drives"
depth_m=${GPU_CHECK_DEPTH_M:-60} lidar_m=${GPU_CHECK_LIDAR_M:-150}
"$after" synth --length-m "$depth_m" --seed 1 --out "$work/d60" >/dev/null 2>&1 ||
    say "synth $depth_m m failed"
"$after" synth --length-m "$lidar_m" --lidar-only --seed 8 --out "$work/d150" >/dev/null 2>&1 ||
    say "synth $lidar_m m failed"

say "## kernel device times and the benchmark, GPU then CPU (after)"
seq60=$work/d60/sequences/00
for dev in gpu cpu; do
    say "### bench --device $dev on the $depth_m m drive's depth"
    "$after" bench --device "$dev" --rgbd "$seq60" --passes 3 2>&1 | tee -a "$log" >/dev/null
done
say "### stereo --method tgv-tensor --device gpu --kernel-times (frame 0 of the $depth_m m drive)"
"$after" stereo "$seq60/image_2/000000.png" "$seq60/image_3/000000.png" --out "$work/disp.pfm" \
    --method tgv-tensor --device gpu --kernel-times 2>&1 | tee -a "$log" >/dev/null

run() { # NAME BINARY ARGS...: one reconstruct, its summary into the log
    local name=$1 bin=$2 rust_log=info
    shift 2
    [ "$bin" = "$after" ] && rust_log=info,denser::mesh::gpu=debug
    say "### $name: reconstruct $*"
    local t0=$(date +%s%N)
    RUST_LOG=$rust_log "$bin" reconstruct "$@" --no-eval --out "$work/$name" 2>&1 | tee -a "$log" >/dev/null
    say "wall: $(( ($(date +%s%N) - t0) / 1000000 )) ms"
}

for r in $(seq 1 "$rounds"); do
    for b in after before; do
        bin=$after; [ $b = before ] && bin=$before
        run "depth-$b-gpu-$r" "$bin" "$work/d60/sequences/00" --depth gt --device gpu
    done
    run "depth-after-cpu-$r" "$after" "$work/d60/sequences/00" --depth gt --device cpu
done
for b in after before; do
    bin=$after; [ $b = before ] && bin=$before
    run "lidar-$b-gpu" "$bin" "$work/d150/sequences/00" --depth lidar --device gpu
done
run "lidar-after-cpu" "$after" "$work/d150/sequences/00" --depth lidar --device cpu
# The depth drive paged through a 40 MiB budget (chunks evicted while frames are in flight).
for b in after before; do
    bin=$after; [ $b = before ] && bin=$before
    run "paged-$b-gpu" "$bin" "$work/d60/sequences/00" --depth gt --device gpu \
        --map "$work/map-$b" --memory-budget 40MiB --skip-regularize
done
last=$(( ${GPU_CHECK_STEREO_FRAMES:-20} - 1 ))
for dev in gpu cpu; do
    run "stereo-after-$dev" "$after" "$work/d60/sequences/00" --depth stereo --last "$last" \
        --device "$dev" --skip-regularize
done
say "## kernel device times of whole runs (after; timing adds a wait per submit: not for wall times)"
run "lidar-after-gpu-timed" "$after" "$work/d150/sequences/00" --depth lidar --device gpu --kernel-times
run "stereo-after-gpu-timed" "$after" "$work/d60/sequences/00" --depth stereo --last 4 \
    --device gpu --skip-regularize --kernel-times

say "## meshes, before against after (GPU)"
for pair in depth-%s-gpu-1 lidar-%s-gpu paged-%s-gpu; do
    a=$work/$(printf "$pair" after) b=$work/$(printf "$pair" before)
    for f in "$a"/*.ply; do
        if cmp -s "$f" "$b/$(basename "$f")"; then say "identical: $(basename "$a")/$(basename "$f")"
        else
            say "DIFFERENT: $(basename "$a")/$(basename "$f")"
            python3 "$(dirname "$0")/ply_diff.py" "$f" "$b/$(basename "$f")" 0.1 2>&1 | tee -a "$log"
        fi
    done
done
rm -rf "$work"
