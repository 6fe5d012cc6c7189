#!/usr/bin/env bash
# Sets everything up on a fresh Debian 12 machine and runs the main job: slscand on the sim
# board (the virtual rig) serves a full-resolution scan of the ball bar over loopback, slscan
# records, reconstructs and measures it, and everything lands in out/.
#   scripts/demo.sh                      the ball bar, 2464 x 2056
#   scripts/demo.sh --scene teacup       another scene (ballbar, sphere, plane, blade, teacup)
#   scripts/demo.sh --small              the 640 x 512 rig: a quick look
set -euo pipefail
cd "$(dirname "$0")/.."

if [ "$(id -u)" -eq 0 ] || command -v sudo >/dev/null; then
  scripts/bootstrap.sh
fi
cmake --preset release >/dev/null
cmake --build --preset release -j "$(nproc)" --target slscan slscand
# --overwrite: each run replaces the demo capture of the last one in out/ (a scan of your own
# into an existing folder is refused unless you say so).
exec build/release/host/app/slscan demo --out out --overwrite "$@"
