"""The ``planet-intersect`` command line.

    planet-intersect demo [--out DIR] [--ppd N] [--pixels N]
    planet-intersect run DEM RAYS [--out DIR] [--step-mode 0|1] [--dem-read-mode 0|1] [--tangent exact|paper]
                         [--method stepping|exact] [--threads N] [--io records|mmap]
    planet-intersect run DSM.tif|DSM.npz RAYS [--method following|exact|iterative] [--interpolation ...]
    planet-intersect examples olympus|limb [--dem HDR | --mola IMG] [--out DIR]
    planet-intersect import-mola OUT (--radius IMG | --topography IMG --areoid IMG) [--overwrite]
    planet-intersect fetch-mola DEST [--product megr90n000cb|megr90n000eb]

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


class Progress:
    """A one-line progress bar on standard error (silent for work that is quick)."""

    def __init__(self, total: int, label: str, min_total: int = 1):
        self.total, self.label = total, label
        self.show = total >= min_total
        self.t0 = time.perf_counter()

    def __call__(self, done: int, total: int | None = None) -> None:
        if not self.show:
            return
        total = total or self.total
        frac = min(done / total, 1.0) if total else 1.0
        bar = "#" * int(30 * frac)
        sys.stderr.write(f"\r{self.label} [{bar:<30}] {100 * frac:5.1f}% ({time.perf_counter() - self.t0:.1f} s)")
        if frac >= 1.0:
            sys.stderr.write("\n")
        sys.stderr.flush()


def intersect_in_chunks(dem, s, l, chunk: int = 200_000, **kwargs):
    """intersect() over many rays in chunks, with a progress bar when there is more than one."""
    from . import intersect
    from .intersect import IntersectResult

    n = max(len(s), len(l))
    s = np.broadcast_to(s, (n, 3))
    l = np.broadcast_to(l, (n, 3))
    bar = Progress(n, "rays", min_total=chunk + 1)
    parts = []
    for a in range(0, n, chunk):
        parts.append(intersect(dem, s[a:a + chunk], l[a:a + chunk], **kwargs))
        bar(min(a + chunk, n))
    if len(parts) == 1:
        return parts[0]
    return IntersectResult(**{k: np.concatenate([getattr(p, k) for p in parts]) for k in parts[0].__dataclass_fields__})


def _run(args) -> int:
    from . import DEM

    if Path(args.dem).suffix.lower() in (".tif", ".tiff", ".npz"):    # a geodetic DSM (Shin & Park)
        return _run_dsm(args)
    dem = DEM.read(args.dem)
    s, l = _read_rays(Path(args.rays))
    res = intersect_in_chunks(dem, s, l, step_mode=args.step_mode, dem_read_mode=args.dem_read_mode,
                              tangent=args.tangent, method=args.method or "stepping", threads=args.threads,
                              io=args.io)
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


def _run_dsm(args) -> int:
    """`run` on a geodetic DSM (GeoTIFF or .npz): rays in its ellipsoid's ECR frame."""
    from . import intersect
    from .dsm import DSMResult, DSMStatus, GeodeticDSM

    dsm = GeodeticDSM.read(args.dem, interpolation=args.interpolation)
    s, l = _read_rays(Path(args.rays))
    method = args.method or "following"
    n = max(len(s), len(l))
    bar = Progress(n, "rays", min_total=200_001)
    parts = []
    for a in range(0, n, 200_000):
        parts.append(intersect(dsm, s[a:a + 200_000], l[a:a + 200_000], method=method, threads=args.threads))
        bar(min(a + 200_000, n))
    res = parts[0] if len(parts) == 1 else DSMResult(
        **{k: np.concatenate([getattr(p, k) for p in parts]) for k in parts[0].__dataclass_fields__})
    out = _new_run_dir(Path(args.out))
    write_csv(out / "results.csv", res)
    written = [out / "results.csv"]
    try:
        res.to_xarray().to_netcdf(out / "results.nc", engine="h5netcdf")
        written.append(out / "results.nc")
    except ImportError as exc:
        print(f"  (no NetCDF output: {exc}; pip install 'planet-intersect[xarray]')")
    print(f"{len(res)} rays ({method} over the DSM {args.dem}): {int(res.hit.sum())} hit, "
          f"{int((res.status == DSMStatus.NO_DATA).sum())} no data, {int((res.status == DSMStatus.LEFT_DSM).sum())} "
          f"left the DSM, {int((res.status == DSMStatus.MISS).sum())} miss; wrote {', '.join(map(str, written))}")
    return 0


def _example_dem(args):
    import os

    from . import DEM
    from .mola import mola_dem

    if args.dem:
        return DEM.read(args.dem), str(args.dem)
    path = Path(args.mola) if args.mola else (
        Path(os.environ.get("PI_SHARED_DATA", "../shared/data")) / "mars_mola_megdr_4ppd" /
        "mars_radius_4ppd_megt_plus_areoid.i2be")
    if not path.is_file():
        raise CLIError(f"no Mars DEM: {path} is missing; give --dem NAME.hdr or --mola MEGDR.img "
                       f"(planet-intersect fetch-mola DEST downloads one)")
    return mola_dem(path), str(path)


