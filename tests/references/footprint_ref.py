"""Independent references for the footprint geometry of issue 13 (Mars Odyssey GRS notes).

Written only from the source notes (seed 003), the shared contract
(``/work/briefs/footprint-contract.md``, DESIGN.md section 10) and textbook
geometry; nothing here calls or copies the package's footprint code. NumPy and
SciPy only (SciPy for ``quad``, ``brentq`` and the Bessel function ``k1e``).

Conventions (the contract's): planet-fixed frame, x to (0 N, 0 E), z north;
latitudes areocentric unless named ``*_detic``; east longitudes; angles in
DEGREES at every public function here unless a name says ``_rad``; lengths in
km for the Mars numbers.

Choices made where the notes and the contract are silent (numbered so that the
tests and the report can refer to them):

R1. Sphere closed forms. A spacecraft at radius ``Rs`` above the
    sub-spacecraft point (lat_s, lon_s) and a cell point at radius ``R0`` at
    (lat_c, lon_c) span the plane of centre, cell and spacecraft. The central
    angle gamma comes from Vincenty's atan2 form of the spherical law of
    cosines (stable for small and large gamma); then, in that plane triangle
    (angles gamma at the centre, psi at the spacecraft, 180 - z at the cell):
    distance**2 = (Rs - R0)**2 + 4 Rs R0 sin**2(gamma/2) (the law of cosines
    written without cancellation), psi = atan2(R0 sin gamma, Rs - R0 cos gamma)
    (law of sines / tangents), zenith z = gamma + psi (angle sum). On a sphere
    the zenith with either normal and the emission are all equal to z.
R2. Position angle = the initial great-circle bearing from the sub-spacecraft
    point to the cell, atan2(sin dlon cos lat2, cos lat1 sin lat2 - sin lat1
    cos lat2 cos dlon), on AREOCENTRIC latitudes (the directions R/|R| and
    r_C/|r_C|), mapped to [0, 360). It equals the azimuth of r_C - R projected
    on the tangent plane at the sub-spacecraft point, because the great circle
    through the two directions has that projection as its tangent. It is
    undefined for a spacecraft exactly over a pole and for a cell exactly at
    the sub-spacecraft point; the tests avoid both.
R3. Areodetic latitude on the spheroid: tan(lat_detic) = tan(lat) / (1 - f)**2
    (1 - e**2 = (1 - f)**2), evaluated as atan2(sin lat, (1 - f)**2 cos lat) so
    that the poles are exact. For a point off the spheroid the areodetic
    latitude is that of the spheroid normal through the point, found by Newton
    iteration on the ellipse's parametric angle in the meridian plane (at most
    60 steps, stops at a step below 1e-15 rad; NaN input gives NaN out).
R4. The latitude series of the notes: printed as lat' = lat - m sin 2lat +
    (1/2) m**2 sin 2lat - ...; the second term's argument is garbled in the
    text conversion and is read here as sin 4lat (the only reading in which it
    is the next term of a series); ``detic_series_notes`` is that reading, and
    ``detic_series_corrected`` = lat + m sin 2lat + (m**2/2) sin 4lat (the
    series of tan lat' = k tan lat with p = (k-1)/(k+1) = e**2/(2 - e**2) = m).
R5. The tilted plane patch: a sphere of radius R0 whose radii inside a
    lat/lon box are replaced by the distance along each pixel centre's
    direction u to the plane n . x = c (r = c / (n . u)); the plane passes
    through R0 u0 at the box centre u0 and its normal n is u0 tilted by
    ``tilt_deg`` toward the azimuth ``tilt_az_deg`` (clockwise from north).
    The DEM samples lie exactly on the plane; the DEM surface between them is
    bilinear in lat/lon, so its local normal departs from n: by up to 1.5e-3
    rad at 8 ppd (``bilinear_normal_spread``, the largest departure over a
    cell, from my own bilinear interpolation of the samples, pixel centres at
    (j + 1/2)/ppd, the DEM format's registration), because a plane is curved
    in (lat, lon, r) and its piecewise-linear interpolant's slope errs by
    O(pixel x curvature). These errors cancel over a cell: the area-weighted
    mean normal of the bilinear surface (``bilinear_mean_normal``) is within
    8-9e-7 rad of n at 8 ppd (2.5e-7 at 16 ppd), and a least-squares plane
    through the samples in the cell gives n to 1e-14. The contract test
    accepts 10 x the mean normal's departure (+ 1e-9 rad): ~9e-6 rad at 8 ppd,
    which any normal built as an average over the cell meets and a normal off
    by 1e-4 rad (or a radial one, 20 deg off) does not.
R6. Flux fraction on a sphere: the weight per unit SURFACE AREA of a point at
    central angle gamma from the sub-spacecraft point is
    w = (solid angle A/d**2) * cos(e)**cos_power, e the emission angle (= z on a
    sphere). ``cos_power`` = 1 (default) is the contract's "solid_angle *
    cos(emission)"; 0 is pure solid angle. The visible cap is z < 90 deg
    (gamma < arccos(R0/Rs)). By symmetry about the nadir the cap integral is
    the 1-D integral over gamma of w(gamma) sin(gamma) (area element
    R0**2 sin gamma dgamma dphi; the phi integral cancels in the ratio),
    evaluated with ``scipy.integrate.quad`` to 1e-12 relative. The cone
    cos psi >= zeta is gamma <= gamma(zeta) with gamma(zeta) = arcsin(Rs sin
    psi / R0) - psi (near-side branch), psi = arccos(zeta).
R7. Chapman air mass: X(z) = (1/H) * integral over s from 0 to infinity of
    exp(-(r(s) - R)/H) ds along the straight line from radius R at zenith
    angle z, r(s)**2 = R**2 + s**2 + 2 R s cos z. Change of variable t = s/H;
    r - R is written as (s**2 + 2 R s cos z)/(r + R) (no cancellation).
    Beyond 90 deg the line passes its tangent point (t = -R cos z / H), where
    the integrand peaks; the quadrature is split there. Known values used to
    check it: at 90 deg X = x e**x K1(x), x = R/H, exactly (s = R sinh u), whose
    large-x limit is sqrt(pi x / 2) (1 + 3/(8x) + ...); beyond 90 deg
    Ch(x, z) = 2 exp(x (1 - sin z)) Ch(x sin z, 90) - Ch(x, 180 - z).
R8. The notes' air-mass series is taken EXACTLY as printed:
    X = sec z - 0.018167 (sec z - 1)**2 - 0.002875 (sec z - 1)**3
        - 0.0008083 (sec z - 1)**4;
    Hardie (1962), as the contract writes it:
    X = sec z - 0.0018167 (sec z - 1) - 0.002875 (sec z - 1)**2
        - 0.0008083 (sec z - 1)**3.
R9. The notes' position-angle recipe, literally: Q1 = P x R^, Q2 = R^ x r^_C,
    cos PA = (R^ x Q1) . (Q2 x R^), with P = (0, 0, 1) and unit R^, r^_C but
    NO normalisation of the cross products (|R^ x Q1| = cos lat_s,
    |Q2 x R^| = sin gamma), so that the cosine is shrunk toward 0 and the angle
    toward 90 deg; ``position_angle_notes_normalised`` normalises them (then the
    angle is the true bearing folded into [0, 180]: east and west coincide).
R10. Scale height H = k T / (m g), g = GM / r**2; Mars defaults: GM =
    42828.37 km**3/s**2 (the value the brief gives), mean molecular mass 43.34
    u (95 % CO2, 2.6 % N2, 1.9 % Ar), r = 3389.5 km; T has no default.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import integrate, optimize, special

__all__ = [
    "MARS_GM", "BOLTZMANN", "AMU", "MARS_MEAN_MOLECULAR_MASS",
    "unit", "angle_deg", "xyz", "latlon", "central_angle", "bearing",
    "sphere_pair", "spheroid_point", "detic_from_centric", "centric_from_detic", "detic_of_point",
    "spheroid_normal", "fd_spheroid_normal", "zenith_detic", "detic_series_notes",
    "detic_series_corrected", "tilted_plane_dem", "bilinear_normal_spread", "bilinear_mean_normal",
    "position_angle_notes_literal", "position_angle_notes_normalised",
    "visible_cap_angle", "gamma_of_zeta", "flux_fraction_sphere", "zeta_for_fraction",
    "airmass_secant", "airmass_notes", "airmass_hardie", "airmass_chapman",
    "chapman_90_exact", "chapman_90_asymptotic", "chapman_beyond_90_identity", "scale_height",
    "quat_to_matrix",
]

#: Mars GM, km^3/s^2 (the brief's value)
MARS_GM = 42828.37
#: Boltzmann constant, J/K (exact, SI 2019)
BOLTZMANN = 1.380649e-23
#: atomic mass unit, kg
AMU = 1.66053906660e-27
#: mean molecular mass of the Mars atmosphere, u (R10)
MARS_MEAN_MOLECULAR_MASS = 43.34


# ----------------------------------------------------------------------------- helpers

def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def angle_deg(a, b):
    """Angle between vectors (last axis), degrees, atan2(|a x b|, a . b): accurate at 0 and 180."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))


