#!/usr/bin/env bash
# Issue 28: from a Bayer raw capture, does a demosaic stage (bilinear, Malvar-He-Cutler) then the
# decoder reconstruct better than a decoder that reads the mosaic directly? One design trained with
# the Wiener objective at the small preset (QDO+A, LEVELS levels, on synthetic scenes: the Wiener
# objective needs no network), then bench/net/mosaic_compare on the 3 CAVE test scenes: the run's
# Wiener decoder on no mosaic / bilinear / MHC / the zero-filled mosaic, and (NET_STEPS > 0)
# Res-UNets trained on the CAVE training scenes for NET_STEPS steps on each of NET_INPUTS
# (none, mhc, zeros: the network that reads the mosaic directly), the same noise seeds for all.
#
# Usage: scripts/experiments_mosaic.sh [OUT]   (parameters below, each overridable from the environment)
# Writes OUT/table.md, OUT/table.csv (per variant) and OUT/cells.csv (per scene and seed).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/experiments_mosaic}
QDO=${QDO:-./build/qdo}
COMPARE=${COMPARE:-./build/mosaic_compare}
LEVELS=${LEVELS:-4}                 # height levels of the design
EPOCHS=${EPOCHS:-20}                # design epochs (x STEPS_PER_EPOCH optimiser steps), as EXPERIMENTS.md
STEPS_PER_EPOCH=${STEPS_PER_EPOCH:-8}
SEEDS=${SEEDS:-0,1,2}               # raw-noise seeds of the test captures
CFA=${CFA:-rggb}
BIT_DEPTH=${BIT_DEPTH:-12}
BLACK=${BLACK:-64}                  # black level, DN
NET_STEPS=${NET_STEPS:-300}         # Res-UNet training steps per input kind (0: Wiener only)
NET_BATCH=${NET_BATCH:-2}
NET_SPEC=${NET_SPEC:-resunet:depth=3,root=8}
NET_LR=${NET_LR:-1e-3}
NET_INPUTS=${NET_INPUTS:-none,mhc,zeros}
TEST=${TEST:-../shared/data/hsi/cave}
TRAIN=${TRAIN:-../shared/data/hsi/cave_train}
mkdir -p "$OUT"
start=$(date +%s)
RUN="$OUT/design_qdoa_L$LEVELS"
if [ ! -f "$RUN/design.h5" ]; then
  echo "[mosaic] $QDO design --preset small --mode qdo+a --levels $LEVELS --epochs $EPOCHS --steps-per-epoch $STEPS_PER_EPOCH --seed 0"
  "$QDO" design --preset small --mode qdo+a --levels "$LEVELS" --epochs "$EPOCHS" --steps-per-epoch "$STEPS_PER_EPOCH" --seed 0 \
    --out "$RUN" > "$OUT/design.log"
fi
echo "[mosaic] $COMPARE --run $RUN --seeds $SEEDS --net-steps $NET_STEPS ..."
"$COMPARE" --run "$RUN" --data "$TEST" --train-data "$TRAIN" --seeds "$SEEDS" --cfa "$CFA" --bit-depth "$BIT_DEPTH" \
  --black-level "$BLACK" --net-steps "$NET_STEPS" --net-batch "$NET_BATCH" --net-spec "$NET_SPEC" --net-lr "$NET_LR" \
  --net-inputs "$NET_INPUTS" --out "$OUT"
echo "[mosaic] finished in $(( $(date +%s) - start )) s: $OUT/table.md"
