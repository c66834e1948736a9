"""Faults of the geodetic DSM's Python side found by an adversarial review
(2026-12-02), each with a test that fails before its fix; the core's (the
following's step, eq. 2 on the axis, the grid's edge, the polar axis) are in
test_follow.py and test_geodetic.py (docs/shin-park-notes.md notes 8, 15 and
"Exact mode")."""

from __future__ import annotations

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect import DSMStatus, GeodeticDSM
from planet_intersect.geodetic import geodetic_to_ecef


def test_outside_ellipsoid_from_below_h0():
    """A focal point below h = 0 (a Dead Sea DSM at -430 m, an aircraft at -300 m): a LEFT_DSM
    ray has no bare-ellipsoid ground. It was the focal point itself (distance 0, height -300 m),
    then the ray's first forward crossing of h = 0, which from inside the ellipsoid is its exit
    through the far side of the Earth (a third review, 2026-12-05: 7,074 km away); the fallback
    is now only where a ray enters the ellipsoid from above (shin-park-notes note 20)."""
    n = 20
    d = 1e-4
    dsm = GeodeticDSM.from_array(np.full((n, n), -430.0), 31.5, 35.5, -d, d)
    s = geodetic_to_ecef(31.5 - 10 * d, 35.5 + 10 * d, -300.0)
    up = s / np.linalg.norm(s)
    east = np.array([-np.sin(np.radians(35.5)), np.cos(np.radians(35.5)), 0.0])
    res = pi.intersect(dsm, s, east - 0.05 * up, method="exact", outside="ellipsoid")
    assert res.status[0] == DSMStatus.LEFT_DSM
    assert not res.on_ellipsoid[0]
    assert np.isnan(res.ellipsoid_distance[0]) and np.isnan(res.ellipsoid_p[0]).all()


def test_geotiff_with_a_nan_nodata_tag(tmp_path):
    """GDAL's usual float nodata, NaN, is read as no data (it was refused: 'nodata must be
    finite, got nan')."""
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF reading needs rasterio")
    from rasterio.transform import from_origin

    h = np.full((6, 5), 12.0, dtype=np.float32)
    h[2, 3] = np.nan
    path = tmp_path / "nan_nodata.tif"
    with rasterio.open(path, "w", driver="GTiff", width=5, height=6, count=1, dtype="float32", crs="EPSG:4326",
                       transform=from_origin(10.0, 45.0, 1e-4, 1e-4), nodata=float("nan")) as dst:
        dst.write(h, 1)
    d = GeodeticDSM.read(path)
    assert np.isnan(d.heights[2, 3]) and np.isnan(d.heights).sum() == 1 and d.hmax == 12.0
    o = pi.OrthoImage.read(path)
    assert o.shape == (6, 5)


def test_error_messages_name_what_is_wrong(tmp_path):
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF reading needs rasterio")
    from rasterio.transform import from_origin

    tr = from_origin(10.0, 45.0, 1e-4, 1e-4)
    dsm_path, geoid_path = tmp_path / "dsm.tif", tmp_path / "geoid.tif"
    with rasterio.open(dsm_path, "w", driver="GTiff", width=4, height=4, count=1, dtype="float64",
                       crs="EPSG:4326", transform=tr) as dst:
        dst.write(np.full((4, 4), 5.0), 1)
    g = np.full((4, 4), 40.0)
    g[1, 2] = np.nan
    with rasterio.open(geoid_path, "w", driver="GTiff", width=4, height=4, count=1, dtype="float64",
                       crs="EPSG:4326", transform=tr) as dst:
        dst.write(g, 1)
    with pytest.raises(ValueError, match=r"geoid raster .*geoid.tif has NaN.*row 1, column 2"):
        GeodeticDSM.read(dsm_path, geoid=geoid_path)
    for band in ("1", 1.5, True):
        with pytest.raises(ValueError, match="band must be a whole number"):
            GeodeticDSM.read(dsm_path, band=band)
    assert pi.geodetic_to_ecef([], [], []).shape == (0, 3)
    d = GeodeticDSM.read(dsm_path)
    with pytest.raises(ValueError, match="lat, lon: expected numbers"):
        d.height("a", 0)


