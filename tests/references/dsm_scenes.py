"""Deterministic building-DSM scenes and labelled rays (pure NumPy, seeded).

Scenes: 1 m cells on a geodetic grid (dlat, dlon in degrees giving 1 m at
the scene's centre latitude; the longitude cells narrow poleward), blocks
3-150 m tall (flat roofs at the highest base point of their footprint plus
their height), one-cell towers, courtyards (a ring building with an open
middle), overhang-free walls (a height field cannot overhang), on flat
ground or a smooth base terrain (a few long sinusoids, +-15 m around 40 m).
Buildings may touch and overlap (the larger height wins). A border of
``MARGIN`` cells stays bare so that rays aimed at the core do not leave the
DSM while low.

Placements (``PLACES``): mid-latitude (Paris, north-up rows, smooth base),
across the antimeridian (south-up rows, lon_first just west of 180 E), near
the north pole (centre 2.8 km from it) and near the south pole (3.3 km).

Ray kinds (labels): ``pushbroom`` (lines of 64 pixels from a satellite at
500-700 km altitude, 0-30 deg off nadir, pixels 0.7 m apart on the ground),
``nadir`` (straight down the ellipsoid normal from 500-700 km),
``graze_out`` (leaves a roof across its edge, passing 0.5-5 cm above the edge:
must NOT hit that roof), ``graze_in_above`` (enters over an edge 0.5-5 cm
above it: hits the roof just inside), ``graze_in_below`` (meets the wall
0.5-5 cm below the top edge), ``wall`` (aimed at a point on a wall face
from outside), ``between`` (aimed at bare ground cells between buildings),
``horizontal`` (airborne, 1-10 deg elevation, aimed at a wall point so that
the low part of the ray before it lies inside the DSM), ``horizontal_pass``
(the same aimed at a point over the core: they often pass over everything
and leave the DSM low). With ``"bilinear"``
interpolation a roof "edge" is the outermost roof node line (the surface
ramps down over one cell beyond it), so the grazing rays are built on it.

Everything is a pure function of its seed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .geodesy import WGS84_A, WGS84_F, east_north, ecef_to_geodetic, geodetic_to_ecef, radii, up_vector, wrap_lon

MARGIN = 130  # bare border (cells); rays at <= 35 deg incidence cross the 150 m slab within 105 m
PLACES = {
    "paris": dict(lat_c=48.85, lon_c=2.35, north_up=True, base="smooth"),
    "antimeridian": dict(lat_c=-17.7, lon_c=180.0, north_up=False, base="flat"),
    "north_pole": dict(lat_c=89.975, lon_c=37.0, north_up=True, base="smooth"),
    "south_pole": dict(lat_c=-89.97, lon_c=-120.0, north_up=False, base="flat"),
}


@dataclass
class Scene:
    """A DSM and what was built on it (grid coordinates: rows i, columns j)."""

    heights: np.ndarray
    grid: dict  # lat_first, lon_first, dlat, dlon, a, f (kwargs for the references and GeodeticDSM.from_array)
    base: np.ndarray  # the base terrain alone
    buildings: list = field(default_factory=list)  # dicts: kind, i0, i1, j0, j1, top (cells inclusive)
    name: str = ""

    @property
    def shape(self):
        return self.heights.shape


def grid_for(lat_c, lon_c, nrows, ncols, cell_m=1.0, north_up=True, a=WGS84_A, f=WGS84_F):
    """Grid kwargs with ~cell_m metre cells centred on (lat_c, lon_c)."""
    M, N = radii(lat_c, a, f)
    dlat = float(np.degrees(cell_m / M)) * (-1.0 if north_up else 1.0)
    dlon = float(np.degrees(cell_m / (N * np.cos(np.radians(lat_c)))))
    return dict(lat_first=float(lat_c - (nrows - 1) / 2 * dlat),
                lon_first=float(wrap_lon(lon_c - (ncols - 1) / 2 * dlon)), dlat=dlat, dlon=dlon, a=a, f=f)


def grid_to_geodetic(grid, u, v):
    """Grid coordinates (u = row, v = column; centres at integers) -> (lat, lon) in degrees."""
    return grid["lat_first"] + np.asarray(u) * grid["dlat"], wrap_lon(grid["lon_first"] + np.asarray(v) * grid["dlon"])


def building_scene(seed, nrows=600, ncols=600, lat_c=48.85, lon_c=2.35, north_up=True, base="smooth",
                   n_blocks=60, n_courtyards=6, n_towers=80, name=""):
    """A building DSM (see the module docstring); deterministic in ``seed``."""
    rng = np.random.default_rng(seed)
    grid = grid_for(lat_c, lon_c, nrows, ncols, north_up=north_up)
    ii, jj = np.mgrid[0:nrows, 0:ncols].astype(np.float64)
    if base == "smooth":
        b = np.full((nrows, ncols), 40.0)
        for _ in range(4):
            kx, ky = rng.uniform(-1, 1, 2) * 2 * np.pi / rng.uniform(300, 1200)
            b += rng.uniform(2, 5) * np.sin(kx * ii + ky * jj + rng.uniform(0, 2 * np.pi))
    else:
        b = np.zeros((nrows, ncols))
    h = b.copy()
    blds = []
    lo, hi_i, hi_j = 2, nrows - 3, ncols - 3

    def put(kind, i0, i1, j0, j1, height, mask=None):
        i0, i1 = max(i0, lo), min(i1, hi_i)
        j0, j1 = max(j0, lo), min(j1, hi_j)
        if i1 < i0 or j1 < j0:
            return
        top = float(b[i0:i1 + 1, j0:j1 + 1].max() + height)
        sub = h[i0:i1 + 1, j0:j1 + 1]
        m = np.ones(sub.shape, bool) if mask is None else mask[: sub.shape[0], : sub.shape[1]]
        sub[m] = np.maximum(sub[m], top)
        blds.append(dict(kind=kind, i0=i0, i1=i1, j0=j0, j1=j1, top=top))

    core = (MARGIN, nrows - MARGIN, MARGIN, ncols - MARGIN)
    for _ in range(n_blocks):
        hgt = float(np.exp(rng.uniform(np.log(3.0), np.log(150.0))))
        w, d = rng.integers(4, 40, 2)
        i0 = int(rng.integers(core[0] - 40, core[1] + 40 - w))
        j0 = int(rng.integers(core[2] - 40, core[3] + 40 - d))
        put("block", i0, i0 + w - 1, j0, j0 + d - 1, hgt)
    for _ in range(n_courtyards):
        hgt = float(rng.uniform(8, 60))
        w, d = rng.integers(20, 50, 2)
        t = int(rng.integers(3, 8))
        i0 = int(rng.integers(core[0] - 20, core[1] + 20 - w))
        j0 = int(rng.integers(core[2] - 20, core[3] + 20 - d))
        mask = np.ones((w, d), bool)
        mask[t:w - t, t:d - t] = False
        put("courtyard", i0, i0 + w - 1, j0, j0 + d - 1, hgt, mask)
        blds[-1]["inner"] = (i0 + t, i0 + w - 1 - t, j0 + t, j0 + d - 1 - t)
    for _ in range(n_towers):
        hgt = float(rng.uniform(20, 150))
        i0 = int(rng.integers(core[0] - 40, core[1] + 40))
        j0 = int(rng.integers(core[2] - 40, core[3] + 40))
        put("tower", i0, i0, j0, j0, hgt)
    # a building's recorded top may be exceeded by a later neighbour: record the top actually standing
    for bd in blds:
        bd["top_max"] = float(h[bd["i0"]:bd["i1"] + 1, bd["j0"]:bd["j1"] + 1].max())
    return Scene(heights=h, grid=grid, base=b, buildings=blds, name=name)


def place_scene(place, seed, **kw):
    """building_scene at one of PLACES."""
    p = dict(PLACES[place])
    p.update(kw)
    return building_scene(seed, name=place, **p)


# ---------------------------------------------------------------- rays
def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _frame(lat, lon):
    up = up_vector(lat, lon)
    e, n = east_north(lat, lon)
    return up, e, n


def _sat_from(target, d, alt, a=WGS84_A):
    """Point at distance t along unit d from target whose geocentric radius is |target| + alt."""
    td = np.sum(target * d, axis=-1)
    R = np.linalg.norm(target, axis=-1)
    t = -td + np.sqrt(td * td - R * R + (R + alt) ** 2)
    return target + t[:, None] * d


def _core_uv(scene, rng, n):
    nr, nc = scene.shape
    u = rng.uniform(MARGIN, nr - 1 - MARGIN, n)
    v = rng.uniform(MARGIN, nc - 1 - MARGIN, n)
    return u, v


def _surface_h(scene, u, v):
    i = np.clip(np.rint(u).astype(int), 0, scene.shape[0] - 1)
    j = np.clip(np.rint(v).astype(int), 0, scene.shape[1] - 1)
    return scene.heights[i, j]


def pushbroom_rays(scene, n, rng, pix=64, gsd=0.7):
    """Lines of ``pix`` rays from one satellite position each (0-30 deg off nadir, 500-700 km)."""
    g = scene.grid
    nl = max(1, -(-n // pix))
    s_all, l_all = [], []
    for _ in range(nl):
        u, v = _core_uv(scene, rng, 1)
        lat, lon = grid_to_geodetic(g, u, v)
        up, e, nn = _frame(lat, lon)
        alt = rng.uniform(500e3, 700e3)
        off = np.radians(rng.uniform(0.0, 30.0))
        R = 6371e3
        zen = np.arcsin(min(1.0, (R + alt) / R * np.sin(off)))  # incidence at the ground for that off-nadir angle
        fly = rng.uniform(0, 2 * np.pi)
        along = np.cos(fly) * nn + np.sin(fly) * e
        cross = np.cos(fly + np.pi / 2) * nn + np.sin(fly + np.pi / 2) * e
        side = rng.choice([-1.0, 1.0])
        d = np.cos(zen) * up + np.sin(zen) * side * cross
        T0 = geodetic_to_ecef(lat, lon, 0.0)
        S = _sat_from(T0, _unit(d), alt)
        k = (np.arange(pix) - (pix - 1) / 2) * gsd
        T = T0 + k[:, None] * cross + rng.uniform(-0.5, 0.5) * gsd * along
        s_all.append(np.repeat(S, pix, axis=0))
        l_all.append(_unit(T - S))
    return np.concatenate(s_all)[:n], np.concatenate(l_all)[:n]


def nadir_rays(scene, n, rng):
    u, v = _core_uv(scene, rng, n)
    lat, lon = grid_to_geodetic(scene.grid, u, v)
    alt = rng.uniform(500e3, 700e3, n)
    return geodetic_to_ecef(lat, lon, alt), -up_vector(lat, lon)


def _edges(scene, rng, n, interpolation):
    """Random points on roof edges: (u, v, top, outward unit vector in (u, v) grid axes)."""
    bl = [b for b in scene.buildings if b["top"] >= b["top_max"] - 1e-9]
    out = []
    off = 0.5 if interpolation == "nearest" else 0.0
    def along(c0, c1):
        lo_, hi_ = c0 + 0.2 - off, c1 - 0.2 + off
        return float(rng.uniform(lo_, hi_)) if hi_ > lo_ else 0.5 * (c0 + c1)

    for _ in range(n):
        b = bl[rng.integers(len(bl))]
        side = rng.integers(4)
        if side == 0:  # low-u edge
            u, v, o = b["i0"] - off, along(b["j0"], b["j1"]), (-1.0, 0.0)
        elif side == 1:
            u, v, o = b["i1"] + off, along(b["j0"], b["j1"]), (1.0, 0.0)
        elif side == 2:
            u, v, o = along(b["i0"], b["i1"]), b["j0"] - off, (0.0, -1.0)
        else:
            u, v, o = along(b["i0"], b["i1"]), b["j1"] + off, (0.0, 1.0)
        out.append((u, v, b["top"], o, b))
    return out


def _uv_dir_to_enu(scene, lat, du, dv):
    """A grid-axis direction (du rows, dv columns) as (north, east) components, normalised."""
    g = scene.grid
    north = du * np.sign(g["dlat"])
    east = dv * 1.0
    nrm = np.hypot(north, east)
    return north / nrm, east / nrm


def graze_rays(scene, n, rng, kind, interpolation="nearest"):
    """Rays grazing roof edges; kind: graze_out, graze_in_above, graze_in_below."""
    g = scene.grid
    S, L = [], []
    for (u, v, top, o, b) in _edges(scene, rng, n, interpolation):
        lat, lon = grid_to_geodetic(g, u, v)
        up, e, nn = _frame(lat, lon)
        no, eo = _uv_dir_to_enu(scene, lat, *o)
        outward = no * nn + eo * e
        along = -eo * nn + no * e
        c = rng.uniform(0.005, 0.05)
        dh = c if kind != "graze_in_below" else -c
        E = geodetic_to_ecef(lat, lon, top + dh)
        turn = np.radians(rng.uniform(-50, 50))
        hor = np.cos(turn) * outward + np.sin(turn) * along
        if kind != "graze_out":
            hor = -hor  # coming from outside, heading into the building
        air = rng.random() < 0.3
        el = np.radians(rng.uniform(15, 55) if air else rng.uniform(56, 89))
        d = _unit(np.cos(el) * hor - np.sin(el) * up)  # direction of travel (down)
        if air:
            Sx = E - rng.uniform(1500, 4000) * d
        else:
            Sx = _sat_from(E[None, :], -d[None, :], rng.uniform(500e3, 700e3))[0]
        S.append(Sx)
        L.append(_unit(E - Sx))
    return np.array(S), np.array(L)


def wall_rays(scene, n, rng):
    """Rays aimed at a point on a wall face (nearest-surface walls), from outside."""
    g = scene.grid
    S, L = [], []
    for (u, v, top, o, b) in _edges(scene, rng, n, "nearest"):
        lat, lon = grid_to_geodetic(g, u, v)
        up, e, nn = _frame(lat, lon)
        no, eo = _uv_dir_to_enu(scene, lat, *o)
        inward = -(no * nn + eo * e)
        along = -eo * nn + no * e
        ground = float(scene.base[int(np.clip(np.rint(u), 0, scene.shape[0] - 1)),
                                   int(np.clip(np.rint(v), 0, scene.shape[1] - 1))])
        hz = ground + rng.uniform(0.1, 0.9) * (top - ground)
        E = geodetic_to_ecef(lat, lon, hz)
        turn = np.radians(rng.uniform(-60, 60))
        hor = np.cos(turn) * inward + np.sin(turn) * along
        el = np.radians(rng.uniform(20, 80))
        d = _unit(np.cos(el) * hor - np.sin(el) * up)
        Sx = E - rng.uniform(1000, 3000) * d if rng.random() < 0.5 else \
            _sat_from(E[None, :], -d[None, :], rng.uniform(500e3, 700e3))[0]
        S.append(Sx)
        L.append(_unit(E - Sx))
    return np.array(S), np.array(L)


def between_rays(scene, n, rng):
    """Steep rays aimed at bare ground cells (streets and courtyards)."""
    g = scene.grid
    nr, nc = scene.shape
    bare = np.argwhere(scene.heights[MARGIN:nr - MARGIN, MARGIN:nc - MARGIN]
                       <= scene.base[MARGIN:nr - MARGIN, MARGIN:nc - MARGIN] + 1e-9) + MARGIN
    pick = bare[rng.integers(len(bare), size=n)]
    u = pick[:, 0] + rng.uniform(-0.45, 0.45, n)
    v = pick[:, 1] + rng.uniform(-0.45, 0.45, n)
    lat, lon = grid_to_geodetic(g, u, v)
    up, e, nn = _frame(lat, lon)
    T = geodetic_to_ecef(lat, lon, scene.base[pick[:, 0], pick[:, 1]])
    zen = np.radians(rng.uniform(0, 30, n))
    az = rng.uniform(0, 2 * np.pi, n)
    d = np.cos(zen)[:, None] * up + np.sin(zen)[:, None] * (np.cos(az)[:, None] * nn + np.sin(az)[:, None] * e)
    Sx = _sat_from(T, _unit(d), rng.uniform(500e3, 700e3, n))
    return Sx, _unit(T - Sx)


def horizontal_rays(scene, n, rng, aim="wall"):
    """Airborne rays at 1-10 deg elevation whose low part before the aim point lies inside the DSM.

    aim="wall": aimed at a wall face point (the ray comes from outside the
    building), at a height chosen so that the ray is above H_max until it is
    inside the DSM (if no such height exists on the wall, another wall is
    drawn). aim="pass": aimed at a point over the core at the lowest such
    height; these rays often pass over everything and leave the DSM low.
    """
    g = scene.grid
    nr, nc = scene.shape
    hmax = float(scene.heights.max())
    S, L = [], []
    tries = 0
    while len(S) < n:
        tries += 1
        if tries > 200 * n:
            raise RuntimeError("horizontal_rays: could not place rays on this scene")
        el = np.radians(rng.uniform(1.0, 10.0))
        if aim == "wall":
            (u, v, top, o, b), = _edges(scene, rng, 1, "nearest")
            lat, lon = grid_to_geodetic(g, u, v)
            up, e, nn = _frame(lat, lon)
            no, eo = _uv_dir_to_enu(scene, lat, *o)
            turn = np.radians(rng.uniform(-60, 60))
            hor = -(np.cos(turn) * (no * nn + eo * e) + np.sin(turn) * (-eo * nn + no * e))
            # back along -hor in grid axes
            bn = -(np.cos(turn) * no + np.sin(turn) * (-eo))
            be = -(np.cos(turn) * eo + np.sin(turn) * no)
        else:
            u, v = (float(x[0]) for x in _core_uv(scene, rng, 1))
            lat, lon = grid_to_geodetic(g, u, v)
            up, e, nn = _frame(lat, lon)
            az = rng.uniform(0, 2 * np.pi)
            hor = np.cos(az) * nn + np.sin(az) * e
            bn, be = -np.cos(az), -np.sin(az)
        du, dv = bn * np.sign(g["dlat"]), be
        t = []
        for x, dx, nmax in ((u, du, nr - 1), (v, dv, nc - 1)):
            if dx > 1e-12:
                t.append((nmax - 5 - x) / dx)
            elif dx < -1e-12:
                t.append((x - 5) / -dx)
        avail = max(1.0, min(t)) * 0.95  # metres (1 m cells)
        ground = float(scene.base[int(np.clip(np.rint(u), 0, nr - 1)), int(np.clip(np.rint(v), 0, nc - 1))])
        zmin = hmax - avail * np.tan(el)
        if aim == "wall":
            if zmin > top - 0.5:
                continue
            hT = rng.uniform(max(ground + 0.1 * (top - ground), zmin), top - 0.1)
        else:
            hT = max(float(_surface_h(scene, np.array([u]), np.array([v]))[0]), zmin)
        T = geodetic_to_ecef(lat, lon, hT)
        d = _unit(np.cos(el) * hor - np.sin(el) * up)
        Sx = T - (hmax + 100.0 - hT) / np.sin(el) * d
        S.append(Sx)
        L.append(d)
    return np.array(S), np.array(L)


MIX = (("pushbroom", 0.40), ("nadir", 0.05), ("graze_out", 0.10), ("graze_in_above", 0.05),
       ("graze_in_below", 0.05), ("wall", 0.14), ("between", 0.14), ("horizontal", 0.05),
       ("horizontal_pass", 0.02))


def scene_rays(scene, n, seed, interpolation="nearest", mix=MIX):
    """n labelled rays on a scene: (s (n, 3), l (n, 3), labels (n,) str)."""
    rng = np.random.default_rng(seed)
    counts = [int(round(n * w)) for _, w in mix]
    counts[0] += n - sum(counts)
    S, L, lab = [], [], []
    for (kind, _), k in zip(mix, counts):
        if k <= 0:
            continue
        if kind == "pushbroom":
            s, l = pushbroom_rays(scene, k, rng)
        elif kind == "nadir":
            s, l = nadir_rays(scene, k, rng)
        elif kind.startswith("graze"):
            s, l = graze_rays(scene, k, rng, kind, interpolation)
        elif kind == "wall":
            s, l = wall_rays(scene, k, rng)
        elif kind == "between":
            s, l = between_rays(scene, k, rng)
        elif kind == "horizontal":
            s, l = horizontal_rays(scene, k, rng, "wall")
        else:
            s, l = horizontal_rays(scene, k, rng, "pass")
        S.append(s)
        L.append(l)
        lab += [f"{scene.name}:{kind}" if scene.name else kind] * len(s)
    return np.concatenate(S), np.concatenate(L), np.array(lab)


def make_case(place, n_rays, seed, interpolation="nearest", **scene_kw):
    """(heights, grid kwargs, s, l, labels) for one placement; deterministic in seed."""
    sc = place_scene(place, seed, **scene_kw)
    s, l, lab = scene_rays(sc, n_rays, seed + 1000, interpolation)
    return sc.heights, dict(sc.grid), s, l, lab


def suite(n_rays, seed=0, interpolation="nearest", places=tuple(PLACES)):
    """The comparison suite: n_rays split over the placements; list of (place, heights, grid, s, l, labels)."""
    out = []
    k = len(places)
    for m, place in enumerate(places):
        nr = n_rays // k + (1 if m < n_rays % k else 0)
        h, g, s, l, lab = make_case(place, nr, seed + 17 * m, interpolation)
        out.append((place, h, g, s, l, lab))
    return out


def min_clearance_at_edge(scene_grid, s, l, u, v, top, a=WGS84_A, f=WGS84_F):
    """Height of the ray above ``top`` where it passes over the edge point (u, v) (checks graze rays).

    The ray's point nearest to the vertical line through the edge point (its
    horizontal position there), minus ``top``.
    """
    lat, lon = grid_to_geodetic(scene_grid, u, v)
    E = geodetic_to_ecef(lat, lon, top)
    up = up_vector(lat, lon)
    w = s - E
    wh = w - np.sum(w * up, axis=-1)[..., None] * up
    lh = l - np.sum(l * up, axis=-1)[..., None] * up
    r = -np.sum(wh * lh, axis=-1) / np.sum(lh * lh, axis=-1)
    _, _, h = ecef_to_geodetic(s + r[..., None] * l, a, f)
    return h - top
