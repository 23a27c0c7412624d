#!/usr/bin/env bash
# Does the adapted Wiener decoder gain on cameras made by an independent model? (EXPERIMENTS.md
# "The fit's model window".) Takes the folder scripts/experiments_fit_raw_sigma.sh wrote and, for each
# of its generated cameras (gen21..25: scripts/asbuilt_generator.py, 1 um grid, impulse-response
# propagation, no qdo code), captures the CAVE test scenes through the generator's own PSF stack as
# raw 12-bit RGGB frames (qdo simulate --psf GEN/asbuilt/psf.h5 --raw, the sensor of camera_raw.json)
# and reconstructs them (--boundary linear, MHC, 16 px border left out) with the design's Wiener
# decoder (design_decoder), the decoder adapted to the camera as qdo fit found it from its raw
# frames (fitted: the PSF of FITDIR's config.json and design.h5 by qdo psf, the fitted geometry and
# model window, centred on the optical axis; fitted_window: FITDIR's psf.h5, the fitted model in the
# measurement's window with the registration), the decoder adapted to the PSF qdo calibrate measures
# from the camera's sweep (measured; --background none, as experiments_fit_raw_draws.sh), and the
# decoder made for the generator's PSF itself (true), at each sigma of SIGMAS. ROWS picks the rows
# (default all five; fitted_window only where FITDIR has psf.h5). CENTRE=sweep: calibrate with
# --centre at the sweep's own axis pixel (sweep_centre_of, known in simulation) into measured_sweep/,
# the grid the captures are on; CENTRE=centroid: --centre centroid (calibrate's default before
# --centre auto) into measured/; default calibrate's own (auto) into measured_auto/. Writes OUT/gen_recon_FITDIR.md:
# per camera the mean PSNR over the scenes, and over the cameras the mean and 95 % t interval of
# each decoder's PSNR and of its difference to the design's decoder, and the cameras at or above it.
# Usage: bash scripts/experiments_gen_decoders.sh OUT   (OUT: experiments_fit_raw_sigma.sh's folder;
# DESIGN: the design.h5 its cameras were made from (its folder is the run reconstruct decodes
# with); FITDIR: the fit's folder in each camera, default fitted_raw; SIGMAS default "model 0.005";
# QDO, SHARED as there)
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:?usage: experiments_gen_decoders.sh OUT (the folder experiments_fit_raw_sigma.sh wrote)}
DESIGN=${DESIGN:?DESIGN: the design.h5 the cameras were made from}
FITDIR=${FITDIR:-fitted_raw}
SIGMAS=${SIGMAS:-"model 0.005"}
QDO=${QDO:-build/qdo}
SHARED=${SHARED:-../shared}
source scripts/experiments_out.sh
if [ ! -f "$OUT/.experiments_fit_raw_sigma" ]; then
  echo "$OUT was not made by experiments_fit_raw_sigma.sh (no $OUT/.experiments_fit_raw_sigma)" >&2
  exit 2
fi
RUN=$(dirname "$DESIGN")
RAWCAM=$OUT/camera_raw.json
SENSOR=$OUT/sensor_raw.json
python3 -c '
import json, sys
c = json.load(open(sys.argv[1]))
json.dump({k: c[k] for k in ("cfa", "bit_depth", "black_level_dn", "read_noise_sigma", "full_well_photons", "noise_seed")},
          open(sys.argv[2], "w"), indent=2)' "$RAWCAM" "$SENSOR"
