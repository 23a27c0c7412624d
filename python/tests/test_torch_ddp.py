"""qdo.torch inside torch.nn.parallel.DistributedDataParallel: a model whose
parameters are a DOE height map (through qdo.torch's PSF and Camera operators) and a 1x1
convolution decoder, trained data-parallel by 2 processes over gloo, each with its own qdo.Optics
(its own OpenCL context) and half of the batch. DDP averages the gradients over the processes, so
the gradients and the step it takes equal those of one process with the whole batch."""
import os
import tempfile

import numpy as np
import pytest

torch = pytest.importorskip("torch")
dist = pytest.importorskip("torch.distributed")
mp = pytest.importorskip("torch.multiprocessing")

import qdo
import qdo.torch as qt
from conftest import tiny_config

BATCH = 4


class Model(torch.nn.Module):
    """scenes (B x bands x H x W) -> the PSF of the height map, the sensor images, a 1x1 conv back to bands."""

    def __init__(self, optics, height_m):
        super().__init__()
        self.height_m = torch.nn.Parameter(height_m.clone())
        self.psf = qt.PSF(optics)
        self.camera = qt.Camera(optics)
        torch.manual_seed(7)
        self.decoder = torch.nn.Conv2d(3, optics.bands, 1).double()

    def forward(self, scenes):
        return self.decoder(self.camera(scenes, self.psf(self.height_m)))


def problem():
    """The model's starting heights and the whole batch (seeded: every process builds the same)."""
    optics = qdo.Optics(config=tiny_config(), precision="f64")
    g = torch.Generator().manual_seed(3)
    h0 = torch.rand(optics.n, optics.n, dtype=torch.float64, generator=g) * optics.h_max_m
    scenes = torch.rand(BATCH, optics.bands, 8, 8, dtype=torch.float64, generator=g)
    return optics, h0, scenes


def step(model, scenes, lr=1e-3):
    """One SGD step on the mean squared error; returns the loss and the gradients it took."""
    loss = torch.nn.functional.mse_loss(model(scenes), scenes)
    loss.backward()
    grads = [p.grad.detach().clone() for p in model.parameters()]
    with torch.no_grad():
        for p in model.parameters():
            p -= lr * p.grad
    return loss.item(), grads


def worker(rank, world, init_file, out_dir):
    dist.init_process_group("gloo", init_method="file://" + init_file, rank=rank, world_size=world)
    try:
        optics, h0, scenes = problem()
        model = torch.nn.parallel.DistributedDataParallel(Model(optics, h0))
        share = BATCH // world
        _, grads = step(model, scenes[rank * share:(rank + 1) * share])
        np.savez(os.path.join(out_dir, "rank%d.npz" % rank), *[g.numpy() for g in grads],
                 params=np.concatenate([p.detach().numpy().ravel() for p in model.parameters()]))
    finally:
        dist.destroy_process_group()


def test_ddp_with_two_processes_takes_the_step_of_one_process_with_the_whole_batch():
    if not dist.is_gloo_available():
        pytest.skip("torch.distributed without gloo")
    optics, h0, scenes = problem()
    model = Model(optics, h0)
    _, want = step(model, scenes)
    want_params = np.concatenate([p.detach().numpy().ravel() for p in model.parameters()])
    with tempfile.TemporaryDirectory() as tmp:
        mp.spawn(worker, args=(2, os.path.join(tmp, "init"), tmp), nprocs=2, join=True)
        for rank in range(2):
            got = np.load(os.path.join(tmp, "rank%d.npz" % rank))
            for i, w in enumerate(want):
                # The heights' gradient is ~1e6 larger than the decoder's (heights ~1e-6 m): relative
                # to each parameter's own scale; float64 sums in another order differ by ~1e-15.
                np.testing.assert_allclose(got["arr_%d" % i], w.numpy(), rtol=1e-10, atol=1e-12 * np.abs(w.numpy()).max())
            # Every process took the same step: the parameters agree with the one-process model.
            np.testing.assert_allclose(got["params"], want_params, rtol=1e-12, atol=0)
    # The heights' gradient is not zero: the optics take part in what DDP averages.
    assert np.abs(want[0].numpy()).max() > 0
