#!/usr/bin/env python3
"""A design and its configuration on a DOE grid K times finer (K odd), for `qdo psf`.

Each fine sample takes the height of the DOE pixel it lies in: qdo's grids are centred on a
sample (sample i at (i - n/2) pitch), so with K odd every fine sample lies inside exactly one
DOE pixel (with K even some would sit on a pixel boundary). The configuration gets n K samples
at pitch / K, the aperture radius written out (the default, (n/2 - 1) pitch, would otherwise
follow the new grid), and a padding large enough for the transfer function to be sampled at the
longest wavelength, M (pitch / K)^2 >= lambda z (REFERENCE.md section 1), with M = n K + 2
padding rounded up to a multiple of 32; never less than K times the old padding. With --band-step
B only every B-th band is kept (the finer field of all bands may not fit a device's largest
allocation). Needs numpy and h5py. Writes OUT_CONFIG and OUT_DESIGN under temporary names, then
renames them, so a failed run leaves neither half-written.

Usage: supersample_design.py --config CONFIG.json --design DESIGN.h5 --k 3 [--band-step 1]
                             --out-config OUT.json --out-design OUT.h5
"""
import argparse
import json
import math
import os
import sys
import tempfile

import h5py
import numpy as np


def fail(msg):
    print(f"supersample_design.py: {msg}", file=sys.stderr)
    sys.exit(2)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--config", required=True)
    ap.add_argument("--design", required=True)
    ap.add_argument("--k", type=int, required=True)
    ap.add_argument("--band-step", type=int, default=1)
    ap.add_argument("--out-config", required=True)
    ap.add_argument("--out-design", required=True)
    a = ap.parse_args()
    k = a.k
    if k < 1 or k > 15 or k % 2 == 0:
        fail(f"--k {k}: an odd integer in [1, 15] (an even factor puts fine samples on pixel boundaries)")
    if a.band_step < 1:
        fail(f"--band-step {a.band_step}: an integer >= 1")
    with open(a.config) as f:
        cfg = json.load(f)
    for key in ("n", "pitch_m", "padding_px", "sensor_distance_m", "wavelength_start_nm", "wavelength_step_nm", "bands"):
        if key not in cfg:
            fail(f"--config {a.config}: no '{key}' (write the whole configuration: qdo config --preset NAME)")
    n, pitch = int(cfg["n"]), float(cfg["pitch_m"])
    with h5py.File(a.design, "r") as f:
        if "height_m" not in f:
            fail(f"--design {a.design}: no /height_m")
        h = f["height_m"][()]
    if h.shape != (n, n):
        fail(f"--design {a.design}: height_m is {h.shape}, the configuration's n is {n}")
    if not np.all(np.isfinite(h)):
        fail(f"--design {a.design}: height_m holds values that are not finite")

    nk = n * k
    j = np.arange(nk)
    # Fine sample j is centred at (j - nk/2) pitch/k; DOE pixel i covers ((i - n/2) -+ 1/2) pitch.
    i = (j - nk // 2 + (k - 1) // 2) // k + n // 2
    outside = (i < 0) | (i >= n)
    i = np.clip(i, 0, n - 1)
    fine = h[np.ix_(i, i)].copy()
    fine[outside, :] = 0.0
    fine[:, outside] = 0.0

    bands = int(cfg["bands"])
    kept = list(range(0, bands, a.band_step))
    lam_max = (float(cfg["wavelength_start_nm"]) + float(cfg["wavelength_step_nm"]) * kept[-1]) * 1e-9
    fine_pitch = pitch / k
    m_needed = lam_max * float(cfg["sensor_distance_m"]) / fine_pitch ** 2
    m = max(nk + 2 * k * int(cfg["padding_px"]), math.ceil(m_needed))
    m = (m + 31) // 32 * 32
    if (m - nk) % 2:
        m += 32
    out = dict(cfg)
    radius = float(cfg.get("aperture_radius_m", 0.0)) or (n / 2 - 1) * pitch
    out.update(n=nk, pitch_m=fine_pitch, padding_px=(m - nk) // 2, aperture_radius_m=radius,
               wavelength_start_nm=float(cfg["wavelength_start_nm"]),
               wavelength_step_nm=float(cfg["wavelength_step_nm"]) * a.band_step, bands=len(kept))
    out.pop("preset", None)

    for path in (a.out_config, a.out_design):
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    tmp_cfg = tempfile.NamedTemporaryFile("w", dir=os.path.dirname(os.path.abspath(a.out_config)), delete=False,
                                          prefix=".supersample.", suffix=".json")
    tmp_h5 = tempfile.NamedTemporaryFile(dir=os.path.dirname(os.path.abspath(a.out_design)), delete=False,
                                         prefix=".supersample.", suffix=".h5")
    tmp_h5.close()
    try:
        json.dump(out, tmp_cfg, indent=1)
        tmp_cfg.close()
        with h5py.File(tmp_h5.name, "w") as f:
            d = f.create_dataset("height_m", data=fine)
            d.attrs["pitch_m"] = fine_pitch
            d.attrs["units"] = np.bytes_("m")  # a fixed-length string, as qdo writes and reads it
            f.attrs["made_by"] = np.bytes_(f"supersample_design.py --k {k} from {os.path.abspath(a.design)}")
        os.replace(tmp_cfg.name, a.out_config)
        os.replace(tmp_h5.name, a.out_design)
    except BaseException:
        for p in (tmp_cfg.name, tmp_h5.name):
            if os.path.exists(p):
                os.remove(p)
        raise
    print(f"n {nk}, pitch {fine_pitch * 1e6:.4g} um, padding {(m - nk) // 2} px (window {m} samples), "
          f"{len(kept)} bands, aperture radius {radius * 1e6:.4g} um")


if __name__ == "__main__":
    main()