REC=recon_$FITDIR
ROWS=${ROWS:-"design_decoder fitted fitted_window measured true"}
MEAS=measured_auto
[ "${CENTRE:-}" = sweep ] && MEAS=measured_sweep
[ "${CENTRE:-}" = centroid ] && MEAS=measured
for c in "$OUT"/gen[0-9]*; do
  [ -f "$c/$FITDIR/fit.json" ] || { echo "$c: no $FITDIR/fit.json, skipped"; continue; }
  t0=$(date +%s)
  [ -f "$c/${FITDIR}_psf/psf.h5" ] || "$QDO" psf --config "$c/$FITDIR/config.json" --design "$c/$FITDIR/design.h5" \
    --out "$c/${FITDIR}_psf" > /dev/null
  centre=()
  [ "$MEAS" = measured_sweep ] && centre=(--centre "$(sweep_centre_of "$c/sweep/sweep.h5")")
  [ "$MEAS" = measured ] && centre=(--centre centroid)
  [ -f "$c/$MEAS/psf.h5" ] || { rm -rf "$c/$MEAS"; "$QDO" calibrate --config "$RAWCAM" --frames "$c/sweep/frames" \
    --darks "$c/sweep/darks" --background none "${centre[@]}" --out "$c/$MEAS" > "$c/$MEAS.log" 2>&1; }
  for f in "$SHARED"/data/hsi/cave/*.mat; do
    s=$(basename "$f" .mat)
    cap=$c/captures/$s
    capture_raw_once "$cap" "$f" --config "$RAWCAM" --psf "$c/asbuilt/psf.h5"
    for sig in $SIGMAS; do
      for row in $ROWS; do
        d=$c/$REC/$sig/$row/$s
        [ -f "$d/metrics.json" ] && continue
        case $row in
          design_decoder) psf=() ;;
          fitted) psf=(--psf "$c/${FITDIR}_psf/psf.h5") ;;
          fitted_window) [ -f "$c/$FITDIR/psf.h5" ] || continue; psf=(--psf "$c/$FITDIR/psf.h5") ;;
          measured) psf=(--psf "$c/$MEAS/psf.h5") ;;
          true) psf=(--psf "$c/asbuilt/psf.h5") ;;
        esac
        recon_raw "$d" "$cap/raw.png" "$f" "$sig" linear "${psf[@]}"
      done
    done
  done
  echo "$(basename "$c"): captures and reconstructions $(( $(date +%s) - t0 )) s"
done
python3 - "$OUT" "$REC" "$FITDIR" "$MEAS" $SIGMAS <<'PY'
import glob, json, os, sys
sys.path.insert(0, "scripts")
from qdo_stats import mean_ci
out, rec, fitdir, meas, sigmas = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4], sys.argv[5:]
rows = [("design_decoder", "decoder made for the design"), ("fitted", "adapted to the camera as fitted (" + fitdir + ", qdo psf)"),
        ("fitted_window", "adapted to the fit's psf.h5 (" + fitdir + ")"),
        ("measured", "adapted to the measured PSF (qdo calibrate, " + meas + ")"), ("true", "made for the generator's PSF")]
L = ["The generated cameras (scripts/asbuilt_generator.py): the CAVE test scenes captured through each camera's own PSF "
     "as raw 12-bit RGGB frames, reconstructed with linear tiles and MHC; PSNR (dB) over the interior (16 px border), "
     "mean over the 3 scenes.", ""]
for sig in sigmas:
    per = {r: {} for r, _ in rows}
    for c in sorted(glob.glob(os.path.join(out, "gen[0-9]*"))):
        for r, _ in rows:
            ms = sorted(glob.glob(os.path.join(c, rec, sig, r, "*", "metrics.json")))
            if len(ms) == 3:
                per[r][os.path.basename(c)] = sum(json.load(open(m))["mean"]["psnr"] for m in ms) / 3
    shown = [(r, lbl) for r, lbl in rows if per[r]]  # rows not run (ROWS, no psf.h5) are left out
    cams = sorted(set.intersection(*(set(per[r]) for r, _ in shown))) if shown else []
    L += [f"σ = {sig}:", "", "| camera | " + " | ".join(lbl for _, lbl in shown) + " |", "|---|" + "---:|" * len(shown)]
    for c in cams:
        L.append(f"| {c} | " + " | ".join(f"{per[r][c]:.2f}" for r, _ in shown) + " |")
    L += ["", "| decoder | PSNR (dB) | − design's decoder (dB) | cameras at or above the design's |", "|---|---:|---:|---:|"]
    for r, lbl in shown:
        if not cams:
            break
        p, pc = mean_ci([per[r][c] for c in cams])
        dd, dc = mean_ci([per[r][c] - per["design_decoder"][c] for c in cams])
        at = sum(round(per[r][c] - per["design_decoder"][c], 2) >= 0 for c in cams)
        L.append(f"| {lbl} | {p:.2f} ± {pc:.2f} | {dd:+.2f} ± {dc:.2f} | {at} of {len(cams)} |")
    L.append("")
path = os.path.join(out, f"gen_recon_{fitdir}.md")
open(path + ".tmp", "w").write("\n".join(L) + "\n")
os.replace(path + ".tmp", path)
print("\n".join(L))
PY
