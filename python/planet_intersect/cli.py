"""The ``planet-intersect`` command line.

    planet-intersect demo [--out DIR] [--ppd N] [--pixels N]
    planet-intersect run DEM RAYS [--out DIR] [--step-mode 0|1] [--dem-read-mode 0|1] [--tangent exact|paper]
                         [--method stepping|exact] [--threads N] [--io records|mmap]
    planet-intersect run DSM.tif|DSM.npz RAYS [--method following|exact|iterative] [--interpolation ...]
    planet-intersect examples olympus|limb [--dem HDR | --mola IMG] [--out DIR]
    planet-intersect examples buildings [--zenith Z] [--size N] [--stride K] [--out DIR]
    planet-intersect import-mola OUT (--radius IMG | --topography IMG --areoid IMG) [--overwrite]
    planet-intersect import-pds LABEL OUT [--heights-above KM] [--overwrite]
    planet-intersect import-shape-table TABLE OUT [--ppd N] [--longitude west|east] [--re KM] [--overwrite]
    planet-intersect import-shadr SHA OUT [--ppd N] [--degree N] [--overwrite]
    planet-intersect fetch-mola DEST [--product megr90n000cb|megr90n000eb]
    planet-intersect footprint (--states CSV | --kernels K... --times FILE) [--dem HDR | --mola IMG] [--zeta Z]
    planet-intersect simulate [--dsm DSM --ortho ORTHO (--oblique Z,AZ | --orbit ... | --geometry NPZ)] [--out DIR]

Errors print one line on standard error and exit with status 2.
"""

from __future__ import annotations

import argparse
import math
import re
import shutil
import sys
import time
import warnings
from contextlib import contextmanager
from pathlib import Path

import numpy as np

__all__ = ["main"]


class CLIError(Exception):
    """A user error: printed as one line, exit status 2."""


def _new_run_dir(base: Path) -> Path:
    """A fresh numbered folder under ``base`` (earlier runs are never overwritten)."""
    if base.exists() and not base.is_dir():
        raise CLIError(f"--out {base}: exists and is not a folder")
    try:
        base.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CLIError(f"--out {base}: cannot make the folder ({exc.strerror})") from None
    k = 1
    while True:
        d = base / f"run-{k:03d}"
        try:
            d.mkdir()
            return d
        except FileExistsError:
            k += 1
        except OSError as exc:
            # (a folder that exists but takes no new entries, /sys/kernel: "[Errno 1] Operation not
            # permitted" without the option's name, a review)
            raise CLIError(f"--out {base}: cannot make {d.name} in it ({exc.strerror})") from None


@contextmanager
def _run_dir(base: Path):
    """A new run folder that is removed again, with whatever was written into it,
    when the work in it fails: nothing is left half-written."""
    out = _new_run_dir(base)
    try:
        yield out
    except BaseException:
        shutil.rmtree(out, ignore_errors=True)
        raise


def _require(module: str, extra: str, what: str) -> None:
    """Import ``module`` or stop with one line naming the extra that provides it."""
    try:
        __import__(module)
    except ImportError:
        raise CLIError(f"{what} needs the Python package {module!r}, which is not installed: "
                       f"pip install 'planet-intersect[{extra}]'") from None


def _provenance(args, **options) -> dict:
    """What a run's outputs were made from, for results.nc's attributes and run.json: the
    surface and ray files (absolute paths), the options that shape the answers, the package's
    version and the command line (two runs with and without --outside could be told apart only
    by one column: a review, 2026-12-05)."""
    from . import __version__

    return {"surface": str(Path(args.dem).resolve()), "rays": str(Path(args.rays).resolve()),
            **{k: ("" if v is None else v) for k, v in options.items()},
            "planet_intersect_version": __version__, "command": _command_line(args)}


def _command_line(args) -> str:
    """The command line a run's records name: the arguments main() was given, else the process's
    (a review: a programmatic call recorded its caller's command line)."""
    argv = getattr(args, "_argv", None)
    return " ".join(["planet-intersect", *argv]) if argv is not None else " ".join(sys.argv)


def _simulate_record(args) -> dict:
    """run.json of a simulate run: the files, every option as given, the version and the command
    line, as strict JSON values (a review: simulate's run folders could not be told apart)."""
    from . import __version__
    from .simulate import _jsonable

    record = {"dsm": str(Path(args.dsm).resolve()), "ortho": str(Path(args.ortho).resolve())}
    for k, v in vars(args).items():
        if k in ("func", "dsm", "ortho") or k.startswith("_"):
            continue
        if isinstance(v, (list, tuple)):
            record[k] = [_jsonable(x) for x in v]
        elif isinstance(v, (bool, int, float, str, type(None))):
            record[k] = _jsonable(v)
    record.update(planet_intersect_version=__version__, command=_command_line(args))
    return record


def _write_run(out: Path, res, prov: dict) -> list:
    """results.csv, results.nc (with prov as attributes) and run.json in the run folder ``out``."""
    import json

    write_csv(out / "results.csv", res)
    ds = res.to_xarray()
    ds.attrs.update({k: (v if isinstance(v, (int, float, str)) else str(v)) for k, v in prov.items()})
    ds.to_netcdf(out / "results.nc", engine="h5netcdf")
    (out / "run.json").write_text(json.dumps(prov, indent=1) + "\n")
    return [out / "results.csv", out / "results.nc", out / "run.json"]


def write_csv(path: Path, result) -> None:
    """Per-ray results as CSV, one row per ray, vectors split into _x/_y/_z; numbers with 17
    significant digits, so that they read back as the same doubles (10 digits, as before, kept
    ~1 mm of a hit point in ECR metres, coarser than the exact mode's 1e-6: a walk-through)."""
    cols = result.to_table()
    names = list(cols)
    data = np.column_stack([np.asarray(cols[k], dtype=np.float64) for k in names])
    fmt = ["%d" if k in ("hit", "status", "nsteps") else "%.17g" for k in names]
    np.savetxt(path, data, delimiter=",", header=",".join(names), comments="", fmt=fmt)


def _demo(args) -> int:
    if not 1 <= args.ppd <= 64:
        raise CLIError(f"--ppd must be in 1..64, got {args.ppd}")
    if not 1 <= args.pixels <= 4001:
        raise CLIError(f"--pixels must be in 1..4001, got {args.pixels}")
    with _run_dir(Path(args.out)) as out:
        return _demo_in(args, out)


def _demo_in(args, out: Path) -> int:
    from . import intersect
    from .synthetic import MARS_MEAN_RADIUS, mars_like_dem, oblique_scene

    t0 = time.perf_counter()
    dem = mars_like_dem(ppd=args.ppd)
    t1 = time.perf_counter()
    s, l = oblique_scene(nh=args.pixels, nv=args.pixels)
    res = intersect(dem, s, l, step_mode=1, dem_read_mode=0)
    t2 = time.perf_counter()

    hit = res.hit
    nan_ok = np.seterr(all="ignore")                 # an all-miss view gives nanmin of nothing
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
    np.seterr(**nan_ok)
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


