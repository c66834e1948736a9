"""Footprint geometry (issue 13, Mars Odyssey GRS notes): cell table, per-pair
geometry, selection, position angle, frames, air mass, flux cone, orbit study.

Expectations are closed forms on a sphere and a spheroid, exhaustive selection
over every cell, and formulas written here independently of the module.
"""

import math
import warnings
import sys

import numpy as np
import pytest

import planet_intersect as pi
import planet_intersect.footprint  # noqa: F401  (the module; pi.footprint is the function)
from planet_intersect.synthetic import MARS_F, MARS_RE

F = sys.modules["planet_intersect.footprint"]

R_SPHERE = 3390.0


@pytest.fixture(scope="module")
def sphere():
    dem = pi.DEM.from_array(np.full((720, 1440), R_SPHERE))
    return pi.CellTable(dem, 0.5)


@pytest.fixture(scope="module")
def spheroid():
    lat = -90 + (np.arange(720) + 0.5) / 4
    r = pi.spheroid_radius(lat, MARS_F, MARS_RE)
    dem = pi.DEM.from_array(np.repeat(r[:, None], 1440, axis=1), f=MARS_F, re=MARS_RE)
    return pi.CellTable(dem, 0.5)


def _xyz(lat, lon, r):
    la, lo = np.radians(lat), np.radians(lon)
    return np.stack([r * np.cos(la) * np.cos(lo), r * np.cos(la) * np.sin(lo), r * np.sin(la)], axis=-1)


def _random_states(rng, n, rmin=3700.0, rmax=4400.0):
    R = rng.standard_normal((n, 3))
    R *= (rng.uniform(rmin, rmax, n) / np.linalg.norm(R, axis=1))[:, None]
    v = rng.standard_normal((n, 3))
    return R, v


# ---------------------------------------------------------------------------------------------
# cell table
# ---------------------------------------------------------------------------------------------
def test_cell_table_on_a_sphere(sphere):
    c = sphere
    assert len(c) == 360 * 720 and c.nrow == 360 and c.ncol == 720
    assert np.allclose(c.radius, R_SPHERE, rtol=0, atol=1e-9)
    # the topographic normal of a sphere is the radial direction; detic = centric
    assert np.max(np.linalg.norm(c.normal - c.u, axis=1)) < 1e-12
    assert np.max(np.abs(c.lat_detic - c.lat)) < 1e-9
    # cell areas sum to the sphere's area
    assert math.isclose(c.area.sum(), 4 * math.pi * R_SPHERE ** 2, rel_tol=1e-12)
    # registration: cell 0 at (-89.75, 0.25), row-major from the south-west
    assert (c.lat[0], c.lon[0], c.lat[720], c.lon[719]) == (-89.75, 0.25, -89.25, 359.75)
    assert c.index(10.1, 359.9) == (int((10.1 + 90) / 0.5)) * 720 + 719
    # cached with the DEM: a second table shares the arrays
    assert pi.CellTable(c.dem, 0.5).normal is c.normal


def test_cell_table_on_the_spheroid(spheroid):
    c = spheroid
    e2 = MARS_F * (2 - MARS_F)
    # spheroid normal at the cell's centric latitude, written here from the implicit surface
    p = c.r
    grad = p / np.array([MARS_RE ** 2, MARS_RE ** 2, (MARS_RE * (1 - MARS_F)) ** 2])
    grad /= np.linalg.norm(grad, axis=1, keepdims=True)
    ang = np.arctan2(np.linalg.norm(np.cross(c.normal, grad), axis=1), np.sum(c.normal * grad, axis=1))
    assert ang.max() < 5e-8                      # rad; measured 1.9e-8 at 4 ppd
    # lat_detic: full conversion of the (nearly on-spheroid) centre point
    exact = np.degrees(np.arctan2(np.tan(np.radians(c.lat)), 1 - e2)) % 180
    exact = np.where(exact > 90, exact - 180, exact)
    assert np.max(np.abs(c.lat_detic_spheroid - exact)) < 1e-10
    assert np.max(np.abs(c.lat_detic - c.lat_detic_spheroid)) < 1e-6
    # areodetic minus areocentric latitude peaks at 45 deg with m = e^2/(2 - e^2) rad to first order
    m = e2 / (2 - e2)
    k45 = c.index(44.75, 10.25)
    assert math.isclose(math.radians(c.lat_detic_spheroid[k45] - c.lat[k45]), m * math.sin(math.radians(89.5)),
                        rel_tol=5e-3)


def test_geodetic_conversion_of_points_off_the_spheroid():
    rng = np.random.default_rng(5)
    latd = rng.uniform(-89.9, 89.9, 500)
    lon = rng.uniform(0, 360, 500)
    h = rng.uniform(-10, 500, 500)
    e2 = MARS_F * (2 - MARS_F)
    b, l = np.radians(latd), np.radians(lon)
    N = MARS_RE / np.sqrt(1 - e2 * np.sin(b) ** 2)
    p = np.stack([(N + h) * np.cos(b) * np.cos(l), (N + h) * np.cos(b) * np.sin(l), (N * (1 - e2) + h) * np.sin(b)], 1)
    lat2, h2 = F.geodetic_latitude(p, MARS_RE, MARS_F)
    assert np.max(np.abs(lat2 - latd)) < 1e-11
    assert np.max(np.abs(h2 - h)) < 1e-8


