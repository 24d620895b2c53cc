# Cross-compiles canbridge for Debian arm64 (64-bit ARMv8, AArch64): the gateway's ARM boards.
# Use: cmake -DCMAKE_TOOLCHAIN_FILE=cmake/toolchains/arm64.cmake (tools/cross-build.sh arm64).
set(CMAKE_SYSTEM_PROCESSOR aarch64)
set(CANBRIDGE_CROSS_ARCH arm64)
set(CANBRIDGE_CROSS_TRIPLET aarch64-linux-gnu)
set(CANBRIDGE_QEMU qemu-aarch64)
include(${CMAKE_CURRENT_LIST_DIR}/debian-cross.cmake)
