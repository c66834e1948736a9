"""What a fuzz case does, run inside the worker process (tests/fuzzing/worker.py).

A *case* is a plain dict (picklable, printable) with an ``op`` key:

* ``from_array``  build a DEM from a described array (``dem`` spec below)
* ``read``        write a generated ``.hdr``/``.dem`` pair, then ``DEM.read`` it
* ``radius``      ``dem.radius(lat, lon)``
* ``intersect``   ``intersect(dem, s, l, **kwargs)`` and, for valid input, the
                  same rays through every configuration (methods, read modes,
                  io paths, threads), which must agree
* ``detector``    ``detector_los(l0, q, nh, nv, dh, dv)``
* ``cli_run``     ``planet-intersect run DEM RAYS`` on a generated rays file

:func:`run_case` performs it and checks the properties of a normal result,
raising :class:`PropertyViolation` when one fails. Exceptions raised by the
package propagate to the worker, which reports them; the parent judges
whether they are clear (tests/fuzzing/harness.py).

DEM spec (``case["dem"]``): ``{"ppd", "base", "rough", "seed", "spikes", "f",
"re", "rmax", "dtype"}``: radii = ``base`` (+ seeded normal noise of standard
deviation ``rough``), then ``radii[j, i] = v`` for each ``(j, i, v)`` in
``spikes`` (row/column taken modulo the grid).
"""

from __future__ import annotations

import contextlib
import io as _io
import math
import os
import tempfile
import warnings
from pathlib import Path

import numpy as np

import planet_intersect as pi
from planet_intersect.geometry import latlon_of

#: stated tolerances of the properties (fractions of rmax unless said)
TOL_SURFACE_STEPPING = 1e-9   # | |p| - dem.radius(lat, lon) |, status 0, stepping (core criterion 1e-12)
TOL_SURFACE_EXACT = 1e-6      # same, method="exact" (1e-9 rmax along the ray times the local slope)
TOL_LATLON_DEG = 1e-9         # lat/lon of p against atan2 of p
TOL_RADIUS_REL = 1e-12        # res.radius against |p|

ALLOWED_STATUS = {0, 1, 2, 3}


class PropertyViolation(AssertionError):
    """A result that came back without an exception but breaks a stated property."""


def fail(msg: str):
    raise PropertyViolation(msg)


# ---------------------------------------------------------------------------- DEMs
def dem_array(spec: dict) -> np.ndarray:
    """The radii array a DEM spec describes (float64, or the spec's dtype)."""
    ppd = int(spec.get("ppd", 1))
    shape = spec.get("shape") or (180 * ppd, 360 * ppd)
    base = spec.get("base", 3390.0)
    rough = spec.get("rough", 0.0)
    dtype = np.dtype(spec.get("dtype", "float64"))
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if rough:
            a = np.random.default_rng(spec.get("seed", 0)).normal(base, rough, shape)
        else:
            a = np.full(shape, base, dtype=np.float64)
        if a.size and a.ndim == 2:
            for j, i, v in spec.get("spikes", ()):
                a[j % a.shape[0], i % a.shape[1]] = v
        a = a.astype(dtype)
    return a


def dem_kwargs(spec: dict) -> dict:
    kw = {}
    for k in ("f", "re", "rmax"):
        if k in spec:
            kw[k] = spec[k]
    if kw.get("f", 0.0) == 0.0 and kw.get("re") == 1.0:
        # Table 1's "no spheroid" setting, said by leaving re out: given explicitly, DEM.from_array
        # warns that it is that setting (paper-notes 20), the same DEM either way
        del kw["re"]
    return kw


#: the bulk mode (bulk.py) sets a dict here: DEMs are then reused across cases by spec
#: (a DEM is immutable, so a cached one behaves as a fresh one); None: a new DEM per case
DEM_CACHE = None


def make_dem(spec: dict) -> pi.DEM:
    if DEM_CACHE is None:
        return pi.DEM.from_array(dem_array(spec), **dem_kwargs(spec))
    key = repr(sorted(spec.items()))
    dem = DEM_CACHE.get(key)
    if dem is None:
        dem = DEM_CACHE[key] = pi.DEM.from_array(dem_array(spec), **dem_kwargs(spec))
    return dem


