#!/usr/bin/env bash
# How far qdo's PSF model is from a finely sampled one (EXPERIMENTS.md "A second generator"): the
# Section 7 design with its relief moved by exactly one DOE pixel (4 um) and no other error, as qdo
# models it (qdo fabricate keeping the preset's window, --model-padding config; qdo psf in f64) and
# as scripts/asbuilt_generator.py makes it on grids 1, 2 and 4 times finer than the DOE's (4, 2 and
# 1 um), the sensor grid placed as qdo's (pixel S/2 centred on the axis: --grid-um -4,-4). Writes
# OUT/table.md: per band the relative L2 difference, the correlation and the peak ratio of each
# stack against the finest generator's (the reference: between 2 and 1 um it changes by about a per
# cent).
# Usage: bash scripts/experiments_generator_check.sh [OUT]   (QDO: the qdo binary, default build/qdo;
# DESIGN: a design.h5, default the Section 7 design trained into OUT/design; PY: a python with numpy,
# scipy and h5py, default /usr/bin/python3)
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/generator_check}
QDO=${QDO:-build/qdo}
SHARED=${SHARED:-../shared}
PY=${PY:-/usr/bin/python3}
NAME=experiments_generator_check
source scripts/experiments_fit_common.sh
rm -rf "$OUT/fab" "$OUT/qdo_psf" "$OUT"/gen_fine*
"$QDO" fabricate "$DESIGN" --config "$CAM" --seed 1 --etch-depth-error-nm 0 --overlay-um 0 --offset-um=4,0 \
  --sensor-distance-error-um 0 --model-padding config --out "$OUT/fab" > /dev/null
"$QDO" psf --config "$OUT/fab/config.json" --design "$OUT/fab/design.h5" --precision f64 --out "$OUT/qdo_psf" > /dev/null
for f in 1 2 4; do
  "$PY" scripts/asbuilt_generator.py --config "$CAM" --design "$DESIGN" --seed 1 --etch-error-nm 0 --offset-um=4,0 \
    --grid-um=-4,-4 --fine "$f" --sellmeier "$SHARED/data/spectral/sellmeier_coefficients.csv" --out "$OUT/gen_fine$f" 2> /dev/null
done
{
  echo "Against the generator on a 1 um grid (fine 4): the relative L2 difference, the correlation and the peak ratio per band"
  echo
  "$PY" scripts/compare_psf_stacks.py "$OUT/gen_fine4/psf.h5" "qdo psf (the DOE's 4 um grid)=$OUT/qdo_psf/psf.h5" \
    "generator, 4 um grid=$OUT/gen_fine1/psf.h5" "generator, 2 um grid=$OUT/gen_fine2/psf.h5"
} > "$OUT/table.md.tmp"
mv "$OUT/table.md.tmp" "$OUT/table.md"
cat "$OUT/table.md"
