"""Array arguments: any float64 dtype spelling and byte order (h5py's arrays included), any memory
layout (copied to C order when needed, with the same results as a contiguous copy), other dtypes
refused with a message naming the argument and the dtype; arrays too large to copy and size
arguments out of range refused before anything is allocated."""
import numpy as np
import pytest

import qdo

# ---------- layouts ----------


def stepped(a):
    """A view of a with the same values and every stride doubled (a slice with steps)."""
    big = np.zeros(tuple(2 * s for s in a.shape))
    big[tuple(slice(None, None, 2) for _ in a.shape)] = a
    return big[tuple(slice(None, None, 2) for _ in a.shape)]


def reversed_view(a):
    """A view with negative strides and the same values."""
    flipped = np.ascontiguousarray(a[tuple(slice(None, None, -1) for _ in a.shape)])
    return flipped[tuple(slice(None, None, -1) for _ in a.shape)]


def transposed(a):
    """A transpose of a C-order array (Fortran-like strides) with the same values."""
    return np.ascontiguousarray(a.T).T


LAYOUTS = {
    "slice_with_steps": stepped,
    "fortran_order": np.asfortranarray,
    "transpose": transposed,
    "negative_strides": reversed_view,
    "read_only": lambda a: np.lib.stride_tricks.as_strided(a, writeable=False),
}


@pytest.mark.parametrize("layout", list(LAYOUTS))
def test_non_contiguous_inputs_give_the_results_of_contiguous_copies(optics64, rng, layout, tmp_path):
    make = LAYOUTS[layout]
    o = optics64
    s = o.sensor_size
    h = rng.uniform(0, o.h_max_m, (o.n, o.n))
    v = make(h)
    assert not v.flags.c_contiguous or layout == "read_only"
    np.testing.assert_array_equal(v, h)
    psf = o.psf(h)
    np.testing.assert_array_equal(o.psf(v), psf)
    g = rng.normal(size=(o.bands, s, s))
    np.testing.assert_array_equal(o.psf_vjp(make(g), make(h)), o.psf_vjp(g, h))
    scene = rng.uniform(0, 1, (2, o.bands, 6, 5))
    rgb = o.camera(scene, psf)
    np.testing.assert_array_equal(o.camera(make(scene), make(psf)), rgb)
    np.testing.assert_array_equal(o.camera(make(scene[0]), psf), rgb[0])
    gr = rng.normal(size=rgb.shape)
    want = o.camera_vjp(gr, scene, psf)
    for got, ref in zip(o.camera_vjp(make(gr), make(scene), make(psf)), want):
        np.testing.assert_array_equal(got, ref)
    np.testing.assert_array_equal(qdo.quantize(v, o.h_max_m, 4), qdo.quantize(h, o.h_max_m, 4))
    scenes = rng.uniform(0, 1, (3, o.bands, 8, 8))
    prior = qdo.estimate_prior(scenes, bins=4)
    np.testing.assert_array_equal(qdo.estimate_prior(make(scenes), bins=4), prior)
    y = o.camera(scenes[0], psf)
    srf = o.srf()
    np.testing.assert_array_equal(qdo.wiener_decode(make(y), make(psf), make(srf), make(prior), 1e-3),
                                  qdo.wiener_decode(y, psf, srf, prior, 1e-3))
    qdo.write_design(tmp_path / "d.h5", v, o.config["pitch_m"])
    np.testing.assert_array_equal(qdo.read_design(tmp_path / "d.h5")[0], h)
    qdo.write_cube(tmp_path / "c.h5", make(scenes[0]), o.wavelengths_nm)
    np.testing.assert_array_equal(qdo.read_h5(tmp_path / "c.h5", "/cube"), scenes[0])


def test_a_broadcast_array_is_copied_with_its_repeated_values(optics64):
    o = optics64
    row = np.linspace(0, o.h_max_m, o.n)
    b = np.broadcast_to(row, (o.n, o.n))  # zero stride along the first axis
    assert b.strides[0] == 0
    np.testing.assert_array_equal(o.psf(b), o.psf(np.ascontiguousarray(b)))


# 2^29 x 2^30 float64 values: 4 EiB, more than any address space, so the copy always fails,
# even where the kernel overcommits memory (a zero-stride view of one value costs nothing).
HUGE = (1 << 29, 1 << 30)


def test_an_array_too_large_to_copy_raises_memory_error_naming_it(optics64):
    huge = np.broadcast_to(np.zeros(1), HUGE)
    with pytest.raises(MemoryError, match=r"^height_m: no memory for a C-order float64 copy of its shape \(536870912, 1073741824\)"):
        qdo.quantize(huge, 1e-6, 4)
    with pytest.raises(MemoryError, match=r"^height_m: no memory"):
        qdo.write_height_figure("never.png", "t", huge, 1e-6)
    with pytest.raises(MemoryError, match=r"^scenes: no memory"):
        qdo.estimate_prior(np.broadcast_to(np.zeros(1), (1, 1) + HUGE), bins=4)
    # Where the shape is fixed, the shape is checked first: no copy is attempted.
    with pytest.raises(ValueError, match=r"^height_m: shape \(536870912, 1073741824\); expected \(16, 16\)$"):
        optics64.psf(huge)


