"""Sensor models for image simulation (issue 12 section 1): Keplerian-orbit
pushbroom, pinhole frame cameras, footprint corners, ground sampling distances.

Every expectation is independent of the code under test: Kepler's laws and
two-body invariants, closed-form sphere geometry, pyproj's geodetic/ECEF
transform, and pi.intersect on flat DSMs.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect.sensors import FrameCamera, Pushbroom, off_nadir_angle, view_zenith_angle

A, F = 6378137.0, 1 / 298.257223563
GM, WE = 3.986004418e14, 7.2921150e-5
R_SPHERE = 6371000.0


def unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def to_ecef(lat, lon, h):
    """Geodetic -> ECEF by pyproj (WGS-84), the independent conversion."""
    pyproj = pytest.importorskip("pyproj", reason="pyproj (extra 'geo') is not installed")
    tr = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    x, y, z = tr.transform(np.asarray(lon, float), np.asarray(lat, float), np.asarray(h, float))
    return np.stack([x, y, z], axis=-1)


def to_geodetic(p):
    """ECEF -> geodetic by the package, confirmed by pyproj's forward transform to
    1e-6 m (pyproj's own inverse is only good to ~2 mm / 2e-8 deg at 700 km up)."""
    p = np.asarray(p, float)
    lat, lon, h = pi.ecef_to_geodetic(p)
    np.testing.assert_allclose(to_ecef(lat, lon, h), p, rtol=0, atol=1e-6)
    return np.asarray(lat), np.asarray(lon), np.asarray(h)


def flat_dsm(lat0, lon0, half_deg, h=0.0, a=A, f=F, n=41):
    d = 2 * half_deg / (n - 1)
    return pi.GeodeticDSM.from_array(np.full((n, n), float(h)), lat0 - half_deg, lon0 - half_deg, d, d, a=a, f=f)


def to_inertial(s, t, omega=WE):
    """Undo the Earth's rotation: inertial = Rz(+omega t) ECR."""
    c, sn = np.cos(omega * t), np.sin(omega * t)
    return np.stack([c * s[:, 0] - sn * s[:, 1], sn * s[:, 0] + c * s[:, 1], s[:, 2]], axis=1)


def normal(lat, lon):
    la, lo = np.radians(lat), np.radians(lon)
    return np.stack([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)], axis=-1)


# ---------------------------------------------------------------- orbit: Kepler
def test_circular_orbit_radius_period_and_reference_point():
    """|s| = r0 on every line; the inertial angle swept per line is 2 pi / 8 for
    line_period = T/8 with T = 2 pi sqrt(r0^3/GM); line 8 returns to line 0; the
    centre line's satellite is at (lat, lon, altitude) by pyproj."""
    lat0, lon0, H = 10.0, 20.0, 700e3
    r0 = np.linalg.norm(to_ecef(lat0, lon0, H))
    period = 2 * math.pi * math.sqrt(r0 ** 3 / GM)
    pb = Pushbroom.from_orbit(altitude=H, inclination=51.6, npixels=3, ifov=0.01, nlines=9,
                              line_period=period / 8, lat=lat0, lon=lon0)
    assert pb.orbit["period"] == pytest.approx(period, rel=1e-12)
    np.testing.assert_allclose(np.linalg.norm(pb.s, axis=1), r0, rtol=0, atol=1e-6)
    si = to_inertial(pb.s, pb.times)
    ang = np.arccos(np.clip(np.sum(unit(si[1:]) * unit(si[:-1]), axis=1), -1, 1))
    np.testing.assert_allclose(ang, 2 * math.pi / 8, rtol=0, atol=1e-11)
    np.testing.assert_allclose(si[8], si[0], rtol=0, atol=1e-6)
    np.testing.assert_allclose(pb.s[4], to_ecef(lat0, lon0, H), rtol=0, atol=1e-6)
    la, lo, h = to_geodetic(pb.s[4])
    assert (float(la), float(lo), float(h)) == pytest.approx((lat0, lon0, H), abs=1e-7)


