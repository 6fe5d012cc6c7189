# Debian packages (CPack DEB), one per component:
#   slscand - the board daemon, its board files, systemd unit, udev rules and /etc/slscan defaults
#             (amd64 from a native build; arm64/armhf from the cross presets)
#   slscan  - the host command (native builds with SLSCAN_BUILD_HOST only)
# `cpack --config <build>/CPackConfig.cmake` after a full build; scripts/package.sh does this
# for CI and checks the result.

set(SLSCAN_PACKAGING_DIR ${PROJECT_SOURCE_DIR}/packaging)

# Board side: installed under the prefix (/usr) except what Debian wants at fixed places.
# The boards a person installs on; not the test-only ones (qemu-vm.toml is the HIL VM's).
install(FILES ${PROJECT_SOURCE_DIR}/boards/rpi.toml ${PROJECT_SOURCE_DIR}/boards/beaglebone-black.toml
              ${PROJECT_SOURCE_DIR}/boards/rpi-gige.toml
              ${PROJECT_SOURCE_DIR}/boards/sim.toml
        DESTINATION share/slscan/boards COMPONENT slscand)
install(FILES ${SLSCAN_PACKAGING_DIR}/slscand.service DESTINATION /lib/systemd/system COMPONENT slscand)
install(FILES ${SLSCAN_PACKAGING_DIR}/60-slscan.rules DESTINATION /lib/udev/rules.d COMPONENT slscand)
install(FILES ${SLSCAN_PACKAGING_DIR}/slscand.toml DESTINATION /etc/slscan COMPONENT slscand)
install(FILES ${PROJECT_SOURCE_DIR}/docs/appliance.md ${PROJECT_SOURCE_DIR}/docs/hardware.md
        DESTINATION share/doc/slscand COMPONENT slscand)
install(FILES ${SLSCAN_PACKAGING_DIR}/copyright DESTINATION share/doc/slscand COMPONENT slscand)

# Debian's changelog.Debian.gz (gzip -9n: no name or time stamp, the same bytes every build).
# Its top entry must carry this version: a release bumps both.
set_property(DIRECTORY APPEND PROPERTY CMAKE_CONFIGURE_DEPENDS ${SLSCAN_PACKAGING_DIR}/changelog.Debian)
file(STRINGS ${SLSCAN_PACKAGING_DIR}/changelog.Debian SLSCAN_CHANGELOG_TOP LIMIT_COUNT 1)
if(NOT SLSCAN_CHANGELOG_TOP MATCHES "^slscan \\(${PROJECT_VERSION}-[0-9]+\\)")
  message(FATAL_ERROR "packaging/changelog.Debian starts with '${SLSCAN_CHANGELOG_TOP}': add an entry for ${PROJECT_VERSION}")
endif()
set(SLSCAN_CHANGELOG_GZ ${CMAKE_CURRENT_BINARY_DIR}/packaging/changelog.Debian.gz)
file(MAKE_DIRECTORY ${CMAKE_CURRENT_BINARY_DIR}/packaging)
execute_process(COMMAND gzip -9nc ${SLSCAN_PACKAGING_DIR}/changelog.Debian OUTPUT_FILE ${SLSCAN_CHANGELOG_GZ}
                RESULT_VARIABLE SLSCAN_GZIP_RESULT)
if(NOT SLSCAN_GZIP_RESULT EQUAL 0)
  message(FATAL_ERROR "packaging: gzip of packaging/changelog.Debian failed")
endif()
install(FILES ${SLSCAN_CHANGELOG_GZ} DESTINATION share/doc/slscand COMPONENT slscand)
if(SLSCAN_BUILD_HOST)
  install(FILES ${SLSCAN_CHANGELOG_GZ} DESTINATION share/doc/slscan COMPONENT slscan)
  install(FILES ${PROJECT_SOURCE_DIR}/docs/cli.md ${PROJECT_SOURCE_DIR}/docs/appliance.md
          DESTINATION share/doc/slscan COMPONENT slscan)
  install(FILES ${SLSCAN_PACKAGING_DIR}/copyright DESTINATION share/doc/slscan COMPONENT slscan)
endif()

