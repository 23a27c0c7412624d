#!/usr/bin/env python3
"""Train a small PyTorch UNet jointly with a quantization-aware DOE on the CAVE scenes, with qdo's
OpenCL optics as differentiable layers (qdo.torch). A starting point for your own decoder.

Per step: a batch of random scene patches (flips, rotations) -> the DOE heights, blended towards
their L-level quantization by the QDO schedule (REFERENCE §2, Eq. 8: alpha from 0 to 1) -> qdo's
PSF stack -> qdo's camera (per-band convolution, RGB sensor, read noise) -> UNet -> MAE loss ->
backward through the network, the camera adjoint and the PSF adjoint -> Adam on both.

At the end the DOE is fully quantized (alpha = 1): the three test crops of ../shared/data/hsi/cave
(never trained on) are reconstructed and scored (PSNR), and OUT/ gets the figures (height map, PSF
montage, a test scene next to its reconstruction, as RGB through the camera response) and
OUT/log.csv (loss per step).

    python3 examples/python/train_decoder.py --out train_decoder_out

Needs the qdo package (`pip install .`, README "Python") and PyTorch; 2.4 minutes on 2 CPU cores
at the defaults (the `small` preset: 256 x 256 DOE, 31 bands, 64 x 64 patches, batch 4, 500 steps;
measured on the 2-core AMD EPYC with PoCL: 140 s, mean test PSNR 22.3 dB).
"""
import argparse
import csv
import glob
import math
import os
import sys
import time

import numpy as np
import torch
import torch.nn as nn

import qdo
import qdo.torch as qt

HERE = os.path.dirname(os.path.abspath(__file__))


