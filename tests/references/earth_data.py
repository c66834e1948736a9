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
    # The text files round the centres to 7 decimals and accumulate the rounded step (their last
    # longitude is 380.1666307, not 380.1666667): taken as printed, dlon = 0.3333333 makes 1,080
    # columns span 359.999964 deg, a grid that is not global (a 4 m gap at the equator: 22 benchmark
    # rays left it, and the Rugged bridge, seeing no wrap, cut its tiles to 3 columns and rebuilt
    # one a ray; an independent review of the benchmark, 2026-12-05). The grid is 20' exactly:
    # take the steps as 180/nrows and 360/ncols and the first centres on that lattice, after
    # checking that the files say so to their printed precision.
    nrows, ncols = z.shape
    dlat, dlon = 180.0 / nrows, 360.0 / ncols
    lat_first = -90.0 + dlat / 2
    lon_first = round(float(lons[0]) / (dlon / 2)) * (dlon / 2)
    for name, got, want in (("latitude step", lats[1] - lats[0], dlat), ("longitude step", lons[1] - lons[0], dlon),
                            ("first latitude", lats[0], lat_first), ("first longitude", lons[0], lon_first)):
        if abs(float(got) - want) > 1e-6:
            raise ValueError(f"{folder}: the ETOPO20 {name} is {float(got)!r}, not {want!r} (a 20' global grid)")
    return dict(heights=z, lat_first=lat_first, lon_first=lon_first, dlat=dlat, dlon=dlon, a=WGS84_A, f=WGS84_F)
