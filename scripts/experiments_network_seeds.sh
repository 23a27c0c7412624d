#!/usr/bin/env bash
# The network comparison of EXPERIMENTS.md ("With the network decoder") with seeds as a grid axis:
# `qdo sweep` of do, do-finetune, qdo and qdo+a at 4 and 8 levels with the
# Res-UNet decoder (depth 4, root 16), SEEDS seeds, trained on the CAVE training scenes and
# evaluated on the 3 CAVE test crops; table1 gives mean ± sd over seeds, comparisons.md the paper's
# comparisons as differences paired by seed and test scene with 95 % intervals.
# The sweep resumes: rerun the same command after an interruption.
#
# Usage: scripts/experiments_network_seeds.sh [OUT]   (env: SEEDS="0,1,2", LEVELS="4,8", EPOCHS=8,
#        STEPS_PER_EPOCH=50, FT_STEPS=100, QDO=./build/qdo, LAUNCH="" e.g. "mpirun -np 2")
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/experiments_network_seeds}
QDO=${QDO:-./build/qdo}
SEEDS=${SEEDS:-0,1,2}
LEVELS=${LEVELS:-4,8}
EPOCHS=${EPOCHS:-8}
SPE=${STEPS_PER_EPOCH:-50}
FT=${FT_STEPS:-100}
# The release decays both learning rates by 0.8 every 500 steps (REFERENCE §3); per epoch of SPE steps that is 0.8^(SPE/500).
DECAY=${DECAY:-$(python3 -c "print(round(0.8 ** ($SPE / 500), 6))")}
TRAIN=../shared/data/hsi/cave_train,../shared/data/hsi/cave_png
TEST=../shared/data/hsi/cave
start=$(date +%s)
${LAUNCH:-} "$QDO" sweep --recipe qdo --preset small --grid decoder=resunet --data "$TRAIN" --test-data "$TEST" \
  --grid levels="$LEVELS" --grid mode=do,do-finetune,qdo,qdo+a --grid seed="$SEEDS" \
  --epochs "$EPOCHS" --steps-per-epoch "$SPE" --decay "$DECAY" --finetune-steps "$FT" --out "$OUT" --into-existing
echo "experiments_network_seeds: $(( $(date +%s) - start )) s for this invocation; tables in $OUT/table1.md and $OUT/comparisons.md"
