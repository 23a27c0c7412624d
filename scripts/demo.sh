#!/usr/bin/env bash
# Sets up (dependencies + build) and runs the main job: a 4-level QDO+A design and a DO design
# on synthetic scenes (small preset), evaluated on held-out synthetic and the CAVE scenes.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/build.sh
./build/qdo demo --preset "${QDO_PRESET:-small}" --out "${1:-out/demo}"
