#!/usr/bin/env bash
# Installs every Debian package that slscan's build, tests, benchmarks and demo need.
# Idempotent: safe to run again; a second run installs nothing new.
# Usage (as root on Debian 12): scripts/bootstrap.sh
set -euo pipefail

if [ "$(id -u)" -ne 0 ]; then
  SUDO=sudo
else
  SUDO=
fi

# bookworm-backports carries libcamera >= 0.3 and libgpiod 2.x (the API that Raspberry Pi OS
# and newer distributions use). It is added beside the machine's own Debian sources, on the
# same mirror, and only the packages named below are taken from it.
backports_list=/etc/apt/sources.list.d/slscan-bookworm-backports.sources
if [ ! -f "$backports_list" ]; then
  mirror=$(grep -hoE 'https?://[^ ]+/debian/?$' /etc/apt/sources.list.d/*.sources /etc/apt/sources.list 2>/dev/null | head -n1 || true)
  mirror=${mirror:-http://deb.debian.org/debian}
  $SUDO tee "$backports_list" >/dev/null <<SRC
Types: deb
URIs: ${mirror}
Suites: bookworm-backports
Components: main
Signed-By: /usr/share/keyrings/debian-archive-keyring.gpg
SRC
fi

packages=(
  # toolchain
  build-essential cmake ninja-build pkg-config git ccache lld  # lld: links the tests ~4x faster
  clang-14 libclang-rt-14-dev clang-format clang-tidy  # clang-tidy: scripts/lint.sh
  # shared / protocol
  libprotobuf-dev protobuf-compiler nlohmann-json3-dev
  # shared: the capture codec (compressed captures; host only, docs/scale.md)
  libzstd-dev zstd
  # host
  libeigen3-dev libopencv-dev libopencv-contrib-dev libtbb-dev libnanoflann-dev libcgal-dev libcli11-dev
  # host: run-time SIMD dispatch of decode and triangulation (Google Highway)
  libhwy-dev
  # host: the mesher (slscan_mesh, docs/mesh.md): OpenVDB level sets (+ Imath); CGAL (above) closes and checks it
  libopenvdb-dev libimath-dev
  # host: the mesh as 3MF (lib3mf 1.8, slscan_io)
  lib3mf-dev
  # host: batch reprocessing (SHA-256 job keys: libssl-dev; a one-node Slurm in the tests)
  libssl-dev slurm-wlm slurmctld slurmd munge
  # firmware hardware backends
  libgpiod-dev gpiod libserialport-dev linux-libc-dev libtomlplusplus-dev
  # GenICam cameras (Aravis 0.8) and its fake GigE Vision camera for the tests; Debian's
  # aravis-0.8.pc requires libusb-1.0.pc, which libaravis-dev does not pull in
  libaravis-dev aravis-tools libusb-1.0-0-dev
  # virtual rig CLI (slrig-render writes PNG frames)
  libpng-dev
  # tests and benchmarks (chromium: report.html is rendered headless, WebGL on SwiftShader)
  googletest libgtest-dev libgmock-dev libbenchmark-dev chromium
  # cross builds
  g++-aarch64-linux-gnu g++-arm-linux-gnueabihf qemu-user-static file
  # appliance: mDNS/DNS-SD (slscand publishes, slscan discover browses; the daemon and D-Bus for
  # the discovery test), Debian packages and their checks (scripts/package.sh)
  libavahi-client-dev avahi-daemon dbus
  dpkg-dev fakeroot systemd lintian
  # HIL in a VM (scripts/hil-vm.sh): qemu, a static busybox for the initramfs, depmod
  qemu-system-x86 busybox-static cpio kmod
)
# The headers gpio-sim is built against; the ABI (57) must match SLSCAN_HIL_ABI in
# scripts/hil-vm.sh. Optional: when the mirror has moved on, only the VM test is affected.
hil_headers=linux-headers-6.1.0-${SLSCAN_HIL_ABI:-57}-amd64

stamp=/var/lib/slscan-bootstrap.stamp
want="$(printf '%s\n' "${packages[@]}" | sort | tr '\n' ' ')"
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ] && dpkg -s "${packages[@]}" >/dev/null 2>&1; then
  echo "bootstrap: all packages present"
else
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${packages[@]}"
  # libcamera >= 0.3 exists only in backports for bookworm; the firmware builds without it.
  $SUDO apt-get install -y -qq --no-install-recommends -t bookworm-backports libcamera-dev || \
    echo "bootstrap: libcamera-dev from bookworm-backports not available; the libcamera backend will be skipped"
  echo "$want" | $SUDO tee "$stamp" >/dev/null
fi
if ! dpkg -s "$hil_headers" >/dev/null 2>&1; then
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "$hil_headers" || \
    echo "bootstrap: $hil_headers not available; scripts/hil-vm.sh (HIL in a VM) will not run"
fi

# report.html's 3D viewer is bundled at build time from npm packages (three, esbuild) pinned by
# host/app/viewer/package-lock.json. Debian's nodejs and npm unless a Node.js with npm is there
# already (a NodeSource nodejs carries its own npm and conflicts with Debian's).
if ! command -v npm >/dev/null; then
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get install -y -qq --no-install-recommends nodejs npm || \
    echo "bootstrap: nodejs/npm not installed; slscan will build without the report's 3D viewer"
fi
viewer="$(cd "$(dirname "$0")/.." && pwd)/host/app/viewer"
if command -v npm >/dev/null; then
  if [ -f "$viewer/node_modules/.package-lock.json" ] && [ "$viewer/node_modules/.package-lock.json" -nt "$viewer/package-lock.json" ]; then
    echo "bootstrap: viewer npm packages present"
  else
    (cd "$viewer" && npm ci --no-audit --no-fund --loglevel=error) || \
      echo "bootstrap: npm ci failed in $viewer; slscan will build without the report's 3D viewer"
  fi
fi
