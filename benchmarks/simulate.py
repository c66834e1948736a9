#!/usr/bin/env python3
"""Benchmark of the image simulation (Shin & Park, issue 12).

    ./dev bench --simulate --quick    # 512 x 512 pixels, a minute; CI runs it (asserts nothing about speed)
    ./dev bench --simulate            # the issue's 4,096 x 4,096-pixel image over the 1 m building DSM

Scene: ``synthetic_dsm.building_scene`` — a 1 m building DSM (blocks 3-150 m
tall, one-cell towers, courtyards) on the Jacksboro 3-arc-second base DEM,
4,096 + 2 x 64 cells a side — with a synthetic ortho-photo of the same grid,
seen by a pushbroom viewing every row at 9 deg zenith from the East
(``ObliqueScan``, Shin & Park's geometry), one pixel per cell. Each case runs
in its own process (its peak memory is its own): the whole image with the
exact mode (backplanes memory-mapped to a temporary folder, occlusion off),
and a band of lines with each method, with two threads, and with the
occlusion mask. Results: benchmarks/results/simulate[-quick].{json,md}.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
MARGIN = 64


def scene(n_pixels: int):
    import numpy as np

    import planet_intersect as pi
    from planet_intersect.synthetic_dsm import ObliqueScan, _texture, building_scene

    n = n_pixels + 2 * MARGIN
    sc = building_scene(n=n, seed=5)
    dsm = pi.GeodeticDSM.from_array(sc["heights"], sc["lat_first"], sc["lon_first"], sc["dlat"], sc["dlon"],
                                    interpolation="nearest")
    rgb = _texture(n, n, np.random.default_rng(3)).astype(np.uint8)
    ortho = pi.OrthoImage.from_array(rgb, sc["lat_first"], sc["lon_first"], sc["dlat"], sc["dlon"])
    sensor = ObliqueScan(sc, zenith=9.0, azimuth=90.0, margin=MARGIN)
    ground = np.zeros_like(sc["heights"])
    roof = sc["roof_id"] > 0
    ground[:] = sc["heights"]
    ground[roof] = np.nan                      # the base terrain under the buildings: filled from around
    from scipy import ndimage

    idx = ndimage.distance_transform_edt(np.isnan(ground), return_distances=False, return_indices=True)
    ground = ground[tuple(idx)]
    return dsm, ortho, sensor, ground


def run_case(case: dict) -> dict:
    import numpy as np

    import planet_intersect as pi

    t0 = time.perf_counter()
    dsm, ortho, sensor, ground = scene(case["n"])
    t_scene = time.perf_counter() - t0
    lines = case.get("lines") or sensor.nlines

    class Band(pi.sensors.Sensor):
        def __init__(self):
            self.shape = (lines, sensor.npixels)

        def rays(self, k0=0, k1=None):
            k0, k1 = self._check_block(k0, self.nlines if k1 is None else k1)
            off = (sensor.nlines - lines) // 2
            return sensor.rays(k0 + off, k1 + off)

    band = Band()
    # warm-up (the DSM's pyramid, first calls), untimed: two lines
    pi.simulate_image(dsm, ortho, pi.Pushbroom(*[a.reshape(2, sensor.npixels, 3)[:, 0] if i == 0 else
                                                a.reshape(2, sensor.npixels, 3) for i, a in
                                                enumerate(sensor.rays(0, 2))]),
                      method=case["method"], ground=ground, occlusion=False, threads=case["threads"])
    with tempfile.TemporaryDirectory() as tmp:
        t1 = time.perf_counter()
        cpu1 = time.process_time()
        sim = pi.simulate_image(dsm, ortho, band, method=case["method"], ground=ground,
                                occlusion=case["occlusion"], threads=case["threads"],
                                out=Path(tmp) / "maps" if case.get("memmap") else None)
        wall = time.perf_counter() - t1
        cpu = time.process_time() - cpu1
        counts = sim.counts()
        npx = int(np.prod(sim.shape))
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return dict(case, pixels=npx, seconds=wall, cpu_seconds=cpu, seconds_rays=sim.meta["seconds_rays"],
                seconds_occlusion=sim.meta.get("seconds_occlusion", 0.0), pixels_per_second=npx / wall,
                pixels_per_cpu_second=npx / cpu, peak_rss_mb=rss, scene_seconds=t_scene,
                hit_fraction=float(np.mean(sim.valid)), walls=counts.get("wall", 0),
                not_converged=counts.get("status OSCILLATION", 0) + counts.get("status NOT_CONVERGED", 0))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--simulate", action="store_true", help="(the ./dev bench switch)")
    ap.add_argument("--quick", action="store_true", help="512 x 512 pixels instead of 4,096 x 4,096")
    ap.add_argument("--case", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.case:
        print(json.dumps(run_case(json.loads(args.case))))
        return 0
    n = 512 if args.quick else 4096
    band = 64 if args.quick else 256
    cases = [
        dict(name="whole image", n=n, lines=None, method="exact", threads=1, occlusion=False, memmap=True),
        dict(name="band", n=n, lines=band, method="exact", threads=1, occlusion=False),
        dict(name="band", n=n, lines=band, method="exact", threads=2, occlusion=False),
        dict(name="band", n=n, lines=band, method="following", threads=1, occlusion=False),
        dict(name="band", n=n, lines=band, method="iterative", threads=1, occlusion=False),
        dict(name="band + occlusion", n=n, lines=band, method="exact", threads=1, occlusion=True),
    ]
    rows = []
    for c in cases:
        t = time.perf_counter()
        out = subprocess.run([sys.executable, __file__, "--case", json.dumps(c)], capture_output=True, text=True)
        if out.returncode != 0:
            print(out.stderr, file=sys.stderr)
            return 1
        r = json.loads(out.stdout.strip().splitlines()[-1])
        rows.append(r)
        print(f"{r['name']:>17} {r['method']:>9} threads={r['threads']} {r['pixels']:>10,} px  "
              f"{r['pixels_per_second']:>10,.0f} px/s  ({r['pixels_per_cpu_second']:,.0f} per CPU-s; rays "
              f"{r['seconds_rays']:.1f} of {r['seconds']:.1f} s)  peak {r['peak_rss_mb']:,.0f} MB  "
              f"[{time.perf_counter() - t:.0f} s]", flush=True)
    load = os.getloadavg()[0]
    meta = dict(date=time.strftime("%Y-%m-%d %H:%M"), machine=platform.machine(), cores=os.cpu_count(),
                python=platform.python_version(), load_average=load, pixels=f"{n} x {n}")
    stem = "simulate-quick" if args.quick else "simulate"
    res = HERE / "results"
    res.mkdir(exist_ok=True)
    (res / f"{stem}.json").write_text(json.dumps(dict(meta=meta, rows=rows), indent=1))
    base = next(r for r in rows if r["name"] == "band" and r["method"] == "exact" and r["threads"] == 1)
    lines = [f"# Image simulation benchmark ({meta['date']}, {meta['machine']}, {meta['cores']} cores, "
             f"Python {meta['python']}, load average {load:.1f})", "",
             f"{n} x {n}-pixel pushbroom at 9 deg from the East over a 1 m building DSM (Jacksboro base, blocks "
             "3-150 m), one pixel per cell. One run; each case in its own process.", "",
             "| case | method | threads | pixels | px/s (wall) | px per CPU-s | rays / total s | vs exact band | "
             "peak RSS (MB) |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['name']} | {r['method']} | {r['threads']} | {r['pixels']:,} | "
                     f"{r['pixels_per_second']:,.0f} | {r['pixels_per_cpu_second']:,.0f} | "
                     f"{r['seconds_rays']:.1f} / {r['seconds']:.1f} | "
                     f"{r['pixels_per_second'] / base['pixels_per_second']:.2f} | {r['peak_rss_mb']:,.0f} |")
    (res / f"{stem}.md").write_text("\n".join(lines) + "\n")
    print(f"wrote {res / (stem + '.md')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
