#!/usr/bin/env python3
"""Benchmark of the geodetic DSM system (Shin & Park, issue 11).

    ./dev bench --geodetic --quick    # small scene, a minute; CI runs it (asserts nothing about speed)
    ./dev bench --geodetic            # the issue's scenes: 2,048 x 2,048 1 m building DSM, global Earth grid

Scenes (planet_intersect.synthetic_dsm): a 1 m building DSM on the Jacksboro
3-arc-second base DEM (matplotlib's sample data, heights above the geoid plus a
constant N = -32 m), viewed along independent lines of sight from 500-700 km at
0-30 deg off nadir (each ray its own orbit position and azimuth: no two share
a focal point), by the lines of pushbroom scans (ten scans from 500-700 km,
rolled 0-30 deg, 1 m pixels: each line's rays share a focal point, which the
exact mode's line sweep uses), and by an aircraft 1-3 km up at 10-45 deg
elevation; and the global
ETOPO20 grid of ../shared/data (20', heights above sea level taken as above
WGS-84), viewed from orbit. Methods on the same rays, each measurement in its
own process (its peak memory is its own) after an untimed warm-up call: the
paper's ray following, the conventional iterative tracing, the exact mode (one
and two threads), Orekit Rugged's Duvenhage algorithm (its Java batch loop
timed after JIT warm-up: called until its speed stops rising), and the closed-form ray-ellipsoid intersection (the
floor). rays/s from the median call. Results: benchmarks/results/geodetic*.{json,md}.
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
ETOPO = SHARED / "earth_etopo20"


def etopo20() -> dict | None:
    """The ETOPO20 grid as a global DSM grid (tests/references/earth_data.py), or None."""
    sys.path.insert(0, str(REPO / "tests"))
    from references.earth_data import etopo20_grid

    return etopo20_grid(ETOPO)


def make_scene(name: str, n: int, nrays: int):
    """(grid dict, s, l) of a named scene."""
    from planet_intersect import synthetic_dsm as sd

    if name in ("buildings-pushbroom", "buildings-airborne", "buildings-scan"):
        grid = sd.building_scene(n=n, seed=11)
        grid.pop("roof_id")
        if name.endswith("pushbroom"):
            s, l = sd.pushbroom_rays(grid, nrays, seed=3)
        elif name.endswith("scan"):
            s, l = scan_rays(grid, nrays, seed=3)
        else:
            s, l = sd.airborne_rays(grid, nrays, seed=4)
        return grid, s, l
    if name == "etopo20-pushbroom":
        grid = etopo20()
        if grid is None:
            raise FileNotFoundError(f"{ETOPO}: no ETOPO20 grid")
        rng = np.random.default_rng(7)
        from planet_intersect.geodetic import geodetic_to_ecef
        lat = np.degrees(np.arcsin(rng.uniform(-0.97, 0.97, nrays)))
        lon = rng.uniform(-180, 180, nrays)
        target = geodetic_to_ecef(lat, lon, np.zeros(nrays))
        s, l = sd._from_above(target, lat, lon, rng.uniform(500e3, 700e3, nrays), rng.uniform(0, 30, nrays),
                              rng.uniform(0, 2 * np.pi, nrays))
        return grid, s, l
    raise ValueError(name)


def scan_rays(grid: dict, nrays: int, seed: int, nscans: int = 10):
    """The lines of ``nscans`` pushbroom scans (pi.Pushbroom.from_orbit): altitudes uniform in
    500-700 km, rolls evenly spaced over 0-30 deg, a sun-synchronous inclination, 1 m pixels
    (ifov = 1 / altitude rad) and ~1 m between lines, each scan centred on a random point of the
    scene's middle third, with lines of up to 500 pixels (a third of the scene at most), as many
    lines as make ``nrays`` in all. Rays in image order: a line's pixels consecutive."""
    import planet_intersect as pi

    rng = np.random.default_rng(seed)
    nr, nc = grid["heights"].shape
    npx = int(min(500, max(2, min(nr, nc) // 3)))
    nl = max(1, nrays // (nscans * npx))
    ss, ll = [], []
    for k, roll in enumerate(np.linspace(0.0, 30.0, nscans)):
        alt = rng.uniform(500e3, 700e3)
        i, j = rng.uniform(1 / 3, 2 / 3) * (nr - 1), rng.uniform(1 / 3, 2 / 3) * (nc - 1)
        lat = grid["lat_first"] + i * grid["dlat"]
        lon = grid["lon_first"] + j * grid["dlon"]
        sen = pi.Pushbroom.from_orbit(altitude=alt, inclination=97.5, npixels=npx, ifov=np.degrees(1.0 / alt),
                                      nlines=nl, line_period=1.0 / 7000.0, target=(lat, lon),
                                      direction="ascending" if k % 2 == 0 else "descending", roll=roll,
                                      a=grid["a"], f=grid["f"])
        s, l = sen.rays()
        ss.append(s)
        ll.append(l)
    return np.concatenate(ss), np.concatenate(ll)


def peak_rss_mb() -> float:
    try:
        return int(Path("/proc/self/status").read_text().split("VmHWM:")[1].split()[0]) / 1024.0
    except (OSError, IndexError):
        return float("nan")


def ellipsoid_floor(s, l, a, b):
    """Closed-form first intersection with the bare ellipsoid (vectorised NumPy)."""
    w = np.array([1 / a, 1 / a, 1 / b])
    S, L = s * w, l * w
    A = np.einsum("ij,ij->i", L, L)
    B = np.einsum("ij,ij->i", S, L)
    C = np.einsum("ij,ij->i", S, S) - 1
    disc = B * B - A * C
    t = (-B - np.sqrt(np.maximum(disc, 0))) / A
    return np.where(disc >= 0, t, np.nan)


def warm_rugged(rug, s, l, max_calls: int = 25) -> list:
    """Call Rugged's Java loop on the rays until its speed stops rising (its JIT keeps compiling
    for several calls: on 20,000 building rays 8,467, then 38,783-48,334 rays/s for calls 2-7 and
    53,974-63,424 from the eighth on, 2026-12-02; three warm-up calls, as before, timed it ~1.3x
    slow): at least 10 calls, then until three calls in a row set no new high by more than 5 %.
    Returns the rays/s of every call."""
    rates = []
    for _ in range(max_calls):
        rates.append(rug.rays_per_second(s, l, warmup=0, repeats=1))
        if len(rates) >= 10 and max(rates[-3:]) <= 1.05 * max(rates[:-3]):
            break
    return rates


def rugged_tiling(scene: str) -> dict:
    """The Rugged bridge's tiles for a scene: one tile over the whole DSM (its fastest on rays from orbit:
    ~120k rays/s against 116k and 110k with 513- and 257-node tiles), except for the airborne rays, whose
    low lines of sight reach the ellipsoid kilometres outside the DSM: Rugged asks for tiles there, and
    rebuilding 2,176^2-node fill tiles in a cache of 8 held it at 20-126 rays/s ("did not finish in
    300 s" until 2026-12-05), where 257-node tiles in a cache of 256 run ~4,000 rays/s (an independent
    review of the benchmark)."""
    return dict(tile_size=257, max_cached_tiles=256) if scene == "buildings-airborne" else {}


def measure(spec: dict) -> dict:
    """One (scene, method) measurement in this process."""
    import planet_intersect as pi

    grid, s, l = make_scene(spec["scene"], spec["n"], spec["nrays"])
    method, threads = spec["method"], 1
    if method.endswith("@2"):
        method, threads = method[:-2], 2
    out = {"rays": len(s)}
    dsm = pi.GeodeticDSM.from_array(grid["heights"], grid["lat_first"], grid["lon_first"], grid["dlat"],
                                    grid["dlon"], a=grid["a"], f=grid["f"])
    if method == "rugged":
        sys.path.insert(0, str(REPO / "tests"))
        from references.rugged.bridge import RuggedDSM, rugged_available
        ok, why = rugged_available()
        if not ok:
            return {"error": f"Rugged not available: {why}"}
        tiling = rugged_tiling(spec["scene"])
        rug = RuggedDSM(grid["heights"], grid["lat_first"], grid["lon_first"], grid["dlat"], grid["dlon"],
                        a=grid["a"], f=grid["f"], **tiling)
        out.update(rugged_tiling=tiling or "the bridge's default: one tile over the DSM (at most half a turn "
                   "on a global grid), 8 cached")
        warm = warm_rugged(rug, s, l)
        rps = rug.rays_per_second(s, l, warmup=0, repeats=5)
        out.update(rugged_warmup_calls=len(warm), rugged_warmup_rays_per_second=[round(w) for w in warm])
        res = rug.intersect(s, l)
        out.update(rays_per_second=rps, steps_per_ray=float("nan"), hits=int(np.sum(res["hit"])),
                   peak_rss_mb=peak_rss_mb())
        return out
    if method == "exact":
        dsm.pyramid()                           # built once per DSM and cached: not ray time
    times, warm, steps, hits = [], True, float("nan"), 0
    while True:
        t0 = time.perf_counter()
        if method == "floor":
            t_floor = ellipsoid_floor(s, l, grid["a"], grid["a"] * (1 - grid["f"]))
            hits = int(np.isfinite(t_floor).sum())            # rays that meet the bare ellipsoid
        else:
            res = pi.intersect(dsm, s, l, method=method, threads=threads)
            steps, hits = float(np.mean(res.nsteps)), int(np.sum(res.hit))
        dt = time.perf_counter() - t0
        if warm:
            warm = False
            continue
        times.append(dt)
        if sum(times) > spec["min_seconds"] or len(times) >= 200:
            break
    q25, med, q75 = np.percentile(times, [25, 50, 75])
    out.update(rays_per_second=len(s) / med, rays_per_second_q25_q75=[len(s) / q75, len(s) / q25],
               calls=len(times), steps_per_ray=steps, hits=hits, peak_rss_mb=peak_rss_mb())
    return out


def measure_alternating(spec: dict) -> dict:
    """Ratios of the exact mode to the following and to Rugged, and of two threads to one, called in turn
    in one process, ``rounds`` times on the same rays (each timed on its second call): this machine's speed moves
    by up to 1.5x between processes, so ratios across separate processes are noisy; per-round
    ratios in one process are not. Returns the median and the range of each ratio."""
    import planet_intersect as pi

    grid, s, l = make_scene(spec["scene"], spec["n"], spec["nrays"])
    dsm = pi.GeodeticDSM.from_array(grid["heights"], grid["lat_first"], grid["lon_first"], grid["dlat"],
                                    grid["dlon"], a=grid["a"], f=grid["f"])
    dsm.pyramid()
    rug = None
    sys.path.insert(0, str(REPO / "tests"))
    from references.rugged.bridge import RuggedDSM, rugged_available
    if rugged_available()[0]:
        rug = RuggedDSM(grid["heights"], grid["lat_first"], grid["lon_first"], grid["dlat"], grid["dlon"],
                        a=grid["a"], f=grid["f"])
        warm_rugged(rug, s, l)                                    # JIT warm-up, until its speed stops rising
    for method in ("exact", "following"):
        pi.intersect(dsm, s, l, method=method, threads=1)        # warm-up
    def timed(method, threads=1):
        # the second of two calls: each method warm (its data in cache), as the separate-process medians
        pi.intersect(dsm, s, l, method=method, threads=threads)
        t0 = time.perf_counter()
        pi.intersect(dsm, s, l, method=method, threads=threads)
        return time.perf_counter() - t0

    fol, rg, two = [], [], []
    for _ in range(spec.get("rounds", 7)):
        te = timed("exact")
        fol.append(timed("following") / te)
        two.append(te / timed("exact", threads=2))
        if rug is not None:                                      # its Java loop's own clock (1 warm + 3 timed)
            rg.append(len(s) / rug.rays_per_second(s, l, warmup=1, repeats=3) / te)
    out = {"rounds": len(fol), "exact_over_following": [float(np.median(fol)), min(fol), max(fol)],
           "two_threads_over_one": [float(np.median(two)), min(two), max(two)]}
    if rg:
        out["exact_over_rugged"] = [float(np.median(rg)), min(rg), max(rg)]
    return out


def run_isolated(spec: dict, timeout: float = 300.0) -> dict:
    try:
        proc = subprocess.run([sys.executable, __file__, "--one", json.dumps(spec)], capture_output=True, text=True,
                              timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"error": f"did not finish within {timeout:.0f} s"}
    if proc.returncode != 0:
        return {"error": proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else f"exit {proc.returncode}"}
    return json.loads(proc.stdout.strip().splitlines()[-1])


METHODS = ["following", "iterative", "exact", "exact@2", "rugged", "floor"]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="a 512 x 512 scene and 2,000 rays (CI)")
    ap.add_argument("--geodetic", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--full", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--one", help=argparse.SUPPRESS)
    ap.add_argument("--out", type=Path, default=HERE / "results",
                    help="folder of the result files (default benchmarks/results)")
    ap.add_argument("--scenes", nargs="+", default=None,
                    choices=["buildings-pushbroom", "buildings-scan", "buildings-airborne", "etopo20-pushbroom"],
                    help="measure only these scenes (the result files then hold only them)")
    args = ap.parse_args(argv)
    if args.one:
        spec = json.loads(args.one)
        print(json.dumps(measure_alternating(spec) if spec.get("method") == "alternating" else measure(spec)))
        return 0
    if args.quick:
        n, nrays, min_s, scenes = 512, 2000, 0.3, ["buildings-pushbroom", "buildings-scan"]
    else:
        n, nrays, min_s = 2048, 20000, 2.0
        scenes = ["buildings-pushbroom", "buildings-scan", "buildings-airborne", "etopo20-pushbroom"]
    if args.scenes:
        scenes = [sc for sc in scenes if sc in args.scenes] or args.scenes
    rows = []
    for sc in scenes:
        for m in METHODS:
            spec = dict(scene=sc, method=m, n=n, nrays=nrays, min_seconds=min_s)
            r = run_isolated(spec)
            r.update(scene=sc, method=m)
            rows.append(r)
            rps = r.get("rays_per_second")
            print(f"{sc:22s} {m:10s} " + (f"{rps:12,.0f} rays/s  steps {r.get('steps_per_ray', float('nan')):8.1f}  "
                                          f"hits {r.get('hits')}  peak {r.get('peak_rss_mb', float('nan')):7.0f} MB"
                                          if rps else r.get("error", "?")), flush=True)
    # the ratios with the methods called in turn in one process (the building scenes viewed from orbit)
    alts = []
    for sc in [x for x in scenes if x in ("buildings-pushbroom", "buildings-scan")]:
        alt = run_isolated(dict(scene=sc, method="alternating", n=n, nrays=nrays, rounds=7), timeout=600.0)
        alt.update(scene=sc)
        alts.append(alt)
        if "exact_over_following" in alt:
            ef = alt["exact_over_following"]
            er = alt.get("exact_over_rugged")
            tw = alt["two_threads_over_one"]
            print(f"{sc:22s} in turn, one process: exact = {ef[0]:.2f}x following ({ef[1]:.2f}-{ef[2]:.2f})"
                  + (f", {er[0]:.2f}x Rugged ({er[1]:.2f}-{er[2]:.2f})" if er else ", Rugged not available")
                  + f"; 2 threads {tw[0]:.2f}x one ({tw[1]:.2f}-{tw[2]:.2f})", flush=True)
        else:
            print(f"{sc:22s} in turn, one process: {alt.get('error', '?')}", flush=True)
    machine = dict(machine=platform.machine(), system=platform.system(), python=platform.python_version(),
                   cores=os.cpu_count(), date=time.strftime("%Y-%m-%d"))
    name = "geodetic-quick" if args.quick else "geodetic"
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}.json").write_text(json.dumps(dict(machine=machine, rows=rows, alternating=alts), indent=1))
    (out / f"{name}.md").write_text(markdown(rows, machine, alts))
    print(f"wrote {out / (name + '.md')}")
    return 0


def markdown(rows, machine, alts=None) -> str:
    lines = [f"# Geodetic DSM benchmark ({machine['date']}, {machine['machine']}, {machine['cores']} cores, "
             f"Python {machine['python']})", "",
             "Scenes: buildings-pushbroom = random rays (each its own orbit position at 500-700 km and azimuth, "
             "0-30 deg off nadir); buildings-scan = the lines of ten pushbroom scans (rays share a focal point per "
             "line); buildings-airborne = 1-3 km up, 10-45 deg elevation; etopo20-pushbroom = random rays from "
             "orbit over the global ETOPO20 grid. The x following and x Rugged columns compare separate processes, "
             "whose speed moves by up to ~1.9x on this machine: quote the in-turn ratios below.", "",
             "| scene | method | rays/s | × following | × Rugged | steps/ray | hits | peak RSS (MB) |",
             "|---|---|---|---|---|---|---|---|"]
    by = {(r["scene"], r["method"]): r for r in rows}
    for r in rows:
        rps = r.get("rays_per_second")
        if not rps:
            lines.append(f"| {r['scene']} | {r['method']} | {r.get('error', '?')} | | | | | |")
            continue
        f = by.get((r["scene"], "following"), {}).get("rays_per_second")
        g = by.get((r["scene"], "rugged"), {}).get("rays_per_second")
        lines.append(f"| {r['scene']} | {r['method']} | {rps:,.0f} | {rps / f:.1f} | " if f else
                     f"| {r['scene']} | {r['method']} | {rps:,.0f} | | ")
        lines[-1] += (f"{rps / g:.1f} | " if g else " | ") + \
            f"{r.get('steps_per_ray', float('nan')):.1f} | {r.get('hits', '')} | {r.get('peak_rss_mb', float('nan')):.0f} |"
    alts = [a for a in (alts or []) if "exact_over_following" in a]
    if alts:
        lines += ["", f"Called in turn in one process ({alts[0]['rounds']} rounds, wall time, one thread; "
                  "median and range of the per-round ratios):", "",
                  "| scene | ratio | median | range |", "|---|---|---|---|"]
        for alt in alts:
            ef, er = alt["exact_over_following"], alt.get("exact_over_rugged")
            lines.append(f"| {alt['scene']} | exact / following | {ef[0]:.2f} | {ef[1]:.2f}-{ef[2]:.2f} |")
            if er:
                lines.append(f"| {alt['scene']} | exact / Rugged (Java loop) | {er[0]:.2f} | {er[1]:.2f}-{er[2]:.2f} |")
            tw = alt.get("two_threads_over_one")
            if tw:
                lines.append(f"| {alt['scene']} | exact, 2 threads / 1 | {tw[0]:.2f} | {tw[1]:.2f}-{tw[2]:.2f} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
