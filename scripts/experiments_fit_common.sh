# Sourced by the fit experiments (experiments_fit_starts.sh, experiments_fit_sigma.sh): their OUT
# folder and the design they fabricate. Needs NAME (the script's name), OUT, QDO and SHARED; sets
# CAM (the small preset's configuration) and DESIGN (a given DESIGN, else the Section 7 design,
# 4-level QDO+A, small preset, seed 0, trained into OUT/design once); defines model_padding_of.
source scripts/experiments_out.sh  # (the scripts run from the repository root)
claim_out "$NAME" "$OUT"
CAM=$OUT/camera.json
"$QDO" config --preset small > "$CAM"
DESIGN=${DESIGN:-$OUT/design/design.h5}
if [ ! -f "$DESIGN" ]; then
  "$QDO" design --recipe qdo --config "$CAM" --mode qdo+a --levels 4 --epochs 15 --steps-per-epoch 8 --seed 0 \
    --data "$SHARED/data/hsi/cave_train" --out "$OUT/design" > "$OUT/design.log" 2>&1
fi

# model_padding_of CONFIG: the padding_px of a camera's as-built config.json, for qdo fit
# --model-padding: a camera qdo simulated is fitted with the window it was made with (qdo fabricate
# writes the sampled window since --model-padding existed, the design's before).
model_padding_of() {
  "${PY:-/usr/bin/python3}" -c 'import json, sys; c = json.load(open(sys.argv[1])); print(c.get("system", c)["padding_px"])' "$1"
}