def write_pair(stem: Path, header: bytes, data: bytes) -> Path:
    hdr = stem.with_suffix(".hdr")
    hdr.write_bytes(header)
    stem.with_suffix(".dem").write_bytes(data)
    return hdr


# ---------------------------------------------------------------------------- checks
def _finite(x) -> bool:
    return bool(np.all(np.isfinite(x)))


def _allnan(x) -> bool:
    return bool(np.all(np.isnan(x)))


def check_result(dem: pi.DEM, s, l, res, method: str) -> dict:
    """The properties every intersect result must have; returns counts by status."""
    with np.errstate(all="ignore"):        # the checks' own arithmetic on extreme inputs is not the package's
        return _check_result(dem, s, l, res, method)


def _norm(v) -> float:
    """|v| without overflow or underflow for any finite v."""
    v = np.asarray(v, dtype=np.float64)
    m = float(np.abs(v).max())
    return m * float(np.linalg.norm(v / m)) if m > 0 and math.isfinite(m) else float(np.linalg.norm(v))


def _check_result(dem, s, l, res, method):
    s = np.broadcast_to(np.asarray(s, dtype=np.float64).reshape(-1, 3), (len(res), 3)) if len(res) else s
    l = np.broadcast_to(np.asarray(l, dtype=np.float64).reshape(-1, 3), (len(res), 3)) if len(res) else l
    status = np.asarray(res.status)
    bad = sorted(set(status.tolist()) - ALLOWED_STATUS)
    if bad:
        fail(f"status codes {bad} returned without an exception (rays {np.flatnonzero(np.isin(status, bad))[:5]})")
    hit = (status == 0) | (status == 3)
    if not np.array_equal(res.hit, hit):
        fail("res.hit disagrees with res.status")
    rmax = dem.rmax
    radii = dem.radii64()
    rmin_dem, rmax_dem = float(radii.min()), float(radii.max())
    irregular = dem.f == 0.0 and dem.re == 1.0
    surface = ("lat", "lon", "radius", "altitude", "emission")
    tangent = ("tangent_lat", "tangent_lon", "tangent_altitude", "tangent_height")
    for k in np.flatnonzero(hit):
        p = res.p[k]
        where = f"ray {k} (status {status[k]}, s={s[k].tolist()}, l={l[k].tolist()}, method={method})"
        if not (_finite(p) and _finite([res.lat[k], res.lon[k], res.radius[k], res.emission[k]])):
            fail(f"{where}: hit with non-finite p/lat/lon/radius/emission: p={p.tolist()}")
        pn = _norm(p)
        if abs(res.radius[k] - pn) > TOL_RADIUS_REL * pn:
            fail(f"{where}: res.radius {res.radius[k]!r} != |p| {pn!r}")
        lat, lon = latlon_of(p)
        dlon = abs((lon[0] - res.lon[k] + 180.0) % 360.0 - 180.0)
        if abs(lat[0] - res.lat[k]) > TOL_LATLON_DEG or dlon > TOL_LATLON_DEG or not 0 <= res.lon[k] < 360:
            fail(f"{where}: lat/lon {res.lat[k]!r}, {res.lon[k]!r} are not those of p ({lat[0]!r}, {lon[0]!r})")
        # on the ray, in front of the spacecraft (s is known to eps |s| only)
        lu = l[k] / np.abs(l[k]).max()
        lu = lu / _norm(lu)
        dp = p - s[k]
        slack = 1e-9 * rmax + 8 * np.finfo(float).eps * _norm(s[k])
        if _norm(np.cross(dp / _norm(dp), lu)) * _norm(dp) > slack + 1e-12 * _norm(dp) or dp @ lu < -slack:
            fail(f"{where}: hit point p={p.tolist()} is not on the ray ahead of s")
        if not (0.0 <= res.emission[k] <= 180.0):
            # against the spheroid normal: a grazing ray that rises into the side of a hill
            # after passing its lowest point enters the surface at more than 90 degrees
            fail(f"{where}: emission {res.emission[k]!r} deg outside [0, 180]")
        if status[k] == 0:
            r_dem = float(dem.radius(res.lat[k], res.lon[k]))
            tol = (TOL_SURFACE_EXACT if method == "exact" else TOL_SURFACE_STEPPING) * rmax
            if abs(pn - r_dem) > tol:
                fail(f"{where}: hit not on the surface: |p| = {pn!r}, dem.radius(lat, lon) = {r_dem!r}, "
                     f"difference {pn - r_dem:.3g} > {tol:.3g}")
        elif not (rmin_dem * (1 - 1e-9) <= pn <= rmax * (1 + 1e-9)):
            fail(f"{where}: unconverged hit at |p| = {pn!r} outside [min radius, rmax] = [{rmin_dem!r}, {rmax!r}]")
        for name in tangent:
            if not np.isnan(getattr(res, name)[k]):
                fail(f"{where}: {name} = {getattr(res, name)[k]!r} for a hit (NaN expected)")
    for k in np.flatnonzero(~hit):
        where = f"ray {k} (status {status[k]}, s={s[k].tolist()}, l={l[k].tolist()}, method={method})"
        for name in surface:
            if not np.isnan(getattr(res, name)[k]):
                fail(f"{where}: {name} = {getattr(res, name)[k]!r} for a miss (NaN expected)")
        if not _allnan(res.p[k]):
            fail(f"{where}: p = {res.p[k].tolist()} for a miss (NaN expected)")
        # a ray that comes closer to the centre than the lowest radius of the DEM must hit it
        # (the surface is a radius field over the sphere of directions, never below its lowest node)
        lu = l[k] / np.abs(l[k]).max()
        lu = lu / _norm(lu)
        if s[k] @ lu < 0:
            closest = _norm(np.cross(s[k], lu))
            slack = 1e-9 * rmax_dem + 8 * np.finfo(float).eps * _norm(s[k])   # (the DEM's radii, not rmax)
            if method == "stepping":
                # the stepping mode tests the ray every delta-alpha <= 1/(2 ppd) deg seen from the
                # centre (eq. 23): a chord shallower than r_min (1 - cos(delta-alpha / 2)) can slip
                # between two test points (paper-notes note 14; the fuzz found one 6.6e-6 deep at
                # 1 pixel/degree, where the limit is 9.5e-6)
                slack = max(slack, 1.001 * rmin_dem * (1.0 - math.cos(math.radians(0.5 / dem.ppd) / 2.0)))
            if closest < rmin_dem - slack:
                fail(f"{where}: a miss whose line passes {closest!r} from the centre, below the DEM's lowest "
                     f"radius {rmin_dem!r} (by more than {slack:.3g}): it must hit")
        if status[k] == 1:
            need = ["tangent_altitude"] + ([] if irregular else ["tangent_lat", "tangent_lon", "tangent_height"])
            for name in need:
                if not np.isfinite(getattr(res, name)[k]):
                    fail(f"{where}: limb ray with non-finite {name} = {getattr(res, name)[k]!r}")
            if not _finite(res.tc[k]):
                fail(f"{where}: limb ray with non-finite tc = {res.tc[k].tolist()}")
            if not irregular and not _finite(res.sc[k]):
                fail(f"{where}: limb ray with non-finite sc = {res.sc[k].tolist()}")
        else:
            for name in tangent:
                if not np.isnan(getattr(res, name)[k]):
                    fail(f"{where}: {name} = {getattr(res, name)[k]!r} for a ray pointing away (NaN expected)")
    return {int(c): int((status == c).sum()) for c in np.unique(status)}


