"""Small-body shape tables (radius at the nodes of a latitude/longitude grid) as DEMs.

P. C. Thomas' shape models of small bodies (PDS Small Bodies Node, data set
EAR-A-5-DDR-SHAPE-MODELS; ``m1phobos.tab`` for Phobos, ``../shared/data/phobos_thomas_m1phobos``)
are text tables of three columns: latitude (deg), longitude (deg), radius (km from the body's
centre) at the **nodes** of a regular grid, latitude the slow index from -90 to +90, longitude
the fast one from 0 to 360 (the 360 column repeating the 0 column).

The DEM format holds radii at **pixel centres** of a global grid with a whole number of pixels
per degree (DESIGN section 3), so a table is resampled: each DEM pixel centre takes the
bilinear interpolation of the table's four surrounding nodes in (latitude, longitude),
longitude periodic. A pole row holds one radius (the table repeats it along the row). Where
the 0 and 360 columns differ (m1phobos: 15 rows, by up to 0.023 km) their mean is used.

Longitude: the table does not say which way longitude runs, and the evidence is mixed (its
PDS label says "planetocentric", east by IAU convention; Stickney's depression lies where west
longitude puts it). West is the default (``longitude="west"``: east longitude = 360 - table
longitude); ``longitude="east"`` reads them as east longitude. docs/paper-notes.md, note 23.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from .dem import DEM, checked_ppd, read_small_text

__all__ = ["ShapeTableError", "read_shape_table", "shape_table_dem", "import_shape_table"]

#: the finest DEM a table may be resampled to (pixels per degree; finer pixels add no detail)
MAX_PPD = 16
#: the largest table file read (bytes); m1phobos.tab is 0.5 MB, a 0.25-degree table ~25 MB
MAX_BYTES = 60_000_000
#: the largest relative difference allowed between the 0 and 360 columns (m1phobos: 0.23 %)
MAX_SEAM = 0.01


class ShapeTableError(ValueError):
    """A shape table that cannot be read as a regular global node grid (names the file)."""


def _line_of(text: str, row: int) -> int:
    """The file line (1-based) of data row ``row`` (0-based; blank lines hold no row): only for
    an error's message."""
    return int(np.flatnonzero([bool(ln.strip()) for ln in text.splitlines()])[row]) + 1


def _rows(text: str, where: str) -> np.ndarray:
    """The table's numbers (n, 3)."""
    import io

    try:
        t = np.loadtxt(io.StringIO(text), dtype=float, comments=None, ndmin=2)
        if t.shape[1] == 3 and np.isfinite(t).all():
            return t
    except ValueError:
        pass
    # something is wrong: the first bad line, named
    for k, line in enumerate(text.splitlines(), start=1):
        parts = line.split()
        if not parts:
            continue
        if len(parts) != 3:
            raise ShapeTableError(f"{where}, line {k}: {len(parts)} columns, expected 3 (latitude, longitude, radius)")
        try:
            vals = [float(x) for x in parts]
        except ValueError:
            raise ShapeTableError(f"{where}, line {k}: not three numbers: {line.strip()[:60]!r}") from None
        if not all(math.isfinite(v) for v in vals):
            raise ShapeTableError(f"{where}, line {k}: NaN or infinity")
    raise ShapeTableError(f"{where}: not a table of three numbers a line")


