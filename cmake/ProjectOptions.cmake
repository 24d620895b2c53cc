# Compiler settings for project code, carried by one interface target instead of global flags,
# so generated code (protobuf) and third-party headers are not held to our warning level.
add_library(canbridge_warnings INTERFACE)
target_compile_options(canbridge_warnings INTERFACE -Wall -Wextra -Werror -Wpedantic -Wshadow
                                                     -Wnon-virtual-dtor -Wold-style-cast)

add_library(canbridge_sanitizers INTERFACE)
if(CANBRIDGE_SANITIZE)
  target_compile_options(canbridge_sanitizers INTERFACE -fsanitize=address,undefined
                                                        -fno-omit-frame-pointer -fno-sanitize-recover=all)
  target_link_options(canbridge_sanitizers INTERFACE -fsanitize=address,undefined)
endif()

# Every project target links this: warnings + sanitizers (when enabled).
add_library(canbridge_project_options INTERFACE)
target_link_libraries(canbridge_project_options INTERFACE canbridge_warnings canbridge_sanitizers)
