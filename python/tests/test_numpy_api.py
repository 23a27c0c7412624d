"""The NumPy API of qdo: configuration, shapes, refusals, and agreement with the `qdo` command on
the same inputs."""
import json
import os
import re
import subprocess

import numpy as np
import pytest

import qdo
from conftest import tiny_config


def test_version_is_the_projects():
    cmake = open(os.path.join(os.path.dirname(__file__), "..", "..", "CMakeLists.txt")).read()
    assert qdo.__version__ == re.search(r"project\(qdo VERSION ([0-9.]+)", cmake).group(1)


def test_version_matches_the_command(qdo_binary):
    out = subprocess.run([qdo_binary, "--version"], capture_output=True, text=True).stdout
    assert qdo.__version__ in out


def test_devices_and_configuration_sources(tmp_path):
    devs = qdo.devices()
    assert devs and all({"name", "selector", "fp64"} <= set(d) for d in devs)
    small = qdo.Optics(preset="small")
    assert small.config["n"] == 256 and small.bands == 31
    cfg = tiny_config()
    path = tmp_path / "c.json"
    path.write_text(json.dumps(cfg))
    a, b = qdo.Optics(config=cfg), qdo.Optics(config=str(path))
    assert a.config == b.config and a.n == 16
    assert qdo.preset("paper")["n"] == 1024


def test_bad_configurations_are_refused_with_the_commands_messages(tmp_path):
    with pytest.raises(ValueError, match="bands"):
        qdo.Optics(config=dict(tiny_config(), bands=0))
    with pytest.raises(ValueError, match="nonsense"):
        qdo.Optics(config=dict(tiny_config(), nonsense=1))
    with pytest.raises(ValueError, match="not found"):
        qdo.Optics(config=str(tmp_path / "missing.json"))
    with pytest.raises(ValueError, match="not both"):
        qdo.Optics(preset="small", config=tiny_config())
    with pytest.raises(ValueError, match="precision"):
        qdo.Optics(preset="small", precision="f16")


def test_psf_shapes_and_normalisation(optics64, rng):
    h = rng.uniform(0, optics64.h_max_m, (optics64.n, optics64.n))
    psf = optics64.psf(h)
    s = optics64.sensor_size
    assert psf.shape == (optics64.bands, s, s) and psf.dtype == np.float64
    np.testing.assert_allclose(psf.sum(axis=(1, 2)), 1.0, rtol=1e-12)
    rgb_psf = optics64.sensor_psf(h)
    assert rgb_psf.shape == (3, s, s)
    np.testing.assert_allclose(rgb_psf.sum(axis=(1, 2)), 1.0, rtol=1e-12)


@pytest.mark.parametrize("bad, match", [
    (np.zeros((16, 16), dtype=np.float32), "height_m: dtype float32; expected float64"),
    (np.zeros((16, 15)), r"height_m: shape \(16, 15\); expected \(16, 16\)"),
    (np.zeros((2, 16, 16)), "height_m: 3 dimensions; expected 2"),
    (np.full((16, 16), np.nan), "height_m: non-finite value"),
    ([[0.0] * 16] * 16, "height_m: expected a NumPy float64 array"),
])
def test_bad_arrays_are_refused_naming_the_argument(optics64, bad, match):
    calls = optics64._o.psf_calls
    with pytest.raises(ValueError, match=match):
        optics64.psf(bad)
    assert optics64._o.psf_calls == calls  # refused before any device work


