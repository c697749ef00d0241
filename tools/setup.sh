#!/usr/bin/env bash
# Installs what the tests need beyond the Rust toolchain. Idempotent; safe to run on a fresh machine.
# Every install may fail (no network, no root): the tests that need a tool then print
# "skipped: <reason>" and pass.
set -uo pipefail
cd "$(dirname "$0")/.."
need=()
if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
  # Mesa's software Vulkan (lavapipe) lets the GPU tests run on the CPU.
  dpkg -s mesa-vulkan-drivers >/dev/null 2>&1 || need+=(mesa-vulkan-drivers libvulkan1)
  # Headless Chromium opens the 3D Tiles export in a real browser (tests/export_tiles.rs).
  dpkg -s chromium >/dev/null 2>&1 || need+=(chromium)
  if [ ${#need[@]} -gt 0 ]; then
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq && apt-get install -y -qq "${need[@]}" >/dev/null || echo "setup: could not install ${need[*]} (the tests that need them will skip)"
  fi
  # PDAL's command line reads LAS/COPC independently where the distribution ships it (Debian 12
  # does not; newer releases do).
  if ! command -v pdal >/dev/null 2>&1 && apt-cache show pdal >/dev/null 2>&1; then
    apt-get install -y -qq pdal >/dev/null || echo "setup: could not install pdal"
  fi
fi
# Independent readers of the LAS/LAZ/COPC exports (tests/export_world.rs, tests/export_copc.rs).
if command -v python3 >/dev/null 2>&1; then
  python3 -c "import laspy, lazrs, pyproj" >/dev/null 2>&1 \
    || python3 -m pip install -q "laspy==2.7.0" "lazrs==0.8.2" "pyproj==3.7.2" >/dev/null 2>&1 \
    || echo "setup: could not install laspy/lazrs/pyproj (the tests that need them will skip)"
fi
# Independent writers of the input fixtures (ROS 2 bags, PCD/PLY scans) that
# tools/make_input_fixtures.py makes for the reader tests.
if command -v python3 >/dev/null 2>&1; then
  python3 -c "import rosbags, pypcd4, plyfile, PIL" >/dev/null 2>&1 \
    || python3 -m pip install -q "rosbags==0.11.9" "pypcd4==1.5.1" "plyfile==1.1.5" "pillow==11.3.0" >/dev/null 2>&1 \
    || echo "setup: could not install rosbags/pypcd4/plyfile/pillow (the tests that need them will skip)"
fi
# A real S3-compatible server for the object-storage tests (tests/tiles/scaleout.rs,
# tests/cli/scaleout.rs start `moto_server -H 127.0.0.1 -p PORT` themselves).
if command -v python3 >/dev/null 2>&1; then
  command -v moto_server >/dev/null 2>&1 \
    || python3 -m pip install -q "moto[server]==5.2.5" >/dev/null 2>&1 \
    || echo "setup: could not install moto[server] (the S3 tests will skip)"
fi
# The glTF validator and the three.js 3D Tiles viewer (tools/web/package.json, locked).
if command -v npm >/dev/null 2>&1 && [ ! -d tools/web/node_modules/3d-tiles-renderer ]; then
  (cd tools/web && npm ci --no-audit --no-fund >/dev/null 2>&1) \
    || echo "setup: npm ci in tools/web failed (the 3D Tiles browser and validator tests will skip)"
fi
exit 0
