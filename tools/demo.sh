#!/usr/bin/env bash
# Quick start 1: install what is missing, build, and run canbridge's embedded default (the demo
# rig: gateway and surface in one process on virtual buses with simulated CANopen nodes).
# It builds only the `canbridge` executable, in the product tree `build-quickstart/` (tools/product-tree.sh:
# a user's build, -O2, warnings not errors). .ci/run runs this script exactly as the README
# writes it, so the quick start is checked on every submission.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
# shellcheck source=tools/product-tree.sh
source "$root/tools/product-tree.sh"
"$root/tools/install-deps.sh"
cmake -S "$root" -B "$product_tree" "${product_tree_flags[@]}" -DCANBRIDGE_BUILD_TESTS=OFF >/dev/null
cmake --build "$product_tree" --target canbridge
exec "$product_tree/app/canbridge" demo "$@"
