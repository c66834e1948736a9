"""The ETOPO20 Earth relief grid of ../shared/data ($PI_SHARED_DATA) as a
global geodetic DSM grid, for the tests and the benchmark harness (one loader,
so that both read the same grid the same way).

``etopo20_grid(folder)``: dict(heights, lat_first, lon_first, dlat, dlon, a, f)
with the 1080 unique columns (the file repeats the first longitude at the
end), south row first, heights in metres above sea level taken as above
WGS-84 (a constant geoid is irrelevant to the geometry tested); None when the
files are absent.
"""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np

FILES = ("etopo20data.gz", "etopo20lats.gz", "etopo20lons.gz")


def etopo20_grid(folder) -> dict | None:
    folder = Path(folder)
    if not all((folder / f).exists() for f in FILES):
        return None
    with gzip.open(folder / FILES[0], "rt") as fh:
        z = np.loadtxt(fh)[:, :1080]
    with gzip.open(folder / FILES[1], "rt") as fh:
        lats = np.loadtxt(fh)
    with gzip.open(folder / FILES[2], "rt") as fh:
        lons = np.loadtxt(fh)
    from planet_intersect.geodetic import WGS84_A, WGS84_F
    return dict(heights=z, lat_first=float(lats[0]), lon_first=float(lons[0]), dlat=float(lats[1] - lats[0]),
                dlon=float(lons[1] - lons[0]), a=WGS84_A, f=WGS84_F)
