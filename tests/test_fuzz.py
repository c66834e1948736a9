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