@pytest.mark.parametrize("e, argp, alt", [(0.05, 30.0, 500e3), (0.01, 250.0, 500e3), (0.7, 270.0, 20000e3)])
def test_eccentric_orbit_two_body_invariants(e, argp, alt):
    """Inertial energy v^2/2 - GM/r and angular momentum r x v constant over an
    orbit; the eccentricity recovered from them, sqrt(1 + 2 eps h^2 / GM^2), is the one asked;
    one period later the inertial position repeats."""
    pb0 = Pushbroom.from_orbit(altitude=alt, inclination=63.4, npixels=1, ifov=0.01, lat=5.0, lon=-40.0,
                               eccentricity=e, arg_perigee=argp)
    T = pb0.orbit["period"]
    pb = Pushbroom.from_orbit(altitude=alt, inclination=63.4, npixels=1, ifov=0.01, lat=5.0, lon=-40.0,
                              eccentricity=e, arg_perigee=argp, nlines=17, line_period=T / 16)
    r = to_inertial(pb.s, pb.times)
    v = to_inertial(pb.velocity, pb.times) + WE * np.stack([-r[:, 1], r[:, 0], 0 * r[:, 0]], axis=1)
    eps = 0.5 * np.sum(v * v, axis=1) - GM / np.linalg.norm(r, axis=1)
    hvec = np.cross(r, v)
    np.testing.assert_allclose(eps, eps[0], rtol=1e-10)
    np.testing.assert_allclose(hvec, np.broadcast_to(hvec[0], hvec.shape), rtol=0, atol=1e-9 * np.linalg.norm(hvec[0]))
    h2 = np.sum(hvec[0] ** 2)
    assert math.sqrt(1 + 2 * eps[0] * h2 / GM ** 2) == pytest.approx(e, abs=1e-9)
    assert -GM / (2 * eps[0]) == pytest.approx(pb.orbit["sma"], rel=1e-10)          # vis-viva
    assert 2 * math.pi * math.sqrt(pb.orbit["sma"] ** 3 / GM) == pytest.approx(T, rel=1e-12)
    np.testing.assert_allclose(r[16], r[0], rtol=0, atol=1e-5)
    inc = math.degrees(math.acos(hvec[0][2] / math.sqrt(h2)))
    assert inc == pytest.approx(63.4, abs=1e-9)
    la, lo, h = to_geodetic(pb.s[8])
    assert (float(la), float(lo), float(h)) == pytest.approx((5.0, -40.0, alt), abs=1e-7)


@pytest.mark.parametrize("inc, direction", [(51.6, "ascending"), (98.2, "ascending"), (51.6, "descending")])
def test_ground_track_max_latitude_is_inclination(inc, direction):
    """Geocentric latitude of the satellite over half an orbit peaks at i (prograde)
    or 180 - i (retrograde); north-bound on an ascending pass, south-bound on a descending one."""
    T = 2 * math.pi * math.sqrt((A + 600e3) ** 3 / GM)
    lat0 = 0.0 if direction == "ascending" else 30.0
    pb = Pushbroom.from_orbit(altitude=600e3, inclination=inc, npixels=1, ifov=0.01, lat=lat0, lon=0.0,
                              direction=direction, nlines=4001, line_period=T / 4000)
    latc = np.degrees(np.arcsin(pb.s[:, 2] / np.linalg.norm(pb.s, axis=1)))
    expect = inc if inc <= 90 else 180 - inc
    assert latc.max() == pytest.approx(expect, abs=2e-4)     # sampling: (2 pi / 4000)^2 / 2 rad ~ 7e-5 deg
    assert latc.min() == pytest.approx(-expect, abs=2e-4)
    kc = 2000
    going_north = pb.s[kc + 1, 2] > pb.s[kc - 1, 2]
    assert going_north == (direction == "ascending")


def test_earth_rotation_moves_polar_track_west():
    """Polar orbit (i = 90): the orbit plane holds the poles, so the sub-satellite
    longitude is lon0 - omega t exactly; without rotation it stays lon0."""
    kw = dict(altitude=700e3, inclination=90.0, npixels=1, ifov=0.01, lat=0.0, lon=30.0, nlines=121,
              line_period=10.0)
    pb = Pushbroom.from_orbit(**kw)
    _, lon, _ = to_geodetic(pb.s)
    np.testing.assert_allclose(lon, 30.0 - np.degrees(WE * pb.times), rtol=0, atol=1e-9)
    pb0 = Pushbroom.from_orbit(rotation_rate=0.0, **kw)
    _, lon0, _ = to_geodetic(pb0.s)
    np.testing.assert_allclose(lon0, 30.0, rtol=0, atol=1e-9)
    assert np.degrees(WE * 600) == pytest.approx(2.507, abs=1e-3)     # 10 min: 2.5 deg west


def test_ground_speed_on_a_sphere():
    """Polar orbit over the equator of a sphere, nadir view: the ground point moves
    at R sqrt(n^2 + omega^2) (orbit rate north, Earth rotation west); the
    along-track GSD is that times the line period."""
    H, dt = 700e3, 1e-3
    pb = Pushbroom.from_orbit(altitude=H, inclination=90.0, npixels=3, ifov=1e-4, lat=0.0, lon=10.0,
                              nlines=3, line_period=dt, a=R_SPHERE, f=0.0)
    dsm = flat_dsm(0.0, 10.0, 1.0, a=R_SPHERE, f=0.0)
    n = math.sqrt(GM / (R_SPHERE + H) ** 3)
    speed = R_SPHERE * math.hypot(n, WE)
    g = pb.gsd(dsm)
    assert g["along"][1] == pytest.approx(speed * dt, rel=1e-7)
    assert speed == pytest.approx(6780.7, abs=0.5)          # ~6.78 km/s ground speed at 700 km


