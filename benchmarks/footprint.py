#!/usr/bin/env python3
"""Benchmark of the footprint geometry (Mars Odyssey GRS notes, issue 13).

    ./dev bench --footprint --quick   # under a minute; CI runs it (asserts nothing about speed)
    ./dev bench --footprint           # the issue's case, >= 2 s of timed calls per measurement

Scene: the MOLA 4 ppd grid of ../shared/data ($PI_SHARED_DATA), 0.5 deg cells
(CellTable), 20-s spectra of a 387 x 450 km, 93.1 deg Odyssey-like orbit
(keplerian_states). Cases, each in its own process (its peak memory is its
own) after an untimed warm-up call, median of timed calls over >= 2 s
(--quick: 0.3 s):

* geometry: ``footprint(cells, R, v, zeta=ZETA, airmass_model=None)``, the
  full geometry with a cone of ~20,000 cells per spectrum, 1 and 2 threads;
  "fresh" allocates new outputs per call (the default), "reuse" passes the
  same output buffers every call (``out=``, where the package supports it);
  "chunks" calls footprint() once per spectrum, each call reusing the last
  one's outputs (``out=``, where supported), so that they stay in cache;
* flux: ``flux_fraction=0.5`` (horizon pass, then the flux cone in NumPy;
  pairs/s counts the pairs of the horizon pass);
* occlusion: the exact ray casting of ``occlusion=True`` on a small subset
  (pairs/s of the occlusion alone: the geometry's time is subtracted);
* cells: the CellTable build (not cached: a fresh DEM object per call).

Each case runs with the core the package chooses (column "core": ``_core_v3``
on x86-64-v3 CPUs, see planet_intersect/_ext.py); the one-thread geometry
cases run a second time with ``PI_CORE=portable`` (``_core``), so that the
two builds are compared in the same run.

Both wall time and CPU time of the process (time.process_time, all threads)
are recorded per call: the machine this was written on is shared, and CPU
time does not count the time spent waiting for a core. pairs/s and ns per
pair come from the median call. Results: benchmarks/results/footprint*.{json,md}.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
SHARED = Path(os.environ.get("PI_SHARED_DATA", REPO.parent / "shared" / "data"))
MOLA = SHARED / "mars_mola_megdr_4ppd" / "mars_radius_4ppd_megt_plus_areoid.i2be"
ZETA = 0.45           # cos psi >= 0.45 (psi <= 63.3 deg): ~18,400 cells per spectrum over the orbit (horizon ~19,400)
PERI, APO = 387.0, 450.0


def peak_rss_mb() -> float:
    try:
        return int(Path("/proc/self/status").read_text().split("VmHWM:")[1].split()[0]) / 1024.0
    except (OSError, IndexError):
        return float("nan")


def scene(nspec: int):
    """(dem, cells, R, v): nspec of the 353 20-s spectra of one Odyssey-like orbit over MOLA, evenly spread."""
    import planet_intersect as pi
    import planet_intersect.footprint  # noqa: F401 (the module, not the function)
    F = sys.modules["planet_intersect.footprint"]
    from planet_intersect.mola import mola_dem

    dem = mola_dem(MOLA)
    cells = pi.CellTable(dem, 0.5)
    rp = float(np.mean(cells.radius))
    t = 20.0 * np.round(np.linspace(0.0, 352.0, nspec))       # spread over one orbit (353 spectra)
    R, v = F.keplerian_states(t, rp + PERI, rp + APO, 93.1)
    return dem, cells, R, v


def timed(fn, min_seconds: float, max_calls: int = 200):
    """Untimed warm-up, then calls until min_seconds of wall time: lists of (wall, cpu) per call."""
    fn()
    wall, cpu = [], []
    while True:
        c0, t0 = time.process_time(), time.perf_counter()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
        if sum(wall) > min_seconds or len(wall) >= max_calls:
            return wall, cpu


def measure(spec: dict) -> dict:
    """One case in this process."""
    import planet_intersect as pi
    from planet_intersect.footprint import footprint

    case, threads, nspec = spec["case"], spec.get("threads", 1), spec["nspec"]
    if case == "cells":
        from planet_intersect.mola import mola_dem
        wall, cpu = timed(lambda: pi.CellTable(mola_dem(MOLA), 0.5), spec["min_seconds"], max_calls=5)
        return dict(seconds_wall=float(np.median(wall)), seconds_cpu=float(np.median(cpu)), calls=len(wall),
                    cells=len(pi.CellTable(mola_dem(MOLA), 0.5)), peak_rss_mb=peak_rss_mb())
    dem, cells, R, v = scene(nspec)
    kw = dict(airmass_model=None, threads=threads)
    if case == "alternate":
        return alternate(cells, R, v, dict(kw, zeta=ZETA), spec["rounds"])
    if case == "flux":
        kw["flux_fraction"] = 0.5
    else:
        kw["zeta"] = ZETA
    box = {}
    if case == "reuse":
        import inspect
        if "out" not in inspect.signature(footprint).parameters:
            return {"error": "footprint() takes no out= buffers in this version"}
        first = footprint(cells, R, v, **kw)
        kw["out"] = first
    if case == "chunk":             # one spectrum per call, each call's outputs (~2.4 MB) reused while in cache
        import inspect
        reuse = "out" in inspect.signature(footprint).parameters
        npairs = len(footprint(cells, R, v, **kw))

        def per_spectrum():
            fp = None
            for s in range(len(R)):
                fp = footprint(cells, R[s:s + 1], v[s:s + 1], **kw, **({"out": fp} if reuse else {}))
        wall, cpu = timed(per_spectrum, spec["min_seconds"])
        hidden = None
    elif case == "occlusion":
        R, v = R[:1], v[:1]
        base = footprint(cells, R, v, **kw)
        npairs = len(base)
        wall, cpu = timed(lambda: footprint(cells, R, v, occlusion=True, **kw), spec["min_seconds"], max_calls=20)
        gw, gc = timed(lambda: footprint(cells, R, v, **kw), 0.2)
        wall = [w - float(np.median(gw)) for w in wall]
        cpu = [c - float(np.median(gc)) for c in cpu]
        box["fp"] = footprint(cells, R, v, occlusion=True, **kw)
        hidden = int(np.sum(~box["fp"].visible))
    if case not in ("chunk", "occlusion"):
        wall, cpu = timed(lambda: box.__setitem__("fp", footprint(cells, R, v, **kw)), spec["min_seconds"])
        npairs = len(box["fp"])
        hidden = None
        if case == "flux":          # the rate counts the pairs evaluated (the horizon pass), not those kept
            kept = npairs
            npairs = len(footprint(cells, R, v, airmass_model=None, threads=threads))
    mw, mc = float(np.median(wall)), float(np.median(cpu))
    out = dict(core=pi.core_info()["module"], pairs=npairs, spectra=len(R), pairs_per_spectrum=npairs / len(R), calls=len(wall),
               pairs_per_second_wall=npairs / mw, pairs_per_cpu_second=npairs / mc,
               ns_per_pair_wall=1e9 * mw / npairs, ns_per_pair_cpu=1e9 * mc / npairs,
               wall_q25_q75=[float(x) for x in np.percentile(wall, [25, 75])], peak_rss_mb=peak_rss_mb())
    if hidden is not None:
        out["hidden"] = hidden
    if case == "flux":
        out["kept_per_spectrum"] = kept / len(R)
    return out


def alternate(cells, R, v, kw, rounds: int) -> dict:
    """The two builds of the core in one process, call by call in turn (fresh
    outputs, then reused outputs, each build in each round): the ratio of their
    CPU times per round does not see the machine's speed changing between
    processes, which moves single measurements here by +-20 %."""
    import importlib

    from planet_intersect import _ext
    from planet_intersect.footprint import footprint

    if not _ext._v3_built():
        return {"error": "no _core_v3 in this installation"}
    flags = _ext.cpu_flags()
    if flags is None or _ext.missing_v3(flags):
        return {"error": "this CPU cannot run the x86-64-v3 build"}
    mods = {n: importlib.import_module("planet_intersect." + n) for n in ("_core", "_core_v3")}
    cpu = {n: {"fresh": [], "reuse": []} for n in mods}
    outs = {}
    saved = _ext._chosen
    try:
        for n in mods:                                   # warm-up, and the outputs to reuse
            _ext._chosen = (mods[n], n, "benchmark")
            outs[n] = footprint(cells, R, v, **kw)
        for _ in range(rounds):
            for n in mods:
                _ext._chosen = (mods[n], n, "benchmark")
                c = time.process_time()
                footprint(cells, R, v, **kw)
                cpu[n]["fresh"].append(time.process_time() - c)
                c = time.process_time()
                footprint(cells, R, v, out=outs[n], **kw)
                cpu[n]["reuse"].append(time.process_time() - c)
    finally:
        _ext._chosen = saved
    npairs = len(outs["_core"])
    out = dict(pairs=npairs, spectra=len(R), rounds=rounds, peak_rss_mb=peak_rss_mb())
    for mode in ("fresh", "reuse"):
        a, b = np.array(cpu["_core"][mode]), np.array(cpu["_core_v3"][mode])
        out[mode] = dict(portable=npairs / float(np.median(a)), v3=npairs / float(np.median(b)),
                         portable_q25_q75=[npairs / float(np.percentile(a, 75)), npairs / float(np.percentile(a, 25))],
                         v3_q25_q75=[npairs / float(np.percentile(b, 75)), npairs / float(np.percentile(b, 25))],
                         ratio_median=float(np.median(a / b)), ratio_min=float(np.min(a / b)))
    return out


def run_isolated(spec: dict) -> dict:
    env = dict(os.environ)
    if spec.get("core"):
        env["PI_CORE"] = spec["core"]
    proc = subprocess.run([sys.executable, __file__, "--one", json.dumps(spec)], capture_output=True, text=True,
                          env=env)
    if proc.returncode != 0:
        return {"error": proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else f"exit {proc.returncode}"}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="few spectra, 0.3 s per case (CI)")
    ap.add_argument("--footprint", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--label", default="", help="suffix of the result files (e.g. before, after)")
    ap.add_argument("--note", default="", help="a sentence for the result files (e.g. which build was measured)")
    ap.add_argument("--one", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one:
        print(json.dumps(measure(json.loads(args.one))))
        return 0
    if not MOLA.exists():
        print(f"skipped: no MOLA grid at {MOLA} (set PI_SHARED_DATA)", file=sys.stderr)
        return 0
    nspec, min_s = (8, 0.3) if args.quick else (64, 2.0)
    cases = [("geometry", "fresh", 1, ""), ("geometry", "fresh", 1, "portable"), ("geometry", "fresh", 2, ""),
             ("geometry", "reuse", 1, ""), ("geometry", "reuse", 1, "portable"), ("geometry", "reuse", 2, ""),
             ("geometry", "chunks", 1, ""), ("geometry", "chunks", 1, "portable"), ("flux", "fresh", 1, ""),
             ("occlusion", "fresh", 1, ""), ("cells", "", 1, "")]
    rows = []
    alt = run_isolated(dict(case="alternate", nspec=nspec, rounds=8 if args.quick else 30))
    if "error" in alt:
        print(f"alternating builds: {alt['error']}", flush=True)
    else:
        for mode in ("fresh", "reuse"):
            a = alt[mode]
            print(f"alternating builds, {mode:5s} outputs, {alt['rounds']} rounds: portable {a['portable']:14,.0f}, "
                  f"x86-64-v3 {a['v3']:14,.0f} pairs per CPU-s (medians); v3 faster by {a['ratio_median']:.2f}x "
                  f"(least {a['ratio_min']:.2f}x)", flush=True)
    for case, mode, threads, core in cases:
        name = "reuse" if mode == "reuse" else case
        name = "chunk" if mode == "chunks" else name
        r = run_isolated(dict(case=name, threads=threads, nspec=nspec, min_seconds=min_s, core=core))
        r.update(case=case, outputs=mode, threads=threads)
        rows.append(r)
        if "error" in r:
            line = r["error"]
        elif case == "cells":
            line = f"{r['seconds_wall']:8.2f} s wall  {r['seconds_cpu']:8.2f} s CPU  ({r['cells']} cells)"
        else:
            line = (f"{r['pairs_per_second_wall']:14,.0f} pairs/s wall  {r['pairs_per_cpu_second']:14,.0f} per CPU-s  "
                    f"{r['ns_per_pair_cpu']:7.1f} ns/pair CPU  {r['pairs_per_spectrum']:8.0f} cells/spectrum")
        print(f"{case:10s} {mode:6s} {threads}t {r.get('core', ''):8s}  {line}  peak {r.get('peak_rss_mb', float('nan')):6.0f} MB", flush=True)
    machine = dict(machine=platform.machine(), system=platform.system(), python=platform.python_version(),
                   cores=os.cpu_count(), date=time.strftime("%Y-%m-%d %H:%M"), loadavg=os.getloadavg(),
                   note="shared machine under load: CPU time per call is the figure to compare", run_note=args.note)
    name = "footprint-quick" if args.quick else "footprint"
    if args.label:
        name += "-" + args.label
    out = HERE / "results"
    out.mkdir(exist_ok=True)
    (out / f"{name}.json").write_text(json.dumps(dict(machine=machine, nspec=nspec, zeta=ZETA, rows=rows,
                                                      alternate=alt), indent=1))
    (out / f"{name}.md").write_text(markdown(rows, machine, nspec, alt))
    print(f"wrote {out / (name + '.md')}")
    return 0


def markdown(rows, machine, nspec, alt=None) -> str:
    lines = [f"# Footprint benchmark ({machine['date']}, {machine['machine']}, {machine['cores']} cores, "
             f"Python {machine['python']}, load average {machine['loadavg'][0]:.1f})", "",
             f"MOLA 4 ppd, 0.5 deg cells, {nspec} 20-s spectra of a {PERI:g} x {APO:g} km orbit, "
             f"geometry with cos psi >= {ZETA}. Shared machine under load: compare the CPU-time columns. "
             f"{machine.get('run_note', '')}", "",
             "| case | outputs | threads | core | pairs/spectrum | pairs/s (wall) | pairs per CPU-s | ns/pair (CPU) | "
             "peak RSS (MB) |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        head = f"| {r['case']} | {r['outputs']} | {r['threads']} | {r.get('core', '')} |"
        if "error" in r:
            lines.append(f"{head} {r['error']} | | | | |")
        elif r["case"] == "cells":
            lines.append(f"{head} {r['cells']} cells | build {r['seconds_wall']:.2f} s | "
                         f"{r['seconds_cpu']:.2f} CPU-s | | {r['peak_rss_mb']:.0f} |")
        else:
            extra = f" ({r['hidden']} hidden)" if "hidden" in r else ""
            if "kept_per_spectrum" in r:
                extra = f" ({r['kept_per_spectrum']:,.0f} kept)"
            lines.append(f"{head} {r['pairs_per_spectrum']:,.0f}{extra} | {r['pairs_per_second_wall']:,.0f} | "
                         f"{r['pairs_per_cpu_second']:,.0f} | {r['ns_per_pair_cpu']:.1f} | {r['peak_rss_mb']:.0f} |")
    if alt and "error" not in alt:
        lines += ["", f"Both builds in one process, call by call in turn ({alt['rounds']} rounds, 1 thread, "
                  f"{alt['pairs']:,} pairs per call; medians of CPU time per call, quartiles in brackets):", "",
                  "| outputs | portable `_core` (pairs per CPU-s) | x86-64-v3 `_core_v3` | v3 / portable per round, "
                  "median (least) |", "|---|---|---|---|"]
        for mode in ("fresh", "reuse"):
            a = alt[mode]
            lines.append(f"| {mode} | {a['portable']:,.0f} ({a['portable_q25_q75'][0]:,.0f}-"
                         f"{a['portable_q25_q75'][1]:,.0f}) | **{a['v3']:,.0f}** ({a['v3_q25_q75'][0]:,.0f}-"
                         f"{a['v3_q25_q75'][1]:,.0f}) | {a['ratio_median']:.2f} ({a['ratio_min']:.2f}) |")
    elif alt:
        lines += ["", f"Both builds in turn: {alt['error']}"]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
