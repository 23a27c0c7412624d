#!/usr/bin/env bash
# Where qdo fit's start decides the basin (EXPERIMENTS.md "The built camera, in simulation": the
# fit's starts). The Section 7 design (a 4-level QDO+A DOE, small preset, seed 0: its speckled PSF
# has several minima in the relief's lateral offset) is "fabricated" seven times with different
# etch depth errors, relief offsets and DOE-sensor distance errors (qdo fabricate; no overlay, so
# that every error is inside qdo fit's model), each camera's true PSF stack is simulated without
# noise (qdo psf), and qdo fit (levels, z, offset) runs on it with the default starts
# (--lateral-starts auto) and from the centroid alone (--lateral-starts 1). Writes OUT/table.md:
# fitted - true per parameter, the loss at the end and the command's wall time.
# Usage: bash scripts/experiments_fit_starts.sh [OUT]   (QDO: the qdo binary, default build/qdo;
# DESIGN: a design.h5 to use instead of training the Section 7 design into OUT/design)
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/fit_starts}
QDO=${QDO:-build/qdo}
SHARED=${SHARED:-../shared}
MODES=${MODES:-"auto 1"}
NAME=experiments_fit_starts
source scripts/experiments_fit_common.sh
# Each case: the relief offset (um), the fabrication seed, the DOE-sensor distance error (um).
CASES=("1.5,-1.0 3 150" "-2.5,0.7 1 -80" "0.6,2.2 2 60" "3.1,-2.9 4 200" "-0.4,-3.6 5 -150" "5.0,1.0 6 100" "-1.1,-0.3 7 0")
ROWS=$OUT/rows.tsv
: > "$ROWS"
i=0
for case in "${CASES[@]}"; do
  read -r off seed dz <<< "$case"
  i=$((i + 1))
  c=$OUT/case$i
  rm -rf "$c"
  mkdir -p "$c"
  "$QDO" fabricate "$DESIGN" --config "$CAM" --seed "$seed" --etch-depth-error-nm 20 --overlay-um 0 --offset-um="$off" \
    --sensor-distance-error-um "$dz" --out "$c/asbuilt" > /dev/null
  "$QDO" psf --config "$c/asbuilt/config.json" --design "$c/asbuilt/design.h5" --out "$c/true_psf" > /dev/null
  for mode in $MODES; do
    t0=$(date +%s.%N)
    "$QDO" fit --config "$CAM" --design "$DESIGN" --psf "$c/true_psf/psf.h5" --lateral-starts "$mode" --out "$c/fit_$mode" > "$c/fit_$mode.log" 2>&1 || true
    t1=$(date +%s.%N)
    printf '%s\t%s\t%s\t%s\t%s\t%s\t%s\n' "$i" "$off" "$seed" "$dz" "$mode" "$(python3 -c "print(f'{$t1 - $t0:.1f}')")" "$c" >> "$ROWS"
    echo "case $i (offset $off um, seed $seed, dz $dz um), --lateral-starts $mode: done"
  done
done
python3 - "$ROWS" "$OUT/table.md" <<'PY'
import json, os, sys
rows, out = sys.argv[1], sys.argv[2]
lines = ["| case | offset (um) | z error (um) | --lateral-starts | level1 | level2 | level3 (nm) | z (um) | dx | dy (um) | loss: end / design | wall (s) |",
         "|---|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
for r in open(rows):
    i, off, seed, dz, mode, wall, c = r.rstrip("\n").split("\t")
    truth = json.load(open(os.path.join(c, "asbuilt", "truth.json")))["fit_parameters"]
    fj = os.path.join(c, "fit_" + mode, "fit.json")
    if not os.path.exists(fj):
        lines.append(f"| {i} | {off} | {dz} | {mode} | (no fit: see {c}/fit_{mode}.log) | | | | | | | {wall} |")
        continue
    f = json.load(open(fj))
    v = {p["name"]: p["value"] for p in f["parameters"]}
    d = lambda k, s: f"{(v[k] - truth[k]) * s:+.3g}"
    lines.append(f"| {i} | {off} | {dz} | {mode} | {d('level1', 1e9)} | {d('level2', 1e9)} | {d('level3', 1e9)} | {d('z', 1e6)} | "
                 f"{d('dx', 1e6)} | {d('dy', 1e6)} | {f['loss_final'] / f['loss_design']:.1e} | {wall} |")
open(out + ".tmp", "w").write("fitted - true (qdo fit on the noise-free true stack of each camera as built)\n\n" + "\n".join(lines) + "\n")
os.replace(out + ".tmp", out)
print("\n".join(lines))
PY