def test_geodetic_latitude_checks_and_nearest_foot():
    """The footprint fuzzing (2026-12-03): geodetic_latitude took f = 1.5, re = -1, strings and
    (1, 2) arrays, and inside the evolute returned the equator's normal instead of the nearest
    foot point. Expectation for the foot: brute force over the meridian ellipse (1e6 points,
    then a local refinement), nothing from the package."""
    for kw, name in ((dict(re=MARS_RE, f=1.5), "f"), (dict(re=-1.0, f=MARS_F), "re"),
                     (dict(re="a", f=MARS_F), "re"), (dict(re=MARS_RE, f=math.nan), "f")):
        with pytest.raises(ValueError, match=name):
            F.geodetic_latitude([3000.0, 0.0, 1000.0], **kw)
    for p in ([[1.0, 2.0]], [math.nan, 0.0, 0.0], "p"):
        with pytest.raises(ValueError, match="p"):
            F.geodetic_latitude(p, MARS_RE, MARS_F)
    a, b = MARS_RE, MARS_RE * (1 - MARS_F)
    for rho, z in ((10.0, 1e-12), (500.0, 1e-7), (1.0, 3000.0), (3000.0, -5.0)):
        t = np.linspace(-np.pi / 2, np.pi / 2, 1_000_001)
        d = np.hypot(rho - a * np.cos(t), z - b * np.sin(t))
        k = int(np.argmin(d))
        tt = np.linspace(t[max(k - 1, 0)], t[min(k + 1, t.size - 1)], 200_001)
        dd = np.hypot(rho - a * np.cos(tt), z - b * np.sin(tt))
        j = int(np.argmin(dd))
        want_lat = math.degrees(math.atan2(a * math.sin(tt[j]), b * math.cos(tt[j])))
        inside = (rho / a) ** 2 + (z / b) ** 2 < 1
        lat, h = F.geodetic_latitude([rho, 0.0, z], MARS_RE, MARS_F)
        assert abs(h[0] - (-dd[j] if inside else dd[j])) < 1e-9, (rho, z, h[0], dd[j])
        assert abs(lat[0] - want_lat) < 1e-5, (rho, z, lat[0], want_lat)


def test_latitude_series_printed_has_the_wrong_sign():
    f = MARS_F
    lat = np.linspace(-85, 85, 35)
    exact = F.detic_latitude(lat, f)
    printed = F.notes_latitude_series(lat, f)
    corrected = F.notes_latitude_series(lat, f, corrected=True)
    e2 = f * (2 - f)
    m = e2 / (2 - e2)
    # the true areodetic latitude is poleward of the areocentric one; the printed series is equatorward
    north = lat > 0
    assert np.all(exact[north] > lat[north]) and np.all(printed[north] < lat[north])
    # at 45 deg the printed series is off by about 2m (0.67 deg on Mars)
    k = np.argmin(np.abs(lat - 45))
    assert math.isclose(exact[k] - printed[k], math.degrees(2 * m), rel_tol=0.01)
    # the exact series is b' - b = sum m^k sin(2kb)/k: the corrected one stops at k = 2, so its
    # error is the third term, m^3/3 at most (4e-6 deg on Mars)
    err = np.max(np.abs(corrected - exact))
    assert 0.9 * math.degrees(m ** 3 / 3) < err < 1.01 * math.degrees(m ** 3 / 3)


# ---------------------------------------------------------------------------------------------
# per-pair geometry on a sphere: closed forms
# ---------------------------------------------------------------------------------------------
def test_solid_angle_of_the_notes_at_400_km(sphere):
    R = _xyz(0.25, 0.25, R_SPHERE + 400.0)
    fp = pi.footprint(sphere, R, [0, 0, 3.4], zeta=0.999)
    k = np.argmin(fp.distance)
    assert math.isclose(fp.distance[k], 400.0, rel_tol=1e-12)
    assert math.isclose(fp.solid_angle[k], 3.4e-9 / 400 ** 2, rel_tol=1e-12)
    assert abs(fp.solid_angle[k] * 1e14 - 2.13) < 0.0051         # the notes: "~ 2.13e-14 sr" (2.125 exactly)
    assert fp.nadir_angle[k] < 1e-9 and fp.zenith_centric[k] < 1e-9


def test_sphere_closed_forms(sphere):
    rng = np.random.default_rng(2)
    R, v = _random_states(rng, 12)
    fp = pi.footprint(sphere, R, v, zeta=0.0)
    c = sphere
    rn = np.linalg.norm(R, axis=1)[fp.spectrum]
    u = c.u[fp.cell]
    theta = np.arccos(np.clip(np.sum(u * R[fp.spectrum], axis=1) / rn, -1, 1))
    dist = np.sqrt(rn ** 2 + R_SPHERE ** 2 - 2 * rn * R_SPHERE * np.cos(theta))
    psi = np.degrees(np.arctan2(R_SPHERE * np.sin(theta), rn - R_SPHERE * np.cos(theta)))
    assert np.max(np.abs(fp.distance - dist) / dist) < 1e-12
    assert np.max(np.abs(fp.nadir_angle - psi)) < 1e-6
    # zenith angle at the cell = central angle + nadir angle (triangle centre, cell, spacecraft)
    assert np.max(np.abs(fp.zenith_centric - (np.degrees(theta) + psi))) < 1e-6
    # on a sphere all three normals agree
    assert np.max(np.abs(fp.zenith_detic - fp.zenith_centric)) < 1e-9
    assert np.max(np.abs(fp.emission - fp.zenith_centric)) < 1e-9
    # every visible cell is above the horizon, and the cap is complete: theta < acos(r/|R|)
    assert fp.zenith_centric.max() < 90
    horizon = np.degrees(np.arccos(R_SPHERE / rn))
    assert np.all(np.degrees(theta) < horizon)
    # elevation in the spacecraft frame is psi - 90
    assert np.max(np.abs(fp.elevation - (fp.nadir_angle - 90))) < 1e-9


def test_selection_equals_exhaustive_search(spheroid):
    """The prefilter never drops a cell: same pairs as testing every cell."""
    c = spheroid
    rng = np.random.default_rng(7)
    R, v = _random_states(rng, 10, 3500, 5000)
    # add states over the poles and across 0/360 E
    R = np.vstack([R, _xyz(89.9, 17.0, 3800.0), _xyz(-89.99, 200.0, 3800.0), _xyz(0.1, 359.9, 3700.0),
                   [0, 0, 3790.0]])
    v = np.vstack([v, [[1, 0, 0]] * 4])
    for zeta in (0.0, 0.5, 0.9, 0.999):
        fp = pi.footprint(c, R, v, zeta=zeta)
        for s in range(len(R)):
            d = R[s] - c.r
            dist = np.linalg.norm(d, axis=1)
            sel = (np.sum(d * c.u, axis=1) > 0) & (d @ (R[s] / np.linalg.norm(R[s])) >= zeta * dist)
            assert np.array_equal(np.sort(fp.cell[fp.spectrum == s]), np.flatnonzero(sel)), (zeta, s)
    # on the spheroid, the emission angle (normal from the DEM) equals the areodetic zenith angle
    assert np.max(np.abs(fp.emission - fp.zenith_detic)) < 1e-5


