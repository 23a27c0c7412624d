"""qdo from Python: the OpenCL optics of qdo as NumPy functions (this module) and PyTorch
operators (`qdo.torch`).

Everything runs in qdo's C++ library (the one the `qdo` command uses), on an OpenCL device; no
physics is re-implemented here. Arrays are NumPy float64 (results in C order):

- height maps: N x N, metres of glass relief (REFERENCE §1);
- PSF stacks: bands x S x S on the sensor grid, each band summing to 1 (as `qdo psf` writes
  `/psf_sensor`);
- scenes: bands x H x W (or batch x bands x H x W), values in [0, 1];
- sensor images: 3 x H x W (or batch x 3 x H x W).

Arguments. An array argument must be a NumPy array of dtype float64, judged by kind and size:
any byte order ('<f8', '=f8', '>f8') and any memory layout (slices with steps, transposes,
Fortran order, arrays h5py returns) are accepted and copied to C order when needed; float32,
integer and other dtypes are refused (convert with .astype(numpy.float64)). A wrong type,
dtype, shape, range or a non-finite value raises ValueError naming the argument, its value or
shape and what is allowed (a short message, never the array's contents), before any allocation
or device work; an array too large to copy raises MemoryError naming it. Configuration and file
errors are the same messages as the command line's.

Threads. An Optics may be shared by threads: each call that uses the device (psf, psf_vjp,
camera, camera_vjp) releases the GIL and holds the lock of the OpenCL device (one per device,
shared by every Optics on it) for the whole call, so they run one at a time. psf_vjp(grad) and
camera_vjp(grad) without forward arguments take the adjoint of the last forward call of any
thread; pass the forward's arguments (psf_vjp(grad, height_m), camera_vjp(grad, scene, psf)) to
get the adjoint at those inputs in one atomic call. qdo.torch does that itself.
"""
import json
import os

import numpy as np

from . import _qdo

__version__ = _qdo.__version__

__all__ = ["__version__", "Optics", "devices", "data_root", "dataset_path", "preset", "quantize", "lens_design", "estimate_prior",
           "wiener_decode", "read_cube", "write_cube", "read_design", "write_design", "read_h5", "write_rgb_png",
           "write_psf_figure", "write_height_figure"]


def devices():
    """Every OpenCL device: a list of dicts (platform, name, type, driver_version, fp64,
    compute_units, selector). Pass a selector, "cpu", "gpu" or a name substring as `device`."""
    return _qdo.devices()


def data_root(root=None):
    """Where qdo looks for datasets, as `qdo data` reports it: a dict with the root's path, its
    source ("QDO_DATA", "settings file ...", "user data folder", "source tree", ...), whether it
    exists, and every place considered. root: use this folder instead (as --data-root)."""
    return _qdo.data_root(root)


def dataset_path(name, root=None):
    """The folder of a named dataset ("cave", "cave_train", "icvl", ...) under the data root;
    ValueError naming the folder looked in when it is missing. A path (with '/' or '.') is
    returned as given. root: use this folder instead of the data root."""
    return _qdo.dataset_path(name, root)


def preset(name):
    """The configuration of a preset ("small", "paper") as a dict (the keys of `qdo config`)."""
    return json.loads(_qdo.preset_json(name))


def _config_text(preset_name, config):
    """(JSON text, origin) of preset= or config= (a dict or the path of a JSON file)."""
    if preset_name is not None and config is not None:
        raise ValueError("Optics: give preset= or config=, not both")
    if config is None:
        name = "small" if preset_name is None else preset_name
        if not isinstance(name, str):
            raise ValueError("preset: expected a str ('small' or 'paper'), got %s" % type(name).__name__)
        return _qdo.preset_json(name), "preset " + name
    if isinstance(config, dict):
        try:
            return json.dumps(config), "config (dict)"
        except (TypeError, ValueError) as e:
            raise ValueError("config: the dict is not JSON (%s)" % str(e)[:120]) from None
    if isinstance(config, (str, os.PathLike)):
        path = os.fspath(config)
        if not os.path.isfile(path):
            raise ValueError("config: file '%s' not found" % path)
        with open(path, "r", encoding="utf-8") as f:
            return f.read(), path
    raise ValueError("config: %s; expected a dict or the path of a JSON file" % type(config).__name__)


