"""Spherical-harmonic shape models (PDS SHADR, e.g. MOLA's GTM090AA) as DEMs.

A SHADR shape model is an ASCII table: a header record (reference radius in km, a constant
that is 1 for a shape model and GM for a gravity field, its uncertainty, degree, order,
normalisation state, reference longitude and latitude) and then one record per coefficient,
``n, m, C_nm, S_nm, sigma_C, sigma_S`` (metres). The model gives the absolute radius from the
body's centre of mass,

    r(lat, lon) = sum_{n=0..N} sum_{m=0..n} Pbar_nm(sin lat) (C_nm cos(m lon) + S_nm sin(m lon)),

in the model's own frame (GTM090AA: IAU 1991, planetocentric, east longitude; the MEGDR grids
use IAU 2000, whose prime meridian differs by ~0.27 deg). Pbar_nm are the geodesists' 4-pi
fully normalised associated Legendre functions without the Condon-Shortley phase. The header's
normalisation state is defined for gravity fields only; GTM090AA says 0 ("unnormalised") but
its coefficients are fully normalised (docs/paper-notes.md, note 24, which measures both
readings), so they are always read as fully normalised here.

A DEM is the model evaluated at the pixel centres of a global grid (DESIGN section 3), in km,
with the Mars reference spheroid when the model is of Mars' size, else the header's reference
radius as a sphere.
"""

from __future__ import annotations

import math
import os
import re as _re
from pathlib import Path

import numpy as np

from .dem import DEM, checked_ppd, read_small_text

__all__ = ["SHADRError", "read_shadr", "legendre_normalised", "shadr_radius", "shadr_dem", "import_shadr"]

#: the finest DEM a model may be evaluated on (pixels per degree)
MAX_PPD = 16
#: the highest degree read (GTM090AA: 90). The column recursions start from the sectorials
#: Pbar_mm ~ cos(lat)^m, which underflow double precision where m > 308 / -log10(cos lat); an
#: order whose functions are O(1) somewhere needs m < n cos(lat). Both hold only where
#: n cos(lat) (-log10 cos lat) > 308, and the left side is at most n 0.16 (cos lat = 1/e):
#: safe to n ~ 1,900. A review found degree 3,000 wrong (1e37 for 1.1 at 60 deg, m = 1,200)
MAX_DEGREE = 1800
#: the largest SHADR file read (bytes): a degree-1,800 model is ~200 MB
MAX_BYTES = 250_000_000


class SHADRError(ValueError):
    """A SHADR file that cannot be read as a shape model (names the file)."""


