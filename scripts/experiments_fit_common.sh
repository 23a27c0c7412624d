# Sourced by the fit experiments (experiments_fit_starts.sh, experiments_fit_sigma.sh): their OUT
# folder and the design they fabricate. Needs NAME (the script's name), OUT, QDO and SHARED; sets
# CAM (the small preset's configuration) and DESIGN (a given DESIGN, else the Section 7 design,
# 4-level QDO+A, small preset, seed 0, trained into OUT/design once).
source scripts/experiments_out.sh  # (the scripts run from the repository root)
claim_out "$NAME" "$OUT"
CAM=$OUT/camera.json
"$QDO" config --preset small > "$CAM"
DESIGN=${DESIGN:-$OUT/design/design.h5}
if [ ! -f "$DESIGN" ]; then
  "$QDO" design --recipe qdo --config "$CAM" --mode qdo+a --levels 4 --epochs 15 --steps-per-epoch 8 --seed 0 \
    --data "$SHARED/data/hsi/cave_train" --out "$OUT/design" > "$OUT/design.log" 2>&1
fi