# ---------------------------------------------------------------- pointing
@pytest.mark.parametrize("direction, west", [("ascending", True), ("descending", False)])
@pytest.mark.parametrize("roll", [10.0, -10.0])
def test_roll_side_and_off_nadir_angle(direction, west, roll):
    """roll > 0 looks left of the flight direction (west when north-bound, east
    when south-bound); the off-nadir angle from the ellipsoid normal through the
    satellite (pyproj) equals |roll|."""
    pb = Pushbroom.from_orbit(altitude=700e3, inclination=60.0, npixels=1, ifov=0.01, lat=20.0, lon=0.0,
                              direction=direction, roll=roll, nlines=3, line_period=0.1)
    s, l = pb.pixel_rays([1], [0])
    la, lo, _ = to_geodetic(s[0])
    off = math.degrees(math.acos(-unit(l[0]) @ normal(la, lo)))
    assert off == pytest.approx(abs(roll), abs=1e-8)
    res = pi.intersect(flat_dsm(20.0, 0.0, 3.0), s, l, method="exact")
    assert res.hit[0]
    flight = pb.s[2] - pb.s[0]
    left = np.cross(normal(la, lo), flight)
    side = (res.p[0] - s[0]) @ left
    assert (side > 0) == (roll > 0)
    assert (res.lon[0] < 0) == (west == (roll > 0))


def test_pitch_looks_forward():
    pb = Pushbroom.from_orbit(altitude=700e3, inclination=60.0, npixels=1, ifov=0.01, lat=20.0, lon=0.0,
                              pitch=5.0, nlines=3, line_period=0.1)
    s, l = pb.pixel_rays([1], [0])
    la, lo, _ = to_geodetic(s[0])
    assert math.degrees(math.acos(-unit(l[0]) @ normal(la, lo))) == pytest.approx(5.0, abs=1e-8)
    assert l[0] @ (pb.s[2] - pb.s[0]) > 0


@pytest.mark.parametrize("off_nadir", [5.0, 20.0, 40.0])
def test_view_zenith_closed_form_on_sphere(off_nadir):
    """Sphere R, altitude H: the hit's zenith angle (pi.intersect's incidence) is
    asin((R+H)/R sin(alpha)) for roll alpha; the helpers agree and invert each other."""
    H = 700e3
    pb = Pushbroom.from_orbit(altitude=H, inclination=97.0, npixels=1, ifov=0.01, lat=0.0, lon=0.0,
                              roll=off_nadir, a=R_SPHERE, f=0.0)
    res = pi.intersect(flat_dsm(0.0, 0.0, 12.0, a=R_SPHERE, f=0.0), *pb.rays(), method="exact")
    expect = math.degrees(math.asin((R_SPHERE + H) / R_SPHERE * math.sin(math.radians(off_nadir))))
    assert res.incidence[0] == pytest.approx(expect, abs=1e-7)
    assert view_zenith_angle(off_nadir, H, R_SPHERE) == pytest.approx(expect, abs=1e-12)
    assert off_nadir_angle(expect, H, R_SPHERE) == pytest.approx(off_nadir, abs=1e-10)
    # the ground distance from the sub-satellite point: R * (theta - alpha)
    gamma = math.radians(expect - off_nadir)
    assert np.linalg.norm(res.p[0] - R_SPHERE * unit(pb.s[0])) == pytest.approx(2 * R_SPHERE * math.sin(gamma / 2),
                                                                               rel=1e-9)


def test_viewing_angle_helpers_numbers_and_errors():
    assert view_zenith_angle(8.0, 700e3) == pytest.approx(
        math.degrees(math.asin((A + 700e3) / A * math.sin(math.radians(8)))), abs=1e-12)
    assert view_zenith_angle(0.0, 700e3) == 0.0
    np.testing.assert_allclose(off_nadir_angle(view_zenith_angle([1.0, 30.0], 500e3), 500e3), [1.0, 30.0])
    horizon = math.degrees(math.asin(A / (A + 700e3)))
    with pytest.raises(ValueError, match="horizon"):
        view_zenith_angle(horizon + 0.1, 700e3)
    with pytest.raises(ValueError, match="altitude"):
        view_zenith_angle(5.0, -1.0)
    with pytest.raises(ValueError, match="off_nadir"):
        view_zenith_angle(float("nan"), 700e3)
    with pytest.raises(ValueError, match="view_zenith"):
        off_nadir_angle(95.0, 700e3)


