"""Fuzz cases of the geodetic system (issues 11-12): ``GeodeticDSM.from_array``,
``intersect`` on a DSM and the geodetic conversions.

The planetary cases (ops.py, bulk.py, strategies.py) do not reach this system,
so it has its own family of bulk operations (``bulk.MIX_GEO``; ``./dev fuzz
--bulk --geo``; ``tests/test_fuzz.py::test_bulk_fuzz_geo`` in CI). The module
both draws the cases (with bulk.R, hypothesis-free, so the worker can import it)
and performs them; ops.OPS dispatches to the ``op_*`` functions here.

Properties of a normal result, checked against the tests' own references
(``references/geodesy.py``, the exhaustive reference's ``Surface`` lookup:
neither shares code with the package):

* every status is one of the documented DSM statuses, every ray has one;
* a ``HIT`` lies on its ray (``p = s + distance l``), its latitude, longitude
  and height are those of ``p``, and it lies on the surface: its height is
  within the surface heights found within 2e-6 m of it horizontally, widened
  by 2e-6 m (the contract's 1e-6 along the ray, and rounding);
* ``method="exact"`` is never late: no point sampled on the ray before its
  answer (hit, no-data or left-the-DSM point, or the whole ray for a miss)
  lies below the surface by more than 1e-5 m over a cell with data;
* ``method="exact"`` gives bit-identical answers on one and on two threads;
* the result converts to a table.

Bad arguments must raise a ValueError/TypeError whose message names the
spoiled argument (harness.judge with the case's ``names``); valid DSMs must be
accepted (``must_succeed``).
"""

from __future__ import annotations

import math

import numpy as np

from .bulk import DBL_MAX, EXTREME, R, bad_vector, spec_cached

WGS84 = (6378137.0, 1.0 / 298.257223563)
#: bodies in metres: the Earth, Mars (areodetic), the Moon (a sphere), a 13 km oblate small body
BODIES = [WGS84, WGS84, (3396190.0, 1.0 / 169.894), (1737400.0, 0.0), (13000.0, 0.3)]
DSM_ARGS = ["heights", "lat_first", "lon_first", "dlat", "dlon", "a", "f", "nodata", "geoid", "interpolation",
            "hmax"]
INTERSECT_DSM_NAMES = ["s", "l", "method", "threads", "outside", "dsm"]

TOL_ON_RAY = 1e-9          # |p - (s + distance l)| relative to max(|s|, a)
TOL_SURFACE = 2e-6         # m: the contract's 1e-6 along the ray, twice, with rounding
TOL_LATE = 1e-5            # m: how deep below the surface a sample before exact's answer may lie
STATUSES = {0, 3, 9, 10, 11, 12, 13, 14}
EXACT_STATUSES = {0, 9, 10, 11}


# ---------------------------------------------------------------------------- DSMs
def _cell_deg(cell_m: float, a: float) -> float:
    return math.degrees(cell_m / a)


def dsm_spec(r: R, valid_only: bool = False) -> dict:
    """A DSM description: grid, body, terrain kind, and (unless valid_only, 30 %) one spoiled argument."""
    a, f = r.pick(BODIES)
    interp = r.pick(["bilinear", "nearest"])
    nmin = 2 if interp == "bilinear" else 1
    nrows, ncols = r.int(nmin, 24), r.int(nmin, 24)
    cell = r.pick([0.5, 1.0, 1.0, 5.0, 30.0, 1000.0, 2e4])
    if a < 1e5:
        cell = min(cell, 30.0)
    dlat = _cell_deg(cell * r.pick([1.0, 1.0, 0.5, 2.0]), a) * r.pick([-1.0, 1.0])
    dlon = _cell_deg(cell, a)
    where = r.pick(["any", "any", "any", "pole", "antimeridian", "equator"])
    span = abs(dlat) * (nrows - 1)
    if where == "pole":
        top = 90.0 - r.pick([0.0, 1e-9, abs(dlat) * 0.5, abs(dlat) * 3])
        lat_lo = top - span
        sign = r.pick([-1.0, 1.0])
    else:
        lat_lo = r.float(-89.0, 89.0 - span) if where == "any" else -span / 2
        sign = 1.0
    lat_first = lat_lo if dlat > 0 else lat_lo + span
    lat_first *= sign
    if sign < 0:
        dlat = -dlat
    if where == "antimeridian":
        lon_first = 180.0 - dlon * r.float(0.2, ncols - 0.2)
    else:
        lon_first = r.float(-180.0, 180.0)
    if r.chance(0.05):
        lon_first += r.pick([360.0, -360.0, 720.0])
    spec = {"shape": (nrows, ncols), "a": a, "f": f, "interpolation": interp,
            "lat_first": lat_first, "lon_first": lon_first, "dlat": dlat, "dlon": dlon,
            "kind": r.pick(["flat", "rough", "blocks", "blocks", "tower", "holes"]),
            "scale": r.pick([1.0, 30.0, 150.0, 3000.0]), "base": r.pick([0.0, -50.0, 120.0, 4000.0]),
            "seed": r.int(0, 2**31)}
    if r.chance(0.1):
        spec["nodata"] = -9999.0
    if r.chance(0.1):
        spec["geoid"] = r.pick(["scalar", "array"])
    if r.chance(0.1):
        spec["hmax"] = r.pick([0.0, 1.0, 500.0])          # added to the grid's largest height
    if not valid_only and r.chance(0.3):
        spoil(r, spec)
    return spec


