#!/usr/bin/env bash
# A design trained at 1 m against one trained over a near depth range, over seeds (EXPERIMENTS.md
# "Object distance and field angle"): scripts/experiments_points.sh at the small preset (CAVE
# training and test scenes) once per seed, then scripts/points_seeds_table.py over the seeds.
# Usage: bash scripts/experiments_points_seeds.sh [OUT_PREFIX]   (default out/points_near; writes
#        OUT_PREFIX_s<seed>/ per seed and OUT_PREFIX_seeds.md)
#   SEEDS (default "0 1 2"), RANGE (default 0.1,0.2,0.5,1), DISTANCES, EPOCHS (20), STEPS (8)
set -euo pipefail
cd "$(dirname "$0")/.."
PREFIX=${1:-out/points_near}
SEEDS=${SEEDS:-"0 1 2"}
export PRESET=small EPOCHS=${EPOCHS:-20} STEPS=${STEPS:-8}
export RANGE=${RANGE:-0.1,0.2,0.5,1}
export DISTANCES=${DISTANCES:-0.1,0.15,0.2,0.3,0.5,0.7,1,2,5,inf}
dirs=()
for s in $SEEDS; do
  echo "== seed $s"
  SEED=$s bash scripts/experiments_points.sh "${PREFIX}_s$s"
  dirs+=("${PREFIX}_s$s")
done
python3 scripts/points_seeds_table.py "${dirs[@]}" > "${PREFIX}_seeds.md"
cat "${PREFIX}_seeds.md"
