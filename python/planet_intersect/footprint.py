"""Footprint geometry of an orbiting nadir instrument (Mars Odyssey GRS notes).

The package's third system (DESIGN section 10; source document 003, *Mars
Odyssey/GRS Geometry*). For every spectrum (spacecraft state vector R, v in
the planet-fixed frame) and every cell of a regular latitude/longitude cell
table in its footprint: the cell-to-spacecraft vector ``d = R - r_C``, its
length, the detector's solid angle ``A/|d|^2``, the zenith angles with the
areocentric and the areodetic normal, the emission angle against the cell's
topographic normal, the nadir angle, the position angle (clockwise from north
through east, 0-360), the cell's coordinates in the spacecraft-local frame
with its azimuth and elevation there, the air mass, and (``occlusion=True``)
whether the terrain hides the cell, found with the package's exact ray
casting.

Frame: planet-fixed, x to (0 N, 0 E), z north; latitudes areocentric unless
named ``*_detic``; east longitudes in [0, 360); angles in degrees; lengths in
the DEM's units (km for the Mars grids). Every deviation from the notes is a
numbered note in ``docs/grs-notes.md``; ``[note N]`` marks the line.

>>> cells = pi.CellTable(dem, cell_deg=0.5)
>>> fp = pi.footprint(cells, R, v, area=3.4e-9, zeta=0.0)
>>> fp.solid_angle, fp.emission, fp.position_angle, fp.to_xarray()
"""

from __future__ import annotations

import math
import os
import warnings
import weakref
from dataclasses import dataclass, field, fields

import numpy as np

from .dem import DEM

__all__ = [
    "CellTable", "FootprintResult", "footprint", "spacecraft_frame", "spacecraft_quaternion",
    "frame_angles", "orbit_frame", "quat_multiply", "quat_conjugate", "quat_rotate", "quat_to_matrix",
    "airmass", "chapman", "scale_height", "detic_latitude", "geodetic_latitude", "notes_latitude_series",
    "position_angle", "position_angle_notes", "visible_cap_area", "keplerian_states", "orbit_study",
    "OrbitStudy", "plot_orbit_study", "plot_footprint_map", "FOOTPRINT_STATUS",
    "MARS_GM", "MARS_CO2_MOLECULAR_MASS", "MARS_ROTATION_RATE", "MARS_MEAN_RADIUS_KM", "BOLTZMANN", "AMU",
    "ODYSSEY_AREA_KM2", "HARDIE_PEAK_DEG", "HARDIE_PEAK_AIRMASS", "KM_RADIUS_MAX",
]

#: Mars GM, km^3/s^2 (GGM1025A, the gravity field of ../shared/data's areoid)
MARS_GM = 42828.369773939
#: mean molecular mass of the Mars atmosphere (95 % CO2, N2, Ar), atomic mass units
MARS_CO2_MOLECULAR_MASS = 43.34
#: Mars rotation rate, rad/s (350.89198226 deg/day, IAU)
MARS_ROTATION_RATE = math.radians(350.89198226) / 86400.0
#: Mars mean radius, km
MARS_MEAN_RADIUS_KM = 3389.5
#: Boltzmann constant, J/K (SI, exact)
BOLTZMANN = 1.380649e-23
#: atomic mass unit, kg
AMU = 1.66053906660e-27
#: the notes' GRS detector cross-section, 34 cm^2, in km^2
ODYSSEY_AREA_KM2 = 3.4e-9

#: radii (of a DEM, or R of the air mass) above this cannot be kilometres of any body these notes
#: concern (Jupiter's equatorial radius is 71,492 km): the km defaults (area, H) are refused [note 19]
KM_RADIUS_MAX = 1e5

#: per-spectrum status codes of the Fortran footprint kernel (pi_footprint)
FOOTPRINT_STATUS = {0: "ok", 1: "spacecraft position NaN/Inf or zero", 2: "spacecraft not above the highest cell",
                    3: "cell arrays inconsistent", 4: "pair offsets inconsistent"}


# ----------------------------------------------------------------------------------------
# input checks
# ----------------------------------------------------------------------------------------
def _vectors(v, name: str) -> np.ndarray:
    if np.iscomplexobj(v):
        raise ValueError(f"{name}: complex values are not positions or directions")
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: not an array of numbers ({exc})") from None
    shape = a.shape
    if a.ndim == 1:
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != 3 or a.shape[0] == 0:
        raise ValueError(f"{name}: expected shape (3,) or (N, 3) with N >= 1, got {shape}")
    bad = ~np.isfinite(a).all(axis=1)
    if bad.any():
        k = int(np.argmax(bad))
        raise ValueError(f"{name}[{k}] has NaN or Inf components: {a[k]}")
    return np.ascontiguousarray(a)


def _pow2_scaled(a: np.ndarray) -> np.ndarray:
    """Rows of a (N, 3) scaled by powers of two so that their largest |component| is in [0.5, 1):
    exact (the same directions, bit for bit, after normalising), and safe from the overflow and
    underflow of |a|^2 for any finite magnitude (a review found v of 1e-200 or 1e200 refused)."""
    _, e = np.frexp(np.max(np.abs(a), axis=1))
    return np.ldexp(a, -e[:, None])


def _angles(x, name: str, limit: float, lo: float | None = None) -> np.ndarray:
    """x (degrees) as a float64 array, finite and within [lo, limit] (lo default -limit), or
    ValueError naming it, the accepted range and the first value outside it."""
    lo = -limit if lo is None else lo
    if np.iscomplexobj(x) or isinstance(x, (bool, np.bool_)):
        raise ValueError(f"{name}: expected real numbers (degrees), got {x!r}")
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected real numbers (degrees), got {x!r}") from None
    with np.errstate(invalid="ignore"):
        bad = ~(np.isfinite(a) & (a >= lo) & (a <= limit))
    if bad.any():
        # one message for every value refused (airmass said [0, 180] for -10 and [-180, 180]
        # for 181 or NaN: a walk-through)
        k = int(np.argmax(bad.reshape(-1)))
        raise ValueError(f"{name}: angles must be finite and within [{lo:g}, {limit:g}] degrees, got "
                         f"{float(a.reshape(-1)[k])!r}" + (f" at flat index {k}" if a.ndim else ""))
    return a


def _nonzero(a: np.ndarray, name: str) -> np.ndarray:
    zero = np.max(np.abs(a), axis=1) == 0                # (not |a| == 0: |a|^2 underflows for 1e-200)
    if zero.any():
        raise ValueError(f"{name}[{int(np.argmax(zero))}] has zero length")
    # |a| through the power-of-two scaling (|a|^2 of 1e200 overflowed with a warning: a review)
    big = np.max(np.abs(a), axis=1)
    _, e = np.frexp(big)
    return np.ldexp(np.linalg.norm(np.ldexp(a, -e[:, None]), axis=1), e)


def _real(x, name: str, lo=None, hi=None, lo_open=False) -> float:
    if isinstance(x, (bool, np.bool_, str, bytes)):          # (float("11") took H="11": one rule for all)
        raise ValueError(f"{name} must be a number, got {x!r}")
    try:
        x = float(x)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {x!r}") from None
    if not math.isfinite(x):
        raise ValueError(f"{name} must be finite, got {x}")
    if lo is not None and (x < lo or (lo_open and x == lo)):
        raise ValueError(f"{name} must be {'>' if lo_open else '>='} {lo}, got {x}")
    if hi is not None and x > hi:
        raise ValueError(f"{name} must be <= {hi}, got {x}")
    return x


# ----------------------------------------------------------------------------------------
# latitudes on the spheroid
# ----------------------------------------------------------------------------------------
def detic_latitude(lat_deg, f: float) -> np.ndarray:
    """Areodetic latitude (deg) of the spheroid point at areocentric latitude ``lat_deg``.

    Exact on the spheroid: ``tan b' = tan b / (1 - e^2)``, ``e^2 = f (2 - f)``
    (docs/grs-notes.md, note 1), computed as atan2(sin b, (1 - e^2) cos b) so
    that the poles are exact.
    """
    f = _real(f, "f", lo=0.0, hi=1.0)
    if f >= 1.0:
        raise ValueError(f"f must be in [0, 1), got {f}")
    e2 = f * (2.0 - f)
    b = np.radians(_angles(lat_deg, "lat_deg", 90.0))
    return np.degrees(np.arctan2(np.sin(b), (1.0 - e2) * np.cos(b)))


def notes_latitude_series(lat_deg, f: float, corrected: bool = False) -> np.ndarray:
    """The notes' series for the areodetic latitude (deg), as printed or corrected.

    As printed: ``b' = b - m sin 2b + (1/2) m^2 sin^2 b`` with ``m = e^2/(2 - e^2)``
    (note 1: wrong sign, and ``sin^2 b`` is not a term of the series). Corrected:
    the series of ``tan b' = tan b/(1 - e^2)`` in ``m``:
    ``b' = b + m sin 2b + (1/2) m^2 sin 4b + ...`` (``tan(b' - b) = m sin 2b / (1 - m cos 2b)``).
    """
    e2 = f * (2.0 - f)
    m = e2 / (2.0 - e2)
    b = np.radians(np.asarray(lat_deg, dtype=np.float64))
    if corrected:
        out = b + m * np.sin(2 * b) + 0.5 * m * m * np.sin(4 * b)
    else:
        out = b - m * np.sin(2 * b) + 0.5 * m * m * np.sin(b) ** 2      # as printed [note 1]
    return np.degrees(out)


def geodetic_latitude(p, re: float, f: float):
    """Areodetic latitude (deg) and height above the spheroid of points ``p`` ((3,) or (N, 3)).

    The foot point is the nearest point of the spheroid (re, f), found by the
    package's exact conversion (:func:`planet_intersect.ecef_to_geodetic`,
    checked against PROJ and SPICE) on p / re, so any radius the DEM format
    allows works; ``f = 0`` gives the areocentric latitude and the height above
    the sphere ``re``. Returns arrays of shape (N,).

    Until 2026-12-03 this was Bowring's iteration on the parametric latitude
    (``tol``, ``max_iter``) with no checks of its own. The footprint fuzzing
    found it taking f = 1.5, re = -1, a string or a (1, 2) array, and,
    inside the evolute (10 km from Mars's centre, 1e-12 km off the equatorial
    plane), returning the equator's normal (h = -3386.19 km) instead of the
    nearest foot point near the pole (h = -3376.2 km). For the cell table's
    points, near the surface, the two agree to 2.8e-14 deg (docs/grs-notes.md,
    note 3).
    """
    from .geodetic import ecef_to_geodetic

    re = _real(re, "re", lo=0.0, lo_open=True)
    f = _real(f, "f", lo=0.0)
    if f >= 1.0:
        raise ValueError(f"f must be in [0, 1), got {f}")
    pts = _vectors(p, "p")
    with np.errstate(over="ignore", under="ignore"):
        q = pts / re
    lat, _, h = ecef_to_geodetic(q, 1.0, f)
    return np.atleast_1d(lat), np.atleast_1d(h) * re


# ----------------------------------------------------------------------------------------
# the cell table
# ----------------------------------------------------------------------------------------
_CELL_CACHE: "weakref.WeakKeyDictionary[DEM, dict]" = weakref.WeakKeyDictionary()
#: bytes per cell of a CellTable (its arrays) and the largest table built
_CELL_BYTES = 8 * 26
_CELL_TABLE_MAX_BYTES = 16e9
#: the build's peak over its arrays' bytes (2.28 GB at 0.1 deg for 1.35 GB of arrays: 1.7, a
#: review; a 0.03 deg table passed the 16 GB check and ran out of memory deep in NumPy)
_CELL_PEAK_FACTOR = 2.0


def _physical_memory() -> float:
    """Bytes of physical memory (inf when the system does not say)."""
    try:
        return float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return math.inf


