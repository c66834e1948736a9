"""The ``planet-intersect`` command line.

    planet-intersect demo [--out DIR] [--ppd N] [--pixels N]
    planet-intersect run DEM RAYS [--out DIR] [--step-mode 0|1] [--dem-read-mode 0|1] [--tangent exact|paper]

Errors print one line on standard error and exit with status 2.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

__all__ = ["main"]


class CLIError(Exception):
    """A user error: printed as one line, exit status 2."""


def _new_run_dir(base: Path) -> Path:
    """A fresh numbered folder under ``base`` (earlier runs are never overwritten)."""
    base.mkdir(parents=True, exist_ok=True)
    k = 1
    while True:
        d = base / f"run-{k:03d}"
        try:
            d.mkdir()
            return d
        except FileExistsError:
            k += 1


def write_csv(path: Path, result) -> None:
    """Per-ray results as CSV, one row per ray, vectors split into _x/_y/_z."""
    cols = result.to_table()
    names = list(cols)
    data = np.column_stack([np.asarray(cols[k], dtype=np.float64) for k in names])
    fmt = ["%d" if k in ("hit", "status", "nsteps") else "%.10g" for k in names]
    np.savetxt(path, data, delimiter=",", header=",".join(names), comments="", fmt=fmt)


def _demo(args) -> int:
    from . import intersect
    from .synthetic import MARS_MEAN_RADIUS, mars_like_dem, oblique_scene

    out = _new_run_dir(Path(args.out))
    t0 = time.perf_counter()
    dem = mars_like_dem(ppd=args.ppd)
    t1 = time.perf_counter()
    s, l = oblique_scene(nh=args.pixels, nv=args.pixels)
    res = intersect(dem, s, l, step_mode=1, dem_read_mode=0)
    t2 = time.perf_counter()

    hit = res.hit
    lines = [
        "planet-intersect demo: synthetic Mars (spheroid + 21 km shield volcano + rough terrain),",
        f"  DEM {dem.ppd} pixels/degree ({dem.nlat} x {dem.nlon}), rmax {dem.rmax:.3f} km, built in {t1 - t0:.2f} s",
        f"  detector {args.pixels} x {args.pixels}, 0.015 rad pixels, spacecraft {np.linalg.norm(s) - MARS_MEAN_RADIUS:.0f} km "
        f"above the mean radius, due south of Olympus Mons",
        f"  {res.status.size} rays in {t2 - t1:.3f} s: {int(hit.sum())} hit the surface, "
        f"{int((res.status == 1).sum())} view the limb, {int((res.status == 2).sum())} point away",
        f"  hits: altitude above the spheroid {np.nanmin(res.altitude):.2f} .. {np.nanmax(res.altitude):.2f} km, "
        f"emission angle {np.nanmin(res.emission):.1f} .. {np.nanmax(res.emission):.1f} deg",
    ]
    if (res.status == 1).any():
        lines.append(f"  limb: tangent altitude above the local surface {np.nanmin(res.tangent_altitude):.1f} .. "
                     f"{np.nanmax(res.tangent_altitude):.1f} km")
    lines.append(f"  mean test points per ray: {res.nsteps.mean():.1f}")
    csv = out / "demo_pixels.csv"
    write_csv(csv, res)
    lines.append(f"  wrote {csv}")
    png = out / "demo_map.png"
    if _plot_demo(png, res, args.pixels):
        lines.append(f"  wrote {png}")
    print("\n".join(lines))
    return 0


def _plot_demo(path: Path, res, npix: int) -> bool:
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("  (matplotlib not installed: no PNG; pip install 'planet-intersect[plot]')")
        return False
    fig, axes = plt.subplots(1, 2, figsize=(12, 5.2))
    alt = res.altitude.reshape(npix, npix)
    talt = np.where(res.status == 1, res.tangent_altitude, np.nan).reshape(npix, npix)
    ax = axes[0]
    im2 = ax.imshow(talt, origin="lower", cmap="Blues_r", alpha=0.55)
    im = ax.imshow(alt, origin="lower", cmap="terrain")
    ax.set_title("(a) detector: hit altitude; limb pixels blue")
    ax.set_xlabel("horizontal pixel")
    ax.set_ylabel("vertical pixel")
    fig.colorbar(im, ax=ax, label="altitude above spheroid (km)")
    fig.colorbar(im2, ax=ax, label="limb: tangent altitude above surface (km)")
    ax = axes[1]
    sc = ax.scatter(res.lon[res.hit], res.lat[res.hit], c=res.altitude[res.hit], s=3, cmap="terrain")
    ax.set_title("(b) map view of the hit points")
    ax.set_xlabel("east longitude (deg)")
    ax.set_ylabel("planetocentric latitude (deg)")
    fig.colorbar(sc, ax=ax, label="altitude above spheroid (km)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def _read_rays(path: Path) -> tuple[np.ndarray, np.ndarray]:
    if not path.is_file():
        raise CLIError(f"rays file {path}: no such file")
    try:
        data = np.loadtxt(path, comments="#", ndmin=2)
    except ValueError as exc:
        raise CLIError(f"rays file {path}: {exc}") from None
    if data.shape[1] != 6:
        raise CLIError(f"rays file {path}: expected 6 columns (sx sy sz lx ly lz), got {data.shape[1]}")
    return data[:, :3], data[:, 3:]


def _run(args) -> int:
    from . import DEM, intersect

    dem = DEM.read(args.dem)
    s, l = _read_rays(Path(args.rays))
    res = intersect(dem, s, l, step_mode=args.step_mode, dem_read_mode=args.dem_read_mode, tangent=args.tangent)
    out = _new_run_dir(Path(args.out))
    write_csv(out / "results.csv", res)
    written = [out / "results.csv"]
    try:
        res.to_xarray().to_netcdf(out / "results.nc", engine="h5netcdf")
        written.append(out / "results.nc")
    except ImportError as exc:
        print(f"  (no NetCDF output: {exc}; pip install 'planet-intersect[xarray]')")
    print(f"{len(res)} rays: {int(res.hit.sum())} hit, {int((res.status == 1).sum())} limb, "
          f"{int((res.status == 2).sum())} away; wrote {', '.join(map(str, written))}")
    return 0


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="planet-intersect",
                                description="Where lines of sight meet a planet's DEM (Teanby 2008 ray stepping).")
    sub = p.add_subparsers(dest="command", required=True)
    d = sub.add_parser("demo", help="oblique view of a synthetic Mars with a shield volcano (built-in default)")
    d.add_argument("--out", default="demo-output", help="results go to a new run-NNN folder here (default: demo-output)")
    d.add_argument("--ppd", type=int, default=4, help="DEM pixels per degree (default 4)")
    d.add_argument("--pixels", type=int, default=101, help="detector pixels per side (default 101, as the paper's Fig. 8)")
    d.set_defaults(func=_demo)
    r = sub.add_parser("run", help="intersect the rays of a text file (sx sy sz lx ly lz per line) with a DEM")
    r.add_argument("dem", help="DEM as NAME, NAME.hdr or NAME.dem")
    r.add_argument("rays", help="text file, one ray per line: sx sy sz lx ly lz")
    r.add_argument("--out", default="planet-intersect-output", help="results go to a new run-NNN folder here")
    r.add_argument("--step-mode", type=int, choices=(0, 1), default=1)
    r.add_argument("--dem-read-mode", type=int, choices=(0, 1), default=0)
    r.add_argument("--tangent", choices=("exact", "paper"), default="exact")
    r.set_defaults(func=_run)
    return p


def main(argv=None) -> int:
    """Entry point of the console script."""
    args = _parser().parse_args(argv)
    try:
        return args.func(args)
    except (CLIError, ValueError, OSError) as exc:
        print(f"planet-intersect: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
