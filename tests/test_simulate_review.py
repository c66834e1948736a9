"""Faults of the image simulation found by an adversarial review (2026-12-02),
each with a test that fails before its fix (docs/simulation-notes.md, note 12):
ortho values at the ortho grid's edge, value-less hits said, ``ground`` given
as a GeodeticDSM, ``sun`` without shading, a huge ``ground_window``, zero
lines of sight, a failed run's maps, a sensor on another body, masked arrays,
the CLI's ``--step``/``--margin``, the occlusion pass's memory, the footprint's
border pixels, geographic rasters on other datums. (The exact mode's rays onto
the DSM's edge are in test_follow.py.)"""

from __future__ import annotations

import subprocess
import sys
import time
import tracemalloc
import warnings

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect.synthetic_dsm import ObliqueScan, metre_steps, oblique_pushbroom

LAT0, LON0 = 36.6, -84.3


def flat_scene(n=40, height=0.0, interpolation="nearest"):
    """A flat DSM ("nearest": its area reaches half a cell beyond the edge nodes, so that the edge
    pixels' rays hit; on a bilinear grid they reach the ground on its edge and are LEFT_DSM or HIT
    by rounding) and an ortho on its grid, every pixel its own value."""
    dlat, dlon = metre_steps(LAT0)
    lat_first = LAT0 + (n - 1) * dlat
    h = np.full((n, n), height)
    dsm = pi.GeodeticDSM.from_array(h, lat_first, LON0, -dlat, dlon, interpolation=interpolation)
    vals = 10.0 + np.arange(n * n, dtype=np.float64).reshape(n, n)          # every pixel its own value
    ortho = pi.OrthoImage.from_array(vals, lat_first, LON0, -dlat, dlon)
    scene = dict(heights=h, lat_first=lat_first, lon_first=LON0, dlat=-dlat, dlon=dlon)
    return dsm, ortho, scene, vals


def nadir_sensor(scene, margin=0):
    return pi.Pushbroom(*oblique_pushbroom(scene, zenith=0.0, azimuth=90.0, margin=margin))


def test_flat_nadir_reproduces_the_ortho_to_its_border():
    """A flat DSM seen at nadir, the ortho on the DSM's own grid: every pixel, the border included,
    shows its ortho pixel (166 of 236 border pixels were fill: hits ~3e-9 pixel outside the
    rectangle of centres)."""
    dsm, ortho, scene, vals = flat_scene()
    with warnings.catch_warnings():
        warnings.simplefilter("error")                     # no "hits without an ortho value" warning
        sim = pi.simulate_image(dsm, ortho, nadir_sensor(scene), occlusion=False)
    assert sim.valid.all() and sim.ortho_value.all()
    np.testing.assert_allclose(sim.image, vals, rtol=0, atol=1e-3)
    assert sim.counts()["hits without an ortho value"] == 0


def test_hits_without_an_ortho_value_are_said():
    """An ortho covering the western half of the DSM: the eastern hits get fill, are counted,
    flagged in ortho_value and warned about (they were indistinguishable from black ground)."""
    dsm, _, scene, vals = flat_scene()
    half = pi.OrthoImage.from_array(vals[:, :20], scene["lat_first"], LON0, scene["dlat"], scene["dlon"])
    with pytest.warns(UserWarning, match=r"800 pixel\(s\) hit the DSM where the ortho-image has no value"):
        sim = pi.simulate_image(dsm, half, nadir_sensor(scene), occlusion=False, fill=-7.0)
    assert sim.valid.all()
    assert (~sim.ortho_value[:, 20:]).all() and sim.ortho_value[:, :20].all()
    assert (sim.image[:, 20:] == -7.0).all()
    assert sim.counts()["hits without an ortho value"] == 800 == sim.meta["hits_without_ortho_value"]