def read_shadr(path: str | os.PathLike) -> dict:
    """The header and coefficients of a SHADR shape model.

    Returns ``dict(ref_radius_km, degree, order, normalisation, C, S)`` with ``C[n, m]``,
    ``S[n, m]`` (metres; zero above the order). Checks: the header's eight fields, a constant
    of 1 (a shape model, not a gravity field), every (n, m) with m <= min(n, order) present
    once, finite values, S_n0 = 0. Raises SHADRError naming the file and the line."""
    p = Path(path)
    where = f"SHADR file {p}"
    text = read_small_text(p, where, MAX_BYTES, SHADRError)
    lines = [(k, ln) for k, ln in enumerate(text.splitlines(), start=1) if ln.strip()]
    if not lines:
        raise SHADRError(f"{where}: empty")

    def fields(k, line, n):
        # fields are separated by commas or white space (GTM090AA: commas; GGM1025A: spaces); an
        # empty field between two commas is an error, never skipped (it shifted the columns: a review)
        parts = [x.strip() for x in _re.split(r"\s*,\s*|\s+", line.strip())]
        if len(parts) < n or "" in parts[:n]:
            raise SHADRError(f"{where}, line {k}: expected {n} fields separated by commas or spaces, none empty: "
                             f"{line.strip()[:70]!r}")
        return parts[:n]

    def number(k, tok, what, integer=False):
        try:
            v = int(tok) if integer else float(tok.replace("D", "E").replace("d", "e"))
        except ValueError:
            raise SHADRError(f"{where}, line {k}: {what} {tok[:30]!r} is not {'an integer' if integer else 'a number'}") \
                from None
        if not integer and not math.isfinite(v):
            raise SHADRError(f"{where}, line {k}: {what} is {tok}")
        return v

    k0, head = lines[0]
    h = fields(k0, head, 8)
    ref = number(k0, h[0], "reference radius")
    const = number(k0, h[1], "constant")
    number(k0, h[2], "uncertainty of the constant")
    degree = number(k0, h[3], "degree", integer=True)
    order = number(k0, h[4], "order", integer=True)
    norm = number(k0, h[5], "normalisation state", integer=True)
    ref_lon = number(k0, h[6], "reference longitude")
    ref_lat = number(k0, h[7], "reference latitude")
    if not ref > 0:
        raise SHADRError(f"{where}, line {k0}: reference radius {ref!r} km is not positive")
    if const != 1.0:
        raise SHADRError(f"{where}, line {k0}: constant {const!r}: a gravity field (GM), not a shape model "
                         f"(constant 1)")
    if ref_lon != 0 or ref_lat != 0:
        raise SHADRError(f"{where}, line {k0}: reference longitude {ref_lon!r} and latitude {ref_lat!r}: a model "
                         f"about a rotated pole is not read (both must be 0)")
    if not (degree >= 1 and 0 <= order <= degree):
        raise SHADRError(f"{where}, line {k0}: degree {degree} and order {order}: need 0 <= order <= degree and "
                         f"1 <= degree")
    if degree > MAX_DEGREE:
        raise SHADRError(f"{where}, line {k0}: degree {degree}: above {MAX_DEGREE}, where this evaluation's "
                         f"Legendre recursion underflows (shadr.MAX_DEGREE)")
    C = np.zeros((degree + 1, degree + 1))
    S = np.zeros((degree + 1, degree + 1))
    seen = np.zeros((degree + 1, degree + 1), dtype=bool)
    for k, line in lines[1:]:
        f = fields(k, line, 4)
        n = number(k, f[0], "degree n", integer=True)
        m = number(k, f[1], "order m", integer=True)
        if not (0 <= m <= n <= degree and m <= order):
            raise SHADRError(f"{where}, line {k}: (n, m) = ({n}, {m}) outside the header's degree {degree}, "
                             f"order {order}")
        if seen[n, m]:
            raise SHADRError(f"{where}, line {k}: (n, m) = ({n}, {m}) given twice")
        C[n, m] = number(k, f[2], "C")
        S[n, m] = number(k, f[3], "S")
        if m == 0 and S[n, m] != 0:
            raise SHADRError(f"{where}, line {k}: S_{n},0 = {S[n, m]:g}; a zonal term has no sine part")
        seen[n, m] = True
    want = np.tril(np.ones_like(seen))
    want[:, order + 1:] = False
    missing = np.argwhere(want & ~seen)
    if len(missing):
        n, m = missing[0]
        raise SHADRError(f"{where}: {len(missing)} coefficients missing, the first (n, m) = ({n}, {m})")
    if not C[0, 0] > 0:
        raise SHADRError(f"{where}: C_00 = {C[0, 0]:g} m; a shape model's mean radius is positive")
    return dict(ref_radius_km=ref, degree=degree, order=order, normalisation=norm, C=C, S=S)


def legendre_normalised(degree: int, x: np.ndarray) -> np.ndarray:
    """Pbar[n, m, k] at x[k] = sin(latitude): 4-pi fully normalised associated Legendre
    functions, no Condon-Shortley phase, by the standard column recursions (vectorised over
    m: one Python step a degree). Valid to MAX_DEGREE (its comment says why)."""
    x = np.asarray(x, dtype=float).ravel()
    u = np.sqrt(np.clip(1.0 - x * x, 0.0, None))                  # cos(latitude)
    P = np.zeros((degree + 1, degree + 1, x.size))
    P[0, 0] = 1.0
    if degree >= 1:
        P[1, 1] = math.sqrt(3.0) * u
        P[1, 0] = math.sqrt(3.0) * x
    for n in range(2, degree + 1):
        m = np.arange(n - 1)
        a = np.sqrt((2 * n - 1) * (2 * n + 1) / ((n - m) * (n + m)))[:, None]
        b = np.sqrt((2 * n + 1) * (n + m - 1) * (n - m - 1) / ((n - m) * (n + m) * (2 * n - 3)))[:, None]
        P[n, :n - 1] = a * x * P[n - 1, :n - 1] - b * P[n - 2, :n - 1]
        P[n, n - 1] = math.sqrt(2 * n + 1) * x * P[n - 1, n - 1]          # (m = n - 1)
        P[n, n] = math.sqrt((2 * n + 1) / (2 * n)) * u * P[n - 1, n - 1]  # sectorial
    return P


