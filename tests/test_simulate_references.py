"""Image simulation (issue 12, section 4) against independent closed forms.

The reference is tests/references/sim_closed_form.py (geometry only; it does
not read the simulation, DSM or sensor code). Scenes: flat ground at H0 on
WGS-84 with one 24 m x 36 m box building of height h (5, 20, 60 m) on a
"nearest" DSM of 1 m cells; pushbroom views at zenith theta (0, 9, 25 deg at
the ground) from the east and from the north-west, 700 km up, 0.5 m ground
pixels; a frame camera 1.5 km up.

Two groups:

* ``test_reference_*``: self-checks of the reference (the caster against
  ``pi.intersect(method="exact")`` of issue 11 and against the closed forms).
  They need no simulation.
* everything else calls ``pi.simulate_image`` and asserts the closed forms
  (roof displacement, wall width and hidden strip each h tan(theta) within one
  pixel), every pixel's hit against the caster (1 cm; distance 1e-5 m), the
  surface classes (disagreements only where the ray passes within 1e-6 m of
  a box edge), nadir views without walls, Lambert walls with the Sun behind
  the sensor (1e-9), the frame camera reproducing the ortho-image on bare
  ground (1e-6 relative), and fill/valid for rays that miss the DSM.

"Within one pixel" is asserted as <= pixel + 1 cm: the count of pixels in a
band of width w is within (-p, p) of w exactly, and the fan of rays and
Earth curvature move the band edges by up to a few millimetres.

Pixel values compared to 1e-9 (Lambert) use 4 ulp instead when the image is
stored in a narrower float type (main stores float32); the same quantity is
held to 1e-9 through the float64 ``local_incidence`` backplane. The choices
the contract leaves open are listed (C1-C10) in the reference's docstring.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

import planet_intersect as pi
from references import sim_closed_form as R

FILL = -7.5
SLACK = 0.01  # m, see the module docstring
H_CASES = ((5.0, 0.0), (20.0, 35.0), (60.0, 0.0))  # (h, H0)
VIEWS = ((0.0, 90.0), (9.0, 90.0), (25.0, 90.0), (9.0, 315.0), (25.0, 315.0))  # (theta, azimuth of the sensor)
SCENARIOS = [(h, H0, th, az) for h, H0 in H_CASES for th, az in VIEWS]
IDS = [f"h{h:g}-H{H0:g}-th{th:g}-az{az:g}" for h, H0, th, az in SCENARIOS]


# ------------------------------------------------------------------ helpers
def ortho_grid(scene: R.BoxScene, sub=2):
    """An ortho grid of cell/sub pixels, south-first (dlat > 0), centres never on a DSM cell edge."""
    dlat = abs(scene.dlat) / sub
    dlon = scene.dlon / sub
    lat_first = scene.row_lat(scene.n - 1) - abs(scene.dlat) / 2 + dlat / 2  # south edge + half a pixel
    lon_first = scene.lon_first - scene.dlon / 2 + dlon / 2
    n = scene.n * sub
    # shift by a quarter ortho pixel so that no centre sits on a DSM cell edge or centre
    lat_first += dlat / 4 if sub == 1 else 0.0
    lon_first += dlon / 4 if sub == 1 else 0.0
    lat = lat_first + np.arange(n) * dlat
    lon = lon_first + np.arange(n) * dlon
    return lat_first, lon_first, dlat, dlon, lat, lon


def two_level_ortho(scene: R.BoxScene, ground=0.2, roof=1.0):
    """0.5 m ortho: ``roof`` on pixels whose centres lie inside the footprint, ``ground`` elsewhere."""
    lat_first, lon_first, dlat, dlon, lat, lon = ortho_grid(scene, 2)
    LA, LO = np.meshgrid(lat, lon, indexing="ij")
    vals = np.where(scene.in_footprint(LA, LO), roof, ground)
    return vals, (lat_first, lon_first, dlat, dlon), LA, LO


def local_u(scene, geom, lat, lon, height):
    """u coordinate (m, along the view direction away from the sensor) of geodetic points."""
    shape = np.shape(lat)
    p = R.to_ecr(np.ravel(lat), np.ravel(lon), np.ravel(height))
    xy = scene.frame.to_local(p)[:, :2]
    return (xy @ (-geom.a)).reshape(shape), (xy @ geom.along).reshape(shape)


@functools.lru_cache(maxsize=None)
def scenario(h, H0, theta, az):
    """Scene, pushbroom geometry, reference hits (reshaped) and the ortho of one scenario."""
    scene = R.BoxScene(h=h, H0=H0)
    geom = R.pushbroom(scene, theta, az)
    nl, npx = geom.l.shape[:2]
    ref = R.cast(scene, np.repeat(geom.s, npx, axis=0), geom.l.reshape(-1, 3))
    return scene, geom, ref, (nl, npx)


@functools.lru_cache(maxsize=None)
def simulated(h, H0, theta, az):
    scene, geom, ref, shape = scenario(h, H0, theta, az)
    vals, grid, LA, LO = two_level_ortho(scene)
    ortho = pi.OrthoImage.from_array(vals, *grid)
    sim = pi.simulate_image(scene.dsm(), ortho, pi.Pushbroom(geom.s, geom.l), method="exact",
                            walls="ortho", ground=scene.ground(), fill=FILL)
    return sim, vals, grid, LA, LO


def _a(x):
    return np.asarray(x)


def value_tolerance(image, tol=1e-9):
    """``tol`` for a float64 image; the rounding of values <= 1 (4 ulp) for a narrower float type."""
    dt = np.asarray(image).dtype
    return max(tol, 4 * float(np.finfo(dt).eps)) if np.issubdtype(dt, np.floating) else tol


# ======================================================= reference self-checks
@pytest.mark.parametrize("case", SCENARIOS, ids=IDS)
def test_reference_caster_matches_issue11_intersect(case):
    """The caster's exact hits equal pi.intersect(method="exact") on the same DSM (issue 11's tested code)."""
    scene, geom, ref, shape = scenario(*case)
    npx = shape[1]
    s = np.repeat(geom.s, npx, axis=0)
    res = pi.intersect(scene.dsm(), s, geom.l.reshape(-1, 3), method="exact")
    hit = _a(res.hit)
    assert np.array_equal(hit, ref.cls >= 0)
    dp = np.linalg.norm(_a(res.p)[hit] - ref.p[hit], axis=1)
    assert dp.max() < 2e-6  # contract: 1e-6 m along the ray for each side
    # stage 1 (tangent plane) is within a few millimetres of the exact surfaces
    far = ref.edge_distance > 0.01
    assert np.array_equal(ref.cls_plane[far], ref.cls[far])
    assert np.nanmax(np.abs(ref.t_plane - ref.t)) < 5e-3


@pytest.mark.parametrize("case", SCENARIOS, ids=IDS)
def test_reference_bands_follow_closed_form(case):
    """The caster's classes give wall width, roof shift and hidden strip h tan(theta) on every line."""
    h, H0, theta, az = case
    scene, geom, ref, shape = scenario(*case)
    d = R.expected_bands(h, theta)["wall_width"]
    th = R.view_zenith(geom.l.reshape(-1, 3), ref.lat, ref.lon)
    assert np.nanmax(np.abs(th - theta)) < 0.01  # zenith at the ground, curvature included
    hu, hv = local_u(scene, geom, ref.lat.reshape(shape), ref.lon.reshape(shape), ref.height.reshape(shape))
    m = R.line_measures(scene, geom, ref.cls.reshape(shape), hu)
    assert len(m) > 40
    assert np.all(np.abs(m[:, 0] - d) <= geom.pixel + SLACK)
    assert np.all((m[:, 1] - d >= -SLACK) & (m[:, 1] - d <= geom.pixel + SLACK))
    assert np.all((m[:, 2] - d <= SLACK) & (m[:, 2] - d >= -geom.pixel - SLACK))
    assert np.all(np.abs(m[:, 3] - d) <= geom.pixel + SLACK)
    # per roof pixel: nominal ground point minus the hit = h tan(theta) along the view, 0 across
    roof = ref.cls.reshape(shape) == R.ROOF
    U = np.broadcast_to(geom.u[None, :], shape)
    V = np.broadcast_to(geom.v[:, None], shape)
    assert np.all(np.abs((U - hu)[roof] - d) < 0.02)
    assert np.all(np.abs((V - hv)[roof]) < 0.02)


