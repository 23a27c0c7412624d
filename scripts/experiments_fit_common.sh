# Sourced by the fit experiments (experiments_fit_starts.sh, experiments_fit_sigma.sh): their OUT
# folder and the design they fabricate. Needs NAME (the script's name), OUT, QDO and SHARED; sets
# CAM (the small preset's configuration) and DESIGN (a given DESIGN, else the Section 7 design,
# 4-level QDO+A, small preset, seed 0, trained into OUT/design once).
export QDO_DEVICE=${QDO_DEVICE:-cpu}
export QDO_CACHE_DIR=${QDO_CACHE_DIR:-$PWD/build/kernel-cache}
# The script deletes and rewrites only the folders it makes under OUT; an OUT it did not make (no
# marker) is refused, so a user's folder is never touched.
if [ -e "$OUT" ] && [ ! -f "$OUT/.$NAME" ]; then
  echo "$NAME: $OUT exists and was not made by this script (no $OUT/.$NAME); choose another OUT" >&2
  exit 2
fi
mkdir -p "$OUT"
touch "$OUT/.$NAME"
CAM=$OUT/camera.json
"$QDO" config --preset small > "$CAM"
DESIGN=${DESIGN:-$OUT/design/design.h5}
if [ ! -f "$DESIGN" ]; then
  "$QDO" design --recipe qdo --config "$CAM" --mode qdo+a --levels 4 --epochs 15 --steps-per-epoch 8 --seed 0 \
    --data "$SHARED/data/hsi/cave_train" --out "$OUT/design" > "$OUT/design.log" 2>&1
fi
