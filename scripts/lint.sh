#!/usr/bin/env bash
# clang-tidy (the checks of .clang-tidy) on the C++ sources a change touches, with the flags of
# a configured build's compile_commands.json. Exit 0 when clean, 1 on a finding (named by
# file:line and check), 2 when it cannot run.
#
#   scripts/lint.sh                  sources changed since main (committed or not), untracked ones too
#   scripts/lint.sh --base REV       ... since REV instead
#   scripts/lint.sh FILE...          these files
#   BUILD=build/asan scripts/lint.sh another build's compile_commands.json (default build/dev)
#
# A changed header is checked through the sources that include it (.clang-tidy's
# HeaderFilterRegex covers shared/, firmware/ and host/); a header no changed source includes is
# listed as not checked. Files outside the build (another backend, a fuzz target) are skipped
# with their name.
set -euo pipefail
cd "$(dirname "$0")/.."
build=${BUILD:-build/dev}
base=main
files=()
while [ $# -gt 0 ]; do
  case $1 in
    --base) base=${2:?--base needs a revision}; shift 2 ;;
    -h|--help) sed -n '2,14p' "$0"; exit 0 ;;
    *) files+=("$1"); shift ;;
  esac
done
tidy=$(command -v clang-tidy || command -v clang-tidy-14 || true)
[ -n "$tidy" ] || { echo "lint: clang-tidy not found (scripts/bootstrap.sh installs it)" >&2; exit 2; }
db=$build/compile_commands.json
[ -f "$db" ] || { echo "lint: no $db: configure first (cmake --preset dev)" >&2; exit 2; }

if [ ${#files[@]} -eq 0 ]; then
  merge_base=$(git merge-base HEAD "$base" 2>/dev/null) || { echo "lint: no revision '$base'" >&2; exit 2; }
  mapfile -t files < <({ git diff --name-only --diff-filter=d "$merge_base" -- '*.cpp' '*.hpp' '*.h'
                         git ls-files --others --exclude-standard -- '*.cpp' '*.hpp' '*.h'; } | sort -u)
fi
[ ${#files[@]} -gt 0 ] || { echo "lint: no C++ file changed since $base"; exit 0; }

# The sources the build compiles, as paths relative to the repository.
root=$(pwd)
mapfile -t compiled < <(python3 -c '
import json, os, sys
root = sys.argv[2]
for e in json.load(open(sys.argv[1])):
    f = os.path.normpath(os.path.join(e["directory"], e["file"]))
    if f.startswith(root + "/"):
        print(f[len(root) + 1:])' "$db" "$root" | sort -u)

sources=() headers=()
for f in "${files[@]}"; do
  case $f in
    *.cpp) if printf '%s\n' "${compiled[@]}" | grep -qxF "$f"; then sources+=("$f")
           else echo "lint: $f is not in $db (not built here), skipped"; fi ;;
    *) headers+=("$f") ;;
  esac
done
# A changed header with no changed includer: check the compiled sources that include it by name.
for h in "${headers[@]}"; do
  name=$(basename "$h")
  covered=0
  for s in "${sources[@]}"; do grep -q "include \".*$name\"" "$s" && { covered=1; break; }; done
  [ $covered -eq 1 ] && continue
  mapfile -t users < <(printf '%s\n' "${compiled[@]}" | xargs grep -l "include \"\(.*/\)\?$name\"" 2>/dev/null | head -n 3)
  if [ ${#users[@]} -eq 0 ]; then echo "lint: $h: no compiled source includes it, not checked"; fi
  sources+=("${users[@]}")
done
mapfile -t sources < <(printf '%s\n' "${sources[@]}" | sed '/^$/d' | sort -u)
[ ${#sources[@]} -gt 0 ] || { echo "lint: nothing to check"; exit 0; }

# The build is GCC's: its GCC-only options (decode's and triangulate's -fvect-cost-model,
# -fno-loop-unroll-and-jam) are unknown arguments to clang, so check with a copy of the
# database without them.
filtered=$(mktemp -d)
trap 'rm -rf "$filtered"' EXIT
python3 -c '
import json, shlex, sys
gcc_only = ("-fvect-cost-model", "-fno-loop-unroll-and-jam", "-fno-tree-")
db = json.load(open(sys.argv[1]))
for e in db:
    if "command" in e:
        e["command"] = shlex.join(a for a in shlex.split(e["command"]) if not a.startswith(gcc_only))
    if "arguments" in e:
        e["arguments"] = [a for a in e["arguments"] if not a.startswith(gcc_only)]
json.dump(db, open(sys.argv[2], "w"))' "$db" "$filtered/compile_commands.json"

echo "lint: clang-tidy on ${#sources[@]} file(s) with $db"
status=0
for s in "${sources[@]}"; do
  if ! nice -n 10 "$tidy" -p "$filtered" --quiet --extra-arg=-Wno-unknown-warning-option "$s" 2>/dev/null; then
    status=1
  fi
done
if [ $status -ne 0 ]; then echo "lint: findings above (checks in .clang-tidy)"; exit 1; fi
echo "lint: ${#sources[@]} file(s) clean"
