"""Fuzz cases of the image-simulation system (issue 12): the sensors
(``Pushbroom``, ``Pushbroom.from_orbit``, ``FrameCamera``, ``.pinhole``,
``.nadir``, ``footprint_corners``, ``gsd``), ``OrthoImage.from_array`` and
``simulate_image``.

A bulk family like geo.py (``bulk.MIX_SIM``): the module draws the cases with
bulk.R (hypothesis-free, picklable plain data) and performs them (``OPS``).

Operations and the properties checked (tolerances and why):

* ``sensor``: a sensor built from random valid arguments must be accepted;
  30 % of the cases spoil one argument (NaN, inf, wrong shape, zero vector,
  negative or huge counts, bool where an int or number is wanted, strings,
  ...), and the error must name it. For a valid sensor:

  - ``shape``, ``rays()`` (finite, ``((nl*npx), 3)``), ``l`` ==
    ``rays()[1]`` reshaped, ``rays(k0, k1)`` == the slice of ``rays()`` and
    ``pixel_rays`` == the rays at those indices, **bit for bit** (one
    computation, so no tolerance); ``rays`` outside ``0 <= k0 <= k1 <= nl``
    is refused naming the lines;
  - user arrays (``Pushbroom(s, l)``, ``FrameCamera(position, l)``) come back
    as given (bit for bit) and are private copies (later edits change nothing);
  - built-in geometry: unit directions (``| |l| - 1 | <= 1e-12``, a few ulps
    of a normalisation); ``from_orbit`` with (lat, lon) and odd ``nlines``:
    the centre line's focal point is at geodetic (lat, lon, altitude) by the
    tests' own geodesy (``references/geodesy.py``): 1e-6 m in height and
    1e-6 m horizontally on the ellipsoid (the conversion's rounding at 7e6 m
    is ~1e-9 m), near the poles too (until a fix of 2026-12-03 the
    sub-satellite point was up to 11 mm off there); for every line and pixel the angle between
    the line of sight and the geodetic nadir of the line's focal point is
    ``acos(cos(pitch) cos(psi_m - roll))`` (the documented Rz(yaw) Ry(pitch)
    Rx(roll) frame; yaw turns about the nadir and does not change it) within
    1e-9 rad (a few ulps of angles computed with atan2; the frames are built
    from the same geodetic normal); ``look_angles`` / the ifov spacing as
    documented (``psi_m = (m - (npx-1)/2) ifov``) within 1e-12 deg;
    ``FrameCamera.nadir``: the position is at geodetic (lat, lon, height)
    (1e-9 deg, 1e-6 m), the centre pixel (odd shape) looks along the
    downward normal (1e-9 rad), every pixel (k, m) is at
    ``atan(p sqrt(du^2 + dv^2))`` from the axis with ``p = 2 tan(ifov/2)``
    (1e-9 rad); ``pinhole``: the centre ray of an odd shape passes through
    ``look_at`` (distance <= 1e-9 |look_at - position| + 1e-6 m);
  - on a DSM under the sensor: ``footprint_corners`` == the (lat, lon) of
    ``pi.intersect`` of the four corner rays (bit for bit: the same four
    rays through the same call; NaN plus a RuntimeWarning for a corner that
    does not hit), ``gsd``'s distances positive where finite and equal to the
    chord between the intersect hits of the documented pixels (1e-9 relative).

* ``simulate``: small random scenes (DSM 2-30 cells a side, 0.5-30 m cells,
  on WGS-84 or Mars, anywhere including the poles and across the
  antimeridian, nearest or bilinear, flat, rough, blocks, towers, no-data
  holes; an ortho-image on its own grid, partly off the DSM, 1 or 3 bands,
  uint8/float32/float64, NaN and nodata holes) seen by small sensors (frame
  cameras at nadir or oblique, orbit pushbrooms, user-array pushbrooms;
  steep, grazing, looking away), random options; 20 % with one spoiled
  argument that the error must name. Every normal result:

  - shapes and dtypes as documented (image float32 (nl, npx[, bands]), valid
    and ortho_value bool, surface and status int8, p (nl, npx, 3));
  - statuses are DSM statuses of the method, ``valid`` == status HIT or
    HIT_UNCONVERGED; ``surface`` in {-1, 0, 1, 2} and -1 exactly where not
    valid; where not valid: ``image`` == fill, every backplane NaN,
    ``ortho_value`` False; where valid: finite lat in [-90, 90], lon in
    [-180, 180), distance > 0, angles in [0, 180];
  - per pixel against ``pi.intersect(dsm, *sensor.rays(), method=method)``:
    the same status; for "following" and "iterative" the same lat, lon,
    height, distance and p **bit for bit** (the same core call; the line
    sweep only groups exact rays); for "exact" the image groups rays per
    image line (``fan=npixels``) where intersect groups runs of equal focal
    points, so hits may differ within the exact contract: ``|dd| <= 2e-6 m
    + 4 ulp(|s|)`` for the distance (1e-6 m each) and the same for |dp|;
    beyond that (seen for a nadir camera exactly above a cell boundary: the
    rays slide down a wall's plane within 5e-10 m and meet the higher or
    the lower cell by rounding, 0.5 m apart) both answers must pass geo.py's
    reference checks of an exact hit (``check_dsm_result``);
  - ``p`` on its ray: ``|p - (s + distance l/|l|)| <= 1e-9 max(|s|, a) +
    1e-6 m`` (as geo.py: the rounding of s + r l far out), and lat, lon,
    height are those of p by the tests' geodesy (1e-9 deg, 1e-9 |p| +
    1e-7 m);
  - the image value of a valid ground or roof pixel (any surface with
    ``walls="ortho"``) with ``shading="none"`` is the bilinear sample of the
    ortho values at (lat, lon) (written here from the DESIGN contract, with
    longitudes taken within 180 deg of the ortho's centre longitude), rounded
    to float32: ``|image - ref| <= 2^-23 |ref| + 1e-7 (max - min of the
    ortho) + 1e-30`` (float32 rounding, and the lat/lon rounding of ~1e-8 of
    a cell); where the reference is NaN the pixel has ``ortho_value`` False
    and ``image == fill`` (pixels within 1e-6 of a cell of the ortho's edge,
    or of an integer row/column with a no-data pixel among the 4 x 4 around,
    are skipped: there inside/outside and the neighbour pair are decided by
    rounding); a multi-band pixel with some bands missing has ortho_value
    False, fill in those bands and the sample in the others; with ``shading="lambert"`` the
    value lies between ``ambient * ref`` and ``ref`` (same tolerance); a wall
    with ``walls="interpolate"`` and no shading lies within the ortho's
    value range of its band;
  - the UserWarning about hits without an ortho value is emitted exactly when
    ``meta["hits_without_ortho_value"] == count(valid & ~ortho_value) > 0``
    (any other warning is a violation, as in bulk.run_batch);
  - ``occlusion=True``: occlusion and footprint are bool arrays of the
    ortho grid's shape, occlusion within footprint, and the ortho pixel
    nearest each valid hit (skipping ties within 1e-6 of a cell) is in the
    footprint (documented in ``_occlusion``; it failed, until a fix of
    2026-12-03, when the image's border pixels missed the DSM); ``occlusion=False``: both
    None;
  - the result is **bit-identical** (every array, NaN where NaN) when re-run
    with the other thread count (1 vs 2), another ``block_lines``, or
    ``out=`` a new directory (memory-mapped arrays); ``out=`` an existing
    directory is refused (FileExistsError naming it); ``save()`` to a new
    .png/.tif/.nc in ``tmp`` writes a file and refuses to overwrite it;
    ``to_xarray()`` has the documented variables.

* ``ortho_from_array``: random grids (as the scenes' ortho-images) with 30 %
  one spoiled argument whose error must name it; a valid image is accepted,
  its ``values`` are read-only float64 with NaN exactly at NaN/nodata,
  ``sample`` at the pixel centres (from ``centres()``) gives the values where
  the eight neighbours of the centre have data (1e-12 relative plus twice
  the largest neighbour step times 8 eps (450 + |lon_first|) / spacing
  cells, as geo.py: the centres' coordinates are rounded), the last row and
  column included (they sampled to NaN until a fix of 2026-12-03), and
  ``shape``/``bands`` match.

Numeric strings ("60", "0.1") for numbers are refused everywhere (until
2026-12-03 simulate_image and OrthoImage.from_array took them with
``float(s)`` while the sensors refused them).
"""

from __future__ import annotations

import math
import os
import warnings

import numpy as np

from .bulk import R, spec_cached

WGS84 = (6378137.0, 1.0 / 298.257223563)
MARS = (3396190.0, 1.0 / 169.894)

TOL_EXACT_SWEEP = 2e-6     # m: two answers each within the exact contract's 1e-6 m along the ray
TOL_ON_RAY = 1e-9          # relative to max(|s|, a), as geo.py
TOL_ANGLE = 1e-9           # rad: closed-form pointing of the built-in sensors
TOL_DEG = 1e-9             # deg: positions of built-in sensors and of hits
SIM_STATUSES = {"exact": {0, 9, 10, 11}, "following": {0, 3, 9, 10, 11, 14},
                "iterative": {0, 3, 9, 10, 11, 12, 13, 14}}
SIM_NAMES = ["dsm", "ortho", "sensor", "method", "walls", "shading", "sun", "ambient", "fill", "occlusion",
             "ground", "ground_window", "wall_slope", "roof_min", "threads", "block_lines", "out"]
NOVALUE_WARNING = "where the ortho-image has no value"


def _ops():
    from . import ops

    return ops


def fail(msg):
    _ops().fail(msg)


def _ecef(lat, lon, h, a, f):
    from references.geodesy import geodetic_to_ecef

    return np.asarray(geodetic_to_ecef(lat, lon, h, a, f), dtype=np.float64)


def _enu(lat, lon):
    from references.geodesy import east_north, up_vector

    e, n = east_north(lat, lon)
    return np.asarray(e, float), np.asarray(n, float), np.asarray(up_vector(lat, lon), float)


def _angle(u, v):
    """Angle between rows of u and v (radians), atan2 form (accurate near 0 and pi)."""
    u = np.atleast_2d(u)
    v = np.atleast_2d(v)
    c = np.linalg.norm(np.cross(u, v), axis=-1)
    d = np.einsum("ij,ij->i", u, v)
    return np.arctan2(c, d)


