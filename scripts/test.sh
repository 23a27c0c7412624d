#!/usr/bin/env bash
# Sets up (dependencies + one build of everything: scripts/build.sh) and runs the default test
# suite with CTest on the OpenCL CPU device (PoCL), then the Python package's tests
# (scripts/test_python.sh) on the extension of the same build, so the core is compiled once.
# Extra arguments go to ctest and skip the Python tests, e.g. scripts/test.sh -R propagate.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/build.sh
# Compiled kernels are cached per device/driver/options/source; keep the test cache apart.
export QDO_CACHE_DIR="${QDO_CACHE_DIR:-$PWD/build/kernel-cache}"
cd build
# Two entries at a time: a cold run is mostly PoCL compiling kernels and FFT plans, one compiler
# thread per process, so two processes halve it on 2 cores (README "Test time").
ctest -L default --output-on-failure -j2 "$@"
cd ..
# Then the Python package (python/, scripts/test_python.sh), unless only some entries were asked for.
if [ "$#" -eq 0 ]; then
  bash scripts/test_python.sh
fi
