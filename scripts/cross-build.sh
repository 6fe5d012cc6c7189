#!/usr/bin/env bash
# Cross-builds the firmware (slscand, its backends and their unit tests) for an ARM board with
# Debian's cross compilers, then runs the unit tests under qemu-user.
#   scripts/cross-build.sh [arm64|armhf]      (default arm64; needs root for the first run)
# 1. adds the target architecture to dpkg (multiarch) and updates apt's lists, once;
# 2. unpacks the target's -dev packages into build/sysroot-<triplet> (apt-get download +
#    dpkg-deb -x: nothing is installed on the build machine);
# 3. configures and builds the `aarch64` / `armhf` preset (host tools off), runs ctest.
# SLSCAN_CROSS_SKIP_TESTS=1 builds only; SLSCAN_CROSS_SYSROOT_ONLY=1 only prepares the sysroot.
set -euo pipefail
cd "$(dirname "$0")/.."
arch=${1:-arm64}
case "$arch" in
  arm64) triplet=aarch64-linux-gnu; preset=aarch64 ;;
  armhf) triplet=arm-linux-gnueabihf; preset=armhf ;;
  *) echo "cross-build: unknown architecture '$arch' (arm64 or armhf)" >&2; exit 2 ;;
esac
sysroot=$PWD/build/sysroot-$triplet
start=$(date +%s)

# Everything the firmware links (protobuf-lite, libgpiod, libserialport), the header-only
# libraries it includes (nlohmann-json, toml++) and GoogleTest for the unit tests. libcamera
# is left out: the cross build's camera backends are V4L2 and sim.
packages=(libprotobuf-dev libprotobuf-lite32 libprotobuf32 zlib1g zlib1g-dev
          nlohmann-json3-dev libtomlplusplus-dev libtomlplusplus3
          libgpiod-dev libgpiod2 libserialport-dev libserialport0
          libgtest-dev libgmock-dev)

stamp=$sysroot/.slscan-packages
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "${packages[*]}" ]; then
  if ! dpkg --print-foreign-architectures | grep -qx "$arch"; then
    dpkg --add-architecture "$arch"
    apt-get update -qq
  fi
  work=$(mktemp -d)
  trap 'rm -rf "$work"' EXIT
  (
    cd "$work"
    names=()
    for p in "${packages[@]}"; do
      # Architecture-independent packages (headers only) have no :arch variant.
      if apt-cache show "$p" 2>/dev/null | grep -m1 '^Architecture:' | grep -qw all; then
        names+=("$p")
      else
        names+=("$p:$arch")
      fi
    done
    apt-get download -q "${names[@]}" >/dev/null 2>&1 || apt-get download "${names[@]}"
  )
  rm -rf "$sysroot"
  mkdir -p "$sysroot"
  for deb in "$work"/*.deb; do dpkg-deb -x "$deb" "$sysroot"; done
  # -dev packages link libfoo.so -> libfoo.so.N with absolute paths in a few cases: make them
  # relative so they resolve inside the sysroot.
  find "$sysroot" -type l -lname '/*' | while read -r link; do
    target=$(readlink "$link")
    ln -sf "$sysroot$target" "$link"
  done
  echo "${packages[*]}" > "$stamp"
fi

export SLSCAN_SYSROOT=$sysroot
if [ "${SLSCAN_CROSS_SYSROOT_ONLY:-0}" = 1 ]; then
  echo "cross-build: sysroot ready in $sysroot"
  exit 0
fi
cmake --preset "$preset" -DSLSCAND_LIBCAMERA=OFF >/dev/null
cmake --build --preset "$preset" -j "$(nproc)"
echo "cross-build: built $preset in $(( $(date +%s) - start )) s"
if [ "${SLSCAN_CROSS_SKIP_TESTS:-0}" != 1 ]; then
  ctest --preset "$preset" -L firmware
  echo "cross-build: tests under qemu done in $(( $(date +%s) - start )) s"
fi
file "build/$preset/firmware/app/slscand"
