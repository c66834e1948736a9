"""Edges of the documented contract that no test pinned down before.

Found by mutation testing of the Python facade (stop 31: 62 mutants of geodetic.py,
sensors.py, dsm.py, footprint.py, simulate.py and intersect.py; each test below fails
for a mutant that survived the whole suite, named in its docstring). The expected
values come from the docstrings' contract, closed forms and geometry set up here, not
from the implementation.
"""
import math

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect.footprint import flux_weights, position_angle
from planet_intersect.synthetic_dsm import metre_steps

WGS84_A = 6378137.0
WGS84_F = 1 / 298.257223563


def _xyz(lat, lon, r):
    la, lo = np.radians(lat), np.radians(lon)
    return np.array([r * np.cos(la) * np.cos(lo), r * np.cos(la) * np.sin(lo), r * np.sin(la)])


# ---------------------------------------------------------------- geodetic.py


def test_longitudes_just_below_minus_180_stay_in_range():
    """A grid whose first longitude is one ulp below -180: mod(x + 180, 360) rounds to
    360 there, and the documented range [-180, 180) needs the guard that maps it to
    -180 (mutant: the guard dropped, lons[0] = +180)."""
    dsm = pi.GeodeticDSM.from_array(np.zeros((2, 2)), 10.0, np.nextafter(-180.0, -np.inf), -1.0, 1.0)
    assert dsm.lons[0] == -180.0
    assert np.all((dsm.lons >= -180.0) & (dsm.lons < 180.0))


@pytest.mark.parametrize("lat", [np.nextafter(90.0, 91.0), np.nextafter(-90.0, -91.0), 90.3])
def test_latitude_one_ulp_past_a_pole_is_refused(lat):
    """geodetic_to_ecef refuses |lat| > 90 (the only test used 91; mutant: the limit
    moved to 90.5, and 90.3 came back as a point 33.5 km past the pole)."""
    with pytest.raises(ValueError, match="lat"):
        pi.geodetic_to_ecef(lat, 0.0, 0.0)
    assert np.allclose(pi.geodetic_to_ecef(90.0, 0.0, 0.0), [0.0, 0.0, WGS84_A * (1 - WGS84_F)], atol=1e-6)


# ---------------------------------------------------------------- sensors.py


@pytest.mark.parametrize("roll, pitch, yaw, lat", [(20.0, 20.0, 0.0, 0.0), (20.0, -10.0, 30.0, 40.0),
                                                   (-15.0, 25.0, -60.0, -55.0)])
def test_boresight_follows_the_documented_3_2_1_rotation(roll, pitch, yaw, lat):
    """The boresight in the orbital frame (x along the ground-relative velocity made
    horizontal, z down the ellipsoid normal, y = z x x) is Rz(yaw) Ry(pitch) Rx(roll)
    applied to +z: (cos y a - sin y b, sin y a + cos y b, cos p cos r) with
    a = sin p cos r, b = -sin r. Roll and pitch together tell the order apart (the
    off-nadir angle acos(cos p cos r) does not; mutant: Rx Ry Rz, the x and y
    components swapped)."""
    sen = pi.Pushbroom.from_orbit(altitude=700e3, inclination=98.0, npixels=1, ifov=1e-3, lat=lat, lon=10.0,
                                  roll=roll, pitch=pitch, yaw=yaw)
    s, l = sen.rays(0, 1)
    s, l = s[0], l[0] / np.linalg.norm(l[0])
    # the ellipsoid normal through s, from the test's own geodesy
    z = -_unit(*_geodetic(s)[:2])
    v = sen.velocity[0]
    x = v - (v @ z) * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    r, p, w = np.radians([roll, pitch, yaw])
    a, b = math.sin(p) * math.cos(r), -math.sin(r)
    want = [math.cos(w) * a - math.sin(w) * b, math.sin(w) * a + math.cos(w) * b, math.cos(p) * math.cos(r)]
    np.testing.assert_allclose([l @ x, l @ y, l @ z], want, atol=1e-12)


@pytest.mark.parametrize("zenith", [90.0001, 91.0, -0.0001])
def test_view_zenith_outside_0_90_is_refused(zenith):
    """off_nadir_angle takes a view zenith in [0, 90] (mutant: the limit moved to 91,
    and 90.5 deg gave an off-nadir angle of 64.3 deg)."""
    with pytest.raises(ValueError, match="view_zenith|zenith"):
        pi.off_nadir_angle(zenith, 700e3)
    # and at the limit itself: sin(alpha) = R / (R + H)
    assert pi.off_nadir_angle(90.0, 700e3) == pytest.approx(math.degrees(math.asin(WGS84_A / (WGS84_A + 700e3))),
                                                            abs=1e-9)


# ---------------------------------------------------------------- dsm.py / intersect.py


def test_outside_ellipsoid_reports_the_ellipsoid_points_latitude_and_longitude():
    """outside="ellipsoid": ellipsoid_lat/lon are the geodetic coordinates of the ray's
    point on the bare ellipsoid (only ellipsoid_p was checked; mutant: lat and lon
    swapped). The point is solved here as a line-quadric intersection, and its
    latitude is the closed form on the surface, atan(z / ((1 - e2) rho))."""
    d = 1e-4
    dsm = pi.GeodeticDSM.from_array(np.zeros((20, 20)), 45.0, 10.0, -d, d)      # flat, h = 0, 45N 10E
    s = pi.geodetic_to_ecef(45.0 - 10 * d, 10.0 + 10 * d, 1000.0)
    up = s / np.linalg.norm(s)
    east = np.array([-math.sin(math.radians(10.0)), math.cos(math.radians(10.0)), 0.0])
    l = east - 0.05 * up
    res = pi.intersect(dsm, s, l, method="exact", outside="ellipsoid")
    assert res.status[0] == pi.DSMStatus.LEFT_DSM and res.on_ellipsoid[0]
    b = WGS84_A * (1 - WGS84_F)
    u = l / np.linalg.norm(l)
    qa = (u[0] ** 2 + u[1] ** 2) / WGS84_A ** 2 + u[2] ** 2 / b ** 2
    qb = 2 * ((s[0] * u[0] + s[1] * u[1]) / WGS84_A ** 2 + s[2] * u[2] / b ** 2)
    qc = (s[0] ** 2 + s[1] ** 2) / WGS84_A ** 2 + s[2] ** 2 / b ** 2 - 1
    t = (-qb - math.sqrt(qb * qb - 4 * qa * qc)) / (2 * qa)
    q = s + t * u
    e2 = WGS84_F * (2 - WGS84_F)
    lat = math.degrees(math.atan2(q[2], (1 - e2) * math.hypot(q[0], q[1])))
    lon = math.degrees(math.atan2(q[1], q[0]))
    np.testing.assert_allclose(res.ellipsoid_p[0], q, atol=1e-6)
    assert res.ellipsoid_lat[0] == pytest.approx(lat, abs=1e-10)
    assert res.ellipsoid_lon[0] == pytest.approx(lon, abs=1e-10)
    assert 10.25 < lon < 10.28 and 44.99 < lat < 45.0             # ~19 km east, a little south


