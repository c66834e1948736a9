#!/usr/bin/env python3
"""planet-intersect benchmark harness.

    ./dev bench --quick          # small, under a minute; what CI runs (asserts nothing about speed)
    ./dev bench --full           # 4-128 pixels/degree, all methods (tens of minutes, ~10 GB of cache)

Scenes: the Olympus Mons oblique view (101 x 101), a limb scan (21-pixel arrays,
many frames) and random rays over the whole globe. DEMs: synthetic global DEMs
with realistic roughness at 4, 16, 64 and 128 pixels/degree, generated in blocks
and cached outside the repository ($PI_BENCH_CACHE, default
~/.cache/planet-intersect/bench), plus the MOLA 4 ppd grid of ../shared/data.
Methods, on the same rays: the paper's stepping with dem_read_mode 0 and 1, the
pure-NumPy reference (subset), SPICE dskxv on a DSK of the same grid (where one
type-2 segment holds it), the exact mode, and a closed-form ray-spheroid
intersection (the floor). Each measurement runs in a fresh process so that its
peak resident memory is its own. Results: JSON and a Markdown table in
benchmarks/results/ (quick runs go to benchmarks/results/quick-*).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
CACHE = Path(os.environ.get("PI_BENCH_CACHE", Path.home() / ".cache" / "planet-intersect" / "bench"))
SHARED = Path(os.environ.get("PI_SHARED_DATA", REPO.parent / "shared" / "data"))
MOLA = SHARED / "mars_mola_megdr_4ppd" / "mars_radius_4ppd_megt_plus_areoid.i2be"
MAX_DSK_VERTICES = 16_000_002     # one type-2 DSK segment


# --------------------------------------------------------------------------- DEMs
def synthetic_dem_path(ppd: int) -> Path:
    """A Mars-like synthetic DEM (spheroid + shield volcano + waves + per-cell roughness)
    written in row blocks as float32, cached; returns the .hdr path."""
    from planet_intersect.synthetic import MARS_F, MARS_MEAN_RADIUS, MARS_RE, OLYMPUS
    from planet_intersect.geometry import spheroid_radius

    hdr = CACHE / f"synthetic_{ppd}ppd.hdr"
    if hdr.exists():
        return hdr
    CACHE.mkdir(parents=True, exist_ok=True)
    nlat, nlon = 180 * ppd, 360 * ppd
    rng = np.random.default_rng(2008)
    waves = [(int(rng.integers(1, 200)), int(rng.integers(1, 200)), rng.standard_normal(), *rng.uniform(0, 2 * np.pi, 2))
             for _ in range(80)]
    lon = np.radians((np.arange(nlon) + 0.5) / ppd)
    lon_terms = [np.cos(m * lon + p2) for (m, k, a, p1, p2) in waves]
    part = hdr.with_suffix(".dem.part")
    top = 0.0
    block = max(1, 2_000_000 // nlon)
    with open(part, "wb") as fh:
        for j0 in range(0, nlat, block):
            lat_deg = -90 + (np.arange(j0, min(j0 + block, nlat)) + 0.5) / ppd
            lat = np.radians(lat_deg)[:, None]
            r = np.repeat(spheroid_radius(lat_deg, MARS_F, MARS_RE)[:, None], nlon, axis=1)
            for (m, k, a, p1, p2), lt in zip(waves, lon_terms):
                r += (1.2 * a / np.sqrt(m * k) * 20) * (np.cos(lat) * np.cos(k * lat + p1)) * lt[None, :]
            la0, lo0 = np.radians(OLYMPUS[0]), np.radians(OLYMPUS[1])
            c = np.sin(lat) * np.sin(la0) + np.cos(lat) * np.cos(la0) * np.cos(lon[None, :] - lo0)
            r += 21.0 * np.exp(-(MARS_MEAN_RADIUS * np.arccos(np.clip(c, -1, 1)) / 160.0) ** 2)
            r += 0.05 * np.random.default_rng(j0).standard_normal(r.shape)      # metre-scale roughness
            r32 = r.astype("<f4")
            top = max(top, float(r32.max()))
            fh.write(r32.tobytes())
    os.replace(part, hdr.with_suffix(".dem"))
    hdr.write_text(f"{ppd}\n{top + 0.001!r}\n{MARS_F!r}\n{MARS_RE!r}\ndtype = float32\nbyteorder = little\n")
    return hdr


def mola_dem_path() -> Path | None:
    from planet_intersect.mola import import_mola

    hdr = CACHE / "mola_4ppd.hdr"
    if not hdr.exists():
        if not MOLA.exists():
            return None
        CACHE.mkdir(parents=True, exist_ok=True)
        import_mola(hdr.with_suffix(""), radius=MOLA)
    return hdr


# --------------------------------------------------------------------------- scenes
def scene(name: str, dem, nrays: int):
    """(s, l) of a scene: the two examples' geometries, or random rays over the globe."""
    from planet_intersect.examples import limb_geometry, olympus_geometry
    from planet_intersect.synthetic import MARS_MEAN_RADIUS

    if name == "olympus":
        s, l = olympus_geometry()
        return np.broadcast_to(s, l.shape).copy(), l
    if name == "limb":
        frames = max(1, nrays // 21)
        S, L = limb_geometry(np.linspace(-20.0, 10.0, frames))
        return np.repeat(S, 21, axis=0), L.reshape(-1, 3)
    if name == "global":
        rng = np.random.default_rng(5)
        u = rng.standard_normal((nrays, 3))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        target = u * 3390.0
        v = rng.standard_normal((nrays, 3))
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        s = u * (MARS_MEAN_RADIUS + rng.uniform(300, 2000, nrays))[:, None] + 300 * v
        return s, target - s
    raise ValueError(name)


# --------------------------------------------------------------------------- one measurement
def measure(spec: dict) -> dict:
    """Run one (dem, scene, method) measurement in this process; return its figures."""
    import planet_intersect as pi

    dem = pi.DEM.read(spec["dem"])
    s, l = scene(spec["scene"], dem, spec["nrays"])
    method = spec["method"]
    if method.startswith("exact"):
        dem.pyramid()                   # built once per DEM and cached: not part of the ray time
    if method == "reference":
        s, l = s[: spec["reference_rays"]], l[: spec["reference_rays"]]
    n = len(s)
    out = {"rays": n}
    threads = spec["threads"]
    if method.endswith("@2"):
        method, threads = method[:-2], 2
    warm = 1                                 # one untimed call: conversions, page faults, kernel loads
    times = []                               # seconds per timed call
    while True:
        t0 = time.perf_counter()
        if method.startswith("stepping") or method.startswith("exact"):
            kind = "exact" if method.startswith("exact") else "stepping"
            mode = 0 if method.endswith("0") else 1
            io = "mmap" if method.endswith("mmap") else "records"
            res = pi.intersect(dem, s, l, dem_read_mode=mode, io=io, method=kind, threads=threads)
            steps = float(res.nsteps.mean())
        elif method == "reference":
            from planet_intersect import reference
            r = reference.intersect(np.asarray(dem.radii), dem.ppd, dem.rmax, dem.f, dem.re, s, l)
            steps = float(r["nsteps"].mean())
        elif method == "spice":
            import spiceypy as sp
            from planet_intersect.spice_dsk import write_dsk
            dsk = CACHE / (Path(spec["dem"]).stem + ".bds")
            if not dsk.exists():
                write_dsk(dem, dsk)
            if warm:
                sp.furnsh(str(dsk))
            xpt, found = sp.dskxv(False, "MARS", [], 0.0, "IAU_MARS", s, l / np.linalg.norm(l, axis=1, keepdims=True))
            steps = float("nan")
        elif method == "floor":
            from planet_intersect.geometry import ray_spheroid_intersection
            ray_spheroid_intersection(s, l, dem.f, dem.re)
            steps = 0.0
        else:
            raise ValueError(method)
        if warm:
            warm = 0
            continue
        times.append(time.perf_counter() - t0)
        if sum(times) > spec["min_seconds"] or len(times) >= 1000:
            break
    # the median call: a busy neighbour on a shared machine slows some calls, not the typical one
    q25, med, q75 = np.percentile(times, [25, 50, 75])
    out.update(seconds=float(med), rays_per_second=n / med, rays_per_second_q25_q75=[n / q75, n / q25],
               calls=len(times), steps_per_ray=steps, peak_rss_mb=peak_rss_mb())
    return out


def peak_rss_mb() -> float:
    """This process's peak resident memory: VmHWM (ru_maxrss would carry the parent's over exec)."""
    try:
        return int(Path("/proc/self/status").read_text().split("VmHWM:")[1].split()[0]) / 1024.0
    except (OSError, IndexError):
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run_isolated(spec: dict) -> dict:
    proc = subprocess.run([sys.executable, __file__, "--one", json.dumps(spec)], capture_output=True, text=True)
    if proc.returncode != 0:
        return {"error": proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else f"exit {proc.returncode}"}
    return json.loads(proc.stdout.strip().splitlines()[-1])


# --------------------------------------------------------------------------- driver
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="small run (the default)")
    ap.add_argument("--full", action="store_true", help="4-128 ppd, all scenes and methods")
    ap.add_argument("--threads", type=int, default=1, help="OpenMP threads for the Fortran methods (default 1)")
    ap.add_argument("--one", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one:
        print(json.dumps(measure(json.loads(args.one))))
        return 0

    full = args.full
    ppds = [4, 16, 64, 128] if full else [4]
    scenes = {"olympus": 10201, "limb": 21 * (400 if full else 40), "global": 20000 if full else 2000}
    dems = [(f"synthetic {p} ppd", synthetic_dem_path(p), p) for p in ppds]
    mola = mola_dem_path()
    if mola:
        dems.insert(0, ("MOLA 4 ppd", mola, 4))
    min_seconds = 2.0 if full else 0.2
    rows = []
    for dem_name, hdr, ppd in dems:
        for scene_name, nrays in scenes.items():
            for method in ("floor", "spice", "stepping0", "stepping0@2", "stepping1", "stepping-mmap", "exact0",
                           "exact-mmap", "reference"):
                if method.endswith("@2") and (ppd != 4 or scene_name == "global"):
                    continue
                if method == "spice" and (180 * ppd) * (360 * ppd) + 2 > MAX_DSK_VERTICES:
                    continue
                if method == "reference" and ppd > 16:
                    continue
                if method.endswith("0") and ppd > 64:       # an 8.5 GB float64 copy: use the mmap path (bit-identical)
                    continue
                if method == "stepping1" and (scene_name == "global" and ppd > 16 or (not full and scene_name != "olympus")):
                    continue
                spec = dict(dem=str(hdr), scene=scene_name, nrays=nrays, method=method, threads=args.threads,
                            min_seconds=min_seconds, reference_rays=300)
                r = run_isolated(spec)
                r.update(dem=dem_name, ppd=ppd, scene=scene_name, method=method)
                rows.append(r)
                print(f"{dem_name:>20} {scene_name:>8} {method:>10}: " +
                      (f"{r['rays_per_second']:12.0f} rays/s, {r['steps_per_ray']:8.1f} steps/ray, "
                       f"{r['peak_rss_mb']:7.0f} MB" if "error" not in r else f"error: {r['error']}"), flush=True)
    # ratios within each (dem, scene)
    for r in rows:
        peers = {q["method"]: q for q in rows if q["dem"] == r["dem"] and q["scene"] == r["scene"] and "error" not in q}
        if "error" in r:
            continue
        for ref in ("spice", "floor", "stepping0", "stepping-mmap"):
            if r["method"] == "stepping0@2" and "stepping0" in peers:
                r["thread_speedup"] = r["rays_per_second"] / peers["stepping0"]["rays_per_second"]
            if ref in peers:
                r[f"vs_{ref}"] = r["rays_per_second"] / peers[ref]["rays_per_second"]
    machine = {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
               "cpus": os.cpu_count(), "python": platform.python_version(), "threads": args.threads,
               "date": time.strftime("%Y-%m-%d")}
    outdir = HERE / "results"
    outdir.mkdir(exist_ok=True)
    stem = "full" if full else "quick"
    (outdir / f"{stem}.json").write_text(json.dumps({"machine": machine, "rows": rows}, indent=1))
    (outdir / f"{stem}.md").write_text(markdown(rows, machine))
    print(f"wrote {outdir / (stem + '.json')} and {outdir / (stem + '.md')}")
    return 0


def markdown(rows, machine) -> str:
    lines = [f"Machine: {machine['processor']}, {machine['cpus']} cores, {machine['platform']}, Python "
             f"{machine['python']}, {machine['threads']} thread(s), {machine['date']}.", "",
             "Methods: stepping0/1 = the paper's stepping with dem_read_mode 0/1 (record reads); "
             "stepping-mmap = mode 1 through the memory map; exact0/exact-mmap = the exact first-hit mode; "
             "stepping0@2 = two OpenMP threads; "
             "reference = the NumPy transcription (first 300 rays); spice = dskxv on a DSK of the same grid; "
             "floor = closed-form ray-spheroid intersection. steps/ray: test points (stepping) or segments (exact). "
             "rays/s: from the median of the timed calls (at least min_seconds of them, after one untimed call); "
             "the JSON also holds the rays/s of the quartile calls.", "",
             "| DEM | scene | method | rays | rays/s | × SPICE | × stepping (mmap) | ÷ floor | steps/ray | peak RSS MB |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['dem']} | {r['scene']} | {r['method']} | | error: {r['error']} | | | | | |")
            continue
        fmt = lambda k: f"{r[k]:.2f}" if k in r else ""
        floor = f"{1 / r['vs_floor']:.1f}" if "vs_floor" in r else ""
        steps = "" if r["steps_per_ray"] != r["steps_per_ray"] else f"{r['steps_per_ray']:.1f}"
        lines.append(f"| {r['dem']} | {r['scene']} | {r['method']} | {r['rays']} | {r['rays_per_second']:.0f} | "
                     f"{fmt('vs_spice')} | {fmt('vs_stepping-mmap')} | {floor} | {steps} | {r['peak_rss_mb']:.0f} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
