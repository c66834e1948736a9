"""Property-based fuzzing of the public API and the CLI's file readers (CI budget).

Each target's cases come from tests/fuzzing/strategies.py and run in a worker
process (tests/fuzzing/harness.py), so that a segfault, abort, Fortran run-time
check or hang fails the test with the input and a reproducer instead of killing
pytest. The properties (tests/fuzzing/ops.py, harness.judge):

* no crash, no hang (``PI_FUZZ_TIMEOUT`` seconds per case, default 20);
* an error is a ValueError (DEMError), TypeError, or for files an OSError, whose
  message names the argument or file at fault; no warning is emitted;
* a result is right where it can be checked: hits lie on the surface
  (``| |p| - dem.radius(lat, lon) | <= 1e-9 rmax`` stepping, ``1e-6 rmax``
  exact), on the ray ahead of the spacecraft, with the lat/lon/radius of p;
  limb rays have finite tangent quantities; what does not apply is NaN; the
  read modes, io paths and thread counts agree bit for bit, and both methods'
  limb outputs agree; a DEM read from a generated header has the values the
  header states; ``planet-intersect run`` writes one row per ray or exits 2
  with one line naming the file (and the line, for a bad value).

The budget is deterministic (hypothesis derandomised; the same cases on every
run) and scales with ``PI_FUZZ_SCALE`` (default 1: about a minute here under
load). ``./dev fuzz --minutes N`` runs the same targets at random for longer.
"""

from __future__ import annotations

import os

import pytest

pytest.importorskip("hypothesis", reason="hypothesis is not installed (pip install 'planet-intersect[test]')")

from fuzzing.harness import Session  # noqa: E402
from fuzzing.runner import ci_settings, make_test  # noqa: E402

#: cases per target in CI (each runs in the worker; `intersect` cases with
#: every configuration make 8 calls)
BUDGET = {"from_array": 60, "read": 60, "radius": 80, "intersect": 150, "mutate": 20, "detector": 80, "cli_run": 50}
SCALE = float(os.environ.get("PI_FUZZ_SCALE", "1"))


@pytest.fixture(scope="module")
def session():
    s = Session(timeout=float(os.environ.get("PI_FUZZ_TIMEOUT", "20")))
    yield s
    s.close()


@pytest.mark.parametrize("target", list(BUDGET))
def test_fuzz(session, target):
    """No crash, hang, unclear error or wrong result over the target's CI budget."""
    n = max(5, int(BUDGET[target] * SCALE))
    before = session.calls
    make_test(target, session, ci_settings(n), raise_known=True)()
    assert session.calls - before >= min(n, 5), "the fuzz target ran no cases"


def test_harness_catches_a_crash_and_a_hang(session):
    """The harness itself: a segfault and a hang in the worker become failures
    with the input, and the worker is replaced (its next case runs normally)."""
    from fuzzing.harness import judge

    crash = {"op": "selftest", "action": "segfault", "names": []}
    hang = {"op": "selftest", "action": "hang", "names": []}
    out = session.worker.call(crash)
    assert out.kind == "crash" and "SIGSEGV" in out.detail
    assert judge(crash, out).startswith("CRASH")
    out = session.worker.call(hang, timeout=2)
    assert out.kind == "hang"
    ok = {"op": "detector", "args": {"l0": [0, 0, -1], "q": [0, 1, 0], "nh": 3, "nv": 3, "dh": 0.01, "dv": 0.01},
          "names": []}
    out = session.worker.call(ok)
    assert out.kind == "ok" and out.detail == {"n": 9}
    bad = dict(ok, args=dict(ok["args"], nh=0), names=["nh"])
    out = session.worker.call(bad)
    assert out.kind == "error" and judge(bad, out) is None, out.detail


# ---------------------------------------------------------------------------- bulk mode
#: API calls of the CI bulk run (tests/fuzzing/bulk.py: the same cases, checks and
#: judgement without hypothesis, in batches); ``./dev fuzz --bulk --calls N`` for more
BULK_CALLS = int(20000 * SCALE)