def test_reference_zenith_and_off_nadir():
    """theta at the ground vs off-nadir angle at 700 km: the sphere formula against the built geometry."""
    scene = R.BoxScene(h=20.0)
    M, N = R.curvature_radii(scene.lat0)
    for theta, az in ((9.0, 90.0), (25.0, 315.0), (40.0, 200.0)):
        S0, d = R._sensor_point(scene, theta, az, 700e3)
        lat, lon, hh = R.to_geodetic(S0)
        assert abs(hh[0] - 700e3) < 1e-3
        up = R.enu_vectors(lat, lon)[2][0]
        alpha = np.degrees(np.arccos(np.dot(-up, -d)))
        assert abs(R.view_zenith(-d, scene.lat0, scene.lon0) - theta) < 1e-9
        # sphere of the local Gaussian radius: right to ~0.01 deg at 25 deg on WGS-84
        assert abs(R.off_nadir_from_zenith(theta, 700e3, np.sqrt(M * N)) - alpha) < 0.02
        assert abs(R.zenith_from_off_nadir(alpha, 700e3, np.sqrt(M * N)) - theta) < 0.03
    assert abs(R.zenith_from_off_nadir(R.off_nadir_from_zenith(9.0, 7e5, 6.37e6), 7e5, 6.37e6) - 9.0) < 1e-12


