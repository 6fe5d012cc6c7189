# Shared by the Debian cross toolchain files: set SLSCAN_CROSS_TRIPLET, _PROCESSOR and _QEMU first.
set(CMAKE_SYSTEM_NAME Linux)
set(CMAKE_SYSTEM_PROCESSOR ${SLSCAN_CROSS_PROCESSOR})
set(CMAKE_C_COMPILER ${SLSCAN_CROSS_TRIPLET}-gcc)
set(CMAKE_CXX_COMPILER ${SLSCAN_CROSS_TRIPLET}-g++)

if(NOT SLSCAN_SYSROOT)
  if(DEFINED ENV{SLSCAN_SYSROOT})
    set(SLSCAN_SYSROOT $ENV{SLSCAN_SYSROOT})
  else()
    get_filename_component(SLSCAN_SYSROOT "${CMAKE_CURRENT_LIST_DIR}/../build/sysroot-${SLSCAN_CROSS_TRIPLET}" ABSOLUTE)
  endif()
endif()
set(SLSCAN_SYSROOT ${SLSCAN_SYSROOT} CACHE PATH "Unpacked target -dev packages")
# try_compile projects see the toolchain file again, without the cache: pass the sysroot on.
list(APPEND CMAKE_TRY_COMPILE_PLATFORM_VARIABLES SLSCAN_SYSROOT)

set(_libdir ${SLSCAN_SYSROOT}/usr/lib/${SLSCAN_CROSS_TRIPLET})
# The cross compiler's own libc/libstdc++ live in /usr/<triplet>; the libraries in the sysroot.
set(CMAKE_FIND_ROOT_PATH ${SLSCAN_SYSROOT} /usr/${SLSCAN_CROSS_TRIPLET})
set(CMAKE_FIND_ROOT_PATH_MODE_PROGRAM NEVER)  # protoc, pkg-config: the build machine's
set(CMAKE_FIND_ROOT_PATH_MODE_LIBRARY ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_INCLUDE ONLY)
set(CMAKE_FIND_ROOT_PATH_MODE_PACKAGE ONLY)
set(CMAKE_LIBRARY_ARCHITECTURE ${SLSCAN_CROSS_TRIPLET})
set(CMAKE_C_FLAGS_INIT "-isystem ${SLSCAN_SYSROOT}/usr/include/${SLSCAN_CROSS_TRIPLET} -isystem ${SLSCAN_SYSROOT}/usr/include")
set(CMAKE_CXX_FLAGS_INIT "-isystem ${SLSCAN_SYSROOT}/usr/include/${SLSCAN_CROSS_TRIPLET} -isystem ${SLSCAN_SYSROOT}/usr/include")
# Shared libraries' own dependencies (libprotobuf-lite -> zlib) are found through rpath-link;
# the ones bookworm still ships in /lib/<triplet> (libdbus, libcap) get theirs in the top-level
# CMakeLists.txt (these *_INIT flags only reach a build directory's first configure).
set(_rootlibdir ${SLSCAN_SYSROOT}/lib/${SLSCAN_CROSS_TRIPLET})
set(CMAKE_EXE_LINKER_FLAGS_INIT "-L${_libdir} -Wl,-rpath-link,${_libdir}")
set(CMAKE_SHARED_LINKER_FLAGS_INIT "-L${_libdir} -Wl,-rpath-link,${_libdir}")

set(ENV{PKG_CONFIG_DIR} "")
set(ENV{PKG_CONFIG_LIBDIR} "${_libdir}/pkgconfig:${SLSCAN_SYSROOT}/usr/share/pkgconfig")
set(ENV{PKG_CONFIG_SYSROOT_DIR} ${SLSCAN_SYSROOT})

# ctest runs the cross-built tests under qemu-user: the cross libc from /usr/<triplet>, the
# sysroot's libraries through the target's LD_LIBRARY_PATH.
find_program(SLSCAN_QEMU ${SLSCAN_CROSS_QEMU})
if(SLSCAN_QEMU)
  set(CMAKE_CROSSCOMPILING_EMULATOR ${SLSCAN_QEMU} -L /usr/${SLSCAN_CROSS_TRIPLET} -E LD_LIBRARY_PATH=${_libdir}:${_rootlibdir})
endif()
