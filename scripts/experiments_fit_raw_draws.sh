#!/usr/bin/env bash
# The as-built fit from the raw frames against the fit from the calibrated stack, over fabrication
# draws (EXPERIMENTS.md "Section 7 again: the fit from the raw frames"). The Section 7 design
# (4-level QDO+A, small preset, seed 0) is fabricated once per draw (qdo fabricate: etch depth
# errors within +-ETCH_NM, default 20 nm, the draw's relief offset and DOE-sensor distance error
# times DZ_SCALE, default 1; each mask's overlay within OVERLAY_UM, default 0: every error inside
# the fit's model; larger ETCH_NM and DZ_SCALE make an as-built PSF further from the design's, for
# the decoders' comparison), a monochromator sweep
# is captured through it as raw 12-bit RGGB frames with read and shot noise and 8 darks (qdo
# simulate --capture psf-sweep), then fitted twice with --fit levels,z,offset,shift: from qdo
# calibrate's stack, and from the frames themselves (qdo fit --frames). Writes OUT/table.md.
# With RECON=1 (the default) each draw also captures the CAVE test scenes through its camera as raw
# frames (qdo simulate --raw) and reconstructs them with the design's Wiener decoder: made for the
# design, adapted to the model fitted to the raw frames, adapted to the model fitted to the
# calibrated stack, and for the true as-built PSF (not a bound: a Wiener decoder built for another
# PSF can score higher on given scenes); the sigma the decoder assumes from the
# noise model with the capture's demosaic error (--noise-sigma model), the capture's marginal
# likelihood (ml), cross-validation (gcv) and 0.03 (SIGMAS), MHC demosaic, scored over the interior
# (16 px border). Writes OUT/recon_table.md: per draw the mean over the scenes, and over the draws
# the mean and 95 % t interval of each decoder's PSNR and of its difference to the design's decoder.
# SIGMAS may also name `train`: each decoder's sigma tuned once per camera on training scenes, as a
# lab can without any test scene: TRAIN_SCENES (default 4 of cave_train: cd, fake_and_real_lemon_slices,
# fake_and_real_tomatoes, photo_and_face) captured as raw frames through the camera as fitted to the
# raw frames (its config.json and design.h5), each decoder run on them at every sigma of TRAIN_GRID,
# the sigma of the best mean PSNR kept (DRAW/recon/train/ROW/sigma.txt) and used on the test scenes;
# and a row "chosen": per camera, the design's decoder or the one adapted to the raw fit, whichever
# scores higher on those training scenes at its tuned sigma. The summary counts the draws where
# each decoder is at or above the design's (to 0.01 dB).
# BOUNDARY (default mirror): how reconstruct's tiles meet the decoder's model (--boundary); linear
# is the capture's own model (tiled.hpp), solved by conjugate gradients, about 20 times slower; its
# reconstructions go to DRAW/recon_linear and its table to OUT/recon_table_linear.md. ROWS: the
# decoders reconstructed (default: design_decoder fitted_raw fitted true).
# Usage: bash scripts/experiments_fit_raw_draws.sh [OUT]   (QDO: the qdo binary, default build/qdo;
# DESIGN: a design.h5 to use instead of training the Section 7 design into OUT/design (its folder is
# the run reconstruct decodes with); DRAWS: how many of the ten draws, default 5)
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/fit_raw_draws}
QDO=${QDO:-build/qdo}
SHARED=${SHARED:-../shared}
OVERLAY_UM=${OVERLAY_UM:-0}
ETCH_NM=${ETCH_NM:-20}
DZ_SCALE=${DZ_SCALE:-1}
NAME=experiments_fit_raw_draws
source scripts/experiments_fit_common.sh
# The sensor as built, as in experiments_section7.sh: RGGB, 12 bits, black level 64 DN, read noise
# 1e-3 of full scale, shot noise at 20000 photons full well.
RAWCAM=$OUT/camera_raw.json
python3 -c '
import json, sys
c = json.load(open(sys.argv[1]))
c.update({"cfa": "rggb", "bit_depth": 12, "black_level_dn": 64, "read_noise_sigma": 0.001,
          "full_well_photons": 20000, "noise_seed": 1})
