"""Ray tracing over geodetic DSMs: following (Shin & Park), exact and iterative.

Expectations are independent of the Fortran core: plane-line intersections for
walls (a meridian is a plane through the axis), level crossings of the exact
geodetic height found by bisection with PROJ's conversion, and the paper's two
failure modes of iterative ray tracing on purpose-built scenes.
"""

from __future__ import annotations

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect import DSMStatus, GeodeticDSM

A, F = 6378137.0, 1 / 298.257223563
METHODS = ("following", "exact", "iterative")


def enu(lat, lon):
    la, lo = np.radians(lat), np.radians(lon)
    up = np.array([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)])
    east = np.array([-np.sin(lo), np.cos(lo), 0.0])
    north = np.cross(up, east)
    return east, north, up


def ray_to(lat, lon, h, off_nadir, azimuth, dist=600e3, a=A, f=F):
    """A ray from `dist` away through geodetic (lat, lon, h), `off_nadir` deg from the
    local vertical, travelling towards `azimuth` (deg clockwise from north)."""
    east, north, up = enu(lat, lon)
    o, z = np.radians(off_nadir), np.radians(azimuth)
    d = -np.cos(o) * up + np.sin(o) * (np.sin(z) * east + np.cos(z) * north)    # travel direction
    target = pi.geodetic_to_ecef(lat, lon, h, a, f)
    return target - dist * d, d


def level_crossing_proj(s, d, level, r0, r1):
    """First r in [r0, r1] where the geodetic height (by PROJ) drops to `level` (bisection)."""
    pyproj = pytest.importorskip("pyproj", reason="pyproj (extra 'geo') is not installed")
    t = pyproj.Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)

    def h(r):
        p = s + r * d
        return t.transform(p[0], p[1], p[2])[2]

    assert h(r0) > level > h(r1)
    for _ in range(80):
        m = 0.5 * (r0 + r1)
        if h(m) > level:
            r0 = m
        else:
            r1 = m
    return r1


def block_dsm(interp="nearest", ground=0.0, top=50.0):
    """1e-5 deg cells (1.11 m N-S, 0.79 m E-W at 45 N); a block 40 cells wide E-W."""
    h = np.full((200, 200), ground)
    h[:, 100:140] = top
    return GeodeticDSM.from_array(h, 45.0, 10.0, 1e-5, 1e-5, interpolation=interp)


WALL_LON = 10.0 + 99.5e-5          # west face of the block (cell edge)


def test_wall_hit_is_the_plane_intersection():
    """Level-0 point 10 cells inside the block: the ray meets the west wall, as the
    plane of the meridian predicts; iterative tracing oscillates (Fig. 1b)."""
    dsm = block_dsm()
    s, d = ray_to(45.001, 10.0 + 109e-5, 0.0, 30.0, 90.0)
    # the wall plane: atan2(y, x) = WALL_LON  <=>  p . (-sin, cos, 0) = 0
    nrm = np.array([-np.sin(np.radians(WALL_LON)), np.cos(np.radians(WALL_LON)), 0.0])
    r_wall = -np.dot(s, nrm) / np.dot(d, nrm)
    lat_w, lon_w, h_w = pi.ecef_to_geodetic(s + r_wall * d)
    assert 0.0 < h_w < 50.0                                   # the ray does meet the wall
    for method in ("following", "exact"):
        res = pi.intersect(dsm, s, d, method=method)
        assert res.status[0] == DSMStatus.HIT, method
        assert res.distance[0] == pytest.approx(r_wall, abs=2e-6), method
        assert res.lon[0] == pytest.approx(WALL_LON, abs=1e-10)
        assert res.height[0] == pytest.approx(h_w, abs=1e-5)
        assert res.surface_height[0] == 50.0                  # the wall top
    it = pi.intersect(dsm, s, d, method="iterative")
    assert it.status[0] == DSMStatus.OSCILLATION             # endless: 0 -> roof -> 50 -> ground -> 0 ...
    assert not it.hit[0]


def test_roof_hit_not_the_ground_behind():
    """Level-0 point on the ground 5 m behind (east of) the block: the ray enters
    through the roof (h = 50); iterative tracing converges to the ground behind (Fig. 1c)."""
    dsm = block_dsm()
    s, d = ray_to(45.001, 10.0 + 146e-5, 0.0, 30.0, 90.0)
    r_roof = level_crossing_proj(s, d, 50.0, 599e3, 600.1e3)
    for method in ("following", "exact"):
        res = pi.intersect(dsm, s, d, method=method)
        assert res.status[0] == DSMStatus.HIT
        assert res.distance[0] == pytest.approx(r_roof, abs=2e-6)
        assert res.height[0] == pytest.approx(50.0, abs=1e-5)
        assert 10.0 + 99.5e-5 < res.lon[0] < 10.0 + 139.5e-5
    it = pi.intersect(dsm, s, d, method="iterative")
    assert it.status[0] == DSMStatus.HIT                      # it "converges" ...
    assert it.height[0] == pytest.approx(0.0, abs=1e-6)        # ... to the ground behind the building
    assert it.distance[0] == pytest.approx(600e3, abs=1e-3)


