"""Faults found by an independent review of threads, hidden state and resources (2026-12-05).

* A process forked after the package ran OpenMP threads hung on its first call with more than
  one thread (GCC's libgomp cannot start threads in such a child): multiprocessing's default
  "fork" pool after one call with threads=2 never returned. Such a child now runs on one thread
  and says so once.
* ``threads=None`` read OMP_NUM_THREADS in ``footprint`` (0 went to OpenMP's own default) but
  not in ``intersect`` or ``simulate_image`` (they counted the cores): one rule for all now.
* ``simulate_image`` swapped the process's warning filters (``warnings.catch_warnings``) around
  its occlusion rays, so other threads' warnings were lost while it ran and two overlapping calls
  could leave "ignore" installed for good.
* The core's DEM descriptor was inherited by programs started while a mode-1 call ran (no
  O_CLOEXEC).
"""

from __future__ import annotations

import importlib
import multiprocessing
import os
import sys
import warnings

import numpy as np
import pytest

import planet_intersect as pi
intersect_mod = importlib.import_module("planet_intersect.intersect")   # (pi.intersect is the function)


def _scene():
    rng = np.random.default_rng(5)
    radii = 3390.0 + rng.uniform(0, 5, (180, 360))
    dem = pi.DEM.from_array(radii, f=0.0, re=3390.0)
    n = 4000
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    s = u * 4000.0
    l = -u + rng.normal(0, 0.05, (n, 3))
    return dem, s, l


def _child_call(_):
    dem, s, l = _scene()
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        res = pi.intersect(dem, s, l, threads=2)
    return res.p, [str(w.message) for w in got]


@pytest.mark.skipif(not hasattr(os, "register_at_fork") or "fork" not in multiprocessing.get_all_start_methods(),
                    reason="needs os.register_at_fork and the 'fork' start method (POSIX)")
def test_a_process_forked_after_openmp_threads_runs_on_one_thread_instead_of_hanging():
    dem, s, l = _scene()
    want = pi.intersect(dem, s, l, threads=2).p          # the parent's OpenMP team exists now
    ctx = multiprocessing.get_context("fork")
    pool = ctx.Pool(1)
    try:
        p, msgs = pool.apply_async(_child_call, (0,)).get(timeout=120)
    except multiprocessing.TimeoutError:
        pytest.fail("the forked child's threads=2 call did not return within 120 s (libgomp after fork)")
    finally:
        pool.terminate()
        pool.join()
    np.testing.assert_array_equal(p, want)
    assert any("forked after the package ran OpenMP threads" in m for m in msgs), msgs


def test_threads_none_follows_omp_num_threads_everywhere(monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    assert intersect_mod.check_threads(None, 1000) == 1
    assert intersect_mod.check_threads(0, 1000) == 1
    assert intersect_mod.check_threads(3, 1000) == 3          # an explicit count is the caller's
    monkeypatch.setenv("OMP_NUM_THREADS", "3,2")               # OpenMP's nested list: its first value
    assert intersect_mod.check_threads(None, 1000) == 3
    assert intersect_mod.check_threads(None, 2) == 2
    monkeypatch.setenv("OMP_NUM_THREADS", "junk")
    assert intersect_mod.check_threads(None, 1000) == len(os.sched_getaffinity(0))
    monkeypatch.delenv("OMP_NUM_THREADS")
    assert intersect_mod.check_threads(None, 1000) == len(os.sched_getaffinity(0))


def test_footprint_resolves_its_threads_by_the_same_rule(monkeypatch):
    # the kernel got 0 (OpenMP's default) where intersect resolved None itself; now both ask check_threads
    seen = []
    real = intersect_mod.check_threads
    monkeypatch.setattr(intersect_mod, "check_threads", lambda t, n: seen.append((t, n)) or real(t, n))
    dem = pi.DEM.from_array(np.full((180, 360), 3390.0), f=0.0, re=3390.0)
    cells = pi.CellTable(dem, cell_deg=5.0)
    fp = pi.footprint(cells, np.array([[0.0, 0.0, 3790.0], [0.0, 3790.0, 0.0]]), zeta=0.5, threads=None)
    assert len(fp) > 0
    assert (None, 2) in seen


def test_simulate_leaves_the_process_warning_filters_alone(monkeypatch):
    from test_simulate import box_scene

    from planet_intersect.synthetic_dsm import oblique_pushbroom

    dsm, ortho, scene = box_scene()
    sensor = pi.Pushbroom(*oblique_pushbroom(scene, zenith=9.0, azimuth=90.0, margin=10))
    # record the package's own calls that swap or edit the process-wide filters (pytest's own go on)
    changed = []

    def from_package() -> bool:
        return "planet_intersect" in sys._getframe(2).f_code.co_filename

    real_catch, real_simple, real_filter = warnings.catch_warnings, warnings.simplefilter, warnings.filterwarnings

    class Recording(real_catch):
        def __init__(self, *a, **k):
            if from_package():
                changed.append(("catch_warnings", sys._getframe(1).f_code.co_name))
            super().__init__(*a, **k)

    def simple(*a, **k):
        if from_package():
            changed.append(("simplefilter", a))
        return real_simple(*a, **k)

    def filt(*a, **k):
        if from_package():
            changed.append(("filterwarnings", a))
        return real_filter(*a, **k)

    monkeypatch.setattr(warnings, "catch_warnings", Recording)
    monkeypatch.setattr(warnings, "simplefilter", simple)
    monkeypatch.setattr(warnings, "filterwarnings", filt)
    sim = pi.simulate_image(dsm, ortho, sensor, threads=1, occlusion=True)
    assert sim.occlusion.any()                                 # the occlusion rays were cast
    assert changed == []


@pytest.mark.skipif(not os.path.isdir("/proc/self/fdinfo"), reason="needs Linux's /proc/self/fdinfo")
def test_the_dem_descriptor_is_not_inherited_by_programs_started_meanwhile(tmp_path):
    # a mode-1 call opens the .dem with the C library's open(); without O_CLOEXEC a program started
    # from another thread during the call (os.system, subprocess) inherited it
    import threading

    rng = np.random.default_rng(2)
    dem = pi.DEM.from_array(3390.0 + rng.uniform(0, 5, (360, 720)), f=0.0, re=3390.0)
    path = tmp_path / "m.hdr"
    dem.write(path)
    dem = pi.DEM.read(path)
    target = str(path.with_suffix(".dem").resolve())
    n = 200_000
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    s, l = u * 4000.0, -u
    flags, done = [], threading.Event()

    def watch():
        while not done.is_set():
            for fd in os.listdir("/proc/self/fd"):
                try:
                    if os.readlink(f"/proc/self/fd/{fd}") == target:
                        with open(f"/proc/self/fdinfo/{fd}") as fh:
                            flags.extend(int(x.split()[1], 8) for x in fh if x.startswith("flags:"))
                except OSError:
                    pass

    w = threading.Thread(target=watch)
    w.start()
    try:
        pi.intersect(dem, s, l, dem_read_mode=1, threads=1)
    finally:
        done.set()
        w.join()
    if not flags:
        pytest.skip("the call ended before the watcher saw the core's descriptor (a fast machine)")
    assert all(f & os.O_CLOEXEC for f in flags), [oct(f) for f in flags]
