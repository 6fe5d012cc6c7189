#!/usr/bin/env bash
# Sets everything up on a fresh Debian 12 machine and runs every test:
#   1. installs the Debian packages (scripts/bootstrap.sh, idempotent)
#   2. dev build (warnings as errors) and the full CTest suite
#   3. ASan + UBSan build and the same suite, less the README check (label "docs"), "product" and
#      the three longest tests (their code runs under ASan in their siblings; see below)
#   4. the libgpiod v2 GPIO backend, compiled and unit-tested against bookworm-backports' 2.x
#   5. the firmware cross-built for aarch64 (scripts/cross-build.sh arm64): slscand must be an
#      aarch64 ELF, and the firmware tests run under qemu-user
#   6. the Debian packages (scripts/package.sh): amd64 slscand + slscan from the dev build, arm64
#      slscand from step 5's cross build, metadata/contents checks, a scratch-root unpack,
#      systemd-analyze verify of the unit, lintian
#   7. HIL in a VM (scripts/hil-vm.sh): the real GPIO, V4L2 and serial backends in qemu
#   8. each libFuzzer target (every parser of outside data) for 15 s on its committed corpus
#   9. clang-format check of every source file
# Usage: scripts/test.sh   (SLSCAN_SKIP_ASAN=1 / SLSCAN_SKIP_FUZZ=1 / SLSCAN_SKIP_GPIOD2=1 /
#        SLSCAN_SKIP_CROSS=1 / SLSCAN_SKIP_PACKAGE=1 / SLSCAN_SKIP_HILVM=1 to shorten)
set -euo pipefail
cd "$(dirname "$0")/.."

if [ "$(id -u)" -eq 0 ] || command -v sudo >/dev/null; then
  scripts/bootstrap.sh
fi

jobs=$(nproc)
# Each step's start is stamped with the seconds since the script began, so a CI log shows where
# the time goes (CI allows 90 minutes for all of it).
step() { printf '\n==== [%ds] %s\n' "$SECONDS" "$*"; }

step "dev build + tests"
# In CI (CI=true) the dev build carries line tables only (-g1, as the sanitizer build): ~20 % less
# compile time; a developer's own run keeps the preset's full -g for the debugger.
dev_flags=()
if [ "${CI:-}" = true ]; then dev_flags=(-DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O2 -g1 -DNDEBUG"); fi
cmake --preset dev "${dev_flags[@]}" >/dev/null
cmake --build --preset dev -j "$jobs"
ctest --preset dev

if [ "${SLSCAN_SKIP_ASAN:-0}" != 1 ]; then
  step "ASan + UBSan build + tests"
  cmake --preset asan >/dev/null
  cmake --build --preset asan -j "$jobs"
  # Without the "docs" tests (the README's commands run as written: each is tested on its own) and
  # the "product" ones (whole-product runs of parts the other tests check under the sanitizers),
  # and without the three longest (2-4 minutes each under the sanitizers), whose code runs there
  # in their siblings: the rig's whole calibration (CalibrateConnect.Disconnect... solves one
  # through slscand, CalibrationSolve.* each solver), the six wrong foreign descriptions
  # (ForeignConventions' axis and offset cases import and detect the same way), the one-CPU
  # scan against two (OneCpu's Ctrl-C cases scan and reprocess on one CPU).
  heavy='^(CalibrationRig\.RecoversTheRigsTruth|ForeignConventions\.EveryWrongDescriptionIsCaughtAndDetectFindsTheRightOne'
  heavy+='|OneCpu\.ScanAndReprocessCompleteAndMatchTwoCpus)$'
  ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1 \
    ctest --preset asan -LE "docs|product" -E "$heavy"
fi

if [ "${SLSCAN_SKIP_GPIOD2:-0}" != 1 ]; then
  step "libgpiod v2 backend"
  pc=$(scripts/fetch-libgpiod2.sh | tail -n1)
  PKG_CONFIG_PATH=$pc cmake -S . -B build/gpiod2 -G Ninja -DSLSCAN_WERROR=ON -DSLSCAN_BUILD_HOST=OFF \
    -DSLSCAN_BUILD_BENCH=OFF >/dev/null
  cmake --build build/gpiod2 -j "$jobs" --target test_firmware_gpio
  build/gpiod2/tests/firmware/test_firmware_gpio
fi

if [ "${SLSCAN_SKIP_CROSS:-0}" != 1 ]; then
  step "aarch64 cross build of the firmware + its tests under qemu-user"
  scripts/cross-build.sh arm64
fi

# ---- BEGIN packages (issue 11: appliance)
if [ "${SLSCAN_SKIP_PACKAGE:-0}" != 1 ]; then
  step "Debian packages: amd64 from the dev build, arm64 from the cross build; unit verify, lintian"
  # The arm64 package is required whenever the cross step above ran.
  if [ "${SLSCAN_SKIP_CROSS:-0}" != 1 ]; then require_arm64=1; else require_arm64=0; fi
  SLSCAN_PACKAGE_REQUIRE_ARM64=$require_arm64 scripts/package.sh build/dev
fi
# ---- END packages

# ---- HIL in a VM (scripts/hil-vm.sh, docs/hil.md): slscand's libgpiod, V4L2 and libserialport
# backends on gpio-sim, vivid and a UART in qemu (TCG); ~30 s warm. SLSCAN_SKIP_HILVM=1 skips.
if [ "${SLSCAN_SKIP_HILVM:-0}" != 1 ]; then
  step "HIL in a VM"
  scripts/hil-vm.sh
fi
# ---- end HIL in a VM

if [ "${SLSCAN_SKIP_FUZZ:-0}" != 1 ] && [ -d tests/fuzz ]; then
  step "fuzz smoke (libFuzzer, clang-14)"
  scripts/fuzz.sh "${SLSCAN_FUZZ_SECONDS:-15}"
fi

step "clang-format"
scripts/check-format.sh
echo "all tests passed in ${SECONDS}s"
