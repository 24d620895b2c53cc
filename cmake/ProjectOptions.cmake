# Compiler settings for project code, carried by one interface target instead of global flags,
# so generated code (protobuf) and third-party headers are not held to our warning level.
add_library(canbridge_warnings INTERFACE)
# Warnings are errors in the developer and CI trees (tools/test.sh and tools/cross-build.sh turn
# this on), never in a user's build: a compiler newer than Debian 12's GCC 12 and clang 14 may
# warn about code they accept, and a user's build must not fail on that.
option(CANBRIDGE_WERROR "Treat compiler warnings as errors (developer and CI trees)" OFF)
target_compile_options(canbridge_warnings INTERFACE -Wall -Wextra $<$<BOOL:${CANBRIDGE_WERROR}>:-Werror>
                                                     -Wpedantic -Wshadow -Wnon-virtual-dtor
                                                     -Wold-style-cast)
# In a unity batch every source but the first is an included file, and GCC then reports the
# coroutine frames of functions using a type from an anonymous namespace (-Wsubobject-linkage),
# which is harmless when the batch is the only translation unit that sees the type.
if(CANBRIDGE_UNITY_BUILD AND CMAKE_CXX_COMPILER_ID STREQUAL "GNU")
  target_compile_options(canbridge_warnings INTERFACE -Wno-subobject-linkage)
endif()

add_library(canbridge_sanitizers INTERFACE)
if(CANBRIDGE_SANITIZE)
  target_compile_options(canbridge_sanitizers INTERFACE -fsanitize=address,undefined
                                                        -fno-omit-frame-pointer -fno-sanitize-recover=all)
  target_link_options(canbridge_sanitizers INTERFACE -fsanitize=address,undefined)
endif()

# Hardening as Debian builds its own packages (dpkg-buildflags; lintian's hardening checks on the
# .deb): stack protector, fortified libc calls where the compiler optimises (FORTIFY needs -O),
# and relocations read-only before main (-z relro -z now). Not with the sanitizers, which do
# those checks themselves and whose interceptors FORTIFY's wrappers would bypass.
add_library(canbridge_hardening INTERFACE)
if(NOT CANBRIDGE_SANITIZE)
  target_compile_options(canbridge_hardening INTERFACE -fstack-protector-strong
                         $<$<CONFIG:Release,RelWithDebInfo,MinSizeRel>:-D_FORTIFY_SOURCE=2>)
  target_link_options(canbridge_hardening INTERFACE LINKER:-z,relro,-z,now)
endif()

# Every project target links this: warnings, hardening, sanitizers (when enabled).
add_library(canbridge_project_options INTERFACE)
target_link_libraries(canbridge_project_options INTERFACE canbridge_warnings canbridge_hardening
                                                          canbridge_sanitizers)