def test_dsm_incidence_is_in_degrees_from_the_normal():
    """DSMResult.incidence: degrees from the ellipsoid normal (mutant: left in radians,
    0.5236, caught before only by a sensors test)."""
    dsm = pi.GeodeticDSM.from_array(np.zeros((21, 21)), 1.0, -1.0, -0.1, 0.1)       # flat, around 0N 0E
    p = np.array([WGS84_A, 0.0, 0.0])                                                  # normal = +x
    for deg in (0.0, 30.0, 60.0):
        t = math.radians(deg)
        l = np.array([-math.cos(t), math.sin(t), 0.0])
        for method in ("following", "exact", "iterative"):
            res = pi.intersect(dsm, p - 1e4 * l, l, method=method)
            assert res.hit[0] and res.incidence[0] == pytest.approx(deg, abs=1e-6), (deg, method)


@pytest.mark.parametrize("option", [dict(step_mode=0), dict(dem_read_mode=1), dict(tangent="paper"),
                                    dict(io="mmap")])
def test_dem_only_options_are_refused_with_a_dsm(option):
    """Every DEM-only option of intersect is refused with a GeodeticDSM, not only
    step_mode (mutant: tangent= dropped from the check and silently ignored)."""
    dsm = pi.GeodeticDSM.from_array(np.zeros((10, 10)), 45.0, 10.0, -1e-3, 1e-3)
    s = pi.geodetic_to_ecef(44.995, 10.005, 1000.0)
    with pytest.raises(TypeError, match=f"{next(iter(option))}.*planetary DEM"):
        pi.intersect(dsm, s, -s, **option)


# ---------------------------------------------------------------- footprint.py


def test_position_angle_is_nan_within_1e_12_rad_of_a_pole():
    """Over a pole the bearing is undefined: NaN when the spacecraft is within 1e-12 rad
    of the axis (mutant: the rule dropped, a bearing of 180 deg from 1e-13 rad)."""
    for off in (0.0, 1e-13, 9e-13):
        assert np.isnan(position_angle([off * 3500.0, 0.0, 3500.0], [3390.0, 0.0, 0.0])[0]), off
        assert np.isnan(position_angle([0.0, off * 3500.0, -3500.0], [3390.0, 0.0, 0.0])[0]), off
    # 1e-6 rad off the north pole on the 0E meridian: the cell at 0N 0E is due south
    assert position_angle([1e-6 * 3500.0, 0.0, 3500.0], [3390.0, 0.0, 0.0])[0] == pytest.approx(180.0, abs=1e-6)


@pytest.mark.parametrize("q", [0.1, 0.01])
def test_a_cell_behind_its_own_slope_is_hidden_at_the_default_tolerance(q):
    """A line of sight that enters the bilinear surface q of a pixel before its cell is
    occluded: the default tolerance is 1e-6 rmax (3.4 m here), far below the ~148 m
    (q = 0.01) and ~1.5 km (q = 0.1) of terrain in the way (mutants: the test
    'shortfall > tol' made '> 100 tol', or the default tolerance 1e-3 rmax; both left
    the cell visible). Construction: a sphere of 3,390 km at 4 pixels/degree, one
    column of nodes raised so that the ramp to the cell's own node crosses the line
    from a spacecraft 10 deg west and 400 km up exactly q of a pixel west of the cell."""
    from scipy.optimize import brentq

    R = 3390.0
    S = _xyz(0.125, 0.125, R + 400.0)
    T = _xyz(0.125, 10.125, R)                         # the cell centre, DEM node (row 360, column 40)
    w = S - T

    def lon_of(t):
        P = T + t * w
        return math.degrees(math.atan2(P[1], P[0]))

    t = brentq(lambda t: lon_of(t) - (10.125 - q * 0.25), 0.0, 0.5)
    h1 = (np.linalg.norm(T + t * w) - R) / q           # the ramp from node 39 (R + h1) to node 40 (R)
    radii = np.full((720, 1440), R)
    radii[:, 39] += h1
    cells = pi.CellTable(pi.DEM.from_array(radii), 0.25)
    fp = pi.footprint(cells, S, [0, 0, 1.0], occlusion=True)
    sel = fp.cell == int(cells.index(0.125, 10.125))
    assert sel.sum() == 1 and not fp.visible[sel][0]
    # the cell two pixels east of it, beyond the ramp's reach on flat ground, is seen
    east = fp.cell == int(cells.index(0.125, 10.625))
    assert east.sum() == 1 and fp.visible[east][0]


def test_flux_weights_are_zero_for_cells_facing_away():
    """flux_weights = area max(cos emission, 0) solid_angle: cells whose surface faces
    away from the spacecraft (emission > 90) weigh nothing (mutant: |cos|, caught
    before only by the bulk fuzz)."""
    R = 3390.0
    radii = np.full((720, 1440), R)
    lon = (np.arange(1440) + 0.5) / 4
    ramp = (lon > 10) & (lon < 12)
    radii[:, ramp] += 40.0 * np.clip(12 - lon[ramp], 0, 1)     # an east-facing scarp between 11 and 12 E
    cells = pi.CellTable(pi.DEM.from_array(radii), 0.5)
    fp = pi.footprint(cells, _xyz(0.25, 0.25, R + 400.0), [0, 0, 1.0])      # 11 deg west of the scarp
    w = flux_weights(fp)
    back = fp.emission > 90.0
    assert back.sum() > 50 and np.all(w[back] == 0.0)
    front = fp.emission < 89.0
    assert np.all(w[front] > 0.0)


# ---------------------------------------------------------------- simulate.py


def _flat_scene():
    dsm = pi.GeodeticDSM.from_array(np.zeros((20, 20)), 36.6, -84.3, -1e-4, 1e-4)
    ortho = pi.OrthoImage.from_array(np.ones((20, 20)), 36.6, -84.3, -1e-4, 1e-4)
    cam = pi.FrameCamera.nadir(36.599, -84.299, 1000.0, (5, 5), 0.01)
    return dsm, ortho, cam


@pytest.mark.parametrize("kw, name", [(dict(ambient=1.5), "ambient"), (dict(ambient=-0.1), "ambient"),
                                      (dict(sun=(0.0, 120.0)), "sun"), (dict(sun=(0.0, -90.5)), "sun")])