@pytest.mark.parametrize("direction", ["ascending", "descending"])
@pytest.mark.parametrize("e", [0.0, 0.002])
def test_target_is_hit_by_the_centre_pixel(direction, e):
    """target=(lat, lon, h): the centre pixel of the centre line hits it within
    1 cm (pi.intersect, exact, flat DSM at h; target converted by pyproj)."""
    tgt = (36.6, -84.3, 300.0)
    pb = Pushbroom.from_orbit(altitude=680e3, inclination=98.2, npixels=5, ifov=0.01, nlines=3, line_rate=500,
                              target=tgt, direction=direction, roll=9.0, pitch=2.0, yaw=3.0,
                              eccentricity=e, arg_perigee=40.0)
    s, l = pb.pixel_rays([1], [2])
    res = pi.intersect(flat_dsm(36.6, -84.3, 1.0, h=300.0), s, l, method="exact")
    assert res.hit[0]
    assert np.linalg.norm(res.p[0] - to_ecef(*tgt)) < 0.01
    la, lo, h = to_geodetic(s[0])
    assert float(h) == pytest.approx(680e3, abs=1e-6)
    going_north = pb.s[2, 2] > pb.s[0, 2]
    assert going_north == (direction == "ascending")
    # the satellite sits east of the target when rolling left on a north-bound pass (and west south-bound)
    assert (float(lo) > -84.3) == (direction == "ascending")


# ---------------------------------------------------------------- GSD
def test_gsd_at_nadir_is_altitude_times_ifov():
    H, ifov_rad = 600e3, 2e-6
    pb = Pushbroom.from_orbit(altitude=H, inclination=98.0, npixels=101, ifov=math.degrees(ifov_rad),
                              lat=45.0, lon=7.0, nlines=3, line_rate=2000.0)
    g = pb.gsd(flat_dsm(45.0, 7.0, 0.2))
    assert g["across"][1] == pytest.approx(H * ifov_rad, rel=1e-3)
    assert g["across"][1] == pytest.approx(1.2, rel=1e-3)


def test_gsd_at_edges_on_sphere():
    """Sphere: the hit at off-nadir alpha is at geocentric angle gamma(alpha) =
    asin((R+H)/R sin alpha) - alpha; edge GSD = chord 2 R sin(dgamma/2)."""
    H, R, ifov = 700e3, R_SPHERE, 0.1
    pb = Pushbroom.from_orbit(altitude=H, inclination=97.0, npixels=201, ifov=ifov, lat=0.0, lon=0.0,
                              a=R, f=0.0)
    g = pb.gsd(flat_dsm(0.0, 0.0, 5.0, a=R, f=0.0))

    def gamma(alpha_deg):
        al = math.radians(alpha_deg)
        return math.asin((R + H) / R * math.sin(al)) - al

    edge = 2 * R * math.sin((gamma(10.0) - gamma(9.9)) / 2)
    centre = 2 * R * math.sin((gamma(0.1) - gamma(-0.1)) / 2) / 2
    np.testing.assert_allclose(g["across"], [edge, centre, edge], rtol=1e-7)
    assert np.isnan(g["along"]).all()                 # one line: no along-track spacing


# ---------------------------------------------------------------- frame cameras
def test_nadir_frame_camera_corners():
    """Nadir camera H above flat ground: corner pixel centres at east/north
    offsets +-H tan(half fov), tan(half fov) = (n-1)/2 * 2 tan(ifov/2); top row north."""
    lat0, lon0, H = 45.0, 7.0, 1000.0
    nrows, ncols, ifov = 5, 7, 5.0
    cam = FrameCamera.nadir(lat0, lon0, H, (nrows, ncols), ifov)
    np.testing.assert_allclose(cam.position, to_ecef(lat0, lon0, H), rtol=0, atol=1e-6)
    corners = cam.footprint_corners(flat_dsm(lat0, lon0, 0.05))
    p = to_ecef(corners[:, 0], corners[:, 1], np.zeros(4))
    p0 = to_ecef(lat0, lon0, 0.0)
    la, lo = math.radians(lat0), math.radians(lon0)
    east = np.array([-math.sin(lo), math.cos(lo), 0.0])
    north = np.array([-math.sin(la) * math.cos(lo), -math.sin(la) * math.sin(lo), math.cos(la)])
    pitch = 2 * math.tan(math.radians(ifov / 2))
    ex, ny = H * (ncols - 1) / 2 * pitch, H * (nrows - 1) / 2 * pitch
    expect = np.array([[-ex, ny], [ex, ny], [ex, -ny], [-ex, -ny]])     # NW, NE, SE, SW
    got = np.column_stack([(p - p0) @ east, (p - p0) @ north])
    np.testing.assert_allclose(got, expect, rtol=1e-4)
    g = cam.gsd(flat_dsm(lat0, lon0, 0.05))
    assert g["across"][1] == pytest.approx(H * pitch, rel=1e-4)
    assert g["along"][1] == pytest.approx(H * pitch, rel=1e-4)