class CellTable:
    """The notes' ``cell_tab``: fixed properties of every cell, computed once per DEM and cell size.

    Cells are ``cell_deg x cell_deg`` boxes bounded by meridians and parallels,
    row-major from the south-west: cell ``k = i*ncol + j`` has its centre at
    areocentric latitude ``-90 + (i + 1/2) cell_deg`` and east longitude
    ``(j + 1/2) cell_deg`` (the DEM's own registration). ``cell_deg`` must
    divide 180.

    How each quantity is made (docs/grs-notes.md, note 3):

    * The cell's surface is fitted by least squares with a plane in the local
      angular frame, ``r(b, l) = r0 + g_b (b - b0) + g_l (l - l0)``, through the
      DEM samples in the cell (when ``cell_deg * ppd`` is an integer >= 2: the
      pixel centres inside it), else through the DEM's bilinear surface sampled
      at n x n points spread evenly over the cell, n = ceil(cell_deg * ppd) + 1
      clipped to 4..32 (at least one sample per DEM pixel up to 31 pixels per cell). The sample grid is symmetric
      about the centre in (b, l), so r0 is the samples' mean and the gradient
      is free of the curvature terms that tilt a Cartesian plane fit over a
      trapezoidal cell (measured on the Mars spheroid, 0.5 deg cells: 1.2e-6 rad
      at 45 deg for a Cartesian plane, 1.9e-8 rad for this fit).
    * ``r``: the centre point ``r0 u``, u the unit vector to (lat, lon): the
      cell's mean radius rather than the DEM at the centre, because the GRS
      integrates over the cell; for 0.5 deg cells on a 4 ppd grid the two are
      identical (the bilinear surface at the centre of four pixel centres is
      their mean).
    * ``normal``: the unit outward normal of the fitted surface at the centre,
      ``u - (g_b/r0) north - (g_l/(r0 cos b)) east``, normalised; an (x, y, z)
      unit vector as the notes advise.
    * ``lat_detic``: areodetic latitude of the point ``r`` itself (full
      conversion, off the spheroid), ``lat_detic_spheroid`` that of the
      spheroid point at the same areocentric latitude (``tan b' = tan b/(1-e^2)``),
      ``normal_detic`` the spheroid normal at (lat_detic, lon). The spheroid is
      the DEM's own (re, f), not the notes' f = 1/154.409 [note 2].
    * ``area``: the area of the cell's latitude/longitude box on the sphere of
      radius r0, ``r0^2 dl (sin b_n - sin b_s)`` (DEM units squared).
    * ``radius_dem``: the DEM's bilinear radius at the centre (the target point
      of the occlusion rays).

    Tables are cached with the DEM: ``CellTable(dem, 0.5)`` a second time shares
    the arrays (read-only).
    """

    def __init__(self, dem: DEM, cell_deg: float = 0.5):
        if not isinstance(dem, DEM):
            raise TypeError(f"dem must be a planet_intersect.DEM, got {type(dem).__name__}")
        cell_deg = _real(cell_deg, "cell_deg", lo=0.0, lo_open=True, hi=180.0)
        nrow = int(round(180.0 / cell_deg))
        if nrow < 1 or abs(nrow * cell_deg - 180.0) > 1e-9 * 180.0:
            raise ValueError(f"cell_deg must divide 180 (0.5, 1, 0.25, ...), got {cell_deg}")
        cell_deg = 180.0 / nrow
        need = 2 * nrow * nrow * _CELL_BYTES
        limit = min(_CELL_TABLE_MAX_BYTES, 0.75 * _physical_memory() / _CELL_PEAK_FACTOR)
        if need > limit:
            raise ValueError(f"cell_deg = {cell_deg:g} makes {2 * nrow * nrow:,} cells, about {need / 1e9:.1f} GB "
                             f"of cell table and ~{_CELL_PEAK_FACTOR * need / 1e9:.0f} GB while it is built (the "
                             f"limit here is {limit / 1e9:.1f} GB of table: at most 16 GB, and 3/4 of this machine's "
                             f"memory for the build): use larger cells")
        self.dem = dem
        self.cell_deg = cell_deg
        self.nrow = nrow
        self.ncol = 2 * nrow
        key = round(cell_deg, 12)
        per_dem = _CELL_CACHE.setdefault(dem, {})
        if key not in per_dem:
            per_dem[key] = _build_cells(dem, nrow)
        for name, value in per_dem[key].items():
            setattr(self, name, value)

    def __len__(self) -> int:
        return self.nrow * self.ncol

    def __repr__(self) -> str:
        return f"CellTable({self.nrow} x {self.ncol} cells of {self.cell_deg} deg, {self.dem!r})"

    def index(self, lat, lon) -> np.ndarray:
        """Index of the cell holding each (areocentric lat, east lon) in degrees.

        Raises ValueError for a latitude outside [-90, 90] or a NaN/Inf coordinate
        (longitudes wrap); lat = 90 is in the northernmost row."""
        try:
            lat = np.asarray(lat, dtype=np.float64)
            lon = np.asarray(lon, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"lat, lon: not arrays of numbers ({exc})") from None
        for name, a in (("lat", lat), ("lon", lon)):
            bad = ~np.isfinite(a)
            if bad.any():
                k = int(np.argmax(bad.reshape(-1)))
                raise ValueError(f"{name}: {bad.sum()} value(s) NaN or Inf, first at flat index {k}")
        bad = np.abs(lat) > 90.0
        if bad.any():
            k = int(np.argmax(bad.reshape(-1)))
            raise ValueError(f"lat: {bad.sum()} value(s) outside [-90, 90] degrees, first "
                             f"{lat.reshape(-1)[k]} at flat index {k}")
        lon = lon % 360.0
        i = np.clip(np.floor((lat + 90.0) / self.cell_deg).astype(np.int64), 0, self.nrow - 1)
        j = np.clip(np.floor(lon / self.cell_deg).astype(np.int64), 0, self.ncol - 1)
        return i * self.ncol + j

    def to_xarray(self):
        """The table as an ``xarray.Dataset`` with dimension ``cell`` (and ``xyz``)."""
        import xarray as xr

        data = {}
        for name in ("lat", "lon", "lat_detic", "lat_detic_spheroid", "radius", "radius_dem", "area", "slope"):
            data[name] = ("cell", getattr(self, name))
        for name in ("r", "normal", "normal_detic"):
            data[name] = (("cell", "xyz"), getattr(self, name))
        ds = xr.Dataset(data, coords={"cell": np.arange(len(self)), "xyz": ["x", "y", "z"]})
        # units and long_name on every variable, as FootprintResult.to_xarray has (none here: a review)
        for name, (units, long_name) in _CELL_XARRAY_ATTRS.items():
            ds[name].attrs.update(units=units, long_name=long_name)
        ds.attrs.update(cell_deg=self.cell_deg, nrow=self.nrow, ncol=self.ncol, re=self.dem.re, f=self.dem.f,
                        angles="degrees; lat areocentric, lat_detic areodetic, lon east [0, 360)",
                        normal="least-squares plane in (lat, lon, r) through the DEM samples in the cell",
                        area="r0^2 dlon (sin lat_n - sin lat_s), DEM units squared")
        return ds