@pytest.mark.parametrize("call, match", [
    (lambda s: qdo.estimate_prior(s, bins=10**9), r"^bins: 1000000000; expected an integer in \[2, 4096\]$"),
    (lambda s: qdo.estimate_prior(s, bins=10**30), r"^bins: 1000000000000000000000000000000; expected an integer in \[2, 4096\]$"),
    (lambda s: qdo.estimate_prior(s, bins=1), r"^bins: 1; expected an integer in \[2, 4096\]$"),
    (lambda s: qdo.estimate_prior(s, bins=-3), r"^bins: -3; expected an integer in \[2, 4096\]$"),
    (lambda s: qdo.estimate_prior(s, bins=16.0), r"^bins: float 16.0; expected an integer in \[2, 4096\]$"),
    (lambda s: qdo.estimate_prior(np.broadcast_to(np.zeros(1), (1, 200, 4, 4)), bins=4096),
     r"^bins: 4096 with 200 bands makes 163840000 covariance values; expected bins x bands x bands <= 2\^27$"),
    (lambda s: qdo.quantize(np.zeros((4, 4)), 1e-6, 10**9), r"^levels: 1000000000; expected an integer in \[2, 65536\]$"),
    (lambda s: qdo.quantize(np.zeros((4, 4)), 1e-6, 1), r"^levels: 1; expected an integer in \[2, 65536\]$"),
])
def test_size_arguments_out_of_range_are_refused_before_allocating(call, match):
    scenes = np.zeros((1, 3, 4, 4))
    with pytest.raises(ValueError, match=match):
        call(scenes)


def test_the_largest_allowed_bins_works(rng):
    prior = qdo.estimate_prior(rng.uniform(0, 1, (2, 2, 6, 6)), bins=np.int64(4096))
    assert prior.shape == (4096, 2, 2)


# ---------- dtypes ----------

FLOAT64_SPELLINGS = {
    "<f8": np.dtype("<f8"),
    "=f8": np.dtype("=f8"),
    ">f8": np.dtype(">f8"),
    "float64 (a new descriptor, as h5py makes)": np.dtype("f8").newbyteorder("="),
    "float64 with metadata": np.dtype("f8", metadata={"h5py": 1}),
}


@pytest.mark.parametrize("spelling", list(FLOAT64_SPELLINGS))
def test_every_spelling_and_byte_order_of_float64_is_accepted_with_its_values(optics64, rng, spelling):
    dt = FLOAT64_SPELLINGS[spelling]
    o = optics64
    h = rng.uniform(0, o.h_max_m, (o.n, o.n))
    hd = h.astype(dt)
    assert hd.dtype == dt and np.array_equal(hd, h)
    np.testing.assert_array_equal(o.psf(hd), o.psf(h))
    np.testing.assert_array_equal(qdo.quantize(hd, o.h_max_m, 4), qdo.quantize(h, o.h_max_m, 4))
    psf = o.psf(h)
    scene = rng.uniform(0, 1, (o.bands, 5, 4))
    np.testing.assert_array_equal(o.camera(scene.astype(dt), psf.astype(dt)), o.camera(scene, psf))


@pytest.mark.parametrize("dtype", ["float32", ">f4", "float16", "longdouble", "int64", "int32", "uint8", "bool",
                                   "complex128", "object"])
def test_other_dtypes_are_refused_naming_the_argument_and_the_dtype(optics64, dtype):
    bad = np.zeros((16, 16), dtype=dtype)
    want = "height_m: dtype %s; expected float64 (convert it with .astype(numpy.float64))" % np.dtype(dtype).name
    for call in (optics64.psf, lambda a: qdo.quantize(a, 1e-6, 4)):
        with pytest.raises(ValueError) as e:
            call(bad)
        assert str(e.value) == want


def test_arrays_read_by_h5py_are_accepted(optics64, rng, tmp_path):
    """The reported case: optics.psf(np.asarray(h5file["height_m"])) on a design file qdo wrote,
    and a big-endian dataset h5py wrote; the values must come through unchanged."""
    h5py = pytest.importorskip("h5py", reason="h5py (Debian python3-h5py) is not installed")
    o = optics64
    h = rng.uniform(0, o.h_max_m, (o.n, o.n))
    qdo.write_design(tmp_path / "d.h5", h, o.config["pitch_m"])
    with h5py.File(tmp_path / "d.h5", "r") as f:
        hh = np.asarray(f["height_m"])
    np.testing.assert_array_equal(hh, h)
    np.testing.assert_array_equal(o.psf(hh), o.psf(h))
    with h5py.File(tmp_path / "be.h5", "w") as f:
        f.create_dataset("h", data=h.astype(">f8"))
        f.create_dataset("h32", data=h.astype("<f4"))
    with h5py.File(tmp_path / "be.h5", "r") as f:
        be, h32 = f["h"][...], f["h32"][...]
    assert be.dtype.byteorder == ">"
    np.testing.assert_array_equal(o.psf(be), o.psf(h))
    with pytest.raises(ValueError, match=r"^height_m: dtype float32; expected float64"):
        o.psf(h32)
