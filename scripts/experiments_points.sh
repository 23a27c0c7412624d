#!/usr/bin/env bash
# What a design can do against object distance and field angle (EXPERIMENTS.md
# "Object distance and field angle"): a 4-level QDO+A design (Wiener decoder, radial) trained for a
# point at 1 m, and the same design trained over a depth range (on-axis object points at 0.5, 1, 2
# and 5 m), each evaluated by `qdo eval-points` from 0.3 m to infinity and from 0 degrees to its
# field edge. Writes OUT/table.md and OUT/table.csv.
#
# Usage: bash scripts/experiments_points.sh [OUT]   (QDO: the qdo binary, default build/qdo)
#   PRESET=paper|small  the optics (default paper: N = 1024, z = 50 mm, S = 512)
#   EPOCHS, STEPS       the schedule (default 10 x 10 = 100 steps: ~15-30 min per design on 2 CPU cores)
#   TRAIN_DATA          training scenes (default: synthetic at paper, whose S = 512 is larger than
#                       the 256 x 256 CAVE scenes qdo design would refuse; cave_train at small)
#   TEST_DATA           eval-points --data (default at paper: the 512 x 512 CAVE scene of cave_png;
#                       at small: cave)
#   RANGE_ONLY=1        only the depth-range design and its evaluation (step 2, then 3 for it)
#   SKIP_RANGE=1        leave the depth-range design out (steps 1 and 3 for the 1 m design)
#   RANGE               the depth-range design's object distances, metres (default 0.5,1,2,5)
#   DISTANCES, ANGLE_STEPS, FOV_TOLERANCE  passed to qdo eval-points
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/points}
QDO=${QDO:-build/qdo}
SHARED=${SHARED:-../shared}
PRESET=${PRESET:-paper}
SEED=${SEED:-0}
EPOCHS=${EPOCHS:-10}
STEPS=${STEPS:-10}
RANGE_ONLY=${RANGE_ONLY:-0}
SKIP_RANGE=${SKIP_RANGE:-0}
DISTANCES=${DISTANCES:-0.3,0.5,0.7,1,1.5,2,3,5,10,inf}
RANGE=${RANGE:-0.5,1,2,5}
export RANGE
ANGLE_STEPS=${ANGLE_STEPS:-8}
FOV_TOLERANCE=${FOV_TOLERANCE:-0.05}
if [ "$PRESET" = paper ]; then
  TRAIN_DATA=${TRAIN_DATA-}
  TEST_DATA=${TEST_DATA-$SHARED/data/hsi/cave_png/beads_ms}
else
  TRAIN_DATA=${TRAIN_DATA-$SHARED/data/hsi/cave_train}
  TEST_DATA=${TEST_DATA-$SHARED/data/hsi/cave}
fi
source scripts/experiments_out.sh  # (the scripts run from the repository root)
claim_out experiments_points "$OUT"
DATA_ARGS=()
[ -n "$TRAIN_DATA" ] && DATA_ARGS=(--data "$TRAIN_DATA")
TEST_ARGS=()
[ -n "$TEST_DATA" ] && TEST_ARGS=(--data "$TEST_DATA")

"$QDO" config --preset "$PRESET" > "$OUT/$PRESET.json"
# The depth-range configuration: the same system, on-axis object points at the RANGE distances.
python3 - "$OUT/$PRESET.json" "$OUT/range.json" "$RANGE" <<'PY'
import json, sys
c = json.load(open(sys.argv[1]))
c["object_points"] = [["inf" if d == "inf" else float(d), 0, 0] for d in sys.argv[3].split(",")]
json.dump(c, open(sys.argv[2], "w"), indent=2)
PY

design() {  # NAME CONFIG
  if [ -f "$OUT/$1/design.h5" ]; then echo "($OUT/$1 exists: kept)"; return 0; fi
  local t0=$SECONDS
  "$QDO" design --recipe qdo --config "$2" --mode qdo+a --levels 4 --epochs "$EPOCHS" --steps-per-epoch "$STEPS" --seed "$SEED" \
    "${DATA_ARGS[@]}" --out "$OUT/$1"
  echo "design $1: $((SECONDS - t0)) s wall" | tee "$OUT/$1.time"
}
evaluate() {  # NAME
  local t0=$SECONDS
  "$QDO" eval-points "$OUT/$1" --distances "$DISTANCES" --angle-steps "$ANGLE_STEPS" --fov-tolerance "$FOV_TOLERANCE" \
    "${TEST_ARGS[@]}" --out "$OUT/eval_$1"
  echo "eval-points $1: $((SECONDS - t0)) s wall" | tee "$OUT/eval_$1.time"
}

if [ "$RANGE_ONLY" != 1 ]; then
  log "1. 4-level QDO+A at the $PRESET preset, point at 1 m ($EPOCHS epochs x $STEPS steps)"
  design design_1m "$OUT/$PRESET.json"
  log "3a. eval-points: the 1 m design"
  evaluate design_1m
