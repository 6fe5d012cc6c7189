#!/usr/bin/env bash
# Installs the peers that bench/speed compares against (PCL, Open3D) and configures a
# release build with them. NOT part of scripts/bootstrap.sh: the default build and the tests
# never need them. OpenCV contrib (structured_light) is already a default dependency.
# Usage (as root on Debian 12): scripts/bench-setup.sh [build-dir]   (default build/release)
set -euo pipefail
cd "$(dirname "$0")/.."
SUDO=
[ "$(id -u)" -ne 0 ] && SUDO=sudo
$SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends libpcl-dev libopen3d-dev
dir=${1:-build/release}
cmake --preset release -B "$dir" -DSLSCAN_BENCH_PEERS=ON
echo "now: cmake --build $dir -j2 --target bench_speed && $dir/bench/speed/bench_speed --out speed.md   # see docs/benchmarks.md"