def _cell_samples(dem: DEM, nrow: int):
    """Yield (row slice, sample radii [rows, nb, ncol, nl], dlat offsets (rad, nb), dlon offsets (rad, nl))."""
    cd = 180.0 / nrow
    ncol = 2 * nrow
    kk = cd * dem.ppd
    k = int(round(kk))
    block = abs(kk - k) < 1e-9 and k >= 2
    if block:
        offs = np.radians((np.arange(k) + 0.5) / dem.ppd - cd / 2.0)
        rows_per = max(1, (4 << 20) // (k * k * ncol))
        for i0 in range(0, nrow, rows_per):
            i1 = min(nrow, i0 + rows_per)
            raw = np.asarray(dem.radii[i0 * k:i1 * k], dtype=np.float64)
            yield slice(i0, i1), raw.reshape(i1 - i0, k, ncol, k), offs, offs
    else:
        # at least one sample per DEM pixel across the cell (a review found a 10 km mesa two
        # pixels wide missing from the mean of a 0.9 deg cell of a 16 ppd DEM with 4 x 4), at
        # most 32 x 32 per cell (the table's build time) [note 3]
        ns = int(min(32, max(4, math.ceil(kk) + 1)))
        frac = (np.arange(ns) + 0.5) / ns - 0.5
        offs = np.radians(frac * cd)
        rows_per = max(1, (2 << 20) // (ns * ns * ncol))
        for i0 in range(0, nrow, rows_per):
            i1 = min(nrow, i0 + rows_per)
            lat_c = -90.0 + (np.arange(i0, i1) + 0.5) * cd
            lon_c = (np.arange(ncol) + 0.5) * cd
            la = lat_c[:, None, None, None] + frac[None, :, None, None] * cd
            lo = lon_c[None, None, :, None] + frac[None, None, None, :] * cd
            la, lo = np.broadcast_arrays(la, lo)
            yield slice(i0, i1), dem.radius(la, lo % 360.0), offs, offs


def _build_cells(dem: DEM, nrow: int) -> dict:
    cd = 180.0 / nrow
    ncol = 2 * nrow
    r0 = np.empty((nrow, ncol))
    gb = np.empty((nrow, ncol))
    gl = np.empty((nrow, ncol))
    for rows, samp, ob, ol in _cell_samples(dem, nrow):
        # least squares on a symmetric grid: mean and the two separable slopes [note 3]
        r0[rows] = samp.mean(axis=(1, 3))
        gb[rows] = np.einsum("ibjl,b->ij", samp, ob) / (samp.shape[3] * np.sum(ob * ob))
        gl[rows] = np.einsum("ibjl,l->ij", samp, ol) / (samp.shape[1] * np.sum(ol * ol))
    lat = -90.0 + (np.arange(nrow) + 0.5) * cd
    lon = (np.arange(ncol) + 0.5) * cd
    LAT, LON = np.meshgrid(lat, lon, indexing="ij")
    b, l = np.radians(LAT), np.radians(LON)
    sb, cb, sl, cl = np.sin(b), np.cos(b), np.sin(l), np.cos(l)
    u = np.stack([cb * cl, cb * sl, sb], axis=-1)
    north = np.stack([-sb * cl, -sb * sl, cb], axis=-1)
    east = np.stack([-sl, cl, np.zeros_like(sl)], axis=-1)
    normal = u - (gb / r0)[..., None] * north - (gl / (r0 * cb))[..., None] * east
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    r = r0[..., None] * u
    lat_detic, _ = geodetic_latitude(r.reshape(-1, 3), dem.re, dem.f)
    bd = np.radians(lat_detic).reshape(nrow, ncol)
    ndet = np.stack([np.cos(bd) * cl, np.cos(bd) * sl, np.sin(bd)], axis=-1)
    half = math.radians(cd) / 2
    area = r0 * r0 * math.radians(cd) * (np.sin(b + half) - np.sin(b - half))
    slope = np.degrees(np.arctan2(np.linalg.norm(np.cross(normal, ndet), axis=-1), np.sum(normal * ndet, axis=-1)))
    radius_dem = dem.radius(LAT.ravel(), LON.ravel())
    out = dict(
        lat=LAT.ravel(), lon=LON.ravel(), lat_detic=lat_detic,
        lat_detic_spheroid=detic_latitude(LAT.ravel(), dem.f),
        radius=r0.ravel(), r=r.reshape(-1, 3), u=u.reshape(-1, 3), normal=normal.reshape(-1, 3),
        normal_detic=ndet.reshape(-1, 3), area=area.ravel(), slope=slope.ravel(), radius_dem=radius_dem,
    )
    if not (np.isfinite(r0).all() and (r0 > 0).all()):
        raise ValueError("CellTable: a cell's mean radius is not positive and finite")
    for v in out.values():
        v.flags.writeable = False
    out["radius_range"] = (float(r0.min()), float(r0.max()))
    return out


# ----------------------------------------------------------------------------------------
# quaternions and the spacecraft-local frame
# ----------------------------------------------------------------------------------------
def quat_multiply(p, q) -> np.ndarray:
    """Hamilton product of quaternions (w, x, y, z), scalar first, broadcasting over (..., 4).

    The notes' definition: ``pq = p0 q0 - p.q + p0 q + q0 p + p x q``.
    """
    p = np.asarray(p, dtype=np.float64)
    q = np.asarray(q, dtype=np.float64)
    p0, pv = p[..., :1], p[..., 1:]
    q0, qv = q[..., :1], q[..., 1:]
    w = p0 * q0 - np.sum(pv * qv, axis=-1, keepdims=True)
    v = p0 * qv + q0 * pv + np.cross(pv, qv)
    return np.concatenate([w, v], axis=-1)


def quat_conjugate(q) -> np.ndarray:
    """``q* = q0 - q`` (the notes' conjugate)."""
    q = np.asarray(q, dtype=np.float64)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def quat_rotate(q, v) -> np.ndarray:
    """The vector part of ``q v q*`` (v as a pure quaternion): the notes' ``L_q(v)``."""
    v = np.asarray(v, dtype=np.float64)
    vq = np.concatenate([np.zeros(v.shape[:-1] + (1,)), v], axis=-1)
    return quat_multiply(quat_multiply(q, vq), quat_conjugate(q))[..., 1:]


def quat_to_matrix(q) -> np.ndarray:
    """Rotation matrix G of a unit quaternion: ``G v = q v q*`` (..., 3, 3)."""
    q = np.asarray(q, dtype=np.float64)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    G = np.empty(q.shape[:-1] + (3, 3))
    G[..., 0, 0] = 1 - 2 * (y * y + z * z)
    G[..., 0, 1] = 2 * (x * y - w * z)
    G[..., 0, 2] = 2 * (x * z + w * y)
    G[..., 1, 0] = 2 * (x * y + w * z)
    G[..., 1, 1] = 1 - 2 * (x * x + z * z)
    G[..., 1, 2] = 2 * (y * z - w * x)
    G[..., 2, 0] = 2 * (x * z - w * y)
    G[..., 2, 1] = 2 * (y * z + w * x)
    G[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return G


def _axis_quat(axis, angle) -> np.ndarray:
    """Unit quaternion of a right-handed rotation by ``angle`` (rad) about a unit ``axis``."""
    angle = np.asarray(angle, dtype=np.float64)
    h = 0.5 * angle
    return np.concatenate([np.cos(h)[..., None], np.sin(h)[..., None] * np.asarray(axis, dtype=np.float64)], axis=-1)


def _passive(axis: str, t) -> np.ndarray:
    """The notes' frame-rotation matrices Rx(t), Ry(t), Rz(t) (..., 3, 3): coordinates in the rotated frame."""
    t = np.asarray(t, dtype=np.float64)
    c, s = np.cos(t), np.sin(t)
    o, z = np.ones_like(t), np.zeros_like(t)
    if axis == "x":
        rows = [[o, z, z], [z, c, s], [z, -s, c]]
    elif axis == "y":
        rows = [[c, z, -s], [z, o, z], [s, z, c]]
    else:
        rows = [[c, s, z], [-s, c, z], [z, z, o]]
    return np.moveaxis(np.array(rows), (0, 1), (-2, -1))


def _radial_velocity(R: np.ndarray, v: np.ndarray, flat: np.ndarray) -> None:
    """ValueError for the first velocity along its position, showing the values as the caller
    gave them (the message showed the internal power-of-two rescaling: v = [3.4, 0, 0] was
    reported as [0.85 0. 0.], a vector the user never passed; a walk-through)."""
    k = int(np.argmax(flat))
    raise ValueError(f"v[{k}] = {np.asarray(v[k]).tolist()} has no component perpendicular to R[{k}] = "
                     f"{np.asarray(R[k]).tolist()}: the along-track axis is undefined")


def frame_angles(R, v):
    """The notes' recommended rotation angles (radians) from state vectors.

    ``lam``: east longitude of the sub-spacecraft point; ``beta``: its
    areocentric latitude; ``alpha``: the angle of the non-radial velocity
    ``v_perp = v - (R_hat . v) R_hat`` from the local parallel (east) toward
    north, from atan2 so that a southbound track has alpha < 0 (the notes'
    arccos gives only 0-180 deg, note 8). Raises ValueError when the velocity
    is radial (the along-track direction is undefined).
    """
    R = _vectors(R, "R")
    v = _vectors(v, "v")
    if len(v) != len(R) and len(v) != 1 and len(R) != 1:
        raise ValueError(f"R and v: {len(R)} positions do not broadcast against {len(v)} velocities")
    n = max(len(R), len(v))
    R = np.broadcast_to(R, (n, 3))
    v = np.broadcast_to(v, (n, 3))
    _nonzero(R, "R")
    v_in = v
    # directions only: scaled by powers of two (exact), so that no magnitude overflows
    Rs, v = _pow2_scaled(R), _pow2_scaled(v)
    rh = Rs / np.linalg.norm(Rs, axis=1)[:, None]
    lam = np.arctan2(rh[:, 1], rh[:, 0])
    beta = np.arctan2(rh[:, 2], np.hypot(rh[:, 0], rh[:, 1]))
    vperp = v - np.sum(v * rh, axis=1)[:, None] * rh
    vp = np.linalg.norm(vperp, axis=1)
    vn = np.linalg.norm(v, axis=1)
    flat = ~(vp > 1e-12 * np.maximum(vn, 1e-300))
    if flat.any():
        _radial_velocity(R, v_in, flat)
    east = np.stack([-np.sin(lam), np.cos(lam), np.zeros(n)], axis=1)
    north = np.stack([-np.sin(beta) * np.cos(lam), -np.sin(beta) * np.sin(lam), np.cos(beta)], axis=1)
    alpha = np.arctan2(np.sum(vperp * north, axis=1), np.sum(vperp * east, axis=1))   # [note 8]
    return lam, beta, alpha


def spacecraft_quaternion(R, v) -> np.ndarray:
    """The spacecraft-local frame as a unit quaternion (w, x, y, z), scalar first.

    ``q = q_{+z}(lam) q_{-y}(beta) q_{+x}(alpha)`` (the notes' recommended
    sequence with beta, not 90 deg + beta, and no conjugates: note 9), where
    ``q_{axis}(t) = cos(t/2) + axis sin(t/2)``. Direction: ``q e_i q*`` is the
    frame's i-th axis in the planet frame (``quat_to_matrix(q)`` = M^T), so the
    coordinates of a planet-frame vector w in the spacecraft frame are
    ``q* w q`` (the notes' L_q*, a frame rotation) = ``M w``.
    Shape (4,) for one state vector, (N, 4) for N.
    """
    single = np.ndim(R) == 1 and np.ndim(v) == 1
    lam, beta, alpha = frame_angles(R, v)
    q = quat_multiply(quat_multiply(_axis_quat([0, 0, 1], lam), _axis_quat([0, -1, 0], beta)),
                      _axis_quat([1, 0, 0], alpha))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return q[0] if single else q


def spacecraft_frame(R, v, method: str = "state") -> np.ndarray:
    """The spacecraft-local frame M: rows are the frame's unit axes in the planet frame.

    x = R/|R| (the zenith, up at the sub-spacecraft point); y = the unit
    non-radial velocity (along the ground track, forward); z = x cross y (to
    the left of the track seen from above). Coordinates of a planet-frame
    vector w in this frame are ``M @ w`` [note 9].

    method: "state" (the axes built directly from R and v), "rotations" (the
    notes' recommended sequence as matrices: ``Rx(alpha) Ry(-beta) Rz(lam)``
    in the notes' frame-rotation matrices), "quaternion" (from
    :func:`spacecraft_quaternion`), "orbit" (the notes' first construction,
    ``Rz(nu) Rx(i) Rz(Omega)`` with the ascending node, inclination and
    argument of latitude of the osculating orbit of (R, v) in the planet-fixed
    frame, :func:`orbit_frame`). All four agree to rounding (tested, 1e-12).
    Shape (3, 3) for one state vector, (N, 3, 3) for N.
    """
    single = np.ndim(R) == 1 and np.ndim(v) == 1
    if method == "state":
        lam, beta, alpha = frame_angles(R, v)          # validates; the angles are not used
        Rv = _pow2_scaled(np.broadcast_to(_vectors(R, "R"), (len(lam), 3)))
        vv = _pow2_scaled(np.broadcast_to(_vectors(v, "v"), (len(lam), 3)))
        x = Rv / np.linalg.norm(Rv, axis=1, keepdims=True)
        y = vv - np.sum(vv * x, axis=1)[:, None] * x
        y /= np.linalg.norm(y, axis=1, keepdims=True)
        M = np.stack([x, y, np.cross(x, y)], axis=1)
    elif method == "rotations":
        lam, beta, alpha = frame_angles(R, v)
        M = _passive("x", alpha) @ _passive("y", -beta) @ _passive("z", lam)
    elif method == "quaternion":
        q = np.atleast_2d(spacecraft_quaternion(R, v))
        M = np.swapaxes(quat_to_matrix(q), -1, -2)
    elif method == "orbit":
        M = orbit_frame(R, v)[0]
        M = np.atleast_3d(M) if M.ndim == 2 else M
        M = M.reshape(-1, 3, 3)
    else:
        raise ValueError(f"method must be 'state', 'rotations', 'quaternion' or 'orbit', got {method!r}")
    return M[0] if single else M


def orbit_frame(R, v):
    """The notes' first construction: node, inclination and argument (matrices and quaternion).

    From the osculating orbit of (R, v) in the planet-fixed frame: h = R x v,
    inclination i = angle of h from +z, ascending node Omega = longitude of
    z x h (0 for an equatorial orbit), argument of latitude nu = angle from the
    node to R in the orbit plane. Returns ``(M, q, (Omega, i, nu))`` with
    ``M = Rz(nu) Rx(i) Rz(Omega)`` (the notes' frame-rotation matrices; the
    notes print the first factor as an x rotation, note 10) and
    ``q = q_z(Omega) q_x(i) q_z(nu)``. The frame equals :func:`spacecraft_frame`'s.
    """
    R = _vectors(R, "R")
    v = _vectors(v, "v")
    if len(v) != len(R) and len(v) != 1 and len(R) != 1:
        raise ValueError(f"R and v: {len(R)} positions do not broadcast against {len(v)} velocities")
    n = max(len(R), len(v))
    _nonzero(R, "R")
    _nonzero(v, "v")
    # directions only (the frame and the angles): scaled by powers of two, exact
    R = np.broadcast_to(_pow2_scaled(R), (n, 3))
    v = np.broadcast_to(_pow2_scaled(v), (n, 3))
    h = np.cross(R, v)
    hn = np.linalg.norm(h, axis=1)
    if (hn == 0).any():
        k = int(np.argmax(hn == 0))
        raise ValueError(f"v[{k}] is parallel to R[{k}]: no orbit plane")
    inc = np.arctan2(np.hypot(h[:, 0], h[:, 1]), h[:, 2])
    node = np.stack([-h[:, 1], h[:, 0], np.zeros(n)], axis=1)           # z x h
    nn = np.linalg.norm(node, axis=1)
    node = np.where(nn[:, None] > 1e-15 * hn[:, None], node, np.array([1.0, 0.0, 0.0]))
    node /= np.linalg.norm(node, axis=1, keepdims=True)
    omega = np.arctan2(node[:, 1], node[:, 0])
    hh = h / hn[:, None]
    nu = np.arctan2(np.sum(np.cross(node, R) * hh, axis=1), np.sum(node * R, axis=1))
    M = _passive("z", nu) @ _passive("x", inc) @ _passive("z", omega)
    q = quat_multiply(quat_multiply(_axis_quat([0, 0, 1], omega), _axis_quat([1, 0, 0], inc)),
                      _axis_quat([0, 0, 1], nu))
    return M, q, (omega, inc, nu)


# ----------------------------------------------------------------------------------------
# position angle
# ----------------------------------------------------------------------------------------
#: angles (deg) from here up to 360 are reported as 0: four ulp of 360 (2.3e-13 deg, 4e-15 rad), far
#: below the angles' accuracy (~1e-13 deg), so that a due-north cell does not come out as
#: 359.99999999999994 in the documented range [0, 360) (a walk-through) [note 5]
_SNAP_360 = 360.0 - 4 * 2.0 ** -44


def _snap_360(a: np.ndarray) -> None:
    """In place: values of a within four ulp below 360 (deg) set to 0 (NaN left as is)."""
    a[a >= _SNAP_360] = 0.0


def position_angle(R, r_c) -> np.ndarray:
    """Position angle (deg, [0, 360)) of points r_c seen from the sub-spacecraft point of R.

    Clockwise from north (toward the north pole along the sub-spacecraft
    meridian) through east: ``atan2(u . E, u . N)`` with u = r_c/|r_c|,
    E = z x R_hat and N = z - (z . R_hat) R_hat (both |.| = cos beta, which
    cancels) [note 5]. NaN over a pole and at the sub-spacecraft point itself
    (within 1e-13 rad, the kernel's rule). Broadcasts R (3,)/(N, 3) against
    r_c (3,)/(N, 3).
    """
    R = _vectors(R, "R")
    r_c = _vectors(r_c, "r_c")
    if len(R) != len(r_c) and 1 not in (len(R), len(r_c)):
        raise ValueError(f"R and r_c: {len(R)} positions do not broadcast against {len(r_c)} points")
    _nonzero(R, "R")
    _nonzero(r_c, "r_c")
    R, r_c = _pow2_scaled(R), _pow2_scaled(r_c)                # exact: directions only
    rh = R / np.linalg.norm(R, axis=1)[:, None]
    u = r_c / np.linalg.norm(r_c, axis=1)[:, None]
    E = np.stack([-rh[:, 1], rh[:, 0], np.zeros(len(rh))], axis=1)
    # N's z component x^2 + y^2 (= 1 - z^2 for a unit R_hat without its cancellation near a pole)
    N = np.stack([-rh[:, 2] * rh[:, 0], -rh[:, 2] * rh[:, 1], rh[:, 0] ** 2 + rh[:, 1] ** 2], axis=1)
    x = np.sum(u * E, axis=1)
    y = np.sum(u * N, axis=1)
    pa = np.degrees(np.arctan2(x, y)) % 360.0
    pa = np.where(pa >= _SNAP_360, 0.0, pa)                   # [0, 360): 360 less rounding is 0 [note 5]
    cb = np.hypot(rh[:, 0], rh[:, 1])
    bad = (cb <= 1e-12) | ~(np.hypot(x, y) > 1e-13 * cb)
    return np.where(bad, np.nan, pa)


def position_angle_notes(R, r_c, normalize: bool = False) -> np.ndarray:
    """The notes' position-angle recipe (deg), literally or with unit vectors.

    ``Q1 = P_hat x R_hat``, ``Q2 = R_hat x r_hat``,
    ``cos PA = (R_hat x Q1) . (Q2 x R_hat)``. Taken literally the two cross
    products are not unit vectors (``|R_hat x Q1| = cos beta_sc``,
    ``|Q2 x R_hat| = sin`` of the cell's central angle), so cos PA is far too
    small and PA comes out near 90 deg for every cell; normalised, arccos still
    gives only 0-180 deg and cannot tell east from west [note 5].
    """
    R = np.atleast_2d(np.asarray(R, dtype=np.float64))
    r_c = np.atleast_2d(np.asarray(r_c, dtype=np.float64))
    rh = R / np.linalg.norm(R, axis=-1, keepdims=True)
    rc = r_c / np.linalg.norm(r_c, axis=-1, keepdims=True)
    P = np.array([0.0, 0.0, 1.0])
    q1 = np.cross(P, rh)
    q2 = np.cross(rh, rc)
    a = np.cross(rh, q1)
    b = np.cross(q2, rh)
    if normalize:
        a /= np.linalg.norm(a, axis=-1, keepdims=True)
        b /= np.linalg.norm(b, axis=-1, keepdims=True)
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=-1), -1.0, 1.0)))