def xyz(lat_deg, lon_deg, r=1.0):
    """Planet-fixed Cartesian point from areocentric latitude, east longitude (deg) and radius."""
    la, lo = np.radians(lat_deg), np.radians(lon_deg)
    r = np.asarray(r, dtype=np.float64)
    return np.stack(np.broadcast_arrays(r * np.cos(la) * np.cos(lo), r * np.cos(la) * np.sin(lo),
                                        r * np.sin(la)), axis=-1)


def latlon(p):
    """Areocentric latitude and east longitude in [0, 360) of points p (..., 3), degrees."""
    p = np.asarray(p, dtype=np.float64)
    lat = np.degrees(np.arctan2(p[..., 2], np.hypot(p[..., 0], p[..., 1])))
    lon = np.degrees(np.arctan2(p[..., 1], p[..., 0])) % 360.0
    return lat, lon


# ----------------------------------------------------------------------------- sphere (R1, R2)

def central_angle(lat1, lon1, lat2, lon2):
    """Great-circle central angle, degrees (Vincenty's atan2 form of the spherical law of cosines)."""
    p1, p2 = np.radians(lat1), np.radians(lat2)
    dl = np.radians(np.asarray(lon2, dtype=np.float64) - lon1)
    num = np.hypot(np.cos(p2) * np.sin(dl), np.cos(p1) * np.sin(p2) - np.sin(p1) * np.cos(p2) * np.cos(dl))
    den = np.sin(p1) * np.sin(p2) + np.cos(p1) * np.cos(p2) * np.cos(dl)
    return np.degrees(np.arctan2(num, den))


