"""Geodetic coordinates on a reference ellipsoid (Shin & Park eq. 2 and exact).

ECR (Earth-centred rotating, i.e. body-fixed) Cartesian ``x, y, z`` <->
geodetic latitude, east longitude and height above the ellipsoid
``(a, f)``. The conversions run in the Fortran core (``fortran/pi_geodetic.f90``).

>>> import planet_intersect as pi
>>> lat, lon, h = pi.ecef_to_geodetic([[6378137.0, 0, 0]])
>>> p = pi.geodetic_to_ecef(45.0, 10.0, 100.0)
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["WGS84_A", "WGS84_F", "ecef_to_geodetic", "geodetic_to_ecef", "check_ellipsoid"]

#: WGS-84 semi-major axis (m) and flattening
WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563

_METHODS = {"exact": 0, "bowring": 1, "printed": 2}


#: the semi-major axes accepted (any unit)
A_MIN, A_MAX = 1e-30, 1e30
#: farthest point ecef_to_geodetic converts, in units of a (|p|^2 stays far from overflow)
P_MAX_A = 1e15


def check_ellipsoid(a, f) -> tuple[float, float]:
    """Validate the ellipsoid: ``a`` positive and finite, ``0 <= f < 1``."""
    try:
        a = float(a)
        f = float(f)
    except (TypeError, ValueError):
        raise ValueError(f"a and f must be numbers, got a={a!r}, f={f!r}") from None
    if not (math.isfinite(a) and A_MIN <= a <= A_MAX):
        # the exact conversion's tolerances and squares hold in this range (a review found it silently
        # wrong for a <= 1e-90 and NaN for a >= 1e120); any unit from micrometres to light years fits
        raise ValueError(f"a (semi-major axis) must be in [{A_MIN:g}, {A_MAX:g}] (any unit), got {a}")
    if not (math.isfinite(f) and 0.0 <= f < 1.0):
        raise ValueError(f"f (flattening) must be in [0, 1), got {f}")
    return a, f


def ecef_to_geodetic(p, a: float = WGS84_A, f: float = WGS84_F, method: str = "exact"):
    """Geodetic latitude, longitude and height of ECR points.

    Parameters
    ----------
    p : array (3,) or (N, 3)
        Points in the body-fixed Cartesian frame (x to lat 0 lon 0, z north), units of ``a``.
    a, f : float
        Semi-major axis and flattening of the ellipsoid (WGS-84 by default).
    method : "exact", "bowring" or "printed"
        "exact" (default): the nearest point on the ellipsoid by a safeguarded
        Newton iteration (relative accuracy ~1e-15, any point within 1e15 a of
        the centre, poles and centre included; within a few a e^2 of the centre
        of a nearly round body the latitude is ill-conditioned, the height is
        not). "bowring": Shin & Park eq. 2 as
        Bowring/Dana state it (one step; docs/shin-park-notes.md notes 1-2 give
        its error; meaningless inside the evolute, within ~e^2 a of the centre,
        where its latitude can leave [-90, 90]). "printed": eq. 2 exactly as
        printed in the paper (a factor b missing: note 1).

    Returns
    -------
    lat, lon, h : arrays (N,) or scalars for a single point
        Geodetic latitude (deg), east longitude (deg, [-180, 180)), height above
        the ellipsoid (units of ``a``; negative inside).
    """
    from ._ext import core as _core

    a, f = check_ellipsoid(a, f)
    if method not in _METHODS:
        raise ValueError(f"method must be 'exact', 'bowring' or 'printed', got {method!r}")
    arr = np.asarray(p, dtype=np.float64)
    single = arr.ndim == 1
    if single:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"p: expected shape (3,) or (N, 3), got {np.shape(p)}")
    if not np.isfinite(arr).all():
        k = int(np.argmax(~np.isfinite(arr).all(axis=1)))
        raise ValueError(f"p[{k}] has NaN or Inf components: {arr[k]}")
    far = np.max(np.abs(arr), axis=1) > P_MAX_A * a if arr.size else np.zeros(0, dtype=bool)
    if far.any():
        k = int(np.argmax(far))
        raise ValueError(f"p[{k}] = {arr[k]} is farther than {P_MAX_A:g} a from the centre")
    lat, lon, h = _core.core_ecr_to_geodetic(np.ascontiguousarray(arr).T, a, f, _METHODS[method])
    lat = np.degrees(lat)
    lon = _wrap180(np.degrees(lon))
    if single:
        return float(lat[0]), float(lon[0]), float(h[0])
    return lat, lon, h


def geodetic_to_ecef(lat, lon, h, a: float = WGS84_A, f: float = WGS84_F) -> np.ndarray:
    """ECR Cartesian points of geodetic coordinates.

    Parameters
    ----------
    lat, lon : float or arrays (N,)
        Geodetic latitude in [-90, 90] and east longitude (deg).
    h : float or array (N,)
        Height above the ellipsoid (units of ``a``). The three broadcast.
    a, f : float
        Semi-major axis and flattening (WGS-84 by default).

    Returns
    -------
    p : array (3,) for scalar input, else (N, 3)
    """
    from ._ext import core as _core

    a, f = check_ellipsoid(a, f)
    try:
        lat, lon, h = np.broadcast_arrays(*(np.asarray(v, dtype=np.float64) for v in (lat, lon, h)))
    except ValueError as exc:
        raise ValueError(f"lat, lon and h do not broadcast: {exc}") from None
    single = lat.ndim == 0
    lat, lon, h = (np.ascontiguousarray(v).ravel() for v in (lat, lon, h))
    if lat.size == 0:
        return np.zeros((0, 3))
    for name, v in (("lat", lat), ("lon", lon), ("h", h)):
        if not np.isfinite(v).all():
            raise ValueError(f"{name}[{int(np.argmax(~np.isfinite(v)))}] is NaN or Inf")
    if (np.abs(lat) > 90.0).any():
        k = int(np.argmax(np.abs(lat) > 90.0))
        raise ValueError(f"lat[{k}] = {lat[k]} is outside [-90, 90] degrees")
    p = _core.core_geodetic_to_ecr(np.radians(lat), np.radians(lon), h, a, f).T.copy()
    return p[0] if single else p


def _wrap180(lon_deg):
    """Longitudes (deg) into [-180, 180)."""
    x = np.array(lon_deg, dtype=np.float64)            # a copy
    out = ~((x >= -180.0) & (x < 180.0))
    if not out.any():                      # the usual case: nothing to wrap
        return x
    # only the values to wrap go through np.mod (slow on NaN: an all-NaN event_lon
    # column cost 1.6 ms per 10,000 rays); NaN stays NaN, +-Inf becomes NaN
    flat = x.reshape(-1)                   # a view (x is a fresh contiguous array), 0-d included
    k = np.flatnonzero((out & np.isfinite(x)).reshape(-1))
    w = np.mod(flat[k] + 180.0, 360.0) - 180.0
    flat[k] = np.where(w >= 180.0, w - 360.0, w)
    flat[np.isinf(flat)] = np.nan
    return x