@pytest.mark.parametrize("interp", ["bilinear", "nearest"])
def test_constant_surface_is_the_level_crossing(interp):
    """A constant DSM at 120 m: every method hits the first point of geodetic height 120."""
    dsm = GeodeticDSM.from_array(np.full((50, 60), 120.0), 44.99, 9.99, 0.0005, 0.0005, interpolation=interp)
    rng = np.random.default_rng(0)
    for k in range(8):
        lat, lon = 45.0 + rng.uniform(-0.002, 0.002), 10.0 + rng.uniform(-0.002, 0.002)
        s, d = ray_to(lat, lon, 120.0, rng.uniform(0, 40), rng.uniform(0, 360), dist=rng.uniform(1e3, 7e5))
        dist = np.linalg.norm(pi.geodetic_to_ecef(lat, lon, 120.0) - s)
        r = level_crossing_proj(s, d, 120.0, dist - 50, dist + 50)
        for method in METHODS:
            res = pi.intersect(dsm, s, d, method=method)
            assert res.status[0] == DSMStatus.HIT
            assert res.distance[0] == pytest.approx(r, abs=2e-6), method
            assert res.height[0] == pytest.approx(120.0, abs=2e-6)


def test_paper_nadir_case():
    """Exactly vertical ray: the paper returns the projected point at once (step 1)."""
    dsm = block_dsm()
    lat, lon = 45.001, 10.0 + 120e-5
    n = enu(lat, lon)[2]
    s = pi.geodetic_to_ecef(lat, lon, 7e5)
    res = pi.intersect(dsm, s, -n, method="following")
    assert res.status[0] == DSMStatus.HIT and res.nsteps[0] == 1
    assert res.height[0] == pytest.approx(50.0, abs=1e-6)
    ex = pi.intersect(dsm, s, -n, method="exact")
    assert ex.distance[0] == pytest.approx(res.distance[0], abs=2e-6)


def test_no_data_left_miss_inside():
    h = np.full((100, 100), 10.0)
    h[40:60, 40:60] = np.nan
    dsm = GeodeticDSM.from_array(h, 45.0, 10.0, 1e-5, 1e-5, interpolation="nearest")
    s_nd, d_nd = ray_to(45.0005, 10.0005, 10.0, 20.0, 45.0)         # aimed into the hole
    s_out, d_out = ray_to(45.0005, 10.002, 10.0, 20.0, 90.0)        # aimed east of the DSM
    s_up, d_up = ray_to(45.0005, 10.0005, 10.0, 20.0, 45.0)
    d_up = -d_up                                                    # pointing to space
    for method in ("following", "exact"):
        res = pi.intersect(dsm, np.array([s_nd, s_out, s_up]), np.array([d_nd, d_out, d_up]),
                           method=method, outside="ellipsoid")
        assert list(res.status) == [DSMStatus.NO_DATA, DSMStatus.LEFT_DSM, DSMStatus.MISS], method
        assert not res.hit.any() and np.isnan(res.p).all()
        # the no-data event: over the hole, at or below H_max to the conversions' accuracy (~1e-15 of
        # a, 6.4e-9 m: the exact mode's event came out 0.80e-9 m above it, 1.16e-9 m once its first
        # conversion took the DSM's centre as its reference)
        assert 45.0004 - 1e-9 <= res.event_lat[0] <= 45.0006 and res.event_height[0] <= 10.0 + 1e-8
        # left the DSM: east of the last cell edge, low
        assert res.event_lon[1] >= 10.0 + 99.5e-5 - 1e-6 and res.event_height[1] <= 10.0 + 1e-9
        # the bare-ellipsoid fallback for that ray
        assert res.on_ellipsoid.tolist() == [False, True, False]
        assert pi.ecef_to_geodetic(res.ellipsoid_p[1])[2] == pytest.approx(0.0, abs=1e-6)
    with pytest.raises(ValueError, match=r"s\[0\] = .* at or below the DSM surface"):
        pi.intersect(dsm, pi.geodetic_to_ecef(45.0001, 10.0001, 5.0), [0, 0, -1.0])


