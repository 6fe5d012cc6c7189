#!/usr/bin/env bash
# Unpacks bookworm-backports' libgpiod 2.x (-dev, the library and the C++ bindings) into a
# prefix without installing it: Debian 12's own libgpiod-dev is 1.6 and both share one
# package name. A build then compiles the v2 GPIO backend with
#   PKG_CONFIG_PATH=<prefix>/usr/lib/<triplet>/pkgconfig cmake ...
# Usage: scripts/fetch-libgpiod2.sh [prefix] [arch]   (default build/libgpiod2, host arch)
# Prints the pkg-config directory on its last line.
set -euo pipefail
cd "$(dirname "$0")/.."
prefix=$(realpath -m "${1:-build/libgpiod2}")
arch=${2:-$(dpkg --print-architecture)}
triplet=$(dpkg-architecture -a "$arch" -qDEB_HOST_MULTIARCH 2>/dev/null)

pcdir="$prefix/usr/lib/$triplet/pkgconfig"
if [ -f "$pcdir/libgpiod.pc" ]; then
  echo "$pcdir"
  exit 0
fi

# bookworm-backports must be in the apt sources (scripts/bootstrap.sh adds it).
version=$(apt-cache madison libgpiod-dev | awk -F'|' '$2 ~ /^ *2\./ {gsub(/ /, "", $2); print $2; exit}')
if [ -z "$version" ]; then
  echo "fetch-libgpiod2: no libgpiod-dev 2.x in the apt sources (is bookworm-backports enabled? run scripts/bootstrap.sh)" >&2
  exit 1
fi
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
(
  cd "$work"
  # libgpiod3 is the 2.x runtime library's package name.
  apt-get download -q "libgpiod-dev:$arch=$version" "libgpiod3:$arch=$version" >/dev/null
)
mkdir -p "$prefix"
for deb in "$work"/*.deb; do
  dpkg-deb -x "$deb" "$prefix"
done
# The .pc file names prefix=/usr; point it at the unpacked tree.
sed -i "s|^prefix=.*|prefix=$prefix/usr|" "$pcdir/libgpiod.pc"
# The -dev package's libgpiod.so is a link to the versioned file, relative, so it still works.
echo "$pcdir"