def _same(a, b) -> bool:
    return np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True)


def compare_results(r0, r1, what: str, fields=None):
    """Two results that the documentation says are bit-identical."""
    from dataclasses import fields as dfields

    np.seterr  # noqa: B018 - (comparisons below raise no floating-point warnings)

    names = fields or [f.name for f in dfields(r0)]
    for name in names:
        a, b = getattr(r0, name), getattr(r1, name)
        if not _same(a, b):
            idx = np.flatnonzero(~np.isclose(a, b, rtol=0, atol=0, equal_nan=True).reshape(len(r0), -1).all(axis=1))
            k = int(idx[0]) if idx.size else 0
            fail(f"{what}: {name} differs (ray {k}: {np.asarray(a)[k].tolist()} vs {np.asarray(b)[k].tolist()})")


# ---------------------------------------------------------------------------- ops
def op_from_array(case, tmp: Path):
    spec = case["dem"]
    radii = dem_array(spec)
    dem = pi.DEM.from_array(radii, **dem_kwargs(spec))
    # a valid DEM: its radii are the given ones, rmax covers them
    a = np.asarray(dem.radii, dtype=np.float64)
    if not np.array_equal(a, radii.astype(np.float64)):
        fail("DEM.from_array: radii differ from the array given")
    if not (np.isfinite(a).all() and (a >= 1e-100).all() and a.max() <= 1e100 and dem.rmax >= a.max()
            and a.min() >= 1e-6 * a.max()):
        fail(f"DEM.from_array accepted radii in [{a.min()!r}, {a.max()!r}] with rmax {dem.rmax!r}")
    # the DEM must not follow later changes to the caller's array
    before = dem.radius([0.0, 45.0, -89.9], [0.5, 100.0, 200.0])
    radii[...] = np.nan if radii.dtype.kind == "f" else 0
    after = dem.radius([0.0, 45.0, -89.9], [0.5, 100.0, 200.0])
    if not _same(before, after):
        fail("DEM.from_array: the DEM changed when the caller changed its array afterwards")
    return {"ppd": dem.ppd}


