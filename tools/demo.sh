#!/usr/bin/env bash
# Quick start 1: install what is missing, build, and run canbridge's embedded default (the demo
# rig: gateway and surface in one process on virtual buses with simulated CANopen nodes).
# A user's build: warnings stay warnings (CANBRIDGE_WERROR is off), so a newer compiler's new
# warning cannot stop the quick start. The tree compiles in unity batches: a first build from
# scratch, which is what this script nearly always does, takes about 40 % less compiler time.
# .ci/run runs this script exactly as the README writes it, so the quick start is checked on
# every submission.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
"$root/tools/install-deps.sh"
# -O2, the optimisation every shipped build uses (the .deb, the image, the ARM builds): GCC 12 at
# Release's default -O3 took 7 minutes for this one executable on a 2-core machine.
cmake -S "$root" -B "$root/build-demo" -G Ninja -DCMAKE_BUILD_TYPE=Release \
  -DCMAKE_CXX_FLAGS_RELEASE="-O2 -DNDEBUG" -DCANBRIDGE_BUILD_TESTS=OFF \
  -DCANBRIDGE_UNITY_BUILD=ON >/dev/null
cmake --build "$root/build-demo" --target canbridge
exec "$root/build-demo/app/canbridge" demo "$@"
