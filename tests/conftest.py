"""Shared helpers: DEM fixtures, ray generators, the path to ../shared/data."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect.synthetic import MARS_F, MARS_RE, rough_dem

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("PI_SHARED_DATA", REPO.parent / "shared" / "data"))


def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def random_unit(rng, n):
    return unit(rng.standard_normal((n, 3)))


def perpendicular_unit(rng, u):
    """Random unit vectors perpendicular to the rows of u."""
    e = rng.standard_normal(u.shape)
    e -= np.sum(e * u, axis=1, keepdims=True) * u
    return unit(e)


def xyz(lat_deg, lon_deg, r):
    la, lo = np.radians(lat_deg), np.radians(lon_deg)
    return np.stack([r * np.cos(la) * np.cos(lo), r * np.cos(la) * np.sin(lo), r * np.sin(la)], axis=-1)


def mixed_rays(dem: pi.DEM, n: int, seed: int = 0):
    """n rays of mixed geometry over ``dem``; returns (s, l, kind) with kind a label per ray.

    Kinds: nadir (within 1e-3 rad of straight down, some exactly), oblique
    (aimed at the surface, 10-80 deg off nadir), grazing (tangent radius between
    the lowest radius and rmax), limb (tangent radius up to 300 above rmax),
    away (pointing away), pole (aimed within a pixel of either pole), antimeridian
    (aimed across 0/360 E, moving east-west), inside_rmax (spacecraft between
    the surface and rmax).
    """
    rng = np.random.default_rng(seed)
    rmin = float(np.min(dem.radii))
    rmax = dem.rmax
    kinds = ["nadir", "oblique", "grazing", "limb", "away", "pole", "antimeridian", "inside_rmax"]
    weights = np.array([1, 2, 3, 2, 1, 1, 1, 0.5])
    counts = np.floor(weights / weights.sum() * n).astype(int)
    counts[1] += n - counts.sum()
    S, L, K = [], [], []
    for kind, m in zip(kinds, counts):
        if kind == "nadir":
            u = random_unit(rng, m)
            s = u * (rmax + rng.uniform(50, 2000, m))[:, None]
            l = -u + 1e-3 * rng.uniform(0, 1, (m, 1)) * perpendicular_unit(rng, u)
            l[: m // 10] = -u[: m // 10]
        elif kind == "oblique":
            u = random_unit(rng, m)
            target = u * rmin
            off = np.radians(rng.uniform(10, 80, m))
            e = perpendicular_unit(rng, u)
            up = np.cos(off)[:, None] * u + np.sin(off)[:, None] * e
            s = target + up * rng.uniform(300, 3000, m)[:, None]
            l = target - s
        elif kind in ("grazing", "limb"):
            u = random_unit(rng, m)
            e = perpendicular_unit(rng, u)
            tr = rng.uniform(rmin - 1.0, rmax, m) if kind == "grazing" else rng.uniform(rmax, rmax + 300, m)
            s = u * tr[:, None] - e * rng.uniform(500, 4000, m)[:, None]
            l = e
        elif kind == "away":
            u = random_unit(rng, m)
            s = u * (rmax + rng.uniform(50, 2000, m))[:, None]
            l = unit(u + 0.8 * perpendicular_unit(rng, u) * rng.uniform(0, 1, (m, 1)))
        elif kind == "pole":
            sign = np.where(rng.uniform(size=m) < 0.5, -1.0, 1.0)
            lat_t = sign * (90.0 - rng.uniform(0, 1.0 / dem.ppd, m))
            target = xyz(lat_t, rng.uniform(0, 360, m), rmin)
            u = unit(target)
            e = perpendicular_unit(rng, u)
            off = np.radians(rng.uniform(0, 85, m))
            s = target + (np.cos(off)[:, None] * u + np.sin(off)[:, None] * e) * rng.uniform(200, 2000, m)[:, None]
            l = target - s
        elif kind == "antimeridian":
            lon_t = rng.uniform(-1.0, 1.0, m) % 360.0
            lat_t = rng.uniform(-60, 60, m)
            target = xyz(lat_t, lon_t, rmin)
            u = unit(target)
            east = unit(np.stack([-np.sin(np.radians(lon_t)), np.cos(np.radians(lon_t)), np.zeros(m)], axis=1))
            direction = np.where(rng.uniform(size=m)[:, None] < 0.5, east, -east)
            s = target + (0.3 * u + direction) * rng.uniform(200, 1500, m)[:, None]
            l = target - s
        else:  # inside_rmax: spacecraft just above the local surface, below rmax
            lat_s = rng.uniform(-80, 80, m)
            lon_s = rng.uniform(0, 360, m)
            r_here = dem.radius(lat_s, lon_s)
            h = np.minimum(rng.uniform(0.05, 1.0, m) * (rmax - r_here), rmax - r_here - 1e-6)
            s = xyz(lat_s, lon_s, r_here + np.maximum(h, 1e-3))
            l = random_unit(rng, m)
        S.append(s)
        L.append(unit(l))
        K += [kind] * m
    return np.concatenate(S), np.concatenate(L), np.array(K)


@pytest.fixture(scope="session")
def rough():
    """A rough synthetic DEM, 2 pixels/degree, Mars-like spheroid in the header."""
    return rough_dem(ppd=2, base=3390.0, rms=3.0, seed=11, f=MARS_F, re=MARS_RE, cell_noise=0.4)


@pytest.fixture(scope="session")
def rough_file(tmp_path_factory, rough):
    """The same DEM written as a float64 file pair and read back."""
    path = tmp_path_factory.mktemp("dem") / "rough"
    rough.write(path)
    return pi.DEM.read(path.with_suffix(".hdr"))


def shared_data_or_skip(*parts) -> Path:
    p = SHARED_DATA.joinpath(*parts)
    if not p.exists():
        pytest.skip(f"real data not available: {p} is missing (set PI_SHARED_DATA to ../shared/data)")
    return p


def write_geotiff(path, a, crs, transform, nodata=None, **kw):
    """Write the array ``a`` ((rows, cols) or (bands, rows, cols)) as a GeoTIFF with rasterio (the
    reviews' tests of the readers); returns ``path``."""
    import rasterio

    a = np.asarray(a)
    with rasterio.open(path, "w", driver="GTiff", width=a.shape[-1], height=a.shape[-2],
                       count=1 if a.ndim == 2 else a.shape[0], dtype=a.dtype, crs=crs,
                       transform=transform, nodata=nodata, **kw) as d:
        d.write(a if a.ndim == 3 else a[None])
    return path

