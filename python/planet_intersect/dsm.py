"""Geodetic digital surface models and ray tracing over them (Shin & Park).

A :class:`GeodeticDSM` holds heights above a reference ellipsoid (WGS-84 by
default; any ``a``, ``f``) on a regular grid in geodetic latitude and east
longitude, pixel-centre registered (DESIGN.md section 8). :func:`intersect_dsm`
(reached through ``planet_intersect.intersect``) finds where rays meet it:

* ``"following"`` (default): Shin & Park's ray following, steps 1-5 and eqs. 1-5;
* ``"exact"``: the first entry into the surface to 1e-6 (units of ``a``) along
  the ray, never late, never a miss, with a max-pyramid built once per DSM;
* ``"iterative"``: the conventional iterative ray tracing the paper criticises.

Choices where the paper is ambiguous: ``docs/shin-park-notes.md``.
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from ._status import DSM_RAY_STATUS, DSMError, DSMStatus
from .geodetic import WGS84_A, WGS84_F, _wrap180, check_ellipsoid, ecef_to_geodetic
from .intersect import RayTable, document_fields

__all__ = ["GeodeticDSM", "DSMResult", "DSMError", "DSMStatus", "DSM_RAY_STATUS", "intersect_dsm"]

_INTERP = {"bilinear": 0, "nearest": 1}
_DSM_METHODS = {"following": 0, "exact": 1, "iterative": 2}


def _number(value, name: str) -> float:
    # (strings too: float("60") took wall_slope="60" while the sensors and the planetary DEM refuse
    # them, the simulation fuzzing, 2026-12-03: one rule for every argument)
    if isinstance(value, (bool, np.bool_, str, bytes)):
        raise DSMError(f"{name} must be a number, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise DSMError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v):
        raise DSMError(f"{name} must be finite, got {v}")
    return v


def _unmask(values, name: str, error=DSMError):
    """``values`` with a masked array's masked elements as NaN (float64); anything else
    unchanged. np.array and np.asarray drop the mask: reviews saw a masked -9999 become a
    9,999 m pit in a DSM and masked placeholders become brightness in an ortho-image.
    Used by GeodeticDSM.from_array and OrthoImage.from_array; ``error`` is raised for
    masked values that are not real numbers."""
    if not np.ma.isMaskedArray(values):
        return values
    if values.dtype.kind not in "fiub":
        raise error(f"{name}: must be real numbers, got dtype {values.dtype}")
    return values.astype(np.float64).filled(np.nan)


def _numeric(values, name: str):
    """``values`` as a NumPy array of real numbers (integers or floats), else DSMError naming
    ``name``: strings, bytes, booleans, dates, durations, complex numbers and ragged lists were
    taken (or crashed inside NumPy) where scalar arguments are refused (a review: '12.5' read as
    12.5 m, True as 1 m, a date as 18,262 m)."""
    try:
        arr = np.asarray(values)
    except (TypeError, ValueError) as exc:
        raise DSMError(f"{name}: not an array of numbers ({_short(exc)})") from None
    if arr.dtype.kind == "O":
        try:
            arr = np.asarray(values, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise DSMError(f"{name}: not an array of numbers ({_short(exc)})") from None
    if arr.dtype.kind not in "fiu":
        raise DSMError(f"{name}: must be real numbers (integers or floats), got dtype {arr.dtype}")
    return arr


def _nodata_cells(values: np.ndarray, nodata) -> np.ndarray:
    """Where ``values`` equal ``nodata``, compared also in the values' own float precision: a
    float32 raster's -999.9 is -999.9000244 in float64 and did not match nodata=-999.9, so no-data
    cells became -999.9 m pits (a review)."""
    cells = values == nodata
    if values.dtype.kind == "f" and values.dtype.itemsize < 8:
        with np.errstate(over="ignore", invalid="ignore"):
            own = np.asarray(nodata, dtype=np.float64).astype(values.dtype)
        if np.isfinite(own):
            cells |= values == own
    return cells


def _short(exc, limit: int = 300) -> str:
    """An exception's text cut to ``limit`` characters (PROJ's errors quote whole CRS definitions:
    2,334 characters of PROJJSON in one message, a review)."""
    s = " ".join(str(exc).split())
    return s if len(s) <= limit else s[:limit] + " ..."


def _file_nodata(nodata, file_nodata):
    """The no-data value of a raster being read: the caller's ``nodata``, else the
    file's tag, where a NaN tag (GDAL's usual) counts as none, NaN being no data
    already (GeodeticDSM.read and OrthoImage.read)."""
    if isinstance(nodata, float) and math.isnan(nodata):
        return None                      # nodata=NaN: only NaN marks no data (the file's tag is replaced)
    nd = nodata if nodata is not None else file_nodata
    if nodata is None and nd is not None and not math.isfinite(nd):
        return None
    return nd


class GeodeticDSM:
    """Heights above an ellipsoid on a regular geodetic latitude/longitude grid.

    Build with :meth:`from_array` or :meth:`read`. Attributes (read-only):
    ``heights`` (float64 ``[nrows, ncols]``, ellipsoidal heights with the geoid
    added, NaN where no data, a private read-only copy), ``lat_first``,
    ``lon_first``, ``dlat``, ``dlon`` (deg), ``nrows``, ``ncols``, ``a``, ``f``,
    ``interpolation``, ``hmax`` (H_max: the largest height, or the given bound),
    ``hmin``, ``nodata``, ``path`` (None in memory), ``resampling`` (how a
    projected raster was warped; None otherwise).

    Row ``i`` is at geodetic latitude ``lat_first + i*dlat`` (``dlat < 0``:
    north-up, the usual raster order; stored as given), column ``j`` at east
    longitude ``lon_first + j*dlon`` (``dlon > 0``); longitudes modulo 360, so
    an extent may cross the antimeridian.
    """

    def __init__(self):
        raise TypeError("use GeodeticDSM.from_array(...) or GeodeticDSM.read(path)")

    @classmethod
    def from_array(cls, heights, lat_first, lon_first, dlat, dlon, a: float = WGS84_A, f: float = WGS84_F,
                   nodata=None, geoid=None, interpolation: str = "bilinear", hmax=None) -> "GeodeticDSM":
        """A DSM from an array and its grid.

        Parameters
        ----------
        heights : array [nrows, ncols]
            Heights above the ellipsoid (or above the geoid with ``geoid``), units
            of ``a``. NaN or ``nodata`` marks no data; infinities are rejected.
        lat_first, lon_first : float
            Geodetic latitude / east longitude (deg) of the centre of row 0 / column 0.
        dlat, dlon : float
            Row and column spacing (deg); ``dlat`` non-zero (negative: north-up),
            ``dlon > 0``; ``ncols*dlon <= 360``.
        a, f : float
            Ellipsoid (WGS-84 by default; e.g. Mars's for areodetic heights).
        nodata : float, optional
            Value marking no data (besides NaN; NaN itself is accepted and adds nothing).
        geoid : float, array [nrows, ncols] or path, optional
            Geoid undulation N added to heights above the geoid: ``h = H + N``;
            a path is read with :meth:`read` and must have the same grid (a
            raster in the DSM file's own projected CRS and grid is warped as
            the DSM is); an array is on the DSM's geodetic grid (``dsm.shape``
            after a warp). Needed wherever there are heights.
        interpolation : "bilinear" or "nearest"
            Bilinear in (lat, lon) between pixel centres, or flat-topped cells
            with vertical walls (building DSMs).
        hmax : float, optional
            H_max for the ray start (Shin & Park step 1): at least the largest height.
        """
        self = object.__new__(cls)
        if isinstance(interpolation, str) is False or interpolation not in _INTERP:
            raise DSMError(f"interpolation must be 'bilinear' or 'nearest', got {interpolation!r}")
        heights = _numeric(_unmask(heights, "heights"), "heights")      # masked cells are no data
        h = np.array(heights, dtype=np.float64, copy=True)
        if h.ndim != 2:
            raise DSMError(f"heights must be 2-D [nrows, ncols], got shape {h.shape}")
        nmin = 2 if interpolation == "bilinear" else 1
        if h.shape[0] < nmin or h.shape[1] < nmin:
            raise DSMError(f"heights: {interpolation} interpolation needs at least {nmin} x {nmin} cells, "
                           f"got {h.shape}")
        if np.isinf(h).any():
            i, j = np.argwhere(np.isinf(h))[0]
            raise DSMError(f"heights[{i}, {j}] is infinite (use NaN or nodata for missing cells)")
        if isinstance(nodata, (float, np.floating)) and math.isnan(nodata):
            nodata = None                                      # NaN marks no data already
        if nodata is not None:
            nd = _number(nodata, "nodata")
            h[_nodata_cells(heights, nd)] = np.nan
            nodata = nd
        lat_first = _number(lat_first, "lat_first")
        lon_first = _number(lon_first, "lon_first")
        if abs(lon_first) >= 360.0:
            # reduced exactly (fmod is exact): radians of an unreduced 1e20 lost the grid (a review)
            lon_first = math.fmod(lon_first, 360.0)
        dlat = _number(dlat, "dlat")
        dlon = _number(dlon, "dlon")
        if dlat == 0:
            raise DSMError("dlat must be non-zero (negative for north-up rows)")
        if dlon <= 0:
            raise DSMError(f"dlon must be positive (columns go east), got {dlon}")
        for name, d in (("dlat", dlat), ("dlon", dlon)):
            if abs(d) < MIN_SPACING_DEG:
                # a grid coordinate is (angle - first) / spacing: with angles of ~100 degrees carried to
                # ~1e-14 degrees, a 1e-12 degree spacing put 0.1 % errors in the heights at pixel
                # centres, and 5e-324 (0 in radians) crashed the core (a review)
                raise DSMError(f"{name} = {d!r} degrees is below {MIN_SPACING_DEG:g} degrees (about 1 mm on "
                               f"the Earth): the grid coordinates of points would be lost to rounding")
        nrows, ncols = h.shape
        lat_last = lat_first + (nrows - 1) * dlat
        if not (-90.0 <= lat_first <= 90.0 and -90.0 <= lat_last <= 90.0):
            raise DSMError(f"lat_first, dlat: the latitudes of the pixel centres run from {lat_first} to "
                           f"{lat_last}: outside [-90, 90] degrees")
        if ncols * dlon > 360.0 * (1 + 1e-12):
            raise DSMError(f"ncols * dlon = {ncols * dlon} degrees exceeds 360")
        a, f = check_ellipsoid(a, f)
        if not DSM_A_MIN <= a <= DSM_A_MAX:
            # the search's tolerances are lengths (1e-6 along the ray: a micrometre in metres, a
            # millimetre in kilometres): in light years they were 9.5e9 m and hits came 670 m late;
            # in nanometres the search ran out of steps (a review)
            raise DSMError(f"a (semi-major axis) = {a:g}: a GeodeticDSM needs lengths in which 1e-6 is a "
                           f"fine tolerance along a ray, a in [{DSM_A_MIN:g}, {DSM_A_MAX:g}] (the Earth in "
                           f"kilometres, metres or millimetres)")
        geoid_name = "geoid"
        if isinstance(geoid, (str, os.PathLike)):            # a second raster on the same grid
            try:
                g = GeodeticDSM.read(geoid, a=a, f=f)
            except FileNotFoundError:
                # (the reader's own message said "DSM file ...": a review)
                raise FileNotFoundError(f"geoid file {geoid}: no such file") from None
            except DSMError as exc:
                # (the reader speaks of a "DSM file": here it is the geoid's, a review)
                raise DSMError(f"geoid: {str(exc).replace('DSM file', 'geoid file', 1)}") from None
            geoid_name = f"geoid raster {geoid}"
            if g.heights.shape != h.shape:
                raise DSMError(f"geoid raster {geoid}: its grid is {g.heights.shape[0]} x {g.heights.shape[1]} "
                               f"cells, the heights' {h.shape[0]} x {h.shape[1]}")
            tol = 1e-9 * max(abs(dlat), abs(dlon))
            for key, mine in (("lat_first", lat_first), ("lon_first", lon_first), ("dlat", dlat), ("dlon", dlon)):
                theirs = getattr(g, key)
                if not abs(theirs - mine) <= tol:
                    raise DSMError(f"geoid raster {geoid}: its grid differs from the heights' grid: {key} = "
                                   f"{theirs!r} degrees against {mine!r}")
            geoid = np.asarray(g.heights)
        if geoid is not None:
            if isinstance(geoid, (bool, np.bool_, str, bytes)):
                raise DSMError(f"geoid must be a number, an array or a raster's path, got {geoid!r}")
            # masked cells are NaN (np.asarray dropped the mask, and a masked -9999 was added as an
            # undulation, a review); then real numbers only
            n_ = np.asarray(_numeric(_unmask(geoid, "geoid"), "geoid"), dtype=np.float64)
            if n_.ndim not in (0, 2) or (n_.ndim == 2 and n_.shape != h.shape):
                raise DSMError(f"geoid must be a scalar or an array shaped like heights {h.shape}, got {n_.shape}")
            # needed where there are heights; no-data cells may have none (a geoid raster warped
            # with its UTM DSM has the same no-data corners: a walk-through saw it refused)
            badg = ~np.isfinite(np.broadcast_to(n_, h.shape)) & ~np.isnan(h)
            if badg.any():
                bad = np.argwhere(badg)[0]
                raise DSMError(f"{geoid_name} has NaN, Inf or no-data values where there are heights (first "
                               f"at row {bad[0]}, column {bad[1]}): the undulation is needed at every such cell")
            with np.errstate(over="ignore"):
                hn = h + n_
            if (np.isinf(hn) & np.isfinite(h)).any():
                i, j = np.argwhere(np.isinf(hn) & np.isfinite(h))[0]
                raise DSMError(f"heights + geoid overflows at row {i}, column {j} ({h[i, j]!r} + "
                               f"{np.broadcast_to(n_, h.shape)[i, j]!r})")
            h = hn
        data = np.isfinite(h)
        if not data.any():
            raise DSMError("heights: every cell is no-data")
        deep = data.copy()
        deep[data] = h[data] <= -a * (1.0 - f)
        if deep.any():
            # at or below minus the polar radius a height lies beyond the body's centre: a DSM
            # at -7e6 m on the Earth was accepted and the following stepped to the far side and
            # reported a hit there (a review). (Relief down to -0.88 b on a 13 km body is
            # supported and tested: test_dsm_edge_rays.py.)
            i, j = np.argwhere(deep)[0]
            raise DSMError(f"heights[{i}, {j}] = {float(h[i, j])!r} is at or below minus the polar radius "
                           f"({a * (1.0 - f):g}): beyond the body's centre")
        hmax_grid = float(np.max(h[data]))
        hmin = float(np.min(h[data]))
        if hmax is None:
            hmax = hmax_grid
        else:
            hmax = _number(hmax, "hmax")
            if hmax < hmax_grid:
                raise DSMError(f"hmax = {hmax} is below the largest height {hmax_grid}")
        h.flags.writeable = False
        self._h = h
        self._lat_first, self._lon_first, self._dlat, self._dlon = lat_first, lon_first, dlat, dlon
        self._a, self._f = a, f
        self._interp = interpolation
        self._hmax, self._hmin = float(hmax), hmin
        self._nodata = nodata
        self._pyramid = None
        self.path = None
        #: bands in the file read (1 for arrays and .npz); the CLI refuses a multi-band DSM file
        self.file_bands = 1
        self.resampling = None
        self.crs = None
        return self

    # ---- read-only attributes
    heights = property(lambda self: self._h, doc="heights above the ellipsoid [nrows, ncols] (read-only copy)")
    lat_first = property(lambda self: self._lat_first)
    lon_first = property(lambda self: self._lon_first)
    dlat = property(lambda self: self._dlat)
    dlon = property(lambda self: self._dlon)
    a = property(lambda self: self._a)
    f = property(lambda self: self._f)
    interpolation = property(lambda self: self._interp)
    hmax = property(lambda self: self._hmax, doc="H_max of Shin & Park step 1")
    hmin = property(lambda self: self._hmin)
    nodata = property(lambda self: self._nodata)
    nrows = property(lambda self: self._h.shape[0])
    ncols = property(lambda self: self._h.shape[1])
    shape = property(lambda self: self._h.shape, doc="(nrows, ncols), as an OrthoImage's")

    @property
    def lats(self) -> np.ndarray:
        """Row-centre latitudes (deg)."""
        return self._lat_first + np.arange(self.nrows) * self._dlat

    @property
    def lons(self) -> np.ndarray:
        """Column-centre longitudes (deg, [-180, 180))."""
        return _wrap180(self._lon_first + np.arange(self.ncols) * self._dlon)

    def __repr__(self) -> str:
        return (f"GeodeticDSM({self.nrows} x {self.ncols}, lat {self._lat_first}{self._dlat:+g}/row, "
                f"lon {self._lon_first}{self._dlon:+g}/col, {self._interp}, a={self._a}, f={self._f})")

    def with_interpolation(self, interpolation: str) -> "GeodeticDSM":
        """The same grid with another interpolation (shares the heights)."""
        if not isinstance(interpolation, str) or interpolation not in _INTERP:
            raise DSMError(f"interpolation must be 'bilinear' or 'nearest', got {interpolation!r}")
        if interpolation == "bilinear" and (self.nrows < 2 or self.ncols < 2):
            raise DSMError(f"interpolation: bilinear interpolation needs at least 2 x 2 cells, "
                           f"this grid has {self._h.shape}")
        new = object.__new__(type(self))
        new.__dict__.update(self.__dict__)
        new._interp = interpolation
        if new._core_heights().shape != self._core_heights().shape:
            new._pyramid = None                           # a global grid's seam column comes or goes
        return new

    def _core_heights(self) -> np.ndarray:
        """The heights the core works on: the grid itself, except a global bilinear one (its columns
        cover 360 degrees), which gets its first column repeated after the last, so that the cell
        across the seam is interpolated between its last and first columns (the core's surface is
        bilinear between nodes: it had no surface there, and every ray into that strip was LEFT_DSM;
        a review). The core knows such a grid by its span (fortran/pi_dsm.f90, dsm_box_bound)."""
        if self._interp == "bilinear" and self.ncols * self._dlon >= 360.0 * (1.0 - 1e-12):
            ch = self.__dict__.get("_ch")
            if ch is None or ch.shape[1] != self.ncols + 1:
                ch = np.concatenate([self._h, self._h[:, :1]], axis=1)
                ch.flags.writeable = False
                self._ch = ch
            return ch
        return self._h

    def _core_grid(self):
        return (self._core_heights().T, math.radians(self._lat_first), math.radians(self._lon_first),
                math.radians(self._dlat), math.radians(self._dlon), self._a, self._f, _INTERP[self._interp])

    def height(self, lat, lon) -> np.ndarray:
        """Surface height H at geodetic (lat, lon) in degrees (NaN outside or over no-data)."""
        from ._ext import core as _core

        try:
            lat, lon = np.broadcast_arrays(np.asarray(lat, dtype=np.float64), np.asarray(lon, dtype=np.float64))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"lat, lon: expected numbers (degrees) that broadcast ({exc})") from None
        shape = lat.shape
        if lat.size == 0:
            return np.zeros(shape)
        hs, code = _core.core_dsm_height(*self._core_grid(), np.radians(lat).ravel(), np.radians(lon).ravel())
        hs = hs.reshape(shape)
        return hs if shape else float(hs)

    def pyramid(self) -> tuple[np.ndarray, np.ndarray]:
        """The max-pyramid of the exact mode, built once and kept with the DSM.

        Level k >= 1 holds the largest height of each 2^k x 2^k block of cells
        (no-data counts as +huge so that the search always looks at it). Returns
        ``(data, meta)``: the levels packed in one float64 array (row-major), and
        ``meta[k-1] = (rows, cols, offset)``.
        """
        if self._pyramid is not None:
            return self._pyramid
        big = np.finfo(np.float64).max
        hc = self._core_heights()
        level = np.where(np.isnan(hc), big, hc)
        parts, meta, off = [], [], 0
        while True:
            r, c = level.shape
            pr, pc = (r + 1) // 2, (c + 1) // 2
            padded = np.full((2 * pr, 2 * pc), -big)
            padded[:r, :c] = level
            level = padded.reshape(pr, 2, pc, 2).max(axis=(1, 3))
            parts.append(level.ravel())
            meta.append((pr, pc, off))
            off += level.size
            if pr == 1 and pc == 1:
                break
        data = np.concatenate(parts)
        data.flags.writeable = False
        self._pyramid = (data, np.array(meta, dtype=np.int32))
        return self._pyramid

    # ---- readers
    @classmethod
    def read(cls, path, band: int | None = None, nodata=None, geoid=None, interpolation: str | None = None,
             resampling: str = "nearest", a: float = WGS84_A, f: float = WGS84_F, hmax=None) -> "GeodeticDSM":
        """Read a DSM from a GeoTIFF (rasterio, extra ``geo``) or an ``.npz``.

        GeoTIFF in a geographic CRS: read as it is (pixel centres from the
        affine transform, which must be axis-aligned). In a projected CRS (UTM
        LiDAR DSMs...): warped to a geodetic grid of about the same resolution
        with ``resampling`` ("nearest" by default so that building edges stay
        sharp; "bilinear" also allowed), recorded in ``dsm.resampling``.
        ``nodata`` defaults to the file's own tag; a value given replaces the
        tag (``nodata=nan``: only NaN marks no data). An untagged band whose
        lowest value is a usual void (-9999, -99999, -32767, -32768, <= -1e30)
        is refused until ``nodata`` says what it is. A compound CRS whose
        vertical part is a geoid height (NAVD88...) is read as ellipsoidal
        heights with a warning unless ``geoid`` is given; a vertical unit in
        feet is converted to metres. ``interpolation`` defaults to
        "nearest" for a warped raster, else "bilinear".

        ``band``: the band to read (default 1; a file with more bands then
        warns). Cells that the file's own mask band or alpha band marks
        invalid are no data, as are cells of its nodata tag.

        ``.npz``: arrays ``heights`` and scalars ``lat_first``, ``lon_first``,
        ``dlat``, ``dlon`` (optional ``a``, ``f``, ``nodata``, ``interpolation``).

        The file is only read, never written.
        """
        if not isinstance(path, (str, os.PathLike)):
            raise DSMError(f"path must be a file's path (str or pathlib.Path), got {type(path).__name__} {path!r}")
        path = Path(path)
        if path.is_dir():
            raise DSMError(f"DSM file {path}: is a directory, not a raster or .npz file")
        if not path.is_file():
            raise FileNotFoundError(f"DSM file {path}: no such file")
        if band is not None and (isinstance(band, (bool, np.bool_)) or not isinstance(band, (int, np.integer))):
            raise DSMError(f"band must be a whole number (1 for the first band), got {band!r}")
        if path.suffix.lower() == ".npz":
            if band not in (None, 1):
                raise DSMError(f"band = {band}: a .npz DSM ({path}) has one band")
            return cls._read_npz(path, nodata, geoid, interpolation, a, f, hmax)
        return cls._read_raster(path, band, nodata, geoid, interpolation, resampling, a, f, hmax)

    @classmethod
    def _read_npz(cls, path, nodata, geoid, interpolation, a, f, hmax):
        d = _npz_arrays(path, ("heights", "lat_first", "lon_first", "dlat", "dlon"), "DSM file", DSMError,
                        hint=" (need heights, lat_first, lon_first, dlat, dlon)")
        interp = interpolation or (str(d["interpolation"]) if "interpolation" in d else "bilinear")
        for key in ("lat_first", "lon_first", "dlat", "dlon", "a", "f", "nodata"):
            if key in d and np.ndim(d[key]) != 0:
                raise DSMError(f"DSM file {path}: {key} must be a single number, got an array of shape "
                               f"{np.shape(d[key])}")
            if key in d and d[key].dtype.kind not in "fiu":
                # (a string '10' was read as 10 degrees, a review)
                raise DSMError(f"DSM file {path}: {key} must be a number, got {d[key]!r} (dtype {d[key].dtype})")
        try:
            dsm = cls.from_array(d["heights"], float(d["lat_first"]), float(d["lon_first"]), float(d["dlat"]),
                                 float(d["dlon"]), a=float(d.get("a", a)), f=float(d.get("f", f)),
                                 nodata=nodata if nodata is not None else (float(d["nodata"]) if "nodata" in d else None),
                                 geoid=geoid, interpolation=interp, hmax=hmax)
        except (DSMError, ValueError, TypeError) as exc:
            raise DSMError(f"DSM file {path}: {exc}") from None
        dsm.path = path
        return dsm

    @classmethod
    def _read_raster(cls, path, band, nodata, geoid, interpolation, resampling, a, f, hmax):
        try:
            import rasterio
            from rasterio.warp import Resampling, reproject
        except ImportError:
            raise ImportError(f"reading {path} needs rasterio: pip install 'planet-intersect[geo]'") from None
        if resampling not in ("nearest", "bilinear"):
            raise DSMError(f"DSM file {path}: resampling must be 'nearest' or 'bilinear', got {resampling!r}")
        try:
            src = rasterio.open(path)
        except Exception as exc:  # noqa: BLE001
            raise DSMError(f"DSM file {path}: cannot be opened as a raster ({exc})") from None
        with src:
            if band is None:
                band = 1
                if src.count > 1:
                    warnings.warn(f"DSM file {path}: has {src.count} bands; band 1 is read (pass band= to "
                                  f"choose another)", UserWarning, stacklevel=3)
            if not (1 <= band <= src.count):
                raise DSMError(f"DSM file {path}: band {band} does not exist (the file has {src.count})")
            nd = _file_nodata(nodata, src.nodata)
            file_bands = int(src.count)
            raw, invalid = _read_bands(src, int(band), path, "DSM", DSMError)   # once: the branches convert it
            if nd is None and raw.dtype == np.int16 and raw[~invalid].size and int(raw[~invalid].min()) == -32768:
                # the usual void of int16 DEMs (SRTM): read as 32.8 km pits (a review); the planetary
                # reader refuses -32768 as well
                raise DSMError(f"DSM file {path}: band {band} is int16 and holds -32768, the usual void value, "
                               f"but has no nodata tag: pass nodata=-32768 (or another value) to read it")
            untagged = nodata is None and (src.nodata is None or not math.isfinite(src.nodata))
            if untagged and raw.size and raw.dtype.kind in "fi":
                # the other usual voids, untagged: a float -9999 was read as a 9,999 m pit and every
                # method hit it (a walk-through)
                values = raw[~invalid & ~np.isnan(raw)] if raw.dtype.kind == "f" else raw[~invalid]
                lowest = float(values.min()) if values.size else math.nan
                if lowest in _VOID_VALUES or lowest <= -1e30:
                    raise DSMError(f"DSM file {path}: band {band} holds {lowest:g}, a usual no-data value, but "
                                   f"has no nodata tag: pass nodata={lowest:g} to read those cells as no data "
                                   f"(or nodata=<a value not in the file> to read them as heights)")
            warped = None
            void = invalid if nd is None else (invalid | _nodata_cells(raw, nd))
            if src.crs.is_geographic and _geographic_datum(src.crs, src.bounds, path, "DSM", a, f) == "as-is":
                t = src.transform
                if t.b != 0 or t.d != 0:
                    raise DSMError(f"DSM file {path}: rotated or sheared pixel grid is not supported")
                heights = raw.astype(np.float64)
                heights[void] = np.nan
                dlon, dlat = t.a, t.e
                lon_first = t.c + 0.5 * t.a
                lat_first = t.f + 0.5 * t.e
                crs = src.crs
            else:
                dst_crs, tr, w, hgt = _geodetic_grid(src, path, "DSM", DSMError, a, f)
                heights = np.full((hgt, w), np.nan)
                srcdata = raw.astype(np.float64)
                srcdata[void] = np.nan
                reproject(srcdata, heights, src_transform=src.transform, src_crs=src.crs, src_nodata=np.nan,
                          dst_transform=tr, dst_crs=dst_crs, dst_nodata=np.nan,
                          resampling=getattr(Resampling, resampling))
                nd = None
                dlon, dlat = tr.a, tr.e
                lon_first = tr.c + 0.5 * tr.a
                lat_first = tr.f + 0.5 * tr.e
                warped = resampling
                crs = src.crs
        heights = _vertical_datum(crs, path, heights, geoid, a, nd)
        interp = interpolation or ("nearest" if warped else "bilinear")
        try:
            dsm = cls.from_array(heights, lat_first, lon_first, dlat, dlon, a=a, f=f, nodata=nd, geoid=geoid,
                                 interpolation=interp, hmax=hmax)
        except DSMError as exc:
            raise DSMError(f"DSM file {path}: {exc}") from None
        dsm.path = path
        dsm.resampling = warped
        dsm.crs = str(crs)
        dsm.file_bands = file_bands
        return dsm


def _read_bands(src, bands, path, what: str, error):
    """(values, invalid) of a raster's band (an int: 2-D) or bands (a list: 3-D), invalid where its
    mask or alpha band says so (_mask_band); ``error`` naming the file when they cannot be read, when
    it has no CRS or when its values are not real numbers. Read before anything else is judged: a
    truncated file raised rasterio's bare "Read failed" naming neither file nor problem, or was said
    to have no CRS (a review). Shared by GeodeticDSM.read and OrthoImage.read."""
    label = f"band {bands} " if isinstance(bands, int) else ""
    try:
        values = src.read(bands)
        invalid = _mask_band(src, bands) if isinstance(bands, int) else np.stack([_mask_band(src, b) for b in bands])
    except Exception as exc:  # noqa: BLE001
        raise error(f"{what} file {path}: {label}cannot be read (truncated or corrupt?): {_short(exc)}") from None
    if src.crs is None:
        raise error(f"{what} file {path}: no CRS (a geographic or projected CRS is needed)")
    if values.dtype.kind not in "fiu":
        raise error(f"{what} file {path}: {label}holds {values.dtype} values, not real numbers")
    return values, invalid


def _mask_band(src, band: int) -> np.ndarray:
    """Cells of ``band`` that the raster's own mask band or alpha band marks invalid (GDAL's
    per-dataset mask, an internal ``.msk`` or an alpha band): True there. A nodata tag is not
    read here (``_file_nodata`` decides it, the caller may replace it). Such cells were read as
    heights of 0 m (a review)."""
    from rasterio.enums import MaskFlags

    flags = src.mask_flag_enums[band - 1]
    if MaskFlags.per_dataset in flags or MaskFlags.alpha in flags:
        return src.read_masks(band) == 0
    return np.zeros((src.height, src.width), dtype=bool)


def _crs_body(c, path, what: str, a, f, error) -> tuple[float, float, bool, bool]:
    """The body of a raster's CRS ``c`` (pyproj) against the target ellipsoid ``a``, ``f`` (the DSM's;
    None: an ortho-image, whose body simulate_image checks): ``(ca, cf, earth, wgs84)``, the CRS's
    semi-major axis (m) and flattening, whether it is an Earth datum, and whether the grid is to be
    WGS-84's (an Earth datum and a WGS-84 or no target); otherwise the CRS's own geodetic CRS is the
    target. ``error`` naming the file for a CRS without an ellipsoid, for an Earth datum with another
    body's (or unit's) a, f, and for another body's CRS with an ellipsoid other than a, f."""
    ell = c.ellipsoid
    if ell is None or c.geodetic_crs is None:
        raise error(f"{what} file {path}: its CRS ({c.name}) is not tied to an ellipsoid (an engineering or "
                    f"local CRS): it cannot be placed on a body")
    ca = ell.semi_major_metre
    cf = 0.0 if not ell.inverse_flattening else 1.0 / ell.inverse_flattening
    earth = abs(ca - WGS84_A) <= 0.01 * WGS84_A
    if a is None:
        return ca, cf, earth, earth
    if earth and math.isclose(a, WGS84_A, rel_tol=1e-12) and math.isclose(f, WGS84_F, rel_tol=1e-9):
        return ca, cf, True, True
    if math.isclose(ca, a, rel_tol=1e-9) and math.isclose(cf, f, rel_tol=1e-9, abs_tol=1e-12):
        return ca, cf, earth, False                        # the caller's own ellipsoid, the CRS's
    if earth:
        raise error(f"{what} file {path}: its CRS ({c.name}, a = {ca:.10g}) is an Earth datum, but "
                    f"a = {a:.10g}, f = {f:.10g} was asked for")
    raise error(f"{what} file {path}: its CRS ({c.name}) is on the ellipsoid a = {ca:.10g}, "
                f"f = {cf:.10g}, not a = {a:.10g}, f = {f:.10g}: pass that body's a= and f=")