def test_reference_expected_occlusion_matches_caster():
    """The hull-based hidden set equals 'the ray from the point toward the sensor meets the box' (caster)."""
    scene, geom, ref, shape = scenario(60.0, 0.0, 25.0, 315.0)
    vals, grid, LA, LO = two_level_ortho(scene)
    hid, margin, on_roof = R.expected_occlusion(scene, geom, LA, LO)
    sel = np.flatnonzero(~on_roof & (margin < 40.0))
    q = R.to_ecr(LA.ravel()[sel], LO.ravel()[sel], scene.H0)
    toward = R.unit(geom.centre_sensor - q)
    far = q + 800e3 * toward  # start beyond the sensor and come back down to the point
    c = R.cast(scene, far, -toward)
    blocked = (c.cls >= 0) & (c.t < 800e3 - 1e-3)
    ok = margin[sel] > R.OCCLUSION_TOLERANCE
    assert hid[sel].sum() > 1000
    assert np.array_equal(blocked[ok], hid[sel][ok])


# ======================================================= the implementation
BACKPLANES = ("lat", "lon", "height", "distance", "incidence", "local_incidence")


@pytest.mark.parametrize("case", SCENARIOS, ids=IDS)
def test_hits_match_reference_every_pixel(case):
    """valid == reference hit; sim.p within 1 cm of the caster's exact hit; the backplanes agree."""
    scene, geom, ref, shape = scenario(*case)
    sim = simulated(*case)[0]
    valid = _a(sim.valid)
    assert valid.shape == shape
    assert np.array_equal(valid.ravel(), ref.cls >= 0)
    assert valid.all()  # every ray of these scenes hits
    p = _a(sim.p).reshape(-1, 3)
    dp = np.linalg.norm(p - ref.p, axis=1)
    assert dp.max() < 0.01
    s = np.repeat(geom.s, shape[1], axis=0)
    dist = _a(sim.distance).ravel()
    assert np.max(np.abs(dist - ref.t)) < 1e-5  # contract: 1e-6 m along the ray (each side)
    assert np.max(np.abs(dist - np.linalg.norm(p - s, axis=1))) < 1e-6
    lat, lon, hgt = (_a(getattr(sim, k)).ravel() for k in ("lat", "lon", "height"))
    q = R.to_ecr(lat, lon, hgt)
    assert np.max(np.linalg.norm(q - ref.p, axis=1)) < 0.01
    assert np.max(np.abs(hgt - ref.height)) < 0.01
    assert np.max(np.abs(_a(sim.incidence).ravel() - ref.incidence)) < 1e-6
    ground = ref.cls == R.GROUND  # the view zenith at the ground is theta (curvature included)
    assert np.max(np.abs(_a(sim.incidence).ravel()[ground] - case[2])) < 0.01
    far = ref.edge_distance > 0.01  # the normal of a hit within 1 cm of an edge may be either face's
    assert np.max(np.abs(_a(sim.local_incidence).ravel()[far] - ref.local_incidence[far])) < 1e-6