def shadr_radius(model: dict, lat_deg, lon_deg, degree: int | None = None) -> np.ndarray:
    """The model's radius (m) at planetocentric latitudes and east longitudes (deg, a grid's
    rows and columns: returns r[len(lat), len(lon)]), to ``degree`` (default: the model's)."""
    nmax = model["degree"] if degree is None else int(degree)
    if not 0 <= nmax <= model["degree"]:
        raise ValueError(f"degree must be 0 to the model's {model['degree']}, got {degree!r}")
    lat = np.atleast_1d(np.asarray(lat_deg, dtype=float))
    lon = np.atleast_1d(np.asarray(lon_deg, dtype=float))
    if not (np.isfinite(lat).all() and np.isfinite(lon).all()) or np.any(np.abs(lat) > 90):
        raise ValueError("lat, lon: finite degrees with |lat| <= 90")
    C = model["C"][: nmax + 1, : nmax + 1]
    S = model["S"][: nmax + 1, : nmax + 1]
    out = np.empty((lat.size, lon.size))
    m = np.arange(nmax + 1)
    cos_ml = np.cos(np.radians(lon)[None, :] * m[:, None])          # (m, lon)
    sin_ml = np.sin(np.radians(lon)[None, :] * m[:, None])
    block = max(1, min(64, 20_000_000 // (nmax + 1) ** 2))          # rows at a time: P is (n, m, rows)
    for start in range(0, lat.size, block):
        rows = slice(start, min(start + block, lat.size))
        P = legendre_normalised(nmax, np.sin(np.radians(lat[rows])))
        a = np.einsum("nmk,nm->km", P, C)                             # sum over n: (rows, m)
        b = np.einsum("nmk,nm->km", P, S)
        out[rows] = a @ cos_ml + b @ sin_ml
    return out


def shadr_dem(path: str | os.PathLike, *, ppd: int = 1, degree: int | None = None) -> DEM:
    """A DEM (km) of a SHADR shape model evaluated at the pixel centres of a ``ppd`` grid."""
    ppd = checked_ppd(ppd, MAX_PPD)
    if degree is not None and (isinstance(degree, bool) or not isinstance(degree, (int, np.integer))):
        raise ValueError(f"degree must be an integer, got {degree!r}")
    model = read_shadr(path)
    lat = -90.0 + (np.arange(180 * ppd) + 0.5) / ppd
    lon = (np.arange(360 * ppd) + 0.5) / ppd
    radii_km = shadr_radius(model, lat, lon, degree) / 1000.0
    from .synthetic import MARS_F, MARS_RE

    if abs(model["ref_radius_km"] - MARS_RE) < 5.0:                  # Mars: its reference spheroid
        re, f = MARS_RE, MARS_F
    else:
        re, f = model["ref_radius_km"], 0.0
    try:
        return DEM.from_array(radii_km, f=f, re=re)
    except ValueError as exc:
        raise SHADRError(f"SHADR file {Path(path)}: {exc}") from None


def import_shadr(path: str | os.PathLike, out: str | os.PathLike, *, ppd: int = 1, degree: int | None = None,
                 overwrite: bool = False) -> Path:
    """Evaluate a SHADR shape model to a ``.hdr``/``.dem`` pair (float32 km); return the ``.hdr``. Never
    over the model's file itself."""
    return shadr_dem(path, ppd=ppd, degree=degree).write(out, dtype="float32", overwrite=overwrite, inputs=[path])
