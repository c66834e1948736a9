"""Image simulation (issue 12): the ortho-image, the simulation's bookkeeping
(blocks, threads, memory maps, files, errors) and the paper's experiment
against the scene's ground truth. The closed-form geometry checks (roof
displacement, wall width, hidden strip) are in test_simulate_references.py,
written independently from the contract."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect.synthetic_dsm import metre_steps, oblique_pushbroom, paper_scene

LAT0, LON0 = 36.6, -84.3


def box_scene(n=120, height=20.0, rows=(50, 70), cols=(40, 80), interpolation="nearest"):
    dlat, dlon = metre_steps(LAT0)
    h = np.zeros((n, n))
    h[rows[0]:rows[1], cols[0]:cols[1]] = height
    lat_first = LAT0 + (n - 1) * dlat
    dsm = pi.GeodeticDSM.from_array(h, lat_first, LON0, -dlat, dlon, interpolation=interpolation)
    vals = np.where(h > 0, 200.0, 50.0 + 100.0 * ((np.arange(n)[None, :] % 10) < 5))
    ortho = pi.OrthoImage.from_array(vals, lat_first, LON0, -dlat, dlon)
    scene = dict(heights=h, ground=np.zeros_like(h), lat_first=lat_first, lon_first=LON0, dlat=-dlat, dlon=dlon)
    return dsm, ortho, scene


# ------------------------------------------------------------------ ortho image
def test_ortho_sample_nodes_midpoints_and_outside():
    v = np.arange(12.0).reshape(3, 4)
    o = pi.OrthoImage.from_array(v, 10.0, 20.0, -0.5, 0.25)
    lat = 10.0 - 0.5 * np.array([0, 1, 2, 0.5, 1.25])
    lon = 20.0 + 0.25 * np.array([0, 3, 1, 0.5, 2.5])
    np.testing.assert_allclose(o.sample(lat, lon), [0, 7, 9, 2.5, 4 * 1.25 + 2.5], rtol=0, atol=1e-12)  # v = 4i + j: exact
    # the outer half pixel is the edge pixels' (the image's bounds: a review found that ring at fill)
    assert o.sample(8.9, 20.1) == pytest.approx(8.4, abs=1e-12) and o.sample(9.5, 20.8) == pytest.approx(7.0)
    assert o.sample(10.2, 20.0) == pytest.approx(0.0, abs=1e-12)
    # beyond the bounds: NaN
    assert np.isnan(o.sample(10.6, 20.1)) and np.isnan(o.sample(8.7, 20.1)) and np.isnan(o.sample(9.5, 20.9))


def test_ortho_rgb_nodata_and_private_copy():
    v = np.zeros((4, 4, 3))
    v[..., 1] = 5.0
    v[0, 0] = -1
    o = pi.OrthoImage.from_array(v, 0.0, 0.0, -1.0, 1.0, nodata=-1)
    assert o.bands == 3 and o.sample(-2.0, 2.0).tolist() == [0.0, 5.0, 0.0]
    assert np.isnan(o.sample(-0.5, 0.5)).all()                       # needs the no-data pixel
    v[2, 2] = 99.0
    assert o.sample(-2.0, 2.0)[1] == 5.0


@pytest.mark.parametrize("kw, match", [
    (dict(values=np.zeros(4)), "values"), (dict(values=np.zeros((1, 5))), "values"),
    (dict(values=np.array([["a", "b"], ["c", "d"]])), "values"), (dict(dlat=0.0), "dlat"),
    (dict(dlon=-1.0), "dlon"), (dict(lat_first=95.0), "lat"), (dict(lat_first=float("nan")), "lat_first"),
    # rasterio's band-first layout: once taken as 3 rows of 48-band pixels, the image nearly all fill
    (dict(values=np.zeros((3, 48, 48), dtype=np.uint8)), "band-first"),
])
def test_ortho_bad_input(kw, match):
    args = dict(values=np.zeros((3, 3)), lat_first=0.0, lon_first=0.0, dlat=-1.0, dlon=1.0)
    args.update(kw)
    with pytest.raises((ValueError, TypeError), match=match):
        pi.OrthoImage.from_array(**args)


def test_ortho_read_geotiff_and_npz(tmp_path):
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF reading needs rasterio")
    from rasterio.transform import from_origin

    v = np.random.default_rng(1).integers(0, 255, (3, 6, 5)).astype(np.uint8)
    path = tmp_path / "o.tif"
    with rasterio.open(path, "w", driver="GTiff", width=5, height=6, count=3, dtype="uint8", crs="EPSG:4326",
                       transform=from_origin(-84.0, 36.0, 0.001, 0.002)) as dst:
        dst.write(v)
    o = pi.OrthoImage.read(path)
    assert o.shape == (6, 5) and o.bands == 3 and o.dtype == np.uint8
    assert o.lat_first == pytest.approx(36.0 - 0.001) and o.lon_first == pytest.approx(-84.0 + 0.0005)
    np.testing.assert_allclose(o.sample(o.lat_first + 2 * o.dlat, o.lon_first + 3 * o.dlon), v[:, 2, 3], atol=1e-6)
    np.savez(tmp_path / "o.npz", values=v[0], lat_first=1.0, lon_first=2.0, dlat=-0.1, dlon=0.1)
    assert pi.OrthoImage.read(tmp_path / "o.npz").sample(1.0, 2.0) == v[0, 0, 0]
    with pytest.raises(FileNotFoundError, match="nope.tif"):
        pi.OrthoImage.read(tmp_path / "nope.tif")
    (tmp_path / "bad.tif").write_text("not a raster")
    with pytest.raises(ValueError, match="bad.tif"):
        pi.OrthoImage.read(tmp_path / "bad.tif")


# ------------------------------------------------------------- the sensor of the benchmarks
def test_oblique_scan_targets_equal_a_conversion_per_pixel():
    """ObliqueScan.rays converts a row's latitude and a column's longitude once each and
    multiplies (geodetic_to_ecr's x = ((N + h) cos lat) cos lon, a product of rounded factors);
    every ray equals, to the bit, the one aimed at a per-pixel geodetic_to_ecef of the pixel's
    (lat, lon) from the line's focal point: on the Earth and on a flattened body, over the
    antimeridian, in blocks that start mid-image, with a non-unit step."""
    from planet_intersect.geodetic import geodetic_to_ecef
    from planet_intersect.synthetic_dsm import ObliqueScan

    rng = np.random.default_rng(11)
    for a, f, lon_first, lat_first in ((6378137.0, 1 / 298.257223563, 179.99, 47.3),
                                       (3396190.0, 1 / 169.894, -40.0, -71.2)):
        h = rng.uniform(0.0, 40.0, (30, 37))
        scene = dict(heights=h, lat_first=lat_first, lon_first=lon_first, dlat=-1e-5, dlon=1.3e-5, a=a, f=f)
        scan = ObliqueScan(scene, zenith=17.0, azimuth=250.0, margin=2, step=1.5)
        nl, npx = scan.shape
        for k0, k1 in ((0, nl), (3, 7), (nl - 1, nl)):
            s, l = scan.rays(k0, k1)
            lat = np.repeat(scan.lat_first + scan.rows[k0:k1] * scan.dlat, npx)
            lon = np.tile(scan.lon_first + scan.cols * scan.dlon, k1 - k0)
            tgt = geodetic_to_ecef(lat, lon, scan.href, a, f)
            assert s.shape == l.shape == ((k1 - k0) * npx, 3)
            assert np.array_equal(s, np.repeat(s[::npx], npx, axis=0))      # one focal point a line
            assert np.array_equal(l, tgt - s)


# ------------------------------------------------------------- the simulation
def _widened_pushbroom(scene, zenith, factor):
    """The scene's oblique pushbroom from the East with each line's directions spread ``factor``
    times about its centre pixel (factor 1.5: aimed 25 % beyond both sides of the scene)."""
    s0, l0 = oblique_pushbroom(scene, zenith=zenith, azimuth=90.0, margin=0)
    lc = l0[:, l0.shape[1] // 2][:, None, :]
    return pi.Pushbroom(s0, lc + factor * (l0 - lc))


@pytest.fixture(scope="module")
def box():
    dsm, ortho, scene = box_scene()
    sensor = pi.Pushbroom(*oblique_pushbroom(scene, zenith=9.0, azimuth=90.0, margin=10))
    return dsm, ortho, scene, sensor


@pytest.mark.filterwarnings("ignore:.*where the ortho-image has no value")
def test_default_blocks_hold_about_block_pixels(box, monkeypatch):
    """block_lines=None: blocks of BLOCK_PIXELS // npixels lines (at least one), the same image as one block."""
    from planet_intersect import simulate as sim_mod

    dsm, ortho, scene, sensor = box
    seen = []

    class Recorder(pi.sensors.Sensor):
        shape = sensor.shape

        def rays(self, k0=0, k1=None):
            seen.append((k0, k1))
            return sensor.rays(k0, k1)

    npx = sensor.shape[1]
    monkeypatch.setattr(sim_mod, "BLOCK_PIXELS", 7 * npx + 3)       # 7 lines per block
    a = pi.simulate_image(dsm, ortho, Recorder(), threads=1, occlusion=False)
    nl = sensor.shape[0]
    # the blocks, then the two end lines' rays the files' record of the sensor reads (simulation note 18)
    assert seen[:-2] == [(k, min(k + 7, nl)) for k in range(0, nl, 7)] and seen[-2:] == [(0, 1), (nl - 1, nl)]
    monkeypatch.setattr(sim_mod, "BLOCK_PIXELS", 5)                 # fewer than a line: one line per block
    seen.clear()
    b = pi.simulate_image(dsm, ortho, Recorder(), threads=1, occlusion=False)
    assert seen[:-2] == [(k, k + 1) for k in range(nl)]
    c = pi.simulate_image(dsm, ortho, sensor, threads=1, occlusion=False, block_lines=nl)
    for name in ("image", "valid", "lat", "lon", "height", "surface", "status", "p"):
        np.testing.assert_array_equal(getattr(a, name), getattr(c, name), err_msg=name)
        np.testing.assert_array_equal(getattr(b, name), getattr(c, name), err_msg=name)


def test_shading_pass_runs_on_the_requested_threads(box, monkeypatch):
    """simulate_image(threads=2) gives its shading pass two threads (it was given min(threads, 1),
    so the pass ran on one thread whatever was asked: simulation note 13); threads=None: all cores."""
    import os

    from planet_intersect import _ext

    core = _ext.core
    seen = []

    class Spy:
        def __getattr__(self, name):
            fn = getattr(core, name)
            if name != "core_sim_shade":
                return fn

            def spy(*args, **kw):
                seen.append(kw["threads"])
                return fn(*args, **kw)
            return spy

    monkeypatch.setattr(_ext, "core", Spy(), raising=False)
    dsm, ortho, scene, sensor = box
    pi.simulate_image(dsm, ortho, sensor, threads=2, occlusion=False)
    assert seen and set(seen) == {2}
    seen.clear()
    pi.simulate_image(dsm, ortho, sensor, threads=None, occlusion=False)
    assert set(seen) == {len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()}


@pytest.mark.filterwarnings("ignore:.*where the ortho-image has no value")
def test_backplanes_equal_the_trace_across_the_antimeridian():
    """The backplanes the shading pass writes (degrees, longitudes wrapped into [-180, 180), NaN
    where not hit) equal pi.intersect's own results for the same rays, on a scene that straddles
    180 deg with a box on it and lines wider than the DSM (misses). Some hits lie a few ulps
    beyond +-180 deg; a wrap by an exact -+360 in the kernel gave 179.99999999999997 where
    pi.intersect gives -180.0 (a review of the change: simulation note 13)."""
    dlat, dlon = metre_steps(LAT0)
    n = 60
    h = np.zeros((n, n))
    h[20:40, 15:45] = 20.0                             # a box across 180 deg, its walls and roof hit
    h[5:9, 40:44] = 35.0
    lon_first = 180.0 - 30 * dlon                      # column 30's centre on 180 deg
    lat_first = LAT0 + (n - 1) * dlat
    dsm = pi.GeodeticDSM.from_array(h, lat_first, lon_first, -dlat, dlon, interpolation="nearest")
    ortho = pi.OrthoImage.from_array(np.arange(n * n, dtype=float).reshape(n, n), lat_first, lon_first, -dlat, dlon)
    scene = dict(heights=h, lat_first=lat_first, lon_first=lon_first, dlat=-dlat, dlon=dlon)
    sensor = _widened_pushbroom(scene, 20.0, 1.3)
    sim = pi.simulate_image(dsm, ortho, sensor, threads=2, occlusion=False, block_lines=9)
    s, l = sensor.rays()
    res = pi.intersect(dsm, s, l, method="exact", threads=1)
    nl, npx = sensor.shape
    hit = res.hit.reshape(nl, npx)
    assert 0 < (~hit).sum() and hit.sum() > 0.5 * hit.size
    np.testing.assert_array_equal(sim.valid, hit)
    lon = sim.lon[hit]
    assert (lon >= -180.0).all() and (lon < 180.0).all() and (lon > 179.0).any() and (lon < -179.0).any()
    for name, ref in (("lat", res.lat), ("lon", res.lon), ("height", res.height), ("distance", res.distance),
                      ("incidence", res.incidence)):
        np.testing.assert_array_equal(getattr(sim, name), np.where(hit, ref.reshape(nl, npx), np.nan), err_msg=name)
    np.testing.assert_array_equal(sim.p, np.where(hit[..., None], res.p.reshape(nl, npx, 3), np.nan))
    assert np.isnan(sim.local_incidence[~hit]).all() and (sim.surface[~hit] == -1).all()
    assert np.isfinite(sim.local_incidence[hit]).all() and (sim.local_incidence[hit] <= 90.0).all()


@pytest.mark.filterwarnings("ignore:.*where the ortho-image has no value")
def test_blocks_threads_and_memmap_give_identical_results(box, tmp_path):
    dsm, ortho, scene, sensor = box
    a = pi.simulate_image(dsm, ortho, sensor, threads=1, block_lines=1000)
    b = pi.simulate_image(dsm, ortho, sensor, threads=2, block_lines=7, out=tmp_path / "maps")
    for name in ("image", "valid", "lat", "lon", "height", "distance", "incidence", "local_incidence", "surface",
                 "status", "p", "occlusion", "footprint", "ortho_value"):
        np.testing.assert_array_equal(getattr(a, name), np.asarray(getattr(b, name)), err_msg=name)
    assert isinstance(b.lat, np.memmap) and (tmp_path / "maps" / "lat.npy").is_file()
    # the memory-mapped files are not pre-filled: pixels whose rays leave the DSM must still get the
    # fill, NaN and -1 entries (a sensor wider than the scene)
    wide = _widened_pushbroom(scene, 9.0, 1.5)              # each line aimed 25 % beyond both sides
    c = pi.simulate_image(dsm, ortho, wide, threads=1, block_lines=1000, occlusion=False)
    d = pi.simulate_image(dsm, ortho, wide, threads=1, block_lines=7, occlusion=False, out=tmp_path / "wide")
    assert (~c.valid).sum() > 0.2 * c.valid.size
    for name in ("image", "valid", "lat", "lon", "height", "distance", "incidence", "local_incidence",
                 "surface", "status", "p", "ortho_value"):
        np.testing.assert_array_equal(getattr(c, name), np.asarray(getattr(d, name)), err_msg=name)
    with pytest.raises(FileExistsError, match="maps"):
        pi.simulate_image(dsm, ortho, sensor, out=tmp_path / "maps")


def test_out_files_are_written_block_by_block_and_complete(box, tmp_path):
    """out=DIR writes each block of lines from a reused buffer into its .npy file
    (simulation note 9): the files are whole, plain .npy files (read without a
    memory map) equal to the in-memory result for an RGB ortho-image, a last
    block shorter than the others and a block longer than the image; the result
    maps them writable; a failed later block leaves no folder."""
    dsm, ortho, scene, _ = box
    sensor = _widened_pushbroom(scene, 9.0, 1.5)            # lines 25 % wider than the scene: misses too
    vals = ortho.values
    rgb = pi.OrthoImage.from_array(np.stack([vals, 0.5 * vals, 255.0 - vals], axis=-1), scene["lat_first"],
                                   scene["lon_first"], scene["dlat"], scene["dlon"])
    ref = pi.simulate_image(dsm, rgb, sensor, threads=1, occlusion=False)
    nl, npx = sensor.shape
    assert nl % 9 != 0
    expect = {"image": (np.float32, (nl, npx, 3)), "valid": (np.bool_, (nl, npx)), "lat": (np.float64, (nl, npx)),
              "lon": (np.float64, (nl, npx)), "height": (np.float64, (nl, npx)),
              "distance": (np.float64, (nl, npx)), "incidence": (np.float64, (nl, npx)),
              "local_incidence": (np.float64, (nl, npx)), "surface": (np.int8, (nl, npx)),
              "ortho_value": (np.bool_, (nl, npx)), "status": (np.int8, (nl, npx)), "p": (np.float64, (nl, npx, 3))}
    for blk in (9, 10 * nl):
        out = tmp_path / f"maps{blk}"
        sim = pi.simulate_image(dsm, rgb, sensor, threads=1, occlusion=False, block_lines=blk, out=out)
        # the maps, and meta.json last (the run finished: simulation note 18; no masks with occlusion=False)
        assert sorted(q.name for q in out.iterdir()) == sorted([f"{k}.npy" for k in expect] + ["meta.json"])
        for name, (dtype, shape) in expect.items():
            path = out / f"{name}.npy"
            plain = np.load(path)                              # no memory map: the file itself
            assert plain.dtype == dtype and plain.shape == shape and not np.isfortran(plain), name
            offset = np.load(path, mmap_mode="r").offset
            assert path.stat().st_size == offset + plain.nbytes, name        # nothing after the data
            np.testing.assert_array_equal(plain, getattr(ref, name), err_msg=name)
            got = getattr(sim, name)
            assert isinstance(got, np.memmap) and got.mode == "r+" and Path(got.filename) == path.resolve(), name
        assert 0 < ref.valid.sum() < ref.valid.size and (ref.surface == 2).any()   # hits, misses and walls
    # a block that fails after the first ones were written: the folder goes, the error stays
    calls = []

    class Failing(pi.sensors.Sensor):
        shape = sensor.shape

        def rays(self, k0=0, k1=None):
            calls.append(k0)
            if len(calls) == 3:
                raise RuntimeError("sensor broke at block 3")
            return sensor.rays(k0, k1)

    with pytest.raises(RuntimeError, match="block 3"):
        pi.simulate_image(dsm, rgb, Failing(), occlusion=False, block_lines=9, out=tmp_path / "failed")
    assert calls == [0, 9, 18] and not (tmp_path / "failed").exists()


def _open_fds() -> int:
    import os

    return len(os.listdir("/proc/self/fd"))


@pytest.mark.skipif(not Path("/proc/self/fd").is_dir(), reason="counts open files through /proc/self/fd (Linux)")
def test_out_writer_faults_found_by_a_review(box, tmp_path, monkeypatch):
    """Five faults of the first block writer (simulation note 9), each now held:
    a sensor shape of NumPy integers; a relative out= while rays() changes the
    working directory; a close that fails while another error propagates, and
    one that fails on success; a MemoryError for the block buffer. Each time
    the error raised is the one that stopped the run, the folder is gone after
    a failure, and no file stays open."""
    from planet_intersect import simulate as sim_mod

    dsm, ortho, scene, sensor = box
    ref = pi.simulate_image(dsm, ortho, sensor, threads=1, occlusion=False)

    class Wrapped(pi.sensors.Sensor):
        def __init__(self, shape, on_rays=None):
            self.shape, self.on_rays = shape, on_rays

        def rays(self, k0=0, k1=None):
            if self.on_rays is not None:
                self.on_rays(k0)
            return sensor.rays(k0, k1)

    # NumPy integers in the shape: the header said "np.int64(100)" and np.load failed at the end
    sim = pi.simulate_image(dsm, ortho, Wrapped(tuple(np.array(sensor.shape))), threads=1, occlusion=False,
                            block_lines=10, out=tmp_path / "npint")
    np.testing.assert_array_equal(np.load(tmp_path / "npint" / "image.npy"), ref.image)
    del sim
    # a relative out= and a sensor that changes the working directory half-way
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    monkeypatch.chdir(tmp_path / "a")

    def move(k0):
        if k0 == 50:
            import os

            os.chdir(tmp_path / "b")

    sim = pi.simulate_image(dsm, ortho, Wrapped(sensor.shape, move), threads=1, occlusion=False, block_lines=10,
                            out="rel")
    assert Path(sim.lat.filename) == tmp_path / "a" / "rel" / "lat.npy" and not (tmp_path / "b" / "rel").exists()
    np.testing.assert_array_equal(sim.lat, ref.lat)
    del sim
    # a close that fails while a sensor error propagates: the sensor's error, every file closed
    fds = _open_fds()
    real_close = sim_mod._BlockFile.close

    def bad_close(self):
        real_close(self)
        if self.path.name == "lat.npy":
            raise OSError(28, "No space left on device (simulated)")

    def boom(k0):
        if k0 == 20:
            raise RuntimeError("sensor broke")

    monkeypatch.setattr(sim_mod._BlockFile, "close", bad_close)
    with pytest.raises(RuntimeError, match="sensor broke") as info:
        pi.simulate_image(dsm, ortho, Wrapped(sensor.shape, boom), occlusion=False, block_lines=10,
                          out=tmp_path / "c1")
    assert _open_fds() == fds and not (tmp_path / "c1").exists()
    del info
    monkeypatch.undo()
    # a flush that fails when the result is mapped: that error, the folder gone, nothing open
    real_result = sim_mod._BlockFile.result

    def bad_result(self):
        if self.path.name == "height.npy":
            raise OSError(28, "No space left on device (simulated)")
        return real_result(self)

    monkeypatch.setattr(sim_mod._BlockFile, "result", bad_result)
    with pytest.raises(OSError, match="No space left") as info:
        pi.simulate_image(dsm, ortho, sensor, occlusion=False, block_lines=10, out=tmp_path / "c2")
    assert _open_fds() == fds and not (tmp_path / "c2").exists()
    del info
    monkeypatch.undo()
    # no memory for a block buffer (65,000 lines of 65,000 pixels, ~2 TB of block temporaries): no
    # handle left open
    with pytest.raises(MemoryError) as info:
        pi.simulate_image(dsm, ortho, Wrapped((65_000, 65_000)), occlusion=False, block_lines=65_000,
                          out=tmp_path / "c3")
    assert _open_fds() == fds and not (tmp_path / "c3").exists()
    del info
    # more than MAX_PIXELS: refused before anything is opened, naming the sensor (200,000 x 200,000
    # failed on a 3.64 TiB allocation that did not: a review)
    with pytest.raises(ValueError, match=r"sensor: 200,000 x 200,000 = 40,000,000,000 pixels"):
        pi.simulate_image(dsm, ortho, Wrapped((200_000, 200_000)), occlusion=False, out=tmp_path / "c4")
    assert _open_fds() == fds and not (tmp_path / "c4").exists()


def test_shading_longitude_from_the_hit_point_near_the_polar_axis():
    """shade_one takes the longitude's cos and sin from the hit point (simulation
    note 14): rays 0 to 1e-3 m from the polar axis, nadir onto a dome on the
    pole whose slope is 20 m per 0.001 deg of latitude, all see the slope's
    angle atan(20 / ((M + h) 0.001 deg)) (M = a^2 / b at the pole). With the
    squares of ~1e-162 m (denormal) it was 11.39 and 10.01 deg (a review)."""
    a, f = 6378137.0, 1 / 298.257223563
    b = a * (1 - f)
    nr, nc, dl = 21, 72, 0.001
    lats = 90.0 - (nr - 1) * dl + dl * np.arange(nr)
    h = np.repeat((100.0 - 20000.0 * (90.0 - lats))[:, None], nc, axis=1)
    dsm = pi.GeodeticDSM.from_array(h, lats[0], -180.0, dl, 5.0, a=a, f=f, interpolation="bilinear")
    ortho = pi.OrthoImage.from_array(np.full((nr, nc), 100.0), lats[0], -180.0, dl, 5.0)
    xs = [0.0, 2.5e-162, 3.1e-162, 1e-160, 1e-3]

    class Raw(pi.sensors.Sensor):
        shape = (1, len(xs))

        def rays(self, k0=0, k1=None):
            return (np.array([[x, 0.0, b + 3000.0] for x in xs]), np.tile([0.0, 0.0, -1.0], (len(xs), 1)))

    sim = pi.simulate_image(dsm, ortho, Raw(), threads=1, occlusion=False, ground=np.zeros_like(h))
    assert sim.valid.all()
    li = sim.local_incidence[0]
    m_h = a * a / b + sim.height[0, 0]
    np.testing.assert_allclose(li, np.degrees(np.arctan(20.0 / (m_h * np.radians(dl)))), atol=1e-4)
    assert np.ptp(li[:4]) < 1e-10, li                 # within 1e-160 m of the axis: one point to rounding
    assert abs(li[4] - li[0]) < 1e-7, li              # 1 mm off it: the dome's slope 1 mm away


def test_occlusion_of_an_image_larger_than_its_dsm(box):
    """The occlusion pass when every border pixel of the image misses the DSM
    (a newcomer's walk-through, 2026-12-04: a 700^2 orbit image of a 600 m DSM
    marked 332 of ~3,200 hidden pixels). The box scene's DSM cropped to rows
    30-90 and columns 20-100, seen by the box pushbroom over the whole 120^2
    scene: the strip hidden behind the 20 m box at 9 deg is the same columns
    37-39 on its 20 rows as when the image lies inside the DSM (the box view
    test: h tan(theta) = 3.17 m), and the footprint is every ortho pixel on the
    cropped DSM (the image covers all of it)."""
    dsm_full, ortho, scene, _ = box
    s0, l0 = oblique_pushbroom(scene, zenith=9.0, azimuth=90.0, margin=0)
    sensor = pi.Pushbroom(s0, l0)
    h = scene["heights"][30:91, 20:101]
    dsm = pi.GeodeticDSM.from_array(h, scene["lat_first"] + 30 * scene["dlat"], scene["lon_first"] + 20 * scene["dlon"],
                                    scene["dlat"], scene["dlon"], interpolation="nearest")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim = pi.simulate_image(dsm, ortho, sensor, threads=1, ground=np.zeros_like(h))
    assert not (sim.valid[0].any() or sim.valid[-1].any() or sim.valid[:, 0].any() or sim.valid[:, -1].any())
    hidden_rows, hidden_cols = np.nonzero(sim.occlusion)
    assert sorted(set(hidden_rows.tolist())) == list(range(50, 70)), hidden_rows
    assert sorted(set(hidden_cols.tolist())) == [37, 38, 39] and len(hidden_rows) == 60
    on_dsm = np.zeros(ortho.shape, dtype=bool)
    on_dsm[30:91, 20:101] = True
    assert np.array_equal(sim.footprint, on_dsm), int(sim.footprint.sum())


def test_box_view_from_east_roof_wall_and_hidden_ground(box):
    """The box (rows 50-69, cols 40-79, 20 m) seen from the east at 9 deg: on a
    line through it, ground | roof (shifted west) | east wall | ground; the wall
    pixels carry the vertical ramp from roof colour (200) to ground colour."""
    dsm, ortho, scene, sensor = box
    sim = pi.simulate_image(dsm, ortho, sensor)
    line = sim.surface[60 - 10]                       # scene row 60, pixel m = column m + 10
    kinds = "".join(".RW"[c] for c in line)
    roof = [m + 10 for m, c in enumerate(line) if c == 1]
    wall = [m + 10 for m, c in enumerate(line) if c == 2]
    shift = 20.0 * np.tan(np.radians(9.0))            # 3.17 m: the roof image moves 3 columns west
    assert roof[0] == 40 - 3 and roof[-1] == 79 - 3, kinds
    assert wall == [77, 78, 79], kinds                # the east wall, h tan(theta) = 3.2 m wide
    w = sim.image[50, [m - 10 for m in wall]]
    assert (np.diff(w) < 0).all() and 50 < w.min() and w.max() < 200       # roof edge -> foot, ramp in height
    t = sim.height[50, [m - 10 for m in wall]] / 20.0           # the ramp is linear in height
    foot = ortho.sample(sim.lat[50, wall[0] - 10], sim.lon[50, wall[0] - 10] + 0.5 * scene["dlon"])
    np.testing.assert_allclose(w, (1 - t) * foot + t * 200.0, rtol=1e-6)   # float32 image
    hidden = np.nonzero(sim.occlusion[60])[0]
    assert hidden.tolist() == [37, 38, 39], hidden   # the ground strip west of the box
    assert abs(len(hidden) - shift) < 1
    assert (sim.surface[sim.valid] >= 0).all() and not (sim.surface[~sim.valid] >= 0).any()


def test_rays_that_miss_get_fill_and_no_hit(box):
    dsm, ortho, scene, sensor = box
    s, l = sensor.rays(0, 2)
    l = l.copy()
    l[: sensor.npixels] = -l[: sensor.npixels]        # line 0 looks up to space
    pb = pi.Pushbroom(s.reshape(2, -1, 3)[:, 0], l.reshape(2, -1, 3))
    sim = pi.simulate_image(dsm, ortho, pb, fill=-7.0, occlusion=False)
    assert (sim.image[0] == -7.0).all() and not sim.valid[0].any() and (sim.surface[0] == -1).all()
    assert np.isnan(sim.lat[0]).all() and sim.valid[1].all()
    assert (sim.status[0] == pi.DSMStatus.MISS).all()


def test_walls_option_and_lambert_shading(box):
    dsm, ortho, scene, sensor = box
    a = pi.simulate_image(dsm, ortho, sensor, occlusion=False)
    b = pi.simulate_image(dsm, ortho, sensor, walls="ortho", occlusion=False)
    differ = a.image != b.image
    assert differ.any() and (a.surface[differ] == 2).all()      # only wall pixels change
    # Sun overhead, no ambient: flat tops keep cos(0) ~ their value (ellipsoid normal vs local up: 0 here)
    c = pi.simulate_image(dsm, ortho, sensor, shading="lambert", sun=(0.0, 90.0), ambient=0.0, occlusion=False)
    flat = a.surface != 2
    np.testing.assert_allclose(c.image[flat], a.image[flat], rtol=1e-6)
    assert np.abs(c.image[a.surface == 2]).max() < 1e-9          # vertical walls get no overhead light
    with pytest.raises(ValueError, match="sun"):
        pi.simulate_image(dsm, ortho, sensor, shading="lambert")


@pytest.mark.parametrize("kw, match", [
    (dict(method="stepping"), "method"), (dict(walls="paint"), "walls"), (dict(shading="phong"), "shading"),
    (dict(ambient=2.0), "ambient"), (dict(block_lines=0), "block_lines"), (dict(wall_slope=95.0), "wall_slope"),
    (dict(shading="lambert", sun=(1.0, 2.0, 3.0, 4.0)), "sun"), (dict(ground=np.zeros((3, 3))), "ground"),
    (dict(threads=-1), "threads"),
])
def test_simulate_bad_arguments(box, kw, match):
    dsm, ortho, scene, sensor = box
    with pytest.raises((ValueError, TypeError), match=match):
        pi.simulate_image(dsm, ortho, sensor, **kw)


def test_simulate_bad_objects(box):
    dsm, ortho, scene, sensor = box
    with pytest.raises(TypeError, match="dsm"):
        pi.simulate_image(scene, ortho, sensor)
    with pytest.raises(TypeError, match="ortho"):
        pi.simulate_image(dsm, np.zeros((3, 3)), sensor)
    with pytest.raises(TypeError, match="sensor"):
        pi.simulate_image(dsm, ortho, (np.zeros(3), np.ones(3)))
    with pytest.raises(ValueError, match="l"):
        pi.Pushbroom(np.zeros((2, 3)), np.zeros((3, 4, 3)))
    with pytest.raises(ValueError, match="NaN"):
        pi.FrameCamera([1.0, 2.0, np.nan], np.ones((2, 2, 3)))


def test_save_formats_and_no_overwrite(box, tmp_path):
    dsm, ortho, scene, sensor = box
    sim = pi.simulate_image(dsm, ortho, sensor, occlusion=False)
    png = sim.save(tmp_path / "a.png")
    from matplotlib import image as mimage

    assert mimage.imread(png).shape[:2] == sim.shape
    with pytest.raises(FileExistsError, match="a.png"):
        sim.save(png)
    with pytest.raises(ValueError, match="format"):
        sim.save(tmp_path / "a.jpg")
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF writing needs rasterio")
    with rasterio.open(sim.save(tmp_path / "a.tif")) as src:
        assert src.descriptions[1] == "lat"
        np.testing.assert_array_equal(src.read(2), sim.lat)
        np.testing.assert_array_equal(src.read(8), sim.surface)
    xr = pytest.importorskip("xarray", reason="NetCDF needs xarray")
    with xr.open_dataset(sim.save(tmp_path / "a.nc"), engine="h5netcdf") as ds:
        np.testing.assert_array_equal(ds["height"].values, sim.height)
        assert "wall" in ds.attrs["surface_codes"]


# ------------------------------------------------------ the paper's experiment
@pytest.fixture(scope="module")
def paper():
    from planet_intersect.sim_run import paper_experiment

    return paper_experiment(size=256)


def test_paper_experiment_against_the_scene_truth(paper):
    """Every exact roof pixel hits a building cell, every ground pixel an open
    cell, walls sit on a building's boundary; no pixel fails; the iterative
    method fails on walls (the paper's white regions) and lands on the ground
    behind roofs (its Fig. 1c), never on open ground far from buildings."""
    from planet_intersect.sim_run import wrong_surface

    sc, ex, it = paper["scene"], paper["sims"]["exact"], paper["sims"]["iterative"]
    dsm = paper["dsm"]
    assert ex.valid.all()
    u = np.rint((ex.lat - sc["lat_first"]) / sc["dlat"]).astype(int)
    v = np.rint((ex.lon - sc["lon_first"]) / sc["dlon"]).astype(int)
    rid = sc["roof_id"][np.clip(u, 0, 255), np.clip(v, 0, 255)]
    assert (rid[ex.surface == 1] > 0).all()
    assert (rid[ex.surface == 0] == 0).all()
    from scipy import ndimage

    near_building = ndimage.binary_dilation(sc["roof_id"] > 0, iterations=2)
    assert near_building[u[ex.surface == 2], v[ex.surface == 2]].all()
    nonconv = np.isin(it.status, (pi.DSMStatus.OSCILLATION, pi.DSMStatus.NOT_CONVERGED))
    assert nonconv.sum() > 100 and (it.surface == 2).sum() == 0
    wrong = wrong_surface(it, ex)
    assert wrong.sum() > 100
    assert np.isin(ex.surface[wrong], (1, 2)).mean() > 0.95       # the exact hit was on a roof or wall
    assert ex.occlusion.sum() > 100 and (ex.occlusion <= ex.footprint).all()
    assert dsm.interpolation == "nearest"


def test_paper_scene_is_deterministic():
    a, b = paper_scene(128), paper_scene(128)
    np.testing.assert_array_equal(a["ortho"], b["ortho"])
    np.testing.assert_array_equal(a["heights"], b["heights"])
    assert set(np.unique(a["roof_id"])) == {0, 1, 2, 3, 4}
    assert a["ortho"].dtype == np.uint8 and a["ortho"].shape == (128, 128, 3)


# --------------------------------------------------------------------- the CLI
def test_cli_simulate_from_geotiffs(tmp_path, capsys):
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF files need rasterio")
    from rasterio.transform import from_origin

    from planet_intersect.cli import main

    sc = paper_scene(160)
    n = sc["heights"].shape[0]
    west, north = sc["lon_first"] - sc["dlon"] / 2, sc["lat_first"] - sc["dlat"] / 2
    tr = from_origin(west, north, sc["dlon"], -sc["dlat"])
    with rasterio.open(tmp_path / "dsm.tif", "w", driver="GTiff", width=n, height=n, count=1, dtype="float64",
                       crs="EPSG:4326", transform=tr) as dst:
        dst.write(sc["heights"], 1)
    with rasterio.open(tmp_path / "ortho.tif", "w", driver="GTiff", width=n, height=n, count=3, dtype="uint8",
                       crs="EPSG:4326", transform=tr) as dst:
        dst.write(np.moveaxis(sc["ortho"], -1, 0))
    rc = main(["simulate", "--dsm", str(tmp_path / "dsm.tif"), "--ortho", str(tmp_path / "ortho.tif"),
               "--oblique", "9,90", "--margin", "16", "--interpolation", "nearest", "--quiet",
               "--out", str(tmp_path / "out")])
    out = capsys.readouterr().out
    assert rc == 0, out
    run = tmp_path / "out" / "run-001"
    for name in ("simulated.png", "simulated.tif", "simulated.nc", "simulated_surface.png",
                 "simulated_occlusion.png"):
        assert (run / name).is_file(), name
    with rasterio.open(run / "simulated.tif") as src:
        assert src.count == 3 + 10 and src.width == n - 32 and src.height == n - 32   # + status, ortho_value
    assert "wall" in out
    lat_c, lon_c = sc["lat_first"] + 79.5 * sc["dlat"], sc["lon_first"] + 79.5 * sc["dlon"]
    rc = main(["simulate", "--dsm", str(tmp_path / "dsm.tif"), "--ortho", str(tmp_path / "ortho.tif"), "--orbit",
               "--target", f"{lat_c},{lon_c}", "--lines", "48", "--pixels", "64", "--roll", "8.1", "--quiet",
               "--no-occlusion", "--out", str(tmp_path / "out")])
    out = capsys.readouterr().out
    assert rc == 0, out
    with rasterio.open(tmp_path / "out" / "run-002" / "simulated.tif") as src:
        assert (src.height, src.width) == (48, 64) and src.read(3 + 8).all()      # every pixel valid
    rc = main(["simulate", "--dsm", str(tmp_path / "dsm.tif"), "--out", str(tmp_path / "out")])
    assert rc == 2 and "--ortho" in capsys.readouterr().err
    assert not (tmp_path / "out" / "run-003").exists()


def test_cli_simulate_help_documents_a_run_from_files(capsys):
    from planet_intersect.cli import main

    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    text = capsys.readouterr().out
    assert "--dsm dsm.tif --ortho ortho.tif" in text and "--geometry" in text and "run-NNN" in text


def test_orbit_pushbroom_over_the_paper_scene():
    """A north-bound pass rolled to look west at 9 deg zenith at the ground
    (``off_nadir_angle``): every pixel hits, the ground is seen at 9 deg from
    the vertical, and the walls that show face east (toward the sensor)."""
    sc = paper_scene(256)
    dsm = pi.GeodeticDSM.from_array(sc["heights"], sc["lat_first"], sc["lon_first"], sc["dlat"], sc["dlon"],
                                    interpolation="nearest")
    ortho = pi.OrthoImage.from_array(sc["ortho"], sc["lat_first"], sc["lon_first"], sc["dlat"], sc["dlon"])
    lat_c = sc["lat_first"] + 127.5 * sc["dlat"]
    lon_c = sc["lon_first"] + 127.5 * sc["dlon"]
    h_c = float(np.median(sc["ground"]))
    sensor = pi.Pushbroom.from_orbit(altitude=685e3, inclination=98.1, target=(lat_c, lon_c, h_c), nlines=160,
                                     npixels=160, ifov=8.4e-5, roll=pi.off_nadir_angle(9.0, 685e3),
                                     line_period=1.0e-4)
    sim = pi.simulate_image(dsm, ortho, sensor, ground=sc["ground"], occlusion=False)
    assert sim.valid.all()
    ground = sim.surface == 0
    assert abs(np.median(sim.incidence[ground]) - 9.0) < 0.05
    corners = sensor.footprint_corners(dsm)
    assert np.isfinite(corners).all()
    walls = sim.surface == 2
    assert walls.sum() > 50
    # a wall seen from the east: its outward normal has a positive east component, so
    # stepping 1 m east of the hit goes down (the ground), 1 m west goes up (the roof)
    from planet_intersect.synthetic_dsm import metre_steps

    dlat, dlon = metre_steps(lat_c)
    east = dsm.height(sim.lat[walls], sim.lon[walls] + dlon)
    west = dsm.height(sim.lat[walls], sim.lon[walls] - dlon)
    assert np.mean(west > east) > 0.9


@pytest.mark.parametrize("interp, opts", [
    ("nearest", dict()),
    ("nearest", dict(walls="ortho", shading="lambert", sun=(120.0, 35.0), ambient=0.2)),
    ("bilinear", dict(shading="lambert", sun=(0.3, -0.2, 0.9))),
    ("bilinear", dict(wall_slope=45.0, roof_min=5.0)),
])
def test_shading_kernel_equals_the_numpy_rules(interp, opts):
    """The Fortran kernel (pi_simulate.f90) computes what the plain NumPy
    statement of the same rules (tests/references/sim_numpy.py, the code before
    the kernel) computes: image to 1e-9 relative (float32 storage aside),
    surface kinds identical, local incidence to 1e-5 deg. (The two place a hit
    in the grid with different roundings: the kernel wraps longitude about the
    grid's centre as pi_dsm does, ~1e-9 cell apart; on the twisted bilinear
    patch of a building corner the wall normal turns by up to ~1e-8 rad.)"""
    import math

    from references import sim_numpy

    sc = paper_scene(192)
    dsm = pi.GeodeticDSM.from_array(sc["heights"], sc["lat_first"], sc["lon_first"], sc["dlat"], sc["dlon"],
                                    interpolation=interp)
    ortho = pi.OrthoImage.from_array(sc["ortho"], sc["lat_first"] - 0.3 * sc["dlat"], sc["lon_first"] + 0.4 * sc["dlon"],
                                     sc["dlat"] * 1.3, sc["dlon"] * 0.8)     # another grid than the DSM's
    sensor = pi.Pushbroom(*oblique_pushbroom(sc, zenith=20.0, azimuth=60.0, margin=20))
    sim = pi.simulate_image(dsm, ortho, sensor, ground=sc["ground"], occlusion=False, **opts)
    s, l = sensor.rays()
    res = pi.intersect(dsm, s, l, method="exact")
    idx = np.flatnonzero(res.hit)
    surf = sim_numpy.surface(dsm, sc["ground"])
    shading = opts.get("shading", "none")
    sun = np.asarray(opts["sun"], dtype=float) if "sun" in opts else None
    vals, kind, loc = sim_numpy.shade_hits(surf, ortho, res, idx, l, opts.get("walls", "interpolate"), shading, sun,
                                          opts.get("ambient", 0.0), math.cos(math.radians(opts.get("wall_slope", 60))),
                                          opts.get("roof_min", 2.0))
    vals = np.where(np.isfinite(vals), vals, 0.0)
    img = sim.image.reshape(len(res), -1)[idx]
    np.testing.assert_allclose(img, vals.reshape(len(idx), -1).astype(np.float32), rtol=1e-6, atol=1e-4)
    np.testing.assert_array_equal(sim.surface.ravel()[idx], kind)
    np.testing.assert_allclose(sim.local_incidence.ravel()[idx], loc, rtol=0, atol=1e-5)
    assert (kind == 2).sum() > 20 and (kind == 1).sum() > 100


def test_cli_simulate_from_projected_geotiffs(tmp_path, capsys):
    """A LiDAR-style pair in UTM (EPSG:32617, metres): both are warped to
    geodetic grids (the DSM by nearest neighbour, so walls stay sharp) and the
    run completes with walls and roofs in the image."""
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF files need rasterio")
    pytest.importorskip("pyproj", reason="the UTM corner needs pyproj")
    from pyproj import Transformer
    from rasterio.transform import from_origin

    from planet_intersect.cli import main

    n = 160
    x0, y0 = Transformer.from_crs("EPSG:4326", "EPSG:32617", always_xy=True).transform(-81.0, 36.5)
    h = np.full((n, n), 300.0)
    h[60:100, 50:90] = 330.0
    tr = from_origin(x0, y0, 1.0, 1.0)
    with rasterio.open(tmp_path / "dsm.tif", "w", driver="GTiff", width=n, height=n, count=1, dtype="float32",
                       crs="EPSG:32617", transform=tr, nodata=-9999) as dst:
        dst.write(h.astype(np.float32), 1)
    rgb = np.zeros((3, n, n), dtype=np.uint8)
    rgb[1] = 120
    rgb[0, 60:100, 50:90] = 220
    with rasterio.open(tmp_path / "ortho.tif", "w", driver="GTiff", width=n, height=n, count=3, dtype="uint8",
                       crs="EPSG:32617", transform=tr) as dst:
        dst.write(rgb)
    rc = main(["simulate", "--dsm", str(tmp_path / "dsm.tif"), "--ortho", str(tmp_path / "ortho.tif"),
               "--oblique", "20,90", "--margin", "25", "--quiet", "--out", str(tmp_path / "out")])
    out = capsys.readouterr().out
    assert rc == 0, out
    import xarray as xr

    with xr.open_dataset(tmp_path / "out" / "run-001" / "simulated.nc", engine="h5netcdf") as ds:
        surf = ds["surface"].values
        img = ds["image"].values
    assert (surf == 1).sum() > 500 and (surf == 2).sum() > 50
    roof = surf == 1
    # roofs show the roof's colour, but for a rim: the ortho is warped bilinearly, the DSM by
    # nearest neighbour, so their edges do not coincide to the pixel
    assert np.mean(np.abs(img[roof][:, 0] - 220) < 1) > 0.8


def test_footprint_polygon_fill_equals_a_point_in_polygon_test():
    """The scanline fill behind ``footprint`` against matplotlib's
    point-in-polygon test (every grid point against every edge), on convex,
    star-shaped and self-intersecting polygons."""
    from matplotlib.path import Path as MPath

    from planet_intersect.simulate import _fill_polygon

    rng = np.random.default_rng(0)
    uu, vv = np.meshgrid(np.arange(40), np.arange(50), indexing="ij")
    pts = np.column_stack([uu.ravel(), vv.ravel()])
    total = 0
    for trial in range(300):
        n = int(rng.integers(3, 40))
        ang = np.sort(rng.uniform(0, 2 * np.pi, n))
        r = rng.uniform(3, 20, n) if trial % 2 else np.full(n, 15.0)
        pu, pv = 20 + r * np.sin(ang) + rng.uniform(-0.3, 0.3), 25 + r * np.cos(ang)
        if trial % 3 == 0:
            pu, pv = rng.uniform(-5, 45, n), rng.uniform(-5, 55, n)
        mask = _fill_polygon(pu, pv, 40, 50)
        ref = MPath(np.column_stack([pu, pv])).contains_points(pts).reshape(40, 50)
        np.testing.assert_array_equal(mask, ref, err_msg=f"polygon {trial}")
        total += ref.sum()
    assert total > 50000