# ----------------------------------------------------------------------------------------
# scale height and air mass
# ----------------------------------------------------------------------------------------
def scale_height(T: float = 210.0, r: float = MARS_MEAN_RADIUS_KM, GM: float = MARS_GM,
                 molecular_mass: float = MARS_CO2_MOLECULAR_MASS) -> float:
    """Atmospheric scale height ``H = k T / (m g)`` with ``g = GM / r^2``, in km.

    T in K (default 210 K, a Mars mean near-surface temperature); r in km (the
    radius where g is taken, default the Mars mean radius 3389.5 km); GM in
    km^3/s^2 (default Mars, GGM1025A); molecular_mass in atomic mass units
    (default 43.34, the mean of Mars' CO2-dominated atmosphere). Mars defaults
    give H = 10.8 km at 210 K. An r above 1e5 with the default GM cannot be
    km of Mars (a radius in metres) and is refused (docs/grs-notes.md, note 19).
    """
    T = _real(T, "T", lo=0.0, lo_open=True)
    r = _real(r, "r", lo=0.0, lo_open=True)
    GM = _real(GM, "GM", lo=0.0, lo_open=True)
    molecular_mass = _real(molecular_mass, "molecular_mass", lo=0.0, lo_open=True)
    with np.errstate(over="ignore", under="ignore", divide="ignore", invalid="ignore"):
        g = np.float64(GM) * 1e9 / (np.float64(r) * 1e3) ** 2      # m/s^2 (NumPy: overflow is inf, not an error)
        H = BOLTZMANN * np.float64(T) / (molecular_mass * AMU * g) / 1e3     # km
    if not (math.isfinite(H) and H > 0):
        # r = 1e160 overflowed, GM = 1e-300 divided by zero, GM = 1e308 gave 0 (a review)
        raise ValueError(f"scale_height: T = {T:g} K, r = {r:g} km, GM = {GM:g} km^3/s^2, molecular_mass = "
                         f"{molecular_mass:g} give no finite positive scale height")
    if r > KM_RADIUS_MAX and GM == MARS_GM:
        # r in metres with Mars's GM in km^3/s^2 gave H 1e6 too large [note 19]
        raise ValueError(f"r = {r:g} is too large to be kilometres of Mars (above {KM_RADIUS_MAX:g} km): "
                         f"scale_height takes r in km with the default GM (km^3/s^2) and returns km; "
                         f"pass r in km (times 1000 the result for metres), or give GM too")
    return float(H)


# Gauss-Legendre panels on tau in [0, 40] for the Chapman integral (see _chapman_le90)
def _chapman_nodes():
    x, w = np.polynomial.legendre.leggauss(24)
    edges = [0.0, 0.5, 1.5, 3.5, 7.0, 12.0, 20.0, 30.0, 40.0]
    nodes, weights = [], []
    for a, b in zip(edges[:-1], edges[1:]):
        nodes.append(0.5 * (b - a) * x + 0.5 * (b + a))
        weights.append(0.5 * (b - a) * w)
    return np.concatenate(nodes), np.concatenate(weights)


_CH_T, _CH_W = _chapman_nodes()


