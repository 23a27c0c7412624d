#!/usr/bin/env bash
# How a tile meets the Wiener decoder's model, on one as-built camera of Section 7 (EXPERIMENTS.md
# "The capture's own boundary"): the design's decoder against the decoder built for the camera's
# true PSF, on captures made circularly (the decoder's own model: the scene repeats) and linearly
# (as a camera makes them), each decoded with the circular, mirror and linear tile boundaries
# (qdo reconstruct --boundary), at several sigmas. The sensor adds no noise (16 bits, no read or
# shot noise, black level 0), so what differs is the model alone. The scenes are the centre 128 x
# 128 of each CAVE test scene (one decoder tile).
# Usage: bash scripts/experiments_boundary.sh [OUT]
#   DRAW_DIR: a draw of scripts/experiments_fit_raw_draws.sh (its asbuilt/ and true_psf/; default
#   out/fit_raw_draws_large/draw12); RUN: the run that decodes (default out/fit_raw_sigma_p160/design);
#   SIGMAS (default "0.001 0.005 0.03"); QDO (default build/qdo).
# Writes OUT/table.md (PSNR per scene, true PSF's decoder − design's) and OUT/table.csv.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-out/boundary}
QDO=${QDO:-build/qdo}
SHARED=${SHARED:-../shared}
DRAW_DIR=${DRAW_DIR:-out/fit_raw_draws_large/draw12}
RUN=${RUN:-out/fit_raw_sigma_p160/design}
SIGMAS=${SIGMAS:-"0.001 0.005 0.03"}
PY=python3
[ -f build/pystage/python-executable ] && PY=$(cat build/pystage/python-executable)
for f in "$DRAW_DIR/asbuilt/config.json" "$DRAW_DIR/asbuilt/design.h5" "$DRAW_DIR/true_psf/psf.h5" "$RUN/design.h5"; do
  [ -f "$f" ] || { echo "experiments_boundary: $f is missing (run scripts/experiments_fit_raw_draws.sh first)" >&2; exit 2; }
done
if [ -e "$OUT" ] && [ ! -f "$OUT/.experiments_boundary" ]; then
  echo "experiments_boundary: $OUT exists and was not made by this script" >&2
  exit 2
fi
mkdir -p "$OUT/scenes"
touch "$OUT/.experiments_boundary"
# The scenes' centre tiles, and the camera without noise, convolving circularly or linearly.
PYTHONPATH="$PWD/build/pystage" "$PY" - "$SHARED/data/hsi/cave" "$DRAW_DIR/asbuilt/config.json" "$OUT" <<'PY'
import glob, json, os, sys
import qdo
cave, cfg_path, out = sys.argv[1:]
cfg = json.load(open(cfg_path))
s = cfg["scene_size_px"]
for f in sorted(glob.glob(os.path.join(cave, "*.mat"))):
    c = qdo.read_cube(f, config=cfg_path)
    r0, c0 = (c.shape[1] - s) // 2, (c.shape[2] - s) // 2
    name = os.path.splitext(os.path.basename(f))[0]
    wl = [cfg["wavelength_start_nm"] + cfg["wavelength_step_nm"] * b for b in range(cfg["bands"])]
    qdo.write_cube(os.path.join(out, "scenes", name + ".h5"), c[:, r0:r0 + s, c0:c0 + s].copy(), wl)
for conv in ("circular", "linear"):
    d = dict(cfg, convolution=conv, bit_depth=16, read_noise_sigma=0.0, full_well_photons=0, black_level_dn=0.0)
    json.dump(d, open(os.path.join(out, f"camera_{conv}.json"), "w"), indent=1)
json.dump({"cfa": cfg.get("cfa", "rggb"), "bit_depth": 16, "black_level_dn": 0.0, "read_noise_sigma": 0.0, "full_well_photons": 0},
          open(os.path.join(out, "sensor.json"), "w"), indent=1)
PY
t0=$(date +%s)
for conv in circular linear; do
  for f in "$OUT"/scenes/*.h5; do
    s=$(basename "$f" .h5)
    cap=$OUT/captures/$conv/$s
    [ -f "$cap/raw.png" ] || { rm -rf "$cap"; mkdir -p "$(dirname "$cap")";
      "$QDO" simulate --config "$OUT/camera_$conv.json" --design "$DRAW_DIR/asbuilt/design.h5" --scene "$f" --raw --out "$cap" > "$cap.log" 2>&1; }
    for sg in $SIGMAS; do
      for dec in design true; do
        psf=()
        [ "$dec" = true ] && psf=(--psf "$DRAW_DIR/true_psf/psf.h5")
        for b in circular mirror linear; do
          d=$OUT/recon/$conv/$b/$sg/$dec/$s
          [ -f "$d/metrics.json" ] && continue
          rm -rf "$d"
          mkdir -p "$(dirname "$d")"
          "$QDO" reconstruct --run "$RUN" --capture "$cap/raw.png" --sensor "$OUT/sensor.json" --demosaic mhc --noise-sigma "$sg" "${psf[@]}" \
            --boundary "$b" --truth "$f" --out "$d" > "$d.log" 2>&1 || echo "$conv $b $sg $dec $s: reconstruct failed (see $d.log)"
        done
      done
    done
  done
done
echo "captures and reconstructions: $(( $(date +%s) - t0 )) s"
"$PY" - "$OUT" $SIGMAS <<'PY'
import glob, json, os, sys
out, sigmas = sys.argv[1], sys.argv[2:]
scenes = sorted(os.path.basename(f)[:-3] for f in glob.glob(os.path.join(out, "scenes", "*.h5")))
def psnr(conv, b, sg, dec, s):
    m = os.path.join(out, "recon", conv, b, sg, dec, s, "metrics.json")
    return json.load(open(m))["mean"]["psnr"] if os.path.exists(m) else None
L = ["PSNR (dB, whole 128 x 128 tile) of the design's decoder and of the decoder for the camera's true PSF; "
     "captures without noise; cell: design / true (true − design).", "",
     "| capture | boundary | σ | " + " | ".join(scenes) + " | mean true − design |", "|---|---|---:|" + "---|" * len(scenes) + "---:|"]
csv = ["capture,boundary,sigma,scene,design_psnr,true_psnr"]
for conv in ("circular", "linear"):
    for b in ("circular", "mirror", "linear"):
        for sg in sigmas:
            cells, diffs = [], []
            for s in scenes:
                a, t = psnr(conv, b, sg, "design", s), psnr(conv, b, sg, "true", s)
                if a is None or t is None:
                    cells.append("—")
                    continue
                cells.append(f"{a:.2f} / {t:.2f} ({t - a:+.2f})")
                diffs.append(t - a)
                csv.append(f"{conv},{b},{sg},{s},{a:.4f},{t:.4f}")
            mean = f"{sum(diffs) / len(diffs):+.2f}" if diffs else "—"
            L.append(f"| {conv} | {b} | {sg} | " + " | ".join(cells) + f" | {mean} |")
for name, text in (("table.md", "\n".join(L) + "\n"), ("table.csv", "\n".join(csv) + "\n")):
    tmp = os.path.join(out, name + ".tmp")
    open(tmp, "w").write(text)
    os.replace(tmp, os.path.join(out, name))
print("\n".join(L))
PY
