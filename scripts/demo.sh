#!/usr/bin/env bash
# Sets up (dependencies + build) and runs the main job: PSF stacks and simulated sensor images
# of the built-in ColorChecker scene through a diffractive lens, full precision and 4 levels.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/build.sh
./build/qdo demo --preset "${QDO_PRESET:-small}" --out "${1:-out/demo}"
