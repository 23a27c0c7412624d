"""scripts/supersample_design.py, which puts a design on a DOE grid K times finer for `qdo psf`
(scripts/experiments_generator_converge.sh): every DOE pixel becomes the K x K fine samples around
its centre (qdo's grids are centred on a sample), the configuration keeps the physical aperture and
gets a window that samples the transfer function, and an even K or a bad input writes nothing."""
import json
import os
import subprocess
import sys

import h5py
import numpy as np

TOOL = os.path.join(os.path.dirname(__file__), "..", "..", "scripts", "supersample_design.py")
N = 16


def make_inputs(tmp_path, n=N):
    cfg = {"n": n, "pitch_m": 4e-6, "padding_px": n // 4, "bands": 31, "wavelength_start_nm": 400.0,
           "wavelength_step_nm": 10.0, "sensor_distance_m": 2e-3, "aperture_radius_m": 0.0, "preset": "small"}
    (tmp_path / "cfg.json").write_text(json.dumps(cfg))
    h = np.random.default_rng(5).uniform(0, 1e-6, size=(n, n))
    with h5py.File(tmp_path / "d.h5", "w") as f:
        f.create_dataset("height_m", data=h).attrs["pitch_m"] = 4e-6
    return cfg, h


def run(tmp_path, k, *extra):
    cmd = [sys.executable, TOOL, "--config", str(tmp_path / "cfg.json"), "--design", str(tmp_path / "d.h5"), "--k", str(k),
           "--out-config", str(tmp_path / "out" / "cfg.json"), "--out-design", str(tmp_path / "out" / "d.h5"), *extra]
    return subprocess.run(cmd, capture_output=True, text=True)


def read(tmp_path):
    with h5py.File(tmp_path / "out" / "d.h5", "r") as f:
        fine, pitch = f["height_m"][()], f["height_m"].attrs["pitch_m"]
    return fine, pitch, json.loads((tmp_path / "out" / "cfg.json").read_text())


def test_each_pixel_becomes_the_k_by_k_samples_around_its_centre(tmp_path):
    cfg, h = make_inputs(tmp_path)
    r = run(tmp_path, 3)
    assert r.returncode == 0, r.stderr
    fine, pitch, out = read(tmp_path)
    k, nk = 3, 3 * N
    assert fine.shape == (nk, nk) and out["n"] == nk
    assert abs(pitch - 4e-6 / 3) < 1e-18 and abs(out["pitch_m"] - 4e-6 / 3) < 1e-18
    # DOE pixel i is centred at (i - N/2) pitch = fine sample k (i - N/2) + nk/2; its K x K block.
    for i in range(N):
        for j in range(N):
            ci, cj = k * (i - N // 2) + nk // 2, k * (j - N // 2) + nk // 2
            block = fine[max(ci - 1, 0):ci + 2, max(cj - 1, 0):cj + 2]
            assert np.all(block == h[i, j]), (i, j)
    # The last fine sample, (nk/2 - 1) pitch/k + ..., lies beyond pixel N - 1's edge: zero relief.
    assert np.all(fine[-1, :] == 0) and np.all(fine[:, -1] == 0)


def test_the_configuration_keeps_the_aperture_and_samples_the_transfer_function(tmp_path):
    cfg, _ = make_inputs(tmp_path)
    r = run(tmp_path, 3, "--band-step", "5")
    assert r.returncode == 0, r.stderr
    _, _, out = read(tmp_path)
    # The default aperture radius, (n/2 - 1) pitch of the original grid, written out.
    assert abs(out["aperture_radius_m"] - (N / 2 - 1) * 4e-6) < 1e-15
    assert "preset" not in out
    # Every 5th band: 400 .. 700 nm.
    assert out["bands"] == 7 and out["wavelength_step_nm"] == 50.0
    window = out["n"] + 2 * out["padding_px"]
    assert window % 32 == 0
    assert window * out["pitch_m"] ** 2 >= 700e-9 * cfg["sensor_distance_m"]
    assert out["padding_px"] >= 3 * cfg["padding_px"]


def test_k_one_keeps_the_heights(tmp_path):
    _, h = make_inputs(tmp_path)
    assert run(tmp_path, 1).returncode == 0
    fine, _, out = read(tmp_path)
    assert np.array_equal(fine, h) and out["n"] == N and out["bands"] == 31


def test_refusals_write_nothing(tmp_path):
    make_inputs(tmp_path)
    for k, extra, what in [(2, [], "--k 2"), (17, [], "--k 17"), (3, ["--band-step", "0"], "--band-step 0")]:
        r = run(tmp_path, k, *extra)
        assert r.returncode == 2 and what in r.stderr
        assert not (tmp_path / "out").exists() or not os.listdir(tmp_path / "out")
    with h5py.File(tmp_path / "d.h5", "w") as f:
        f.create_dataset("height_m", data=np.zeros((N + 1, N + 1)))
    r = run(tmp_path, 3)
    assert r.returncode == 2 and "the configuration's n is 16" in r.stderr
    assert not (tmp_path / "out").exists() or not os.listdir(tmp_path / "out")