def test_exact_mode_edge_statuses():
    dsm = block_dsm()
    s, d = ray_to(45.001, 10.0 + 120e-5, 50.0, 10.0, 0.0)
    # a ray starting outside the area but low enough: hits once it is over the DSM
    s2 = pi.geodetic_to_ecef(45.001, 9.9999, 60.0)
    east = enu(45.001, 10.0)[0]
    d2 = east - 0.2 * enu(45.001, 10.0)[2]
    for method in ("following", "exact"):
        res = pi.intersect(dsm, np.array([s, s2]), np.array([d, d2]), method=method)
        assert res.status.tolist() == [DSMStatus.HIT, DSMStatus.HIT], method
    # ... on the block's west wall: the meridian plane's intersection
    nrm = np.array([-np.sin(np.radians(WALL_LON)), np.cos(np.radians(WALL_LON)), 0.0])
    d2u = d2 / np.linalg.norm(d2)
    r_wall = -np.dot(s2, nrm) / np.dot(d2u, nrm)
    res = pi.intersect(dsm, s2, d2, method="exact")
    assert res.distance[0] == pytest.approx(r_wall, abs=2e-6)
    assert 0.0 < res.height[0] < 50.0


@pytest.fixture(scope="module")
def city():
    """A 1 m-class building DSM (1e-5 deg cells) with blocks 3-150 m and one-cell towers."""
    rng = np.random.default_rng(7)
    n = 400
    h = np.full((n, n), 100.0) + np.linspace(0, 5, n)[None, :]
    for _ in range(500):
        i, j = rng.integers(0, n, 2)
        w, e = rng.integers(1, 25, 2)
        h[i:i + w, j:j + e] = 100 + rng.uniform(3, 150)
    for _ in range(60):
        i, j = rng.integers(0, n, 2)
        h[i, j] = 100 + rng.uniform(50, 150)
    return h


def city_rays(dsm, n, seed=3):
    rng = np.random.default_rng(seed)
    s, d = [], []
    for _ in range(n):
        lat = dsm.lat_first + rng.uniform(0.3, 0.7) * (dsm.nrows - 1) * dsm.dlat
        lon = dsm.lon_first + rng.uniform(0.3, 0.7) * (dsm.ncols - 1) * dsm.dlon
        si, di = ray_to(lat, lon, 100.0, rng.uniform(0, 30), rng.uniform(0, 360), dist=rng.uniform(5e5, 7e5))
        s.append(si)
        d.append(di)
    return np.array(s), np.array(d)


@pytest.mark.parametrize("interp", ["nearest", "bilinear"])
def test_following_never_before_exact(city, interp):
    """Every crossing the following finds is at or after the exact first entry;
    most agree (the rest are the paper's steps across corners: notes 14-15)."""
    dsm = GeodeticDSM.from_array(city, 45.0, 10.0, 1e-5, 1e-5, interpolation=interp)
    s, d = city_rays(dsm, 3000)
    ex = pi.intersect(dsm, s, d, method="exact")
    fo = pi.intersect(dsm, s, d, method="following")
    assert ex.hit.all() and fo.hit.all()
    late = fo.distance - ex.distance
    assert late.min() > -2e-6
    agree = np.abs(late) <= 2e-6
    assert agree.mean() > 0.9
    # each exact hit is on the surface: height at or below H there, on a wall or at H
    assert (ex.height <= ex.surface_height + 1e-6).all()
    if interp == "bilinear":
        # 1e-6 m along the ray on slopes up to 150 m per 0.79 m cell: |h - H| <= 2e-4 m
        np.testing.assert_allclose(ex.height, ex.surface_height, atol=2e-4)
        assert np.median(np.abs(ex.height - ex.surface_height)) < 1e-6


@pytest.mark.parametrize("method", METHODS)
def test_threads_bit_identical(city, method):
    dsm = GeodeticDSM.from_array(city, 45.0, 10.0, 1e-5, 1e-5, interpolation="nearest")
    s, d = city_rays(dsm, 2000, seed=11)
    r1 = pi.intersect(dsm, s, d, method=method, threads=1)
    r2 = pi.intersect(dsm, s, d, method=method, threads=2)
    for name in ("p", "status", "nsteps", "distance", "event_p"):
        np.testing.assert_array_equal(getattr(r1, name), getattr(r2, name))


