# Cross build for 32-bit ARM boards (BeagleBone Black, Raspberry Pi OS 32-bit) with Debian's
# cross compiler (g++-arm-linux-gnueabihf). Sysroot: scripts/cross-build.sh armhf.
set(SLSCAN_CROSS_TRIPLET arm-linux-gnueabihf)
set(SLSCAN_CROSS_PROCESSOR arm)
set(SLSCAN_CROSS_QEMU qemu-arm-static)
include(${CMAKE_CURRENT_LIST_DIR}/cross-common.cmake)
