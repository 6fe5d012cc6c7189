# Cross build for 64-bit ARM boards (Raspberry Pi 4/5, Jetson, ...) with Debian's cross
# compiler (g++-aarch64-linux-gnu). Libraries come from a sysroot of arm64 -dev packages that
# scripts/cross-build.sh unpacks (apt-get download + dpkg-deb -x); point elsewhere with
# -DSLSCAN_SYSROOT=... or the SLSCAN_SYSROOT environment variable. Tests run under qemu-user.
set(SLSCAN_CROSS_TRIPLET aarch64-linux-gnu)
set(SLSCAN_CROSS_PROCESSOR aarch64)
set(SLSCAN_CROSS_QEMU qemu-aarch64-static)
include(${CMAKE_CURRENT_LIST_DIR}/cross-common.cmake)