def test_ground_as_a_dsm_is_sampled_on_its_own_grid():
    """The same bare earth (rising 0.5 m per row) given north-up and south-up as GeodeticDSMs
    classifies every pixel alike (its heights array alone was used: 1,296 pixels relabelled)."""
    n = 56
    dlat, dlon = metre_steps(LAT0)
    lat_first = LAT0 + (n - 1) * dlat
    ground = 0.5 * (n - 1 - np.arange(n))[:, None] * np.ones((1, n))        # north-up rows
    h = ground.copy()
    h[20:36, 20:36] += 12.0
    dsm = pi.GeodeticDSM.from_array(h, lat_first, LON0, -dlat, dlon, interpolation="nearest")
    ortho = pi.OrthoImage.from_array(np.full((n, n), 100.0), lat_first, LON0, -dlat, dlon)
    scene = dict(heights=h, lat_first=lat_first, lon_first=LON0, dlat=-dlat, dlon=dlon)
    sensor = pi.Pushbroom(*oblique_pushbroom(scene, zenith=9.0, azimuth=90.0, margin=0))
    north = pi.GeodeticDSM.from_array(ground, lat_first, LON0, -dlat, dlon)
    south = pi.GeodeticDSM.from_array(ground[::-1], LAT0, LON0, dlat, dlon)
    assert south.height(LAT0 + 10 * dlat, LON0) == pytest.approx(north.height(LAT0 + 10 * dlat, LON0))
    kw = dict(occlusion=False, roof_min=2.0)
    a = pi.simulate_image(dsm, ortho, sensor, ground=ground, **kw)
    b = pi.simulate_image(dsm, ortho, sensor, ground=north, **kw)
    c = pi.simulate_image(dsm, ortho, sensor, ground=south, **kw)
    np.testing.assert_array_equal(a.surface, b.surface)
    np.testing.assert_array_equal(a.surface, c.surface)
    assert (a.surface == 1).sum() > 100                 # roofs found (the test sees the difference)
    mars = pi.GeodeticDSM.from_array(ground, lat_first, LON0, -dlat, dlon, a=3396190.0, f=0.0)
    with pytest.raises(ValueError, match="ground: its ellipsoid"):
        pi.simulate_image(dsm, ortho, sensor, ground=mars, **kw)


def test_sun_without_lambert_shading_is_refused():
    dsm, ortho, scene, _ = flat_scene(n=8)
    sensor = nadir_sensor(scene)
    with pytest.raises(ValueError, match="sun and ambient apply only with shading='lambert'"):
        pi.simulate_image(dsm, ortho, sensor, sun=(135.0, 10.0), occlusion=False)
    with pytest.raises(ValueError, match="sun and ambient"):
        pi.simulate_image(dsm, ortho, sensor, ambient=0.3, occlusion=False)


def test_huge_ground_window_is_quick_and_the_same():
    """Any window wider than twice the grid opens as one of the grid's size (1e7 m took 7.6 s,
    1e12 m a MemoryError without a message)."""
    from planet_intersect.simulate import _opening_ground

    dsm, _, _, _ = flat_scene(n=60)
    h = dsm.heights.copy()
    h[10:20, 30:50] = 9.0
    h += np.linspace(0, 3, 60)[None, :]
    d = pi.GeodeticDSM.from_array(h, dsm.lat_first, dsm.lon_first, dsm.dlat, dsm.dlon)
    ref = _opening_ground(d, 1e3)
    t = time.perf_counter()
    for w in (1e6, 1e12, 1e300):
        np.testing.assert_array_equal(_opening_ground(d, w), ref)
    assert time.perf_counter() - t < 5.0


