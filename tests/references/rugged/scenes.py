"""Small scenes for the Rugged reference: geodetic conversions, a building DSM, pushbroom rays.

Written for the Rugged checks and benchmark only (pure NumPy), independent of
the package's own geodetic code.
"""

from __future__ import annotations

import numpy as np

WGS84_A = 6378137.0
WGS84_F = 1 / 298.257223563


def geodetic_to_ecr(lat, lon, h, a=WGS84_A, f=WGS84_F):
    """ECR Cartesian (N, 3) of geodetic latitude, longitude (degrees) and height (units of a)."""
    e2 = f * (2 - f)
    la, lo = np.radians(lat), np.radians(lon)
    n = a / np.sqrt(1 - e2 * np.sin(la) ** 2)
    h = np.asarray(h, dtype=np.float64)
    return np.stack([(n + h) * np.cos(la) * np.cos(lo),
                     (n + h) * np.cos(la) * np.sin(lo),
                     (n * (1 - e2) + h) * np.sin(la)], axis=-1)


def ecr_to_geodetic(p, a=WGS84_A, f=WGS84_F):
    """Geodetic latitude, longitude (degrees) and height of ECR points (N, 3).

    Fixed-point iteration on the latitude (20 passes, converged to ~1e-15 rad
    away from the centre of the body), height from the projection formula
    h = p cos(lat) + z sin(lat) - a sqrt(1 - e2 sin^2 lat), good at every latitude.
    """
    p = np.asarray(p, dtype=np.float64)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    e2 = f * (2 - f)
    rho = np.hypot(x, y)
    lat = np.arctan2(z, rho * (1 - e2))
    for _ in range(20):
        s = np.sin(lat)
        n = a / np.sqrt(1 - e2 * s * s)
        lat = np.arctan2(z + e2 * n * s, rho)
    s, c = np.sin(lat), np.cos(lat)
    h = rho * c + z * s - a * np.sqrt(1 - e2 * s * s)
    return np.degrees(lat), np.degrees(np.arctan2(y, x)), h


def local_frame(lat, lon):
    """East, north, up unit vectors (N, 3) at geodetic (lat, lon) in degrees."""
    la, lo = np.radians(lat), np.radians(lon)
    east = np.stack([-np.sin(lo), np.cos(lo), np.zeros_like(lo)], axis=-1)
    north = np.stack([-np.sin(la) * np.cos(lo), -np.sin(la) * np.sin(lo), np.cos(la)], axis=-1)
    up = np.stack([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)], axis=-1)
    return east, north, up


def metre_steps(lat0, cell=1.0, a=WGS84_A, f=WGS84_F):
    """(dlat, dlon) in degrees of a `cell`-metre cell at latitude lat0 (degrees)."""
    e2 = f * (2 - f)
    s2 = np.sin(np.radians(lat0)) ** 2
    n = a / np.sqrt(1 - e2 * s2)
    m = a * (1 - e2) / (1 - e2 * s2) ** 1.5
    return np.degrees(cell / m), np.degrees(cell / (n * np.cos(np.radians(lat0))))


def building_dsm(n=1000, seed=0, nblocks=None, hmin=3.0, hmax=150.0):
    """n x n heights (metres) of random rectangular blocks 3-150 m tall on flat ground at 0.

    Blocks are 4-60 cells wide, placed at random (later ones over earlier ones),
    some one-cell towers; about 40 % of the ground is built.
    """
    rng = np.random.default_rng(seed)
    h = np.zeros((n, n))
    nblocks = nblocks if nblocks is not None else max(1, int(0.4 * n * n / 900))
    for _ in range(nblocks):
        wi, wj = rng.integers(4, 61, size=2)
        i, j = rng.integers(0, n - 1, size=2)
        h[i:i + wi, j:j + wj] = rng.uniform(hmin, hmax)
    for _ in range(max(1, n // 20)):  # narrow towers, one cell wide
        i, j = rng.integers(0, n, size=2)
        h[i, j] = rng.uniform(hmin, hmax)
    return h


def pushbroom_rays(n, lat_range, lon_range, altitude=600e3, max_off_nadir=30.0, seed=0,
                   a=WGS84_A, f=WGS84_F, ground=None):
    """Rays of a pushbroom scanner at `altitude` looking 0..max_off_nadir deg off nadir.

    Each ray aims at a random ground point of the given lat/lon box (at height
    ``ground(lat, lon)`` when given, else 0); the
    satellite sits up-range of it across track (east or west), at the off-nadir
    angle drawn uniformly in [0, max_off_nadir] degrees (incidence from the
    spherical relation sin(i) = (R+H)/R sin(off-nadir)). Returns s, l (N, 3) ECR.
    """
    rng = np.random.default_rng(seed)
    lat = rng.uniform(*lat_range, n)
    lon = rng.uniform(*lon_range, n)
    g = geodetic_to_ecr(lat, lon, 0.0 if ground is None else ground(lat, lon), a, f)
    east, _, up = local_frame(lat, lon)
    off = np.radians(rng.uniform(0.0, max_off_nadir, n))
    r = np.linalg.norm(g, axis=1)
    inc = np.arcsin(np.clip((r + altitude) / r * np.sin(off), -1, 1))
    side = rng.choice([-1.0, 1.0], n)[:, None]
    u = np.cos(inc)[:, None] * up + np.sin(inc)[:, None] * side * east
    # distance from g along u to the sphere of radius r + altitude
    b = np.einsum("ij,ij->i", g, u)
    d = -b + np.sqrt(b * b - r * r + (r + altitude) ** 2)
    s = g + d[:, None] * u
    return s, -u
