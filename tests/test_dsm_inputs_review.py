"""A third independent review of how a GeodeticDSM is built from user input, and of
``outside="ellipsoid"`` (2026-12-05; docs/shin-park-notes.md note 20). Each test is one
of the review's findings, with the numbers it must now meet; the references are pyproj
(where a warped pixel lies) and the rasters' own pixels.
"""

from __future__ import annotations

import math
import os
import warnings

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect.dsm import DSMError

rasterio = pytest.importorskip("rasterio", reason="rasterio (the [geo] extra) reads GeoTIFFs")
pyproj = pytest.importorskip("pyproj", reason="pyproj places the warped pixels independently")
from rasterio.transform import from_origin  # noqa: E402

from conftest import write_geotiff  # noqa: E402


write = write_geotiff


def place(dsm_path, crs, x, y):
    """(lat, lon) of projected (x, y) by pyproj on the CRS's own geodetic CRS."""
    c = pyproj.CRS(crs)
    lon, lat = pyproj.Transformer.from_crs(c, c.geodetic_crs, always_xy=True).transform(x, y)
    return lat, lon


# ---- the warp's cells: the source's pixel size both ways, not square degrees

@pytest.mark.parametrize("crs, origin, lat_expected", [
    ("EPSG:3413", (-200000.0, -2000000.0), 72.0),       # polar stereographic, Greenland
    ("EPSG:32633", (500000.0, 5000000.0), 45.0),         # UTM 33N
])
def test_a_warped_raster_keeps_its_pixel_size_north_south_and_east_west(tmp_path, crs, origin, lat_expected):
    a = np.arange(150 * 150, dtype="float32").reshape(150, 150) % 97
    p = write(tmp_path / "dsm.tif", a, crs, from_origin(*origin, 2.0, 2.0))
    d = pi.GeodeticDSM.read(p)
    lat_c = d.lat_first + 0.5 * (d.shape[0] - 1) * d.dlat
    assert abs(lat_c - lat_expected) < 1.5
    geod = pyproj.Geod(ellps="WGS84")
    _, _, ns = geod.inv(10.0, lat_c, 10.0, lat_c + d.dlat)
    _, _, ew = geod.inv(10.0, lat_c, 10.0 + d.dlon, lat_c)
    # both within 5 % of the source's 2 m (rasterio's default gave 5.07 m x 1.60 m at 72 N)
    assert ns == pytest.approx(2.0, rel=0.05) and ew == pytest.approx(2.0, rel=0.05)
    # nearest: almost every source pixel survives (11,124 of 22,500 did before)
    assert len(np.unique(d.heights[np.isfinite(d.heights)])) == 97


def test_one_pixel_walls_of_a_utm_raster_survive_the_warp(tmp_path):
    a = np.zeros((200, 200), "float32")
    a[10::20, 20:180] = 30.0                       # nine east-west walls one pixel thick
    p = write(tmp_path / "walls.tif", a, "EPSG:32633", from_origin(500000.0, 7800000.0, 1.0, 1.0))  # ~70 N
    d = pi.GeodeticDSM.read(p)
    for k, row in enumerate(range(10, 200, 20)):
        lat, lon = place(p, "EPSG:32633", 500100.0, 7800000.0 - row - 0.5)
        assert d.height(lat, lon) == 30.0, f"wall {k} lost"


# ---- the ellipsoid: the caller's a, f must be the raster's body

def test_a_projected_earth_raster_is_not_taken_as_another_body_or_unit(tmp_path):
    p = write(tmp_path / "utm.tif", np.full((20, 20), 10.0, "float32"), "EPSG:32633",
              from_origin(500000.0, 5000000.0, 1.0, 1.0))
    with pytest.raises(DSMError, match="utm.tif: its CRS .* is an Earth datum, but a = 3396190"):
        pi.GeodeticDSM.read(p, a=3396190.0, f=1 / 169.894447223612)
    with pytest.raises(DSMError, match="Earth datum, but a = 6378.137"):
        pi.GeodeticDSM.read(p, a=6378.137)          # the Earth in km: 10 m would have been 10 km


