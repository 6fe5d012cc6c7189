#!/usr/bin/env bash
# Builds the fuzz preset (clang-14, libFuzzer + ASan + UBSan) and runs every fuzz target for
# SECONDS each on a scratch copy of its committed seed corpus (tests/fuzz/corpus/<target>).
# Fails on the first crash, leak, sanitizer report or timeout; the offending input is kept in
# build/fuzz/artifacts/.
# Usage: scripts/fuzz.sh [SECONDS=60]
#   Longer campaign that grows the committed corpus (then review and commit new files):
#     scripts/fuzz.sh 3600 && build/fuzz/tests/fuzz/fuzz_frame_decoder -merge=1 \
#         tests/fuzz/corpus/frame_decoder build/fuzz/corpus-work/frame_decoder
set -euo pipefail
cd "$(dirname "$0")/.."

seconds=${1:-60}
targets=(frame_decoder capture_reader)
build=build/fuzz

cmake --preset fuzz >/dev/null
cmake --build --preset fuzz -j "$(nproc)" --target "${targets[@]/#/fuzz_}"

mkdir -p "$build/artifacts"
work="$build/corpus-work"
rm -rf "$work"
for target in "${targets[@]}"; do
  mkdir -p "$work/$target"
  cp tests/fuzz/corpus/"$target"/* "$work/$target"/
  echo "==== fuzz_$target for ${seconds}s"
  if ! ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
      "$build/tests/fuzz/fuzz_$target" -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 \
      -print_final_stats=1 -artifact_prefix="$build/artifacts/$target-" "$work/$target" \
      >"$build/fuzz_$target.log" 2>&1; then
    tail -n 60 "$build/fuzz_$target.log"
    echo "fuzz_$target FAILED: reproducer in $build/artifacts/ (log: $build/fuzz_$target.log)" >&2
    exit 1
  fi
  grep -E "^stat::number_of_executed_units|^stat::peak_rss_mb" "$build/fuzz_$target.log" || true
  echo "fuzz_$target: no crash; corpus $(ls "$work/$target" | wc -l) inputs"
done