def test_antimeridian_and_pole_and_mars():
    # a DSM across the antimeridian: a ray aimed at lon 180.0005
    h = np.full((100, 100), 30.0)
    h[:, 50:] = 60.0
    dsm = GeodeticDSM.from_array(h, -10.0, 179.9995, 1e-5, 1e-5, interpolation="nearest")
    s, d = ray_to(-9.9995, -179.9997, 60.0, 15.0, 0.0)
    for method in ("following", "exact"):
        res = pi.intersect(dsm, s, d, method=method)
        assert res.status[0] == DSMStatus.HIT and res.height[0] == pytest.approx(60.0, abs=2e-6)
        assert res.lon[0] == pytest.approx(-179.9997, abs=2e-5)
    # near the north pole
    dsm = GeodeticDSM.from_array(np.full((40, 400), 5.0), 89.99, -180.0, 0.00025, 0.9, interpolation="bilinear")
    s, d = ray_to(89.995, 30.0, 5.0, 20.0, 10.0)
    for method in METHODS:
        res = pi.intersect(dsm, s, d, method=method)
        assert res.status[0] == DSMStatus.HIT and res.height[0] == pytest.approx(5.0, abs=2e-6)
    # Mars areodetic heights
    a, f = 3396190.0, 1 / 169.8
    dsm = GeodeticDSM.from_array(np.full((20, 20), -2000.0), 18.0, 226.0, 0.01, 0.01, a=a, f=f)
    s, d = ray_to(18.1, 226.1, -2000.0, 25.0, 200.0, dist=3e5, a=a, f=f)
    res = pi.intersect(dsm, s, d, method="exact")
    assert res.status[0] == DSMStatus.HIT
    assert res.distance[0] == pytest.approx(3e5, abs=2e-6)
    assert pi.ecef_to_geodetic(res.p[0], a, f)[2] == pytest.approx(-2000.0, abs=2e-6)


def test_dispatch_and_errors(city):
    dsm = GeodeticDSM.from_array(city, 45.0, 10.0, 1e-5, 1e-5)
    s, d = city_rays(dsm, 2)
    assert pi.intersect(dsm, s, d).nsteps.sum() == pi.intersect(dsm, s, d, method="following").nsteps.sum()
    with pytest.raises(ValueError, match=r"method \(for a GeodeticDSM\) must be one of 'following', 'exact', 'iterative', got 'stepping'"):
        pi.intersect(dsm, s, d, method="stepping")
    with pytest.raises(TypeError, match=r"\['step_mode'\] apply to a planetary DEM"):
        pi.intersect(dsm, s, d, step_mode=0)
    with pytest.raises(ValueError, match="outside must be"):
        pi.intersect(dsm, s, d, outside="wall")
    with pytest.raises(ValueError, match=r"l\[1\] has zero length"):
        pi.intersect(dsm, s, [d[0], [0, 0, 0]])
    with pytest.raises(ValueError, match=r"s\[0\] has NaN"):
        pi.intersect(dsm, [np.nan, 0, 0], d[0])
    with pytest.raises(ValueError, match="threads must be"):
        pi.intersect(dsm, s, d, threads=-1)
    dem = pi.DEM.from_array(np.full((180, 360), 3390.0))
    with pytest.raises(ValueError, match=r"method \(for a planetary DEM\) must be one of 'stepping', 'exact', got 'following'"):
        pi.intersect(dem, [5000.0, 0, 0], [-1.0, 0, 0], method="following")
    with pytest.raises(TypeError, match=r"\['outside'\] apply to a GeodeticDSM only"):
        pi.intersect(dem, [5000.0, 0, 0], [-1.0, 0, 0], outside="ellipsoid")


def test_result_export(city):
    xr = pytest.importorskip("xarray", reason="xarray is an optional extra")
    dsm = GeodeticDSM.from_array(city, 45.0, 10.0, 1e-5, 1e-5)
    s, d = city_rays(dsm, 5)
    res = pi.intersect(dsm, s, d, method="exact")
    ds = res.to_xarray()
    assert isinstance(ds, xr.Dataset) and ds["p"].dims == ("ray", "xyz")
    np.testing.assert_array_equal(ds["distance"].values, res.distance)
    table = res.to_table()
    np.testing.assert_array_equal(table["p_z"], res.p[:, 2])
    assert len(res) == 5