# ---------------------------------------------------------------------------- scenes
def scene_dsm_spec(r: R) -> dict:
    """A small DSM spec in geo.py's format (geo.dsm_args / geo.make_dsm build it)."""
    a, f = r.pick([WGS84, WGS84, WGS84, MARS])
    interp = r.pick(["bilinear", "nearest"])
    nrows, ncols = r.int(2, 30), r.int(2, 30)
    cell = r.pick([0.5, 1.0, 2.0, 5.0, 10.0, 30.0])
    dlat = math.degrees(cell * r.pick([1.0, 1.0, 0.5, 2.0]) / a) * r.pick([-1.0, 1.0])
    where = r.pick(["any", "any", "any", "pole", "antimeridian", "equator"])
    span = abs(dlat) * (nrows - 1)
    if where == "pole":
        top = 90.0 - r.pick([0.0, 1e-9, abs(dlat) * 0.5, abs(dlat) * 3])
        lat_lo = top - span
        sign = r.pick([-1.0, 1.0])
    else:
        lat_lo = r.float(-85.0, 85.0 - span) if where == "any" else -span / 2
        sign = 1.0
    # columns about `cell` metres wide at the scene's latitude (at most 1 degree)
    lat_mid = abs(lat_lo + span / 2)
    dlon = min(math.degrees(cell / a) / max(math.cos(math.radians(min(lat_mid, 89.99))), 1e-3), 1.0)
    lat_first = lat_lo if dlat > 0 else lat_lo + span
    lat_first *= sign
    if sign < 0:
        dlat = -dlat
    if where == "antimeridian":
        lon_first = 180.0 - dlon * r.float(0.2, ncols - 0.2)
    else:
        lon_first = r.float(-180.0, 180.0)
    spec = {"shape": (nrows, ncols), "a": a, "f": f, "interpolation": interp,
            "lat_first": lat_first, "lon_first": lon_first, "dlat": dlat, "dlon": dlon,
            "kind": r.pick(["flat", "rough", "blocks", "blocks", "blocks", "tower", "holes"]),
            "scale": r.pick([1.0, 5.0, 20.0, 60.0]), "base": r.pick([0.0, -30.0, 120.0, 2000.0]),
            "seed": r.int(0, 2**31)}
    if r.chance(0.1):
        spec["nodata"] = -9999.0
    return spec


def _dsm_box(spec):
    """(lat_min, lat_max, lon_centre, lon_span) of a DSM spec's pixel centres."""
    nrows, ncols = spec["shape"]
    lats = [spec["lat_first"], spec["lat_first"] + (nrows - 1) * spec["dlat"]]
    lon_c = spec["lon_first"] + 0.5 * (ncols - 1) * spec["dlon"]
    return min(lats), max(lats), lon_c, (ncols - 1) * spec["dlon"]


def ortho_spec(r: R, dsm: dict | None = None, valid_only: bool = True) -> dict:
    """An ortho-image on its own grid, about over the DSM (partly off it now and then)."""
    if dsm is None:
        dsm = scene_dsm_spec(r)
    lat_lo, lat_hi, lon_c, lon_span = _dsm_box(dsm)
    ratio = r.pick([0.5, 1.0, 1.0, 2.0, 3.0, 0.37])
    dlat = abs(dsm["dlat"]) * ratio * r.pick([-1.0, 1.0])
    dlon = dsm["dlon"] * ratio * r.pick([1.0, 0.8, 1.3])
    lat_span = (lat_hi - lat_lo) * r.pick([1.0, 1.0, 1.2, 0.6])
    lon_span_o = lon_span * r.pick([1.0, 1.0, 1.2, 0.6])
    nrows = int(min(max(round(lat_span / abs(dlat)) + 1, 2), 30))
    ncols = int(min(max(round(lon_span_o / dlon) + 1, 2), 30))
    shift_u = r.pick([0.0, 0.0, r.float(-0.5, 0.5)]) * (nrows - 1) * abs(dlat)
    shift_v = r.pick([0.0, 0.0, r.float(-0.5, 0.5)]) * (ncols - 1) * dlon
    o_lat_lo = 0.5 * (lat_lo + lat_hi) - 0.5 * (nrows - 1) * abs(dlat) + shift_u
    o_lat_hi = o_lat_lo + (nrows - 1) * abs(dlat)
    if o_lat_hi > 90.0:
        o_lat_lo -= o_lat_hi - 90.0
        o_lat_hi = 90.0
    if o_lat_lo < -90.0:
        o_lat_hi += -90.0 - o_lat_lo
        o_lat_lo = -90.0
    lat_first = o_lat_lo if dlat > 0 else o_lat_hi
    lat_first = min(max(lat_first, -90.0), 90.0)
    last = lat_first + (nrows - 1) * dlat
    if abs(last) > 90.0:                                  # rounding at a pole
        lat_first -= math.copysign(abs(last) - 90.0 + 1e-12, last)
    lon_first = lon_c - 0.5 * (ncols - 1) * dlon + shift_v
    bands = r.pick([1, 1, 3])
    dtype = r.pick(["uint8", "float32", "float64"])
    spec = {"shape": (nrows, ncols), "bands": bands, "dtype": dtype, "lat_first": lat_first,
            "lon_first": lon_first, "dlat": dlat, "dlon": dlon, "seed": r.int(0, 2**31),
            "holes": r.chance(0.2), "negative": dtype != "uint8" and r.chance(0.1)}
    if r.chance(0.15):
        spec["nodata"] = 0.0 if dtype == "uint8" else -1.0
    if not valid_only and r.chance(0.3):
        arg = r.pick(sorted(ORTHO_SPOILS))
        spec["spoil"] = (arg, r.pick(ORTHO_SPOILS[arg]))
    return spec


ORTHO_SPOILS = {
    "values": ["1d", "0d", "1x5", "5x1", "3d0", "4d", "complex", "strings", "object", "none", "empty"],
    "lat_first": [math.nan, math.inf, 95.0, -90.5, "10", None, 1e300],
    "lon_first": [math.nan, -math.inf, "east", None],
    "dlat": [0.0, -0.0, math.nan, math.inf, 91.0, None, "0.1", 1e-9],
    "dlon": [0.0, -1e-5, math.nan, math.inf, 400.0, 5e-324, None, 1e-9],
    "nodata": ["x", [1, 2], math.inf, complex(1, 1), math.nan],
}


def ortho_values(spec: dict) -> np.ndarray:
    nrows, ncols = spec["shape"]
    g = np.random.default_rng(spec["seed"])
    shape = (nrows, ncols) if spec["bands"] == 1 else (nrows, ncols, spec["bands"])
    if spec["dtype"] == "uint8":
        v = g.integers(1, 256, shape).astype(np.uint8)
        if "nodata" in spec and v.size > 2:
            v.reshape(-1)[g.integers(0, v.size, 2)] = int(spec["nodata"])
        return v
    v = g.uniform(-500.0 if spec["negative"] else 0.0, 1000.0, shape).astype(spec["dtype"])
    if spec["holes"]:
        m = g.random((nrows, ncols)) < 0.15
        v[m] = np.nan
    if "nodata" in spec and v.size > 2:
        v.reshape(-1)[g.integers(0, v.size, 2)] = spec["nodata"]
    return v


def ortho_args(spec: dict):
    v = ortho_values(spec)
    args = [v, spec["lat_first"], spec["lon_first"], spec["dlat"], spec["dlon"]]
    kw = {"nodata": spec["nodata"]} if "nodata" in spec else {}
    if "spoil" in spec:
        arg, bad = spec["spoil"]
        if arg == "values":
            bad = {"1d": v.ravel(), "0d": np.float64(3.0), "1x5": np.ones((1, 5)), "5x1": np.ones((5, 1)),
                   "3d0": np.ones((3, 3, 0)), "4d": np.ones((2, 2, 2, 2)), "complex": v.astype(complex),
                   "strings": np.full(v.shape[:2], "a"), "object": v.astype(object),
                   "none": None, "empty": np.zeros((0, 0))}[bad]
            args[0] = bad
        elif arg == "nodata":
            kw["nodata"] = bad
        else:
            args[["lat_first", "lon_first", "dlat", "dlon"].index(arg) + 1] = bad
    return args, kw


def _ortho_spoil_valid(spec) -> bool:
    arg, v = spec["spoil"]
    if arg == "values":
        return False                       # (an object array of numbers may be refused: TypeError naming values)
    if arg == "dlat" and v == 1e-9:
        return False
    if arg == "lat_first" and isinstance(v, float) and math.isfinite(v):
        last = v + (spec["shape"][0] - 1) * spec["dlat"]
        return -90 <= v <= 90 and -90 <= last <= 90
    if arg == "nodata" and isinstance(v, float) and math.isnan(v):
        return None                        # NaN as nodata: either refused (not finite) or no-op
    return False


_ORTHO_CACHE: dict = {}


def make_ortho(spec: dict):
    import planet_intersect as pi

    def build():
        args, kw = ortho_args(spec)
        return pi.OrthoImage.from_array(*args, **kw)

    return spec_cached(_ORTHO_CACHE, spec, build)


def _dsm(spec):
    from .geo import make_dsm

    return make_dsm(spec)


# ---------------------------------------------------------------------------- sensors
def _scene_centre(dsm: dict):
    lat_lo, lat_hi, lon_c, _ = _dsm_box(dsm)
    return 0.5 * (lat_lo + lat_hi), lon_c


def _extent_m(dsm: dict):
    nrows, ncols = dsm["shape"]
    a = dsm["a"]
    lat_c, _ = _scene_centre(dsm)
    ey = math.radians(abs(dsm["dlat"])) * a * max(nrows - 1, 1)
    ex = math.radians(dsm["dlon"]) * a * max(math.cos(math.radians(lat_c)), 1e-6) * max(ncols - 1, 1)
    return max(ey, ex, 1.0)


def _hmax(dsm: dict) -> float:
    from .geo import dsm_heights

    h = dsm_heights(dsm)
    if "nodata" in dsm:
        h = np.where(h == dsm["nodata"], np.nan, h)
    return float(np.nanmax(h))


