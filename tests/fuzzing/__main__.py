"""Long fuzzing mode: ``./dev fuzz --minutes N`` (``python -m tests.fuzzing``).

``./dev fuzz --bulk --calls N [--jobs 2]`` (or ``--minutes M``): the bulk mode
(tests/fuzzing/bulk.py), the same cases and checks without hypothesis, in
batches, at about a thousand times the rate.

Runs every target (or ``--targets a,b``) round-robin under hypothesis, each
case in the crash-safe worker, for N minutes; prints the number of cases and
API calls made and every kind of failure found with a reproducer; exits 1 when
anything failed.
"""

from __future__ import annotations

import argparse
import sys
import time

from .harness import describe
from .runner import long_run
from .strategies import TARGETS


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="./dev fuzz", description=__doc__.splitlines()[0])
    p.add_argument("--minutes", type=float, default=None, help="how long to fuzz (default 5)")
    p.add_argument("--seed", type=int, default=int(time.time()) % 100000, help="first hypothesis seed")
    p.add_argument("--targets", default=",".join(TARGETS), help=f"comma-separated subset of {', '.join(TARGETS)}")
    p.add_argument("--timeout", type=float, default=20.0, help="seconds before a case counts as a hang (default 20)")
    p.add_argument("--chunk", type=int, default=300, help="examples per hypothesis run (default 300)")
    p.add_argument("--bulk", action="store_true", help="bulk mode (numpy-drawn cases in batches, no hypothesis)")
    p.add_argument("--calls", type=int, default=None, help="bulk: stop after this many API calls")
    p.add_argument("--jobs", type=int, default=1, help="bulk: workers in parallel (default 1)")
    p.add_argument("--batch", type=int, default=300, help="bulk: cases per worker round trip (default 300)")
    p.add_argument("--geo", action="store_true",
                   help="bulk: the geodetic system's cases (GeodeticDSM, intersect on a DSM, conversions)")
    p.add_argument("--grs", action="store_true",
                   help="bulk: the footprint system's cases (CellTable, footprint, frames, air mass)")
    p.add_argument("--sim", action="store_true",
                   help="bulk: the image simulation's cases (sensors, OrthoImage, simulate_image)")
    args = p.parse_args(argv)
    if args.geo + args.grs + args.sim > 1:
        p.error("--geo, --grs, --sim: one family at a time")
    if args.bulk:
        return bulk_main(args)
    if args.calls is not None:
        p.error("--calls needs --bulk")
    if (args.geo or args.grs or args.sim) and not args.bulk:
        p.error("--geo, --grs and --sim need --bulk")
    if args.minutes is None:
        args.minutes = 5.0
    targets = [t for t in args.targets.split(",") if t]
    unknown = set(targets) - set(TARGETS)
    if unknown:
        p.error(f"--targets: unknown {', '.join(sorted(unknown))} (known: {', '.join(TARGETS)})")
    t0 = time.monotonic()
    print(f"[fuzz] {args.minutes:g} minutes over {', '.join(targets)}, seed {args.seed}", flush=True)
    session = long_run(args.minutes, args.seed, targets, args.chunk, args.timeout,
                       log=lambda m: print(m, flush=True))
    dt = time.monotonic() - t0
    print(f"[fuzz] done in {dt / 60:.1f} min: {session.calls} cases, {session.api_calls} API calls "
          f"({session.api_calls / max(dt, 1e-9):.0f}/s), worker restarts {session.worker.restarts}")
    if not session.failures:
        print("[fuzz] no crash, hang, unclear error or property violation")
        return 0
    print(f"[fuzz] {len(session.failures)} kinds of failure (first case of each; shrunk ones above):")
    for sig, (case, failure) in session.failures.items():
        print(f"\n=== {sig}\n{describe(case, failure)}")
    return 1


def bulk_main(args) -> int:
    from .bulk import MIX_GEO, MIX_GRS, MIX_SIM, BulkRun

    minutes = args.minutes if args.minutes is not None or args.calls is not None else 5.0
    print(f"[bulk] seed {args.seed}, {args.jobs} worker(s), batches of {args.batch}, until "
          + (f"{args.calls} API calls" if args.calls is not None else "") + (" or " if args.calls and minutes else "")
          + (f"{minutes:g} minutes" if minutes else ""), flush=True)
    run = BulkRun(args.seed, calls=args.calls, minutes=minutes, jobs=args.jobs, batch=args.batch,
                  timeout=args.timeout, mix=MIX_GEO if args.geo else MIX_GRS if args.grs else MIX_SIM if args.sim else None, log=lambda m: print(m, flush=True)).run()
    dt = run.seconds
    print(f"[bulk] done in {dt / 60:.1f} min: {run.cases} cases, {run.api_calls} API calls "
          f"({run.api_calls / max(dt, 1e-9):.0f}/s), {run.batches} batches, worker restarts {run.restarts}")
    print("[bulk] cases by operation: " + ", ".join(f"{k} {v}" for k, v in sorted(run.by_op.items())))
    print("[bulk] outcomes: " + ", ".join(f"{k} {v}" for k, v in sorted(run.kinds.items())))
    if not run.failures:
        print("[bulk] no crash, hang, unclear error or property violation")
        return 0
    print(f"[bulk] {len(run.failures)} kinds of failure (first case of each):")
    for sig, (case, failure) in run.failures.items():
        print(f"\n=== {sig}\n{describe(case, failure)}")
    return 1


if __name__ == "__main__":
    sys.exit(main())
