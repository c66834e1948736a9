"""Faults a newcomer's walk-through of the geodetic DSM reader and `run` found (2026-12-04).

Each test builds its raster here and checks the answer against geometry of its own
(pyproj for the projection, the roof and ground heights it wrote), not against the
reader's code.
"""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect import DSMError, GeodeticDSM
from planet_intersect.cli import main

rasterio = pytest.importorskip("rasterio", reason="rasterio (extra 'geo') is not installed")
pyproj = pytest.importorskip("pyproj", reason="pyproj (extra 'geo') is not installed")
from rasterio.transform import from_origin  # noqa: E402


def _utm_city(path, crs, x0, y0, n=120, ground=150.0, roof=200.0, dtype="float32", nodata=None, count=1):
    """An n x n raster of 1 m cells in ``crs`` with its NW corner at (x0, y0): ground at ``ground``,
    a 30 x 30 m building of ``roof`` in the middle. Returns the building centre's (x, y)."""
    h = np.full((n, n), ground, dtype=dtype)
    h[n // 2 - 15:n // 2 + 15, n // 2 - 15:n // 2 + 15] = roof
    with rasterio.open(path, "w", driver="GTiff", height=n, width=n, count=count, dtype=dtype, crs=crs,
                       transform=from_origin(x0, y0, 1.0, 1.0), nodata=nodata) as dst:
        for b in range(1, count + 1):
            dst.write(h, b)
    return x0 + n / 2, y0 - n / 2


def _nadir_height(dsm, lat, lon, method="exact"):
    s = np.array(pi.geodetic_to_ecef(lat, lon, 600e3))
    g = np.array(pi.geodetic_to_ecef(lat, lon, 0.0))
    r = pi.intersect(dsm, s, g - s, method=method)
    return int(r.status[0]), float(r.height[0]), float(r.lon[0])


@pytest.mark.parametrize("crs, x0", [("EPSG:32760", 821039.0), ("EPSG:32701", 178840.0)])
def test_utm_raster_across_the_antimeridian_is_read_whole(tmp_path, crs, x0):
    # zone 60 S east of 180 E and zone 1 S west of it: rasterio's EPSG:4326 grid for these had 0 rows
    # (CPLE_AppDefinedError "Invalid dataset dimensions" came out of GeodeticDSM.read and of `run`)
    f = tmp_path / "cross.tif"
    xc, yc = _utm_city(f, crs, x0, 8228895.0)
    to_geo = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    lon_w, _ = to_geo.transform(x0, yc)
    lon_e, _ = to_geo.transform(x0 + 120.0, yc)
    assert lon_w > 0 > lon_e                                    # the raster does cross 180 degrees
    dsm = GeodeticDSM.read(f)
    assert dsm.resampling == "nearest" and dsm.interpolation == "nearest"
    assert dsm.ncols * dsm.dlon < 0.01                          # ~120 m of longitude, not 360 degrees
    assert dsm.lon_first < 180.0 < dsm.lon_first + dsm.ncols * dsm.dlon
    lon, lat = to_geo.transform(xc, yc)                          # the building's centre
    assert dsm.height(lat, lon) == 200.0
    lon_g, lat_g = to_geo.transform(x0 + 10.0, yc)               # ground 10 m inside the west edge
    assert dsm.height(lat_g, lon_g) == 150.0
    status, h, hit_lon = _nadir_height(dsm, lat, lon)
    assert status == 0 and abs(h - 200.0) < 1e-6 and abs(hit_lon - lon) < 1e-9


def test_ortho_image_across_the_antimeridian_is_read(tmp_path):
    f = tmp_path / "ortho.tif"
    _utm_city(f, "EPSG:32760", 821039.0, 8228895.0, dtype="uint8", ground=50, roof=250, count=3)
    o = pi.OrthoImage.read(f)
    assert o.values.shape[2] == 3 and o.values.shape[1] * o.dlon < 0.01


def test_compound_crs_with_a_geoid_height_warns_unless_geoid_is_given(tmp_path):
    f = tmp_path / "navd88.tif"
    _utm_city(f, "EPSG:32614+5703", 500000.0, 4300000.0)        # UTM 14N + NAVD88 height
    with pytest.warns(UserWarning, match=r"NAVD88 height.*geoid="):
        dsm = GeodeticDSM.read(f)
    assert (dsm.hmin, dsm.hmax) == (150.0, 200.0)               # read as given, and said
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        dsm = GeodeticDSM.read(f, geoid=-25.0)
    assert (dsm.hmin, dsm.hmax) == (125.0, 175.0)


def test_compound_crs_in_us_feet_is_converted_to_metres(tmp_path):
    f = tmp_path / "feet.tif"
    _utm_city(f, "EPSG:32614+6360", 500000.0, 4300000.0, ground=500.0, roof=600.0)   # NAVD88 height (ftUS)
    with pytest.warns(UserWarning, match="NAVD88"):
        dsm = GeodeticDSM.read(f)
    ft = 1200.0 / 3937.0                                         # the US survey foot in metres
    assert dsm.hmin == pytest.approx(500.0 * ft, rel=1e-12) and dsm.hmax == pytest.approx(600.0 * ft, rel=1e-12)


def test_projected_crs_in_feet_warns_that_heights_are_taken_as_metres(tmp_path):
    f = tmp_path / "stateplane.tif"
    _utm_city(f, "EPSG:2277", 2300000.0, 10100000.0)             # Texas Central, US feet
    with pytest.warns(UserWarning, match="US survey foot.*read as metres"):
        GeodeticDSM.read(f)


@pytest.mark.parametrize("void", [-9999.0, -32767.0, -3.0e38])
def test_untagged_usual_void_is_refused_until_nodata_says(tmp_path, void):
    f = tmp_path / "untagged.tif"
    h = np.full((8, 8), 120.0, dtype="float32")
    h[2:4, 2:4] = void
    with rasterio.open(f, "w", driver="GTiff", height=8, width=8, count=1, dtype="float32", crs="EPSG:4326",
                       transform=from_origin(10.0, 50.0, 1e-5, 1e-5)) as dst:
        dst.write(h, 1)
    with pytest.raises(DSMError, match=re.escape(f"untagged.tif: band 1 holds {float(np.float32(void)):g}, a usual "
                                                 f"no-data value, but has no nodata tag")):
        GeodeticDSM.read(f)
    dsm = GeodeticDSM.read(f, nodata=float(np.float32(void)))
    assert np.isnan(dsm.heights[2:4, 2:4]).all() and dsm.hmin == 120.0


def test_nodata_nan_is_accepted_and_replaces_the_files_tag(tmp_path):
    f = tmp_path / "tagged.tif"
    h = np.full((6, 6), 80.0, dtype="float32")
    h[1, 1] = -9999.0
    h[2, 2] = np.nan
    with rasterio.open(f, "w", driver="GTiff", height=6, width=6, count=1, dtype="float32", crs="EPSG:4326",
                       transform=from_origin(10.0, 50.0, 1e-5, 1e-5), nodata=-9999.0) as dst:
        dst.write(h, 1)
    d = GeodeticDSM.read(f)                                      # the tag: both cells no data
    assert np.isnan(d.heights[1, 1]) and np.isnan(d.heights[2, 2])
    # nodata=nan replaces the tag: only NaN marks no data (-9999 is then a height, not refused
    # because the file's own tag is not "untagged")
    d = GeodeticDSM.read(f, nodata=np.nan)
    assert d.heights[1, 1] == -9999.0 and np.isnan(d.heights[2, 2])
    d = GeodeticDSM.from_array(np.array([[1.0, 2.0], [np.nan, 3.0]]), 10.0, 10.0, -1e-5, 1e-5, nodata=np.nan)
    assert d.nodata is None and d.hmin == 1.0


def test_geoid_raster_on_the_dsms_utm_grid_is_warped_with_it(tmp_path):
    # refused before: the warp adds no-data corners to both, and the geoid was needed at every cell
    f, g = tmp_path / "dsm.tif", tmp_path / "geoid.tif"
    _utm_city(f, "EPSG:32614", 250000.0, 4300000.0)           # 2.9 deg west of the zone's meridian: rotated
    with rasterio.open(g, "w", driver="GTiff", height=120, width=120, count=1, dtype="float64",
                       crs="EPSG:32614", transform=from_origin(250000.0, 4300000.0, 1.0, 1.0)) as dst:
        dst.write(np.full((120, 120), -25.0), 1)
    dsm = GeodeticDSM.read(f, geoid=g)
    assert np.isnan(dsm.heights).any()                           # the warp's corners
    assert (dsm.hmin, dsm.hmax) == (125.0, 175.0)
    with pytest.raises(DSMError, match="where there are heights"):
        GeodeticDSM.from_array(np.full((3, 3), 10.0), 10.0, 10.0, -1e-5, 1e-5, geoid=np.full((3, 3), np.nan))


def test_geographic_crs_on_an_earth_sized_sphere_warns(tmp_path):
    f = tmp_path / "sphere.tif"
    with rasterio.open(f, "w", driver="GTiff", height=4, width=4, count=1, dtype="float32",
                       crs="+proj=longlat +R=6371000 +no_defs", transform=from_origin(10.0, 50.0, 1e-4, 1e-4)) as dst:
        dst.write(np.full((4, 4), 30.0, dtype="float32"), 1)
    with pytest.warns(UserWarning, match="on a sphere of radius 6371000 m"):
        dsm = GeodeticDSM.read(f)
    assert dsm.lat_first == pytest.approx(50.0 - 0.5e-4, abs=1e-12)      # read as it is


def test_junk_npz_says_what_it_is_not(tmp_path):
    f = tmp_path / "junk.npz"
    f.write_bytes(b"not a zip at all")
    with pytest.raises(DSMError, match=r"junk.npz: not a .npz file \(a .npz is a zip archive"):
        GeodeticDSM.read(f)


def test_a_directory_is_not_a_dsm(tmp_path):
    with pytest.raises(DSMError, match="is a directory"):
        GeodeticDSM.read(tmp_path)
    with pytest.raises(ValueError, match="is a directory"):
        pi.OrthoImage.read(tmp_path)


def test_intersect_names_itself_for_an_unknown_keyword():
    dsm = GeodeticDSM.from_array(np.full((3, 3), 10.0), 10.0, 10.0, -1e-5, 1e-5)
    with pytest.raises(TypeError, match=r"^intersect: unexpected keyword argument\(s\) \['outsde'\]"):
        pi.intersect(dsm, [7e6, 0, 0], [-1, 0, 0], outsde="ellipsoid")


# ------------------------------------------------------------------------------------------- CLI
def _rays_file(path, pts):
    with open(path, "w") as fh:
        for s, l in pts:
            fh.write(" ".join(repr(float(x)) for x in (*s, *l)) + "\n")


def _city_rays(lat, lon, n=6):
    """n nadir rays from 600 km and one horizontal ray from 60 m towards the east."""
    out = []
    for k in range(n):
        la, lo = lat + (k - n / 2) * 2e-5, lon
        s = np.array(pi.geodetic_to_ecef(la, lo, 600e3))
        out.append((s, np.array(pi.geodetic_to_ecef(la, lo, 0.0)) - s))
    return out


def test_cli_run_on_a_dsm_refuses_dem_options_and_counts_every_status(tmp_path, capsys):
    f = tmp_path / "utm.tif"
    xc, yc = _utm_city(f, "EPSG:32614", 500000.0, 4300000.0)
    lon, lat = pyproj.Transformer.from_crs("EPSG:32614", "EPSG:4326", always_xy=True).transform(xc, yc)
    rays = tmp_path / "rays.txt"
    _rays_file(rays, _city_rays(lat, lon))
    assert main(["run", str(f), str(rays), "--step-mode", "0", "--out", str(tmp_path / "o")]) == 2
    assert "--step-mode: for a planetary DEM only" in capsys.readouterr().err
    assert main(["run", str(f), str(rays), "--method", "exact", "--geoid", "-25", "--out", str(tmp_path / "o")]) == 0
    captured = capsys.readouterr()
    out = captured.out
    assert "6 rays (exact over the DSM" in out and "6 hit;" in out
    assert "matmul" not in captured.err                       # rasterio's own deprecation: no note
    table = np.genfromtxt(tmp_path / "o" / "run-001" / "results.csv", delimiter=",", names=True)
    assert np.allclose(table["height"], 175.0, rtol=0, atol=1e-6)   # roof 200 m - 25 m at every nadir ray
    # the CSV carries the answers to the last bit (10 digits kept ~1 mm of an ECR coordinate)
    dsm = GeodeticDSM.read(f, geoid=-25.0)
    pts = _city_rays(lat, lon)
    res = pi.intersect(dsm, np.array([p[0] for p in pts]), np.array([p[1] for p in pts]), method="exact")
    assert np.array_equal(table["p_x"], res.p[:, 0]) and np.array_equal(table["distance"], res.distance)


def test_cli_run_summary_adds_up_with_the_iterative_methods_failures(tmp_path, capsys):
    # a tall narrow tower and rays grazing it: the iterative method oscillates or does not converge
    # on some; every status is counted in the summary
    h = np.full((60, 60), 0.0)
    h[28:32, 28:32] = 150.0
    dsm_path = tmp_path / "tower.npz"
    np.savez(dsm_path, heights=h, lat_first=0.0, lon_first=0.0, dlat=1e-5, dlon=1e-5, interpolation="nearest")
    pts = []
    for k in range(40):
        lat, lon = 0.00028 + 1e-6 * k, 0.0002 + 5e-6 * k
        s = np.array(pi.geodetic_to_ecef(lat, lon - 0.3, 600e3))  # from the west, steeply oblique
        pts.append((s, np.array(pi.geodetic_to_ecef(lat, lon, 0.0)) - s))
    rays = tmp_path / "rays.txt"
    _rays_file(rays, pts)
    assert main(["run", str(dsm_path), str(rays), "--method", "iterative", "--out", str(tmp_path / "o")]) == 0
    line = capsys.readouterr().out.splitlines()[-1]
    counts = [int(w.split()[0]) for w in line.split(": ", 1)[1].split(";")[0].split(", ")]
    assert sum(counts) == 40 and "oscillation" in line, line


def test_cli_run_turns_the_readers_warnings_into_notes(tmp_path, capsys):
    f = tmp_path / "navd88.tif"
    xc, yc = _utm_city(f, "EPSG:32614+5703", 500000.0, 4300000.0)
    lon, lat = pyproj.Transformer.from_crs("EPSG:32614", "EPSG:4326", always_xy=True).transform(xc, yc)
    rays = tmp_path / "rays.txt"
    _rays_file(rays, _city_rays(lat, lon, n=2))
    assert main(["run", str(f), str(rays), "--out", str(tmp_path / "o")]) == 0
    err = capsys.readouterr().err
    assert err.count("run: note: ") == 1 and "NAVD88 height" in err and "geoid=" in err, err


def test_cli_run_refuses_dsm_options_with_a_dem(tmp_path, capsys):
    from planet_intersect.synthetic import mars_like_dem

    dem = mars_like_dem(ppd=1)
    dem.write(tmp_path / "m.hdr")
    rays = tmp_path / "rays.txt"
    rays.write_text("4000 0 0 -1 0 0\n")
    assert main(["run", str(tmp_path / "m.hdr"), str(rays), "--geoid", "3", "--out", str(tmp_path / "o")]) == 2
    assert "--geoid: for a geodetic DSM (.tif, .npz) only" in capsys.readouterr().err
    assert main(["run", str(tmp_path / "m.hdr"), str(rays), "--out", str(tmp_path / "o")]) == 0