def test_large_lon_first_is_reduced_exactly():
    """lon_first beyond 360 is reduced modulo 360 exactly: the same grid as its reduced value
    (1e20 left no grid at all; 10 + 360e10 lost its edge columns)."""
    h = np.arange(12.0).reshape(3, 4)
    ref = GeodeticDSM.from_array(h, 45.0, 10.0, -1e-3, 1e-3)
    for lon_first in (10.0 + 360.0 * 1e10, 10.0 - 360.0 * 7, 370.0):
        d = GeodeticDSM.from_array(h, 45.0, lon_first, -1e-3, 1e-3)
        np.testing.assert_allclose(d.lons, ref.lons, rtol=0, atol=1e-9)
        np.testing.assert_allclose(d.height(ref.lats[:, None], ref.lons[None, :]), h, rtol=0, atol=1e-6)
    with pytest.raises(ValueError):
        GeodeticDSM.from_array(h, 45.0, float("inf"), -1e-3, 1e-3)


def _brute_first_hit(dsm, s, l, r0, r1, n=20001):
    """First r in [r0, r1] with h(r) <= H(r) by dense sampling then bisection (pure NumPy +
    the exact conversion; H from dsm.height): an independent check of the seam cell."""
    r = np.linspace(r0, r1, n)
    p = s[None, :] + r[:, None] * l[None, :]
    la, lo, h = pi.ecef_to_geodetic(p, dsm.a, dsm.f)
    below = h <= dsm.height(la, lo)
    k = int(np.argmax(below))
    assert below[k] and k > 0
    a, b = r[k - 1], r[k]
    for _ in range(60):
        m = 0.5 * (a + b)
        la, lo, h = pi.ecef_to_geodetic(s + m * l, dsm.a, dsm.f)
        if h <= dsm.height(la, lo):
            b = m
        else:
            a = m
    return b


def test_global_bilinear_grid_has_a_surface_across_its_seam():
    """A global bilinear grid (columns centred at 2.5 .. 357.5 E): between its last and first
    columns the surface interpolates them (it was NaN there, and all three methods said
    LEFT_DSM); exact and following hit there, at the first entry a brute-force search finds."""
    rng = np.random.default_rng(4)
    nr, nc = 36, 72
    h = rng.uniform(0.0, 3000.0, (nr, nc))
    dsm = GeodeticDSM.from_array(h, -87.5, 2.5, 5.0, 5.0)
    lat = -87.5 + 5.0 * 20.3
    for lon, w in ((0.0, 0.5), (359.0, 0.3), (-1.0, 0.3), (1.25, 0.75)):
        i = 20
        fv = 0.3
        left = (1 - fv) * h[i, nc - 1] + fv * h[i + 1, nc - 1]
        right = (1 - fv) * h[i, 0] + fv * h[i + 1, 0]
        assert dsm.height(lat, lon) == pytest.approx((1 - w) * left + w * right, abs=1e-6)
    assert not np.isnan(dsm.height(np.linspace(-87.5, 87.5, 50)[:, None], np.linspace(-180, 180, 97)[None, :])).any()
    nearest = dsm.with_interpolation("nearest")
    assert nearest.height(lat, 0.0) in (h[20, 0], h[20, nc - 1])
    # rays into the seam strip from orbit, nadir and oblique
    for lon_t, off, az in ((0.0, 0.0, 0.0), (0.5, 20.0, 90.0), (-1.0, 35.0, 270.0), (359.7, 10.0, 10.0)):
        tgt = geodetic_to_ecef(lat, lon_t, 0.0)
        up = tgt / np.linalg.norm(tgt)
        east = np.array([-np.sin(np.radians(lon_t)), np.cos(np.radians(lon_t)), 0.0])
        north = np.cross(up, east)
        look = -np.cos(np.radians(off)) * up + np.sin(np.radians(off)) * (np.cos(np.radians(az)) * north
                                                                          + np.sin(np.radians(az)) * east)
        s = tgt - 700e3 * look
        res = pi.intersect(dsm, s, look, method="exact")
        assert res.status[0] == DSMStatus.HIT, (lon_t, off, res.status[0])
        ref = _brute_first_hit(dsm, s, look, 690e3, 712e3)
        assert abs(res.distance[0] - ref) < 1e-3, (lon_t, res.distance[0] - ref)
        fol = pi.intersect(dsm, s, look, method="following")
        assert fol.status[0] == DSMStatus.HIT and fol.distance[0] >= res.distance[0] - 1e-6


