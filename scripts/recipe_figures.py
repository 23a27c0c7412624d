#!/usr/bin/env python3
"""Figures of scripts/experiments_recipe.sh (EXPERIMENTS.md "The release's recipe"), PNG and SVG.

  psnr_vs_levels   Table 1: PSNR against the level count per mode, mean and sd over seeds
  deviation        Table 2: the ring deviation against the level count (log scale), with the paper's
  network_psnr     the Res-UNet's table (OUT/network_qdo_items): PSNR per mode at 4 and 8 levels, seeds
                   and 95 % intervals; network_release_items_psnr the same of OUT/network
  training_<sweep> the training curves of every design of a sweep (loss per step, and the network's
                   MAE when it has one), one line per run, a moving median over 25 steps

Needs matplotlib (Debian: python3-matplotlib). Usage: python3 scripts/recipe_figures.py OUT [FIGDIR]
(default out/recipe, FIGDIR = OUT/figures).
"""
import csv
import glob
import json
import os
import statistics
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

PAPER_DEV = {"qdo": {2: 285.0, 4: 202.51, 8: 94.192, 16: 44.075, 32: 20.707},
             "qdo+a": {2: 188.01, 4: 18.911, 8: 1.822, 16: 1.965, 32: 0.763}}
COLORS = {"do": "tab:blue", "do-refit": "tab:red", "qdo": "tab:green", "qdo+a": "tab:orange",
          "do-finetune": "tab:purple", "full": "black"}


def cells(folder):
    out = {}
    for path in glob.glob(os.path.join(folder, "cells", "*", "metrics.json")):
        with open(path) as f:
            out[os.path.basename(os.path.dirname(path))] = json.load(f)
    return out


def save(fig, figdir, name):
    os.makedirs(figdir, exist_ok=True)
    for ext in ("png", "svg"):
        fig.savefig(os.path.join(figdir, f"{name}.{ext}"), dpi=120, bbox_inches="tight")
    plt.close(fig)


def by_mode_level(cs, key):
    table = {}
    for name, j in cs.items():
        if "_L" not in name:
            continue
        mode, rest = name.split("_L")
        level = int(rest.split("_")[0])
        value = j["mean"]["psnr_db"] if key == "psnr" else j.get("deviation_rings_nm")
        if value is not None:
            table.setdefault(mode, {}).setdefault(level, []).append(value)
    return table


def grid_figures(out, figdir, title):
    cs = cells(os.path.join(out, "grid"))
    if not cs:
        return
    psnr = by_mode_level(cs, "psnr")
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for k, mode in enumerate(["do", "do-refit", "qdo", "qdo+a"]):
        if mode not in psnr:
            continue
        levels = sorted(psnr[mode])
        x = [lv * (1 + 0.03 * (k - 1.5)) for lv in levels]
        m = [statistics.mean(psnr[mode][lv]) for lv in levels]
        sd = [statistics.stdev(psnr[mode][lv]) if len(psnr[mode][lv]) > 1 else 0 for lv in levels]
        ax.errorbar(x, m, yerr=sd, marker="o", capsize=3, color=COLORS[mode], label=mode.upper().replace("-REFIT", " refit"))
    full = [j["mean"]["psnr_db"] for n, j in cs.items() if n.startswith("full")]
    if full:
        ax.axhline(statistics.mean(full), color="black", ls="--", lw=1, label="full precision")
    ax.set_xscale("log", base=2)
    ax.set_xticks([2, 4, 8, 16, 32], ["2", "4", "8", "16", "32"])
    ax.set_xlabel("quantization levels L")
    ax.set_ylabel("PSNR [dB] (CAVE test patches)")
    ax.set_title(title + ": Table 1, mean ± sd over seeds")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    save(fig, figdir, "psnr_vs_levels")

    dev = by_mode_level(cs, "dev")
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for mode in ["do", "qdo", "qdo+a"]:
        if mode not in dev:
            continue
        levels = sorted(dev[mode])
        ax.plot(levels, [statistics.mean(dev[mode][lv]) for lv in levels], marker="o", color=COLORS[mode],
                label=mode.upper() + " (here)")
    for mode, d in PAPER_DEV.items():
        ax.plot(sorted(d), [d[lv] for lv in sorted(d)], marker="x", ls=":", color=COLORS[mode], label=mode.upper() + " (paper)")
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xticks([2, 4, 8, 16, 32], ["2", "4", "8", "16", "32"])
    ax.set_xlabel("quantization levels L")
    ax.set_ylabel("mean |H_q − H_f| over the rings [nm]")
    ax.set_title(title + ": Table 2, quantization deviation")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    save(fig, figdir, "deviation")