def test_a_mars_equirectangular_dtm_is_warped_on_mars(tmp_path):
    crs = "IAU_2015:49910"                          # Mars (sphere) equirectangular
    try:
        pyproj.CRS(crs)
    except pyproj.exceptions.CRSError:
        pytest.skip("this PROJ has no IAU_2015 CRS database")
    a = (np.arange(40 * 30, dtype="float64").reshape(40, 30) * 7.0) - 3000.0
    x0, y0 = 1_000_000.0, 500_000.0
    p = write(tmp_path / "mars.tif", a, crs, from_origin(x0, y0, 200.0, 200.0))
    with pytest.raises(DSMError, match="not a = 6378137"):
        pi.GeodeticDSM.read(p)                       # WGS-84 asked (the default): refused, named
    d = pi.GeodeticDSM.read(p, a=3396190.0, f=0.0)
    assert d.resampling == "nearest"
    for i, j in ((3, 4), (20, 15), (36, 27)):
        lat, lon = place(p, crs, x0 + (j + 0.5) * 200.0, y0 - (i + 0.5) * 200.0)
        assert d.height(lat, lon) == a[i, j]


def test_a_crs_without_an_ellipsoid_is_named(tmp_path):
    wkt = 'LOCAL_CS["arbitrary",UNIT["metre",1],AXIS["Easting",EAST],AXIS["Northing",NORTH]]'
    p = write(tmp_path / "local.tif", np.ones((4, 4), "float32"), rasterio.crs.CRS.from_wkt(wkt),
              from_origin(0.0, 0.0, 1.0, 1.0))
    with pytest.raises(DSMError, match="local.tif") as e:
        pi.GeodeticDSM.read(p)
    assert len(str(e.value)) < 500                   # (2,334 characters of PROJJSON before)


# ---- no-data: masks, float32 tags, masked geoids

def test_float32_nodata_given_by_the_caller_matches(tmp_path):
    a = np.full((6, 8), 50.0, "float32")
    a[2:4, 2:5] = -999.9
    assert pi.GeodeticDSM.from_array(a, 10, 20, -0.1, 0.1, nodata=-999.9).hmin == 50.0
    p = write(tmp_path / "f32.tif", a, "EPSG:4326", from_origin(10, 50, 1e-3, 1e-3))
    d = pi.GeodeticDSM.read(p, nodata=-999.9)
    assert d.hmin == 50.0 and int(np.isnan(d.heights).sum()) == 6


def test_a_gdal_mask_band_is_no_data_not_zero(tmp_path):
    a = np.full((6, 8), 50.0, "float32")
    a[1:3, 2:5] = 0.0
    mask = np.full((6, 8), 255, "uint8")
    mask[1:3, 2:5] = 0
    with rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True):
        with rasterio.open(tmp_path / "m.tif", "w", driver="GTiff", width=8, height=6, count=1, dtype="float32",
                           crs="EPSG:4326", transform=from_origin(10, 50, 1e-3, 1e-3)) as d:
            d.write(a[None])
            d.write_mask(mask)
    d = pi.GeodeticDSM.read(tmp_path / "m.tif")
    assert np.array_equal(np.isnan(d.heights), mask == 0)
    assert d.hmin == 50.0


def test_a_masked_geoid_cell_is_refused_not_added():
    n = np.ma.masked_array(np.full((4, 5), -30.0))
    n.data[0, 0] = -9999.0
    n[0, 0] = np.ma.masked
    with pytest.raises(DSMError, match=r"geoid has NaN, Inf or no-data values .* row 0, column 0"):
        pi.GeodeticDSM.from_array(np.full((4, 5), 100.0), 10, 20, -0.1, 0.1, geoid=n)


# ---- what is not a number, and messages that name their argument

@pytest.mark.parametrize("heights", [np.full((4, 5), "12.5"), np.full((4, 5), True),
                                     np.full((4, 5), np.datetime64("2020-01-01")),
                                     np.full((4, 5), np.timedelta64(3, "s"))],
                         ids=["str", "bool", "datetime", "timedelta"])
def test_heights_that_are_not_real_numbers_are_refused(heights):
    with pytest.raises(DSMError, match="heights: must be real numbers"):
        pi.GeodeticDSM.from_array(heights, 10, 20, -0.1, 0.1)