def _geodetic_grid(src, path, what: str, error, a=None, f=None):
    """The geodetic grid a raster ``src`` (rasterio, projected or another datum) is warped to:
    ``(dst_crs, transform, width, height)``.

    Target CRS: WGS-84 (EPSG:4326) for a raster on an Earth datum; for a raster on another body,
    that body's own geographic CRS (it was always EPSG:4326: a Mars equirectangular DTM failed with
    2,334 characters of PROJJSON, a review). ``a``, ``f`` (the DSM's ellipsoid; None: an
    ortho-image, WGS-84 as before) must be the target's: a UTM raster was taken as Mars, or as the
    Earth in kilometres with 49 m buildings 49 km tall, where the geographic reader refuses (a review).

    Cells: the source's pixel size on the ground at the raster's centre (its projected size over
    the projection's scale factors there), north-south and east-west separately (rasterio's
    default grid has square cells in degrees: at 72 N a 2 m raster became 5.1 m north-south, and
    one-pixel walls vanished, a review); for a raster in degrees, rasterio's default. A raster
    across the antimeridian has, in EPSG:4326, a grid spanning -180..180 with
    zero rows (a 300 m UTM tile at 180 E crashed rasterio: a walk-through); the same datum with
    longitudes in [0, 360) keeps it whole, and GeodeticDSM and OrthoImage take grids that cross the
    antimeridian. Any failure is ``error`` naming the file."""
    import pyproj
    from rasterio.crs import CRS
    from rasterio.warp import calculate_default_transform

    try:
        c = pyproj.CRS.from_user_input(src.crs.to_wkt())
    except Exception as exc:  # noqa: BLE001
        raise error(f"{what} file {path}: its CRS cannot be used ({_short(exc)})") from None
    ca, cf, _, wgs84 = _crs_body(c, path, what, a, f, error)
    if wgs84:
        dst_crs, wrap = "EPSG:4326", "+proj=longlat +datum=WGS84 +lon_wrap=180 +no_defs"
    else:
        dst_crs = CRS.from_wkt(c.geodetic_crs.to_wkt())
        wrap = f"+proj=longlat +a={ca!r} +rf={1.0 / cf!r} +lon_wrap=180 +no_defs" if cf else \
            f"+proj=longlat +R={ca!r} +lon_wrap=180 +no_defs"
    res = None
    if c.is_projected:
        # the source's pixel in metres (its unit: feet...), as degrees of latitude and longitude at
        # the raster's centre (the meridian and prime-vertical radii of its ellipsoid)
        try:
            unit = c.axis_info[0].unit_conversion_factor if c.axis_info else 1.0
            to_geo = pyproj.Transformer.from_crs(c, c.geodetic_crs, always_xy=True)
            xc = 0.5 * (src.bounds.left + src.bounds.right)
            yc = 0.5 * (src.bounds.bottom + src.bounds.top)
            lon_c, lat_c = to_geo.transform(xc, yc)
        except Exception:  # noqa: BLE001  (then rasterio's default grid below)
            lat_c = math.nan
        if math.isfinite(lat_c) and abs(lat_c) < 89.99:
            e2 = cf * (2.0 - cf)
            s2 = math.sin(math.radians(lat_c)) ** 2
            m_rad = ca * (1.0 - e2) / (1.0 - e2 * s2) ** 1.5
            n_rad = ca / math.sqrt(1.0 - e2 * s2)
            px, py = abs(src.transform.a) * unit, abs(src.transform.e) * unit
            try:
                # the projection's own scale there: a Web Mercator pixel of 10 units is 6.43 m on the
                # ground at 50 N, and the grid came out 2.4 times coarser than the source (a review)
                fac = pyproj.Proj(c).get_factors(lon_c, lat_c)
                ks, km = float(fac.parallel_scale), float(fac.meridional_scale)
                if math.isfinite(ks) and math.isfinite(km) and ks > 0 and km > 0:
                    px, py = px / ks, py / km
            except Exception:  # noqa: BLE001  (no factors: the pixel's size in projected units)
                pass
            if px > 0 and py > 0:
                res = (math.degrees(px / (n_rad * math.cos(math.radians(lat_c)))), math.degrees(py / m_rad))
    try:
        kw = {"resolution": res} if res else {}
        tr, w, hgt = calculate_default_transform(src.crs, dst_crs, src.width, src.height, *src.bounds, **kw)
        if w == 0 or hgt == 0 or w * abs(tr.a) > 180.0:
            dst_crs = wrap
            tr, w, hgt = calculate_default_transform(src.crs, dst_crs, src.width, src.height, *src.bounds, **kw)
        if w == 0 or hgt == 0:
            raise ValueError(f"the geodetic grid has {hgt} x {w} cells")
    except Exception as exc:  # noqa: BLE001
        raise error(f"{what} file {path}: cannot be warped to a geodetic grid ({_short(exc)}); a raster that "
                    f"contains or nearly reaches a pole cannot be put on a latitude/longitude grid: crop it "
                    f"away from the pole") from None
    if w * hgt > 16 * max(src.width * src.height, 1) + 1_000_000:
        raise error(f"{what} file {path}: its geodetic grid would have {hgt} x {w} cells for "
                    f"{src.height} x {src.width} pixels (a raster reaching near a pole): crop it away "
                    f"from the pole")
    return dst_crs, tr, w, hgt