def _chapman_le90(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Exact Chapman function Ch(x, z) for 0 <= z <= 90 deg, x = R/H, given the
    co-angle w = 90 deg - z in radians (>= 0).

    Ch = (1/H) int_0^inf exp(-(r(s) - R)/H) ds along the straight line from
    radius R at zenith angle z. With c = x sin z, a = x - c and the height
    variable written as y = (sqrt(a) + s)^2 - a, the integrand becomes smooth:
    ``Ch = 2 int_0^inf exp(-2 sqrt(a) s - s^2) (c + (sqrt(a) + s)^2) / sqrt((sqrt(a) + s)^2 + 2c) ds``
    (no singularity at z = 90 deg, no overflow). Scaled by the e-folding
    length s1 = 1/(sqrt(a) + sqrt(a + 1)) the exponent is >= tau beyond
    tau = 1, so panels of Gauss-Legendre nodes on [0, 40] integrate it to
    rounding (the tail beyond is < 5e-18).

    1 - sin z is taken as 2 sin^2(w/2) from the co-angle: computed as 1 - sin z
    it lost all its digits near 90 deg, and with x = 3.4e6 (R = 3389.5, H = 1 m)
    Ch(x, 89.999999 deg) came out 3.7e-6 too high (the footprint fuzzing; an
    independent quadrature in mpmath gives 2307.36696943413).
    """
    c = x * np.cos(w)
    a = 2.0 * x * np.sin(0.5 * w) ** 2
    sa = np.sqrt(a)
    s1 = 1.0 / (sa + np.sqrt(a + 1.0))
    out = np.empty(np.shape(x))
    flat_n = out.size
    cf, af, saf, s1f = c.ravel(), a.ravel(), sa.ravel(), s1.ravel()
    res = out.ravel()
    step = max(1, (1 << 22) // _CH_T.size)
    for i in range(0, flat_n, step):
        sl = slice(i, i + step)
        s = s1f[sl, None] * _CH_T[None, :]
        w = saf[sl, None] + s
        f = np.exp(-2.0 * saf[sl, None] * s - s * s) * (cf[sl, None] + w * w) / np.sqrt(w * w + 2.0 * cf[sl, None])
        res[sl] = 2.0 * s1f[sl] * (f @ _CH_W)
    return res.reshape(np.shape(x))


def chapman(x, z_deg) -> np.ndarray:
    """Exact Chapman function Ch(x, z): relative air mass of a spherically stratified
    exponential atmosphere, x = R/H, zenith angle z in degrees, 0 <= z <= 180.

    Beyond 90 deg the line first descends to its tangent radius R sin z:
    ``Ch(x, z) = 2 exp(x (1 - sin z)) Ch(x sin z, 90) - Ch(x, 180 - z)`` (the
    line integral is symmetric about the tangent point). Returns inf where the
    value overflows (x (1 - sin z) > ~700).
    """
    x, z = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(z_deg, dtype=np.float64))
    # the co-angle |90 - z| from the degrees (exact near 90 deg), not from radians(z)
    w = np.radians(np.abs(90.0 - z))
    out = np.full(x.shape, np.nan)
    ok = np.isfinite(x) & np.isfinite(z) & (x > 0) & (z >= 0) & (z <= 180)
    lo = ok & (z <= 90)
    out[lo] = _chapman_le90(x[lo], w[lo])
    hi = ok & (z > 90)
    if hi.any():
        xs, ws = x[hi], w[hi]
        sz = np.cos(ws)                                   # sin z
        with np.errstate(over="ignore"):
            grow = np.exp(2.0 * xs * np.sin(0.5 * ws) ** 2)   # exp(x (1 - sin z))
        # Ch(x, 180 - z): the same co-angle on the other side of 90 deg
        out[hi] = 2.0 * grow * _chapman_le90(xs * sz, np.zeros(xs.shape)) - _chapman_le90(xs, ws)
    return out


_AIRMASS_MODELS = ("secant", "notes", "hardie", "chapman")

# Hardie's cubic X(s) = 1 + (1 - 0.0018167) s - 0.002875 s^2 - 0.0008083 s^3 in s = sec z - 1
# stops increasing where dX/ds = 0.9981833 - 0.00575 s - 0.0024249 s^2 = 0: its positive root
# (written 2c/(b + sqrt(b^2 + 4ac)), free of cancellation) s = 19.1378838, z = 87.1536556 deg,
# X = 13.3844128. Beyond it the fit falls (through 0 at 88.36 deg, to -2.5e7 at 89.98 deg): NaN there
# [note 20]
_HARDIE_S_PEAK = 2.0 * 0.9981833 / (0.00575 + math.sqrt(0.00575 ** 2 + 4.0 * 0.0024249 * 0.9981833))
#: zenith angle (deg) and value of the peak of Hardie's (1962) air-mass fit: beyond it airmass(model="hardie") is NaN
HARDIE_PEAK_DEG = math.degrees(math.acos(1.0 / (1.0 + _HARDIE_S_PEAK)))
HARDIE_PEAK_AIRMASS = (1.0 + _HARDIE_S_PEAK - 0.0018167 * _HARDIE_S_PEAK - 0.002875 * _HARDIE_S_PEAK ** 2
                       - 0.0008083 * _HARDIE_S_PEAK ** 3)


def airmass(z_deg, H: float | None = None, R: float | np.ndarray | None = None, model: str = "chapman") -> np.ndarray:
    """Relative air mass at zenith angle ``z_deg`` (degrees).

    model:

    * "secant": plane parallel, ``sec z`` (inf at 90 deg, NaN beyond).
    * "notes": the notes' spherical series exactly as printed,
      ``sec z - 0.018167 (sec z - 1)^2 - 0.002875 (sec z - 1)^3 - 0.0008083 (sec z - 1)^4``
      (Hardie's fit with the first coefficient ten times his and every power
      one higher: 12 % low at 80 deg and negative at 85 deg for Mars, note 4);
      NaN at and beyond 90 deg.
    * "hardie": Hardie (1962), ``sec z - 0.0018167 (sec z - 1) - 0.002875 (sec z - 1)^2
      - 0.0008083 (sec z - 1)^3`` (a fit for Earth's atmosphere, z < ~85 deg). The cubic in
      ``s = sec z - 1`` peaks where ``0.9981833 - 0.00575 s - 0.0024249 s^2 = 0``:
      s = 19.1378838, z = 87.1536556 deg (``HARDIE_PEAK_DEG``), X = 13.3844128
      (``HARDIE_PEAK_AIRMASS``); beyond it the formula falls (0 at 88.36 deg, -2.5e7 at
      89.98 deg) and the value is NaN, as at and beyond 90 deg (docs/grs-notes.md, note 20).
    * "chapman": exact for a spherically stratified exponential atmosphere of
      scale height H above radius R (the same unit; km for the defaults), valid
      from 0 to 180 deg (:func:`chapman` with x = R/H). H defaults to
      :func:`scale_height` (Mars, 210 K, 10.8 km), R to the Mars mean radius
      (3389.5 km). The default H is refused (ValueError naming H) when R
      exceeds 1e5, which cannot be km of any body the notes concern: pass H in
      R's unit (docs/grs-notes.md, note 19).

    H and R are the Chapman model's: the other models do not use them (the
    signature is one for all models, DESIGN section 10; a review asked).
    """
    if model not in _AIRMASS_MODELS:
        raise ValueError(f"model must be one of {', '.join(_AIRMASS_MODELS)}, got {model!r}")
    z = _angles(z_deg, "z_deg", 180.0, lo=0.0)
    if model == "chapman":
        if H is not None:
            H = _real(H, "H", lo=0.0, lo_open=True)
        if R is None:
            R = MARS_MEAN_RADIUS_KM
        if np.iscomplexobj(R):
            raise ValueError("R: radii must be real")
        R = np.asarray(R, dtype=np.float64)
        if not (np.isfinite(R).all() and (R > 0).all()):
            raise ValueError("R: radii must be positive and finite")
        if H is None:
            # the default H is in km: R beyond any body's km radius is in another unit [note 19]
            _km_defaults(float(np.max(R)) if R.size else 0.0, "R", False, True)
            H = scale_height()
        with np.errstate(over="ignore"):
            x = R / H
        if not np.isfinite(x).all():
            raise ValueError(f"R / H overflows (H = {H:g}): the scale height is too small for these radii")
        try:
            x, z = np.broadcast_arrays(x, z)
        except ValueError:
            raise ValueError(f"z_deg and R: shapes {np.shape(z)} and {np.shape(R)} do not broadcast") from None
        return chapman(x, z)
    with np.errstate(divide="ignore", invalid="ignore"):
        sec = 1.0 / np.cos(np.radians(z))
    sec = np.where(z == 90.0, np.inf, sec)
    if model == "secant":
        return np.where(z > 90.0, np.nan, sec)
    s1 = sec - 1.0
    with np.errstate(invalid="ignore"):
        if model == "notes":
            x = sec - 0.018167 * s1 ** 2 - 0.002875 * s1 ** 3 - 0.0008083 * s1 ** 4     # as printed [note 4]
        else:
            x = sec - 0.0018167 * s1 - 0.002875 * s1 ** 2 - 0.0008083 * s1 ** 3       # Hardie (1962)
            # beyond its peak (87.15 deg) the fit falls, to -2.5e7 near 90 deg: NaN [note 20]
            x = np.where(s1 > _HARDIE_S_PEAK, np.nan, x)
    x = np.where(z >= 90.0, np.nan, x)
    if model == "notes":
        with np.errstate(invalid="ignore"):
            neg = int(np.count_nonzero(x < 0))
        if neg:
            # as printed, and documented; a CLI run wrote 9,144 negative air masses without a word (a review)
            warnings.warn(f"airmass model 'notes' (the series exactly as printed, docs/grs-notes.md note 4) is "
                          f"negative at {neg:,} of the zenith angles (from ~85 deg): 'chapman' or 'hardie' "
                          f"give physical values", UserWarning, stacklevel=2)
    return x


# ----------------------------------------------------------------------------------------
# the footprint
# ----------------------------------------------------------------------------------------
_PAIR_FIELDS = ("spectrum", "cell", "d", "distance", "solid_angle", "zenith_centric", "zenith_detic", "emission",
                "nadir_angle", "position_angle", "gsh", "azimuth", "elevation", "visible")


@dataclass(eq=False)
class FootprintResult:
    """Geometry of every (spectrum, cell) pair in the footprints, flat over the pairs.

    Pairs are ordered by spectrum, then cell row (south to north), then
    column eastward from the footprint's western edge in that row: where a
    row's footprint crosses 0 E the column indices wrap (e.g. ..., 118, 119,
    0, 1, ... of 120), so ``cell`` is not sorted within a spectrum (the
    fuzzing found the earlier wording, "then column", untrue there). Angles in
    degrees, lengths in the DEM's units.

    spectrum, cell : int arrays
        Index of the state vector and of the cell (into the :class:`CellTable`).
    d : (M, 3)
        ``R - r_C``, from the cell to the spacecraft, planet frame.
    distance, solid_angle :
        ``|d|`` and ``area/|d|^2`` (sr).
    zenith_centric, zenith_detic, emission :
        Angle of d from the areocentric normal r_C/|r_C|, the spheroid normal at
        the cell's areodetic latitude, and the cell's topographic normal.
    nadir_angle :
        psi, ``cos psi = d_hat . R_hat``.
    position_angle :
        Azimuth of the cell from the sub-spacecraft point, clockwise from north
        through east, [0, 360).
    gsh : (M, 3)
        ``r_C - R`` in the spacecraft frame (x up, y along track, z left).
    azimuth, elevation :
        Direction of the cell in the spacecraft frame: azimuth from +y (forward)
        toward +z (left), [0, 360); elevation above the y-z plane (negative below).
        The azimuth and the position angle are NaN for a cell at the
        sub-spacecraft point (within 1e-13 rad: straight down) [note 5]. Without
        a velocity (``v=None``) the azimuth is NaN and the elevation, which
        needs only R, is still given.
    visible : bool
        False when ``occlusion=True`` found the terrain blocking the line to the
        spacecraft (such pairs stay in the arrays; the footprint proper is
        ``fp.subset(fp.visible)``); True otherwise.
    zeta : (N,)
        The cos psi threshold used for each spectrum.
    airmass : (M,)
        Computed on first access: :func:`airmass` of ``zenith_centric`` with the
        model, H and the cell's radius given to :func:`footprint` [note 4].

    ``a == b`` is True when both hold the same pairs with every array equal
    exactly (NaN equal to NaN), the same ``airmass_model`` and ``H``, and cell
    tables of the same DEM object and cell size; for a tolerance compare the
    arrays (``np.allclose(a.emission, b.emission)``). Results are not hashable.
    """

    spectrum: np.ndarray
    cell: np.ndarray
    d: np.ndarray
    distance: np.ndarray
    solid_angle: np.ndarray
    zenith_centric: np.ndarray
    zenith_detic: np.ndarray
    emission: np.ndarray
    nadir_angle: np.ndarray
    position_angle: np.ndarray
    gsh: np.ndarray
    azimuth: np.ndarray
    elevation: np.ndarray
    visible: np.ndarray
    zeta: np.ndarray
    cells: CellTable = field(repr=False)
    airmass_model: str = "chapman"
    H: float | None = None
    _airmass: np.ndarray | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return len(self.spectrum)

    # the dataclass's own == compared the arrays as tuples and raised "the truth value of an
    # array ... is ambiguous" (a walk-through): an equality of values instead
    def __eq__(self, other):
        if not isinstance(other, FootprintResult):
            return NotImplemented
        if self is other:
            return True
        same_cells = self.cells is other.cells or (self.cells.dem is other.cells.dem
                                                   and self.cells.cell_deg == other.cells.cell_deg)
        if not (same_cells and self.airmass_model == other.airmass_model and self.H == other.H):
            return False
        for name in _PAIR_FIELDS + ("zeta",):
            a, b = np.asarray(getattr(self, name)), np.asarray(getattr(other, name))
            if a.shape != b.shape:
                return False
            if not np.array_equal(a, b, equal_nan=a.dtype.kind == "f" and b.dtype.kind == "f"):
                return False
        return True

    __hash__ = None          # mutable arrays: not hashable (as the dataclass made it)

    @property
    def airmass(self) -> np.ndarray:
        if self._airmass is None:
            if self.airmass_model is None:
                self._airmass = np.full(len(self), np.nan)
            else:
                self._airmass = airmass(np.minimum(self.zenith_centric, 180.0), H=self.H,
                                        R=self.cells.radius[self.cell], model=self.airmass_model)
        return self._airmass

    @property
    def n_spectra(self) -> int:
        return len(self.zeta)

    def counts(self, visible_only: bool = True) -> np.ndarray:
        """Number of footprint cells per spectrum (visible ones only by default)."""
        sel = self.visible if visible_only else np.ones(len(self), bool)
        return np.bincount(self.spectrum[sel], minlength=self.n_spectra)

    def subset(self, mask) -> "FootprintResult":
        """The pairs where ``mask`` is True (e.g. ``fp.subset(fp.visible)``)."""
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != (len(self),):
            raise ValueError(f"mask: expected shape ({len(self)},), got {mask.shape}")
        kw = {name: getattr(self, name)[mask] for name in _PAIR_FIELDS}
        out = FootprintResult(**kw, zeta=self.zeta, cells=self.cells, airmass_model=self.airmass_model, H=self.H)
        if self._airmass is not None:
            out._airmass = self._airmass[mask]
        return out

    def to_table(self) -> dict:
        """Flat columns for CSV (vectors split into _x/_y/_z; cell lat/lon added)."""
        cols = {"spectrum": self.spectrum, "cell": self.cell,
                "lat": self.cells.lat[self.cell], "lon": self.cells.lon[self.cell]}
        for name in _PAIR_FIELDS[2:]:
            value = getattr(self, name)
            if value.ndim == 2:
                for k, axis in enumerate("xyz"):
                    cols[f"{name}_{axis}"] = value[:, k]
            else:
                cols[name] = value
        cols["airmass"] = self.airmass
        return cols

    def to_xarray(self, layout: str = "pairs", length_unit: str | None = None):
        """An ``xarray.Dataset``: ``layout="pairs"`` (dimension ``pair``, with the
        spectrum and cell of each as coordinates) or ``"dense"`` (dimensions
        ``spectrum`` x ``cell`` over the cells that occur in any footprint, NaN
        where a cell is not in a spectrum's footprint; every spectrum keeps its row,
        so one left without pairs by :meth:`subset` is a row of NaN, its index and
        zeta unchanged).

        Every variable and coordinate has ``units`` and ``long_name`` attributes
        (angles "degree", lat/lon "degrees_north"/"degrees_east", solid angle
        "sr", air mass and zeta "1"). Lengths (d, distance, gsh) are in the
        DEM's unit, which the DEM does not record: their ``units`` is
        ``length_unit`` when given (e.g. "km" for the Mars grids), else
        "DEM length unit"."""
        import xarray as xr

        if length_unit is not None and not isinstance(length_unit, str):
            raise TypeError(f"length_unit must be a string such as 'km' or 'm', got {length_unit!r}")

        attrs = dict(angles="degrees; position_angle clockwise from north through east [0, 360)",
                     frame="planet-fixed, x to 0N 0E, z north; gsh: x up, y along track, z left",
                     cell_deg=self.cells.cell_deg, airmass_model=str(self.airmass_model))
        if layout == "pairs":
            data = {}
            for name in _PAIR_FIELDS[2:]:
                value = getattr(self, name)
                data[name] = (("pair", "xyz"), value) if value.ndim == 2 else ("pair", value)
            data["airmass"] = ("pair", self.airmass)
            data["zeta"] = ("spectrum", self.zeta)
            coords = {"pair": np.arange(len(self)), "xyz": ["x", "y", "z"],
                      "pair_spectrum": ("pair", self.spectrum), "pair_cell": ("pair", self.cell),
                      "spectrum": np.arange(self.n_spectra),
                      "lat": ("pair", self.cells.lat[self.cell]), "lon": ("pair", self.cells.lon[self.cell])}
            return self._var_attrs(xr.Dataset(data, coords=coords, attrs=attrs), length_unit)
        if layout != "dense":
            raise ValueError(f"layout must be 'pairs' or 'dense', got {layout!r}")
        used, col = np.unique(self.cell, return_inverse=True)
        ns = self.n_spectra
        data = {}
        for name in _PAIR_FIELDS[2:] + ("airmass",):
            value = getattr(self, name)
            if name == "visible":
                grid = np.zeros((ns, len(used)), dtype=bool)
            else:
                grid = np.full((ns, len(used)) + value.shape[1:], np.nan)
            grid[self.spectrum, col] = value
            data[name] = (("spectrum", "cell", "xyz"), grid) if value.ndim == 2 else (("spectrum", "cell"), grid)
        # (visible=False also meant "not in the footprint" there, like "hidden by terrain": a review)
        inside = np.zeros((ns, len(used)), dtype=bool)
        inside[self.spectrum, col] = True
        data["in_footprint"] = (("spectrum", "cell"), inside)
        data["zeta"] = ("spectrum", self.zeta)
        coords = {"spectrum": np.arange(ns), "cell": used, "xyz": ["x", "y", "z"],
                  "lat": ("cell", self.cells.lat[used]), "lon": ("cell", self.cells.lon[used])}
        return self._var_attrs(xr.Dataset(data, coords=coords, attrs=attrs), length_unit)

    def _var_attrs(self, ds, length_unit: str | None):
        """units and long_name of each variable and coordinate present in ds (only a global
        "angles: degrees" until a walk-through asked for them per variable)."""
        L = length_unit if length_unit is not None else _DEM_LENGTH_UNIT
        table = dict(_XARRAY_ATTRS)
        table["airmass"] = ("1", f"relative air mass at zenith_centric ({self.airmass_model} model)")
        for name, (units, long_name) in table.items():
            if name in ds.variables:
                if units is not None:
                    ds[name].attrs["units"] = L if units == "L" else units
                ds[name].attrs["long_name"] = long_name
        return ds


#: units of the lengths in to_xarray when the caller does not name the DEM's unit
_DEM_LENGTH_UNIT = "DEM length unit"

#: CellTable.to_xarray's per-variable attributes (lengths in the DEM's unit, which it does not record)
_CELL_XARRAY_ATTRS = {
    "lat": ("degrees_north", "areocentric latitude of the cell centre"),
    "lon": ("degrees_east", "east longitude of the cell centre"),
    "lat_detic": ("degrees_north", "areodetic latitude of the cell's centre point r"),
    "lat_detic_spheroid": ("degrees_north", "areodetic latitude of the spheroid point at the centre's areocentric "
                                            "latitude"),
    "radius": ("DEM length unit", "the cell's mean radius r0 (fitted plane at the centre)"),
    "radius_dem": ("DEM length unit", "the DEM's bilinear radius at the cell centre"),
    "area": ("DEM length unit squared", "area of the cell's latitude/longitude box on the sphere of radius r0"),
    "slope": ("degree", "angle between the cell's topographic normal and the spheroid normal normal_detic"),
    "r": ("DEM length unit", "cell centre point r0 u, planet-fixed frame"),
    "normal": ("1", "unit outward normal of the cell's fitted surface, planet-fixed frame"),
    "normal_detic": ("1", "unit spheroid normal at (lat_detic, lon), planet-fixed frame"),
    "cell": ("1", "index of the cell in the table, row-major from the south-west"),
    "xyz": ("1", "vector component"),
}

#: to_xarray's per-variable attributes: (units, "L" = the DEM's length unit, None for none; long_name)
_XARRAY_ATTRS = {
    "d": ("L", "cell centre to spacecraft, R - r_C, planet-fixed frame"),
    "distance": ("L", "distance from the cell centre to the spacecraft, |d|"),
    "solid_angle": ("sr", "solid angle of the detector seen from the cell, area / |d|^2"),
    "zenith_centric": ("degree", "zenith angle of the spacecraft at the cell, from the areocentric normal"),
    "zenith_detic": ("degree", "zenith angle of the spacecraft at the cell, from the areodetic (spheroid) normal"),
    "emission": ("degree", "emission angle, from the cell's topographic normal"),
    "nadir_angle": ("degree", "nadir angle psi of the cell seen from the spacecraft"),
    "position_angle": ("degree", "bearing of the cell from the sub-spacecraft point, clockwise from north "
                                 "through east, [0, 360)"),
    "gsh": ("L", "r_C - R in the spacecraft frame (x up, y along track, z left)"),
    "azimuth": ("degree", "direction of the cell in the spacecraft frame, from +y (forward) toward +z (left), "
                          "[0, 360)"),
    "elevation": ("degree", "elevation of the cell above the spacecraft frame's y-z plane"),
    "visible": ("1", "line of sight not blocked by terrain (all True without occlusion); dense layout: "
                     "False also where the cell is not in the footprint (see in_footprint)"),
    "in_footprint": ("1", "the cell is in the spectrum's footprint (dense layout)"),
    "zeta": ("1", "cos psi threshold of the footprint cone, per spectrum"),
    "lat": ("degrees_north", "areocentric latitude of the cell centre"),
    "lon": ("degrees_east", "east longitude of the cell centre"),
    "pair_spectrum": ("1", "index of the pair's spectrum (state vector)"),
    "pair_cell": ("1", "index of the pair's cell in the cell table"),
    "spectrum": ("1", "index of the spectrum (state vector)"),
    "cell": ("1", "index of the cell in the cell table"),
    "pair": ("1", "index of the (spectrum, cell) pair"),
    "xyz": ("1", "vector component"),
}


class _PairBuffers:
    """Flat output memory for ``capacity`` pairs, filled in place by the kernel and viewed
    in the results' final layout (Fortran order of the kernel's arrays, no copies)."""

    def __init__(self, capacity: int):
        self.capacity = int(capacity)
        c = max(self.capacity, 1)
        self.idx = np.empty(2 * c, dtype=np.int32)
        self.d = np.empty(3 * c)
        self.gsh = np.empty(3 * c)
        self.scal = np.empty(9 * c)
        self.visible = np.empty(c, dtype=bool)

    def views(self, m: int):
        """(idx (m, 2), d (3, m), gsh (3, m), scal (m, 9)) Fortran-ordered views of the first m pairs."""
        return (self.idx[:2 * m].reshape((m, 2), order="F"), self.d[:3 * m].reshape((3, m), order="F"),
                self.gsh[:3 * m].reshape((3, m), order="F"), self.scal[:9 * m].reshape((m, 9), order="F"))


def _state_frames(R: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``spacecraft_frame(R, v, method="state")`` for checked (N, 3) R and v: the same
    arithmetic (bit for bit) and the same error for a radial velocity, without
    :func:`frame_angles`' angles, which footprint() does not use (a third of its
    per-call time for one spectrum per call). Both are scaled by powers of two first
    (exact: the same frame for any magnitude)."""
    R_in, v_in = R, v
    R, v = _pow2_scaled(R), _pow2_scaled(v)
    x = R / np.linalg.norm(R, axis=1, keepdims=True)
    y = v - np.sum(v * x, axis=1)[:, None] * x
    vp = np.linalg.norm(y, axis=1)
    flat = ~(vp > 1e-12 * np.maximum(np.linalg.norm(v, axis=1), 1e-300))
    if flat.any():
        _radial_velocity(R_in, v_in, flat)
    y /= vp[:, None]
    M = np.empty((len(R), 3, 3))
    M[:, 0] = x
    M[:, 1] = y
    # x cross y as numpy.cross evaluates it (a1 b2 - a2 b1, ...)
    M[:, 2, 0] = x[:, 1] * y[:, 2] - x[:, 2] * y[:, 1]
    M[:, 2, 1] = x[:, 2] * y[:, 0] - x[:, 0] * y[:, 2]
    M[:, 2, 2] = x[:, 0] * y[:, 1] - x[:, 1] * y[:, 0]
    return M