#: one spoiled argument: (argument, value); the value replaces the argument as given to from_array
SPOILS = {
    "heights": ["3d", "1d", "empty", "inf", "allnan", "complex", "object", "strings", "toosmall", "none"],
    "lat_first": [math.nan, math.inf, 95.0, -90.5, "10", None, 1e300],
    "lon_first": [math.nan, -math.inf, "east", None],
    "dlat": [0.0, -0.0, math.nan, math.inf, 50.0, None, "0.1"],
    "dlon": [0.0, -1e-5, math.nan, math.inf, 400.0, 5e-324, None],
    "a": [0.0, -1.0, math.nan, math.inf, None, "6378137", 5e-324],
    "f": [1.0, -0.1, math.nan, 2.0, math.inf, None],
    "nodata": ["x", [1, 2], math.inf, complex(1, 1)],
    "geoid": ["wrongshape", "nan", "string", "3d"],
    "interpolation": ["Bilinear", "cubic", "", None, 1],
    "hmax": [-1e9, math.nan, "high", math.inf],
}


def spoil(r: R, spec: dict) -> None:
    arg = r.pick(sorted(SPOILS))
    spec["spoil"] = (arg, r.pick(SPOILS[arg]))


def dsm_heights(spec: dict) -> np.ndarray:
    nrows, ncols = spec["shape"]
    g = np.random.default_rng(spec["seed"])
    kind, scale, base = spec["kind"], spec["scale"], spec["base"]
    h = np.full((nrows, ncols), base)
    if kind in ("rough", "holes"):
        h = h + g.normal(0.0, 0.2 * scale, (nrows, ncols))
    if kind in ("blocks", "holes"):
        for _ in range(g.integers(1, 4)):
            i0, j0 = g.integers(0, nrows), g.integers(0, ncols)
            i1, j1 = i0 + g.integers(1, 6), j0 + g.integers(1, 6)
            h[i0:i1, j0:j1] = base + scale * g.uniform(0.1, 1.0)
    if kind == "tower":
        h[g.integers(0, nrows), g.integers(0, ncols)] = base + scale
    if kind == "holes":
        m = g.random((nrows, ncols)) < 0.2
        m[0, 0] = False
        h[m] = np.nan
    if "nodata" in spec and h.size > 1:
        i, j = g.integers(0, nrows), g.integers(0, ncols)
        if (i, j) != (0, 0):                          # cell (0, 0) keeps data (the 1 x 1 spoil's DSM)
            h[i, j] = spec["nodata"]
    return h