def sensor_spec(r: R, dsm: dict, kind: str | None = None) -> dict:
    """A valid sensor (plain data) over a DSM spec."""
    a, f = dsm["a"], dsm["f"]
    lat_c, lon_c = _scene_centre(dsm)
    ext = _extent_m(dsm)
    hmax = _hmax(dsm)
    kind = kind or r.pick(["nadir", "nadir", "pinhole", "orbit", "orbit", "arrays", "frame_arrays"])
    nl, npx = r.int(1, 6), r.int(1, 8)
    look = r.pick(["steep", "steep", "steep", "oblique", "graze", "away"])
    el = {"steep": r.float(60.0, 90.0), "oblique": r.float(20.0, 60.0), "graze": r.float(0.3, 8.0),
          "away": r.float(30.0, 90.0)}[look]
    az = r.float(0.0, 360.0)
    spec = {"kind": kind, "shape": (nl, npx), "look": look, "a": a, "f": f}
    if kind == "nadir":
        height = max(hmax, 0.0) + r.pick([30.0, 300.0, 3000.0, 7e5])
        spec.update(lat=min(max(lat_c + r.float(-0.3, 0.3) * abs(dsm["dlat"]) * dsm["shape"][0], -90.0), 90.0),
                    lon=lon_c, height=height,
                    ifov=min(math.degrees(ext * r.pick([0.5, 1.0, 1.6]) / max(npx, nl) / height),
                             120.0 / max(npx, nl)),
                    rotation=r.pick([0.0, 0.0, r.float(-180, 180)]))
        if look == "away":
            spec["kind"] = kind = "pinhole"
    if kind == "pinhole":
        dist = r.pick([200.0, 2000.0, 2e4, 7e5]) if look != "graze" else r.pick([2000.0, 2e4])
        e, n, u = _enu(lat_c, lon_c)
        elr, azr = math.radians(el), math.radians(az)
        d = math.cos(elr) * (math.sin(azr) * e + math.cos(azr) * n) + math.sin(elr) * u
        target = _ecef(lat_c, lon_c, dsm["base"], a, f)
        pos = target + dist * d
        pos = _lift(pos, hmax, a, f)
        at = target if look != "away" else pos + (pos - target)
        spec.update(kind="pinhole", position=pos.tolist(), look_at=at.tolist(),
                    ifov=min(math.degrees(ext * r.pick([0.5, 1.0, 1.6]) / max(npx, nl) / dist), 120.0 / max(npx, nl)),
                    rotation=r.pick([0.0, r.float(-180, 180)]))
    elif kind == "orbit":
        alt = r.pick([4.5e5, 7e5, 8e5])
        roll = r.pick([0.0, 0.0, r.float(-30.0, 30.0)])
        pitch = r.pick([0.0, 0.0, r.float(-20.0, 20.0)])
        yaw = r.pick([0.0, 0.0, r.float(-180.0, 180.0)])
        ifov = math.degrees(ext * r.pick([0.5, 1.0, 1.6]) / max(npx, 1) / alt)
        spec.update(altitude=alt, inclination=r.pick([98.0, 97.4, 45.0, 0.0, 90.0, 180.0, r.float(0, 180)]),
                    npixels=npx, nlines=nl, ifov=ifov, roll=roll, pitch=pitch, yaw=yaw,
                    direction=r.pick(["ascending", "descending"]), yaw_steering=r.chance(0.8),
                    line_period=ext / max(nl, 1) / 7000.0 * r.pick([1.0, 0.5, 2.0]))
        if r.chance(0.5) and abs(lat_c) < 80:
            spec["target"] = [lat_c, lon_c, dsm["base"]]
        else:
            # sub-satellite point: a little off the scene for roll/pitch (they point back roughly)
            spec["lat"], spec["lon"] = lat_c, lon_c
        # a pointed boresight meets the ground up to gamma of arc from the ground track (the off-nadir
        # angle theta seen from the body's centre; 6.8 deg for 26 deg of roll from 800 km over Mars): the
        # orbit must reach the latitude with that margin (a target at 76.02 N with 97.4 deg and 26 deg of
        # roll was out of reach by 10 km, and from_orbit said so; seed 7304)
        theta = math.radians(min(math.hypot(spec["roll"], spec["pitch"]), 60.0))
        gamma = math.degrees(math.asin(min(1.0, (a + alt) / a * math.sin(theta))) - theta)
        if abs(lat_c) > 80.0:
            spec["inclination"] = 90.0                      # the orbit must reach the (geocentric) latitude
        elif spec["inclination"] < abs(lat_c) + 2.0 + gamma or spec["inclination"] > 178.0 - abs(lat_c) - gamma:
            spec["inclination"] = 90.0 if "target" in spec and gamma > 0.0 else r.pick([90.0, 98.0])
        if r.chance(0.15):
            spec["look_angles"] = sorted(r.g.uniform(-1.0, 1.0, npx) * math.degrees(ext / alt)).copy()
        if r.chance(0.1):
            spec["eccentricity"] = r.pick([0.001, 0.01])
            spec["arg_perigee"] = r.float(-180, 180)
        if look == "away":
            spec["pitch"] = 0.0
            spec["roll"] = r.pick([85.0, -85.0])           # toward the horizon: misses
            spec.pop("target", None)
            spec["lat"], spec["lon"] = lat_c, lon_c
    elif kind in ("arrays", "frame_arrays"):
        dist = r.pick([200.0, 2000.0, 2e4, 7e5]) if look != "graze" else r.pick([2000.0, 2e4])
        e, n, u = _enu(lat_c, lon_c)
        elr, azr = math.radians(el), math.radians(az)
        d = math.cos(elr) * (math.sin(azr) * e + math.cos(azr) * n) + math.sin(elr) * u
        g = r.g
        target = _ecef(lat_c, lon_c, dsm["base"], a, f)
        along = math.cos(azr) * e - math.sin(azr) * n        # horizontal, across the view direction
        nl_, npx_ = (nl, npx)
        s = np.empty((nl_, 3))
        l = np.empty((nl_, npx_, 3))
        across = np.cross(d, along)
        for k in range(nl_):
            off = (k - (nl_ - 1) / 2) * ext / max(nl_, 1) if kind == "arrays" else 0.0
            s[k] = _lift(target + dist * d + off * along, hmax, a, f)
            for m in range(npx_):
                t = ((m - (npx_ - 1) / 2) / max(npx_, 1) * ext * g.uniform(0.8, 1.2)) * across \
                    + off * along * (1.0 if kind == "arrays" else 0.0) \
                    + ((k - (nl_ - 1) / 2) / max(nl_, 1) * ext * along if kind == "frame_arrays" else 0.0)
                l[k, m] = (target + t) - s[k]
                if look == "away":
                    l[k, m] = -l[k, m]
        l = l * r.pick([1.0, 1.0, 1e-3, 1e3, 1e-150, 1e150])
        if kind == "frame_arrays":
            spec["position"] = s[0].tolist()
        else:
            spec["s"] = s
        spec["l"] = l
    return spec


def _lift(pos, hmax, a, f):
    """pos raised along the normal so that it is at least 2 m above the DSM's highest point."""
    from references.geodesy import ecef_to_geodetic

    la, lo, h = ecef_to_geodetic(pos, a, f)
    if h < hmax + 2.0:
        pos = _ecef(float(la), float(lo), hmax + 2.0 + abs(hmax) * 1e-9, a, f)
    return pos


def build_sensor(spec: dict):
    import planet_intersect as pi

    k = spec["kind"]
    if k == "nadir":
        return pi.FrameCamera.nadir(spec["lat"], spec["lon"], spec["height"], spec["shape"], spec["ifov"],
                                    rotation=spec.get("rotation", 0.0), a=spec["a"], f=spec["f"])
    if k == "pinhole":
        kw = {kk: spec[kk] for kk in ("rotation", "up", "geodetic") if kk in spec}
        return pi.FrameCamera.pinhole(spec["position"], spec["look_at"], spec["shape"], spec["ifov"],
                                      a=spec["a"], f=spec["f"], **kw)
    if k == "orbit":
        kw = {kk: spec[kk] for kk in ("altitude", "inclination", "npixels", "ifov", "nlines", "line_rate",
                                      "line_period", "lat", "lon", "target", "direction", "roll", "pitch", "yaw",
                                      "look_angles", "eccentricity", "arg_perigee", "yaw_steering", "gm",
                                      "rotation_rate") if kk in spec}
        if spec.get("omit_ellipsoid"):
            return pi.Pushbroom.from_orbit(**kw)
        return pi.Pushbroom.from_orbit(a=spec["a"], f=spec["f"], **kw)
    if k == "arrays":
        return pi.Pushbroom(spec["s"], spec["l"])
    if k == "frame_arrays":
        return pi.FrameCamera(spec["position"], spec["l"])
    raise AssertionError(k)


#: spoiled sensor arguments per kind: (argument, value, names the error may use)
SENSOR_SPOILS = {
    "nadir": {"lat": [math.nan, 91.0, "10", None, True], "lon": [math.inf, "x", None],
              "height": [0.0, -5.0, math.nan, 1e30, True], "shape": [(0, 3), (3,), (2, 2.0), (-1, 4), (True, 2),
                                                                     "ab", None, (10**7, 1)],
              "ifov": [0.0, -1.0, 180.0, math.nan, "1"], "rotation": [math.nan, math.inf, "r"],
              "a": [0.0, -1.0, math.nan], "f": [1.0, -0.1, math.nan]},
    "pinhole": {"position": [[0.0, 0.0], [math.nan, 0.0, 1.0], "xyz", [[1.0, 2.0, 3.0]] * 2, None],
                "look_at": ["same", [math.inf, 0, 0], [1.0, 2.0, 3.0, 4.0]],
                "shape": [(0, 3), (3, 1, 1), (2.5, 2)], "ifov": [0.0, 200.0, math.nan],
                "up": ["axis", [0.0, 0.0, 0.0], [math.nan, 1.0, 0.0], [1.0, 2.0]],
                "geodetic": ["yes", 1, None], "rotation": [math.nan, "0"]},
    "orbit": {"altitude": [0.0, -7e5, math.nan, math.inf, "700000", True],
              "inclination": [-1.0, 181.0, math.nan, None], "npixels": [0, -3, 2.5, True, 10**9, "4", 3.0],
              "nlines": [0, -1, 1.5, False, 10**9],
              "ifov": [0.0, -0.1, 180.0, math.nan, math.inf, "0.01", 60.0],
              "roll": [90.0, -90.0, math.nan, 1e300, "0"], "pitch": [90.0, math.inf, None],
              "yaw": [400.0, math.nan, "0"], "direction": ["north", "Ascending", None, 1],
              "yaw_steering": ["yes", 1, None], "line_period": [0.0, -1.0, math.nan, "1"],
              "line_rate": [0.0, -5.0, math.inf], "both_rates": [1.0],
              "look_angles": ["short", [math.nan], [95.0], "x", [[0.0]]],
              "eccentricity": [1.0, -0.1, 0.9, math.nan], "arg_perigee": [math.nan, 400.0],
              "lat": [91.0, math.nan, "n", True], "lon": [math.nan, math.inf, "e"],
              "target": [[math.nan, 0.0], [95.0, 0.0], "here", [1.0], [1.0, 2.0, 3.0, 4.0]],
              "gm": [0.0, -1.0, math.nan], "rotation_rate": [math.nan, math.inf, "w"],
              "a": [0.0, math.nan, -1.0], "f": [1.0, math.nan]},
    "arrays": {"s": ["nan", "shape", "lines", "empty", "complex", "strings", "bool", "object"],
               "l": ["nan", "zero", "shape", "inf", "2d", "nopixels", "complex"]},
    "frame_arrays": {"position": ["nan", "shape", "strings", "4"], "l": ["nan", "zero", "shape", "2d"]},
}
#: what the error may name, beyond the argument itself
SENSOR_ALIASES = {"both_rates": ["line_rate", "line_period"], "look_angles": ["look_angles", "npixels"],
                  "npixels": ["npixels", "ifov"], "ifov": ["ifov", "npixels"],
                  "eccentricity": ["eccentricity", "perigee"], "lat": ["lat", "target"],
                  "target": ["target", "lat"], "shape": ["shape"], "a": ["a", "f", "semi-major"],
                  "f": ["f", "a", "flattening"], "altitude": ["altitude"], "gm": ["gm"],
                  "up": ["up"], "look_at": ["look_at", "position"], "position": ["position"],
                  "s": ["s", "l"], "l": ["l", "s"], "height": ["height"], "inclination": ["inclination"],
                  "roll": ["roll"], "pitch": ["pitch"], "line_period": ["line_period", "nlines"],
                  "line_rate": ["line_rate", "nlines"]}