set(CPACK_GENERATOR DEB)
set(CPACK_PACKAGE_NAME slscan)
set(CPACK_PACKAGE_VENDOR "slscan project")
set(CPACK_PACKAGE_CONTACT "slscan maintainers <maintainers@slscan.invalid>")  # set a real address before publishing
set(CPACK_PACKAGE_VERSION ${PROJECT_VERSION})
set(CPACK_PACKAGING_INSTALL_PREFIX /usr)
set(CPACK_STRIP_FILES ON)  # the dev build's -g would make slscan ~10x larger
set(CPACK_DEB_COMPONENT_INSTALL ON)
set(CPACK_DEBIAN_FILE_NAME DEB-DEFAULT)  # slscand_0.2.0-1_arm64.deb
set(CPACK_DEBIAN_PACKAGE_RELEASE 1)
set(CPACK_DEBIAN_PACKAGE_SECTION science)
set(CPACK_DEBIAN_PACKAGE_PRIORITY optional)
set(CPACK_DEBIAN_PACKAGE_CONTROL_STRICT_PERMISSION ON)
set(CPACK_DEBIAN_COMPRESSION_TYPE xz)
set(CPACK_WARN_ON_ABSOLUTE_INSTALL_DESTINATION OFF)  # /etc, /lib/systemd, /lib/udev on purpose

set(CPACK_COMPONENTS_ALL slscand)
if(SLSCAN_BUILD_HOST)
  list(APPEND CPACK_COMPONENTS_ALL slscan)
endif()
set(CPACK_DEBIAN_SLSCAND_PACKAGE_NAME slscand)
set(CPACK_DEBIAN_SLSCAN_PACKAGE_NAME slscan)
# First line: the synopsis; CPack indents the rest.
set(CPACK_DEBIAN_SLSCAND_DESCRIPTION
    "structured-light 3D scanner daemon for the scanner board
slscand drives two DLP projectors, a camera and a turntable from a board
file and serves scans to the slscan host program over the network
(slproto). This package runs it as the slscand service with real-time
priority and hardware access granted by its systemd unit and udev rules.")
set(CPACK_DEBIAN_SLSCAN_DESCRIPTION
    "structured-light 3D scanner host program
slscan scans with a networked slscand scanner, reconstructs, registers and
meshes the views, calibrates the rig and measures artefacts.")
set(CPACK_DEBIAN_SLSCAND_PACKAGE_CONTROL_EXTRA
    "${SLSCAN_PACKAGING_DIR}/deb/conffiles;${SLSCAN_PACKAGING_DIR}/deb/postinst;${SLSCAN_PACKAGING_DIR}/deb/prerm;${SLSCAN_PACKAGING_DIR}/deb/postrm")

# Dependencies. Native: dpkg-shlibdeps reads the installed libraries' packages. Cross: this
# machine's dpkg knows no arm64/armhf packages, so they are declared from the sonames the
# board build links (the cross sysroot's packages, scripts/cross-build.sh); scripts/package.sh
# checks every NEEDED entry of the binary is covered by this list.
if(CMAKE_CROSSCOMPILING)
  if(CMAKE_SYSTEM_PROCESSOR STREQUAL "aarch64")
    set(SLSCAN_DEB_ARCH arm64)
  elseif(CMAKE_SYSTEM_PROCESSOR MATCHES "^arm")
    set(SLSCAN_DEB_ARCH armhf)
  else()
    message(FATAL_ERROR "packaging: no Debian architecture for ${CMAKE_SYSTEM_PROCESSOR}")
  endif()
  set(CPACK_DEBIAN_PACKAGE_ARCHITECTURE ${SLSCAN_DEB_ARCH})
  set(CPACK_DEBIAN_PACKAGE_SHLIBDEPS OFF)
  # soname -> package (bookworm versions, the oldest the board build was linked against).
  set(SLSCAN_CROSS_DEPENDS
      "libc6 (>= 2.36), libstdc++6 (>= 12), libgcc-s1 (>= 3.0), libprotobuf-lite32 (>= 3.21.12), libgpiod2 (>= 1.6.3), libserialport0 (>= 0.1.1)")
  get_property(SLSCAN_HAVE_AVAHI GLOBAL PROPERTY SLSCAN_HAVE_AVAHI)
  if(SLSCAN_HAVE_AVAHI)
    string(APPEND SLSCAN_CROSS_DEPENDS ", libavahi-client3 (>= 0.8), libavahi-common3 (>= 0.8)")
  endif()
  set(CPACK_DEBIAN_SLSCAND_PACKAGE_DEPENDS "${SLSCAN_CROSS_DEPENDS}")
else()
  set(CPACK_DEBIAN_PACKAGE_SHLIBDEPS ON)
endif()
# useradd/groupadd (passwd) and deb-systemd-helper (init-system-helpers) are in every Debian
# and Raspberry Pi OS base system; systemd-sysv is only recommended: the package installs into
# containers and chroots without it.
set(CPACK_DEBIAN_SLSCAND_PACKAGE_RECOMMENDS "systemd-sysv, udev, avahi-daemon")
set(CPACK_DEBIAN_SLSCAN_PACKAGE_RECOMMENDS "avahi-daemon")

include(CPack)
