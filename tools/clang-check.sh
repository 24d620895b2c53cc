#!/usr/bin/env bash
# Holds every source of the project to clang's warnings: configures TREE with clang and the
# project's warning flags plus -Werror, and builds every target (product, unit and system tests,
# rig programs, benches) in check-only mode: each unit is parsed, its templates instantiated and
# its warnings reported (-fsyntax-only), no code is generated and nothing is linked. CI's trees
# are GCC's; without this, sources that only clang refuses (Debian 12's clang 14 lacks some C++20
# GCC 12 accepts; unity batches shadow names across files) reached main unseen (issue 28).
# About 2 minutes of two idle cores from scratch (1 min 50 s and 2 min 8 s, measured on this
# project's build machine); a real clang build of the tree was not timed.
#
#   tools/clang-check.sh [TREE]          (default: build-clang-check/ in the checkout)
#
# The tree calls this script back as its compiler launcher (--compile) and its linker launcher
# (--link); those modes are not for use by hand.
set -euo pipefail

# Output of a compiler or linker command line: the argument after -o.
output_of() {
  local out='' prev=''
  for arg in "$@"; do
    [[ $prev == -o ]] && out=$arg
    prev=$arg
  done
  printf '%s' "$out"
}

case "${1:-}" in
  --compile)
    shift
    "$@" -fsyntax-only
    # An empty object in its place: archives of the tree are made of them, so that every target
    # that depends on a library still builds (its own sources checked the same way).
    out=$(output_of "$@")
    [[ -z $out ]] || exec "$1" -c -x c /dev/null -o "$out"
    exit 0
    ;;
  --link)
    shift
    # A program some step runs (a test lister, a man page generator) finds one that does nothing.
    out=$(output_of "$@")
    [[ -z $out ]] || { printf '#!/bin/sh\nexit 0\n' >"$out" && chmod +x "$out"; }
    exit 0
    ;;
esac

root=$(cd "$(dirname "$0")/.." && pwd)
tree=${1:-$root/build-clang-check}
self=$root/tools/clang-check.sh
for tool in clang clang++; do
  command -v "$tool" >/dev/null || {
    echo "clang-check: $tool not found; run tools/install-deps.sh" >&2
    exit 2
  }
done
# Unity batches, as every tree CI builds: names one file declares then meet another's.
CC=clang CXX=clang++ cmake -S "$root" -B "$tree" -G Ninja -DCMAKE_BUILD_TYPE=Debug \
  -DCMAKE_CXX_FLAGS_DEBUG= -DCANBRIDGE_WERROR=ON -DCANBRIDGE_UNITY_BUILD=ON \
  -DCANBRIDGE_TEST_EACH_CASE=OFF \
  "-DCMAKE_CXX_COMPILER_LAUNCHER=$self;--compile" "-DCMAKE_CXX_LINKER_LAUNCHER=$self;--link" \
  >/dev/null
# Objects only: the rest of the tree (man pages made by running the programs) means nothing here.
mapfile -t objects < <(ninja -C "$tree" -t targets all | sed -n 's/^\([^:]*\.o\): .*/\1/p')
if ! ninja -C "$tree" -k 0 "${objects[@]}"; then
  echo "clang-check: clang refused the sources above (warnings are errors here)" >&2
  exit 1
fi
echo "clang-check: ${#objects[@]} compilation units clean with $(clang++ --version | head -1)"