@pytest.mark.parametrize("case", SCENARIOS, ids=IDS)
def test_surface_class_agrees_with_caster(case):
    """sim.surface == the caster's class except where the ray passes within 1e-6 m of a box edge."""
    scene, geom, ref, shape = scenario(*case)
    surface = _a(simulated(*case)[0].surface).ravel()
    bad = surface != ref.cls
    excused = ref.edge_distance < 1e-6 + scene.edge_sag_bound()
    assert np.count_nonzero(bad & ~excused) == 0, (
        f"{np.count_nonzero(bad)} class disagreements, {np.count_nonzero(bad & ~excused)} not at an edge")
    # and the reference classes are all present where they should be
    counts = [np.count_nonzero(surface == k) for k in (R.GROUND, R.ROOF, R.WALL)]
    assert counts[0] > 1000 and counts[1] > 1000
    if case[2] > 0:
        assert counts[2] > 0


@pytest.mark.parametrize("case", SCENARIOS, ids=IDS)
def test_closed_form_bands_in_simulated_image(case):
    """Roof displacement, visible wall width and hidden ground strip = h tan(theta), within one pixel.

    Measured on every image line that crosses the box: wall width = wall
    pixels (sim.surface) x pixel; roof displacement = first/last roof pixel
    minus the box's near/far crossing of that line, and per roof pixel its
    nominal ground point minus its hit (sim.lat/lon); hidden strip = first
    ground hit (sim.lat/lon) beyond the box minus the far crossing; and in
    sim.image the centroid of the roof-coloured pixels minus the footprint's.
    """
    h, H0, theta, az = case
    scene, geom, ref, shape = scenario(*case)
    sim = simulated(*case)[0]
    d = R.expected_bands(h, theta)
    p = geom.pixel
    surface = _a(sim.surface)
    hu, hv = local_u(scene, geom, _a(sim.lat), _a(sim.lon), _a(sim.height))
    m = R.line_measures(scene, geom, surface, hu)
    assert len(m) > 40
    assert np.all(np.abs(m[:, 0] - d["wall_width"]) <= p + SLACK), m[:, 0]
    assert np.all(np.abs(m[:, 1] - d["roof_displacement"]) <= p + SLACK), m[:, 1]
    assert np.all(np.abs(m[:, 2] - d["roof_displacement"]) <= p + SLACK), m[:, 2]
    assert np.all(np.abs(m[:, 3] - d["hidden_strip"]) <= p + SLACK), m[:, 3]
    # per roof pixel, from the hits
    roof = surface == R.ROOF
    U = np.broadcast_to(geom.u[None, :], shape)
    V = np.broadcast_to(geom.v[:, None], shape)
    assert abs(np.mean((U - hu)[roof]) - d["roof_displacement"]) <= p
    assert np.all(np.abs((U - hu)[roof] - d["roof_displacement"]) < 0.02)
    assert np.all(np.abs((V - hv)[roof]) < 0.02)
    # in the image: the roof colour (1.0; ground 0.2, walls="ortho" walls <= 0.6) moved away from the sensor
    img = _a(sim.image)
    bright = img > 0.8
    C = scene.corners_local()
    du = np.mean(U[bright]) - np.mean(C @ (-geom.a))
    dv = np.mean(V[bright]) - np.mean(C @ geom.along)
    assert abs(du - d["roof_displacement"]) <= p and abs(dv) <= p
    # every pixel (walls="ortho" included): the contract's bilinear sample at the caster's hit
    vals, grid = simulated(*case)[1:3]
    want = R.ortho_bilinear(vals, *grid, ref.lat, ref.lon).reshape(shape)
    assert np.max(np.abs(img - want)) < 1e-5  # 1e-6 m of hit error moves a 1.6/m ramp by 1.6e-6


