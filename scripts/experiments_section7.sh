#!/usr/bin/env bash
# The paper's Section 7 (the built camera) in simulation, end to end (EXPERIMENTS.md "The built
# camera, in simulation"): a 4-level QDO+A design (small preset, Wiener decoder, CAVE training
# scenes) is "fabricated" with errors of the tolerance study's size plus an assembly error
# (qdo fabricate), a monochromator sweep and the CAVE test scenes are captured through that camera
# as raw 12-bit RGGB frames with black level, read and shot noise (qdo simulate --capture psf-sweep,
# qdo simulate --raw), then calibrate -> fit -> adapt -> reconstruct, each reconstruction scored
# against the scene (qdo reconstruct --truth). Two fabrications of the same design: "depth" (each
# mask's etch depth error, a relief offset, a DOE-sensor distance error: all inside qdo fit's
# model) and "full" (the same plus each mask's own overlay shift, as qdo tolerance draws it: outside
# the model). Writes OUT/table.md and OUT/table.csv, and OUT/fit_compare.md (the fit from the
# calibrated stack against the fit from the raw frames, scripts/section7_fit_compare.py).
# With DRAWS=N the table is made over N fabrication draws instead (each its own etch errors within
# ETCH_NM, relief offset and DOE-sensor distance error, every error inside the fit's model; fitted
# from the calibrated stack and from the raw frames; reconstructions with 95 % t intervals over the
# draws, the decoders' sigma from DRAW_SIGMAS, default "model ml 0.03 train"):
# scripts/experiments_fit_raw_draws.sh on this script's design, into OUT/draws (its table.md and
# recon_table.md).
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
LATERAL_STARTS=${LATERAL_STARTS:-auto}   # qdo fit --lateral-starts
SIGMAS=${SIGMAS:-"run model 0.01 0.03"}  # noise sigmas the decoder assumes: run (the run's), model (the sensor's at the capture's level), or values
RECON_ONLY=${RECON_ONLY:-0}           # 1: only steps 7-8 (reconstruct and tables) on an earlier run's files
BORDER=${BORDER:-16}                  # pixels left out of each score at every edge
BOUNDARY=${BOUNDARY:-mirror}          # qdo reconstruct --boundary (EXPERIMENTS' tables: mirror; reconstruct's default is linear)
source scripts/experiments_out.sh  # (the scripts run from the repository root)
claim_out experiments_section7 "$OUT"

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
  "$QDO" design --recipe qdo --config "$CAM" --mode qdo+a --levels 4 --epochs "$EPOCHS" --steps-per-epoch "$STEPS" --seed "$SEED" \
    --data "$SHARED/data/hsi/cave_train" --out "$OUT/design"
fi

if [ -n "${DRAWS:-}" ]; then
  log "2-8 over $DRAWS fabrication draws: scripts/experiments_fit_raw_draws.sh into $OUT/draws"
  DESIGN="$OUT/design/design.h5" DRAWS="$DRAWS" ETCH_NM="$ETCH_NM" OVERLAY_UM=0 SIGMAS="${DRAW_SIGMAS:-model ml 0.03 train}" \
    QDO="$QDO" SHARED="$SHARED" BOUNDARY="$BOUNDARY" bash scripts/experiments_fit_raw_draws.sh "$OUT/draws"
  exit 0
fi

if [ "$RECON_ONLY" != 1 ]; then
log "2. the camera as built, twice: inside qdo fit's model (depth) and with per-mask overlay (full)"
for sc in depth full; do
  ov=$([ $sc = depth ] && echo 0 || echo "$OVERLAY_UM")
  rm -rf "$OUT/$sc"
  mkdir -p "$OUT/$sc"
  "$QDO" fabricate "$OUT/design" --seed "$FAB_SEED" --etch-depth-error-nm "$ETCH_NM" --overlay-um "$ov" \
    --offset-um="$OFFSET_UM" --sensor-distance-error-um "$DZ_UM" --out "$OUT/$sc/asbuilt"
  "$QDO" psf --config "$OUT/$sc/asbuilt/config.json" --design "$OUT/$sc/asbuilt/design.h5" --out "$OUT/$sc/true_psf" > /dev/null

  log "3. [$sc] calibration sweep through the camera as built (a point source per band, dark frames)"
  "$QDO" simulate --config "$OUT/$sc/asbuilt/config.json" --design "$OUT/$sc/asbuilt/design.h5" --capture psf-sweep --peak 0.6 \
    --darks 8 --out "$OUT/$sc/sweep"

  log "4. [$sc] calibrate (--background none: the DOE's PSF has energy out to the crop's edge)"
  "$QDO" calibrate --config "$CAM" --frames "$OUT/$sc/sweep/frames" --darks "$OUT/$sc/sweep/darks" --background none \
    --design "$OUT/design/design.h5" --out "$OUT/$sc/measured"

  log "5. [$sc] fit: levels, z, offset, and the registration of the measured stack (calibrate centres it on its centroid)"
  "$QDO" fit --config "$CAM" --design "$OUT/design/design.h5" --psf "$OUT/$sc/measured/psf.h5" --fit levels,z,offset,shift \
    --lateral-starts "$LATERAL_STARTS" --iterations 60 --out "$OUT/$sc/fitted"
  # The fitted camera's PSF with its fitted geometry (qdo reconstruct --design simulates with the run's).
  "$QDO" psf --config "$OUT/$sc/fitted/config.json" --design "$OUT/$sc/fitted/design.h5" --out "$OUT/$sc/fitted_psf" > /dev/null
  # A diagnostic: the same fit on the true as-built stack (no calibration: no noise, no centring, no
  # mosaic), to tell the calibration's share of the fit's error from the model's.
  "$QDO" fit --config "$CAM" --design "$OUT/design/design.h5" --psf "$OUT/$sc/true_psf/psf.h5" --fit levels,z,offset \
    --lateral-starts "$LATERAL_STARTS" --iterations 60 --out "$OUT/$sc/fitted_true"
  log "5b. [$sc] the same fit on the raw frames themselves (no calibrated stack)"
  "$QDO" fit --config "$CAM" --design "$OUT/design/design.h5" --frames "$OUT/$sc/sweep/frames" --darks "$OUT/$sc/sweep/darks" \
    --fit levels,z,offset,shift --lateral-starts "$LATERAL_STARTS" --iterations 60 --out "$OUT/$sc/fitted_raw"
  rm -rf "$OUT/$sc/fitted_raw_psf"
