#!/usr/bin/env python3
"""A plain-PyTorch reference of one qdo joint-training step, timed stage by stage: the reference to beat.

What it is: the optics, the camera and the Res-UNet of qdo's joint training (REFERENCE.md sections 1-3,
docs/physics.md, src/net/resunet.cpp) written the way a user of DeepLens-like tools writes them: one
autograd graph, torch.fft for the PSF and the convolution, torch.nn for the network, torch.optim.Adam.
The sizes are qdo's (printed at the start), so the work is the same as bench/net/bench_train.cpp's.

Usage (Debian's /usr/bin/python3 has torch; plain `python3` may not):
    /usr/bin/python3 bench/joint_torch.py [--preset small|paper] [--batch 4] [--repeats 5] [--warmup 1]
        [--threads T] [--device cpu|cuda] [--depth 4] [--root 16] [--mode qdo+a|full] [--levels 4]
        [--alpha 0.5] [--conv linear|circular] [--srf-in-frequency] [--json FILE]
    /usr/bin/python3 bench/joint_torch.py --check [--qdo-psf PSF.npy]   # correctness checks, float64, ~1 min

Stages (each the median of --repeats runs after --warmup unmeasured runs; CUDA synchronised):
  optics forward   radial parameters w (N/2 rings) -> QDO+A quantizer (alpha blend, trainable level
                   offsets) -> N x N heights -> field exp(i k (n-1) H) times the point source's exact
                   spherical phase on the circular aperture -> zero-padded FFT (M x M) -> Fresnel transfer
                   function -> inverse FFT -> |U|^2 on the N x N crop, normalised per band -> area
                   integration onto the S x S sensor grid -> normalised again (bands x S x S).
  camera forward   per-band linear (zero-padded) FFT convolution of the batch of scenes (B x bands x H x W)
                   with the sensor PSF (rfft2 on the alias-free grid H + S/2, qdo's grid), sensor
                   integration with the normalised FLIR GS3-U3-41S4C response (3 x bands), + Gaussian
                   noise sigma = 1e-3 on RGB. Includes the PSF's rfft2 (its OTF).
  network fwd+bwd  zero_grad, Res-UNet forward on the RGB images (inputs requiring grad), MAE against the
                   scenes, backward (network weight gradients and dL/dRGB).
  camera backward  torch.autograd.grad of the camera output w.r.t. the PSF given dL/dRGB.
  optics backward  torch.autograd.grad of the PSF w.r.t. the radial parameters and level offsets given
                   dL/dPSF (includes the quantizer's and the ring expansion's backward).
  network Adam     torch.optim.Adam.step() on the network (lr 1e-3).  (optics Adam, lr 1e-2 on w and the
                   offsets, is timed apart: it is tiny and qdo's bench_train has no such row.)
  whole step       everything above as a user writes it: one graph, loss = MAE + beta L_aq, one
                   loss.backward(), both Adam steps, clamp of w and the offsets to [-1, 1].
Stage timings split the graph at the PSF and at the RGB images (detached leaves), so each backward is
timed alone; the whole step does not split it.

What differs from qdo (see also the --check output):
  * Precision: float32 / complex64 with the constant phases (source sphere, transfer function) formed
    in float64 and reduced mod 2 pi before the cast (qdo's f32 does the same); --check runs float64.
  * Optics forward/backward is the plain 2-D FFT path (qdo's bench_train stages too), with the
    quantizer and ring expansion included (bench_train's optics stage takes a ready N x N map; this
    costs a gather and a few element-wise ops on N^2 values). qdo's design step uses its radial engine
    (no 2-D FFT), a different algorithm: its row is shown for information only.
  * qdo's camera caches the PSF's OTF per PSF generation, so its timed camera stage (same PSF every
    repeat) does not transform the PSF; this one does (as a training step must). qdo also packs two
    real bands into one complex FFT and integrates the sensor before the inverse FFT; here rfft2 does
    the former's job, and --srf-in-frequency does the latter (off by default: a plain user inverts each
    band and then integrates).
  * Network: the same architecture, init (He-uniform, zero bias) and torch batch norm (momentum 0.1,
    eps 1e-5); weights are drawn from torch's generator (not qdo's seed), so values differ.
  * Quantizer: QDO+A as qdo's Designer (inclusive placement, level l at (l + 0.5 a_l) / (L - 1), a_0 = 0,
    H = h_max (alpha Q(u) + (1 - alpha) u), gradient to u through the (1 - alpha) branch only, L_aq =
    mean((Q(u) - u)^2) over the N/2 ring values (the release's domain; qdo's default is the pixels),
    beta = 0.01); alpha is fixed (--alpha, default 0.5 so both branches carry gradient). No learning-rate
    decay (a scalar per step), no fabrication height noise. --mode full: plain heights, no quantizer.
  * Scenes are fixed uniform random cubes (bench_train's are too); no crops, flips or data loading.
  * This machine's torch (Debian 1.13) has the generic reference BLAS (printed as "BLAS ..."): the area
    integration A P A^T is therefore done separably as weighted strided slices when the pitch ratio is an
    integer (both presets: kernel [0.5, 1, 0.5], stride 2; checked equal to the matrix form), not as two
    matrix products (~0.5 s forward at small) nor as a strided conv2d (its backward ~0.1 s); the slices
    cost ~5 ms forward, ~15 ms backward. The camera's 3 x bands sensor integration stays an einsum (fast
    enough here). With an MKL/OpenBLAS torch the choice matters less.

Checks (--check, float64, batch <= 2, ~1 min on 2 cores): Parseval through the propagation, PSF plane sums,
the lens focus on the axis, the convolution's alignment (a point scene images to srf @ PSF), optionally
qdo's own f64 sensor PSF of lens:550 (--qdo-psf, an .npy of `qdo psf`'s /psf_sensor; bench/joint_torch.sh
makes it), and autograd against central differences of the whole joint loss on 3 ring weights and one level
offset. Exit status 1 when a check fails.
"""
import argparse
import csv
import json
import math
import os
import statistics
import sys
import time