def _as_batch(name, a, rank, what, first):
    """A (rank)-D array as a batch of one, else the (rank + 1)-D array as it is; `what` names
    the axes of one item, e.g. "bands, H, W", whose first has length `first`."""
    if not isinstance(a, np.ndarray):
        raise ValueError("%s: expected a NumPy float64 array, got %s" % (name, type(a).__name__))
    if a.ndim not in (rank, rank + 1):
        raise ValueError("%s: %d dimensions; expected %d (%s) or %d (batch, %s)" % (name, a.ndim, rank, what, rank + 1, what))
    if a.shape[a.ndim - rank] != first:
        item = what.replace(what.split(",")[0], str(first), 1)
        raise ValueError("%s: shape %s; expected (%s) or (batch, %s)" % (name, a.shape, item, item))
    if a.ndim == rank:
        return a[None], True
    return a, False


def _name(v):
    return type(v).__name__


class Optics:
    """A qdo configuration on an OpenCL device: the PSF chain and the camera operator, with their
    adjoints.

    Optics(preset="small") | Optics(config={...} or "config.json"), device="" (default choice:
    QDO_DEVICE, else the first GPU, else the CPU), precision="f32" | "f64".

    Thread-safe: psf, psf_vjp, camera and camera_vjp each release the GIL and hold the device's
    lock (shared by every Optics on that OpenCL device) for the whole call, so calls from several
    threads run one at a time, each with the result it would have alone. An adjoint without
    forward arguments pairs with the last forward call of any thread: from several threads, pass
    the forward's arguments (psf_vjp(g, height_m), camera_vjp(g, scene, psf)).
    """

    def __init__(self, preset=None, config=None, device="", precision="f32"):
        text, origin = _config_text(preset, config)
        if not isinstance(precision, str):
            raise ValueError("precision: expected 'f32' or 'f64', got %s" % _name(precision))
        if precision not in ("f32", "f64"):
            raise ValueError("precision: %r; expected 'f32' or 'f64'" % (precision[:40],))
        self._o = _qdo.Optics(text, origin, device, precision)

    @property
    def config(self):
        """The full configuration (dict, the keys of `qdo config`)."""
        return json.loads(self._o.config_json)

    @property
    def device(self):
        return self._o.device_name

    @property
    def precision(self):
        return self._o.precision

    @property
    def n(self):
        """DOE samples per side (height maps are n x n)."""
        return self._o.n

    @property
    def bands(self):
        return self._o.bands

    @property
    def sensor_size(self):
        """S: PSF stacks are bands x S x S."""
        return self._o.sensor_size

    @property
    def wavelengths_nm(self):
        return np.asarray(self._o.wavelengths_nm)

    @property
    def h_max_m(self):
        """The height of one 2π phase step at the base wavelength (quantizers' full scale)."""
        return self._o.h_max_m

    def srf(self):
        """The sensor response, 3 x bands, rows summing to 1."""
        return self._o.srf()

    def psf(self, height_m, object_points=None):
        """height_m (n x n float64, metres) -> the sensor-grid PSF stack (bands x S x S).

        object_points: a sequence of (distance_m, field_x_deg, field_y_deg) point sources
        (distance > 0 or float("inf"); the point sits at (d tan θx, d tan θy)), or None for the
        configuration's own ("object_points" key, default one on-axis point at scene_distance_m).
        With object points the stack is points x bands x S x S, all computed in one batched pass;
        every plane lies on the sensor window centred on the optical axis (an off-axis point's PSF
        near its chief-ray image (-z tan θx, -z tan θy)). Angles beyond what the sampling supports
        and distances <= 0 raise ValueError naming the point and the limit."""
        return self._o.psf(height_m, object_points)

    def psf_vjp(self, grad_psf, height_m=None, object_points=None):
        """Adjoint of psf(): dL/dPSF (bands x S x S, or points x bands x S x S with object
        points) -> dL/dheight (n x n, per metre; the points' contributions summed).

        Without height_m: at the last psf() call of any thread with these object points
        (ValueError when there was none). With height_m: at those heights, the forward re-run
        inside the same locked call, so no other thread's psf() can come in between (one extra
        forward)."""
        return self._o.psf_vjp(grad_psf, height_m, 0, object_points)

    def read_psf(self, path):
        """A PSF stack file as `qdo psf` writes it (psf.h5, /psf_sensor) -> bands x S x S, for
        camera() in place of psf(height_m): a measured or otherwise computed PSF. Checked against
        this configuration (bands, sensor size, pitch, non-negative bands summing to 1); a file
        of other bands or size raises ValueError naming both."""
        return self._o.read_psf(path)

    def psf_from(self, psf=None, design=None):
        """The PSF as qdo's commands name it (their --psf and --design): psf a PSF stack file
        (as read_psf reads it), or design "lens:NM", "flat" or a design .h5 file (a run's, or
        qdo fit's as-built design.h5), simulated here -> bands x S x S. Exactly one of the two;
        both are read and checked before any device work (ValueError naming the argument)."""
        return self._o.psf_from(psf, design)

    def sensor_psf(self, height_m):
        """The PSF as the RGB sensor sees it: 3 x S x S, srf · psf (each channel sums to 1)."""
        p = self.psf(height_m)
        return np.tensordot(self.srf(), p, axes=(1, 0))

    def camera(self, scene, psf):
        """Sensor image(s) of scene(s) through a PSF stack on the device: scene bands x H x W
        (or batch x bands x H x W), psf bands x S x S -> 3 x H x W (or batch x 3 x H x W).
        The configuration's convolution (linear by default), sensor response and noise."""
        batch, single = _as_batch("scene", scene, 3, "bands, H, W", self.bands)
        out = self._o.camera(batch, psf)
        return out[0] if single else out

    def capture(self, scene, psf, raw=False, noise=True, demosaic="bilinear"):
        """One scene (bands x H x W) through the whole capture chain `qdo simulate` runs (the
        camera, the sensor's shot and read noise, the full-scale clip, and with raw=True the sensor
        as built: mosaic, black level, gain, bit depth, then the demosaic): a dict with "clean"
        (3 x H x W before noise and clip), "rgb" (after), "clipped_fraction", and with raw
        "raw_dn" (1 x H x W code values) and "demosaiced" (3 x H x W, linear; demosaic "bilinear"
        or "mhc"). raw=True needs a configuration whose cfa is a mosaic."""
        return self._o.capture(scene, psf, bool(raw), bool(noise), demosaic)

    def camera_vjp(self, grad_rgb, scene=None, psf=None):
        """Adjoint of camera()'s noiseless camera: dL/dimage (3 x H x W or batch x 3 x H x W)
        -> (dL/dpsf bands x S x S, dL/dscene shaped as grad_rgb with bands for 3).

        Without scene and psf: of the last camera() call of any thread. With both: of
        camera(scene, psf), re-run inside the same locked call (atomic across threads)."""
        g, single = _as_batch("grad_rgb", grad_rgb, 3, "3, H, W", 3)
        if scene is not None and single:
            scene, _ = _as_batch("scene", scene, 3, "bands, H, W", self.bands)
        g_psf, g_scene = self._o.camera_vjp(g, scene, psf)
        return g_psf, (g_scene[0] if single else g_scene)