def _read_rays(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays of a text file, one per line (sx sy sz lx ly lz; ``#`` starts a
    comment): s (N, 3), l (N, 3) and the file's line number of each ray."""
    from .dem import regular_file

    try:
        path = regular_file(path, "rays file")
    except (OSError, ValueError) as exc:
        raise CLIError(str(exc)) from None
    rows, lines = [], []
    with open(path, "rb") as fh:
        content = fh.read()
    # lines end at LF, CR or CRLF, as in a .hdr (docs/dem-format.md)
    for lineno, raw in enumerate(re.split(rb"\r\n|\r|\n", content), start=1):
        text = raw.split(b"#", 1)[0].strip()
        if not text:
            continue
        words = text.split()
        if len(words) != 6:
            raise CLIError(f"rays file {path}, line {lineno}: expected 6 numbers (sx sy sz lx ly lz), "
                           f"got {len(words)}")
        try:
            rows.append([float(w) for w in words])
        except ValueError:
            raise CLIError(f"rays file {path}, line {lineno}: not a number in "
                           f"{text.decode('ascii', errors='backslashreplace')!r}") from None
        if not all(np.isfinite(rows[-1])):
            raise CLIError(f"rays file {path}, line {lineno}: NaN or Inf in {rows[-1]}")
        lines.append(lineno)
    if not rows:
        raise CLIError(f"rays file {path}: no rays (every line is blank or a comment)")
    data = np.asarray(rows, dtype=np.float64)
    return data[:, :3], data[:, 3:], np.asarray(lines)


class Progress:
    """A one-line progress bar on standard error (silent for work that is quick)."""

    def __init__(self, total: int, label: str, min_total: int = 1):
        self.total, self.label = total, label
        self.show = total >= min_total
        self.open = False                              # a bar drawn part-way, its line not ended
        self.t0 = time.perf_counter()

    def __call__(self, done: int, total: int | None = None) -> None:
        if not self.show:
            return
        total = total or self.total
        frac = min(done / total, 1.0) if total else 1.0
        bar = "#" * int(30 * frac)
        shown = math.floor(1000 * frac) / 10          # 200,000 of 200,001 is 99.9 %, not "100.0"
        sys.stderr.write(f"\r{self.label} [{bar:<30}] {shown:5.1f}% ({time.perf_counter() - self.t0:.1f} s)")
        self.open = frac < 1.0
        if not self.open:
            sys.stderr.write("\n")
        sys.stderr.flush()

    def close(self) -> None:
        """End a bar left part-way (before an error message, which then has its own line)."""
        if self.open:
            sys.stderr.write("\n")
            sys.stderr.flush()
            self.open = False


def intersect_in_chunks(dem, s, l, chunk: int = 200_000, where=None, **kwargs):
    """intersect() over many rays in chunks, with a progress bar when there is more
    than one. where: (file name, line number of each ray), so that an error about
    ray k names the file's line instead of an index."""
    from . import intersect

    n = max(len(s), len(l))
    s = np.broadcast_to(s, (n, 3))
    l = np.broadcast_to(l, (n, 3))
    bar = Progress(n, "rays", min_total=chunk + 1)
    parts = []
    for a in range(0, n, chunk):
        try:
            parts.append(intersect(dem, s[a:a + chunk], l[a:a + chunk], **kwargs))
        except ValueError as exc:
            bar.close()
            if where is None:
                raise
            name, lines = where
            msg = re.sub(r"\b([sl])\[(\d+)\]",
                         lambda m: f"{m.group(1)} on line {lines[a + int(m.group(2))]} of {name}", str(exc))
            raise CLIError(msg) from None
        bar(min(a + chunk, n))
    if len(parts) == 1:
        return parts[0]
    return type(parts[0])(**{k: np.concatenate([getattr(p, k) for p in parts]) for k in parts[0].__dataclass_fields__})


def _notes(caught):
    """The warnings worth a user's one-line note: the package's UserWarnings. Libraries'
    deprecation warnings (rasterio's PendingDeprecationWarning on every projected read) are
    not about the user's files."""
    return [w for w in caught if issubclass(w.category, UserWarning)]


#: `run` options of a planetary DEM only (with their defaults) and of a geodetic DSM only
_DEM_RUN_OPTIONS = {"step_mode": 1, "dem_read_mode": 0, "tangent": "exact", "io": "records"}
_DSM_RUN_OPTIONS = ("interpolation", "geoid", "nodata", "band", "outside")


def _run(args) -> int:
    from . import DEM

    if Path(args.dem).suffix.lower() in (".tif", ".tiff", ".npz"):    # a geodetic DSM (Shin & Park)
        return _run_dsm(args)
    # a DSM's options with a DEM, and the other way round, are refused rather than ignored (a
    # walk-through saw --step-mode 0 taken silently with a DSM)
    given = [f"--{k.replace('_', '-')}" for k in _DSM_RUN_OPTIONS if getattr(args, k) is not None]
    if given:
        raise CLIError(f"{', '.join(given)}: for a geodetic DSM (.tif, .npz) only, not the DEM {args.dem}")
    if args.io == "mmap" and args.dem_read_mode != 1:
        raise CLIError("--io mmap says how --dem-read-mode 1 reads the .dem file; pass --dem-read-mode 1 "
                       "with it, or leave --io out (the default mode 0 holds the grid in memory)")
    for k, default in _DEM_RUN_OPTIONS.items():
        if getattr(args, k) is None:
            setattr(args, k, default)
    _require("xarray", "xarray", "run (NetCDF output)")
    _require("h5netcdf", "xarray", "run (NetCDF output)")
    if args.method is not None and args.method not in ("stepping", "exact"):
        raise CLIError(f"--method {args.method}: not a method for the planetary DEM {args.dem} (stepping or exact)")
    dem = DEM.read(args.dem)
    s, l, lines = _read_rays(Path(args.rays))
    res = intersect_in_chunks(dem, s, l, where=(args.rays, lines), step_mode=args.step_mode,
                              dem_read_mode=args.dem_read_mode, tangent=args.tangent, method=args.method or "stepping",
                              threads=args.threads, io=args.io)
    prov = _provenance(args, method=args.method or "stepping", step_mode=args.step_mode,
                       dem_read_mode=args.dem_read_mode, tangent=args.tangent)
    with _run_dir(Path(args.out)) as out:
        written = _write_run(out, res, prov)
    print(f"{len(res)} rays: {int(res.hit.sum())} hit, {int((res.status == 1).sum())} limb, "
          f"{int((res.status == 2).sum())} away; wrote {', '.join(map(str, written))}")
    return 0


def _run_dsm(args) -> int:
    """`run` on a geodetic DSM (GeoTIFF or .npz): rays in its ellipsoid's ECR frame."""
    from .dsm import DSMError, DSMStatus, GeodeticDSM

    given = [f"--{k.replace('_', '-')}" for k in _DEM_RUN_OPTIONS if getattr(args, k) is not None]
    if given:
        raise CLIError(f"{', '.join(given)}: for a planetary DEM only, not the geodetic DSM {args.dem}")
    _require("xarray", "xarray", "run (NetCDF output)")
    _require("h5netcdf", "xarray", "run (NetCDF output)")
    geoid = args.geoid
    if geoid is not None:
        try:
            geoid = float(geoid)
        except ValueError:
            if not Path(geoid).is_file():
                raise CLIError(f"--geoid {geoid}: neither a number (metres) nor a file") from None
    if args.method is not None and args.method not in ("following", "exact", "iterative"):
        raise CLIError(f"--method {args.method}: not a method for the geodetic DSM {args.dem} "
                       f"(following, exact or iterative)")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            dsm = GeodeticDSM.read(args.dem, band=args.band if args.band is not None else 1, nodata=args.nodata,
                                   geoid=geoid, interpolation=args.interpolation)
        except DSMError as exc:
            # the reader speaks Python's keywords; here they are options (a review: "pass nodata=-9999")
            msg = re.sub(r"\b(nodata|band|geoid)=", lambda m: f"--{m.group(1)} ", str(exc))
            raise CLIError(msg) from None
    for w in _notes(caught):                    # one line each (not a Python warning)
        print(f"run: note: {w.message}", file=sys.stderr)
    if getattr(dsm, "file_bands", 1) > 1 and args.band is None:
        raise CLIError(f"{args.dem}: the file has {dsm.file_bands} bands; a DSM has one band of heights "
                       f"(--band N reads band N)")
    s, l, lines = _read_rays(Path(args.rays))
    method = args.method or "following"
    res = intersect_in_chunks(dsm, s, l, where=(args.rays, lines), method=method, threads=args.threads,
                              outside=args.outside or "none")
    prov = _provenance(args, method=method, outside=args.outside or "none", interpolation=dsm.interpolation,
                       band=args.band if args.band is not None else 1, nodata=args.nodata, geoid=args.geoid,
                       resampling=dsm.resampling, hmax=dsm.hmax, hmin=dsm.hmin, a=dsm.a, f=dsm.f)
    with _run_dir(Path(args.out)) as out:
        written = _write_run(out, res, prov)
    # every status counted, so that the counts add up to the rays (a walk-through missed OSCILLATION)
    codes, counts = np.unique(res.status, return_counts=True)
    names = {v: k.lower().replace("_", " ") for k, v in vars(DSMStatus).items() if k.isupper()}
    parts = [f"{int(c)} {names.get(int(k), f'status {int(k)}')}" for k, c in zip(codes, counts)]
    if res.on_ellipsoid.any():
        parts.append(f"({int(res.on_ellipsoid.sum())} of those left the DSM given the ellipsoid point)")
    print(f"{len(res)} rays ({method} over the DSM {args.dem}): {', '.join(parts) or 'none'}; "
          f"wrote {', '.join(map(str, written))}")
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
    if not path.exists():
        raise CLIError(f"no Mars DEM: {path} is missing (looked for relative to {Path.cwd()}; set "
                       f"PI_SHARED_DATA to the shared data folder); give --dem NAME.hdr or --mola MEGDR.img "
                       f"(planet-intersect fetch-mola DEST downloads one)")
    return mola_dem(path), str(path)


def _examples(args) -> int:
    _require("matplotlib", "plot", f"examples {args.which} (its figure)")
    if args.which == "buildings":
        return _examples_buildings(args)
    for name in ("zenith", "size", "stride"):
        if getattr(args, name) is not None:
            raise CLIError(f"--{name} is for 'examples buildings', not {args.which}")
    from . import examples

    dem, source = _example_dem(args)
    with _run_dir(Path(args.out)) as out:
        return _examples_in(args, examples, dem, source, out)


def _examples_in(args, examples, dem, source, out) -> int:
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


def _examples_buildings(args) -> int:
    """Shin & Park's Figs. 1 and 2 on a section through the paper's buildings (dsm_examples)."""
    from . import dsm_examples

    for name in ("dem", "mola"):
        if getattr(args, name):
            raise CLIError(f"--{name} is for the Mars examples (olympus, limb); 'examples buildings' builds its own "
                           f"scene")
    zenith = 25.0 if args.zenith is None else args.zenith
    size = 640 if args.size is None else args.size
    stride = 2 if args.stride is None else args.stride
    if not (math.isfinite(zenith) and 0.0 < zenith < 80.0):
        raise CLIError(f"--zenith: degrees in (0, 80), got {zenith:g}")
    if not 64 <= size <= 4096:
        raise CLIError(f"--size: the scene's side in metres, 64 to 4096, got {size}")
    if not 1 <= stride <= size:
        raise CLIError(f"--stride: 1 to --size ({size}), got {stride}")
    t0 = time.perf_counter()
    ex = dsm_examples.buildings(size=size, zenith=zenith, stride=stride)
    with _run_dir(Path(args.out)) as out:
        dsm_examples.plot_buildings(ex, out / "buildings.png")
        lines = [f"examples buildings: the paper's scene ({size} m, flat ground, 'nearest'), rays from the east at "
                 f"{zenith:g} deg zenith, in {time.perf_counter() - t0:.1f} s",
                 f"  section (row {ex.row}, {len(ex.x)} rays) and {ex.nscene:,} rays over the scene, each method "
                 f"against the exact mode's first hit:"]
        for m in ("following", "iterative"):
            c = ex.counts[m]
            parts = [f"{label.split(' (')[0]} {n:,}" for label, n in zip(dsm_examples.OUTCOMES, c) if n]
            lines.append(f"    {m:9s} " + ", ".join(parts))
        lines.append(f"  wrote {out}/buildings.png")
        print("\n".join(lines))
    return 0


def _import_mola(args) -> int:
    from .mola import import_mola

    if bool(args.radius) == bool(args.topography):
        raise CLIError("give --radius IMG, or --topography IMG with --areoid IMG")
    return _imported(import_mola, args.out, radius=args.radius, topography=args.topography, areoid=args.areoid,
                     overwrite=args.overwrite)


def _imported(write, *args, **kw) -> int:
    """Run an importer that writes a DEM pair and report it (its FileExistsError's advice names the
    library's argument: the CLI's is --overwrite)."""
    try:
        hdr = write(*args, **kw)
    except FileExistsError as exc:
        raise CLIError(str(exc).replace("pass overwrite=True", "give --overwrite")) from None
    print(f"wrote {hdr} and {hdr.with_suffix('.dem')}")
    return 0


def _import_pds(args) -> int:
    from .pds import import_pds

    return _imported(import_pds, args.label, args.out, heights_above=args.heights_above, overwrite=args.overwrite)


def _import_shape_table(args) -> int:
    from .shape_table import import_shape_table

    return _imported(import_shape_table, args.table, args.out, ppd=args.ppd, longitude=args.longitude, re=args.re,
                     overwrite=args.overwrite)


def _import_shadr(args) -> int:
    from .shadr import import_shadr

    return _imported(import_shadr, args.sha, args.out, ppd=args.ppd, degree=args.degree, overwrite=args.overwrite)


def _fetch_mola(args) -> int:
    from .mola import fetch_mola

    bar = Progress(1, f"downloading {args.product}")
    hdr = fetch_mola(args.dest, product=args.product, progress=bar)
    print(f"wrote {hdr} and {hdr.with_suffix('.dem')}")
    return 0


# --- footprint (Mars Odyssey GRS notes, issue 13) ------------------------------------------------
#: largest image `simulate --oblique` makes (its rays are held whole: 48 bytes per pixel)
_SIM_MAX_PIXELS = 100_000_000


def _read_states_csv(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """State vectors from CSV: x,y,z,vx,vy,vz or time,x,y,z,vx,vy,vz per line (an optional header line)."""
    if path.is_dir():
        raise CLIError(f"states file {path}: is a directory")
    if not path.is_file():
        raise CLIError(f"states file {path}: no such file")
    with open(path, encoding="utf-8", errors="replace") as fh:
        lines = [ln for ln in fh if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise CLIError(f"states file {path}: no state vectors")

    def number(tok: str) -> bool:
        try:
            float(tok)
            return True
        except ValueError:
            return False

    # a header line has no number in it; a first line with some numbers is data (a damaged
    # first row was once dropped as a "header", shifting every spectrum number by one)
    if not any(number(tok) for tok in lines[0].replace(",", " ").split()):
        lines = lines[1:]
    if not lines:
        raise CLIError(f"states file {path}: no state vectors (only a header line)")
    rows = []
    for i, ln in enumerate(lines):
        toks = ln.replace(",", " ").split()
        bad = [tok for tok in toks if not number(tok)]
        if bad:
            tok = bad[0] if len(bad[0]) <= 40 else bad[0][:40] + "..."
            if not tok.isprintable() or "\ufffd" in tok:
                # (a binary file's bytes were echoed into the message: a review)
                raise CLIError(f"states file {path}: data line {i + 1} is not text (a binary file?)")
            raise CLIError(f"states file {path}: data line {i + 1}: cannot read {tok!r} as a number")
        rows.append(toks)
    widths = {len(r) for r in rows}
    if len(widths) != 1:
        i = next(i for i, r in enumerate(rows) if len(r) != len(rows[0]))
        raise CLIError(f"states file {path}: data line {i + 1} has {len(rows[i])} columns, the first has "
                       f"{len(rows[0])}")
    data = np.array(rows, dtype=np.float64)
    if data.shape[1] not in (6, 7):
        raise CLIError(f"states file {path}: expected 6 columns (x y z vx vy vz) or 7 (time x y z vx vy vz), "
                       f"got {data.shape[1]}")
    if not np.isfinite(data).all():
        row = int(np.argmax(~np.isfinite(data).all(axis=1)))
        raise CLIError(f"states file {path}: row {row + 1} has NaN or Inf values")
    t = data[:, 0] if data.shape[1] == 7 else None
    return data[:, -6:-3], data[:, -3:], t


def _read_times(path: Path) -> list:
    if not path.is_file():
        raise CLIError(f"times file {path}: no such file")
    out = []
    for ln in path.read_text(encoding="utf-8", errors="replace").splitlines():
        ln = ln.strip()
        if not ln or ln.startswith("#"):
            continue
        try:
            out.append(float(ln))
        except ValueError:
            out.append(ln)
    if not out:
        raise CLIError(f"times file {path}: no times")
    return out


def _footprint(args) -> int:
    import importlib

    from . import CellTable, footprint

    fpm = importlib.import_module("planet_intersect.footprint")
    if bool(args.states) == bool(args.kernels):
        raise CLIError("give --states CSV, or --kernels KERNEL... with --times FILE")
    if args.zeta is not None and args.flux_fraction is not None:
        raise CLIError("give --zeta or --flux-fraction, not both")
    if args.states:
        R, v, t = _read_states_csv(Path(args.states))
        source = str(args.states)
    else:
        if not args.times:
            raise CLIError("--kernels needs --times FILE (one UTC time or ET per line)")
        from .spice_states import state_vectors

        times = _read_times(Path(args.times))
        R, v, t = state_vectors(times, kernels=args.kernels, target=args.target, observer=args.observer,
                                frame=args.frame, abcorr=args.abcorr)
        source = f"SPICE ({len(args.kernels)} kernels)"
    dem, dem_source = _example_dem(args)
    cells = CellTable(dem, args.cell_deg)
    n = len(R)
    chunk = int(args.chunk)
    if chunk < 1:
        raise CLIError(f"--chunk must be a positive number of spectra, got {args.chunk}")
    bar = Progress(n, "spectra", min_total=chunk + 1)
    parts = []
    t0 = time.perf_counter()
    for a in range(0, n, chunk):
        try:
            parts.append(footprint(cells, R[a:a + chunk], v[a:a + chunk], zeta=args.zeta,
                                   flux_fraction=args.flux_fraction, occlusion=args.occlusion, threads=args.threads,
                                   airmass_model=args.airmass_model, H=args.scale_height,
                                   # (only when given: the km default is refused for a DEM in metres, grs-notes 19)
                                   **({"area": args.area} if args.area is not None else {})))
        except ValueError as exc:
            # the API's keywords as this command's options (a review: "pass area=3.4e-3")
            msg = re.sub(r"\bairmass_model=", "--airmass-model ", str(exc))
            msg = re.sub(r"\barea=", "--area ", msg)
            msg = re.sub(r"\bH=", "--scale-height ", msg)
            raise CLIError(msg) from None
        bar(min(a + chunk, n))
    fp = _concat_footprints(parts, chunk)
    elapsed = time.perf_counter() - t0
    out = _new_run_dir(Path(args.out))
    written = []
    cols = fp.to_table()
    names = list(cols)
    table = np.column_stack([np.asarray(cols[k], dtype=np.float64) for k in names])
    fmt = ["%d" if k in ("spectrum", "cell", "visible") else "%.10g" for k in names]
    np.savetxt(out / "footprint.csv", table, delimiter=",", header=",".join(names), comments="", fmt=fmt)
    written.append(out / "footprint.csv")
    try:
        # lengths in km where the DEM's radii can be km (grs-notes 19), else the DEM's own unit
        km = float(cells.radius_range[1]) <= fpm.KM_RADIUS_MAX
        ds = fp.to_xarray(length_unit="km" if km else None)
        unit = "km" if km else "DEM length unit"
        # (R, v and time had no attributes while every other variable had units and long_name: a review)
        ds["R"] = (("spectrum", "xyz"), R, {"units": unit, "long_name": "spacecraft position, planet-fixed frame"})
        ds["v"] = (("spectrum", "xyz"), v, {"units": f"{unit} per unit of time, as given",
                                           "long_name": "spacecraft velocity, planet-fixed (only its direction "
                                                        "is used)"})
        if t is not None:
            ds["time"] = ("spectrum", np.asarray(t, dtype=np.float64),
                          {"units": "as given" if args.states else "s (ET, TDB seconds past J2000)",
                           "long_name": "time of the state vector"})
        ds.attrs.update(states=source, dem=dem_source)
        ds.to_netcdf(out / "footprint.nc", engine="h5netcdf")
        written.append(out / "footprint.nc")
    except ImportError as exc:
        print(f"  (no NetCDF output: {exc}; pip install 'planet-intersect[xarray]')")
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        print("  (matplotlib not installed: no PNG; pip install 'planet-intersect[plot]')")
    else:
        if len(fp):
            fpm.plot_footprint_map(fp, out / "footprint_map.png", color=args.color,
                                   spectrum=None if n > 1 else 0)
            written.append(out / "footprint_map.png")
        _plot_states(out / "orbit.png", R, fp, dem, t)
        written.append(out / "orbit.png")
    counts = fp.counts()
    hidden = int((~fp.visible).sum())
    print(f"footprint: {n} spectra from {source} over {dem_source}, {len(cells)} cells of {cells.cell_deg:g} deg\n"
          f"  {len(fp)} (spectrum, cell) pairs, {counts.min()}-{counts.max()} visible cells per spectrum"
          + (f", {hidden} hidden by terrain" if args.occlusion else "") + f"; {elapsed:.2f} s\n"
          f"  wrote {', '.join(map(str, written))}")
    return 0


def _concat_footprints(parts, chunk):
    if len(parts) == 1:
        return parts[0]
    import dataclasses

    first = parts[0]
    kw = {}
    for f in dataclasses.fields(first):
        if f.name in ("cells", "airmass_model", "H", "_airmass"):
            continue
        if f.name == "spectrum":
            kw[f.name] = np.concatenate([p.spectrum + k * chunk for k, p in enumerate(parts)])
        else:
            kw[f.name] = np.concatenate([getattr(p, f.name) for p in parts])
    return type(first)(**kw, cells=first.cells, airmass_model=first.airmass_model, H=first.H)


def _plot_states(path: Path, R, fp, dem, t) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .geometry import latlon_of, spheroid_radius

    lat, lon = latlon_of(R)
    alt = np.linalg.norm(R, axis=1) - (spheroid_radius(lat, dem.f, dem.re) if dem.f > 0 else dem.re)
    x = np.arange(len(R)) if t is None else np.asarray(t) - t[0]
    counts = fp.counts()
    fig, axes = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
    axes[0].plot(x, alt, "k.-")
    axes[0].set_ylabel("altitude above spheroid")
    axes[1].plot(x, counts, "C0.-")
    axes[1].set_ylabel("cells in footprint")
    psi = np.full(len(R), np.nan)
    if len(fp):
        psi = np.array([fp.nadir_angle[fp.spectrum == k].max() if counts[k] else np.nan for k in range(len(R))])
    axes[2].plot(x, psi, "C1.-")
    axes[2].set_ylabel("largest nadir angle (deg)")
    axes[2].set_xlabel("spectrum" if t is None else "time since first spectrum")
    axes[0].set_title(f"{len(R)} spectra: sub-spacecraft latitude {lat.min():.1f} .. {lat.max():.1f} deg", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _add_footprint_parser(sub) -> None:
    g = sub.add_parser("footprint", help="GRS-style footprint geometry of nadir spectra over a cell table (Odyssey notes)")
    g.add_argument("--states", help="CSV of planet-fixed state vectors: x,y,z,vx,vy,vz or time,x,y,z,vx,vy,vz (km, km/s)")
    g.add_argument("--kernels", nargs="+", help="SPICE kernels (SPK, PCK, LSK, ...) to take the states from")
    g.add_argument("--times", help="with --kernels: file with one UTC time or ET (s past J2000) per line")
    g.add_argument("--target", default="-53", help="SPICE target (default -53, Mars Odyssey)")
    g.add_argument("--observer", default="MARS", help="SPICE observer (default MARS)")
    g.add_argument("--frame", default="IAU_MARS", help="SPICE frame (default IAU_MARS)")
    g.add_argument("--abcorr", default="NONE", help="SPICE aberration correction (default NONE)")
    g.add_argument("--dem", help="DEM NAME.hdr in km (default: the MOLA grid in $PI_SHARED_DATA, or in "
                                 "../shared/data relative to the current folder)")
    g.add_argument("--mola", help="a MEGDR radius grid to use instead")
    g.add_argument("--cell-deg", type=float, default=0.5, help="cell size in degrees, dividing 180 (default 0.5)")
    g.add_argument("--zeta", type=float, help="footprint cone cos(psi) >= ZETA (default: every cell above the horizon)")
    g.add_argument("--flux-fraction", type=float, help="instead of --zeta: the cone holding this fraction of the flux")
    g.add_argument("--area", type=float, default=None,
                   help="detector area in the DEM's unit squared (default 3.4e-9 km^2, 34 cm^2, for a DEM in km)")
    g.add_argument("--airmass-model", choices=("chapman", "hardie", "notes", "secant"), default="chapman",
                   help="air mass of each pair (default chapman)")
    g.add_argument("--scale-height", type=float, default=None,
                   help="chapman's scale height H in the DEM's unit (default 10.8 km: Mars at 210 K)")
    g.add_argument("--occlusion", action="store_true",
                   help="also test each pair's line of sight against the terrain (exact ray casting): "
                        "hidden pairs are kept, with visible = 0")
    g.add_argument("--color", choices=("solid_angle", "emission"), default="solid_angle", help="map colouring")
    g.add_argument("--threads", type=int, default=0, help="OpenMP threads (default 0: OMP_NUM_THREADS if set, else all cores)")
    g.add_argument("--chunk", type=int, default=50, help="spectra per call (progress is shown between chunks)")
    g.add_argument("--out", default="footprint-output",
                   help="results go to a new run-NNN folder here (default: footprint-output)")
    g.set_defaults(func=_footprint)
# --- end footprint ------------------------------------------------------------------------------


# --- simulate (Shin & Park image simulation) ----------------------------------------------------
def _sensor_from_args(args, dsm, scene):
    """The sensor of a ``simulate`` run: a geometry file, an oblique pushbroom
    over the DSM, or a built-in orbit."""
    from .sensors import FrameCamera, Pushbroom
    from .synthetic_dsm import oblique_pushbroom

    _check_sensor_options(args)
    if args.geometry:
        path = Path(args.geometry)
        if not path.is_file():
            raise CLIError(f"--geometry {path}: no such file")
        with open(path, "rb") as fh:
            magic = fh.read(4)
        if magic != b"PK\x03\x04":                      # an .npz is a zip archive
            raise CLIError(f"--geometry {path}: not an .npz file (np.savez writes one)")
        try:
            with np.load(path, allow_pickle=False) as z:
                d = {k: z[k] for k in z.files}
        except Exception as exc:  # noqa: BLE001
            raise CLIError(f"--geometry {path}: cannot be read as .npz ({exc})") from None
        if "l" not in d or ("s" not in d and "position" not in d):
            raise CLIError(f"--geometry {path}: needs arrays s (nlines, 3) and l (nlines, npixels, 3) "
                           "for a pushbroom, or position (3,) and l (nrows, ncols, 3) for a frame camera")
        if "s" in d and "position" in d:
            raise CLIError(f"--geometry {path}: holds both s (a pushbroom) and position (a frame camera); "
                           "keep one")
        try:
            sensor = Pushbroom(d["s"], d["l"]) if "s" in d else FrameCamera(d["position"], d["l"])
        except (TypeError, ValueError) as exc:
            raise CLIError(f"--geometry {path}: {exc}") from None
        # positions in km (or any unit but metres) put the sensor inside the body: say so here, with
        # the file's name, not later as a ray's error
        pos = np.asarray(d["s"] if "s" in d else d["position"], dtype=float).reshape(-1, 3)
        r = np.linalg.norm(pos, axis=1)
        b = dsm.a * (1.0 - dsm.f)
        if np.any(r < b):
            k = int(np.argmin(r))
            raise CLIError(f"--geometry {path}: {'s' if 's' in d else 'position'}[{k}] is {r[k]:.6g} m from the "
                           f"body's centre, inside the ellipsoid (b = {b:.6g} m): positions are ECR metres")
        return sensor
    if args.orbit:
        return _orbit_sensor(args, dsm)
    zen, az = args.oblique if args.oblique is not None else _OBLIQUE_DEFAULT
    if not 0 <= zen < 80:
        raise CLIError(f"--oblique: zenith {zen} outside [0, 80) degrees")
    grid = scene if scene is not None else dict(heights=dsm.heights, lat_first=dsm.lat_first,
                                                lon_first=dsm.lon_first, dlat=dsm.dlat, dlon=dsm.dlon,
                                                a=dsm.a, f=dsm.f)
    margin = args.margin if args.margin is not None else (grid["heights"].shape[0] // 10 if scene else 0)
    if args.step is None:
        args.step = 1.0
    if not args.step > 0:
        raise CLIError(f"--step must be positive, got {args.step}")
    if margin < 0:
        raise CLIError(f"--margin must be >= 0 cells, got {margin}")
    nr, nc = grid["heights"].shape
    npix = len(np.arange(margin, nr - margin, args.step)) * len(np.arange(margin, nc - margin, args.step)) \
        if max(nr, nc) / args.step <= 1e6 else float("inf")
    if npix > _SIM_MAX_PIXELS:
        raise CLIError(f"--step {args.step:g} makes an image of {npix:.3g} pixels over the {nr} x {nc} DSM "
                       f"(at most {_SIM_MAX_PIXELS:,}; use a larger --step)")
    if args.altitude is None:
        args.altitude = _ALTITUDE_DEFAULT
    if not (math.isfinite(args.altitude) and 0 < args.altitude <= 1e15 * grid.get("a", 6378137.0)):
        # inf reached the sensor as "s[0] has NaN" (a review)
        raise CLIError(f"--altitude must be a finite positive height in metres, got {args.altitude}")
    return Pushbroom(*oblique_pushbroom(grid, zenith=zen, azimuth=az, altitude=args.altitude,
                                        margin=margin, step=args.step))


def _orbit_sensor(args, dsm):
    from .sensors import Pushbroom

    if args.target is None:
        raise CLIError("--orbit needs --target LAT,LON (the point the centre pixel looks at)")
    for name, value in _ORBIT_DEFAULTS.items():
        if getattr(args, name) is None:
            setattr(args, name, value)
    lat, lon = args.target
    h = float(dsm.height(lat, lon))
    if not np.isfinite(h):
        raise CLIError(f"--target {lat},{lon}: not over the DSM's data")
    if args.lines < 1 or args.pixels < 1:
        raise CLIError(f"--lines and --pixels must be >= 1, got {args.lines} and {args.pixels}")
    period = args.line_period
    if period is None:
        # square pixels: the line period is the nadir GSD over the ground speed of a circular orbit
        from .sensors import EARTH_GM

        r = dsm.a + args.altitude
        period = args.altitude * np.radians(args.ifov) / (np.sqrt(EARTH_GM / r) * dsm.a / r)
    return Pushbroom.from_orbit(altitude=args.altitude, inclination=args.inclination,
                                direction="descending" if args.descending else "ascending",
                                target=(lat, lon, h), nlines=args.lines, npixels=args.pixels, ifov=args.ifov,
                                roll=args.roll, pitch=args.pitch, yaw=args.yaw, line_period=period)


#: defaults of the sensor options (None in the parser, so that options given to a sensor that
#: does not use them can be refused: a newcomer's --roll without --orbit was silently ignored)
_OBLIQUE_DEFAULT = (9.0, 90.0)
_ALTITUDE_DEFAULT = 685e3
_ORBIT_DEFAULTS = dict(inclination=98.0, lines=1024, pixels=1024, ifov=8.4e-5, roll=0.0, pitch=0.0, yaw=0.0,
                       altitude=_ALTITUDE_DEFAULT)
_ORBIT_ONLY = ("target", "inclination", "descending", "lines", "pixels", "ifov", "line_period", "roll", "pitch",
               "yaw")
_OBLIQUE_ONLY = ("oblique", "step", "margin")


def _given(args, names) -> list:
    """The options among ``names`` (attribute names) given on the command line, as --flags (store_true
    flags count when set; a value of 0 counts: ``0.0 in (None, False)`` is true in Python)."""
    return ["--" + n.replace("_", "-") for n in names
            if getattr(args, n) is not None and getattr(args, n) is not False]


def _check_sensor_options(args) -> None:
    """Refuse sensor options that the chosen sensor would ignore."""
    if args.geometry:
        extra = _given(args, ("orbit", "altitude") + _ORBIT_ONLY + _OBLIQUE_ONLY)
        if extra:
            raise CLIError(f"--geometry takes the whole sensor from its file: {', '.join(extra)} would be ignored")
    elif args.orbit:
        extra = _given(args, _OBLIQUE_ONLY)
        if extra:
            raise CLIError(f"--orbit: {', '.join(extra)} {'belongs' if len(extra) == 1 else 'belong'} to --oblique "
                           "runs and would be ignored")
    else:
        extra = _given(args, _ORBIT_ONLY)
        if extra:
            raise CLIError(f"{', '.join(extra)}: need --orbit (without it the sensor is --oblique's pushbroom, "
                           "which would ignore them)")


def _pair(text: str) -> tuple[float, float]:
    try:
        a, b = (float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected two numbers A,B, got {text!r}") from None
    if not (np.isfinite(a) and np.isfinite(b)):
        raise argparse.ArgumentTypeError(f"expected finite numbers, got {text!r}")
    return a, b


def _simulate(args) -> int:
    from . import GeodeticDSM, OrthoImage, simulate_image
    from .sim_run import fig4, paper_experiment, write_outputs, wrong_surface

    _require("scipy", "sim", "simulate")
    _require("matplotlib", "plot", "simulate")
    if args.threads is not None and args.threads < 0:
        raise CLIError(f"--threads must be >= 0, got {args.threads}")
    if args.block_lines is not None and args.block_lines < 1:
        raise CLIError(f"--block-lines must be >= 1, got {args.block_lines}")
    if args.ground is not None and args.ground_window is not None:
        raise CLIError("--ground-window shapes the bare earth estimated when --ground is not given: give one of them")
    if args.ground_window is not None and not (math.isfinite(args.ground_window) and args.ground_window > 0):
        raise CLIError(f"--ground-window must be a positive number of metres, got {args.ground_window}")
    t0 = time.perf_counter()
    if args.dsm is None:
        if args.ortho is not None or args.geometry is not None or args.ground is not None:
            raise CLIError("--ortho, --geometry and --ground need --dsm (without --dsm the built-in paper scene is "
                           "used)")
        extra = _given(args, ("orbit", "altitude", "step", "margin") + _ORBIT_ONLY)
        if extra:
            raise CLIError(f"{', '.join(extra)}: need --dsm (the built-in paper scene takes only --oblique's "
                           "zenith and --size)")
        if not 128 <= args.size <= 8192:
            raise CLIError(f"--size must be in [128, 8192] metres, got {args.size}")
        with _run_dir(Path(args.out)) as out:
            zenith = (args.oblique or _OBLIQUE_DEFAULT)[0]
            exp = paper_experiment(size=args.size, methods=("exact", "iterative"), zenith=zenith,
                                   threads=args.threads, progress=not args.quiet)
            counts = fig4(exp, out / "fig4.png")
            written = [out / "fig4.png"]
            written += write_outputs(exp["sims"]["exact"], out, "exact")
            written += write_outputs(exp["sims"]["iterative"], out, "iterative", netcdf=False, geotiff=False)
            lines = [f"{k}: {v}" for k, v in counts.items()]
            (out / "counts.txt").write_text("\n".join(lines) + "\n")
            written.append(out / "counts.txt")
        ex = exp["sims"]["exact"]
        print(f"simulate: Shin & Park's experiment, {ex.shape[0]} x {ex.shape[1]} pixels, "
              f"{time.perf_counter() - t0:.1f} s\n  exact: {counts['exact_roofs']:,} roof, {counts['exact_walls']:,} "
              f"wall pixels, {counts['occluded_ortho_pixels']:,} occluded ortho pixels\n  iterative: "
              f"{counts['iterative_not_converged']:,} not converged, {counts['iterative_wrong_surface']:,} on the "
              f"wrong surface\n  wrote {', '.join(str(p) for p in written)}")
        return 0
    if args.ortho is None:
        raise CLIError("--dsm needs --ortho (the ortho-image to drape)")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        dsm = GeodeticDSM.read(args.dsm, interpolation=args.interpolation)
        ortho = OrthoImage.read(args.ortho, resampling=args.ortho_resampling)
        # the bare earth for the surface classes, on the DSM's ellipsoid (simulate_image samples it
        # on the DSM's grid)
        ground = None if args.ground is None else GeodeticDSM.read(args.ground, interpolation=dsm.interpolation)
    for w in _notes(caught):                    # what the readers say of the files, one line each
        print(f"simulate: note: {w.message}", file=sys.stderr)
    sensor = _sensor_from_args(args, dsm, None)
    if getattr(dsm, "resampling", None):
        # the warp's grid is rasterio's choice: say what it became (a 1 m UTM grid became 1.29 x 0.85 m cells)
        dy, dx = abs(math.radians(dsm.dlat)) * dsm.a, math.radians(dsm.dlon) * dsm.a * math.cos(
            math.radians(dsm.lat_first + 0.5 * (dsm.nrows - 1) * dsm.dlat))
        print(f"simulate: note: --dsm {args.dsm} ({dsm.crs}) warped ({dsm.resampling}) to a geodetic grid of "
              f"{dsm.nrows} x {dsm.ncols} cells of {dy:.3g} m x {dx:.3g} m, read {dsm.interpolation!r}",
              file=sys.stderr)
    if getattr(dsm, "file_bands", 1) > 1:
        # an image given as the DSM ran with its first band as heights (a newcomer's walk-through)
        raise CLIError(f"--dsm {args.dsm}: the file has {dsm.file_bands} bands; a DSM has one band of heights "
                       "(was the ortho-image given as --dsm?)")
    with _run_dir(Path(args.out)) as out:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            ground_kw = {} if args.ground_window is None else {"ground_window": args.ground_window}
            sim = simulate_image(dsm, ortho, sensor, method=args.method, walls=args.walls, shading=args.shading,
                                 sun=args.sun, ambient=args.ambient, fill=args.fill, ground=ground, **ground_kw,
                                 occlusion=not args.no_occlusion, threads=args.threads,
                                 block_lines=args.block_lines, progress=not args.quiet,
                                 out=out / "backplanes" if args.memmap else None)
        for w in _notes(caught):                # one line each, naming the file (not a Python warning)
            print(f"simulate: note: --ortho {args.ortho}: {w.message}", file=sys.stderr)
        written = write_outputs(sim, out, "simulated")
        import json

        (out / "run.json").write_text(json.dumps(_simulate_record(args), indent=1, allow_nan=False) + "\n")
        written.append(out / "run.json")
        if args.compare_iterative:
            # memory-mapped too when the main run was (a review: in memory, a machine too small for it
            # refused it after the main run, and the whole run folder went)
            it = simulate_image(dsm, ortho, sensor, method="iterative", occlusion=False, threads=args.threads,
                                block_lines=args.block_lines,
                                out=out / "backplanes_iterative" if args.memmap else None)
            written += write_outputs(it, out, "iterative", netcdf=False, geotiff=False)
            print(f"  iterative: {int((~it.valid).sum()):,} pixels without a hit, "
                  f"{int(wrong_surface(it, sim).sum()):,} on the wrong surface")
    c = sim.counts()
    print(f"simulate: {sim.shape[0]} x {sim.shape[1]} pixels of {args.ortho} on {args.dsm} ({args.method}), "
          f"{time.perf_counter() - t0:.1f} s in all (the simulation itself {sim.meta['seconds_simulation']:.2f} s, "
          f"{sim.meta['pixels_per_second']:,.0f} px/s; reading, occlusion and writing the rest)\n  "
          + ", ".join(f"{k} {v:,}" for k, v in c.items()) + f"\n  wrote {', '.join(str(p) for p in written)}")
    return 0


def _add_simulate_parser(sub) -> None:
    s = sub.add_parser(
        "simulate", help="simulate an oblique image of an ortho-photo draped on a DSM (Shin & Park)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Simulate the image a sensor takes of an ortho-photo draped on a DSM: every pixel's ray is\n"
                    "followed to its first hit and the ortho-photo's value there becomes the pixel's value.\n\n"
                    "Without --dsm: Shin & Park's experiment on the built-in scene (Jacksboro base DEM, four\n"
                    "buildings, synthetic ortho-photo), exact and iterative methods, and their Fig. 4.\n\n"
                    "A complete run from files:\n"
                    "  planet-intersect simulate --dsm dsm.tif --ortho ortho.tif --oblique 9,90 --out sims\n"
                    "    (a pushbroom viewing every DSM row at 9 deg zenith from the east, one pixel per cell)\n"
                    "  planet-intersect simulate --dsm dsm.tif --ortho ortho.tif --orbit --target 36.6,-84.2 \\\n"
                    "      --altitude 685000 --lines 2000 --pixels 2000 --ifov 8.4e-5 --roll 8.1 --out sims\n"
                    "    (an ascending, north-bound pass looking 8.1 deg to the West: 9 deg zenith at the ground)\n"
                    "  planet-intersect simulate --dsm dsm.tif --ortho ortho.tif --geometry sensor.npz --out sims\n"
                    "    (sensor.npz: s (nlines, 3) and l (nlines, npixels, 3) in ECR metres for a pushbroom,\n"
                    "     or position (3,) and l (nrows, ncols, 3) for a frame camera)\n\n"
                    "GeoTIFFs in a geographic CRS are read as they are; projected ones are warped to a\n"
                    "geodetic grid. DSM heights must be above WGS-84 (add the geoid undulation if not).\n"
                    "Image orientation: --oblique lines are the DSM's rows in its stored order and pixels its\n"
                    "columns west to east (a north-up DSM gives a north-up image); --orbit and --geometry\n"
                    "lines are in acquisition order and pixels in the sensor's order (--orbit: from the left\n"
                    "of the flight direction, so an ascending pass's image has south at the top).\n"
                    "Outputs in a new run-NNN folder: simulated.png (the image), simulated_surface.png,\n"
                    "simulated_occlusion.png, simulated.tif (image + backplanes in sensor geometry),\n"
                    "simulated.nc (NetCDF of image, lat, lon, height, distance, incidence, surface, masks).")
    s.add_argument("--dsm", help="DSM GeoTIFF or .npz (heights above WGS-84, metres)")
    s.add_argument("--ortho", help="ortho-image GeoTIFF or .npz (one band or RGB)")
    s.add_argument("--ortho-resampling", choices=("bilinear", "nearest"), default="bilinear",
                   help="how an ortho-image in a projected CRS is warped to a geodetic grid (default bilinear)")
    s.add_argument("--geometry", help=".npz with the sensor's rays (see above)")
    s.add_argument("--oblique", type=_pair, default=None, metavar="ZENITH,AZIMUTH",
                   help="pushbroom over the DSM grid viewing at ZENITH deg from AZIMUTH (deg from north; "
                        "default 9,90: from the East); the sensor when neither --orbit nor --geometry is given")
    s.add_argument("--orbit", action="store_true", help="built-in Keplerian orbit (with --target, --altitude, ...)")
    s.add_argument("--target", type=_pair, metavar="LAT,LON", help="--orbit: where the centre pixel looks")
    s.add_argument("--altitude", type=float, default=None, help="sensor altitude in m (default 685 km)")
    s.add_argument("--inclination", type=float, default=None, help="--orbit: inclination, deg (default 98)")
    s.add_argument("--descending", action="store_true", help="--orbit: descending pass (default ascending)")
    s.add_argument("--lines", type=int, default=None, help="--orbit: image lines (default 1024)")
    s.add_argument("--pixels", type=int, default=None, help="--orbit: pixels per line (default 1024)")
    s.add_argument("--ifov", type=float, default=None,
                   help="--orbit: instantaneous field of view per pixel, degrees (default 8.4e-5: 1 m at 685 km)")
    s.add_argument("--line-period", type=float,
                   help="--orbit: seconds per line (default: square pixels, the nadir GSD over the ground speed)")
    s.add_argument("--roll", type=float, default=None,
                   help="--orbit: roll, deg (> 0 looks left of the flight direction: west when north-bound; "
                        "default 0)")
    s.add_argument("--pitch", type=float, default=None, help="--orbit: pitch, deg (default 0)")
    s.add_argument("--yaw", type=float, default=None, help="--orbit: yaw, deg (default 0)")
    s.add_argument("--step", type=float, default=None, help="--oblique: DSM cells per pixel and line (default 1)")
    s.add_argument("--margin", type=int, help="--oblique: DSM cells left out on each side")
    s.add_argument("--method", choices=("exact", "following", "iterative"), default="exact")
    s.add_argument("--interpolation", choices=("bilinear", "nearest"),
                   help="DSM interpolation (default: the reader's: bilinear for a geographic GeoTIFF, nearest for "
                        "a projected one, warped nearest); nearest for buildings: flat roofs, vertical walls "
                        "(bilinear makes each wall a one-cell ramp)")
    s.add_argument("--walls", choices=("interpolate", "ortho"), default="interpolate")
    s.add_argument("--shading", choices=("none", "lambert"), default="none")
    s.add_argument("--sun", type=_pair, metavar="AZIMUTH,ELEVATION", help="Sun direction for --shading lambert, deg")
    s.add_argument("--ambient", type=float, default=0.0, help="ambient fraction for --shading lambert")
    s.add_argument("--fill", type=float, default=0.0, help="value of pixels without a hit")
    s.add_argument("--ground", metavar="FILE",
                   help="bare-earth heights (a raster or .npz as --dsm, read the same way) for the roof/wall/ground "
                        "classes; default: an opening of the DSM (see --ground-window)")
    s.add_argument("--ground-window", type=float, default=None, metavar="METRES",
                   help="without --ground: the width of the DSM opening that estimates bare earth (default 100; "
                        "wider than the widest building, narrower than the terrain's hills)")
    s.add_argument("--no-occlusion", action="store_true", help="skip the occlusion mask (one ray per ortho pixel)")
    s.add_argument("--compare-iterative", action="store_true", help="also simulate with the iterative method")
    s.add_argument("--memmap", action="store_true", help="keep the backplanes in memory-mapped files (huge images)")
    s.add_argument("--block-lines", type=int, default=None,
                   help="image lines per block (default: as many as make ~131,072 pixels)")
    s.add_argument("--threads", type=int, help="OpenMP threads (default: OMP_NUM_THREADS if set, else all cores)")
    s.add_argument("--size", type=int, default=640, help="without --dsm: the paper scene's size in metres")
    s.add_argument("--quiet", action="store_true", help="no progress bar")
    s.add_argument("--out", default="simulate-output",
                   help="results go to a new run-NNN folder here (default: simulate-output)")
    s.set_defaults(func=_simulate)
# --- end simulate -------------------------------------------------------------------------------


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors, as every other error of the command line: its own printed the
    whole usage block first, ~10 lines for --threads 1.5 (a review). Subcommands inherit it."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _parser() -> argparse.ArgumentParser:
    p = _Parser(prog="planet-intersect",
                                description="Where lines of sight meet a planet's DEM (Teanby 2008 ray stepping).")
    sub = p.add_subparsers(dest="command", required=True)
    d = sub.add_parser("demo", help="oblique view of a synthetic Mars with a shield volcano (built-in default)")
    d.add_argument("--out", default="demo-output", help="results go to a new run-NNN folder here (default: demo-output)")
    d.add_argument("--ppd", type=int, default=4, help="DEM pixels per degree, 1..64 (default 4)")
    d.add_argument("--pixels", type=int, default=101, help="detector pixels per side (default 101, as the paper's Fig. 8)")
    d.set_defaults(func=_demo)
    r = sub.add_parser("run", help="intersect the rays of a text file (sx sy sz lx ly lz per line) with a DEM")
    r.add_argument("dem", help="DEM as NAME, NAME.hdr or NAME.dem; or a geodetic DSM (.tif GeoTIFF, .npz)")
    r.add_argument("rays", help="text file, one ray per line: sx sy sz lx ly lz")
    r.add_argument("--out", default="planet-intersect-output",
                   help="results go to a new run-NNN folder here (default: planet-intersect-output)")
    r.add_argument("--method", choices=("stepping", "exact", "following", "iterative"), default=None,
                   help="DEM: stepping (default) or exact; DSM: following (default), exact or iterative")
    r.add_argument("--threads", type=int, default=0, help="OpenMP threads (default 0: OMP_NUM_THREADS if set, else all cores)")
    dem_g = r.add_argument_group("planetary DEM only")
    dem_g.add_argument("--step-mode", type=int, choices=(0, 1), default=None, help="default 1")
    dem_g.add_argument("--dem-read-mode", type=int, choices=(0, 1), default=None, help="default 0")
    dem_g.add_argument("--tangent", choices=("exact", "paper"), default=None,
                       help="spheroid tangent point: true nearest point (default) or the paper's eqs. 55-58")
    dem_g.add_argument("--io", choices=("records", "mmap"), default=None,
                       help="with --dem-read-mode 1 only: one read per record (default) or a memory map")
    dsm_g = r.add_argument_group("geodetic DSM only (.tif, .npz)")
    dsm_g.add_argument("--interpolation", choices=("bilinear", "nearest"), default=None,
                       help="DSM surface (default: nearest for a warped projected raster, else bilinear)")
    dsm_g.add_argument("--geoid", default=None,
                       help="geoid undulation N (metres, or a raster on the DSM's grid): heights above the "
                            "geoid become H + N above the ellipsoid (default: heights are ellipsoidal)")
    dsm_g.add_argument("--nodata", type=float, default=None,
                       help="no-data value (replaces the file's tag; nan: only NaN marks no data)")
    dsm_g.add_argument("--band", type=int, default=None, help="the band of heights (default: the only one)")
    dsm_g.add_argument("--outside", choices=("none", "ellipsoid"), default=None,
                       help="rays that leave the DSM without a hit: status LEFT_DSM only (default), or also "
                            "the point on the bare ellipsoid")
    r.set_defaults(func=_run)
    e = sub.add_parser("examples", help="the papers' examples: olympus (Fig. 8) or limb (Fig. 9), on MOLA; "
                                        "buildings (Shin & Park's Figs. 1-2, on a built-in scene)")
    e.add_argument("which", choices=("olympus", "limb", "buildings"))
    e.add_argument("--zenith", type=float, default=None,
                   help="buildings: the rays' zenith angle in degrees, arriving from the east (default 25)")
    e.add_argument("--size", type=int, default=None, help="buildings: the scene's side in metres (default 640)")
    e.add_argument("--stride", type=int, default=None,
                   help="buildings: a ray at every K-th row and column of the scene for the counts (default 2)")
    e.add_argument("--dem", help="a Mars DEM NAME.hdr in km (default: the MOLA grid in $PI_SHARED_DATA, or in "
                                 "../shared/data relative to the current folder)")
    e.add_argument("--mola", help="a MEGDR radius grid (megr*.img style) to use instead")
    e.add_argument("--out", default="examples-output",
                   help="results go to a new run-NNN folder here (default: examples-output)")
    e.set_defaults(func=_examples)
    m = sub.add_parser("import-mola", help="convert MOLA MEGDR grids to a .hdr/.dem DEM (km)")
    m.add_argument("out", help="output NAME (writes NAME.hdr and NAME.dem)")
    m.add_argument("--radius", help="MEGDR radius grid (value + 3,396,000 m)")
    m.add_argument("--topography", help="MEGDR topography grid (m above the areoid)")
    m.add_argument("--areoid", help="areoid grid (value + 3,396,000 m) for --topography")
    m.add_argument("--overwrite", action="store_true", help="replace existing NAME.hdr/.dem")
    m.set_defaults(func=_import_mola)
    m = sub.add_parser("import-pds", help="convert a global PDS3 simple-cylindrical radius grid (LOLA LDEM, "
                                          "MEGDR, ...) with its label to a .hdr/.dem DEM (km)")
    m.add_argument("label", help="the PDS3 label (.LBL, or an .IMG with its label attached)")
    m.add_argument("out", help="output NAME (writes NAME.hdr and NAME.dem)")
    m.add_argument("--heights-above", type=float, default=None, metavar="KM",
                   help="for a grid of heights: the radius (km) of the sphere they are above")
    m.add_argument("--overwrite", action="store_true", help="replace existing NAME.hdr/.dem")
    m.set_defaults(func=_import_pds)
    m = sub.add_parser("import-shape-table", help="convert a small-body shape table (latitude, longitude, radius "
                                                  "at grid nodes; P. C. Thomas' m1phobos.tab, ...) to a .hdr/.dem DEM")
    m.add_argument("table", help="the text table: latitude, longitude (deg), radius (km) at the nodes of a global grid")
    m.add_argument("out", help="output NAME (writes NAME.hdr and NAME.dem)")
    m.add_argument("--ppd", type=int, default=None, help="DEM pixels per degree (default: as fine as the table, >= 1)")
    m.add_argument("--longitude", choices=("west", "east"), default="west",
                   help="which way the table's longitudes run (default west: the shape's evidence; docs/paper-notes.md "
                        "note 23)")
    m.add_argument("--re", type=float, default=None, metavar="KM",
                   help="a reference sphere's radius for altitudes (default none: an irregular body)")
    m.add_argument("--overwrite", action="store_true", help="replace existing NAME.hdr/.dem")
    m.set_defaults(func=_import_shape_table)
    m = sub.add_parser("import-shadr", help="evaluate a PDS SHADR spherical-harmonic shape model (MOLA's GTM090AA, "
                                            "...) on a global grid as a .hdr/.dem DEM (km)")
    m.add_argument("sha", help="the SHADR ASCII coefficient file (header record, then n, m, C, S, ...)")
    m.add_argument("out", help="output NAME (writes NAME.hdr and NAME.dem)")
    m.add_argument("--ppd", type=int, default=1, help="DEM pixels per degree (default 1)")
    m.add_argument("--degree", type=int, default=None, help="truncate the series at this degree (default: all)")
    m.add_argument("--overwrite", action="store_true", help="replace existing NAME.hdr/.dem")
    m.set_defaults(func=_import_shadr)
    f = sub.add_parser("fetch-mola", help="download a MEGDR radius grid from the PDS Geosciences Node and import it")
    f.add_argument("dest", help="folder for the download and the DEM")
    f.add_argument("--product", default="megr90n000cb", choices=("megr90n000cb", "megr90n000eb"),
                   help="megr90n000cb: 4 pixels/degree (2 MB); megr90n000eb: 16 pixels/degree (33 MB)")
    f.set_defaults(func=_fetch_mola)
    c = sub.add_parser("config", help="link flags of the legacy FORTRAN77 library (pkg-config style), "
                                      "or which compiled core is in use")
    what = c.add_mutually_exclusive_group(required=True)
    what.add_argument("--libs", action="store_true", help="the link flags, for after the program's sources")
    what.add_argument("--cflags", action="store_true", help="the compile flags (empty: implicit interfaces)")
    what.add_argument("--pkg-config-path", action="store_true",
                      help="the folder of planet-intersect-legacy.pc, for PKG_CONFIG_PATH")
    what.add_argument("--core", action="store_true",
                      help="which compiled core the package uses (_core, or _core_v3 on x86-64-v3 CPUs) "
                           "and why; PI_CORE=portable|v3|auto chooses")
    c.set_defaults(func=_config)
    _add_footprint_parser(sub)
    _add_simulate_parser(sub)
    return p


def _config(args) -> int:
    from . import legacy_config

    if args.core:
        from ._ext import core_info

        info = core_info()
        print(f"{info['module']}: {info['reason']}")
    elif args.pkg_config_path:
        print(legacy_config.pc_file().parent)
    else:
        print(legacy_config.link_flags() if args.libs else legacy_config.compile_flags())
    return 0


def main(argv=None) -> int:
    """Entry point of the console script."""
    args = _parser().parse_args(argv)
    args._argv = None if argv is None else [str(a) for a in argv]
    try:
        return args.func(args)
    except (CLIError, ValueError, TypeError, OSError) as exc:
        print(f"planet-intersect: error: {exc}", file=sys.stderr)
        return 2
    except MemoryError as exc:
        print(f"planet-intersect: error: out of memory ({exc or 'an array too large for this machine'}); "
              "ask for less in one run (fewer rays, lines or spectra)", file=sys.stderr)
        return 2
    except ImportError as exc:
        print(f"planet-intersect: error: a Python package is missing ({exc}); "
              "pip install 'planet-intersect[all]'", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        # one line, not a traceback (a review); run folders of the interrupted command are removed.
        # Run as a program, die of SIGINT as before, so that a shell loop around it stops too (a
        # return code of 130 let bash run the next iteration: a second review)
        print("planet-intersect: interrupted", file=sys.stderr)
        if argv is None:
            import os
            import signal

            signal.signal(signal.SIGINT, signal.SIG_DFL)
            os.kill(os.getpid(), signal.SIGINT)
        return 130


if __name__ == "__main__":
    sys.exit(main())
