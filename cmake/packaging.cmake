# Installing canbridge as a system service, and its Debian package (docs/install.md):
# executables in bin, the commented sample configs as <sysconfdir>/canbridge/*.yaml (an edited
# one is never overwritten), rigs and docs, the systemd units and the sysusers.d file; then
# CPack's DEB generator with conffiles and small maintainer scripts.
# The executables' install() lines sit next to their targets (app/, sim/, tools/link_emulator/).

# Where the roles look for their configs when --config is not given (the same variable).
set(CANBRIDGE_CONFIG_DIR "${CMAKE_INSTALL_FULL_SYSCONFDIR}/canbridge")
set(CANBRIDGE_BIN_DIR "${CMAKE_INSTALL_FULL_BINDIR}")
set(CANBRIDGE_DOC_DIR "${CMAKE_INSTALL_FULL_DOCDIR}")

# systemd's own directories when installing into /usr (Debian 12: units in /lib/systemd/system),
# else below the prefix, where nothing outside it is touched.
set(canbridge_unit_dir "${CMAKE_INSTALL_PREFIX}/lib/systemd/system")
set(canbridge_sysusers_dir "${CMAKE_INSTALL_PREFIX}/lib/sysusers.d")
find_package(PkgConfig QUIET)
if(PKG_CONFIG_FOUND AND CMAKE_INSTALL_PREFIX STREQUAL "/usr")
  pkg_get_variable(systemd_unit_dir systemd systemdsystemunitdir)
  pkg_get_variable(systemd_sysusers_dir systemd sysusersdir)
  if(systemd_unit_dir)
    set(canbridge_unit_dir "${systemd_unit_dir}")
  endif()
  if(systemd_sysusers_dir)
    set(canbridge_sysusers_dir "${systemd_sysusers_dir}")
  endif()
endif()
set(CANBRIDGE_SYSTEMD_UNIT_DIR "${canbridge_unit_dir}" CACHE PATH "Where the systemd units go")
set(CANBRIDGE_SYSUSERS_DIR "${canbridge_sysusers_dir}" CACHE PATH "Where the sysusers.d file goes")

