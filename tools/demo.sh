#!/usr/bin/env bash
# Quick start 1: install what is missing, build, and run canbridge's embedded default (the demo
# rig: gateway and surface in one process on virtual buses with simulated CANopen nodes).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
"$root/tools/install-deps.sh"
cmake -S "$root" -B "$root/build-demo" -G Ninja -DCMAKE_BUILD_TYPE=Release -DCANBRIDGE_BUILD_TESTS=OFF >/dev/null
cmake --build "$root/build-demo" --target canbridge
exec "$root/build-demo/app/canbridge" demo "$@"
