"""qdo.read_cube reads a scene file as `qdo simulate --scene FILE` does (the same library calls):
the radiance rule (HDR divided by its maximum, slight negatives clipped, strong ones refused),
the band axis against the configuration (refused, or reordered / resampled with
resample_bands) and the band count; checked value by value and against the command's image and
refusal messages on the same files."""
import json
import struct
import subprocess
import zlib

import numpy as np
import pytest

import qdo
from conftest import tiny_config


def write_gray_png(path, img):
    """An 8-bit grayscale PNG of img (H x W, integers 0..255), written by hand (no imaging library)."""
    h, w = img.shape
    raw = b"".join(b"\x00" + bytes(int(v) for v in row) for row in img)

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0)) +
                chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


@pytest.fixture(scope="module")
def setup(tmp_path_factory, qdo_binary):
    """A tiny configuration (3 bands, 450/500/550 nm) on disk, its Optics and a design file."""
    SIMULATE["binary"] = qdo_binary
    d = tmp_path_factory.mktemp("cube")
    cfg = tiny_config()
    (d / "c.json").write_text(json.dumps(cfg))
    o = qdo.Optics(config=cfg, precision="f64")
    rng = np.random.default_rng(7)
    h = qdo.quantize(rng.uniform(0, o.h_max_m, (o.n, o.n)), o.h_max_m, 4)
    qdo.write_design(d / "d.h5", h, o.config["pitch_m"])
    return d, o, h


SIMULATE = {}  # the qdo binary (the setup fixture sets it)


def simulate(d, scene, *extra, out="out"):
    """`qdo simulate` of the design on `scene` under the tiny configuration: (returncode, stderr, rgb)."""
    run = subprocess.run([SIMULATE["binary"], "simulate", "--config", str(d / "c.json"), "--design", str(d / "d.h5"), "--scene",
                          str(scene), "--precision", "f64", "--out", str(d / out), *extra], capture_output=True, text=True)
    rgb = qdo.read_h5(d / out / "sensor.h5", "/rgb") if run.returncode == 0 else None
    return run.returncode, run.stderr, rgb


def test_an_hdr_file_with_slight_negatives_and_a_reversed_axis_is_the_command_s_scene(setup, rng):
    d, o, h = setup
    wl = o.wavelengths_nm  # 450, 500, 550
    cube = rng.uniform(0, 5.0, (3, 12, 10))  # HDR: up to 5 times full scale
    cube[1, 2, 3] = -0.004                   # dark-frame noise, within the tolerance
    cube[2, 0, 0] = 5.0                      # the maximum
    # Stored with a descending band axis: plane k of the file is at wl[2 - k].
    qdo.write_cube(d / "rev.h5", cube[::-1], wl[::-1])
    got = qdo.read_cube(d / "rev.h5", config=o, resample_bands=True)
    want = np.maximum(cube, 0.0) / 5.0
    assert got.shape == (3, 12, 10) and got.dtype == np.float64 and got.flags.c_contiguous
    np.testing.assert_allclose(got, want, rtol=1e-15, atol=0)
    assert got.min() == 0.0 and got.max() == 1.0
    # The command reads the same scene: its image is the Python camera's of read_cube's cube, and
    # not that of the file's values as stored.
    rc, err, rgb = simulate(d, d / "rev.h5", "--resample-bands")
    assert rc == 0, err
    assert "divided by that maximum" in err and "clipped to 0" in err
    mine = o.camera(got, o.psf(h))
    np.testing.assert_allclose(rgb, np.minimum(mine, 1.0), rtol=0, atol=1e-12)
    raw = o.camera(np.ascontiguousarray(cube[::-1]), o.psf(h))
    assert np.abs(raw - rgb).max() > 0.1


def test_a_reversed_axis_without_resampling_is_refused_as_the_command_refuses_it(setup, rng):
    d, o, _ = setup
    cube = rng.uniform(0, 1, (3, 6, 5))
    qdo.write_cube(d / "rev2.h5", cube, o.wavelengths_nm[::-1])
    with pytest.raises(ValueError) as e:
        qdo.read_cube(d / "rev2.h5", config=o)
    msg = str(e.value)
    assert "(descending)" in msg and "450" in msg and "550" in msg and "resample" in msg
    rc, err, _ = simulate(d, d / "rev2.h5", out="out_rev2")
    assert rc == 2 and msg in err
    # Resampled, a descending axis on the configured centres is an exact reordering.
    np.testing.assert_array_equal(qdo.read_cube(d / "rev2.h5", config=o, resample_bands=True), cube[::-1])