def test_cli_run_on_a_dsm(tmp_path, capsys):
    from planet_intersect.cli import main

    h = np.full((200, 200), 0.0)
    h[:, 100:140] = 50.0
    f = tmp_path / "block.npz"
    np.savez(f, heights=h, lat_first=45.0, lon_first=10.0, dlat=1e-5, dlon=1e-5, interpolation="nearest")
    s1, d1 = ray_to(45.001, 10.0 + 146e-5, 0.0, 30.0, 90.0)           # roof (test above)
    s2, d2 = ray_to(45.001, 10.0 + 50e-5, 0.0, 10.0, 0.0)              # ground in front
    rays = tmp_path / "rays.txt"
    np.savetxt(rays, np.array([np.r_[s1, d1], np.r_[s2, d2]]), fmt="%.17g")
    assert main(["run", str(f), str(rays), "--out", str(tmp_path / "out"), "--method", "exact"]) == 0
    assert "2 rays (exact over the DSM" in capsys.readouterr().out
    table = np.genfromtxt(tmp_path / "out" / "run-001" / "results.csv", delimiter=",", names=True)
    np.testing.assert_allclose(table["height"], [50.0, 0.0], atol=1e-5)
    assert list(table["status"]) == [0, 0]
    assert main(["run", str(f), str(rays), "--method", "stepping", "--out", str(tmp_path / "o2")]) == 2
    assert "--method stepping: not a method for the geodetic DSM" in capsys.readouterr().err


@pytest.mark.parametrize("interp", ["bilinear", "nearest"])
def test_rays_onto_the_grid_edge(interp):
    """An oblique scan (9 deg from the East) whose edge pixels reach the ground exactly on the
    DSM's edge, and whose first and last lines run along its first and last rows, over a 40 x 40
    grid with one 20 m building (a review's case): 38 rays were MISS and 11 STEP_LIMIT after
    200,000 segments (shin-park-notes, "Exact mode"). The surface is defined on the closed
    rectangle of pixel centres, the edge included to rounding (a point within a few ulps of the
    edge is on it: a second review found the DSM's own edge centres outside), so every ray hits,
    the edge rays at their ground point, each in a few conversions; the following gives HIT or
    LEFT_DSM."""
    from planet_intersect.synthetic_dsm import metre_steps, oblique_pushbroom

    n = 40
    lat0, lon0 = 36.6, -84.3
    dlat, dlon = metre_steps(lat0)
    lat_first = lat0 + (n - 1) * dlat
    h = np.zeros((n, n))
    h[15:25, 15:25] = 20.0
    scene = dict(heights=h, lat_first=lat_first, lon_first=lon0, dlat=-dlat, dlon=dlon)
    dsm = GeodeticDSM.from_array(h, lat_first, lon0, -dlat, dlon, interpolation=interp)
    s, l = oblique_pushbroom(scene, zenith=9.0, azimuth=90.0, margin=0)
    S, L = np.repeat(s, n, axis=0), l.reshape(-1, 3)
    fol = pi.intersect(dsm, S, L, method="following", threads=1)
    assert set(np.unique(fol.status)) <= {DSMStatus.HIT, DSMStatus.LEFT_DSM}
    res = pi.intersect(dsm, S, L, method="exact", threads=1)
    assert (res.status == DSMStatus.HIT).all(), np.unique(res.status, return_counts=True)
    assert res.nsteps.max() < 100, res.nsteps.max()
    u = (res.lon - lon0) / dlon
    v = (lat_first - res.lat) / dlat
    edge = np.zeros((n, n), dtype=bool)
    edge[:, [0, -1]] = True                              # pixels aimed at the west and east edge columns
    edge = edge.ravel()
    assert np.all(np.abs(res.height[edge]) < 1e-6), np.abs(res.height[edge]).max()
    assert np.all(np.minimum(np.abs(u[edge]), np.abs(u[edge] - (n - 1))) < 1e-6)
    assert np.all((v > -1e-6) & (v < n - 1 + 1e-6)) and np.all((u > -1e-6) & (u < n - 1 + 1e-6))


def test_edge_pixel_centres_are_on_the_surface():
    """The DSM's own pixel centres (dsm.lats, dsm.lons) are inside its area, edges included (a
    review: 6 of 12 centres of a 3 x 4 grid were NaN, 9,169 of 214,552 over 300 random grids)."""
    rng = np.random.default_rng(5)
    bad = total = 0
    for _ in range(300):
        nr, nc = rng.integers(2, 12, 2)
        dlat = rng.choice([-1, 1]) * 10 ** rng.uniform(-5, -1)
        dlon = 10 ** rng.uniform(-5, -1)
        lat_first = rng.uniform(-80, 80 - abs(dlat) * nr) if dlat > 0 else rng.uniform(-80 + abs(dlat) * nr, 80)
        for interp in ("bilinear", "nearest"):
            d = GeodeticDSM.from_array(rng.uniform(0, 50, (nr, nc)), lat_first, rng.uniform(-180, 180), dlat, dlon,
                                       interpolation=interp)
            hs = d.height(d.lats[:, None], d.lons[None, :])
            bad += int(np.isnan(hs).sum())
            total += hs.size
            np.testing.assert_allclose(hs, d.heights, rtol=0, atol=1e-6)   # (a node to rounding: ~1e-10 cell)
    assert bad == 0 and total > 10000


