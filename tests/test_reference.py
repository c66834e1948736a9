"""Fortran core vs the independent NumPy transcription (planet_intersect.reference),
ray by ray, on >= 10,000 rays of mixed geometry, both step modes, both read modes."""

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect import reference

from conftest import mixed_rays

N_RAYS = 12000


@pytest.fixture(scope="module")
def rays(rough):
    return mixed_rays(rough, N_RAYS, seed=2008)


@pytest.mark.parametrize("step_mode", [0, 1])
@pytest.mark.parametrize("dem_read_mode", [0, 1])
def test_fortran_matches_reference(rough_file, rays, step_mode, dem_read_mode):
    s, l, kind = rays
    dem = rough_file
    res = pi.intersect(dem, s, l, step_mode=step_mode, dem_read_mode=dem_read_mode, tangent="paper")
    ref = reference.intersect(np.asarray(dem.radii), dem.ppd, dem.rmax, dem.f, dem.re, s, l, step_mode=step_mode)

    # every geometry class is present, and the mix has hits, limb views and rays pointing away
    assert set(kind) == {"nadir", "oblique", "grazing", "limb", "away", "pole", "antimeridian", "inside_rmax"}
    counts = np.bincount(res.status, minlength=4)
    assert counts[0] > 3000 and counts[1] > 2000 and counts[2] > 500

    np.testing.assert_array_equal(res.status, ref["status"])
    np.testing.assert_array_equal(res.hit, (ref["status"] == 0) | (ref["status"] == 3))
    np.testing.assert_array_equal(res.nsteps, ref["nsteps"])
    R = dem.rmax
    for key in ("p", "t", "tc", "sc"):
        a, b = getattr(res, key), ref[key]
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b), err_msg=key)
        assert np.nanmax(np.abs(a - b)) <= 1e-9 * R, key
    for key in ("radius", "tangent_altitude", "tangent_height"):
        a, b = getattr(res, key), ref[key]
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b), err_msg=key)
        assert np.nanmax(np.abs(a - b)) <= 1e-9 * R, key
    for key in ("lat", "emission", "tangent_lat"):
        a, b = getattr(res, key), ref[key]
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b), err_msg=key)
        assert np.nanmax(np.abs(a - b)) <= 1e-9, key
    for key in ("lon", "tangent_lon"):   # compare on the circle: 359.999... and 0 are neighbours
        a, b = getattr(res, key), ref[key]
        diff = np.abs((a - b + 180.0) % 360.0 - 180.0)
        assert np.nanmax(diff) <= 1e-9, key


def test_reference_radius_matches_fortran(rough):
    rng = np.random.default_rng(3)
    lat = np.concatenate([rng.uniform(-90, 90, 5000), [-90, 90, -89.9, 89.9, 0.0], rng.uniform(89.5, 90, 200)])
    lon = np.concatenate([rng.uniform(-360, 720, 5000), [0, 360, 0.25, 359.75, 0.0], rng.uniform(0, 360, 200)])
    grid = reference._Grid(np.asarray(rough.radii), rough.ppd)
    np.testing.assert_allclose(rough.radius(lat, lon), reference.dem_radius(grid, lat, lon), rtol=0, atol=1e-9)
