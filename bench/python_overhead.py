#!/usr/bin/env python3
"""What crossing between PyTorch and qdo costs: the same PSF and camera work called (1) through
qdo's NumPy API (the C++ call and its float64 copies) and (2) through the qdo.torch operators
(adds the tensor <-> NumPy conversions and autograd), forward and forward + backward; median of
--repeats runs after one warm-up, small preset, float32 device work. The C++ in-process figures of
the same work are bench_step's "OpenCL PSF forward" rows.

    PYTHONPATH=build/pystage /usr/bin/python3 bench/python_overhead.py [--repeats 7] [--preset small]
    (or a pip-installed package: build/venv/bin/python bench/python_overhead.py ...)
"""
import argparse
import statistics
import time

import numpy as np
import torch

import qdo
import qdo.torch as qt


def timed(fn, repeats):
    fn()
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return statistics.median(ts), min(ts), max(ts)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--preset", default="small")
    a = ap.parse_args()
    o = qdo.Optics(preset=a.preset, precision="f32")
    h = qdo.lens_design(o, 550.0)
    s = o.sensor_size
    scene = np.random.default_rng(0).uniform(0, 1, (4, o.bands, 64, 64))
    psf = o.psf(h)
    ht = torch.tensor(h, requires_grad=True)
    st = torch.tensor(scene)
    pt = torch.tensor(psf, requires_grad=True)
    P, C = qt.PSF(o), qt.Camera(o)
    rows = [
        ("PSF forward, NumPy API", lambda: o.psf(h)),
        ("PSF forward, qdo.torch.PSF", lambda: P(ht)),
        ("PSF forward + backward, NumPy API (psf, psf_vjp)", lambda: (o.psf(h), o.psf_vjp(np.ones((o.bands, s, s))))),
        ("PSF forward + backward, qdo.torch.PSF", lambda: P(ht).sum().backward()),
        ("camera forward (4 x 31 x 64 x 64), NumPy API", lambda: o.camera(scene, psf)),
        ("camera forward, qdo.torch.Camera", lambda: C(st, pt)),
        ("camera forward + backward, NumPy API", lambda: (o.camera(scene, psf), o.camera_vjp(np.ones((4, 3, 64, 64))))),
        ("camera forward + backward, qdo.torch.Camera", lambda: C(st, pt).sum().backward()),
    ]
    print("qdo %s, %s preset, device %s, f32; torch %s, %d threads" % (qdo.__version__, a.preset, o.device,
                                                                      torch.__version__, torch.get_num_threads()))
    print("| work | median ms | min ms | max ms |\n|---|---:|---:|---:|")
    for name, fn in rows:
        med, lo, hi = timed(fn, a.repeats)
        print("| %s | %.1f | %.1f | %.1f |" % (name, 1e3 * med, 1e3 * lo, 1e3 * hi))


if __name__ == "__main__":
    main()