def moving_median(v, w=25):
    out = []
    for i in range(len(v)):
        win = [x for x in v[max(0, i - w + 1):i + 1] if x == x]
        out.append(statistics.median(win) if win else float("nan"))
    return out


def training_figure(folder, figdir, name, title):
    runs = sorted(glob.glob(os.path.join(folder, "runs", "*", "log.csv")))
    if not runs:
        return
    network = False
    fig, ax = plt.subplots(figsize=(7.2, 4.4))
    for path in runs:
        with open(path) as f:
            rows = list(csv.DictReader(f))
        if not rows:
            continue
        key = "mae" if "mae" in rows[0] and rows[0]["mae"] else "loss"
        network = network or key == "mae"
        steps = [int(r["step"]) for r in rows]
        vals = [float(r[key]) if r[key] else float("nan") for r in rows]
        run = os.path.basename(os.path.dirname(path))
        mode = run.split("_")[0]
        ax.plot(steps, moving_median(vals), lw=1, color=COLORS.get(mode, "grey"), alpha=0.8, label=run)
    ax.set_xlabel("optimiser step")
    ax.set_ylabel("training MAE (network)" if network else "training loss (Wiener expected error + β L_aq)")
    ax.set_yscale("log")
    ax.set_title(title + " (moving median over 25 steps)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=6, ncol=3)
    save(fig, figdir, name)


def network_figure(out, figdir, sweep, name, title):
    """The Res-UNet under the release recipe: PSNR per mode at each level count, one dot per seed,
    the mean with its 95 % t interval; full precision (DO's design unquantized) as a band."""
    cs = cells(os.path.join(out, sweep))
    if not cs:
        return
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from qdo_stats import mean_ci
    tag = "_resunet-depth4-root16"
    levels = sorted({int(n.split("_L")[1].split("_")[0]) for n in cs if "_L" in n})
    modes = ["do", "do-finetune", "qdo", "qdo+a"]
    fig, ax = plt.subplots(figsize=(7.2, 4.4))
    full = [c["mean"]["psnr_db"] for n, c in cs.items() if n.startswith("full" + tag)]
    if full:
        m, hw = mean_ci(full)
        ax.axhspan(m - (hw if hw == hw else 0), m + (hw if hw == hw else 0), color="black", alpha=0.08)
        ax.axhline(m, color="black", lw=1, ls="--", label=f"full precision ({len(full)} seeds)")
    for k, mode in enumerate(modes):
        xs, ms, errs = [], [], []
        for i, L in enumerate(levels):
            v = [c["mean"]["psnr_db"] for n, c in cs.items() if n.startswith(f"{mode}_L{L}{tag}_s")]
            if not v:
                continue
            x = i + (k - 1.5) * 0.15
            ax.scatter([x] * len(v), v, s=12, color=COLORS[mode], alpha=0.5)
            m, hw = mean_ci(v)
            xs.append(x)
            ms.append(m)
            errs.append(hw if hw == hw else 0)
        if xs:
            ax.errorbar(xs, ms, yerr=errs, fmt="o", color=COLORS[mode], capsize=3, label=f"{mode.upper()} (mean, 95 % interval)")
    ax.set_xticks(range(len(levels)))
    ax.set_xticklabels([f"{L} levels" for L in levels])
    ax.set_ylabel("PSNR on the CAVE test crops (dB)")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    save(fig, figdir, name)


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else "out/recipe"
    figdir = sys.argv[2] if len(sys.argv) > 2 else os.path.join(out, "figures")
    grid_figures(out, figdir, "Release recipe, Wiener decoder, small preset")
    network_figure(out, figdir, "network_qdo_items", "network_psnr",
                   "Res-UNet (depth 4, root 16), release recipe with qdo's network items, small preset, 300 steps")
    network_figure(out, figdir, "network", "network_release_items_psnr",
                   "Res-UNet (depth 4, root 16), every item the release's, small preset, 300 steps")
    for sweep in ["grid", "network_qdo_items", "network"]:
        training_figure(os.path.join(out, sweep), figdir, f"training_{sweep}",
                        f"Training curves, release recipe ({sweep})")
    print(f"recipe_figures: wrote {figdir}")


if __name__ == "__main__":
    main()