def spoil_sensor(r: R, spec: dict):
    kind = spec["kind"]
    pool = SENSOR_SPOILS[kind]
    arg = r.pick(sorted(pool))
    val = r.pick(pool[arg])
    spec = dict(spec)
    spec["spoiled"] = (arg, val)
    if kind in ("arrays", "frame_arrays"):
        if arg in ("s", "position"):
            base = np.array(spec["s"] if arg == "s" else spec["position"], dtype=float)
            if val == "nan":
                base = base.copy()
                base.reshape(-1)[-1] = math.nan
            else:
                base = {"shape": base.reshape(-1)[:2] if arg == "position" else base[:, :2],
                        "lines": np.concatenate([base, base[-1:]]) if arg == "s" else base,
                        "empty": np.zeros((0, 3)), "complex": base.astype(complex),
                        "strings": np.full(base.shape, "x"), "bool": np.ones(base.shape, dtype=bool),
                        "object": base.astype(object), "4": np.ones(4)}[val]
            spec["s" if arg == "s" else "position"] = base
        else:
            l = np.array(spec["l"], dtype=float)
            if val == "nan":
                l[-1, -1, 0] = math.nan
            elif val == "inf":
                l[0, 0, 2] = -math.inf
            elif val == "zero":
                l[-1, 0] = 0.0
            else:
                l = {"shape": l[..., :2], "2d": l[0], "nopixels": l[:, :0], "complex": l.astype(complex)}[val]
            spec["l"] = l
    elif arg == "both_rates":
        spec["line_rate"], spec["line_period"] = 10.0, 0.1
    elif arg == "look_angles":
        n = spec["npixels"]
        spec[arg] = [0.0] * (n + 1) if val == "short" else val * n if isinstance(val, list) and len(val) == 1 \
            and not isinstance(val[0], list) else val
    elif arg == "look_at" and val == "same":
        spec["look_at"] = spec["position"]
    elif arg == "up" and val == "axis":
        spec["up"] = (np.array(spec["look_at"]) - np.array(spec["position"])).tolist()
    elif arg in ("lat", "lon") and kind == "orbit":
        spec.pop("target", None)
        spec.setdefault("lat", 0.0)
        spec.setdefault("lon", 0.0)
        spec[arg] = val
    elif arg == "target":
        spec.pop("lat", None)
        spec.pop("lon", None)
        spec[arg] = val
    elif arg == "nlines" and kind == "orbit":
        spec["nlines"] = val
    elif arg in ("shape",):
        spec["shape"] = val
    else:
        spec[arg] = val
    return spec


def _sensor_names(spec) -> list:
    arg = spec["spoiled"][0]
    return list(dict.fromkeys([arg] + SENSOR_ALIASES.get(arg, [])))


def _sensor_spoil_expect(spec) -> str:
    """What a spoiled sensor argument must do: "refuse" (every value in SENSOR_SPOILS is outside
    the documented domain: non-finite, wrong shape or type, a string or bool for a number, out of
    range), "accept" (still valid) or "either"."""
    arg, v = spec["spoiled"]
    if arg == "f" and v == -0.1:
        return "either"                                 # a prolate ellipsoid: not excluded by the docs
    if arg == "eccentricity" and v == 0.9:
        return "either"                                 # refused only if the perigee is below the surface
    if arg == "ifov" and v == 60.0 and spec["kind"] == "orbit":
        if spec.get("look_angles") is not None:
            return "accept"                             # ifov then only documents the pixel size
        # outer pixels (n-1)/2 * 60 deg off the boresight, refused from 90 (from_orbit's docs): n >= 4
        return "accept" if spec["npixels"] <= 3 else "refuse"
    return "refuse"


def sensor_case(r: R, seed: int) -> dict:
    dsm = scene_dsm_spec(r)
    sp = sensor_spec(r, dsm)
    case = {"op": "sensor", "sensor": sp, "dsm": dsm, "names": ["sensor"], "must_succeed": True}
    if r.chance(0.3):
        sp = spoil_sensor(r, sp)
        case["sensor"] = sp
        case["names"] = _sensor_names(sp)
        case["expect"] = _sensor_spoil_expect(sp)
        case["must_succeed"] = case["expect"] == "accept"
        case["spoil"] = sp["spoiled"]
    else:
        case["helpers"] = r.chance(0.5)
        if r.chance(0.1):
            case["bad_block"] = r.pick([(-1, 1), (2, 1), (0, 10**6), (0.5, 1)])
    return case