def parse():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", default=os.path.join(HERE, "..", "..", "..", "shared", "data", "hsi"),
                   help="folder holding cave_train/ (training) and cave/ (test)")
    p.add_argument("--steps", type=int, default=500)
    p.add_argument("--levels", type=int, default=4, help="height levels L of the fabricated DOE")
    p.add_argument("--patch", type=int, default=64)
    p.add_argument("--batch", type=int, default=4)
    p.add_argument("--lr-optics", type=float, default=0.01)
    p.add_argument("--lr-net", type=float, default=1e-3)
    p.add_argument("--device", default="", help="OpenCL device for the optics (default: qdo's choice)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="train_decoder_out")
    a = p.parse_args()
    for k in ("steps", "levels", "patch", "batch"):
        if getattr(a, k) < (2 if k == "levels" else 1):
            p.error("--%s must be >= %d" % (k, 2 if k == "levels" else 1))
    return a


class Block(nn.Module):
    """Residual block: (conv, batch norm, ELU) x 2 plus a 1x1 identity projection."""

    def __init__(self, cin, cout):
        super().__init__()
        self.body = nn.Sequential(nn.Conv2d(cin, cout, 3, padding=1), nn.BatchNorm2d(cout), nn.ELU(),
                                  nn.Conv2d(cout, cout, 3, padding=1), nn.BatchNorm2d(cout), nn.ELU())
        self.skip = nn.Conv2d(cin, cout, 1)

    def forward(self, x):
        return self.body(x) + self.skip(x)


class UNet(nn.Module):
    """A small residual UNet: 3 sensor channels in, `bands` spectral channels out (sigmoid)."""

    def __init__(self, bands, root=16):
        super().__init__()
        self.e1, self.e2, self.e3 = Block(3, root), Block(root, 2 * root), Block(2 * root, 4 * root)
        self.u2 = nn.ConvTranspose2d(4 * root, 2 * root, 2, stride=2)
        self.d2 = Block(4 * root, 2 * root)
        self.u1 = nn.ConvTranspose2d(2 * root, root, 2, stride=2)
        self.d1 = Block(2 * root, root)
        self.out = nn.Conv2d(root, bands, 1)

    def forward(self, y):
        x1 = self.e1(y)
        x2 = self.e2(nn.functional.max_pool2d(x1, 2))
        x3 = self.e3(nn.functional.max_pool2d(x2, 2))
        z = self.d2(torch.cat([self.u2(x3), x2], 1))
        z = self.d1(torch.cat([self.u1(z), x1], 1))
        return torch.sigmoid(self.out(z))


def load(folder, optics):
    bands = optics.bands
    files = sorted(glob.glob(os.path.join(folder, "*.mat")) + glob.glob(os.path.join(folder, "*.h5")))
    if not files:
        sys.exit("train_decoder: no .mat or .h5 scenes in %s (--data)" % folder)
    cubes = [qdo.read_cube(f, config=optics) for f in files]  # as `qdo simulate --scene` reads them
    for f, c in zip(files, cubes):
        if c.shape[0] != bands:
            sys.exit("train_decoder: %s has %d bands; the configuration has %d" % (f, c.shape[0], bands))
    return files, cubes


def patches(cubes, size, count, rng):
    out = np.empty((count, cubes[0].shape[0], size, size))
    for i in range(count):
        c = cubes[rng.integers(len(cubes))]
        y, x = rng.integers(c.shape[1] - size + 1), rng.integers(c.shape[2] - size + 1)
        p = c[:, y:y + size, x:x + size]
        p = np.rot90(p, rng.integers(4), axes=(1, 2))
        if rng.integers(2):
            p = p[:, :, ::-1]
        out[i] = p
    return torch.from_numpy(out).float()


def alpha_at(step, total):
    """QDO's cubic schedule (Eq. 10): 0 until 10 % of the steps, 1 from 80 % on."""
    t0, t1 = 0.1 * total, 0.8 * total
    if step <= t0:
        return 0.0
    if step >= t1:
        return 1.0
    return 1.0 - ((t1 - step) / (t1 - t0)) ** 3


def heights(w, h_max, levels, alpha):
    """H = alpha * h_max * Q(H_f / h_max) + (1 - alpha) * H_f with H_f = h_max * sigmoid(w);
    Q rounds to the L inclusive levels and passes no gradient (Eq. 8)."""
    hf = h_max * torch.sigmoid(w)
    q = torch.round(hf.detach() / h_max * (levels - 1)) / (levels - 1) * h_max
    return alpha * q + (1.0 - alpha) * hf


def psnr(x, ref):
    mse = float(np.mean((x - ref) ** 2))
    return 10 * math.log10(1.0 / max(mse, 1e-20))


def main():
    a = parse()
    torch.manual_seed(a.seed)
    torch.set_num_threads(max(1, os.cpu_count() or 1))
    rng = np.random.default_rng(a.seed)
    optics = qdo.Optics(preset="small", device=a.device, precision="f32")
    print("qdo %s on %s; PyTorch %s with %d threads" % (qdo.__version__, optics.device, torch.__version__,
                                                       torch.get_num_threads()))
    _, train = load(os.path.join(a.data, "cave_train"), optics)
    test_files, test = load(os.path.join(a.data, "cave"), optics)
    print("training on %d scenes of %s, testing on %d" % (len(train), os.path.join(a.data, "cave_train"), len(test)))

    psf_layer, camera = qt.PSF(optics), qt.Camera(optics)
    net = UNet(optics.bands)
    h_max = optics.h_max_m
    lens = qdo.lens_design(optics, 550.0) / h_max
    w = torch.tensor(np.log(np.clip(lens, 0.02, 0.98) / (1 - np.clip(lens, 0.02, 0.98))), dtype=torch.float64,
                     requires_grad=True)
    opt_optics = torch.optim.Adam([w], lr=a.lr_optics)
    opt_net = torch.optim.Adam(net.parameters(), lr=a.lr_net)

    os.makedirs(a.out, exist_ok=True)
    log = []
    t0 = time.time()
    for step in range(1, a.steps + 1):
        alpha = alpha_at(step, a.steps)
        x = patches(train, a.patch, a.batch, rng)
        psf = psf_layer(heights(w, h_max, a.levels, alpha))            # bands x S x S (float64)
        y = camera(x.double(), psf).float()                             # batch x 3 x P x P
        loss = (net(y) - x).abs().mean()
        opt_optics.zero_grad()
        opt_net.zero_grad()
        loss.backward()
        opt_optics.step()
        opt_net.step()
        log.append((step, float(loss), alpha))
        el = time.time() - t0
        eta = el / step * (a.steps - step)
        bar = "#" * int(30 * step / a.steps)
        sys.stdout.write("\r[%-30s] step %d/%d  loss %.4f  alpha %.2f  %.0fs, ETA %.0fs " %
                         (bar, step, a.steps, float(loss), alpha, el, eta))
        sys.stdout.flush()
    print()

    # Evaluation through the fabricated (fully quantized) DOE on the unseen test crops.
    net.eval()
    with torch.no_grad():
        h_fab = heights(w, h_max, a.levels, 1.0)
        psf = optics.psf(h_fab.numpy())
        scores, recs = [], []
        for f, c in zip(test_files, test):
            y = optics.camera(c, psf)
            xr = net(torch.from_numpy(y[None]).float())[0].double().numpy()
            recs.append(xr)
            scores.append(psnr(xr, c))
            print("test %-28s PSNR %.2f dB" % (os.path.basename(f), scores[-1]))
        print("mean test PSNR %.2f dB (%d levels, %d steps, %.0f s)" % (np.mean(scores), a.levels, a.steps,
                                                                         time.time() - t0))
        srf = optics.srf()
        qdo.write_height_figure(os.path.join(a.out, "height.png"), "Fabricated DOE heights", h_fab.numpy(), optics.config["pitch_m"])
        qdo.write_psf_figure(os.path.join(a.out, "psf.png"), "PSF stack of the trained DOE", psf, optics.wavelengths_nm,
                             optics.config["sensor_pitch_m"])
        # The first test scene (left) and its reconstruction (right), seen through the camera response.
        side = np.concatenate([np.tensordot(srf, test[0], axes=(1, 0)), np.tensordot(srf, recs[0], axes=(1, 0))], axis=2)
        qdo.write_rgb_png(os.path.join(a.out, "test_vs_reconstruction.png"), np.ascontiguousarray(side))
    qdo.write_design(os.path.join(a.out, "design.h5"), h_fab.numpy(), optics.config["pitch_m"])
    with open(os.path.join(a.out, "log.csv"), "w", newline="") as f:
        wr = csv.writer(f)
        wr.writerow(["step", "loss_mae", "alpha"])
        wr.writerows(log)
    print("wrote %s/{height.png, psf.png, test_vs_reconstruction.png, design.h5, log.csv}" % a.out)


if __name__ == "__main__":
    main()
