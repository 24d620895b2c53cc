# Shared part of the Debian cross toolchain files (armhf.cmake, arm64.cmake): Debian's cross
# compiler for CANBRIDGE_CROSS_TRIPLET, the target's libraries from the sysroot that
# tools/install-cross-deps.sh unpacks, the build machine's protoc, and qemu-user to run what the
# build produces (ctest, gtest discovery).

set(CMAKE_SYSTEM_NAME Linux)
set(CMAKE_C_COMPILER ${CANBRIDGE_CROSS_TRIPLET}-gcc)
set(CMAKE_CXX_COMPILER ${CANBRIDGE_CROSS_TRIPLET}-g++)
set(CMAKE_LIBRARY_ARCHITECTURE ${CANBRIDGE_CROSS_TRIPLET})

# The environment, not a cache variable, so that try_compile projects see the same sysroot.
if(DEFINED ENV{CANBRIDGE_SYSROOT_BASE})
  set(CANBRIDGE_SYSROOT $ENV{CANBRIDGE_SYSROOT_BASE}/${CANBRIDGE_CROSS_ARCH})
else()
  set(CANBRIDGE_SYSROOT /opt/canbridge-sysroot/${CANBRIDGE_CROSS_ARCH})
endif()
if(NOT EXISTS ${CANBRIDGE_SYSROOT}/usr/include/google/protobuf)
  message(FATAL_ERROR "No ${CANBRIDGE_CROSS_ARCH} sysroot at ${CANBRIDGE_SYSROOT}: run "
                      "tools/install-cross-deps.sh ${CANBRIDGE_CROSS_ARCH} (or tools/cross-build.sh)")
endif()

# Not CMAKE_SYSROOT: libc, libstdc++ and the kernel headers are the cross compiler's own
# (/usr/<triplet>), and the sysroot holds only the libraries canbridge uses. Both are searched
# for target files; programs (protoc) come from the build machine.
set(CMAKE_FIND_ROOT_PATH ${CANBRIDGE_SYSROOT} /usr/${CANBRIDGE_CROSS_TRIPLET})
set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)
set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_PACKAGE ONLY)

# What Debian's multiarch layout means for the compiler without --sysroot: the
# architecture-specific headers (openssl/opensslconf.h, ...) sit in include/<triplet>, and the
# libraries' own dependencies (libprotobuf -> libz) must be found when linking.
set(CMAKE_CXX_STANDARD_INCLUDE_DIRECTORIES
    ${CANBRIDGE_SYSROOT}/usr/include/${CANBRIDGE_CROSS_TRIPLET} ${CANBRIDGE_SYSROOT}/usr/include)
set(CMAKE_C_STANDARD_INCLUDE_DIRECTORIES ${CMAKE_CXX_STANDARD_INCLUDE_DIRECTORIES})
set(canbridge_cross_lib_dirs ${CANBRIDGE_SYSROOT}/usr/lib/${CANBRIDGE_CROSS_TRIPLET}
                             ${CANBRIDGE_SYSROOT}/lib/${CANBRIDGE_CROSS_TRIPLET})
set(canbridge_cross_link_flags "")
foreach(dir ${canbridge_cross_lib_dirs})
  string(APPEND canbridge_cross_link_flags " -L${dir} -Wl,-rpath-link,${dir}")
endforeach()
set(CMAKE_EXE_LINKER_FLAGS_INIT "${canbridge_cross_link_flags}")
set(CMAKE_SHARED_LINKER_FLAGS_INIT "${canbridge_cross_link_flags}")
set(CMAKE_MODULE_LINKER_FLAGS_INIT "${canbridge_cross_link_flags}")

# pkg-config (FindOpenSSL asks it first) must describe the target's libraries, not the host's.
set(ENV{PKG_CONFIG_LIBDIR}
    "${CANBRIDGE_SYSROOT}/usr/lib/${CANBRIDGE_CROSS_TRIPLET}/pkgconfig:${CANBRIDGE_SYSROOT}/usr/share/pkgconfig")
set(ENV{PKG_CONFIG_SYSROOT_DIR} ${CANBRIDGE_SYSROOT})

# qemu-user runs target programs: -L makes the cross libc's loader (/lib/ld-linux-*.so.*) and
# libc/libstdc++ resolve under /usr/<triplet>; the sysroot's libraries come by LD_LIBRARY_PATH
# (of the emulated program, -E), so nothing of the sysroot's path ends up in the binaries.
string(REPLACE ";" ":" canbridge_cross_library_path "${canbridge_cross_lib_dirs}")
set(CMAKE_CROSSCOMPILING_EMULATOR
    ${CANBRIDGE_QEMU};-L;/usr/${CANBRIDGE_CROSS_TRIPLET};-E;LD_LIBRARY_PATH=${canbridge_cross_library_path})
# Test discovery when ctest runs, not after every link: building needs no emulator, and a
# loaded build machine cannot make qemu miss gtest_discover_tests' timeout mid-build.
set(CMAKE_GTEST_DISCOVER_TESTS_DISCOVERY_MODE PRE_TEST)
