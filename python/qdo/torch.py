"""qdo's optics as PyTorch operators: autograd Functions whose backward calls qdo's hand-written,
gradient-checked adjoint kernels, and nn.Modules holding the configuration and device state.

- `PSF(optics)`: height map (n x n, metres) -> sensor-grid PSF stack (bands x S x S).
- `Camera(optics)`: (scene bands x H x W or batch x bands x H x W, PSF stack) -> sensor image(s).

Tensors cross through host memory: each call copies its inputs to float64 NumPy arrays and its
results back (BENCHMARKS "Python" measures what it costs). qdo runs on its own OpenCL device, so
only CPU tensors are taken; a tensor on another device (CUDA, meta) raises ValueError saying so,
nothing is copied behind the caller's back. Results come back in the input's dtype on the CPU.

Each Function keeps the count of its own forward call on the Optics: backward passes it with the
forward's inputs to the adjoint, which re-runs the forward inside the same locked call when
another forward ran since (two graphs alive at once, or another thread), so the adjoint is
always that of its own inputs, also when several threads share one Optics. Double backward is
not supported.

Wrong arguments raise ValueError naming them (a non-tensor, a tensor off the CPU, a
non-floating-point or non-strided tensor, a wrong shape), as the NumPy API does.
"""
import numpy as np
import torch
from torch.autograd.function import once_differentiable

from . import Optics

__all__ = ["PSF", "Camera", "PSFFunction", "CameraFunction", "to_numpy"]


def to_numpy(name, t):
    """A CPU tensor as a C-order float64 NumPy array (a copy); ValueError naming `name` otherwise."""
    if not isinstance(t, torch.Tensor):
        raise ValueError("%s: expected a torch.Tensor, got %s" % (name, type(t).__name__))
    if t.device.type != "cpu":
        raise ValueError("%s: tensor on device '%s'; qdo.torch takes CPU tensors (qdo computes on its own "
                         "OpenCL device): pass t.cpu(), and move the result back with .to(device)" % (name, t.device))
    if t.layout != torch.strided:
        raise ValueError("%s: layout %s; expected a dense (strided) tensor (use .to_dense())" % (name, t.layout))
    if not t.is_floating_point():
        raise ValueError("%s: dtype %s; expected a floating-point tensor" % (name, t.dtype))
    return np.ascontiguousarray(t.detach().resolve_neg().to(torch.float64).numpy())


def _optics(optics):
    if not isinstance(optics, Optics):
        raise ValueError("optics: expected a qdo.Optics, got %s" % type(optics).__name__)
    return optics


class PSFFunction(torch.autograd.Function):
    @staticmethod
    def forward(ctx, height_m, optics, object_points=None):
        psf, ctx.calls = _optics(optics)._o.psf_counted(to_numpy("height_m", height_m), object_points)
        ctx.optics = optics
        ctx.object_points = object_points
        ctx.save_for_backward(height_m)
        return torch.from_numpy(psf).to(height_m.dtype)

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_psf):
        (height_m,) = ctx.saved_tensors
        # The adjoint at this forward's heights: re-run inside the same locked call unless this
        # forward (count ctx.calls) is still the Optics' last one.
        g = ctx.optics._o.psf_vjp(to_numpy("grad_psf", grad_psf), to_numpy("height_m", height_m), ctx.calls,
                                  ctx.object_points)
        return torch.from_numpy(g).to(height_m.dtype), None, None


class CameraFunction(torch.autograd.Function):
    @staticmethod
    def forward(ctx, scene, psf, optics):
        s = to_numpy("scene", scene)
        p = to_numpy("psf", psf)
        if s.ndim not in (3, 4):
            raise ValueError("scene: %d dimensions; expected 3 (bands, H, W) or 4 (batch, bands, H, W)" % s.ndim)
        single = s.ndim == 3
        rgb, ctx.calls = _optics(optics)._o.camera_counted(s[None] if single else s, p)
        ctx.optics = optics
        ctx.single = single
        ctx.save_for_backward(scene, psf)
        return torch.from_numpy(rgb[0] if single else rgb).to(scene.dtype)

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_rgb):
        scene, psf = ctx.saved_tensors
        s, g = to_numpy("scene", scene), to_numpy("grad_rgb", grad_rgb)
        if ctx.single:
            s, g = s[None], g[None]
        # The adjoint of this forward's camera (re-run in the same locked call when needed).
        g_psf, g_scene = ctx.optics._o.camera_vjp(g, s, to_numpy("psf", psf), ctx.calls)
        if ctx.single:
            g_scene = g_scene[0]
        gs = torch.from_numpy(g_scene).to(scene.dtype) if ctx.needs_input_grad[0] else None
        gp = torch.from_numpy(g_psf).to(psf.dtype) if ctx.needs_input_grad[1] else None
        return gs, gp, None


class PSF(torch.nn.Module):
    """height map (n x n, metres) -> PSF stack (bands x S x S), differentiable in the heights.

    object_points (here or per call): passed through to Optics.psf: the stack is then
    points x bands x S x S and the gradient wrt the heights sums over the points."""

    def __init__(self, optics=None, object_points=None, **optics_kwargs):
        super().__init__()
        self.optics = _optics(optics) if optics is not None else Optics(**optics_kwargs)
        self.object_points = None if object_points is None else [tuple(p) for p in object_points]

    def forward(self, height_m, object_points=None):
        pts = self.object_points if object_points is None else [tuple(p) for p in object_points]
        return PSFFunction.apply(height_m, self.optics, pts)


class Camera(torch.nn.Module):
    """(scene, PSF stack) -> sensor image(s), differentiable in both."""

    def __init__(self, optics=None, **optics_kwargs):
        super().__init__()
        self.optics = _optics(optics) if optics is not None else Optics(**optics_kwargs)

    def forward(self, scene, psf):
        return CameraFunction.apply(scene, psf, self.optics)
