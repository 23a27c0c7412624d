#!/usr/bin/env python3
"""The framework baseline: the paper preset's PSF stack written in NumPy as a user
would write it (one vectorised pass over the 31 bands), timed beside qdo in the same run.

Physics as qdo's paper preset (REFERENCE §1): 31 bands 400..700 nm, N = 1024 samples of 4 um,
padding N/4 per side (M = 1536), point source at d = 1 m (exact spherical phase), Fresnel
transfer function over z = 50 mm, |U|^2 on the central N x N, normalised per band. The DOE is a
550 nm diffractive lens of SK1300-like index (n - 1 = 0.5 here: the time does not depend on it).
The area resampling to the sensor pitch is left out (a small share of qdo's time too), so this is
a lower bound for the same work. numpy.fft (pocketfft) computes in complex128 whatever the input
precision, and single-threaded: that is what a NumPy user gets.

Usage: psf_numpy.py [--n 1024] [--bands 31] [--repeats 3] [--dtype complex64|complex128]
Prints one line: "numpy PSF stack: median S s (min, max) over R runs, N=..., M=..., bands=..."
"""
import argparse
import statistics
import time

import numpy as np


def psf_stack(n, bands, dtype):
    pitch, z, d = 4e-6, 0.05, 1.0
    pad = n // 4
    m = n + 2 * pad
    lam = (400 + 10 * np.arange(bands)) * 1e-9                      # bands
    k = (2 * np.pi / lam)[:, None, None]
    dn = 0.5
    c = (np.arange(n) - n // 2) * pitch
    y, x = np.meshgrid(c, c, indexing="ij")
    r2 = x * x + y * y
    aperture = r2 <= (n // 2 * pitch) ** 2
    f_lens = 0.05
    h = np.mod(-r2 / (2 * f_lens) * (2 * np.pi / 550e-9) / (2 * np.pi / 550e-9 * dn), 550e-9 / dn)
    src = r2 / (np.sqrt(r2 + d * d) + d)
    u1 = np.zeros((bands, m, m), dtype=dtype)
    u1[:, pad:pad + n, pad:pad + n] = (aperture * np.exp(1j * k * (src + dn * h))).astype(dtype)
    f = np.fft.fftfreq(m, pitch)
    tf = np.exp(-1j * np.pi * lam[:, None, None] * z * (f[None, :, None] ** 2 + f[None, None, :] ** 2)).astype(dtype)
    u2 = np.fft.ifft2(np.fft.fft2(u1, axes=(1, 2)) * tf, axes=(1, 2))
    p = np.abs(u2[:, pad:pad + n, pad:pad + n]) ** 2
    return p / p.sum(axis=(1, 2), keepdims=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=1024)
    ap.add_argument("--bands", type=int, default=31)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--dtype", default="complex64")
    a = ap.parse_args()
    dtype = np.dtype(a.dtype)
    psf_stack(a.n, a.bands, dtype)  # warm-up
    t = []
    for _ in range(a.repeats):
        t0 = time.perf_counter()
        p = psf_stack(a.n, a.bands, dtype)
        t.append(time.perf_counter() - t0)
    assert np.all(np.isfinite(p))
    print(f"numpy PSF stack: median {statistics.median(t):.3f} s (min {min(t):.3f}, max {max(t):.3f}) over {a.repeats} runs, "
          f"N={a.n}, M={a.n + 2 * (a.n // 4)}, bands={a.bands}, {a.dtype}, numpy {np.__version__}")


if __name__ == "__main__":
    main()
