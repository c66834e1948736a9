"""Deterministic synthetic DEMs and the demo scene.

``mars_like_dem`` is the built-in default of the quick start: Mars's reference
spheroid (eq. 61) plus a large shield volcano where Olympus Mons stands and
rough terrain from a fixed sum of smooth periodic waves. Nothing is random at
run time: the same call gives the same grid everywhere.
"""

from __future__ import annotations

import numpy as np

from .dem import DEM
from .geometry import detector_los, spheroid_radius

__all__ = ["MARS_RE", "MARS_F", "MARS_MEAN_RADIUS", "OLYMPUS", "mars_like_dem", "rough_dem", "oblique_scene",
           "adversarial_dem"]

#: Mars equatorial radius (km) and flattening used throughout (IAU-style values;
#: re = 3396.19 km, polar 3376.2 km gives f = 1/169.9; DESIGN uses 1/169.8)
MARS_RE = 3396.19
MARS_F = 1.0 / 169.8
#: Mars mean radius, km
MARS_MEAN_RADIUS = 3389.5
#: Olympus Mons summit region (planetocentric lat, east lon, degrees)
OLYMPUS = (18.65, 226.2)


def _waves(lat_deg, lon_deg, seed: int, n_waves: int, rms: float, max_wavenumber: int):
    """A fixed sum of waves cos(k lat) x cos(m lon + phase), continuous over the sphere."""
    rng = np.random.default_rng(seed)
    lat = np.radians(lat_deg)[:, None]
    lon = np.radians(lon_deg)[None, :]
    z = np.zeros((lat.shape[0], lon.shape[1]))
    for _ in range(n_waves):
        m = int(rng.integers(1, max_wavenumber + 1))
        k = int(rng.integers(1, max_wavenumber + 1))
        amp = rng.standard_normal() / np.sqrt(m * k)
        ph1, ph2 = rng.uniform(0, 2 * np.pi, 2)
        # the cos(lat) factor makes every wave single-valued at the poles
        z += amp * np.cos(lat) * np.cos(k * lat + ph1) * np.cos(m * lon + ph2)
    return z * (rms / z.std())


def _great_circle_km(lat_deg, lon_deg, lat0, lon0, radius):
    la, lo = np.radians(lat_deg)[:, None], np.radians(lon_deg)[None, :]
    la0, lo0 = np.radians(lat0), np.radians(lon0)
    c = np.sin(la) * np.sin(la0) + np.cos(la) * np.cos(la0) * np.cos(lo - lo0)
    return radius * np.arccos(np.clip(c, -1.0, 1.0))


def mars_like_dem(ppd: int = 4, seed: int = 2008) -> DEM:
    """A synthetic Mars DEM in km: spheroid + 21 km shield volcano + ~1.5 km rough terrain.

    The volcano is a Gaussian of 21 km height and 160 km e-folding width
    centred on Olympus Mons (18.65 N, 226.2 E); the terrain is 120 fixed waves
    of up to wavenumber 60 with 1.5 km RMS.
    """
    lat = -90.0 + (np.arange(180 * ppd) + 0.5) / ppd
    lon = (np.arange(360 * ppd) + 0.5) / ppd
    radii = np.broadcast_to(spheroid_radius(lat, MARS_F, MARS_RE)[:, None], (lat.size, lon.size)).copy()
    dist = _great_circle_km(lat, lon, *OLYMPUS, MARS_MEAN_RADIUS)
    radii += 21.0 * np.exp(-(dist / 160.0) ** 2)
    radii += _waves(lat, lon, seed, n_waves=120, rms=1.5, max_wavenumber=60)
    return DEM.from_array(radii, f=MARS_F, re=MARS_RE)


