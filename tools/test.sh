#!/usr/bin/env bash
# Quick start 2: the whole test suite from scratch. Installs what is missing, checks formatting,
# builds and runs the unit tests under ASan+UBSan, then builds the plain (optimised) tree of the
# product and runs the tests that need it: system tests on real vcan in the rig and the checks
# that are not unit tests; last, the unit tests cross-built for armhf run under qemu-arm.
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

# The container image test (tests/container/, `ctest -L image`) builds the image from the plain
# tree's own executables (Dockerfile target `prebuilt`). What it needs from the network is made
# here in the background while the trees compile: podman and debootstrap, the Debian base
# (debootstrap) and the image's runtime layers (apt in the `runtime-base` stage, cached by
# podman), so that the test itself only copies the executables in and checks the image.
image_prep_log=/tmp/canbridge-image-prep.log
# One apt at a time: the two background jobs take turns on this lock.
apt_lock=/tmp/canbridge-apt.lock
# Both background jobs run at the lowest weight (below): unpacking packages and building the
# image's layers took CPU from the sanitizer build while it waits for nothing until the image test.
lowest_weight() {
  local sid_file=$1
  shift
  nice -n 19 setsid --wait bash -c \
    'echo $$ >"$0"; echo 19 >/proc/self/autogroup 2>/dev/null; exec "$@"' "$sid_file" "$@"
}
image_prep_session=/tmp/canbridge-image-prep.sid
rm -f "$image_prep_session"
{
  flock "$apt_lock" env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
    --no-install-recommends podman debootstrap docker-compose &&
    IMAGE=localhost/canbridge-runtime-base:warm lowest_weight "$image_prep_session" \
      "$root/docker/build.sh" -- --target runtime-base
} >"$image_prep_log" 2>&1 &
image_prep_pid=$!

# The last phase runs the unit tests cross-built for armhf under qemu-arm. Their cross build
# (~740 s of CPU) starts now, in a session of its own whose autogroup has the lowest weight
# (nice 19): it takes only the CPU time the native trees and the rig tests leave unused (link
# steps, single-threaded fuzz runs, tests waiting on timers), which would otherwise be lost, and
# yields at once when they want it back. The phase then finishes what is left and runs the tests.
# (The weights are relative: run from a session whose own autogroup is niced, the native trees
# lose that advantage; one such run took 615 s instead of ~460 s for its sanitizer build.)
armhf_tree=$root/build-armhf-ci
# The product's libraries compile at the shipped -O2; the test programs' own code at -O0, which
# tests the product's code the same and compiled one test source in 14.8 s against 19.6 s
# (glibc's _FORTIFY_SOURCE needs optimisation, so it is off there).
armhf_cmake_args=(-DCANBRIDGE_UNITY_BUILD=ON -DCANBRIDGE_TEST_EACH_CASE=OFF
  "-DCANBRIDGE_TEST_PROGRAM_OPTIONS=-O0;-U_FORTIFY_SOURCE")
armhf_build_log=/tmp/canbridge-armhf-build.log
armhf_session=/tmp/canbridge-armhf-build.sid
rm -rf "$armhf_tree" "$armhf_session"
{
  flock "$apt_lock" "$root/tools/install-cross-deps.sh" armhf &&
    CANBRIDGE_CROSS_BUILD_ONLY=1 lowest_weight "$armhf_session" \
      "$root/tools/cross-build.sh" armhf "$armhf_tree" -- "${armhf_cmake_args[@]}"
} >"$armhf_build_log" 2>&1 &
armhf_build_pid=$!
# clang's check of every source (tools/clang-check.sh: parse and warn only, no code), also in the
# background at the lowest weight: CI's trees are GCC's, and sources only clang refuses reached
# main unseen before. Its result is read before the armhf phase.
clang_check_log=/tmp/canbridge-clang-check.log
clang_check_session=/tmp/canbridge-clang-check.sid
rm -rf "$root/build-clang-check" "$clang_check_session"
lowest_weight "$clang_check_session" "$root/tools/clang-check.sh" "$root/build-clang-check" \
  >"$clang_check_log" 2>&1 &
clang_check_pid=$!
# A failing phase ends this script early: the build's session (compilers included) goes with it.
# The trap must not fail itself: under `set -e` a failing command in it (pkill finding nothing
# left in the session, the normal case at the end of a green run) becomes the script's status.
stop_background_jobs() {
  local sid_file
  for sid_file in "$armhf_session" "$image_prep_session" "$clang_check_session"; do
    if [[ -s $sid_file ]]; then
      pkill -s "$(cat "$sid_file")" 2>/dev/null || true
    fi
  done
}
trap stop_background_jobs EXIT