def bearing(lat1, lon1, lat2, lon2):
    """Initial great-circle bearing from point 1 to point 2, clockwise from north, [0, 360) deg (R2).

    Standard spherical trigonometry: atan2(sin dlon cos lat2, cos lat1 sin lat2 -
    sin lat1 cos lat2 cos dlon). Use areocentric latitudes for the position angle.
    """
    p1, p2 = np.radians(lat1), np.radians(lat2)
    dl = np.radians(np.asarray(lon2, dtype=np.float64) - lon1)
    b = np.degrees(np.arctan2(np.sin(dl) * np.cos(p2), np.cos(p1) * np.sin(p2) - np.sin(p1) * np.cos(p2) * np.cos(dl)))
    b = np.mod(b, 360.0)
    return np.where(b >= 360.0, 0.0, b)   # mod of a tiny negative can round to 360


def sphere_pair(R0, sc_lat, sc_lon, sc_radius, cell_lat, cell_lon, area=3.4e-9):
    """Every per-pair quantity for a spherical planet of radius R0, from the plane triangle (R1).

    Parameters
    ----------
    R0 : planet radius (km); the cell point is at R0.
    sc_lat, sc_lon, sc_radius : areocentric latitude, east longitude (deg) and radius (km) of the
        spacecraft.
    cell_lat, cell_lon : the cell's latitude and east longitude (deg).
    area : detector projected area (km^2), 34 cm^2 by default.

    Returns
    -------
    dict with gamma (central angle, deg), distance (km), solid_angle (sr), nadir_angle psi (deg),
    zenith (deg; = zenith_centric = zenith_detic = emission on a sphere), position_angle (deg).
    """
    g = np.radians(central_angle(sc_lat, sc_lon, cell_lat, cell_lon))
    Rs = np.asarray(sc_radius, dtype=np.float64)
    dist = np.sqrt((Rs - R0) ** 2 + 4.0 * Rs * R0 * np.sin(0.5 * g) ** 2)
    psi = np.arctan2(R0 * np.sin(g), Rs - R0 * np.cos(g))
    z = g + psi
    return {
        "gamma": np.degrees(g),
        "distance": dist,
        "solid_angle": area / dist ** 2,
        "nadir_angle": np.degrees(psi),
        "zenith": np.degrees(z),
        "position_angle": bearing(sc_lat, sc_lon, cell_lat, cell_lon),
    }