def test_lambert_options_out_of_range_are_refused(kw, name):
    """With shading="lambert" (where sun and ambient are used), ambient outside [0, 1]
    and a sun elevation outside [-90, 90] are refused (the existing test passed ambient
    without lambert and was caught by another check; mutants: the range checks
    dropped)."""
    dsm, ortho, cam = _flat_scene()
    kw = dict(sun=(0.0, 30.0), **kw) if "sun" not in kw else kw
    with pytest.raises(ValueError, match=name):
        pi.simulate_image(dsm, ortho, cam, shading="lambert", occlusion=False, **kw)


def test_ortho_centres_follow_the_grid_sign():
    """OrthoImage.centres(): row i at lat_first + i dlat, column j at lon_first + j dlon,
    north-up (dlat < 0) and south-up alike (mutant: |dlat|)."""
    o = pi.OrthoImage.from_array(np.zeros((3, 3)), 10.0, 20.0, -0.5, 0.25)
    lat, lon = o.centres()
    np.testing.assert_array_equal(np.unique(lat)[::-1], [10.0, 9.5, 9.0])
    np.testing.assert_array_equal(np.unique(lon), [20.0, 20.25, 20.5])
    lat, _ = pi.OrthoImage.from_array(np.zeros((3, 3)), 9.0, 20.0, 0.5, 0.25).centres()
    np.testing.assert_array_equal(np.unique(lat), [9.0, 9.5, 10.0])


def test_ground_just_behind_a_ridge_is_occluded():
    """The occlusion mask's margin is 1 cm: an ortho pixel 0.25 m west of a ridge's
    crest (10 m high, slopes 5 m/m, bilinear, 1 m cells), seen at 45 deg from the east,
    is hidden by 0.59 m of the ridge along the line (its 45-deg line leaves the ridge
    where 8.75 + x = 11.25 - 5x, x = 0.417 m east of it); the pixels 0.5 and 0.75 m
    west by 1.18 and 1.77 m (mutant: the margin 1 m, and the first became visible)."""
    lat0, lon0 = 36.6, -84.3
    dlat, dlon = metre_steps(lat0)
    n, j0 = 40, 20
    h = np.tile(10.0 - 5.0 * np.abs(np.arange(n) - j0), (n, 1)).clip(0)
    lat_first = lat0 + (n - 1) * dlat
    dsm = pi.GeodeticDSM.from_array(h, lat_first, lon0, -dlat, dlon, interpolation="bilinear")
    m = 4 * (n - 1) + 1
    ortho = pi.OrthoImage.from_array(np.ones((m, m)), lat_first, lon0, -dlat / 4, dlon / 4)    # 0.25 m pixels
    lat_c, lon_c = lat0 + 20 * dlat, lon0 + j0 * dlon
    cam = pi.FrameCamera.pinhole((lat_c, lon_c + 1000 * dlon, 1010.0), (lat_c, lon_c, 10.0), (61, 61), 0.01,
                                 geodetic=True)
    sim = pi.simulate_image(dsm, ortho, cam, occlusion=True)
    row = 4 * 20
    for k in (1, 2, 3):
        assert sim.footprint[row, 4 * j0 - k] and sim.occlusion[row, 4 * j0 - k], k
    # the crest itself and the east slope facing the camera are seen (the image ends ~2 m east)
    for k in (0, -2, -6):
        assert sim.footprint[row, 4 * j0 - k] and not sim.occlusion[row, 4 * j0 - k], k


# ================================================================ the compiled cores
# Found by mutation testing of fortran/pi_follow.f90, pi_footprint.f90 and pi_simulate.f90
# (stop 31: 55 mutants; 7 survived the whole suite, 4 more were caught only by the fuzz or
# another system's tests). The geodesy here is the test's own (fixed-point latitude).


def _geodetic(p):
    """(lat deg, lon deg, h) of an ECR point on WGS-84: the fixed-point iteration on the
    latitude (contraction ~e2 per pass), the test's own code."""
    e2 = WGS84_F * (2 - WGS84_F)
    rho = math.hypot(p[0], p[1])
    phi = math.atan2(p[2], rho * (1 - e2))
    h = 0.0
    for _ in range(30):
        n_rad = WGS84_A / math.sqrt(1 - e2 * math.sin(phi) ** 2)
        h = rho / math.cos(phi) - n_rad
        phi = math.atan2(p[2], rho * (1 - e2 * n_rad / (n_rad + h)))
    return math.degrees(phi), math.degrees(math.atan2(p[1], p[0])), h


def _root(f, t0, t1):
    """The sign change of f in [t0, t1] by bisection to rounding."""
    f0 = f(t0)
    assert f0 * f(t1) < 0
    for _ in range(200):
        tm = 0.5 * (t0 + t1)
        if tm in (t0, t1):
            break
        if f(tm) * f0 > 0:
            t0 = tm
        else:
            t1 = tm
    return 0.5 * (t0 + t1)


def _enu(lat, lon):
    la, lo = np.radians(lat), np.radians(lon)
    up = np.array([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)])
    east = np.array([-np.sin(lo), np.cos(lo), 0.0])
    return east, np.cross(up, east), up


def _ray_to(lat, lon, h, off_rad, azimuth_deg, dist=600e3):
    """A ray that reaches the geodetic point (lat, lon, h) after dist, off_rad from its
    normal toward azimuth_deg (clockwise from north)."""
    east, north, up = _enu(lat, lon)
    z = math.radians(azimuth_deg)
    d = -math.cos(off_rad) * up + math.sin(off_rad) * (math.sin(z) * east + math.cos(z) * north)
    return pi.geodetic_to_ecef(lat, lon, h) - dist * d, d


def _block_dsm(interpolation="nearest"):
    h = np.zeros((200, 200))
    h[:, 100:140] = 50.0              # a 50 m block between lon 10.000995 and 10.001395 (1e-5 deg cells)
    return pi.GeodeticDSM.from_array(h, 45.0, 10.0, 1e-5, 1e-5, interpolation=interpolation)