def _run_kernel(cells: CellTable, R: np.ndarray, frames: np.ndarray, zeta: np.ndarray, area: float, threads: int,
                ascale: float = 1.0, buffers: "_PairBuffers | None" = None):
    """Both kernel passes; returns (idx, d, gsh, scal, buffers). The angles come out times
    ``ascale`` (180/pi: degrees). ``buffers`` is reused when it holds enough pairs."""
    from ._ext import core as _core

    cd = math.radians(cells.cell_deg)
    u = cells.u
    rmin, rtop = cells.radius_range
    counts, status, stat = _core.core_footprint_count(R.T, zeta, cells.nrow, cells.ncol, cd, u.T, cells.radius,
                                                      rmin, rtop, threads=threads)
    _raise_status(stat, status, R, cells)
    offsets = np.zeros(len(R), dtype=np.int64)
    if len(R) > 1:
        np.cumsum(counts[:-1], out=offsets[1:])
    m = int(counts.sum())
    if buffers is None or buffers.capacity < m:
        # reused memory that is too small grows by half at least, so that a sequence of
        # calls with slowly growing footprints (one spectrum per call along an orbit)
        # does not take fresh memory, and its page faults, on almost every call
        grow = 0 if buffers is None else buffers.capacity + buffers.capacity // 2
        buffers = _PairBuffers(max(m, grow))
    idx, d, gsh, scal = buffers.views(m)
    if m == 0:                      # nothing to fill (f2py refuses zero-size in-place arrays)
        return idx, d, gsh, scal, buffers
    fr = np.ascontiguousarray(frames)
    status, stat = _core.core_footprint_fill(
        R.T, fr.transpose(2, 1, 0), zeta, cells.nrow, cells.ncol, cd, u.T, cells.radius, rmin, rtop,
        cells.normal_detic.T, cells.normal.T, area, ascale, offsets, m, idx, d, gsh, scal, threads=threads)
    _raise_status(stat, status, R, cells)
    return idx, d, gsh, scal, buffers


#: largest |component| of a spacecraft position: |R - r_C|^2 stays finite (a review found
#: |R| ~ 1e155 returned with distance inf, solid angle 0 and emission up to 120 deg)
_R_COMPONENT_MAX = 1e150


def _check_above_surface(cells: CellTable, R: np.ndarray) -> None:
    """ValueError naming R where a position is too far to compute with or not above the DEM's
    surface at its own sub-spacecraft point (checked only for |R| <= rmax, which bounds every
    radius of the DEM)."""
    big = np.max(np.abs(R), axis=1) > _R_COMPONENT_MAX
    if big.any():
        k = int(np.argmax(big))
        raise ValueError(f"R[{k}] = {R[k]} is too far from the centre (a component above {_R_COMPONENT_MAX:g} "
                         f"DEM units): |R - r_C|^2 would overflow")
    rn = np.linalg.norm(R, axis=1)
    near = np.flatnonzero(rn <= cells.dem.rmax)
    if near.size == 0:
        return
    Rn = R[near]
    lat = np.degrees(np.arctan2(Rn[:, 2], np.hypot(Rn[:, 0], Rn[:, 1])))
    lon = np.degrees(np.arctan2(Rn[:, 1], Rn[:, 0])) % 360.0
    rs = cells.dem.radius(lat, lon)
    low = np.flatnonzero(~(rn[near] > rs))
    if low.size:
        i = int(low[0])
        k = int(near[i])
        raise ValueError(f"R[{k}] = {R[k]} (|R| = {rn[k]:.6g}) is not above the surface: the DEM radius at its "
                         f"sub-spacecraft point ({lat[i]:.6g} N, {lon[i]:.6g} E) is {rs[i]:.6g}")


def _raise_status(stat, status, R, cells):
    if stat != 0:
        raise RuntimeError(f"footprint kernel: {FOOTPRINT_STATUS.get(int(stat), stat)} (status {stat})")
    bad = np.flatnonzero(status)
    if bad.size:
        k = int(bad[0])
        if status[k] == 2:
            # footprint() has checked the surface under R: this is the kernel's own limit [note 17]
            top = int(np.argmax(cells.radius))
            raise ValueError(f"R[{k}] = {R[k]} (|R| = {np.linalg.norm(R[k]):.6g}) is above the surface at its "
                             f"sub-spacecraft point but not above the highest cell centre ({cells.radius[top]:.6g}, "
                             f"cell {top} at {cells.lat[top]:.6g} N, {cells.lon[top]:.6g} E): the footprint's cell "
                             f"search needs the spacecraft above every cell centre (docs/grs-notes.md, note 17)")
        raise ValueError(f"R[{k}] = {R[k]}: {FOOTPRINT_STATUS.get(int(status[k]), status[k])}")


class _DefaultFloat(float):
    """A float default whose identity marks "not given" (area=None stays refused, the signature
    still shows the number): the km default can then be refused where it cannot apply [note 19]."""

    def __repr__(self) -> str:
        return float.__repr__(self)


_AREA_DEFAULT = _DefaultFloat(ODYSSEY_AREA_KM2)


def _km_defaults(radius: float, where: str, area_default: bool, h_default: bool) -> None:
    """ValueError when a km default would be applied to lengths that cannot be km [note 19].

    ``radius``: the largest radius of the user's lengths (the cell table's largest cell radius, or
    the largest R of :func:`airmass`); ``area_default``/``h_default``: the user relies on the
    default ``area`` (3.4e-9 km^2) or scale height H (:func:`scale_height`, 10.8 km)."""
    if not radius > KM_RADIUS_MAX or not (area_default or h_default):
        return
    names, what = [], []
    if area_default:
        names.append("area")
        what.append(f"area (default {ODYSSEY_AREA_KM2:g} km^2, the GRS's 34 cm^2; in metres area=3.4e-3)")
    if h_default:
        names.append("H")
        what.append(f"H (default scale_height() = {scale_height():.4g} km; in metres H={1e3 * scale_height():.5g})")
    raise ValueError(
        f"{' and '.join(names)}: {where} reaches {radius:.6g}, too large to be kilometres (no body these "
        f"notes concern has a radius above {KM_RADIUS_MAX:g} km), so the km default"
        f"{'s' if len(names) > 1 else ''} of {' and '.join(what)} would be wrong by powers of 1000: pass "
        f"{' and '.join(names)} in the same unit as the radii (explicit values are taken as given"
        + ("; or airmass_model=None or 'secant', 'hardie', 'notes', which do not use H" if h_default
           and where.startswith("the DEM") else "") + "; docs/grs-notes.md, note 19)")