def test_threads_give_identical_results(spheroid):
    rng = np.random.default_rng(3)
    R, v = _random_states(rng, 16)
    a = pi.footprint(spheroid, R, v, threads=1)
    b = pi.footprint(spheroid, R, v, threads=2)
    for name in ("spectrum", "cell", "d", "emission", "position_angle", "azimuth"):
        assert np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True)



_ANGLES = ("zenith_centric", "zenith_detic", "emission", "nadir_angle", "position_angle", "azimuth", "elevation")


def test_degrees_from_the_kernel_equal_radians_scaled_afterwards(spheroid):
    # the kernel multiplies each angle by 180/pi as its last operation; the
    # expectation is the kernel in radians (ascale 1) scaled by NumPy afterwards,
    # which is what footprint() did before: bit for bit equal
    rng = np.random.default_rng(5)
    R, v = _random_states(rng, 6)
    fp = pi.footprint(spheroid, R, v, threads=1)
    frames = pi.spacecraft_frame(R, v, method="state").reshape(-1, 3, 3)
    idx, d, gsh, scal, _ = F._run_kernel(spheroid, R, frames, np.zeros(len(R)), F.ODYSSEY_AREA_KM2, 1, ascale=1.0)
    assert len(fp) == len(idx) > 6 * 1000
    deg = scal[:, 2:] * (180.0 / math.pi)
    for k, name in enumerate(_ANGLES):
        assert np.array_equal(getattr(fp, name), deg[:, k], equal_nan=True), name
    assert np.array_equal(fp.d, d.T) and np.array_equal(fp.gsh, gsh.T)
    assert np.array_equal(fp.distance, scal[:, 0]) and np.array_equal(fp.solid_angle, scal[:, 1])
    # radians: the zenith angle on the spheroid stays within [0, pi/2) above the horizon
    assert 0.0 <= scal[:, 2].min() and scal[:, 2].max() < math.pi / 2


def test_reused_output_buffers(spheroid):
    rng = np.random.default_rng(8)
    R, v = _random_states(rng, 8)
    fresh = pi.footprint(spheroid, R, v, threads=1)
    first = pi.footprint(spheroid, R[:4], v[:4], threads=1)
    # a smaller call writes into the earlier result's memory ...
    again = pi.footprint(spheroid, R[4:], v[4:], threads=1, out=fresh)
    assert np.shares_memory(again.emission, fresh._buffers.scal) and np.shares_memory(again.d, fresh._buffers.d)
    ref = pi.footprint(spheroid, R[4:], v[4:], threads=1)
    for name in F._PAIR_FIELDS:
        assert np.array_equal(getattr(again, name), getattr(ref, name), equal_nan=True), name
    # ... a larger one takes new memory, with the same results as a fresh call
    big = pi.footprint(spheroid, R, v, threads=2, out=first)
    assert not np.shares_memory(big.emission, first._buffers.scal)
    ref = pi.footprint(spheroid, R, v, threads=1)
    for name in F._PAIR_FIELDS:
        assert np.array_equal(getattr(big, name), getattr(ref, name), equal_nan=True), name
    # the flux cone's result (a subset) keeps the raw pass's memory for the next call
    # only when reuse was asked for
    q = pi.footprint(spheroid, R[:2], v[:2], flux_fraction=0.5, out=big)
    assert q._buffers is big._buffers and 0 < len(q) < len(ref) and q.visible.all()
    assert getattr(pi.footprint(spheroid, R[:2], v[:2], flux_fraction=0.5), "_buffers") is None
    with pytest.raises(TypeError, match="out must be a FootprintResult"):
        pi.footprint(spheroid, R, v, out=np.empty(10))
    # an empty footprint, fresh and into reused memory: zeta = 1 takes only a cell
    # centre exactly at nadir, and (0 N, 0 E) is a cell corner, not a centre
    for prev in (None, big):
        e = pi.footprint(spheroid, [4000.0, 0.0, 0.0], [0.0, 0.0, 1.0], zeta=1.0, out=prev)
        assert len(e) == 0 and e.d.shape == (0, 3) and e.emission.shape == (0,) and e.counts().tolist() == [0]
# ---------------------------------------------------------------------------------------------
# position angle
# ---------------------------------------------------------------------------------------------
def _bearing(lat1, lon1, lat2, lon2):
    """Initial great-circle bearing from point 1 to point 2, clockwise from north (deg)."""
    p1, p2 = np.radians(lat1), np.radians(lat2)
    dl = np.radians(lon2 - lon1)
    y = np.sin(dl) * np.cos(p2)
    x = np.cos(p1) * np.sin(p2) - np.sin(p1) * np.cos(p2) * np.cos(dl)
    return np.degrees(np.arctan2(y, x)) % 360