def dsm_args(spec: dict) -> tuple[tuple, dict]:
    """The from_array arguments a spec describes (with its spoiled one)."""
    h = dsm_heights(spec)
    kw = {"a": spec["a"], "f": spec["f"], "interpolation": spec["interpolation"]}
    if "nodata" in spec:
        kw["nodata"] = spec["nodata"]
    if "geoid" in spec:
        shape = (1, 1) if spec.get("spoil") == ("heights", "toosmall") else h.shape
        kw["geoid"] = 17.5 if spec["geoid"] == "scalar" else np.linspace(-30, 60, h.size)[:shape[0] * shape[1]].reshape(shape)
    if "hmax" in spec:
        kw["hmax"] = float(np.nanmax(np.where(h == spec.get("nodata", np.nan), np.nan, h))) + spec["hmax"] + (
            float(np.max(kw["geoid"])) if "geoid" in kw else 0.0)
    args = {"heights": h, "lat_first": spec["lat_first"], "lon_first": spec["lon_first"], "dlat": spec["dlat"],
            "dlon": spec["dlon"]}
    if "spoil" in spec:
        arg, v = spec["spoil"]
        if arg == "heights":
            v = {"3d": h[..., None], "1d": h.ravel(), "empty": np.zeros((0, 0)), "inf": _with(h, math.inf),
                 "allnan": np.full_like(h, np.nan), "complex": h.astype(complex), "object": h.astype(object),
                 "strings": h.astype(str), "toosmall": h[:1, :1], "none": None}[v]
        elif arg == "geoid":
            v = {"wrongshape": np.zeros((h.shape[0] + 1, h.shape[1])), "nan": _with(np.zeros(h.shape), math.nan),
                 "string": "no such geoid file.tif", "3d": np.zeros(h.shape + (2,))}[v]
        elif arg == "dlon" and v == 400.0:
            pass
        (args if arg in args else kw)[arg] = v
    return (args["heights"], args["lat_first"], args["lon_first"], args["dlat"], args["dlon"]), kw


