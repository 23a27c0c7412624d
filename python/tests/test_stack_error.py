"""scripts/stack_error.py, the per-band difference of two PSF stacks that docs/built-camera.md
quotes for calibrate's halo cut: the relative L2 of the unit-sum planes and each stack's light
beyond a radius, against values computed here by hand; refusals name the file."""
import os
import subprocess
import sys

import h5py
import numpy as np

TOOL = os.path.join(os.path.dirname(__file__), "..", "..", "scripts", "stack_error.py")


def write(path, a):
    with h5py.File(path, "w") as f:
        f.create_dataset("psf_sensor", data=a)


def run(*args):
    return subprocess.run([sys.executable, TOOL, *map(str, args)], capture_output=True, text=True)


def test_relative_l2_and_outer_light(tmp_path):
    s = 16
    true = np.zeros((2, s, s))
    true[:, 8, 8] = 3.0          # the core
    true[:, 0, 0] = 1.0          # light far out: 1/4 of each plane, at radius 8 sqrt(2)
    meas = true.copy()
    meas[1, 0, 0] = 0.0          # band 1 measured without it: the halo cut
    write(tmp_path / "m.h5", meas)
    write(tmp_path / "t.h5", true)
    r = run(tmp_path / "m.h5", tmp_path / "t.h5", "--radius", 8)
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    rows = [l.split("|") for l in lines[2:4]]
    want_line = f"relative L2 over 2 bands: median {np.hypot(1 - 0.75, 0.25) / np.hypot(0.75, 0.25) / 2:.3f}, "
    assert lines[-1].startswith(want_line) and lines[-1].endswith("(band 1)"), lines[-1]
    # band 0 equal; band 1: unit-sum planes (1, 0) vs (0.75, 0.25) at two pixels
    want = np.hypot(1 - 0.75, 0.25) / np.hypot(0.75, 0.25)
    assert float(rows[0][2]) == 0.0
    assert abs(float(rows[1][2]) - want) < 5e-4
    assert float(rows[1][3]) == 0.0 and abs(float(rows[1][4]) - 0.25) < 5e-4


def test_refusals_name_the_file(tmp_path):
    write(tmp_path / "a.h5", np.ones((2, 8, 8)))
    write(tmp_path / "b.h5", np.ones((3, 8, 8)))
    r = run(tmp_path / "a.h5", tmp_path / "b.h5")
    assert r.returncode == 2 and "one shape" in r.stderr
    with h5py.File(tmp_path / "c.h5", "w") as f:
        f.create_dataset("other", data=np.ones(3))
    r = run(tmp_path / "c.h5", tmp_path / "a.h5")
    assert r.returncode == 2 and "c.h5" in r.stderr and "psf_sensor" in r.stderr
