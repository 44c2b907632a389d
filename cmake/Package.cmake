# The Debian package (scripts/package.sh builds it with CPack; docs/fleet.md):
# binpickd, binpick and binpick-robot, the assets, the systemd unit, its
# system user, the packaged cell and the man page. Installs nothing into the
# build itself: `cpack` (or `cmake --install`) reads these rules.

# `cmake --install` and cpack install what is built, and build nothing: the
# package of a tree whose programs are built takes seconds, not a rebuild of
# `all` (the tests and benches; scripts/package.sh builds the three programs).
set(CMAKE_SKIP_INSTALL_ALL_DEPENDENCY ON)

install(TARGETS binpickd binpick binpick-robot RUNTIME DESTINATION bin)
install(DIRECTORY ${PROJECT_SOURCE_DIR}/assets/ DESTINATION share/binpick/assets)

# The packaged cell: the default cell with its mesh paths absolute under the
# installed assets and its state (hand-eye calibration and, next to it, the
# precision references; recordings) in the service's state
# directory, /var/lib/binpick: under ProtectSystem=strict only that is writable.
set(_default_cell ${PROJECT_SOURCE_DIR}/assets/cells/default.yaml)
set_property(DIRECTORY APPEND PROPERTY CMAKE_CONFIGURE_DEPENDS ${_default_cell})
file(READ ${_default_cell} _cell)
string(REPLACE "../" "/usr/share/binpick/assets/" _cell "${_cell}")
set(_hand_eye_line "  # hand_eye_file: calib/hand_eye.yaml   # overrides pose when present")
string(FIND "${_cell}" "${_hand_eye_line}" _at)
if(_at EQUAL -1)
  message(FATAL_ERROR "cmake/Package.cmake: assets/cells/default.yaml has no '${_hand_eye_line}' line to replace")
endif()
string(REPLACE "${_hand_eye_line}"
  "  hand_eye_file: /var/lib/binpick/hand_eye.yaml   # written by calibration; overrides pose when present"
  _cell "${_cell}")
string(REGEX REPLACE "# relative paths resolve[^\n]*\n[^\n]*\n[^\n]*\n"
  "# Installed by the binpick package as /etc/binpick/cell.yaml on the first\n# install and never overwritten: this file is the integrator's (docs/fleet.md).\n"
  _cell "${_cell}")
string(APPEND _cell "
# The package's service (binpickd.service) can write only /var/lib/binpick
# (it passes --taught-grasps /var/lib/binpick/taught.yaml for taught grasps).
recording:
  directory: /var/lib/binpick/recordings
")
file(WRITE ${CMAKE_BINARY_DIR}/package/cell.yaml "${_cell}")
install(FILES ${CMAKE_BINARY_DIR}/package/cell.yaml DESTINATION share/binpick)

install(FILES ${PROJECT_SOURCE_DIR}/deploy/debian/binpickd.service DESTINATION lib/systemd/system)
install(FILES ${PROJECT_SOURCE_DIR}/deploy/debian/binpick.sysusers DESTINATION lib/sysusers.d
  RENAME binpick.conf)
# Debian keeps man pages gzip'ed (-n: no name or time stamp, a reproducible file).
set_property(DIRECTORY APPEND PROPERTY CMAKE_CONFIGURE_DEPENDS ${PROJECT_SOURCE_DIR}/deploy/debian/binpickd.8)
execute_process(COMMAND gzip -9nc ${PROJECT_SOURCE_DIR}/deploy/debian/binpickd.8
  OUTPUT_FILE ${CMAKE_BINARY_DIR}/package/binpickd.8.gz COMMAND_ERROR_IS_FATAL ANY)
install(FILES ${CMAKE_BINARY_DIR}/package/binpickd.8.gz DESTINATION share/man/man8)
install(FILES ${PROJECT_SOURCE_DIR}/docs/fleet.md DESTINATION share/doc/binpick)

set(CPACK_GENERATOR DEB)
set(CPACK_PACKAGE_NAME binpick)
set(CPACK_PACKAGE_VERSION ${PROJECT_VERSION})
set(CPACK_PACKAGE_CONTACT "binpick maintainers <binpick@localhost>")
set(CPACK_PACKAGE_DESCRIPTION_SUMMARY "bin-picking vision server (binpickd) and tools")
set(CPACK_PACKAGE_DESCRIPTION "binpickd answers robots that ask where to pick next over the DaoAI socket,
 Modbus TCP and the Roboception GRI; binpick is its command line (render,
 eval, calibration, replay of recorded sessions). Runs as the binpickd
 systemd service, user binpick, cell in /etc/binpick, state in /var/lib/binpick.")
set(CPACK_PACKAGING_INSTALL_PREFIX /usr)
set(CPACK_DEBIAN_FILE_NAME DEB-DEFAULT)
set(CPACK_DEBIAN_PACKAGE_SECTION misc)
set(CPACK_DEBIAN_PACKAGE_PRIORITY optional)
# Library dependencies from the binaries themselves (dpkg-shlibdeps), plus
# what the maintainer scripts run (systemd-sysusers when there, else adduser).
# systemd is only recommended: the container image runs binpickd as PID 1.
set(CPACK_DEBIAN_PACKAGE_SHLIBDEPS ON)
set(CPACK_DEBIAN_PACKAGE_DEPENDS "adduser, init-system-helpers")
set(CPACK_DEBIAN_PACKAGE_RECOMMENDS "systemd")
set(CPACK_DEBIAN_PACKAGE_CONTROL_EXTRA
  ${PROJECT_SOURCE_DIR}/deploy/debian/postinst
  ${PROJECT_SOURCE_DIR}/deploy/debian/prerm
  ${PROJECT_SOURCE_DIR}/deploy/debian/postrm)
set(CPACK_DEBIAN_PACKAGE_CONTROL_STRICT_PERMISSION TRUE)
# The installed programs without their -g1 line tables (about a third of their size).
set(CPACK_STRIP_FILES TRUE)
set(CPACK_OUTPUT_FILE_PREFIX ${CMAKE_BINARY_DIR}/package)
include(CPack)