@pytest.mark.parametrize("method", ["following", "exact"])
def test_near_nadir_ray_past_a_roof_edge_hits_the_roof(method):
    """A ray 5e-7 rad off the vertical, travelling west, whose h = 0 point is 1e-5 m west
    of the block's west wall: at h = 50 it is 1.5e-5 m east of the wall, over the roof,
    so its first hit is the roof (the paper's nadir shortcut takes only rays within
    1e-12 of the vertical; mutant: 1e-6, and the ray went to the ground beside the
    block at 600 km)."""
    dsm = _block_dsm()
    lat = 45.001
    wall = 10.0 + 99.5e-5
    e2 = WGS84_F * (2 - WGS84_F)
    m_per_deg_lon = math.pi / 180 * WGS84_A / math.sqrt(1 - e2 * math.sin(math.radians(lat)) ** 2) \
        * math.cos(math.radians(lat))
    s, d = _ray_to(lat, wall - 1e-5 / m_per_deg_lon, 0.0, 5e-7, 270.0)
    res = pi.intersect(dsm, s, d, method=method)
    t50 = _root(lambda t: _geodetic(s + t * d)[2] - 50.0, 599_000.0, 600_000.0)
    assert res.status[0] == pi.DSMStatus.HIT
    assert res.height[0] == pytest.approx(50.0, abs=1e-5)
    assert res.distance[0] == pytest.approx(t50, abs=1e-5)
    assert res.lon[0] > wall                                        # over the roof


@pytest.mark.parametrize("method", ["following", "exact", "iterative"])
def test_focal_point_below_the_ellipsoid_over_negative_heights(method):
    """A drone 100 m below the ellipsoid, 300 m above a flat DSM at -400 m (the Dead Sea's
    shore lies ~430 m below sea level), looking 30 deg off nadir: a hit at h = -400 at
    the level crossing (mutant: the ellipsoid entry of a point inside the ellipsoid
    taken at its far root, and the following answered MISS)."""
    dsm = pi.GeodeticDSM.from_array(np.full((200, 200), -400.0), 31.4, 35.4, 1e-3, 1e-3,
                                    interpolation="bilinear")
    east, _, up = _enu(31.5, 35.5)
    s = pi.geodetic_to_ecef(31.5, 35.5, -100.0)
    d = -math.cos(math.radians(30)) * up + math.sin(math.radians(30)) * east
    res = pi.intersect(dsm, s, d, method=method)
    t = _root(lambda t: _geodetic(s + t * d)[2] + 400.0, 0.0, 1000.0)
    assert res.status[0] == pi.DSMStatus.HIT
    assert res.height[0] == pytest.approx(-400.0, abs=1e-5)
    assert res.distance[0] == pytest.approx(t, abs=1e-5)
    assert t == pytest.approx(300 / math.cos(math.radians(30)), abs=0.05)          # flat-earth check


def test_iterative_hit_on_a_slope_is_within_its_tolerance():
    """The iterative method's hits satisfy |h - H| <= 1e-6 m (its documented tolerance)
    and lie at the crossing of the ray with the surface: a bilinear ramp rising east at
    ~0.5, a ray 30 deg off nadir travelling east into it (the tests had flat ground and
    blocks only, where one iteration converges; mutant: tolerance 1e-3, 0.5 mm short)."""
    slope_per_col = 0.5 * 0.787
    dsm = pi.GeodeticDSM.from_array(np.tile(slope_per_col * np.arange(200), (200, 1)), 45.0, 10.0, 1e-5, 1e-5,
                                    interpolation="bilinear")
    s, d = _ray_to(45.001, 10.001, 0.0, math.radians(30.0), 90.0)

    def above(t):
        lat, lon, h = _geodetic(s + t * d)
        return h - slope_per_col * (lon - 10.0) / 1e-5            # H is linear in longitude on this grid

    t = _root(above, 599_000.0, 600_100.0)
    for method in ("iterative", "exact", "following"):
        res = pi.intersect(dsm, s, d, method=method)
        assert res.status[0] == pi.DSMStatus.HIT, method
        assert abs(res.height[0] - res.surface_height[0]) <= 1e-6, method
        assert res.distance[0] == pytest.approx(t, abs=1e-5), method


@pytest.mark.parametrize("method", ["following", "exact"])
def test_ray_entering_the_grids_side_below_its_top_hits_the_edge(method):
    """The surface ends at the grid's edge ("nearest": half a cell beyond the first
    centre): a ray that enters through the west side at h = 20 m, where the edge column
    is 50 m tall, hits the side at the edge (mutant: the no-data gap's margin dropped,
    and the following reported a hit outside the grid at h = 50 with no surface height)."""
    h = np.zeros((200, 200))
    h[:, :5] = 50.0
    dsm = pi.GeodeticDSM.from_array(h, 45.0, 10.0, 1e-5, 1e-5, interpolation="nearest")
    edge = 10.0 - 0.5e-5
    s, d = _ray_to(45.001, edge, 20.0, math.radians(60.0), 90.0)
    res = pi.intersect(dsm, s, d, method=method)
    assert res.status[0] == pi.DSMStatus.HIT
    assert res.lon[0] == pytest.approx(edge, abs=1e-9)
    assert res.height[0] == pytest.approx(20.0, abs=1e-5) and res.surface_height[0] == 50.0
    assert res.distance[0] == pytest.approx(600e3, abs=1e-4)


@pytest.mark.parametrize("method", ["following", "exact"])
def test_vertical_ray_beside_the_dsm_leaves_at_its_top(method):
    """A ray straight down beside the DSM never meets it: LEFT_DSM, its event where it
    reaches H_max = 50 m, 700 km - 50 m down (mutant: the event put on the ellipsoid)."""
    dsm = _block_dsm()
    s = pi.geodetic_to_ecef(45.001, 9.99, 7e5)
    res = pi.intersect(dsm, s, -_enu(45.001, 9.99)[2], method=method)
    assert res.status[0] == pi.DSMStatus.LEFT_DSM
    assert res.event_height[0] == pytest.approx(50.0, abs=1e-6)
    assert res.event_distance[0] == pytest.approx(7e5 - 50.0, abs=1e-6)


def test_iterative_oscillation_stops_at_the_first_repeated_level():
    """On the block's wall the iteration visits the levels 0, 50, 0: it stops when a
    level first repeats, with p at the last level before the repeat, the h = 50 crossing
    (docs/status-codes.md; mutant: the first level left out of the comparison, and the
    cycle was found one round later, at h = 0 after 10 steps instead of 7)."""
    dsm = _block_dsm()
    s, d = _ray_to(45.001, 10.0 + 109e-5, 0.0, math.radians(30.0), 90.0)
    res = pi.intersect(dsm, s, d, method="iterative")
    t50 = _root(lambda t: _geodetic(s + t * d)[2] - 50.0, 599_000.0, 600_000.0)
    assert res.status[0] == pi.DSMStatus.OSCILLATION
    assert res.height[0] == pytest.approx(50.0, abs=1e-5)
    assert res.distance[0] == pytest.approx(t50, abs=1e-4)


def _unit(lat, lon):
    la, lo = np.radians(lat), np.radians(lon)
    return np.array([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)])