def test_zero_line_of_sight_and_a_failed_run_leaves_no_maps(tmp_path):
    dsm, ortho, scene, _ = flat_scene(n=20)
    s, l = oblique_pushbroom(scene, zenith=0.0, azimuth=90.0)
    bad = l.copy()
    bad[7, 3] = 0.0
    with pytest.raises(ValueError, match=r"l\[7, 3\] has zero length"):
        pi.Pushbroom(s, bad)
    lf = np.ones((2, 2, 3))
    lf[1, 0] = 0.0
    with pytest.raises(ValueError, match=r"l\[1, 0\] has zero length"):
        pi.FrameCamera([0.0, 0.0, 7e6], lf)

    class Failing(pi.sensors.Sensor):
        def __init__(self):
            self.shape = (20, 20)

        def rays(self, k0=0, k1=None):
            k0, k1 = self._check_block(k0, self.nlines if k1 is None else k1)
            if k1 > 10:
                raise RuntimeError("the sensor's clock stopped")
            return np.repeat(s[k0:k1], 20, axis=0), l[k0:k1].reshape(-1, 3)

    out = tmp_path / "maps"
    with pytest.raises(RuntimeError, match="clock stopped"):
        pi.simulate_image(dsm, ortho, Failing(), out=out, block_lines=5, occlusion=False)
    assert not out.exists()                            # the half-filled maps are gone: a retry can use out
    sim = pi.simulate_image(dsm, ortho, nadir_sensor(scene), out=out, occlusion=False)
    assert sim.valid.all() and (out / "lat.npy").is_file()


def test_sensor_on_another_body_is_refused():
    dsm, ortho, scene, _ = flat_scene(n=20)
    mars = pi.GeodeticDSM.from_array(dsm.heights, dsm.lat_first, dsm.lon_first, dsm.dlat, dsm.dlon,
                                     a=3396190.0, f=0.005)
    sen = pi.Pushbroom.from_orbit(altitude=300e3, inclination=97.0, npixels=8, ifov=1e-4, nlines=4,
                                  line_period=1e-3, target=(LAT0, LON0))
    with pytest.raises(ValueError, match=r"sensor: its orbit was built on the ellipsoid a = 6378137.*"
                                         r"the DSM's is a = 3396190"):
        pi.simulate_image(mars, ortho, sen, occlusion=False)


def test_masked_arrays_are_no_data():
    dsm, _, scene, vals = flat_scene(n=10)
    m = np.ma.masked_equal(np.where(np.eye(10, dtype=bool), -9999.0, vals), -9999.0)
    o = pi.OrthoImage.from_array(m, scene["lat_first"], LON0, scene["dlat"], scene["dlon"])
    assert np.isnan(o.sample(scene["lat_first"], LON0)) and o.sample(scene["lat_first"], LON0 + 5 * scene["dlon"]) == pytest.approx(15.0)
    mi = np.ma.masked_equal(np.where(np.eye(10, dtype=bool), 0, 7).astype(np.uint8), 0)
    o8 = pi.OrthoImage.from_array(mi, scene["lat_first"], LON0, scene["dlat"], scene["dlon"])
    assert np.isnan(o8.sample(scene["lat_first"], LON0))
    hm = np.ma.masked_equal(np.where(np.eye(10, dtype=bool), -9999.0, 5.0), -9999.0)
    d = pi.GeodeticDSM.from_array(hm, scene["lat_first"], LON0, scene["dlat"], scene["dlon"])
    assert np.isnan(d.heights[0, 0]) and d.hmin == 5.0


def test_cli_step_and_margin_refused(tmp_path):
    dsm, ortho, scene, vals = flat_scene(n=20)
    np.savez(tmp_path / "dsm.npz", heights=dsm.heights, lat_first=dsm.lat_first, lon_first=dsm.lon_first,
             dlat=dsm.dlat, dlon=dsm.dlon)
    np.savez(tmp_path / "o.npz", values=vals, lat_first=dsm.lat_first, lon_first=dsm.lon_first, dlat=dsm.dlat,
             dlon=dsm.dlon)
    for extra, message in ((["--step", "1e-9"], "--step 1e-09 makes an image of"),
                           (["--margin", "-5"], "--margin must be >= 0"),
                           (["--altitude", "inf"], "--altitude must be a finite positive height")):
        r = subprocess.run([sys.executable, "-m", "planet_intersect.cli", "simulate", "--dsm", tmp_path / "dsm.npz",
                            "--ortho", tmp_path / "o.npz", "--oblique", "9,90", "--out", tmp_path / "run", *extra],
                           capture_output=True, text=True, timeout=300)
        assert r.returncode == 2 and message in r.stderr and "Traceback" not in r.stderr, r.stderr
    with pytest.raises(ValueError, match="margin must be a whole number"):
        ObliqueScan(scene, margin=-5)
    with pytest.raises(ValueError, match="step 1e-09 makes"):
        ObliqueScan(scene, step=1e-9)


