#!/usr/bin/env bash
# Coverage-guided fuzzing of every file reader with libFuzzer (clang from Debian).
#
#   scripts/fuzz.sh [SECONDS] [TARGET ...]     # default: 60 s for each of all targets
#
# Targets (fuzz/fuzz_<name>.cpp): config (JSON), design_h5, cube_h5, checkpoint (HDF5), mat
# (.mat v5 / v7.3), png (PNG band folders), capture_png, capture_tiff and capture_raw (16-bit
# captures and camera raw files), csv (CSV tables and the camera response),
# kernel_cache (one kernel-cache entry), run_folder (what `qdo design --resume` reads),
# sweep_cell (a sweep cell's metrics.json), network_state (a network run's state file).
# Builds them into build-fuzz/ with clang and -fsanitize=fuzzer,address,undefined, then runs
# each from its seed corpus fuzz/corpus/<name>/. New interesting inputs go to
# build-fuzz/corpus/<name>/ (the repository's corpus stays small); crashes, leaks, timeouts and
# sanitizer reports go to build-fuzz/artifacts/<name>-*. A crash found becomes a regression
# input: fix the reader, copy the file to fuzz/corpus/<name>/crash-<what>, add a test; the
# fuzz-regression CTest entry then replays it in every build (without libFuzzer).
set -euo pipefail
cd "$(dirname "$0")/.."
SECONDS_EACH="${1:-60}"
shift || true
ALL=(config design_h5 cube_h5 mat checkpoint png capture_png capture_tiff capture_raw csv kernel_cache run_folder sweep_cell network_state)
TARGETS=("$@")
[ ${#TARGETS[@]} -eq 0 ] && TARGETS=("${ALL[@]}")

if ! command -v clang++ >/dev/null || ! ls /usr/lib/llvm-*/lib/clang/*/lib/linux/libclang_rt.fuzzer-x86_64.a >/dev/null 2>&1; then
  echo "fuzz.sh: needs clang and libFuzzer: sudo apt-get install clang libclang-rt-14-dev" >&2
  exit 2
fi
BUILD="${BUILD:-build-fuzz}"
mkdir -p "$BUILD"
if [ ! -f "$BUILD/CMakeCache.txt" ]; then
  CC=clang CXX=clang++ cmake -S . -B "$BUILD" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DQDO_FUZZ=ON > "$BUILD/build.log" 2>&1 ||
    { cat "$BUILD/build.log"; exit 1; }
fi
cmake --build "$BUILD" -j"${JOBS:-2}" --target $(printf 'fuzz_%s ' "${TARGETS[@]}") >> "$BUILD/build.log" 2>&1 ||
  { tail -n 60 "$BUILD/build.log"; exit 1; }

# Leak reports from libhdf5/libmatio error paths would stop every run at the first corrupt
# file; see scripts/lsan.supp for what is suppressed and why.
export ASAN_OPTIONS="${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=1:fast_unwind_on_malloc=0:allocator_may_return_null=1}"
export LSAN_OPTIONS="${LSAN_OPTIONS:-suppressions=$PWD/scripts/lsan.supp:print_suppressions=0}"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:-halt_on_error=1:print_stacktrace=1}"
export HDF5_USE_FILE_LOCKING=FALSE
status=0
for t in "${TARGETS[@]}"; do
  mkdir -p "$BUILD/corpus/$t" "$BUILD/artifacts"
  echo "== fuzz_$t: ${SECONDS_EACH} s"
  # -rss_limit_mb / -malloc_limit_mb: a reader that allocates what a tiny file merely declares
  # (unbounded allocation) is reported as a crash.
  if ! "$BUILD/fuzz_$t" -max_total_time="$SECONDS_EACH" -timeout=10 -rss_limit_mb=2048 -malloc_limit_mb=1024 \
       -max_len=16384 -print_final_stats=1 -artifact_prefix="$BUILD/artifacts/$t-" \
       "$BUILD/corpus/$t" "fuzz/corpus/$t" 2> "$BUILD/fuzz_$t.log"; then
    # Known and not ours (STABILITY.md): libhdf5 1.10.8 requests blocks of the sizes a corrupt
    # file declares in its metadata cache (H5C_protect) while opening it, before qdo can check
    # anything. Reported, not counted as a failure.
    if grep -q 'libFuzzer: out-of-memory (malloc' "$BUILD/fuzz_$t.log" &&
       grep -E '#[0-9]+ 0x' "$BUILD/fuzz_$t.log" | grep -v -E 'fuzzer::|__sanitizer|__asan|malloc' | head -n 1 | grep -q 'H5C_protect'; then
      echo "   known libhdf5 issue (allocation request in H5C_protect while opening a corrupt file): $(ls "$BUILD/artifacts/$t-"* | tail -n 1)"
      continue
    fi
    status=1
    echo "   FOUND a problem: $(grep -m1 -E 'ERROR|deadly signal|uncaught|invariant violated' "$BUILD/fuzz_$t.log" || true)"
    ls "$BUILD/artifacts/$t-"* 2>/dev/null | sed 's/^/   input: /'
    echo "   log: $BUILD/fuzz_$t.log"
  else
    grep -E 'stat::number_of_executed_units|cov:' "$BUILD/fuzz_$t.log" | tail -n 2 | sed 's/^/   /'
  fi
done
exit $status