@pytest.mark.parametrize("side", [+1, -1])
def test_narrow_cone_edge_on_a_cell_centre(side):
    """The footprint is every cell with cos psi >= zeta: with the cone's edge 1e-12 (in
    cos psi) beyond or short of a cell centre at psi = 1e-4 rad, that cell is in or out
    (the exhaustive-search test used zeta <= 0.999, where the search's slack hides under
    its margin; mutant: the slack's sign flipped, and the cell outside came in)."""
    R0 = 3390.0
    cells = pi.CellTable(pi.DEM.from_array(np.full((360, 720), R0)), 0.5)
    uc = _unit(0.25, 0.25)                                       # the centre of cell (row 180, column 0)
    R = (R0 + 400.0) * _unit(0.25, 0.25 + np.degrees(1.2e-5) / np.cos(np.radians(0.25)))
    d = R - R0 * uc
    cos_psi = d @ R / (np.linalg.norm(d) * np.linalg.norm(R))
    fp = pi.footprint(cells, R, zeta=cos_psi - side * 1e-12)
    k = int(cells.index(0.25, 0.25))
    assert list(fp.cell) == ([k] if side > 0 else [])


@pytest.mark.parametrize("beyond", [5e-8, -5e-8])
def test_horizon_edge_on_a_cell_centre(beyond):
    """zeta = 0: the footprint is every cell the spacecraft is above the horizon of
    (d . u > 0). A spacecraft 1.7 m over a 3,390 km sphere (horizon 1e-3 rad) with a
    cell centre 5e-8 rad beyond or inside its horizon (mutant: the horizon slack's sign
    flipped, and the cell beyond came in)."""
    R0 = 3390.0
    cells = pi.CellTable(pi.DEM.from_array(np.full((360, 720), R0)), 0.5)
    uc = _unit(0.25, 0.25)
    gh = 1e-3
    g0 = gh + beyond
    dl = 2 * np.arcsin(np.sin(g0 / 2) / np.cos(np.radians(0.25)))
    R = R0 / np.cos(gh) * _unit(0.25, 0.25 + np.degrees(dl))
    assert np.sign((R - R0 * uc) @ uc) == -np.sign(beyond)       # the construction's own check
    fp = pi.footprint(cells, R, zeta=0.0)
    k = int(cells.index(0.25, 0.25))
    assert (k in set(fp.cell)) == (beyond < 0)


def test_a_last_spectrum_with_an_empty_footprint():
    """Two spectra, the second over a cell corner with a 0.01-deg cone that holds no
    cell centre: the result has one pair, of the first spectrum, and counts [1, 0]
    (mutant: the pair-offset check '>' made '>=', and the call raised)."""
    R0 = 3390.0
    cells = pi.CellTable(pi.DEM.from_array(np.full((360, 720), R0)), 0.5)
    R = np.array([(R0 + 400) * _unit(0.25, 0.25), (R0 + 400) * _unit(10.5, 20.5)])
    fp = pi.footprint(cells, R, zeta=np.cos(np.radians(0.01)))
    assert list(fp.spectrum) == [0] and list(fp.cell) == [int(cells.index(0.25, 0.25))]
    assert list(fp.counts()) == [1, 0] and fp.n_spectra == 2


def test_wall_texture_with_an_unknown_roof_edge_is_the_mean():
    """walls="interpolate" mixes the ortho values at the wall's foot and at its roof edge
    by the hit's height; where the roof edge's height is no-data, the mix is the mean of
    the two values (docs/simulation-notes.md note 2; mutant: the fallback t = 0, the
    ground's value). Roof 200, ground 50: every wall pixel is 125."""
    from planet_intersect.synthetic_dsm import oblique_pushbroom

    lat0, lon0, n = 36.6, -84.3, 120
    dlat, dlon = metre_steps(lat0)
    h = np.zeros((n, n))
    h[50:70, 40:80] = 20.0
    h[50:58, 78] = np.nan                 # no data on the roof, two cells inside the east wall, rows 50-57
    lat_first = lat0 + (n - 1) * dlat
    dsm = pi.GeodeticDSM.from_array(h, lat_first, lon0, -dlat, dlon, interpolation="bilinear")
    vals = np.where(np.isfinite(h) & (h > 0), 200.0, 50.0)
    vals[50:58, 78] = 200.0
    ortho = pi.OrthoImage.from_array(vals, lat_first, lon0, -dlat, dlon)
    scene = dict(heights=np.nan_to_num(h), ground=np.zeros_like(h), lat_first=lat_first, lon_first=lon0,
                 dlat=-dlat, dlon=dlon)
    sensor = pi.Pushbroom(*oblique_pushbroom(scene, zenith=9.0, azimuth=90.0, margin=10))
    sim = pi.simulate_image(dsm, ortho, sensor, occlusion=False, ground=np.zeros_like(h))
    row = 44                                           # image line 44 sees scene row 54
    wall = np.flatnonzero((sim.surface[row] == 2) & (sim.height[row] > 1.0))   # above the wall's foot
    assert len(wall) == 4
    np.testing.assert_allclose(sim.lat[row, wall], lat_first - 54 * dlat, atol=0.1 * dlat)
    np.testing.assert_array_equal(sim.image[row, wall], 125.0)
    # the same wall where its roof edge is known (scene row 65): the ramp (1 - t) 50 + t 200, t = h / 20
    known = np.flatnonzero((sim.surface[55] == 2) & (sim.height[55] > 1.0))
    assert len(known) == 4
    np.testing.assert_allclose(sim.image[55, known], 50.0 + 150.0 * sim.height[55, known] / 20.0, atol=2e-4)


# ================================================================ planetary DEM and the command line
# From a second mutation review of the Python code (dem.py, geometry.py, cli.py, mola.py,
# sim_run.py: 49 mutants, 14 gaps). Limits are those the docs state.


def test_header_size_limit_is_999999_bytes(tmp_path):
    """docs/dem-format.md: a header has at most 999,999 bytes (mutant: '>=' made '>')."""
    from planet_intersect.dem import read_header

    body = b"1\n3400\n0\n3400\n"
    for size, ok in ((999_999, True), (1_000_000, False)):
        hdr = tmp_path / f"h{size}.hdr"
        hdr.write_bytes(body + b"#" * (size - len(body) - 1) + b"\n")
        assert hdr.stat().st_size == size
        if ok:
            assert read_header(hdr)["ppd"] == 1
        else:
            with pytest.raises(pi.DEMError, match="999999"):
                read_header(hdr)