# ---------------------------------------------------------------- 2026-12-03: the geodetic fuzz family and a review
def test_spacing_below_the_floor_is_refused():
    """A sub-normal spacing (0 in radians) crashed the core; 1e-12 degrees at 22 degrees put
    0.1 % errors into the heights at pixel centres. Spacings below 1e-8 degrees are refused,
    for the DSM and the ortho-image alike."""
    for kw in (dict(dlon=5e-324), dict(dlat=-1e-12), dict(dlon=1e-310)):
        args = dict(heights=np.zeros((3, 3)), lat_first=22.0, lon_first=0.0, dlat=-1e-3, dlon=1e-3) | kw
        name = next(iter(kw))
        with pytest.raises(pi.DSMError, match=rf"{name} = .* below 1e-08 degrees"):
            GeodeticDSM.from_array(**args)
    with pytest.raises(ValueError, match="dlat = .* below 1e-08"):
        pi.OrthoImage.from_array(np.zeros((3, 3)), 0.0, 0.0, -5e-324, 1e-3)
    GeodeticDSM.from_array(np.zeros((3, 3)), 22.0, 0.0, -1e-8, 1e-8)          # the floor itself is accepted


def test_semi_major_axis_range_of_a_dsm():
    """The search's tolerances are lengths (1e-6 along a ray): in light years a hit came 670 m
    late, in nanometres the search ran out of steps. A GeodeticDSM takes a in [1, 1e10]."""
    for a in (6378137.0 / 9.4607e15, 6378137.0e9):
        with pytest.raises(pi.DSMError, match=r"a \(semi-major axis\) = .* a in \[1, 1e\+10\]"):
            GeodeticDSM.from_array(np.zeros((2, 2)), 0.0, 0.0, -1e-3, 1e-3, a=a)
    dsm = GeodeticDSM.from_array(np.zeros((2, 2)), 0.0, 0.0, -1e-3, 1e-3, a=6378.137)     # kilometres
    assert dsm.a == 6378.137


def test_heights_beyond_the_centre_are_refused():
    """A DSM at -7e6 m was accepted and the following 'hit' the far side of the Earth with no
    surface height there."""
    with pytest.raises(pi.DSMError, match=r"heights\[0, 0\] = -7000000.0 is at or below minus the polar radius"):
        GeodeticDSM.from_array(np.full((3, 3), -7e6), 0.002, 0.0, -1e-3, 1e-3)


def test_focal_point_deep_inside_the_body_is_refused():
    """1e-200 m from the Moon's centre (where every latitude is as near as any) the following took
    the focal point for a point under the grid and reported a hit there (a fuzz case)."""
    h = np.random.default_rng(1).normal(120.0, 600.0, (10, 23))
    dsm = GeodeticDSM.from_array(h, 0.0742, 179.279, -0.016489, 0.032978, a=1737400.0, f=0.0,
                                 interpolation="nearest")
    for method in ("following", "exact", "iterative"):
        with pytest.raises(ValueError, match=r"s\[0\] = .* deeper than half the polar radius"):
            pi.intersect(dsm, [-1e-200, 0.0, 0.0], [-1.0, 0.0, 0.0], method=method)


