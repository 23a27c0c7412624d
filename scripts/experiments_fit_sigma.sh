#!/usr/bin/env bash
# Does qdo fit's sigma cover its error when the camera has errors its model does not have?
# (EXPERIMENTS.md "The built camera, in simulation": honest sigma.) The Section 7 design (4-level
# QDO+A, small preset, seed 0) is "fabricated" ten times (qdo fabricate, seeds 11..20): etch depth
# errors within +-20 nm, the relief offset and DOE-sensor distance error of each draw (inside the
# fit's model) and each mask's own overlay shift within +-0.5 um per axis (outside it: the fit can
# only absorb it); each camera's true PSF stack is simulated without noise (qdo psf) and fitted with
# the defaults (levels, z, offset). Writes OUT/table.md: per parameter, |fitted - true| against the
# curvature sigma and the jackknife sigma over band groups, and the share within 3 of each.
# Usage: bash scripts/experiments_fit_sigma.sh [OUT]   (QDO: the qdo binary, default build/qdo;
# DESIGN: a design.h5 to use instead of training the Section 7 design into OUT/design)
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/fit_sigma}
QDO=${QDO:-build/qdo}
SHARED=${SHARED:-../shared}
OVERLAY_UM=${OVERLAY_UM:-0.5}
NAME=experiments_fit_sigma
source scripts/experiments_fit_common.sh
# Each draw: the fabrication seed, the relief offset (um), the DOE-sensor distance error (um).
DRAWS=("11 1.5,-1.0 150" "12 -2.0,0.5 -100" "13 0.7,2.4 60" "14 2.8,-1.9 180" "15 -0.6,-3.1 -140"
       "16 4.2,1.1 90" "17 -1.3,-0.4 0" "18 0.2,-0.9 -60" "19 -3.5,2.0 120" "20 1.0,1.0 -200")
for draw in "${DRAWS[@]}"; do
  read -r seed off dz <<< "$draw"
  c=$OUT/draw$seed
  rm -rf "$c"
  mkdir -p "$c"
  "$QDO" fabricate "$DESIGN" --config "$CAM" --seed "$seed" --etch-depth-error-nm 20 --overlay-um "$OVERLAY_UM" --offset-um="$off" \
    --sensor-distance-error-um "$dz" --out "$c/asbuilt" > /dev/null
  "$QDO" psf --config "$c/asbuilt/config.json" --design "$c/asbuilt/design.h5" --out "$c/true_psf" > /dev/null
  "$QDO" fit --config "$CAM" --design "$DESIGN" --psf "$c/true_psf/psf.h5" --out "$c/fit" > "$c/fit.log" 2>&1 || true
  echo "draw $seed (offset $off um, dz $dz um, overlay within $OVERLAY_UM um): done"
done
python3 - "$OUT" <<'PY'
import glob, json, os, sys
out = sys.argv[1]
scale = {"level1": 1e9, "level2": 1e9, "level3": 1e9, "z": 1e6, "dx": 1e6, "dy": 1e6}
unit = {"level1": "nm", "level2": "nm", "level3": "nm", "z": "um", "dx": "um", "dy": "um"}
rows, within, within_jk, total, flagged, fits = [], 0, 0, 0, 0, 0
for d in sorted(glob.glob(os.path.join(out, "draw*"))):
    truth = json.load(open(os.path.join(d, "asbuilt", "truth.json")))["fit_parameters"]
    fj = os.path.join(d, "fit", "fit.json")
    if not os.path.exists(fj):
        rows.append(f"| {os.path.basename(d)} | (no fit: see {d}/fit.log) | | | | |")
        continue
    f = json.load(open(fj))
    fits += 1
    flagged += f.get("sigma_reliable") is False
    for p in f["parameters"]:
        n = p["name"]
        if n not in truth:
            continue
        err = abs(p["value"] - truth[n]) * scale[n]
        sg = p["sigma"] * scale[n]
        sj = (p.get("sigma_jackknife") or float("nan")) * scale[n]
        total += 1
        within += err <= 3 * sg
        within_jk += err <= 3 * sj
        rows.append(f"| {os.path.basename(d)} | {n} ({unit[n]}) | {err:.3g} | {sg:.3g} | {sj:.3g} | {err / sg if sg > 0 else float('inf'):.1f} | {err / sj if sj > 0 else float('inf'):.1f} |")
head = ["| draw | parameter | abs(fitted - true) | sigma (curvature) | sigma (jackknife) | error / sigma | error / jackknife sigma |",
        "|---|---|---:|---:|---:|---:|---:|"]
summary = (f"within 3 sigma: curvature {within} of {total} ({100 * within / max(total, 1):.0f} %), "
           f"jackknife {within_jk} of {total} ({100 * within_jk / max(total, 1):.0f} %); "
           f"fits that said sigma_reliable false: {flagged} of {fits}")
text = "qdo fit on the noise-free true stacks of cameras with per-mask overlay (outside the model)\n\n" + "\n".join(head + rows) + "\n\n" + summary + "\n"
open(os.path.join(out, "table.md.tmp"), "w").write(text)
os.replace(os.path.join(out, "table.md.tmp"), os.path.join(out, "table.md"))
print(text)
PY