def test_following_near_nadir_and_over_the_pole():
    """The following's step is at most the slab along the ray: rays 1e-7 and 1e-6 rad off nadir
    over a flat 100 m DSM with one 150 m pixel (1 arc-second cells) hit at 100 m (they were MISS
    after two steps of thousands of km); and eq. 2 on the polar axis gives h = |z| - b, so a
    drone 50 m over the pole finds the ground, not its own focal point (h was -N there)."""
    n = 40
    d = 1.0 / 3600.0
    hgt = np.full((n, n), 100.0)
    hgt[5, 5] = 150.0
    dsm = GeodeticDSM.from_array(hgt, 45.0 + (n - 1) * d, 10.0, -d, d)
    lat, lon = 45.0 + 20 * d, 10.0 + 20 * d
    for off in (1e-7, 1e-6, 1e-4):
        s, l = ray_to(lat, lon, 100.0, np.degrees(off), 30.0, dist=700e3)
        for method in ("following", "exact"):
            r = pi.intersect(dsm, s, l, method=method)
            assert r.status[0] == DSMStatus.HIT, (off, method, r.status[0])
            assert abs(r.height[0] - 100.0) < 1e-3, (off, method, r.height[0])
        assert r.nsteps[0] < 50
    lat_p, lon_p, h_p = pi.ecef_to_geodetic([0.0, 0.0, 6356752.314245 + 10.0], method="bowring")
    assert lat_p == 90.0 and h_p == pytest.approx(10.0, abs=1e-6)
    lat_p, lon_p, h_p = pi.ecef_to_geodetic([0.0, 0.0, -6356752.314245 - 10.0], method="printed")
    assert lat_p == -90.0 and h_p == pytest.approx(10.0, abs=1e-6)
    # a polar DSM: ground 0, a 100 m tower elsewhere; a drone 50 m over the pole looking down
    m = 60
    pole = np.zeros((m, m))
    pole[10, 10] = 100.0
    dp = GeodeticDSM.from_array(pole, 90.0, -180.0, -0.001, 6.0, interpolation="nearest")
    s = np.array([0.0, 0.0, 6356752.314245 + 50.0])
    l = np.array([1e-3, 0.0, -1.0])
    for method in ("following", "exact", "iterative"):
        r = pi.intersect(dp, s, l, method=method)
        assert r.status[0] == DSMStatus.HIT and r.distance[0] > 49.0 and abs(r.height[0]) < 1e-3, \
            (method, r.status[0], r.distance[0], r.height[0])


def test_drone_on_the_polar_axis_over_a_bilinear_pole():
    """A drone on the polar axis (and 1 mm, 5 mm off it) looking straight down at a global
    bilinear grid whose first row is the pole (one height there): a hit in a few dozen
    conversions. The node rows' maximum over the polar band took in the next row's heights, and
    the segments at the pole were never ruled out: STEP_LIMIT (a second review)."""
    rng = np.random.default_rng(2)
    nr, nc = 30, 36
    h = rng.uniform(5.0, 8.0, (nr, nc))
    h[0] = 6.0                                            # the pole: one height
    dsm = GeodeticDSM.from_array(h, 90.0, -180.0, -0.5, 10.0)
    b = 6356752.314245
    for off in (0.0, 1e-3, 5e-3):
        s = np.array([off, 0.0, b + 50.0])
        r = pi.intersect(dsm, s, np.array([0.0, 0.0, -1.0]), method="exact")
        assert r.status[0] == DSMStatus.HIT and r.nsteps[0] < 200, (off, r.status[0], r.nsteps[0])
        assert abs(r.height[0] - 6.0) < 1e-4 and abs(r.distance[0] - 44.0) < 1e-3, (off, r.height[0], r.distance[0])