def test_occlusion_memory_is_bounded_and_chunks_agree():
    """The occlusion pass in chunks: the same masks for any chunk size; its peak memory per image
    pixel is tens of bytes (it held every footprint pixel's ray at once: ~600 bytes per pixel)."""
    from planet_intersect import simulate as S

    n = 300
    dsm, ortho, scene, _ = flat_scene(n=n, interpolation="nearest")
    h = dsm.heights.copy()
    h[100:140, 100:200] = 30.0
    dsm = pi.GeodeticDSM.from_array(h, dsm.lat_first, dsm.lon_first, dsm.dlat, dsm.dlon, interpolation="nearest")
    scan = ObliqueScan(dict(scene, heights=h), zenith=20.0, azimuth=90.0)
    sim = pi.simulate_image(dsm, ortho, scan, occlusion=False, block_lines=16)
    tracemalloc.start()
    occ, foot = S._occlusion(dsm, ortho, scan, sim, threads=1, chunk=4096)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    occ2, foot2 = S._occlusion(dsm, ortho, scan, sim, threads=1)
    np.testing.assert_array_equal(occ, occ2)
    np.testing.assert_array_equal(foot, foot2)
    hidden = int(occ.sum())
    expect = 30.0 * np.tan(np.radians(20.0)) * 40                       # the strip behind the west wall
    assert abs(hidden - expect) < 0.15 * expect, (hidden, expect)
    assert peak / (n * n) < 60, peak / (n * n)


def test_footprint_holds_every_pixel_seen_at_its_centre():
    """A nadir image of a flat DSM: each image pixel looks at an ortho pixel's centre, and every one
    of them is in the footprint (the border row and column were decided by rounding)."""
    for lon0 in (LON0, 10.0, 179.99):
        dsm, ortho, scene, _ = flat_scene(n=30)
        dlat, dlon = metre_steps(LAT0)
        d = pi.GeodeticDSM.from_array(dsm.heights, dsm.lat_first, lon0, dsm.dlat, dsm.dlon, interpolation="nearest")
        o = pi.OrthoImage.from_array(np.ones((30, 30)), dsm.lat_first, lon0, dsm.dlat, dsm.dlon)
        sc = dict(scene, lon_first=lon0)
        sim = pi.simulate_image(d, o, nadir_sensor(sc), occlusion=True)
        assert sim.footprint.all(), (lon0, int(sim.footprint.sum()))
        assert not sim.occlusion.any()


