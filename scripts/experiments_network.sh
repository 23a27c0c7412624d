#!/usr/bin/env bash
# The paper's comparison with the network decoder: a Res-UNet (resunet: depth 4,
# root 16) trained jointly with the optics at the small preset on the CAVE training scenes
# (../shared/data/hsi/cave_train and cave_png), evaluated on the 3 CAVE test scenes
# (../shared/data/hsi/cave, never trained on), for do, do-finetune, qdo and qdo+a at each level.
# DO is trained once in full precision; do-finetune trains its network on with the DOE quantized to
# L levels and frozen. Finished runs are skipped, interrupted ones resumed, so a rerun continues.
#
# Usage: scripts/experiments_network.sh [OUT]   (env: LEVELS="2 4 8", EPOCHS=8, STEPS_PER_EPOCH=50, DECAY,
#        FT_STEPS=100, SYNTH=0, QDO=./build/qdo). Writes OUT/table.md and OUT/table.csv.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/experiments_network}
QDO=${QDO:-./build/qdo}
LEVELS=${LEVELS:-"2 4 8"}
EPOCHS=${EPOCHS:-8}
# The release decays both learning rates by 0.8 every 500 steps (REFERENCE §3); per epoch of SPE steps that is 0.8^(SPE/500).
DECAY=${DECAY:-$(python3 -c "print(round(0.8 ** (${STEPS_PER_EPOCH:-50} / 500), 6))")}
SPE=${STEPS_PER_EPOCH:-50}
FT=${FT_STEPS:-100}
TRAIN=../shared/data/hsi/cave_train,../shared/data/hsi/cave_png
# SYNTH=N adds N synthetic training scenes (to measure whether they help)
if [ "${SYNTH:-0}" != 0 ]; then TRAIN="$TRAIN,synthetic:$SYNTH"; fi
TEST=../shared/data/hsi/cave
COMMON=(--preset small --decoder resunet --data "$TRAIN" --epochs "$EPOCHS" --steps-per-epoch "$SPE" --decay "$DECAY" --seed 0)
mkdir -p "$OUT"
start=$(date +%s)

design() {  # design NAME ARGS...: skip a finished run, resume an interrupted one
  local name=$1; shift
  if [ -f "$OUT/$name/design.h5" ]; then echo "[$name] finished, skipped"; return; fi
  if [ -f "$OUT/$name/checkpoint.h5" ]; then "$QDO" design --resume --out "$OUT/$name"; return; fi
  echo "[$name] $QDO design $*"
  "$QDO" design --recipe qdo "$@" --out "$OUT/$name"  # the recipe its EXPERIMENTS tables ran with
}
evaluate() {  # evaluate CELL RUN ARGS...
  local cell=$1 run=$2; shift 2
  if [ -f "$OUT/eval/$cell/metrics.json" ]; then return; fi
  "$QDO" eval "$OUT/$run" --data "$TEST" --renders 2 "$@" --out "$OUT/eval/$cell" > /dev/null
}

design do "${COMMON[@]}" --mode do
evaluate do_full do --decoder mismatch --levels 65536  # 65536 levels: the full-precision design to 0.02 nm
for L in $LEVELS; do
  design "qdo_L$L" "${COMMON[@]}" --mode qdo --levels "$L"
  design "qdoa_L$L" "${COMMON[@]}" --mode qdo+a --levels "$L"
  design "doft_L$L" --mode do-finetune --from "$OUT/do" --levels "$L" --finetune-steps "$FT"
  evaluate "do_L$L" do --decoder mismatch --levels "$L"
  evaluate "doft_L$L" "doft_L$L" --decoder matched
  evaluate "qdo_L$L" "qdo_L$L" --decoder matched
  evaluate "qdoa_L$L" "qdoa_L$L" --decoder matched
done
python3 - "$OUT" "$LEVELS" "$(( $(date +%s) - start ))" <<'PY'
import json, os, sys
out, levels, secs = sys.argv[1], sys.argv[2].split(), int(sys.argv[3])
def cell(name):
    p = os.path.join(out, "eval", name, "metrics.json")
    if not os.path.exists(p): return None
    m = json.load(open(p))
    return m["mean"], m["deviation_nm"]
def fmt(c):
    if c is None: return ""
    m, _ = c
    return "%.2f / %.3f / %.4f / %.1f" % (m["psnr_db"], m["ssim"], m["rmse"], m["ergas"])
rows = ["| levels | DO (paper's: network for H_f) | DO-finetune | QDO | QDO+A |", "|---|---|---|---|---|"]
csv = ["levels,mode,psnr_db,ssim,rmse,ergas,deviation_nm"]
full = cell("do_full")
rows.append("| full | %s | | | |" % fmt(full))
for L in sorted(levels, key=int, reverse=True):
    cs = [cell("%s_L%s" % (k, L)) for k in ("do", "doft", "qdo", "qdoa")]
    rows.append("| %s | %s |" % (L, " | ".join(fmt(c) for c in cs)))
    for k, c in zip(("do", "do-finetune", "qdo", "qdo+a"), cs):
        if c: csv.append("%s,%s,%.4f,%.4f,%.5f,%.3f,%.3f" % (L, k, c[0]["psnr_db"], c[0]["ssim"], c[0]["rmse"], c[0]["ergas"], c[1]))
open(os.path.join(out, "table.md"), "w").write("\n".join(rows) + "\n\nPSNR dB / SSIM / RMSE / ERGAS on the 3 CAVE test scenes; %d s for this invocation.\n" % secs)
open(os.path.join(out, "table.csv"), "w").write("\n".join(csv) + "\n")
print("\n".join(rows))
PY