def test_far_focal_points_are_reanchored():
    """From 1e12-1e13 m, rays aimed into a 1 m grid came back MISS or STEP_LIMIT (and the
    following hit 20 km underground from 1.7e13 m): the focal points are now moved along their
    rays to twice the body's radius and the distances counted from the caller's s."""
    h = np.zeros((40, 40))
    h[10:20, 10:20] = 30.0
    dsm = GeodeticDSM.from_array(h, 45.0, 7.0, -1e-5, 1.4e-5)
    tgt = geodetic_to_ecef(44.9998, 7.0003, 0.0)
    up = geodetic_to_ecef(44.9998, 7.0003, 1.0) - tgt
    rng = np.random.default_rng(0)
    d = up + rng.normal(0, 0.35, (30, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d = d[(d @ up) > 0.77]
    near = pi.intersect(dsm, tgt + 1e6 * d, -d, method="exact")
    assert (near.status == DSMStatus.HIT).all()
    for dist in (1e12, 1e13):
        for method in ("exact", "following"):
            res = pi.intersect(dsm, tgt + dist * d, -d, method=method)
            assert (res.status == DSMStatus.HIT).all(), (dist, method, res.status)
            # the same ground points (to the rounding of a line 1e13 m long: ulp ~2e-3 m)
            assert np.max(np.linalg.norm(res.p - near.p, axis=1)) < 0.05
            assert np.allclose(res.distance - dist, near.distance - 1e6, rtol=0, atol=0.05)
            assert np.allclose(res.height, res.surface_height, rtol=0, atol=1e-3)


def test_geoid_errors_and_overflow():
    with pytest.raises(FileNotFoundError, match="geoid file no-such-geoid.tif: no such file"):
        GeodeticDSM.from_array(np.zeros((2, 2)), 0.0, 0.0, -1e-3, 1e-3, geoid="no-such-geoid.tif")
    with pytest.raises(pi.DSMError, match="heights \\+ geoid overflows at row 0, column 0"):
        GeodeticDSM.from_array(np.full((2, 2), 1e308), 0.0, 0.0, -1e-3, 1e-3, geoid=1e308)


def test_with_interpolation_checks_its_argument():
    d1 = GeodeticDSM.from_array(np.full((1, 1), 50.0), 0.001, 0.001, -1e-3, 1e-3, interpolation="nearest")
    with pytest.raises(pi.DSMError, match="interpolation must be 'bilinear' or 'nearest', got \\['nearest'\\]"):
        d1.with_interpolation(["nearest"])
    with pytest.raises(pi.DSMError, match="bilinear interpolation needs at least 2 x 2 cells"):
        d1.with_interpolation("bilinear")


def test_npz_dsm_band_and_array_scalars(tmp_path):
    path = tmp_path / "d.npz"
    np.savez(path, heights=np.zeros((3, 3)), lat_first=0.0, lon_first=0.0, dlat=-1e-3, dlon=1e-3)
    with pytest.raises(pi.DSMError, match="band = 2: a .npz DSM"):
        GeodeticDSM.read(path, band=2)
    bad = tmp_path / "e.npz"
    np.savez(bad, heights=np.zeros((3, 3)), lat_first=np.zeros(3), lon_first=0.0, dlat=-1e-3, dlon=1e-3)
    with pytest.raises(pi.DSMError, match="lat_first must be a single number"):
        GeodeticDSM.read(bad)


def test_intersect_names_both_surfaces_and_the_latitude_arguments():
    with pytest.raises(TypeError, match="dem must be a planet_intersect.DEM or GeodeticDSM, got NoneType"):
        pi.intersect(None, [1e7, 0, 0], [-1, 0, 0], outside="ellipsoid")
    with pytest.raises(pi.DSMError, match="lat_first, dlat: the latitudes of the pixel centres"):
        GeodeticDSM.from_array(np.zeros((3, 3)), 95.0, 0.0, -1e-3, 1e-3)


def test_int16_geotiff_with_voids_and_no_nodata_tag(tmp_path):
    """-32768 in an int16 band without a nodata tag (SRTM's void) was read as 32.8 km pits."""
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF reading needs rasterio")
    from rasterio.transform import from_origin

    data = np.full((4, 4), 120, dtype=np.int16)
    data[1, 2] = -32768
    path = tmp_path / "voids.tif"
    with rasterio.open(path, "w", driver="GTiff", width=4, height=4, count=1, dtype="int16", crs="EPSG:4326",
                       transform=from_origin(7.0, 45.0, 1e-3, 1e-3)) as dst:
        dst.write(data, 1)
    with pytest.raises(pi.DSMError, match="int16 and holds -32768.*pass nodata=-32768"):
        GeodeticDSM.read(path)
    dsm = GeodeticDSM.read(path, nodata=-32768)
    assert np.isnan(dsm.heights[1, 2]) and dsm.hmin == 120.0
