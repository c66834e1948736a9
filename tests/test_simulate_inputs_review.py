"""An independent review of the simulation's ortho-image inputs (2026-12-05; simulation-notes
note 16). Each test is one of its findings, with the numbers it must now meet; the
references are the rasters' own pixels, placed by pyproj where a warp is involved.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect.synthetic_dsm import oblique_pushbroom

rasterio = pytest.importorskip("rasterio", reason="rasterio (the [geo] extra) reads GeoTIFFs")
pyproj = pytest.importorskip("pyproj", reason="pyproj places the warped pixels independently")
from rasterio.transform import from_origin  # noqa: E402

from conftest import write_geotiff  # noqa: E402


write = write_geotiff


def test_the_outer_half_pixel_of_an_ortho_image_has_its_edge_values(tmp_path):
    # an 8 x 8 ortho of 0.001 deg pixels with exactly the bounds of an 80 x 80 DSM of 0.0001 deg
    vals = (np.arange(64).reshape(8, 8) + 1).astype(np.uint8)
    o = pi.OrthoImage.read(write(tmp_path / "o.tif", vals, "EPSG:4326", from_origin(10.0, 50.0, 0.001, 0.001)))
    flat = pi.GeodeticDSM.from_array(np.full((80, 80), 50.0), 50.0 - 0.00005, 10.00005, -0.0001, 0.0001)
    sensor = pi.Pushbroom(*oblique_pushbroom(dict(heights=flat.heights, lat_first=flat.lat_first,
                                                  lon_first=flat.lon_first, dlat=flat.dlat, dlon=flat.dlon),
                                             zenith=0.0, azimuth=90.0))
    with warnings.catch_warnings():
        warnings.simplefilter("error")          # (a "hits without an ortho value" warning before)
        sim = pi.simulate_image(flat, o, sensor, occlusion=False, fill=0)
    assert sim.valid.all() and sim.ortho_value.all()          # 1,500 of 6,400 were fill before
    # every pixel's value is the bilinear of the ortho at its hit, clamped to the edge pixels
    # beyond the outer centres: recomputed here from the pixel grid alone
    u = np.clip((49.9995 - sim.lat) / 0.001, 0, 7)
    v = np.clip((sim.lon - 10.0005) / 0.001, 0, 7)
    i, j = np.minimum(np.floor(u).astype(int), 6), np.minimum(np.floor(v).astype(int), 6)
    fu, fv = u - i, v - j
    f = vals.astype(float)
    want = ((1 - fu) * ((1 - fv) * f[i, j] + fv * f[i, j + 1]) + fu * ((1 - fv) * f[i + 1, j] + fv * f[i + 1, j + 1]))
    assert np.abs(sim.image - want).max() < 1e-4
    corner = (sim.lat > 49.9995) & (sim.lon < 10.0005)     # the north-west corner's quarter pixel
    assert corner.any() and np.all(sim.image[corner] == 1.0)


def test_a_no_data_neighbour_of_no_weight_is_not_read():
    v = np.arange(30.0).reshape(5, 6)
    v[2, 3] = np.nan
    o = pi.OrthoImage.from_array(v, 10.0, 20.0, -0.001, 0.001)
    lat, lon = o.centres()
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    # a hit within rounding of a valid centre next to the no-data pixel (3e-10 pixel off)
    got = o.sample(la + 3e-13, lo - 3e-13)
    assert np.array_equal(np.isnan(got), np.isnan(v))      # 1 NaN, not 3-9
    np.testing.assert_allclose(got[~np.isnan(v)], v[~np.isnan(v)], rtol=0, atol=1e-8)   # (3e-10 px x 6 a row)


def test_mask_and_alpha_bands_are_no_data_not_brightness(tmp_path):
    a = np.full((6, 8), 100.0, "float32")
    mask = np.full((6, 8), 255, "uint8")
    mask[2:4, 3:6] = 0
    with rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True):
        with rasterio.open(tmp_path / "m.tif", "w", driver="GTiff", width=8, height=6, count=1, dtype="float32",
                           crs="EPSG:4326", transform=from_origin(10, 50, 1e-3, 1e-3)) as d:
            d.write(a[None])
            d.write_mask(mask)
    o = pi.OrthoImage.read(tmp_path / "m.tif")
    assert np.array_equal(np.isnan(o.values), mask == 0)        # (0.0 there before)
    rgba = np.zeros((4, 6, 8), "uint8")
    rgba[:3] = 163
    rgba[3] = 255
    rgba[3, 1, 1] = 0
    write(tmp_path / "rgba.tif", rgba, "EPSG:4326", from_origin(10, 50, 1e-3, 1e-3), photometric="RGB", alpha="YES")
    o = pi.OrthoImage.read(tmp_path / "rgba.tif")
    assert o.bands == 3                                          # (4 brightness bands before)
    assert np.isnan(o.values[1, 1]).all() and (o.values[0, 0] == 163).all()


def test_float32_nodata_given_by_the_caller_matches(tmp_path):
    a = np.full((6, 8), 50.0, "float32")
    a[2, 2:5] = -999.9
    assert np.isnan(pi.OrthoImage.from_array(a, 10, 20, -0.1, 0.1, nodata=-999.9).values).sum() == 3
    p = write(tmp_path / "f.tif", a, "EPSG:4326", from_origin(10, 50, 1e-3, 1e-3))
    assert np.isnan(pi.OrthoImage.read(p, nodata=-999.9).values).sum() == 3
    u = write(tmp_path / "u.tif", np.where(np.arange(400).reshape(20, 20) % 7 == 0, -999.9, 50.0).astype("float32"),
              "EPSG:32633", from_origin(500000.0, 5000000.0, 1.0, 1.0))
    vals = pi.OrthoImage.read(u, nodata=-999.9).values
    assert np.nanmin(vals) >= 0.0                               # (-997.24 blended in before)


@pytest.mark.parametrize("reader", ["ortho", "dsm"])
def test_a_web_mercator_raster_keeps_its_ground_pixel_size(tmp_path, reader):
    # EPSG:3857 pixels of 10 units at 50 N are 6.43 m on the ground (pyproj's scale factors)
    x0, y0 = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:3857", always_xy=True).transform(10.0, 50.0)
    a = (np.arange(60 * 60) % 11).reshape(60, 60).astype("float32") + 1
    p = write(tmp_path / "m.tif", a, "EPSG:3857", from_origin(x0, y0, 10.0, 10.0))
    g = pi.OrthoImage.read(p) if reader == "ortho" else pi.GeodeticDSM.read(p)
    lat_c = g.lat_first + 0.5 * (g.shape[0] - 1) * g.dlat
    geod = pyproj.Geod(ellps="WGS84")
    ns = geod.inv(10.0, lat_c, 10.0, lat_c + g.dlat)[2]
    ew = geod.inv(10.0, lat_c, 10.0 + g.dlon, lat_c)[2]
    k = pyproj.Proj("EPSG:3857").get_factors(10.0, lat_c).parallel_scale
    assert ns == pytest.approx(10.0 / k, rel=0.03) and ew == pytest.approx(10.0 / k, rel=0.03)
    assert g.shape[0] >= 58                                     # (39 x 39 from 60 x 60 before)


def test_more_than_360_degrees_of_columns_is_refused():
    with pytest.raises(ValueError, match="ncols \\* dlon = 500.0 degrees exceeds 360"):
        pi.OrthoImage.from_array([[0, 1, 2, 3, 4]] * 2, 0, 0, -1, 100)


def test_odd_ortho_inputs_are_named(tmp_path):
    with pytest.raises(TypeError, match="path must be a file's path"):
        pi.OrthoImage.read(5)
    p = write(tmp_path / "c.tif", np.ones((4, 4), "complex64"), "EPSG:4326", from_origin(10, 50, 1e-3, 1e-3))
    with pytest.raises(ValueError, match="c.tif: holds complex64 values"):
        pi.OrthoImage.read(p)
    np.savez(tmp_path / "s.npz", values=np.ones((3, 3)), lat_first="1", lon_first=2.0, dlat=-0.1, dlon=0.1)
    with pytest.raises(ValueError, match="s.npz: lat_first must be a single number"):
        pi.OrthoImage.read(tmp_path / "s.npz")
    np.savez(tmp_path / "a.npz", values=np.ones((3, 3)), lat_first=np.ones(2), lon_first=2.0, dlat=-0.1, dlon=0.1)
    with pytest.raises(ValueError, match="a.npz: lat_first must be a single number"):
        pi.OrthoImage.read(tmp_path / "a.npz")
    o = pi.OrthoImage.from_array(np.ones((3, 3)), 10, 20, -0.1, 0.1)
    with pytest.raises(TypeError, match="lat: must be real numbers"):
        o.sample("10", "20")
    with pytest.raises(ValueError, match="lat and lon: shapes \\(3,\\) and \\(2,\\) do not broadcast"):
        o.sample([10.0, 9.9, 9.8], [20.0, 20.1])


def test_fill_true_is_refused():
    dsm = pi.GeodeticDSM.from_array(np.zeros((10, 10)), 0.0, 0.0, 1e-4, 1e-4)
    o = pi.OrthoImage.from_array(np.ones((10, 10)), 0.0, 0.0, 1e-4, 1e-4)
    sensor = pi.Pushbroom(*oblique_pushbroom(dict(heights=dsm.heights, lat_first=0.0, lon_first=0.0, dlat=1e-4,
                                                  dlon=1e-4), zenith=0.0, azimuth=90.0))
    with pytest.raises(ValueError, match="fill must be a number"):
        pi.simulate_image(dsm, o, sensor, fill=True)


def test_an_ortho_image_on_another_body_is_refused(tmp_path):
    mars = pyproj.CRS.from_proj4("+proj=longlat +R=3396190 +no_defs")
    p = write(tmp_path / "mars.tif", np.full((10, 10), 7, "uint8"), rasterio.crs.CRS.from_wkt(mars.to_wkt()),
              from_origin(10.0, 50.0, 1e-3, 1e-3))
    o = pi.OrthoImage.read(p)
    assert o.semi_major == pytest.approx(3396190.0)
    dsm = pi.GeodeticDSM.from_array(np.zeros((10, 10)), 49.9995, 10.0005, -1e-3, 1e-3)
    sensor = pi.Pushbroom(*oblique_pushbroom(dict(heights=dsm.heights, lat_first=dsm.lat_first,
                                                  lon_first=dsm.lon_first, dlat=dsm.dlat, dlon=dsm.dlon),
                                             zenith=0.0, azimuth=90.0))
    with pytest.raises(ValueError, match="ortho: its file .*mars.tif is on a body of semi-major axis 3396190"):
        pi.simulate_image(dsm, o, sensor, occlusion=False)
    # the same ortho on a Mars DSM (in km: lat/lon do not care for the unit) is fine
    mdsm = pi.GeodeticDSM.from_array(np.zeros((10, 10)), 49.9995, 10.0005, -1e-3, 1e-3, a=3396.19, f=0.0)
    msensor = pi.Pushbroom(*oblique_pushbroom(dict(heights=mdsm.heights, lat_first=mdsm.lat_first,
                                                   lon_first=mdsm.lon_first, dlat=mdsm.dlat, dlon=mdsm.dlon,
                                                   a=mdsm.a, f=mdsm.f), zenith=0.0, azimuth=90.0))
    sim = pi.simulate_image(mdsm, o, msensor, occlusion=False)
    assert np.all(sim.image[sim.ortho_value] == 7.0)


def test_resampling_nearest_keeps_a_one_pixel_pattern(tmp_path):
    # a one-pixel checkerboard of 50/150 in UTM: bilinear (the default) averages it toward 100 in
    # the warp, "nearest" keeps every value one of the source's, right at the source's centres
    a = np.where((np.add.outer(np.arange(60), np.arange(60)) % 2) == 0, 50.0, 150.0).astype("float32")
    x0, y0 = 500000.0, 5000000.0
    p = write(tmp_path / "chk.tif", a, "EPSG:32632", from_origin(x0, y0, 1.0, 1.0))
    near = pi.OrthoImage.read(p, resampling="nearest")
    smooth = pi.OrthoImage.read(p)
    assert near.resampling == "nearest" and smooth.resampling == "bilinear"
    assert set(np.unique(near.values[np.isfinite(near.values)])) == {50.0, 150.0}
    to_geo = pyproj.Transformer.from_crs("EPSG:32632", "EPSG:4326", always_xy=True)
    i, j = np.meshgrid(np.arange(5, 55), np.arange(5, 55), indexing="ij")
    lon, lat = to_geo.transform(x0 + j + 0.5, y0 - i - 0.5)
    uu, vv = near.grid_coords(lat, lon)
    got = near.values[np.rint(uu).astype(int), np.rint(vv).astype(int)]
    assert np.mean(got == a[i, j]) >= 0.9
    with pytest.raises(ValueError, match="resampling must be 'bilinear' or 'nearest'"):
        pi.OrthoImage.read(p, resampling="cubic")
