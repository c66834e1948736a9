"""The image simulation's per-pixel rules (surface kind, local incidence, wall
texture, Lambertian shading) written in plain NumPy, as they were before the
Fortran kernel (fortran/pi_simulate.f90) took over: the equivalence test
(tests/test_simulate.py) checks that the kernel computes the same numbers.
This is NOT an independent reference (the closed-form checks are in
test_simulate_references.py); it guards the translation into Fortran."""

from __future__ import annotations


import numpy as np

from planet_intersect.dsm import GeodeticDSM
from planet_intersect.simulate import _bilinear, _grid_coords, _metres_per_degree


def _enu(lat_deg, lon_deg):
    """East, north, up unit vectors (N, 3) at geodetic (lat, lon)."""
    la, lo = np.radians(lat_deg), np.radians(lon_deg)
    sl, cl, so, co = np.sin(la), np.cos(la), np.sin(lo), np.cos(lo)
    e = np.stack([-so, co, np.zeros_like(so)], axis=-1)
    n = np.stack([-sl * co, -sl * so, cl], axis=-1)
    u = np.stack([cl * co, cl * so, sl], axis=-1)
    return e, n, u


class _Surface:
    """What the simulation needs of the DSM beyond the ray's hit: heights at
    fractional grid positions, the local gradient in metres, the ground model."""

    def __init__(self, dsm: GeodeticDSM, ground):
        self.dsm = dsm
        self.h = np.asarray(dsm.heights, dtype=np.float64)
        self.nearest = dsm.interpolation == "nearest"
        lat_mid = dsm.lat_first + 0.5 * (dsm.nrows - 1) * dsm.dlat
        my, mx = _metres_per_degree(lat_mid, 0.0, dsm.a, dsm.f)
        self.cell_y, self.cell_x = abs(dsm.dlat) * my, dsm.dlon * mx     # metres per cell (scene middle)
        self.ground = ground

    def uv(self, lat, lon):
        d = self.dsm
        return _grid_coords(lat, lon, d.lat_first, d.lon_first, d.dlat, d.dlon, d.ncols)

    def height_at(self, lat, lon):
        return np.asarray(self.dsm.height(lat, lon), dtype=np.float64)

    def gradient(self, lat, lon, h):
        """(dH/d east, dH/d north) in m/m of the DSM at the hits: the bilinear
        patch's gradient ("bilinear"); for "nearest" the step across the cell
        side the hit lies on, per cell width (zero on a flat top)."""
        d = self.dsm
        u, v = self.uv(lat, lon)
        my, mx = _metres_per_degree(lat, h, d.a, d.f)
        nr, nc = self.h.shape
        if not self.nearest:
            i = np.clip(np.floor(u).astype(np.intp), 0, max(nr - 2, 0))
            j = np.clip(np.floor(v).astype(np.intp), 0, max(nc - 2, 0))
            fu, fv = np.clip(u - i, 0, 1), np.clip(v - j, 0, 1)
            z = self.h
            i1, j1 = np.minimum(i + 1, nr - 1), np.minimum(j + 1, nc - 1)
            dhdu = (1 - fv) * (z[i1, j] - z[i, j]) + fv * (z[i1, j1] - z[i, j1])
            dhdv = (1 - fu) * (z[i, j1] - z[i, j]) + fu * (z[i1, j1] - z[i1, j])
        else:
            # the hit is on the side between the cell it is over and a neighbour when
            # u or v is within rounding of a half-integer [sim note 3]
            dhdu = np.zeros_like(u)
            dhdv = np.zeros_like(v)
            eps = 1e-6
            ic = np.clip(np.rint(u).astype(np.intp), 0, nr - 1)
            jc = np.clip(np.rint(v).astype(np.intp), 0, nc - 1)
            for axis, coord, out in ((0, u, dhdu), (1, v, dhdv)):
                frac = coord - np.floor(coord)
                side = np.abs(frac - 0.5) < eps
                lo = np.clip(np.floor(coord).astype(np.intp), 0, (nr if axis == 0 else nc) - 1)
                hi = np.clip(lo + 1, 0, (nr if axis == 0 else nc) - 1)
                if axis == 0:
                    step = self.h[hi, jc] - self.h[lo, jc]
                else:
                    step = self.h[ic, hi] - self.h[ic, lo]
                out[side] = np.nan_to_num(step[side])
        dnorth = dhdu / (d.dlat * my)            # d/d(lat deg) / (m per deg), sign of dlat included
        deast = dhdv / (d.dlon * mx)
        return deast, dnorth

    def ground_height(self, lat, lon):
        if self.ground is None:
            return None
        u, v = self.uv(lat, lon)
        return _bilinear(self.ground, u, v)


