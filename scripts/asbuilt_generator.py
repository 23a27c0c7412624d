#!/usr/bin/env python3
"""A second generator of as-built cameras, independent of qdo's simulator (numpy, float64).

It makes the sensor-grid PSF stack of a quantized design as fabricated, by another discretisation
than qdo's, so that `qdo fit` meets errors its model does not have:

- the relief on a grid FINE times finer than the DOE's (default 4: 1 um at a 4 um pitch), each fine
  sample taking the level of the DOE pixel under it after the relief's lateral offset (an exact move
  of a piecewise-constant relief, no height between two levels; qdo's model blends heights);
- each level's realised height drawn within +-ETCH nm of its design value (inside qdo fit's model);
- the aperture a continuous circle of the configuration's radius on the fine grid (qdo's: whole
  DOE pixels);
- the point source a spherical wave from the configured distance, exp(+ik(sqrt(r^2 + d^2) - d));
- Fresnel propagation by the impulse response exp(i pi r^2 / (lambda z)), a linear convolution on
  the fine grid (qdo: the transfer function on the DOE grid with N/4 padding, whose window wraps);
- the sensor's pixel grid displaced by (GX, GY) um against the axis (whole fine samples), each
  sensor pixel the sum of the fine intensity samples inside it (qdo: area integration of the
  DOE-grid PSF), each band normalised to unit sum over the S x S window.

Sign conventions are REFERENCE.md's (Goodman's), as qdo's. Needs numpy and h5py only. Writes OUT/psf.h5 (/psf_sensor bands x S
x S, /wavelengths_nm: the layout qdo reads as a PSF stack), OUT/truth.json (the true values in qdo
fit's names: levelL = realised L - realised 0 + design 0 in metres, z, dx, dy in metres, and the
grid displacement in sensor px) and OUT/generator.json (every input). The folder is written under a
temporary name and renamed, so a killed run leaves no half-written OUT.

Usage: asbuilt_generator.py --config CONFIG.json --design DESIGN.h5 --seed S --out OUT
       [--etch-error-nm 20] [--offset-um DX,DY] [--z-error-um DZ] [--grid-um GX,GY] [--fine 4]
       [--sellmeier ../shared/data/spectral/sellmeier_coefficients.csv]
"""
import argparse
import json
import os
import shutil
import sys
import tempfile

import h5py
import numpy as np


def fail(msg):
    sys.exit(f"asbuilt_generator: {msg}")


def pair(text, name):
    try:
        a, b = (float(v) for v in text.split(","))
    except ValueError:
        fail(f"--{name} {text!r}: two numbers X,Y")
    return a, b


def fast_len(n):
    """The smallest 2^a 3^b 5^c >= n (a size numpy's FFT handles fast)."""
    best = 1 << (n - 1).bit_length()
    p5 = 1
    while p5 < best:
        p35 = p5
        while p35 < best:
            m = p35
            while m < n:
                m *= 2
            best = min(best, m)
            p35 *= 3
        p5 *= 5
    return best


def convolve_valid(u, h):
    """The 'valid' part of the linear 2-D convolution of u (A x A) with h (B x B, B >= A): out[m] =
    sum_j u[j] h[m + A - 1 - j], (B - A + 1) x (B - A + 1), by zero-padded FFTs (no wrap-around)."""
    A, B = u.shape[0], h.shape[0]
    P = fast_len(A + B - 1)
    full = np.fft.ifft2(np.fft.fft2(u, s=(P, P)) * np.fft.fft2(h, s=(P, P)))
    return full[A - 1:B, A - 1:B]