def test_pinhole_aims_at_target_and_rotates():
    pos = (46.0, 8.0, 3000.0)
    tgt = (46.01, 8.02, 450.0)
    cam = FrameCamera.pinhole(pos, tgt, (9, 9), 0.5, geodetic=True)
    np.testing.assert_allclose(cam.position, to_ecef(*pos), rtol=0, atol=1e-6)
    s, l = cam.pixel_rays([4], [4])
    res = pi.intersect(flat_dsm(46.0, 8.0, 0.1, h=450.0), s, l, method="exact")
    assert np.linalg.norm(res.p[0] - to_ecef(*tgt)) < 0.01
    cam90 = FrameCamera.pinhole(pos, tgt, (9, 9), 0.5, rotation=90.0, geodetic=True)
    l0, l90 = cam.l, cam90.l
    np.testing.assert_allclose(l90, l0[:, ::-1].transpose(1, 0, 2), rtol=0, atol=1e-14)   # l90[k,m] = l0[m, n-1-k]
    # the central pixel spans +-p/2 on a unit focal plane, p = 2 tan(ifov/2): its neighbour's centre is atan(p) away
    _, lc = cam.pixel_rays([4, 4], [4, 5])
    p = 2 * math.tan(math.radians(0.25))
    assert math.acos(unit(lc[0]) @ unit(lc[1])) == pytest.approx(math.atan(p), abs=1e-12)


def test_corner_outside_dsm_is_nan_with_warning():
    cam = FrameCamera.nadir(45.0, 7.0, 1000.0, (3, 3), 20.0)
    small = pi.GeodeticDSM.from_array(np.zeros((5, 5)), 45.0, 7.0, 0.002, 0.002)   # NE quadrant only
    with pytest.warns(RuntimeWarning, match="corner pixel"):
        c = cam.footprint_corners(small)
    assert np.isfinite(c[1]).all() and np.isnan(c[[0, 2, 3]]).all()


# ---------------------------------------------------------------- contract
def test_lazy_directions_follow_the_rays_contract():
    pb = Pushbroom.from_orbit(altitude=700e3, inclination=98.0, npixels=6, ifov=0.001, lat=10.0, lon=10.0,
                              nlines=7, line_rate=100.0, roll=3.0, yaw=1.0)
    s_all, l_all = pb.rays()
    s_blk, l_blk = zip(*(pb.rays(k, min(k + 3, 7)) for k in range(0, 7, 3)))
    np.testing.assert_array_equal(np.concatenate(l_blk), l_all)
    np.testing.assert_array_equal(np.concatenate(s_blk), s_all)
    user = Pushbroom(pb.s, pb.l)                      # the same geometry given as arrays
    np.testing.assert_array_equal(user.rays(2, 5)[1], pb.rays(2, 5)[1])
    np.testing.assert_allclose(np.linalg.norm(l_all, axis=1), 1.0, atol=1e-15)
    # across-track look angles of the detectors: (m - 2.5) * ifov from the boresight
    b = pb.frames[3][:, 2]
    ang = np.degrees(np.arctan2(np.linalg.norm(np.cross(pb.l[3], b), axis=1), pb.l[3] @ b))
    np.testing.assert_allclose(ang, np.abs(np.arange(6) - 2.5) * 0.001, atol=1e-9)
    cam = FrameCamera.nadir(0.0, 0.0, 100.0, (4, 5), 1.0)
    np.testing.assert_array_equal(FrameCamera(cam.position, cam.l).rays(1, 3)[1], cam.rays(1, 3)[1])