def test_position_angle_is_the_great_circle_bearing(sphere):
    rng = np.random.default_rng(4)
    R, v = _random_states(rng, 8)
    fp = pi.footprint(sphere, R, v)
    lat_s = np.degrees(np.arctan2(R[:, 2], np.hypot(R[:, 0], R[:, 1])))
    lon_s = np.degrees(np.arctan2(R[:, 1], R[:, 0]))
    b = _bearing(lat_s[fp.spectrum], lon_s[fp.spectrum], sphere.lat[fp.cell], sphere.lon[fp.cell])
    diff = (fp.position_angle - b + 180) % 360 - 180
    assert np.nanmax(np.abs(diff)) < 1e-8
    assert np.all((fp.position_angle >= 0) & (fp.position_angle < 360))
    # cardinal directions from a spacecraft over (20 N, 100 E)
    S = _xyz(20, 100, 3790)
    cells = _xyz(np.array([25.0, 20.0, 15.0, 20.0]), np.array([100.0, 105.0, 100.0, 95.0]), 3390)
    pa = F.position_angle(S, cells)
    assert np.allclose(pa[[0, 2]], [0, 180], atol=1e-9)
    assert 89 < pa[1] < 91 and 269 < pa[3] < 271       # due east/west along the parallel (not a great circle)


def test_notes_position_angle_recipe_fails_literally():
    """The notes' recipe with its non-unit cross products returns ~90 deg for everything;
    normalised it gives min(PA, 360 - PA) and cannot tell east from west."""
    S = _xyz(40.0, 30.0, 3790.0)
    lat = np.array([45.0, 40.0, 35.0, 40.0, 44.0, 36.0])
    lon = np.array([30.0, 36.0, 30.0, 24.0, 35.0, 25.0])
    cells = _xyz(lat, lon, 3390.0)
    right = F.position_angle(S, cells)
    literal = F.position_angle_notes(S, cells)
    normalised = F.position_angle_notes(S, cells, normalize=True)
    assert np.allclose(right, _bearing(40.0, 30.0, lat, lon), atol=1e-9)
    # literal: |R x Q1| = cos 40 deg, |Q2 x R| = sin(<= 6 deg): cos PA tiny, PA within 86-94 deg
    assert np.all((literal > 85.5) & (literal < 94.5))
    assert np.max(np.abs(literal - right)) > 80
    # normalised: the angle's cosine is right but the half-plane is lost
    assert np.allclose(normalised, np.minimum(right, 360 - right), atol=1e-5)    # arccos: 1e-6 deg near 0 and 180
    west = right > 180
    assert west.sum() == 2 and np.all(np.abs(normalised[west] - right[west]) > 90)


# ---------------------------------------------------------------------------------------------
# spacecraft frame
# ---------------------------------------------------------------------------------------------
def test_frames_agree_and_are_what_they_say():
    rng = np.random.default_rng(8)
    R, v = _random_states(rng, 200)
    R[0] = [0, 0, 3800.0]                      # over the north pole
    v[0] = [1.0, 2.0, 0.5]
    M = pi.spacecraft_frame(R, v)
    for method in ("rotations", "quaternion", "orbit"):
        assert np.max(np.abs(pi.spacecraft_frame(R, v, method=method) - M)) < 1e-12, method
    # orthonormal, right-handed, x up, y along the horizontal velocity
    assert np.max(np.abs(M @ np.swapaxes(M, 1, 2) - np.eye(3))) < 1e-13
    assert np.allclose(np.linalg.det(M), 1.0)
    rh = R / np.linalg.norm(R, axis=1, keepdims=True)
    assert np.max(np.abs(M[:, 0] - rh)) < 1e-15
    vp = v - np.sum(v * rh, axis=1, keepdims=True) * rh
    assert np.max(np.abs(M[:, 1] - vp / np.linalg.norm(vp, axis=1, keepdims=True))) < 1e-13
    # quaternion: q* w q gives the frame coordinates M w; q e_i q* gives the axes
    q = pi.spacecraft_quaternion(R, v)
    w = rng.standard_normal((200, 3))
    wq = np.concatenate([np.zeros((200, 1)), w], axis=1)
    coords = F.quat_multiply(F.quat_multiply(F.quat_conjugate(q), wq), q)[:, 1:]
    assert np.max(np.abs(coords - np.einsum("nij,nj->ni", M, w))) < 1e-12
    assert np.max(np.abs(F.quat_rotate(q, np.array([1.0, 0, 0])) - rh)) < 1e-13
    # the notes' first construction: the frame of the osculating orbit
    _, q_orb, (node, inc, nu) = F.orbit_frame(R, v)
    assert np.max(np.abs(np.swapaxes(F.quat_to_matrix(q_orb), 1, 2) - M)) < 1e-12
    h = np.cross(R, v)
    assert np.allclose(np.cos(inc), h[:, 2] / np.linalg.norm(h, axis=1))


def test_alpha_sign_on_a_southbound_track():
    # the notes' alpha = arccos(v_perp . east) is 45 deg both northbound and southbound
    R = _xyz(0.0, 0.0, 3800.0)
    north_east, south_east = np.array([0, 1.0, 1.0]), np.array([0, 1.0, -1.0])
    _, _, a_n = F.frame_angles(R, north_east)
    _, _, a_s = F.frame_angles(R, south_east)
    assert np.allclose(np.degrees([a_n[0], a_s[0]]), [45, -45])
    M = pi.spacecraft_frame(R, south_east, method="rotations")
    assert np.allclose(M[1], south_east / np.sqrt(2), atol=1e-15)


def test_gsh_coordinates_azimuth_elevation(spheroid):
    rng = np.random.default_rng(9)
    R, v = _random_states(rng, 6)
    fp = pi.footprint(spheroid, R, v)
    M = pi.spacecraft_frame(R, v)
    g = np.einsum("pij,pj->pi", M[fp.spectrum], spheroid.r[fp.cell] - R[fp.spectrum])
    assert np.max(np.abs(g - fp.gsh)) < 1e-9
    az = np.degrees(np.arctan2(g[:, 2], g[:, 1])) % 360
    el = np.degrees(np.arctan2(g[:, 0], np.hypot(g[:, 1], g[:, 2])))
    assert np.max(np.abs((fp.azimuth - az + 180) % 360 - 180)) < 1e-8
    assert np.max(np.abs(fp.elevation - el)) < 1e-9
    assert np.all(fp.elevation < 0)


