#!/usr/bin/env bash
# Backbone session throughput and wire cost: CAN frames through a FrameOutbox, a gateway and a
# surface session end in one process, over TCP loopback and an emulated 115200 bit/s line (TCP,
# pty pair, pty pair at BER 1e-4). Needs no vcan, so it runs on the host, not in the rig.
#
#   bench/backbone_bench.sh [BUILD_DIR] [BENCH OPTIONS...]   (default: build-bench, 5 runs)
#   e.g. bench/backbone_bench.sh build-bench --runs 3 --scenario serial-emulated-115200
#
# Configures BUILD_DIR as a Release build without tests (a bench must not measure a debug or
# sanitizer build), builds the bench and canbridge-link-emulator, and runs the bench; it prints
# every run, the medians with min/max, and one RESULT line per scenario. canbridge-backbone-bench
# --help lists the options.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(dirname "$here")
build=$root/build-bench
if [[ $# -gt 0 && $1 != -* ]]; then
  build=$1
  shift
fi

# Build output only when the build fails, so the bench's own output stays a clean table.
log=$(mktemp /tmp/canbridge-backbone-bench-build.XXXXXX)
trap 'rm -f "$log"' EXIT
if ! { cmake -S "$root" -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=Release \
  -DCANBRIDGE_BUILD_TESTS=OFF -DCANBRIDGE_SYSTEM_TESTS=OFF &&
  cmake --build "$build" --target canbridge-backbone-bench canbridge-link-emulator; } >"$log" 2>&1; then
  cat "$log" >&2
  exit 1
fi
"$build/bench/canbridge-backbone-bench" \
  --emulator "$build/tools/link_emulator/canbridge-link-emulator" "$@"
