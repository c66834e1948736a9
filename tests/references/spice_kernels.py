"""Offline SPICE kernels for the footprint tests, and SPICE cross-check helpers (issue 13).

Everything is written at test time into a directory the caller gives (pytest's
``tmp_path``): nothing is downloaded, nothing generated is committed.

Choices (where the notes, the issue and the contract are silent):

S1. Leapseconds: a complete, valid LSK text (the standard DELTET constants and
    the 28 leap seconds from 1972 to 2017-JAN-1, TAI - UTC = 37 s after it).
S2. PCK: Mars (499) radii from the DEM's own re and f (a = b = re,
    c = re (1 - f)); the IAU 2000 Mars orientation (pole RA 317.68143 -
    0.1061 T, Dec 52.88650 - 0.0609 T deg, T in Julian centuries; prime
    meridian W = 176.630 + 350.89198226 d deg, d in days from J2000 TDB).
    With a positive W rate Mars is a prograde rotator, so SPICE's
    planetographic longitude (``recpgr``) is positive WEST; ``pgr_latlon``
    converts it to east longitude, lon_east = (-lon_west) mod 360.
S3. SPK: type 5 (two-body) segments in J2000, which reproduce a Keplerian
    orbit exactly between the given states. Target -53 (Mars Odyssey's NAIF
    code), centre 499, GM 42828.37 km^3/s^2; the orbit: periapsis altitude
    387 km and apoapsis 450 km above re (so a = re + 418.5 km, e = 63 / (2 a)),
    inclination 93.1 deg (Odyssey's near-polar sun-synchronous mapping
    orbit), node 30 deg, argument of periapsis 270 deg (periapsis over the
    south, as Odyssey's frozen orbit), mean anomaly 0 at the epoch
    2002-03-01T00:00:00 TDB (ET = 68 212 800 s), states every 60 s over
    ``hours`` hours. A second type-5 segment puts the Sun (10) on a
    heliocentric Mars-like orbit about Mars (GM_sun), only because ``ilumin``
    needs the Sun; no test uses illumination.
S4. The Keplerian states are computed here independently of SPICE: mean
    anomaly -> eccentric anomaly by Newton iteration (to 1e-15 rad), then the
    perifocal state rotated by R3(-node) R1(-i) R3(-argp).
S5. Cross-check helpers: ``ilumin`` with method ELLIPSOID, abcorr NONE,
    frame IAU_MARS (its emission angle is measured from the spheroid's outward
    normal at the point, i.e. the areodetic zenith); ``subpnt`` with
    INTERCEPT/ELLIPSOID (the surface point along -R: the areocentric
    sub-spacecraft point) or NEAR POINT/ELLIPSOID (the foot of the spheroid
    normal through the spacecraft: the areodetic one); ``twovec(R, 1, v, 2)``
    whose rows are x = R/|R|, y = the unit component of v normal to R, z = x cross y
    (the contract's frame).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

__all__ = ["ODYSSEY", "MARS", "GM_MARS", "GM_SUN", "EPOCH_ET", "write_lsk", "write_pck", "kepler_state",
           "odyssey_elements", "write_spk", "MarsKernels", "states_iau_mars", "states_j2000", "et_of", "iau_mars_matrix",
           "ilumin_emission", "subpnt_latlon", "pgr_latlon", "twovec_frame"]

ODYSSEY = -53
MARS = 499
GM_MARS = 42828.37
GM_SUN = 1.32712440018e11
#: 2002-03-01T00:00:00 TDB in seconds past J2000 TDB
EPOCH_ET = (
    (2002 - 2000) * 365 * 86400.0 + 1 * 86400.0            # 2000 was a leap year
    + (31 + 28) * 86400.0 - 12 * 3600.0)

_LEAPS = [(10, "1972-JAN-1"), (11, "1972-JUL-1"), (12, "1973-JAN-1"), (13, "1974-JAN-1"), (14, "1975-JAN-1"),
          (15, "1976-JAN-1"), (16, "1977-JAN-1"), (17, "1978-JAN-1"), (18, "1979-JAN-1"), (19, "1980-JAN-1"),
          (20, "1981-JUL-1"), (21, "1982-JUL-1"), (22, "1983-JUL-1"), (23, "1985-JUL-1"), (24, "1988-JAN-1"),
          (25, "1990-JAN-1"), (26, "1991-JAN-1"), (27, "1992-JUL-1"), (28, "1993-JUL-1"), (29, "1994-JUL-1"),
          (30, "1996-JAN-1"), (31, "1997-JUL-1"), (32, "1999-JAN-1"), (33, "2006-JAN-1"), (34, "2009-JAN-1"),
          (35, "2012-JUL-1"), (36, "2015-JUL-1"), (37, "2017-JAN-1")]


def write_lsk(path) -> Path:
    """A valid leapseconds kernel (S1)."""
    path = Path(path)
    leaps = "\n".join(f"                           {n:2d}, @{d}" for n, d in _LEAPS)
    path.write_text(
        "KPL/LSK\n\nLeapseconds kernel written by the planet-intersect tests (S1).\n\n"
        "\\begindata\n\n"
        "DELTET/DELTA_T_A       =   32.184\n"
        "DELTET/K               =    1.657D-3\n"
        "DELTET/EB              =    1.671D-2\n"
        "DELTET/M               = (  6.239996D0   1.99096871D-7 )\n"
        "DELTET/DELTA_AT        = (\n" + leaps + " )\n\n"
        "\\begintext\n")
    return path


def write_pck(path, re: float, f: float) -> Path:
    """A text PCK for Mars: radii (re, re, re (1 - f)) and the IAU 2000 orientation (S2)."""
    path = Path(path)
    c = re * (1.0 - f)
    path.write_text(
        "KPL/PCK\n\nMars constants written by the planet-intersect tests (S2).\n\n"
        "\\begindata\n\n"
        f"BODY499_RADII     = ( {re!r:s} {re!r:s} {c!r:s} )\n"
        "BODY499_POLE_RA   = ( 317.68143   -0.1061    0. )\n"
        "BODY499_POLE_DEC  = (  52.88650   -0.0609    0. )\n"
        "BODY499_PM        = ( 176.630    350.89198226 0. )\n\n"
        "\\begintext\n")
    return path


def odyssey_elements(re: float, peri_alt=387.0, apo_alt=450.0, inc=93.1, node=30.0, argp=270.0, m0=0.0):
    """Keplerian elements (a km, e, i, node, argp, M0 deg) of the Odyssey-like orbit (S3)."""
    rp, ra = re + peri_alt, re + apo_alt
    a = 0.5 * (rp + ra)
    return dict(a=a, e=(ra - rp) / (ra + rp), inc=inc, node=node, argp=argp, m0=m0)


def kepler_state(el: dict, gm: float, et, epoch=EPOCH_ET) -> np.ndarray:
    """J2000 state(s) (N, 6) km, km/s of an elliptic Keplerian orbit at ET(s) (S4)."""
    et = np.atleast_1d(np.asarray(et, dtype=np.float64))
    a, e = el["a"], el["e"]
    n = math.sqrt(gm / a ** 3)
    M = np.radians(el["m0"]) + n * (et - epoch)
    M = np.mod(M + np.pi, 2 * np.pi) - np.pi
    E = M + e * np.sin(M)
    for _ in range(50):
        step = (E - e * np.sin(E) - M) / (1.0 - e * np.cos(E))
        E = E - step
        if np.max(np.abs(step)) < 1e-15:
            break
    cE, sE = np.cos(E), np.sin(E)
    b = a * math.sqrt(1.0 - e * e)
    pos = np.stack([a * (cE - e), b * sE, 0 * E], axis=1)
    vel = np.stack([-a * n * sE / (1 - e * cE), b * n * cE / (1 - e * cE), 0 * E], axis=1)

    def r1(t):
        c, s = math.cos(t), math.sin(t)
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])

    def r3(t):
        c, s = math.cos(t), math.sin(t)
        return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])

    Q = r3(math.radians(el["node"])) @ r1(math.radians(el["inc"])) @ r3(math.radians(el["argp"]))
    return np.concatenate([pos @ Q.T, vel @ Q.T], axis=1)


def _sun_elements():
    # Sun about Mars = minus Mars about the Sun: a heliocentric Mars-like ellipse (S3)
    return dict(a=227.9392e6, e=0.0934, inc=24.7, node=3.4, argp=250.0, m0=20.0)


def write_spk(path, re: float, hours: float = 6.0, step: float = 60.0, elements: dict | None = None) -> Path:
    """Type-5 SPK: Odyssey-like orbit (-53 about 499) and the Sun (10 about 499), J2000 (S3)."""
    import spiceypy as sp

    path = Path(path)
    if path.exists():
        path.unlink()
    el = elements or odyssey_elements(re)
    t = EPOCH_ET + np.arange(0.0, hours * 3600.0 + step, step)
    handle = sp.spkopn(str(path), "planet-intersect tests", 0)
    try:
        sp.spkw05(handle, ODYSSEY, MARS, "J2000", float(t[0]), float(t[-1]), "ODYSSEY-LIKE KEPLER",
                  GM_MARS, len(t), kepler_state(el, GM_MARS, t), t)
        ts = EPOCH_ET + np.arange(-2.0, 3.0) * 86400.0 * max(1.0, math.ceil(hours / 24.0))
        sp.spkw05(handle, 10, MARS, "J2000", float(ts[0]), float(ts[-1]), "SUN ABOUT MARS",
                  GM_SUN, len(ts), kepler_state(_sun_elements(), GM_SUN, ts), ts)
    finally:
        sp.spkcls(handle)
    return path


class MarsKernels:
    """Write LSK, PCK and SPK into ``directory`` and load them; ``close()`` unloads exactly these."""

    def __init__(self, directory, re: float, f: float, hours: float = 6.0):
        import spiceypy as sp

        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        self.re, self.f = re, f
        self.elements = odyssey_elements(re)
        self.files = [str(write_lsk(d / "test.tls")), str(write_pck(d / "mars.tpc", re, f)),
                      str(write_spk(d / "odyssey.bsp", re, hours))]
        self.et0, self.et1 = EPOCH_ET, EPOCH_ET + hours * 3600.0
        for k in self.files:
            sp.furnsh(k)

    def close(self):
        import spiceypy as sp

        for k in self.files:
            sp.unload(k)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def et_of(times) -> np.ndarray:
    """ET (s past J2000 TDB) of UTC strings (via str2et and the loaded LSK); numbers pass as ET."""
    import spiceypy as sp

    if isinstance(times, (str, float, int, np.floating, np.integer)):
        items = [times]
    elif isinstance(times, np.ndarray):
        items = times.ravel().tolist()
    else:
        items = list(times)
    return np.array([sp.str2et(t) if isinstance(t, str) else float(t) for t in items])


def iau_mars_matrix(et) -> np.ndarray:
    """J2000 -> IAU_MARS rotation from the PCK's formulas, computed here (S2): Rz(W) Rx(90 - dec)
    Rz(90 + ra), so that the PCK text can be checked against SPICE's pxform."""
    d = float(et) / 86400.0
    T = d / 36525.0
    ra, dec = math.radians(317.68143 - 0.1061 * T), math.radians(52.88650 - 0.0609 * T)
    W = math.radians((176.630 + 350.89198226 * d) % 360.0)

    def rz(t):
        c, s = math.cos(t), math.sin(t)
        return np.array([[c, s, 0], [-s, c, 0], [0, 0, 1.0]])

    def rx(t):
        c, s = math.cos(t), math.sin(t)
        return np.array([[1.0, 0, 0], [0, c, s], [0, -s, c]])

    return rz(W) @ rx(math.pi / 2 - dec) @ rz(math.pi / 2 + ra)


