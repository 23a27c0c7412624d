"""Every public entry point refuses a wrong type, shape or value with ValueError (as the rest of
the API does), in a short message that names the argument and never holds an array's contents:
no TypeError from pybind11 listing every argument, no RuntimeError for a bad argument. Large
arrays ride along in some calls to show their contents stay out of the message."""
import numpy as np
import pytest

import qdo
from conftest import tiny_config

torch = pytest.importorskip("torch")
import qdo.torch as qt  # noqa: E402

OPTICS = qdo.Optics(config=tiny_config(), precision="f64")
N, B, S = OPTICS.n, OPTICS.bands, OPTICS.sensor_size
H = np.zeros((N, N))
PSF = OPTICS.psf(H)
BIG = np.random.default_rng(0).uniform(size=(300, 300))  # its repr would be thousands of characters
SCENE = np.full((B, 5, 4), 0.5)
SCENES = np.full((2, B, 8, 8), 0.5)
PRIOR = qdo.estimate_prior(SCENES, bins=4)
Y = np.full((3, 8, 8), 0.5)
SRF = OPTICS.srf()


class NotAPath:
    pass


def cases(tmp):
    """(id, call, the argument's name in the message)."""
    missing = str(tmp / "missing.h5")
    return [
        # module functions
        ("preset name int", lambda: qdo.preset(5), "name"),
        ("preset unknown", lambda: qdo.preset("nonsense"), "preset"),
        ("Optics preset int", lambda: qdo.Optics(preset=5), "preset"),
        ("Optics config int", lambda: qdo.Optics(config=5), "config"),
        ("Optics config not JSON", lambda: qdo.Optics(config={"n": BIG}), "config"),
        ("Optics config bad n", lambda: qdo.Optics(config=dict(tiny_config(), n=17)), "'n'"),
        ("Optics device int", lambda: qdo.Optics(config=tiny_config(), device=5), "device"),
        ("Optics device unknown", lambda: qdo.Optics(config=tiny_config(), device="no-such-device"), "device"),
        ("Optics precision", lambda: qdo.Optics(config=tiny_config(), precision="f16"), "precision"),
        ("Optics precision array", lambda: qdo.Optics(config=tiny_config(), precision=BIG), "precision"),
        ("psf list", lambda: OPTICS.psf([[0.0] * N] * N), "height_m"),
        ("psf None", lambda: OPTICS.psf(None), "height_m"),
        ("psf big", lambda: OPTICS.psf(BIG), "height_m"),
        ("psf float32", lambda: OPTICS.psf(H.astype(np.float32)), "height_m"),
        ("psf 3-D", lambda: OPTICS.psf(H[None]), "height_m"),
        ("psf empty", lambda: OPTICS.psf(np.zeros((0, 0))), "height_m"),
        ("psf nan", lambda: OPTICS.psf(np.full((N, N), np.nan)), "height_m"),
        ("psf out of range", lambda: OPTICS.psf(np.full((N, N), 1.0)), "height_m"),
        ("sensor_psf str", lambda: OPTICS.sensor_psf("heights"), "height_m"),
        ("psf_vjp shape", lambda: OPTICS.psf_vjp(BIG), "grad_psf"),
        ("psf_vjp heights shape", lambda: OPTICS.psf_vjp(PSF, BIG), "height_m"),
        ("camera scene list", lambda: OPTICS.camera([[0.0]], PSF), "scene"),
        ("camera scene 2-D", lambda: OPTICS.camera(BIG, PSF), "scene"),
        ("camera scene 5-D", lambda: OPTICS.camera(SCENES[None], PSF), "scene"),
        ("camera scene bands", lambda: OPTICS.camera(np.zeros((B + 1, 4, 4)), PSF), "scene"),
        ("camera scene empty", lambda: OPTICS.camera(np.zeros((B, 0, 4)), PSF), "scene"),
        ("camera psf shape", lambda: OPTICS.camera(SCENE, BIG[None]), "psf"),
        ("camera psf int", lambda: OPTICS.camera(SCENE, PSF.astype(int)), "psf"),
        ("camera_vjp grad 2-D", lambda: OPTICS.camera_vjp(BIG), "grad_rgb"),
        ("camera_vjp scene without psf", lambda: OPTICS.camera_vjp(np.zeros((3, 5, 4)), SCENE), "psf"),
        ("camera_vjp grad of another size", lambda: (OPTICS.camera(SCENE, PSF), OPTICS.camera_vjp(np.zeros((3, 6, 4)))),
         "grad_rgb"),
        ("read_psf path int", lambda: OPTICS.read_psf(5), "path"),
        ("read_psf missing", lambda: OPTICS.read_psf(missing), "missing.h5"),
        ("quantize heights list", lambda: qdo.quantize([[0.0]], 1e-6, 4), "height_m"),
        ("quantize h_max str", lambda: qdo.quantize(BIG, "1e-6", 4), "h_max_m"),
        ("quantize h_max array", lambda: qdo.quantize(BIG, BIG, 4), "h_max_m"),
        ("quantize h_max negative", lambda: qdo.quantize(BIG, -1.0, 4), "h_max_m"),
        ("quantize h_max nan", lambda: qdo.quantize(BIG, float("nan"), 4), "h_max_m"),
        ("quantize levels float", lambda: qdo.quantize(BIG, 1e-6, 2.5), "levels"),
        ("quantize levels str", lambda: qdo.quantize(BIG, 1e-6, "4"), "levels"),
        ("quantize levels huge", lambda: qdo.quantize(BIG, 1e-6, 10**12), "levels"),
        ("quantize placement int", lambda: qdo.quantize(BIG, 1e-6, 4, 5), "placement"),
        ("quantize placement unknown", lambda: qdo.quantize(BIG, 1e-6, 4, "sideways"), "placement"),
        ("lens_design optics", lambda: qdo.lens_design(BIG), "optics"),
        ("lens_design wavelength str", lambda: qdo.lens_design(OPTICS, "550"), "wavelength_nm"),
        ("lens_design wavelength negative", lambda: qdo.lens_design(OPTICS, -550.0), "wavelength_nm"),
        ("lens_design wavelength outside the glass", lambda: qdo.lens_design(OPTICS, 50.0), "wavelength_nm"),
        ("estimate_prior 3-D", lambda: qdo.estimate_prior(SCENES[0]), "scenes"),
        ("estimate_prior bins str", lambda: qdo.estimate_prior(SCENES, "16"), "bins"),
        ("estimate_prior bins huge", lambda: qdo.estimate_prior(SCENES, 10**9), "bins"),
        ("wiener y channels", lambda: qdo.wiener_decode(np.zeros((4, 8, 8)), PSF, SRF, PRIOR, 0.01), "y"),
        ("wiener psf not square", lambda: qdo.wiener_decode(Y, np.zeros((B, 4, 5)), SRF, PRIOR, 0.01), "psf"),
        ("wiener srf shape", lambda: qdo.wiener_decode(Y, PSF, BIG, PRIOR, 0.01), "srf"),
        ("wiener prior bands", lambda: qdo.wiener_decode(Y, PSF, SRF, np.zeros((4, 2, 2)), 0.01), "prior"),
        ("wiener sigma negative", lambda: qdo.wiener_decode(Y, PSF, SRF, PRIOR, -1.0), "noise_sigma"),
        ("wiener sigma str", lambda: qdo.wiener_decode(Y, PSF, SRF, PRIOR, "0.1"), "noise_sigma"),
        ("wiener boundary unknown", lambda: qdo.wiener_decode(Y, PSF, SRF, PRIOR, 0.01, boundary="wrap"), "boundary"),
        ("wiener linear sigma 0", lambda: qdo.wiener_decode(Y, PSF, SRF, PRIOR, 0.0, boundary="linear"), "noise_sigma"),
        ("wiener sigma 0 singular", lambda: qdo.wiener_decode(Y, np.zeros_like(PSF), SRF, np.zeros_like(PRIOR), 0.0),
         "noise_sigma"),
        ("read_cube path int", lambda: qdo.read_cube(5), "path"),
        ("read_cube path object", lambda: qdo.read_cube(NotAPath()), "path"),
        ("read_cube missing", lambda: qdo.read_cube(missing), "missing.h5"),
        ("read_cube key int", lambda: qdo.read_cube(missing, key=5), "key"),
        ("read_cube config int", lambda: qdo.read_cube(missing, config=5), "config"),
        ("read_cube resample str", lambda: qdo.read_cube(missing, resample_bands="yes"), "resample_bands"),
        ("write_cube path None", lambda: qdo.write_cube(None, SCENE, [1, 2, 3]), "path"),
        ("write_cube cube 2-D", lambda: qdo.write_cube(str(tmp / "c.h5"), BIG, [1.0]), "cube"),
        ("write_cube wavelengths count", lambda: qdo.write_cube(str(tmp / "c.h5"), SCENE, [500.0]), "wavelengths_nm"),
        ("write_cube wavelengths str", lambda: qdo.write_cube(str(tmp / "c.h5"), SCENE, "abc"), "wavelengths_nm"),
        ("read_design path list", lambda: qdo.read_design([1, 2]), "path"),
        ("read_design missing", lambda: qdo.read_design(missing), "missing.h5"),
        ("write_design heights not square", lambda: qdo.write_design(str(tmp / "d.h5"), BIG[:, :10], 1e-6), "height_m"),
        ("write_design pitch negative", lambda: qdo.write_design(str(tmp / "d.h5"), BIG, -1e-6), "pitch_m"),
        ("write_design pitch array", lambda: qdo.write_design(str(tmp / "d.h5"), BIG, BIG), "pitch_m"),
        ("write_design levels str", lambda: qdo.write_design(str(tmp / "d.h5"), BIG, 1e-6, ["a"]), "levels_m"),
        ("write_design levels nan", lambda: qdo.write_design(str(tmp / "d.h5"), BIG, 1e-6, [float("nan")]), "levels_m"),
        ("read_h5 name int", lambda: qdo.read_h5(missing, 5), "name"),
        ("read_h5 path None", lambda: qdo.read_h5(None, "/x"), "path"),
        ("write_rgb_png channels", lambda: qdo.write_rgb_png(str(tmp / "a.png"), np.zeros((4, 3, 3))), "rgb"),
        ("write_rgb_png path int", lambda: qdo.write_rgb_png(5, np.zeros((3, 3, 3))), "path"),
        ("write_psf_figure pitch 0", lambda: qdo.write_psf_figure(str(tmp / "m.png"), "t", SCENE, (), 0), "pitch_m"),
        ("write_psf_figure wavelengths count",
         lambda: qdo.write_psf_figure(str(tmp / "m.png"), "t", SCENE, [1.0], 1e-6), "wavelengths_nm"),
        ("write_psf_figure wavelengths int", lambda: qdo.write_psf_figure(str(tmp / "m.png"), "t", SCENE, 5, 1e-6), "wavelengths_nm"),
        ("write_psf_figure not png", lambda: qdo.write_psf_figure(str(tmp / "m.jpg"), "t", SCENE, (), 1e-6), "png"),
        ("write_height_figure 3-D", lambda: qdo.write_height_figure(str(tmp / "m.png"), "t", SCENE, 1e-6), "height_m"),
        # qdo.torch
        ("torch PSF optics", lambda: qt.PSF(BIG), "optics"),
        ("torch Camera optics", lambda: qt.Camera("small"), "optics"),
        ("torch PSF array", lambda: qt.PSF(OPTICS)(BIG), "height_m"),
        ("torch PSF shape", lambda: qt.PSF(OPTICS)(torch.zeros(N, N + 2, dtype=torch.float64)), "height_m"),
        ("torch PSF int tensor", lambda: qt.PSF(OPTICS)(torch.zeros(N, N, dtype=torch.int64)), "height_m"),
        ("torch PSF sparse", lambda: qt.PSF(OPTICS)(torch.zeros(N, N, dtype=torch.float64).to_sparse()), "height_m"),
        ("torch Camera scene 2-D", lambda: qt.Camera(OPTICS)(torch.zeros(5, 4, dtype=torch.float64), torch.from_numpy(PSF)),
         "scene"),
        ("torch Camera psf shape", lambda: qt.Camera(OPTICS)(torch.from_numpy(SCENE), torch.zeros(B, S, S + 1, dtype=torch.float64)),
         "psf"),
        ("torch Camera psf array", lambda: qt.Camera(OPTICS)(torch.from_numpy(SCENE), PSF), "psf"),
    ]


CASE_IDS = [c[0] for c in cases(__import__("pathlib").Path("."))]


@pytest.mark.parametrize("case_id", CASE_IDS)
def test_a_bad_argument_is_a_short_value_error_naming_it(case_id, tmp_path):
    _, call, name = next(c for c in cases(tmp_path) if c[0] == case_id)
    with pytest.raises(ValueError) as e:
        call()
    msg = str(e.value)
    assert type(e.value) is ValueError, type(e.value)
    assert name in msg, msg
    assert len(msg) < 300 or case_id == "Optics device unknown", (len(msg), msg[:300])  # that one lists the devices
    assert "array(" not in msg and "[[" not in msg and "Invoked with" not in msg, msg[:300]


def test_the_refusals_happen_before_any_device_work():
    calls = OPTICS._o.psf_calls, OPTICS._o.camera_calls
    for bad in (BIG, H.astype(np.float32), np.full((N, N), np.inf), [[0.0]]):
        with pytest.raises(ValueError):
            OPTICS.psf(bad)
        with pytest.raises(ValueError):
            OPTICS.camera(SCENE, bad)
    assert (OPTICS._o.psf_calls, OPTICS._o.camera_calls) == calls