def test_look_angles_and_yaw_steering():
    la = np.array([-2.0, 0.0, 1.5])
    pb = Pushbroom.from_orbit(altitude=700e3, inclination=98.0, npixels=3, ifov=1.0, lat=0.0, lon=0.0,
                              look_angles=la, yaw_steering=False)
    b = pb.frames[0][:, 2]
    y = pb.frames[0][:, 1]
    ang = np.degrees(np.arctan2(pb.l[0] @ y, pb.l[0] @ b))
    np.testing.assert_allclose(ang, la, atol=1e-12)
    # without yaw steering x follows the inertial velocity: v_ecr + omega z x s
    v_in = pb.velocity[0] + WE * np.array([-pb.s[0, 1], pb.s[0, 0], 0.0])
    x = pb.frames[0][:, 0]
    assert x @ unit(v_in - (v_in @ b) * b) == pytest.approx(1.0, abs=1e-12)
    pb2 = Pushbroom.from_orbit(altitude=700e3, inclination=98.0, npixels=3, ifov=1.0, lat=0.0, lon=0.0)
    v = pb2.velocity[0]
    b2 = pb2.frames[0][:, 2]
    assert pb2.frames[0][:, 0] @ unit(v - (v @ b2) * b2) == pytest.approx(1.0, abs=1e-12)
    # the two differ by the ground-track crab angle, atan(omega R cos(i') / v) ~ 3.9 deg at the equator
    crab = math.degrees(math.acos(pb.frames[0][:, 0] @ pb2.frames[0][:, 0]))
    assert 3.0 < crab < 4.5


# ---------------------------------------------------------------- validation
GOOD = dict(altitude=700e3, inclination=98.0, npixels=3, ifov=0.01, lat=10.0, lon=10.0)


@pytest.mark.parametrize("change, exc, match", [
    (dict(altitude=-5.0), ValueError, "altitude"),
    (dict(altitude=float("nan")), ValueError, "altitude"),
    (dict(inclination=181.0), ValueError, "inclination"),
    (dict(npixels=0), ValueError, "npixels"),
    (dict(npixels=2.5), TypeError, "npixels"),
    (dict(ifov=0.0), ValueError, "ifov"),
    (dict(ifov="1"), TypeError, "ifov"),
    (dict(ifov=1.0, npixels=200), ValueError, "npixels \\* ifov"),
    (dict(nlines=5), ValueError, "line_rate"),
    (dict(nlines=5, line_rate=10.0, line_period=0.1), ValueError, "line_rate or line_period"),
    (dict(nlines=5, line_rate=-1.0), ValueError, "line_rate"),
    (dict(direction="north"), ValueError, "direction"),
    (dict(roll=95.0), ValueError, "roll"),
    (dict(pitch=float("inf")), ValueError, "pitch"),
    (dict(eccentricity=1.0), ValueError, "eccentricity"),
    (dict(eccentricity=0.5, arg_perigee=180.0 + 10.0), ValueError, "perigee"),
    (dict(lat=None), ValueError, "lat and lon"),
    (dict(target=(10.0, 10.0)), ValueError, "not both"),
    (dict(lat=85.0), ValueError, "lat = 85.0"),
    (dict(look_angles=[0.0, 1.0]), ValueError, "look_angles"),
    (dict(look_angles=[0.0, 1.0, 95.0]), ValueError, "look_angles"),
    (dict(a=-1.0), ValueError, "semi-major"),
    (dict(gm=0.0), ValueError, "gm"),
    (dict(yaw_steering="yes"), TypeError, "yaw_steering"),
])
def test_from_orbit_rejects_bad_input(change, exc, match):
    kw = dict(GOOD)
    kw.update(change)
    with pytest.raises(exc, match=match):
        Pushbroom.from_orbit(**kw)


def test_target_errors():
    kw = dict(GOOD, lat=None, lon=None)
    with pytest.raises(ValueError, match="target"):
        Pushbroom.from_orbit(**dict(kw, target=(10.0,)))
    with pytest.raises(ValueError, match="target lat"):
        Pushbroom.from_orbit(**dict(kw, target=(100.0, 0.0)))
    with pytest.raises(ValueError, match="misses the surface"):          # 70 deg roll from 700 km: past the horizon
        Pushbroom.from_orbit(**dict(kw, target=(10.0, 10.0), roll=70.0))


@pytest.mark.parametrize("call, exc, match", [
    (lambda: FrameCamera.pinhole([1e7, 0, 0], [1e7, 0, 0], (3, 3), 1.0), ValueError, "look_at coincides"),
    (lambda: FrameCamera.pinhole([1e7, 0, 0], [0, 0, 0], (3, 0), 1.0), ValueError, "ncols"),
    (lambda: FrameCamera.pinhole([1e7, 0, 0], [0, 0, 0], 3, 1.0), TypeError, "shape"),
    (lambda: FrameCamera.pinhole([1e7, 0, 0], [0, 0, 0], (3, 3), -1.0), ValueError, "ifov"),
    (lambda: FrameCamera.pinhole([1e7, 0, 0], [0, 0, 0], (3, 3), 1.0, up=[1, 0, 0]), ValueError, "up"),
    (lambda: FrameCamera.pinhole([1e7, 0, np.nan], [0, 0, 0], (3, 3), 1.0), ValueError, "position"),
    (lambda: FrameCamera.pinhole([1e7, 0], [0, 0, 0], (3, 3), 1.0), ValueError, "position"),
    (lambda: FrameCamera.pinhole((95.0, 0, 10), (0, 0, 0), (3, 3), 1.0, geodetic=True), ValueError, "latitude"),
    (lambda: FrameCamera.nadir(45.0, 7.0, 0.0, (3, 3), 1.0), ValueError, "height"),
    (lambda: FrameCamera.nadir(91.0, 7.0, 10.0, (3, 3), 1.0), ValueError, "lat"),
])
def test_frame_camera_rejects_bad_input(call, exc, match):
    with pytest.raises(exc, match=match):
        call()