def sellmeier_index(path, material, wavelength_um):
    rows = [l for l in open(path) if l.strip() and not l.startswith("#")]
    head = rows[0].strip().split(",")
    for line in rows[1:]:
        f = line.strip().split(",")
        if f[0] == material:
            v = dict(zip(head, f))
            lam2 = wavelength_um ** 2
            n2 = 1.0
            for i in (1, 2, 3):
                n2 += float(v[f"B{i}"]) * lam2 / (lam2 - float(v[f"C{i}_um2"]))
            return np.sqrt(n2)
    fail(f"material {material!r} is not in {path} (a Sellmeier row is needed)")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", required=True)
    ap.add_argument("--design", required=True)
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--etch-error-nm", type=float, default=20.0)
    ap.add_argument("--offset-um", default="0,0")
    ap.add_argument("--z-error-um", type=float, default=0.0)
    ap.add_argument("--grid-um", default="0,0")
    ap.add_argument("--fine", type=int, default=4)
    here = os.path.dirname(os.path.abspath(__file__))
    ap.add_argument("--sellmeier", default=os.path.join(here, "..", "..", "shared", "data", "spectral",
                                                        "sellmeier_coefficients.csv"))
    a = ap.parse_args()

    if os.path.exists(a.out):
        fail(f"--out {a.out}: exists (remove it or name another)")
    cfg = json.load(open(a.config))
    n, pitch = int(cfg["n"]), float(cfg["pitch_m"])
    bands, wl0, dwl = int(cfg["bands"]), float(cfg["wavelength_start_nm"]), float(cfg["wavelength_step_nm"])
    z = float(cfg["sensor_distance_m"]) + a.z_error_um * 1e-6
    d = float(cfg["scene_distance_m"])
    spitch = float(cfg["sensor_pitch_m"])
    if cfg.get("propagator", "fresnel") != "fresnel":
        fail(f"config propagator {cfg['propagator']!r}: this generator models Fresnel propagation only")
    if not np.isfinite(d) or d <= 0:
        fail(f"config scene_distance_m {d}: a finite distance > 0")
    radius = float(cfg.get("aperture_radius_m", 0.0)) or (n / 2 - 1) * pitch
    strict = cfg.get("aperture_edge", "inclusive") == "strict"
    F = a.fine
    if F < 1 or F > 16:
        fail(f"--fine {F}: an integer in [1, 16]")
    fine = pitch / F
    ratio = spitch / fine
    if abs(ratio - round(ratio)) > 1e-9:
        fail(f"--fine {F}: the sensor pitch {spitch} m must be a whole number of fine samples ({fine} m)")
    per_px = int(round(ratio))
    S = int(round(n * pitch / spitch))
    dx_um, dy_um = pair(a.offset_um, "offset-um")
    gx_um, gy_um = pair(a.grid_um, "grid-um")
    gx, gy = gx_um * 1e-6 / fine, gy_um * 1e-6 / fine
    if abs(gx - round(gx)) > 1e-9 or abs(gy - round(gy)) > 1e-9:
        fail(f"--grid-um {a.grid_um}: whole fine samples ({fine * 1e6:g} um)")
    gx, gy = int(round(gx)), int(round(gy))

    with h5py.File(a.design, "r") as f:
        if "levels_m" not in f or "height_m" not in f:
            fail(f"--design {a.design}: a quantized design (/height_m and /levels_m)")
        h = f["height_m"][()]
        levels = np.asarray(f["levels_m"][()], dtype=float)
    if h.shape != (n, n):
        fail(f"--design {a.design}: height_m is {h.shape}, the configuration's n is {n}")
    index = np.abs(h[..., None] - levels[None, None, :]).argmin(axis=2)
    rng = np.random.default_rng(a.seed)
    realised = levels + rng.uniform(-a.etch_error_nm, a.etch_error_nm, size=levels.size) * 1e-9

    # Fine sample j's centre: -n pitch / 2 - pitch / 2 + (j + 0.5) fine, so that DOE pixel i (centred at
    # (i - n/2) pitch) holds fine samples i F .. i F + F - 1.
    c0 = -n * pitch / 2 - pitch / 2 + fine / 2
    u = c0 + np.arange(n * F) * fine
    # The relief moved by (dx, dy): fine sample at x takes the DOE pixel under x - dx.
    col = np.floor((u - dx_um * 1e-6 - c0 + fine / 2) / pitch + 1e-9).astype(int)
    row = np.floor((u - dy_um * 1e-6 - c0 + fine / 2) / pitch + 1e-9).astype(int)
    inside_c, inside_r = (col >= 0) & (col < n), (row >= 0) & (row < n)
    col, row = np.clip(col, 0, n - 1), np.clip(row, 0, n - 1)
    H = realised[index[np.ix_(row, col)]]
    H[~inside_r, :] = 0.0  # no relief brought in from outside the DOE (as qdo's shift)
    H[:, ~inside_c] = 0.0
    X, Y = np.meshgrid(u, u)
    r2 = X ** 2 + Y ** 2
    aperture = (r2 < radius ** 2) if strict else (r2 <= radius ** 2)

    # The output lattice: the sensor window of S x S pixels, the axis at pixel (S/2, S/2)'s top-left
    # corner plus the grid displacement; fine output samples on the input's lattice.
    first = int(round((-S / 2 * spitch - c0 + fine / 2) / fine))  # lattice index of the window's first sample
    v_idx = first + np.arange(S * per_px)
    v_r, v_c = v_idx + gy, v_idx + gx
    A = n * F
    # Kernel offsets for 'valid' linear convolution: (v_min - u_max) .. (v_max - u_min) in samples.
    kr = np.arange(v_r[0] - (A - 1), v_r[-1] + 1) * fine
    kc = np.arange(v_c[0] - (A - 1), v_c[-1] + 1) * fine
    KX, KY = np.meshgrid(kc, kr)
    kr2 = KX ** 2 + KY ** 2

    wavelengths = wl0 + dwl * np.arange(bands)
    nidx = sellmeier_index(a.sellmeier, cfg["material"], wavelengths * 1e-3)
    stack = np.zeros((bands, S, S))
    for b, lam_nm in enumerate(wavelengths):
        lam = lam_nm * 1e-9
        k = 2 * np.pi / lam
        src = k * (np.sqrt(r2 + d * d) - d)
        U1 = np.where(aperture, np.exp(1j * (src + k * (nidx[b] - 1) * H)), 0)
        hker = np.exp(1j * np.pi * kr2 / (lam * z))  # the constant exp(ikz)/(i lambda z) drops out
        U2 = convolve_valid(U1, hker)
        I = np.abs(U2) ** 2
        I = I.reshape(S, per_px, S, per_px).sum(axis=(1, 3))
        stack[b] = I / I.sum()
        print(f"band {b + 1}/{bands} ({lam_nm:.0f} nm)", file=sys.stderr, flush=True)

    parent = os.path.dirname(os.path.abspath(a.out))
    os.makedirs(parent, exist_ok=True)
    if os.path.exists(a.out):
        fail(f"--out {a.out}: appeared while this ran (another writer?); nothing written")
    tmp = tempfile.mkdtemp(prefix=".asbuilt_generator.", dir=parent)
    try:
        with h5py.File(os.path.join(tmp, "psf.h5"), "w") as f:
            ds = f.create_dataset("psf_sensor", data=stack)
            ds.attrs["pitch_m"] = spitch
            ds.attrs["units"] = np.bytes_("fraction of band energy per sensor pixel")  # fixed-length, as qdo writes
            w = f.create_dataset("wavelengths_nm", data=wavelengths)
            w.attrs["units"] = np.bytes_("nm")
            f.attrs["made_by"] = np.bytes_("scripts/asbuilt_generator.py")
        truth = {f"level{L}": float(realised[L] - realised[0] + levels[0]) for L in range(1, levels.size)}
        truth.update({"z": z, "dx": dx_um * 1e-6, "dy": dy_um * 1e-6})
        json.dump({"fit_parameters": truth,
                   "grid_displacement_px": [gx * fine / spitch, gy * fine / spitch],
                   "realised_levels_m": realised.tolist(), "design_levels_m": levels.tolist()},
                  open(os.path.join(tmp, "truth.json"), "w"), indent=2)
        json.dump({"config": os.path.abspath(a.config), "design": os.path.abspath(a.design), "seed": a.seed,
                   "etch_error_nm": a.etch_error_nm, "offset_um": [dx_um, dy_um], "z_error_um": a.z_error_um,
                   "grid_um": [gx_um, gy_um], "fine": F, "aperture_radius_m": radius, "strict_aperture": strict},
                  open(os.path.join(tmp, "generator.json"), "w"), indent=2)
        os.rename(tmp, a.out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


if __name__ == "__main__":
    main()