@pytest.mark.parametrize("geoid, match", [
    (True, "geoid must be a number"), (np.full((4, 5), 1 + 2j), "geoid: must be real numbers"),
    (np.complex128(3), "geoid: must be real numbers"), ([["1"] * 5] * 4, "geoid: must be real numbers"),
])
def test_geoids_that_are_not_real_numbers_are_refused(geoid, match):
    with warnings.catch_warnings():
        warnings.simplefilter("error")               # (a ComplexWarning was all there was)
        with pytest.raises(DSMError, match=match):
            pi.GeodeticDSM.from_array(np.full((4, 5), 1.0), 10, 20, -0.1, 0.1, geoid=geoid)


def test_ragged_heights_and_odd_paths_are_named(tmp_path):
    with pytest.raises(DSMError, match="heights: not an array of numbers"):
        pi.GeodeticDSM.from_array([[1.0, 2.0], [3.0]], 10, 20, -0.1, 0.1)
    for bad in (None, 3, b"x.tif"):
        with pytest.raises(DSMError, match="path must be a file's path"):
            pi.GeodeticDSM.read(bad)
    np.savez(tmp_path / "s.npz", heights=np.ones((3, 3)), lat_first="10", lon_first=20.0, dlat=-0.1, dlon=0.1)
    with pytest.raises(DSMError, match="s.npz: lat_first must be a number"):
        pi.GeodeticDSM.read(tmp_path / "s.npz")


