"""Rugged's Duvenhage speed on a 1 m building DSM (run by hand, not collected by pytest).

    .venv/bin/python tests/references/rugged/bench_rugged.py [--n 1000] [--rays 20000]

Prints JVM start-up time, tile build, rays/s of the Java batch loop after JIT
warm-up (median of repeats), the share of each Rugged status, memory.
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # tests/

from references.rugged.bridge import RuggedDSM, jvm_startup_seconds, rugged_available  # noqa: E402
from references.rugged.scenes import building_dsm, metre_steps, pushbroom_rays  # noqa: E402


def rss_mib() -> float:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=1000, help="DSM cells per side (1 m)")
    ap.add_argument("--rays", type=int, default=20000)
    ap.add_argument("--warmup", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--lat0", type=float, default=45.0)
    args = ap.parse_args()
    ok, why = rugged_available()
    if not ok:
        sys.exit(f"Rugged not available: {why}")

    n = args.n
    dlat, dlon = metre_steps(args.lat0)
    h = building_dsm(n, seed=1)
    lat0, lon0 = args.lat0, 10.0
    print(f"DSM {n} x {n} cells of 1 m at lat {lat0}: max {h.max():.1f} m, built {np.mean(h > 0):.0%}")
    rss0 = rss_mib()
    t = time.perf_counter()
    dsm = RuggedDSM(h, lat0, lon0, dlat, dlon)
    t_make = time.perf_counter() - t
    print(f"JVM start + class load: {jvm_startup_seconds():.2f} s; RuggedDSM() total {t_make:.2f} s "
          f"(tiles {dsm.tile_rows} x {dsm.tile_cols} nodes)")
    lat_r = (lat0 + 0.05 * n * dlat, lat0 + 0.95 * n * dlat)
    lon_r = (lon0 + 0.05 * n * dlon, lon0 + 0.95 * n * dlon)
    s, l = pushbroom_rays(args.rays, lat_r, lon_r, seed=2)
    t = time.perf_counter()
    res = dsm.intersect(s, l)
    t_first = time.perf_counter() - t
    st = res["status"]
    print(f"first batch (tile build + cold JIT + transfer): {t_first:.2f} s for {args.rays} rays; "
          f"status HIT {np.mean(st == 0):.4f} REFINE_NULL {np.mean(st == 1):.4f} ERROR {np.mean(st == 2):.4f}; "
          f"inside {np.mean(res['inside']):.4f}")
    # hits off the bilinear surface at their own (lat, lon): Rugged's 1/8-cell
    # tolerance (a root on the extension of a neighbouring cell's patch)
    u = (res["lat"] - lat0) / dlat
    v = (res["lon"] - lon0) / dlon
    i = np.clip(np.floor(u).astype(int), 0, n - 2)
    j = np.clip(np.floor(v).astype(int), 0, n - 2)
    fu, fv = u - i, v - j
    hs = ((1 - fu) * ((1 - fv) * h[i, j] + fv * h[i, j + 1]) + fu * ((1 - fv) * h[i + 1, j] + fv * h[i + 1, j + 1]))
    gap = np.abs(res["h"] - hs)[res["inside"]]
    print(f"hits more than 1 mm off the bilinear surface: {np.sum(gap > 1e-3)} of {gap.size} inside hits "
          f"(max {gap.max():.2f} m)")
    rps = dsm.rays_per_second(s, l, warmup=args.warmup, repeats=args.repeats)
    tm = dsm.last_timing["times"]
    t = time.perf_counter()
    dsm.intersect(s, l)
    t_second = time.perf_counter() - t
    print(f"Java loop after {args.warmup} warm-up batches: {rps:,.0f} rays/s "
          f"(median of {args.repeats}: {np.median(tm):.3f} s, min {tm.min():.3f}, max {tm.max():.3f}); "
          f"then one whole intersect() call incl. transfer: {args.rays / t_second:,.0f} rays/s")
    mem = dsm.java_memory()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"memory: JVM heap used {mem['used'] / 2**20:.0f} MiB (committed {mem['committed'] / 2**20:.0f}, "
          f"max {mem['max'] / 2**20:.0f}); process RSS {rss0:.0f} MiB before JVM -> {rss_mib():.0f} MiB now, "
          f"peak {peak:.0f} MiB; tiles built {mem['tiles_built']}")


if __name__ == "__main__":
    main()