#: untagged values read as no-data only when the caller says so (GeodeticDSM.read refuses them)
_VOID_VALUES = (-9999.0, -99999.0, -32767.0, -32768.0)


def _vertical_datum(crs, path, heights: np.ndarray, geoid, a: float, nodata=None) -> np.ndarray:
    """The heights of a raster read in ``crs``, with what its CRS says of them applied or said.

    * A compound CRS with a vertical part (e.g. "UTM 14N + NAVD88 height") states heights above
      a geoid or a vertical datum, not the ellipsoid: without ``geoid`` a UserWarning says so
      (they are read as ellipsoidal heights, ~25 m off in Kansas; a walk-through saw no word of
      it). A vertical unit other than the metre (a foot) is converted to metres when the DSM is
      in metres (``a`` of the Earth in metres), else said.
    * A projected CRS whose unit is not the metre (a State Plane grid in US feet) says nothing of
      the heights' unit: a UserWarning that they are taken as the DSM's unit (metres).
    """
    import pyproj

    try:
        c = pyproj.CRS.from_user_input(crs.to_wkt())
    except Exception:  # noqa: BLE001  (the warp has already used the CRS: nothing more to say)
        return heights
    vert = [sc for sc in c.sub_crs_list if sc.is_vertical] if c.is_compound else []
    metres = abs(a - WGS84_A) < 0.01 * WGS84_A
    if vert:
        v = vert[0]
        unit = v.axis_info[0].unit_name if v.axis_info else "metre"
        factor = v.axis_info[0].unit_conversion_factor if v.axis_info else 1.0
        if geoid is None:
            warnings.warn(f"DSM file {path}: its CRS gives the heights as '{v.name}' (above a geoid or a "
                          f"vertical datum, not the ellipsoid); they are read as heights above the ellipsoid: "
                          f"pass geoid= (the undulation N) to make them ellipsoidal", UserWarning, stacklevel=4)
        if factor != 1.0:
            if metres:                                 # (cells of the nodata value stay as they are)
                heights = np.where(heights == nodata, heights, heights * factor) if nodata is not None \
                    else heights * factor
            else:
                warnings.warn(f"DSM file {path}: its heights are in {unit} ('{v.name}'); they are read "
                              f"unconverted in the unit of a = {a:g}", UserWarning, stacklevel=4)
    elif c.is_projected and c.axis_info and c.axis_info[0].unit_conversion_factor != 1.0:
        warnings.warn(f"DSM file {path}: its CRS ({c.name}) is in {c.axis_info[0].unit_name}, and says "
                      f"nothing of the heights' unit: they are read as metres", UserWarning, stacklevel=4)
    return heights