def test_geographic_rasters_on_other_datums(tmp_path):
    """A GeoTIFF in the Tokyo datum (EPSG:4301) is placed where PROJ puts it in WGS-84 (it was read
    as WGS-84: ~360 m off); one in a Mars CRS needs Mars's a, f."""
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF reading needs rasterio")
    pyproj = pytest.importorskip("pyproj")
    from rasterio.transform import from_origin

    n, step = 40, 1e-4
    lon0, lat0 = 139.70, 35.70
    h = np.zeros((n, n))
    h[18:22, 18:22] = 50.0                               # a tower near the middle
    for crs in ("EPSG:4326", "EPSG:4301"):
        path = tmp_path / f"{crs.replace(':', '')}.tif"
        with rasterio.open(path, "w", driver="GTiff", width=n, height=n, count=1, dtype="float64", crs=crs,
                           transform=from_origin(lon0, lat0, step, step)) as dst:
            dst.write(h, 1)
    d84 = pi.GeodeticDSM.read(tmp_path / "EPSG4326.tif")
    dtk = pi.GeodeticDSM.read(tmp_path / "EPSG4301.tif")
    assert d84.resampling is None and dtk.resampling == "nearest"
    # the tower's centre: where PROJ takes the Tokyo coordinates of its centre
    lon_t, lat_t = lon0 + 20 * step, lat0 - 20 * step
    lon_w, lat_w = pyproj.Transformer.from_crs("EPSG:4301", "EPSG:4326", always_xy=True).transform(lon_t, lat_t)
    shift = np.hypot((lat_w - lat_t) * 111e3, (lon_w - lon_t) * 90e3)
    assert shift > 300.0                                 # the datums differ by hundreds of metres here
    assert dtk.height(lat_w - step / 2, lon_w - step / 2) == 50.0
    assert np.isnan(dtk.height(lat_t - step / 2, lon_t - step / 2)) or dtk.height(lat_t - step / 2,
                                                                                 lon_t - step / 2) == 0.0
    assert d84.height(lat_t - step / 2, lon_t - step / 2) == 50.0
    o = pi.OrthoImage.read(tmp_path / "EPSG4301.tif")
    assert o.sample(lat_w - step / 2, lon_w - step / 2) == pytest.approx(50.0)
    mars = tmp_path / "mars.tif"
    with rasterio.open(mars, "w", driver="GTiff", width=n, height=n, count=1, dtype="float64",
                       crs=pyproj.CRS("IAU_2015:49900").to_wkt(), transform=from_origin(10.0, 5.0, step, step)) as dst:
        dst.write(h, 1)
    with pytest.raises(ValueError, match=r"mars.tif: its CRS .* a = 3396190, f = 0, not a = 6378137"):
        pi.GeodeticDSM.read(mars)
    dm = pi.GeodeticDSM.read(mars, a=3396190.0, f=0.0)
    assert dm.a == 3396190.0 and dm.resampling is None