def test_bulk_pools_are_those_of_the_strategies():
    """The bulk generator draws from the same value pools as the hypothesis strategies."""
    from fuzzing import bulk, strategies

    assert repr(bulk.EXTREME) == repr(strategies.EXTREME)
    assert bulk.INTERSECT_NAMES == strategies.INTERSECT_NAMES
    assert bulk.EOLS == strategies.EOLS
    assert set(bulk.MIX) == set(strategies.TARGETS)
    # deterministic: case i of batch b under a seed is always the same case
    a, b = bulk.gen_case(7, 3, 11), bulk.gen_case(7, 3, 11)
    assert repr(a) == repr(b) and a["op"] in bulk.MIX


def test_bulk_fuzz():
    """No crash, hang, unclear error or wrong result over BULK_CALLS API calls
    drawn by the bulk generator (fixed seed: the same cases on every run)."""
    from fuzzing.bulk import MIX, BulkRun
    from fuzzing.harness import describe

    run = BulkRun(seed=20260101, calls=BULK_CALLS, jobs=1, batch=250,
                  timeout=float(os.environ.get("PI_FUZZ_TIMEOUT", "20")), log=lambda m: None).run()
    assert not run.failures, "\n\n".join(f"=== {sig}\n{describe(c, f)}" for sig, (c, f) in run.failures.items())
    assert run.api_calls >= BULK_CALLS
    assert run.restarts == 0
    # every operation ran, valid cases succeeded and bad ones were refused
    assert set(run.by_op) == set(MIX), run.by_op
    assert run.kinds.get("ok", 0) > run.cases // 2 and run.kinds.get("error:ValueError", 0) > 0, run.kinds


#: API calls of the CI bulk run over the geodetic system (tests/fuzzing/geo.py)
BULK_GEO_CALLS = int(4000 * SCALE)


def test_bulk_fuzz_geo():
    """The geodetic system (GeodeticDSM.from_array, intersect on a DSM by every method,
    the conversions): no crash, hang, unclear error or wrong result over BULK_GEO_CALLS
    API calls (fixed seed). Its first runs found a following hit outside the grid on a
    strongly flattened body, a following hit on the side of a cell facing no-data, the
    exact conversion 5,000 km off inside the evolute, a focal point at a body's centre
    taken for a point under the grid, and two errors that named no argument."""
    from fuzzing.bulk import MIX_GEO

    _family_run(MIX_GEO, seed=20261203, calls=BULK_GEO_CALLS, batch=200)


def _family_run(mix: dict, seed: int, calls: int, batch: int) -> None:
    """A bulk run over one family's operations: no failure, every operation drawn, most cases
    normal results and some refused with a ValueError."""
    from fuzzing.bulk import BulkRun
    from fuzzing.harness import describe

    run = BulkRun(seed=seed, calls=calls, jobs=1, batch=batch, mix=mix,
                  timeout=float(os.environ.get("PI_FUZZ_TIMEOUT", "20")), log=lambda m: None).run()
    assert not run.failures, "\n\n".join(f"=== {sig}\n{describe(c, f)}" for sig, (c, f) in run.failures.items())
    assert run.api_calls >= calls and run.restarts == 0
    assert set(run.by_op) == set(mix), run.by_op
    assert run.kinds.get("ok", 0) > run.cases // 2 and run.kinds.get("error:ValueError", 0) > 0, run.kinds


#: API calls of the CI bulk run over the footprint system (tests/fuzzing/grs.py)
BULK_GRS_CALLS = int(1500 * SCALE)


def test_bulk_fuzz_grs():
    """The footprint system (CellTable, footprint with the flux cone, occlusion and reused
    memory, the spacecraft frame and quaternion, the air mass): no crash, hang, unclear error
    or wrong result over BULK_GRS_CALLS API calls (fixed seed). Its first runs found the flux
    cone losing a faint spectrum's weights after a bright one, occlusion_tol = 0 hiding cells
    of a bare sphere, Ch(x, z) 3.7e-6 off a hair from the horizon, and two docstrings that
    said otherwise than the results (the pairs' column order, the elevation without v)."""
    from fuzzing.bulk import MIX_GRS

    _family_run(MIX_GRS, seed=20261204, calls=BULK_GRS_CALLS, batch=100)


#: API calls of the CI bulk run over the image simulation (tests/fuzzing/sim.py)
BULK_SIM_CALLS = int(3000 * SCALE)


