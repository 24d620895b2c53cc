# Third-party packages, all from Debian 12 (see tools/install-deps.sh).
find_package(Threads REQUIRED)
find_package(Boost 1.81 REQUIRED)
find_package(Protobuf 3.21 REQUIRED)
find_package(yaml-cpp REQUIRED)
find_package(spdlog REQUIRED)
# libcrypto only (HMAC, HKDF, RAND) for the backbone's peer authentication.
find_package(OpenSSL 3.0 REQUIRED)
if(CANBRIDGE_BUILD_TESTS)
  find_package(GTest 1.12 REQUIRED)
endif()

# Boost.Asio is header-only; this target carries the definitions every user needs.
add_library(canbridge_asio INTERFACE)
target_link_libraries(canbridge_asio INTERFACE Boost::headers Threads::Threads)
target_compile_definitions(canbridge_asio INTERFACE BOOST_ASIO_NO_DEPRECATED BOOST_ASIO_DISABLE_BOOST_COROUTINE)
include(${CMAKE_CURRENT_LIST_DIR}/IoUring.cmake)
