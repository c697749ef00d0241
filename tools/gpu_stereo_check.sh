#!/usr/bin/env bash
# Stereo on a hardware GPU against the same machine's CPU cores, one build (issue 35): a short
# synthetic drive's stereo pairs matched by `reconstruct --depth stereo` with SGM and with
# TGV-tensor, `--device gpu` and `--device cpu` in alternating rounds (the summary's "stereo on
# DEVICE: X ms per frame", reading and matching; fusion's own line beside it), then one pair of
# each method with `stereo --kernel-times` (each kernel's device time); then a 60 m LiDAR drive
# fused on either device (rounds), and its map exported with the chunks meshed on the GPU and on
# the CPU (`export --device`). One log (docs/bench/gpu.md quotes it).
#
#   tools/gpu_stereo_check.sh DENSER OUT_DIR [ROUNDS] [FRAMES]
#
# DENSER may be zstd- or gzip-compressed (`.zst`, `.gz`). ROUNDS: 3; FRAMES: 10 per run.
# On the lent machines: carry .gl (Debian's libvulkan1, see the device notes) and the binary.
set -u
bin=$1 out=$2 rounds=${3:-3} frames=${4:-10}
mkdir -p "$out"
log=$out/gpu_stereo_check.log
work=$(mktemp -d)
say() { echo "$*" | tee -a "$log"; }
case $bin in
    *.zst) zstd -dq "$bin" -o "$work/denser" ;;
    *.gz) gzip -dc "$bin" >"$work/denser" ;;
    *) cp "$bin" "$work/denser" ;;
esac
chmod +x "$work/denser"
d=$work/denser
say "# gpu_stereo_check $(date -u +%FT%TZ) on $(hostname), $(nproc) cores"
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader 2>/dev/null | sed 's/^/GPU: /' | tee -a "$log"
"$d" --version 2>&1 | tee -a "$log"
"$d" synth --out "$work/drive" --length-m 14 --seed 3 >/dev/null 2>&1 || say "synth failed"
seq=$work/drive/sequences/00
for round in $(seq 1 "$rounds"); do
    for method in sgm tgv-tensor; do
        for dev in gpu cpu; do
            say "### round $round: $method on $dev"
            "$d" reconstruct "$seq" --depth stereo --method "$method" --last $((frames - 1)) \
                --device "$dev" --skip-regularize --no-eval --out "$work/r" 2>&1 |
                grep -E "^(stereo on|fused|GPU traffic|  depth|  stereo)" | tee -a "$log"
        done
    done
done
for method in sgm tgv-tensor; do
    say "### stereo --method $method --device gpu --kernel-times (frame 0)"
    "$d" stereo "$seq/image_2/000000.png" "$seq/image_3/000000.png" --out "$work/x.pfm" \
        --method "$method" --device gpu --kernel-times 2>&1 | grep -v "^20" | tee -a "$log" >/dev/null
    "$d" stereo "$seq/image_2/000000.png" "$seq/image_3/000000.png" --out "$work/y.pfm" \
        --method "$method" --device cpu 2>&1 | grep "matched in" | tee -a "$log" >/dev/null
    if cmp -s "$work/x.pfm" "$work/y.pfm"; then say "$method: GPU and CPU disparities identical"
    else say "$method: GPU and CPU disparities differ"; fi
done
"$d" synth --out "$work/lidar" --length-m 60 --lidar-only --seed 3 >/dev/null 2>&1 || say "synth failed"
for round in $(seq 1 "$rounds"); do
    for dev in gpu cpu; do
        say "### round $round: the 60 m LiDAR drive's fusion on $dev"
        "$d" reconstruct "$work/lidar/sequences/00" --depth lidar --device "$dev" --skip-regularize \
            --no-eval --out "$work/r3" 2>&1 | grep -E "^(fused|GPU traffic per LiDAR|GPU tier)" |
            tee -a "$log"
    done
done
say "### export: the 60 m LiDAR map's raw mesh, chunks meshed with --device gpu and cpu"
"$d" reconstruct "$work/lidar/sequences/00" --depth lidar --map "$work/map" --skip-regularize \
    --no-eval --out "$work/r2" >/dev/null 2>&1 || say "mapping failed"
for round in $(seq 1 "$rounds"); do
    for dev in gpu cpu; do
        "$d" export "$work/map" --raw --mesh "$work/$dev.ply" --device "$dev" 2>&1 |
            grep -E "^wrote" | sed "s/^/round $round, $dev: /" | tee -a "$log"
    done
done
if cmp -s "$work/gpu.ply" "$work/cpu.ply"; then say "export: GPU and CPU meshes identical"
else say "export: GPU and CPU meshes differ (vertices within the stated tolerance)"; fi
rm -rf "$work"
