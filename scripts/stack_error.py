#!/usr/bin/env python3
"""Per-band difference of two PSF stacks (psf.h5 files with /psf_sensor, bands x S x S), e.g. a
calibrated stack (qdo calibrate) against the true one (qdo psf on the as-built camera).

For each band: the relative L2 of the unit-sum planes, ||a - b|| / ||b||, and the share of each
stack's light beyond --radius pixels of the window's centre (S/2, S/2). Prints a Markdown table,
then one line: the median and the worst band's relative L2.
Needs numpy and h5py. Exit 2 on bad input (naming the file and what is wrong), nothing written.

Usage: stack_error.py MEASURED.h5 TRUE.h5 [--radius 32]
"""
import argparse
import sys

import h5py
import numpy as np


def fail(msg):
    print(f"stack_error: {msg}", file=sys.stderr)
    sys.exit(2)


def load(path):
    try:
        with h5py.File(path, "r") as f:
            if "psf_sensor" not in f:
                fail(f"{path}: no /psf_sensor (a psf.h5 of qdo psf or qdo calibrate)")
            a = np.asarray(f["psf_sensor"][()], dtype=float)
    except OSError as e:
        fail(f"{path}: not a readable HDF5 file ({e})")
    if a.ndim != 3 or a.shape[1] != a.shape[2]:
        fail(f"{path}: /psf_sensor is {a.shape}, expected bands x S x S")
    if not np.all(np.isfinite(a)):
        fail(f"{path}: /psf_sensor holds non-finite values")
    return a


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("measured")
    ap.add_argument("true")
    ap.add_argument("--radius", type=float, default=32.0)
    a = ap.parse_args(argv)
    m, t = load(a.measured), load(a.true)
    if m.shape != t.shape:
        fail(f"{a.measured} is {m.shape}, {a.true} is {t.shape}: the stacks must have one shape")
    if not a.radius > 0:
        fail(f"--radius {a.radius}: a radius > 0 pixels")
    s = m.shape[1]
    yy, xx = np.mgrid[:s, :s]
    outer = np.hypot(yy - s // 2, xx - s // 2) >= a.radius
    print(f"| band | relative L2 | light beyond {a.radius:g} px, measured | light beyond {a.radius:g} px, true |")
    print("|---:|---:|---:|---:|")
    rels = []
    for b in range(m.shape[0]):
        ms, ts = m[b].sum(), t[b].sum()
        if not (ms > 0 and ts > 0):
            fail(f"band {b}: a plane with no light ({a.measured} sum {ms}, {a.true} sum {ts})")
        mb, tb = m[b] / ms, t[b] / ts
        rel = np.linalg.norm(mb - tb) / np.linalg.norm(tb)
        rels.append(rel)
        print(f"| {b} | {rel:.3f} | {mb[outer].sum():.3f} | {tb[outer].sum():.3f} |")
    worst = int(np.argmax(rels))
    print(f"\nrelative L2 over {len(rels)} bands: median {np.median(rels):.3f}, worst {rels[worst]:.3f} (band {worst})")


if __name__ == "__main__":
    main()
