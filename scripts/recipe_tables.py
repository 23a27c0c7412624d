#!/usr/bin/env python3
"""Tables of scripts/experiments_recipe.sh (EXPERIMENTS.md "The release's recipe").

Reads the sweeps' cell metrics (cells/<mode>_L<levels>_s<seed>/metrics.json, as qdo eval writes
them) and prints Markdown:
  - the sums of learning rates of the release and of the run's schedule;
  - the paper's comparisons on the grid, paired by seed and test scene: QDO+A - DO, QDO - DO,
    QDO+A - QDO, QDO+A - DO-refit per level count (mean PSNR difference and its 95 % t interval
    over seeds, each seed's difference averaged over the test scenes);
  - the ablation: each item switched back to qdo's, against the release recipe, for QDO and QDO+A
    at 4 levels (PSNR and ring deviation, paired the same way; the baseline: the grid's 4-level cells);
  - the Res-UNet tables: OUT/network (every item the release's) and OUT/network_qdo_items (the same
    sweep with the network's four items qdo's), the paired effect of those four items, and DO with
    one of them set back at a time (OUT/network_ablation_<item>).
Usage: python3 scripts/recipe_tables.py OUT [EPOCHS STEPS_PER_EPOCH]   (default out/recipe 50 36)
"""
import glob
import json
import math
import os
import sys

from qdo_stats import mean_ci  # noqa: E402 (scripts/qdo_stats.py)


def lr_sum(t_from, t_to, lr=0.01, rate=0.8, period=500.0):
    """Sum of lr * rate^(t / period) over steps t_from .. t_to - 1 (continuous decay)."""
    return sum(lr * rate ** (t / period) for t in range(int(t_from), int(t_to)))


def cells(folder):
    out = {}
    for path in glob.glob(os.path.join(folder, "cells", "*", "metrics.json")):
        name = os.path.basename(os.path.dirname(path))
        with open(path) as f:
            j = json.load(f)
        out[name] = j
    return out


def scene_psnr(cell):
    return {s["scene"]: s["psnr_db"] for s in cell.get("per_scene", [])}


def paired(a_cells, a_name, b_cells, b_name, seeds):
    """Per seed: mean over test scenes of PSNR(a) - PSNR(b); then mean and 95 % half-width."""
    diffs = []
    for s in seeds:
        a, b = a_cells.get(a_name.format(s=s)), b_cells.get(b_name.format(s=s))
        if a is None or b is None:
            continue
        pa, pb = scene_psnr(a), scene_psnr(b)
        common = sorted(set(pa) & set(pb))
        if not common:
            continue
        diffs.append(sum(pa[k] - pb[k] for k in common) / len(common))
    if not diffs:
        return None
    m, hw = mean_ci(diffs)
    return m, hw, len(diffs)


def fmt(r):
    if r is None:
        return "–"
    m, hw, n = r
    return f"{m:+.2f} [{m - hw:+.2f}, {m + hw:+.2f}]" if n > 1 else f"{m:+.2f} (1 seed)"


def seeds_of(cs):
    return sorted({int(n.rsplit("_s", 1)[1]) for n in cs if "_s" in n})


