"""Orekit Rugged's Duvenhage algorithm as an independent reference for geodetic DSMs.

Rugged (the CS GROUP library for direct location of satellite pixels on DEMs)
is driven at the algorithm level, without any Orekit data file: an
``ExtendedEllipsoid`` on a plain body frame, a ``TileUpdater`` serving the
grid as overlapping tiles, ``DuvenhageAlgorithm.intersection`` followed by
``refineIntersection``. The updater and the batch loop are a few lines of Java
(``RuggedBatch.java`` beside this file), compiled with ``javac`` at run time
against the jars that the PyPI package ``orekit-jpype`` bundles, into a cache
folder outside the repository (``$PI_RUGGED_CACHE``, else
``$XDG_CACHE_HOME/planet-intersect/rugged``, else
``~/.cache/planet-intersect/rugged``), in a sub-folder named after a hash of
the source, the jars and the javac version. Rays cross into Java once per
batch, as Java ``double[]`` copied in bulk; there is no Python callback.

The answer is Rugged's, as it is: nothing here corrects it. Known from use:
Rugged accepts a cell root up to 1/8 cell outside the cell it solves in
(``SimpleTile.TOLERANCE``), so on a building DSM about 1 ray in 1,000 comes
back as a false hit on the extension of a neighbouring wall cell, up to tens
of metres before the true first hit; finding and explaining those rays is the
comparison's job.

What Rugged sees (the grid of ``../shared/DESIGN.md`` section 8)
------------------------------------------------------------------
* Pixel centres are Rugged's tile nodes: node (I, J) of a south-up lattice at
  latitude ``lat_south + I*|dlat|`` and longitude ``lon_west + J*dlon``; Rugged
  interpolates bilinearly in (latitude, longitude) between nodes, as the
  contract's ``"bilinear"`` surface. A north-up grid (``dlat < 0``) is flipped
  to south-up here; the surface is the same.
* The lattice goes on outside the DSM: every node that is not a pixel centre
  of the DSM has the height ``fill`` (default: the DSM's lowest height). So
  Rugged sees the DSM, then a one-cell bilinear ramp from its edge nodes to
  ``fill``, then a flat surface at ``fill`` over the rest of the planet. A hit
  there is flagged ``inside=False`` (the contract's LEFT_DSM region).
* Tiles hold ``tile_size`` x ``tile_size`` nodes (fewer when the DSM plus its
  margin is smaller) and overlap their neighbours by one row / column. Tile
  (0, 0) starts ``margin`` nodes south-west of the DSM's first node, so a DSM
  of up to ``tile_size - 2*margin`` nodes each way lies in one tile with a
  ring of ``margin`` fill nodes around it.
* Longitudes: a tile is built around the longitude Rugged asks for, which may
  be below -180 deg or above 180 deg, so an extent crossing the antimeridian
  is seen whole. When a whole number K of columns makes a full turn
  (``K*dlon = 360`` to 1e-9), the lattice is periodic: node J is column
  ``J mod K``, a DSM column when below ``ncols`` (K = ncols: a global grid,
  with no fill in longitude). Otherwise the DSM copy nearest to the requested
  longitude (shifted by whole turns) is used, and tiles are kept narrower
  than half the gap between the DSM and its next copy.

Limitations of Rugged to keep in mind (its answers, reported as they are):

* ``intersection`` starts from the ray's point on the bare ellipsoid (h = 0):
  a ray that never descends to h = 0 (near-horizontal rays, rays pointing up)
  is an ERROR ("line-of-sight does not reach ground") even if it meets a
  building first; a ray starting below the surface is an ERROR ("enters the
  Digital Elevation Model behind spacecraft") -- Rugged's "inside" answer.
* It takes the maximum height of the tile under that ellipsoid point to find
  where the ray enters the terrain, and only raises it when that entry lies in
  another tile. A ray that crosses a taller tile before reaching that height
  over the lower one is not examined there. With one tile over the whole DSM
  plus ``margin`` this only concerns rays whose ellipsoid point lies more than
  ``margin`` cells outside the DSM.
* Nothing here bounds Rugged's own loops; no ray of the tests or the
  benchmark has stalled with overlapping tiles.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["RuggedDSM", "rugged_available", "jvm_startup_seconds",
           "HIT", "REFINE_NULL", "ERROR"]

HERE = Path(__file__).resolve().parent
JAVA_SOURCES = (HERE / "RuggedBatch.java",)
CLASS_NAME = "RuggedBatch"

#: status codes of :meth:`RuggedDSM.intersect` (same values as RuggedBatch.java)
HIT, REFINE_NULL, ERROR = 0, 1, 2
_NOUT = 10  # values per ray in the Java output array

_state: dict = {"cls": None, "startup": None}


# ----------------------------------------------------------------------------
# availability, compilation, JVM
# ----------------------------------------------------------------------------
def _jars_dir() -> Path:
    import orekit_jpype  # noqa: PLC0415

    return Path(orekit_jpype.__file__).resolve().parent / "jars"


def rugged_available() -> tuple[bool, str]:
    """Whether Rugged can be driven here.

    Returns
    -------
    (bool, str)
        ``(True, "")`` when a Java runtime, ``javac``, JPype and orekit-jpype
        (with its Rugged jar) are present and the Java helper compiles;
        otherwise ``(False, reason)`` with what is missing and how to get it.
    """
    if shutil.which("java") is None:
        return False, "no Java runtime: `java` is not on PATH (apt-get install default-jre-headless)"
    if shutil.which("javac") is None:
        return False, "no Java compiler: `javac` is not on PATH (apt-get install default-jdk-headless)"
    try:
        import jpype  # noqa: F401, PLC0415
    except ImportError as exc:
        return False, f"JPype is not installed (pip install jpype1): {exc}"
    try:
        jars = _jars_dir()
    except ImportError as exc:
        return False, f"orekit-jpype is not installed (pip install orekit-jpype): {exc}"
    if not any(jars.glob("rugged-*.jar")):
        return False, f"orekit-jpype has no Rugged jar in {jars}"
    try:
        _compile()
    except (OSError, RuntimeError) as exc:
        return False, f"the Java helper does not compile: {exc}"
    return True, ""


def _cache_root() -> Path:
    env = os.environ.get("PI_RUGGED_CACHE")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg else Path.home() / ".cache"
    return base / "planet-intersect" / "rugged"


def _compile() -> Path:
    """Compile the Java helper once per (source, jars, javac) into the cache; return its folder."""
    jars = _jars_dir()
    javac = shutil.which("javac")
    if javac is None:
        raise RuntimeError("javac is not on PATH")
    version = subprocess.run([javac, "-version"], capture_output=True, text=True, check=False)
    digest = hashlib.sha256()
    for src in JAVA_SOURCES:
        digest.update(src.read_bytes())
    for jar in sorted(jars.glob("*.jar")):
        digest.update(jar.name.encode())
    digest.update((version.stdout + version.stderr).encode())
    target = _cache_root() / digest.hexdigest()[:16]
    if (target / f"{CLASS_NAME}.class").is_file():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".build-", dir=target.parent))
    try:
        proc = subprocess.run(
            [javac, "-nowarn", "-cp", str(jars / "*"), "-d", str(tmp), *map(str, JAVA_SOURCES)],
            capture_output=True, text=True, check=False, timeout=300)
        if proc.returncode != 0:
            raise RuntimeError(f"javac failed on {[s.name for s in JAVA_SOURCES]}:\n{proc.stderr.strip()}")
        try:
            tmp.rename(target)  # atomic: a concurrent compiler may have won, which is fine
        except OSError:
            if not (target / f"{CLASS_NAME}.class").is_file():
                raise
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return target


def _batch_class():
    """The RuggedBatch Java class, starting the JVM (once per process) if needed."""
    if _state["cls"] is not None:
        return _state["cls"]
    ok, reason = rugged_available()
    if not ok:
        raise RuntimeError(f"Rugged is not available: {reason}")
    import jpype  # noqa: PLC0415
    import orekit_jpype  # noqa: PLC0415

    classes = _compile()
    t0 = time.perf_counter()
    if not jpype.isJVMStarted():
        orekit_jpype.initVM(additional_classpaths=[str(classes)])
        cls = jpype.JClass(CLASS_NAME)
    else:  # someone else started it: load the helper through its own class loader
        url = jpype.JClass("java.io.File")(str(classes)).toURI().toURL()
        loader = jpype.JClass("java.net.URLClassLoader")(
            jpype.JArray(jpype.JClass("java.net.URL"))([url]),
            jpype.JClass("java.lang.ClassLoader").getSystemClassLoader())
        try:
            cls = jpype.JClass(CLASS_NAME, loader=loader)
        except Exception as exc:  # noqa: BLE001
            raise RuntimeError("the JVM was started without the orekit-jpype jars; "
                               f"RuggedBatch cannot be loaded: {exc}") from exc
    _state["startup"] = time.perf_counter() - t0
    _state["cls"] = cls
    return cls


def jvm_startup_seconds() -> float | None:
    """Wall-clock seconds this process spent starting the JVM and loading RuggedBatch (None before)."""
    return _state["startup"]


def _jdoubles(a: np.ndarray):
    import jpype  # noqa: PLC0415

    return jpype.JArray(jpype.JDouble)(np.ascontiguousarray(a, dtype=np.float64).ravel())


# ----------------------------------------------------------------------------
# the surface
# ----------------------------------------------------------------------------
def _finite_scalar(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be a real number, got {value!r}") from exc
    if not np.isfinite(v):
        raise ValueError(f"{name} must be finite, got {v}")
    return v


def _rays(s, l):
    try:
        s = np.asarray(s, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"s must be an array of real numbers: {exc}") from exc
    try:
        l = np.asarray(l, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"l must be an array of real numbers: {exc}") from exc
    if s.ndim == 1:
        s = s[None, :]
    if l.ndim == 1:
        l = l[None, :]
    if s.ndim != 2 or s.shape[1] != 3:
        raise ValueError(f"s must have shape (N, 3) or (3,), got {np.shape(s)}")
    if l.ndim != 2 or l.shape[1] != 3:
        raise ValueError(f"l must have shape (N, 3) or (3,), got {np.shape(l)}")
    if l.shape[0] != s.shape[0]:
        if s.shape[0] == 1:
            s = np.broadcast_to(s, l.shape)
        elif l.shape[0] == 1:
            l = np.broadcast_to(l, s.shape)
        else:
            raise ValueError(f"s and l must hold the same number of rays, got {s.shape[0]} and {l.shape[0]}")
    if not np.all(np.isfinite(s)):
        raise ValueError(f"s has non-finite values (ray {int(np.argmin(np.isfinite(s).all(axis=1)))})")
    if not np.all(np.isfinite(l)):
        raise ValueError(f"l has non-finite values (ray {int(np.argmin(np.isfinite(l).all(axis=1)))})")
    norm = np.linalg.norm(l, axis=1)
    if np.any(norm == 0):
        raise ValueError(f"l has a zero direction (ray {int(np.argmin(norm))})")
    return np.ascontiguousarray(s), np.ascontiguousarray(l / norm[:, None])


class RuggedDSM:
    """A height grid handed to Rugged's Duvenhage algorithm.

    Parameters
    ----------
    heights : array_like, shape (nrows, ncols)
        Heights above the ellipsoid (units of ``a``, metres for Earth) at the
        pixel centres; finite (Rugged has no notion of no data).
        ``nrows, ncols >= 2``.
    lat_first, lon_first : float
        Geodetic latitude and east longitude of pixel centre (0, 0), degrees.
    dlat : float
        Latitude step between rows, degrees; negative for north-up grids.
    dlon : float
        Longitude step between columns, degrees, > 0; ``ncols*dlon <= 360``
        (exactly 360: periodic in longitude).
    a, f : float
        Semi-major axis (units of heights and rays) and flattening; WGS-84 by default.
    tile_size : int, optional
        Nodes per side of Rugged's tiles (>= 3). Default: the DSM plus its
        margin in one tile, at most 4097 nodes per side, and on a grid
        periodic in longitude at most half a turn plus one node (a tile wider
        than the period made Rugged spin forever on a ray near 180 degrees).
    margin : int, optional
        Fill nodes between tile (0, 0)'s south-west corner and the DSM (default 64).
    fill : float, optional
        Height Rugged sees at every node outside the DSM (default: the DSM's minimum).
    max_cached_tiles : int, optional
        Size of Rugged's tile cache (default 8).

    Notes
    -----
    Not thread-safe (Rugged's tile cache is shared): one batch at a time.
    """

    def __init__(self, heights, lat_first, lon_first, dlat, dlon,
                 a=6378137.0, f=1 / 298.257223563, tile_size=None, margin=64,
                 fill=None, max_cached_tiles=8):
        h = np.asarray(heights)
        if h.ndim != 2:
            raise ValueError(f"heights must be 2-D (nrows, ncols), got shape {h.shape}")
        if not np.issubdtype(h.dtype, np.number) or np.iscomplexobj(h):
            raise TypeError(f"heights must be real numbers, got dtype {h.dtype}")
        h = h.astype(np.float64)
        nrows, ncols = h.shape
        if nrows * ncols > 2**31 - 1:
            raise ValueError(f"heights has {nrows * ncols} values, more than a Java array holds (2**31 - 1)")
        if nrows < 2 or ncols < 2:
            raise ValueError(f"heights needs at least 2 rows and 2 columns for Rugged's bilinear cells, got {h.shape}")
        if not np.all(np.isfinite(h)):
            raise ValueError("heights has NaN or infinite values: Rugged has no no-data cells "
                             "(fill them before handing the grid to Rugged)")
        lat_first = _finite_scalar("lat_first", lat_first)
        lon_first = _finite_scalar("lon_first", lon_first)
        dlat = _finite_scalar("dlat", dlat)
        dlon = _finite_scalar("dlon", dlon)
        a = _finite_scalar("a", a)
        f = _finite_scalar("f", f)
        if dlat == 0:
            raise ValueError("dlat must not be 0")
        if dlon <= 0:
            raise ValueError(f"dlon must be > 0 (columns run east), got {dlon}")
        if a <= 0:
            raise ValueError(f"a must be > 0, got {a}")
        if not 0 <= f < 1:
            raise ValueError(f"f must be in [0, 1), got {f}")
        lat_last = lat_first + (nrows - 1) * dlat
        if not (-90 <= lat_first <= 90 and -90 <= lat_last <= 90):
            raise ValueError(f"the pixel centres' latitudes {lat_first} .. {lat_last} leave [-90, 90]")
        span = ncols * dlon
        if span > 360 * (1 + 1e-12):
            raise ValueError(f"ncols*dlon = {span} deg exceeds a full turn")
        wrap = abs(span - 360) <= 360e-12
        k = int(round(360.0 / dlon))
        period = k if abs(k * dlon - 360.0) <= 360e-9 and k >= ncols else 0
        if wrap:
            period = ncols
        margin = int(margin)
        if margin < 0:
            raise ValueError(f"margin must be >= 0, got {margin}")
        if tile_size is None:
            tile_size = min(max(nrows, ncols) + 2 * margin, 4097)
            if period:
                # a tile wider than the planet's period (ETOPO20: 1,208 columns for 1,080) made
                # Duvenhage spin forever on a ray hitting at 178.8 E; tiles of half a turn do not
                # (measured 2026-12-05, when the ETOPO20 grid first came in as global)
                tile_size = min(tile_size, period // 2 + 1)
        tile_size = int(tile_size)
        if tile_size < 3:
            raise ValueError(f"tile_size must be >= 3 nodes, got {tile_size}")
        max_cached_tiles = int(max_cached_tiles)
        if max_cached_tiles < 1:
            raise ValueError(f"max_cached_tiles must be >= 1, got {max_cached_tiles}")
        fill = float(h.min()) if fill is None else _finite_scalar("fill", fill)

        if dlat < 0:  # north-up: Rugged's rows run south to north
            h = h[::-1]
        self.nrows, self.ncols = nrows, ncols
        self.lat_south = min(lat_first, lat_last)
        self.lat_north = max(lat_first, lat_last)
        self.dlat_abs = abs(dlat)
        self.lon_west = (lon_first + 180.0) % 360.0 - 180.0
        self.dlon = dlon
        self.a, self.f = a, f
        self.fill = fill
        self.wrap = wrap
        self.period = period
        self.margin = margin
        rows = min(tile_size, nrows + 2 * margin)
        cols = min(tile_size, ncols + 2 * margin)
        if period == 0:  # a tile never reaches the next copy of the DSM around the planet
            room = int(np.floor((360.0 - span) / 2 / dlon)) + 1
            cols = max(3, min(cols, room))
        self.tile_rows, self.tile_cols = max(rows, 3), max(cols, 3)

        cls = _batch_class()
        self._heights_j = _jdoubles(h)
        self._java = cls(self._heights_j, nrows, ncols,
                         np.radians(self.lat_south), np.radians(self.lon_west),
                         np.radians(self.dlat_abs), np.radians(dlon), fill,
                         self.tile_rows, self.tile_cols, margin, period, a, f, max_cached_tiles)
        self.last_timing: dict | None = None

    # ------------------------------------------------------------------
    def inside(self, lat, lon) -> np.ndarray:
        """Whether (lat, lon) (degrees) lies on the rectangle spanned by the pixel centres."""
        lat = np.asarray(lat, dtype=np.float64)
        lon = np.asarray(lon, dtype=np.float64)
        eps_lat = 1e-9 * self.dlat_abs
        in_lat = (lat >= self.lat_south - eps_lat) & (lat <= self.lat_north + eps_lat)
        if self.wrap:
            return in_lat & np.isfinite(lon)
        x = (lon - self.lon_west) % 360.0
        x = np.where(x > 360.0 - 1e-9 * self.dlon, x - 360.0, x)
        return in_lat & (x >= -1e-9 * self.dlon) & (x <= (self.ncols - 1) * self.dlon * (1 + 1e-12) + 1e-9 * self.dlon)

    def intersect(self, s, l) -> dict:
        """Rugged's first hit of each ray, in one batch call into Java.

        Parameters
        ----------
        s : array_like, shape (N, 3) or (3,)
            Ray origins in the body-fixed (ECR) Cartesian frame of the ellipsoid, units of ``a``.
        l : array_like, shape (N, 3) or (3,)
            Ray directions in the same frame (normalised here).

        Returns
        -------
        dict
            ``hit`` (N,) bool: Rugged returned a refined point (``status == HIT``);
            ``status`` (N,) int: HIT (0), REFINE_NULL (1: ``refineIntersection``
            returned null), ERROR (2: Rugged threw; see ``message``);
            ``inside`` (N,) bool: the hit lies on the DSM's pixel-centre
            rectangle (False: on the fill outside it, or no hit);
            ``lat``, ``lon`` (N,) geodetic degrees, lon in [-180, 180);
            ``h`` (N,) height of the hit above the ellipsoid;
            ``p`` (N, 3) hit in ECR; ``r`` (N,) distance from ``s`` along ``l``;
            ``lat0``, ``lon0``, ``h0``: ``intersection()``'s point before refining;
            ``message``: list of N (str or None), Rugged's exception per ERROR ray.
            NaN where there is no value.
        """
        s, l = _rays(s, l)
        n = s.shape[0]
        if n == 0:
            e = np.empty(0)
            return {"hit": e.astype(bool), "status": e.astype(np.int32), "inside": e.astype(bool),
                    "lat": e, "lon": e, "h": e, "p": np.empty((0, 3)), "r": e,
                    "lat0": e, "lon0": e, "h0": e, "message": []}
        import jpype  # noqa: PLC0415

        out_j = jpype.JArray(jpype.JDouble)(_NOUT * n)
        self._java.intersect(_jdoubles(s), _jdoubles(l), out_j)
        out = np.array(out_j, dtype=np.float64).reshape(n, _NOUT)
        status = out[:, 0].astype(np.int32)
        hit = status == HIT
        lat = np.degrees(out[:, 1])
        lon = (np.degrees(out[:, 2]) + 180.0) % 360.0 - 180.0
        p = out[:, 4:7].copy()
        r = np.where(hit, np.einsum("ij,ij->i", p - s, l), np.nan)
        messages = [None] * n
        if np.any(status == ERROR):
            jm = self._java.getMessages()
            for k in np.flatnonzero(status == ERROR):
                messages[k] = str(jm[int(k)])
        return {"hit": hit, "status": status, "inside": hit & self.inside(lat, lon),
                "lat": lat, "lon": lon, "h": out[:, 3].copy(), "p": p, "r": r,
                "lat0": np.degrees(out[:, 7]),
                "lon0": (np.degrees(out[:, 8]) + 180.0) % 360.0 - 180.0,
                "h0": out[:, 9].copy(), "message": messages}

    def rays_per_second(self, s, l, warmup=3, repeats=5) -> float:
        """Rays per second of the Java batch loop alone, after JIT warm-up.

        The rays are copied into Java once; the loop then runs ``warmup``
        untimed times and ``repeats`` timed times (``System.nanoTime``); the
        result is N / median time. Details in ``self.last_timing``.
        """
        s, l = _rays(s, l)
        warmup, repeats = int(warmup), int(repeats)
        if warmup < 0 or repeats < 1:
            raise ValueError(f"warmup must be >= 0 and repeats >= 1, got {warmup}, {repeats}")
        n = s.shape[0]
        if n == 0:
            raise ValueError("s and l hold no ray to time")
        times = np.array(self._java.time(_jdoubles(s), _jdoubles(l), warmup, repeats), dtype=np.float64)
        med = float(np.median(times))
        self.last_timing = {"n": n, "warmup": warmup, "times": times, "median": med}
        return n / med

    def java_memory(self) -> dict:
        """JVM heap figures in bytes after a GC request: used, committed and max."""
        import jpype  # noqa: PLC0415

        rt = jpype.JClass("java.lang.Runtime").getRuntime()
        jpype.JClass("java.lang.System").gc()
        return {"used": int(rt.totalMemory() - rt.freeMemory()),
                "committed": int(rt.totalMemory()), "max": int(rt.maxMemory()),
                "tiles_built": int(self._java.getTilesBuilt())}