def make_special(path: Path, kind: str) -> None:
    """Put a directory, a FIFO, a symlink loop or a dangling symlink at ``path``."""
    if path.exists() or path.is_symlink():
        path.unlink()
    if kind == "dir":
        path.mkdir()
    elif kind == "fifo":
        os.mkfifo(path)
    elif kind == "loop":
        os.symlink(path.name, path)                 # a link to itself
    elif kind == "dangling":
        os.symlink(path.name + ".missing", path)


def _check_special_message(case, exc):
    """A special file is not missing: the message must not say so."""
    if case.get("special") in ("dir", "fifo", "loop") and "no such file" in str(exc).lower():
        fail(f"a {case['special']} given as {case['special_which']} is reported as missing: {exc}")


def op_read(case, tmp: Path):
    stem = tmp / case.get("name", "d")
    hdr = write_pair(stem, case["header"], case["data"])
    if case.get("special"):
        make_special(stem.with_suffix("." + case["special_which"]), case["special"])
        try:
            pi.DEM.read(hdr)
        except Exception as exc:  # noqa: BLE001 - judged here for the message, then by the parent
            _check_special_message(case, exc)
            raise
        fail(f"DEM.read accepted a {case['special']} as its .{case['special_which']} file")
    target = {"hdr": hdr, "dem": stem.with_suffix(".dem"), "stem": stem}[case.get("open", "hdr")]
    dem = pi.DEM.read(target)
    expect = case.get("expect")          # what a valid header means, or None when it must be refused
    if expect is None:
        fail(f"DEM.read accepted a header that must be refused: {case['why']}")
    for k in ("ppd", "rmax", "f", "re"):
        if getattr(dem, k) != expect[k]:
            fail(f"DEM.read: {k} = {getattr(dem, k)!r}, the header says {expect[k]!r}")
    want = np.frombuffer(case["data"], dtype=np.dtype(expect["dtype"]).newbyteorder(expect["byteorder"]))
    if not np.array_equal(np.asarray(dem.radii, dtype=np.float64).ravel(), want.astype(np.float64)):
        fail(f"DEM.read: radii are not the file's {expect['byteorder']}-endian {expect['dtype']} values")
    info = {"ppd": dem.ppd}
    rays = case.get("rays")
    if rays is not None:
        s, l = rays
        ref = pi.intersect(dem, s, l)
        check_result(dem, s, l, ref, "stepping")
        for mode, io in ((1, "records"), (1, "mmap")):
            r = pi.intersect(dem, s, l, dem_read_mode=mode, io=io)
            compare_results(ref, r, f"DEM.read then intersect, dem_read_mode={mode} io={io} vs mode 0")
        if case.get("shrink"):
            # the file shrinks after DEM.read: a clear DEMError, never SIGBUS
            with open(stem.with_suffix(".dem"), "r+b") as fh:
                fh.truncate(case["shrink"])
            for mode, io in ((0, "records"), (1, "records"), (1, "mmap")):
                try:
                    r = pi.intersect(dem, s, l, dem_read_mode=mode, io=io)
                except pi.DEMError as exc:
                    if str(stem) not in str(exc):
                        fail(f"file shrunk after DEM.read: DEMError does not name the file: {exc}")
                    continue
                if mode == 1:
                    fail(f"file shrunk after DEM.read: dem_read_mode=1 io={io} returned without an error")
                compare_results(ref, r, "file shrunk after DEM.read, dem_read_mode=0 (the grid was checked)")
    return info