def quantize(height_m, h_max_m, levels, placement="inclusive"):
    """Uniform L-level quantization of a height map (REFERENCE §2): n x n -> n x n.
    h_max_m > 0 (metres), levels an integer in [2, 65536], placement "inclusive" or "wrapped"."""
    return _qdo.quantize(height_m, h_max_m, levels, placement)


def lens_design(optics, wavelength_nm=550.0):
    """The Fresnel lens of `optics`' configuration focused at wavelength_nm (n x n heights)."""
    if not isinstance(optics, Optics):
        raise ValueError("optics: expected a qdo.Optics, got %s" % _name(optics))
    return _qdo.lens_design(optics._o.config_json, wavelength_nm)


def estimate_prior(scenes, bins=16):
    """The Wiener decoder's spectral prior from training scenes (count x bands x H x W):
    bins x bands x bands, one second-moment matrix per radial frequency bin. bins: an integer
    in [2, 4096] with bins x bands x bands <= 2^27; checked before anything is allocated."""
    return _qdo.estimate_prior(scenes, bins)


def wiener_decode(y, psf, srf, prior, noise_sigma, boundary="circular"):
    """Linear MMSE reconstruction: sensor image y (3 x H x W), PSF stack (bands x S x S), srf
    (3 x bands), prior (from estimate_prior), noise_sigma >= 0 -> bands x H x W.

    boundary: "circular" takes y as a circular blur (the scene repeats; one division per
    frequency); "linear" takes y as a camera records it, the window of a larger scene whose light
    reaches it from around (the Wiener objective for a scene (H + S) x (W + S) from y's pixels, by
    conjugate gradients, `qdo reconstruct --boundary linear` on one tile; noise_sigma > 0)."""
    return _qdo.wiener_decode(y, psf, srf, prior, noise_sigma, boundary)


