"""``intersect``: where each line of sight meets the DEM surface, or passes it.

The work is done by the Fortran core (``planet_intersect._core``), a port of
Teanby (2008) section 2.3-2.4.1; this module validates input, broadcasts
vectors, and turns the core's status codes into exceptions.
"""

from __future__ import annotations

import os
import re
import warnings
from dataclasses import dataclass, fields

import numpy as np

from ._status import RAY_STATUS as RAY_STATUS_TEXT
from ._status import DEMError, RayStatus, raise_for_stat
from .dem import DEM

__all__ = ["intersect", "IntersectResult"]

_TANGENT = {"paper": 0, "exact": 1}
_METHOD = {"stepping": 0, "exact": 1}
_NO_PYRAMID = (np.zeros(1, dtype=np.float32), np.zeros((1, 3), dtype=np.int32))


class RayTable:
    """Export of a per-ray result dataclass (arrays of length N, vectors (N, 3)),
    shared by the planetary and the geodetic results. Subclasses set ANGLES and
    _status_items()."""

    ANGLES = ""
    #: field name -> what it is (the class docstring's Attributes and to_xarray's long_name)
    FIELD_DOCS: dict = {}
    #: fields in degrees, and fields that are lengths (in LENGTHS); the rest are codes, counts
    #: or flags (to_xarray's "units": "degree", LENGTHS, "1")
    ANGLE_FIELDS: frozenset = frozenset()
    LENGTH_FIELDS: frozenset = frozenset()
    #: the unit of the lengths, as to_xarray writes it
    LENGTHS = ""

    @staticmethod
    def _status_items():
        return ()

    def __len__(self) -> int:
        return len(self.status)

    def to_xarray(self):
        """The results as an :class:`xarray.Dataset` with dimensions ``ray`` and ``xyz``."""
        import xarray as xr

        data = {}
        for fld in fields(self):
            value = getattr(self, fld.name)
            data[fld.name] = (("ray", "xyz") if value.ndim == 2 else ("ray",), value)
        ds = xr.Dataset(data, coords={"ray": np.arange(len(self)), "xyz": ["x", "y", "z"]})
        for name, doc in self.FIELD_DOCS.items():          # what each variable is (a walk-through)
            if name in ds:
                ds[name].attrs["long_name"] = doc
        for name in ds.data_vars:                          # (none had units: a review, 2026-12-05)
            ds[name].attrs["units"] = ("degree" if name in self.ANGLE_FIELDS else
                                       self.LENGTHS if name in self.LENGTH_FIELDS else "1")
        ds.attrs["status_codes"] = "; ".join(f"{k}: {v}" for k, v in self._status_items())
        ds.attrs["angles"] = self.ANGLES
        ds.attrs["lengths"] = self.LENGTHS
        return ds

    def to_table(self) -> dict:
        """Flat columns (vectors split into _x/_y/_z) for CSV export."""
        cols = {}
        for fld in fields(self):
            value = getattr(self, fld.name)
            if value.ndim == 2:
                for k, axis in enumerate("xyz"):
                    cols[f"{fld.name}_{axis}"] = value[:, k]
            else:
                cols[fld.name] = value
        return cols