def test_helpers_reject_bad_input():
    cam = FrameCamera.nadir(45.0, 7.0, 1000.0, (3, 3), 1.0)
    with pytest.raises(TypeError, match="dsm"):
        cam.footprint_corners("dsm.tif")
    with pytest.raises(TypeError, match="dsm"):
        cam.gsd(None)
    with pytest.raises(ValueError, match="method"):
        cam.footprint_corners(flat_dsm(45.0, 7.0, 0.1), method="fast")
    with pytest.raises(ValueError, match="pixels"):
        cam.pixel_rays([0], [3])


# ---------------------------------------------------------------- other bodies, orientation details
def test_mars_orbit_uses_the_given_body():
    """Mars (a, f, GM, rotation): the period is 2 pi sqrt(r^3/GM_mars) and the
    reference point sits at the requested areodetic height (pi.geodetic_to_ecef on Mars's ellipsoid)."""
    a, f, gm, w = 3396190.0, 1 / 169.8, 4.282837e13, 7.088218e-5
    pb = Pushbroom.from_orbit(altitude=300e3, inclination=93.0, npixels=1, ifov=0.01, lat=18.65, lon=-133.8,
                              a=a, f=f, gm=gm, rotation_rate=w, nlines=3, line_period=60.0)
    p_ref = pi.geodetic_to_ecef(18.65, -133.8, 300e3, a, f)
    np.testing.assert_allclose(pb.s[1], p_ref, rtol=0, atol=1e-6)
    r0 = np.linalg.norm(p_ref)
    assert pb.orbit["period"] == pytest.approx(2 * math.pi * math.sqrt(r0 ** 3 / gm), rel=1e-12)
    si = to_inertial(pb.s, pb.times, omega=w)
    ang = math.acos(unit(si[2]) @ unit(si[1]))
    assert ang == pytest.approx(math.sqrt(gm / r0 ** 3) * 60.0, rel=1e-10)


def test_equatorial_orbit_and_retrograde_equatorial():
    """i = 0 moves east at the orbit rate minus the Earth's; i = 180 moves west at both."""
    for inc, sign in ((0.0, 1.0), (180.0, -1.0)):
        pb = Pushbroom.from_orbit(altitude=700e3, inclination=inc, npixels=1, ifov=0.01, lat=0.0, lon=10.0,
                                  nlines=3, line_period=10.0)
        _, lon, _ = to_geodetic(pb.s)
        n = math.sqrt(GM / np.linalg.norm(pb.s[1]) ** 3)
        np.testing.assert_allclose(lon - 10.0, np.degrees((sign * n - WE) * pb.times), rtol=0, atol=1e-9)


def test_horizontal_pinhole_falls_back_to_zenith_up():
    """Looking due north horizontally, north cannot be the image's up: the zenith is,
    so the top row looks higher than the bottom row; default north-up otherwise."""
    p = pi.geodetic_to_ecef(45.0, 7.0, 100.0)
    la, lo = math.radians(45.0), math.radians(7.0)
    north = np.array([-math.sin(la) * math.cos(lo), -math.sin(la) * math.sin(lo), math.cos(la)])
    cam = FrameCamera.pinhole(p, p + 1000.0 * north, (5, 5), 1.0)     # exactly along north: no projection left
    assert np.isfinite(cam.l).all()
    up = normal(45.0, 7.0)
    top, bottom = cam.l[0, 2] @ up, cam.l[4, 2] @ up
    assert top > bottom
    assert abs(cam.axes[:, 0] @ np.array([-math.sin(math.radians(7)), math.cos(math.radians(7)), 0])) \
        == pytest.approx(1.0, abs=1e-6)      # x_c (image right) is east when looking north


def test_pixel_rays_validation():
    cam = FrameCamera.nadir(45.0, 7.0, 1000.0, (3, 4), 1.0)
    with pytest.raises(ValueError, match="lines"):
        cam.pixel_rays([3], [0])
    with pytest.raises(ValueError, match="one length"):
        cam.pixel_rays([0, 1], [0])
    with pytest.raises(TypeError, match="integers"):
        cam.pixel_rays([0.5], [0])
    with pytest.raises(ValueError, match=r"look_angles\[1\]"):
        Pushbroom.from_orbit(**dict(GOOD, look_angles=[0.0, float("nan"), 1.0]))