# ----------------------------------------------------------------------------- spheroid (R3, R4)

def spheroid_point(lat_deg, lon_deg, re, f):
    """Point of the spheroid (re, b = re (1 - f)) at areocentric latitude / east longitude (deg)."""
    b = re * (1.0 - f)
    la = np.radians(lat_deg)
    r = re * b / np.sqrt((b * np.cos(la)) ** 2 + (re * np.sin(la)) ** 2)
    return xyz(lat_deg, lon_deg, r)


def detic_from_centric(lat_deg, f):
    """Areodetic latitude of the spheroid point at areocentric latitude lat (deg): exact (R3)."""
    la = np.radians(lat_deg)
    return np.degrees(np.arctan2(np.sin(la), (1.0 - f) ** 2 * np.cos(la)))


def centric_from_detic(lat_detic_deg, f):
    """Inverse of detic_from_centric on the spheroid (deg)."""
    la = np.radians(lat_detic_deg)
    return np.degrees(np.arctan2((1.0 - f) ** 2 * np.sin(la), np.cos(la)))


def detic_of_point(p, re, f, max_iter=60):
    """Areodetic latitude (deg), east longitude (deg) and height (km) of arbitrary points (R3).

    Newton iteration for the parametric angle t of the foot point (a cos t, b sin t) of
    (rho, z) on the meridian ellipse: g(t) = (a^2 - b^2) sin t cos t - a rho sin t + b z cos t = 0.
    The latitude of the normal there is atan2(a sin t, b cos t).
    """
    p = np.asarray(p, dtype=np.float64)
    a, b = re, re * (1.0 - f)
    rho = np.hypot(p[..., 0], p[..., 1])
    z = p[..., 2]
    t = np.arctan2(a * z, b * rho)
    for _ in range(max_iter):
        s, c = np.sin(t), np.cos(t)
        g = (a * a - b * b) * s * c - a * rho * s + b * z * c
        dg = (a * a - b * b) * (c * c - s * s) - a * rho * c - b * z * s
        step = g / dg
        t = t - step
        if not np.any(np.abs(step) > 1e-15):   # NaN compares False: NaN input stops too
            break
    lat = np.arctan2(a * np.sin(t), b * np.cos(t))
    foot_rho, foot_z = a * np.cos(t), b * np.sin(t)
    h = (rho - foot_rho) * np.cos(lat) + (z - foot_z) * np.sin(lat)
    lon = np.degrees(np.arctan2(p[..., 1], p[..., 0])) % 360.0
    return np.degrees(lat), lon, h


