#!/usr/bin/env bash
# AddressSanitizer + UndefinedBehaviorSanitizer run of the default test suite, and valgrind on
# the CPU-only paths.
#
#   scripts/sanitize.sh              # build build-sanitize/ (-DQDO_SANITIZE=ON), ctest -L default
#   scripts/sanitize.sh --valgrind   # also valgrind (memcheck) on the CPU-only stress cases
#                                    # (CPU reference and every file reader), Release build
#
# UBSan is made fatal (halt_on_error), so any report fails its test. Reports from code that is
# not ours are suppressed in scripts/lsan.supp (LeakSanitizer) with the reason for each.
set -euo pipefail
cd "$(dirname "$0")/.."
VALGRIND=0
[ "${1:-}" = "--valgrind" ] && VALGRIND=1
bash scripts/install-deps.sh
BUILD="${BUILD:-build-sanitize}"
mkdir -p "$BUILD"
cmake -S . -B "$BUILD" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DQDO_SANITIZE=ON > "$BUILD/build.log" 2>&1 ||
  { cat "$BUILD/build.log"; exit 1; }
cmake --build "$BUILD" -j"${JOBS:-2}" --target qdo_tests qdo qdo_fuzz_replay >> "$BUILD/build.log" 2>&1 ||
  { tail -n 80 "$BUILD/build.log"; exit 1; }
echo "sanitize build: ok ($BUILD/build.log)"

export QDO_CACHE_DIR="${QDO_CACHE_DIR:-$PWD/$BUILD/kernel-cache}"
# new_delete_type_mismatch=0: libclFFT 2.12 (Debian 12) deletes every plan through a pointer of
#   the wrong type (FFTRepo::deletePlan: 616-byte object, 16-byte type) when clfftDestroyPlan runs,
#   i.e. whenever a Runtime goes away. ASan cannot suppress one library for this check; qdo itself
#   has no raw new/delete (RAII and smart pointers only), so nothing of ours is hidden.
# allocator_may_return_null=1: a corrupt HDF5 file can make libhdf5 ask for an absurd block (a
#   bit-flipped 5 KiB checkpoint: 967 GB, in H5C_protect); glibc refuses it, libhdf5 reports the
#   error and qdo turns it into an InputError. ASan would abort instead; this keeps glibc's answer.
# fast_unwind_on_malloc=0: full stacks through libraries built without frame pointers (libhdf5),
#   so the LeakSanitizer suppressions match.
export ASAN_OPTIONS="${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=1:fast_unwind_on_malloc=0:new_delete_type_mismatch=0:allocator_may_return_null=1}"
export LSAN_OPTIONS="${LSAN_OPTIONS:-suppressions=$PWD/scripts/lsan.supp:print_suppressions=0}"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:-halt_on_error=1:print_stacktrace=1}"
(cd "$BUILD" && ctest -L default --output-on-failure -j1)

if [ "$VALGRIND" = 1 ]; then
  command -v valgrind >/dev/null || { echo "sanitize.sh: valgrind not installed (apt-get install valgrind)" >&2; exit 2; }
  bash scripts/build.sh
  # CPU-only cases (no OpenCL: PoCL's JIT and thread pool are not valgrind material).
  valgrind --error-exitcode=1 --leak-check=full --errors-for-leak-kinds=definite --track-origins=yes \
    --suppressions=scripts/valgrind.supp \
    build/qdo_tests --test-suite=stress --test-case='*[cpu]*' --no-intro=true
fi
