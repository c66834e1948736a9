"""NAIF SPICE type-2 DSK plate models written from a DEM, and ray intercepts on them.

The plate model has a vertex at every pixel centre of the DEM plus one at each
pole (carrying the polar-row mean radius, as the paper's interpolation does),
two triangles per cell between neighbouring rows and columns (wrapping across
0/360 E) and a fan of triangles round each pole. It samples the same radii as
the DEM, but its surface is planar between vertices while the paper's surface
is bilinear in latitude/longitude: :func:`plate_bilinear_bound` bounds the radial
difference cell by cell. Needs ``spiceypy`` (bundles CSPICE; works offline).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .dem import DEM

__all__ = ["plate_model", "write_dsk", "PlateIntercept", "plate_bilinear_bound", "bound_at"]

MARS_ID = 499  #: NAIF ID of Mars, used as the DSK's centre body by default


def plate_model(dem: DEM):
    """Vertices (nv, 3) and 1-based plates (np, 3) of the DEM's triangulated surface."""
    nlat, nlon = dem.nlat, dem.nlon
    lat = np.radians(dem.lat)[:, None]
    lon = np.radians(dem.lon)[None, :]
    r = np.asarray(dem.radii, dtype=np.float64)
    xyz = np.stack([r * np.cos(lat) * np.cos(lon), r * np.cos(lat) * np.sin(lon), r * np.sin(lat) + 0 * lon], -1)
    south = r[0].sum() / nlon
    north = r[-1].sum() / nlon
    verts = np.concatenate([xyz.reshape(-1, 3), [[0.0, 0.0, -south], [0.0, 0.0, north]]])
    vid = np.arange(nlat * nlon).reshape(nlat, nlon) + 1          # 1-based
    i2 = np.roll(np.arange(nlon), -1)
    a, b = vid[:-1, :], vid[:-1, i2]                                # SW, SE
    c, d = vid[1:, :], vid[1:, i2]                                  # NW, NE
    quads = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    sp, np_ = nlat * nlon + 1, nlat * nlon + 2
    row0, rowN = vid[0], vid[-1]
    caps = np.concatenate([np.stack([np.full(nlon, sp), row0[i2], row0], -1),
                           np.stack([np.full(nlon, np_), rowN, rowN[i2]], -1)])
    plates = np.concatenate([quads, caps]).astype(np.int32)
    # outward orientation: the normal must point away from the centre
    v = verts[plates - 1]
    normal = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    flip = np.sum(normal * v.mean(axis=1), axis=1) < 0
    plates[flip] = plates[flip][:, [0, 2, 1]]
    return verts, plates


def write_dsk(dem: DEM, path: str | os.PathLike, body: int = MARS_ID, surface: int = 1,
              frame: str = "IAU_MARS") -> Path:
    """Write the DEM's plate model as a type-2 DSK segment (``dskmi2`` + ``dskw02``)."""
    import spiceypy as sp

    path = Path(path)
    if path.exists():
        raise FileExistsError(f"{path} exists")
    verts, plates = plate_model(dem)
    nv, npl = len(verts), len(plates)
    if nv > 16_000_002 or npl > 32_000_000:
        raise ValueError(f"{nv} vertices / {npl} plates exceed one DSK type-2 segment (16,000,002 / 32,000,000)")
    finscl, corscl = 5.0, 4
    worksz = max(1_000_000, 12 * npl)
    voxpsz = max(100_000, 6 * npl)
    voxlsz = max(100_000, 6 * npl)
    spaisz = 100_007 + voxpsz + voxlsz + nv + 3 * npl + 1 + 10 * npl
    spaixd, spaixi = sp.dskmi2(verts, plates, finscl, corscl, worksz, voxpsz, voxlsz, False, spaisz)
    corpar = np.zeros(10)
    mncor3, mxcor3 = sp.dskrb2(verts, plates, 1, corpar)
    handle = sp.dskopn(str(path), "planet-intersect DEM plates", 0)
    try:
        sp.dskw02(handle, body, surface, 1, frame, 1, corpar, -np.pi, np.pi, -np.pi / 2, np.pi / 2,
                  mncor3, mxcor3, -1e12, 1e12, verts, plates, spaixd, spaixi)
    finally:
        sp.dskcls(handle, True)
    return path


class PlateIntercept:
    """Ray intercepts with a DSK written by :func:`write_dsk` (``dskx02``), as a context manager."""

    def __init__(self, path: str | os.PathLike):
        import spiceypy as sp

        self._sp = sp
        self.handle = sp.dasopr(str(path))
        try:
            self.dladsc = sp.dlabfs(self.handle)
        except Exception as exc:             # spiceypy raises when there is no segment
            sp.dascls(self.handle)
            raise ValueError(f"{path}: no DSK segment ({exc})") from None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        if self.handle is not None:
            self._sp.dascls(self.handle)
            self.handle = None

    def intercept(self, s, l):
        """First plate hit of rays s + d l: (points (N,3) with NaN where none, plate ids)."""
        s = np.atleast_2d(np.asarray(s, dtype=np.float64))
        l = np.atleast_2d(np.asarray(l, dtype=np.float64))
        s, l = np.broadcast_arrays(s, l)
        out = np.full(s.shape, np.nan)
        plate = np.zeros(len(s), dtype=np.int64)
        for k in range(len(s)):
            pid, x, found = self._sp.dskx02(self.handle, self.dladsc, s[k], l[k])
            if found:
                out[k] = x
                plate[k] = pid
        return out, plate


