"""The order in which a batch of DSM rays is traced (fortran/pi_ray_order.f90).

The core traces an incoherent batch (rays landing far from their predecessors:
independent lines of sight) in the Z-order of where the rays meet the
ellipsoid raised to the DSM's middle height, so that the grid stays in cache;
a coherent batch (image lines, scans) keeps its order. Only speed may depend
on it. The checks:

* the order is a permutation; it puts consecutive rays' landings close
  together (their mean distance falls from ~1 km to a few cells, measured
  here with an ellipsoid intersection written for this test);
* coherent and small batches keep the identity order; rays that miss the
  raised ellipsoid, point away or are not finite go last, in their order;
* every method's answers are the same bit for bit whatever the order in
  which the rays come and however the batch is cut (a sorted batch against
  batches of 200 rays, which are never sorted), on one thread and two,
  with fans of shared focal points in the batch.
"""

from __future__ import annotations

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect import _core
from planet_intersect import synthetic_dsm as sd

MIN_SORTED = 256                    # pi_ray_order's ray_order_min


@pytest.fixture(scope="module")
def scene():
    grid = sd.building_scene(n=384, seed=5)
    grid.pop("roof_id")
    dsm = pi.GeodeticDSM.from_array(grid["heights"], grid["lat_first"], grid["lon_first"], grid["dlat"],
                                    grid["dlon"], a=grid["a"], f=grid["f"])
    return grid, dsm


def core_order(dsm, s, l):
    g = dsm._core_grid()
    order, srt = _core.core_ray_order(*g[:7], g[7], dsm.hmax, dsm.hmin, np.ascontiguousarray(s, dtype=float).T,
                                      np.ascontiguousarray(l, dtype=float).T)
    return order - 1, bool(srt)


def landing(s, l, a, b):
    """First intersection of each line with the ellipsoid (a, a, b), by the textbook quadratic
    in r (NaN where it misses or lies behind s)."""
    w = np.array([1 / a, 1 / a, 1 / b])
    S, L = s * w, l * w
    A = np.einsum("ij,ij->i", L, L)
    B = 2 * np.einsum("ij,ij->i", S, L)
    C = np.einsum("ij,ij->i", S, S) - 1
    disc = B * B - 4 * A * C
    with np.errstate(invalid="ignore"):
        r = (-B - np.sqrt(disc)) / (2 * A)
    r = np.where((disc >= 0) & (r >= 0), r, np.nan)
    return s + r[:, None] * l


def test_independent_rays_are_sorted_into_neighbourhoods(scene):
    grid, dsm = scene
    s, l = sd.pushbroom_rays(grid, 3000, seed=8)
    order, srt = core_order(dsm, s, l)
    assert srt
    assert np.array_equal(np.sort(order), np.arange(len(s)))
    hm = 0.5 * (dsm.hmax + dsm.hmin)
    p = landing(s, l, grid["a"] + hm, grid["a"] * (1 - grid["f"]) + hm)
    assert np.isfinite(p).all()
    given = np.linalg.norm(np.diff(p, axis=0), axis=1)
    after = np.linalg.norm(np.diff(p[order], axis=0), axis=1)
    # a 384 m scene: random landings ~200 m apart on average; in Z-order about the spacing of
    # the points themselves, sqrt(area / n) (~7 m here)
    nr, nc = grid["heights"].shape
    lat = np.radians(grid["lat_first"] + 0.5 * nr * grid["dlat"])
    area = (nr * np.radians(abs(grid["dlat"])) * grid["a"]) * (nc * np.radians(grid["dlon"]) * grid["a"] * np.cos(lat))
    spacing = np.sqrt(area / len(p))
    assert np.mean(given) > 100.0
    assert np.median(after) < 1.2 * spacing
    assert np.mean(after) < 0.1 * np.mean(given)


def test_coherent_and_small_batches_keep_their_order(scene):
    grid, dsm = scene
    # the lines of a pushbroom: consecutive pixels ~1 m apart on the ground
    sen = pi.Pushbroom.from_orbit(altitude=600e3, inclination=97.5, npixels=200, ifov=np.degrees(1 / 600e3),
                                  nlines=10, line_period=1 / 7000.0,
                                  target=(grid["lat_first"] + 190 * grid["dlat"], grid["lon_first"] + 190 * grid["dlon"]),
                                  roll=20.0, a=grid["a"], f=grid["f"])
    s, l = sen.rays()
    order, srt = core_order(dsm, s, l)
    assert not srt and np.array_equal(order, np.arange(len(s)))
    s2, l2 = sd.pushbroom_rays(grid, MIN_SORTED - 1, seed=9)
    order, srt = core_order(dsm, s2, l2)
    assert not srt and np.array_equal(order, np.arange(len(s2)))
    s3, l3 = sd.pushbroom_rays(grid, MIN_SORTED, seed=9)
    order, srt = core_order(dsm, s3, l3)
    assert srt and not np.array_equal(order, np.arange(len(s3)))