# ---------------------------------------------------------------------------------------------
# air mass and scale height
# ---------------------------------------------------------------------------------------------
def test_scale_height_mars_defaults():
    g = 42828.369773939e9 / 3389.5e3 ** 2
    H = 1.380649e-23 * 210 / (43.34 * 1.66053906660e-27 * g) / 1e3
    assert math.isclose(pi.scale_height(), H, rel_tol=1e-14)
    assert 10.7 < H < 10.9
    assert math.isclose(pi.scale_height(T=150.0, r=3500.0), H * 150 / 210 * (3500 / 3389.5) ** 2, rel_tol=1e-13)


def test_airmass_models_and_their_table():
    z = np.array([0.0, 60.0, 80.0, 85.0])
    sec = 1 / np.cos(np.radians(z))
    s1 = sec - 1
    assert np.allclose(pi.airmass(z, model="secant"), sec, rtol=1e-15)
    assert np.allclose(pi.airmass(z, model="hardie"),
                       sec - 0.0018167 * s1 - 0.002875 * s1 ** 2 - 0.0008083 * s1 ** 3, rtol=1e-15)
    assert np.allclose(pi.airmass(z, model="notes"),
                       sec - 0.018167 * s1 ** 2 - 0.002875 * s1 ** 3 - 0.0008083 * s1 ** 4, rtol=1e-15)
    ch = pi.airmass(z, model="chapman")
    notes = pi.airmass(z, model="notes")
    # taken as printed the notes' series is ~12 % low at 80 deg and negative at 85 deg (Mars)
    assert 0.11 < 1 - notes[2] / ch[2] < 0.14
    assert notes[3] < 0 < ch[3]
    assert np.isnan(pi.airmass(90.0, model="notes")) and np.isinf(pi.airmass(90.0, model="secant"))


def test_chapman_closed_forms():
    x = 3389.5 / pi.scale_height()
    H = pi.scale_height()
    # zenith: 1; horizon: x e^x K1(x) from the asymptotic series of K1 (error ~1e-12 at x ~ 314)
    assert math.isclose(pi.airmass(0.0), 1.0, rel_tol=1e-14)
    k1 = math.sqrt(math.pi * x / 2) * (1 + 3 / (8 * x) - 15 / (128 * x ** 2) + 315 / (3072 * x ** 3))
    assert math.isclose(float(pi.airmass(90.0)), k1, rel_tol=1e-9)
    # straight down through the centre: 2 e^x - 1 (exact); use a small x to stay finite
    assert math.isclose(float(F.chapman(5.0, 180.0)), 2 * math.exp(5.0) - 1, rel_tol=1e-12)
    # large x tends to sec z (plane parallel)
    assert math.isclose(float(F.chapman(1e8, 60.0)), 2.0, rel_tol=1e-7)
    # continuous through 90 deg
    a, b = pi.airmass([89.999999, 90.000001], H=H, R=3389.5)
    assert abs(a - b) / a < 1e-5
    # beyond 90 it keeps growing (the line descends below the observer)
    z = np.linspace(80, 110, 31)
    assert np.all(np.diff(pi.airmass(z)) > 0)


def test_chapman_a_hair_from_the_horizon():
    """The footprint fuzzing (2026-12-03): 1 - sin z lost its digits near 90 deg, and with
    x = R/H = 3.4e6 Ch came out 3.7e-6 too high at 89.999999 deg. Expectations: the line
    integral of exp(-(r(t) - R)/H) dt/H by mpmath quadrature at 40 digits (tanh-sinh, split
    at the tangent point and at multiples of sqrt(2 R H)), not this module's variable."""
    for z, H, R, want in ((89.999999, 0.001, 3389.5, 2307.366969434126),
                          (90.000001, 0.001, 3389.5, 2307.4852853041594),
                          (89.9999999999, 11.0, 3389.5, 22.027189775121685),
                          (91.0, 8.5, 6371.0, 52.601908326606537)):
        got = float(pi.airmass(z, H=H, R=R))
        assert abs(got - want) <= 1e-12 * want, (z, H, R, got, want)


def test_chapman_against_a_direct_integral():
    """Brute-force trapezoid on the line integral (a different variable and rule)."""
    H, R = 11.0, 3389.5
    for zdeg in (30.0, 75.0, 88.0, 90.0, 93.0):
        zr = math.radians(zdeg)
        w = np.linspace(0, 60.0, 1_200_001)
        s = w * w                                 # path length along the line, sqrt-spaced
        r = np.sqrt(R * R + s * s + 2 * R * s * math.cos(zr))
        integral = np.trapezoid(np.exp(-(r - R) / H) * 2 * w / H, w)
        assert math.isclose(float(pi.airmass(zdeg, H=H, R=R)), integral, rel_tol=1e-8), zdeg


# ---------------------------------------------------------------------------------------------
# flux cone, result containers
# ---------------------------------------------------------------------------------------------
def test_flux_fraction_cone(sphere):
    rng = np.random.default_rng(10)
    R, v = _random_states(rng, 5)
    full = pi.footprint(sphere, R, v)
    w = F.flux_weights(full)
    for q in (0.25, 0.5, 0.9):
        fp = pi.footprint(sphere, R, v, flux_fraction=q)
        for s in range(5):
            mine = fp.spectrum == s
            psi_q = fp.nadir_angle[mine].max()
            ws = w[full.spectrum == s]
            psi = full.nadir_angle[full.spectrum == s]
            inside = ws[psi <= psi_q].sum() / ws.sum()
            below = ws[psi < psi_q].sum() / ws.sum()
            assert below < q <= inside + 1e-12
            assert math.isclose(fp.zeta[s], math.cos(math.radians(psi_q)), rel_tol=1e-14)
            assert mine.sum() == (psi <= psi_q).sum()
    assert len(pi.footprint(sphere, R, v, flux_fraction=1.0)) == len(full)


