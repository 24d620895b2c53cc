#!/usr/bin/env bash
# Quick start 2: the whole test suite from scratch. Installs what is missing, checks formatting,
# builds and runs the unit tests under ASan+UBSan, then builds the plain (optimised) tree of the
# product and runs the tests that need it: system tests on real vcan in the rig and the checks
# that are not unit tests, ending with ctest's summary.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
jobs=$(nproc)
# Each phase's wall time, so that the run's budget (25 minutes in CI) is spent where it is seen.
started=$SECONDS
phase_started=$SECONDS
phase() {
  echo "=== $1 (previous phase $((SECONDS - phase_started)) s, $((SECONDS - started)) s so far)"
  phase_started=$SECONDS
}
"$root/tools/install-deps.sh"
"$root/tools/format.sh" --check

phase "sanitizer build (ASan+UBSan): unit tests"
rm -rf "$root/build-asan"
# Both trees compile in unity batches (CANBRIDGE_UNITY_BUILD): ~40 % less compiler time from
# scratch, which is all this script ever builds.
# -g1: line tables are all a sanitizer report needs, at a fraction of full debug info's build time.
cmake -S "$root" -B "$root/build-asan" -G Ninja -DCMAKE_BUILD_TYPE=Debug -DCMAKE_CXX_FLAGS_DEBUG=-g1 \
  -DCANBRIDGE_SANITIZE=ON -DCANBRIDGE_SYSTEM_TESTS=OFF -DCANBRIDGE_BENCH_TOOLS=OFF \
  -DCANBRIDGE_TEST_EACH_CASE=OFF -DCANBRIDGE_UNITY_BUILD=ON >/dev/null
cmake --build "$root/build-asan" -j "$jobs"
phase "unit tests under the sanitizers"
ctest --test-dir "$root/build-asan" -L unit -j "$jobs" --output-on-failure

phase "fuzzing (clang, libFuzzer): a short run of every target (docs/fuzzing.md for long runs)"
rm -rf "$root/build-fuzz"
"$root/tools/fuzz.sh" --seconds 5 "$root/build-fuzz"

phase "build: the product, system tests in the rig"
rm -rf "$root/build"
# The product's optimisation (-O2, as the default RelWithDebInfo) without debug info: nobody
# debugs these binaries, and leaving -g out keeps the whole run well inside its time budget.
# The unit tests ran above under the sanitizers; building them a second time here cost four of
# the run's 25 minutes to repeat what the sanitizer build already checks.
# The container image test (tests/container/, `ctest -L image`) is not part of this run yet: built
# from source on a fresh machine the image takes 12-14 minutes of an idle 2-core machine (a
# debootstrap base, apt in two stages, the product compiled a third time), which the run's
# 25-minute budget does not hold. Run it on its own: cmake -DCANBRIDGE_IMAGE_TEST=ON, then
# ctest --test-dir build -L image (docker/README.md). bench/ is left out too (the benches run in
# their own sittings, bench/README.md; `cmake --build build` of a developer tree builds them).
cmake -S "$root" -B "$root/build" -G Ninja -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O2 -DNDEBUG" \
  -DCANBRIDGE_UNIT_TESTS=OFF -DCANBRIDGE_IMAGE_TEST=OFF -DCANBRIDGE_BENCH_TOOLS=OFF \
  -DCANBRIDGE_UNITY_BUILD=ON >/dev/null
cmake --build "$root/build" -j "$jobs"
phase "system tests and the other checks of the plain build"
ctest --test-dir "$root/build" -j "$jobs" --output-on-failure
phase "done"