def test_strongly_negative_values_are_refused_with_the_command_s_message(setup, rng):
    d, o, _ = setup
    cube = rng.uniform(0, 1, (3, 6, 5))
    cube[0, 1, 1] = -0.5
    qdo.write_cube(d / "neg.h5", cube, o.wavelengths_nm)
    with pytest.raises(ValueError) as e:
        qdo.read_cube(d / "neg.h5", config=o)
    msg = str(e.value)
    assert "neg.h5" in msg and "negative radiance" in msg and "-0.5" in msg
    rc, err, _ = simulate(d, d / "neg.h5", out="out_neg")
    assert rc == 2 and msg in err


def test_values_in_range_come_back_as_stored_and_other_grids_are_refused(setup, rng):
    d, o, _ = setup
    cube = rng.uniform(0, 1, (3, 7, 4))
    qdo.write_cube(d / "ok.h5", cube, o.wavelengths_nm)
    np.testing.assert_array_equal(qdo.read_cube(d / "ok.h5", config=o), cube)
    # The configuration as a dict or a JSON file is the same as the Optics.
    np.testing.assert_array_equal(qdo.read_cube(d / "ok.h5", config=tiny_config()), cube)
    np.testing.assert_array_equal(qdo.read_cube(d / "ok.h5", config=str(d / "c.json")), cube)
    # A maximum within 1e-6 of full scale is clipped, not a reason to rescale the cube.
    near = cube.copy()
    near[0, 0, 0] = 1.0 + 5e-7
    qdo.write_cube(d / "near.h5", near, o.wavelengths_nm)
    got = qdo.read_cube(d / "near.h5", config=o)
    assert got[0, 0, 0] == 1.0 and np.array_equal(got.ravel()[1:], cube.ravel()[1:])
    # Default configuration: the preset "small" (31 bands, 400..700 nm), as `qdo simulate`.
    with pytest.raises(ValueError, match=r"ok\.h5.*31"):
        qdo.read_cube(d / "ok.h5")
    cube31 = rng.uniform(0, 1, (31, 3, 2))
    qdo.write_cube(d / "c31.h5", cube31, np.arange(400.0, 701.0, 10.0))
    np.testing.assert_array_equal(qdo.read_cube(d / "c31.h5"), cube31)
    # Another band count or a shifted grid: refused naming the file and both.
    four = tiny_config(bands=4)
    with pytest.raises(ValueError, match=r"ok\.h5.*the file's bands are 3 bands.*the configuration's 4 bands"):
        qdo.read_cube(d / "ok.h5", config=four)
    qdo.write_cube(d / "shift.h5", cube, o.wavelengths_nm + 5.0)
    with pytest.raises(ValueError, match=r"shift\.h5.*455.*450"):
        qdo.read_cube(d / "shift.h5", config=o)
    with pytest.raises(ValueError, match=r"'/nothing'"):
        qdo.read_cube(d / "ok.h5", key="/nothing", config=o)


def test_a_png_band_folder_is_read_as_the_command_reads_it(setup):
    d, o, h = setup
    folder = d / "pngs"
    folder.mkdir()
    bands = [np.arange(20).reshape(4, 5) * (k + 3) % 256 for k in range(3)]
    for k, b in enumerate(bands):
        write_gray_png(folder / ("scene_ms_%02d.png" % (k + 1)), b)
    got = qdo.read_cube(folder, config=o)
    np.testing.assert_allclose(got, np.stack(bands) / 255.0, rtol=1e-15, atol=0)
    rc, err, rgb = simulate(d, folder, out="out_png")
    assert rc == 0, err
    np.testing.assert_allclose(rgb, np.minimum(o.camera(got, o.psf(h)), 1.0), rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match=r"key.*PNG band folder"):
        qdo.read_cube(folder, key="cube", config=o)
    with pytest.raises(ValueError, match=r"pngs': 3 PNG band files, 4 expected"):
        qdo.read_cube(folder, config=tiny_config(bands=4))