def test_ppd_limit_is_inclusive(tmp_path):
    """ppd must be in 1..1000000: the upper end is accepted (mutant: '<=' made '<')."""
    from planet_intersect.dem import read_header

    (tmp_path / "a.hdr").write_text("1000000\n3400\n0\n3400\n")
    assert read_header(tmp_path / "a.hdr")["ppd"] == 1_000_000
    (tmp_path / "b.hdr").write_text("1000001\n3400\n0\n3400\n")
    with pytest.raises(pi.DEMError, match="ppd"):
        read_header(tmp_path / "b.hdr")


def test_rmax_at_most_twice_the_largest_radius():
    """rmax may exceed the largest radius by a factor 2 at most (mutant: 4)."""
    r = np.full((180, 360), 100.0)
    assert pi.DEM.from_array(r, rmax=200.0).rmax == 200.0
    with pytest.raises(pi.DEMError, match="rmax"):
        pi.DEM.from_array(r, rmax=201.0)


def test_radii_within_a_factor_1e6():
    """Radii must lie within a factor 1e6 of each other (mutant: 1e8)."""
    r = np.full((180, 360), 1.0)
    r[10, 10] = 1.0000001e-6
    pi.DEM.from_array(r)
    r[10, 10] = 1e-7
    with pytest.raises(pi.DEMError, match="factor"):
        pi.DEM.from_array(r)


def test_write_never_replaces_a_lone_dem_file(tmp_path):
    """DEM.write replaces no existing file: a NAME.dem without its NAME.hdr is kept, byte
    for byte (mutant: only the .hdr checked, and 13 bytes of someone's data became a
    259,200-byte grid)."""
    (tmp_path / "x.dem").write_bytes(b"precious data")
    dem = pi.DEM.from_array(np.full((180, 360), 100.0, dtype=np.float32))
    with pytest.raises(FileExistsError, match="x.dem"):
        dem.write(tmp_path / "x")
    assert (tmp_path / "x.dem").read_bytes() == b"precious data"
    assert not (tmp_path / "x.hdr").exists()


def test_dem_file_rewritten_in_place_is_refused(tmp_path):
    """check_file refuses a .dem rewritten since DEM.read at the same size (mutant: size
    compared only, and NaN radii that were never checked were used)."""
    import os

    pi.DEM.from_array(np.full((180, 360), 100.0, dtype=np.float32)).write(tmp_path / "x")
    dem = pi.DEM.read(tmp_path / "x")
    st = (tmp_path / "x.dem").stat()
    with open(tmp_path / "x.dem", "r+b") as fh:
        fh.write(np.full(3600, np.nan, dtype="<f4").tobytes())
    os.utime(tmp_path / "x.dem", ns=(st.st_atime_ns, st.st_mtime_ns + 10_000_000))
    with pytest.raises(pi.DEMError, match="rewritten|changed"):
        dem.check_file()
    with pytest.raises(pi.DEMError):
        dem.radius(-89.9, 0.0)


@pytest.mark.parametrize("dh, dv", [(0.0, 0.01), (0.01, 0.0)])
def test_detector_pixel_spacing_zero_is_refused(dh, dv):
    """detector_los: spacings in (0, pi] (mutant: 0 accepted, 9 pixels in 3 directions)."""
    from planet_intersect.geometry import detector_los

    with pytest.raises(ValueError, match="dh|dv"):
        detector_los([0, 0, -1], [0, 1, 0], 3, 3, dh, dv)


def test_detector_field_beyond_90_degrees_is_refused():
    """detector_los: eq. 18's sin() folds pixels back past pi/2 from l0, so a half field
    0.5 (n - 1) d above pi/2 is refused and one below accepted (mutant: pi)."""
    from planet_intersect.geometry import detector_los

    d = math.pi / 100
    los = detector_los([0, 0, -1], [0, 1, 0], 101, 1, d * 0.999, 0.01)        # half field 0.999 pi/2
    ang = np.degrees(np.arccos(np.clip(los @ np.array([0, 0, -1.0]), -1, 1)))
    assert np.all(np.diff(ang[:51]) < 0) and np.all(np.diff(ang[50:]) > 0)     # no pixel folds back
    with pytest.raises(ValueError, match="dh|field|pi"):
        detector_los([0, 0, -1], [0, 1, 0], 101, 1, d * 1.001, 0.01)


def test_exact_mode_by_the_south_pole_sees_the_pole_mean():
    """The pole node carries the mean of its neighbouring row (section 2.2): row 0 half at
    110 and half at 90 makes a 100 pole, and a slanted ray near it enters at the same
    point in the exact mode as in the stepping (mutant: the pyramid's pole value taken
    from row 1, the exact hit 5 degrees later; only the 4-minute exhaustive test saw it)."""
    r = np.full((180, 360), 90.0)
    r[0, :180] = 110.0
    dem = pi.DEM.from_array(r)
    assert float(dem.radius(-90.0, 0.0)) == pytest.approx(100.0, abs=1e-12)
    s = 200 * _unit(-89.8, 270.0) + 150 * np.array([-math.sin(math.radians(270)), math.cos(math.radians(270)), 0])
    l = -s + 95 * _unit(-89.8, 270.0)
    step = pi.intersect(dem, s, l, method="stepping")
    exact = pi.intersect(dem, s, l, method="exact")
    assert step.hit[0] and exact.hit[0]
    assert step.lat[0] < -89.5                         # in the polar cap, above the 90 floor
    np.testing.assert_allclose(exact.p[0], step.p[0], atol=1e-6)


def test_cli_failed_examples_leave_no_run_folder(tmp_path, capsys, monkeypatch):
    """A subcommand that fails after its run folder is made removes it (cli._run_dir;
    mutant: left behind), and says why in one line: example 1 on a unit-radius DEM sees
    no surface (np.polyfit's 'expected non-empty vector for x' before)."""
    from planet_intersect.cli import main

    pytest.importorskip("matplotlib")
    pi.DEM.from_array(np.full((180, 360), 1.0, dtype=np.float32), f=0.1, re=1.0).write(tmp_path / "unit")
    monkeypatch.chdir(tmp_path)
    assert main(["examples", "olympus", "--dem", "unit.hdr", "--out", "ex"]) == 2
    err = capsys.readouterr().err
    assert "pixels hit the DEM" in err and err.count("\n") == 1
    assert not list((tmp_path / "ex").glob("run-*"))


