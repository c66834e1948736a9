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
