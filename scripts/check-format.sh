#!/usr/bin/env bash
# Fails (naming the files) when a committed C++ source is not clang-formatted.
set -euo pipefail
cd "$(dirname "$0")/.."
mapfile -t files < <(git ls-files '*.cpp' '*.hpp' '*.h' 2>/dev/null || find shared firmware host tests bench -name '*.[ch]pp')
bad=()
for f in "${files[@]}"; do
  [ -f "$f" ] || continue
  clang-format --dry-run -Werror "$f" >/dev/null 2>&1 || bad+=("$f")
done
if [ ${#bad[@]} -gt 0 ]; then
  printf 'clang-format would change:\n'; printf '  %s\n' "${bad[@]}"
  printf 'fix with: clang-format -i <files>\n'
  exit 1
fi
echo "clang-format: ${#files[@]} files clean"