def test_yaw_turns_the_detector_line_clockwise_from_above():
    """yaw = 0: the line's last pixel is right of the first (across track, +y);
    yaw = 90: turned clockwise seen from above, the last pixel lies behind the first."""
    kw = dict(altitude=700e3, inclination=60.0, npixels=3, ifov=1.0, lat=20.0, lon=0.0, nlines=3, line_period=0.1)
    dsm = flat_dsm(20.0, 0.0, 3.0)
    for yaw in (0.0, 90.0):
        pb = Pushbroom.from_orbit(yaw=yaw, **kw)
        res = pi.intersect(dsm, *pb.pixel_rays([1, 1], [0, 2]), method="exact")
        d = res.p[1] - res.p[0]
        flight = pb.s[2] - pb.s[0]
        right = np.cross(flight, normal(20.0, 0.0))
        if yaw == 0.0:
            assert d @ unit(right) == pytest.approx(np.linalg.norm(d), rel=1e-3)
        else:
            assert d @ unit(flight) == pytest.approx(-np.linalg.norm(d), rel=1e-3)


def test_second_review_sensor_arguments():
    """A second review (2026-12-03): FrameCamera.nadir below ~6 mm or at 1e300 failed with
    "look_at coincides with position", an argument the user never passed; from_orbit with
    gm = 1e-300 around a = 1e30 died of a ZeroDivisionError; NaN positions were named
    "position[np.int64(0)]"."""
    cam = pi.FrameCamera.nadir(45.0, 7.0, 1e-3, (4, 4), 0.1)
    s, l = cam.rays()
    up = pi.geodetic_to_ecef(45.0, 7.0, 1.0) - pi.geodetic_to_ecef(45.0, 7.0, 0.0)
    centre = l.reshape(4, 4, 3)[1:3, 1:3].mean(axis=(0, 1))
    assert np.dot(centre / np.linalg.norm(centre), -up / np.linalg.norm(up)) > 0.99
    with pytest.raises(ValueError, match="height = 1e\\+300: at most 1e15 a"):
        pi.FrameCamera.nadir(45.0, 7.0, 1e300, (4, 4), 0.1)
    with pytest.raises(ValueError, match="no finite positive mean motion"):
        pi.Pushbroom.from_orbit(altitude=685000.0, inclination=98.0, npixels=64, ifov=0.001, nlines=1,
                                lat=-42.7, lon=144.9, gm=1e-300, a=1e30)
    with pytest.raises(ValueError, match=r"position\[0\] has NaN"):
        pi.FrameCamera.pinhole([np.nan, 0, 7e6], [0, 0, 0], (4, 4), 0.1)


def test_rays_refuse_non_integer_lines():
    """The simulation fuzzing (2026-12-03): int() truncated rays(0.5, 1.9) to line 0 and
    rays(True, 2.7) to line 1 without a word."""
    cam = pi.FrameCamera.nadir(45.0, 7.0, 1000.0, (4, 3), 0.01)
    for k0, k1 in ((0.5, 1.9), (True, 2), (0, 2.0), ("0", 2)):
        with pytest.raises(TypeError, match="integer line index"):
            cam.rays(k0, k1)
    s, l = cam.rays(np.int64(1), np.int32(3))
    s2, l2 = cam.rays(1, 3)
    assert np.array_equal(l, l2) and l.shape == (2 * 3, 3)


@pytest.mark.parametrize("lat", [89.99995059265937, 89.9999999, 90.0 - 1e-12, -89.9999999])
def test_from_orbit_puts_the_satellite_over_a_point_near_a_pole(lat):
    """The simulation fuzzing (2026-12-03): the argument of latitude came from asin(sin lat_c /
    sin i), which lost half its digits near 1: the sub-satellite point 0.69 mm and 11.2 mm off the
    asked point 1e-5 and 1e-7 deg from the pole. Expectation: the asked geodetic point, by the
    package's conversion, within 1e-6 m, and the altitude within 1e-6 m."""
    sen = Pushbroom.from_orbit(altitude=450000.0, inclination=90.0, npixels=1, ifov=1e-4, lat=lat, lon=4.96)
    la, lo, h = pi.ecef_to_geodetic(sen.s[0], 6378137.0, 1 / 298.257223563)
    off = np.linalg.norm(pi.geodetic_to_ecef(la, lo, 0.0) - pi.geodetic_to_ecef(lat, 4.96, 0.0))
    assert off < 1e-6, off
    assert abs(float(h) - 450000.0) < 1e-6