def test_cli_run_names_the_line_past_the_first_chunk(tmp_path, capsys, monkeypatch):
    """run reads rays in chunks of 200,000: an error about ray 200,001 names line 200001
    (mutant: line 1), on its own line after the part-way progress bar."""
    from planet_intersect.cli import main

    pi.DEM.from_array(np.full((180, 360), 100.0, dtype=np.float32)).write(tmp_path / "d")
    with open(tmp_path / "rays.txt", "w") as fh:
        fh.write("0 0 300 0 0 -1\n" * 200_000)
        fh.write("0 0 50 0 0 -1\n")                    # the spacecraft inside the planet
    monkeypatch.chdir(tmp_path)
    assert main(["run", "d.hdr", "rays.txt", "--out", "o"]) == 2
    err = capsys.readouterr().err
    last = err.replace("\r", "\n").strip().splitlines()[-1]
    assert last.startswith("planet-intersect: error: s on line 200001 of rays.txt"), err[-300:]
    assert "100.0%" not in err
    assert not list((tmp_path / "o").glob("run-*"))


def _cli_scene(tmp_path, n):
    from planet_intersect.synthetic_dsm import metre_steps

    lat0, lon0 = 36.6, -84.2
    dlat, dlon = metre_steps(lat0)
    lat_first = lat0 + (n - 1) * dlat
    grid = dict(heights=np.full((n, n), 80.0), lat_first=lat_first, lon_first=lon0, dlat=-dlat, dlon=dlon)
    np.savez(tmp_path / "dsm.npz", interpolation="nearest", **grid)
    np.savez(tmp_path / "ortho.npz", values=np.ones((n, n)), lat_first=lat_first, lon_first=lon0, dlat=-dlat,
             dlon=dlon)
    return grid, (lat0 + 0.5 * (n - 1) * dlat, lon0 + 0.5 * (n - 1) * dlon)


def test_cli_orbit_pixels_are_square(tmp_path):
    """simulate --orbit without --line-period: square pixels, the nadir GSD over the
    ground speed (--help). The ground step between lines equals the step between pixels
    to 3 % (mutant: the period computed for r = a, ratio 0.87)."""
    xr = pytest.importorskip("xarray")
    pytest.importorskip("h5netcdf")
    from planet_intersect.cli import main

    _, c = _cli_scene(tmp_path, 200)
    assert main(["simulate", "--dsm", str(tmp_path / "dsm.npz"), "--ortho", str(tmp_path / "ortho.npz"), "--orbit",
                 "--target", f"{c[0]},{c[1]}", "--lines", "5", "--pixels", "5", "--ifov", "8.4e-5",
                 "--no-occlusion", "--quiet", "--out", str(tmp_path / "o")]) == 0
    ds = xr.open_dataset(next((tmp_path / "o").glob("run-*/simulated.nc")), engine="h5netcdf")
    lat, lon = ds["lat"].values, ds["lon"].values
    m_lat = math.radians(1) * 6371e3
    m_lon = m_lat * math.cos(math.radians(c[0]))

    def step(i0, j0, i1, j1):
        return math.hypot((lat[i1, j1] - lat[i0, j0]) * m_lat, (lon[i1, j1] - lon[i0, j0]) * m_lon)

    along, across = step(2, 2, 3, 2), step(2, 2, 2, 3)
    assert across == pytest.approx(1.0, rel=0.05)      # 8.4e-5 deg at ~680 km: ~1 m
    assert along / across == pytest.approx(1.0, abs=0.03)


def test_cli_altitude_beside_geometry_is_refused(tmp_path, capsys):
    """--geometry takes the whole sensor from its file: --altitude beside it is refused,
    not ignored (mutant: dropped from the conflicts, exit 0 and a run folder)."""
    from planet_intersect.cli import main
    from planet_intersect.synthetic_dsm import oblique_pushbroom

    grid, _ = _cli_scene(tmp_path, 24)
    s, l = oblique_pushbroom(grid, zenith=9.0, azimuth=90.0)[:2]
    np.savez(tmp_path / "push.npz", s=s, l=l)
    assert main(["simulate", "--dsm", str(tmp_path / "dsm.npz"), "--ortho", str(tmp_path / "ortho.npz"),
                 "--geometry", str(tmp_path / "push.npz"), "--altitude", "500000", "--no-occlusion", "--quiet",
                 "--out", str(tmp_path / "o")]) == 2
    assert "--altitude" in capsys.readouterr().err
    assert not list((tmp_path / "o").glob("run-*"))


def test_fetch_mola_refuses_an_existing_img_of_another_size(tmp_path):
    """fetch_mola: an existing PRODUCT.img must have exactly the product's size (180 x 360
    ppd^2 x 2 bytes); a 5-ppd grid under the 4-ppd name is refused, never imported
    (mutant: only a smaller file refused)."""
    from planet_intersect.mola import fetch_mola

    for ppd in (5, 3):
        np.zeros((180 * ppd, 360 * ppd), dtype=">i2").tofile(tmp_path / "megr90n000cb.img")
        with pytest.raises(FileExistsError, match="megr90n000cb"):
            fetch_mola(tmp_path, product="megr90n000cb", base_url="file:///nonexistent")
        assert not list(tmp_path.glob("*.hdr"))


def test_fig4_counts_add_up():
    """The Fig. 4 counts: every iterative pixel without a hit is 'not converged'
    (OSCILLATION, NOT_CONVERGED, STEP_LIMIT: white in the paper) or 'left the DSM', and
    the two add up to the pixels without a hit (mutants: OSCILLATION not counted; the
    not-converged counted twice)."""
    import tempfile
    from pathlib import Path

    from planet_intersect.dsm import DSMStatus
    from planet_intersect.sim_run import fig4, paper_experiment

    pytest.importorskip("matplotlib")
    exp = paper_experiment(size=96, methods=("exact", "iterative"), threads=1)
    it = exp["sims"]["iterative"]
    st = np.asarray(it.status)
    stuck = np.isin(st, [DSMStatus.OSCILLATION, DSMStatus.NOT_CONVERGED, DSMStatus.STEP_LIMIT])
    with tempfile.TemporaryDirectory() as d:
        c = fig4(exp, Path(d) / "fig4.png")
    assert stuck.sum() > 0
    assert c["iterative_not_converged"] == int(stuck.sum())
    assert c["iterative_not_converged"] + c["iterative_left_dsm"] == int((~np.asarray(it.valid)).sum())


# ================================================================ the exact modes' soundness margins
# From a mutation review of fortran/pi_dsm_fast.f90, pi_dsm_exact.f90, pi_dsm.f90, pi_exact.f90
# (45 mutants): two margins whose removal gave wrong answers that no test saw. The truth is a
# brute-force search along the ray (fine samples, bisection) with the package's conversion and
# lookup, which the exhaustive reference of tests/references/ checks independently.