def read_cube(path, key="", config=None, resample_bands=False):
    """A hyperspectral scene file as `qdo simulate --scene PATH` reads it: the same library calls
    in the same order, so the same array, the same notes on stderr and the same refusals.

    path: a cube file (MATLAB .mat v5/v7.3, or HDF5 with /cube) or a folder of PNG bands (CAVE).
    key: the variable / dataset of the cube ("" = found automatically; --key); must be "" for a
    folder. config: the configuration the scene is for, whose bands and band centres it must
    have: an Optics, a configuration dict or the path of a JSON file (--config), or None for the
    preset "small" (the command's default, --preset small). resample_bands: --resample-bands.

    Returns a new float64 C-order array, bands x H x W, bands = the configuration's, band b at
    its wavelength b (ascending as configured), values in [0, 1]:
      1. Layout: the band axis is the axis of length `bands` (for .mat files MATLAB's last axis
         first, for HDF5 the first axis first).
      2. Scale: integer data divided by its type's maximum (uint16: 65535), a dataset named
         `rad` whose maximum is <= 4095 (ICVL) by 4095, floating-point data as stored.
      3. Band axis: a file that stores its band centres (wavelengths_nm, wavelengths or bands,
         nm) must match the configured ones within 0.5 nm, else ValueError naming both grids;
         with resample_bands=True it is interpolated linearly onto the configured grid instead
         (so a descending axis comes back in ascending order). A file without an axis is taken
         to be on the configured grid. A PNG folder's files are bands in file-number order.
      4. Radiance rule (conform_radiance): a non-finite value or one below -0.01 raises
         ValueError naming the file; values in [-0.01, 0) are set to 0; when the maximum exceeds
         1 (HDR or unscaled data) the whole cube is divided by it (a maximum within 1e-6 of 1 is
         clipped to 1). Steps 3 and 4 print the command's notes on stderr.
    A band count that does not fit the configuration raises ValueError naming the file, the
    shape found and the bands expected."""
    if isinstance(config, Optics):
        text, origin = config._o.config_json, "Optics.config"
    elif config is None:
        text, origin = _qdo.preset_json("small"), "preset small"
    else:
        text, origin = _config_text(None, config)
    return _qdo.read_cube(path, key, text, origin, resample_bands)


def write_cube(path, cube, wavelengths_nm):
    """A cube (bands x H x W float64) as qdo's HDF5 scene file: /cube and /wavelengths_nm (one
    centre per band, nm), atomically. Values are written as given (read_cube applies its rules
    when reading)."""
    _qdo.write_cube(path, cube, wavelengths_nm)


def read_design(path):
    """A design file: (height_m n x n, pitch_m, levels_m list)."""
    return _qdo.read_design(path)


def write_design(path, height_m, pitch_m, levels_m=()):
    """Writes a design file qdo's commands (and `qdo export`) read, atomically."""
    _qdo.write_design(path, height_m, pitch_m, levels_m)


def read_h5(path, name):
    """One dataset of a qdo HDF5 file (e.g. read_h5("out/psf.h5", "/psf_sensor"))."""
    return _qdo.read_h5(path, name)


def write_rgb_png(path, rgb):
    """A 3 x H x W image as an 8-bit sRGB PNG (99.9th percentile to white), atomically."""
    _qdo.write_rgb_png(path, rgb)


def write_psf_figure(path, title, stack, wavelengths_nm, pitch_m, crop=0):
    """A PSF stack (planes x S x S at pitch_m metres) as a figure: one panel per plane titled by its
    wavelength (one per plane, or () for "plane k"), log colour scale with its bar, axes in µm;
    the central crop x crop of each plane (0: whole). Writes path (.png) and the .svg beside it."""
    _qdo.write_psf_figure(path, title, stack, wavelengths_nm, pitch_m, crop)


def write_height_figure(path, title, height_m, pitch_m, value_label="height (nm)"):
    """A height map (H x W metres at pitch_m) as a figure: colours in nm with a colour bar, axes in
    mm. Writes path (.png) and the .svg beside it."""
    _qdo.write_height_figure(path, title, height_m, pitch_m, value_label)
