"""scripts/asbuilt_generator.py, the second generator of as-built cameras the fit experiments use
(EXPERIMENTS.md): its coordinates (a symmetric relief gives a symmetric PSF about the axis's pixel;
the relief's offset moves the relief as qdo fit's offset does), its truth file, its refusals. It
needs numpy and h5py only; a tiny system (N = 32 at 4 um, 3 bands, z = 2 mm) keeps it fast."""
import json
import os
import subprocess
import sys

import h5py
import numpy as np
import pytest

GEN = os.path.join(os.path.dirname(__file__), "..", "..", "scripts", "asbuilt_generator.py")
N = 32


def rings(n=N):
    """A 4-level relief of rings about pixel (n/2, n/2): symmetric under i -> n - i in each axis (row and
    column 0 at level 0, like the bare plate a moved relief brings in from outside)."""
    i = np.arange(n) - n // 2
    r = np.hypot(i[:, None], i[None, :])
    index = np.minimum((r / 2.5).astype(int) % 4, 3)
    levels = np.array([0.0, 400e-9, 800e-9, 1200e-9])
    h = levels[index]
    h[0, :] = h[:, 0] = 0.0  # row and column 0 have no mirror partner: level 0, as outside the DOE
    return h, levels


@pytest.fixture()
def system(tmp_path):
    cfg = {"n": N, "pitch_m": 4e-6, "bands": 3, "wavelength_start_nm": 450.0, "wavelength_step_nm": 100.0,
           "scene_distance_m": 1.0, "sensor_distance_m": 2e-3, "sensor_pitch_m": 8e-6, "material": "GLASS",
           "aperture_radius_m": 0.0, "aperture_edge": "inclusive", "propagator": "fresnel"}
    (tmp_path / "cfg.json").write_text(json.dumps(cfg))
    (tmp_path / "sellmeier.csv").write_text("# a test glass\nmaterial,B1,C1_um2,B2,C2_um2,B3,C3_um2\nGLASS,1.0,0.01,0,0,0,0\n")
    return tmp_path


def design(path, heights, levels):
    with h5py.File(path, "w") as f:
        f.create_dataset("height_m", data=heights).attrs["pitch_m"] = 4e-6
        f.create_dataset("levels_m", data=levels)
    return str(path)


def generate(system, design_file, out, *extra):
    cmd = [sys.executable, GEN, "--config", str(system / "cfg.json"), "--design", design_file, "--seed", "3",
           "--sellmeier", str(system / "sellmeier.csv"), "--out", str(system / out), *extra]
    return subprocess.run(cmd, capture_output=True, text=True)


def stack(system, out):
    with h5py.File(system / out / "psf.h5", "r") as f:
        return f["psf_sensor"][()], f["wavelengths_nm"][()]


def test_a_symmetric_relief_images_symmetrically_about_the_axis_pixel(system):
    h, lv = rings()
    d = design(system / "d.h5", h, lv)
    r = generate(system, d, "sym", "--etch-error-nm", "0", "--grid-um=-4,-4", "--fine", "2")
    assert r.returncode == 0, r.stderr
    psf, wl = stack(system, "sym")
    S = N * 4 // 8
    assert psf.shape == (3, S, S)
    np.testing.assert_allclose(wl, [450, 550, 650])
    np.testing.assert_allclose(psf.sum(axis=(1, 2)), 1, rtol=1e-12)
    # Pixel S/2 is centred on the axis (--grid-um -4,-4): columns S/2 + k and S/2 - k see the same light.
    c = S // 2
    for k in range(1, c):
        np.testing.assert_allclose(psf[:, :, c + k], psf[:, :, c - k], rtol=1e-9, atol=1e-12 * psf.max())
        np.testing.assert_allclose(psf[:, c + k, :], psf[:, c - k, :], rtol=1e-9, atol=1e-12 * psf.max())
    # The sensor grid moved by half a pixel: another image of the same light.
    r = generate(system, d, "half", "--etch-error-nm", "0", "--grid-um=0,0", "--fine", "2")
    assert r.returncode == 0, r.stderr
    assert np.abs(stack(system, "half")[0] - psf).max() > 0.05 * psf.max()