def spheroid_normal(lat_detic_deg, lon_deg):
    """Outward unit normal of the spheroid at areodetic latitude / east longitude (the notes' n_Cell)."""
    return xyz(lat_detic_deg, lon_deg, 1.0)


def fd_spheroid_normal(lat_deg, lon_deg, re, f, h_deg=1e-4):
    """Spheroid normal by central finite differences of the surface parametrisation (areocentric
    lat/lon): unit(dP/dlon x dP/dlat). Independent of R3; not valid at the poles."""
    dlon = (spheroid_point(lat_deg, lon_deg + h_deg, re, f) - spheroid_point(lat_deg, lon_deg - h_deg, re, f))
    dlat = (spheroid_point(lat_deg + h_deg, lon_deg, re, f) - spheroid_point(lat_deg - h_deg, lon_deg, re, f))
    return unit(np.cross(dlon, dlat))


def zenith_detic(R, p, lat_detic_deg, lon_deg):
    """Angle (deg) between d = R - p and the spheroid normal at (lat_detic, lon)."""
    d = np.asarray(R, dtype=np.float64) - np.asarray(p, dtype=np.float64)
    return angle_deg(d, spheroid_normal(lat_detic_deg, lon_deg))


def _m_of_f(f):
    e2 = f * (2.0 - f)
    return e2 / (2.0 - e2)


def detic_series_notes(lat_deg, f):
    """The notes' series as printed, second term read as sin 4lat (R4): lat - m sin 2lat + m^2/2 sin 4lat."""
    m = _m_of_f(f)
    la = np.radians(lat_deg)
    return np.degrees(la - m * np.sin(2 * la) + 0.5 * m * m * np.sin(4 * la))


def detic_series_corrected(lat_deg, f):
    """The series with the right sign (R4): lat + m sin 2lat + m^2/2 sin 4lat."""
    m = _m_of_f(f)
    la = np.radians(lat_deg)
    return np.degrees(la + m * np.sin(2 * la) + 0.5 * m * m * np.sin(4 * la))


# ----------------------------------------------------------------------------- tilted plane (R5)

def _pixel_centres(ppd):
    lat = -90.0 + (np.arange(180 * ppd) + 0.5) / ppd
    lon = (np.arange(360 * ppd) + 0.5) / ppd
    return lat, lon


def tilted_plane_dem(ppd, R0, lat0, lon0, half_width_deg, tilt_deg, tilt_az_deg):
    """Radii (180 ppd, 360 ppd), row 0 south, of a sphere R0 with a tilted plane patch (R5).

    Returns ``(radii, n, c)``: the plane is n . x = c, n its outward unit normal (planet frame).
    The patch is |lat - lat0| <= half_width and |lon - lon0| <= half_width (no wrap: keep it
    away from 0/360 and the poles).
    """
    u0 = xyz(lat0, lon0, 1.0)
    north = np.array([-np.sin(np.radians(lat0)) * np.cos(np.radians(lon0)),
                      -np.sin(np.radians(lat0)) * np.sin(np.radians(lon0)),
                      np.cos(np.radians(lat0))])
    east = np.array([-np.sin(np.radians(lon0)), np.cos(np.radians(lon0)), 0.0])
    az, t = np.radians(tilt_az_deg), np.radians(tilt_deg)
    n = unit(np.cos(t) * u0 + np.sin(t) * (np.cos(az) * north + np.sin(az) * east))
    c = float(np.dot(n, R0 * u0))
    lat, lon = _pixel_centres(ppd)
    radii = np.full((lat.size, lon.size), float(R0))
    i = np.flatnonzero(np.abs(lat - lat0) <= half_width_deg)
    j = np.flatnonzero(np.abs(lon - lon0) <= half_width_deg)
    u = xyz(lat[i][:, None], lon[j][None, :], 1.0)
    radii[np.ix_(i, j)] = c / (u @ n)
    return radii, n, c