phase "sanitizer build (ASan+UBSan): unit tests"
rm -rf "$root/build-asan"
# Both trees compile in unity batches (CANBRIDGE_UNITY_BUILD): ~40 % less compiler time from
# scratch, which is all this script ever builds.
# -g1: line tables are all a sanitizer report needs, at a fraction of full debug info's build time.
# lld links this tree's 57 executables in 30 s against ~56 s for GNU ld (ASan-instrumented test
# programs are large); the product tree keeps the system's default linker, as a user builds.
cmake -S "$root" -B "$root/build-asan" -G Ninja -DCMAKE_BUILD_TYPE=Debug -DCMAKE_CXX_FLAGS_DEBUG=-g1 \
  -DCMAKE_EXE_LINKER_FLAGS=-fuse-ld=lld \
  -DCANBRIDGE_SANITIZE=ON -DCANBRIDGE_SYSTEM_TESTS=OFF -DCANBRIDGE_BENCH_TOOLS=OFF \
  -DCANBRIDGE_TEST_EACH_CASE=OFF -DCANBRIDGE_UNITY_BUILD=ON -DCANBRIDGE_WERROR=ON \
  -DCANBRIDGE_TEST_PROGRAM_OPTIONS="-fno-sanitize=vptr,null,alignment" >/dev/null
cmake --build "$root/build-asan" -j "$jobs"
phase "unit tests under the sanitizers"
ctest --test-dir "$root/build-asan" -L unit -j "$jobs" --output-on-failure

phase "fuzzing (clang, libFuzzer): a short run of every target (docs/fuzzing.md for long runs)"
rm -rf "$root/build-fuzz"
"$root/tools/fuzz.sh" --seconds 5 "$root/build-fuzz"

phase "build: the product, system tests in the rig"
# The product tree of the quick start (tools/product-tree.sh), which tools/demo.sh has built when
# .ci/run ran it first: the product compiles once per run, as a user builds it (-O2, warnings
# not errors), and any warning an object of the tree was compiled with then fails this phase
# (tools/keep-warnings.sh). Added here: the system tests and the programs of the rig, those
# compiled at -O0 (they drive the product's processes and mostly wait on them).
# The unit tests ran above under the sanitizers and are not built here. The image test checks
# the image made from this tree's executables (the from-source image, which compiles the product
# once more inside its build stage, takes 12-14 minutes here and is built by `docker/build.sh`,
# docker/README.md). bench/ is left out (the benches run in their own sittings, bench/README.md;
# `cmake --build build` of a developer tree builds them).
# shellcheck source=tools/product-tree.sh
source "$root/tools/product-tree.sh"
cmake -S "$root" -B "$product_tree" "${product_tree_flags[@]}" -DCANBRIDGE_BUILD_TESTS=ON \
  -DCANBRIDGE_UNIT_TESTS=OFF -DCANBRIDGE_SYSTEM_TESTS=ON -DCANBRIDGE_IMAGE_TEST=ON \
  -DCANBRIDGE_IMAGE_TEST_PREBUILT=ON -DCANBRIDGE_BENCH_TOOLS=OFF \
  -DCANBRIDGE_RIG_PROGRAM_OPTIONS=-O0 >/dev/null
cmake --build "$product_tree" -j "$jobs"
mapfile -t warned < <(find "$product_tree" -name '*.o.warnings' | sort)
if ((${#warned[@]})); then
  cat "${warned[@]}"
  echo "test: ${#warned[@]} object(s) of $product_tree compiled with warnings (above)" >&2
  exit 1
fi
phase "system tests and the other checks of the plain build"
# One apt at a time: the background preparation must be done before a test could install.
wait "$image_prep_pid" ||
  echo "image preparation failed (see $image_prep_log); the image test makes what it needs itself"
ctest --test-dir "$product_tree" -j "$jobs" --output-on-failure

phase "clang: every source compiled by clang 14 with -Werror (tools/clang-check.sh)"
if ! wait "$clang_check_pid"; then
  grep -E -B2 -A6 'error:|warning:' "$clang_check_log" | head -80 || tail -40 "$clang_check_log"
  echo "test: clang refused sources (full log: $clang_check_log)" >&2
  exit 1
fi
tail -1 "$clang_check_log"

phase "armhf (the gateway's 32-bit ARM boards): cross build, unit tests under qemu-arm"
# The unit tests once more, compiled for the board by Debian's cross compiler (the product at the
# shipped -O2) and run by qemu-user: 32-bit size_t and time_t, unsigned char, ARM alignment. arm64 is built
# and tested the same way by tools/cross-build.sh arm64 (docs/cross-build.md): a second
# architecture would not fit the run's 25 minutes.
wait "$armhf_build_pid" ||
  echo "the background armhf build failed (see $armhf_build_log); building again here"
"$root/tools/cross-build.sh" armhf "$armhf_tree" -- "${armhf_cmake_args[@]}"
phase "done"
