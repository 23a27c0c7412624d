"""Object points: qdo.Optics.psf(height_m, object_points=...) returns
points x bands x S x S from one batched pass; qdo.torch passes the points through and the gradient
wrt the heights sums over them; bad points are refused before any work."""
import math

import numpy as np
import pytest

import qdo
from conftest import tiny_config

POINTS = [(0.05, 0.0, 0.0), (0.1, 1.5, -1.0), (float("inf"), -1.0, 0.5)]


def heights(o, seed):
    return np.random.default_rng(seed).uniform(0, o.h_max_m, (o.n, o.n))


def test_psf_with_object_points_is_points_by_bands_and_each_point_matches_its_own_config(optics64):
    h = heights(optics64, 0)
    stack = optics64.psf(h, object_points=POINTS)
    s = optics64.sensor_size
    assert stack.shape == (3, optics64.bands, s, s)
    np.testing.assert_allclose(stack.sum(axis=(2, 3)), 1.0, rtol=0, atol=1e-12)
    for q, (d, tx, ty) in enumerate(POINTS):
        cfg = tiny_config()
        if tx == 0 and ty == 0:
            cfg["scene_distance_m"] = "inf" if math.isinf(d) else d
        else:
            cfg["object_points"] = [["inf" if math.isinf(d) else d, tx, ty]]
        one = qdo.Optics(config=cfg, precision="f64")
        single = one.psf(h)
        assert single.ndim == (3 if tx == 0 and ty == 0 else 4)
        np.testing.assert_allclose(stack[q], single.reshape(stack[q].shape), rtol=0, atol=1e-14)
    # Without object points: the configuration's one on-axis point, bands x S x S as before.
    assert optics64.psf(h).shape == (optics64.bands, s, s)


def test_psf_vjp_with_object_points_sums_the_points(optics64):
    h = heights(optics64, 1)
    s = optics64.sensor_size
    g = np.random.default_rng(2).uniform(-1, 1, (3, optics64.bands, s, s))
    total = optics64.psf_vjp(g, h, object_points=POINTS)
    parts = sum(optics64.psf_vjp(g[q:q + 1], h, object_points=[POINTS[q]]) for q in range(3))
    np.testing.assert_allclose(total, parts, rtol=1e-10, atol=1e-10 * np.abs(total).max())
    # Directional finite difference of <g, psf> along a random direction.
    d = np.random.default_rng(3).uniform(-1, 1, h.shape) * 1e-12
    fd = (np.sum(g * optics64.psf(h + d, POINTS)) - np.sum(g * optics64.psf(h - d, POINTS))) / 2
    assert abs(fd - np.sum(total * d)) <= 1e-6 * abs(fd) + 1e-12
    with pytest.raises(ValueError, match="grad_psf"):
        optics64.psf_vjp(g[0], h, object_points=POINTS)


@pytest.mark.parametrize(
    "points, words",
    [
        ([(0.0, 0, 0)], "object_points\\[0\\] distance"),
        ([(1.0, 0, 0), (-2.0, 0, 0)], "object_points\\[1\\] distance"),
        ([(1.0, 45.0, 0)], "supports field angles up to"),
        ([(1.0, float("nan"), 0)], "field_x_deg"),
        ([], "empty"),
        ([(1.0, 0)], "object_points\\[0\\]"),
        ("far", "object_points"),
    ],
)
def test_bad_object_points_are_refused(optics64, points, words):
    h = heights(optics64, 4)
    calls = optics64._o.psf_calls
    with pytest.raises(ValueError, match=words):
        optics64.psf(h, object_points=points)
    assert optics64._o.psf_calls == calls  # refused before any device work


def test_torch_passes_object_points_through():
    torch = pytest.importorskip("torch")
    import qdo.torch as qt

    o = qdo.Optics(config=tiny_config(n=16, bands=2), precision="f64")
    torch.manual_seed(0)
    h = (torch.rand(o.n, o.n, dtype=torch.float64) * o.h_max_m).requires_grad_()
    op = qt.PSF(o, object_points=POINTS[1:])
    out = op(h)
    assert tuple(out.shape) == (2, o.bands, o.sensor_size, o.sensor_size)
    np.testing.assert_array_equal(out.detach().numpy(), o.psf(h.detach().numpy(), POINTS[1:]))
    # eps 1e-11 m: at 1e-10 one entry's central difference (of 256 x 256) is off by 1.6e-4 relative
    # from truncation (it converges to the adjoint's value as eps shrinks: 1e-9, 1e-10, 1e-11 m give
    # 1.6e-2, 1.6e-4, 1.7e-6); atol 1e-5 for the rounding of the smaller step.
    assert torch.autograd.gradcheck(lambda x: op(x), (h,), eps=1e-11, atol=1e-5, rtol=1e-4)
    # Per call, and the gradient is the sum over the points.
    w = torch.rand(2, o.bands, o.sensor_size, o.sensor_size, dtype=torch.float64)
    (op(h, object_points=POINTS[1:]) * w).sum().backward()
    want = o.psf_vjp(w.numpy(), h.detach().numpy(), object_points=POINTS[1:])
    np.testing.assert_allclose(h.grad.numpy(), want, rtol=1e-12, atol=0)
