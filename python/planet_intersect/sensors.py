"""Sensor geometry for image simulation (Shin & Park, issue 12): which ray each
image pixel casts.

* :class:`Pushbroom` — a line camera: one focal point per image line and one
  line of detectors, either the user's geometry as it is (``Pushbroom(s, l)``,
  e.g. from SPICE or Orekit) or a built-in Keplerian orbit
  (:meth:`Pushbroom.from_orbit`).
* :class:`FrameCamera` — all pixels from one focal point (airborne, drone),
  given as it is or built as a pinhole camera (:meth:`FrameCamera.pinhole`,
  :meth:`FrameCamera.nadir`).
* Helpers on every sensor: :meth:`Sensor.footprint_corners` (where the four
  corner pixels look on a DSM) and :meth:`Sensor.gsd` (ground sampling
  distances); :func:`view_zenith_angle` / :func:`off_nadir_angle` convert
  between the two meanings of "viewing angle".

Every sensor gives its rays a block of lines at a time (:meth:`rays`), so that
a simulation of an image larger than memory never holds all of them (the
built-in orbit and pinhole cameras compute their directions per block).
Positions are ECR (Earth-centred rotating = body-fixed) Cartesian, in the
units of the DSM's semi-major axis (metres for Earth).

Viewing angles
--------------
Two angles are both called "viewing angle" in the literature:

* the **off-nadir angle** alpha, at the satellite: between the line of sight
  and the nadir, the downward ellipsoid normal through the satellite;
* the **view zenith angle** theta, at the ground: between the reversed line of
  sight and the ellipsoid normal at the point seen (``intersect``'s
  ``incidence``).

Earth curvature makes theta larger than alpha; on a sphere of radius R seen
from altitude H, ``sin(theta) = (R + H) / R * sin(alpha)``
(:func:`view_zenith_angle`, :func:`off_nadir_angle`). At 700 km, alpha = 8 deg
gives theta = 8.88 deg.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from .geodetic import WGS84_A, WGS84_F, check_ellipsoid, ecef_to_geodetic, geodetic_to_ecef

__all__ = ["Sensor", "Pushbroom", "FrameCamera", "view_zenith_angle", "off_nadir_angle",
           "EARTH_GM", "EARTH_ROTATION_RATE"]

#: Earth's gravitational parameter GM (m^3/s^2, WGS-84 / EGM96 value with the atmosphere)
EARTH_GM = 3.986004418e14
#: Earth's rotation rate (rad/s, WGS-84 omega; ECR turns about +z)
EARTH_ROTATION_RATE = 7.2921150e-5


def _array(v, name: str, shape_tail: tuple, ndim: int) -> np.ndarray:
    try:
        arr = np.asarray(v)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: not an array of numbers ({exc})") from None
    if arr.dtype.kind not in "fiu":
        raise TypeError(f"{name}: must be real numbers, got dtype {arr.dtype}")
    arr = np.array(arr, dtype=np.float64)          # a private copy: later edits by the caller change nothing
    if arr.ndim != ndim or arr.shape[ndim - len(shape_tail):] != shape_tail:
        want = "(" + ", ".join(["n"] * (ndim - len(shape_tail)) + [str(t) for t in shape_tail]) + ")"
        raise ValueError(f"{name}: expected shape {want}, got {arr.shape}")
    if not np.isfinite(arr).all():
        k = np.argwhere(~np.isfinite(arr))[0]
        raise ValueError(f"{name}{[int(i) for i in k[:-1]]} has NaN or Inf components")
    arr.flags.writeable = False
    return arr


# ---------------------------------------------------------------- input checks
def _num(value, name: str, lo=None, hi=None, lo_open=False, hi_open=False) -> float:
    """A finite real number within [lo, hi] (open ends when asked); errors name the argument."""
    if isinstance(value, (bool, np.bool_)) or isinstance(value, str):
        raise TypeError(f"{name} must be a number, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {v}")
    if lo is not None and (v < lo or (lo_open and v == lo)):
        raise ValueError(f"{name} must be {'>' if lo_open else '>='} {lo}, got {v}")
    if hi is not None and (v > hi or (hi_open and v == hi)):
        raise ValueError(f"{name} must be {'<' if hi_open else '<='} {hi}, got {v}")
    return v


def _count(value, name: str, lo: int = 1, hi: int = 10**8) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be an integer, got {value!r}")
    v = int(value)
    if not lo <= v <= hi:
        raise ValueError(f"{name} must be between {lo} and {hi}, got {v}")
    return v


#: most pixels (lines x pixels) a sensor may have: simulate_image's MAX_PIXELS (a million by a
#: million was accepted, and failed on a 21.8 TiB allocation naming nothing: a review)
MAX_SENSOR_PIXELS = 1 << 32
#: most lines from_orbit builds (its frames take ~0.3 kB a line: 10**8 lines ran 13 s and failed on
#: a MemoryError naming nothing, a review)
MAX_ORBIT_LINES = 10**7


def _pixels(nlines: int, npixels: int, names: str) -> None:
    if nlines * npixels > MAX_SENSOR_PIXELS:
        raise ValueError(f"{names}: {nlines:,} x {npixels:,} = {nlines * npixels:,} pixels, more than "
                         f"{MAX_SENSOR_PIXELS:,}")


def _shape(shape, name: str = "shape") -> tuple[int, int]:
    try:
        n = len(shape)
    except TypeError:
        raise TypeError(f"{name} must be a pair (nrows, ncols), got {shape!r}") from None
    if n != 2:
        raise ValueError(f"{name} must be a pair (nrows, ncols), got {shape!r}")
    return _count(shape[0], f"{name}[0] (nrows)", 1, 10**6), _count(shape[1], f"{name}[1] (ncols)", 1, 10**6)


def _unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _normal(lat_deg, lon_deg):
    """Outward ellipsoid normal(s) at geodetic (lat, lon) in degrees, ECR."""
    la, lo = np.radians(lat_deg), np.radians(lon_deg)
    return np.stack([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)], axis=-1)


def _north(lat_deg, lon_deg):
    la, lo = np.radians(lat_deg), np.radians(lon_deg)
    return np.stack([-np.sin(la) * np.cos(lo), -np.sin(la) * np.sin(lo), np.cos(la)], axis=-1)


def _east(lon_deg):
    lo = np.radians(lon_deg)
    return np.stack([-np.sin(lo), np.cos(lo), np.zeros_like(lo)], axis=-1)


def _rx(t):
    c, s = math.cos(t), math.sin(t)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _ry(t):
    c, s = math.cos(t), math.sin(t)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rz(t):
    c, s = math.cos(t), math.sin(t)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


# ---------------------------------------------------------------- viewing angles
def view_zenith_angle(off_nadir, altitude, radius=WGS84_A):
    """View zenith angle at the ground from the off-nadir angle at the satellite (sphere).

    ``sin(theta) = (R + H) / R * sin(alpha)`` (triangle centre-satellite-ground point).

    Parameters
    ----------
    off_nadir : float or array
        Off-nadir angle alpha at the satellite (deg, 0 <= alpha < 90).
    altitude : float
        Satellite altitude H above the sphere (units of ``radius``, > 0).
    radius : float
        Sphere radius R (default: WGS-84 semi-major axis, m). For an ellipsoid,
        use the local radius for a close approximation.

    Returns
    -------
    theta : float or array
        View zenith angle (deg). Raises ValueError where the line of sight
        misses the sphere (alpha beyond the horizon, ``asin(R/(R+H))``).
    """
    h = _num(altitude, "altitude", 0.0, lo_open=True)
    r = _num(radius, "radius", 0.0, lo_open=True)
    a = np.asarray(off_nadir, dtype=np.float64)
    if not np.isfinite(a).all() or (a < 0).any() or (a >= 90).any():
        raise ValueError(f"off_nadir must be finite and in [0, 90) degrees, got {off_nadir!r}")
    x = (r + h) / r * np.sin(np.radians(a))
    if (x > 1.0).any():
        horizon = math.degrees(math.asin(r / (r + h)))
        raise ValueError(f"off_nadir = {np.max(a)} deg looks past the horizon ({horizon:.4f} deg "
                         f"at altitude {h} over radius {r})")
    out = np.degrees(np.arcsin(x))
    return float(out) if out.ndim == 0 else out


def off_nadir_angle(view_zenith, altitude, radius=WGS84_A):
    """Off-nadir angle at the satellite from the view zenith angle at the ground (sphere).

    ``sin(alpha) = R / (R + H) * sin(theta)``, the inverse of :func:`view_zenith_angle`.

    Parameters
    ----------
    view_zenith : float or array
        View zenith angle theta at the ground point (deg, 0 <= theta <= 90).
    altitude, radius : float
        As in :func:`view_zenith_angle`.

    Returns
    -------
    alpha : float or array (deg)
    """
    h = _num(altitude, "altitude", 0.0, lo_open=True)
    r = _num(radius, "radius", 0.0, lo_open=True)
    t = np.asarray(view_zenith, dtype=np.float64)
    if not np.isfinite(t).all() or (t < 0).any() or (t > 90).any():
        raise ValueError(f"view_zenith must be finite and in [0, 90] degrees, got {view_zenith!r}")
    out = np.degrees(np.arcsin(r / (r + h) * np.sin(np.radians(t))))
    return float(out) if out.ndim == 0 else out


# ---------------------------------------------------------------- Kepler orbit
def _kepler_states(el: dict, dt: np.ndarray):
    """Inertial position and velocity (n, 3) of a Keplerian orbit at times dt after t_ref.

    The inertial frame coincides with ECR at t_ref. Elements: semi-major axis
    ``sma``, ``e``, ``inc``, ``raan``, ``argp`` (rad), mean anomaly ``m0`` at
    t_ref, mean motion ``n`` (rad/s).
    """
    e = el["e"]
    m = el["m0"] + el["n"] * dt
    if e > 0:                          # Newton on Kepler's equation E - e sin E = M, M reduced to [0, 2 pi)
        turns = m - np.mod(m, 2 * np.pi)
        mr = m - turns
        ecc = mr.copy() if e < 0.8 else np.full_like(mr, np.pi)   # E0 = pi converges for any e < 1
        for _ in range(60):            # bounded: quadratic convergence needs < 10 steps
            d = (ecc - e * np.sin(ecc) - mr) / (1.0 - e * np.cos(ecc))
            ecc = ecc - d
            if not np.max(np.abs(d), initial=0.0) > 1e-15:
                break
        ecc = ecc + turns
    else:
        ecc = m.copy()
    sma, q = el["sma"], math.sqrt(1.0 - e * e)
    cE, sE = np.cos(ecc), np.sin(ecc)
    xp = np.stack([sma * (cE - e), sma * q * sE, np.zeros_like(cE)], axis=1)
    rate = el["n"] * sma / (1.0 - e * cE)
    vp = np.stack([-rate * sE, rate * q * cE, np.zeros_like(cE)], axis=1)
    rot = _rz(el["raan"]) @ _rx(el["inc"]) @ _rz(el["argp"])
    return xp @ rot.T, vp @ rot.T


def _ecr_states(el: dict, dt: np.ndarray, omega: float):
    """ECR position and velocity (n, 3) at dt after t_ref (Earth rotation omega rad/s about +z)."""
    r_i, v_i = _kepler_states(el, dt)
    th = omega * dt
    c, s = np.cos(th), np.sin(th)
    # r_ecr = Rz(-omega dt) r_inertial
    r = np.stack([c * r_i[:, 0] + s * r_i[:, 1], -s * r_i[:, 0] + c * r_i[:, 1], r_i[:, 2]], axis=1)
    v = np.stack([c * v_i[:, 0] + s * v_i[:, 1], -s * v_i[:, 0] + c * v_i[:, 1], v_i[:, 2]], axis=1)
    v = v - omega * np.stack([-r[:, 1], r[:, 0], np.zeros(len(r))], axis=1)   # - omega z x r
    return r, v


def _elements(u0, raan, inc, altitude, e, argp, a, f, gm):
    """Orbital elements whose satellite at t_ref is at argument of latitude u0 with
    geodetic height ``altitude`` (all angles rad)."""
    d = np.array([math.cos(raan) * math.cos(u0) - math.sin(raan) * math.sin(u0) * math.cos(inc),
                  math.sin(raan) * math.cos(u0) + math.cos(raan) * math.sin(u0) * math.cos(inc),
                  math.sin(u0) * math.sin(inc)])
    r0 = a + altitude
    for _ in range(20):                 # geodetic height of r0*d equals altitude; dh/dr = d . normal
        la, lo, h = ecef_to_geodetic(r0 * d, a, f)
        step = (h - altitude) / float(d @ _normal(la, lo))
        r0 -= step
        if abs(step) <= 1e-12 * r0:
            break
    nu0 = u0 - argp
    sma = r0 * (1.0 + e * math.cos(nu0)) / (1.0 - e * e)
    ecc0 = 2.0 * math.atan2(math.sqrt(1.0 - e) * math.sin(nu0 / 2), math.sqrt(1.0 + e) * math.cos(nu0 / 2))
    return {"sma": sma, "e": e, "inc": inc, "raan": raan, "argp": argp, "u0": u0, "r0": r0,
            "m0": ecc0 - e * math.sin(ecc0), "n": math.sqrt(gm / sma ** 3)}


def _node_of(lat, lon, inc, ascending, altitude, a, f):
    """(u0, raan) in rad of the orbit of inclination inc (rad) whose satellite at t_ref is at
    geodetic (lat, lon, altitude) (deg, deg, units of a), on the ascending or descending half."""
    p = geodetic_to_ecef(lat, lon, altitude, a, f)
    sin_lat_c = p[2] / np.linalg.norm(p)
    lon_r = math.atan2(p[1], p[0])
    si = math.sin(inc)
    if si < 1e-12:                      # equatorial orbit: u measured from the x axis
        if abs(sin_lat_c) > 1e-12:
            raise ValueError(f"lat = {lat}: an equatorial orbit (inclination 0 or 180) has its "
                             "sub-satellite point on the equator")
        return (lon_r if inc < 1 else -lon_r), 0.0
    x = sin_lat_c / si
    if abs(x) > 1.0 + 1e-12:
        maxlat = math.degrees(min(inc, math.pi - inc))
        raise ValueError(f"lat = {lat}: the sub-satellite point of an orbit of inclination "
                         f"{math.degrees(inc):g} deg never goes beyond {maxlat:g} deg (geocentric)")
    # u0 from atan2(sin u0, cos u0) with cos^2 u0 sin^2 i = cos^2 lat_c - cos^2 i, formed from the
    # cosines (precise near the pole, where the sine of the latitude is flat): asin(x) lost half
    # its digits near x = 1 and put the sub-satellite point 11 mm off 1e-7 deg from a pole (the
    # simulation fuzzing, 2026-12-03)
    cos_lat_c = math.hypot(p[0], p[1]) / np.linalg.norm(p)
    ci = abs(math.cos(inc))
    cu = math.sqrt(max(0.0, (cos_lat_c - ci) * (cos_lat_c + ci))) / si
    u0 = math.atan2(max(-1.0, min(1.0, x)), cu)
    if not ascending:
        u0 = math.pi - u0
    raan = lon_r - math.atan2(math.cos(inc) * math.sin(u0), math.cos(u0))
    return u0, raan


def _ray_height_hit(s, l, h, a, f):
    """Distance r along unit l from s to the surface of geodetic height h (NaN if missed)."""
    b = (1.0 - f) * a
    w = np.array([1.0 / (a + h), 1.0 / (a + h), 1.0 / (b + h)])
    ls, ss = l * w, s * w
    qa, qb, qc = ls @ ls, ls @ ss, ss @ ss - 1.0
    disc = qb * qb - qa * qc
    if disc < 0:
        return math.nan
    r = (-qb - math.sqrt(disc)) / qa
    if r < 0:
        return math.nan
    for _ in range(30):                 # Newton on the exact geodetic height
        la, lo, hh = ecef_to_geodetic(s + r * l, a, f)
        slope = float(l @ _normal(la, lo))
        if slope >= 0:
            return math.nan
        step = (hh - h) / slope
        r -= step
        if abs(step) <= 1e-12 * (abs(r) + a):
            break
    return r


# ---------------------------------------------------------------- sensors
class Sensor:
    """Common interface: ``shape`` = (nlines, npixels); ``rays(k0, k1)`` gives
    the focal points and directions of lines k0..k1-1 as (n, 3) arrays, pixels of
    a line contiguous (row-major in (line, pixel))."""

    shape: tuple[int, int]

    @property
    def nlines(self) -> int:
        return self.shape[0]

    @property
    def npixels(self) -> int:
        return self.shape[1]

    @property
    def l(self) -> np.ndarray:
        """Lines of sight (nlines, npixels, 3), ECR: the user's array where one was
        given (``_l``), else built on access from the sensor's own geometry (an
        orbit pushbroom, a pinhole camera: ``_directions``)."""
        if getattr(self, "_l", None) is None:
            return self._directions(0, self.nlines).reshape(self.nlines, self.npixels, 3)
        return self._l

    def _directions(self, k0: int, k1: int) -> np.ndarray:
        # unit directions of lines k0..k1-1, (n, 3); sensors with a model of their own override it
        return self.rays(k0, k1)[1]

    def _check_block(self, k0: int, k1: int) -> tuple[int, int]:
        # integers only: int() truncated rays(0.5, 1.9) to line 0 and rays(True, 2.7) to line 1
        # without a word (the simulation fuzzing, 2026-12-03)
        for name, k in (("k0", k0), ("k1", k1)):
            if isinstance(k, (bool, np.bool_)) or not isinstance(k, (int, np.integer)):
                raise TypeError(f"lines: {name} must be an integer line index, got {k!r}")
        k0, k1 = int(k0), int(k1)
        if not 0 <= k0 <= k1 <= self.nlines:
            raise ValueError(f"lines {k0}:{k1} outside 0:{self.nlines}")
        return k0, k1

    def rays(self, k0: int = 0, k1: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The rays of image lines k0..k1-1.

        Parameters
        ----------
        k0, k1 : int
            First line and one past the last (default: all lines); 0 <= k0 <= k1 <= nlines.

        Returns
        -------
        s, l : arrays ((k1 - k0) * npixels, 3)
            Focal points and line-of-sight directions (ECR; units of the body's
            semi-major axis for ``s``), row-major in (line, pixel). ``s`` may be
            a read-only broadcast view.
        """
        raise NotImplementedError

    def pixel_rays(self, lines, pixels) -> tuple[np.ndarray, np.ndarray]:
        """Focal points and directions of single pixels.

        Parameters
        ----------
        lines, pixels : int arrays (n,)
            Line and pixel index of each wanted ray.

        Returns
        -------
        s, l : arrays (n, 3)
            Focal points and directions, ECR, for (lines[i], pixels[i]).
        """
        lines = np.atleast_1d(np.asarray(lines))
        pixels = np.atleast_1d(np.asarray(pixels))
        if lines.shape != pixels.shape or lines.ndim != 1:
            raise ValueError(f"lines and pixels must be 1-D of one length, got {lines.shape} and {pixels.shape}")
        if lines.dtype.kind not in "iu" or pixels.dtype.kind not in "iu":
            raise TypeError("lines and pixels must be integers")
        if lines.size and ((lines < 0).any() or (lines >= self.nlines).any()):
            raise ValueError(f"lines must be in 0..{self.nlines - 1}, got {lines}")
        if pixels.size and ((pixels < 0).any() or (pixels >= self.npixels).any()):
            raise ValueError(f"pixels must be in 0..{self.npixels - 1}, got {pixels}")
        s_out, l_out = np.empty((lines.size, 3)), np.empty((lines.size, 3))
        for i, (k, m) in enumerate(zip(lines.tolist(), pixels.tolist())):
            s, l = self.rays(k, k + 1)
            s_out[i], l_out[i] = s[m], l[m]
        return s_out, l_out

    def _hits(self, dsm, lines, pixels, method):
        from .intersect import intersect

        s, l = self.pixel_rays(lines, pixels)
        return intersect(dsm, s, l, method=method)

    def footprint_corners(self, dsm, method: str = "exact") -> np.ndarray:
        """Where the four corner pixels look on a DSM.

        Parameters
        ----------
        dsm : GeodeticDSM
            The surface, in the sensor's ECR frame and units.
        method : str
            Intersection method of :func:`planet_intersect.intersect` ("exact" by default).

        Returns
        -------
        corners : array (4, 2)
            Geodetic latitude and east longitude (deg) of the first hits of pixels
            (line 0, pixel 0), (0, last), (last, last), (last, 0) — around the
            image. NaN for a corner whose ray does not hit the DSM (a
            RuntimeWarning names it and its status).
        """
        from .dsm import DSM_RAY_STATUS, GeodeticDSM

        if not isinstance(dsm, GeodeticDSM):
            raise TypeError(f"dsm must be a planet_intersect.GeodeticDSM, got {type(dsm).__name__}")
        kl, ml = self.nlines - 1, self.npixels - 1
        lines, pixels = np.array([0, 0, kl, kl]), np.array([0, ml, ml, 0])
        res = self._hits(dsm, lines, pixels, method)
        out = np.column_stack([res.lat, res.lon])
        for i in np.flatnonzero(~res.hit):
            out[i] = np.nan
            warnings.warn(f"footprint_corners: corner pixel (line {lines[i]}, pixel {pixels[i]}) does not hit "
                          f"the DSM ({DSM_RAY_STATUS.get(int(res.status[i]), res.status[i])})",
                          RuntimeWarning, stacklevel=2)
        return out

    def gsd(self, dsm, method: str = "exact") -> dict:
        """Ground sampling distances on a DSM at the centre and the two edges of the centre line.

        The distance between the first hits of neighbouring pixels (the chord
        between ECR hit points, which equals the ground distance to ~1e-9
        relative at pixel spacings below a kilometre): central differences
        ``|P[m+1] - P[m-1]| / 2`` at the centre pixel, one-sided ones
        ``|P[1] - P[0]|`` and ``|P[n-1] - P[n-2]|`` at the edges. "Across" is
        along the detector line (pixel index), "along" across lines (line index;
        the flight direction of a pushbroom, the row direction of a frame camera).

        Parameters
        ----------
        dsm : GeodeticDSM
        method : str
            Intersection method ("exact" by default).

        Returns
        -------
        dict
            ``"line"``: the line used (nlines // 2); ``"pixel"``: array (3,) of
            the pixels first, centre (npixels // 2), last; ``"across"`` and
            ``"along"``: arrays (3,) of distances there (units of ``dsm.a``). NaN
            where a needed ray misses the DSM, or across with one pixel, along
            with one line.
        """
        from .dsm import GeodeticDSM

        if not isinstance(dsm, GeodeticDSM):
            raise TypeError(f"dsm must be a planet_intersect.GeodeticDSM, got {type(dsm).__name__}")
        nl, npx = self.shape
        kc, mc = nl // 2, npx // 2
        pix = np.array([0, mc, npx - 1])

        def pairs(n, c):   # index pairs (i, j, divisor) at first, centre, last
            if n == 1:
                return None
            lo, hi = (c - 1, c + 1) if 0 < c < n - 1 else (max(c - 1, 0), min(c + 1, n - 1))
            return [(0, 1, 1.0), (lo, hi, float(hi - lo)), (n - 2, n - 1, 1.0)]

        across = np.full(3, np.nan)
        along = np.full(3, np.nan)
        pa = pairs(npx, mc)
        if pa is not None:
            lines = np.full(6, kc)
            pixels = np.array([q for (i, j, _) in pa for q in (i, j)])
            res = self._hits(dsm, lines, pixels, method)
            p = np.where(res.hit[:, None], res.p, np.nan)
            for t, (_, _, div) in enumerate(pa):
                across[t] = np.linalg.norm(p[2 * t + 1] - p[2 * t]) / div
        pl = pairs(nl, kc)
        if pl is not None:
            i0, i1, div = pl[1]
            lines = np.repeat([i0, i1], 3)
            pixels = np.tile(pix, 2)
            res = self._hits(dsm, lines, pixels, method)
            p = np.where(res.hit[:, None], res.p, np.nan)
            along = np.linalg.norm(p[3:] - p[:3], axis=1) / div
        return {"line": kc, "pixel": pix, "across": across, "along": along}


