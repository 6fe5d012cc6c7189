#!/usr/bin/env bash
# Builds the Debian packages and checks them (docs/appliance.md, "Packages"):
#   1. slscand + slscan for amd64 with CPack from a finished native build (default build/dev);
#   2. slscand for arm64 (and armhf) from the cross build dirs scripts/cross-build.sh leaves
#      (build/aarch64, build/armhf): no second build;
#   3. dpkg-deb -I / -c: names, version, architecture, dependencies (cross: every NEEDED soname
#      of slscand covered by Depends), conffiles, maintainer scripts, the expected files;
#   4. dpkg -x of the amd64 packages into a scratch root: the files, slscand --check on the
#      packaged sim board with the packaged configuration, slscan runs, every library resolves;
#   5. the maintainer scripts (install, upgrade, remove, purge) in a private mount namespace
#      (scripts/package-maintscripts-test.sh: /etc and /var/lib are throw-away copies);
#      systemd-analyze verify of the unit inside the scratch root (ExecStart resolved there);
#   6. lintian: errors fail, warnings are printed.
# Usage: scripts/package.sh [native build dir]   (SLSCAN_PACKAGE_REQUIRE_ARM64=1: fail without
#        the arm64 cross build instead of skipping it; the CI block sets it unless cross is off)
# Output: build/packages/*.deb
set -euo pipefail
cd "$(dirname "$0")/.."
native=${1:-build/dev}
out=$PWD/build/packages
start=$(date +%s)
fail() { echo "package: $*" >&2; exit 1; }
note() { echo "package: $*"; }

version=$(sed -nE 's/^project\(slscan VERSION ([0-9.]+) .*/\1/p' CMakeLists.txt)
[ -n "$version" ] || fail "cannot read the project version from CMakeLists.txt"
debversion=$version-1
for tool in cpack dpkg-deb dpkg-shlibdeps readelf systemd-analyze; do
  command -v "$tool" >/dev/null || fail "$tool is missing (scripts/bootstrap.sh installs it)"
done
[ -f "$native/CPackConfig.cmake" ] || fail "$native/CPackConfig.cmake missing: configure and build $native first"
for binary in firmware/app/slscand host/app/slscan; do
  [ -x "$native/$binary" ] || fail "$native/$binary is not built (cmake --build $native)"
done

