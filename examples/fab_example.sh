#!/usr/bin/env bash
# From design to fab, worked example (docs/fab.md):
#   1. a 4-level QDO+M design (levels = subset sums of 2 trainable etch depths) at the small preset;
#   2. its binary-coded mask set: GDSII (2 mask layers), manifest (JSON + Markdown), PNG previews,
#      checked by reading the GDSII back; for comparison the nested (3-mask) set of the same design;
#   3. a Monte Carlo tolerance report over etch-depth errors (±20 nm), overlay (±0.5 µm), edge blur
#      and height noise;
#   4. when KLayout is installed (apt-get install klayout), KLayout reads the GDSII independently.
# 2 to 5 minutes on 2 CPU cores. Usage: bash examples/fab_example.sh [OUT]   (default out/fab_example)
# QDO=path/to/qdo overrides the binary (default: ./build/qdo, built by scripts/build.sh if missing).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT="${1:-out/fab_example}"
QDO="${QDO:-./build/qdo}"
[ -x "$QDO" ] || bash scripts/build.sh
mkdir -p "$OUT"

echo "== 1. design: QDO+M, 4 levels from 2 binary masks (small preset)"
rm -rf "$OUT/design"
"$QDO" design --preset small --mode qdo+m --levels 4 --epochs 10 --steps-per-epoch 6 --seed 0 --out "$OUT/design"
"$QDO" eval "$OUT/design" --renders 1 --out "$OUT/design/eval" | tail -n 2

echo "== 2. masks: binary-coded (2 masks) and, for comparison, nested (3 masks)"
"$QDO" export "$OUT/design" --scheme binary --out "$OUT/masks_binary"
"$QDO" export "$OUT/design" --scheme nested --out "$OUT/masks_nested" | head -n 1

echo "== 3. tolerance: ±20 nm etch depth, ±0.5 um overlay, 0.25 um edge blur, ±10 nm height noise"
"$QDO" tolerance "$OUT/design" --etch-depth-error-nm 20 --overlay-um 0.5 --edge-blur-um 0.25 --height-noise-nm 10 \
  --trials 6 --seed 1 --out "$OUT/tolerance" 2> "$OUT/tolerance.log"

if command -v klayout > /dev/null 2>&1; then
  echo "== 4. KLayout reads masks.gds (layer: shapes, area in mm^2)"
  cat > "$OUT/klayout_probe.py" << 'PY'
import pya
ly = pya.Layout()
ly.read(gds)
top = ly.top_cell()
for li in ly.layer_indexes():
    reg = pya.Region(top.begin_shapes_rec(li))
    print("layer %3d: %6d shapes, area %.6f mm^2, self-overlapping polygons %d" % (
        ly.get_info(li).layer, top.shapes(li).size(), reg.area() * ly.dbu ** 2 * 1e-6, reg.strange_polygon_check().count()))
PY
  klayout -b -rd gds="$OUT/masks_binary/masks.gds" -r "$OUT/klayout_probe.py"
else
  echo "== 4. (klayout not installed: skipped)"
fi
echo "outputs in $OUT: design/, masks_binary/ (masks.gds manifest.json manifest.md mask_L*.png heights_from_masks.png),"
echo "masks_nested/, tolerance/ (tolerance.md tolerance.csv tolerance.json psnr_by_scenario.png worst_*.png)"