def test_rays_without_a_landing_go_last_in_their_order(scene):
    grid, dsm = scene
    s, l = sd.pushbroom_rays(grid, 1000, seed=10)
    s, l = s.copy(), l.copy()
    away = [3, 500, 999]
    l[away] = -l[away]                                   # pointing to space
    l[17] = 0.0                                          # no direction
    s[40] = np.nan                                       # no position
    l[41] = [np.inf, 0.0, 0.0]
    l[600] = s[600] / np.linalg.norm(s[600])             # radially outwards
    last = sorted(away + [17, 40, 41, 600])
    order, srt = core_order(dsm, s, l)
    assert srt
    assert list(order[-len(last):]) == last
    assert set(order[:-len(last)]) == set(range(len(s))) - set(last)


@pytest.mark.parametrize("method", ["exact", "following", "iterative"])
@pytest.mark.parametrize("threads", [1, 2])
def test_answers_do_not_depend_on_the_order(scene, method, threads):
    grid, dsm = scene
    s, l = sd.pushbroom_rays(grid, 1200, seed=11)
    # a fan of rays with one focal point in the middle of the batch (swept by the exact mode)
    sen = pi.Pushbroom.from_orbit(altitude=650e3, inclination=97.5, npixels=150, ifov=np.degrees(1 / 650e3),
                                  nlines=2, line_period=1 / 7000.0,
                                  target=(grid["lat_first"] + 150 * grid["dlat"], grid["lon_first"] + 200 * grid["dlon"]),
                                  roll=12.0, a=grid["a"], f=grid["f"])
    fs, fl = sen.rays()
    s = np.concatenate([s[:600], fs, s[600:]])
    l = np.concatenate([l[:600], fl, l[600:]])
    assert core_order(dsm, s, l)[1]                      # the whole batch is sorted
    fields = ("status", "distance", "lat", "lon", "height", "surface_height", "incidence", "nsteps")
    whole = pi.intersect(dsm, s, l, method=method, threads=threads)
    assert np.sum(whole.hit) > (0.9 if method != "iterative" else 0.4) * len(s)
    # in batches of 200 (below ray_order_min: traced in the given order; the fan split across two)
    parts = [pi.intersect(dsm, s[k:k + 200], l[k:k + 200], method=method, threads=threads)
             for k in range(0, len(s), 200)]
    # reversed (the fan's rays too: its runs of one focal point stay runs)
    rev = pi.intersect(dsm, s[::-1], l[::-1], method=method, threads=threads)
    for f in fields:
        a = np.asarray(getattr(whole, f))
        b = np.concatenate([np.asarray(getattr(p, f)) for p in parts])
        c = np.asarray(getattr(rev, f))[::-1]
        if method == "exact":
            # the fan cut at a batch boundary, or reversed, is swept in other chunks: the exact
            # mode's answers within its tolerance there, not bit for bit (dsm_trace_packed);
            # every other ray's identical
            fan = np.zeros(len(s), bool)
            fan[600:600 + len(fs)] = True
            assert np.array_equal(a[~fan], b[~fan], equal_nan=True), f
            assert np.array_equal(a[~fan], c[~fan], equal_nan=True), f
            if f == "status":
                assert np.array_equal(a, b) and np.array_equal(a, c)
            elif f == "distance":
                assert np.nanmax(np.abs(a - b)) <= 2e-6 and np.nanmax(np.abs(a - c)) <= 2e-6
        else:
            assert np.array_equal(a, b, equal_nan=True), f
            assert np.array_equal(a, c, equal_nan=True), f


def test_long_directions_are_ordered_as_unit_ones(scene):
    """|l| up to 1e300 (the core takes any length; pi.intersect scales l first): the landing is
    computed on l scaled to its largest component (a review found |l| >= 1e161 overflowing to
    inf - inf, and such rays sent last)."""
    grid, dsm = scene
    s, l = sd.pushbroom_rays(grid, 600, seed=12)
    o1, srt1 = core_order(dsm, s, l)
    o2, srt2 = core_order(dsm, s, l * 1e300)
    o3, srt3 = core_order(dsm, s, l * 1e-300)
    assert srt1 and srt2 and srt3
    assert np.array_equal(o1, o2) and np.array_equal(o1, o3)