def states_j2000(et):
    """spkezr(-53, et, J2000, NONE, 499): (N, 6)."""
    import spiceypy as sp

    return np.array([sp.spkezr(str(ODYSSEY), float(t), "J2000", "NONE", str(MARS))[0]
                     for t in np.atleast_1d(et)])


def states_iau_mars(et):
    """Spacecraft R (N, 3) km and v (N, 3) km/s in IAU_MARS from the loaded kernels; ``et`` are
    ETs or UTC strings (``et_of``)."""
    import spiceypy as sp

    s = np.array([sp.spkezr(str(ODYSSEY), float(t), "IAU_MARS", "NONE", str(MARS))[0]
                  for t in et_of(et)])
    return s[:, :3], s[:, 3:]


def ilumin_emission(spoint, et) -> np.ndarray:
    """SPICE ilumin emission angle (deg) at IAU_MARS points (N, 3) seen by -53 at ET(s) (S5)."""
    import spiceypy as sp

    spoint = np.atleast_2d(np.asarray(spoint, dtype=np.float64))
    et = np.broadcast_to(np.asarray(et, dtype=np.float64), (len(spoint),))
    out = np.empty(len(spoint))
    for k, (p, t) in enumerate(zip(spoint, et)):
        out[k] = sp.ilumin("ELLIPSOID", "MARS", float(t), "IAU_MARS", "NONE", str(ODYSSEY), p)[4]
    return np.degrees(out)