def test_flux_cone_of_a_faint_spectrum_after_a_bright_one():
    """The footprint fuzzing (2026-12-03): the flux cone's running sum ran over all spectra, so
    a spectrum whose weights were 1e-15 of an earlier one's (1,000 radii away, after one 6 m
    above a 4-degree cell) lost them to rounding and kept 11 cells holding 0.06 % of its flux
    for q = 0.5. Expectation: the same spectrum alone, and the fraction from its own weights."""
    dem = pi.DEM.from_array(np.full((180, 360), 6378.137))
    cells = pi.CellTable(dem, 4.0)
    near = [0.0, -6378.14338, 0.0]
    far = [0.0, 0.0, -6.38451514e6]
    both = pi.footprint(cells, [near, far], [1.0, 0.0, 0.0], flux_fraction=0.5)
    alone = pi.footprint(cells, far, [1.0, 0.0, 0.0], flux_fraction=0.5)
    assert np.array_equal(both.cell[both.spectrum == 1], alone.cell)
    full = pi.footprint(cells, far, [1.0, 0.0, 0.0], zeta=0.0)
    w = F.flux_weights(full)
    kept = np.isin(full.cell, alone.cell)
    frac = w[kept].sum() / w.sum()
    inner = full.nadir_angle < alone.nadir_angle.max() - 1e-9        # the cone without its last ring
    assert 0.5 <= frac and w[inner].sum() / w.sum() < 0.5, frac
    assert len(alone) > 900


def test_result_exports(sphere):
    pytest.importorskip("xarray")
    R = np.array([_xyz(10, 20, 3800), _xyz(12, 21, 3800)])
    fp = pi.footprint(sphere, R, [0, 0, 1.0], zeta=0.9)
    ds = fp.to_xarray()
    assert ds.sizes["pair"] == len(fp) and ds.sizes["spectrum"] == 2
    dense = fp.to_xarray("dense")
    assert dense["emission"].dims == ("spectrum", "cell")
    k = 5
    cell_pos = int(np.searchsorted(dense.cell.values, fp.cell[k]))
    assert dense["emission"].values[fp.spectrum[k], cell_pos] == fp.emission[k]
    assert np.isnan(dense["emission"].values).any()
    assert np.all(np.isfinite(fp.airmass)) and np.all(fp.airmass >= 1)
    cols = fp.to_table()
    assert len(cols["lat"]) == len(fp) and "gsh_x" in cols
    # a subset that keeps only the second spectrum: the first keeps its row, all NaN, not visible
    second = fp.subset(fp.spectrum == 1).to_xarray("dense")
    assert second.sizes["spectrum"] == 2 and second.sizes["cell"] == np.count_nonzero(np.bincount(
        fp.cell[fp.spectrum == 1]))
    assert np.isnan(second["emission"].values[0]).all() and not second["visible"].values[0].any()
    assert np.isfinite(second["emission"].values[1]).all()
    np.testing.assert_array_equal(second["zeta"].values, fp.zeta)
    ct = sphere.to_xarray()
    assert ct.sizes["cell"] == len(sphere)


# ---------------------------------------------------------------------------------------------
# bad input
# ---------------------------------------------------------------------------------------------
def test_status_codes_agree_with_the_fortran():
    from planet_intersect import _core

    assert list(F.FOOTPRINT_STATUS) == list(_core.core_footprint_codes())


def test_bad_input_raises_clear_errors(sphere):
    with pytest.raises(ValueError, match="cell_deg must divide 180"):
        pi.CellTable(sphere.dem, 0.7)
    with pytest.raises(ValueError, match="cell_deg"):
        pi.CellTable(sphere.dem, float("nan"))
    with pytest.raises(TypeError, match="dem"):
        pi.CellTable("mars.hdr")
    R = _xyz(0, 0, 3800)
    with pytest.raises(ValueError, match=r"R\[0\] has NaN"):
        pi.footprint(sphere, [np.nan, 0, 0], [0, 0, 1])
    with pytest.raises(ValueError, match=r"R\[0\] .* is not above the surface: the DEM radius at its "
                                         r"sub-spacecraft point \(0 N, 0 E\) is 3390"):
        pi.footprint(sphere, _xyz(0, 0, 3000), [0, 0, 1])
    with pytest.raises(ValueError, match="zeta"):
        pi.footprint(sphere, R, [0, 0, 1], zeta=1.5)
    with pytest.raises(ValueError, match="not both"):
        pi.footprint(sphere, R, [0, 0, 1], zeta=0.5, flux_fraction=0.5)
    with pytest.raises(ValueError, match="flux_fraction"):
        pi.footprint(sphere, R, [0, 0, 1], flux_fraction=0.0)
    with pytest.raises(ValueError, match="perpendicular"):
        pi.footprint(sphere, R, R)
    with pytest.raises(ValueError, match="area"):
        pi.footprint(sphere, R, [0, 0, 1], area=-1)
    with pytest.raises(ValueError, match="shape"):
        pi.footprint(sphere, np.ones((2, 2)), [0, 0, 1])
    with pytest.raises(ValueError, match="model"):
        pi.airmass(30, model="kasten")
    with pytest.raises(ValueError, match="z_deg"):
        pi.airmass(np.nan)
    with pytest.raises(ValueError, match="T must be"):
        pi.scale_height(T=-5)
    with pytest.raises(ValueError, match="threads"):
        pi.footprint(sphere, R, [0, 0, 1], threads=-1)
    with pytest.raises(ValueError, match="threads"):
        pi.footprint(sphere, R, [0, 0, 1], threads=10 ** 6)
    with pytest.raises(ValueError, match="use larger cells"):
        pi.CellTable(sphere.dem, 0.001)
    with pytest.raises(ValueError, match="v: 2 velocities"):
        pi.footprint(sphere, R, [[0, 0, 1.0], [0, 1.0, 0]])


