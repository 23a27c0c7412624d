#!/usr/bin/env python3
"""Compare PSF stacks band by band: each stack against the reference (the first), as qdo writes them
(/psf_sensor bands x S x S, /wavelengths_nm). Prints a Markdown table: per band (every STEP-th and
the last) the relative L2 difference |A - R| / |R|, the correlation and the peak ratio max A / max R,
and the mean relative L2 over all bands.

Usage: compare_psf_stacks.py REFERENCE.h5 NAME=A.h5 [NAME=B.h5 ...] [--step 5]
"""
import argparse
import sys

import h5py
import numpy as np


def read(path):
    with h5py.File(path, "r") as f:
        return f["psf_sensor"][()], f["wavelengths_nm"][()]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("reference")
    ap.add_argument("stacks", nargs="+", help="NAME=FILE.h5")
    ap.add_argument("--step", type=int, default=5)
    a = ap.parse_args()
    ref, wl = read(a.reference)
    named = []
    for item in a.stacks:
        if "=" not in item:
            sys.exit(f"compare_psf_stacks: {item!r}: NAME=FILE.h5")
        name, path = item.split("=", 1)
        st, w = read(path)
        if st.shape != ref.shape or not np.allclose(w, wl):
            sys.exit(f"compare_psf_stacks: {path}: {st.shape} over {w[0]}..{w[-1]} nm, the reference is {ref.shape} over "
                     f"{wl[0]}..{wl[-1]} nm")
        named.append((name, st))
    bands = sorted(set(list(range(0, ref.shape[0], a.step)) + [ref.shape[0] - 1]))
    print("| stack | " + " | ".join(f"{wl[b]:.0f} nm: rel L2 / corr / peak" for b in bands) + " | mean rel L2 |")
    print("|---|" + "---:|" * (len(bands) + 1))
    for name, st in named:
        rel = [np.linalg.norm(st[b] - ref[b]) / np.linalg.norm(ref[b]) for b in range(ref.shape[0])]
        cells = []
        for b in bands:
            corr = np.corrcoef(st[b].ravel(), ref[b].ravel())[0, 1]
            cells.append(f"{rel[b]:.3f} / {corr:.4f} / {st[b].max() / ref[b].max():.2f}")
        print(f"| {name} | " + " | ".join(cells) + f" | {np.mean(rel):.3f} |")


if __name__ == "__main__":
    main()