@dataclass
class IntersectResult(RayTable):
    """Per-ray results of :func:`intersect`; arrays of length N (vectors (N, 3)).

    Angles in degrees, lengths in the DEM's units; NaN where a quantity does not
    apply (surface quantities for rays that miss, tangent quantities for rays
    that hit or point away).
    """

    hit: np.ndarray  #: True where the ray meets the surface
    p: np.ndarray  #: hit point (eq. 35 at convergence)
    lat: np.ndarray  #: planetocentric latitude of p (eq. 42)
    lon: np.ndarray  #: east longitude of p in [0, 360) (eq. 43)
    radius: np.ndarray  #: |p| (eq. 44)
    altitude: np.ndarray  #: radius minus the spheroid radius at lat (eq. 61); NaN without a spheroid
    emission: np.ndarray  #: angle between -l and the spheroid normal at p (eqs. 45, 50)
    t: np.ndarray  #: limb rays: the point of the line nearest the planet's centre (spherical tangent point, eq. 20)
    tc: np.ndarray  #: limb rays: the point of the line nearest the spheroid (its tangent point, eq. 57)
    sc: np.ndarray  #: limb rays: the point of the spheroid nearest tc, below it; NaN without a spheroid
    tangent_lat: np.ndarray  #: limb rays: planetocentric latitude of the tangent point (of sc, eq. 59)
    tangent_lon: np.ndarray  #: limb rays: east longitude of the tangent point (eq. 60)
    tangent_altitude: np.ndarray  #: limb rays: height of tc above the DEM surface below it (eq. 63)
    tangent_height: np.ndarray  #: limb rays: signed distance from sc to tc, the line's height above the spheroid (eq. 58); NaN without a spheroid
    status: np.ndarray  #: per-ray code, see :class:`RayStatus`
    nsteps: np.ndarray  #: test points evaluated along each ray

    #: what to_xarray() writes as the Dataset's "angles" attribute
    ANGLES = "degrees; latitudes planetocentric, longitudes east in [0, 360)"
    ANGLE_FIELDS = frozenset({"lat", "lon", "emission", "tangent_lat", "tangent_lon"})
    LENGTH_FIELDS = frozenset({"p", "radius", "altitude", "t", "tc", "sc", "tangent_altitude", "tangent_height"})
    LENGTHS = "the DEM's length unit (km for the legacy DEM format)"

    @staticmethod
    def _status_items():
        return _ray_status_items()


def document_fields(cls):
    """Class decorator: the ``#:`` comments of a result dataclass's fields (read from its source)
    as ``FIELD_DOCS`` and as an Attributes section of its docstring, so that ``help()`` and the
    NetCDF files say what ``tc``, ``sc`` or ``tangent_height`` are (a walk-through found them
    explained nowhere a user looks)."""
    import inspect

    try:
        src = inspect.getsource(cls)
    except (OSError, TypeError):                       # no source (frozen): the fields stay undocumented
        return cls
    docs = {}
    for fld in fields(cls):
        m = re.search(rf"^\s+{fld.name}: [^\n]*?#:\s*(.+)$", src, re.M)
        if m:
            docs[fld.name] = m.group(1).strip()
    cls.FIELD_DOCS = docs
    if docs and cls.__doc__:
        width = max(map(len, docs))
        cls.__doc__ = cls.__doc__.rstrip() + "\n\n    Attributes\n    ----------\n" + "".join(
            f"    {k:<{width}} : {v}\n" for k, v in docs.items())
    return cls


IntersectResult = document_fields(IntersectResult)


def _ray_status_items():
    from ._status import RAY_STATUS

    return RAY_STATUS.items()


#: keywords of intersect() that only a GeodeticDSM takes (intersect_dsm's own)
_DSM_ONLY_OPTIONS = frozenset({"outside"})

#: Largest squared length taken without rescaling, and the smallest.
_N2_MAX, _N2_MIN = 1e300, 1e-300
#: Spacecraft farther than this many rmax are rejected (pi_intersect::far_limit).
FAR_LIMIT = 1e15
#: Most OpenMP threads one call may ask for.
MAX_THREADS = 1024


def as_vectors(v, name: str) -> np.ndarray:
    """``v`` as a float64 (N, 3) array of finite, non-zero vectors (a (3,) vector
    becomes (1, 3)); ValueError or TypeError naming ``name`` and the row otherwise."""
    return _as_vectors_n2(v, name)[0]


def _as_vectors_n2(v, name: str) -> tuple[np.ndarray, np.ndarray]:
    """as_vectors, and the rows' squared lengths (overflowed to inf, underflowed to 0),
    which the DSM trace reuses instead of computing them three more times."""
    try:
        arr = np.asarray(v)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: not an array of numbers ({exc})") from None
    if arr.dtype.kind not in "fiu":
        raise TypeError(f"{name}: must be real numbers, got dtype {arr.dtype}")
    v = arr.astype(np.float64, copy=False)
    shape = v.shape
    if v.ndim == 1:
        v = v[None, :]
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"{name}: expected shape (3,) or (N, 3), got {shape}")
    with np.errstate(over="ignore", under="ignore"):
        n2 = np.einsum("ij,ij->i", v, v)                 # one pass: finite, well-scaled rows pass
    if ((n2 >= _N2_MIN) & (n2 <= _N2_MAX)).all():
        return v, n2
    bad = ~np.isfinite(v).all(axis=1)
    if bad.any():
        raise ValueError(f"{name}[{int(np.argmax(bad))}] has NaN or Inf components: {v[np.argmax(bad)]}")
    zero = ~v.any(axis=1)
    if zero.any():
        raise ValueError(f"{name}[{int(np.argmax(zero))}] has zero length")
    return v, n2


