#!/usr/bin/env bash
# Runs slscand's maintainer scripts as dpkg would (install, upgrade, remove, purge) inside a
# private mount namespace whose /etc, /var/lib and /lib/systemd/system are throw-away copies:
# the users, groups, token and unit symlinks they create never reach the machine.
# Usage (root): scripts/package-maintscripts-test.sh CONTROL_DIR UNPACKED_ROOT
#   CONTROL_DIR: `dpkg-deb -e` of the slscand package; UNPACKED_ROOT: its `dpkg -x`.
# Called by scripts/package.sh; exits non-zero naming the first wrong result.
set -euo pipefail
control=$1
root=$2
if [ "${SLSCAN_IN_NAMESPACE:-0}" != 1 ]; then
  work=$(mktemp -d)
  trap 'rm -rf "$work"' EXIT
  export SLSCAN_IN_NAMESPACE=1 SLSCAN_NS_WORK=$work
  exec unshare --mount --propagation private "$0" "$control" "$root"
fi

fail() { echo "maintainer scripts: $*" >&2; exit 1; }
work=$SLSCAN_NS_WORK
cp -a /etc "$work/etc"
mkdir -p "$work/var-lib" "$work/units"
cp -a /lib/systemd/system/. "$work/units/"
mount --bind "$work/etc" /etc
mount --bind "$work/var-lib" /var/lib
mount --bind "$work/units" /lib/systemd/system
# What dpkg unpacks before postinst: the conffile and the unit.
cp -a "$root/etc/slscan" /etc/slscan
cp "$root/lib/systemd/system/slscand.service" /lib/systemd/system/
getent passwd slscand >/dev/null && fail "the copied /etc already has a slscand user (test set-up)"
# As dpkg runs them (deb-systemd-helper refuses to run otherwise).
export DPKG_MAINTSCRIPT_PACKAGE=slscand DPKG_MAINTSCRIPT_ARCH=amd64
run() { DPKG_MAINTSCRIPT_NAME=$1 "$control/$1" "${@:2}"; }

run postinst configure
entry=$(getent passwd slscand) || fail "postinst did not create the slscand user"
[[ "$entry" == *:/var/lib/slscand:/usr/sbin/nologin ]] || fail "slscand user entry: $entry"
for group in slscan gpio video dialout; do
  getent group "$group" >/dev/null || fail "group $group missing"
  id -nG slscand | tr ' ' '\n' | grep -qx "$group" || fail "slscand is not in group $group ($(id -nG slscand))"
done
[ "$(stat -c '%a %U %G' /etc/slscan/token)" = "600 root root" ] ||
  fail "token: $(stat -c '%a %U %G' /etc/slscan/token), want 600 root root"
token=$(cat /etc/slscan/token)
[ "${#token}" -ge 32 ] || fail "token has ${#token} characters"
[ "$(stat -c '%a %U' /var/lib/slscand)" = "750 slscand" ] || fail "/var/lib/slscand: $(stat -c '%a %U' /var/lib/slscand)"
if command -v deb-systemd-helper >/dev/null; then
  [ -L /etc/systemd/system/multi-user.target.wants/slscand.service ] || fail "postinst did not enable slscand.service"
fi

# An upgrade keeps the token and the user.
run postinst configure 0.1.0-1
[ "$(cat /etc/slscan/token)" = "$token" ] || fail "an upgrade replaced the token"

# remove, then purge (dpkg deletes the conffile between the two).
run prerm remove
run postrm remove
rm -f /etc/slscan/slscand.toml
run postrm purge
[ ! -e /etc/slscan/token ] || fail "purge left /etc/slscan/token"
[ ! -e /etc/slscan ] || fail "purge left /etc/slscan: $(ls -A /etc/slscan)"
[ ! -e /var/lib/slscand ] || fail "purge left /var/lib/slscand"
[ ! -e /etc/systemd/system/multi-user.target.wants/slscand.service ] || fail "purge left the unit enabled"
echo "maintainer scripts: install (user, groups, 0600 token, state dir, unit enabled), upgrade (token kept), remove, purge (token, /etc/slscan, state, unit links gone)"