def _examples(args) -> int:
    from . import examples

    dem, source = _example_dem(args)
    out = _new_run_dir(Path(args.out))
    if args.which == "olympus":
        ex = examples.olympus(dem)
        examples.plot_olympus(ex, out / "olympus_fig8.png")
        write_csv(out / "olympus_pixels.csv", ex.res)
        print(f"example 1 (Fig. 8) on {source}: {int(ex.res.hit.sum())} of {ex.res.status.size} pixels on the surface, "
              f"altitude {np.nanmin(ex.z):.2f} .. {np.nanmax(ex.z):.2f} km above the mean surface\n"
              f"  lapse rate {ex.lapse_fit:.4f} +- {ex.lapse_se:.4f} K/km (true {ex.lapse}), "
              f"T0 {ex.T0_fit:.3f} +- {ex.T0_se:.3f} K (true {ex.T0})\n  wrote {out}/olympus_fig8.png, olympus_pixels.csv")
    else:
        ex = examples.limb(dem)
        examples.plot_limb(ex, out / "limb_fig9.png")
        write_csv(out / "limb_pixels.csv", ex.res)
        status = ex.grid("status")
        mountain = int(((status == 0) & ex.spheroid_miss).sum())
        print(f"example 2 (Fig. 9) on {source}: {ex.nframes} frames x {ex.npix} pixels, {int((status == 0).sum())} hit "
              f"the surface, {mountain} of them miss the smooth spheroid but hit the mountain\n"
              f"  wrote {out}/limb_fig9.png, limb_pixels.csv")
    return 0


def _import_mola(args) -> int:
    from .mola import import_mola

    if bool(args.radius) == bool(args.topography):
        raise CLIError("give --radius IMG, or --topography IMG with --areoid IMG")
    hdr = import_mola(args.out, radius=args.radius, topography=args.topography, areoid=args.areoid,
                      overwrite=args.overwrite)
    print(f"wrote {hdr} and {hdr.with_suffix('.dem')}")
    return 0


def _fetch_mola(args) -> int:
    from .mola import fetch_mola

    bar = Progress(1, f"downloading {args.product}")
    hdr = fetch_mola(args.dest, product=args.product, progress=bar)
    print(f"wrote {hdr} and {hdr.with_suffix('.dem')}")
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
    r.add_argument("dem", help="DEM as NAME, NAME.hdr or NAME.dem; or a geodetic DSM (.tif GeoTIFF, .npz)")
    r.add_argument("rays", help="text file, one ray per line: sx sy sz lx ly lz")
    r.add_argument("--out", default="planet-intersect-output", help="results go to a new run-NNN folder here")
    r.add_argument("--step-mode", type=int, choices=(0, 1), default=1)
    r.add_argument("--dem-read-mode", type=int, choices=(0, 1), default=0)
    r.add_argument("--tangent", choices=("exact", "paper"), default="exact",
                   help="spheroid tangent point: true nearest point (default) or the paper's eqs. 55-58")
    r.add_argument("--method", choices=("stepping", "exact", "following", "iterative"), default=None,
                   help="DEM: stepping (default) or exact; DSM: following (default), exact or iterative")
    r.add_argument("--interpolation", choices=("bilinear", "nearest"), default=None,
                   help="DSM surface (default: nearest for a warped projected raster, else bilinear)")
    r.add_argument("--threads", type=int, default=0, help="OpenMP threads (default 0: all cores)")
    r.add_argument("--io", choices=("records", "mmap"), default="records",
                   help="with --dem-read-mode 1: one read per record (default) or a memory map")
    r.set_defaults(func=_run)
    e = sub.add_parser("examples", help="the paper's Mars examples: olympus (Fig. 8) or limb (Fig. 9), on MOLA")
    e.add_argument("which", choices=("olympus", "limb"))
    e.add_argument("--dem", help="a Mars DEM NAME.hdr in km (default: the MOLA grid in $PI_SHARED_DATA or ../shared/data)")
    e.add_argument("--mola", help="a MEGDR radius grid (megr*.img style) to use instead")
    e.add_argument("--out", default="examples-output", help="results go to a new run-NNN folder here")
    e.set_defaults(func=_examples)
    m = sub.add_parser("import-mola", help="convert MOLA MEGDR grids to a .hdr/.dem DEM (km)")
    m.add_argument("out", help="output NAME (writes NAME.hdr and NAME.dem)")
    m.add_argument("--radius", help="MEGDR radius grid (value + 3,396,000 m)")
    m.add_argument("--topography", help="MEGDR topography grid (m above the areoid)")
    m.add_argument("--areoid", help="areoid grid (value + 3,396,000 m) for --topography")
    m.add_argument("--overwrite", action="store_true", help="replace existing NAME.hdr/.dem")
    m.set_defaults(func=_import_mola)
    f = sub.add_parser("fetch-mola", help="download a MEGDR radius grid from the PDS Geosciences Node and import it")
    f.add_argument("dest", help="folder for the download and the DEM")
    f.add_argument("--product", default="megr90n000cb", choices=("megr90n000cb", "megr90n000eb"),
                   help="megr90n000cb: 4 pixels/degree (2 MB); megr90n000eb: 16 pixels/degree (33 MB)")
    f.set_defaults(func=_fetch_mola)
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