def test_a_complex_raster_and_a_truncated_raster_are_named(tmp_path):
    p = write(tmp_path / "c.tif", np.ones((4, 4), "complex64"), "EPSG:4326", from_origin(10, 50, 1e-3, 1e-3))
    with pytest.raises(DSMError, match="c.tif: band 1 holds complex64 values"):
        pi.GeodeticDSM.read(p)
    a = (np.arange(64 * 64, dtype="float32").reshape(64, 64) % 13)
    good = write(tmp_path / "big.tif", a, "EPSG:4326", from_origin(10, 50, 1e-3, 1e-3),
                 tiled=True, blockxsize=16, blockysize=16, compress="deflate")
    raw = good.read_bytes()
    named = 0
    for cut in range(200, len(raw), max(1, len(raw) // 40)):
        t = tmp_path / "cut.tif"
        t.write_bytes(raw[:cut])
        try:
            pi.GeodeticDSM.read(t)
        except DSMError as exc:
            assert "cut.tif" in str(exc)
            named += 1
        # (a cut that still reads is fine: the tiles it lost are GDAL's to report)
    assert named >= 30


def test_a_geoid_raster_on_another_grid_says_what_differs(tmp_path):
    h = np.full((10, 12), 100.0, "float32")
    g = np.full((10, 12), -30.0, "float32")
    dsm_p = write(tmp_path / "dsm.tif", h, "EPSG:4326", from_origin(10, 50, 1e-3, 1e-3))
    shifted = write(tmp_path / "geoid.tif", g, "EPSG:4326", from_origin(10.0005, 50, 1e-3, 1e-3))
    with pytest.raises(DSMError, match="geoid raster .*geoid.tif.*lon_first"):
        pi.GeodeticDSM.read(dsm_p, geoid=str(shifted))
    untagged = write(tmp_path / "g2.tif", np.where(np.eye(10, 12) > 0, -9999.0, -30.0).astype("float32"),
                     "EPSG:4326", from_origin(10, 50, 1e-3, 1e-3))
    with pytest.raises(DSMError, match="geoid: geoid file .*g2.tif"):
        pi.GeodeticDSM.read(dsm_p, geoid=str(untagged))


def test_a_multiband_file_read_without_band_warns(tmp_path):
    p = write(tmp_path / "two.tif", np.stack([np.full((4, 5), 1.0), np.full((4, 5), 2.0)]).astype("float32"),
              "EPSG:4326", from_origin(10, 50, 1e-3, 1e-3))
    with pytest.warns(UserWarning, match="has 2 bands; band 1 is read"):
        assert pi.GeodeticDSM.read(p).hmax == 1.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert pi.GeodeticDSM.read(p, band=2).hmax == 2.0


def test_reading_writes_nothing(tmp_path):
    p = write(tmp_path / "utm.tif", np.full((20, 20), 10.0, "float32"), "EPSG:32633",
              from_origin(500000.0, 5000000.0, 1.0, 1.0))
    before = (p.read_bytes(), os.stat(p).st_mtime_ns, sorted(os.listdir(tmp_path)))
    pi.GeodeticDSM.read(p)
    assert before == (p.read_bytes(), os.stat(p).st_mtime_ns, sorted(os.listdir(tmp_path)))


# ---- outside="ellipsoid": the ground a ray that left falls back to

def _below_zero_scene():
    dlat, dlon = 1 / 110900.0, 1 / 94900.0
    h = np.full((200, 200), -400.0)
    h[90:110, 90:110] = -370.0
    return pi.GeodeticDSM.from_array(h, 31.5, 35.4, dlat, dlon), dlat, dlon


def test_no_ellipsoid_fallback_through_the_earth_from_below_zero():
    dsm, dlat, dlon = _below_zero_scene()
    s = pi.geodetic_to_ecef(31.5 + 100 * dlat, 35.4 + 100 * dlon, -200.0)
    t = pi.geodetic_to_ecef(31.5 + 100 * dlat, 35.4 + 400 * dlon, -400.0)
    r = pi.intersect(dsm, s, t - s, method="exact", outside="ellipsoid")
    assert r.status[0] == pi.DSMStatus.LEFT_DSM
    # (it was the exit through the far side of the Earth, 7,073,766 m away)
    assert not r.on_ellipsoid[0] and np.isnan(r.ellipsoid_distance[0])


def test_no_ellipsoid_fallback_before_the_ray_left():
    dsm, dlat, dlon = _below_zero_scene()
    s = pi.geodetic_to_ecef(31.5 + 100 * dlat, 35.4 + 5 * dlon, 20.0)
    e, n, u = np.radians(35.4), np.radians(31.5), None
    east = np.array([-math.sin(e), math.cos(e), 0.0])
    up = np.array([math.cos(n) * math.cos(e), math.cos(n) * math.sin(e), math.sin(n)])
    l = math.cos(math.radians(10)) * east - math.sin(math.radians(10)) * up
    r = pi.intersect(dsm, s, l, method="exact", outside="ellipsoid")
    assert r.status[0] == pi.DSMStatus.HIT or not r.on_ellipsoid[0] or \
        r.ellipsoid_distance[0] >= r.event_distance[0]
    # the ray crosses h = 0 over the DSM, 400 m above its surface (column ~118): never its "ground"
    lat, lon = r.ellipsoid_lat[0], r.ellipsoid_lon[0]
    if r.on_ellipsoid[0]:
        assert not np.isfinite(dsm.height(lat, lon))


def test_the_ellipsoid_fallback_is_where_the_ray_enters_h0_after_it_left():
    # a control: a DSM above h = 0; the fallback is the ray's entry into the bare ellipsoid, by pyproj
    h = np.full((50, 50), 100.0)
    dsm = pi.GeodeticDSM.from_array(h, 10.0, 20.0, -1e-4, 1e-4)
    s = pi.geodetic_to_ecef(10.0, 19.99, 150.0)
    t = pi.geodetic_to_ecef(10.0, 19.98, 0.0)
    r = pi.intersect(dsm, s, t - s, method="exact", outside="ellipsoid")
    assert r.status[0] == pi.DSMStatus.LEFT_DSM and r.on_ellipsoid[0]
    to_geo = pyproj.Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
    lon, lat, hh = to_geo.transform(*r.ellipsoid_p[0])
    assert abs(hh) < 1e-6
    assert r.ellipsoid_distance[0] >= r.event_distance[0]
    assert np.linalg.norm(r.ellipsoid_p[0] - t) < 1e-3


def test_python_dash_m_runs_the_command_line():
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-m", "planet_intersect", "--help"], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0 and "import-shape-table" in out.stdout


# ---- the exact mode beside a no-data node on a small body (a third independent reference)

def test_a_ray_in_a_node_columns_plane_beside_no_data_is_never_a_hit():
    """A 9 x 9 bilinear grid cut from the review's 10 km body (f = 0.3), one no-data node in
    column 5, and a ray in the meridian plane of node column 4: the lookup can put its points on
    either side of the line. The rays 1e-9 off the plane are decided at once (east: NO_DATA
    where the ray enters the no-data cells, 15,842.7988 m by the review's reference; west:
    LEFT_DSM); the ray on the plane may end STEP_LIMIT (shin-park-notes note 20), never a hit
    and never another answer."""
    H = np.array([[1.1000000000000001e+00,1.5000000000000000e+00,1.0000000000000001e-01,1.3999999999999999e+00,1.1000000000000001e+00,5.0000000000000000e-01,5.0000000000000000e-01,1.3999999999999999e+00,
      1.2000000000000000e+00],
     [9.0000000000000002e-01,8.0000000000000004e-01,5.0000000000000000e-01,1.3000000000000000e+00,5.9999999999999998e-01,1.0000000000000001e-01,2.0000000000000001e-01,1.2000000000000000e+00,
      1.6000000000000001e+00],
     [1.8999999999999999e+00,6.9999999999999996e-01,1.3999999999999999e+00,1.0000000000000000e+00,1.0000000000000000e+00,4.0000000000000002e-01,0.0000000000000000e+00,1.7000000000000000e+00,
      1.3999999999999999e+00],
     [5.9999999999999998e-01,5.0000000000000000e-01,1.6000000000000001e+00,1.6000000000000001e+00,1.0000000000000001e-01,1.7000000000000000e+00,4.0000000000000002e-01,1.3000000000000000e+00,
      1.2000000000000000e+00],
     [1.3000000000000000e+00,1.8000000000000000e+00,1.5000000000000000e+00,1.2000000000000000e+00,1.7000000000000000e+00,2.0000000000000000e+00,1.6000000000000001e+00,1.1000000000000001e+00,
      6.9999999999999996e-01],
     [1.3000000000000000e+00,2.9999999999999999e-01,1.6000000000000001e+00,1.7000000000000000e+00,2.0000000000000000e+00,                   np.nan,5.9999999999999998e-01,5.9999999999999998e-01,
      5.9999999999999998e-01],
     [4.0000000000000002e-01,6.9999999999999996e-01,1.8000000000000000e+00,2.9999999999999999e-01,1.3000000000000000e+00,1.7183029614609342e+02,0.0000000000000000e+00,8.0000000000000004e-01,
      2.0000000000000001e-01],
     [2.0000000000000001e-01,1.8000000000000000e+00,1.8999999999999999e+00,8.0000000000000004e-01,2.9999999999999999e-01,1.6000000000000001e+00,2.9999999999999999e-01,1.3999999999999999e+00,
      6.9999999999999996e-01],
     [1.1000000000000001e+00,1.3999999999999999e+00,5.9999999999999998e-01,1.8000000000000000e+00,9.0000000000000002e-01,1.3000000000000000e+00,1.1000000000000001e+00,1.2000000000000000e+00,
      1.3999999999999999e+00]])
    lat0, lon0, dlat, dlon = 50.46784102032849, -18.379147056088247, -0.11347808309132745, 0.18009477154575038
    s = np.array([20481.043469960787, -6520.098433211989, -3354.9426774893955])
    l = np.array([-0.8271915435875159, 0.26333474147552766, 0.49639597515423095])
    dsm = pi.GeodeticDSM.from_array(H, lat0, lon0, dlat, dlon, a=10000.0, f=0.3, interpolation="bilinear")
    east = l + 1e-9 * np.cross(l, [0, 0, 1.0])
    west = l - 1e-9 * np.cross(l, [0, 0, 1.0])
    r = pi.intersect(dsm, np.array([s, s, s]), np.array([east, west, l]), method="exact", threads=1)
    assert r.status[0] == pi.DSMStatus.NO_DATA and abs(r.event_distance[0] - 15842.798824934) < 1e-6
    assert r.status[1] == pi.DSMStatus.LEFT_DSM
    assert r.nsteps[0] < 1000 and r.nsteps[1] < 1000
    assert r.status[2] in (pi.DSMStatus.NO_DATA, pi.DSMStatus.LEFT_DSM, pi.DSMStatus.STEP_LIMIT)


def test_every_variable_of_to_xarray_has_units_and_a_long_name():
    pytest.importorskip("xarray", reason="to_xarray needs xarray")
    dsm = pi.GeodeticDSM.from_array(np.full((20, 20), 5.0), 10.0, 20.0, -1e-4, 1e-4)
    s = pi.geodetic_to_ecef(10.0 - 1e-3, 20.0 + 1e-3, 500.0)
    t = pi.geodetic_to_ecef(10.0 - 1e-3, 20.0 + 1e-3, 0.0)
    ds = pi.intersect(dsm, s, t - s, method="exact").to_xarray()
    # (seven variables had no attributes and none had units: a review)
    for name, var in ds.data_vars.items():
        assert var.attrs.get("long_name"), name
        assert var.attrs.get("units"), name
    assert ds["lat"].attrs["units"] == "degree" and ds["incidence"].attrs["units"] == "degree"
    assert "semi-major axis" in ds["distance"].attrs["units"] and ds["status"].attrs["units"] == "1"
    assert ds["distance"].values[0] == pytest.approx(500.0 - 5.0, abs=1e-6)
    from planet_intersect.synthetic import rough_dem

    ds2 = pi.intersect(rough_dem(ppd=1), [10000.0, 0.0, 0.0], [-1.0, 0.0, 0.0]).to_xarray()
    for name, var in ds2.data_vars.items():
        assert var.attrs.get("units"), name
    assert ds2["emission"].attrs["units"] == "degree" and "km" in ds2["radius"].attrs["units"]


# ---- the command line: what a run was made from, and messages in its own words

def _npz_and_rays(tmp_path):
    h = np.full((40, 40), 0.0)
    h[18:22, 18:22] = 30.0
    dsm_path = tmp_path / "tower.npz"
    np.savez(dsm_path, heights=h, lat_first=0.0, lon_first=0.0, dlat=1e-5, dlon=1e-5, interpolation="nearest")
    lines = []
    for k in range(5):
        lat, lon = 0.0002 + 1e-5 * k, 0.0002
        s = np.array(pi.geodetic_to_ecef(lat, lon, 1000.0))
        t = np.array(pi.geodetic_to_ecef(lat, lon, 0.0))
        lines.append(" ".join(f"{x:.17g}" for x in (*s, *(t - s))))
    rays = tmp_path / "rays.txt"
    rays.write_text("\n".join(lines) + "\n")
    return dsm_path, rays


def test_a_runs_outputs_say_what_it_was_made_from(tmp_path, capsys):
    import json

    xr = pytest.importorskip("xarray", reason="run writes NetCDF through xarray")
    from planet_intersect.cli import main

    dsm_path, rays = _npz_and_rays(tmp_path)
    assert main(["run", str(dsm_path), str(rays), "--method", "exact", "--outside", "ellipsoid",
                 "--out", str(tmp_path / "o")]) == 0
    assert main(["run", str(dsm_path), str(rays), "--out", str(tmp_path / "o")]) == 0
    one, two = tmp_path / "o" / "run-001", tmp_path / "o" / "run-002"
    j1, j2 = (json.loads((d / "run.json").read_text()) for d in (one, two))
    assert (j1["method"], j1["outside"], j2["method"], j2["outside"]) == ("exact", "ellipsoid", "following", "none")
    assert j1["surface"] == str(dsm_path.resolve()) and j1["rays"] == str(rays.resolve())
    with xr.open_dataset(one / "results.nc", engine="h5netcdf") as ds:
        assert ds.attrs["method"] == "exact" and ds.attrs["outside"] == "ellipsoid"
        assert ds["lat"].attrs["units"] == "degree"
        assert np.all(ds["hit"].values)
    assert "run.json" in capsys.readouterr().out


def test_run_speaks_in_options(tmp_path, capsys):
    from planet_intersect.cli import main

    dsm_path, rays = _npz_and_rays(tmp_path)
    assert main(["run", str(dsm_path), str(rays), "--method", "stepping", "--out", str(tmp_path / "o")]) == 2
    assert "--method stepping: not a method for the geodetic DSM" in capsys.readouterr().err
    f = write(tmp_path / "void.tif", np.where(np.eye(6, 8) > 0, -9999.0, 10.0).astype("float32"), "EPSG:4326",
              from_origin(10, 50, 1e-3, 1e-3))
    assert main(["run", str(f), str(rays), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "pass --nodata -9999" in err and "nodata=" not in err
