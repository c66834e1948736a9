"""A speed bound for any cell-walking exact mode, measured in turn with the package's exact mode, the
faithful following and Orekit Rugged on the geodetic benchmark's building scene and rays.

    ./dev bench --cell-walk [--n 2048] [--rays 20000] [--rounds 7] [--out benchmarks/results/cell_walk.json]
                            [--figure docs/figures/cell_walk_bound.png]

Issue 11 asks the exact mode for 10x Rugged's Duvenhage and 20x the faithful following. Fourteen
looks at the exact mode (docs/shin-park-notes.md) left it at 4.2-6.3x and 4.4-7.1x. This probe asks
a different question: how fast could ANY design that walks the ray's cells be? It times
``benchmarks/cell_walk/cell_walk_bound.f90``, compiled here with the package's own flags. Per ray:
two crossings of raised ellipsoids, two conversions, a walk over 8 x 8-cell block maxima and then
cells, and a closed-form bilinear root on a straight track. Also timed: cells alone, 32 x 32-cell
superblocks above the blocks, and the walk followed by the least refinement a sound answer adds
(two exact conversions 1 mm either side of its root and the root again: "Sixteenth look"), and the
exact mode's own sharing step alone (the line sweep over rays that share a focal point), whose cost plus
that least refinement bounds the package's sharing design from above ("Seventeenth look").
None of what makes an answer exact is there (margins, the curved track, no-data, walls). It is not
sound (the output counts how many of its hits differ from the exact mode's), so its speed is an
upper bound on a sound walk's.

Two conversions are timed: Heikkinen's exact closed form, and a cubic polynomial fitted over the
scene's box (the fit's error on fresh points is measured against the package's geodetic_to_ecef and
printed): what a regional DSM could precompute instead of converting.

Each round calls every method on the same rays, each timed on its second call, one thread; the
medians of the per-round ratios are printed and written as JSON.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SOURCE = REPO / "benchmarks" / "cell_walk" / "cell_walk_bound.f90"
FLAGS = ["-O3", "-fno-fast-math", "-ffp-contract=off", "-march=x86-64-v3", "-shared", "-fPIC"]
BLOCK = 8


def monomials() -> list[tuple[int, int, int]]:
    """The cubic's 20 exponents, in the order cell_walk_bound.f90's to_grid loops over them."""
    return [(a, b, c) for a in range(4) for b in range(4 - a) for c in range(4 - a - b)]


def fit_cubic(grid: dict, hmin: float, hmax: float, npts: int = 200_000, seed: int = 1):
    """Least-squares cubic maps from a body-fixed point's offset from the scene's centre (km) to its
    fractional (row, column) and height, over the scene's extent (+5 cells) and [hmin - 10, hmax + 10].
    Returns (coef (20, 3), centre (3,), max errors on fresh points: rows, columns, metres)."""
    from planet_intersect.geodetic import geodetic_to_ecef

    nr, nc = grid["heights"].shape
    rng = np.random.default_rng(seed)

    def points(m):
        i = rng.uniform(-5, nr + 4, m)
        j = rng.uniform(-5, nc + 4, m)
        h = rng.uniform(hmin - 10, hmax + 10, m)
        p = geodetic_to_ecef(grid["lat_first"] + i * grid["dlat"], grid["lon_first"] + j * grid["dlon"], h,
                             a=grid["a"], f=grid["f"])
        return np.asarray(p, float), np.c_[i, j, h]

    cen = np.asarray(geodetic_to_ecef(grid["lat_first"] + nr / 2 * grid["dlat"],
                                      grid["lon_first"] + nc / 2 * grid["dlon"], (hmin + hmax) / 2,
                                      a=grid["a"], f=grid["f"]), float).reshape(3)
    mons = monomials()

    def design(p):
        x = (p - cen) * 1e-3
        return np.stack([x[:, 0] ** a * x[:, 1] ** b * x[:, 2] ** c for a, b, c in mons], axis=1)

    p, g = points(npts)
    coef = np.linalg.lstsq(design(p), g, rcond=None)[0]
    p2, g2 = points(npts)
    err = np.abs(design(p2) @ coef - g2).max(axis=0)
    return coef, cen, err


class CellWalk:
    """The compiled probe, loaded with ctypes (no f2py: it is not part of the package)."""

    def __init__(self, workdir: Path):
        fc = shutil.which("gfortran")
        if fc is None:
            raise RuntimeError("gfortran not found: the cell-walk probe is compiled at run time (./dev setup installs it)")
        lib = workdir / "libcell_walk_bound.so"
        subprocess.run([fc, *FLAGS, "-J", str(workdir), "-o", str(lib), str(SOURCE)], check=True)
        self.lib = ctypes.CDLL(str(lib))
        self.lib.walk_prepare.restype = None
        self.lib.walk_trace.restype = None

    def prepare(self, grid: dict, coef, cen) -> None:
        """Everything that depends on the grid alone (its maxima, H_min and H_max, the cubic map):
        once, outside any timed call."""
        self.h = np.ascontiguousarray(grid["heights"], dtype=np.float64)
        nr, nc = self.h.shape
        self.nbr, self.nbc = -(-(nr - 1) // BLOCK), -(-(nc - 1) // BLOCK)
        self.nsr, self.nsc = -(-self.nbr // 4), -(-self.nbc // 4)
        self.cmax = np.empty((nr - 1, nc - 1), np.float32)
        self.bmax = np.empty((self.nbr, self.nbc), np.float32)
        self.smax = np.empty((self.nsr, self.nsc), np.float32)
        i, p = ctypes.c_int, lambda a: a.ctypes.data_as(ctypes.c_void_p)
        self.lib.walk_prepare(i(nr), i(nc), p(self.h), i(BLOCK), i(self.nbr), i(self.nbc), p(self.cmax), p(self.bmax),
                              i(self.nsr), i(self.nsc), p(self.smax))
        self.g = np.array([grid["lat_first"], grid["lon_first"], grid["dlat"], grid["dlon"], grid["a"], grid["f"],
                           float(self.h.min()), float(self.h.max())])
        self.coef_f = np.ascontiguousarray(np.asarray(coef, np.float64).T)    # Fortran coef(20, 3)
        self.cen = np.ascontiguousarray(cen, np.float64)
        self._grid_args = (i(nr), i(nc), p(self.h), p(self.cmax), i(BLOCK), i(self.nbr), i(self.nbc), p(self.bmax),
                           i(self.nsr), i(self.nsc), p(self.smax), p(self.g))
        self._grid_keep = (self.h, self.cmax, self.bmax, self.smax, self.g)   # what _grid_args points into

    def bind(self, s, l):
        """A call on these rays: call(conv, level) runs the probe and returns (dist, counts) in arrays it
        reuses. Only the Fortran call is left for the timer (no O(grid) or O(rays) work in Python)."""
        s = np.ascontiguousarray(s, np.float64)
        l = np.ascontiguousarray(l, np.float64)
        dist = np.empty(len(s))
        count = np.zeros(3)
        i, p = ctypes.c_int, lambda a: a.ctypes.data_as(ctypes.c_void_p)
        tail = (i(len(s)), p(s), p(l), p(dist), p(count))
        keep = (s, l)                                           # alive while the call is

        def call(conv: int, level: int = 1):
            self.lib.walk_trace(*self._grid_args, i(conv), p(self.coef_f), p(self.cen), i(level), *tail)
            return dist, count

        call.keep = keep
        return call

    def trace(self, s, l, conv: int, level: int = 1):
        """(distances, NaN where no hit; (cells, blocks, superblocks) visited per ray). level 0: cells
        only; 1: 8 x 8-cell blocks, then cells; 3: 32 x 32-cell superblocks, blocks, cells; 2: the
        set-up alone (crossings and conversions, no walk); 4: as 1, then the least refinement a sound
        answer needs (two exact conversions 1 mm either side of the root, the root again)."""
        dist, count = self.bind(s, l)(conv, level)
        return np.where(dist >= 0, dist, np.nan), count / len(s)


def run(scene: str, n: int, nrays: int, rounds: int, workdir: Path) -> dict:
    for d in (REPO / "benchmarks", REPO / "tests"):           # geodetic.py's scenes, the Rugged bridge
        if str(d) not in sys.path:
            sys.path.insert(0, str(d))
    import planet_intersect as pi
    from geodetic import make_scene, warm_rugged
    from references.rugged.bridge import RuggedDSM, rugged_available

    grid, s, l = make_scene(scene, n, nrays)
    h = grid["heights"]
    dsm = pi.GeodeticDSM.from_array(h, grid["lat_first"], grid["lon_first"], grid["dlat"], grid["dlon"],
                                    a=grid["a"], f=grid["f"])
    dsm.pyramid()
    coef, cen, fit_err = fit_cubic(grid, float(h.min()), float(h.max()))
    fl = CellWalk(workdir)
    fl.prepare(grid, coef, cen)
    exact = pi.intersect(dsm, s, l, method="exact", threads=1)
    ref = np.where(exact.hit, exact.distance, np.nan)
    out = {"scene": scene, "n": n, "rays": len(s), "block": BLOCK,
           "cubic_fit_max_error": {"rows": fit_err[0], "columns": fit_err[1], "metres": fit_err[2]}}
    for conv, name in ((0, "heikkinen"), (1, "cubic")):
        d, count = fl.trace(s, l, conv)
        both = np.isfinite(d) & np.isfinite(ref)
        diff = np.abs(d - ref)[both]
        out[f"walk_{name}"] = {"cells_per_ray": count[0], "blocks_per_ray": count[1],
                                "hits": int(np.isfinite(d).sum()), "exact_hits": int(np.isfinite(ref).sum()),
                                "within_1mm_of_exact": int((diff <= 1e-3).sum()),
                                "max_difference_m": float(diff.max()) if diff.size else float("nan")}
    # the walk plus the refinement a sound answer needs at least (level 4): how close to the exact hits
    for conv, name in ((0, "heikkinen"), (1, "cubic")):
        d, _ = fl.trace(s, l, conv, level=4)
        walk, _ = fl.trace(s, l, conv, level=1)
        both = np.isfinite(d) & np.isfinite(ref)
        diff = np.abs(d - ref)[both]
        bracketed = both & (np.abs(walk - ref) < 0.9e-3)     # the exact hit inside the +-1 mm bracket
        out[f"refined_{name}"] = {"hits": int(np.isfinite(d).sum()),
                                  "within_1um_of_exact": int((diff <= 1e-6).sum()),
                                  "bracketed": int(bracketed.sum()),
                                  "bracketed_within_1um_of_exact": int((np.abs(d - ref)[bracketed] <= 1e-6).sum()),
                                  "median_difference_m": float(np.median(diff)) if diff.size else float("nan"),
                                  "p99_difference_m": float(np.quantile(diff, 0.99)) if diff.size else float("nan")}
    # the other walks' visits (the same hits: the levels only change what is skipped)
    for level, name in ((0, "cells_only"), (3, "three_levels")):
        _, count = fl.trace(s, l, 0, level=level)
        out[f"{name}_visits_per_ray"] = {"cells": count[0], "blocks": count[1], "superblocks": count[2]}
    rug = None
    if rugged_available()[0]:
        rug = RuggedDSM(h, grid["lat_first"], grid["lon_first"], grid["dlat"], grid["dlon"], a=grid["a"], f=grid["f"])
        warm_rugged(rug, s, l)

    probe = fl.bind(s, l)                   # the probe's calls time its Fortran alone

    def timed(fn):
        fn()
        t0 = time.perf_counter()
        fn()
        return time.perf_counter() - t0

    # the exact mode's own sharing step alone: the line sweep's certificates for the fans of rays that share a
    # focal point (fan=-1: as pi.intersect finds them). Only scans have fans; on random rays it finds none.
    from planet_intersect import _core
    pyr, meta = dsm.pyramid()
    core_grid = dsm._core_grid()
    s_t = np.ascontiguousarray(np.asarray(s, dtype=np.float64).T)
    l_t = np.ascontiguousarray((l / np.linalg.norm(l, axis=1, keepdims=True)).T)
    rclear = _core.core_dsm_sweep(*core_grid[:7], core_grid[7], dsm.hmax, dsm.hmin, pyr, meta.T, s_t, l_t, -1)
    certified = np.isfinite(rclear) & (rclear > 0)
    out["line_sweep"] = {"certified_rays": int(certified.sum()),
                         "median_gap_to_exact_event_m": float(np.median((ref - rclear)[certified & np.isfinite(ref)]))
                         if np.any(certified & np.isfinite(ref)) else float("nan")}

    calls = {
        "line_sweep": lambda: _core.core_dsm_sweep(*core_grid[:7], core_grid[7], dsm.hmax, dsm.hmin, pyr, meta.T,
                                                   s_t, l_t, -1),
        "exact": lambda: pi.intersect(dsm, s, l, method="exact", threads=1),
        "following": lambda: pi.intersect(dsm, s, l, method="following", threads=1),
        "walk_heikkinen": lambda: probe(0, 1),
        "walk_cubic": lambda: probe(1, 1),
        "setup_heikkinen": lambda: probe(0, 2),
        "setup_cubic": lambda: probe(1, 2),
        "cells_only_heikkinen": lambda: probe(0, 0),
        "three_levels_heikkinen": lambda: probe(0, 3),
        "three_levels_cubic": lambda: probe(1, 3),
        "refined_heikkinen": lambda: probe(0, 4),
        "refined_cubic": lambda: probe(1, 4),
    }
    per = {k: [] for k in calls}
    per["rugged"] = []
    for k in range(rounds):
        for name, fn in calls.items():
            per[name].append(timed(fn))
        if rug is not None:                  # its Java loop's own clock (1 warm + 3 timed)
            per["rugged"].append(len(s) / rug.rays_per_second(s, l, warmup=1, repeats=3))
        print(f"  {scene}: round {k + 1} of {rounds}", file=sys.stderr, flush=True)
    out["rays_per_second"] = {k: len(s) / float(np.median(v)) for k, v in per.items() if v}
    ratios = {}
    for num in ("following", "rugged", "exact"):
        for den in ("exact", "walk_heikkinen", "walk_cubic", "refined_heikkinen", "refined_cubic"):
            if num != den and per[num]:
                r = np.array(per[num]) / np.array(per[den])
                ratios[f"{den}_over_{num}"] = [float(np.median(r)), float(r.min()), float(r.max())]
    # a bound on the package's sharing design (line sweep, then a per-ray search): even if the search after the
    # certificate cost nothing but the least refinement (the probe's level 4 minus its level 1), a ray costs
    # the sweep plus that refinement
    # (only where the sweep shares anything: on rays without a common focal point it certifies none, and
    # a "bound" of its near-zero time plus the refinement would bound nothing)
    if out["line_sweep"]["certified_rays"] == 0:
        out["ratios"] = ratios
        return out
    least = np.array(per["line_sweep"]) + np.array(per["refined_heikkinen"]) - np.array(per["walk_heikkinen"])
    per["sweep_plus_least_refinement"] = list(least)
    out["rays_per_second"]["sweep_plus_least_refinement"] = len(s) / float(np.median(least))
    for num in ("following", "rugged", "exact"):
        if per[num]:
            r = np.array(per[num]) / least
            ratios[f"sweep_plus_least_refinement_over_{num}"] = [float(np.median(r)), float(r.min()), float(r.max())]
    out["ratios"] = ratios
    return out


def plot(results: list[dict], path: Path) -> None:
    """Microseconds per ray of each method on each ray set (medians of the rounds), the probes'
    set-up (two crossings and two conversions) shaded, and the cost the two targets allow."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [("following", "following\n(faithful)"), ("rugged", "Rugged\nDuvenhage"), ("exact", "exact\n(package)"),
             ("walk_heikkinen", "cell walk,\nexact conv."), ("refined_heikkinen", "+ least\nrefinement"),
             ("walk_cubic", "cell walk,\ncubic conv."), ("refined_cubic", "+ least\nrefinement"),
             ("sweep_plus_least_refinement", "line sweep +\nleast refin.")]
    fig, axes = plt.subplots(1, len(results), figsize=(6.4 * len(results), 4.6), sharey=True)
    for ax, res in zip(np.atleast_1d(axes), results):
        rps = res["rays_per_second"]
        # the line sweep shares work only between rays with one focal point: a bound for the scans alone
        shares = res["scene"] == "buildings-scan"
        us = [1e6 / rps[k] if k in rps and (shares or not k.startswith("sweep")) else np.nan for k, _ in names]
        x = np.arange(len(names))
        colours = ["#999999", "#c77c2e", "#2e6fc7", "#7fb07f", "#a7d0a7", "#3f8f3f", "#8fbf8f", "#9b6fc7"]
        ax.bar(x, us, color=colours)
        for k, key in ((3, "setup_heikkinen"), (5, "setup_cubic")):
            ax.bar(x[k], 1e6 / rps[key], color="none", edgecolor="black", hatch="//", linewidth=0.6,
                   label="set-up: 2 crossings, 2 conversions" if k == 3 else None)
        if shares and "line_sweep" in rps:
            ax.bar(x[7], 1e6 / rps["line_sweep"], color="none", edgecolor="black", hatch="..", linewidth=0.6,
                   label="the line sweep alone")
        if "rugged" in rps:
            ax.axhline(1e6 / (10 * rps["rugged"]), color="#c77c2e", ls="--", lw=1, label="10x Rugged")
        ax.axhline(1e6 / (20 * rps["following"]), color="#555555", ls=":", lw=1.2, label="20x the following")
        for xi, u in zip(x, us):
            if np.isfinite(u):
                ax.text(xi, u * 1.04, f"{u:.2f}", ha="center", fontsize=8)
        ax.set_yscale("log")
        ax.set_xticks(x, [n for _, n in names], fontsize=7)
        label = {"buildings-pushbroom": "random rays", "buildings-scan": "pushbroom scans"}.get(res["scene"], res["scene"])
        ax.set_title(f"{label} ({res['rays']:,} rays) on the {res['n']}$^2$ 1 m building DSM", fontsize=9)
        ax.grid(axis="y", alpha=0.3, which="both")
    np.atleast_1d(axes)[0].set_ylabel("microseconds per ray (one thread)")
    for ax in np.atleast_1d(axes):
        ax.legend(fontsize=7, loc="upper right")
    fig.suptitle("What a cell walk could cost: the unsound probe (no margins, straight track) beside the methods",
                 fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cell-walk", action="store_true", help="(the ./dev bench switch that selects this script)")
    ap.add_argument("--n", type=int, default=2048, help="scene size in cells (default 2048)")
    ap.add_argument("--rays", type=int, default=20000, help="rays per scene (default 20000)")
    ap.add_argument("--rounds", type=int, default=7, help="rounds of calls in turn (default 7)")
    ap.add_argument("--out", type=Path, default=REPO / "benchmarks" / "results" / "cell_walk.json")
    ap.add_argument("--figure", type=Path, default=None,
                    help="also draw microseconds per ray to this PNG (docs/figures/cell_walk_bound.png)")
    ap.add_argument("--plot-only", action="store_true", help="draw --figure from the --out JSON without measuring")
    a = ap.parse_args(argv)
    if not (64 <= a.n <= 8192 and 100 <= a.rays <= 1_000_000 and 1 <= a.rounds <= 100):
        ap.error(f"--n must be 64 to 8192 (got {a.n}), --rays 100 to 1,000,000 (got {a.rays}), "
                 f"--rounds 1 to 100 (got {a.rounds})")
    if a.plot_only:
        if a.figure is None:
            ap.error("--plot-only needs --figure")
        try:
            saved = json.loads(a.out.read_text())["results"]
        except (OSError, ValueError, KeyError) as exc:
            ap.error(f"--out {a.out}: cannot read a cell-walk result ({exc})")
        plot(saved, a.figure)
        print(f"written {a.figure}")
        return 0
    results = []
    with tempfile.TemporaryDirectory(prefix="pi-cell-walk-") as tmp:
        for scene in ("buildings-pushbroom", "buildings-scan"):
            res = run(scene, a.n, a.rays, a.rounds, Path(tmp))
            results.append(res)
            print(json.dumps(res, indent=1))
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps({"date": time.strftime("%Y-%m-%d %H:%M"), "results": results}, indent=1) + "\n")
    print(f"written {a.out}")
    if a.figure is not None:
        plot(results, a.figure)
        print(f"written {a.figure}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