def read_shape_table(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The table's node latitudes (nlat,), longitudes (nlon,) and radii (nlat, nlon), as stored.

    Checks that the rows form a complete regular global grid: latitudes -90 to 90 and
    longitudes 0 to 360 (the 360 column optional), one step for both, dividing 180, latitude
    the slow index; every value finite, every radius positive, a pole row constant, the 360
    column within MAX_SEAM of the 0 column. Raises ShapeTableError naming the file and the
    first problem (with its line)."""
    p = Path(path)
    where = f"shape table {p}"
    text = read_small_text(p, where, MAX_BYTES, ShapeTableError)
    t = _rows(text, where)
    if len(t) < 4:
        raise ShapeTableError(f"{where}: {len(t)} rows of data, too few for a grid")
    lat, lon, rad = t[:, 0], t[:, 1], t[:, 2]
    nlon = int(np.argmax(lat != lat[0])) if np.any(lat != lat[0]) else len(lat)
    if nlon < 2 or len(t) % nlon:
        raise ShapeTableError(f"{where}: {len(t)} rows do not form rows of {nlon} longitudes each "
                              f"(latitude must be the slow index)")
    nlat = len(t) // nlon
    lat2, lon2, rad2 = lat.reshape(nlat, nlon), lon.reshape(nlat, nlon), rad.reshape(nlat, nlon)
    lats, lons = lat2[:, 0], lon2[0]
    if not (np.all(lat2 == lats[:, None]) and np.all(lon2 == lons[None, :])):
        bad = int(np.argmax((lat2 != lats[:, None]) | (lon2 != lons[None, :])))
        raise ShapeTableError(f"{where}, line {_line_of(text, bad)}: latitude {float(lat[bad])!r}, longitude {float(lon[bad])!r} "
                              f"breaks the grid (each latitude's row must list the same longitudes)")
    step = (lats[-1] - lats[0]) / (nlat - 1) if nlat > 1 else 0.0
    if not (lats[0] == -90.0 and lats[-1] == 90.0 and step > 0):
        raise ShapeTableError(f"{where}: latitudes run {float(lats[0])!r} to {float(lats[-1])!r}; a global table runs -90 to 90")
    n180 = 180.0 / step
    if abs(n180 - round(n180)) > 1e-9 or not np.allclose(lats, -90.0 + step * np.arange(nlat), rtol=0, atol=1e-9):
        raise ShapeTableError(f"{where}: latitudes are not evenly spaced by a step that divides 180 deg")
    want = np.arange(nlon) * step
    last_ok = np.isclose(lons[-1], 360.0, rtol=0, atol=1e-9) or np.isclose(lons[-1], 360.0 - step, rtol=0, atol=1e-9)
    if not (np.allclose(lons, want, rtol=0, atol=1e-9) and last_ok):
        raise ShapeTableError(f"{where}: longitudes must run 0 to 360 (or 360 - {step:.10g}) by the latitudes' "
                              f"step {step:.10g} deg; they run {float(lons[0])!r} to {float(lons[-1])!r} in {nlon} values")
    if not np.all(rad2 > 0):
        k = int(np.argmax(~(rad2.ravel() > 0)))
        raise ShapeTableError(f"{where}, line {_line_of(text, k)}: radius {float(rad[k])!r} is not positive")
    for row, name in ((0, "south"), (nlat - 1, "north")):
        if not np.all(rad2[row] == rad2[row, 0]):
            raise ShapeTableError(f"{where}: the {name} pole row holds {np.unique(rad2[row]).size} different radii; "
                                  f"a pole has one")
    if np.isclose(lons[-1], 360.0, rtol=0, atol=1e-9):
        with np.errstate(over="ignore"):                # a subnormal radius: inf, refused below
            seam = np.abs(rad2[:, -1] - rad2[:, 0]) / rad2[:, 0]
        if seam.max() > MAX_SEAM:
            i = int(np.argmax(seam))
            raise ShapeTableError(f"{where}: at latitude {float(lats[i])!r} the 360 and 0 longitude columns differ by "
                                  f"{100 * float(seam[i]):.3g} % ({float(rad2[i, -1])!r} vs {float(rad2[i, 0])!r}); more than "
                                  f"{100 * MAX_SEAM:g} % is not one surface")
    return lats.copy(), lons.copy(), rad2.copy()


def shape_table_dem(path: str | os.PathLike, *, ppd: int | None = None, longitude: str = "west",
                    re: float | None = None, f: float = 0.0) -> DEM:
    """A DEM (radii in the table's unit, km) from a shape table (see the module's text).

    ppd: pixels per degree of the DEM (default: the fewest with pixels no larger than the
    table's step, at least 1; at most MAX_PPD). longitude: "west" (default) or "east", how the
    table's longitudes run. re, f: the DEM's reference spheroid (default none: Table 1's
    irregular-body setting, altitude and tangent height NaN)."""
    if longitude not in ("west", "east"):
        raise ValueError(f"longitude must be 'west' or 'east', got {longitude!r}")
    if re is None and f != 0:
        raise ValueError(f"f = {f!r} needs re: a flattening belongs to a reference spheroid")
    if re is not None:
        if isinstance(re, bool) or not isinstance(re, (int, float, np.integer, np.floating)) or \
                not (math.isfinite(re) and re > 0):
            raise ValueError(f"re must be a positive radius in the table's unit (km), got {re!r}")
        if re == 1.0 and f == 0:
            raise ValueError("re = 1 with f = 0 is Table 1's 'no spheroid' placeholder: leave re out for no spheroid")
    lats, lons, rad = read_shape_table(path)
    if re is not None and not (rad.max() / 10 <= re <= 10 * rad.max()):
        raise ValueError(f"re = {re!r} is not within a factor 10 of the table's largest radius {float(rad.max())!r} "
                         f"(the same unit, km, is needed)")
    step = float(lats[1] - lats[0])
    if ppd is None:
        ppd = min(MAX_PPD, max(1, math.ceil(1.0 / step - 1e-9)))
    ppd = checked_ppd(ppd, MAX_PPD)
    nodes = rad
    if np.isclose(lons[-1], 360.0, rtol=0, atol=1e-9):     # the repeated column: the mean of the two
        nodes = rad[:, :-1].copy()
        nodes[:, 0] = 0.5 * (rad[:, 0] + rad[:, -1])
    nlon_n = nodes.shape[1]                            # 360 / step nodes, periodic
    lon_e = (np.arange(360 * ppd) + 0.5) / ppd         # the DEM's east longitudes
    lon_t = (360.0 - lon_e) % 360.0 if longitude == "west" else lon_e
    u = lon_t / step
    j0 = np.floor(u).astype(int) % nlon_n
    wu = (u - np.floor(u))[None, :]
    j1 = (j0 + 1) % nlon_n
    big = rad.max() > 1e38 or rad.min() < 1e-37        # beyond float32: keep float64
    radii = np.empty((180 * ppd, 360 * ppd), dtype=np.float64 if big else np.float32)
    for start in range(0, 180 * ppd, 256):             # rows in blocks: no full-size float64 temporaries
        rows = np.arange(start, min(start + 256, 180 * ppd))
        v = (rows + 0.5) / ppd / step                  # the pixel centres' latitude + 90, in node steps
        i0 = np.minimum(np.floor(v).astype(int), nodes.shape[0] - 2)
        wv = (v - i0)[:, None]
        r00, r01 = nodes[i0][:, j0], nodes[i0][:, j1]
        r10, r11 = nodes[i0 + 1][:, j0], nodes[i0 + 1][:, j1]
        radii[rows] = (1 - wv) * ((1 - wu) * r00 + wu * r01) + wv * ((1 - wu) * r10 + wu * r11)
    try:
        return DEM.from_array(radii, f=f, re=re)
    except ValueError as exc:                          # radii out of the DEM format's range: name the table
        raise ShapeTableError(f"shape table {Path(path)}: {exc}") from None


def import_shape_table(path: str | os.PathLike, out: str | os.PathLike, *, ppd: int | None = None,
                       longitude: str = "west", re: float | None = None, f: float = 0.0,
                       overwrite: bool = False) -> Path:
    """Convert a shape table (see :func:`shape_table_dem`) to a ``.hdr``/``.dem`` pair (the table's unit,
    float32 where it holds the radii, else float64); return the ``.hdr``. Never over the table itself."""
    dem = shape_table_dem(path, ppd=ppd, longitude=longitude, re=re, f=f)
    return dem.write(out, overwrite=overwrite, inputs=[path])