# ---------------------------------------------------------------------------------------------
# eccentric orbit (notes' last section)
# ---------------------------------------------------------------------------------------------
def test_eccentric_orbit_study(sphere):
    st = F.orbit_study(sphere, n=181)
    # the notes' 16 % from their own altitudes 385.6 and 454.4 km above 3397 km
    a = lambda h: h / (3397.0 + h)       # noqa: E731  (cap area / 2 pi r^2)
    assert math.isclose(st.notes_variation, a(454.4) / a(385.6) - 1, rel_tol=1e-12)
    assert round(100 * st.notes_variation) == 16
    assert math.isclose(st.area_variation, a(450.0) / a(387.0) - 1, rel_tol=1e-6)
    assert 0.14 < st.area_variation < 0.145
    # periapsis at t = 0, apoapsis half an orbit later; altitudes 387 and 450 km
    assert st.periapsis_index == 0 and abs(st.apoapsis_index - 90) <= 1
    assert math.isclose(st.altitude.min(), 387.0, abs_tol=1e-6)
    assert math.isclose(st.altitude.max(), 450.0, abs_tol=1e-3)
    # more cells above the horizon at apoapsis; nadir angles to a fixed ground offset shrink with altitude
    c0 = st.counts[0.0]
    assert c0[st.apoapsis_index] > c0[st.periapsis_index]
    assert np.all(st.nadir[st.apoapsis_index] < st.nadir[st.periapsis_index])


def test_keplerian_states_conserve_energy_and_momentum():
    t = np.linspace(0, 7000, 50)
    R, v = F.keplerian_states(t, 3784.0, 3847.0, 93.1, rotation_rate=0.0)
    eps = 0.5 * np.sum(v * v, axis=1) - F.MARS_GM / np.linalg.norm(R, axis=1)
    assert np.ptp(eps) / abs(eps.mean()) < 1e-12
    assert math.isclose(eps.mean(), -F.MARS_GM / (3784.0 + 3847.0), rel_tol=1e-12)


# ------------------------------------------------------------- faults found by a review (2026-12-02)
def test_position_angle_near_a_pole(sphere):
    """Spacecraft 1e-6 deg from the north pole: the position angle against the great-circle
    bearing written from colatitudes (cos(lat) = sin(colatitude), no cancellation). North's z
    component was 1 - z^2, which cancels here: 2.3e-4 deg off (grs-notes note 5)."""
    for colat_deg in (1e-3, 1e-6, 1e-8):
        c = math.radians(colat_deg)
        lon0 = math.radians(37.0)
        R = 3790.0 * np.array([math.sin(c) * math.cos(lon0), math.sin(c) * math.sin(lon0), math.cos(c)])
        fp = pi.footprint(sphere, R, [1.0, 0.0, 0.0], zeta=0.99)
        lat2 = np.radians(sphere.lat[fp.cell])
        c2 = np.radians(90.0 - sphere.lat[fp.cell])                 # the cells' colatitudes, exact in degrees
        dl = np.radians(sphere.lon[fp.cell]) - lon0
        ref = np.degrees(np.arctan2(np.sin(dl) * np.sin(c2),
                                    math.sin(c) * np.cos(c2) - math.cos(c) * np.sin(c2) * np.cos(dl))) % 360.0
        assert np.all(lat2 > 0) and len(fp) > 100
        for pa in (fp.position_angle, F.position_angle(R, sphere.u[fp.cell])):
            err = np.abs((pa - ref + 180.0) % 360.0 - 180.0)
            assert err.max() < 1e-8, (colat_deg, err.max())


def test_cell_at_the_sub_spacecraft_point(sphere):
    """A cell straight below the spacecraft: position angle and azimuth NaN (both directions are
    rounding noise there: the review saw PA 0 or 180 deg and azimuths 12-345 deg); every other
    cell finite."""
    for k in (40 * 720 + 100, 200 * 720 + 555, 350 * 720 + 3):
        R = 3790.0 * sphere.u[k]
        for v in ([0.0, 0.0, 1.0], [1.0, 2.0, 0.5], [-3.0, 0.2, 1.0]):
            v = np.array(v) - np.dot(v, sphere.u[k]) * sphere.u[k]
            fp = pi.footprint(sphere, R, v, zeta=0.999)
            at = fp.cell == k
            assert at.sum() == 1
            assert np.isnan(fp.position_angle[at]).all() and np.isnan(fp.azimuth[at]).all()
            assert np.isfinite(fp.position_angle[~at]).all() and np.isfinite(fp.azimuth[~at]).all()
            assert np.isnan(F.position_angle(R, sphere.u[k]))[0]
            assert fp.elevation[at][0] == pytest.approx(-90.0, abs=1e-9)


def test_spacecraft_inside_a_mesa_and_above_lowland():
    """A 30 km mesa filling one 1-degree cell: a spacecraft 10 km inside it is refused, naming R
    and the surface under it (it used to get a footprint: the check was the highest cell mean,
    anywhere); one 20 km above lowland on the far side is refused by the cell search's own
    limit, and the message says so (grs-notes note 17)."""
    radii = np.full((720, 1440), 3390.0)
    radii[400:404, 800:804] += 30.0                     # cell (10-11 N, 200-201 E) at 4 ppd
    cells = pi.CellTable(pi.DEM.from_array(radii), 1.0)
    inside = _xyz(10.5, 200.5, 3410.0)
    with pytest.raises(ValueError, match=r"R\[0\] .*\(\|R\| = 3410\) is not above the surface: the DEM radius at "
                                         r"its sub-spacecraft point \(10.5 N, 200.5 E\) is 3420"):
        pi.footprint(cells, inside, [0, 0, 1.0])
    with pytest.raises(ValueError, match=r"not above the surface"):
        pi.footprint(cells, inside, [0, 0, 1.0], occlusion=True)
    low = _xyz(-10.5, 20.5, 3410.0)
    with pytest.raises(ValueError, match=r"above the surface at its sub-spacecraft point but not above the highest "
                                         r"cell centre \(3420, cell \d+ at 10.5 N, 200.5 E\)"):
        pi.footprint(cells, low, [0, 0, 1.0])
    fp = pi.footprint(cells, _xyz(-10.5, 20.5, 3421.0), [0, 0, 1.0])       # above every cell centre: fine
    assert len(fp) > 0
    with pytest.raises(ValueError, match=r"R\[1\] .* too far from the centre"):
        pi.footprint(cells, [_xyz(0, 0, 3800.0), [1e155, 0, 0]], [0, 0, 1.0])


