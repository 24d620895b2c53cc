#!/usr/bin/env bash
# Cross-builds canbridge for a Debian ARM architecture and runs its unit tests under qemu-user:
#   tools/cross-build.sh ARCH [BUILD_DIR [-- CMAKE_ARGS...]]
# ARCH: armhf or arm64; BUILD_DIR: build-ARCH; CMAKE_ARGS are added to the configure line
# (tools/test.sh passes -DCANBRIDGE_UNITY_BUILD=ON for its from-scratch tree).
# Installs what is missing (tools/install-cross-deps.sh), configures with
# cmake/toolchains/ARCH.cmake (Release, -O2, unit tests, no rig or bench programs), builds, runs
# `ctest -L unit` under qemu-user and prints the stripped size of the gateway executable.
# CANBRIDGE_JOBS sets the parallelism (default: nproc); CANBRIDGE_CROSS_BUILD_ONLY=1 stops after
# the build (tools/test.sh builds in the background and tests later). docs/cross-build.md has the
# details.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
usage() {
  echo "usage: $0 armhf|arm64 [BUILD_DIR [-- CMAKE_ARGS...]]" >&2
  exit 2
}
arch=${1:-}
case $arch in
  armhf) triplet=arm-linux-gnueabihf ;;
  arm64) triplet=aarch64-linux-gnu ;;
  *) usage ;;
esac
build=${2:-$root/build-$arch}
extra_cmake_args=()
if (($# > 2)); then
  [[ $3 == -- ]] || usage
  extra_cmake_args=("${@:4}")
fi
jobs=${CANBRIDGE_JOBS:-$(nproc)}

"$root/tools/install-cross-deps.sh" "$arch"

launcher=()
command -v ccache >/dev/null && launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
cmake -S "$root" -B "$build" -G Ninja -DCMAKE_TOOLCHAIN_FILE="$root/cmake/toolchains/$arch.cmake" \
  "${launcher[@]}" -DCMAKE_BUILD_TYPE=Release -DCMAKE_CXX_FLAGS_RELEASE="-O2 -DNDEBUG" \
  -DCANBRIDGE_UNIT_TESTS=ON -DCANBRIDGE_SYSTEM_TESTS=OFF -DCANBRIDGE_BENCH_TOOLS=OFF \
  -DCANBRIDGE_WERROR=ON "${extra_cmake_args[@]}" >/dev/null
cmake --build "$build" -j "$jobs"
[[ ${CANBRIDGE_CROSS_BUILD_ONLY:-0} == 1 ]] && exit 0

# Unit tests qemu-user cannot run faithfully; each entry is a ctest regex with its reason.
excluded=(
)
exclude_regex=$(IFS='|'; echo "${excluded[*]}")
echo "=== $arch: unit tests under $(grep -o 'qemu-[a-z0-9_]*' "$root/cmake/toolchains/$arch.cmake" | head -1)"
ctest --test-dir "$build" -L unit -j "$jobs" --output-on-failure ${exclude_regex:+-E "$exclude_regex"}

stripped=$(mktemp -d)
"$triplet-strip" -o "$stripped/canbridge" "$build/app/canbridge"
echo "=== $arch: stripped app/canbridge: $(stat -c %s "$stripped/canbridge") bytes"
rm -r "$stripped"