@pytest.mark.parametrize("case", SCENARIOS, ids=IDS)
def test_occlusion_is_the_hidden_strip(case):
    """sim.occlusion on the ortho grid = the sweep of the footprint away from the sensor (C6).

    Per pixel (disagreements only within 3 cm of the shadow's edge), and as a
    width: the occluded length along every line parallel to the view that
    crosses the box = h tan(theta) within one ortho pixel (0.5 m, plus the
    0.02 m sampling step and SLACK).
    """
    h, H0, theta, az = case
    scene, geom, ref, shape = scenario(*case)
    sim, vals, grid, LA, LO = simulated(*case)
    occ = _a(sim.occlusion)
    assert occ.shape == vals.shape and occ.dtype == bool
    hid, margin, on_roof = R.expected_occlusion(scene, geom, LA, LO)
    bad = occ.ravel() != hid
    assert np.count_nonzero(bad & (margin >= R.OCCLUSION_TOLERANCE)) == 0, np.count_nonzero(bad)
    strip = R.strip_along_lines(scene, geom, occ, grid)
    assert len(strip) > 40
    assert np.all(np.abs(strip - R.expected_bands(h, theta)["hidden_strip"]) <= 0.5 + 0.02 + SLACK), strip
    # footprint: ortho centres more than one image pixel inside the image's ground grid are in it,
    # those more than one pixel outside are not
    fu, fv = local_u(scene, geom, LA, LO, np.full(LA.shape, scene.H0))
    fp = _a(sim.footprint)
    inner = ((fu > geom.u[0] + geom.pixel) & (fu < geom.u[-1] - geom.pixel)
             & (fv > geom.v[0] + geom.pixel) & (fv < geom.v[-1] - geom.pixel))
    outer = ((fu < geom.u[0] - geom.pixel) | (fu > geom.u[-1] + geom.pixel)
             | (fv < geom.v[0] - geom.pixel) | (fv > geom.v[-1] + geom.pixel))
    assert fp[inner].all() and not fp[outer].any()


@pytest.mark.parametrize("h", [5.0, 20.0, 60.0])
def test_nadir_view_shows_no_walls(h):
    """Rays along each aim point's ellipsoid normal: no wall pixel; the roof exactly over the footprint."""
    scene = R.BoxScene(h=h, H0=0.0 if h != 20.0 else 35.0)
    s, l, lat, lon = R.nadir_pushbroom(scene)
    vals, grid, LA, LO = two_level_ortho(scene)
    sim = pi.simulate_image(scene.dsm(), pi.OrthoImage.from_array(vals, *grid), pi.Pushbroom(s, l),
                            ground=scene.ground())
    surface = _a(sim.surface).ravel()
    assert np.count_nonzero(surface == R.WALL) == 0
    assert np.array_equal(surface == R.ROOF, scene.in_footprint(lat, lon))
    ref = R.cast(scene, s, l.reshape(-1, 3))
    assert np.array_equal(ref.cls, surface)
    assert np.max(np.linalg.norm(_a(sim.p).reshape(-1, 3) - ref.p, axis=1)) < 0.01
    assert np.max(np.abs(_a(sim.incidence).ravel())) < 1e-5  # arccos near 1: 1e-16 in cos is 1e-6 deg


LAMBERT_VIEWS = [(9.0, 90.0), (25.0, 90.0), (9.0, 315.0), (25.0, 315.0)]