def _geographic_datum(crs, bounds, path, what: str, a=None, f=None) -> str:
    """How to read a raster in the geographic CRS ``crs``: "as-is" (its latitudes and longitudes
    are the target's), or "warp" (an Earth datum other than WGS-84 that moves the raster's centre by
    more than 1 cm: warped to EPSG:4326 like a projected raster; a review saw a Tokyo-datum raster
    taken as WGS-84, 359 m south and 292 m east of its place). ``a``, ``f``: the target ellipsoid
    (the DSM's; None for an ortho-image, whose datum must be the DSM's): a raster on another body
    must be on it, else DSMError naming the file and its CRS. The heights are not changed:
    they stay above the geoid (``geoid=``) or the ellipsoid they were given on."""
    import pyproj

    c = pyproj.CRS.from_user_input(crs.to_wkt())
    ca, cf, _, wgs84 = _crs_body(c, path, what, a, f, DSMError)
    if not wgs84:                                          # another body, or the caller's own datum
        return "as-is"
    lon_c = 0.5 * (bounds.left + bounds.right)
    lat_c = min(89.0, max(-89.0, 0.5 * (bounds.bottom + bounds.top)))
    try:
        tr = pyproj.Transformer.from_crs(c, pyproj.CRS("EPSG:4326"), always_xy=True)
        lon2, lat2 = tr.transform(lon_c, lat_c)
    except Exception as exc:  # noqa: BLE001
        raise DSMError(f"{what} file {path}: no transformation from its CRS ({c.name}) to WGS-84 ({exc})") from None
    if not (math.isfinite(lon2) and math.isfinite(lat2)):
        raise DSMError(f"{what} file {path}: no transformation from its CRS ({c.name}) to WGS-84")
    shift = math.hypot((lat2 - lat_c) * 111_320.0, (lon2 - lon_c) * 111_320.0 * math.cos(math.radians(lat_c)))
    if shift <= 0.01 and cf == 0.0:
        # PROJ has no datum shift from an Earth-sized sphere (a "ballpark" transformation): its
        # latitudes are taken as WGS-84's, which they usually are; if they are spherical
        # (geocentric) ones they are up to 0.19 deg off (a walk-through saw it taken silently)
        warnings.warn(f"{what} file {path}: its CRS ({c.name}) is on a sphere of radius {ca:.10g} m; its "
                      f"latitudes and longitudes are read as WGS-84 geodetic ones", UserWarning, stacklevel=4)
    return "warp" if shift > 0.01 else "as-is"