json.dump(c, open(sys.argv[2], "w"), indent=2)' "$CAM" "$RAWCAM"
# The same sensor keys alone, for qdo reconstruct --sensor: the captures are raw whatever sensor the
# run that decodes them was trained with.
SENSOR=$OUT/sensor_raw.json
python3 -c '
import json, sys
c = json.load(open(sys.argv[1]))
json.dump({k: c[k] for k in ("cfa", "bit_depth", "black_level_dn", "read_noise_sigma", "full_well_photons", "noise_seed")},
          open(sys.argv[2], "w"), indent=2)' "$RAWCAM" "$SENSOR"
# Each draw: the fabrication seed, the relief offset (um), the DOE-sensor distance error (um)
# (experiments_fit_sigma.sh's list).
ALL=("11 1.5,-1.0 150" "12 -2.0,0.5 -100" "13 0.7,2.4 60" "14 2.8,-1.9 180" "15 -0.6,-3.1 -140"
     "16 4.2,1.1 90" "17 -1.3,-0.4 0" "18 0.2,-0.9 -60" "19 -3.5,2.0 120" "20 1.0,1.0 -200")
n=${DRAWS:-5}
for draw in "${ALL[@]:0:$n}"; do
  read -r seed off dz <<< "$draw"
  dz=$(python3 -c "import sys; print(float(sys.argv[1]) * float(sys.argv[2]))" "$dz" "$DZ_SCALE")
  c=$OUT/draw$seed
  if [ -f "$c/fitted_raw/fit.json" ] && [ -f "$c/fitted/fit.json" ]; then echo "draw $seed: done before"; continue; fi
  rm -rf "$c"
  mkdir -p "$c"
  t0=$(date +%s)
  "$QDO" fabricate "$DESIGN" --config "$RAWCAM" --seed "$seed" --etch-depth-error-nm "$ETCH_NM" --overlay-um "$OVERLAY_UM" --offset-um="$off" \
    --sensor-distance-error-um "$dz" --out "$c/asbuilt" > /dev/null
  "$QDO" simulate --config "$c/asbuilt/config.json" --design "$c/asbuilt/design.h5" --capture psf-sweep --peak 0.6 --darks 8 \
    --out "$c/sweep" > /dev/null
  "$QDO" calibrate --config "$RAWCAM" --frames "$c/sweep/frames" --darks "$c/sweep/darks" --background none --out "$c/measured" > /dev/null
  "$QDO" fit --config "$RAWCAM" --design "$DESIGN" --psf "$c/measured/psf.h5" --fit levels,z,offset,shift --iterations 60 \
    --out "$c/fitted" > "$c/fitted.log" 2>&1 || true
  "$QDO" fit --config "$RAWCAM" --design "$DESIGN" --frames "$c/sweep/frames" --darks "$c/sweep/darks" --fit levels,z,offset,shift \
    --iterations 60 --out "$c/fitted_raw" > "$c/fitted_raw.log" 2>&1 || true
  echo "draw $seed (offset $off um, dz $dz um, etch within $ETCH_NM nm, overlay within $OVERLAY_UM um): $(( $(date +%s) - t0 )) s"