@pytest.mark.parametrize("theta,az", LAMBERT_VIEWS, ids=[f"th{t:g}-az{a:g}" for t, a in LAMBERT_VIEWS])
def test_lambert_sun_behind_sensor_walls_are_cos_incidence(theta, az):
    """shading="lambert", sun = -l (ECR), ambient 0, ortho of ones: pixel = cos(local incidence), 1e-9.

    Exactly parallel rays (one pixel per line, C4) so that -l is the Sun for
    every pixel. Walls: cos of the angle between -l and the wall's outward
    horizontal normal (the caster's), = sin(theta) cos(azimuth - wall azimuth)
    in closed form; roofs and ground: n . (-l) with n the ellipsoid normal.
    """
    scene = R.BoxScene(h=20.0, H0=35.0)
    s, l, l0, u, v = R.parallel_pushbroom(scene, theta, az)
    lat_first, lon_first, dlat, dlon, lat, lon = ortho_grid(scene, 2)
    ones = np.ones((lat.size, lon.size))
    sim = pi.simulate_image(scene.dsm(), pi.OrthoImage.from_array(ones, lat_first, lon_first, dlat, dlon),
                            pi.Pushbroom(s, l), shading="lambert", sun=-l0, ambient=0.0,
                            walls="interpolate", ground=scene.ground())
    ref = R.cast(scene, s, l.reshape(-1, 3))
    img = _a(sim.image).ravel()
    surface = _a(sim.surface).ravel()
    far = ref.edge_distance > 1e-6 + scene.edge_sag_bound()
    assert np.array_equal(surface[far], ref.cls[far])
    wall = (surface == R.WALL) & far
    assert wall.sum() > 50
    cos_impl = np.cos(np.radians(_a(sim.local_incidence).ravel()))
    cos_ref = np.sum(ref.normal * (-l0), axis=1)
    # the geometry (float64 backplane) to 1e-9; the pixel values to 1e-9 or, for an image stored
    # in a narrower float type (float32 on main at the time of writing), to its rounding
    tol = value_tolerance(sim.image)
    assert np.max(np.abs(cos_impl[wall] - cos_ref[wall])) < 1e-9
    assert np.max(np.abs(img[wall] - cos_impl[wall])) < tol
    assert np.max(np.abs(img[wall] - cos_ref[wall])) < tol
    wall_az = np.array([180.0, 90.0, 0.0, 270.0])[ref.wall[wall]]
    closed = np.sin(np.radians(theta)) * np.cos(np.radians(az - wall_az))
    assert np.max(np.abs(img[wall] - np.maximum(closed, 0.0))) < 1e-4
    flat = ~wall & far & (surface >= 0)
    assert np.max(np.abs(img[flat] - cos_ref[flat])) < tol
    cos_flat = np.cos(np.radians(_a(sim.local_incidence).ravel()))
    assert np.max(np.abs(cos_flat[flat] - cos_ref[flat])) < 1e-9
    assert np.max(np.abs(img[flat] - np.cos(np.radians(theta)))) < 1e-4


def test_wall_interpolation_is_linear_in_height():
    """walls="interpolate": on the east wall, seen from the east, with an ortho that varies only east-west
    (1.0 over the building's longitudes, 0.2 elsewhere), the wall value is affine in the hit height,
    from the roof-edge colour (>= 0.6, bilinear just inside) at the top to the ground colour
    (<= 0.6, just outside) at the foot."""
    scene = R.BoxScene(h=20.0, H0=35.0)
    geom = R.pushbroom(scene, 25.0, 90.0)
    lat_first, lon_first, dlat, dlon, lat, lon = ortho_grid(scene, 2)
    LA, LO = np.meshgrid(lat, lon, indexing="ij")
    vals = np.where((LO >= scene.lon_w) & (LO <= scene.lon_e), 1.0, 0.2)
    sim = pi.simulate_image(scene.dsm(), pi.OrthoImage.from_array(vals, lat_first, lon_first, dlat, dlon),
                            pi.Pushbroom(geom.s, geom.l), walls="interpolate", ground=scene.ground())
    nl, npx = geom.l.shape[:2]
    ref = R.cast(scene, np.repeat(geom.s, npx, axis=0), geom.l.reshape(-1, 3))
    surface = _a(sim.surface).ravel()
    east = (surface == R.WALL) & (ref.wall == 1) & (ref.edge_distance > 0.01)
    assert east.sum() > 200
    z = _a(sim.height).ravel()[east]
    val = _a(sim.image).ravel()[east]
    A = np.stack([np.ones_like(z), z - scene.H0], axis=1)
    coef, *_ = np.linalg.lstsq(A, val, rcond=None)
    tol = value_tolerance(sim.image)
    assert np.max(np.abs(A @ coef - val)) < 1e-6  # "just inside/outside" moves with latitude: ~1e-8
    top, foot = coef[0] + coef[1] * scene.h, coef[0]
    assert 0.6 - tol <= top <= 1.0 + tol and 0.2 - tol <= foot <= 0.6 + tol and top > foot


