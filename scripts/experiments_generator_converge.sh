#!/usr/bin/env bash
# Does qdo's PSF converge to the second generator's when it is sampled as finely (EXPERIMENTS.md
# "A second generator")? Takes the folder scripts/experiments_generator_check.sh wrote (its fabricated
# relief fab/ and the generator's gen_fine2/ and gen_fine4/) and makes qdo's PSF of the same relief
#   - as that script does (the preset's padding, the DOE's 4 um grid),
#   - on the DOE's 4 um grid with a window wide enough for the transfer function (K = 1),
#   - on a grid 3 times finer (4/3 um) with such a window, every 5th band (the field of all 31
#     bands at that size does not fit this machine's largest device allocation),
# both made by scripts/supersample_design.py, then compares every stack with the 1 um generator on
# the bands they share (400, 450, ..., 700 nm). Writes OUT/converge.md.
# Usage: bash scripts/experiments_generator_converge.sh OUT   (OUT: experiments_generator_check.sh's;
#        QDO: the qdo binary, default build/qdo; PY: a python with numpy and h5py, default /usr/bin/python3)
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:?usage: scripts/experiments_generator_converge.sh OUT (the folder of experiments_generator_check.sh)}
QDO=${QDO:-build/qdo}
PY=${PY:-/usr/bin/python3}
for f in fab/config.json fab/design.h5 gen_fine2/psf.h5 gen_fine4/psf.h5; do
  [ -f "$OUT/$f" ] || { echo "experiments_generator_converge.sh: $OUT/$f missing: run scripts/experiments_generator_check.sh $OUT first" >&2; exit 2; }
done
[ -f "$OUT/.experiments_generator_check" ] ||
  { echo "experiments_generator_converge.sh: $OUT was not made by scripts/experiments_generator_check.sh (no $OUT/.experiments_generator_check)" >&2; exit 2; }
# OUT/converge is this script's own folder (claim_out refuses one it did not make); it rewrites only
# what it makes there.
source scripts/experiments_out.sh
W="$OUT/converge"
claim_out experiments_generator_converge "$W"
rm -rf "$W/k0" "$W/k1" "$W/k3" "$W"/*_b7.h5 "$W/k0.log" "$W/k1.txt" "$W/k3.txt"
"$PY" scripts/supersample_design.py --config "$OUT/fab/config.json" --design "$OUT/fab/design.h5" --k 1 \
  --out-config "$W/k1/config.json" --out-design "$W/k1/design.h5" > "$W/k1.txt"
"$PY" scripts/supersample_design.py --config "$OUT/fab/config.json" --design "$OUT/fab/design.h5" --k 3 --band-step 5 \
  --out-config "$W/k3/config.json" --out-design "$W/k3/design.h5" > "$W/k3.txt"
"$QDO" psf --config "$OUT/fab/config.json" --design "$OUT/fab/design.h5" --precision f64 --out "$W/k0/psf" > "$W/k0.log" 2>&1
"$QDO" psf --config "$W/k1/config.json" --design "$W/k1/design.h5" --precision f64 --out "$W/k1/psf" > "$W/k1/psf.log" 2>&1
"$QDO" psf --config "$W/k3/config.json" --design "$W/k3/design.h5" --precision f32 --out "$W/k3/psf" > "$W/k3/psf.log" 2>&1
# Every 5th band of the 31-band stacks (400, 450, ..., 700 nm), as the K = 3 stack has them.
"$PY" - "$OUT" "$W" <<'EOF'
import sys, h5py
out, w = sys.argv[1], sys.argv[2]
for src, dst in [("gen_fine4/psf.h5", "gen_fine4_b7.h5"), ("gen_fine2/psf.h5", "gen_fine2_b7.h5"),
                 ("converge/k0/psf/psf.h5", "k0_b7.h5"), ("converge/k1/psf/psf.h5", "k1_b7.h5")]:
    with h5py.File(f"{out}/{src}", "r") as f:
        p, wl = f["psf_sensor"][()], f["wavelengths_nm"][()]
    with h5py.File(f"{w}/{dst}", "w") as f:
        f["psf_sensor"], f["wavelengths_nm"] = p[::5], wl[::5]
EOF
{
  echo "Against the generator on a 1 um grid: the relative L2 difference, the correlation and the peak ratio per band"
  echo
  echo "- qdo, 4 um grid, the preset's padding: $(grep -o 'transfer function under-sampled in [0-9]* of [0-9]* bands' "$W/k0.log")"
  echo "- qdo, 4 um grid, wide window: $(cat "$W/k1.txt"); $(grep -o 'transfer function under-sampled in [0-9]* of [0-9]* bands' "$W/k1/psf.log")"
  echo "- qdo, 4/3 um grid, wide window: $(cat "$W/k3.txt"); $(grep -o 'transfer function under-sampled in [0-9]* of [0-9]* bands' "$W/k3/psf.log")"
  echo
  "$PY" scripts/compare_psf_stacks.py --step 1 "$W/gen_fine4_b7.h5" "qdo, 4 um grid, the preset's padding=$W/k0_b7.h5" \
    "qdo, 4 um grid, wide window=$W/k1_b7.h5" "qdo, 4/3 um grid, wide window (f32)=$W/k3/psf/psf.h5" \
    "generator, 2 um grid=$W/gen_fine2_b7.h5"
} > "$OUT/converge.md.tmp"
mv "$OUT/converge.md.tmp" "$OUT/converge.md"
cat "$OUT/converge.md"
