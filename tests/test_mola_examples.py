"""Real Mars topography (MOLA MEGDR) and the paper's two examples (section 4)."""

import urllib.request

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect import examples, mola

from conftest import shared_data_or_skip
from golden import GOLDEN, MOLA_RADIUS, limb_fields, olympus_fields


@pytest.fixture(scope="module")
def mola4():
    return mola.mola_dem(shared_data_or_skip(*MOLA_RADIUS))


def test_mola_radius_grid_landmarks(mola4):
    r = np.asarray(mola4.radii, dtype=np.float64)
    assert r.shape == (720, 1440) and mola4.ppd == 4
    assert (mola4.re, mola4.f) == (3396.19, 1 / 169.8)
    # area-weighted mean radius of Mars: 3389.5 km
    w = np.cos(np.radians(mola4.lat))[:, None]
    assert abs((r * w).sum() / (w.sum() * r.shape[1]) - 3389.5) < 0.05
    # Olympus Mons: the grid's highest cell, ~21 km above the 3396 km datum, near 18.65 N 226.2 E
    j, i = np.unravel_index(np.argmax(r), r.shape)
    assert abs(mola4.lat[j] - 18.65) < 1.5 and abs(mola4.lon[i] - 226.2) < 1.0
    assert abs(r.max() - (3396.0 + 21.2)) < 0.2
    assert 3396.0 + 19.0 < mola4.radius(18.65, 226.2) < 3396.0 + 21.2
    # Hellas floor, south row first: 42.4 S 70.5 E is about 14 km below the datum
    assert 3381.0 < mola4.radius(-42.4, 70.5) < 3383.0
    # orientation: south polar row below the north? (no -- the south pole is ~6 km higher)
    assert r[0].mean() - r[-1].mean() > 5.0


def test_topography_plus_areoid_equals_radius_grid(mola4):
    d = shared_data_or_skip("mars_mola_megdr_4ppd")
    pair = mola.mola_dem(topography=d / "megt90n000cb.img", areoid=d / "mars_areoid_4ppd_ggm1025a_deg50.i2be")
    # the radius file was rounded to whole metres from the unrounded areoid
    assert np.max(np.abs(np.asarray(pair.radii, float) - np.asarray(mola4.radii, float))) <= 0.0011


def test_import_and_fetch_paths(tmp_path):
    src = shared_data_or_skip(*MOLA_RADIUS)
    hdr = mola.import_mola(tmp_path / "mola4", radius=src)
    dem = pi.DEM.read(hdr)
    assert dem.ppd == 4 and dem.radii.dtype == np.float32
    with pytest.raises(FileExistsError):
        mola.import_mola(tmp_path / "mola4", radius=src)
    # fetch-mola's download, size check and import, on a local file:// "server"
    server = tmp_path / "server" / "meg004"
    server.mkdir(parents=True)
    (server / "megr90n000cb.img").write_bytes(src.read_bytes())
    seen = []
    out = mola.fetch_mola(tmp_path / "fetched", base_url=(tmp_path / "server").as_uri(),
                          progress=lambda done, total: seen.append(done))
    assert pi.DEM.read(out).rmax == dem.rmax and seen[-1] == src.stat().st_size
    # a truncated download is rejected and leaves nothing behind
    (server / "megr90n000cb.img").write_bytes(src.read_bytes()[:1000])
    with pytest.raises(OSError, match="gave 1000 bytes, expected 2073600"):
        mola.fetch_mola(tmp_path / "again", base_url=(tmp_path / "server").as_uri())
    assert not (tmp_path / "again").exists()          # (the folder it made is removed too)


@pytest.fixture(scope="module")
def olympus_run(mola4):
    return examples.olympus(mola4)


def test_example1_olympus_lapse_rate(olympus_run, mola4):
    ex = olympus_run
    r = ex.res
    # the 1.5 rad field of view, centred 20 deg off nadir, stays below the horizon: all pixels hit
    assert r.hit.sum() == 101 * 101
    # altitudes above the 3389.5 km mean surface: the summit region is in view (the DEM's
    # highest cell is 27.74 km up) and the lowest pixels are on the plains at the foot
    assert 27.0 < np.nanmax(ex.z) <= mola4.rmax - 3389.5
    assert 0.0 < np.nanmin(ex.z) < 3.0
    # the least-squares line recovers the lapse rate and T0 within 3 standard errors
    assert abs(ex.lapse_fit - ex.lapse) < 3 * ex.lapse_se
    assert abs(ex.T0_fit - ex.T0) < 3 * ex.T0_se
    assert ex.lapse_se < 0.01 and ex.T0_se < 0.1


@pytest.fixture(scope="module")
def limb_run(mola4):
    return examples.limb(mola4)


def test_example2_limb(limb_run):
    ex = limb_run
    status = ex.grid("status")
    height = ex.grid("tangent_height")
    assert ex.npix == 21 and ex.nframes == 121
    limb = status == pi.RayStatus.LIMB
    assert set(np.unique(status)) <= {0, 1}
    for f in range(ex.nframes):
        h = height[f][limb[f]]
        assert np.all(np.diff(h) > 0), f"frame {f}: tangent height not increasing up the array"
        hits = np.flatnonzero(~limb[f])
        # hitting pixels are the lowest ones: a contiguous block from pixel 0
        assert np.array_equal(hits, np.arange(hits.size)), f"frame {f}"
    # the Fig. 1b effect: pixels whose line misses the smooth spheroid but hits the mountain
    mountain = (~limb) & ex.spheroid_miss
    frames_with = np.flatnonzero(mountain.any(axis=1))
    assert mountain.sum() == 195 and frames_with.size > 10
    # ... and they land on Olympus Mons itself, kilometres above the spheroid
    lat = ex.grid("lat")[mountain]
    assert np.all((lat > 13.0) & (lat < 24.0))
    assert np.all(ex.grid("altitude")[mountain] > 4.0)


def _compare(current: dict, golden_file):
    golden = np.load(golden_file)
    assert set(golden.files) == set(current)
    for key in golden.files:
        g, c = golden[key], np.asarray(current[key])
        if g.dtype.kind in "iu":
            np.testing.assert_array_equal(c, g, err_msg=key)
        else:
            np.testing.assert_allclose(c, g, rtol=1e-9, atol=0, equal_nan=True, err_msg=key)


def test_golden_olympus(olympus_run):
    _compare(olympus_fields(olympus_run), GOLDEN / "olympus_mola4.npz")


def test_golden_limb(limb_run):
    _compare(limb_fields(limb_run), GOLDEN / "limb_mola4.npz")