def _frame_rays(scene, position, lat, lon, height):
    aim = R.to_ecr(lat, lon, height)
    return R.unit(aim - position)


def test_frame_camera_reproduces_ortho_on_bare_ground():
    """A frame camera 1.5 km up whose rays aim at ortho pixel centres: where the first hit is that
    centre (bare, unhidden ground: the caster) the image equals the ortho value to 1e-6 relative;
    elsewhere (roof, wall, hidden ground) it is the contract's bilinear sample at the caster's hit."""
    scene = R.BoxScene(h=20.0, H0=35.0)
    lat_first, lon_first, dlat, dlon, lat, lon = ortho_grid(scene, 1)  # 1 m ortho, quarter-cell offset
    rng = np.random.default_rng(12)
    vals = rng.uniform(1.0, 2.0, (lat.size, lon.size))
    ic = np.argmin(np.abs(lat - scene.lat0))
    jc = np.argmin(np.abs(lon - scene.lon0))
    rows = np.arange(ic - 50, ic + 50)
    cols = np.arange(jc - 50, jc + 50)
    LA, LO = np.meshgrid(lat[rows], lon[cols], indexing="ij")
    position = R.to_ecr(scene.lat0 - 0.002, scene.lon0, 1500.0)  # about 220 m south: oblique
    l = _frame_rays(scene, position, LA, LO, scene.H0)
    sim = pi.simulate_image(scene.dsm(), pi.OrthoImage.from_array(vals, lat_first, lon_first, dlat, dlon),
                            pi.FrameCamera(position, l), walls="ortho", ground=scene.ground())
    ref = R.cast(scene, np.broadcast_to(position, (l.size // 3, 3)), l.reshape(-1, 3))
    img = _a(sim.image).ravel()
    aim = R.to_ecr(LA.ravel(), LO.ravel(), scene.H0)
    bare = (ref.cls == R.GROUND) & (np.linalg.norm(ref.p - aim, axis=1) < 1e-6)
    assert bare.sum() > 8000
    want = vals[np.ix_(rows, cols)].ravel()
    assert np.max(np.abs(img[bare] / want[bare] - 1.0)) < 1e-6
    other = ~bare & (ref.edge_distance > 0.01)
    assert other.sum() > 500
    samp = R.ortho_bilinear(vals, lat_first, lon_first, dlat, dlon, ref.lat[other], ref.lon[other])
    assert np.max(np.abs(img[other] / samp - 1.0)) < 1e-5


def test_fill_and_valid_for_rays_that_miss_the_dsm():
    """Rays to the sky (miss), beyond the DSM edge (left the DSM) and into a no-data patch are
    invalid: image = fill in every band, surface -1, backplanes NaN; the others are ground hits
    with the 3-band ortho sampled at the hit."""
    scene = R.BoxScene(h=20.0, H0=35.0)
    z = scene.heights()
    z[20:41, 20:41] = np.nan
    dsm = pi.GeodeticDSM.from_array(z, scene.lat_first, scene.lon_first, scene.dlat, scene.dlon,
                                    interpolation="nearest")
    lat_first, lon_first, dlat, dlon, lat, lon = ortho_grid(scene, 2)
    rng = np.random.default_rng(3)
    base = rng.uniform(1.0, 2.0, (lat.size, lon.size))
    vals = np.stack([base, 2 * base, base + 5], axis=-1)
    position = R.to_ecr(scene.lat0, scene.lon0, 1500.0)
    e, n, u = R.enu_vectors(scene.lat0, scene.lon0)
    la_min, la_max, lo_min, lo_max = scene.extent
    k = np.arange(5)
    sky = R.unit(u + 0.1 * (k[:, None] - 2) * e)
    outside = _frame_rays(scene, position, np.full(5, la_max + 0.0005), scene.lon0 + (k - 2) * 1e-4,
                          np.full(5, scene.H0))
    nodata = _frame_rays(scene, position, scene.row_lat(28 + k), scene.col_lon(np.full(5, 30)),
                         np.full(5, scene.H0))
    ground = _frame_rays(scene, position, scene.lat0 + (k - 2) * 3e-4 + 1.1e-6, np.full(5, scene.lon0 + 4e-4),
                         np.full(5, scene.H0))
    l = np.stack([sky, outside, nodata, ground])
    sim = pi.simulate_image(dsm, pi.OrthoImage.from_array(vals, lat_first, lon_first, dlat, dlon),
                            pi.FrameCamera(position, l), fill=FILL, ground=scene.ground())
    valid = _a(sim.valid)
    assert valid.shape == (4, 5)
    assert not valid[:3].any() and valid[3].all()
    img = _a(sim.image)
    assert img.shape == (4, 5, 3)
    assert np.all(img[:3] == FILL)
    assert np.all(_a(sim.surface)[:3] == -1) and np.all(_a(sim.surface)[3] == R.GROUND)
    for name in BACKPLANES:
        b = _a(getattr(sim, name))
        assert np.all(np.isnan(b[:3])), name
        assert np.all(np.isfinite(b[3])), name
    assert np.all(np.isnan(_a(sim.p)[:3]))
    ref = R.cast(scene, np.broadcast_to(position, (5, 3)), ground)
    samp = R.ortho_bilinear(vals, lat_first, lon_first, dlat, dlon, ref.lat, ref.lon)
    assert np.max(np.abs(img[3] / samp - 1.0)) < 1e-6


@pytest.mark.parametrize("case", SCENARIOS, ids=IDS)
def test_reference_strip_measure_on_expected_raster(case):
    """strip_along_lines on the reference's own hidden raster gives h tan(theta) within one ortho pixel."""
    h, H0, theta, az = case
    scene, geom, ref, shape = scenario(*case)
    vals, grid, LA, LO = two_level_ortho(scene)
    hid = R.expected_occlusion(scene, geom, LA, LO)[0].reshape(LA.shape)
    strip = R.strip_along_lines(scene, geom, hid, grid)
    assert len(strip) > 40
    assert np.all(np.abs(strip - R.expected_bands(h, theta)["hidden_strip"]) <= 0.5 + 0.02 + SLACK)


def test_threads_and_block_lines_do_not_change_the_result():
    """The contract: identical results for any threads and block_lines (one oblique scene, every array)."""
    case = (60.0, 0.0, 25.0, 315.0)
    scene, geom, ref, shape = scenario(*case)
    sim, vals, grid, LA, LO = simulated(*case)
    other = pi.simulate_image(scene.dsm(), pi.OrthoImage.from_array(vals, *grid), pi.Pushbroom(geom.s, geom.l),
                              method="exact", walls="ortho", ground=scene.ground(), fill=FILL,
                              threads=2, block_lines=7)
    for name in ("image", "valid", "surface", "p", "occlusion", "footprint") + BACKPLANES:
        assert np.array_equal(_a(getattr(sim, name)), _a(getattr(other, name)), equal_nan=True), name


def test_default_ground_estimate_gives_the_same_classes():
    """ground=None: the opening (window wider than the 24 m x 36 m building) finds the flat ground,
    so the classes equal the caster's as with the explicit ground."""
    case = (20.0, 35.0, 25.0, 315.0)
    scene, geom, ref, shape = scenario(*case)
    vals, grid = simulated(*case)[1:3]
    sim = pi.simulate_image(scene.dsm(), pi.OrthoImage.from_array(vals, *grid), pi.Pushbroom(geom.s, geom.l),
                            walls="ortho")
    surface = _a(sim.surface).ravel()
    excused = ref.edge_distance < 1e-6 + scene.edge_sag_bound()
    assert np.count_nonzero((surface != ref.cls) & ~excused) == 0
    assert np.count_nonzero(surface == R.ROOF) > 1000
