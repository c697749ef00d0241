#!/usr/bin/env bash
# Installs what the tests need beyond the Rust toolchain. Idempotent; safe to run on a fresh machine.
set -euo pipefail
need=()
if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
  # Mesa's software Vulkan (lavapipe) lets the GPU tests run on the CPU.
  dpkg -s mesa-vulkan-drivers >/dev/null 2>&1 || need+=(mesa-vulkan-drivers libvulkan1)
  if [ ${#need[@]} -gt 0 ]; then
    apt-get update -qq && apt-get install -y -qq "${need[@]}" >/dev/null || echo "setup: could not install ${need[*]} (GPU tests will skip)"
  fi
fi