@dataclass
class DSMResult(RayTable):
    """Per-ray results of ``intersect(dsm, ...)``; arrays of length N, vectors (N, 3).

    Angles in degrees (latitudes geodetic, longitudes in [-180, 180)), lengths
    in the DSM's units; NaN where a quantity does not apply.
    """

    hit: np.ndarray  #: True where the ray meets the surface (HIT or HIT_UNCONVERGED)
    p: np.ndarray  #: hit point, ECR
    lat: np.ndarray  #: geodetic latitude of p
    lon: np.ndarray  #: east longitude of p
    height: np.ndarray  #: exact geodetic height of p above the ellipsoid
    surface_height: np.ndarray  #: DSM height H at (lat, lon) of p (= height except on walls of "nearest" and where a low ray enters the grid through its edge)
    distance: np.ndarray  #: r, distance from s along the unit ray
    incidence: np.ndarray  #: angle between -l and the ellipsoid normal at p (0 = vertical view)
    status: np.ndarray  #: per-ray code, see :class:`DSMStatus`
    nsteps: np.ndarray  #: ray points evaluated
    event_p: np.ndarray  #: NO_DATA / LEFT_DSM: first low point over no-data or outside the DSM, ECR
    event_lat: np.ndarray  #: geodetic latitude of event_p
    event_lon: np.ndarray  #: east longitude of event_p
    event_height: np.ndarray  #: geodetic height of event_p above the ellipsoid
    event_distance: np.ndarray  #: distance of event_p from s along the unit ray
    on_ellipsoid: np.ndarray  #: outside="ellipsoid": LEFT_DSM rays given the bare-ellipsoid point
    ellipsoid_p: np.ndarray  #: where those rays enter the bare ellipsoid h = 0 from above, after leaving the DSM; ECR
    ellipsoid_lat: np.ndarray  #: geodetic latitude of ellipsoid_p
    ellipsoid_lon: np.ndarray  #: east longitude of ellipsoid_p
    ellipsoid_distance: np.ndarray  #: distance of ellipsoid_p from s along the unit ray

    #: what to_xarray() writes as the Dataset's "angles" attribute
    ANGLES = "degrees; latitudes geodetic, longitudes east in [-180, 180)"
    ANGLE_FIELDS = frozenset({"lat", "lon", "incidence", "event_lat", "event_lon", "ellipsoid_lat", "ellipsoid_lon"})
    LENGTH_FIELDS = frozenset({"p", "height", "surface_height", "distance", "event_p", "event_height",
                               "event_distance", "ellipsoid_p", "ellipsoid_distance"})
    LENGTHS = "the unit of the DSM's semi-major axis a (metres for the default WGS-84)"

    @staticmethod
    def _status_items():
        return DSM_RAY_STATUS.items()


