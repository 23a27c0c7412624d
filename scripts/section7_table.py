#!/usr/bin/env python3
"""The tables of scripts/experiments_section7.sh -> OUT/table.md, OUT/table.csv:
1. reconstruction: OUT/recon/<sigma>/<row>/<scene>/metrics.json (qdo reconstruct --truth), per row the
   per-scene PSNR, the mean over the CAVE test scenes with a 95 % t interval, SSIM and SAM means, for
   both noise sigmas the decoder assumed (run: the run's; model: the sensor's noise at the capture's level);
2. parameters: OUT/<scenario>/fitted/fit.json (and fitted_true, the diagnostic) against
   OUT/<scenario>/asbuilt/truth.json.
Usage: section7_table.py OUT [SIGMA ...]   (the sigma folders of OUT/recon, default: run model)"""
import csv
import json
import math
import os
import sys

from qdo_stats import mean_ci  # noqa: E402 (scripts/qdo_stats.py)
SCENARIOS = [("depth", "depth errors + offset + z (inside qdo fit's model)"),
             ("full", "the same + per-mask overlay (as qdo tolerance draws it; outside the model)")]
ROWS = [("design", "the design as simulated (RGGB 12-bit, noise, MHC)")]
for sc, _ in SCENARIOS:
    ROWS += [(f"{sc}/design_decoder", f"{sc}: as built, decoder made for the design"),
             (f"{sc}/measured", f"{sc}: as built, decoder adapted to the measured PSF"),
             (f"{sc}/fitted", f"{sc}: as built, decoder adapted to the fitted model"),
             (f"{sc}/fitted_raw", f"{sc}: as built, decoder adapted to the model fitted to the raw frames"),
             (f"{sc}/oracle", f"{sc}: as built, decoder for its true PSF (bound)")]
METRICS = ["psnr", "ssim", "sam_rad"]


def recon_table(out, rows_csv):
    rec = os.path.join(out, "recon")
    base = os.path.join(rec, "run", "design")
    scenes = sorted(d for d in os.listdir(base) if os.path.isdir(os.path.join(base, d)))
    names = [s.replace("_256", "") for s in scenes]
    lines = ["| camera / decoder | σ assumed | " + " | ".join(names) + " | PSNR mean ± 95 % CI (dB) | SSIM | SAM (rad) |",
             "|---|---|" + "---:|" * (len(scenes) + 3)]
    for key, label in ROWS:
        for sig in SIGMAS:
            sig_label = {"run": "run's 1e-3", "model": "noise model"}.get(sig, sig)
            per = {m: [] for m in METRICS}
            for s in scenes:
                j = json.load(open(os.path.join(rec, sig, key, s, "metrics.json")))["mean"]
                for m in METRICS:
                    per[m].append(j[m])
                rows_csv.append({"row": key, "sigma": sig, "scene": s, **{m: j[m] for m in METRICS}})
            p, pci = mean_ci(per["psnr"])
            lines.append(f"| {label} | {sig_label} | " + " | ".join(f"{v:.2f}" for v in per["psnr"]) +
                         f" | {p:.2f} ± {pci:.2f} | {mean_ci(per['ssim'])[0]:.4f} | {mean_ci(per['sam_rad'])[0]:.4f} |")
    return lines


def parameter_table(out, sc, folder, title):
    truth = json.load(open(os.path.join(out, sc, "asbuilt", "truth.json")))["fit_parameters"]
    fit = json.load(open(os.path.join(out, sc, folder, "fit.json")))
    res_fit = sum(fit["residual_rel_fit"]) / len(fit["residual_rel_fit"])
    res_des = sum(fit["residual_rel_design"]) / len(fit["residual_rel_design"])
    lines = ["", f"**{sc}, {title}**: mean relative residual per band {res_fit:.3f} (design: {res_des:.3f}), "
             f"{fit['iterations']} iterations", "",
             "| parameter | design | true | fitted ± 1 σ | fitted − true | in σ |", "|---|---:|---:|---:|---:|---:|"]
    for v in fit["parameters"]:
        name = v["name"]
        if name not in truth:
            lines.append(f"| {name} (px, registration) | {v['design']:.4g} | — | {v['value']:.4f} ± {v['sigma']:.4f} | — | — |")
            continue
        scale, unit = (1e9, "nm") if name.startswith("level") else (1e3, "mm") if name == "z" else (1e6, "µm")
        t, f, s, d = truth[name] * scale, v["value"] * scale, v["sigma"] * scale, v["design"] * scale
        ins = f"{abs(f - t) / s:.1f}" if s > 1e-9 * max(abs(t), 1e-12) else "— (σ ≈ 0: exact fit)"
        lines.append(f"| {name} ({unit}) | {d:.4f} | {t:.4f} | {f:.4f} ± {s:.4f} | {f - t:+.4f} | {ins} |")
    return lines


SIGMAS = ["run", "model"]


def main(out):
    rows_csv = []
    lines = recon_table(out, rows_csv)
    for sc, label in SCENARIOS:
        lines += ["", f"### {sc}: {label}"]
        lines += parameter_table(out, sc, "fitted", "fit to the measured stack")
        lines += parameter_table(out, sc, "fitted_true", "diagnostic: fit to the true as-built stack (no calibration)")
    with open(os.path.join(out, "table.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=["row", "sigma", "scene"] + METRICS)
        w.writeheader()
        w.writerows(rows_csv)
    text = "\n".join(lines) + "\n"
    with open(os.path.join(out, "table.md"), "w") as f:
        f.write(text)
    print(text)


if __name__ == "__main__":
    if len(sys.argv) > 2:
        SIGMAS[:] = sys.argv[2:]
    main(sys.argv[1] if len(sys.argv) > 1 else "out/section7")
