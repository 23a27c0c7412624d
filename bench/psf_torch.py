#!/usr/bin/env python3
"""A framework baseline: the paper preset's PSF stack written in PyTorch as a user would write it
(one vectorised pass over the bands), on the CPU or on a CUDA GPU, timed beside qdo in the same run.

The physics and its simplifications are those of bench/psf_numpy.py (31 bands 400..700 nm,
N = 1024 samples of 4 um, padding N/4 per side, point source at 1 m, Fresnel transfer function over
z = 50 mm, |U|^2 on the central N x N, normalised per band; no resampling to the sensor pitch, so a
lower bound for qdo's work). The phase k * (path) is formed in float64 and reduced before the
complex64 exponential, as a careful user would (REFERENCE §1's phase-precision trap); the error
column is the largest PSF difference relative to the stack's peak, against the same code in
complex128.

Usage: psf_torch.py [--device cpu|cuda] [--threads T] [--n 1024] [--bands 31] [--repeats 5] [--dtype complex64|complex128]
Prints one line: "torch PSF stack (DEVICE): median S s (min, max) over R runs, ..., max error E"
"""
import argparse
import math
import os
import statistics
import time

import torch


def psf_stack(n, bands, cdtype, dev):
    pitch, z, d, dn, f_lens = 4e-6, 0.05, 1.0, 0.5, 0.05
    pad = n // 4
    m = n + 2 * pad
    f64 = torch.float64
    lam = (400 + 10 * torch.arange(bands, device=dev, dtype=f64)) * 1e-9
    k = (2 * math.pi / lam)[:, None, None]
    c = (torch.arange(n, device=dev, dtype=f64) - n // 2) * pitch
    y, x = torch.meshgrid(c, c, indexing="ij")
    r2 = x * x + y * y
    aperture = r2 <= (n // 2 * pitch) ** 2
    h = torch.remainder(-r2 / (2 * f_lens) / dn, 550e-9 / dn)
    src = r2 / (torch.sqrt(r2 + d * d) + d)
    phase = torch.remainder(k * (src + dn * h), 2 * math.pi)           # bands x N x N, float64
    rdtype = torch.float32 if cdtype == torch.complex64 else f64
    u1 = torch.zeros((bands, m, m), dtype=cdtype, device=dev)
    u1[:, pad:pad + n, pad:pad + n] = torch.polar(aperture.to(rdtype).expand(bands, n, n), phase.to(rdtype))
    f = torch.fft.fftfreq(m, pitch, device=dev, dtype=f64)
    tf_phase = torch.remainder(-math.pi * lam[:, None, None] * z * (f[None, :, None] ** 2 + f[None, None, :] ** 2),
                               2 * math.pi)
    tf = torch.polar(torch.ones_like(tf_phase, dtype=rdtype), tf_phase.to(rdtype))
    u2 = torch.fft.ifft2(torch.fft.fft2(u1) * tf)
    p = u2[:, pad:pad + n, pad:pad + n].abs() ** 2
    return p / p.sum(dim=(1, 2), keepdim=True)


def sync(dev):
    if dev.type == "cuda":
        torch.cuda.synchronize()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--n", type=int, default=1024)
    ap.add_argument("--bands", type=int, default=31)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--dtype", default="complex64", choices=["complex64", "complex128"])
    ap.add_argument("--threads", type=int, default=os.cpu_count(),
                    help="CPU threads (Debian's torch starts with one; default: all cores)")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    dev = torch.device(a.device)
    cdtype = getattr(torch, a.dtype)
    psf_stack(a.n, a.bands, cdtype, dev)  # warm-up (plans, allocator)
    sync(dev)
    t = []
    for _ in range(a.repeats):
        t0 = time.perf_counter()
        p = psf_stack(a.n, a.bands, cdtype, dev)
        sync(dev)
        t.append(time.perf_counter() - t0)
    ref = psf_stack(a.n, a.bands, torch.complex128, dev)
    err = ((p.double() - ref).abs().max() / ref.max()).item()
    assert math.isfinite(err)
    name = torch.cuda.get_device_name(dev) if dev.type == "cuda" else f"{torch.get_num_threads()} threads"
    print(f"torch PSF stack ({a.device}, {name}): median {statistics.median(t):.4f} s (min {min(t):.4f}, "
          f"max {max(t):.4f}) over {a.repeats} runs, N={a.n}, M={a.n + 2 * (a.n // 4)}, bands={a.bands}, "
          f"{a.dtype}, torch {torch.__version__}, max error / peak {err:.1e}")


if __name__ == "__main__":
    main()