def test_vertical_rays_at_the_pole_itself_on_a_bilinear_grid():
    """A nadir view of the pole built the obvious way: target and sensor both at latitude 90 by
    geodetic_to_ecef, which puts them ~4e-10 m off the axis (cos 90 deg rounds to 6e-17). On a
    polar cap grid (89-90 deg, 1 deg columns, the pole row one height of 50 m) the exact mode ran
    ~100,000 conversions and ended STEP_LIMIT for half of these rays (a differential review): the
    polar box's longitude rounding bound took the rounding of r l_x relative to |l| instead of
    |l_x|, a degree of longitude, and the node rows' maximum held the next row's heights. Now a
    hit on the pole row in a few dozen conversions, as the ray following's."""
    rng = np.random.default_rng(5)
    h = rng.uniform(0.0, 100.0, (201, 360))
    h[-1] = 50.0                                          # the pole: one height
    dsm = GeodeticDSM.from_array(h, 89.0, -180.0, 0.005, 1.0, interpolation="bilinear")
    bad = []
    for lon in (0.0, 37.3, -120.0):
        for alt in (2000.0, 600e3):
            t = pi.geodetic_to_ecef(90.0, lon, 50.0)
            s = pi.geodetic_to_ecef(90.0, lon, alt)
            f = pi.intersect(dsm, s, t - s, method="following")
            assert f.status[0] == DSMStatus.HIT and abs(f.height[0] - 50.0) < 1e-3
            r = pi.intersect(dsm, s, t - s, method="exact")
            if not (r.status[0] == DSMStatus.HIT and abs(r.height[0] - 50.0) < 1e-6 and r.nsteps[0] < 200):
                bad.append((lon, alt, int(r.status[0]), int(r.nsteps[0]), float(r.height[0])))
    assert not bad, bad
    # a pole row that varies with longitude (one point, many heights: the lookup's convention, the
    # point's own longitude, decides): each ray hits where the following does, within 1e-6 m
    h[-1] = rng.uniform(0.0, 100.0, 360)
    for interp in ("bilinear", "nearest"):
        dsm = GeodeticDSM.from_array(h, 89.0, -180.0, 0.005, 1.0, interpolation=interp)
        for lon in (0.0, 37.3, -120.0, 179.5):
            t = pi.geodetic_to_ecef(90.0, lon, 50.0)
            s = pi.geodetic_to_ecef(90.0, lon, 2000.0)
            f = pi.intersect(dsm, s, t - s, method="following")
            r = pi.intersect(dsm, s, t - s, method="exact")
            assert r.status[0] == DSMStatus.HIT and r.nsteps[0] < 200, (interp, lon, r.status[0], r.nsteps[0])
            assert abs(r.distance[0] - f.distance[0]) < 2e-6, (interp, lon, r.distance[0], f.distance[0])


def test_following_on_a_strongly_flattened_body():
    """Eq. 2 (Bowring's one step) is 116 m off at 4 km on a 13 km body with f = 0.3: the
    following stepped with it and hit a flat 2,000 m surface 11 m below it, or (a fuzz case)
    five rows outside the grid. Where eq. 2's error over the DSM's heights exceeds 1e-10 a
    the steps now use the exact conversion (shin-park-notes note 10); the hits are on the
    surface and agree with the exact mode's."""
    for f, s, l in ((0.3, [22251.634724514723, 17807.81377808193, -8832.59601152783],
                     [-0.6308988755117648, -0.7752594319274209, 0.030649993239211804]),
                    (0.6, [740.3193151731393, -9141.780527240719, 11223.99333860314],
                     [0.6886744838807429, 0.15863079236655286, -0.7075052840542974])):
        dsm = GeodeticDSM.from_array(np.full((19, 36), 2000.0), -90.0, 0.0, 10.0, 10.0, a=13000.0, f=f)
        fo = pi.intersect(dsm, s, l, method="following")
        ex = pi.intersect(dsm, s, l, method="exact")
        assert fo.status[0] == ex.status[0] == DSMStatus.HIT
        # the height the tests' own geodesy gives the hit point
        from references.geodesy import ecef_to_geodetic as ref

        assert abs(ref(fo.p, 13000.0, f)[2][0] - 2000.0) < 1e-6
        assert abs(fo.distance[0] - ex.distance[0]) < 2e-6