import torch
import torch.nn as nn
import torch.nn.functional as F

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

# ---------------------------------------------------------------------------------------------------
# Configuration (qdo's presets, src/data/config.cpp)
# ---------------------------------------------------------------------------------------------------
SK1300 = (7.44386780e-01, 4.95119834e-03, 3.60198890e-01, 1.41130274e-02, 9.18623119e-01, 1.00428510e02)


def preset(name):
    c = dict(n=1024, pitch=4e-6, bands=31, lam0_nm=400.0, dlam_nm=10.0, d=1.0, z=0.05, pad=256,
             sensor_pitch=8e-6, base_nm=700.0, sigma=1e-3)
    if name == "small":  # z scaled with N: same NA and transfer-function sampling ratio as the paper
        c.update(n=256, z=0.0125, pad=64)
    elif name != "paper":
        raise SystemExit(f"unknown preset {name}: small or paper")
    c["s"] = round(c["n"] * c["pitch"] / c["sensor_pitch"])  # sensor PSF size = scene size (128 / 512)
    c["m"] = smooth7(c["n"] + 2 * c["pad"])
    return c


def smooth7(x):
    while True:
        y = x
        for p in (2, 3, 5, 7):
            while y % p == 0:
                y //= p
        if y == 1:
            return x
        x += 1


def index_sk1300(lam_nm):
    l2 = (lam_nm * 1e-3) ** 2
    b1, c1, b2, c2, b3, c3 = SK1300
    return math.sqrt(1 + b1 * l2 / (l2 - c1) + b2 * l2 / (l2 - c2) + b3 * l2 / (l2 - c3))


def load_srf(bands, lam0, dlam):
    """3 x bands sensor response (R, G, B rows), each row normalised to unit sum (Eq. 7)."""
    rows = {}
    with open(os.path.join(ROOT, "data", "srf_FLIR_GS3-U3-41S4C.csv")) as f:
        for r in csv.DictReader(line for line in f if not line.startswith("#")):
            rows[round(float(r["wavelength_nm"]))] = [float(r["R"]), float(r["G"]), float(r["B"])]
    srf = torch.tensor([rows[round(lam0 + b * dlam)] for b in range(bands)], dtype=torch.float64).T
    return srf / srf.sum(dim=1, keepdim=True)