done
python3 scripts/section7_fit_compare.py "$OUT" depth full > "$OUT/fit_compare.md"

log "6. captures of the CAVE test scenes: through the design (as simulated) and through each camera as built"
capture() {  # SET CONFIG DESIGN
  local set=$1 cfg=$2 design=$3
  for f in "$SHARED"/data/hsi/cave/*.mat; do
    s=$(basename "$f" .mat)
    d=$OUT/captures/$set/$s
    rm -rf "$d"
    mkdir -p "$(dirname "$d")"
    "$QDO" simulate --config "$cfg" --design "$design" --scene "$f" --raw --out "$d" > "$d.log"
  done
}
capture design "$CAM" "$OUT/design/design.h5"
for sc in depth full; do capture "$sc" "$OUT/$sc/asbuilt/config.json" "$OUT/$sc/asbuilt/design.h5"; done
fi

log "7. adapt + reconstruct: the run's Wiener decoder refit in closed form for each PSF, scored against the scene"
# The noise sigma the decoder assumes: the run's (1e-3, what the design was trained with), the
# sensor's noise model at each capture's mean signal (qdo reconstruct --noise-sigma model: read,
# shot and quantization noise), and fixed larger values (a sensitivity: the same for every row,
# not tuned per row).
run_rec() {  # NAME CAPTURE_SET PSF_ARGS...
  local name=$1 set=$2; shift 2
  for f in "$SHARED"/data/hsi/cave/*.mat; do
    s=$(basename "$f" .mat)
    for sig in $SIGMAS; do
      d=$OUT/recon/$sig/$name/$s
      rm -rf "$d"
      mkdir -p "$(dirname "$d")"
      case $sig in
        run) ns=0.001 ;;
        model) ns=model ;;
        *) ns=$sig ;;
      esac
      "$QDO" reconstruct --run "$OUT/design" --capture "$OUT/captures/$set/$s/raw.png" --demosaic mhc --noise-sigma "$ns" "$@" \
        --boundary "$BOUNDARY" --truth "$f" --truth-border "$BORDER" --out "$d" > "$d.log"
    done
  done
}
run_rec design design                                                 # the design as simulated (same sensor chain)
for sc in depth full; do
  run_rec "$sc/design_decoder" "$sc"                                  # the camera as built, the decoder made for the design
  run_rec "$sc/measured" "$sc" --psf "$OUT/$sc/measured/psf.h5"       # decoder adapted to the measured PSF
  run_rec "$sc/fitted" "$sc" --psf "$OUT/$sc/fitted_psf/psf.h5"       # decoder adapted to the fitted model
  # ... and to the model fitted to the raw frames (its PSF with its fitted geometry, made once)
  [ -f "$OUT/$sc/fitted_raw_psf/psf.h5" ] ||
    "$QDO" psf --config "$OUT/$sc/fitted_raw/config.json" --design "$OUT/$sc/fitted_raw/design.h5" --out "$OUT/$sc/fitted_raw_psf" > /dev/null
  run_rec "$sc/fitted_raw" "$sc" --psf "$OUT/$sc/fitted_raw_psf/psf.h5"
  run_rec "$sc/oracle" "$sc" --psf "$OUT/$sc/true_psf/psf.h5"         # decoder for the true as-built PSF (a bound)
done

log "8. table"
python3 scripts/section7_table.py "$OUT" $SIGMAS
