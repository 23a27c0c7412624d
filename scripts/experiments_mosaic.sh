#!/usr/bin/env bash
# From a Bayer raw capture, does a demosaic stage (bilinear, Malvar-He-Cutler) then the
# decoder reconstruct better than a decoder that reads the mosaic directly? One design trained with
# the Wiener objective at the small preset (QDO+A, LEVELS levels, on synthetic scenes: the Wiener
# objective needs no network), then bench/net/mosaic_compare on the 3 CAVE test scenes: the run's
# Wiener decoder on no mosaic / bilinear / MHC / the zero-filled mosaic, and (NET_STEPS > 0)
# Res-UNets trained on the CAVE training scenes for NET_STEPS steps on each of NET_INPUTS
# (none, mhc, zeros: the network that reads the mosaic directly), the same noise seeds for all.
#
# Usage: scripts/experiments_mosaic.sh [OUT]   (parameters below, each overridable from the environment;
#        TABLE_ONLY=1 only rewrites OUT/table_scenes.md from an earlier run's OUT/cells.csv)
# Writes OUT/table.md, OUT/table.csv (per variant, intervals over the (scene, seed) cells), OUT/cells.csv
# (per scene and seed) and OUT/table_scenes.md: the seeds averaged per scene first, intervals over the
# scenes (the noise seeds move PSNR by ~0.01 dB, so the cells are not independent draws: the scenes are
# the sample), and each scene's difference against the same decoder on mhc.
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
  echo "[mosaic] $QDO design --recipe qdo --preset small --mode qdo+a --levels $LEVELS --epochs $EPOCHS --steps-per-epoch $STEPS_PER_EPOCH --seed 0"
  "$QDO" design --recipe qdo --preset small --mode qdo+a --levels "$LEVELS" --epochs "$EPOCHS" --steps-per-epoch "$STEPS_PER_EPOCH" --seed 0 \
    --out "$RUN" > "$OUT/design.log"
fi
if [ "${TABLE_ONLY:-0}" != 1 ]; then
echo "[mosaic] $COMPARE --run $RUN --seeds $SEEDS --net-steps $NET_STEPS ..."
"$COMPARE" --run "$RUN" --data "$TEST" --train-data "$TRAIN" --seeds "$SEEDS" --cfa "$CFA" --bit-depth "$BIT_DEPTH" \
  --black-level "$BLACK" --net-steps "$NET_STEPS" --net-batch "$NET_BATCH" --net-spec "$NET_SPEC" --net-lr "$NET_LR" \
  --net-inputs "$NET_INPUTS" --out "$OUT"
fi
python3 - "$OUT" <<'PY'
import collections, csv, math, os, sys
out = sys.argv[1]
cells = collections.defaultdict(lambda: collections.defaultdict(list))  # variant -> scene -> [psnr per seed]
order = []
for r in csv.DictReader(open(os.path.join(out, "cells.csv"))):
    if r["variant"] not in order: order.append(r["variant"])
    cells[r["variant"]][r["scene"]].append(float(r["psnr"]))
T975 = {1: 12.706, 2: 4.303, 3: 3.182, 4: 2.776, 5: 2.571}
def ci(v):
    n = len(v); m = sum(v) / n
    if n < 2: return m, float("nan")
    sd = math.sqrt(sum((x - m) ** 2 for x in v) / (n - 1))
    return m, T975.get(n - 1, 1.96) * sd / math.sqrt(n)
scenes = sorted(next(iter(cells.values())).keys())
lines = ["| decoder / input | PSNR dB, mean over scenes (95 %% CI, n = %d scenes) | " % len(scenes)
         + " | ".join(s.replace("_256", "") for s in scenes) + " | difference to same decoder on mhc, per scene (dB) |",
         "|---|---|" + "---|" * len(scenes) + "---|"]
for v in order:
    per = [sum(cells[v][s]) / len(cells[v][s]) for s in scenes]
    m, h = ci(per)
    base = v.split("/")[0] + "/mhc"
    diff = ""
    if base in cells and base != v:
        d = [p - sum(cells[base][s]) / len(cells[base][s]) for p, s in zip(per, scenes)]
        diff = ", ".join("%+.2f" % x for x in d) + " (mean %+.2f)" % (sum(d) / len(d))
    lines.append("| %s | %.2f (+-%.2f) | %s | %s |" % (v, m, h, " | ".join("%.2f" % p for p in per), diff))
open(os.path.join(out, "table_scenes.md"), "w").write("\n".join(lines) + "\n")
print("\n".join(lines))
PY
echo "[mosaic] finished in $(( $(date +%s) - start )) s: $OUT/table.md"