def _bilinear_and_gradient(radii, ppd, lat, lon):
    """My own bilinear interpolation of radii at pixel centres (j + 1/2)/ppd, with d r/d lat and
    d r/d lon (per degree); lon wraps; for points at least half a pixel from the poles."""
    nlat, nlon = radii.shape
    y = (np.asarray(lat) + 90.0) * ppd - 0.5
    x = np.asarray(lon) % 360.0 * ppd - 0.5
    i0 = np.floor(y).astype(int)
    j0 = np.floor(x).astype(int)
    ty, tx = y - i0, x - j0
    j0w, j1w = j0 % nlon, (j0 + 1) % nlon
    r00, r01 = radii[i0, j0w], radii[i0, j1w]
    r10, r11 = radii[i0 + 1, j0w], radii[i0 + 1, j1w]
    r = (1 - ty) * ((1 - tx) * r00 + tx * r01) + ty * ((1 - tx) * r10 + tx * r11)
    dr_dlat = ppd * (((1 - tx) * r10 + tx * r11) - ((1 - tx) * r00 + tx * r01))
    dr_dlon = ppd * ((1 - ty) * (r01 - r00) + ty * (r11 - r10))
    return r, dr_dlat, dr_dlon


def _bilinear_local_normals(radii, ppd, lat_c, lon_c, cell_deg, samples):
    """Unnormalised local normals dP/dlon x dP/dlat (area-weighted) of the bilinear DEM surface at a
    samples x samples grid of cell midpoints."""
    s = (np.arange(samples) + 0.5) / samples - 0.5
    la = lat_c + cell_deg * s[:, None] + 0 * s[None, :]
    lo = lon_c + 0 * s[:, None] + cell_deg * s[None, :]
    r, r_lat, r_lon = _bilinear_and_gradient(radii, ppd, la, lo)
    u = xyz(la, lo, 1.0)
    rad = np.pi / 180.0
    u_lat = xyz(la + 90.0, lo, 1.0) * rad          # d u / d lat (per degree)
    u_lon = np.stack([-np.sin(np.radians(lo)), np.cos(np.radians(lo)), 0 * lo], axis=-1) \
        * np.cos(np.radians(la))[..., None] * rad   # d u / d lon (per degree)
    P_lat = r_lat[..., None] * u + r[..., None] * u_lat
    P_lon = r_lon[..., None] * u + r[..., None] * u_lon
    return np.cross(P_lon, P_lat)


def bilinear_normal_spread(radii, ppd, lat_c, lon_c, cell_deg, n, samples=41):
    """Largest angle (rad) between n and the local normal of the bilinear DEM surface over the
    cell centred at (lat_c, lon_c) (R5), sampled on a samples x samples grid."""
    local = unit(_bilinear_local_normals(radii, ppd, lat_c, lon_c, cell_deg, samples))
    return float(np.max(np.radians(angle_deg(local, np.broadcast_to(n, local.shape)))))


def bilinear_mean_normal(radii, ppd, lat_c, lon_c, cell_deg, samples=201):
    """Area-weighted mean unit normal of the bilinear DEM surface over the cell (R5): the midpoint
    rule on samples x samples sub-cells of the integral of dP/dlon x dP/dlat."""
    local = _bilinear_local_normals(radii, ppd, lat_c, lon_c, cell_deg, samples)
    return unit(local.reshape(-1, 3).sum(axis=0))


# ----------------------------------------------------------------------------- position angle (R9)

