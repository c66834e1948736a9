"""GeodeticDSM: construction, validation, the surface H(lat, lon), readers."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect import DSMError, GeodeticDSM


def small(interp="bilinear", **kw):
    h = np.arange(12, dtype=float).reshape(3, 4) * 10.0     # rows 0..2, cols 0..3
    return GeodeticDSM.from_array(h, 45.0, 10.0, 0.001, 0.002, interpolation=interp, **kw)


def test_grid_attributes_and_private_copy():
    h = np.ones((3, 4))
    dsm = GeodeticDSM.from_array(h, 45.0, 10.0, -0.001, 0.002)
    h[0, 0] = 99.0                                           # the caller's array is not shared
    assert dsm.heights[0, 0] == 1.0
    with pytest.raises(ValueError):
        dsm.heights[0, 0] = 5.0                              # read-only
    assert (dsm.nrows, dsm.ncols, dsm.dlat, dsm.dlon) == (3, 4, -0.001, 0.002)
    assert dsm.a == 6378137.0 and dsm.f == pytest.approx(1 / 298.257223563)
    np.testing.assert_allclose(dsm.lats, [45.0, 44.999, 44.998])
    assert dsm.hmax == 1.0 and dsm.hmin == 1.0


def test_bilinear_heights():
    dsm = small()
    lat0, lon0 = 45.0, 10.0
    # nodes
    assert dsm.height(lat0 + 0.001, lon0 + 0.004) == pytest.approx(60.0, abs=1e-9)
    # centre of the first cell: mean of 0, 10, 40, 50
    assert dsm.height(lat0 + 0.0005, lon0 + 0.001) == pytest.approx(25.0, abs=1e-6)
    # bilinear in (lat, lon): a quarter of the way in each direction
    expect = 0.75 * (0.75 * 0 + 0.25 * 10) + 0.25 * (0.75 * 40 + 0.25 * 50)
    assert dsm.height(lat0 + 0.00025, lon0 + 0.0005) == pytest.approx(expect, abs=1e-6)
    # outside the rectangle of centres: NaN
    assert np.isnan(dsm.height(lat0 - 1e-7, lon0 + 0.001))
    assert np.isnan(dsm.height(lat0 + 0.001, lon0 + 0.006 + 1e-7))


def test_nearest_heights_and_walls():
    dsm = small("nearest")
    lat0, lon0 = 45.0, 10.0
    assert dsm.height(lat0 + 0.0004, lon0 + 0.0009) == 0.0        # inside cell (0, 0)
    assert dsm.height(lat0 + 0.0006, lon0 + 0.0011) == 50.0       # inside cell (1, 1)
    # the cell-edge rectangle reaches half a cell beyond the centres
    assert dsm.height(lat0 - 0.0004, lon0 - 0.0009) == 0.0
    assert np.isnan(dsm.height(lat0 - 0.0006, lon0))
    # on a shared boundary the larger height (walls are solid): longitude 10.001 between cols 0 and 1
    assert dsm.height(lat0 + 0.0001, 10.001) == 10.0
    # a corner shared by four cells: the largest
    assert dsm.height(45.0005, 10.001) == 50.0


def test_nodata_and_geoid():
    h = np.array([[1.0, 2.0, -9999.0], [4.0, 5.0, 6.0]])
    dsm = GeodeticDSM.from_array(h, 0.0, 0.0, 1.0, 1.0, nodata=-9999.0, geoid=10.0)
    assert np.isnan(dsm.heights[0, 2]) and dsm.heights[1, 1] == 15.0
    assert np.isnan(dsm.height(0.5, 1.5))                   # needs the no-data node
    assert dsm.height(0.5, 0.5) == pytest.approx(13.0)      # (11 + 12 + 14 + 15) / 4
    n = np.full(h.shape, 2.0)
    dsm2 = GeodeticDSM.from_array(h, 0.0, 0.0, 1.0, 1.0, nodata=-9999.0, geoid=n)
    assert dsm2.heights[1, 1] == 7.0 and dsm2.hmax == 8.0 and dsm2.hmin == 3.0


def test_antimeridian_extent():
    h = np.arange(8, dtype=float).reshape(2, 4)
    dsm = GeodeticDSM.from_array(h, -1.0, 179.0, 1.0, 1.0)     # centres 179, 180, 181 (= -179), 182
    assert dsm.height(-1.0, -179.0) == pytest.approx(2.0)
    assert dsm.height(-1.0, 179.5) == pytest.approx(0.5)
    assert dsm.height(-0.5, -178.5) == pytest.approx(0.5 * (2.5 + 6.5))
    assert np.isnan(dsm.height(-1.0, 178.9))
    np.testing.assert_allclose(dsm.lons, [179.0, -180.0, -179.0, -178.0])


@pytest.mark.parametrize("kw, match", [
    (dict(heights=np.ones(4)), "heights must be 2-D"),
    (dict(heights=np.ones((1, 4))), "bilinear interpolation needs at least 2 x 2"),
    (dict(heights=np.array([[1.0, np.inf], [1, 1]])), r"heights\[0, 1\] is infinite"),
    (dict(heights=np.full((2, 2), np.nan)), "every cell is no-data"),
    (dict(heights=[["a", "b"], ["c", "d"]]), "heights: must be real numbers"),
    (dict(dlat=0.0), "dlat must be non-zero"),
    (dict(dlon=-1.0), "dlon must be positive"),
    (dict(dlon=np.nan), "dlon must be finite"),
    (dict(lat_first=89.5, dlat=1.0), r"outside \[-90, 90\]"),
    (dict(dlon=200.0), "exceeds 360"),
    (dict(a=0.0), "a .semi-major axis. must be in"),
    (dict(f=-0.1), "f .flattening. must be in"),
    (dict(interpolation="cubic"), "interpolation must be 'bilinear' or 'nearest'"),
    (dict(geoid=np.ones((3, 3))), "geoid must be a scalar or an array shaped like heights"),
    (dict(geoid=np.nan), "geoid has NaN"),
    (dict(nodata="x"), "nodata must be a number"),
    (dict(hmax=0.5), "hmax = 0.5 is below the largest height 1.0"),
])
def test_bad_arrays(kw, match):
    args = dict(heights=np.ones((2, 2)), lat_first=0.0, lon_first=0.0, dlat=1.0, dlon=1.0)
    args.update(kw)
    with pytest.raises(ValueError, match=match):
        GeodeticDSM.from_array(**args)


def test_constructor_is_not_public():
    with pytest.raises(TypeError, match="from_array"):
        GeodeticDSM()


def _sha(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_read_npz(tmp_path):
    h = np.array([[1.0, 2.0], [3.0, 4.0]])
    f = tmp_path / "d.npz"
    np.savez(f, heights=h, lat_first=10.0, lon_first=20.0, dlat=-0.5, dlon=0.5, interpolation="nearest")
    before = _sha(f)
    dsm = GeodeticDSM.read(f)
    assert dsm.interpolation == "nearest" and dsm.dlat == -0.5 and dsm.path == f
    assert dsm.height(9.5, 20.5) == 4.0
    assert _sha(f) == before
    bad = tmp_path / "bad.npz"
    np.savez(bad, heights=h)
    with pytest.raises(DSMError, match=r"bad.npz: missing arrays \['lat_first'"):
        GeodeticDSM.read(bad)
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    with pytest.raises(DSMError, match="junk.npz: not a .npz file"):
        GeodeticDSM.read(junk)
    with pytest.raises(FileNotFoundError, match="no such file"):
        GeodeticDSM.read(tmp_path / "missing.tif")


def test_read_geotiff_geographic(tmp_path):
    rasterio = pytest.importorskip("rasterio", reason="rasterio (extra 'geo') is not installed")
    from rasterio.transform import from_origin

    h = np.arange(20, dtype=np.float32).reshape(4, 5)
    h[0, 0] = -32768
    f = tmp_path / "geo.tif"
    with rasterio.open(f, "w", driver="GTiff", height=4, width=5, count=1, dtype="float32", crs="EPSG:4326",
                       transform=from_origin(7.0, 46.0, 0.01, 0.01), nodata=-32768) as dst:
        dst.write(h, 1)
    before = _sha(f)
    dsm = GeodeticDSM.read(f)
    assert _sha(f) == before
    assert dsm.lat_first == pytest.approx(45.995) and dsm.dlat == pytest.approx(-0.01)
    assert dsm.lon_first == pytest.approx(7.005) and dsm.dlon == pytest.approx(0.01)
    assert np.isnan(dsm.heights[0, 0]) and dsm.heights[2, 3] == 13.0
    assert dsm.height(45.975, 7.035) == pytest.approx(13.0)
    assert dsm.resampling is None and dsm.interpolation == "bilinear"


def test_read_geotiff_projected_is_warped(tmp_path):
    rasterio = pytest.importorskip("rasterio", reason="rasterio (extra 'geo') is not installed")
    pyproj = pytest.importorskip("pyproj", reason="pyproj (extra 'geo') is not installed")
    from rasterio.transform import from_origin

    # 1 m UTM 32N raster: ground 100 m, one 20 x 20 m building 130 m tall
    h = np.full((100, 100), 100.0, dtype=np.float32)
    h[40:60, 40:60] = 130.0
    f = tmp_path / "utm.tif"
    with rasterio.open(f, "w", driver="GTiff", height=100, width=100, count=1, dtype="float32",
                       crs="EPSG:32632", transform=from_origin(500000.0, 5000100.0, 1.0, 1.0)) as dst:
        dst.write(h, 1)
    dsm = GeodeticDSM.read(f)
    assert dsm.resampling == "nearest" and dsm.interpolation == "nearest"
    assert set(np.unique(dsm.heights[np.isfinite(dsm.heights)])) <= {100.0, 130.0}   # nearest: no new values
    to_geo = pyproj.Transformer.from_crs("EPSG:32632", "EPSG:4326", always_xy=True)
    lon, lat = to_geo.transform(500050.0, 5000050.0)          # the building's centre
    assert dsm.height(lat, lon) == 130.0
    lon, lat = to_geo.transform(500010.0, 5000090.0)
    assert dsm.height(lat, lon) == 100.0


def test_read_bad_raster(tmp_path):
    pytest.importorskip("rasterio", reason="rasterio (extra 'geo') is not installed")
    f = tmp_path / "x.tif"
    f.write_bytes(b"garbage")
    with pytest.raises(DSMError, match="x.tif: cannot be opened as a raster"):
        GeodeticDSM.read(f)


def test_dsm_status_table_matches_compiled_codes():
    from planet_intersect import _core
    from planet_intersect._status import RAY_STATUS, DSMStatus

    codes = list(_core.core_dsm_codes())
    assert codes == [DSMStatus.NO_DATA, DSMStatus.LEFT_DSM, DSMStatus.MISS, DSMStatus.NOT_CONVERGED,
                     DSMStatus.OSCILLATION, DSMStatus.STEP_LIMIT] == list(range(9, 15))
    assert not set(codes) & set(RAY_STATUS)                      # the DEM codes keep their numbers
    assert sorted(pi.DSM_RAY_STATUS) == [0, 3, 4, 5, 6] + codes


def test_geoid_from_a_second_raster(tmp_path):
    f = tmp_path / "geoid.npz"
    np.savez(f, heights=np.full((2, 3), 47.5), lat_first=0.0, lon_first=0.0, dlat=1.0, dlon=1.0)
    dsm = GeodeticDSM.from_array(np.ones((2, 3)), 0.0, 0.0, 1.0, 1.0, geoid=f)
    assert (dsm.heights == 48.5).all()
    with pytest.raises(DSMError, match="geoid raster .*grid differs"):
        GeodeticDSM.from_array(np.ones((2, 3)), 0.0, 0.0, 1.0, 2.0, geoid=f)