DSMResult = document_fields(DSMResult)


def _empty_result() -> "DSMResult":
    """A DSMResult of zero rays (the fields' kinds as for any other)."""
    out = {}
    for fld in fields(DSMResult):
        if fld.name in ("p", "event_p", "ellipsoid_p"):
            out[fld.name] = np.zeros((0, 3))
        elif fld.name in ("hit", "on_ellipsoid"):
            out[fld.name] = np.zeros(0, dtype=bool)
        elif fld.name == "status":
            out[fld.name] = np.zeros(0, dtype=np.int8)
        elif fld.name == "nsteps":
            out[fld.name] = np.zeros(0, dtype=np.int32)
        else:
            out[fld.name] = np.zeros(0)
    return DSMResult(**out)


def intersect_dsm(dsm: GeodeticDSM, s, l, method: str = "following", threads: int | None = None,
                  outside: str = "none") -> DSMResult:
    """Where rays P(r) = s + r l meet a geodetic DSM (Shin & Park).

    Parameters
    ----------
    dsm : GeodeticDSM
    s : array (3,) or (N, 3)
        Focal point(s) in the DSM ellipsoid's ECR frame, units of ``dsm.a``.
    l : array (3,) or (N, 3)
        Ray direction(s), any non-zero length (normalised here).
    method : "following", "exact" or "iterative"
        "following" (default): the paper's ray following (steps 1-5, eqs. 1-5,
        refinement by safeguarded false position to 1e-6 along the ray).
        "exact": the first entry into the surface (to 1e-6 along the ray).
        Consecutive rays with the same focal point (a pushbroom's line, a
        frame camera's row: ``s`` repeated bit for bit, or one ``s`` for all)
        are swept together first, which speeds them up; a ray's answer can
        then differ from the same ray's alone within that tolerance.
        "iterative": the conventional iterative ray tracing (status
        OSCILLATION / NOT_CONVERGED where it fails).
    threads : int, optional
        OpenMP threads (None or 0: OMP_NUM_THREADS if set, else all cores); results bit-identical for any count.
    outside : "none" or "ellipsoid"
        "ellipsoid": rays that leave the DSM (LEFT_DSM) also get the point where
        they enter the bare ellipsoid (h = 0, from above) at or after the point
        where they left (``ellipsoid_*``, ``on_ellipsoid``); none for a ray that
        crossed h = 0 before it left (a DSM below the ellipsoid) or starts
        below h = 0.

    Raises
    ------
    ValueError
        Bad shapes, NaN/Inf or zero-length vectors, unknown method/outside, or a
        focal point at or below the surface (names ``s`` and the ray).
    """
    from .intersect import _choice, check_threads

    if not isinstance(dsm, GeodeticDSM):
        raise TypeError(f"dsm must be a planet_intersect.GeodeticDSM, got {type(dsm).__name__}")
    # the same checks as for a planetary DEM (intersect.py): one set of rules for every surface
    _choice(method, "method (for a GeodeticDSM)", tuple(_DSM_METHODS))
    _choice(outside, "outside", ("none", "ellipsoid"))
    check_threads(threads, 1)
    n, s, l, p, q, scal, status, nsteps = _trace_raw(dsm, s, l, method, threads, fan=FAN_RUNS)
    if n == 0:
        return _empty_result()
    nan3 = np.full((n, 3), np.nan)
    nan1 = np.full(n, np.nan)
    res = DSMResult(
        hit=(status == DSMStatus.HIT) | (status == DSMStatus.HIT_UNCONVERGED),
        p=p.T.copy(), lat=np.degrees(scal[0]), lon=_wrap180(np.degrees(scal[1])), height=scal[2].copy(),
        surface_height=scal[3].copy(), distance=scal[4].copy(), incidence=np.degrees(scal[5]),
        status=status.astype(np.int8), nsteps=nsteps.astype(np.int32),
        event_p=q.T.copy(), event_lat=np.degrees(scal[6]), event_lon=_wrap180(np.degrees(scal[7])),
        event_height=scal[8].copy(), event_distance=scal[9].copy(),
        on_ellipsoid=np.zeros(n, dtype=bool), ellipsoid_p=nan3, ellipsoid_lat=nan1.copy(),
        ellipsoid_lon=nan1.copy(), ellipsoid_distance=nan1.copy())
    if outside == "ellipsoid":
        left = np.flatnonzero(status == DSMStatus.LEFT_DSM)
        if left.size:
            # the ground a ray that left the DSM falls back to: where it enters the bare ellipsoid from
            # above (h = 0 going down), at or after the point where it left (event_distance). The
            # first forward crossing of h = 0 was taken before: a focal point below h = 0 (a DSM of
            # negative heights) got the exit through the far side of the Earth, 7,074 km away, and a
            # ray over a -400 m DSM got a point over the DSM, 400 m above its surface, before it
            # left (a review). Such rays now have no fallback (on_ellipsoid False).
            r = _ellipsoid_entering(s[left], l[left] / np.linalg.norm(l[left], axis=1, keepdims=True),
                                    dsm.a, dsm.f)
            ev = res.event_distance[left]
            with np.errstate(invalid="ignore"):
                after = np.where(np.isfinite(ev), r >= ev - 1e-9 * np.maximum(np.abs(ev), dsm.a), True)
            r = np.where(after, r, np.nan)
            ok = np.isfinite(r)
            k = left[ok]
            pe = s[k] + r[ok, None] * (l[k] / np.linalg.norm(l[k], axis=1, keepdims=True))
            res.on_ellipsoid[k] = True
            res.ellipsoid_p[k] = pe
            res.ellipsoid_distance[k] = r[ok]
            if k.size:
                la, lo, _ = ecef_to_geodetic(pe, dsm.a, dsm.f)
                res.ellipsoid_lat[k], res.ellipsoid_lon[k] = la, lo
    return res