def test_the_offset_moves_the_relief_as_qdo_fits_offset_does(system):
    h, lv = rings()
    # A relief moved by +4 um (one DOE pixel) along x is the relief rolled by one column: H(x) = H0(x - dx).
    moved = design(system / "moved.h5", np.roll(h, 1, axis=1), lv)
    base = design(system / "base.h5", h, lv)
    assert generate(system, base, "off", "--etch-error-nm", "0", "--offset-um=4,0", "--fine", "2").returncode == 0
    assert generate(system, moved, "rolled", "--etch-error-nm", "0", "--fine", "2").returncode == 0
    np.testing.assert_allclose(stack(system, "off")[0], stack(system, "rolled")[0], rtol=1e-9, atol=1e-14)
    # ... and -4 um is its mirror image about the axis (the relief is symmetric).
    assert generate(system, base, "neg", "--etch-error-nm", "0", "--offset-um=-4,0", "--grid-um=-4,-4", "--fine", "2").returncode == 0
    assert generate(system, base, "pos", "--etch-error-nm", "0", "--offset-um=4,0", "--grid-um=-4,-4", "--fine", "2").returncode == 0
    neg, pos = stack(system, "neg")[0], stack(system, "pos")[0]
    # x -> -x about column S/2 maps columns 1 .. S-1 onto themselves (column 0's mirror lies outside the
    # window, so each band is compared normalised over columns 1 .. S-1).
    a, b = neg[:, :, 1:], pos[:, :, :0:-1]
    a, b = a / a.sum(axis=(1, 2), keepdims=True), b / b.sum(axis=(1, 2), keepdims=True)
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12 * b.max())
    assert np.abs(a - pos[:, :, 1:] / pos[:, :, 1:].sum(axis=(1, 2), keepdims=True)).max() > 0.05 * b.max()  # not symmetric itself


def test_truth_and_refusals(system):
    h, lv = rings()
    d = design(system / "d.h5", h, lv)
    r = generate(system, d, "t", "--etch-error-nm", "20", "--z-error-um", "50", "--offset-um=1.5,-1", "--grid-um=2,-3")
    assert r.returncode == 0, r.stderr
    t = json.loads((system / "t" / "truth.json").read_text())
    p, real = t["fit_parameters"], np.array(t["realised_levels_m"])
    assert np.all(np.abs(real - lv) <= 20e-9)
    assert p["level2"] == pytest.approx(real[2] - real[0] + lv[0])
    assert p["z"] == pytest.approx(2e-3 + 50e-6)
    assert (p["dx"], p["dy"]) == (pytest.approx(1.5e-6), pytest.approx(-1e-6))
    assert t["grid_displacement_px"] == [pytest.approx(0.25), pytest.approx(-0.375)]
    # Refused, naming the argument: a grid displacement that is no whole fine sample, an existing
    # --out (nothing of it touched), a design that is not quantized.
    r = generate(system, d, "g", "--grid-um=0.5,0", "--fine", "2")
    assert r.returncode != 0 and "--grid-um" in r.stderr
    assert not (system / "g").exists()
    before = (system / "t" / "truth.json").read_text()
    r = generate(system, d, "t")
    assert r.returncode != 0 and "--out" in r.stderr and "exists" in r.stderr
    assert (system / "t" / "truth.json").read_text() == before
    with h5py.File(system / "plain.h5", "w") as f:
        f.create_dataset("height_m", data=h)
    r = generate(system, str(system / "plain.h5"), "p")
    assert r.returncode != 0 and "levels_m" in r.stderr
    leftovers = [x for x in os.listdir(system) if x.startswith(".asbuilt_generator")]
    assert leftovers == []
