"""Hypothesis runs of the fuzz targets against one crash-safe :class:`harness.Session`."""

from __future__ import annotations

import time
from pathlib import Path

from hypothesis import HealthCheck, Phase, Verbosity, given, seed, settings
from hypothesis.database import DirectoryBasedExampleDatabase

from .harness import Session, describe, signature
from .strategies import TARGETS

REPO = Path(__file__).resolve().parents[2]


class FuzzFailure(AssertionError):
    """A case failed; the message holds the failure, a reproducer and the case."""


def ci_settings(max_examples: int) -> settings:
    """Deterministic, no shrinking (the failing case is printed as generated)."""
    return settings(max_examples=max_examples, deadline=None, derandomize=True, database=None,
                    phases=(Phase.explicit, Phase.generate), suppress_health_check=list(HealthCheck),
                    print_blob=False, verbosity=Verbosity.quiet)   # the failure text has the case and a reproducer


def long_settings(max_examples: int) -> settings:
    """Random, shrinking, failures kept in .cache/hypothesis for the next run."""
    db = DirectoryBasedExampleDatabase(str(REPO / ".cache" / "hypothesis"))
    return settings(max_examples=max_examples, deadline=None, database=db,
                    suppress_health_check=list(HealthCheck), print_blob=False, verbosity=Verbosity.quiet)


def make_test(target: str, session: Session, cfg: settings, raise_known: bool = True):
    """A hypothesis test of one target. With ``raise_known`` every failing case
    fails the test; without, only the first new kind of failure of this run does
    (it is shrunk), and kinds already reported are counted and skipped, so that a
    long run keeps exploring past a known defect."""
    state = {"current": None}

    @cfg
    @given(TARGETS[target])
    def test(case):
        failure = session.run(case)
        if not failure:
            return
        sig = signature(case, failure)
        if raise_known is None:          # survey: record only
            return
        if not raise_known and failure.startswith("HANG"):
            return                       # long mode: shrinking a hang costs a timeout per step; printed unshrunk
        if state["current"] is None and sig not in session.reported:
            state["current"] = sig
        if raise_known or sig == state["current"]:
            raise FuzzFailure(describe(session.last_case, failure))

    test.state = state
    return test


def long_run(minutes: float, first_seed: int = 0, targets=None, chunk: int = 300, timeout: float = 20.0,
             log=print) -> Session:
    """Round-robin hypothesis runs over the targets until ``minutes`` have passed."""
    names = list(targets or TARGETS)
    session = Session(timeout=timeout, expand=True)
    t_end = time.monotonic() + 60.0 * minutes
    k = 0
    last_log = time.monotonic()
    try:
        while time.monotonic() < t_end:
            name = names[k % len(names)]
            plain = make_test(name, session, long_settings(chunk), raise_known=False)
            state = plain.state
            test = seed(first_seed + k)(plain)
            k += 1
            try:
                test()
            except FuzzFailure as exc:
                text = str(exc)
                sig = state["current"] or signature({"op": name}, text)
                if sig not in session.reported:
                    session.reported[sig] = text
                    log(f"[fuzz] NEW FAILURE ({name}):\n{text}\n")
            except Exception as exc:  # noqa: BLE001 - hypothesis' own errors (flaky...) are reported, not fatal
                log(f"[fuzz] {name}: hypothesis stopped: {type(exc).__name__}: {str(exc)[:500]}")
            if time.monotonic() - last_log > 60:
                last_log = time.monotonic()
                log(f"[fuzz] {session.calls} cases ({session.api_calls} API calls), "
                    f"{len(session.failures)} kinds of failure, worker restarts {session.worker.restarts}")
    finally:
        session.close()
    return session