def _with(h, v):
    h = np.array(h, dtype=np.float64)
    h.flat[h.size // 2] = v
    return h


def spoiled_is_valid(spec: dict) -> bool:
    """Spoils that are still valid input for some grids (the DSM must then be accepted)."""
    if "spoil" not in spec:
        return True
    arg, v = spec["spoil"]
    if arg == "heights" and v == "toosmall":
        return spec["interpolation"] == "nearest"
    if arg == "heights" and v == "object":
        return True                                   # an object array of floats converts
    if arg == "lat_first" and isinstance(v, float) and math.isfinite(v):
        nrows = spec["shape"][0]
        return -90 <= v <= 90 and -90 <= v + (nrows - 1) * spec["dlat"] <= 90
    if arg == "dlat" and v == 50.0:
        lo = spec["lat_first"] + (spec["shape"][0] - 1) * 50.0
        return -90 <= lo <= 90
    if arg == "dlon" and v == 5e-324:
        return False                                  # below the 1e-8 degree floor (a review)
    if arg == "a" and v == 5e-324:
        return False
    return False


#: the worker reuses valid DSMs by spec (a GeodeticDSM is immutable)
DSM_CACHE: dict = {}


def make_dsm(spec: dict):
    import planet_intersect as pi

    def build():
        args, kw = dsm_args(spec)
        return pi.GeodeticDSM.from_array(*args, **kw)

    return spec_cached(DSM_CACHE, spec, build)


_POOL: dict = {}


def valid_dsm_pool(seed: int, n: int = 40) -> list:
    if seed not in _POOL:
        r = R(np.random.default_rng([seed, 2**31 + 7]))
        _POOL[seed] = [dsm_spec(r, valid_only=True) for _ in range(n)]
    return _POOL[seed]


# ---------------------------------------------------------------------------- cases
def dsm_from_array_case(r: R, seed: int) -> dict:
    spec = dsm_spec(r)
    names = [spec["spoil"][0]] if "spoil" in spec else DSM_ARGS
    if "spoil" in spec and spec["spoil"][0] in ("lat_first", "dlat"):
        names = ["lat_first", "dlat"]                 # the centres' latitudes come from both
    if "spoil" in spec and spec["spoil"][0] == "hmax":
        names = ["hmax"]
    case = {"op": "dsm_from_array", "dsm": spec, "names": names, "must_succeed": spoiled_is_valid(spec)}
    if spec.get("spoil", (None, None))[1] == "string":
        case["files"] = True                          # a geoid path: an OSError naming the file is clear
        case["names"] = ["geoid", "no such geoid file.tif"]
    return case


def _enu(lat, lon):
    from references.geodesy import east_north, up_vector

    east, north = east_north(lat, lon)
    return np.asarray(east, dtype=float), np.asarray(north, dtype=float), np.asarray(up_vector(lat, lon), dtype=float)


def _ecef(lat, lon, h, a, f):
    from references.geodesy import geodetic_to_ecef

    return np.asarray(geodetic_to_ecef(lat, lon, h, a, f), dtype=np.float64)


def dsm_rays(r: R, spec: dict):
    """Rays at the DSM: from orbit or the air at any off-nadir angle, grazing, nadir, away, fans."""
    a, f = spec["a"], spec["f"]
    nrows, ncols = spec["shape"]
    n = r.int(1, 8)
    kind = r.pick(["orbit", "orbit", "air", "graze", "nadir", "away", "fan", "fan", "far", "deep"])
    g = r.g
    u = g.uniform(-1.0, nrows, n)                      # aim a little beyond the grid too
    v = g.uniform(-1.0, ncols, n)
    lat = np.clip(spec["lat_first"] + u * spec["dlat"], -90.0, 90.0)
    lon = spec["lon_first"] + v * spec["dlon"]
    hmid = spec["base"] + spec["scale"] * g.uniform(-0.2, 1.2, n)
    s = np.empty((n, 3))
    l = np.empty((n, 3))
    dist = {"orbit": r.pick([5e5, 7e5, 3.6e7]), "air": r.pick([300.0, 3000.0]), "graze": 2000.0,
            "nadir": 1e5, "away": 1e4, "fan": r.pick([6e5, 2000.0]), "far": 1e7,
            "deep": r.pick([1e10, 1e12, 1e13])}[kind]         # re-anchored near the body (a review)
    if a < 1e5 and kind != "deep":
        dist = min(dist, 5e4)
    for k in range(n):
        east, north, up = _enu(lat[k], lon[k])
        target = _ecef(lat[k], lon[k], hmid[k], a, f)
        if kind == "graze":
            el = r.pick([1e-6, 1e-4, 1e-2, 0.2])
        elif kind == "nadir":
            el = math.pi / 2
        else:
            el = math.radians(r.float(10.0, 90.0))
        az = r.float(0.0, 2 * math.pi)
        d = math.cos(el) * (math.sin(az) * east + math.cos(az) * north) + math.sin(el) * up
        s[k] = target + dist * d
        l[k] = -d
        if kind == "away":
            l[k] = d
    if kind == "fan":                                 # one focal point, bit for bit: the line sweep
        s[:] = s[0]
        l = np.array([_ecef(lat[k], lon[k], hmid[k], a, f) for k in range(n)]) - s
        order = np.argsort(v)
        l = l[order]
    if kind == "far":
        l = l + g.normal(0.0, 0.05, l.shape)          # mostly misses
    l = l * r.pick([1.0, 1.0, 1e-3, 1e3, 1e-150, 1e150])
    return s, l, kind


def dsm_intersect_case(r: R, seed: int) -> dict:
    spec = dict(r.pick(valid_dsm_pool(seed)))
    s, l, kind = dsm_rays(r, spec)
    kw = {}
    if r.chance(0.8):
        kw["method"] = r.pick(["following", "exact", "exact", "iterative"])
    if r.chance(0.3):
        kw["threads"] = r.pick([None, 0, 1, 2])
    if r.chance(0.2):
        kw["outside"] = r.pick(["none", "ellipsoid"])
    case = {"op": "dsm_intersect", "dsm": spec, "s": s, "l": l, "kwargs": kw, "kind": kind,
            "names": INTERSECT_DSM_NAMES, "per_ray": True}
    which = r.int(0, 15)
    if which == 0:
        case["s"] = bad_vector(r, len(s))
        case["names"] = ["s"]
    elif which == 1:
        case["l"] = bad_vector(r, len(l))
        case["names"] = ["l", "s"]                    # a grazing ray's focal point may be inside a building
    elif which == 2:
        bad = r.pick(["method", "threads", "outside"])
        kw[bad] = r.pick({"method": ["Exact", "stepping", "", None, 1],
                          "threads": [-1, 1.5, "2", True, 2**31],
                          "outside": ["Ellipsoid", None, 0, "sphere"]}[bad])
        case["names"] = [bad, "s"]                    # a grazing ray's focal point may be inside a building
    elif which == 3:                                  # a focal point below the surface
        case["s"] = np.array(s, copy=True)
        case["s"][0] = case["s"][0] / np.linalg.norm(case["s"][0]) * spec["a"] * (1 - spec["f"]) * 0.5
        case["names"] = ["s"]
    elif which == 4:
        case["s"] = s[0]                              # one focal point for every ray
    elif which == 5:
        case["dsm_is"] = r.pick(["array", "DEM", "None"])
        case["names"] = ["dem"]                       # pi.intersect's first argument
    return case


def geodetic_case(r: R, seed: int) -> dict:
    a, f = r.pick(BODIES)
    n = r.int(1, 6)
    g = r.g
    case = {"op": "geodetic", "a": a, "f": f, "names": ["p", "a", "f", "method", "lat", "lon", "h"]}
    pick = r.int(0, 9)
    scale = a * 10.0 ** g.uniform(-3, 3, n)
    p = g.standard_normal((n, 3))
    p = p / np.linalg.norm(p, axis=1)[:, None] * scale[:, None]
    if pick == 0:
        p[0] = [0.0, 0.0, r.pick([0.0, a, -a * (1 - f), 1e-300])]          # centre and poles
    elif pick == 1:
        p[0, r.int(0, 2)] = r.pick(EXTREME)
        case["names"] = ["p"]
    elif pick == 2:
        case["a"] = r.pick([0.0, -1.0, math.nan, math.inf, "a"])
        case["names"] = ["a"]
    elif pick == 3:
        case["f"] = r.pick([1.0, -0.5, math.nan, 3.0])
        case["names"] = ["f"]
    case["p"] = p
    case["method"] = r.pick(["exact", "exact", "bowring", "printed"]) if pick != 4 else r.pick(["Exact", "", None])
    if pick == 4:
        case["names"] = ["method"]
    case["h_of"] = g.uniform(-0.01, 2.0, n) * a if pick != 5 else np.array([r.pick(EXTREME)] * n)
    return case


# ---------------------------------------------------------------------------- operations
def _ops():
    from . import ops

    return ops


def op_dsm_from_array(case, tmp):
    import planet_intersect as pi

    spec = case["dsm"]
    args, kw = dsm_args(spec)
    dsm = pi.GeodeticDSM.from_array(*args, **kw)
    fail = _ops().fail
    h = np.asarray(dsm.heights)
    if h.flags.writeable:
        fail("GeodeticDSM.heights is writeable: the DSM could be changed behind its pyramid")
    data = np.isfinite(h)
    if not (dsm.hmin <= dsm.hmax and dsm.hmax >= float(np.max(h[data]))):
        fail(f"hmin {dsm.hmin} / hmax {dsm.hmax} do not bound the heights {np.min(h[data])}..{np.max(h[data])}")
    if "spoil" not in spec:
        # the surface at the pixel centres is the grid's value (or NaN for no data)
        nrows, ncols = h.shape
        i = np.arange(nrows)[:, None].repeat(ncols, 1).ravel()
        j = np.arange(ncols)[None, :].repeat(nrows, 0).ravel()
        lat = dsm.lat_first + i * dsm.dlat
        lon = dsm.lon_first + j * dsm.dlon
        got = np.asarray(dsm.height(lat, lon)).ravel()
        want = h.ravel()
        if dsm.interpolation == "bilinear":
            # a cell with a no-data corner is no data (DESIGN 8): only centres whose
            # eight neighbours have data are the grid's value
            pad = np.pad(np.isfinite(h), 1, constant_values=True)
            full = np.ones_like(data)
            for di in (0, 1, 2):
                for dj in (0, 1, 2):
                    full &= pad[di:di + nrows, dj:dj + ncols]
            step = np.nanmax(np.abs(np.diff(h, axis=0)), initial=0.0) + np.nanmax(np.abs(np.diff(h, axis=1)),
                                                                                initial=0.0)
        else:
            full, step = data, 0.0
        # the centres' coordinates are rounded in degrees and in radians: a grid
        # coordinate off by ~(|lat| + |lon| + 360) eps / spacing moves a bilinear height
        cells = 8 * 2.2e-16 * (450.0 + abs(dsm.lon_first)) / min(abs(dsm.dlat), dsm.dlon)
        tol = 1e-9 * (1 + np.abs(want)) + step * cells
        got, want = got[full.ravel()], want[full.ravel()]
        i, j = i[full.ravel()], j[full.ravel()]
        bad = ~((got == want) | (np.abs(got - want) <= tol[full.ravel()]))
        if bad.any():
            k = int(np.argmax(bad))
            fail(f"dsm.height at pixel centre ({i[k]}, {j[k]}) = {got[k]}, the grid holds {want[k]}")
    return {"calls": 1}


def _reference_surface(dsm):
    from references.dsm_exhaustive import Surface

    return Surface(np.asarray(dsm.heights), dsm.lat_first, dsm.lon_first, dsm.dlat, dsm.dlon, dsm.a, dsm.f,
                   dsm.interpolation, None)


def _surface_at(srf, p, a, f):
    """Reference (h, H, inside, has data) at ECR points p (N, 3)."""
    from references.geodesy import ecef_to_geodetic_rad

    sphi, cphi, lon, h = ecef_to_geodetic_rad(p[:, 0], p[:, 1], p[:, 2], a, f)
    u, v = srf.uv(sphi, cphi, lon)
    inside = srf.inside(u, v)
    H = np.full(len(p), np.nan)
    ok = np.zeros(len(p), dtype=bool)
    if inside.any():
        Hi, oki = srf.height(u[inside], v[inside])
        H[inside], ok[inside] = Hi, oki
    return h, H, inside, ok, u, v


def _surface_range(srf, u, v, du, dv):
    """Smallest and largest reference surface height within (du, dv) cells of (u, v).

    Sampled at most half a cell apart (a window over a cell wide sampled at its ends and centre
    only skipped the cells between: seed 7420 flagged a following hit beside a 3989 m column
    at 1.7 um wide cells by the pole, whose wall it had hit, as below a surface of 4000-4007 m)."""
    lo, hi = np.inf, -np.inf

    def offsets(d, n):
        k = int(min(max(2, math.ceil(4.0 * d)), 4 * n + 4))     # (a window wider than the grid: every cell)
        return np.unique(np.concatenate([np.linspace(-d, d, k + 1), [0.0]]))

    for eu in offsets(du, srf.nrows):
        for ev in offsets(dv, srf.ncols):
            uu, vv = np.array([u + eu]), np.array([v + ev])
            if not srf.inside(uu, vv).all():
                # at the grid's edge: a ray that comes in low from outside (and was
                # still allowed to hit, shin-park-notes 12) meets the edge cell's side
                lo = -np.inf
                continue
            H, ok = srf.height(uu, vv)
            if ok.all() and np.isfinite(H).all():
                lo, hi = min(lo, float(H[0])), max(hi, float(H[0]))
    return lo, hi


def check_dsm_result(dsm, s, l, res, method: str) -> None:
    fail = _ops().fail
    n = len(s)
    st = np.asarray(res.status)
    if st.shape != (n,):
        fail(f"{len(st)} statuses for {n} rays")
    odd = sorted(set(st.tolist()) - (EXACT_STATUSES if method == "exact" else STATUSES))
    if odd:
        fail(f"method={method!r}: status {odd} is not one it may return")
    a, f = dsm.a, dsm.f
    srf = _reference_surface(dsm)
    lu = l / np.max(np.abs(l), axis=1)[:, None]              # no overflow for |l| ~ 1e300
    lu = lu / np.linalg.norm(lu, axis=1)[:, None]
    cell_m = [abs(math.radians(dsm.dlat)) * a, abs(math.radians(dsm.dlon)) * a]
    for k in np.flatnonzero(st == 0):
        p = np.asarray(res.p[k])
        if not np.isfinite(p).all() or not math.isfinite(res.distance[k]):
            fail(f"ray {k}: HIT with p = {p}, distance {res.distance[k]}")
        scale = max(float(np.linalg.norm(s[k])), a)
        off = float(np.linalg.norm(p - (s[k] + res.distance[k] * lu[k])))
        if off > TOL_ON_RAY * scale + 1e-6:
            fail(f"ray {k}: the hit is {off:.3g} off its ray (s + distance l)")
        h, H, inside, ok, u, v = _surface_at(srf, p[None, :], a, f)
        if abs(h[0] - res.height[k]) > 1e-9 * scale + 1e-7:
            fail(f"ray {k}: reported height {res.height[k]!r}, the reference's at p {h[0]!r}")
        if not inside[0]:
            # within the rounding of the grid's edge only
            du = 1e-6 / max(cell_m[0], 1e-300) + 1e-9
            dv = 1e-6 / max(cell_m[1] * max(math.cos(math.radians(res.lat[k])), 1e-12), 1e-300) + 1e-9
            if not srf.inside(np.array([np.clip(u[0], srf.u_lo, srf.u_hi)]),
                              np.array([np.clip(v[0], srf.v_lo, srf.v_hi)])).all() or \
                    max(srf.u_lo - u[0], u[0] - srf.u_hi, 0) > du or max(srf.v_lo - v[0], v[0] - srf.v_hi, 0) > dv:
                fail(f"ray {k}: HIT outside the DSM's area (grid u, v = {u[0]:.9g}, {v[0]:.9g})")
            continue
        near = 2e-6 + 1e-14 * scale                      # and the rounding of s + r l far out
        du = near / max(cell_m[0], 1e-300) + 1e-9
        dv = near / max(cell_m[1] * max(math.cos(math.radians(res.lat[k])), 1e-12), 1e-300) + 1e-9
        lo, hi = _surface_range(srf, float(u[0]), float(v[0]), du, dv)
        if abs(res.lat[k]) > 90.0 - 1e-7:
            # at a pole every column of the polar row meets (the following's nadir case
            # takes the column under its projected point: shin-park-notes note 6)
            row = np.full(srf.ncols, float(u[0]))
            H, ok = srf.height(row, np.arange(srf.ncols, dtype=float))
            if ok.any():
                lo, hi = min(lo, float(np.min(H[ok]))), max(hi, float(np.max(H[ok])))
        if not (lo - TOL_SURFACE - 1e-14 * scale <= h[0] <= hi + TOL_SURFACE + 1e-14 * scale):
            fail(f"ray {k} ({method}): HIT at height {h[0]!r}, the surface around it spans {lo!r}..{hi!r}")
    if method == "exact":
        _check_not_late(srf, s, lu, res, a, f)


#: radians: how far apart two careful conversions of one point may put its latitude or longitude
#: (the package's and the reference's differ by ~1e-16 rad; 8 ulp(pi), the lookup's edge slack)
ROUNDING_RAD = 3.6e-15


def _low_by_rounding(srf, u, v, h) -> bool:
    """True when the point (u, v, h) of a "nearest" surface is below the surface only on one side
    of a cell boundary that lies within ROUNDING_RAD of it: which cell holds such a point is decided
    by the last bits of its conversion, which differ between the package's conversions and the
    reference's. A ray sliding down a wall's plane within that distance (shin-park-notes, "Exact
    mode": the frame camera over a column boundary, fuzz seed 6262) may be answered on either side.
    """
    du = ROUNDING_RAD / math.radians(abs(srf.dlon))
    dv = ROUNDING_RAD / math.radians(abs(srf.dlat))
    lo, _ = _surface_range(srf, u, v, du, dv)
    return lo - h <= TOL_LATE


def _check_not_late(srf, s, lu, res, a, f) -> None:
    """No sample of the ray before exact's answer lies below the surface over data."""
    fail = _ops().fail
    st = np.asarray(res.status)
    for k in range(len(s)):
        # how far before the answer the samples stop: the contract's 1e-6, twice, and the
        # rounding of a point s + r l far out (ulp(|s|): 2e-6 m at 1e10 m, a wall's width)
        margin = 2e-6 + 1e-14 * float(np.linalg.norm(s[k]))
        if st[k] == 0:
            r_end = float(res.distance[k]) - margin
        elif st[k] in (9, 10):
            r_end = float(res.event_distance[k]) - margin
        else:
            r_end = float(np.linalg.norm(s[k])) + 2.0 * a
        if not r_end > 0:
            continue
        r = np.concatenate([np.linspace(0.0, r_end, 400), r_end * (1 - np.geomspace(1e-9, 1e-2, 40))])
        p = s[k] + r[:, None] * lu[k]
        h, H, inside, ok, u, v = _surface_at(srf, p, a, f)
        low = inside & ok & (H - h > TOL_LATE + 1e-12 * np.abs(r))
        if low.any():
            # a stay shorter than the contract's 1e-6 m may be stepped over (near a pole the
            # columns of a 0.5 m grid are 1e-7 m wide): a low sample counts only if the stay
            # holding it, sampled every 2.5e-8 m over +-1.2e-6 m, is 1e-6 m long or more
            for j in np.flatnonzero(low):
                if srf.nearest and _low_by_rounding(srf, float(u[j]), float(v[j]), float(h[j])):
                    continue
                dr = np.linspace(-1.2e-6, 1.2e-6, 97)
                q = s[k] + (r[j] + dr)[:, None] * lu[k]
                h2, H2, in2, ok2, _, _ = _surface_at(srf, q, a, f)
                below = in2 & ok2 & (H2 - h2 > 0.0)
                c = 48
                lo_i, hi_i = c, c
                while lo_i > 0 and below[lo_i - 1]:
                    lo_i -= 1
                while hi_i < 96 and below[hi_i + 1]:
                    hi_i += 1
                if below[c] and dr[hi_i] - dr[lo_i] >= 1e-6 - 5e-8:
                    break
            else:
                continue
            fail(f"ray {k} (exact, status {st[k]}): the point {r[j]!r} along the ray, before the answer at "
                 f"{r_end + margin!r}, lies {H[j] - h[j]:.3g} below the surface (late or missed hit)")


def op_dsm_intersect(case, tmp):
    import planet_intersect as pi

    dsm = make_dsm(case["dsm"])
    surface = {"array": np.zeros((4, 4)), "DEM": None, "None": None}.get(case.get("dsm_is"), dsm) \
        if "dsm_is" in case else dsm
    kw = case["kwargs"]
    res = pi.intersect(surface, case["s"], case["l"], **kw)
    s = np.asarray(case["s"], dtype=np.float64)
    l = np.asarray(case["l"], dtype=np.float64)
    s, l = np.broadcast_arrays(np.atleast_2d(s), np.atleast_2d(l))
    method = kw.get("method", "following")
    with np.errstate(all="ignore"):
        check_dsm_result(dsm, s, l, res, method)
    res.to_table()
    calls = len(s)
    if method == "exact" and len(s) > 1:
        other = pi.intersect(dsm, case["s"], case["l"], **dict(kw, threads=2 if kw.get("threads") == 1 else 1))
        for name in ("status", "p", "distance", "event_distance"):
            x, y = np.asarray(getattr(res, name)), np.asarray(getattr(other, name))
            if not np.array_equal(x, y, equal_nan=True):
                fail = _ops().fail
                fail(f"exact: {name} differs between thread counts: {x!r} vs {y!r}")
        calls += len(s)
    return {"calls": calls}


def op_geodetic(case, tmp):
    import planet_intersect as pi
    from references.geodesy import ecef_to_geodetic

    fail = _ops().fail
    a, f, p, method = case["a"], case["f"], case["p"], case["method"]
    lat, lon, h = pi.ecef_to_geodetic(p, a, f, method=method)
    lat, lon, h = (np.atleast_1d(x) for x in (lat, lon, h))
    if not (np.isfinite(lat).all() and np.isfinite(lon).all() and np.isfinite(h).all()):
        fail(f"ecef_to_geodetic({method}) returned non-finite values for finite points")
    if (np.abs(lat) > 90).any() and method == "exact":
        fail(f"ecef_to_geodetic latitude {lat} outside [-90, 90]")
    calls = 1
    if method == "exact":
        rl, ro, rh = ecef_to_geodetic(p, a, f)
        far = np.linalg.norm(p, axis=1) > 0.9 * a * (1 - f)           # the reference iterates slowly deeper
        scale = np.maximum(np.linalg.norm(p, axis=1), a)
        dl = np.abs(lat - rl)
        do = np.abs((lon - ro + 180.0) % 360.0 - 180.0) * np.cos(np.radians(rl))
        if (far & ((dl > 1e-9) | (do > 1e-9) | (np.abs(h - rh) > 1e-12 * scale + 1e-9))).any():
            k = int(np.argmax(far & ((dl > 1e-9) | (do > 1e-9) | (np.abs(h - rh) > 1e-12 * scale + 1e-9))))
            fail(f"ecef_to_geodetic(p[{k}] = {p[k]}) = ({lat[k]!r}, {lon[k]!r}, {h[k]!r}); "
                 f"reference ({rl[k]!r}, {ro[k]!r}, {rh[k]!r})")
        q = pi.geodetic_to_ecef(lat, lon, h, a, f)
        err = np.linalg.norm(q - p, axis=1)
        if (err > 1e-12 * scale * 8 + 1e-9).any():
            k = int(np.argmax(err))
            fail(f"geodetic_to_ecef(ecef_to_geodetic(p[{k}])) is {err[k]:.3g} from p = {p[k]}")
        calls += 1
    hh = case["h_of"]
    if method != "exact":                  # bowring/printed latitudes may leave [-90, 90] (documented)
        lat = np.clip(lat, -90.0, 90.0)
    q = pi.geodetic_to_ecef(lat, lon, hh, a, f)
    if not np.isfinite(q).all():
        fail(f"geodetic_to_ecef returned non-finite points for heights {hh}")
    return {"calls": calls + 1}


OPS = {"dsm_from_array": op_dsm_from_array, "dsm_intersect": op_dsm_intersect, "geodetic": op_geodetic}
GENERATORS = {"dsm_from_array": dsm_from_array_case, "dsm_intersect": dsm_intersect_case, "geodetic": geodetic_case}