def network_table(net, tag, title):
    """The Res-UNet table of one sweep's cells: PSNR per mode and level count, paired differences."""
    seeds = seeds_of(net)
    levels = sorted({int(n.split("_L")[1].split("_")[0]) for n in net if "_L" in n})
    print(f"### The Res-UNet under the release recipe, {title} (PSNR dB, mean [95 % interval] over the seeds that finished)\n")
    print("| levels | DO | DO-finetune | QDO | QDO+A | QDO+A - DO | QDO - DO | QDO+A - QDO | QDO+A - DO-finetune | ring dev. QDO / QDO+A (nm) |")
    print("|---|---|---|---|---|---|---|---|---|---|")

    def mean_of(name):
        v = [net[name.format(s=s)]["mean"]["psnr_db"] for s in seeds if name.format(s=s) in net]
        if not v:
            return "–"
        m, hw = mean_ci(v)
        return f"{m:.2f} [{m - hw:.2f}, {m + hw:.2f}] ({len(v)})" if len(v) > 1 else f"{m:.2f} (1 seed)"

    def ring_dev(name):
        v = [net[name.format(s=s)].get("deviation_rings_nm") for s in seeds if name.format(s=s) in net]
        v = [x for x in v if x is not None]
        return f"{sum(v) / len(v):.1f}" if v else "–"

    full = mean_of("full" + tag + "_s{s}")
    for L in levels:
        n = {m: f"{m}_L{L}{tag}_s{{s}}" for m in ["do", "do-finetune", "qdo", "qdo+a"]}
        row = [mean_of(n["do"]), mean_of(n["do-finetune"]), mean_of(n["qdo"]), mean_of(n["qdo+a"]),
               fmt(paired(net, n["qdo+a"], net, n["do"], seeds)), fmt(paired(net, n["qdo"], net, n["do"], seeds)),
               fmt(paired(net, n["qdo+a"], net, n["qdo"], seeds)), fmt(paired(net, n["qdo+a"], net, n["do-finetune"], seeds)),
               ring_dev(n["qdo"]) + " / " + ring_dev(n["qdo+a"])]
        print(f"| {L} | " + " | ".join(row) + " |")
    print(f"\nFull precision (DO's design unquantized): {full}.\n")


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else "out/recipe"
    epochs = int(sys.argv[2]) if len(sys.argv) > 2 else 50
    spe = int(sys.argv[3]) if len(sys.argv) > 3 else 36
    total, t0, t1 = epochs * spe, 0.1 * epochs * spe, 0.8 * epochs * spe
    print("### Sums of learning rates (optics, 0.01 x 0.8^(t/500))\n")
    print("| schedule | steps | alpha window (steps) | sum while alpha blends | sum in all |")
    print("|---|---|---|---|---|")
    print(f"| release (50 x 418) | 20900 | 2090-16720 | {lr_sum(2090, 16720):.2f} | {lr_sum(0, 20900):.2f} |")
    print(f"| here ({epochs} x {spe}) | {total} | {t0:.0f}-{t1:.0f} | {lr_sum(t0, t1):.2f} | {lr_sum(0, total):.2f} |")
    qsum = sum(0.01 * 0.8 ** (t // 8) for t in range(160))
    print(f"| qdo's earlier tables (20 x 8, x0.8 per epoch) | 160 | 16-128 | "
          f"{sum(0.01 * 0.8 ** (t // 8) for t in range(16, 128)):.2f} | {qsum:.2f} |\n")

    grid = cells(os.path.join(out, "grid"))
    if grid:
        seeds = seeds_of(grid)
        levels = sorted({int(n.split("_L")[1].split("_")[0]) for n in grid if "_L" in n})
        print(f"### Paired PSNR differences on the grid (dB, mean [95 % interval] over {len(seeds)} seeds)\n")
        print("| levels | QDO+A - DO | QDO - DO | QDO+A - QDO | QDO+A - DO-refit |")
        print("|---|---|---|---|---|")
        for L in levels:
            row = [paired(grid, f"qdo+a_L{L}_s{{s}}", grid, f"do_L{L}_s{{s}}", seeds),
                   paired(grid, f"qdo_L{L}_s{{s}}", grid, f"do_L{L}_s{{s}}", seeds),
                   paired(grid, f"qdo+a_L{L}_s{{s}}", grid, f"qdo_L{L}_s{{s}}", seeds),
                   paired(grid, f"qdo+a_L{L}_s{{s}}", grid, f"do-refit_L{L}_s{{s}}", seeds)]
            print(f"| {L} | " + " | ".join(fmt(r) for r in row) + " |")
        print()

    tag = "_resunet-depth4-root16"
    net = cells(os.path.join(out, "network"))
    old = cells(os.path.join(out, "network_qdo_items"))
    for folder_cells, title in [(net, "every item the release's, the network's four included"),
                                (old, "the network's four items qdo's (--noise-at rgb --patches random --batch-norm torch "
                                      "--final-init he)")]:
        if folder_cells:
            network_table(folder_cells, tag, title)

    # The network's recipe items (batch norm, last initialiser, noise on the bands, fixed patches)
    # against the same sweep with qdo's, paired by seed and test scene.
    if net and old:
        seeds = seeds_of(net)
        levels = sorted({int(n.split("_L")[1].split("_")[0]) for n in net if "_L" in n})
        print("### The network's four recipe items: release's minus qdo's (PSNR dB, paired by seed, mean [95 % interval])\n")
        print("| levels | DO | DO-finetune | QDO | QDO+A |")
        print("|---|---|---|---|---|")
        for L in levels:
            row = [fmt(paired(net, f"{m}_L{L}{tag}_s{{s}}", old, f"{m}_L{L}{tag}_s{{s}}", seeds))
                   for m in ["do", "do-finetune", "qdo", "qdo+a"]]
            print(f"| {L} | " + " | ".join(row) + " |")
        full_d = fmt(paired(net, f"full{tag}_s{{s}}", old, f"full{tag}_s{{s}}", seeds))
        print(f"\nFull precision (DO's design unquantized): {full_d}.\n")

    # DO with one of the network's four items set back to qdo's (OUT/network_ablation_<item>),
    # against DO with all of the release's (OUT/network), 4 levels, paired by seed.
    net_abl = sorted(glob.glob(os.path.join(out, "network_ablation_*")))
    if net and net_abl:
        print("### The network's items one at a time: DO at 4 levels with one item qdo's, minus DO with all the "
              "release's (PSNR dB, paired by seed)\n")
        print("| item set back to qdo's | seeds | PSNR difference | DO (that item qdo's) |")
        print("|---|---|---|---|")
        name = f"do_L4{tag}_s{{s}}"
        for folder in net_abl:
            cs = cells(folder)
            sd = [x for x in seeds_of(cs) if name.format(s=x) in net]
            if not sd:
                continue
            v = [cs[name.format(s=x)]["mean"]["psnr_db"] for x in sd]
            print(f"| {os.path.basename(folder)[len('network_ablation_'):]} | {len(sd)} | "
                  f"{fmt(paired(cs, name, net, name, sd))} | {sum(v) / len(v):.2f} |")
        print()

    ablations = [os.path.join(out, "grid")] + sorted(glob.glob(os.path.join(out, "ablation_*")))
    base = grid  # the release recipe's 4-level cells
    if base and ablations:
        seeds = seeds_of(base)
        print(f"### Ablation at 4 levels: one item set back to qdo's (PSNR difference to the release recipe, dB, "
              f"mean [95 % interval] over {len(seeds)} seeds; ring deviation, nm, mean over seeds)\n")
        print("| item switched back | QDO: PSNR diff | QDO+A: PSNR diff | QDO+A - QDO | QDO ring dev. | QDO+A ring dev. |")
        print("|---|---|---|---|---|---|")
        for folder in ablations:
            if not os.path.isdir(folder):
                continue
            name = "release" if folder == ablations[0] else os.path.basename(folder)[len("ablation_"):]
            cs = cells(folder)
            if not cs:
                continue

            def dev(mode):
                v = [cs[f"{mode}_L4_s{s}"].get("deviation_rings_nm") for s in seeds if f"{mode}_L4_s{s}" in cs]
                v = [x for x in v if x is not None]
                return f"{sum(v) / len(v):.1f}" if v else "–"

            same = name == "release"
            r_q = None if same else paired(cs, "qdo_L4_s{s}", base, "qdo_L4_s{s}", seeds)
            r_a = None if same else paired(cs, "qdo+a_L4_s{s}", base, "qdo+a_L4_s{s}", seeds)
            r_aq = paired(cs, "qdo+a_L4_s{s}", cs, "qdo_L4_s{s}", seeds)
            label = "(none: the release recipe)" if same else name
            print(f"| {label} | {fmt(r_q)} | {fmt(r_a)} | {fmt(r_aq)} | {dev('qdo')} | {dev('qdo+a')} |")
        print()


if __name__ == "__main__":
    main()