def qdo_psf_file(qdo_binary, folder, cfg, h, pitch_m):
    """`qdo psf --precision f64` of the height map h under the configuration cfg, run in `folder`
    (created): the path of the psf.h5 it writes."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "c.json").write_text(json.dumps(cfg))
    qdo.write_design(folder / "d.h5", h, pitch_m)
    run = subprocess.run([qdo_binary, "psf", "--config", str(folder / "c.json"), "--design", str(folder / "d.h5"),
                          "--precision", "f64", "--out", str(folder / "out")], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    return folder / "out" / "psf.h5"


def test_psf_equals_the_qdo_command_on_the_same_design(tmp_path, qdo_binary, rng):
    cfg = tiny_config()
    o = qdo.Optics(config=cfg, precision="f64")
    h = qdo.quantize(rng.uniform(0, o.h_max_m, (o.n, o.n)), o.h_max_m, 4)
    ref = qdo.read_h5(qdo_psf_file(qdo_binary, tmp_path, cfg, h, o.config["pitch_m"]), "/psf_sensor")
    np.testing.assert_allclose(o.psf(h), ref, rtol=0, atol=1e-14)


def test_a_psf_file_as_the_camera_s_psf_and_other_grids_refused(tmp_path, qdo_binary, rng):
    cfg = tiny_config()
    o = qdo.Optics(config=cfg, precision="f64")
    h = qdo.quantize(rng.uniform(0, o.h_max_m, (o.n, o.n)), o.h_max_m, 4)
    psf = o.read_psf(qdo_psf_file(qdo_binary, tmp_path, cfg, h, o.config["pitch_m"]))
    assert psf.shape == (o.bands, o.sensor_size, o.sensor_size)
    np.testing.assert_allclose(psf, o.psf(h), rtol=0, atol=1e-14)
    scene = rng.uniform(0, 1, (o.bands, 12, 10))
    np.testing.assert_allclose(o.camera(scene, psf), o.camera(scene, o.psf(h)), rtol=0, atol=1e-13)
    # A stack of another band count (4 bands) or sensor grid (n = 24) is refused, naming both.
    for key, value in (("bands", 4), ("n", 24)):
        other = tiny_config(**{key: value})
        oo = qdo.Optics(config=other, precision="f64")
        hh = np.full((oo.n, oo.n), 0.5 * oo.h_max_m)
        path = qdo_psf_file(qdo_binary, tmp_path / ("other_" + key), other, hh, oo.config["pitch_m"])
        s_file, s_here = oo.sensor_size, o.sensor_size
        with pytest.raises(ValueError) as e:
            o.read_psf(path)
        msg = str(e.value)
        assert "the file holds" in msg and "the configuration's sensor grid" in msg
        assert f"{oo.bands} x {s_file} x {s_file}" in msg and f"{o.bands} x {s_here} x {s_here}" in msg
    with pytest.raises(ValueError, match="missing.h5"):
        o.read_psf(tmp_path / "missing.h5")


def test_psf_from_takes_the_commands_psf_spec(qdo_binary, tmp_path, rng):
    # The commands' --psf / --design: a stack file is read_psf's, a design file is psf() of its
    # heights, lens:NM is the lens; one of the two, checked before any device work.
    cfg = tiny_config()
    o = qdo.Optics(config=cfg, precision="f64")
    h = qdo.quantize(rng.uniform(0, o.h_max_m, (o.n, o.n)), o.h_max_m, 4)
    path = qdo_psf_file(qdo_binary, tmp_path, cfg, h, o.config["pitch_m"])
    np.testing.assert_array_equal(o.psf_from(psf=path), o.read_psf(path))
    np.testing.assert_allclose(o.psf_from(design=str(tmp_path / "d.h5")), o.psf(h), rtol=0, atol=1e-14)
    flat = o.psf_from(design="flat")
    np.testing.assert_allclose(flat, o.psf(np.zeros((o.n, o.n))), rtol=0, atol=1e-14)
    # A lens focuses: its on-axis value beats the flat plate's in every band.
    lens = o.psf_from(design="lens:550")
    c = o.sensor_size // 2
    assert lens.shape == flat.shape and np.all(lens[:, c, c] > flat[:, c, c])
    with pytest.raises(ValueError, match="not both"):
        o.psf_from(psf=path, design="lens:550")
    with pytest.raises(ValueError, match="psf"):
        o.psf_from()
    with pytest.raises(ValueError, match="design"):
        o.psf_from(design="lens:-3")


def test_capture_runs_the_simulate_chain_rgb_and_raw(rng):
    # Noiseless, the pipeline's clean image is the camera operator's.
    cfg = tiny_config()
    o = qdo.Optics(config=cfg, precision="f64")
    psf = o.psf(rng.uniform(0, o.h_max_m, (o.n, o.n)))
    scene = rng.uniform(0, 0.5, (o.bands, 10, 8))
    f = o.capture(scene, psf, noise=False)
    assert set(f) == {"clean", "rgb", "clipped_fraction"}
    np.testing.assert_allclose(f["clean"], o.camera(scene, psf), rtol=0, atol=1e-13)
    np.testing.assert_array_equal(f["rgb"], np.minimum(f["clean"], 1.0))
    # The sensor as built: RGGB, 12 bits, black level 64 DN, gain 1. Without noise each code value
    # is the clean value of its mosaic colour, scaled to [64, 4095] and rounded.
    raw_cfg = dict(cfg, cfa="rggb", bit_depth=12, black_level_dn=64.0, gain=1.0)
    r = qdo.Optics(config=raw_cfg, precision="f64")
    fr = r.capture(scene, psf, raw=True, noise=False, demosaic="mhc")
    assert fr["raw_dn"].shape == (1, 10, 8) and fr["demosaiced"].shape == (3, 10, 8)
    colour = np.array([[0, 1], [1, 2]])  # RGGB
    rows, cols = np.indices((10, 8))
    v = fr["clean"][colour[rows % 2, cols % 2], rows, cols]
    np.testing.assert_array_equal(fr["raw_dn"][0], np.clip(np.rint(64 + v * (4095 - 64)), 0, 4095))
    # A flat grey scene under circular convolution stays flat in each colour, so both demosaics
    # give back the clean image, to the 12-bit rounding.
    c = qdo.Optics(config=dict(raw_cfg, convolution="circular"), precision="f64")
    flat = np.full((c.bands, 10, 8), 0.3)
    for method in ("bilinear", "mhc"):
        ff = c.capture(flat, psf, raw=True, noise=False, demosaic=method)
        np.testing.assert_allclose(ff["demosaiced"], ff["clean"], rtol=0, atol=0.5 / (4095 - 64) + 1e-12)
    with pytest.raises(ValueError, match="cfa"):
        o.capture(scene, psf, raw=True)
    with pytest.raises(ValueError, match="demosaic"):
        r.capture(scene, psf, raw=True, demosaic="nearest")
    with pytest.raises(ValueError, match="scene"):
        o.capture(scene[:2], psf)


def test_camera_and_its_adjoint(optics64, rng):
    s = optics64.sensor_size
    psf = optics64.psf(rng.uniform(0, optics64.h_max_m, (optics64.n, optics64.n)))
    scene = rng.uniform(0, 1, (2, optics64.bands, 9, 7))
    rgb = optics64.camera(scene, psf)
    assert rgb.shape == (2, 3, 9, 7)
    assert optics64.camera(scene[0], psf).shape == (3, 9, 7)
    # Dot-product test of the adjoint (linear in the scene for a fixed PSF, and in the PSF).
    rgb = optics64.camera(scene, psf)
    g = rng.normal(size=rgb.shape)
    g_psf, g_scene = optics64.camera_vjp(g)
    assert g_psf.shape == (optics64.bands, s, s) and g_scene.shape == scene.shape
    lhs = float(np.sum(rgb * g))
    np.testing.assert_allclose(lhs, float(np.sum(scene * g_scene)), rtol=1e-12)
    np.testing.assert_allclose(lhs, float(np.sum(psf * g_psf)), rtol=1e-12)
    with pytest.raises(ValueError, match="scene"):
        optics64.camera(rng.uniform(0, 1, (2, optics64.bands + 1, 9, 7)), psf)


def test_wiener_decoder_linear_boundary_models_a_capture_as_a_camera_makes_it(rng):
    # A capture as a camera makes it: the centre h x w of the circular blur of a scene larger by
    # the PSF's size S, so light from around the window lands inside it. boundary="linear" solves
    # for that larger scene (MaskedWienerDecoder); "circular" takes the window as the whole scene.
    # Measured: 0.032 against 0.159 relative RMS; the bound is under a third.
    o = qdo.Optics(config=dict(tiny_config(), convolution="circular"), precision="f64")
    b, s, h = o.bands, o.sensor_size, 24

    def smooth(n):  # smooth random scenes n x n: a 7-tap box filter of uniform noise
        x = rng.uniform(0, 1, (b, n + 6, n + 6))
        k = np.ones(7) / 7
        for ax in (1, 2):
            x = np.apply_along_axis(lambda v: np.convolve(v, k, "valid"), ax, x)
        return x

    prior = qdo.estimate_prior(np.stack([smooth(h) for _ in range(8)]), bins=6)
    psf = rng.uniform(0, 1, (b, s, s))
    psf /= psf.sum(axis=(1, 2), keepdims=True)
    big = smooth(h + s)
    a = s // 2
    y = o.camera(big, psf)[:, a:a + h, a:a + h]
    truth = big[:, a:a + h, a:a + h]
    err = {bd: np.sqrt(np.mean((qdo.wiener_decode(y, psf, o.srf(), prior, 1e-3, boundary=bd) - truth) ** 2))
           / np.sqrt(np.mean(truth ** 2)) for bd in ("circular", "linear")}
    assert err["linear"] < err["circular"] / 3


def test_wiener_decoder_recovers_a_scene_through_a_sharp_psf(optics64, rng):
    b, hh, ww = optics64.bands, 12, 12
    scenes = rng.uniform(0.2, 0.8, (6, b, hh, ww))
    prior = qdo.estimate_prior(scenes, bins=4)
    assert prior.shape == (4, b, b)
    s = optics64.sensor_size
    delta = np.zeros((b, s, s))
    delta[:, s // 2, s // 2] = 1.0
    srf = optics64.srf()
    o = qdo.Optics(config=dict(tiny_config(), convolution="circular"), precision="f64")
    y = o.camera(scenes[0], delta)
    x = qdo.wiener_decode(y, delta, srf, prior, 1e-3)
    assert x.shape == (b, hh, ww)
    # 3 channels cannot determine 3 bands exactly under noise regularisation, but the estimate
    # is far closer than the prior mean alone.
    err = np.sqrt(np.mean((x - scenes[0]) ** 2))
    assert err < 0.5 * np.sqrt(np.mean((scenes[0] - scenes.mean(axis=0)) ** 2)) + 0.05