def test_bulk_fuzz_sim():
    """The image simulation (the sensors, OrthoImage.from_array, simulate_image with every option):
    no crash, hang, unclear error or wrong result over BULK_SIM_CALLS API calls (fixed seed),
    checked against pi.intersect on the sensor's own rays, the tests' geodesy and a bilinear
    reference of the ortho-image. Its first runs (a helper, 2026-12-03, ~82,000 calls) found the
    exact mode giving up (STEP_LIMIT) on a nadir ray down a row boundary beside a column
    boundary, the occlusion footprint missing hits when the image's border missed the DSM,
    OrthoImage.sample NaN at its own edge centres, from_orbit 11 mm off near a pole, rays()
    truncating non-integer lines, and numeric strings taken for numbers."""
    from fuzzing.bulk import MIX_SIM

    _family_run(MIX_SIM, seed=20261205, calls=BULK_SIM_CALLS, batch=100)


def test_bulk_catches_a_crash_and_names_the_case():
    """A segfault inside a batch: the batch is replayed one case at a time, the
    crashing case is reported with its (seed, batch, index), the worker is
    restarted and the run goes on."""
    from fuzzing.bulk import BulkRun, gen_case

    mix = {"selftest": 0.5, "detector": 0.5}
    run = BulkRun(seed=5, calls=300, jobs=1, batch=60, mix=mix, timeout=20, log=lambda m: None).run()
    crashes = [(c, f) for c, f in run.failures.values() if f.startswith("CRASH")]
    assert crashes and all("SIGSEGV" in f for _, f in crashes)
    case, _ = crashes[0]
    seed, b, i = case["bulk_id"]
    assert gen_case(seed, b, i, mix)["action"] == "segfault"
    # the first segfaulting case of that batch, none before it
    assert all(gen_case(seed, b, k, mix).get("action") != "segfault" for k in range(i))
    assert run.restarts >= len(crashes) and run.api_calls >= 300


def test_sim_family_allows_the_node_line_step_limit_only_on_the_node_line():
    """The simulation family's allowance for the exact mode's documented node-line STEP_LIMIT
    (docs/shin-park-notes.md; fuzzing/sim.py, _on_node_line_by_nodata) takes the case it was
    made for (seed 7500: a nadir sensor 10 m from Mars's south pole exactly on a bilinear column's
    centre meridian, no-data nodes beside it) and nothing near it: the same sensor 1e-9 degrees
    off the meridian, the same DSM without no-data nodes, or "nearest" interpolation. The statuses
    are given, not traced, so the test is of the allowance alone."""
    import numpy as np

    import planet_intersect as pi
    from fuzzing import sim as fs

    dsm_spec = {'shape': (26, 13), 'a': 3396190.0, 'f': 0.005886023049666262, 'interpolation': 'bilinear',
                'lat_first': -89.99915646875709, 'lon_first': -17.15938910843238, 'dlat': -3.374120971623043e-05,
                'dlon': 0.016870604858115215, 'kind': 'holes', 'scale': 60.0, 'base': 120.0, 'seed': 1066221050,
                'nodata': -9999.0}
    sensor_spec = {'kind': 'nadir', 'shape': (5, 1), 'look': 'steep', 'a': 3396190.0, 'f': 0.005886023049666262,
                   'lat': -89.99982988112156, 'lon': -17.058165479283687, 'height': 204.02936802190655,
                   'ifov': 4.493139792066052, 'rotation': 0.0}
    dsm = fs._dsm(dsm_spec)
    st = np.array([[9], [14], [9], [9], [9]])
    assert fs._on_node_line_by_nodata(fs.build_sensor(sensor_spec), st, dsm)
    assert not fs._on_node_line_by_nodata(fs.build_sensor(dict(sensor_spec, lon=sensor_spec["lon"] + 1e-9)), st, dsm)
    h = np.asarray(dsm.heights, dtype=np.float64)
    filled = pi.GeodeticDSM.from_array(np.where(np.isfinite(h), h, 100.0), dsm.lat_first, dsm.lon_first, dsm.dlat,
                                       dsm.dlon, a=dsm.a, f=dsm.f, interpolation="bilinear")
    assert not fs._on_node_line_by_nodata(fs.build_sensor(sensor_spec), st, filled)
    assert not fs._on_node_line_by_nodata(fs.build_sensor(sensor_spec), st, dsm.with_interpolation("nearest"))