def position_angle_notes_literal(R, rC):
    """The notes' recipe taken literally (R9): degrees in [0, 180], cross products not normalised."""
    Rh, rh = unit(R), unit(rC)
    P = np.broadcast_to(np.array([0.0, 0.0, 1.0]), Rh.shape)
    Q1 = np.cross(P, Rh)
    Q2 = np.cross(Rh, rh)
    c = np.sum(np.cross(Rh, Q1) * np.cross(Q2, Rh), axis=-1)
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def position_angle_notes_normalised(R, rC):
    """The notes' recipe with both tangent vectors normalised: the bearing folded into [0, 180]."""
    Rh, rh = unit(R), unit(rC)
    P = np.broadcast_to(np.array([0.0, 0.0, 1.0]), Rh.shape)
    t1 = unit(np.cross(Rh, np.cross(P, Rh)))
    t2 = unit(np.cross(np.cross(Rh, rh), Rh))
    return np.degrees(np.arccos(np.clip(np.sum(t1 * t2, axis=-1), -1.0, 1.0)))


# ----------------------------------------------------------------------------- flux fraction (R6)

def visible_cap_angle(R0, Rs):
    """Central angle (deg) of the horizon (z = 90 deg) seen from radius Rs over a sphere R0."""
    return math.degrees(math.acos(R0 / Rs))


def gamma_of_zeta(zeta, R0, Rs):
    """Central angle (deg) of the cone cos psi = zeta's edge on the near side; the cap edge when the
    cone is wider than the visible cap (R6)."""
    psi = math.acos(min(1.0, max(-1.0, zeta)))
    s = Rs * math.sin(psi) / R0
    if s >= 1.0 or psi >= math.pi / 2:
        return visible_cap_angle(R0, Rs)
    return math.degrees(math.asin(s) - psi)


def _flux_weight(g, R0, Rs, cos_power):
    d2 = (Rs - R0) ** 2 + 4.0 * Rs * R0 * np.sin(0.5 * g) ** 2
    psi = np.arctan2(R0 * np.sin(g), Rs - R0 * np.cos(g))
    ce = np.maximum(np.cos(g + psi), 0.0)
    return ce ** cos_power / d2 * np.sin(g)


def flux_fraction_sphere(zeta, R0, Rs, cos_power=1.0):
    """Fraction of the visible cap's flux inside the nadir cone cos psi >= zeta (R6).

    Weight per unit surface area: (1/d^2) cos(e)^cos_power (the detector area cancels).
    """
    gh = math.radians(visible_cap_angle(R0, Rs))
    gz = math.radians(gamma_of_zeta(zeta, R0, Rs))
    opts = dict(epsabs=0.0, epsrel=1e-12, limit=400)
    total = integrate.quad(_flux_weight, 0.0, gh, args=(R0, Rs, cos_power), **opts)[0]
    inside = integrate.quad(_flux_weight, 0.0, min(gz, gh), args=(R0, Rs, cos_power), **opts)[0]
    return inside / total


def zeta_for_fraction(q, R0, Rs, cos_power=1.0):
    """The zeta whose cone holds the fraction q (0 < q < 1) of the flux (R6); brentq to 1e-14."""
    if not 0.0 < q < 1.0:
        raise ValueError(f"q: must be in (0, 1), got {q}")
    psi_h = math.asin(R0 / Rs)          # nadir angle of the horizon
    lo = math.cos(psi_h)
    return optimize.brentq(lambda z: flux_fraction_sphere(z, R0, Rs, cos_power) - q, lo, 1.0, xtol=1e-14)


# ----------------------------------------------------------------------------- air mass (R7, R8, R10)

def airmass_secant(z_deg):
    return 1.0 / np.cos(np.radians(z_deg))


def airmass_notes(z_deg):
    """The notes' 'spherical' series exactly as printed (R8)."""
    s = airmass_secant(z_deg) - 1.0
    return s + 1.0 - 0.018167 * s ** 2 - 0.002875 * s ** 3 - 0.0008083 * s ** 4


