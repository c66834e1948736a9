"""One surface, two systems: the planetary DEM's exact mode (fortran/pi_exact.f90, Teanby's
system) and the geodetic DSM's (fortran/pi_dsm_exact.f90 with pi_dsm_fast.f90, Shin & Park's)
on the same bilinear surface.

On a sphere (f = 0) geodetic latitude is planetocentric latitude and the height above the
sphere is the radius less a, so a DEM of radii R + h and a DSM of heights h on the same
pixel-centre grid (first centre 1/(2 ppd) deg from the south pole and from 0 E, cells 1/ppd)
are one surface: bilinear in (lat, lon) in both. The two exact modes were written for
different contracts, share no search code, work in different units (km here, m there) and
report longitudes in different ranges; each claims the first entry into that surface (the
DEM's to 1e-9 rmax along the ray, the DSM's to 1e-6 m). So they must agree on which rays hit
and, where both hit, on the point, to the sum of the two tolerances.

Measured when written (2026-12-05, 20,000 rays at 4 ppd from 100-2,000 km, nadir to grazing,
on a rough random surface): 19,910 hits in both, no disagreement, distances within 3.4e-9 km
(3.4 um; the DEM's tolerance is 3.4e-6 km).
"""

from __future__ import annotations

import numpy as np
import pytest

import planet_intersect as pi

R = 3390.0                      # km


def _surface(ppd: int, seed: int):
    rng = np.random.default_rng(seed)
    nlat, nlon = 180 * ppd, 360 * ppd
    lat = -90 + (np.arange(nlat) + 0.5) / ppd
    lon = (np.arange(nlon) + 0.5) / ppd
    la, lo = np.meshgrid(np.radians(lat), np.radians(lon), indexing="ij")
    h = 3.0 * np.sin(3 * lo) * np.cos(2 * la) + 2.0 * np.cos(5 * la + lo) + rng.normal(0, 0.8, (nlat, nlon))
    dem = pi.DEM.from_array(R + h, f=0.0, re=R)
    dsm = pi.GeodeticDSM.from_array(h * 1000.0, lat[0], lon[0], 1.0 / ppd, 1.0 / ppd, a=R * 1000.0, f=0.0)
    return dem, dsm


def _rays(n: int, seed: int):
    """From 100-2,000 km up, aimed at impact parameters from 3,000 km inside the sphere to 15 km
    above it: nadir to grazing, over all latitudes (both systems' grids reach +-89.875 deg)."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    s = u * (R + rng.uniform(100, 2000, n))[:, None]
    w = rng.normal(size=(n, 3))
    w -= (w * u).sum(1)[:, None] * u
    w /= np.linalg.norm(w, axis=1)[:, None]
    b = np.clip(R + rng.uniform(-3000, 15, n), 0, None)
    ang = np.arcsin(np.minimum(b / np.linalg.norm(s, axis=1), 1.0))
    l = -np.cos(ang)[:, None] * u + np.sin(ang)[:, None] * w
    return s, l


@pytest.mark.parametrize("ppd, seed", [(4, 1), (2, 7)])
def test_the_dem_and_the_dsm_exact_modes_agree_on_one_surface(ppd, seed):
    dem, dsm = _surface(ppd, seed)
    s, l = _rays(6000, seed + 100)
    a = pi.intersect(dem, s, l, method="exact", threads=1)
    b = pi.intersect(dsm, s * 1000.0, l, method="exact", threads=1)
    hit_a, hit_b = np.asarray(a.hit), np.asarray(b.hit)
    assert hit_a.sum() > 5000 and (~hit_a).sum() > 5           # hits and misses (grazing rays) both
    assert np.array_equal(hit_a, hit_b), np.flatnonzero(hit_a != hit_b)[:10]
    # the misses are grazing rays that never come down to the surface (MISS), not rays that left
    # the DSM's grid: its polar caps beyond the outer rows of centres have no surface, the DEM's
    # are filled in (paper-notes note 9), but no ray here reaches them low
    assert set(np.unique(b.status[~hit_b]).tolist()) == {int(pi.DSMStatus.MISS)}
    ra = np.linalg.norm(a.p - s, axis=1)[hit_a]
    rb = np.asarray(b.distance)[hit_b] / 1000.0
    tol = 1e-9 * dem.rmax + 1e-6 / 1000.0                      # the two contracts' tolerances, km
    assert np.max(np.abs(ra - rb)) <= tol
    # the same point, to the same tolerance: in space, in latitude and longitude (DEM [0, 360), DSM
    # [-180, 180)) as an angle at the centre, and in height (the DEM's radius less R against the
    # DSM's height above the sphere)
    assert np.max(np.linalg.norm(a.p[hit_a] - np.asarray(b.p)[hit_b] / 1000.0, axis=1)) <= tol
    ang = np.degrees(tol / R)
    assert np.max(np.abs(a.lat[hit_a] - b.lat[hit_b])) <= ang
    dlon = (a.lon[hit_a] - b.lon[hit_b] + 180.0) % 360.0 - 180.0
    assert np.max(np.abs(dlon * np.cos(np.radians(a.lat[hit_a])))) <= ang
    np.testing.assert_allclose(a.radius[hit_a] - R, b.height[hit_b] / 1000.0, atol=tol, rtol=0)
