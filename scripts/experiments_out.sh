# shellcheck shell=bash
# Sourced by the experiment scripts: the environment they run in and the one folder they write.
#   claim_out NAME OUT   OUT becomes NAME's output folder. The script deletes and rewrites only the
#                        folders it makes under OUT; an OUT it did not make (no OUT/.NAME marker) is
#                        refused with exit 2, so a user's folder is never touched.
#   recon_raw, model_padding_of, sweep_centre_of   below
export QDO_DEVICE=${QDO_DEVICE:-cpu}
export QDO_CACHE_DIR=${QDO_CACHE_DIR:-$PWD/build/kernel-cache}
claim_out() {
  local name=$1 out=$2
  if [ -e "$out" ] && [ ! -f "$out/.$name" ]; then
    echo "$name: $out exists and was not made by this script (no $out/.$name); choose another OUT" >&2
    exit 2
  fi
  mkdir -p "$out"
  touch "$out/.$name"
}
log() { printf '\n== %s\n' "$*"; }
# recon_raw DIR CAPTURE TRUTH SIGMA BOUNDARY [ARG ...]: qdo reconstruct of one raw capture (a raw.png)
# by the Wiener decoder of the run $RUN with the sensor keys $SENSOR, MHC demosaic, --noise-sigma
# SIGMA, --boundary BOUNDARY and ARGs (e.g. --psf FILE), scored against TRUTH over the interior (16
# px border) into DIR (made again), its log DIR.log; a failure is reported, not fatal. Needs QDO, RUN
# and SENSOR.
recon_raw() {
  local d=$1 cap=$2 truth=$3 sig=$4 boundary=$5
  shift 5
  rm -rf "$d"
  mkdir -p "$(dirname "$d")"
  "$QDO" reconstruct --run "$RUN" --capture "$cap" --sensor "$SENSOR" --demosaic mhc --noise-sigma "$sig" "$@" \
    --boundary "$boundary" --truth "$truth" --truth-border 16 --out "$d" > "$d.log" 2>&1 || echo "$d: reconstruct failed (see $d.log)"
}

# capture_raw_once CAP SCENE ARG...: qdo simulate ARGs (the camera: --config and --design or --psf)
# --scene SCENE --raw into CAP, its log CAP.log, unless CAP/raw.png is there (a CAP a killed run left
# without it is made again). Needs QDO.
capture_raw_once() {
  local cap=$1 scene=$2
  shift 2
  [ -f "$cap/raw.png" ] && return 0
  rm -rf "$cap"
  mkdir -p "$(dirname "$cap")"
  "$QDO" simulate "$@" --scene "$scene" --raw --out "$cap" > "$cap.log"
}

# model_padding_of CONFIG: the padding_px of a camera's as-built config.json, for qdo fit
# --model-padding: a camera qdo simulated is fitted with the window it was made with (qdo fabricate
# writes the sampled window since --model-padding existed, the design's before).
model_padding_of() {
  "${PY:-/usr/bin/python3}" -c 'import json, sys; c = json.load(open(sys.argv[1])); print(c.get("system", c)["padding_px"])' "$1"
}

# sweep_centre_of SWEEP.h5: ROW,COL, the frame pixel where qdo simulate --capture psf-sweep put the
# optical axis (its centre_row_col), for qdo calibrate / qdo fit --centre in a simulation.
sweep_centre_of() {
  "${PY:-/usr/bin/python3}" -c 'import h5py, sys; print(h5py.File(sys.argv[1], "r").attrs["centre_row_col"].decode())' "$1"
}
