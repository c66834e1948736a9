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

    assert counts[3] == 0          # every refinement converged (paper-notes, note 5)
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


def named_edge_rays(dem):
    """Rugged-style named edge cases."""
    from conftest import xyz, unit
    rays = {}
    R = dem.rmax
    # a ray in the meridian plane lon = 0/180 through both polar caps (grazing over the north pole)
    rays["meridian_over_pole"] = (np.array([-3000.0, 0.0, R - 2.0]), np.array([1.0, 0.0, 0.0]))
    # exactly nadir onto each pole, and onto the equator at 0 E
    rays["nadir_north_pole"] = (np.array([0.0, 0.0, R + 500.0]), np.array([0.0, 0.0, -1.0]))
    rays["nadir_south_pole"] = (np.array([0.0, 0.0, -R - 500.0]), np.array([0.0, 0.0, 1.0]))
    rays["nadir_lon0"] = (np.array([R + 500.0, 0.0, 0.0]), np.array([-1.0, 0.0, 0.0]))
    # along a parallel (constant latitude plane z = const) grazing the surface at 30 N
    z = 3390.0 * np.sin(np.radians(30))
    rays["along_parallel"] = (np.array([-4000.0, 3390.0 * np.cos(np.radians(30)) - 1.0, z]), np.array([1.0, 0.0, 0.0]))
    # aimed exactly at a grid node and at a cell corner (midway between four nodes)
    node = xyz(dem.lat[100], dem.lon[200], 3380.0)
    corner = xyz(dem.lat[100] + 0.5 / dem.ppd, dem.lon[200] + 0.5 / dem.ppd, 3380.0)
    for name, target in (("at_node", node), ("at_cell_corner", corner)):
        s = target + 800.0 * unit(target) + 300.0 * unit(np.cross(target, [0, 0, 1.0]))
        rays[name] = (s, target - s)
    # a ray crossing 0/360 E exactly on the equator, moving east to west
    rays["antimeridian_equator"] = (np.array([3000.0, 2000.0, 0.0]), np.array([0.0, -1.0, 0.0]))
    return rays


@pytest.mark.parametrize("step_mode", [0, 1])
def test_named_edge_cases(rough, step_mode):
    rays = named_edge_rays(rough)
    s = np.array([v[0] for v in rays.values()])
    l = np.array([v[1] for v in rays.values()], dtype=float)
    l /= np.linalg.norm(l, axis=1, keepdims=True)
    res = pi.intersect(rough, s, l, step_mode=step_mode, tangent="paper")
    ref = reference.intersect(np.asarray(rough.radii), rough.ppd, rough.rmax, rough.f, rough.re, s, l, step_mode=step_mode)
    np.testing.assert_array_equal(res.status, ref["status"])
    assert np.nanmax(np.abs(res.p - ref["p"])) <= 1e-9 * rough.rmax
    names = list(rays)
    hit = dict(zip(names, res.hit))
    for name in ("nadir_north_pole", "nadir_south_pole", "nadir_lon0", "at_node", "at_cell_corner"):
        assert hit[name], name
    # nadir hits lie straight below the spacecraft, at the DEM radius there
    for name, lat in (("nadir_north_pole", 90.0), ("nadir_south_pole", -90.0)):
        k = names.index(name)
        assert abs(res.lat[k] - lat) < 1e-9
        np.testing.assert_allclose(res.radius[k], rough.radius(lat, 0.0), rtol=0, atol=1e-9 * rough.rmax)
    # every hit lies on the interpolated surface
    h = res.hit
    np.testing.assert_allclose(res.radius[h], rough.radius(res.lat[h], res.lon[h]), rtol=0, atol=1e-9 * rough.rmax)