def op_radius(case, tmp: Path):
    dem = make_dem(case["dem"])
    lat, lon = case["lat"], case["lon"]
    r = dem.radius(lat, lon)
    calls = 1
    la, lo = np.broadcast_arrays(np.asarray(lat, dtype=np.float64), np.asarray(lon, dtype=np.float64))
    if r.shape != la.shape:
        fail(f"dem.radius: shape {r.shape}, inputs broadcast to {la.shape}")
    a = dem.radii64()
    if r.size and not (np.isfinite(r).all() and (r >= a.min() * (1 - 1e-12)).all() and (r <= a.max() * (1 + 1e-12)).all()):
        fail(f"dem.radius: values {r.ravel()[:5].tolist()} outside the DEM's range [{a.min()!r}, {a.max()!r}]")
    if r.size:
        r2 = dem.radius(la, lo + 360.0)
        if not np.allclose(r, r2, rtol=1e-9, atol=0):
            fail(f"dem.radius: not periodic in longitude ({r.ravel()[:3].tolist()} vs {r2.ravel()[:3].tolist()})")
    if case.get("per_ray"):
        for a, b, want in zip(la.ravel(), lo.ravel(), r.ravel()):
            one = dem.radius(a, b)
            calls += 1
            if not _same(one, want):
                fail(f"dem.radius({a!r}, {b!r}) alone = {one!r}, in the array {want!r}")
    return {"n": int(r.size), "calls": calls + bool(r.size)}


CONFIGS = [  # (method, dem_read_mode, io, threads): all bit-identical for the same method
    ("stepping", 0, "records", 1), ("stepping", 0, "records", 2),
    ("stepping", 1, "records", 1), ("stepping", 1, "mmap", 2),
    ("exact", 0, "records", 1), ("exact", 1, "mmap", 1), ("exact", 1, "records", 2),
]