rm -rf "$out"
mkdir -p "$out"
build_packages() {  # build dir, architecture
  local dir=$1 arch=$2 work=$out/cpack-$2
  # Re-run cmake so CPackConfig.cmake matches the current packaging files.
  cmake "$dir" >/dev/null
  cpack --config "$dir/CPackConfig.cmake" -B "$work" >"$work.log" 2>&1 || { cat "$work.log"; fail "cpack failed for $arch"; }
  mv "$work"/*.deb "$out"/
  rm -rf "$work" "$work.log"
}

build_packages "$native" amd64
if [ -f build/aarch64/CPackConfig.cmake ] && [ -x build/aarch64/firmware/app/slscand ]; then
  build_packages build/aarch64 arm64
elif [ "${SLSCAN_PACKAGE_REQUIRE_ARM64:-0}" = 1 ]; then
  fail "no arm64 cross build in build/aarch64 (scripts/cross-build.sh arm64 first)"
else
  note "arm64: skipped, no cross build in build/aarch64 (scripts/cross-build.sh arm64)"
fi
if [ -f build/armhf/CPackConfig.cmake ] && [ -x build/armhf/firmware/app/slscand ]; then
  build_packages build/armhf armhf
fi
ls -l "$out"/*.deb

# ---- metadata and contents
field() { dpkg-deb -f "$1" "$2"; }
board_files=(./etc/slscan/slscand.toml ./lib/systemd/system/slscand.service ./lib/udev/rules.d/60-slscan.rules
             ./usr/bin/slscand ./usr/share/slscan/boards/rpi.toml ./usr/share/slscan/boards/beaglebone-black.toml
             ./usr/share/slscan/boards/sim.toml ./usr/share/doc/slscand/appliance.md
             ./usr/share/doc/slscand/copyright ./usr/share/doc/slscand/changelog.Debian.gz)
host_files=(./usr/bin/slscan ./usr/share/doc/slscan/copyright ./usr/share/doc/slscan/changelog.Debian.gz)
# soname -> Debian package, for the cross builds' declared Depends.
declare -A soname_package=([libc.so.6]=libc6 [libm.so.6]=libc6 [ld-linux-aarch64.so.1]=libc6
  [ld-linux-armhf.so.3]=libc6 [libstdc++.so.6]=libstdc++6 [libgcc_s.so.1]=libgcc-s1
  [libprotobuf-lite.so.32]=libprotobuf-lite32 [libgpiod.so.2]=libgpiod2 [libserialport.so.0]=libserialport0
  [libavahi-client.so.3]=libavahi-client3 [libavahi-common.so.3]=libavahi-common3)

check_deb() {  # file, package, architecture, expected files...
  local deb=$1 package=$2 arch=$3
  shift 3
  [ "$(field "$deb" Package)" = "$package" ] || fail "$deb: Package is $(field "$deb" Package), want $package"
  [ "$(field "$deb" Version)" = "$debversion" ] || fail "$deb: Version is $(field "$deb" Version), want $debversion"
  [ "$(field "$deb" Architecture)" = "$arch" ] || fail "$deb: Architecture is $(field "$deb" Architecture), want $arch"
  local depends
  depends=$(field "$deb" Depends)
  [[ "$depends" == *libc6* && "$depends" == *libprotobuf-lite32* ]] || fail "$deb: Depends lacks libc6/libprotobuf-lite32: $depends"
  local contents
  contents=$(dpkg-deb -c "$deb" | awk '{print $6}')
  for f in "$@"; do
    grep -qxF "$f" <<<"$contents" || fail "$deb: $f is missing"
  done
  if grep -q 'qemu-vm.toml' <<<"$contents"; then fail "$deb: ships the HIL VM's test board"; fi
  if grep -v '^\./\(usr\|etc\|lib\)/' <<<"$contents" | grep -qv '^\./$'; then
    fail "$deb: files outside /usr, /etc, /lib: $(grep -v '^\./\(usr\|etc\|lib\)/' <<<"$contents" | grep -v '^\./$')"
  fi
  note "$deb: $package $debversion $arch, $(wc -l <<<"$contents") entries, Depends: $depends"
}

check_board_deb() {  # file, architecture
  local deb=$1 arch=$2 control
  check_deb "$deb" slscand "$arch" "${board_files[@]}"
  control=$(mktemp -d)
  dpkg-deb -e "$deb" "$control"
  [ "$(cat "$control/conffiles")" = /etc/slscan/slscand.toml ] || fail "$deb: conffiles is not /etc/slscan/slscand.toml"
  for script in postinst prerm postrm; do
    [ -x "$control/$script" ] || fail "$deb: no executable $script"
    sh -n "$control/$script" || fail "$deb: $script has a shell syntax error"
  done
  grep -q 'useradd --system' "$control/postinst" || fail "$deb: postinst does not create the slscand user"
  grep -q '/etc/slscan/token' "$control/postinst" || fail "$deb: postinst does not create the token"
  rm -rf "$control"
  if [ "$arch" != amd64 ]; then
    # Cross: every library slscand needs must be declared.
    local x depends
    x=$(mktemp -d)
    dpkg-deb -x "$deb" "$x"
    depends=$(field "$deb" Depends)
    while read -r soname; do
      local pkg=${soname_package[$soname]:-}
      [ -n "$pkg" ] || fail "$deb: slscand needs $soname, which cmake/Packaging.cmake does not map to a package"
      [[ "$depends" == *"$pkg "* || "$depends" == *"$pkg," || "$depends" == *"$pkg" ]] || fail "$deb: slscand needs $soname but Depends has no $pkg"
    done < <(readelf -d "$x/usr/bin/slscand" | sed -nE 's/.*\(NEEDED\).*\[(.*)\]/\1/p')
    file -b "$x/usr/bin/slscand" | grep -q "ELF" || fail "$deb: /usr/bin/slscand is not an ELF"
    note "$deb: $(file -b "$x/usr/bin/slscand" | cut -d, -f1-2); every NEEDED soname declared"
    rm -rf "$x"
  fi
}

check_board_deb "$out/slscand_${debversion}_amd64.deb" amd64
check_deb "$out/slscan_${debversion}_amd64.deb" slscan amd64 "${host_files[@]}"
for arch in arm64 armhf; do
  if [ -f "$out/slscand_${debversion}_${arch}.deb" ]; then check_board_deb "$out/slscand_${debversion}_${arch}.deb" "$arch"; fi
done

# ---- the amd64 packages unpacked into a scratch root
root=$out/root
rm -rf "$root"
mkdir -p "$root"
dpkg -x "$out/slscand_${debversion}_amd64.deb" "$root"
dpkg -x "$out/slscan_${debversion}_amd64.deb" "$root"
for binary in "$root/usr/bin/slscand" "$root/usr/bin/slscan"; do
  if ldd "$binary" | grep -q 'not found'; then fail "$binary: $(ldd "$binary" | grep 'not found')"; fi
done
"$root/usr/bin/slscan" --help >/dev/null || fail "the packaged slscan does not run"
# The packaged configuration parses, and the packaged binary passes every check on the
# packaged sim board (any free port; a token so the token check has one).
check_token=$(mktemp)
echo "package-check-token-0123456789" > "$check_token"
chmod 600 "$check_token"
check_out=$("$root/usr/bin/slscand" --config "$root/etc/slscan/slscand.toml" \
  --board "$root/usr/share/slscan/boards/sim.toml" --port 0 --token-file "$check_token" --check) ||
  { echo "$check_out"; fail "slscand --check on the packaged sim board failed"; }
rm -f "$check_token"
note "scratch root: $(tail -n1 <<<"$check_out") (packaged slscand, sim board, packaged configuration)"
grep -q '^token_file = "/etc/slscan/token"' "$root/etc/slscan/slscand.toml" || fail "slscand.toml: no token_file"

# ---- the maintainer scripts, run as dpkg would in a private mount namespace (root only)
if [ "$(id -u)" -eq 0 ] && command -v unshare >/dev/null; then
  control=$out/control-amd64
  mkdir -p "$control"
  dpkg-deb -e "$out/slscand_${debversion}_amd64.deb" "$control"
  scripts/package-maintscripts-test.sh "$control" "$root" 2>&1 | grep -v '^Created symlink\|^Removed' ||
    fail "maintainer scripts"
  [ "${PIPESTATUS[0]}" -eq 0 ] || fail "maintainer scripts"
  rm -rf "$control"
else
  note "maintainer scripts: not run (needs root and unshare)"
fi

# ---- the unit, verified where it would be installed: the scratch root holds the system's own
# units (targets it orders against) and /usr/bin/slscand for ExecStart.
mkdir -p "$root/usr/lib/systemd"
cp -a /usr/lib/systemd/system "$root/usr/lib/systemd/"
verify=$(systemd-analyze verify --root="$root" slscand.service 2>&1) || { echo "$verify"; fail "systemd-analyze verify failed"; }
# Unknown keys and bad values are only warnings to systemd: any output is a finding here.
[ -z "$verify" ] || { echo "$verify"; fail "systemd-analyze verify reported problems in slscand.service"; }
note "systemd-analyze verify: slscand.service clean"

# ---- lintian (about 10 s): errors fail the step, warnings are shown
if command -v lintian >/dev/null; then
  lint=$(lintian --tag-display-limit 0 "$out"/*.deb 2>&1 | grep -v 'running with root privileges' || true)
  [ -z "$lint" ] || echo "$lint"
  if grep -q '^E:' <<<"$lint"; then fail "lintian reported errors"; fi
  note "lintian: no errors ($(grep -c '^W:' <<<"$lint" || true) warnings)"
else
  note "lintian not installed: skipped"
fi
rm -rf "$root"
note "packages checked in $(( $(date +%s) - start )) s: $(cd "$out" && ls *.deb | tr '\n' ' ')"
