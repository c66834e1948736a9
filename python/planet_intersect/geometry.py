"""Viewing geometry helpers: detector lines of sight (eqs. 16-18), the reference
spheroid (eqs. 46-50, 61) and closed-form ray intersections used as references."""

from __future__ import annotations

import numpy as np

__all__ = ["detector_los", "spheroid_radius", "ray_spheroid_intersection", "latlon_of"]


#: Most detector pixels per side (a 100,000 x 100,000 array is 240 GB of directions).
MAX_PIXELS = 100_000


def _unit(v, name):
    try:
        arr = np.asarray(v)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: not an array of numbers ({exc})") from None
    if arr.dtype.kind not in "fiu":
        raise TypeError(f"{name}: must be real numbers, got dtype {arr.dtype}")
    v = arr.astype(np.float64)
    if v.shape != (3,):
        raise ValueError(f"{name}: expected a 3-vector, got shape {v.shape}")
    if not np.isfinite(v).all() or not v.any():
        raise ValueError(f"{name}: must be finite and non-zero, got {v}")
    v = np.ldexp(v, -int(np.frexp(np.abs(v).max())[1]))      # exact power-of-two scaling: no over/underflow
    return v / np.sqrt(v @ v)


def _count(value, name: str) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name}: must be an integer, got {type(value).__name__} {value!r}")
    if not 1 <= value <= MAX_PIXELS:
        raise ValueError(f"{name}: must be in 1..{MAX_PIXELS}, got {value}")
    return int(value)


def _spacing(value, name: str) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name}: must be a real number (radians), got {type(value).__name__} {value!r}")
    value = float(value)
    if not (np.isfinite(value) and 0 < value <= np.pi):
        raise ValueError(f"{name}: must be a finite pixel spacing in (0, pi] radians, got {value}")
    return value


def detector_los(l0, q, nh: int, nv: int, dh: float, dv: float) -> np.ndarray:
    """Unit lines of sight of an ``nh x nv`` detector array, eqs. 16-18.

    ``l0`` is the line of sight of the centre of the field of view, ``q`` the
    direction of the array's vertical side, ``dh``/``dv`` the pixel spacing in
    radians. ``h = l0 x q / |l0 x q|`` (eq. 16), ``v = q`` (eq. 17) and
    ``l_ij = l0 + sin((i - (nh+1)/2) dh) h + sin((j - (nv+1)/2) dv) v`` (eq. 18),
    normalised. Returns shape ``(nv*nh, 3)``, row-major in (j, i): pixel
    ``(i, j)`` (1-based) is row ``(j-1)*nh + (i-1)``.
    """
    l0 = _unit(l0, "l0")
    q = _unit(q, "q")
    nh, nv = _count(nh, "nh"), _count(nv, "nv")
    dh, dv = _spacing(dh, "dh"), _spacing(dv, "dv")
    if nh * nv > 50_000_000:
        raise ValueError(f"nh x nv = {nh * nv} pixels: at most 50,000,000 in one call (1.2 GB of directions)")
    for n, d, name in ((nh, dh, "dh"), (nv, dv, "dv")):
        # beyond pi/2 from the centre eq. 18's sin() folds the pixels back onto ones nearer it (a
        # walk-through gave dh = 0.86, degrees meant, to 101 pixels: a field of 86 radians)
        if 0.5 * (n - 1) * d > 0.5 * np.pi:
            raise ValueError(f"{name} = {d:g} rad over {n} pixels: the field reaches {0.5 * (n - 1) * d:.4g} rad "
                             f"from l0, beyond pi/2, where eq. 18's sin() repeats directions (degrees given "
                             f"as radians?)")
    h = np.cross(l0, q)
    hn = np.linalg.norm(h)
    if hn < 1e-12:
        raise ValueError("q is parallel to l0: the detector orientation is undefined")
    h /= hn                                                    # eq. 16
    v = q                                                      # eq. 17
    i = np.arange(1, nh + 1)
    j = np.arange(1, nv + 1)
    jj, ii = np.meshgrid(j, i, indexing="ij")
    los = (l0[None, None, :]
           + np.sin((ii - (nh + 1) / 2) * dh)[..., None] * h
           + np.sin((jj - (nv + 1) / 2) * dv)[..., None] * v)  # eq. 18
    los /= np.linalg.norm(los, axis=-1, keepdims=True)
    return los.reshape(nv * nh, 3)


