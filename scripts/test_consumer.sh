#!/usr/bin/env bash
# CTest entry "consumer": qdo as an installed C++ library.
#   scripts/test_consumer.sh BUILD_DIR [CXX_COMPILER]
# Installs BUILD_DIR (cmake --install) into a scratch prefix, checks the installed layout,
# configures and builds examples/consumer against it (find_package(qdo), qdo::qdo), runs it
# (QDO_DEVICE, default cpu) and checks its output: the bands, N, one PSF sum per band, "ok".
# The scratch folder (prefix and consumer build) is removed on exit, pass or fail. Exits nonzero
# on the first failing step, with that step's log.
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
build="$(cd "${1:?usage: test_consumer.sh BUILD_DIR [CXX_COMPILER]}" && pwd)"
cxx="${2:-}"
# Compiled kernels: reuse the build's test cache unless the caller chose one (scripts/test.sh).
export QDO_CACHE_DIR="${QDO_CACHE_DIR:-$build/kernel-cache}"
export QDO_DEVICE="${QDO_DEVICE:-cpu}"
tmp="$(mktemp -d "${TMPDIR:-/tmp}/qdo-consumer.XXXXXX")"
trap 'rm -rf "$tmp"' EXIT
prefix="$tmp/prefix"

fail() { echo "consumer: FAILED: $*" >&2; exit 1; }
# step NAME CMD...: runs CMD with its output in $tmp/NAME.log, printed if it fails; times it.
step() {
  local name="$1" t0=$SECONDS
  shift
  if ! "$@" > "$tmp/$name.log" 2>&1; then
    cat "$tmp/$name.log" >&2
    fail "$name: $*"
  fi
  echo "consumer: $name ok ($((SECONDS - t0)) s)"
}

step install cmake --install "$build" --prefix "$prefix"
for f in bin/qdo include/qdo/physics/simulator.hpp include/qdo/data/config.hpp; do
  [[ -f "$prefix/$f" ]] || fail "not installed: $f"
done
cfgdir="$(dirname "$(find "$prefix" -path '*/cmake/qdo/qdoConfig.cmake' | head -n1)")"
[[ "$cfgdir" != . ]] || fail "not installed: lib/cmake/qdo/qdoConfig.cmake"
for f in qdoConfigVersion.cmake qdoTargets.cmake; do [[ -f "$cfgdir/$f" ]] || fail "not installed: $cfgdir/$f"; done
ls "$(dirname "$(dirname "$cfgdir")")"/libqdo_core.a > /dev/null || fail "not installed: libqdo_core.a"
# The exported targets must not point into the source or build tree.
if grep -nF -e "$repo/" -e "$build/" "$cfgdir"/*.cmake; then fail "installed CMake files name the source or build tree"; fi

step configure cmake -S "$repo/examples/consumer" -B "$tmp/build" -DCMAKE_PREFIX_PATH="$prefix" \
  -DCMAKE_BUILD_TYPE=Release ${cxx:+"-DCMAKE_CXX_COMPILER=$cxx"}
step build cmake --build "$tmp/build" -j1
step run "$tmp/build/qdo_consumer"
out="$tmp/run.log"
cat "$out"
grep -qx 'bands: 31' "$out" || fail "no line 'bands: 31'"
grep -qx 'N: 256' "$out" || fail "no line 'N: 256'"
n_band="$(grep -cE '^band [0-9]+ \([0-9]+ nm\): psf sum [0-9.]+$' "$out" || true)"
[[ "$n_band" == 31 ]] || fail "$n_band band lines, expected 31"
grep -q '^consumer: ok' "$out" || fail "no line 'consumer: ok'"
echo "consumer: passed"