def area_matrix(n, pitch_in, s, pitch_out):
    """S x N area-integration weights (qdo's AreaWeights::make): sensor pixel o covers the native cells
    its edges cut, sensor axis S/2 on native axis N/2."""
    a = torch.zeros(s, n, dtype=torch.float64)
    r = pitch_out / pitch_in
    for o in range(s):
        lo = (o - s // 2 - 0.5) * r + n // 2 + 0.5
        hi = lo + r
        for i in range(max(0, math.floor(lo)), min(n, math.ceil(hi))):
            ov = min(hi, i + 1) - max(lo, i)
            if ov > 0:
                a[o, i] = ov
    return a


def area_kernel(a, n, s):
    """The area matrix as (1-D kernel k, stride r, left pad, right pad) when its rows are shifts of one
    kernel by an integer stride (pitch ratio an integer, N = ratio x S); None otherwise."""
    if n % s:
        return None
    r = n // s
    nz = [(int(row.nonzero().min()), int(row.nonzero().max())) for row in a]
    i0, i1 = nz[s // 2]
    k = a[s // 2, i0:i1 + 1].clone()
    off = i0 - r * (s // 2)                       # input index of tap 0 for output 0
    for o, row in enumerate(a):                   # every row the same kernel, shifted by r
        full = torch.zeros(n + 2 * len(k), dtype=a.dtype)
        lo = off + r * o + len(k)
        full[lo:lo + len(k)] = k
        if not torch.equal(full[len(k):len(k) + n], row):
            return None
    pad_l = -off
    pad_r = max(0, r * (s - 1) + off + len(k) - n)
    return [float(v) for v in k], r, pad_l, pad_r


# ---------------------------------------------------------------------------------------------------
# Optics: heights -> sensor PSF stack
# ---------------------------------------------------------------------------------------------------
class Optics:
    """Constants built once (aperture, source phase, k (n-1), transfer function, area weights); forward
    is differentiable in the height map."""

    def __init__(self, c, dev, real):
        self.c, self.dev, self.real = c, dev, real
        self.cplx = torch.complex64 if real == torch.float32 else torch.complex128
        n, m, p, f64 = c["n"], c["m"], c["pitch"], torch.float64
        lam = (c["lam0_nm"] + c["dlam_nm"] * torch.arange(c["bands"], dtype=f64)) * 1e-9
        self.lam = lam
        k = 2 * math.pi / lam
        dn = torch.tensor([index_sk1300(float(l) * 1e9) - 1 for l in lam], dtype=f64)
        self.h_max = c["base_nm"] * 1e-9 / (index_sk1300(c["base_nm"]) - 1)
        idx = torch.arange(n, dtype=f64) - n // 2
        self.di2 = (idx[:, None] ** 2 + idx[None, :] ** 2)                      # integer px^2
        r2 = self.di2 * p * p
        self.aperture = (self.di2 <= (n // 2 - 1) ** 2).to(real).to(dev)        # inclusive edge, R = (N/2-1) pitch
        src = r2 / (torch.sqrt(r2 + c["d"] ** 2) + c["d"])                       # sqrt(r^2+d^2) - d, no cancellation
        self.src_phase = torch.remainder(k[:, None, None] * src, 2 * math.pi).to(real).to(dev)   # bands x N x N
        self.kdn = (k * dn).to(real).to(dev)[:, None, None]                     # phase per metre of relief
        f = torch.fft.fftfreq(m, p, dtype=f64)
        tf = torch.remainder(-math.pi * lam[:, None, None] * c["z"] * (f[None, :, None] ** 2 + f[None, None, :] ** 2),
                             2 * math.pi)
        self.tf = torch.polar(torch.ones_like(tf), tf).to(self.cplx).to(dev)    # bands x M x M
        area = area_matrix(n, p, c["s"], c["sensor_pitch"]).to(real)
        self.area, self.area_k = area.to(dev), area_kernel(area, n, c["s"])
        # ring index of every pixel (radial parameterisation: ring k holds k <= r/pitch < k+1)
        self.ring = torch.clamp(torch.floor(torch.sqrt(self.di2) + 1e-9).long(), max=n // 2 - 1).to(dev)

    def lens_heights(self, lam_nm=550.0):
        """qdo's lens_design(cfg, 550): the diffractive lens imaging the source onto the sensor."""
        c, p = self.c, self.c["pitch"]
        k, dn = 2 * math.pi / (lam_nm * 1e-9), index_sk1300(lam_nm) - 1
        r2 = self.di2 * p * p
        path = r2 / (torch.sqrt(r2 + c["z"] ** 2) + c["z"]) + r2 / (torch.sqrt(r2 + c["d"] ** 2) + c["d"])
        return torch.clamp(torch.remainder(-k * path, 2 * math.pi) / (k * dn), max=self.h_max)

    def resample(self, p, matrix=False):
        """bands x N x N -> bands x S x S by area integration, A p A^T. For an integer pitch ratio it is
        computed separably as a weighted sum of strided slices (each axis: y[o] = sum_t k[t] x[r o + t + off]):
        this torch's BLAS is the generic reference one, with which the two matrix products take ~0.5 s at
        the small preset, and a strided conv2d's backward (oneDNN, one channel) ~0.1 s."""
        if self.area_k is None or matrix:
            return self.area @ p @ self.area.T
        k, r, pad_l, pad_r = self.area_k
        s = self.c["s"]
        x = F.pad(p, (pad_l, pad_r, pad_l, pad_r))
        x = sum(kt * x[:, t:t + r * (s - 1) + 1:r, :] for t, kt in enumerate(k))
        return sum(kt * x[:, :, t:t + r * (s - 1) + 1:r] for t, kt in enumerate(k))

    def psf(self, h, keep=None):
        """h: N x N heights (metres, real dtype) -> sensor PSF stack bands x S x S (each plane sums to 1).
        keep: a dict that receives intermediates for the checks."""
        n = self.c["n"]
        m = self.c["m"]
        u1 = self.aperture * torch.exp(1j * (self.src_phase + self.kdn * h))   # bands x N x N complex
        u2 = torch.fft.ifft2(torch.fft.fft2(u1, s=(m, m)) * self.tf)            # zero-padded to M x M
        crop = u2[:, :n, :n]
        p = crop.real ** 2 + crop.imag ** 2
        sums = p.sum(dim=(1, 2), keepdim=True)
        p = p / sums
        ps = self.resample(p)                                                    # area integration onto S x S
        ps = ps / ps.sum(dim=(1, 2), keepdim=True)
        if keep is not None:
            keep.update(u1=u1, u2=u2, psf_native=p, crop_energy=sums)
        return ps


# ---------------------------------------------------------------------------------------------------
# Quantizer (QDO+A) and parameterisation
# ---------------------------------------------------------------------------------------------------
class Heights:
    """Radial weights w in [-1, 1] (N/2 rings), u = (w + 1) / 2; QDO+A: L levels (inclusive placement)
    with trainable offsets a (a_0 fixed at 0), alpha-blended; returns (N x N heights, L_aq)."""

    def __init__(self, optics, levels, mode, alpha):
        self.o, self.levels, self.mode, self.alpha = optics, levels, mode, alpha
        self.mask = torch.ones(levels, dtype=optics.real, device=optics.dev)
        self.mask[0] = 0

    def __call__(self, w, a):
        u = (w + 1) / 2
        if self.mode == "full":
            uh, laq = u, torch.zeros((), dtype=u.dtype, device=u.device)
        else:
            lm1 = self.levels - 1
            idx = torch.clamp(torch.floor(lm1 * u.detach() + 0.5), 0, lm1).long()   # round half up
            q = (idx.to(u.dtype) + 0.5 * (a * self.mask)[idx]) / lm1                 # level values
            uh = self.alpha * q + (1 - self.alpha) * u   # q: no gradient to u (index detached), to a yes
            laq = ((q - u) ** 2).mean()
        return self.o.h_max * uh[self.o.ring], laq


# ---------------------------------------------------------------------------------------------------
# Camera
# ---------------------------------------------------------------------------------------------------
class Camera:
    def __init__(self, c, srf, dev, real, conv, srf_in_frequency):
        self.h = self.w = c["s"]
        self.s = c["s"]
        self.g = self.h + self.s // 2 if conv == "linear" else self.h   # qdo's alias-free grid
        self.srf = srf.to(real).to(dev)
        self.sigma = c["sigma"]
        self.fuse = srf_in_frequency

    def otf(self, psf):
        """bands x S x S PSF (axis at S/2) -> bands x G x (G/2+1), the PSF's centre moved to (0, 0)."""
        s, g = self.s, self.g
        k = F.pad(psf, (0, g - s, 0, g - s)) if g > s else psf
        k = torch.roll(k, shifts=(-(s // 2), -(s // 2)), dims=(1, 2))
        return torch.fft.rfft2(k)

    def __call__(self, psf, scenes, noise=None):
        g = self.g
        spec = torch.fft.rfft2(scenes, s=(g, g)) * self.otf(psf)                 # B x bands x G x G/2+1
        if self.fuse:
            rgb = torch.fft.irfft2(torch.einsum("cb,nbyx->ncyx", self.srf.to(spec.dtype), spec), s=(g, g))
        else:
            blur = torch.fft.irfft2(spec, s=(g, g))
            rgb = torch.einsum("cb,nbyx->ncyx", self.srf, blur)
        rgb = rgb[:, :, :self.h, :self.w]
        if noise is None:
            noise = self.sigma * torch.randn_like(rgb)
        return rgb + noise


# ---------------------------------------------------------------------------------------------------
# Res-UNet (src/net/resunet.cpp)
# ---------------------------------------------------------------------------------------------------
def he_uniform(conv):
    nn.init.kaiming_uniform_(conv.weight, a=0, nonlinearity="relu")   # U(-sqrt(6/fan_in), +)
    if conv.bias is not None:
        nn.init.zeros_(conv.bias)
    return conv


def conv(cin, cout, k, bias=True):
    return he_uniform(nn.Conv2d(cin, cout, k, padding=k // 2, bias=bias))


class Down(nn.Module):
    def __init__(self, cin, c, k):
        super().__init__()
        self.identity, self.conv1, self.bn1 = conv(cin, c, 1, False), conv(cin, c, k), nn.BatchNorm2d(c)
        self.conv2, self.bn2 = conv(c, c, 3), nn.BatchNorm2d(c)

    def forward(self, x):
        a = F.elu(self.bn1(self.conv1(x)))
        return F.elu(self.identity(x) + self.bn2(self.conv2(a)))


class Up(nn.Module):
    def __init__(self, cin, c):
        super().__init__()
        self.up_conv = conv(cin, c, 1)
        self.conv1, self.bn1 = conv(2 * c, c, 3), nn.BatchNorm2d(c)
        self.conv2, self.bn2 = conv(c, c, 3), nn.BatchNorm2d(c)
        self.identity = conv(2 * c, c, 1, False)

    def forward(self, x, skip):
        up = F.elu(self.up_conv(F.interpolate(x, scale_factor=2, mode="nearest")))
        cat = torch.cat([up, skip], 1)
        a = F.elu(self.bn1(self.conv1(cat)))
        return F.elu(self.identity(cat) + self.bn2(self.conv2(a)))


class ResUNet(nn.Module):
    """depth levels of root * 2^i filters; first conv 7x7; residual blocks with 1x1 identities; BN before
    ELU; max-pool down, nearest-neighbour up + 1x1 conv, skip concatenation; final 1x1 conv + sigmoid."""

    def __init__(self, cin, cout, depth, root):
        super().__init__()
        chans = [root << i for i in range(depth)]
        self.downs = nn.ModuleList(Down(cin if i == 0 else chans[i - 1], chans[i], 7 if i == 0 else 3)
                                   for i in range(depth))
        self.ups = nn.ModuleList(Up(chans[i + 1], chans[i]) for i in range(depth - 1))
        self.final = conv(root, cout, 1)

    def forward(self, x):
        skips = []
        for i, d in enumerate(self.downs):
            x = d(x)
            if i + 1 < len(self.downs):
                skips.append(x)
                x = F.max_pool2d(x, 2)
        for i in reversed(range(len(self.ups))):
            x = self.ups[i](x, skips[i])
        return torch.sigmoid(self.final(x))


# ---------------------------------------------------------------------------------------------------
# The joint model
# ---------------------------------------------------------------------------------------------------
class Joint:
    def __init__(self, a, dev, real):
        self.c = preset(a.preset)
        self.dev, self.real = dev, real
        c = self.c
        self.optics = Optics(c, dev, real)
        self.heights = Heights(self.optics, a.levels, a.mode, a.alpha)
        self.camera = Camera(c, load_srf(c["bands"], c["lam0_nm"], c["dlam_nm"]), dev, real, a.conv,
                             a.srf_in_frequency)
        self.net = ResUNet(3, c["bands"], a.depth, a.root).to(dev).to(real)
        self.beta = 0.01
        # initial design: the 550 nm lens's ring profile (ring k at r = k pitch), as normalised weights
        ring_h = self.optics.lens_heights()[c["n"] // 2, c["n"] // 2:].to(real)
        self.w = (2 * ring_h / self.optics.h_max - 1).clamp(-1, 1).to(dev).requires_grad_(True)
        self.a = torch.zeros(a.levels, dtype=real, device=dev, requires_grad=True)
        self.opt_net = torch.optim.Adam(self.net.parameters(), lr=1e-3)
        self.opt_optics = torch.optim.Adam([self.w, self.a], lr=1e-2)
        gen = torch.Generator().manual_seed(1)
        shape = (a.batch, c["bands"], c["s"], c["s"])
        self.scenes = torch.rand(shape, generator=gen, dtype=torch.float64).to(real).to(dev)

    def sizes(self):
        c = self.c
        return dict(N=c["n"], M=c["m"], bands=c["bands"], sensor_psf=f"{c['s']}x{c['s']}",
                    scene=f"{self.scenes.shape[0]}x{c['bands']}x{c['s']}x{c['s']}", camera_grid=self.camera.g,
                    rings=c["n"] // 2, net_params=sum(p.numel() for p in self.net.parameters()))

    def clamp(self):
        with torch.no_grad():
            self.w.clamp_(-1, 1)
            self.a.clamp_(-1, 1)
            self.a[0] = 0

    def step(self):
        """One whole training step as a user writes it."""
        self.opt_net.zero_grad(set_to_none=True)
        self.opt_optics.zero_grad(set_to_none=True)
        h, laq = self.heights(self.w, self.a)
        psf = self.optics.psf(h)
        rgb = self.camera(psf, self.scenes)
        loss = (self.net(rgb) - self.scenes).abs().mean() + self.beta * laq
        loss.backward()
        self.opt_net.step()
        self.opt_optics.step()
        self.clamp()
        return loss


# ---------------------------------------------------------------------------------------------------
# Timing
# ---------------------------------------------------------------------------------------------------
def sync(dev):
    if dev.type == "cuda":
        torch.cuda.synchronize()


def median_time(dev, warmup, repeats, f):
    for _ in range(warmup):
        f()
    sync(dev)
    t = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        f()
        sync(dev)
        t.append(time.perf_counter() - t0)
    return statistics.median(t)


def bench(a):
    dev = torch.device(a.device)
    j = Joint(a, dev, torch.float32)
    st = {}

    def optics():
        st["h"], st["laq"] = j.heights(j.w, j.a)
        st["psf"] = j.optics.psf(st["h"])

    def camera():
        st["psf_leaf"] = st["psf"].detach().requires_grad_(True)
        st["rgb"] = j.camera(st["psf_leaf"], j.scenes)

    def network():
        j.opt_net.zero_grad(set_to_none=True)
        st["rgb_leaf"] = st["rgb"].detach().requires_grad_(True)
        loss = (j.net(st["rgb_leaf"]) - j.scenes).abs().mean()
        loss.backward()
        st["g_rgb"] = st["rgb_leaf"].grad

    def camera_bwd():
        st["g_psf"], = torch.autograd.grad(st["rgb"], st["psf_leaf"], st["g_rgb"], retain_graph=True)

    def optics_bwd():
        st["g_w"], st["g_a"] = torch.autograd.grad(st["psf"], [j.w, j.a], st["g_psf"], retain_graph=True,
                                                   allow_unused=True)

    def net_adam():
        j.opt_net.step()

    def optics_adam():
        j.w.grad = st["g_w"]
        j.a.grad = st["g_a"] if st["g_a"] is not None else torch.zeros_like(j.a)
        j.opt_optics.step()
        j.clamp()

    wall0 = time.perf_counter()
    w, r = a.warmup, a.repeats
    t = {}
    t["optics forward"] = median_time(dev, w, r, optics)
    t["camera forward"] = median_time(dev, w, r, camera)
    t["network forward + backward"] = median_time(dev, w, r, network)
    t["camera backward"] = median_time(dev, w, r, camera_bwd)
    t["optics backward"] = median_time(dev, w, r, optics_bwd)
    t["network Adam step"] = median_time(dev, w, r, net_adam)
    t["optics Adam step"] = median_time(dev, w, r, optics_adam)
    st.clear()
    t["whole step"] = median_time(dev, w, r, j.step)
    wall = time.perf_counter() - wall0
    return j, t, wall


# ---------------------------------------------------------------------------------------------------
# Checks (float64)
# ---------------------------------------------------------------------------------------------------
def check(a):
    dev = torch.device(a.device)
    f64 = torch.float64
    torch.manual_seed(0)
    a.batch = min(a.batch, 2)
    j = Joint(a, dev, f64)
    c, o = j.c, j.optics
    ok = True
    print(f"check ({a.preset}, float64, batch {a.batch}, {a.mode}, {a.levels} levels, alpha {a.alpha})")

    # 1. energy: the propagation conserves it (Parseval: |TF| = 1), the crop keeps most of it, each PSF
    #    plane sums to 1 on both grids, and the 550 nm lens focuses on the axis.
    keep = {}
    ps = o.psf(o.lens_heights().to(dev), keep)
    e1 = keep["u1"].abs().pow(2).sum(dim=(1, 2))
    e2 = keep["u2"].abs().pow(2).sum(dim=(1, 2))
    parseval = ((e2 - e1).abs() / e1).max().item()
    frac = (keep["crop_energy"].flatten() / e1)
    s_nat = (keep["psf_native"].sum(dim=(1, 2)) - 1).abs().max().item()
    s_sen = (ps.sum(dim=(1, 2)) - 1).abs().max().item()
    b550 = round((550 - c["lam0_nm"]) / c["dlam_nm"])
    peak = divmod(int(ps[b550].argmax()), c["s"])
    res_err = (o.resample(keep["psf_native"]) - o.resample(keep["psf_native"], matrix=True)).abs().max().item()
    good = (parseval < 1e-12 and s_nat < 1e-12 and s_sen < 1e-12 and peak == (c["s"] // 2, c["s"] // 2)
            and res_err < 1e-14)
    ok &= good
    print(f"  energy: max |sum|U2|^2 - sum|U1|^2| / sum|U1|^2 = {parseval:.1e}; propagated energy inside the "
          f"N x N crop {frac.min().item():.4f} .. {frac.max().item():.4f} (bands); PSF plane sums - 1: native "
          f"{s_nat:.1e}, sensor {s_sen:.1e}; area integration by strided slices - as the matrix product "
          f"{res_err:.1e}; 550 nm lens peak at {peak} (axis {c['s'] // 2}) "
          f"{'ok' if good else 'FAIL'}")

    # 2. camera: a point scene at the centre images to srf @ PSF (alignment, linear convolution), no noise.
    h = w = c["s"]
    delta = torch.zeros(1, c["bands"], h, w, dtype=f64, device=dev)
    delta[0, :, h // 2, w // 2] = 1
    img = j.camera(ps, delta, noise=0)[0]
    want = torch.einsum("cb,byx->cyx", j.camera.srf, ps)
    s2 = c["s"] // 2
    ref = torch.zeros_like(img)
    ref[:, max(0, h // 2 - s2):h // 2 + s2, max(0, w // 2 - s2):w // 2 + s2] = want[:, :min(h, c["s"]), :min(w, c["s"])]
    cam_err = ((img - ref).abs().max() / want.abs().max()).item()
    good = cam_err < 1e-10
    ok &= good
    print(f"  camera: point scene -> srf @ PSF, max error / peak {cam_err:.1e} {'ok' if good else 'FAIL'}")

    # 3. optional: qdo's own sensor PSF of the same lens (an .npy from `qdo psf --design lens:550`).
    if a.qdo_psf:
        import numpy as np
        q = torch.from_numpy(np.load(a.qdo_psf)).to(f64).reshape(ps.shape)
        rel = ((q - ps.cpu()).norm() / q.norm()).item()
        mx = ((q - ps.cpu()).abs().max() / q.max()).item()
        good = rel < 1e-3
        ok &= good
        print(f"  against qdo's sensor PSF of lens:550 ({a.qdo_psf}): rel-L2 {rel:.1e}, max / peak {mx:.1e} "
              f"{'ok' if good else 'FAIL'}")

    # 4. gradient of the whole joint loss (quantizer, optics, camera, network, MAE + beta L_aq) w.r.t. 3
    #    ring weights and one level offset, against central differences. Fixed noise; the quantizer's
    #    rounding is piecewise constant, so the samples are taken away from its thresholds.
    with torch.no_grad():
        j.a.copy_(torch.tensor([0.0, 0.1, -0.08, 0.05][:a.levels] + [0.0] * max(0, a.levels - 4), dtype=f64))
    noise = c["sigma"] * torch.randn(a.batch, 3, h, w, dtype=f64, device=dev)

    def loss_fn():
        hh, laq = j.heights(j.w, j.a)
        rgb = j.camera(o.psf(hh), j.scenes, noise)
        return (j.net(rgb) - j.scenes).abs().mean() + j.beta * laq

    j.net.train()
    loss = loss_fn()
    gw, ga = torch.autograd.grad(loss, [j.w, j.a])
    lm1, eps = a.levels - 1, 1e-5
    rings = []
    for r in [c["n"] // 16, c["n"] // 5, c["n"] // 3, c["n"] // 2 - 10] + list(range(5, c["n"] // 2, 7)):
        u = (j.w[r].item() + 1) / 2
        if a.mode == "full" or abs((lm1 * u + 0.5) % 1 - 0.5) > 10 * eps:
            rings.append(r)
        if len(rings) == 3:
            break
    worst = 0.0
    for kind, i in [("w", r) for r in rings] + ([("a", 1)] if a.mode != "full" else []):
        t = j.w if kind == "w" else j.a
        with torch.no_grad():
            v = t[i].item()
            t[i] = v + eps
            lp = loss_fn().item()
            t[i] = v - eps
            lm = loss_fn().item()
            t[i] = v
        fd = (lp - lm) / (2 * eps)
        ad = (gw if kind == "w" else ga)[i].item()
        rel = abs(ad - fd) / max(abs(fd), 1e-12)
        worst = max(worst, rel)
        print(f"  dL/d{kind}[{i}]: autograd {ad:+.10e}, central difference {fd:+.10e}, rel. error {rel:.1e}")
    good = worst < 1e-5
    ok &= good
    print(f"  gradient check (eps {eps:g}): worst rel. error {worst:.1e} {'ok' if good else 'FAIL'}")
    print("check:", "all ok" if ok else "FAILED")
    return ok


def blas_info():
    cfg = torch.__config__.show()
    i = cfg.find("BLAS_INFO=")
    return cfg[i + 10:cfg.find(",", i)] if i >= 0 else "?"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", default="small", choices=["small", "paper"])
    ap.add_argument("--batch", type=int, default=4)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--warmup", type=int, default=1)
    ap.add_argument("--threads", type=int, default=os.cpu_count(), help="torch CPU threads (default: all cores)")
    ap.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    ap.add_argument("--depth", type=int, default=4, help="Res-UNet levels (qdo's `resunet`: 4; resunet:paper: 7)")
    ap.add_argument("--root", type=int, default=16, help="filters of the first level (qdo: 16; paper: 32)")
    ap.add_argument("--mode", default="qdo+a", choices=["qdo+a", "full"])
    ap.add_argument("--levels", type=int, default=4)
    ap.add_argument("--alpha", type=float, default=0.5, help="fixed blend weight of the quantized heights")
    ap.add_argument("--conv", default="linear", choices=["linear", "circular"])
    ap.add_argument("--srf-in-frequency", action="store_true",
                    help="sensor integration before the inverse FFT (3 inverse transforms per image, not bands)")
    ap.add_argument("--check", action="store_true", help="run the float64 correctness checks instead of timing")
    ap.add_argument("--qdo-psf", help="with --check: qdo's sensor PSF of lens:550 (bands x S x S .npy) to compare")
    ap.add_argument("--json", help="also write the timings and sizes to this JSON file")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    if a.check:
        sys.exit(0 if check(a) else 1)
    torch.manual_seed(0)
    j, t, wall = bench(a)
    sz = j.sizes()
    name = torch.cuda.get_device_name() if a.device == "cuda" else f"CPU, {torch.get_num_threads()} threads"
    print(f"torch {torch.__version__} ({name}); preset {a.preset}; mode {a.mode} (L={a.levels}, alpha={a.alpha}); "
          f"{a.conv} convolution; float32/complex64; median of {a.repeats} after {a.warmup} warm-up; BLAS "
          f"{blas_info()}")
    print("sizes: " + ", ".join(f"{k} {v}" for k, v in sz.items()) + f"; Res-UNet depth {a.depth}, root {a.root}")
    for k, v in t.items():
        print(f"  {k:28s} {v:9.4f} s  {100 * v / t['whole step']:5.1f} %")
    print(f"timed in {wall:.1f} s")
    if a.json:
        with open(a.json, "w") as f:
            json.dump(dict(preset=a.preset, batch=a.batch, blas=blas_info(), threads=torch.get_num_threads(),
                           device=a.device,
                           depth=a.depth, root=a.root, mode=a.mode, sizes=sz, times=t, wall_s=wall,
                           torch=torch.__version__), f, indent=1)


if __name__ == "__main__":
    main()