def plate_bilinear_bound(dem: DEM) -> np.ndarray:
    """Bound on |plate surface radius - bilinear surface radius|, per cell: an array
    ``[nlat + 1, nlon]`` whose row 0 is the south polar cap, row ``nlat`` the north cap
    and row j (1..nlat-1) the cell between DEM rows j-1 and j; column i spans
    DEM columns i and i+1 (wrapping). Look cells up with :func:`bound_at`.

    Two terms: (1) in (lat, lon, r) the bilinear patch differs from the linear
    interpolant on either of its triangles by the twist term, at most
    |r1 - r2 - r3 + r4| / 4 (at a cap r1 = r2 = the polar mean, so |r3 - r4| / 4);
    (2) a planar plate departs from the surface that is linear in angle by at
    most twice the sag of a chord spanning the cell's longer diagonal D,
    2 r_max (1 - cos(D/2)); (3) a plate edge joining two vertices of one row is
    a great-circle chord, which bulges poleward of the row's parallel by up to
    tan(lat) h^2/8 (h the column spacing): near a pole the plate above a
    direction interpolates a shifted spot of the grid, which changes the
    radius by at most the cell's largest radius gradient times that shift.
    Because of that shift the plate above a direction may belong to a
    neighbouring cell, so each cell finally takes the largest bound of its 3 x 3
    neighbourhood (wrapping in longitude).
    """
    r = np.asarray(dem.radii, dtype=np.float64)
    r2 = np.roll(r, -1, axis=1)
    twist = np.abs(r[:-1] - r2[:-1] - r[1:] + r2[1:]) / 4.0
    caps_twist = np.abs(r[[0, -1]] - r2[[0, -1]]) / 4.0
    lat = np.radians(dem.lat)
    h = np.radians(1.0 / dem.ppd)
    diag = np.arccos(np.clip(np.sin(lat[:-1]) * np.sin(lat[1:]) + np.cos(lat[:-1]) * np.cos(lat[1:]) * np.cos(h), -1, 1))
    rmax = r.max()
    sag = 2 * rmax * (1 - np.cos(np.maximum(diag, h) / 2))
    cap_sag = 2 * rmax * (1 - np.cos(h / 2))            # pole to the row half a pixel away, columns h apart
    # (3): largest radius gradient (km/rad) of each cell's edges, times the poleward bulge
    south, north = r[0].mean(), r[-1].mean()
    dlon = np.abs(r - r2) / h
    dlat = np.abs(np.diff(r, axis=0)) / h
    grad = np.maximum.reduce([dlon[:-1], dlon[1:], dlat, np.roll(dlat, -1, axis=1)])
    cap_grad = [np.maximum(dlon[0], np.abs(r[0] - south) / (h / 2)),
                np.maximum(dlon[-1], np.abs(r[-1] - north) / (h / 2))]
    poleward = np.maximum(np.abs(lat[:-1]), np.abs(lat[1:]))
    bulge = np.tan(poleward) * h * h / 8
    cap_bulge = np.tan(np.abs(lat[0])) * h * h / 8
    out = np.empty((dem.nlat + 1, dem.nlon))
    out[0] = caps_twist[0] + cap_sag + cap_grad[0] * cap_bulge
    out[-1] = caps_twist[1] + cap_sag + cap_grad[1] * cap_bulge
    out[1:-1] = twist + sag[:, None] + grad * bulge[:, None]
    nb = np.maximum(out, np.maximum(np.roll(out, 1, axis=1), np.roll(out, -1, axis=1)))
    nb[1:] = np.maximum(nb[1:], nb[:-1].copy())
    nb[:-1] = np.maximum(nb[:-1], nb[1:].copy())
    return nb


def bound_at(dem: DEM, bound: np.ndarray, lat, lon) -> np.ndarray:
    """The cell of :func:`plate_bilinear_bound` holding each (lat, lon) in degrees."""
    lat = np.asarray(lat, dtype=np.float64)
    lon = np.asarray(lon, dtype=np.float64)
    row = np.clip(np.floor((lat + 90.0) * dem.ppd - 0.5).astype(np.int64) + 1, 0, dem.nlat)
    col = np.floor(np.mod(lon - 0.5 / dem.ppd, 360.0) * dem.ppd).astype(np.int64) % dem.nlon
    return bound[row, col]
