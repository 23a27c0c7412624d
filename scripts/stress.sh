#!/usr/bin/env bash
# The stability suite (tests/test_stress_*.cpp, STABILITY.md): installs and builds like
# scripts/test.sh, then runs the quick part (CTest "stress-quick", also in the default label),
# the long cases (CTest "stress", label "stress": 10,000 design steps, N up to 4096, kill -9 of
# design runs; about 5 minutes on 2 cores) and the fuzz corpus replay ("fuzz-regression").
# Extra arguments go to ctest.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/build.sh
export QDO_CACHE_DIR="${QDO_CACHE_DIR:-$PWD/build/kernel-cache}"
cd build
ctest -R '^(stress-quick|stress|fuzz-regression)$' --output-on-failure -j1 "$@"
