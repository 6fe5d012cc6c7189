#!/usr/bin/env bash
# Cross-builds the firmware (slscand, its backends and their unit tests) for an ARM board with
# Debian's cross compilers, then runs the firmware tests under qemu-user.
#   scripts/cross-build.sh [arm64|armhf]      (default arm64)
# 1. installs the cross compiler, qemu-user-static and file if they are missing (root, Debian);
# 2. unpacks the target's -dev packages into build/sysroot-<triplet>: `apt-get download` through
#    a private apt state (build/apt-<arch>: the machine's sources, its own package lists), then
#    `dpkg-deb -x`. Nothing is installed for the target and dpkg's architectures are untouched;
# 3. configures and builds the `aarch64` / `armhf` preset (host tools off), checks that slscand
#    is an ELF for the target, and runs ctest -L firmware under qemu-user.
# Environment: SLSCAN_CROSS_SKIP_TESTS=1 builds only; SLSCAN_CROSS_SYSROOT_ONLY=1 only prepares
# the sysroot; SLSCAN_CROSS_CTEST_ARGS adds ctest arguments (e.g. "-LE integration" runs only
# the unit tests, without slscand serving sim scans under emulation).
set -euo pipefail
cd "$(dirname "$0")/.."
arch=${1:-arm64}
case "$arch" in
  arm64) triplet=aarch64-linux-gnu; preset=aarch64; qemu=qemu-aarch64-static; elf="ARM aarch64" ;;
  armhf) triplet=arm-linux-gnueabihf; preset=armhf; qemu=qemu-arm-static; elf="ARM, EABI5" ;;
  *) echo "cross-build: unknown architecture '$arch' (arm64 or armhf)" >&2; exit 2 ;;
esac
sysroot=$PWD/build/sysroot-$triplet
start=$(date +%s)
elapsed() { echo $(( $(date +%s) - start )); }

# The cross compiler and qemu-user (scripts/bootstrap.sh installs both; this covers a machine
# that only wants the cross build).
need=()
command -v "$triplet-g++" >/dev/null || need+=("g++-$triplet")
command -v "$qemu" >/dev/null || need+=(qemu-user-static)
command -v file >/dev/null || need+=(file)  # checks what the build produced
if [ ${#need[@]} -gt 0 ]; then
  if [ "$(id -u)" -ne 0 ]; then
    echo "cross-build: missing ${need[*]}; install them (apt-get install ${need[*]}) or run as root" >&2
    exit 1
  fi
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${need[@]}"
fi

# Everything the firmware links (protobuf-lite, libgpiod, libserialport, avahi-client), the header-only
# libraries it includes (nlohmann-json, toml++) and GoogleTest for the unit tests. libcamera
# is left out: the cross build's camera backends are V4L2 and sim.
packages=(libprotobuf-dev libprotobuf-lite32 libprotobuf32 zlib1g zlib1g-dev
          nlohmann-json3-dev libtomlplusplus-dev libtomlplusplus3
          libgpiod-dev libgpiod2 libserialport-dev libserialport0
          libgtest-dev libgmock-dev
          # mDNS/DNS-SD (slscand announces itself through avahi-daemon): the client library and,
          # for the linker to resolve it, what it loads down to libc (D-Bus, libsystemd, ...)
          libavahi-client-dev libavahi-client3 libavahi-common-dev libavahi-common3 libdbus-1-3
          libsystemd0 libcap2 libgcrypt20 libgpg-error0 liblz4-1 liblzma5 libzstd1)

stamp=$sysroot/.slscan-packages
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "${packages[*]}" ]; then
  # A private apt state for the target architecture: the machine's sources, but its own lists
  # and an empty dpkg status. Needs no root, leaves dpkg's architectures and apt's lists alone.
  apt_dir=$PWD/build/apt-$arch
  mkdir -p "$apt_dir/lists/partial" "$apt_dir/cache/archives/partial"
  : >"$apt_dir/status"
  apt_opts=(-q -o "Dir::State=$apt_dir" -o "Dir::State::Lists=$apt_dir/lists"
            -o "Dir::State::status=$apt_dir/status" -o "Dir::Cache=$apt_dir/cache"
            -o "APT::Architecture=$arch" -o "APT::Architectures=$arch" -o Debug::NoLocking=1)
  # As root apt drops to the _apt user to download, which cannot write to our directories.
  if [ "$(id -u)" -eq 0 ]; then apt_opts+=(-o APT::Sandbox::User=root); fi
  apt-get "${apt_opts[@]}" update >/dev/null
  work=$(mktemp -d)
  trap 'rm -rf "$work"' EXIT
  (cd "$work" && apt-get "${apt_opts[@]}" download "${packages[@]}" >/dev/null)
  rm -rf "$sysroot"
  mkdir -p "$sysroot"
  for deb in "$work"/*.deb; do dpkg-deb -x "$deb" "$sysroot"; done
  # -dev packages link libfoo.so -> /usr/lib/... with absolute paths in a few cases: point
  # them into the sysroot so they resolve there, not to the build machine's libraries.
  find "$sysroot" -type l -lname '/*' | while read -r link; do
    target=$(readlink "$link")
    ln -sf "$sysroot$target" "$link"
  done
  echo "${packages[*]}" > "$stamp"
  echo "cross-build: sysroot of $(find "$work" -name '*.deb' | wc -l) $arch packages ready in $(elapsed) s"
fi

export SLSCAN_SYSROOT=$sysroot
if [ "${SLSCAN_CROSS_SYSROOT_ONLY:-0}" = 1 ]; then
  echo "cross-build: sysroot ready in $sysroot"
  exit 0
fi
cmake --preset "$preset" -DSLSCAND_LIBCAMERA=OFF >/dev/null
cmake --build --preset "$preset" -j "$(nproc)"
echo "cross-build: built $preset in $(elapsed) s"
binary=build/$preset/firmware/app/slscand
description=$(file -b "$binary")
echo "cross-build: $binary: $description"
case "$description" in
  *ELF*"$elf"*) ;;
  *) echo "cross-build: $binary is not an ELF for $arch ($elf)" >&2; exit 1 ;;
esac
if [ "${SLSCAN_CROSS_SKIP_TESTS:-0}" != 1 ]; then
  # shellcheck disable=SC2086  # word splitting of the extra arguments is wanted
  ctest --preset "$preset" -L firmware ${SLSCAN_CROSS_CTEST_ARGS:-}
  echo "cross-build: tests under $qemu done, $(elapsed) s in all"
fi