def op_sensor(case, tmp):
    import planet_intersect as pi
    from references.geodesy import ecef_to_geodetic

    sp = case["sensor"]
    sensor = build_sensor(sp)
    if "spoil" in case:
        if case.get("expect") == "refuse":
            fail(f"{sp['kind']}: accepted {case['spoil'][0]} = {case['spoil'][1]!r}")
        # a spoiled argument that was accepted: the sensor must still be usable
        s, l = sensor.rays()
        if not (np.isfinite(s).all() and np.isfinite(l).all()):
            fail(f"spoiled {case['spoil']!r} accepted and the rays are not finite")
        return {"calls": 2}
    nl, npx = sp["shape"]
    if tuple(sensor.shape) != (nl, npx) or sensor.nlines != nl or sensor.npixels != npx:
        fail(f"sensor.shape {sensor.shape}, built for {(nl, npx)}")
    s, l = sensor.rays()
    n = nl * npx
    if s.shape != (n, 3) or l.shape != (n, 3):
        fail(f"rays() shapes {s.shape}, {l.shape}; expected ({n}, 3)")
    if not (np.isfinite(s).all() and np.isfinite(l).all()):
        fail("rays() not finite")
    if (np.max(np.abs(l), axis=1) == 0).any():
        fail("rays() has a zero direction")
    L = sensor.l
    if L.shape != (nl, npx, 3) or not np.array_equal(L.reshape(-1, 3), l):
        fail("sensor.l differs from rays()[1]")
    g = np.random.default_rng(len(case["names"]) + n)
    for _ in range(2):
        k0 = int(g.integers(0, nl + 1))
        k1 = int(g.integers(k0, nl + 1))
        sb, lb = sensor.rays(k0, k1)
        if not (np.array_equal(sb, s[k0 * npx:k1 * npx]) and np.array_equal(lb, l[k0 * npx:k1 * npx])):
            fail(f"rays({k0}, {k1}) differs from rays()[{k0 * npx}:{k1 * npx}]")
    li = g.integers(0, nl, 3)
    pix = g.integers(0, npx, 3)
    ps, pl = sensor.pixel_rays(li, pix)
    if not (np.array_equal(ps, s[li * npx + pix]) and np.array_equal(pl, l[li * npx + pix])):
        fail(f"pixel_rays({li}, {pix}) differ from rays()")
    calls = 5
    if "bad_block" in case:
        k0, k1 = case["bad_block"]
        try:
            sensor.rays(k0, k1)
        except (ValueError, TypeError) as exc:
            if "line" not in str(exc) and "k0" not in str(exc):
                fail(f"rays({k0}, {k1}) refused without naming the lines: {exc}")
        else:
            if not (isinstance(k0, int) and isinstance(k1, int) and 0 <= k0 <= k1 <= nl):
                fail(f"rays({k0!r}, {k1!r}) accepted on a sensor of {nl} lines")
        calls += 1
    kind = sp["kind"]
    a, f = sp["a"], sp["f"]
    if kind == "arrays":
        want_l = np.asarray(sp["l"], dtype=float)
        if not (np.array_equal(l, want_l.reshape(-1, 3)) and np.array_equal(s, np.repeat(sp["s"], npx, axis=0))):
            fail("Pushbroom(s, l).rays() is not (s repeated, l) as given")
    elif kind == "frame_arrays":
        if not (np.array_equal(l, np.asarray(sp["l"], dtype=float).reshape(-1, 3))
                and (s == np.asarray(sp["position"])).all()):
            fail("FrameCamera(position, l).rays() is not (position, l) as given")
    else:
        norm = np.linalg.norm(l, axis=1)
        if np.abs(norm - 1).max() > 1e-12:
            fail(f"built-in sensor: |l| - 1 up to {np.abs(norm - 1).max():.3g}")
    if kind == "orbit":
        la, lo, h = ecef_to_geodetic(s[::npx], a, f)
        nadir = -np.asarray(_enu(la, lo)[2]).reshape(-1, 3)
        psi = np.asarray(sensor.look_angles, dtype=float)
        want_psi = np.asarray(sp["look_angles"], dtype=float) if "look_angles" in sp else \
            (np.arange(npx) - (npx - 1) / 2.0) * sp["ifov"]
        if psi.shape != (npx,) or np.abs(psi - want_psi).max() > 1e-12 * max(1.0, np.abs(want_psi).max()):
            fail(f"look_angles {psi} differ from the documented {want_psi}")
        # body direction of pixel m after Rx(roll), Ry(pitch) (yaw turns about the nadir):
        # (sin(pitch) cos(psi - roll), sin(psi - roll), cos(pitch) cos(psi - roll))
        q = np.radians(psi - sp["roll"])
        pr = math.radians(sp["pitch"])
        want = np.arctan2(np.hypot(math.sin(pr) * np.cos(q), np.sin(q)), math.cos(pr) * np.cos(q))
        got = _angle(l, np.repeat(nadir, npx, axis=0)).reshape(nl, npx)
        dif = np.abs(got - want[None, :])
        if dif.max() > TOL_ANGLE:
            k = np.unravel_index(int(np.argmax(dif)), dif.shape)
            fail(f"from_orbit: pixel {k} is {math.degrees(got[k]):.12g} deg off nadir, the documented frame "
                 f"(roll {sp['roll']}, pitch {sp['pitch']}, psi {psi[k[1]]}) gives {math.degrees(want[k[1]]):.12g}")
        if "lat" in sp and nl % 2 == 1:
            c = nl // 2
            # horizontal distance on the ellipsoid between the asked and the actual sub-satellite point
            q0 = _ecef(sp["lat"], sp["lon"], 0.0, a, f)
            q1 = _ecef(float(la[c]), float(lo[c]), 0.0, a, f)
            horiz = float(np.linalg.norm(q1 - q0))
            # 1e-6 m, near the poles too (the node's arcsine lost sqrt(eps) there, 11 mm at
            # 89.9999999 deg, until a fix of 2026-12-03)
            tol_h = 1e-6
            if horiz > tol_h or abs(h[c] - sp["altitude"]) > 1e-6:
                fail(f"from_orbit: the centre line's focal point is at ({la[c]!r}, {lo[c]!r}, {h[c]!r}), "
                     f"{horiz:.3g} m from the asked sub-satellite point ({sp['lat']}, {sp['lon']}), "
                     f"altitude {sp['altitude']}")
    if kind == "nadir":
        la, lo, h = ecef_to_geodetic(s[0], a, f)
        dlon = abs((float(lo) - sp["lon"] + 180.0) % 360.0 - 180.0) * math.cos(math.radians(sp["lat"]))
        if abs(float(la) - sp["lat"]) > TOL_DEG or (abs(sp["lat"]) < 89.9999 and dlon > TOL_DEG) \
                or abs(float(h) - sp["height"]) > 1e-6 + 1e-15 * sp["height"]:
            fail(f"FrameCamera.nadir at ({float(la)!r}, {float(lo)!r}, {float(h)!r}), asked "
                 f"({sp['lat']}, {sp['lon']}, {sp['height']})")
        axis = -_enu(sp["lat"], sp["lon"])[2]
        p = 2.0 * math.tan(math.radians(sp["ifov"]) / 2.0)
        kk, mm = np.meshgrid(np.arange(nl) - (nl - 1) / 2.0, np.arange(npx) - (npx - 1) / 2.0, indexing="ij")
        want = np.arctan(p * np.hypot(kk, mm)).ravel()
        got = _angle(l, np.broadcast_to(axis, l.shape))
        if np.abs(got - want).max() > TOL_ANGLE:
            k = int(np.argmax(np.abs(got - want)))
            fail(f"FrameCamera.nadir: ray {k} is {got[k]!r} rad off the downward normal, the pinhole model "
                 f"gives {want[k]!r}")
    if kind == "pinhole" and nl % 2 == 1 and npx % 2 == 1:
        c = (nl // 2) * npx + npx // 2
        pos, at = np.asarray(sp["position"]), np.asarray(sp["look_at"])
        u = l[c] / np.linalg.norm(l[c])
        off = np.linalg.norm(np.cross(at - pos, u))
        if off > 1e-9 * np.linalg.norm(at - pos) + 1e-6:
            fail(f"pinhole: the centre ray passes {off:.3g} from look_at")
    if case.get("helpers"):
        calls += _check_helpers(sensor, case, s, l)
    return {"calls": calls}


def _check_helpers(sensor, case, s, l) -> int:
    import planet_intersect as pi

    dsm = _dsm(case["dsm"])
    nl, npx = sensor.shape
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        corners = sensor.footprint_corners(dsm)
    idx = np.array([0, npx - 1, (nl - 1) * npx + npx - 1, (nl - 1) * npx])
    ref = pi.intersect(dsm, s[idx], l[idx], method="exact")
    want = np.column_stack([ref.lat, ref.lon])
    want[~ref.hit] = np.nan
    if corners.shape != (4, 2) or not np.array_equal(corners, want, equal_nan=True):
        fail(f"footprint_corners {corners.tolist()} differ from intersect's corner hits {want.tolist()}")
    n_warn = sum(1 for w in caught if issubclass(w.category, RuntimeWarning) and "footprint_corners" in str(w.message))
    others = [w for w in caught if not (issubclass(w.category, RuntimeWarning)
                                        and "footprint_corners" in str(w.message))
              and not issubclass(w.category, (DeprecationWarning, ResourceWarning))]
    if others:
        fail(f"footprint_corners emitted {others[0].category.__name__}: {others[0].message}")
    if n_warn != int((~ref.hit).sum()):
        fail(f"footprint_corners: {n_warn} warnings for {int((~ref.hit).sum())} corners that miss")
    gsd = sensor.gsd(dsm)
    kc = nl // 2
    for name in ("across", "along"):
        v = np.asarray(gsd[name], dtype=float)
        if v.shape != (3,) or (np.isfinite(v) & ~(v > 0)).any():
            fail(f"gsd[{name!r}] = {v}: finite values must be positive")
    if npx > 1:
        c = (npx // 2)
        lo, hi = (c - 1, c + 1) if 0 < c < npx - 1 else (max(c - 1, 0), min(c + 1, npx - 1))
        pairs = [(0, 1), (lo, hi), (npx - 2, npx - 1)]
        pix = np.array([q for pr in pairs for q in pr])
        rr = pi.intersect(dsm, s[kc * npx + pix], l[kc * npx + pix], method="exact")
        p = np.where(rr.hit[:, None], rr.p, np.nan)
        want = np.array([np.linalg.norm(p[2 * t + 1] - p[2 * t]) / (pairs[t][1] - pairs[t][0]) for t in range(3)])
        got = np.asarray(gsd["across"], dtype=float)
        # the sensor's pixel_rays go through intersect in other groups (exact: within 1e-6 m per hit)
        if not (np.array_equal(np.isnan(got), np.isnan(want))
                and np.all(np.abs(got - want)[np.isfinite(want)] <= 1e-9 * want[np.isfinite(want)] + 4e-6)):
            fail(f"gsd across {got.tolist()}, chords of intersect's hits {want.tolist()}")
    return 3


# ---------------------------------------------------------------------------- simulate
SIM_SPOILS = {
    "method": ["Exact", "stepping", "", None, 1],
    "walls": ["Interpolate", "none", None],
    "shading": ["Lambert", "phong", None],
    "sun": ["none_lambert", [1.0, 2.0, 3.0, 4.0], [math.nan, 10.0], [0.0, 0.0, 0.0], [10.0, 95.0], "north",
            "sun_no_lambert"],
    "ambient": [-0.1, 1.5, math.nan, "0.2", "no_lambert"],
    "fill": [1e39, "x", None, [1.0]],
    "occlusion": ["yes", 1, None],
    "wall_slope": [0.0, 90.0, math.nan, -5.0, "60"],
    "roof_min": [math.nan, math.inf, "2"],
    "ground_window": [0.0, -1.0, math.nan],
    "ground": ["shape", "strings", "other_ellipsoid"],
    "block_lines": [0, -1, 1.5, True, "2"],
    "threads": [-1, 1.5, "2", True, 2**31],
    "out": ["exists", "file"],
    "dsm": ["array", None, "ortho"],
    "ortho": ["array", "dsm"],
    "sensor": ["tuple", "ellipsoid", "inside"],
}


def simulate_case(r: R, seed: int) -> dict:
    dsm = scene_dsm_spec(r)
    ortho = ortho_spec(r, dsm)
    sensor = sensor_spec(r, dsm)
    kw = {}
    kw["method"] = r.pick(["exact", "exact", "exact", "following", "iterative"])
    if r.chance(0.5):
        kw["walls"] = r.pick(["interpolate", "ortho"])
    if r.chance(0.3):
        kw["shading"] = "lambert"
        kw["sun"] = r.pick([[r.float(0, 360), r.float(-10, 90)], (r.g.standard_normal(3) * 1e8).tolist()])
        if r.chance(0.6):
            kw["ambient"] = r.pick([0.0, 1.0, r.float(0, 1)])
    if r.chance(0.5):
        kw["fill"] = r.pick([0.0, -1.0, math.nan, 255.5, -3.4e38, math.inf])
    kw["occlusion"] = r.chance(0.4)
    if r.chance(0.2):
        kw["ground"] = r.pick(["array", "dsm"])
    if r.chance(0.2):
        kw["ground_window"] = r.pick([1.0, 10.0, 1e6])
    if r.chance(0.2):
        kw["wall_slope"] = r.float(1.0, 89.0)
    if r.chance(0.2):
        kw["roof_min"] = r.pick([0.0, -1.0, 0.5, 50.0])
    if r.chance(0.5):
        kw["threads"] = r.pick([None, 1, 2])
    if r.chance(0.5):
        kw["block_lines"] = r.pick([1, 2, 3, 100])
    case = {"op": "simulate", "dsm": dsm, "ortho": ortho, "sensor": sensor, "kwargs": kw,
            "names": SIM_NAMES, "files": True, "must_succeed": True,
            "variant": r.pick(["threads", "block_lines", "out", "out", "none"]),
            "save": r.pick([".png", ".tif", ".nc"]) if r.chance(0.04) else None,
            "xarray": r.chance(0.04)}
    if r.chance(0.2):
        arg = r.pick(sorted(SIM_SPOILS))
        val = r.pick(SIM_SPOILS[arg])
        case["spoil"] = (arg, val)
        case["must_succeed"] = False
        case["names"] = [arg]
        case["variant"] = "none"
        if arg in ("sun", "ambient"):
            case["names"] = ["sun", "ambient", "shading"]
        if arg == "sensor":
            case["names"] = ["sensor", "s"]
        if arg == "out":
            case["names"] = ["out"]
    return case


def _bilinear_ref(spec_o, values, lat, lon):
    """The contract's bilinear sample (written from DESIGN 9 / the docstring): between pixel
    centres, the edge pixels' values over the image's outer half pixel (its pixels are areas,
    simulation-notes note 16), NaN beyond its bounds or where a needed pixel has no data;
    longitudes within 180 deg of the grid's centre. Returns (value (N[, bands]), near_edge (N,)
    where rounding decides)."""
    v = np.asarray(values, dtype=float)
    nr, nc = v.shape[:2]
    lat_first, lon_first, dlat, dlon = spec_o
    u = (lat - lat_first) / dlat
    lon_c = lon_first + 0.5 * (nc - 1) * dlon
    w = np.mod(lon - lon_c + 180.0, 360.0) - 180.0
    vv = (w + (lon_c - lon_first)) / dlon
    eps = 1e-6
    near = ((np.abs(u + 0.5) < eps) | (np.abs(u - (nr - 0.5)) < eps) | (np.abs(vv + 0.5) < eps)
            | (np.abs(vv - (nc - 0.5)) < eps))
    inside = (u >= -0.5) & (u <= nr - 0.5) & (vv >= -0.5) & (vv <= nc - 0.5)
    uu = np.where(inside, np.clip(u, 0.0, nr - 1), 0.0)
    vw = np.where(inside, np.clip(vv, 0.0, nc - 1), 0.0)
    i = np.clip(np.floor(uu).astype(int), 0, max(nr - 2, 0))
    j = np.clip(np.floor(vw).astype(int), 0, max(nc - 2, 0))
    fu, fv = uu - i, vw - j
    i1, j1 = np.minimum(i + 1, nr - 1), np.minimum(j + 1, nc - 1)
    # at an integer coordinate one of the two neighbours has weight 0: whether its no-data counts
    # is a convention (and rounding decides which neighbour pair is used): skipped
    nanny = np.zeros(i.shape, dtype=bool)
    for di in (-1, 0, 1, 2):                   # the 4 x 4 pixels around: either neighbour pair may be used
        for dj in (-1, 0, 1, 2):
            x = ~np.isfinite(v[np.clip(i + di, 0, nr - 1), np.clip(j + dj, 0, nc - 1)])
            nanny |= x.any(axis=-1) if v.ndim == 3 else x
    frac_edge = (np.minimum(fu, 1 - fu) < eps) | (np.minimum(fv, 1 - fv) < eps)
    near |= nanny & frac_edge
    if v.ndim == 3:
        fu, fv, ins = fu[:, None], fv[:, None], inside[:, None]
    else:
        ins = inside
    with np.errstate(invalid="ignore"):
        out = (1 - fu) * ((1 - fv) * v[i, j] + fv * v[i, j1]) + fu * ((1 - fv) * v[i1, j] + fv * v[i1, j1])
    return np.where(ins, out, np.nan), near, u, vv


def _sim_arrays(res):
    names = ["image", "valid", "lat", "lon", "height", "distance", "incidence", "local_incidence", "surface",
             "status", "p", "ortho_value", "occlusion", "footprint"]
    return {k: getattr(res, k) for k in names}


def _same(r1, r2, what):
    a, b = _sim_arrays(r1), _sim_arrays(r2)
    for k in a:
        x, y = a[k], b[k]
        if x is None or y is None:
            if (x is None) != (y is None):
                fail(f"{what}: {k} is None in one result only")
            continue
        x, y = np.asarray(x), np.asarray(y)
        if x.shape != y.shape or x.dtype != y.dtype or not np.array_equal(x, y, equal_nan=x.dtype.kind == "f"):
            bad = ~((x == y) | (np.isnan(x) & np.isnan(y))) if x.dtype.kind == "f" and x.shape == y.shape \
                else (x != y) if x.shape == y.shape else None
            where = np.argwhere(bad)[:3].tolist() if bad is not None else "shape"
            fail(f"{what}: {k} differs (at {where})")


def _run_sim(dsm, ortho, sensor, kw):
    """simulate_image with its documented UserWarning recorded: (res, n_novalue_warnings)."""
    import planet_intersect as pi

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = pi.simulate_image(dsm, ortho, sensor, **kw)
    n = 0
    for w in caught:
        if issubclass(w.category, (DeprecationWarning, ResourceWarning)):
            continue
        if issubclass(w.category, UserWarning) and NOVALUE_WARNING in str(w.message):
            n += 1
            continue
        fail(f"a {w.category.__name__} was emitted: {w.message} ({os.path.basename(w.filename)}:{w.lineno})")
    return res, n


def _spoiled_call(case, dsm, ortho, sensor, kw, tmp):
    import planet_intersect as pi

    arg, val = case["spoil"]
    kw = dict(kw)
    if arg == "sun":
        if val == "none_lambert":
            kw.update(shading="lambert")
            kw.pop("sun", None)
        elif val == "sun_no_lambert":
            kw["shading"] = "none"
            kw.pop("ambient", None)
            kw["sun"] = [10.0, 40.0]
        else:
            kw.update(shading="lambert", sun=val)
    elif arg == "ambient":
        if val == "no_lambert":
            kw["shading"] = "none"
            kw.pop("sun", None)
            kw["ambient"] = 0.5
        else:
            kw.update(shading="lambert", sun=[0.0, 45.0], ambient=val)
    elif arg == "ground":
        if val == "shape":
            kw["ground"] = np.zeros((dsm.nrows + 1, dsm.ncols))
        elif val == "strings":
            kw["ground"] = np.full((dsm.nrows, dsm.ncols), "x")
        else:
            kw["ground"] = pi.GeodeticDSM.from_array(np.zeros((2, 2)), dsm.lat_first, dsm.lon_first, dsm.dlat,
                                                     dsm.dlon, a=dsm.a * 1.001, f=dsm.f)
    elif arg == "out":
        d = _new_path(tmp, "out")
        if val == "exists":
            d.mkdir()
        else:
            d.write_bytes(b"x")
        kw["out"] = str(d)
    elif arg == "dsm":
        dsm = {"array": np.zeros((3, 3)), "ortho": ortho}.get(val)
    elif arg == "ortho":
        ortho = {"array": np.zeros((3, 3)), "dsm": dsm}.get(val)
    elif arg == "sensor":
        if val == "tuple":
            sensor = sensor.rays()
        elif val == "ellipsoid":
            sp = dict(case["sensor"], kind="orbit", altitude=7e5, inclination=90.0, npixels=2, nlines=1,
                      ifov=1e-4, lat=dsm.lat_first, lon=dsm.lon_first, omit_ellipsoid=False)
            for k in ("target", "look_angles", "line_period"):
                sp.pop(k, None)
            sp["a"] = dsm.a * (1.0 + 1e-6)
            sensor = build_sensor(sp)
        else:                                            # a focal point 50 m below a cell with data
            s, l = sensor.rays(0, 1)
            h = np.asarray(dsm.heights, dtype=float)
            ok = np.isfinite(h)
            pad = np.pad(ok, 1, constant_values=True)
            for di in (0, 1, 2):                         # (bilinear: its neighbours too)
                for dj in (0, 1, 2):
                    ok = ok & pad[di:di + h.shape[0], dj:dj + h.shape[1]]
            if ok.any():
                i, j = np.argwhere(ok)[0]
                hc = h[i, j]
            else:
                # no node with data all round (a tiny grid with holes): a node where the package's own
                # surface has data (a node beside a no-data node may have none there: a focal point under
                # it is not inside, and simulate_image rightly took it; seed 7304)
                ii, jj = np.nonzero(np.isfinite(h))
                hh = dsm.height(dsm.lat_first + dsm.dlat * ii, dsm.lon_first + dsm.dlon * jj)
                good = np.flatnonzero(np.isfinite(hh))
                if not good.size:
                    # every bilinear cell has a no-data node (a 5 x 2 grid with holes): no point is
                    # inside the surface, so there is no such spoil to make; the call must then work
                    return "no spoil"
                k = int(good[0])
                i, j, hc = ii[k], jj[k], hh[k]
            c = _ecef(dsm.lat_first + dsm.dlat * i, dsm.lon_first + dsm.dlon * j, hc - 50.0, dsm.a, dsm.f)
            sensor = pi.Pushbroom(c[None, :], -np.asarray(l[:1])[None, :, :])
    else:
        kw[arg] = val
    return pi.simulate_image(dsm, ortho, sensor, **kw)


_COUNTER = [0]


def _step_limit_rays(sensor, st):
    """(s, l) of the pixels whose status is STEP_LIMIT (14), as float64 rows."""
    s, l = sensor.rays()
    k = np.flatnonzero(np.asarray(st).ravel() == 14)
    return np.asarray(s, dtype=np.float64)[k], np.asarray(l, dtype=np.float64)[k]


def _near_axis_only(sensor, st, dsm) -> bool:
    """True when every STEP_LIMIT pixel's ray passes within 1e-6 a of the polar axis: the exact
    mode's documented gap (docs/shin-park-notes.md, "The chord rule near the poles": nadir rays
    between polar_box's 1e-9 a and the chord rule's 1e-6 a of the axis may end STEP_LIMIT). Seen
    by this family on 2026-12-03: a nadir ray 1.55 m from Mars's pole down a column boundary."""
    s, l = _step_limit_rays(sensor, st)
    lu = l / np.linalg.norm(l, axis=1, keepdims=True)
    # the closest approach of s + t lu (0 <= t <= |s| + a) to the axis, in closed form: it was the
    # least of 2,001 samples over that length (one per ~6 km on Earth), which missed a ray passing
    # 5.8 m from the south pole at the surface (the family, seed 7480, 2026-12-04)
    t_max = np.linalg.norm(s, axis=1) + dsm.a
    h2 = lu[:, 0] ** 2 + lu[:, 1] ** 2
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.where(h2 > 0, -(s[:, 0] * lu[:, 0] + s[:, 1] * lu[:, 1]) / h2, 0.0)
    t = np.clip(t, 0.0, t_max)
    d = np.hypot(s[:, 0] + t * lu[:, 0], s[:, 1] + t * lu[:, 1])
    return bool(np.all(d <= 1e-6 * dsm.a * 1.01))


def _on_node_line_by_nodata(sensor, st, dsm) -> bool:
    """True when every STEP_LIMIT pixel's ray lies in the meridian half-plane of one of a bilinear
    DSM's node columns (to rounding: 1e-9 cells, 1e-14 relative) with a no-data node in that column or a neighbour: the
    exact mode's documented flicker (docs/shin-park-notes.md, "Still STEP_LIMIT": the points of a
    ray on a node line round to either side of it, so the lookup flips between a data cell and a
    no-data cell and every box of the search holds the no-data one). Seen by this family on
    2026-12-05 (seed 7500): a nadir sensor 10 m from Mars's south pole exactly on a column's
    centre meridian, its N-S line of rays down that node line; the build of 2026-12-04 (b49f058)
    gives the same STEP_LIMIT."""
    s, l = _step_limit_rays(sensor, st)
    return bool(_rays_on_node_column_by_nodata(s, l, dsm).all())


def _rays_on_node_column_by_nodata(s, l, dsm) -> np.ndarray:
    """Per ray (s, l rows): it lies in the meridian half-plane of one of a bilinear DSM's node
    columns (1e-9 cells, 1e-14 relative) with a no-data node in that column or a neighbour. On such a
    line the lookup puts the ray's points on either side by rounding, over the data cell or the
    no-data one, so the answer (HIT, NO_DATA, LEFT_DSM or STEP_LIMIT) may depend on which points a
    search evaluates: a line sweep and the same ray alone may differ (seed 7591: a nadir pixel
    1.4e-10 cells west of a node column, HIT over the data cell in the image, NO_DATA 1.27 m earlier
    over the no-data cell from intersect; shin-park-notes note 20)."""
    out = np.zeros(len(s), dtype=bool)
    if dsm.interpolation != "bilinear" or dsm.ncols * abs(dsm.dlon) >= 359.0:
        return out
    h = np.asarray(dsm.heights, dtype=np.float64)
    if dsm.nodata is not None:
        h = np.where(h == dsm.nodata, np.nan, h)
    for k, (sk, lk) in enumerate(zip(s, l)):
        rho = np.hypot(sk[0], sk[1])
        if not rho > 0:
            continue
        lon = np.degrees(np.arctan2(sk[1], sk[0]))
        u = ((lon - dsm.lon_first) / dsm.dlon) % (360.0 / abs(dsm.dlon))
        j = int(round(u))
        if not (abs(u - j) <= 1e-9 and 0 <= j < dsm.ncols):
            continue
        lam = np.radians(dsm.lon_first + j * dsm.dlon)
        east = np.array([-np.sin(lam), np.cos(lam), 0.0])
        lu = lk / np.linalg.norm(lk)
        if not (abs(east @ sk) <= 1e-14 * np.linalg.norm(sk) and abs(east @ lu) <= 1e-14):
            continue
        out[k] = bool(np.isnan(h[:, max(j - 1, 0):j + 2]).any())
    return out


def _new_path(tmp, stem, suffix=""):
    from pathlib import Path

    _COUNTER[0] += 1
    return Path(tmp) / f"sim-{os.getpid()}-{_COUNTER[0]}-{stem}{suffix}"


def op_simulate(case, tmp):
    import planet_intersect as pi
    from references.geodesy import ecef_to_geodetic

    dsm = _dsm(case["dsm"])
    ortho = make_ortho(case["ortho"])
    try:
        sensor = build_sensor(case["sensor"])
    except ValueError as exc:
        # the generator's orbit cannot point at its target (a high-latitude target, an inclination
        # and pointing that do not reach it): the sensor family judges that error; no scene here
        if str(exc).startswith("target = ") and "no orbit" in str(exc):
            return {"calls": 1}
        raise
    kw = dict(case["kwargs"])
    if kw.get("ground") == "array":
        kw["ground"] = np.minimum(np.nan_to_num(np.asarray(dsm.heights), nan=0.0), case["dsm"]["base"])
    elif kw.get("ground") == "dsm":
        kw["ground"] = pi.GeodeticDSM.from_array(np.full((dsm.nrows, dsm.ncols), case["dsm"]["base"]),
                                                 dsm.lat_first, dsm.lon_first, dsm.dlat, dsm.dlon,
                                                 a=dsm.a, f=dsm.f, interpolation="nearest")
    if "spoil" in case:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            got = _spoiled_call(case, dsm, ortho, sensor, kw, tmp)
        arg, val = case["spoil"]
        if isinstance(got, str) and got == "no spoil":
            return {"calls": 0}
        fail(f"simulate_image accepted {arg} = {val!r}")
    res, n_warn = _run_sim(dsm, ortho, sensor, kw)
    calls = 1
    nl, npx = sensor.shape
    method = kw.get("method", "exact")
    fill = float(kw.get("fill", 0.0))
    bands = ortho.bands
    # shapes and dtypes
    ishape = (nl, npx) if bands == 1 else (nl, npx, bands)
    want = {"image": (ishape, np.float32), "valid": ((nl, npx), np.bool_), "surface": ((nl, npx), np.int8),
            "status": ((nl, npx), np.int8), "p": ((nl, npx, 3), np.float64), "ortho_value": ((nl, npx), np.bool_)}
    for k in ("lat", "lon", "height", "distance", "incidence", "local_incidence"):
        want[k] = ((nl, npx), np.float64)
    for k, (shape, dt) in want.items():
        x = np.asarray(getattr(res, k))
        if x.shape != shape or x.dtype != dt:
            fail(f"sim.{k}: shape {x.shape} dtype {x.dtype}, documented {shape} {np.dtype(dt)}")
    st = np.asarray(res.status)
    valid = np.asarray(res.valid)
    odd = sorted(set(st.ravel().tolist()) - SIM_STATUSES[method])
    if odd == [14] and method == "exact" and (_near_axis_only(sensor, st, dsm)
                                               or _on_node_line_by_nodata(sensor, st, dsm)):
        odd = []            # the documented gaps: near the polar axis, down a node line beside no data
    if odd:
        fail(f"method={method!r}: status {odd} is not one it may return")
    if not np.array_equal(valid, (st == 0) | (st == 3)):
        fail("valid differs from status in (HIT, HIT_UNCONVERGED)")
    surf = np.asarray(res.surface)
    if not np.isin(surf, [-1, 0, 1, 2]).all():
        fail(f"surface codes {sorted(set(surf.ravel().tolist()))}")
    if not np.array_equal(surf == -1, ~valid):
        fail("surface is -1 where valid, or not -1 where not valid")
    img = np.asarray(res.image, dtype=np.float64)
    img_px = img if img.ndim == 3 else img[..., None]
    inv = ~valid
    fill32 = float(np.float32(fill))
    if inv.any():
        vals = img_px[inv]
        ok = np.isnan(vals) if math.isnan(fill) else vals == fill32
        if not ok.all():
            fail(f"an invalid pixel's image value is {vals[~ok][0]!r}, fill is {fill!r}")
        for k in ("lat", "lon", "height", "distance", "incidence", "local_incidence"):
            if not np.isnan(np.asarray(getattr(res, k))[inv]).all():
                fail(f"sim.{k} is not NaN where the ray did not hit (status {st[inv].tolist()})")
        if not np.isnan(np.asarray(res.p)[inv]).all():
            fail("sim.p is not NaN where the ray did not hit")
        if np.asarray(res.ortho_value)[inv].any():
            fail("ortho_value True on a pixel that did not hit")
    lat, lon = np.asarray(res.lat), np.asarray(res.lon)
    hgt, dist = np.asarray(res.height), np.asarray(res.distance)
    p = np.asarray(res.p)
    if valid.any():
        vl, vo = lat[valid], lon[valid]
        if not (np.isfinite(vl).all() and (np.abs(vl) <= 90).all() and (vo >= -180).all() and (vo < 180).all()):
            fail(f"hit lat/lon out of range: {vl.tolist()[:4]}, {vo.tolist()[:4]}")
        if not (dist[valid] > 0).all() or not np.isfinite(hgt[valid]).all() or not np.isfinite(p[valid]).all():
            fail("a hit with a non-positive distance or non-finite height/p")
        for k in ("incidence", "local_incidence"):
            x = np.asarray(getattr(res, k))[valid]
            if not (np.isfinite(x).all() and (x >= 0).all() and (x <= 180).all()):
                fail(f"sim.{k} outside [0, 180] on a hit: {x.tolist()[:4]}")
    # against pi.intersect on the sensor's own rays
    s, l = sensor.rays()
    ref = pi.intersect(dsm, s, l, method=method)
    calls += 1
    rst = np.asarray(ref.status).reshape(nl, npx)
    differ = (rst != st).ravel()
    flicker = np.zeros(nl * npx, dtype=bool)
    if differ.any() and method == "exact":
        # the documented ambiguity down a node column beside no-data: either answer is the lookup's
        flicker[differ] = _rays_on_node_column_by_nodata(np.asarray(s, dtype=float)[differ],
                                                         np.asarray(l, dtype=float)[differ], dsm)
        flicker &= np.isin(st.ravel(), (0, 9, 10, 14)) & np.isin(rst.ravel(), (0, 9, 10, 14))
    if (differ & ~flicker).any():
        k = np.unravel_index(int(np.flatnonzero(differ & ~flicker)[0]), (nl, npx))
        fail(f"pixel {tuple(int(x) for x in k)}: status {st[k]} in the image, {rst[k]} from intersect "
             f"(method {method})")
    hv = valid.ravel() & ~flicker & (rst.ravel() == st.ravel())
    if hv.any():
        rp = np.asarray(ref.p)[hv]
        rd = np.asarray(ref.distance)[hv]
        pv = p.reshape(-1, 3)[hv]
        dv = dist.ravel()[hv]
        sv = np.asarray(s)[hv]
        scale = np.maximum(np.linalg.norm(sv, axis=1), dsm.a)
        if method == "exact":
            tol = TOL_EXACT_SWEEP + 4 * np.spacing(scale)
            dd = np.abs(dv - rd)
            dp = np.linalg.norm(pv - rp, axis=1)
            far = (dd > tol) | (dp > tol)
            if far.any():
                # two different answers: legitimate only where the first entry is ill-conditioned (a ray
                # within rounding of a wall's plane, or a stay below the surface shorter than the contract's
                # 1e-6 m): then both must be valid exact answers by geo.py's reference checks (on the
                # surface within 2e-6 m; no sample before them 1e-5 m below the surface over a stay >= 1e-6 m)
                from types import SimpleNamespace

                from .geo import check_dsm_result

                kk = np.flatnonzero(far)
                ss, ll = np.asarray(s)[hv][kk], np.asarray(l, dtype=float)[hv][kk]
                z = np.zeros(len(kk), dtype=np.int8)
                for who, pp, d_, la_, lo_, hh_ in (
                        ("image", pv[kk], dv[kk], lat.ravel()[hv][kk], lon.ravel()[hv][kk], hgt.ravel()[hv][kk]),
                        ("intersect", rp[kk], rd[kk], np.asarray(ref.lat)[hv][kk], np.asarray(ref.lon)[hv][kk],
                         np.asarray(ref.height)[hv][kk])):
                    ns = SimpleNamespace(status=z, p=pp, distance=d_, lat=la_, lon=lo_, height=hh_,
                                         event_distance=np.full(len(kk), np.nan))
                    try:
                        with np.errstate(all="ignore"):
                            check_dsm_result(dsm, ss, ll, ns, "exact")
                    except _ops().PropertyViolation as exc:
                        k = int(np.argmax(np.maximum(dd - tol, dp - tol)))
                        fail(f"exact: a hit differs from intersect's by {dd[k]:.3g} in distance, {dp[k]:.3g} in "
                             f"p (tolerance {tol[k]:.3g}), and the {who}'s answer fails the reference: {exc}")
        else:
            for k_, x, y in (("p", pv, rp), ("distance", dv, rd), ("lat", lat.ravel()[hv], np.asarray(ref.lat)[hv]),
                             ("lon", lon.ravel()[hv], np.asarray(ref.lon)[hv]),
                             ("height", hgt.ravel()[hv], np.asarray(ref.height)[hv])):
                if not np.array_equal(x, y):
                    bad = np.flatnonzero(~np.all(np.reshape(x == y, (len(x), -1)), axis=1))
                    fail(f"{method}: {k_} differs from intersect's (bit for bit) on {bad.size} hit(s), e.g. "
                         f"{np.reshape(x, (len(x), -1))[bad[0]].tolist()} vs {np.reshape(y, (len(y), -1))[bad[0]].tolist()}")
        lu = np.asarray(l, dtype=float)[hv]
        lu = lu / np.max(np.abs(lu), axis=1)[:, None]
        lu = lu / np.linalg.norm(lu, axis=1)[:, None]
        off = np.linalg.norm(pv - (sv + dv[:, None] * lu), axis=1)
        if (off > TOL_ON_RAY * scale + 1e-6).any():
            fail(f"a hit is {off.max():.3g} off its ray (s + distance l)")
        gla, glo, gh = ecef_to_geodetic(pv, dsm.a, dsm.f)
        dlo = np.abs((lon.ravel()[hv] - glo + 180.0) % 360.0 - 180.0) * np.cos(np.radians(gla))
        if (np.abs(lat.ravel()[hv] - gla) > TOL_DEG).any() or (dlo > TOL_DEG).any() or \
                (np.abs(hgt.ravel()[hv] - gh) > 1e-9 * np.linalg.norm(pv, axis=1) + 1e-7).any():
            fail("a hit's lat/lon/height are not those of p (tests' geodesy)")
    # image values against the reference bilinear sample of the ortho
    ov = np.asarray(res.ortho_value)
    shading = kw.get("shading", "none")
    walls = kw.get("walls", "interpolate")
    if valid.any():
        refv, near, u_o, v_o = _bilinear_ref((ortho.lat_first, ortho.lon_first, ortho.dlat, ortho.dlon),
                                              ortho.values, lat[valid], lon[valid])
        refv = refv.reshape(-1, bands)
        has = np.isfinite(refv).all(axis=1)
        sv_ = surf[valid]
        ovv = ov[valid]
        iv = img_px[valid]
        vals = np.asarray(ortho.values, dtype=float).reshape(-1, bands)
        with warnings.catch_warnings():                  # an ortho band with no value at all: NaN (seed 7301)
            warnings.simplefilter("ignore", RuntimeWarning)
            vmin, vmax = np.nanmin(vals, axis=0), np.nanmax(vals, axis=0)
        vrange = np.where(np.isfinite(vmax - vmin), vmax - vmin, 0.0)
        plain = ((sv_ != 2) | (walls == "ortho")) & ~near
        if (plain & (ovv != has)).any():
            k = int(np.argmax(plain & (ovv != has)))
            fail(f"hit at ({lat[valid][k]!r}, {lon[valid][k]!r}) (surface {sv_[k]}): ortho_value {ovv[k]}, the "
                 f"reference sample there is {refv[k].tolist()} (ortho row/col {u_o[k]:.9g}, {v_o[k]:.9g})")
        # a band without a value gets fill (a multi-band pixel with one band missing keeps its other
        # bands and has ortho_value False)
        fin = np.isfinite(refv)
        miss = plain[:, None] & ~fin
        if miss.any():
            x = iv[miss]
            ok = np.isnan(x) if math.isnan(fill) else x == fill32
            if not ok.all():
                fail(f"a hit's band without an ortho value has image {x[~ok][0]!r}, fill {fill!r}")
        tol = 2.0 ** -23 * np.abs(refv) + 1e-7 * vrange[None, :] + 1e-30
        chk = plain[:, None] & fin
        if chk.any():
            if shading == "none":
                d = np.abs(iv[chk] - refv[chk])
                if (d > tol[chk]).any():
                    k = int(np.argmax(d - tol[chk]))
                    fail(f"image value {iv[chk][k]!r}, the reference bilinear ortho sample {refv[chk][k]!r} "
                         f"(walls {walls})")
            else:
                amb = float(kw.get("ambient", 0.0))
                lo_ = np.minimum(amb * refv[chk], refv[chk]) - tol[chk]
                hi_ = np.maximum(amb * refv[chk], refv[chk]) + tol[chk]
                if ((iv[chk] < lo_) | (iv[chk] > hi_)).any():
                    k = int(np.argmax((iv[chk] < lo_) | (iv[chk] > hi_)))
                    fail(f"lambert: image {iv[chk][k]!r} outside [{lo_[k]!r}, {hi_[k]!r}] (ortho {refv[chk][k]!r}, "
                         f"ambient {amb})")
        wall = (sv_ == 2) & (walls == "interpolate") & ovv
        if wall.any() and shading == "none":
            x = iv[wall]
            x = np.where(x == fill32, np.nan, x) if not math.isnan(fill) else x
            if ((x < vmin - 1e-7 * vrange - 2 ** -23 * np.abs(vmin)) |
                    (x > vmax + 1e-7 * vrange + 2 ** -23 * np.abs(vmax))).any():
                fail(f"wall value {x.tolist()[:3]} outside the ortho's range {vmin.tolist()}..{vmax.tolist()}")
    n_noval = int((valid & ~ov).sum())
    if res.meta.get("hits_without_ortho_value") != n_noval or (n_warn > 0) != (n_noval > 0):
        fail(f"{n_noval} hits without an ortho value; meta says {res.meta.get('hits_without_ortho_value')}, "
             f"{n_warn} warning(s)")
    # occlusion
    if kw.get("occlusion", True):
        occ, foot = res.occlusion, res.footprint
        if occ is None or foot is None:
            fail("occlusion=True but occlusion/footprint is None")
        occ, foot = np.asarray(occ), np.asarray(foot)
        if occ.shape != ortho.shape or foot.shape != ortho.shape or occ.dtype != bool or foot.dtype != bool:
            fail(f"occlusion {occ.shape} {occ.dtype} / footprint {foot.shape}, ortho grid {ortho.shape}")
        if (occ & ~foot).any():
            fail("an occluded ortho pixel outside the footprint")
        if valid.any():
            _, _, u_o, v_o = _bilinear_ref((ortho.lat_first, ortho.lon_first, ortho.dlat, ortho.dlon),
                                           ortho.values, lat[valid], lon[valid])
            iu, iv_ = np.rint(u_o), np.rint(v_o)
            tie = (np.abs(np.abs(u_o - np.floor(u_o)) - 0.5) < 1e-6) | (np.abs(np.abs(v_o - np.floor(v_o)) - 0.5) < 1e-6)
            ins = (iu >= 0) & (iu < ortho.shape[0]) & (iv_ >= 0) & (iv_ < ortho.shape[1]) & ~tie
            # (documented in _occlusion: every ortho pixel a hit lands on is in the footprint; it failed
            # when the image's border pixels missed the DSM, until a fix of 2026-12-03)
            if ins.any():
                miss = np.zeros_like(ins)
                idx = np.flatnonzero(ins)
                miss[idx] = ~foot[iu[idx].astype(int), iv_[idx].astype(int)]
                if miss.any():
                    k = int(np.argmax(miss))
                    fail(f"a hit lands on ortho pixel ({int(iu[k])}, {int(iv_[k])}) outside the footprint")
    elif res.occlusion is not None or res.footprint is not None:
        fail("occlusion=False but the masks were computed")
    # variants: bit-identical
    var = case.get("variant")
    if var == "threads":
        t = kw.get("threads")
        kw2 = dict(kw, threads=2 if t in (None, 1) else 1)
        res2, _ = _run_sim(dsm, ortho, sensor, kw2)
        _same(res, res2, f"threads {t} vs {kw2['threads']}")
        calls += 1
    elif var == "block_lines":
        b = kw.get("block_lines")
        kw2 = dict(kw, block_lines=1 if b != 1 else 2)
        res2, _ = _run_sim(dsm, ortho, sensor, kw2)
        _same(res, res2, f"block_lines {b} vs {kw2['block_lines']}")
        calls += 1
    elif var == "out":
        d = _new_path(tmp, "out")
        res2, _ = _run_sim(dsm, ortho, sensor, dict(kw, out=str(d)))
        _same(res, res2, f"out={d.name} vs in memory")
        if not isinstance(res2.image, np.memmap) or not (d / "image.npy").is_file():
            fail(f"out=: the image is a {type(res2.image).__name__}, not a memory map in {d}")
        try:
            _run_sim(dsm, ortho, sensor, dict(kw, out=str(d)))
        except FileExistsError as exc:
            if str(d) not in str(exc) and "out" not in str(exc):
                fail(f"out= an existing directory: the error names neither: {exc}")
        else:
            fail(f"out={d}: an existing directory was accepted (overwritten)")
        del res2
        import shutil

        shutil.rmtree(d, ignore_errors=True)
        calls += 2
    if case.get("save"):
        path = _new_path(tmp, "save", case["save"])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res.save(path)
        if not path.is_file() or path.stat().st_size == 0:
            fail(f"save({path.name}) wrote no file")
        size = path.stat().st_size
        try:
            res.save(path)
        except FileExistsError:
            pass
        else:
            fail(f"save({path.name}) overwrote an existing file")
        if path.stat().st_size != size:
            fail(f"save({path.name}) refused but changed the file")
        path.unlink()
        calls += 2
    if case.get("xarray"):
        ds = res.to_xarray()
        for k in ("image", "valid", "lat", "lon", "height", "distance", "surface", "status", "p"):
            if k not in ds:
                fail(f"to_xarray() lacks {k}")
        if ds["lat"].shape != (nl, npx):
            fail(f"to_xarray lat shape {ds['lat'].shape}")
        calls += 1
    return {"calls": calls}


# ---------------------------------------------------------------------------- ortho_from_array
def ortho_from_array_case(r: R, seed: int) -> dict:
    spec = ortho_spec(r, None, valid_only=False)
    case = {"op": "ortho_from_array", "ortho": spec, "names": ["values", "lat_first", "lon_first", "dlat", "dlon",
                                                                "nodata"], "must_succeed": "spoil" not in spec}
    if "spoil" in spec:
        arg = spec["spoil"][0]
        case["names"] = ["lat_first", "dlat"] if arg in ("lat_first", "dlat") else [arg]
        ok = _ortho_spoil_valid(spec)
        case["must_succeed"] = bool(ok)
        if ok is None:
            case["either"] = True
    return case


def op_ortho_from_array(case, tmp):
    import planet_intersect as pi

    spec = case["ortho"]
    args, kw = ortho_args(spec)
    src = args[0]
    keep = np.array(src, copy=True) if isinstance(src, np.ndarray) else None
    o = pi.OrthoImage.from_array(*args, **kw)
    if "spoil" in spec and not case.get("must_succeed") and not case.get("either"):
        fail(f"OrthoImage.from_array accepted {spec['spoil'][0]} = {spec['spoil'][1]!r}")
    v = np.asarray(o.values)
    if v.dtype != np.float64 or v.flags.writeable:
        fail(f"OrthoImage.values: dtype {v.dtype}, writeable {v.flags.writeable} (documented read-only float64)")
    if "spoil" in spec:
        return {"calls": 1}
    raw = np.asarray(keep, dtype=float)
    want = raw.copy()
    if "nodata" in spec:
        want[raw == spec["nodata"]] = np.nan
    if v.shape != want.shape or not np.array_equal(v, want, equal_nan=True):
        fail("OrthoImage.values differ from the array with NaN at nodata")
    if isinstance(src, np.ndarray):
        src.reshape(-1)[0] = 7 if src.dtype.kind in "iu" else 7.5
        if np.asarray(o.values).reshape(-1)[0] in (7.0, 7.5) and want.reshape(-1)[0] not in (7.0, 7.5):
            fail("OrthoImage keeps a view of the caller's array")
    nr, nc = spec["shape"]
    if tuple(o.shape) != (nr, nc) or o.bands != spec["bands"]:
        fail(f"OrthoImage shape {o.shape} bands {o.bands}")
    clat, clon = o.centres()
    la, lo = np.meshgrid(clat, clon, indexing="ij")
    got = np.asarray(o.sample(la.ravel(), lo.ravel())).reshape(want.shape)
    fin = np.isfinite(want) if want.ndim == 2 else np.isfinite(want).all(axis=2)
    pad = np.pad(fin, 1, constant_values=True)
    full = np.ones_like(fin)
    for di in (0, 1, 2):
        for dj in (0, 1, 2):
            full &= pad[di:di + nr, dj:dj + nc]
    # the centres' coordinates are rounded: a grid coordinate off by ~8 eps (450 + |lon|) / spacing
    # moves a bilinear value by that many cells times the largest step between neighbours (as geo.py)
    cells = 8 * 2.2e-16 * (450.0 + abs(o.lon_first)) / min(abs(o.dlat), o.dlon)
    fw = np.where(np.isfinite(want), want, 0.0)
    step = max(np.abs(np.diff(fw, axis=0)).max(initial=0.0), np.abs(np.diff(fw, axis=1)).max(initial=0.0))
    w = want[full]
    gg = got[full]
    tol = 1e-12 * np.abs(w) + 2 * step * cells
    if not (np.abs(gg - w) <= tol).all():
        k = int(np.argmax(~(np.abs(gg - w) <= tol)))
        fail(f"sample at a pixel centre gives {np.ravel(gg)[k]!r}, the image holds {np.ravel(w)[k]!r}")
    return {"calls": 2}


OPS = {"sensor": op_sensor, "simulate": op_simulate, "ortho_from_array": op_ortho_from_array}
GENERATORS = {"sensor": sensor_case, "simulate": simulate_case, "ortho_from_array": ortho_from_array_case}
