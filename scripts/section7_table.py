#!/usr/bin/env python3
"""The table of scripts/experiments_section7.sh: OUT/recon/<row>/<scene>/metrics.json (qdo reconstruct
--truth) -> per-row means over the CAVE test scenes with a 95 % t interval, the fitted parameters against
the true ones (OUT/fitted/fit.json, OUT/asbuilt/truth.json) -> OUT/table.md, OUT/table.csv.
Usage: section7_table.py OUT"""
import csv
import json
import math
import os
import sys

T975 = {1: 12.706, 2: 4.303, 3: 3.182, 4: 2.776, 5: 2.571, 6: 2.447, 7: 2.365, 8: 2.306, 9: 2.262, 10: 2.228}
ROWS = [
    ("design", "the design as simulated (same sensor chain: RGGB 12-bit, noise, MHC demosaic)"),
    ("asbuilt_design_decoder", "the camera as built, the decoder made for the design"),
    ("asbuilt_measured", "the camera as built, the decoder adapted to the measured PSF (qdo calibrate)"),
    ("asbuilt_fitted", "the camera as built, the decoder adapted to the fitted model (qdo fit)"),
    ("asbuilt_oracle", "the camera as built, the decoder for its true PSF (a bound, not reachable in a lab)"),
]
METRICS = ["psnr", "ssim", "sam_rad"]


def mean_ci(v):
    n = len(v)
    m = sum(v) / n
    if n < 2:
        return m, float("nan")
    sd = math.sqrt(sum((x - m) ** 2 for x in v) / (n - 1))
    return m, T975.get(n - 1, 1.96) * sd / math.sqrt(n)


def main(out):
    rec = os.path.join(out, "recon")
    scenes = sorted(d for d in os.listdir(os.path.join(rec, "design")) if os.path.isdir(os.path.join(rec, "design", d)))
    lines = ["| camera / decoder | " + " | ".join(s.replace("_256", "") for s in scenes) + " | PSNR mean ± 95 % CI (dB) | SSIM | SAM (rad) |",
             "|---|" + "---:|" * (len(scenes) + 3)]
    rows_csv = []
    for key, label in ROWS:
        per = {m: [] for m in METRICS}
        for s in scenes:
            j = json.load(open(os.path.join(rec, key, s, "metrics.json")))["mean"]
            for m in METRICS:
                per[m].append(j[m])
            rows_csv.append({"row": key, "scene": s, **{m: j[m] for m in METRICS}})
        p, pci = mean_ci(per["psnr"])
        ss, _ = mean_ci(per["ssim"])
        sa, _ = mean_ci(per["sam_rad"])
        lines.append(f"| {label} | " + " | ".join(f"{v:.2f}" for v in per["psnr"]) + f" | {p:.2f} ± {pci:.2f} | {ss:.4f} | {sa:.4f} |")
    with open(os.path.join(out, "table.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=["row", "scene"] + METRICS)
        w.writeheader()
        w.writerows(rows_csv)

    truth = json.load(open(os.path.join(out, "asbuilt", "truth.json")))["fit_parameters"]
    plines = []
    for folder, title in (("fitted", "fit to the measured stack (qdo calibrate of the simulated sweep)"),
                          ("fitted_true", "diagnostic: fit to the true as-built stack (no calibration)")):
        fit = json.load(open(os.path.join(out, folder, "fit.json")))
        plines += ["", f"{title}: mean relative residual per band {sum(fit['residual_rel_fit']) / len(fit['residual_rel_fit']):.3f} "
                   f"(design {sum(fit['residual_rel_design']) / len(fit['residual_rel_design']):.3f})", "",
                   "| parameter | design | true (as built) | fitted ± 1 σ | fitted − true | in σ |", "|---|---:|---:|---:|---:|---:|"]
        for v in fit["parameters"]:
            name = v["name"]
            if name not in truth:
                plines.append(f"| {name} (px, registration) | {v['design']:.4g} | — | {v['value']:.4f} ± {v['sigma']:.4f} | — | — |")
                continue
            scale, unit = (1e9, "nm") if name.startswith("level") else (1e3, "mm") if name == "z" else (1e6, "µm")
            t = truth[name] * scale
            f = v["value"] * scale
            s = v["sigma"] * scale
            d = v["design"] * scale
            plines.append(f"| {name} ({unit}) | {d:.4f} | {t:.4f} | {f:.4f} ± {s:.4f} | {f - t:+.4f} | {abs(f - t) / s if s > 0 else float('inf'):.1f} |")
    text = "\n".join(lines) + "\n\n" + "\n".join(plines) + "\n"
    with open(os.path.join(out, "table.md"), "w") as f:
        f.write(text)
    print(text)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "out/section7")