done
if [ "${RECON:-1}" = 1 ]; then
  RUN=$(dirname "$DESIGN")
  BOUNDARY=${BOUNDARY:-mirror}
  case $BOUNDARY in
    mirror) REC=recon; TABLE=recon_table.md ;;
    linear|circular) REC=recon_$BOUNDARY; TABLE=recon_table_$BOUNDARY.md ;;
    *) echo "BOUNDARY: '$BOUNDARY' is not mirror, linear or circular" >&2; exit 2 ;;
  esac
  ROWS=${ROWS:-"design_decoder fitted_raw fitted true"}
  for r in $ROWS; do
    case $r in design_decoder|fitted_raw|fitted|true) ;; *) echo "ROWS: '$r' is not design_decoder, fitted_raw, fitted or true" >&2; exit 2 ;; esac
  done
  SIGMAS=${SIGMAS:-"model ml gcv 0.03"}  # the noise model, the capture's likelihood, cross-validation, a fixed value (not tuned)
  for draw in "${ALL[@]:0:$n}"; do
    read -r seed _ <<< "$draw"
    c=$OUT/draw$seed
    t0=$(date +%s)
    for kind in true fitted fitted_raw; do
      [ -f "$c/${kind}_psf/psf.h5" ] && continue
      case $kind in
        true) "$QDO" psf --config "$c/asbuilt/config.json" --design "$c/asbuilt/design.h5" --out "$c/true_psf" > /dev/null ;;
        *) [ -f "$c/$kind/config.json" ] &&
             "$QDO" psf --config "$c/$kind/config.json" --design "$c/$kind/design.h5" --out "$c/${kind}_psf" > /dev/null ;;
      esac
    done
    # `train`: each decoder's sigma from the training scenes through the camera as fitted (above).
    if [[ " $SIGMAS " == *" train "* ]] && [ -f "$c/fitted_raw/config.json" ]; then
      for ts in ${TRAIN_SCENES:-cd fake_and_real_lemon_slices fake_and_real_tomatoes photo_and_face}; do
        f=$SHARED/data/hsi/cave_train/${ts}_256.mat
        capture_raw_once "$c/train_captures/$ts" "$f" --config "$c/fitted_raw/config.json" --design "$c/fitted_raw/design.h5"
      done
      for row in $ROWS; do
        [ -f "$c/$REC/train/$row/sigma.txt" ] && continue
        psf=()
        [ "$row" = design_decoder ] || psf=(--psf "$c/${row}_psf/psf.h5")
        [ "$row" = design_decoder ] || [ -f "$c/${row}_psf/psf.h5" ] || continue
        best=
        for sg in ${TRAIN_GRID:-0.001 0.002 0.003 0.005 0.01 0.02 0.03}; do
          for ts in ${TRAIN_SCENES:-cd fake_and_real_lemon_slices fake_and_real_tomatoes photo_and_face}; do
            d=$c/$REC/train_grid/$row/$sg/$ts
            [ -f "$d/metrics.json" ] && continue
            recon_raw "$d" "$c/train_captures/$ts/raw.png" "$SHARED/data/hsi/cave_train/${ts}_256.mat" "$sg" "$BOUNDARY" "${psf[@]}"
          done
        done
        best=$(python3 - "$c/$REC/train_grid/$row" <<'PY'
import glob, json, os, sys
scores = {}
for m in glob.glob(os.path.join(sys.argv[1], "*", "*", "metrics.json")):
    sg = os.path.basename(os.path.dirname(os.path.dirname(m)))
    scores.setdefault(sg, []).append(json.load(open(m))["mean"]["psnr"])
n = max(len(v) for v in scores.values())
print(max((sum(v) / len(v), k) for k, v in scores.items() if len(v) == n)[1])
PY
)
        mkdir -p "$c/$REC/train/$row"
        echo "$best" > "$c/$REC/train/$row/sigma.txt.tmp" && mv "$c/$REC/train/$row/sigma.txt.tmp" "$c/$REC/train/$row/sigma.txt"
      done
    fi
    for f in "$SHARED"/data/hsi/cave/*.mat; do
      s=$(basename "$f" .mat)
      cap=$c/captures/$s
      capture_raw_once "$cap" "$f" --config "$c/asbuilt/config.json" --design "$c/asbuilt/design.h5"
      for sig in $SIGMAS; do
        for row in $ROWS; do
          d=$c/$REC/$sig/$row/$s
          [ -f "$d/metrics.json" ] && continue
          psf=()
          [ "$row" = design_decoder ] || psf=(--psf "$c/${row}_psf/psf.h5")
          [ "$row" = design_decoder ] || [ -f "$c/${row}_psf/psf.h5" ] || continue
          use=$sig
          if [ "$sig" = train ]; then
            [ -f "$c/$REC/train/$row/sigma.txt" ] || continue
            use=$(cat "$c/$REC/train/$row/sigma.txt")
          fi
          recon_raw "$d" "$cap/raw.png" "$f" "$use" "$BOUNDARY" "${psf[@]}"
        done
      done
    done
    echo "draw $seed: captures and reconstructions $(( $(date +%s) - t0 )) s"
  done
  python3 - "$OUT" "$REC" "$TABLE" "$BOUNDARY" $SIGMAS <<'PY'
import glob, json, os, sys
sys.path.insert(0, "scripts")
from qdo_stats import mean_ci
out, rec, table, boundary, sigmas = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4], sys.argv[5:]
rows = [("design_decoder", "decoder made for the design"), ("fitted_raw", "adapted to the model fitted to the raw frames"),
        ("fitted", "adapted to the model fitted to the calibrated stack"), ("true", "for the true as-built PSF")]
L = ["Reconstructions of the CAVE test scenes through each draw's camera (raw RGGB 12-bit, MHC), PSNR (dB) over the "
     "interior (16 px border left out), mean over the 3 scenes; tiles meet the decoder by the " + boundary + " boundary; σ assumed: `model` = the sensor's noise model at each "
     "capture's mean signal with the capture's demosaic error (`--noise-sigma model`); `ml` = chosen from each capture, "
     "the largest marginal likelihood under the decoder's model (`--noise-sigma ml`); `gcv` = by generalised "
     "cross-validation (`--noise-sigma gcv`); or a fixed value.", ""]
for sig in sigmas:
    per = {r: {} for r, _ in rows}
    used = {}
    for d in sorted(glob.glob(os.path.join(out, "draw*"))):
        for r, _ in rows:
            ms = sorted(glob.glob(os.path.join(d, rec, sig, r, "*", "metrics.json")))
            if ms:
                per[r][os.path.basename(d)] = [json.load(open(m))["mean"] for m in ms]
            if r == "design_decoder":
                for m in ms:
                    rj = json.load(open(os.path.join(os.path.dirname(m), "reconstruct.json")))
                    used.setdefault(os.path.basename(d), []).append(
                        (rj["noise_sigma"], rj.get("noise_sigma_model", {}).get("demosaic_sigma", float("nan"))))
    draws = sorted(per["design_decoder"])
    if not draws:
        continue
    if sig == "train":
        # "chosen": per camera, the design's decoder or the one adapted to the raw fit, whichever
        # has the better mean PSNR on the training scenes (through the camera as fitted) at its
        # tuned sigma; a lab can do this without any test scene.
        def train_score(d, r):
            f = os.path.join(out, d, rec, "train", r, "sigma.txt")
            if not os.path.exists(f):
                return None
            ms = glob.glob(os.path.join(out, d, rec, "train_grid", r, open(f).read().strip(), "*", "metrics.json"))
            return sum(json.load(open(m))["mean"]["psnr"] for m in ms) / len(ms) if ms else None
        per["chosen"], picked = {}, []
        for d in draws:
            a, b = train_score(d, "design_decoder"), train_score(d, "fitted_raw")
            if a is None or b is None or d not in per["fitted_raw"]:
                continue
            r = "fitted_raw" if b > a else "design_decoder"
            per["chosen"][d] = per[r][d]
            picked.append(f"{d} {'raw fit' if r == 'fitted_raw' else 'design'} ({b - a:+.2f} dB on the training scenes)")
        rows_sig = rows + [("chosen", "chosen on the training scenes: the design's or the raw fit's")]
    else:
        rows_sig = rows
    L += [f"σ = {sig}:", "", "| draw | σ assumed (mean) | its demosaic term (mean) | " + " | ".join(label for _, label in rows_sig) + " |",
          "|---|---:|---:|" + "---:|" * len(rows_sig)]
    for d in draws:
        cells = []
        for r, _ in rows_sig:
            v = per[r].get(d)
            cells.append(f"{sum(x['psnr'] for x in v) / len(v):.2f}" if v else "—")
        ns = [a for a, _ in used[d]]
        dm = [b for _, b in used[d]]
        L.append(f"| {d} | {sum(ns) / len(ns):.4f} | {sum(dm) / len(dm):.5f} | " + " | ".join(cells) + " |")
    if sig == "train":
        tuned = []
        for d in draws:
            got = []
            for r, _ in rows:
                f = os.path.join(out, d, rec, "train", r, "sigma.txt")
                got.append(open(f).read().strip() if os.path.exists(f) else "—")
            tuned.append(f"{d} " + "/".join(got))
        L += ["", "σ tuned on the training scenes (design / raw fit / stack fit / true): " + "; ".join(tuned),
              "", "chosen on the training scenes (raw fit − design there): " + "; ".join(picked)]
    L += ["", "Over the draws (mean ± 95 % t interval of the per-draw means; the difference paired by draw):", "",
          "| decoder | PSNR (dB) | − design's decoder (dB) | draws at or above the design's | SSIM | SAM (rad) |",
          "|---|---:|---:|---:|---:|---:|"]
    for r, label in rows_sig:
        ds = [d for d in draws if d in per[r]]
        if not ds:
            continue
        mean = lambda d, k: sum(x[k] for x in per[r][d]) / len(per[r][d])
        base = lambda d: sum(x["psnr"] for x in per["design_decoder"][d]) / len(per["design_decoder"][d])
        p, pc = mean_ci([mean(d, "psnr") for d in ds])
        dd, dc = mean_ci([mean(d, "psnr") - base(d) for d in ds])
        at = sum(round(mean(d, "psnr") - base(d), 2) >= 0 for d in ds)
        L.append(f"| {label} | {p:.2f} ± {pc:.2f} | {dd:+.2f} ± {dc:.2f} | {at} of {len(ds)} | "
                 f"{mean_ci([mean(d, 'ssim') for d in ds])[0]:.4f} | "
                 f"{mean_ci([mean(d, 'sam_rad') for d in ds])[0]:.4f} |")
    L.append("")
tmp = os.path.join(out, table + ".tmp")
open(tmp, "w").write("\n".join(L))
os.replace(tmp, os.path.join(out, table))
print("\n".join(L))
PY
fi
python3 - "$OUT" "$OVERLAY_UM" <<'PY'
import glob, json, os, sys
out, overlay = sys.argv[1], sys.argv[2]
scale = {"level1": 1e9, "level2": 1e9, "level3": 1e9, "z": 1e6, "dx": 1e6, "dy": 1e6}
unit = {"level1": "nm", "level2": "nm", "level3": "nm", "z": "µm", "dx": "µm", "dy": "µm"}
rows, worst = [], {"stack": [], "raw": []}
within3 = total = 0
chi2 = []
for d in sorted(glob.glob(os.path.join(out, "draw*"))):
    truth = json.load(open(os.path.join(d, "asbuilt", "truth.json")))["fit_parameters"]
    fits = {}
    for kind, folder in (("stack", "fitted"), ("raw", "fitted_raw")):
        fj = os.path.join(d, folder, "fit.json")
        fits[kind] = json.load(open(fj)) if os.path.exists(fj) else None
    if not fits["stack"] or not fits["raw"]:
        rows.append(f"| {os.path.basename(d)} | (a fit failed: see {d}/*.log) | | | | |")
        continue
    chi2.append(fits["raw"].get("chi2_reduced", float("nan")))
    p = {k: {q["name"]: q for q in f["parameters"]} for k, f in fits.items()}
    lv = {k: max(abs(p[k][n]["value"] - truth[n]) * 1e9 for n in ("level1", "level2", "level3")) for k in p}
    for k in p:
        worst[k].append(lv[k])
    for n in ("level1", "level2", "level3", "z", "dx", "dy"):
        s = scale[n]
        es, er, sg = (p["stack"][n]["value"] - truth[n]) * s, (p["raw"][n]["value"] - truth[n]) * s, p["raw"][n]["sigma"] * s
        total += 1
        within3 += abs(er) <= 3 * sg
        rows.append(f"| {os.path.basename(d)} | {n} ({unit[n]}) | {es:+.2f} | {er:+.2f} | {sg:.3f} | {abs(er) / sg if sg > 0 else float('inf'):.1f} |")
L = [f"Fitted minus true over {len(chi2)} draws (overlay within {overlay} um per mask), `--fit levels,z,offset,shift`:", "",
     "| draw | parameter | stack fit − true | raw fit − true | raw σ | raw error / σ |", "|---|---|---:|---:|---:|---:|"] + rows
if chi2:
    L += ["", f"- worst level error per draw (nm): stack {', '.join(f'{x:.1f}' for x in worst['stack'])}; "
              f"raw {', '.join(f'{x:.1f}' for x in worst['raw'])}",
          f"- draws with every level within 8 nm: stack {sum(x <= 8 for x in worst['stack'])} of {len(chi2)}, "
          f"raw {sum(x <= 8 for x in worst['raw'])} of {len(chi2)}",
          f"- raw fit: reduced chi^2 {', '.join(f'{x:.3f}' for x in chi2)}; {within3} of {total} errors within 3 sigma"]
open(os.path.join(out, "table.md"), "w").write("\n".join(L) + "\n")
print("\n".join(L))
PY