def _nonzero_directions(l: np.ndarray) -> None:
    """ValueError naming the first line of sight l[line, pixel] of zero length (found here,
    not when a simulation reaches its block)."""
    zero = np.max(np.abs(l), axis=-1) == 0
    if zero.any():
        k, m = (int(x) for x in np.argwhere(zero)[0])
        raise ValueError(f"l[{k}, {m}] has zero length: a line of sight needs a direction")


class Pushbroom(Sensor):
    """A pushbroom (line) camera given by the user's geometry, as it is.

    Parameters
    ----------
    s : array (nlines, 3)
        Focal point of each image line, ECR.
    l : array (nlines, npixels, 3)
        Line of sight of each detector of each line, ECR, any non-zero length.

    See :meth:`from_orbit` for a built-in Keplerian orbit.
    """

    def __init__(self, s, l):
        self.s = _array(s, "s", (3,), 2)
        self._l = _array(l, "l", (3,), 3)
        _nonzero_directions(self._l)
        if self._l.shape[0] != self.s.shape[0]:
            raise ValueError(f"s has {self.s.shape[0]} lines but l has {self._l.shape[0]}")
        if self.s.shape[0] == 0 or self._l.shape[1] == 0:
            raise ValueError(f"an image needs at least one line and one pixel, got l of shape {self._l.shape}")
        self.shape = (self._l.shape[0], self._l.shape[1])
        self._m = self._d = None

    def _directions(self, k0, k1):
        # unit ECR directions of lines k0..k1-1: l[k, m] = M_k d_m (orbital frame x attitude x detector)
        return np.matmul(self._d[None], self._m[k0:k1].transpose(0, 2, 1)).reshape(-1, 3)

    def rays(self, k0: int = 0, k1: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        k0, k1 = self._check_block(k0, self.nlines if k1 is None else k1)
        s = np.repeat(self.s[k0:k1], self.npixels, axis=0)
        if self._l is None:
            return s, self._directions(k0, k1)
        return s, self._l[k0:k1].reshape(-1, 3)

    def __repr__(self) -> str:
        return f"Pushbroom({self.nlines} lines x {self.npixels} pixels)"

    @classmethod
    def from_orbit(cls, *, altitude, inclination, npixels, ifov, nlines=1, line_rate=None, line_period=None,
                   lat=None, lon=None, target=None, direction="ascending", roll=0.0, pitch=0.0, yaw=0.0,
                   look_angles=None, eccentricity=0.0, arg_perigee=0.0, yaw_steering=True,
                   a=WGS84_A, f=WGS84_F, gm=EARTH_GM, rotation_rate=EARTH_ROTATION_RATE) -> "Pushbroom":
        """A pushbroom camera on a Keplerian orbit about a rotating ellipsoid.

        *Time*: line k is acquired at ``t_k = (k - (nlines - 1)/2) * line_period``
        seconds after the reference time t_ref (the centre line; ``times``).

        *Orbit*: a Keplerian ellipse (two-body, no perturbations) in an
        inertial frame that coincides with ECR at t_ref; ECR positions are that
        orbit turned by ``-rotation_rate * t_k`` about +z (Earth rotation), so
        the ground track drifts west. At t_ref the satellite is at geodetic
        height ``altitude`` exactly above the sub-satellite point (lat, lon)
        (the foot of the ellipsoid normal through it), on the ascending
        (moving north: argument of latitude in (-90, 90) deg) or descending half
        of the orbit. For ``eccentricity > 0`` the orbit's radius at t_ref is
        that point's and the semi-major axis follows from
        ``r = p / (1 + e cos(nu))``; the period is ``2 pi sqrt(sma^3 / gm)``.
        With ``target`` instead of (lat, lon), the sub-satellite point is
        solved (Newton, to 0.1 mm) so that the boresight of t_ref — after
        roll, pitch and yaw — meets the surface of geodetic height ``h`` at the target.

        *Orbital frame* (per line): z to nadir (down the ellipsoid normal
        through the satellite, "geodetic nadir"), x along track (the ECR
        velocity, i.e. relative to the ground, made perpendicular to z, when
        ``yaw_steering``; the inertial velocity otherwise), y = z cross x (to
        the right of the flight direction).

        *Pointing*: body = orbital frame turned by yaw about z, then pitch about
        the new y, then roll about the newest x (3-2-1 Euler angles, right-hand
        rule; matrix ``Rz(yaw) Ry(pitch) Rx(roll)``). The boresight is body +z,
        so **roll > 0 turns the view to the left of the flight direction**
        (toward -y; west on a north-bound pass) by ``roll`` degrees off nadir,
        **pitch > 0 looks forward** (+x), and yaw > 0 turns the detector line
        clockwise seen from above (its +y end toward -x).

        *Detector*: npixels detectors along body y; pixel m looks at angle
        ``psi_m = (m - (npixels - 1)/2) * ifov`` from the boresight toward +y
        (direction ``(0, sin psi, cos psi)`` in the body frame), or at
        ``look_angles[m]`` when given. Pixel 0 is the leftmost (toward -y).

        Parameters
        ----------
        altitude : float
            Geodetic height of the satellite at t_ref (units of ``a``; m for Earth), > 0.
        inclination : float
            Orbit inclination (deg, [0, 180]; above 90 retrograde, e.g. 98 for sun-synchronous).
        npixels : int
            Detectors in the line.
        ifov : float
            Instantaneous field of view: angle between neighbouring detectors
            (**degrees**, as every angle here; 1 microradian = 5.7296e-5 deg).
        nlines : int
            Image lines (default 1).
        line_rate, line_period : float
            Lines per second, or seconds per line: exactly one of the two (may be
            omitted when ``nlines == 1``).
        lat, lon : float
            Geodetic latitude and east longitude (deg) of the sub-satellite
            point at t_ref; or give ``target``.
        target : (lat, lon) or (lat, lon, h)
            The point (deg, deg, height above the ellipsoid in units of ``a``,
            default 0) that the t_ref boresight looks at.
        direction : "ascending" or "descending"
            Which half of the orbit the reference point is on (north- or south-bound).
        roll, pitch, yaw : float
            Body pointing (deg), see above.
        look_angles : array (npixels,), optional
            Per-pixel across-track look angles (deg, toward +y, in (-90, 90));
            replaces the regular ``ifov`` spacing (``ifov`` then only documents the pixel size).
        eccentricity : float
            Orbit eccentricity, [0, 1) (perigee above the surface).
        arg_perigee : float
            Argument of perigee (deg; irrelevant for a circular orbit).
        yaw_steering : bool
            x axis from the ground-relative (ECR) velocity (default: lines
            perpendicular to the ground track) or from the inertial velocity.
        a, f : float
            Body ellipsoid (WGS-84 by default).
        gm : float
            Gravitational parameter (units of ``a`` cubed per second squared).
        rotation_rate : float
            Body rotation rate (rad/s, about +z; 0 for an inertial body).

        Returns
        -------
        Pushbroom
            With extra attributes: ``times`` (nlines,) s from t_ref, ``velocity``
            (nlines, 3) ECR velocity, ``look_angles`` (npixels,) deg,
            ``frames`` (nlines, 3, 3) columns = body x, y, z axes in ECR,
            ``orbit`` (dict: sma, e, inclination, raan, arg_perigee,
            arg_latitude at t_ref in deg, period s, r_ref, sub-satellite lat/lon).
            Directions are computed per block in :meth:`rays`.
        """
        a, f = check_ellipsoid(a, f)
        gm = _num(gm, "gm", 0.0, lo_open=True)
        omega = _num(rotation_rate, "rotation_rate")
        altitude = _num(altitude, "altitude", 0.0, lo_open=True)
        from .intersect import FAR_LIMIT

        if altitude > FAR_LIMIT * a:
            # (the focal points' check said "p[0] = [9.25e+29 ...] is farther than ...": a review)
            raise ValueError(f"altitude = {altitude:g} is more than {FAR_LIMIT:g} semi-major axes (a = {a:g}): "
                             f"a line of sight from there loses its position at the body to rounding")
        inc = math.radians(_num(inclination, "inclination", 0.0, 180.0))
        npixels = _count(npixels, "npixels")
        nlines = _count(nlines, "nlines", 1, MAX_ORBIT_LINES)
        _pixels(nlines, npixels, "nlines x npixels")
        ifov = _num(ifov, "ifov (deg)", 0.0, 180.0, lo_open=True, hi_open=True)
        roll = math.radians(_num(roll, "roll (deg)", -90.0, 90.0, True, True))
        pitch = math.radians(_num(pitch, "pitch (deg)", -90.0, 90.0, True, True))
        yaw = math.radians(_num(yaw, "yaw (deg)", -360.0, 360.0))
        e = _num(eccentricity, "eccentricity", 0.0, 1.0, hi_open=True)
        argp = math.radians(_num(arg_perigee, "arg_perigee (deg)", -360.0, 360.0))
        if direction not in ("ascending", "descending"):
            raise ValueError(f"direction must be 'ascending' or 'descending', got {direction!r}")
        if not isinstance(yaw_steering, (bool, np.bool_)):
            raise TypeError(f"yaw_steering must be True or False, got {yaw_steering!r}")
        if line_rate is not None and line_period is not None:
            raise ValueError("give line_rate or line_period, not both")
        if line_rate is not None:
            period = 1.0 / _num(line_rate, "line_rate (lines/s)", 0.0, lo_open=True)
        elif line_period is not None:
            period = _num(line_period, "line_period (s)", 0.0, lo_open=True)
        elif nlines == 1:
            period = 0.0
        else:
            raise ValueError(f"nlines = {nlines}: give line_rate (lines/s) or line_period (s)")
        if look_angles is None:
            psi = (np.arange(npixels) - (npixels - 1) / 2.0) * ifov
            if np.abs(psi).max() >= 90.0:
                raise ValueError(f"npixels * ifov: the outer pixels look {np.abs(psi).max():g} deg off the "
                                 "boresight (must stay below 90)")
        else:
            try:
                psi = np.array(look_angles, dtype=np.float64)
            except (TypeError, ValueError):
                raise TypeError(f"look_angles must be an array of numbers, got {look_angles!r}") from None
            if psi.shape != (npixels,):
                raise ValueError(f"look_angles: expected shape ({npixels},) (npixels), got {psi.shape}")
            bad = ~(np.abs(psi) < 90.0)                  # NaN included
            if bad.any():
                k = int(np.argmax(bad))
                raise ValueError(f"look_angles[{k}] = {psi[k]}: must be finite and in (-90, 90) degrees")
        psi_r = np.radians(psi)
        det = np.column_stack([np.zeros(npixels), np.sin(psi_r), np.cos(psi_r)])
        att = _rz(yaw) @ _ry(pitch) @ _rx(roll)
        ascending = direction == "ascending"
        if target is None:
            if lat is None or lon is None:
                raise ValueError("give lat and lon of the sub-satellite point, or target")
            lat = _num(lat, "lat (deg)", -90.0, 90.0)
            lon = _num(lon, "lon (deg)")
            u0, raan = _node_of(lat, lon, inc, ascending, altitude, a, f)
        else:
            if lat is not None or lon is not None:
                raise ValueError("give either lat/lon (sub-satellite point) or target, not both")
            u0, raan = _solve_target(target, inc, ascending, altitude, e, argp, att, yaw_steering,
                                     a, f, gm, omega)
        el = _elements(u0, raan, inc, altitude, e, argp, a, f, gm)
        if not (math.isfinite(el["n"]) and el["n"] > 0):
            # gm = 1e-300 around a = 1e30 gave a zero mean motion and a ZeroDivisionError (a review)
            raise ValueError(f"gm = {gm:g}, a = {a:g}, altitude = {altitude:g}: the orbit has no finite "
                             f"positive mean motion (sqrt(gm / sma^3) = {el['n']!r})")
        if el["sma"] * (1.0 - e) <= a * (1.0 - f):
            raise ValueError(f"eccentricity = {e}: the perigee radius {el['sma'] * (1 - e):.6g} is below "
                             f"the body's polar radius {a * (1 - f):.6g}")
        times = (np.arange(nlines) - (nlines - 1) / 2.0) * period
        r, v = _ecr_states(el, times, omega)
        frames = _body_frames(r, v, att, yaw_steering, omega, a, f)
        _, _, h = ecef_to_geodetic(r, a, f)
        if (np.atleast_1d(h) <= 0).any():
            raise ValueError("the orbit goes below the ellipsoid during the image lines")
        self = object.__new__(cls)
        self.s = r.copy()
        self.s.flags.writeable = False
        self._l = None
        self._m = frames
        self._d = det
        self.shape = (nlines, npixels)
        self.times = times
        self.velocity = v
        self.look_angles = psi
        self.frames = frames
        la0, lo0, _ = ecef_to_geodetic(_ecr_states(el, np.zeros(1), omega)[0][0], a, f)
        self.orbit = {"sma": el["sma"], "e": e, "inclination": math.degrees(inc),
                      "raan": math.degrees(raan) % 360.0, "arg_perigee": math.degrees(argp),
                      "arg_latitude": math.degrees(u0) % 360.0, "period": 2 * math.pi / el["n"],
                      "r_ref": el["r0"], "lat_ref": la0, "lon_ref": lo0, "line_period": period,
                      "a": a, "f": f, "gm": gm, "rotation_rate": omega}
        return self


def _body_frames(r, v, att, yaw_steering, omega, a, f):
    """(n, 3, 3): columns are the body x, y, z axes in ECR, for satellite states r, v (ECR)."""
    la, lo, _ = ecef_to_geodetic(r, a, f)
    z = -np.atleast_2d(_normal(la, lo))
    vel = v if yaw_steering else v + omega * np.stack([-r[:, 1], r[:, 0], np.zeros(len(r))], axis=1)
    x = vel - np.sum(vel * z, axis=1, keepdims=True) * z
    nx = np.linalg.norm(x, axis=1, keepdims=True)
    if (nx <= 1e-12 * np.linalg.norm(vel, axis=1, keepdims=True)).any():
        raise ValueError("the satellite moves along the vertical: the along-track axis is undefined")
    x = x / nx
    y = np.cross(z, x)
    orb = np.stack([x, y, z], axis=2)          # columns x, y, z
    return orb @ att


def _solve_target(target, inc, ascending, altitude, e, argp, att, yaw_steering, a, f, gm, omega):
    """(u0, raan) such that the t_ref boresight meets the geodetic-height-h surface at target."""
    try:
        n = len(target)
    except TypeError:
        raise TypeError(f"target must be (lat, lon) or (lat, lon, h), got {target!r}") from None
    if n not in (2, 3):
        raise ValueError(f"target must be (lat, lon) or (lat, lon, h), got {target!r}")
    tlat = _num(target[0], "target lat (deg)", -90.0, 90.0)
    tlon = _num(target[1], "target lon (deg)")
    th = _num(target[2], "target h") if n == 3 else 0.0
    pt = geodetic_to_ecef(tlat, tlon, th, a, f)
    east, north = _east(tlon), _north(tlat, tlon)
    maxlat = math.degrees(min(inc, math.pi - inc))
    glat = max(-maxlat, min(maxlat, tlat)) * (1 - 1e-9)  # first guess: sub-satellite point at the target
    if math.sin(inc) < 1e-12:
        glat = 0.0
    x = np.array(_node_of(glat, tlon, inc, ascending, altitude, a, f))

    def residual(x):
        el = _elements(x[0], x[1], inc, altitude, e, argp, a, f, gm)
        r, v = _ecr_states(el, np.zeros(1), omega)
        bore = _body_frames(r, v, att, yaw_steering, omega, a, f)[0][:, 2]
        d = _ray_height_hit(r[0], bore, th, a, f)
        if not math.isfinite(d):
            return None
        q = r[0] + d * bore - pt
        return np.array([q @ east, q @ north])

    res = residual(x)
    if res is None:
        raise ValueError(f"target: the boresight (roll/pitch) misses the surface at height {th} from altitude "
                         f"{altitude}")
    fixed_raan = math.sin(inc) < 1e-12           # equatorial: only u0 moves the ground point
    for _ in range(40):
        if np.hypot(*res) < 1e-5:
            break
        eps = 1e-7
        cols = []
        for j in range(2):
            dx = np.zeros(2)
            dx[j] = eps
            rj = residual(x + dx)
            if rj is None:
                raise ValueError("target: the boresight leaves the surface during the solution")
            cols.append((rj - res) / eps)
        jac = np.column_stack(cols)
        if fixed_raan:
            step = np.array([-(jac[:, 0] @ res) / (jac[:, 0] @ jac[:, 0]), 0.0])
        else:
            try:
                step = -np.linalg.solve(jac, res)
            except np.linalg.LinAlgError:
                raise ValueError("target: singular geometry (the boresight does not move with the orbit)") from None
        scale = 1.0
        for _ in range(30):                       # damped: accept the step only if it reduces the miss
            rn = residual(x + scale * step)
            if rn is not None and np.hypot(*rn) < np.hypot(*res):
                break
            scale *= 0.5
        else:
            break
        x, res = x + scale * step, rn
    miss = float(np.hypot(*res))
    if miss > 1e-3 or not math.isfinite(miss):
        raise ValueError(f"target = {tuple(target)}: no orbit of this inclination and altitude whose boresight "
                         f"meets it (closest {miss:.3g} away); is it within reach of the pointing?")
    if (math.cos(x[0]) > 0) != ascending and math.sin(inc) >= 1e-12:
        raise ValueError(f"target = {tuple(target)}: the solution lies on the "
                         f"{'descending' if ascending else 'ascending'} half of the orbit; "
                         "change direction or the pointing")
    return float(x[0]), float(x[1])


class FrameCamera(Sensor):
    """A frame camera: every pixel's ray starts at one focal point.

    Parameters
    ----------
    position : array (3,)
        Focal point, ECR.
    l : array (nrows, ncols, 3)
        Line of sight of each pixel, ECR, any non-zero length.

    See :meth:`pinhole` and :meth:`nadir` for a pinhole camera built from a
    position, a target and a field of view.
    """

    def __init__(self, position, l):
        try:
            shp = np.shape(position)
        except (TypeError, ValueError):                    # ragged: _array names it
            shp = None
        if shp is not None and shp not in ((3,), (1, 3)) and (len(shp) == 1 or (len(shp) == 2 and shp[1] == 3)):
            # (reshaped to (1, n) it was reported as "expected shape (n, 3), got (1, 2)"; a (k, 3) array
            # became a camera at its first row without a word, and (0, 3) an IndexError: reviews)
            raise ValueError(f"position: expected shape (3,), got {shp} (a camera has one focal point)")
        self.position = _array(np.reshape(position, (1, -1)) if np.ndim(position) == 1 else position,
                               "position", (3,), 2)[0]
        self._l = _array(l, "l", (3,), 3)
        _nonzero_directions(self._l)
        if self._l.shape[0] == 0 or self._l.shape[1] == 0:
            raise ValueError(f"an image needs at least one row and one column, got l of shape {self._l.shape}")
        self.shape = (self._l.shape[0], self._l.shape[1])
        self.axes = None

    def _directions(self, k0, k1):
        # pinhole: z_c + (m - cx) p x_c + (k - cy) p y_c, unit
        u = (np.arange(self.npixels) - (self.npixels - 1) / 2.0) * self.pitch
        v = (np.arange(k0, k1) - (self.nlines - 1) / 2.0) * self.pitch
        x, y, z = self.axes[:, 0], self.axes[:, 1], self.axes[:, 2]
        d = z[None, None, :] + u[None, :, None] * x[None, None, :] + v[:, None, None] * y[None, None, :]
        return _unit(d).reshape(-1, 3)

    def rays(self, k0: int = 0, k1: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        k0, k1 = self._check_block(k0, self.nlines if k1 is None else k1)
        l = self._directions(k0, k1) if self._l is None else self._l[k0:k1].reshape(-1, 3)
        return np.broadcast_to(self.position, l.shape), l

    def __repr__(self) -> str:
        return f"FrameCamera({self.nlines} x {self.npixels} pixels)"

    @classmethod
    def pinhole(cls, position, look_at, shape, ifov, rotation=0.0, up=None, geodetic=False,
                a=WGS84_A, f=WGS84_F) -> "FrameCamera":
        """A pinhole frame camera at ``position`` whose optical axis passes through ``look_at``.

        Camera frame: z_c the optical axis (toward ``look_at``), x_c to the
        right of the image (increasing column), y_c down the image (increasing
        row), x_c cross y_c = z_c. Unrotated, the image's up (-y_c) is the
        projection of ``up`` on the image plane — by default the local
        geodetic north at the camera, or the local zenith when the axis is
        within 0.01 deg of north or south (then the image's up points away
        from the ground). ``rotation`` then turns x_c and y_c about z_c by the
        right-hand rule (rotation > 0: x_c toward y_c; the scene appears turned
        the other way).

        Pixel (row k, column m) looks along ``z_c + (m - (ncols-1)/2) p x_c +
        (k - (nrows-1)/2) p y_c`` with the pixel pitch on a unit focal length
        ``p = 2 tan(ifov/2)``, so the central pixel subtends ``ifov`` and the
        corner pixel centres are ``atan((n-1)/2 p)`` off axis in each direction.
        For odd shapes the central pixel's ray passes through ``look_at``.

        Parameters
        ----------
        position : array (3,)
            Focal point: ECR (units of ``a``), or (lat, lon, h) with ``geodetic=True``.
        look_at : array (3,)
            A point on the optical axis: ECR, or (lat, lon, h) with ``geodetic=True``.
        shape : (nrows, ncols)
            Image size in pixels.
        ifov : float
            Angular size of a pixel at the image centre (deg).
        rotation : float
            Turn about the optical axis (deg), see above.
        up : array (3,), optional
            ECR vector whose projection is the image's up (default: north).
        geodetic : bool
            ``position`` and ``look_at`` are (geodetic lat deg, east lon deg,
            height above the ellipsoid (a, f)).
        a, f : float
            Ellipsoid for ``geodetic`` and the default north (WGS-84).

        Returns
        -------
        FrameCamera
            With ``axes`` (3, 3) columns x_c, y_c, z_c in ECR and ``pitch``;
            directions computed per block in :meth:`rays`.
        """
        a, f = check_ellipsoid(a, f)
        if not isinstance(geodetic, (bool, np.bool_)):
            raise TypeError(f"geodetic must be True or False, got {geodetic!r}")
        nrows, ncols = _shape(shape)
        _pixels(nrows, ncols, "shape")
        ifov = _num(ifov, "ifov (deg)", 0.0, 180.0, lo_open=True, hi_open=True)
        rot = math.radians(_num(rotation, "rotation (deg)"))
        pts = []
        for name, v in (("position", position), ("look_at", look_at)):
            arr = _array(np.reshape(v, (1, -1)) if np.ndim(v) == 1 else v, name, (3,), 2)
            if arr.shape[0] != 1:
                raise ValueError(f"{name}: expected shape (3,), got {np.shape(v)}")
            arr = arr[0]
            if geodetic:
                if abs(arr[0]) > 90:
                    raise ValueError(f"{name}: latitude {arr[0]} is outside [-90, 90] degrees")
                arr = geodetic_to_ecef(arr[0], arr[1], arr[2], a, f)
            pts.append(np.asarray(arr, dtype=np.float64))
        pos, tgt = pts
        axis = tgt - pos
        dist = float(np.linalg.norm(axis))
        if dist <= 1e-9 * max(1.0, float(np.linalg.norm(pos))):
            raise ValueError("look_at coincides with position: the optical axis is undefined")
        z = axis / dist
        if up is None:
            la, lo, _ = ecef_to_geodetic(pos, a, f)
            up_v = _north(la, lo)
            if abs(float(up_v @ z)) > math.cos(math.radians(0.01)):
                up_v = _normal(la, lo)
        else:
            up_v = _array(np.reshape(up, (1, -1)) if np.ndim(up) == 1 else up, "up", (3,), 2)
            if up_v.shape[0] != 1:
                raise ValueError(f"up: expected shape (3,), got {np.shape(up)}")
            up_v = np.asarray(up_v[0], dtype=np.float64)
            nu = float(np.linalg.norm(up_v))
            if nu == 0.0 or abs(float(up_v @ z)) > nu * math.cos(math.radians(0.01)):
                raise ValueError("up must not be zero or (within 0.01 deg) parallel to the optical axis")
        y = -(up_v - (up_v @ z) * z)
        y = y / np.linalg.norm(y)
        x = np.cross(y, z)
        xr = math.cos(rot) * x + math.sin(rot) * y
        yr = -math.sin(rot) * x + math.cos(rot) * y
        pitch = 2.0 * math.tan(math.radians(ifov) / 2.0)
        self = object.__new__(cls)
        self.position = pos.copy()
        self.position.flags.writeable = False
        self._l = None
        self.axes = np.column_stack([xr, yr, z])
        self.axes.flags.writeable = False
        self.pitch = pitch
        self.shape = (nrows, ncols)
        return self

    @classmethod
    def nadir(cls, lat, lon, height, shape, ifov, rotation=0.0, a=WGS84_A, f=WGS84_F) -> "FrameCamera":
        """A pinhole camera at geodetic (lat, lon, height) looking straight down the ellipsoid normal.

        The image's top is north and its columns increase eastward (unless
        turned by ``rotation``, see :meth:`pinhole`); at a pole, "north" is the
        limit along the meridian ``lon``: the image's top points along
        ``-(cos lon, sin lon, 0)``.

        Parameters
        ----------
        lat, lon : float
            Geodetic latitude and east longitude (deg).
        height : float
            Height above the ellipsoid (units of ``a``), > 0.
        shape, ifov, rotation, a, f
            As in :meth:`pinhole`.
        """
        a, f = check_ellipsoid(a, f)
        lat = _num(lat, "lat (deg)", -90.0, 90.0)
        lon = _num(lon, "lon (deg)")
        height = _num(height, "height", 0.0, lo_open=True)
        if height > 1e15 * a:
            raise ValueError(f"height = {height:g}: at most 1e15 a (the direction of a unit vector is "
                             f"resolved to ~1e-16)")
        pos = geodetic_to_ecef(lat, lon, height, a, f)
        down = -_normal(lat, lon)
        # the look-at point a semi-major axis down the normal (height * down rounded onto pos for
        # heights below ~6 mm and overflowed at 1e300: "look_at coincides with position", a review)
        return cls.pinhole(pos, pos + a * down, shape, ifov, rotation=rotation, up=_north(lat, lon),
                           a=a, f=f)