def op_intersect(case, tmp: Path):
    spec = case["dem"]
    dem = make_dem(spec)
    kwargs = dict(case.get("kwargs", {}))
    if kwargs.get("dem_read_mode") == 1 or case.get("all_configs"):
        dem.write(tmp / "dem", dtype=spec.get("file_dtype", "float64"), byteorder=spec.get("byteorder", "little"))
        dem = pi.DEM.read(tmp / "dem.hdr")
    s, l = case["s"], case["l"]
    res = pi.intersect(dem, s, l, **kwargs)
    method = kwargs.get("method", "stepping")
    counts = check_result(dem, s, l, res, method if isinstance(method, str) else "stepping")
    calls = 1
    if case.get("all_configs"):
        first = {}
        for m, mode, io, th in CONFIGS:
            r = pi.intersect(dem, s, l, method=m, dem_read_mode=mode, io=io, threads=th,
                             step_mode=kwargs.get("step_mode", 1), tangent=kwargs.get("tangent", "exact"))
            calls += 1
            if m not in first:
                first[m] = r
                check_result(dem, s, l, r, m)
            else:
                compare_results(first[m], r, f"method={m}, dem_read_mode={mode}, io={io}, threads={th} "
                                             f"vs the first {m} configuration")
        # limb outputs are identical for both methods (intersect's docstring)
        a, b = first["stepping"], first["exact"]
        both = (a.status == 1) & (b.status == 1)
        for name in ("tc", "sc", "tangent_lat", "tangent_lon", "tangent_altitude", "tangent_height"):
            if not _same(getattr(a, name)[both], getattr(b, name)[both]):
                fail(f"limb ray: {name} differs between method='stepping' and method='exact'")
    if case.get("per_ray") and len(res):
        # each ray alone gives its row of the batch (no dependence on the other rays)
        sb = np.broadcast_to(np.asarray(s, dtype=np.float64).reshape(-1, 3), (len(res), 3))
        lb = np.broadcast_to(np.asarray(l, dtype=np.float64).reshape(-1, 3), (len(res), 3))
        for k in range(len(res)):
            one = pi.intersect(dem, sb[k], lb[k], **kwargs)
            calls += 1
            for name in ("status", "p", "tc", "tangent_altitude", "nsteps"):
                if not _same(getattr(one, name)[0], getattr(res, name)[k]):
                    fail(f"ray {k} alone: {name} = {getattr(one, name)[0]!r}, in the batch {getattr(res, name)[k]!r}")
    return {"status": counts, "calls": calls}


def op_mutate(case, tmp: Path):
    """DEM.from_array, then the caller overwrites its array: results must not change."""
    radii = dem_array(case["dem"])
    dem = pi.DEM.from_array(radii, **dem_kwargs(case["dem"]))
    s, l = case["s"], case["l"]
    ref = {m: pi.intersect(dem, s, l, method=m) for m in ("stepping", "exact")}
    for j, i, v in case["mutations"]:
        radii[j % radii.shape[0], i % radii.shape[1]] = v
    for m in ("stepping", "exact"):
        r = pi.intersect(dem, s, l, method=m)
        compare_results(ref[m], r, f"method={m} after the caller changed the array given to DEM.from_array")
    return {"calls": 4}