# ---------------------------------------------------------------- 2026-12-03: a second review
def test_arguments_that_were_misread_or_overflowed():
    """occlusion="no" was taken as True; block_lines=np.int8(100) overflowed in the block
    arithmetic ("lines 100:-56"); fill=1e300 became inf in the float32 image; a sun vector of
    1e308 components overflowed into an all-black image. Each is refused or handled, with no
    warning."""
    dsm, ortho, scene, vals = flat_scene(n=20)
    sensor = nadir_sensor(scene)
    with pytest.raises(TypeError, match="occlusion must be True or False, got 'no'"):
        pi.simulate_image(dsm, ortho, sensor, occlusion="no")
    with pytest.raises(ValueError, match="fill = 1e\\+300: the image is float32"):
        pi.simulate_image(dsm, ortho, sensor, fill=1e300, occlusion=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        a = pi.simulate_image(dsm, ortho, sensor, occlusion=False, block_lines=np.int8(7))
        b = pi.simulate_image(dsm, ortho, sensor, occlusion=False)
        np.testing.assert_array_equal(a.image, b.image)
        up = pi.geodetic_to_ecef(LAT0, LON0, 1.0) - pi.geodetic_to_ecef(LAT0, LON0, 0.0)
        big = pi.simulate_image(dsm, ortho, sensor, occlusion=False, shading="lambert", sun=up * 1e308)
        unit = pi.simulate_image(dsm, ortho, sensor, occlusion=False, shading="lambert", sun=up)
    np.testing.assert_array_equal(big.image, unit.image)
    assert np.nanmax(unit.image) > 0


def test_ortho_lon_first_is_reduced_and_tiny_spacing_refused():
    """An ortho-image's lon_first of 7 + 360 * 2**40 drifted by up to 17.6 in the image (the DSM
    already reduced its own exactly); a spacing of 5e-324 degrees overflowed."""
    vals = np.arange(16.0).reshape(4, 4)
    o = pi.OrthoImage.from_array(vals, 0.0, 7.0 + 360.0 * 2**40, -1e-3, 1e-3)
    assert o.lon_first == 7.0
    with pytest.raises(ValueError, match="dlon = 5e-324 degrees is below"):
        pi.OrthoImage.from_array(vals, 0.0, 7.0, -1e-3, 5e-324)


def test_ortho_sample_at_its_own_edge_centres():
    """The simulation fuzzing (2026-12-03): OrthoImage.sample at the image's own centres() gave NaN
    for the whole last column of a 22 x 6 grid (its column coordinate rounds to 5.000000000000342
    of 5); the shading kernel already took points within 1e-6 pixels of the edge onto it. The
    expectation is the stored values themselves. Since 2026-12-05 the image's outer half pixel
    holds its edge pixels' values (its bounds, a review): 1e-3 pixels outside is the edge value,
    0.6 pixels outside NaN."""
    vals = np.arange(22 * 6, dtype=float).reshape(22, 6)
    o = pi.OrthoImage.from_array(vals, 70.67173795162601, 8.788884874354663, 8.435302429057608e-05,
                                 0.0006626611809803053)
    lat, lon = o.centres()
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    got = o.sample(la, lo)
    assert not np.isnan(got).any()
    assert np.max(np.abs(got - vals)) < 1e-9
    assert o.sample(lat[0] - 1e-3 * o.dlat, lon[2]) == pytest.approx(vals[0, 2], abs=1e-9)
    assert o.sample(lat[3], lon[-1] + 1e-3 * o.dlon) == pytest.approx(vals[3, -1], abs=1e-9)
    assert np.isnan(o.sample(lat[0] - 0.6 * o.dlat, lon[2]))
    assert np.isnan(o.sample(lat[3], lon[-1] + 0.6 * o.dlon))


def test_footprint_holds_every_hit_when_the_border_misses_the_dsm():
    """The simulation fuzzing (2026-12-03): an image wider than its DSM (every border pixel misses
    it) had hits on 9 ortho pixels and a footprint of 0 (the mask was built only inside the box of
    the border's hits, and not at all with fewer than 3). Expectation, from the hits themselves:
    every ortho pixel a hit lands on (nearest centre) is in the footprint; a flat DSM hides none.
    The image (9 x 9 pixels of ~3.5 m at nadir from 100 m, ~31 m across) covers the whole DSM
    (11 x 11 cells of ~1.1 x 0.8 m), so since 2026-12-04, when the border's rays that miss the DSM
    also bound the footprint (simulation note 5), every ortho pixel on the DSM is in it (it was the
    9 pixels hit, which the walk-through of that day showed to be wrong: test_simulate.py,
    test_occlusion_of_an_image_larger_than_its_dsm)."""
    lat0, lon0, d = 45.0, 7.0, 1e-5
    dsm = pi.GeodeticDSM.from_array(np.zeros((11, 11)), lat0, lon0, d, d)
    ortho = pi.OrthoImage.from_array(np.full((11, 11), 100.0), lat0, lon0, d, d)
    cam = pi.FrameCamera.nadir(lat0 + 5 * d, lon0 + 5 * d, 100.0, (9, 9), 2.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim = pi.simulate_image(dsm, ortho, cam, occlusion=True)
    assert int(sim.valid.sum()) == 9
    assert not (sim.valid[0].any() or sim.valid[-1].any() or sim.valid[:, 0].any() or sim.valid[:, -1].any())
    u, v = ortho.grid_coords(sim.lat[sim.valid], sim.lon[sim.valid])
    seen = set(zip(np.rint(u).astype(int).tolist(), np.rint(v).astype(int).tolist()))
    assert len(seen) == 9
    assert all(bool(sim.footprint[i, j]) for i, j in seen)
    assert sim.footprint.all() and not sim.occlusion.any()