fi
if [ "$SKIP_RANGE" != 1 ]; then
  log "2. the same trained over a depth range (on-axis object points at $RANGE m)"
  design design_range "$OUT/range.json"
  log "3b. eval-points: the depth-range design"
  evaluate design_range
fi

log "table"
python3 - "$OUT" <<'PY'
import csv, json, os, sys
out = sys.argv[1]
runs = [(n, label) for n, label in [("design_1m", "trained at 1 m"), ("design_range", "trained over " + os.environ.get("RANGE", "0.5,1,2,5") + " m")]
        if os.path.exists(os.path.join(out, "eval_" + n, "points.json"))]
P = {n: json.load(open(os.path.join(out, "eval_" + n, "points.json"))) for n, _ in runs}
def f(v, d=2):
    return v if isinstance(v, str) else f"{v:.{d}f}"
md, rows = [], []
md.append("**Against object distance** (on axis; PSNR dB mean over the test scenes [min, max]; "
          "mismatch: the decoder for the nominal 1 m PSF; matched: refit to that distance's PSF)\n")
head = "| distance m | " + " | ".join(f"{l}: mismatch | {l}: matched" for _, l in runs) + " |"
md += [head, "|---:|" + "---:|---:|" * len(runs)]
dists = [d["distance_m"] for d in P[runs[0][0]]["distances"]] if runs else []
for i, dist in enumerate(dists):
    cells = []
    for n, l in runs:
        r = P[n]["distances"][i]
        for k in ("mismatch", "matched"):
            q = r[k]["psnr_db"]
            cells.append(f"{q['mean']:.2f} [{q['min']:.2f}, {q['max']:.2f}]")
            rows.append({"design": n, "sweep": "distance", "distance_m": dist, "angle_deg": 0, "decoder": k,
                         "psnr_db": q["mean"], "psnr_min_db": q["min"], "psnr_max_db": q["max"],
                         "ssim": r[k]["ssim"]["mean"], "sam_rad": r[k]["sam_rad"]["mean"], "model_error": ""})
    md.append(f"| {dist} | " + " | ".join(cells) + " |")
md.append("\n**Against field angle** (at the nominal distance, asm propagator; e: model error of the "
          "shift-invariant image; PSNR with the on-axis decoder)\n")
for n, l in runs:
    md += [f"{l}:\n", "| angle deg | model error e | PSNR dB [min, max] | energy lost |", "|---:|---:|---:|---:|"]
    for a in P[n]["angles"]:
        q = a["on_axis_decoder"]["psnr_db"]
        md.append(f"| {a['angle_deg']:.3f} | {a['model_error']:.4f} | {q['mean']:.2f} [{q['min']:.2f}, {q['max']:.2f}] | {a['energy_lost']:.3g} |")
        rows.append({"design": n, "sweep": "angle", "distance_m": P[n]["nominal_distance_m"], "angle_deg": a["angle_deg"],
                     "decoder": "on-axis", "psnr_db": q["mean"], "psnr_min_db": q["min"], "psnr_max_db": q["max"],
                     "ssim": a["on_axis_decoder"]["ssim"]["mean"], "sam_rad": a["on_axis_decoder"]["sam_rad"]["mean"],
                     "model_error": a["model_error"]})
    md.append("")
md += ["**Summary**\n", "| design | nominal PSNR dB | depth of field (mismatch within margin) | field edge deg (binds) | valid FOV half / full deg (limited by) |",
       "|---|---:|---|---|---|"]
for n, l in runs:
    d, fl = P[n]["depth_of_field"], P[n]["field"]
    near = ("<= " if d["near_open"] else "") + f(d["near_m"], 3)
    far = (">= " if d["far_open"] else "") + f(d["far_m"], 3)
    md.append(f"| {l} | {d['nominal_psnr_db']:.2f} | {near} .. {far} m ({d['margin_db']} dB) | {fl['field_edge_deg']:.3f} ({fl['field_edge_binds']}) | "
              f"{fl['fov_half_deg']:.3f} / {fl['fov_full_deg']:.3f} ({fl['fov_limited_by']}, e <= {fl['fov_tolerance']}) |")
open(os.path.join(out, "table.md"), "w").write("\n".join(md) + "\n")
with open(os.path.join(out, "table.csv"), "w", newline="") as fh:
    w = csv.DictWriter(fh, fieldnames=["design", "sweep", "distance_m", "angle_deg", "decoder", "psnr_db", "psnr_min_db",
                                       "psnr_max_db", "ssim", "sam_rad", "model_error"])
    w.writeheader()
    w.writerows(rows)
print("\n".join(md))
PY
echo "wrote $OUT/table.md, $OUT/table.csv"
