#!/usr/bin/env python3
"""Summarise scripts/experiments_points.sh runs over seeds: for each evaluated distance the
mismatch PSNR (decoder for the nominal PSF) of the design trained at one point and of the one
trained over a range, mean over seeds with min..max, and the paired difference (range - one point)
per seed; then the depth of field and the valid field of view of each.
Usage: points_seeds_table.py OUT_s0 OUT_s1 ...   (each holding eval_design_1m/ and eval_design_range/)"""
import json
import os
import sys


def load(d, name):
    with open(os.path.join(d, "eval_" + name, "points.json")) as f:
        return json.load(f)


def stats(v):
    return sum(v) / len(v), min(v), max(v)


def fmt(t, n=2):
    m, lo, hi = t
    return f"{m:.{n}f} ({lo:.{n}f}..{hi:.{n}f})"


def main(dirs):
    runs = [(load(d, "design_1m"), load(d, "design_range")) for d in dirs]
    dist = [r["distance_m"] for r in runs[0][0]["distances"]]
    print(f"{len(dirs)} seeds ({', '.join(dirs)}); mismatch PSNR dB, mean over seeds (min..max); "
          "each seed's value is the mean over the test scenes\n")
    print("| distance m | trained at 1 m | trained over the range | range - 1 m (paired) |")
    print("|---:|---:|---:|---:|")
    for i, d in enumerate(dist):
        a = [r[0]["distances"][i]["mismatch"]["psnr_db"]["mean"] for r in runs]
        b = [r[1]["distances"][i]["mismatch"]["psnr_db"]["mean"] for r in runs]
        print(f"| {d} | {fmt(stats(a))} | {fmt(stats(b))} | {fmt(stats([y - x for x, y in zip(a, b)]))} |")
    print("\n| design | depth of field near end m (per seed) | valid FOV half-angle deg (per seed) |")
    print("|---|---|---|")
    for k, label in ((0, "trained at 1 m"), (1, "trained over the range")):
        near = ", ".join(("<=" if r[k]["depth_of_field"]["near_open"] else "") + f"{r[k]['depth_of_field']['near_m']:.3g}"
                         for r in runs)
        fov = ", ".join(f"{r[k]['field']['fov_half_deg']:.3f}" for r in runs)
        print(f"| {label} | {near} | {fov} |")


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1:])
