#!/usr/bin/env bash
# Sets up (the core packages + the tool alone: scripts/build.sh --demo) and runs the main job: a
# 4-level QDO+A design and a DO design on synthetic scenes (small preset), evaluated on held-out
# synthetic and the CAVE scenes. Tests, benches, the network plugin and Python are not built.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/build.sh --demo
./build/qdo demo --preset "${QDO_PRESET:-small}" --out "${1:-out/demo}"
