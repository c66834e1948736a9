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
    ray's ellipsoid point is the ray's first forward crossing of h = 0 (from inside the ellipsoid:
    where it leaves it); it was the focal point itself (distance 0, height -300 m)."""
    n = 20
    d = 1e-4
    dsm = GeodeticDSM.from_array(np.full((n, n), -430.0), 31.5, 35.5, -d, d)
    s = geodetic_to_ecef(31.5 - 10 * d, 35.5 + 10 * d, -300.0)
    up = s / np.linalg.norm(s)
    east = np.array([-np.sin(np.radians(35.5)), np.cos(np.radians(35.5)), 0.0])
    res = pi.intersect(dsm, s, east - 0.05 * up, method="exact", outside="ellipsoid")
    assert res.status[0] == DSMStatus.LEFT_DSM
    assert res.on_ellipsoid[0] and res.ellipsoid_distance[0] > 1e5
    _, _, h = pi.ecef_to_geodetic(res.ellipsoid_p[0])
    assert abs(h) < 1e-3
    np.testing.assert_allclose(res.ellipsoid_p[0], s + res.ellipsoid_distance[0] * (east - 0.05 * up)
                               / np.linalg.norm(east - 0.05 * up), rtol=0, atol=1e-6)


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