def op_detector(case, tmp: Path):
    a = case["args"]
    los = pi.detector_los(a["l0"], a["q"], a["nh"], a["nv"], a["dh"], a["dv"])
    nh, nv = int(a["nh"]), int(a["nv"])
    if los.shape != (nh * nv, 3):
        fail(f"detector_los: shape {los.shape}, expected ({nh * nv}, 3)")
    if not np.isfinite(los).all() or not np.allclose(np.linalg.norm(los, axis=1), 1.0, rtol=0, atol=1e-12):
        fail("detector_los: rows are not finite unit vectors")
    if nh % 2 and nv % 2:
        l0 = np.asarray(a["l0"], dtype=np.float64)
        l0 = l0 / np.abs(l0).max()                  # (a subnormal l0's squared norm underflows to 0)
        c = los[(nv // 2) * nh + nh // 2]
        if not np.allclose(c, l0 / np.linalg.norm(l0), rtol=0, atol=1e-12):
            fail(f"detector_los: the centre pixel {c.tolist()} is not l0")
    return {"n": int(los.shape[0])}


_CLI_DEM = {}


def cli_dem(tmp_root: Path, spec: dict) -> Path:
    key = repr(sorted(spec.items()))
    if key not in _CLI_DEM:
        d = Path(tempfile.mkdtemp(dir=tmp_root.parent))
        _CLI_DEM[key] = make_dem(spec).write(d / "cli")
    return _CLI_DEM[key]


def op_cli_run(case, tmp: Path):
    from planet_intersect import cli

    hdr = cli_dem(tmp, case["dem"])
    rays = tmp / case.get("rays_name", "rays.txt")
    rays.write_bytes(case["rays"])
    if case.get("special"):
        make_special(rays, case["special"])
    out = tmp / "out"
    argv = ["run", str(hdr), str(rays), "--out", str(out)] + list(case.get("options", []))
    so, se = _io.StringIO(), _io.StringIO()
    with contextlib.redirect_stdout(so), contextlib.redirect_stderr(se):
        try:
            rc = cli.main(argv)
        except SystemExit as exc:           # argparse: usage error, exit 2
            rc = exc.code
    err = se.getvalue()
    if rc == 0:
        nrows = case.get("nrays")
        csvs = list(out.glob("run-*/results.csv"))
        if len(csvs) != 1:
            fail(f"planet-intersect run: exit 0 but {len(csvs)} results.csv files")
        got = len(csvs[0].read_text().splitlines()) - 1
        if nrows is not None and got != nrows:
            fail(f"planet-intersect run: {got} result rows for a rays file of {nrows} rays")
        if nrows is None:
            fail("planet-intersect run: exit 0 on a rays file that must be refused: " + case.get("why", ""))
        if err.strip() and "rays [" not in err:
            fail(f"planet-intersect run: exit 0 but wrote to stderr: {err[:300]!r}")
        return {"rc": 0}
    lines = [x for x in err.splitlines() if x.strip()]
    if case.get("special") in ("dir", "fifo", "loop") and "no such file" in err.lower():
        fail(f"a {case['special']} given as the rays file is reported as missing: {err.strip()}")
    if rc != 2:
        fail(f"planet-intersect run: exit status {rc!r} (2 expected for an error); stderr: {err[-500:]!r}")
    if "Traceback" in err or len(lines) != 1 and not err.startswith("usage:"):
        fail(f"planet-intersect run: the error is not one line: {err[-800:]!r}")
    if list(out.glob("run-*")):
        fail("planet-intersect run: failed but left a run-NNN folder behind")
    raise CLIFailure(lines[-1] if lines else "")


class CLIFailure(Exception):
    """The CLI exited with status 2 and this one-line message (judged by the parent)."""


def op_selftest(case, tmp: Path):
    """The harness's own test: a real segfault or a hang in the worker."""
    if case["action"] == "segfault":
        import ctypes

        ctypes.string_at(0)
    elif case["action"] == "hang":
        import time

        time.sleep(3600)
    return {}


OPS = {
    "selftest": op_selftest,
    "from_array": op_from_array, "read": op_read, "radius": op_radius, "intersect": op_intersect,
    "mutate": op_mutate, "detector": op_detector, "cli_run": op_cli_run,
}

from .geo import OPS as _GEO_OPS  # noqa: E402  (the geodetic system's operations)

OPS.update(_GEO_OPS)
from .grs import OPS as _GRS_OPS  # noqa: E402  (the footprint system's operations)

OPS.update(_GRS_OPS)
from .sim import OPS as _SIM_OPS  # noqa: E402  (the image simulation's operations)

OPS.update(_SIM_OPS)


def documented_warning(w) -> bool:
    """A warning the package documents as its answer, not a fault: airmass(model="notes") where the
    notes' series as printed is negative (docs/grs-notes.md notes 4 and 21); a DEM whose re = 1 (Table
    1's placeholder) comes with a flattening under radii far from 1 (paper-notes note 25)."""
    m = str(w.message)
    return issubclass(w.category, UserWarning) and (m.startswith("airmass model 'notes'")
                                                    or " re = 1 with f = " in m)


def run_case(case: dict) -> dict:
    """Perform one case in a fresh temporary folder; warnings are property violations."""
    with tempfile.TemporaryDirectory(prefix="pifuzz-") as d, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        info = OPS[case["op"]](case, Path(d))
        caught = [w for w in caught if not issubclass(w.category, (DeprecationWarning, ResourceWarning))
                  and not documented_warning(w)]
        if caught:
            w = caught[0]
            fail(f"a {w.category.__name__} was emitted: {w.message} ({os.path.basename(w.filename)}:{w.lineno})")
    return info or {}