def _spheroid(f, re, where: str) -> tuple[float, float]:
    """(f, re) checked: 0 <= f < 1, re finite and > 0 (ValueError naming them)."""
    try:
        f, re = float(f), float(re)
    except (TypeError, ValueError):
        raise TypeError(f"{where}: f and re must be real numbers, got {f!r}, {re!r}") from None
    if not (np.isfinite(f) and 0.0 <= f < 1.0):
        raise ValueError(f"{where}: flattening f must be in [0, 1), got {f}")
    if not (np.isfinite(re) and re > 0.0):
        raise ValueError(f"{where}: equatorial radius re must be finite and > 0, got {re}")
    return f, re


def spheroid_radius(lat_deg, f: float, re: float) -> np.ndarray:
    """Radius of the spheroid (f, re) at planetocentric latitude, eq. 61.

    ``lat_deg`` within [-90, 90], ``0 <= f < 1``, ``re > 0`` (ValueError otherwise:
    95 degrees gave the radius at 85, f = 2 a sphere, and a negative re a positive radius)."""
    f, re = _spheroid(f, re, "spheroid_radius")
    lat = np.asarray(lat_deg, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        bad = ~(np.abs(lat) <= 90.0)
    if bad.any():
        raise ValueError(f"spheroid_radius: lat_deg must be finite and within [-90, 90], got "
                         f"{float(lat.reshape(-1)[int(np.argmax(bad.reshape(-1)))])!r}")
    lat_deg = lat
    e2 = f * (2.0 - f)
    c = np.cos(np.radians(lat_deg))
    return np.sqrt(re * re * (1.0 - e2) / (1.0 - e2 * c * c))


def ray_spheroid_intersection(s, l, f: float, re: float):
    """Where rays ``s + d l`` (d >= 0) enter the spheroid; NaN where they do not.

    Closed form: substitute the ray into eq. 49 and solve the quadratic in d.
    Returns ``(points (N,3), d (N,))``. A ray from inside the spheroid does not
    enter it and gets NaN (its exit is the quadratic's other root). ``l`` must
    be non-zero and finite, ``0 <= f < 1``, ``re > 0`` (ValueError otherwise).
    """
    f, re = _spheroid(f, re, "ray_spheroid_intersection")
    s = np.atleast_2d(np.asarray(s, dtype=np.float64))
    l = np.atleast_2d(np.asarray(l, dtype=np.float64))
    ln = np.linalg.norm(l, axis=1, keepdims=True)
    if not (np.isfinite(ln).all() and (ln > 0).all()):
        raise ValueError("ray_spheroid_intersection: l must be non-zero and finite")
    l = l / ln
    w2 = 1.0 / (1.0 - f) ** 2
    scale = np.array([1.0, 1.0, w2])
    a = np.sum(l * l * scale, axis=1)
    b = 2 * np.sum(s * l * scale, axis=1)
    c = np.sum(s * s * scale, axis=1) - re * re
    disc = b * b - 4 * a * c
    with np.errstate(invalid="ignore"):
        sq = np.sqrt(disc)
        # numerically stable root of the smaller d
        qq = -0.5 * (b + np.sign(b) * sq)
        d1 = qq / a
        d2 = c / qq
    d = np.where(d1 < d2, d1, d2)
    d = np.where((disc >= 0) & (d >= 0), d, np.nan)
    return s + d[:, None] * l, d


def latlon_of(x) -> tuple[np.ndarray, np.ndarray]:
    """Planetocentric latitude and east longitude in [0, 360) of points (N,3), degrees."""
    x = np.atleast_2d(np.asarray(x, dtype=np.float64))
    lat = np.degrees(np.arctan2(x[:, 2], np.hypot(x[:, 0], x[:, 1])))
    lon = np.degrees(np.arctan2(x[:, 1], x[:, 0])) % 360.0
    lon = np.where(lon >= 360.0, 0.0, lon)
    return lat, lon
