#!/usr/bin/env bash
# Installs missing dependencies, then configures and builds qdo (Release) into ./build.
#   bash scripts/build.sh          everything: the tool, its network plugin (LibTorch), the tests,
#                                  the benches and the Python extension (staged in build/pystage),
#                                  the core compiled once for all of them (scripts/test.sh)
#   bash scripts/build.sh --demo   the tool alone, with the core packages (scripts/demo.sh): on a
#                                  fresh build folder without LibTorch and Python (the demo uses
#                                  neither); a configured folder keeps its settings, and a later
#                                  `bash scripts/build.sh` adds the rest without recompiling the core
set -euo pipefail
cd "$(dirname "$0")/.."
profile=all
case "${1:-}" in
  "") ;;
  --demo) profile=demo ;;
  *) echo "build.sh: unknown argument '$1' (allowed: none, or --demo)" >&2; exit 2 ;;
esac
if [ "$profile" = demo ]; then
  bash scripts/install-deps.sh core
  opts=()
  # A fresh folder: no network decoder, no Python (a configured one keeps what it has).
  [ -f build/CMakeCache.txt ] || opts=(-DQDO_TORCH=OFF -DQDO_PYTHON=OFF)
  targets=(--target qdo)
else
  bash scripts/install-deps.sh all
  # The extension for Debian's interpreter, whose NumPy, PyTorch and pytest install-deps.sh
  # installs (another python3 earlier on PATH, a pyenv's, has none of them).
  opts=(-DQDO_TORCH=ON -DQDO_PYTHON=ON -DPython_EXECUTABLE=/usr/bin/python3)
  targets=()
fi
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release -DQDO_WERROR=ON "${opts[@]}" > build.log 2>&1 || { cat build.log; exit 1; }
start=$(date +%s)
cmake --build build -j"$(nproc)" "${targets[@]}" >> build.log 2>&1 || { tail -n 80 build.log; exit 1; }
echo "build: ok, $profile, $(( $(date +%s) - start )) s (log in build.log)"
