#!/usr/bin/env bash
# The paper's Section 7 (the built camera) in simulation, end to end (EXPERIMENTS.md "The built
# camera, in simulation"): a 4-level QDO+A design (small preset, Wiener decoder, CAVE training
# scenes) is "fabricated" with errors of the tolerance study's size plus an assembly error
# (qdo fabricate), a monochromator sweep and the CAVE test scenes are captured through that camera
# as raw 12-bit RGGB frames with black level, read and shot noise (qdo simulate --capture psf-sweep,
# qdo simulate --raw), then calibrate -> fit -> adapt -> reconstruct, each reconstruction scored
# against the scene (qdo reconstruct --truth). Writes OUT/table.md and OUT/table.csv.
# Usage: bash scripts/experiments_section7.sh [OUT]   (QDO: the qdo binary, default build/qdo)
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/section7}
QDO=${QDO:-build/qdo}
SHARED=${SHARED:-../shared}
SEED=${SEED:-0}            # design seed
FAB_SEED=${FAB_SEED:-3}    # the fabrication draw (qdo tolerance's seed, trial 0)
EPOCHS=${EPOCHS:-15}
STEPS=${STEPS:-8}
ETCH_NM=${ETCH_NM:-20}     # per-mask etch depth error bound (REFERENCE §6)
OVERLAY_UM=${OVERLAY_UM:-0.5}
OFFSET_UM=${OFFSET_UM:-1.5,-1.0}      # relief against the aperture (assembly of the aperture stop)
DZ_UM=${DZ_UM:-150}                   # DOE-sensor distance error (1.2 % of z = 12.5 mm)
BORDER=${BORDER:-16}                  # pixels left out of each score at every edge
export QDO_DEVICE=${QDO_DEVICE:-cpu}
export QDO_CACHE_DIR=${QDO_CACHE_DIR:-$PWD/build/kernel-cache}
mkdir -p "$OUT"
log() { printf '\n== %s\n' "$*"; }

# The camera: small preset physics, the sensor as built (RGGB, 12 bits, black level 64 DN,
# read noise 1e-3 of full scale ~ 4 DN, shot noise at 20000 photons full well).
CAM=$OUT/camera.json
"$QDO" config --preset small | python3 -c '
import json, sys
c = json.load(sys.stdin)
c.update({"cfa": "rggb", "bit_depth": 12, "black_level_dn": 64, "read_noise_sigma": 0.001,
          "full_well_photons": 20000, "noise_seed": 1})
print(json.dumps(c, indent=2))' > "$CAM"

log "1. design: 4-level QDO+A, Wiener decoder, CAVE training scenes"
if [ ! -f "$OUT/design/design.h5" ]; then
  "$QDO" design --config "$CAM" --mode qdo+a --levels 4 --epochs "$EPOCHS" --steps-per-epoch "$STEPS" --seed "$SEED" \
    --data "$SHARED/data/hsi/cave_train" --out "$OUT/design"
fi

log "2. fabricate: one draw of the tolerance study's mask errors, a relief offset, a z error"
rm -rf "$OUT/asbuilt"
"$QDO" fabricate "$OUT/design" --seed "$FAB_SEED" --etch-depth-error-nm "$ETCH_NM" --overlay-um "$OVERLAY_UM" \
  --offset-um="$OFFSET_UM" --sensor-distance-error-um "$DZ_UM" --out "$OUT/asbuilt"

log "3. calibration sweep through the camera as built (point source per band, dark frames)"
rm -rf "$OUT/sweep"
"$QDO" simulate --config "$OUT/asbuilt/config.json" --design "$OUT/asbuilt/design.h5" --capture psf-sweep --peak 0.6 \
  --darks 8 --out "$OUT/sweep"

log "4. calibrate: measured PSF stack"
rm -rf "$OUT/measured"
"$QDO" calibrate --config "$CAM" --frames "$OUT/sweep/frames" --darks "$OUT/sweep/darks" --design "$OUT/design/design.h5" \
  --out "$OUT/measured"

log "5. fit: the as-built levels, z and offset, with the registration of the measured stack (calibrate centres it on its centroid)"
rm -rf "$OUT/fitted"
"$QDO" fit --config "$CAM" --design "$OUT/design/design.h5" --psf "$OUT/measured/psf.h5" --fit levels,z,offset,shift --iterations 60 --out "$OUT/fitted"
# The fitted camera's PSF with its fitted geometry (qdo reconstruct --design simulates with the run's).
rm -rf "$OUT/fitted_psf"
"$QDO" psf --config "$OUT/fitted/config.json" --design "$OUT/fitted/design.h5" --out "$OUT/fitted_psf"
rm -rf "$OUT/true_psf"
"$QDO" psf --config "$OUT/asbuilt/config.json" --design "$OUT/asbuilt/design.h5" --out "$OUT/true_psf"
# A diagnostic: the same fit on the true as-built stack (no calibration: no noise, no centring,
# no mosaic), to tell the calibration's share of the fit's error from the model's (per-mask overlay
# shifts are not in qdo fit's model).
rm -rf "$OUT/fitted_true"
"$QDO" fit --config "$CAM" --design "$OUT/design/design.h5" --psf "$OUT/true_psf/psf.h5" --fit levels,z,offset --iterations 60 \
  --out "$OUT/fitted_true"

log "6. captures of the CAVE test scenes: through the design (as simulated) and through the camera as built"
for f in "$SHARED"/data/hsi/cave/*.mat; do
  s=$(basename "$f" .mat)
  for cam in design asbuilt; do
    d=$OUT/captures/$cam/$s
    rm -rf "$d"
    mkdir -p "$(dirname "$d")"
    if [ $cam = design ]; then
      "$QDO" simulate --config "$CAM" --design "$OUT/design/design.h5" --scene "$f" --raw --out "$d" > "$d.log"
    else
      "$QDO" simulate --config "$OUT/asbuilt/config.json" --design "$OUT/asbuilt/design.h5" --scene "$f" --raw --out "$d" > "$d.log"
    fi
  done
done

log "7. adapt + reconstruct: the run's Wiener decoder refit in closed form for each PSF, scored against the scene"
run_rec() {  # NAME CAPTURE_SET PSF_ARGS...
  local name=$1 set=$2; shift 2
  for f in "$SHARED"/data/hsi/cave/*.mat; do
    s=$(basename "$f" .mat)
    d=$OUT/recon/$name/$s
    rm -rf "$d"
    mkdir -p "$(dirname "$d")"
    "$QDO" reconstruct --run "$OUT/design" --capture "$OUT/captures/$set/$s/raw.png" --demosaic mhc "$@" \
      --truth "$f" --truth-border "$BORDER" --out "$d" > "$d.log"
  done
}
mkdir -p "$OUT/recon"
run_rec design design                                   # the design as simulated (same sensor chain)
run_rec asbuilt_design_decoder asbuilt                  # the camera as built, the decoder made for the design
run_rec asbuilt_measured asbuilt --psf "$OUT/measured/psf.h5"   # decoder adapted to the measured PSF
run_rec asbuilt_fitted asbuilt --psf "$OUT/fitted_psf/psf.h5"   # decoder adapted to the fitted model
run_rec asbuilt_oracle asbuilt --psf "$OUT/true_psf/psf.h5"     # decoder for the true as-built PSF (the bound)

log "8. table"
python3 scripts/section7_table.py "$OUT"