def footprint(cells: CellTable, R, v=None, area: float = _AREA_DEFAULT, zeta: float | None = None,
              flux_fraction: float | None = None, occlusion: bool = False, airmass_model: str | None = "chapman",
              H: float | None = None, threads: int | None = None, occlusion_tol: float | None = None,
              progress=None, out: FootprintResult | None = None) -> FootprintResult:
    """Footprint geometry of N spectra over a cell table (DESIGN section 10).

    Parameters
    ----------
    cells : CellTable
        The cells (and through ``cells.dem`` the terrain for occlusion).
    R, v : array (3,) or (N, 3)
        Spacecraft position and velocity, planet-fixed frame (DEM units, and
        any unit per second for v: only its direction is used). v builds the
        spacecraft frame (gsh, azimuth); with v=None those are NaN. The
        elevation needs only R (the frame's x axis is R_hat, so it is the
        nadir angle less 90 deg) and is given with or without v.
    area : float
        The detector's projected area A in DEM units squared (default the
        notes' 34 cm^2 = 3.4e-9 km^2, for a DEM in km): solid angle = A/|d|^2.
        A DEM whose radii exceed 1e5 (``KM_RADIUS_MAX``) cannot be in km: there
        the default is refused (ValueError naming ``area``) and area must be
        given in the DEM's unit squared (3.4e-3 for metres) [note 19].
    zeta : float, optional
        Footprint cone: cells with cos psi >= zeta (psi the nadir angle),
        within [-1, 1]. Default (and zeta <= 0): every cell above its horizon, the
        plane through the cell centre normal to its radius vector (areocentric, not
        the spheroid's or the terrain's normal: on the Mars spheroid that takes cells
        up to 0.26 deg behind the true horizon and leaves out a few in front of it,
        3.7e-5 of the flux; docs/grs-notes.md note 7).
    flux_fraction : float, optional
        Instead of zeta: per spectrum, the zeta whose cone holds this fraction
        (0 < q <= 1) of the total flux of the cells above the horizon (hidden by
        terrain or not: the cone is chosen before ``occlusion``), each weighted by
        ``area_cell * max(cos emission, 0) * solid_angle`` (an isotropically
        radiating surface seen by the detector) [note 6]. ``fp.zeta`` gives the
        value used; the cells taken are those with nadir angle up to the first
        at which the running sum, in order of nadir angle, reaches the fraction.
    occlusion : bool
        Also test each pair's line of sight against the terrain, by casting the
        ray from the spacecraft to the DEM surface at the cell centre with
        ``intersect(dem, R, l, method="exact")``: the pair is hidden
        (``visible`` False) when the ray enters the surface more than
        ``occlusion_tol`` (default 1e-6 rmax; at least 1e-9 rmax, the exact
        casting's accuracy) before reaching that point.
    airmass_model : "chapman", "hardie", "notes", "secant" or None
        Model of ``fp.airmass`` (computed on first access) with the zenith angle
        ``zenith_centric``, the scale height H (default :func:`scale_height`)
        and the cell's radius.
    H : float, optional
        The Chapman model's scale height, in the DEM's unit (default
        :func:`scale_height`, 10.8 km, for a DEM in km; refused like ``area``'s
        default for a DEM whose radii exceed 1e5: pass H, e.g. 1.0807e4 for
        metres, or a model that does not use it) [note 19].
    threads : int, optional
        OpenMP threads over the spectra (None or 0: OMP_NUM_THREADS if set, else all cores); results are
        bit-identical for any count.
    progress : callable, optional
        ``progress(done, total)`` during the occlusion rays.
    out : FootprintResult, optional
        A result of an earlier call whose output memory is reused when it holds
        enough pairs (else new memory is taken): for chunked processing of many
        spectra, it saves the first touch of fresh memory on every call. The
        earlier result's arrays are overwritten and must not be used again.

    Returns
    -------
    FootprintResult

    Raises
    ------
    ValueError
        Bad shapes, NaN/Inf, zeta outside [-1, 1] or together with
        flux_fraction, a radial velocity, a spacecraft not above the DEM's
        surface at its sub-spacecraft point, or not above the highest cell
        centre (the cell search's own limit, docs/grs-notes.md note 17).
    """
    if not isinstance(cells, CellTable):
        raise TypeError(f"cells must be a planet_intersect.CellTable, got {type(cells).__name__}")
    if out is not None and not isinstance(out, FootprintResult):
        raise TypeError(f"out must be a FootprintResult of an earlier call, got {type(out).__name__}")
    R = _vectors(R, "R")
    _nonzero(R, "R")
    _check_above_surface(cells, R)
    area_default = area is _AREA_DEFAULT
    area = _real(area, "area", lo=0.0, lo_open=True)
    if zeta is not None and flux_fraction is not None:
        raise ValueError("give zeta or flux_fraction, not both")
    if airmass_model is not None and airmass_model not in _AIRMASS_MODELS:
        raise ValueError(f"airmass_model must be one of {', '.join(_AIRMASS_MODELS)} or None, got {airmass_model!r}")
    if H is not None:
        H = _real(H, "H", lo=0.0, lo_open=True)
    # km defaults on a DEM that cannot be in km (metres: solid angles 1e6 too small, air
    # masses up to 612; a walk-through) [note 19]
    _km_defaults(cells.radius_range[1], "the DEM's largest cell radius", area_default,
                 airmass_model == "chapman" and H is None)
    if not isinstance(occlusion, (bool, np.bool_)):
        # "no" was taken as True (a review)
        raise TypeError(f"occlusion must be True or False, got {occlusion!r}")
    if not occlusion and (occlusion_tol is not None or progress is not None):
        raise ValueError("occlusion_tol and progress apply only with occlusion=True (they would be ignored)")
    if occlusion:
        _occlusion_tol(cells.dem, occlusion_tol)          # before the kernel, not after it
    from .intersect import check_threads
    # one rule for every entry point (0 or None: OMP_NUM_THREADS if set, else all cores; one thread in a
    # process forked after OpenMP ran): 0 used to reach the kernel as OpenMP's own default, which read
    # OMP_NUM_THREADS where intersect did not (an independent review, 2026-12-05)
    threads = check_threads(threads, max(1, len(R)))
    if v is None:
        frames = np.full((len(R), 3, 3), np.nan)
    else:
        vv = _vectors(v, "v")
        if len(vv) != len(R) and len(vv) != 1:
            raise ValueError(f"v: {len(vv)} velocities for {len(R)} positions")
        frames = _state_frames(R, np.broadcast_to(vv, R.shape))
    if flux_fraction is not None:
        q = _real(flux_fraction, "flux_fraction", lo=0.0, lo_open=True, hi=1.0)
        zeta_arr = np.zeros(len(R))
    else:
        z = 0.0 if zeta is None else _real(zeta, "zeta", lo=-1.0, hi=1.0)
        zeta_arr = np.full(len(R), z)
    # angles in degrees from the kernel (the same rounding as multiplying the radians afterwards)
    try:
        idx, d, gsh, scal, buffers = _run_kernel(cells, R, frames, zeta_arr, area, int(threads),
                                                 ascale=180.0 / math.pi, buffers=getattr(out, "_buffers", None))
    except MemoryError:
        # (NumPy's own message named neither the spectra nor the cells: a review)
        raise MemoryError(f"footprint: {len(R):,} spectra over {len(cells):,} cells of {cells.cell_deg:g} deg do "
                          f"not fit in memory: pass fewer spectra per call (chunks; out= reuses the memory), "
                          f"a cone (zeta, flux_fraction) or larger cells") from None
    # the kernel's [0, 360) wraps leave a due-north PA (or a due-forward azimuth) at
    # 359.99999999999994 now and then: within four ulp of 360 is 0 [note 5]
    _snap_360(scal[:, 6])
    _snap_360(scal[:, 7])
    visible = buffers.visible[:len(idx)]
    visible.fill(True)
    res = FootprintResult(
        spectrum=idx[:, 0], cell=idx[:, 1], d=d.T, distance=scal[:, 0], solid_angle=scal[:, 1],
        zenith_centric=scal[:, 2], zenith_detic=scal[:, 3], emission=scal[:, 4],
        nadir_angle=scal[:, 5], position_angle=scal[:, 6], gsh=gsh.T, azimuth=scal[:, 7],
        elevation=scal[:, 8], visible=visible, zeta=zeta_arr,
        cells=cells, airmass_model=airmass_model, H=H)
    # the output memory goes with the result for a later footprint(out=res) (not a dataclass
    # field); the flux cone's result is a smaller copy: it keeps the raw pass's memory only
    # when the caller asked for reuse (out=), so that it does not hold ~10 times its size
    res._buffers = buffers
    if flux_fraction is not None:
        res = _flux_cone(res, q)
        res._buffers = buffers if out is not None else None
    if occlusion:
        res.visible = occluded_not(cells, R, res, tol=occlusion_tol, threads=int(threads), progress=progress)
    return res


def flux_weights(fp: FootprintResult) -> np.ndarray:
    """Flux weight of each pair: ``area_cell * max(cos emission, 0) * solid_angle`` [note 6]."""
    return fp.cells.area[fp.cell] * np.maximum(np.cos(np.radians(fp.emission)), 0.0) * fp.solid_angle


def _flux_cone(res: FootprintResult, q: float) -> FootprintResult:
    """Keep, per spectrum, the cells up to the nadir angle where the flux reaches q of the total."""
    n = len(res)
    ns = res.n_spectra
    if n == 0:
        return res
    w = flux_weights(res)
    order = np.lexsort((res.nadir_angle, res.spectrum))
    spec = res.spectrum[order]
    ws = w[order]
    psi = res.nadir_angle[order]
    starts = np.searchsorted(spec, np.arange(ns))
    counts = np.bincount(spec, minlength=ns)
    # each spectrum's weights as fractions of its own total before the running sum: a running
    # sum over all spectra, less the spectra before, lost a spectrum whose weights were 1e-15 of
    # an earlier one's (1,000 R away after one 6 m up: the footprint fuzzing kept 0.06 % of its
    # flux for q = 0.5); now each spectrum's share is off by at most ~ns ulp
    tot = np.bincount(spec, weights=ws, minlength=ns)
    ts = tot[spec]
    wn = np.divide(ws, ts, out=np.zeros_like(ws), where=ts > 0)    # (a spectrum with no flux: all 0)
    cum = np.cumsum(wn)
    base = np.where(starts > 0, cum[np.maximum(starts - 1, 0)], 0.0)
    rel = cum - base[spec]
    total = rel[np.maximum(starts + counts - 1, 0)]
    reach = rel >= q * total[spec] * (1.0 - 1e-14)
    before = np.bincount(spec[~reach], minlength=ns)          # cells before the fraction is reached
    last = starts + np.minimum(before, np.maximum(counts - 1, 0))
    psi_q = np.where(counts > 0, psi[np.minimum(last, n - 1)], 0.0)
    keep = res.nadir_angle <= psi_q[res.spectrum]
    out = res.subset(keep)
    out.zeta = np.where(counts > 0, np.cos(np.radians(psi_q)), 1.0)
    return out


#: the smallest occlusion_tol, in units of rmax: the exact casting's accuracy along a ray
OCCLUSION_TOL_MIN = 1e-9


def _occlusion_tol(dem: DEM, tol) -> float:
    """occlusion_tol checked (default 1e-6 rmax), or ValueError naming it."""
    tol = 1e-6 * dem.rmax if tol is None else _real(tol, "occlusion_tol", lo=0.0)
    if tol < OCCLUSION_TOL_MIN * dem.rmax:
        raise ValueError(f"occlusion_tol = {tol:g} is below the exact ray casting's accuracy, "
                         f"{OCCLUSION_TOL_MIN:g} rmax = {OCCLUSION_TOL_MIN * dem.rmax:g}: its hits may come that "
                         f"much early, and clear lines of sight would be called hidden")
    return tol


def occluded_not(cells: CellTable, R: np.ndarray, fp: FootprintResult, tol: float | None = None,
                 threads: int = 0, chunk: int = 200_000, progress=None) -> np.ndarray:
    """True for each pair whose line from the spacecraft to the cell is not blocked by terrain [note 14].

    The ray runs from R[spectrum] to the DEM surface at the cell centre
    (``cells.radius_dem`` along u); it is cast with the package's exact first
    hit (``intersect(..., method="exact")``); the pair is hidden when the hit
    lies more than ``tol`` (default 1e-6 rmax) short of that point, measured
    along the ray from the hit to the point (both near the surface, so the
    shortfall keeps its precision from any distance). ``tol`` must be at least
    the exact casting's own accuracy, 1e-9 rmax: its hits may come that much
    early, so a smaller tol would call clear lines hidden (the fuzzing found
    tol = 0 hiding 8-34 cells of a bare sphere, which hides none) [note 14].
    """
    from .intersect import intersect

    dem = cells.dem
    tol = _occlusion_tol(dem, tol)
    n = len(fp)
    out = np.ones(n, dtype=bool)
    if n == 0:
        return out
    R = np.asarray(R, dtype=np.float64)
    for a in range(0, n, chunk):
        sl = slice(a, min(n, a + chunk))
        s = R[fp.spectrum[sl]]
        target = cells.u[fp.cell[sl]] * cells.radius_dem[fp.cell[sl]][:, None]
        l = target - s
        res = intersect(dem, s, l, method="exact", threads=threads)
        # how far the hit lies before the cell's point along the ray, from two points near the
        # surface (|l| - |p - s| has both lengths rounded at ulp(|s|), which from 1e10 km is the
        # size of the smallest allowed tol; no pair was found misjudged that way)
        lu = l / np.linalg.norm(l, axis=1)[:, None]
        with np.errstate(invalid="ignore"):
            short = np.einsum("ij,ij->i", target - res.p, lu)
        out[sl] = ~(res.hit & (short > tol))
        if progress:
            progress(sl.stop, n)
    return out


# ----------------------------------------------------------------------------------------
# the eccentric orbit (notes' last section)
# ----------------------------------------------------------------------------------------
def visible_cap_area(altitude, radius: float) -> np.ndarray:
    """Area of the cap of a sphere of ``radius`` visible from ``altitude`` above it:
    ``2 pi r^2 h/(r + h)`` (the horizon is at cos theta = r/(r + h)); altitude >= 0."""
    radius = _real(radius, "radius", lo=0.0, lo_open=True)
    if np.iscomplexobj(altitude):
        raise ValueError("altitude: expected real numbers")
    try:
        h = np.asarray(altitude, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"altitude: expected numbers, got {altitude!r}") from None
    if not (np.isfinite(h).all() and (h >= 0).all()):
        raise ValueError("altitude: must be finite and >= 0 (a point on or above the sphere)")
    return 2.0 * np.pi * radius ** 2 * h / (radius + h)


