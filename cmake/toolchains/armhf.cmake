# Cross-compiles canbridge for Debian armhf (32-bit ARMv7, hard float): the gateway's ARM boards.
# Use: cmake -DCMAKE_TOOLCHAIN_FILE=cmake/toolchains/armhf.cmake (tools/cross-build.sh armhf).
set(CMAKE_SYSTEM_PROCESSOR arm)
set(CANBRIDGE_CROSS_ARCH armhf)
set(CANBRIDGE_CROSS_TRIPLET arm-linux-gnueabihf)
set(CANBRIDGE_QEMU qemu-arm)
# GCC notes on every std::copy over deques that their argument passing changed in GCC 7.1 (the
# AAPCS psABI note): it concerns mixing objects built by GCC < 7.1, which nothing here does.
set(CMAKE_CXX_FLAGS_INIT -Wno-psabi)
include(${CMAKE_CURRENT_LIST_DIR}/debian-cross.cmake)