def _unit_scaled(v: np.ndarray, n2: np.ndarray | None = None) -> np.ndarray:
    """Directions whose squared length would underflow or overflow, scaled by a
    power of two (exact: the direction is unchanged to the last bit) so that
    their largest component lies in [0.5, 1); other rows as they are. ``n2``:
    the rows' squared lengths if already known (_as_vectors_n2)."""
    if n2 is None:
        with np.errstate(over="ignore", under="ignore"):
            n2 = np.einsum("ij,ij->i", v, v)
    odd = ~((n2 >= _N2_MIN) & (n2 <= _N2_MAX))
    if not odd.any():
        return v
    v = v.copy()
    _, e = np.frexp(np.abs(v[odd]).max(axis=1))
    v[odd] = np.ldexp(v[odd], -e[:, None])
    return v


# libgomp (GCC's OpenMP) cannot start threads in a child forked after its own threads ran in the
# parent: the child's first parallel region with more than one thread never returns (an independent
# review, 2026-12-05: a call, then multiprocessing's default "fork" pool, hung). So the package notes
# when it has run OpenMP on more than one thread, and a process forked after that runs every call on
# one thread, with one warning. Process-level facts of the Python layer, never read by the Fortran.
_omp_used_threads = False
_forked_after_omp = False
_fork_warned = False


def _after_fork_in_child() -> None:
    global _forked_after_omp, _fork_warned
    if _omp_used_threads:
        _forked_after_omp = True
        _fork_warned = False


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork_in_child)


def _default_threads() -> int:
    """None or 0: OMP_NUM_THREADS when it is set to a positive integer (its first value, as OpenMP
    reads it), else the cores this process may run on."""
    env = os.environ.get("OMP_NUM_THREADS", "").split(",")[0].strip()
    if env.isdigit() and int(env) > 0:
        return min(int(env), MAX_THREADS)
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def check_threads(threads, n: int) -> int:
    """The OpenMP thread count for n rays: None or 0 means OMP_NUM_THREADS if set, else all
    cores; otherwise an integer in 1..MAX_THREADS, used as min(threads, n) (threads beyond the
    rays would idle). In a process forked after the package ran OpenMP threads: 1 (libgomp cannot
    start threads there; see above). Results are bit-identical for any count."""
    global _omp_used_threads, _fork_warned
    if threads is None:
        threads = 0
    if isinstance(threads, (bool, np.bool_)) or not isinstance(threads, (int, np.integer)) \
            or not 0 <= threads <= MAX_THREADS:
        raise ValueError(f"threads must be an integer in 0..{MAX_THREADS} (0 or None: OMP_NUM_THREADS "
                         f"if set, else all cores), got {threads!r}")
    threads = int(threads)
    if threads == 0:
        threads = _default_threads()
    threads = max(1, min(threads, n))
    if threads > 1 and _forked_after_omp:
        if not _fork_warned:
            _fork_warned = True
            warnings.warn("planet_intersect: this process was forked after the package ran OpenMP threads, "
                          "and GCC's OpenMP cannot start threads again in it: calls here run on one thread "
                          "(start worker processes with multiprocessing's 'spawn' or 'forkserver' method "
                          "to keep their threads)", RuntimeWarning, stacklevel=3)
        return 1
    if threads > 1:
        _omp_used_threads = True
    return threads


def _choice(value, name: str, allowed) -> str:
    if not isinstance(value, str) or value not in allowed:
        raise ValueError(f"{name} must be one of {', '.join(repr(a) for a in allowed)}, got {value!r}")
    return value


