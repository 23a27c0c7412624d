#!/usr/bin/env bash
# Mutation harness: does the default test suite catch realistic bugs?
#
# Each tests/mutations/*.patch is one small bug (a physics slip in a kernel or in host code, an
# adjoint, a data table, the quantizer, the decoder, ...). For each one, in a scratch copy of the
# working tree (never in the tree itself), this script applies the patch, rebuilds incrementally,
# runs the default CTest suite until the first failing entry, reverts the patch, and prints
#   caught  NAME  by ENTRY (TEST CASE)        or        MISSED  NAME
# and last the line "N of M mutations caught". Exit 0 only when every mutation is caught.
#
# Usage: scripts/mutate.sh [NAME_SUBSTRING ...]       (default: every patch)
# Environment: QDO_MUTATE_DIR (scratch folder, default build/mutate; kept between runs so the
# rebuilds are incremental), QDO_MUTATE_TIMEOUT (seconds per CTest entry, default 900).
# Not part of the default CI run: a full pass rebuilds and retests M times (tens of minutes on
# 2 cores). See docs/mutations.md.
set -euo pipefail
cd "$(dirname "$0")/.."
repo="$PWD"
scratch="${QDO_MUTATE_DIR:-$repo/build/mutate}"
timeout_s="${QDO_MUTATE_TIMEOUT:-900}"
src="$scratch/src"
bld="$scratch/build"
logs="$scratch/logs"

patches=()
for p in tests/mutations/*.patch; do
  name="$(basename "$p" .patch)"
  if (($# == 0)); then patches+=("$p"); continue; fi
  for want in "$@"; do [[ "$name" == *"$want"* ]] && { patches+=("$p"); break; }; done
done
((${#patches[@]})) || { echo "mutate: no patch in tests/mutations matches: $*" >&2; exit 2; }

bash scripts/install-deps.sh > /dev/null
# The scratch copy: tracked and untracked-but-not-ignored files. A file is copied (with a new
# timestamp) only when its content differs from the copy's, so the incremental build recompiles
# exactly what changed since the last run (copying timestamps instead would leave objects newer
# than an older-dated but changed source stale); files gone from the tree go from the copy.
mkdir -p "$scratch" "$logs" "$src"
git ls-files -co --exclude-standard > "$scratch/files.txt"
while IFS= read -r f; do
  [[ -f "$f" ]] || continue
  if ! cmp -s "$f" "$src/$f"; then mkdir -p "$src/$(dirname "$f")" && cp "$f" "$src/$f"; fi
done < "$scratch/files.txt"
(cd "$src" && find . -type f -printf '%P\n') | sort > "$scratch/copy.txt"
sort "$scratch/files.txt" | comm -13 - "$scratch/copy.txt" | while IFS= read -r f; do rm -f "$src/$f"; done
ln -sfn "$repo/../shared" "$scratch/shared"  # the tests find ../shared next to the source copy

build() {
  cmake -S "$src" -B "$bld" -DCMAKE_BUILD_TYPE=Release -DQDO_WERROR=ON > "$1" 2>&1 &&
    cmake --build "$bld" -j"$(nproc)" --target qdo qdo_tests qdo_fuzz_replay >> "$1" 2>&1
}
# Runs the default suite, stopping at the first failing entry; prints "ENTRY|TEST CASE" of it.
run_suite() {
  local log="$1"
  (cd "$bld" && QDO_CACHE_DIR="$bld/kernel-cache" ctest -L default -j1 --timeout "$timeout_s" \
      --stop-on-failure --output-on-failure > "$log" 2>&1) && return 0
  local entry case_name
  entry="$(grep -E '\*\*\*(Failed|Timeout|Exception)|Subprocess aborted|\(Failed\)|\(Timeout\)' "$log" | head -n1 |
           sed -E 's/.*Test +#[0-9]+: ([^ ]+).*/\1/')"
  # The doctest case of the first error: the last "TEST CASE:" header before the first ERROR line
  # (passing cases print headers too, for their MESSAGEs).
  case_name="$(awk '/^TEST CASE: /{c=$0; sub(/^TEST CASE: +/, "", c)} /(ERROR|FATAL ERROR): /{print c; exit}' "$log")"
  echo "${entry:-?}|${case_name}"
  return 1
}

echo "mutate: building the unmutated tree in $bld ..."
build "$logs/baseline-build.log" || { tail -n 40 "$logs/baseline-build.log"; echo "mutate: the unmutated tree does not build" >&2; exit 2; }
echo "mutate: running the default suite on the unmutated tree ..."
if ! out="$(run_suite "$logs/baseline-ctest.log")"; then
  echo "mutate: the unmutated tree fails its own suite ($out); see $logs/baseline-ctest.log" >&2
  exit 2
fi

caught=0 total=0
declare -a missed=()
for p in "${patches[@]}"; do
  name="$(basename "$p" .patch)"
  total=$((total + 1))
  t0=$(date +%s)
  if ! patch -p1 -s -d "$src" --dry-run < "$p" > /dev/null 2>&1; then
    printf 'STALE    %-34s the patch no longer applies to this tree: update it\n' "$name"
    missed+=("$name (stale)")
    continue
  fi
  patch -p1 -s -d "$src" < "$p"
  if ! build "$logs/$name-build.log"; then
    result="BUILD    $(printf '%-34s' "$name") does not compile (an unrealistic mutation: fix the patch)"
    missed+=("$name (does not compile)")
  elif out="$(run_suite "$logs/$name-ctest.log")"; then
    result="MISSED   $(printf '%-34s' "$name") every default test passed"
    missed+=("$name")
  else
    caught=$((caught + 1))
    entry="${out%%|*}" case_name="${out#*|}"
    result="caught   $(printf '%-34s' "$name") by ${entry}${case_name:+ (${case_name})}"
  fi
  patch -p1 -s -R -d "$src" < "$p"
  echo "$result  [$(( $(date +%s) - t0 )) s]"
done
# Leave the scratch build matching the unmutated tree for the next run.
build "$logs/final-build.log" || true
echo
if ((${#missed[@]})); then printf 'not caught: %s\n' "${missed[@]}"; fi
echo "$caught of $total mutations caught"
((caught == total))
