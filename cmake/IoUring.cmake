# Optional io_uring backend for Boost.Asio (experimental; see docs/performance.md): with
# CANBRIDGE_IO_URING=ON every io_context runs on io_uring instead of epoll -- sockets, CAN
# descriptors, serial ports, timers and signals alike. Asio is header-only, so the choice is made
# by definitions every translation unit must agree on; they ride on canbridge_asio, the one target
# through which project code reaches Asio.
option(CANBRIDGE_IO_URING "Run Boost.Asio on io_uring instead of epoll (needs liburing, Linux >= 5.10)" OFF)

if(CANBRIDGE_IO_URING)
  find_path(CANBRIDGE_LIBURING_INCLUDE_DIR liburing.h)
  find_library(CANBRIDGE_LIBURING_LIBRARY uring)
  if(NOT CANBRIDGE_LIBURING_INCLUDE_DIR OR NOT CANBRIDGE_LIBURING_LIBRARY)
    message(FATAL_ERROR
      "CANBRIDGE_IO_URING=ON needs liburing: install the Debian package liburing-dev "
      "(apt-get install liburing-dev; tools/install-deps.sh does it) or configure with -DCANBRIDGE_IO_URING=OFF")
  endif()
  add_library(canbridge_liburing UNKNOWN IMPORTED)
  set_target_properties(canbridge_liburing PROPERTIES
    IMPORTED_LOCATION "${CANBRIDGE_LIBURING_LIBRARY}"
    INTERFACE_INCLUDE_DIRECTORIES "${CANBRIDGE_LIBURING_INCLUDE_DIR}")
  target_link_libraries(canbridge_asio INTERFACE canbridge_liburing)
  # HAS_IO_URING alone would use io_uring for files only; without epoll it serves every object.
  target_compile_definitions(canbridge_asio INTERFACE BOOST_ASIO_HAS_IO_URING BOOST_ASIO_DISABLE_EPOLL)
  message(WARNING "canbridge: Boost.Asio on io_uring (${CANBRIDGE_LIBURING_LIBRARY}) is experimental: "
    "serial ports (ptys) fail with 'Interrupted system call' on it, so the serial backbone does not "
    "work (docs/performance.md)")
endif()