def test_following_does_not_hit_the_side_of_a_cell_facing_no_data():
    """The steps can pass over a no-data cell (a cell apart, they clip corners); the refinement
    then ended on the side of the next data cell, below its roof, entered from over no-data, and
    called it a hit (a fuzz case, 12.6 m below the roof; here 6 of 300 random rays over a
    building DSM with 15 % no-data cells, 22-27 m below). Such a ray reaches that side low over
    no-data: NO_DATA, as the exact mode says (note 12). Checked: no following hit is entered
    from over no-data (the ray 2e-6 m before it is over data or above H_max)."""
    rng = np.random.default_rng(7)
    n, d = 24, 1e-5
    changed = 0
    for _ in range(300):
        h = 10.0 + 30.0 * (rng.random((n, n)) < 0.3)
        h[rng.random((n, n)) < 0.15] = np.nan
        dsm = GeodeticDSM.from_array(h, 45.0, 7.0, -d, d, interpolation="nearest")
        lat, lon = 45.0 - rng.uniform(4, 20) * d, 7.0 + rng.uniform(4, 20) * d
        tgt = pi.geodetic_to_ecef(lat, lon, 10.0)
        up = tgt / np.linalg.norm(tgt)
        east = np.array([-np.sin(np.radians(7.0)), np.cos(np.radians(7.0)), 0.0])
        north = np.cross(up, east)
        az, el = rng.uniform(0, 2 * np.pi), rng.uniform(0.2, 1.2)
        l = -(np.cos(el) * (np.sin(az) * east + np.cos(az) * north) + np.sin(el) * up)
        s = tgt - 700e3 * l
        fo = pi.intersect(dsm, s, l, method="following")
        if fo.status[0] == DSMStatus.HIT:
            la, lo, hb = pi.ecef_to_geodetic(s + (fo.distance[0] - 2e-6) * l / np.linalg.norm(l))
            inside = -0.5 <= (la - 45.0) / -d <= n - 0.5 and -0.5 <= (lo - 7.0) / d <= n - 0.5
            assert not (inside and np.isnan(dsm.height(la, lo)) and hb <= dsm.hmax), "a hit entered from no-data"
        else:
            ex = pi.intersect(dsm, s, l, method="exact")
            changed += fo.status[0] == DSMStatus.NO_DATA == ex.status[0]
    assert changed >= 6


def test_following_steps_confirmed_near_a_pole():
    """Eq. 2's h = p / cos(phi) - N amplifies rounding near a pole (1.7e-3 m at 0.77 m from
    Mars's pole): a step it put at the surface was 1.2e-4 m above it by the exact conversion,
    and the hit came back there (a fuzz case of tests/fuzzing/geo.py). A step's "at or below"
    is now confirmed by the exact conversion; the hit lies on the surface, as the exact mode's."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from fuzzing.geo import dsm_heights

    spec = {"shape": (24, 19), "kind": "holes", "scale": 1.0, "base": -50.0, "seed": 1505585986,
            "nodata": -9999.0}
    a, f = 3396190.0, 1 / 169.894
    d = 8.435302429057608e-06
    dsm = GeodeticDSM.from_array(dsm_heights(spec), -89.99980598804413, -64.98559265879823, -d, d, a=a, f=f,
                                 nodata=-9999.0, interpolation="nearest")
    s = [0.3264698110470176, -0.6996536666458845, -3476150.484331621]
    l = [-6.46912308e-07, 1.38639520e-06, 1.0]
    fo = pi.intersect(dsm, s, l, method="following")
    ex = pi.intersect(dsm, s, l, method="exact")
    assert fo.status[0] == ex.status[0] == DSMStatus.HIT
    assert abs(fo.height[0] - fo.surface_height[0]) < 2e-6
    assert abs(fo.distance[0] - ex.distance[0]) < 2e-6


def test_following_brackets_a_crossing_that_eq2_stepped_over_near_a_pole():
    """The geodetic fuzz family (seed 7302): three nadir-ish rays 8.6 m from Mars's north pole over a
    0.5 m "tower" grid (heights 0 and 1 m) in a narrow wedge of longitude. Near the pole eq. 2 (the
    steps' conversion) is off by more than the steps there (the parallel's cells, and so D, are
    2.5e-6 m wide), so a step it called above the ground was already below it; the refinement
    bracketed after it and ray 2 came back 3.45e-6 m below flat ground (notes 9-10). Each ray's
    following hit must lie on the surface (tests' geodesy) and agree with the exact mode's first
    entry to the refinement's 1e-6 m."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from fuzzing import bulk
    from fuzzing.geo import make_dsm
    from references.geodesy import ecef_to_geodetic_rad

    case = bulk.gen_case(7302, 384, 5, bulk.MIX_GEO)
    dsm = make_dsm(case["dsm"])
    s = np.asarray(case["s"], dtype=float)
    for l in np.asarray(case["l"], dtype=float):
        fol = pi.intersect(dsm, s, l, method="following")
        ex = pi.intersect(dsm, s, l, method="exact")
        assert fol.status[0] == ex.status[0] == DSMStatus.HIT
        assert abs(fol.distance[0] - ex.distance[0]) <= 1e-6, fol.distance[0] - ex.distance[0]
        p = fol.p[0]
        _, _, _, h = ecef_to_geodetic_rad(p[:1], p[1:2], p[2:], dsm.a, dsm.f)
        assert abs(float(h[0]) - fol.surface_height[0]) <= 1e-6, (float(h[0]), fol.surface_height[0])