def airmass_hardie(z_deg):
    """Hardie (1962), as in the contract (R8)."""
    s = airmass_secant(z_deg) - 1.0
    return s + 1.0 - 0.0018167 * s - 0.002875 * s ** 2 - 0.0008083 * s ** 3


def _chapman_integrand(t, H, R, c):
    s = H * t
    r = math.sqrt(R * R + s * s + 2.0 * R * s * c)
    return math.exp(-(H * t * t + 2.0 * R * t * c) / (r + R))


def airmass_chapman(z_deg, H, R, epsrel=1e-12):
    """Relative air mass of an exponential atmosphere (scale height H) seen from radius R at zenith
    angle z (deg), by direct quadrature along the straight line to infinity (R7). Any z in
    [0, 180) for which the line stays finite; scalar in, float out."""
    z = float(z_deg)
    if not (math.isfinite(z) and 0.0 <= z < 180.0):
        raise ValueError(f"z_deg: must be in [0, 180), got {z_deg}")
    if not (H > 0 and R > 0):
        raise ValueError(f"H and R: must be positive, got H={H}, R={R}")
    c = math.cos(math.radians(z))
    width = 1.0 + math.sqrt(2.0 * R / H)      # the integrand's scale in t near 90 deg
    opts = dict(epsabs=0.0, epsrel=epsrel, limit=500)
    args = (H, R, c)
    t0 = max(0.0, -R * c / H)                 # tangent point (0 when z <= 90)
    parts = [(0.0, t0)] if t0 > 0 else []
    edges = [t0 + k * width for k in (0, 1, 4, 20, 100)]
    parts += list(zip(edges[:-1], edges[1:]))
    total = sum(integrate.quad(_chapman_integrand, a, b, args=args, **opts)[0] for a, b in parts)
    total += integrate.quad(_chapman_integrand, edges[-1], np.inf, args=args, **opts)[0]
    return total


def chapman_90_exact(x):
    """Ch(x, 90 deg) = x e^x K1(x) (R7), x = R/H."""
    return x * special.k1e(x)


def chapman_90_asymptotic(x):
    """Leading large-x form sqrt(pi x / 2) of the air mass at 90 deg."""
    return math.sqrt(math.pi * x / 2.0)


def chapman_beyond_90_identity(z_deg, H, R):
    """Ch(x, z) = 2 exp(x (1 - sin z)) Ch(x sin z, 90) - Ch(x, 180 - z) for z > 90 (R7): the line
    is symmetric about its tangent point, of radius R sin z."""
    x = R / H
    sz = math.sin(math.radians(z_deg))
    return 2.0 * math.exp(x * (1.0 - sz)) * chapman_90_exact(x * sz) - airmass_chapman(180.0 - z_deg, H, R)


def scale_height(T, m_amu=MARS_MEAN_MOLECULAR_MASS, GM=MARS_GM, r=3389.5):
    """H = k T / (m g) in km, g = GM / r^2 (R10). T in K, m in u, GM in km^3/s^2, r in km."""
    g = GM / r ** 2 * 1e3                   # m/s^2
    return BOLTZMANN * T / (m_amu * AMU * g) / 1e3


# ----------------------------------------------------------------------------- quaternions

def quat_to_matrix(q):
    """Matrix A with A v = vector part of q v q* for a unit quaternion q = (w, x, y, z), scalar first."""
    q = unit(q)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    A = np.empty(q.shape[:-1] + (3, 3))
    A[..., 0, 0] = 1 - 2 * (y * y + z * z)
    A[..., 0, 1] = 2 * (x * y - w * z)
    A[..., 0, 2] = 2 * (x * z + w * y)
    A[..., 1, 0] = 2 * (x * y + w * z)
    A[..., 1, 1] = 1 - 2 * (x * x + z * z)
    A[..., 1, 2] = 2 * (y * z - w * x)
    A[..., 2, 0] = 2 * (x * z - w * y)
    A[..., 2, 1] = 2 * (y * z + w * x)
    A[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return A