def keplerian_states(t, periapsis_radius: float, apoapsis_radius: float, inclination_deg: float = 93.1,
                     node_deg: float = 0.0, argp_deg: float = 0.0, mean_anomaly0_deg: float = 0.0,
                     GM: float = MARS_GM, rotation_rate: float = MARS_ROTATION_RATE):
    """Planet-fixed state vectors (km, km/s) of a Keplerian orbit at times t (s).

    The orbit is fixed in an inertial frame that coincides with the
    planet-fixed frame at t = 0; the planet turns at ``rotation_rate`` (rad/s)
    about +z, so ``R_fixed = Rz(-w t) R_inertial`` and
    ``v_fixed = Rz(-w t) (v_inertial - w z x R_inertial)``. Kepler's equation
    is solved by Newton's method (at most 30 steps).
    """
    try:
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
    except (TypeError, ValueError):
        raise ValueError(f"t: expected times in seconds, got {t!r}") from None
    if not np.isfinite(t).all():
        raise ValueError("t: times must be finite")
    rp = _real(periapsis_radius, "periapsis_radius", lo=0.0, lo_open=True)
    ra = _real(apoapsis_radius, "apoapsis_radius", lo=0.0, lo_open=True)
    if not rp <= ra:
        raise ValueError(f"periapsis_radius and apoapsis_radius: need 0 < rp <= ra, got {rp}, {ra}")
    GM = _real(GM, "GM", lo=0.0, lo_open=True)
    rotation_rate = _real(rotation_rate, "rotation_rate")
    for name, val in (("inclination_deg", inclination_deg), ("node_deg", node_deg), ("argp_deg", argp_deg),
                      ("mean_anomaly0_deg", mean_anomaly0_deg)):
        _real(val, name)
    a = 0.5 * (rp + ra)
    e = (ra - rp) / (ra + rp)
    n = math.sqrt(GM / a ** 3)
    M = math.radians(mean_anomaly0_deg) + n * t
    E = M.copy()
    for _ in range(30):
        dE = (E - e * np.sin(E) - M) / (1.0 - e * np.cos(E))
        E -= dE
        if np.all(np.abs(dE) < 1e-15):
            break
    cosE, sinE = np.cos(E), np.sin(E)
    b = a * math.sqrt(1 - e * e)
    xp, yp = a * (cosE - e), b * sinE
    edot = n / (1 - e * cosE)
    vxp, vyp = -a * sinE * edot, b * cosE * edot
    i, O, w = (math.radians(v) for v in (inclination_deg, node_deg, argp_deg))
    P = np.array([math.cos(O) * math.cos(w) - math.sin(O) * math.sin(w) * math.cos(i),
                  math.sin(O) * math.cos(w) + math.cos(O) * math.sin(w) * math.cos(i),
                  math.sin(w) * math.sin(i)])
    Q = np.array([-math.cos(O) * math.sin(w) - math.sin(O) * math.cos(w) * math.cos(i),
                  -math.sin(O) * math.sin(w) + math.cos(O) * math.cos(w) * math.cos(i),
                  math.cos(w) * math.sin(i)])
    Ri = xp[:, None] * P + yp[:, None] * Q
    vi = vxp[:, None] * P + vyp[:, None] * Q
    vi = vi - rotation_rate * np.stack([-Ri[:, 1], Ri[:, 0], np.zeros(len(t))], axis=1)
    th = -rotation_rate * t
    c, s = np.cos(th), np.sin(th)

    def rot(x):
        return np.stack([c * x[:, 0] - s * x[:, 1], s * x[:, 0] + c * x[:, 1], x[:, 2]], axis=1)

    return rot(Ri), rot(vi)


@dataclass
class OrbitStudy:
    """Results of :func:`orbit_study` (lengths km, angles deg, times s)."""

    t: np.ndarray
    altitude: np.ndarray
    visible_area: np.ndarray
    area_variation: float
    notes_variation: float
    counts: dict
    nadir_offsets_deg: np.ndarray
    nadir: np.ndarray
    periapsis_index: int
    apoapsis_index: int
    radius: float
    periapsis_alt: float
    apoapsis_alt: float


def orbit_study(cells: CellTable | None = None, periapsis_alt: float = 387.0, apoapsis_alt: float = 450.0,
                radius: float = 3397.0, inclination_deg: float = 93.1, n: int = 721,
                zetas=(0.0, 0.5), offsets_deg=(2.0, 5.0, 10.0, 15.0, 20.0)) -> OrbitStudy:
    """One orbit of an eccentric mapping orbit: visible area, cell counts, nadir angles.

    ``radius`` is the notes' r_Mars (3397 km): altitudes are above it. The
    visible area is the sphere's cap :func:`visible_cap_area`; its variation
    ``max/min - 1`` is compared with the notes' "16 %" (``notes_variation``:
    the same from their own altitudes 385.6 and 454.4 km). With ``cells``,
    ``counts[zeta]`` is the number of footprint cells (above the horizon and
    cos psi >= zeta) at each time. ``nadir[:, k]`` is the nadir angle of a cell
    at the central angle ``offsets_deg[k]`` from the sub-spacecraft point on a
    sphere of ``radius`` (a cell at a fixed ground offset, e.g. across track):
    ``psi = atan2(r sin theta, |R| - r cos theta)``.
    """
    if cells is not None and cells.radius_range[1] > KM_RADIUS_MAX:
        # the orbit is in km (Mars's GM in km^3/s^2, radius and altitudes in km) [note 19]
        raise ValueError(f"cells: the DEM's largest cell radius is {cells.radius_range[1]:.6g}, too large to be "
                         f"kilometres; orbit_study computes its orbit in km (radius, altitudes and Mars's GM): "
                         f"give it the cells of a DEM in km")
    rp, ra = radius + periapsis_alt, radius + apoapsis_alt
    a = 0.5 * (rp + ra)
    period = 2 * math.pi * math.sqrt(a ** 3 / MARS_GM)
    t = np.linspace(0.0, period, n)
    R, v = keplerian_states(t, rp, ra, inclination_deg)
    rn = np.linalg.norm(R, axis=1)
    alt = rn - radius
    area = visible_cap_area(alt, radius)
    variation = float(area.max() / area.min() - 1)
    notes = float(visible_cap_area(454.4, 3397.0) / visible_cap_area(385.6, 3397.0) - 1)
    counts = {}
    if cells is not None:
        from ._ext import core as _core

        for z in zetas:
            c, status, stat = _core.core_footprint_count(R.T, np.full(n, float(z)), cells.nrow, cells.ncol,
                                                         math.radians(cells.cell_deg), cells.u.T, cells.radius,
                                                         *cells.radius_range)
            _raise_status(stat, status, R, cells)
            counts[float(z)] = c
    th = np.radians(np.asarray(offsets_deg, dtype=np.float64))
    nadir = np.degrees(np.arctan2(radius * np.sin(th)[None, :], rn[:, None] - radius * np.cos(th)[None, :]))
    return OrbitStudy(t=t, altitude=alt, visible_area=area, area_variation=variation, notes_variation=notes,
                      counts=counts, nadir_offsets_deg=np.asarray(offsets_deg, float), nadir=nadir,
                      periapsis_index=int(np.argmin(rn)), apoapsis_index=int(np.argmax(rn)), radius=radius,
                      periapsis_alt=periapsis_alt, apoapsis_alt=apoapsis_alt)


def plot_orbit_study(study: OrbitStudy, path) -> None:
    """Three panels over one orbit: altitude and visible area; footprint cell counts; nadir angles."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tm = study.t / 60.0
    fig, axes = plt.subplots(3, 1, figsize=(8, 9), sharex=True)
    ax = axes[0]
    ax.plot(tm, study.altitude, "k-")
    ax.set_ylabel("altitude (km)")
    ax2 = ax.twinx()
    ax2.plot(tm, study.visible_area / 1e6, "C0--")
    ax2.set_ylabel("visible area (10^6 km^2)", color="C0")
    ax.set_title(f"Mapping orbit {study.periapsis_alt:.0f} x {study.apoapsis_alt:.0f} km: visible area varies "
                 f"{100 * study.area_variation:.1f} % (notes' 385.6/454.4 km: {100 * study.notes_variation:.1f} %)",
                 fontsize=9)
    ax = axes[1]
    for z, c in study.counts.items():
        lab = "above the horizon" if z <= 0 else f"cos psi >= {z:g} (psi <= {math.degrees(math.acos(z)):.0f} deg)"
        ax.plot(tm, c, label=lab)
    ax.set_ylabel("cells in the footprint")
    if study.counts:
        ax.legend(fontsize=8)
    ax = axes[2]
    for k, off in enumerate(study.nadir_offsets_deg):
        ax.plot(tm, study.nadir[:, k], label=f"cell {off:g} deg from nadir point")
    ax.set_ylabel("nadir angle psi (deg)")
    ax.set_xlabel("time since periapsis (min)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _shade(dem: DEM, lat_rng, lon_rng):
    """Hillshade of the DEM's height above its spheroid over a lat/lon box (deg)."""
    from .geometry import spheroid_radius

    ppd = dem.ppd
    i0 = max(0, int((lat_rng[0] + 90) * ppd))
    i1 = min(dem.nlat, int(math.ceil((lat_rng[1] + 90) * ppd)))
    j0 = int(math.floor(lon_rng[0] * ppd))
    j1 = int(math.ceil(lon_rng[1] * ppd))
    cols = np.arange(j0, j1) % dem.nlon
    block = np.asarray(dem.radii[i0:i1], dtype=np.float64)[:, cols]
    h = block - spheroid_radius(dem.lat[i0:i1], dem.f, dem.re)[:, None] if dem.f > 0 else block - block.mean()
    gy, gx = np.gradient(h)
    az, alt = math.radians(315), math.radians(45)
    slope = np.arctan(np.hypot(gx, gy) * ppd * 180 / math.pi / dem.re * 3)
    aspect = np.arctan2(-gx, gy)
    shade = np.sin(alt) * np.cos(slope) + np.cos(alt) * np.sin(slope) * np.cos(az - aspect)
    extent = (j0 / ppd, j1 / ppd, i0 / ppd - 90, i1 / ppd - 90)
    return shade, extent


def plot_footprint_map(fp: FootprintResult, path, color: str = "solid_angle", spectrum: int | None = None,
                       title: str | None = None) -> None:
    """Map of footprint cells coloured by solid angle or emission over the DEM's shading.

    ``spectrum``: one spectrum's footprint (default: all, showing each cell's
    largest solid angle or smallest emission). Hidden cells (occlusion) are
    hatched grey.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if color not in ("solid_angle", "emission"):
        raise ValueError(f"color must be 'solid_angle' or 'emission', got {color!r}")
    cells = fp.cells
    sel = np.ones(len(fp), bool) if spectrum is None else fp.spectrum == spectrum
    if not sel.any():
        raise ValueError("no footprint cells to plot")
    val = getattr(fp, color)[sel]
    cid = fp.cell[sel]
    vis = fp.visible[sel]
    grid = np.full(len(cells), np.nan)
    order = np.argsort(val if color == "solid_angle" else -val)
    grid[cid[order]] = val[order]
    hidden = np.zeros(len(cells), bool)
    hidden[cid[~vis]] = True
    grid = grid.reshape(cells.nrow, cells.ncol)
    lat, lon = cells.lat[cid], cells.lon[cid]
    # longitudes unwrapped around the footprint's circular mean
    lon0 = math.degrees(math.atan2(np.mean(np.sin(np.radians(lon))), np.mean(np.cos(np.radians(lon)))))
    rel = (lon - lon0 + 180) % 360 - 180
    pad = 2.0
    lon_rng = (lon0 + rel.min() - pad, lon0 + rel.max() + pad)
    lat_rng = (max(-90.0, lat.min() - pad), min(90.0, lat.max() + pad))
    fig, ax = plt.subplots(figsize=(9, 7))
    shade, extent = _shade(cells.dem, lat_rng, lon_rng)
    ax.imshow(shade, origin="lower", extent=extent, cmap="gray", aspect="auto")
    cd = cells.cell_deg
    jj = np.arange(int(math.floor(lon_rng[0] / cd)), int(math.ceil(lon_rng[1] / cd)))
    i0, i1 = int((lat_rng[0] + 90) / cd), min(cells.nrow, int(math.ceil((lat_rng[1] + 90) / cd)))
    sub = grid[i0:i1][:, jj % cells.ncol]
    shown = sub * 1e14 if color == "solid_angle" else sub
    im = ax.imshow(shown, origin="lower", extent=(jj[0] * cd, (jj[-1] + 1) * cd, i0 * cd - 90, i1 * cd - 90),
                   cmap="viridis" if color == "solid_angle" else "magma_r", alpha=0.6, aspect="auto")
    hid = hidden.reshape(cells.nrow, cells.ncol)[i0:i1][:, jj % cells.ncol]
    if hid.any():
        ax.imshow(np.where(hid, 1.0, np.nan), origin="lower", extent=(jj[0] * cd, (jj[-1] + 1) * cd, i0 * cd - 90,
                                                                     i1 * cd - 90), cmap="Reds", vmin=0, vmax=1.2,
                  aspect="auto")
    fig.colorbar(im, ax=ax, label="solid angle (1e-14 sr)" if color == "solid_angle" else "emission angle (deg)")
    ax.set_xlabel("east longitude (deg)")
    ax.set_ylabel("areocentric latitude (deg)")
    ax.set_title(title or f"footprint cells ({int(sel.sum())} pairs, {int((~vis).sum())} hidden by terrain in red)",
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