def test_cell_mean_sees_a_narrow_mesa():
    """0.9-degree cells on a 16 ppd DEM (not a whole number of pixels): the cell's radius is the
    mean of the bilinear surface over the cell, sampled at least once per pixel; a 10 km mesa two
    pixels wide (0.125 deg) at the cell's centre raises it by about its share of the area
    (4 x 4 samples missed it: 0 km)."""
    n = 180 * 16
    radii = np.full((n, 2 * n), 3390.0)
    # cell 0.9 deg: row i = 111 holds latitudes 9.9..10.8; its centre 10.35 N, 180.45 E
    r0, c0 = int((10.35 + 90) * 16), int(180.45 * 16)
    radii[r0 - 1:r0 + 1, c0 - 1:c0 + 1] += 10.0
    cells = pi.CellTable(pi.DEM.from_array(radii), 0.9)
    k = cells.index(10.35, 180.45)
    area_share = (0.125 / 0.9) ** 2                   # the mesa's pixel box over the cell's
    rise = float(cells.radius[k]) - 3390.0
    # the bilinear surface ramps over one pixel around the 2 x 2 plateau: between the plateau's
    # share (1/4 of the box of centres) and the box's share
    assert 10.0 * area_share / 4 < rise < 10.0 * area_share * 2.5, rise


def test_cell_index_refuses_bad_coordinates(sphere):
    assert sphere.index(90.0, 359.99) == 359 * 720 + 719
    assert sphere.index(-90.0, -0.1) == 719
    for lat, lon, what in ((np.nan, 0.0, "lat"), (0.0, np.inf, "lon"), (95.0, 0.0, "outside"),
                           ([0.0, -1000.0], 0.0, "outside")):
        with pytest.raises(ValueError, match=what):
            sphere.index(lat, lon)


def test_velocity_magnitude_does_not_matter(sphere):
    """Only v's direction is used: 1e-200 and 1e200 give the frame of 1, bit for bit."""
    R = _xyz(30.0, 40.0, 3790.0)
    v1 = np.array([0.3, -0.2, 1.0])
    v1 = v1 - np.dot(v1, R) / np.dot(R, R) * R
    ref = pi.footprint(sphere, R, v1, zeta=0.99)
    for s in (2.0 ** -660, 2.0 ** 650, 1e-200, 1e200):
        exact = s in (2.0 ** -660, 2.0 ** 650)           # powers of two scale v exactly: bit for bit
        same = np.testing.assert_array_equal if exact else (
            lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-13, atol=1e-10))
        fp = pi.footprint(sphere, R, s * v1, zeta=0.99)
        same(fp.gsh, ref.gsh)
        same(fp.azimuth, ref.azimuth)
        same(F.spacecraft_frame(R, s * v1), F.spacecraft_frame(R, v1))
        same(F.frame_angles(R, s * v1)[2], F.frame_angles(R, v1)[2])
        same(F.orbit_frame(R, s * v1)[0], F.orbit_frame(R, v1)[0])


def test_helpers_refuse_bad_arguments(sphere):
    cases = [
        (lambda: F.visible_cap_area(-100.0, 3390.0), "altitude"),
        (lambda: F.visible_cap_area(400.0, -1.0), "radius"),
        (lambda: F.detic_latitude(45.0, 1.5), "f must be"),
        (lambda: F.detic_latitude(45.0, -1.0), "f must be"),
        (lambda: F.detic_latitude(95.0, 0.005), "lat_deg"),
        (lambda: F.keplerian_states([0.0], 3700.0, np.inf), "apoapsis_radius"),
        (lambda: F.keplerian_states([0.0], 3700.0, 3800.0, GM=-1.0), "GM"),
        (lambda: F.position_angle([0.0, 0.0, 0.0], [1.0, 0.0, 0.0]), "R"),
        (lambda: F.orbit_frame([[3790.0, 0, 0]] * 2, [[0, 1.0, 0]] * 3), "R and v"),
        (lambda: F.airmass(45.0, H=1e-320), "overflows"),
        (lambda: F.airmass([1.0, 2.0, 3.0], R=[3390.0, 3391.0]), "z_deg and R"),
        (lambda: F.airmass(True), "z_deg"),
        (lambda: pi.footprint(sphere, np.array([3790.0 + 1j, 0, 0]), [0, 0, 1.0]), "complex"),
    ]
    for call, what in cases:
        with pytest.raises(ValueError, match=what):
            call()
    assert F.visible_cap_area(0.0, 3390.0) == 0.0


def test_second_review_arguments(sphere):
    """A second review (2026-12-03): occlusion="no" was taken as True; occlusion_tol and
    progress without occlusion were ignored; scale_height overflowed (r = 1e160), divided by
    zero (GM = 1e-300) or returned 0 (GM = 1e308); a spacecraft 1e200 km away leaked an
    overflow warning from |R|^2."""
    R = _xyz(30.0, 40.0, 3790.0)
    v = np.array([0.3, -0.2, 1.0])
    v = v - np.dot(v, R) / np.dot(R, R) * R
    with pytest.raises(TypeError, match="occlusion must be True or False, got 'no'"):
        pi.footprint(sphere, R, v, occlusion="no")
    with pytest.raises(ValueError, match="occlusion_tol and progress apply only with occlusion=True"):
        pi.footprint(sphere, R, v, occlusion_tol=1e-3)
    for kw in (dict(r=1e160), dict(GM=1e-300), dict(GM=1e308), dict(T=1e-320)):
        with pytest.raises(ValueError, match="give no finite positive scale height"):
            pi.scale_height(**kw)
    assert pi.scale_height() == pytest.approx(10.8, abs=0.1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")                 # refused, and without an overflow warning first
        with pytest.raises(ValueError, match=r"R\[0\] = .* is too far from the centre"):
            pi.footprint(sphere, [1e200, 0, 0], [0, 0, 1.0])
