"""qdo.torch: gradcheck of the PSF and camera operators in double on tiny configurations, the
results against the NumPy API, and the refusals (non-CPU tensors)."""
import numpy as np
import pytest

torch = pytest.importorskip("torch")

import qdo
import qdo.torch as qt
from conftest import tiny_config


def test_psf_operator_gradcheck(optics64):
    torch.manual_seed(0)
    h = (torch.rand(optics64.n, optics64.n, dtype=torch.float64) * optics64.h_max_m).requires_grad_()
    psf_op = qt.PSF(optics64)
    # Heights are ~1e-6 m: the step must be a small fraction of one (eps 1e-10 m = 1e-4 rad).
    assert torch.autograd.gradcheck(lambda x: psf_op(x), (h,), eps=1e-10, atol=1e-6, rtol=1e-4)
    np.testing.assert_allclose(psf_op(h).detach().numpy(), optics64.psf(h.detach().numpy()), rtol=0, atol=0)


def test_camera_operator_gradcheck(optics64):
    torch.manual_seed(1)
    s = optics64.sensor_size
    scene = torch.rand(1, optics64.bands, 5, 4, dtype=torch.float64, requires_grad=True)
    psf = torch.rand(optics64.bands, s, s, dtype=torch.float64)
    psf = (psf / psf.sum(dim=(1, 2), keepdim=True)).requires_grad_()
    cam = qt.Camera(optics64)
    assert torch.autograd.gradcheck(lambda a, b: cam(a, b), (scene, psf), eps=1e-6, atol=1e-8, rtol=1e-6)


def test_chain_heights_to_image_and_interleaved_graphs(optics64):
    torch.manual_seed(2)
    psf_op, cam = qt.PSF(optics64), qt.Camera(optics64)
    h1 = (torch.rand(optics64.n, optics64.n, dtype=torch.float64) * optics64.h_max_m).requires_grad_()
    h2 = (torch.rand(optics64.n, optics64.n, dtype=torch.float64) * optics64.h_max_m).requires_grad_()
    scene = torch.rand(2, optics64.bands, 6, 6, dtype=torch.float64)
    loss1 = cam(scene, psf_op(h1)).square().sum()
    loss2 = cam(scene, psf_op(h2)).square().sum()  # a second forward before the first backward
    loss1.backward()
    g1 = h1.grad.clone()
    h1.grad = None
    cam(scene, psf_op(h1)).square().sum().backward()  # alone: nothing in between
    np.testing.assert_allclose(g1.numpy(), h1.grad.numpy(), rtol=1e-12, atol=0)
    loss2.backward()
    assert torch.isfinite(h2.grad).all()


def test_float32_tensors_come_back_as_float32():
    o = qdo.Optics(config=tiny_config())
    h = torch.zeros(o.n, o.n, dtype=torch.float32, requires_grad=True)
    p = qt.PSF(o)(h)
    assert p.dtype == torch.float32 and p.shape == (o.bands, o.sensor_size, o.sensor_size)
    p.sum().backward()
    assert h.grad.dtype == torch.float32


def test_tensors_off_the_cpu_are_refused_with_the_way_out(optics64):
    h = torch.zeros(optics64.n, optics64.n, dtype=torch.float64, device="meta")
    with pytest.raises(ValueError, match=r"height_m: tensor on device 'meta'.*\.cpu\(\)"):
        qt.PSF(optics64)(h)
    with pytest.raises(ValueError, match="floating-point"):
        qt.PSF(optics64)(torch.zeros(optics64.n, optics64.n, dtype=torch.int64))


def test_graphs_on_one_optics_from_several_threads_get_their_own_gradients(optics64):
    """Each thread's forward and backward through one shared Optics: the backward's adjoint is
    of its own forward (re-run inside the locked adjoint call when another thread's forward came
    in between), so every gradient equals the serial one."""
    import threading

    torch.manual_seed(3)
    psf_op, cam = qt.PSF(optics64), qt.Camera(optics64)
    hs = [torch.rand(optics64.n, optics64.n, dtype=torch.float64) * optics64.h_max_m for _ in range(4)]
    scene = torch.rand(optics64.bands, 6, 5, dtype=torch.float64)

    def grads(h):
        h = h.clone().requires_grad_()
        s = scene.clone().requires_grad_()
        cam(s, psf_op(h)).square().sum().backward()
        return h.grad, s.grad

    serial = [grads(h) for h in hs]
    got = [[None] * 6 for _ in hs]
    barrier = threading.Barrier(len(hs))

    def work(k):
        barrier.wait()
        for r in range(6):
            got[k][r] = grads(hs[k])

    threads = [threading.Thread(target=work, args=(k,)) for k in range(len(hs))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for k in range(len(hs)):
        for r in range(6):
            assert got[k][r] is not None
            np.testing.assert_array_equal(got[k][r][0].numpy(), serial[k][0].numpy())
            np.testing.assert_array_equal(got[k][r][1].numpy(), serial[k][1].numpy())