def _npz_arrays(path, required, what: str, error=ValueError, hint: str = "") -> dict:
    """The arrays of a .npz file (no pickles) as a dict; ``error`` naming ``what``
    and the path when it cannot be read or lacks one of ``required``."""
    import zipfile

    try:
        if not zipfile.is_zipfile(path):
            # (np.load's own message for such a file is a hint about allow_pickle: a walk-through)
            raise error(f"{what} {path}: not a .npz file (a .npz is a zip archive of NumPy arrays)")
    except OSError as exc:
        raise error(f"{what} {path}: cannot be read ({exc})") from None
    try:
        with np.load(path, allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
    except Exception as exc:  # noqa: BLE001 - any unreadable file
        raise error(f"{what} {path}: cannot be read as .npz ({exc})") from None
    missing = [k for k in required if k not in d]
    if missing:
        raise error(f"{what} {path}: missing arrays {missing}{hint}")
    return d


#: smallest |dlat| and dlon of a grid (degrees; ~1.1 mm on the Earth)
MIN_SPACING_DEG = 1e-8
#: the range of the semi-major axis of a GeodeticDSM (its tolerances are lengths: 1e-6 along a ray)
DSM_A_MIN, DSM_A_MAX = 1.0, 1e10

#: ``_trace_raw``'s ``fan`` for groups found from the focal points: runs of
#: consecutive rays with one focal point (pi_dsm_sweep's sweep_runs)
FAN_RUNS = -1


def _trace_raw(dsm: GeodeticDSM, s, l, method: str, threads, fan: int = 0):
    """The checks and the core call shared by :func:`intersect_dsm` and the image
    simulation: (n, s, l, p, q, scal, status, nsteps) as the core returns them
    (p, q (3, n); scal (10, n): lat, lon (radians), height, surface height,
    distance, incidence (radians), event lat, lon, height, distance).

    ``fan`` >= 2 (the simulation: the pixels of a line): the rays come in
    consecutive groups of ``fan``; for the exact method, a group whose rays share
    one focal point is swept as a whole first (fortran/pi_dsm_sweep.f90), which
    changes the answers only within the exact mode's tolerance. ``fan`` =
    ``FAN_RUNS`` (pi.intersect): the groups are the runs of consecutive rays
    with one focal point (s equal bit for bit), whatever their lengths."""
    if method == "following":
        # below the ellipsoid's smallest radius of curvature (b^2/a, the meridian's at the equator) the
        # normal lines cross before reaching the surface: the paper's nadir shortcut (the point at depth
        # H along the foot's normal) then lands off the surface (a hit 31 m above it on a = 1000,
        # f = 0.3, H = -630; an independent review, 2026-12-05) [shin-park note 21]
        m_min = dsm.a * (1.0 - dsm.f) ** 2
        if dsm.hmin < -m_min:
            raise ValueError(f"method='following': the DSM reaches {dsm.hmin:g} below its ellipsoid, deeper than "
                             f"the ellipsoid's smallest radius of curvature b^2/a = {m_min:g}, where the paper's "
                             "nadir shortcut and steps do not hold: use method='exact'")
    from ._ext import core as _core
    from .intersect import FAR_LIMIT, _as_vectors_n2, _unit_scaled, check_threads

    s, n2s = _as_vectors_n2(s, "s")
    l, n2l = _as_vectors_n2(l, "l")
    if len(s) != len(l) and len(s) != 1 and len(l) != 1:
        raise ValueError(f"s and l: {len(s)} positions do not broadcast against {len(l)} directions")
    far = n2s > (FAR_LIMIT * dsm.a) ** 2                # (n2s: einsum("ij,ij->i", s, s), inf on overflow)
    if far.any():
        k = int(np.argmax(far))
        raise ValueError(f"s[{k}] = {s[k]} is farther than {FAR_LIMIT:g} semi-major axes from the centre "
                         "(the line's position at the body would be lost to rounding)")
    _check_depth(dsm, s, n2s)
    l = _unit_scaled(l, n2l)
    n = 0 if min(len(s), len(l)) == 0 else max(len(s), len(l))
    if n == 0:
        return 0, s, l, None, None, None, None, None
    threads = check_threads(threads, n)
    s = np.ascontiguousarray(np.broadcast_to(s, (n, 3)))
    l = np.ascontiguousarray(np.broadcast_to(l, (n, 3)))
    pyr, meta = dsm.pyramid()
    s_core, r0 = _reanchor(dsm, s, l, np.broadcast_to(n2s, (n,)))
    p, q, scal, status, nsteps, stat = _core.core_dsm_trace(
        *dsm._core_grid()[:7], dsm._core_grid()[7], dsm.hmax, dsm.hmin, pyr, meta.T, s_core.T, l.T,
        _DSM_METHODS[method], int(threads), int(fan))
    if r0 is not None:
        scal[4] += r0                                 # distances from the caller's s
        scal[9] += r0
    if stat != 0:
        raise ValueError(f"intersect: the core rejected method {method!r} (status {stat})")
    bad = np.flatnonzero((status == DSMStatus.BAD_POSITION) | (status == DSMStatus.BAD_DIRECTION))
    if bad.size:                              # the checks above should have caught it: never silent
        k = int(bad[0])
        which = "s" if status[k] == DSMStatus.BAD_POSITION else "l"
        raise ValueError(f"{which}[{k}] = {(s if which == 's' else l)[k]} cannot be used by the core "
                         f"({DSM_RAY_STATUS[int(status[k])]}; {bad.size} ray(s) affected)")
    inside = np.flatnonzero(status == DSMStatus.INSIDE)
    if inside.size:
        k = int(inside[0])
        raise ValueError(f"s[{k}] = {s[k]} is at or below the DSM surface ({inside.size} ray(s) affected): "
                         f"the focal point must be above the surface")
    return n, s, l, p, q, scal, status, nsteps


def _reanchor(dsm: GeodeticDSM, s: np.ndarray, l: np.ndarray, n2s: np.ndarray | None = None):
    """(s for the core, r0 or None): focal points beyond 16 R from the centre (R = a +
    max(H_max, 0), a sphere holding every point at or below H_max) moved along their
    (unit) rays to where they enter the sphere of radius 2 R; r0 is added back to the
    distances. As the planetary core re-anchors a far spacecraft: the core's searches
    work in lengths near a; from 1e12 m rays aimed into a grid came back MISS or
    STEP_LIMIT and the following hit 20 km underground (a review). Rays that miss the
    2 R sphere are left as they are (the core finds them MISS). ``n2s``: the rows'
    squared lengths if already known (_as_vectors_n2)."""
    big = 16.0 * (dsm.a + max(dsm.hmax, 0.0))
    if n2s is None:
        with np.errstate(over="ignore", invalid="ignore"):
            n2s = np.einsum("ij,ij->i", s, s)
    far = n2s > big * big
    if not far.any():
        return s, None
    rb = 2.0 * (dsm.a + max(dsm.hmax, 0.0))
    sf, lf = s[far], l[far]
    lf = lf / np.linalg.norm(lf, axis=1)[:, None]     # _unit_scaled keeps |l|^2 finite and normal
    b = np.einsum("ij,ij->i", sf, lf)
    m = sf - b[:, None] * lf                          # the closest approach to the centre
    d2 = np.einsum("ij,ij->i", m, m)
    enter = (b < 0) & (d2 < rb * rb)
    r0 = np.zeros(len(s))
    r0f = np.where(enter, -b - np.sqrt(np.maximum(rb * rb - d2, 0.0)), 0.0)
    r0[far] = r0f
    s2 = s.copy()
    s2[far] = sf + r0f[:, None] * lf
    return np.ascontiguousarray(s2), r0


def _check_depth(dsm: GeodeticDSM, s: np.ndarray, n2: np.ndarray | None = None) -> None:
    """Refuse focal points below every height of the DSM and deeper than half the polar
    radius: below all of the surface model and nowhere near a viewpoint, where the
    geodetic coordinates stop meaning a place on the surface (at the centre of a sphere
    every latitude is as near as any: the following took a focal point 1e-200 m from the
    Moon's centre for a point under the grid and reported a hit there, a fuzz case)."""
    from .geodetic import ecef_to_geodetic

    b = dsm.a * (1 - dsm.f)
    # depth d > b/2 below an ellipsoid that lies within radius a needs |s| < a - b/2
    if n2 is None:                                    # (the rows' squared lengths, if known)
        with np.errstate(over="ignore", invalid="ignore"):
            n2 = np.einsum("ij,ij->i", s, s)
    near = np.flatnonzero(n2 < (dsm.a - 0.5 * b) ** 2)
    if near.size == 0:
        return
    h = np.atleast_1d(ecef_to_geodetic(s[near], dsm.a, dsm.f)[2])
    deep = h < min(dsm.hmin, -0.5 * b)
    if deep.any():
        k = int(near[np.argmax(deep)])
        raise ValueError(f"s[{k}] = {s[k]} lies {-float(h[np.argmax(deep)]):.6g} below the ellipsoid, under every "
                         f"height of the DSM and deeper than half the polar radius: the focal point must be "
                         f"above the surface")


def _ellipsoid_roots(s, l, a, f):
    """(r1, r2, outside, real): the two roots r1 <= r2 of s + r l on the ellipsoid (a, f), NaN where
    the line misses it; whether s lies outside it; whether the line meets it."""
    b = a * (1 - f)
    w = np.array([1 / a, 1 / a, 1 / b])
    ls, ss = l * w, s * w
    qa = np.sum(ls * ls, axis=1)
    qb = np.sum(ls * ss, axis=1)
    qc = np.sum(ss * ss, axis=1) - 1
    disc = qb * qb - qa * qc
    with np.errstate(invalid="ignore"):
        sq = np.sqrt(disc)
        r1 = (-qb - sq) / qa
        r2 = (-qb + sq) / qa
    return r1, r2, qc > 0, disc >= 0


def _ellipsoid_entering(s, l, a, f):
    """First r >= 0 where s + r l enters the ellipsoid from outside (NaN if s is not outside it,
    or the line never enters ahead): the ground of intersect_dsm's outside="ellipsoid"."""
    r1, _, outside, real = _ellipsoid_roots(s, l, a, f)
    with np.errstate(invalid="ignore"):
        return np.where(real & outside & (r1 >= 0), r1, np.nan)


def _ellipsoid_entry(s, l, a, f):
    """First r >= 0 where s + r l meets the ellipsoid (NaN if never)."""
    r1, r2, _, real = _ellipsoid_roots(s, l, a, f)
    # the nearer root when s is outside, the exit root when s is inside the ellipsoid (a point below
    # h = 0 over a DSM of negative heights: it was given as r = 0, the focal point itself; a review)
    with np.errstate(invalid="ignore"):
        r = np.where(r1 >= 0, r1, np.where(r2 >= 0, r2, np.nan))
    return np.where(real, r, np.nan)