def _empty_result() -> "IntersectResult":
    vec, sca = np.zeros((0, 3)), np.zeros(0)
    return IntersectResult(hit=np.zeros(0, dtype=bool), p=vec, lat=sca, lon=sca.copy(), radius=sca.copy(),
                           altitude=sca.copy(), emission=sca.copy(), t=vec.copy(), tc=vec.copy(), sc=vec.copy(),
                           tangent_lat=sca.copy(), tangent_lon=sca.copy(), tangent_altitude=sca.copy(),
                           tangent_height=sca.copy(), status=np.zeros(0, dtype=np.int8),
                           nsteps=np.zeros(0, dtype=np.int32))


def _check_mode(value, name: str) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or value not in (0, 1):
        raise ValueError(f"{name} must be 0 or 1, got {value!r}")
    return int(value)


def intersect(dem: DEM, s, l, step_mode: int = 1, dem_read_mode: int = 0,
              tangent: str = "exact", threads: int | None = None, method: str | None = None,
              io: str = "records", **dsm_options):
    """Intersect lines of sight with a planetary DEM (Teanby's zcalc_planet_intersect)
    or a geodetic DSM (Shin & Park's ray following).

    The one entry point of both systems. For a :class:`GeodeticDSM` (heights
    above an ellipsoid on a geodetic grid) the methods are "following" (the
    default: the paper's ray following), "exact" (the first entry into the
    interpolated surface, to 1e-6 along the ray in the DSM's units: 1e-6 m for
    metres) and "iterative" (the
    conventional iterative ray tracing the paper criticises); ``s`` and ``l``
    are ECR metres (the DSM's units), ``threads`` as below, keyword
    ``outside="ellipsoid"`` falls back to the bare ellipsoid where a ray
    leaves the DSM; ``step_mode``, ``dem_read_mode``, ``tangent`` and ``io``
    are the DEM's only (a value other than their defaults is refused). The result is then a
    :class:`~planet_intersect.dsm.DSMResult` (lat, lon in degrees, lon in
    [-180, 180); height above the ellipsoid; incidence in degrees from the
    ellipsoid normal; status codes in docs/status-codes.md). The parameters
    below are those of a planetary DEM.

    Parameters
    ----------
    dem : DEM or GeodeticDSM
        The surface (see :class:`DEM`); lengths in its units.
    s : array (3,) or (N, 3)
        Spacecraft position(s), planet-fixed Cartesian (x to lat 0 lon 0, z north).
        One position broadcasts over all rays.
    l : array (3,) or (N, 3)
        Line-of-sight direction(s), any non-zero length (normalised here).
    step_mode : 0 or 1
        1: angular step ``cos(lat)/(2 ppd)`` degrees (eq. 23); 0: without ``cos(lat)``.
    dem_read_mode : 0 or 1
        0: the whole grid in memory; 1: radii read record by record from the
        ``.dem`` file by the Fortran core (file-backed DEMs only). Bit-identical results.
    tangent : "exact" or "paper"
        Spheroid tangent point of limb rays: "exact" is the nearest point between
        line and spheroid; "paper" the construction of eqs. 55-58, which agrees
        when the line touches the spheroid (docs/paper-notes.md gives the difference).
    threads : int, optional
        OpenMP threads for the ray loop; None or 0: OMP_NUM_THREADS if set, else all cores. Results are
        bit-identical for any count.
    method : "stepping" or "exact" (a DEM); "following", "exact" or "iterative" (a DSM)
        "stepping": the paper's algorithm (eqs. 23-41). "exact": the first entry
        of the ray into the same bilinear surface, found by subdividing the ray
        against a max-pyramid of the DEM (built on first use and kept with the
        DEM); exact to 1e-9 rmax along the ray, never a later entry, never a
        miss of a chord longer than that. ``nsteps`` then counts the segments
        examined. Limb outputs are identical for both.
    io : "records" or "mmap"
        How dem_read_mode=1 reads the file ("mmap" is refused with dem_read_mode=0): "records", one pread per record (the
        paper's direct access; resident memory stays small whatever the DEM size);
        "mmap", from a read-only memory map (faster; the kernel pages in what the
        rays touch): the DEM's own map, kept open between calls, when the file is
        float32 or float64 in the machine's byte order, else one made for the
        call. Bit-identical results.

    Returns
    -------
    IntersectResult, or DSMResult for a GeodeticDSM

    A :class:`GeodeticDSM` as ``dem`` is traced by ``dsm.intersect_dsm``
    (methods "following" (default), "exact", "iterative"; keyword ``outside``).

    Raises
    ------
    ValueError
        Bad shapes, NaN/Inf or zero-length vectors, modes out of range, or a
        spacecraft below the surface.
    DEMError
        The DEM file cannot be used (mode 1).
    """
    from ._ext import core as _core
    from .dsm import GeodeticDSM, intersect_dsm

    # an unknown keyword is intersect's error (not the inner intersect_dsm's, nor "a DSM option"
    # for a misspelt stepmode: a walk-through)
    unknown = sorted(set(dsm_options) - _DSM_ONLY_OPTIONS)
    if unknown:
        raise TypeError(f"intersect: unexpected keyword argument(s) {unknown} (a GeodeticDSM takes method, "
                        f"threads and {', '.join(sorted(_DSM_ONLY_OPTIONS))})")
    if isinstance(dem, GeodeticDSM):                     # the Shin & Park system (dsm.py)
        given = {k: v for k, v in (("step_mode", step_mode != 1), ("dem_read_mode", dem_read_mode != 0),
                                   ("tangent", tangent != "exact"), ("io", io != "records")) if v}
        if given:
            raise TypeError(f"intersect: {sorted(given)} apply to a planetary DEM, not a GeodeticDSM")
        return intersect_dsm(dem, s, l, method="following" if method is None else method, threads=threads,
                             **dsm_options)
    if not isinstance(dem, DEM):
        raise TypeError(f"dem must be a planet_intersect.DEM or GeodeticDSM, got {type(dem).__name__}")
    if dsm_options:
        raise TypeError(f"intersect: {sorted(dsm_options)} apply to a GeodeticDSM only")
    if method is None:
        method = "stepping"
    step_mode = _check_mode(step_mode, "step_mode")
    dem_read_mode = _check_mode(dem_read_mode, "dem_read_mode")
    _choice(io, "io", ("records", "mmap"))
    if io != "records" and dem_read_mode == 0:
        # io says how mode 1 reads the file; taken silently with mode 0 it looked used (stop 30's list)
        raise ValueError(f"io={io!r} says how dem_read_mode=1 reads the DEM's file; with dem_read_mode=0 "
                         "the grid is in memory and io has no use: pass dem_read_mode=1 with it, or leave io out")
    _choice(method, "method (for a planetary DEM)", tuple(_METHOD))
    _choice(tangent, "tangent", tuple(_TANGENT))
    check_threads(threads, 1)
    s = as_vectors(s, "s")
    l = as_vectors(l, "l")
    if len(s) != len(l) and len(s) != 1 and len(l) != 1:
        raise ValueError(f"s and l: {len(s)} positions do not broadcast against {len(l)} lines of sight")
    with np.errstate(over="ignore"):
        far = np.einsum("ij,ij->i", s, s) > (FAR_LIMIT * dem.rmax) ** 2
    if far.any():
        k = int(np.argmax(far))
        big = np.abs(s[k]).max()
        with np.errstate(over="ignore"):
            dist = big * np.linalg.norm(s[k] / big) / dem.rmax
        dist = f"{dist:.3g}" if np.isfinite(dist) else "more than 1e300"
        raise ValueError(f"s[{k}] = {s[k]} is {dist} rmax from the centre: "
                         f"at most {FAR_LIMIT:g} rmax (a unit vector's direction is resolved to ~1e-16, so "
                         "farther away the line's position at the planet is lost to rounding)")
    l = _unit_scaled(l)
    n = 0 if min(len(s), len(l)) == 0 else max(len(s), len(l))
    if n == 0:
        return _empty_result()
    threads = check_threads(threads, n)
    s = np.ascontiguousarray(np.broadcast_to(s, (n, 3)))
    l = np.ascontiguousarray(np.broadcast_to(l, (n, 3)))

    pyr_data, pyr_meta = dem.pyramid() if method == "exact" else _NO_PYRAMID
    extra = dict(threads=int(threads), method=_METHOD[method])
    if dem_read_mode == 0:
        out = _core.core_intersect_grid(dem.radii64().T, dem.ppd, dem.rmax, dem.f, dem.re,
                                        s.T, l.T, step_mode, _TANGENT[tangent], pyr_data, pyr_meta.T, **extra)
        where = "intersect"
    else:
        if dem.path is None:
            raise ValueError("dem_read_mode=1 reads records from the DEM's file: "
                             "this DEM is in memory (write it with dem.write() and DEM.read() it)")
        dem.check_file()
        mapped = dem.mapped_bytes() if io == "mmap" else None
        if mapped is not None:
            # the DEM's own memory map, open between calls: pages already brought in stay mapped
            out = _core.core_intersect_mapped(mapped, dem.radii.dtype.itemsize, dem.ppd, dem.rmax, dem.f, dem.re,
                                              dem.mapped_poles(), s.T, l.T, step_mode, _TANGENT[tangent], pyr_data, pyr_meta.T, **extra)
        else:
            # the path as bytes: f2py takes a str only in ASCII (a non-ASCII path failed with
            # "function takes exactly 5 arguments (1 given)": a review); the Fortran opens bytes
            out = _core.core_intersect_file(os.fsencode(str(dem.path)), 1, *dem.header_args(), s.T, l.T,
                                            step_mode,
                                            _TANGENT[tangent], pyr_data, pyr_meta.T, use_map=int(io == "mmap"),
                                            **extra)
        where = f"intersect (dem_read_mode=1, {dem.path})"
    p, t, tc, sc, scal, status, nsteps, stat = out
    raise_for_stat(stat, where)

    inside = np.flatnonzero(status == RayStatus.INSIDE)
    if inside.size:
        k = int(inside[0])
        raise ValueError(f"s[{k}] = {s[k]} is inside the planet surface "
                         f"({inside.size} ray(s) affected): the spacecraft must be above the DEM")
    bad = np.flatnonzero((status == RayStatus.BAD_POSITION) | (status == RayStatus.BAD_DIRECTION))
    if bad.size:                              # the checks above should have caught it: never silent
        k = int(bad[0])
        which = "s" if status[k] == RayStatus.BAD_POSITION else "l"
        raise ValueError(f"{which}[{k}] = {(s if which == 's' else l)[k]} cannot be used by the core "
                         f"({RAY_STATUS_TEXT[int(status[k])]}; {bad.size} ray(s) affected)")
    unreadable = np.flatnonzero(status == RayStatus.READ_ERROR)
    if unreadable.size:
        raise DEMError(f"{where}: a DEM record needed by ray {int(unreadable[0])} could not be read or is invalid")
    if dem.path is not None and dem_read_mode == 1:
        dem.check_file()                      # changed during the call: the records read may be mixed
    unresolved = int(np.count_nonzero(status == RayStatus.UNRESOLVED))
    if unresolved:
        warnings.warn(f"{where}: {unresolved} ray(s) could not be resolved in floating point (status 8, "
                      f"first: ray {int(np.argmax(status == RayStatus.UNRESOLVED))}); their results are NaN",
                      RuntimeWarning, stacklevel=2)

    lat, lon = np.degrees(scal[0]), np.degrees(scal[1])
    tlat, tlon = np.degrees(scal[5]), np.degrees(scal[6])
    return IntersectResult(
        hit=(status == RayStatus.HIT) | (status == RayStatus.HIT_UNCONVERGED),
        p=p.T.copy(), lat=lat, lon=lon, radius=scal[2].copy(), altitude=scal[3].copy(),
        emission=np.degrees(scal[4]),
        t=t.T.copy(), tc=tc.T.copy(), sc=sc.T.copy(),
        tangent_lat=tlat, tangent_lon=tlon, tangent_altitude=scal[7].copy(), tangent_height=scal[8].copy(),
        status=status.astype(np.int8), nsteps=nsteps.astype(np.int32),
    )