def subpnt_latlon(et, method="INTERCEPT/ELLIPSOID"):
    """Sub-spacecraft point from SPICE subpnt (S5): (points (N, 3), areocentric lat, east lon deg)."""
    import spiceypy as sp

    pts = np.array([sp.subpnt(method, "MARS", float(t), "IAU_MARS", "NONE", str(ODYSSEY))[0]
                    for t in np.atleast_1d(et)])
    lat = np.degrees(np.arctan2(pts[:, 2], np.hypot(pts[:, 0], pts[:, 1])))
    lon = np.degrees(np.arctan2(pts[:, 1], pts[:, 0])) % 360.0
    return pts, lat, lon


def pgr_latlon(points, re: float, f: float):
    """SPICE recpgr on Mars (S2): planetographic (= areodetic) latitude and EAST longitude (deg),
    converted from SPICE's positive-west planetographic longitude, and height (km)."""
    import spiceypy as sp

    pts = np.atleast_2d(np.asarray(points, dtype=np.float64))
    out = np.array([sp.recpgr("MARS", p, re, f) for p in pts])
    lon_west = np.degrees(out[:, 0])
    return np.degrees(out[:, 1]), np.mod(-lon_west, 360.0), out[:, 2]


def twovec_frame(R, v) -> np.ndarray:
    """SPICE twovec(R, 1, v, 2): rows x = R^, y = unit(v - (v.x)x), z = x cross y; (N, 3, 3) (S5)."""
    import spiceypy as sp

    R = np.atleast_2d(np.asarray(R, dtype=np.float64))
    v = np.atleast_2d(np.asarray(v, dtype=np.float64))
    return np.array([sp.twovec(r, 1, w, 2) for r, w in zip(R, v)])