def _first_below(dsm, s, l, r0, r1, eps, step=1e-4):
    """First r in [r0, r1] with h(r) <= H(lat, lon) + eps: samples every `step`, then bisection."""
    rs = np.arange(r0, r1, step)
    lat, lon, hh = pi.ecef_to_geodetic(s[None, :] + rs[:, None] * l[None, :])
    low = np.flatnonzero(hh <= dsm.height(lat, lon) + eps)
    assert low.size and low[0] > 0
    a, b = rs[low[0] - 1], rs[low[0]]
    for _ in range(60):
        m = 0.5 * (a + b)
        la, lo, hm = pi.ecef_to_geodetic(s + m * l)
        if hm <= float(dsm.height(la, lo)) + eps:
            b = m
        else:
            a = m
    return b


@pytest.mark.parametrize("interpolation", ["nearest", "bilinear"])
def test_rays_dipping_nanometres_below_a_roof_are_not_late(interpolation):
    """Horizontal rays whose lowest point is 1.5-6e-8 m below a flat 20 m roof: below the
    roof over a chord of ~1-2 m around that point. The hit lies between the first point
    with h <= H + 1e-8 m and the first with h <= H - 1e-8 m (the +-1e-8 m band covers
    the conversions' rounding, ~1.5e-15 a; near a tangency 1e-9 m of height moves r by
    ~1 cm), to 1e-6 m (mutant: the fast path's lower height bound raised by its rounding
    margin instead of lowered, 14 of 40 rays up to 0.53 m late).

    On "bilinear" the exact mode gave up on these rays before this stop (STEP_LIMIT after
    ~101,000 segments, ~45 ms a ray, for dips up to 3e-7 m: found by this test); a box whose
    nodes all have one height is now a flat top, as in "nearest" (shin-park-notes,
    "Thirteenth look"), and every ray hits in ~45 segments."""
    lat0, lon0 = 36.6, -84.3
    dlat, dlon = metre_steps(lat0, 1.0)
    n, roof = 200, 20.0
    h = np.zeros((n, n))
    h[80:121, 40:161] = roof
    h[5, 5] = 50.0                                   # a tower off the path: H_max above the roof
    dsm = pi.GeodeticDSM.from_array(h, lat0, lon0, dlat, dlon, interpolation=interpolation)
    rng = np.random.default_rng(1)
    for k in range(40):
        delta = rng.uniform(1.5e-8, 6e-8)
        plat, plon = lat0 + rng.uniform(95, 105) * dlat, lon0 + rng.uniform(90, 110) * dlon
        az = rng.uniform(-0.3, 0.3)
        p = pi.geodetic_to_ecef(plat, plon, roof - delta)
        east, north, _ = _enu(plat, plon)
        l = math.cos(az) * east + math.sin(az) * north            # horizontal at its lowest point
        d = rng.uniform(30.0, 45.0)
        s = p - d * l
        res = pi.intersect(dsm, s, l, method="exact")
        assert res.nsteps[0] < 200, (k, int(res.status[0]), int(res.nsteps[0]))
        early = _first_below(dsm, s, l, d - 3.0, d + 3.0, +1e-8)
        surely = _first_below(dsm, s, l, d - 3.0, d + 3.0, -1e-8)
        assert res.hit[0], k
        assert early - 1e-6 <= res.distance[0] <= surely + 1e-6, (k, delta, res.distance[0], early, surely)


def test_rays_onto_the_grids_edge_are_never_a_miss():
    """Rays from 600 km aimed at ground points within +-3e-8 cells of a "nearest" grid's
    east edge (flat 0 m, one 30 m tower far away): a ray that goes below H_min cannot be
    MISS. It is HIT where its ground point is inside the area (half a cell past the edge
    nodes plus the documented edge slack eu = 8 ulp(pi)/dlon cells) by more than 5e-9
    cells, LEFT_DSM where it is outside by as much, either in between (mutant: the
    exact_ray fallback's segment widening without the slack: MISS on 9 of 3,000 rays
    alone, 23 through pi.intersect)."""
    from test_dsm_fast import REFERENCE, trace

    lat0, lon0 = 36.6, -84.3
    dlat, dlon = metre_steps(lat0, 1.0)
    n = 64
    h = np.zeros((n, n))
    h[2, 2] = 30.0
    dsm = pi.GeodeticDSM.from_array(h, lat0, lon0, dlat, dlon, interpolation="nearest")
    rng = np.random.default_rng(3)
    N = 3000
    i = rng.uniform(10, n - 10, N)
    du = rng.uniform(-3e-8, 3e-8, N)
    tlat, tlon = lat0 + i * dlat, lon0 + ((n - 1) + 0.5 + du) * dlon
    T = pi.geodetic_to_ecef(tlat, tlon, np.zeros(N))
    zen, az = np.radians(rng.uniform(0, 30, N)), rng.uniform(0, 2 * np.pi, N)
    lr, lo = np.radians(tlat), np.radians(tlon)
    up = np.stack([np.cos(lr) * np.cos(lo), np.cos(lr) * np.sin(lo), np.sin(lr)], 1)
    east = np.stack([-np.sin(lo), np.cos(lo), 0 * lo], 1)
    north = np.cross(up, east)
    v = np.cos(zen)[:, None] * up + np.sin(zen)[:, None] * (np.cos(az)[:, None] * east
                                                             + np.sin(az)[:, None] * north)
    s, l = T + 600e3 * v, -v
    eu = 8 * np.spacing(np.pi) / np.radians(dlon)
    inside, ambiguous = du < eu - 5e-9, np.abs(du - eu) <= 5e-9
    want = np.where(inside, int(pi.DSMStatus.HIT), int(pi.DSMStatus.LEFT_DSM))
    alone = trace(dsm, s, l, REFERENCE)[0]              # the exact_ray fallback on its own
    public = np.asarray(pi.intersect(dsm, s, l, method="exact").status)
    for name, st in (("exact_ray", alone), ("pi.intersect", public)):
        assert not np.any(st == pi.DSMStatus.MISS), name
        ok = (st == want) | (ambiguous & np.isin(st, [pi.DSMStatus.HIT, pi.DSMStatus.LEFT_DSM]))
        assert ok.all(), (name, np.flatnonzero(~ok)[:5], du[~ok][:5])


def test_demo_ppd_range(tmp_path, capsys, monkeypatch):
    """demo --ppd is 1..64 (its help says so): 65 is refused before any work (mutant: 640
    accepted, and a 2 GB grid was allocated)."""
    from planet_intersect.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(["demo", "--ppd", "65", "--out", "o"]) == 2
    assert "--ppd must be in 1..64, got 65" in capsys.readouterr().err
    assert not (tmp_path / "o").exists() or not list((tmp_path / "o").glob("run-*"))