def shade_hits(surf: _Surface, ortho: OrthoImage, res, idx, l, walls, shading, sun_arr, ambient, cos_wall,
                roof_min):
    """Values, surface kinds and local incidence angles of the hit rays ``idx``."""
    lat, lon, h = res.lat[idx], res.lon[idx], res.height[idx]
    li = l[idx] / np.linalg.norm(l[idx], axis=1, keepdims=True)
    gx, gy = surf.gradient(lat, lon, h)                   # dH/deast, dH/dnorth (m/m)
    e, n, u = _enu(lat, lon)
    g2 = gx * gx + gy * gy
    # slope steeper than wall_slope <=> cos(slope) = 1/sqrt(1+g^2) < cos(wall_slope)  [sim note 1]
    wall = 1.0 / np.sqrt(1.0 + g2) < cos_wall
    if surf.nearest:
        # "nearest": a hit below the cell-top height lies on a cell side; it is a wall
        # when the step there is steep at cell scale (the gradient above) [sim note 3]
        on_side = res.surface_height[idx] - h > 1e-6
        wall &= on_side
    gn = np.sqrt(np.maximum(g2, 1e-300))
    horiz = (-(gx / gn))[:, None] * e + (-(gy / gn))[:, None] * n    # outward horizontal: downhill
    normal = (-gx)[:, None] * e + (-gy)[:, None] * n + u
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    if surf.nearest:
        normal = np.where(wall[:, None], horiz, u)         # flat tops; vertical sides
    else:
        normal = np.where(wall[:, None], horiz, normal)
    cosi = np.clip(-np.einsum("ij,ij->i", li, normal), -1, 1)
    loc_inc = np.degrees(np.arccos(cosi))
    ground = surf.ground_height(lat, lon)
    roof = ~wall & (h - ground > roof_min)
    kind = np.where(wall, 2, np.where(roof, 1, 0)).astype(np.int8)
    vals = ortho.sample(lat, lon)
    if walls == "interpolate" and wall.any():
        w = np.flatnonzero(wall)
        vals = np.array(vals, dtype=np.float64)
        vals[w] = _wall_values(surf, ortho, lat[w], lon[w], h[w], gx[w], gy[w], gn[w])
    if shading == "lambert":
        sun = _sun_vectors(sun_arr, lat, lon)
        fac = ambient + (1 - ambient) * np.maximum(0.0, np.einsum("ij,ij->i", normal, sun))
        vals = vals * (fac if vals.ndim == 1 else fac[:, None])
    return vals, kind, loc_inc


def _wall_values(surf: _Surface, ortho: OrthoImage, lat, lon, h, gx, gy, gn):
    """Wall texture [sim note 2]: the ortho-photo has none, so a wall hit's value
    is interpolated linearly in height between the ortho value at the roof edge
    (a point one sample inside the building, against the outward horizontal
    normal) and at the wall's foot (one sample outside): a vertical ramp from
    the roof-edge colour at the top to the ground colour at the bottom.

    The sample step is half a cell for "nearest" (the wall is a cell side: the
    two cell centres) and one cell for "bilinear" (the wall is a one-cell ramp
    between the roof's last node and the ground's first)."""
    d = surf.dsm
    step_cells = 0.5 if surf.nearest else 1.0
    dx, dy = gx / gn, gy / gn                               # uphill unit direction (east, north)
    my, mx = _metres_per_degree(lat, h, d.a, d.f)
    # one step in cells along the direction: metres per cell projected on it
    cell_m = np.abs(dx) * surf.cell_x + np.abs(dy) * surf.cell_y
    step_m = step_cells * np.maximum(cell_m, 1e-9)
    lat_in = lat + dy * step_m / my
    lon_in = lon + dx * step_m / mx
    lat_out = lat - dy * step_m / my
    lon_out = lon - dx * step_m / mx
    h_top = surf.height_at(lat_in, lon_in)
    h_foot = surf.height_at(lat_out, lon_out)
    v_top = ortho.sample(lat_in, lon_in)
    v_foot = ortho.sample(lat_out, lon_out)
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.clip((h - h_foot) / (h_top - h_foot), 0.0, 1.0)
    t = np.where(np.isfinite(t), t, 0.5)
    if v_top.ndim == 2:
        t = t[:, None]
    val = (1 - t) * v_foot + t * v_top
    # a sample that fell outside the ortho-image: the other one, then the plain value
    plain = ortho.sample(lat, lon)
    val = np.where(np.isfinite(val), val, np.where(np.isfinite(v_top), v_top, np.where(np.isfinite(v_foot),
                                                                                      v_foot, plain)))
    return val




def _sun_vectors(sun, lat, lon):
    arr = np.asarray(sun, dtype=np.float64)
    if arr.shape == (2,):
        az, el = np.radians(arr)
        e, n, u = _enu(lat, lon)
        return np.cos(el) * (np.sin(az) * e + np.cos(az) * n) + np.sin(el) * u
    return np.broadcast_to(arr / np.linalg.norm(arr), (len(lat), 3))


def surface(dsm, ground):
    return _Surface(dsm, ground)
