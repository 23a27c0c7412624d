"""One qdo.Optics (and several on one device) used from several Python threads at once: every
call that touches the device holds the device's lock for the whole call (taken after the GIL is
released), so each call is atomic and returns what it returns alone; an adjoint given its
forward's arguments is that forward's, whatever the other threads do. Without the lock these
crash (the device objects are shared) or return other threads' results."""
import threading

import numpy as np
import pytest

import qdo
from conftest import tiny_config

THREADS = 4
ROUNDS = 12


def run_threads(work):
    """Runs work(k) on THREADS threads started together; re-raises the first exception."""
    barrier = threading.Barrier(THREADS)
    errors = []

    def body(k):
        try:
            barrier.wait()
            work(k)
        except BaseException as e:  # noqa: B902 - reported to the main thread
            errors.append(e)

    threads = [threading.Thread(target=body, args=(k,)) for k in range(THREADS)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        raise errors[0]


@pytest.fixture(scope="module")
def case():
    """An Optics, height maps, scenes and gradients with their serial results."""
    o = qdo.Optics(config=tiny_config(), precision="f64")
    rng = np.random.default_rng(11)
    s = o.sensor_size
    hs = [rng.uniform(0, o.h_max_m, (o.n, o.n)) for _ in range(THREADS)]
    gp = [rng.normal(size=(o.bands, s, s)) for _ in range(THREADS)]
    scenes = [rng.uniform(0, 1, (2, o.bands, 7, 6)) for _ in range(THREADS)]
    gr = [rng.normal(size=(2, 3, 7, 6)) for _ in range(THREADS)]
    ref = {"psf": [], "psf_vjp": [], "rgb": [], "cam_vjp": []}
    for k in range(THREADS):
        p = o.psf(hs[k])
        ref["psf"].append(p)
        ref["psf_vjp"].append(o.psf_vjp(gp[k]))
        ref["rgb"].append(o.camera(scenes[k], p))
        ref["cam_vjp"].append(o.camera_vjp(gr[k]))
    return o, hs, gp, scenes, gr, ref


def test_concurrent_psf_calls_each_return_the_psf_of_their_own_heights(case):
    o, hs, _, _, _, ref = case
    before = o._o.psf_calls
    wrong = []

    def work(k):
        for r in range(ROUNDS):
            i = (k + r) % THREADS
            if not np.array_equal(o.psf(hs[i]), ref["psf"][i]):
                wrong.append((k, r))

    run_threads(work)
    assert wrong == []
    assert o._o.psf_calls == before + THREADS * ROUNDS  # every forward counted once (atomic counter)


def test_concurrent_forward_and_adjoint_pairs_equal_the_serial_ones(case):
    """psf / psf_vjp(g, height_m) / camera / camera_vjp(g, scene, psf) from all threads at once."""
    o, hs, gp, scenes, gr, ref = case
    wrong = []

    def work(k):
        for r in range(ROUNDS // 2):
            i = (k + r) % THREADS
            checks = [
                ("psf", o.psf(hs[i]), ref["psf"][i]),
                ("psf_vjp", o.psf_vjp(gp[i], hs[i]), ref["psf_vjp"][i]),
                ("camera", o.camera(scenes[i], ref["psf"][i]), ref["rgb"][i]),
            ]
            g_psf, g_scene = o.camera_vjp(gr[i], scenes[i], ref["psf"][i])
            checks += [("camera_vjp psf", g_psf, ref["cam_vjp"][i][0]), ("camera_vjp scene", g_scene, ref["cam_vjp"][i][1])]
            wrong.extend((k, r, name) for name, got, want in checks if not np.array_equal(got, want))

    run_threads(work)
    assert wrong == []


def test_adjoints_paired_by_an_outer_lock_equal_the_serial_ones(case):
    """The documented use of the forward-less adjoint from threads: psf(); psf_vjp(g) under the
    caller's own lock, which every forward call must then take too (the pair is the caller's to
    keep together)."""
    o, hs, gp, scenes, gr, ref = case
    pair = threading.Lock()
    wrong = []

    def work(k):
        for r in range(ROUNDS // 2):
            i = (k + r) % THREADS
            with pair:
                o.psf(hs[i])
                g = o.psf_vjp(gp[i])
                o.camera(scenes[i], ref["psf"][i])
                g_psf, g_scene = o.camera_vjp(gr[i])
            if not (np.array_equal(g, ref["psf_vjp"][i]) and np.array_equal(g_psf, ref["cam_vjp"][i][0])
                    and np.array_equal(g_scene, ref["cam_vjp"][i][1])):
                wrong.append((k, r))

    run_threads(work)
    assert wrong == []


def test_the_forward_less_adjoint_pairs_with_the_last_forward_of_any_thread(case):
    o, hs, gp, _, _, ref = case
    t = threading.Thread(target=o.psf, args=(hs[2],))
    o.psf(hs[1])
    t.start()
    t.join()
    np.testing.assert_array_equal(o.psf_vjp(gp[2]), ref["psf_vjp"][2])  # the other thread's, not ours


def test_several_optics_on_one_device_from_threads(case):
    """Two configurations share the device (its queue, kernels and FFT plans): used at once from
    threads, each still returns its serial results."""
    o, hs, _, scenes, _, ref = case
    o4 = qdo.Optics(config=tiny_config(bands=4), precision="f64")
    rng = np.random.default_rng(12)
    h4 = rng.uniform(0, o4.h_max_m, (o4.n, o4.n))
    s4 = rng.uniform(0, 1, (1, 4, 9, 11))
    p4 = o4.psf(h4)
    rgb4 = o4.camera(s4, p4)
    wrong = []

    def work(k):
        for r in range(ROUNDS // 2):
            if k % 2:
                ok = np.array_equal(o4.psf(h4), p4) and np.array_equal(o4.camera(s4, p4), rgb4)
            else:
                i = (k + r) % THREADS
                ok = np.array_equal(o.psf(hs[i]), ref["psf"][i]) and np.array_equal(o.camera(scenes[i], ref["psf"][i]), ref["rgb"][i])
            if not ok:
                wrong.append((k, r))

    run_threads(work)
    assert wrong == []


def test_two_optics_of_one_configuration_from_threads(case):
    """Two Optics of the same configuration share the device's cached kernels and FFT plans
    (the same plan objects): used at once from threads, each still returns its serial results."""
    o, hs, gp, scenes, gr, ref = case
    twins = [o, qdo.Optics(config=tiny_config(), precision="f64")]
    wrong = []

    def work(k):
        t = twins[k % 2]
        for r in range(ROUNDS // 2):
            i = (k + r) % THREADS
            ok = (np.array_equal(t.psf_vjp(gp[i], hs[i]), ref["psf_vjp"][i])
                  and np.array_equal(t.camera(scenes[i], ref["psf"][i]), ref["rgb"][i]))
            if not ok:
                wrong.append((k, r))

    run_threads(work)
    assert wrong == []


def test_two_optics_planning_new_image_sizes_at_once(case):
    """Each new image size makes the device's Runtime plan and cache new FFTs (a shared map, a
    planner that is not thread-safe): two Optics doing that at once from threads must not
    crash, and their images equal those computed serially afterwards."""
    o = case[0]
    o2 = qdo.Optics(config=tiny_config(), precision="f64")
    rng = np.random.default_rng(13)
    psf = case[5]["psf"][0]
    sizes = [[(9 + 2 * r + k, 31 - 2 * r + 3 * k) for r in range(ROUNDS)] for k in range(THREADS)]  # unused before
    scenes = [[rng.uniform(0, 1, (1, o.bands, h, w)) for h, w in sizes[k]] for k in range(THREADS)]
    got = [[None] * ROUNDS for _ in range(THREADS)]

    def work(k):
        t = (o, o2)[k % 2]
        for r in range(ROUNDS):
            got[k][r] = t.camera(scenes[k][r], psf)

    run_threads(work)
    for k in range(THREADS):
        for r in range(ROUNDS):
            np.testing.assert_array_equal(got[k][r], o.camera(scenes[k][r], psf))


def test_an_optics_made_and_dropped_while_another_thread_computes(case):
    o, hs, _, _, _, ref = case
    wrong = []

    def work(k):
        for r in range(3):
            if k == 0:
                tmp = qdo.Optics(config=tiny_config(n=24), precision="f64")
                tmp.psf(np.zeros((24, 24)))
                del tmp
            elif not np.array_equal(o.psf(hs[k]), ref["psf"][k]):
                wrong.append((k, r))

    run_threads(work)
    assert wrong == []