# The sample configs: installed as <name> only where there is none; beside an edited one as
# <name>.sample, with a message (cmake/install_sample_configs.cmake). dpkg does the same for the
# .deb through conffiles.
install(CODE "set(canbridge_config_dir \"${CANBRIDGE_CONFIG_DIR}\")
set(canbridge_sample_configs \"${PROJECT_SOURCE_DIR}/config/gateway.yaml;${PROJECT_SOURCE_DIR}/config/surface.yaml\")")
install(SCRIPT ${PROJECT_SOURCE_DIR}/cmake/install_sample_configs.cmake)

# The rig files canbridge-sim runs (canbridge-sim --rig ...), and the docs.
install(DIRECTORY ${PROJECT_SOURCE_DIR}/config/rigs/
        DESTINATION ${CMAKE_INSTALL_DATADIR}/canbridge/rigs)
file(GLOB canbridge_docs ${PROJECT_SOURCE_DIR}/docs/*.md)
install(FILES ${PROJECT_SOURCE_DIR}/README.md ${canbridge_docs} DESTINATION ${CMAKE_INSTALL_DOCDIR})

foreach(unit canbridge-gateway.service canbridge-surface.service)
  configure_file(${PROJECT_SOURCE_DIR}/config/systemd/${unit}.in
                 ${PROJECT_BINARY_DIR}/systemd/${unit} @ONLY)
  install(FILES ${PROJECT_BINARY_DIR}/systemd/${unit} DESTINATION ${CANBRIDGE_SYSTEMD_UNIT_DIR})
endforeach()
install(FILES ${PROJECT_SOURCE_DIR}/config/systemd/canbridge.sysusers
        DESTINATION ${CANBRIDGE_SYSUSERS_DIR} RENAME canbridge.conf)

# The Debian package: cpack -G DEB in the build directory.
if(NOT CMAKE_INSTALL_PREFIX STREQUAL "/usr")
  message(STATUS "canbridge: install prefix ${CMAKE_INSTALL_PREFIX}: a .deb built from this tree "
                 "installs there (Debian packages use -DCMAKE_INSTALL_PREFIX=/usr)")
endif()
foreach(script postinst prerm postrm)
  configure_file(${PROJECT_SOURCE_DIR}/cmake/debian/${script}.in
                 ${PROJECT_BINARY_DIR}/debian/${script} @ONLY
                 FILE_PERMISSIONS OWNER_READ OWNER_WRITE OWNER_EXECUTE GROUP_READ GROUP_EXECUTE
                                  WORLD_READ WORLD_EXECUTE)
endforeach()
# Debian's copyright file and the changelog of a native package (gzip -9n: no name or time
# in the header, as Debian policy wants), beside the docs; lintian checks both (tests/package).
set(CANBRIDGE_PACKAGE_MAINTAINER "canbridge developers <dev@canbridge.invalid>"
    CACHE STRING "The .deb's Maintainer: (.invalid never resolves: a packager sets their own)")
configure_file(${PROJECT_SOURCE_DIR}/cmake/debian/changelog.in ${PROJECT_BINARY_DIR}/debian/changelog
               @ONLY)
execute_process(COMMAND gzip -9nc ${PROJECT_BINARY_DIR}/debian/changelog
                OUTPUT_FILE ${PROJECT_BINARY_DIR}/debian/changelog.gz COMMAND_ERROR_IS_FATAL ANY)
install(FILES ${PROJECT_SOURCE_DIR}/cmake/debian/copyright
              ${PROJECT_BINARY_DIR}/debian/changelog.gz DESTINATION ${CMAKE_INSTALL_DOCDIR})

# Manual pages (man canbridge, ...) made from each executable's --help and --version by help2man
# at build time, gzipped as Debian installs them, with what --help does not say from
# cmake/man/<program>.h2m.in (help2man --include: canbridge's commands and their options, signals,
# exit status, environment, files). None where help2man is missing (a message says so) or where
# the executables cannot run on the build machine (cross builds).
find_program(CANBRIDGE_HELP2MAN help2man)
if(NOT CANBRIDGE_HELP2MAN AND NOT CMAKE_CROSSCOMPILING)
  message(STATUS "canbridge: no help2man: no manual pages (apt-get install help2man)")
endif()
function(canbridge_man_page program summary)
  if(NOT CANBRIDGE_HELP2MAN OR CMAKE_CROSSCOMPILING)
    return()
  endif()
  set(page ${PROJECT_BINARY_DIR}/man/${program}.1)
  set(include ${PROJECT_BINARY_DIR}/man/${program}.h2m)
  set(CANBRIDGE_RIG_DIR "${CMAKE_INSTALL_FULL_DATADIR}/canbridge/rigs")
  configure_file(${PROJECT_SOURCE_DIR}/cmake/man/${program}.h2m.in ${include} @ONLY)
  add_custom_command(
    OUTPUT ${page}.gz
    COMMAND ${CMAKE_COMMAND} -E make_directory ${PROJECT_BINARY_DIR}/man
    COMMAND ${CANBRIDGE_HELP2MAN} --no-info --no-discard-stderr --name=${summary}
            --include=${include} --output=${page} $<TARGET_FILE:${program}>
    COMMAND gzip -9nf ${page}
    DEPENDS ${program} ${include}
    COMMENT "Manual page ${program}.1"
    VERBATIM)
  add_custom_target(${program}-man-page ALL DEPENDS ${page}.gz)
  install(FILES ${page}.gz DESTINATION ${CMAKE_INSTALL_MANDIR}/man1)
endfunction()
canbridge_man_page(canbridge "CANopen gateway and surface roles tunnelling CAN buses over a backbone")
canbridge_man_page(canbridge-sim "simulated CANopen nodes and modules on CAN buses")
canbridge_man_page(canbridge-link-emulator "a slow, noisy, breakable wireline between two endpoints")

file(WRITE ${PROJECT_BINARY_DIR}/debian/conffiles
     "${CANBRIDGE_CONFIG_DIR}/gateway.yaml\n${CANBRIDGE_CONFIG_DIR}/surface.yaml\n")

set(CPACK_GENERATOR DEB)
set(CPACK_PACKAGE_NAME canbridge)
set(CPACK_PACKAGE_VENDOR canbridge)
set(CPACK_PACKAGE_CONTACT "${CANBRIDGE_PACKAGE_MAINTAINER}")
# The synopsis; the extended description below must not repeat it, and its lines stay within
# 80 columns (lintian).
set(CPACK_PACKAGE_DESCRIPTION_SUMMARY "CANopen gateway tunnelling SocketCAN buses over a backbone link")
set(CPACK_DEBIAN_PACKAGE_DESCRIPTION
    "canbridge presents the CANopen nodes of several module CAN buses (the gateway\n\
role, on the tool's board) on one surface CAN interface (the surface role, on a\n\
PC), over TCP or serial lines, authenticated with pre-shared keys or\n\
certificates. Includes systemd units for both roles, canbridge-sim (simulated\n\
nodes) and canbridge-link-emulator (a slow, noisy wireline for tests).")
set(CPACK_DEBIAN_PACKAGE_SECTION net)
set(CPACK_DEBIAN_PACKAGE_PRIORITY optional)
set(CPACK_DEBIAN_FILE_NAME DEB-DEFAULT)
# Shared-library dependencies from dpkg-shlibdeps (package dpkg-dev); adduser for postinst;
# procps for /bin/kill, the units' ExecReload (systemctl reload). openssl makes the keys and
# tokens (`openssl rand -hex 32`, docs/security.md): recommended, the roles never run it.
set(CPACK_DEBIAN_PACKAGE_SHLIBDEPS ON)
set(CPACK_DEBIAN_PACKAGE_DEPENDS "adduser, procps")
set(CPACK_DEBIAN_PACKAGE_RECOMMENDS "openssl")
set(CPACK_DEBIAN_PACKAGE_SUGGESTS "can-utils, iproute2")
set(CPACK_DEBIAN_PACKAGE_CONTROL_EXTRA
    ${PROJECT_BINARY_DIR}/debian/conffiles ${PROJECT_BINARY_DIR}/debian/postinst
    ${PROJECT_BINARY_DIR}/debian/prerm ${PROJECT_BINARY_DIR}/debian/postrm)
set(CPACK_DEBIAN_PACKAGE_CONTROL_STRICT_PERMISSION ON)
# Absolute destinations (/etc, /lib/systemd/system) are staged below DESTDIR.
set(CPACK_SET_DESTDIR ON)
set(CPACK_INSTALL_PREFIX "${CMAKE_INSTALL_PREFIX}")
# Nobody debugs the packaged binaries; their symbols would make most of the package.
set(CPACK_STRIP_FILES ON)
set(CPACK_SOURCE_GENERATOR "")
include(CPack)
