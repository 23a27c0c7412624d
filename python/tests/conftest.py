"""Shared fixtures of the Python package's tests (pytest; scripts/test.sh runs them after the C++
suite). The device is QDO_DEVICE's (CI: PoCL's CPU device)."""
import os

import numpy as np
import pytest

import qdo


def tiny_config(n=16, bands=3, noise=0.0):
    """A configuration small enough for gradcheck: n x n DOE, `bands` bands over 450-550 nm
    (tests/common.hpp's tiny_config), noiseless unless asked."""
    return {
        "preset": "small",
        "n": n,
        "padding_px": n // 4,
        "bands": bands,
        "wavelength_start_nm": 450.0,
        "wavelength_step_nm": 100.0 / (bands - 1) if bands > 1 else 10.0,
        "sensor_distance_m": 0.0125 * n / 256.0,
        "srf_interpolate": True,
        "read_noise_sigma": noise,
        "full_well_photons": 0.0,
    }


@pytest.fixture(scope="session")
def optics64():
    return qdo.Optics(config=tiny_config(), precision="f64")


@pytest.fixture(scope="session")
def qdo_binary():
    path = os.environ.get("QDO_BINARY", os.path.join(os.path.dirname(__file__), "..", "..", "build", "qdo"))
    if not os.path.isfile(path):
        pytest.skip("the qdo binary (QDO_BINARY or build/qdo) is not built")
    return path


@pytest.fixture
def rng():
    return np.random.default_rng(2026)