def rough_dem(ppd: int = 2, base: float = 3390.0, rms: float = 3.0, seed: int = 7,
              f: float = 0.0, re: float | None = None, cell_noise: float = 0.0) -> DEM:
    """A rough synthetic DEM for tests: constant base radius + smooth waves +
    optional independent per-cell noise (spikes between neighbouring cells).
    Without ``re``: no reference spheroid (Table 1's f = 0, re = 1; DEM.from_array)."""
    lat = -90.0 + (np.arange(180 * ppd) + 0.5) / ppd
    lon = (np.arange(360 * ppd) + 0.5) / ppd
    radii = base + _waves(lat, lon, seed, n_waves=60, rms=rms, max_wavenumber=40)
    if cell_noise:
        radii += cell_noise * np.random.default_rng(seed + 1).standard_normal(radii.shape)
    return DEM.from_array(radii, f=f, re=re)


def oblique_scene(nh: int = 101, nv: int = 101, pixel: float = 0.015, altitude: float = 325.0,
                  south_offset_deg: float = 12.0):
    """The paper's Fig. 8 geometry: a detector due south of Olympus Mons looking at it.

    The spacecraft is ``south_offset_deg`` degrees of latitude south of the summit
    region, ``altitude`` km above the mean radius; the centre pixel looks at the
    summit region on the mean sphere; the array's vertical side is the local
    "up" of the image (towards north, perpendicular to the line of sight).
    Returns ``(s, l)`` with ``s`` shape (3,) and ``l`` shape (nv*nh, 3).
    """
    lat0, lon0 = OLYMPUS
    la, lo = np.radians(lat0 - south_offset_deg), np.radians(lon0)
    r_s = MARS_MEAN_RADIUS + altitude
    s = r_s * np.array([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)])
    lt, lg = np.radians(lat0), np.radians(lon0)
    target = MARS_MEAN_RADIUS * np.array([np.cos(lt) * np.cos(lg), np.cos(lt) * np.sin(lg), np.sin(lt)])
    l0 = target - s
    l0 /= np.linalg.norm(l0)
    up = s / np.linalg.norm(s)
    q = up - np.dot(up, l0) * l0
    q /= np.linalg.norm(q)
    return s, detector_los(l0, q, nh, nv, pixel, pixel)


def adversarial_dem(kind: str, ppd: int = 1, base: float = 3390.0, seed: int = 0) -> DEM:
    """DEMs built to break ray stepping: ``needles`` (isolated one-node spikes
    3-15 km high, some within a pixel of the poles and at 0/360 E), ``blocks``
    (building-like rectangles of nodes raised 2-8 km with vertical-as-possible
    walls), ``ridges`` (one-node-wide walls along meridians and parallels)."""
    rng = np.random.default_rng(seed)
    nlat, nlon = 180 * ppd, 360 * ppd
    radii = np.full((nlat, nlon), base) + 0.05 * rng.standard_normal((nlat, nlon))
    if kind == "needles":
        n = nlat * nlon // 40
        radii[rng.integers(0, nlat, n), rng.integers(0, nlon, n)] += rng.uniform(3, 15, n)
        radii[[0, 0, -1, -1, 1, -2], [0, nlon // 2, 3, nlon - 1, 7, 11]] += 12.0      # at the poles
        radii[rng.integers(0, nlat, 20), 0] += 9.0                                      # at 0/360 E
        radii[rng.integers(0, nlat, 20), -1] += 9.0
    elif kind == "blocks":
        for _ in range(nlat * nlon // 300):
            j, i = rng.integers(0, nlat - 4), rng.integers(0, nlon)
            h, w = rng.integers(1, 4), rng.integers(1, 4)
            cols = np.arange(i, i + w) % nlon
            radii[j:j + h, cols] += rng.uniform(2, 8)
    elif kind == "ridges":
        for _ in range(ppd * 12):
            i = rng.integers(0, nlon)
            j0, j1 = sorted(rng.integers(0, nlat, 2))
            radii[j0:j1, i] += rng.uniform(2, 6)
            j = rng.integers(0, nlat)
            i0 = rng.integers(0, nlon)
            radii[j, np.arange(i0, i0 + nlon // 6) % nlon] += rng.uniform(2, 6)
    else:
        raise ValueError(f"kind must be needles, blocks or ridges, got {kind!r}")
    return DEM.from_array(radii)
