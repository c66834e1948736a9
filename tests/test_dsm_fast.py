"""Fast path of the exact DSM mode (fortran/pi_dsm_fast.f90) against the
exact mode's reference search (pi_dsm_exact's exact_ray, itself checked
against the exhaustive reference in test_dsm_references.py).

The core's dsm_trace takes two internal method codes for this: 3 runs
exact_ray alone (the reference), 4 runs the fast path alone (status 99 where
it declines and ``method="exact"`` falls back to exact_ray). Each scene
asserts, ray by ray, that ``method="exact"`` (fast path + fallback) and the
fast path alone (where it answers) give exact_ray's status and its distance
to 1e-6 m (hits and no-data / left-the-DSM events), and the fraction of rays
the fast path answers.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect import _core
from planet_intersect import synthetic_dsm as sd
from planet_intersect.geodetic import geodetic_to_ecef

EXACT, REFERENCE, FAST_ONLY, DECLINED = 1, 3, 4, 99
TOL_R = 1e-6     # m: the contract's tolerance along the ray
HIT, NO_DATA, LEFT_DSM, MISS = (int(pi.DSMStatus.HIT), int(pi.DSMStatus.NO_DATA), int(pi.DSMStatus.LEFT_DSM),
                                int(pi.DSMStatus.MISS)) if hasattr(pi, "DSMStatus") else (0, 9, 10, 11)


def trace(dsm, s, l, method, threads=1):
    """The core's trace with a method code; returns (status, r of the hit or event, nsteps)."""
    s = np.ascontiguousarray(np.atleast_2d(s), dtype=np.float64)
    l = np.atleast_2d(l).astype(np.float64)
    l = np.ascontiguousarray(l / np.linalg.norm(l, axis=1, keepdims=True))
    pyr, meta = dsm.pyramid()
    g = dsm._core_grid()
    p, q, scal, status, nsteps, stat = _core.core_dsm_trace(*g[:7], g[7], dsm.hmax, dsm.hmin, pyr, meta.T,
                                                           s.T, l.T, method, threads)
    assert stat == 0
    r = np.where(np.isfinite(scal[4]), scal[4], scal[9])
    return status, r, nsteps


def compare(dsm, s, l, min_fast):
    """Assert fast == reference per ray; return (fraction answered by the fast path, status counts)."""
    st_ref, r_ref, n_ref = trace(dsm, s, l, REFERENCE)
    st_ex, r_ex, n_ex = trace(dsm, s, l, EXACT)
    st_f, r_f, _ = trace(dsm, s, l, FAST_ONLY)
    bad = np.flatnonzero(st_ex != st_ref)
    assert bad.size == 0, f"{bad.size} status differences, first ray {bad[:5]}: {st_ex[bad[:5]]} vs {st_ref[bad[:5]]}"
    fin = np.isfinite(r_ref)
    np.testing.assert_array_equal(np.isfinite(r_ex), fin)
    dr = np.abs(r_ex[fin] - r_ref[fin])
    assert dr.max(initial=0.0) <= TOL_R, f"max |dr| = {dr.max():.3g} m"
    took = st_f != DECLINED
    np.testing.assert_array_equal(st_f[took], st_ref[took])
    np.testing.assert_array_equal(r_f[took], r_ex[took])           # method 1 uses the fast answer as is
    frac = float(took.mean())
    assert frac >= min_fast, f"fast path answered {frac:.3f} of the rays"
    counts = {int(k): int(v) for k, v in zip(*np.unique(st_ref, return_counts=True))}
    return frac, counts, float(n_ref.mean()), float(n_ex.mean())


@pytest.fixture(scope="module")
def city():
    g = sd.building_scene(n=256, seed=5)
    g.pop("roof_id")
    return g


@pytest.mark.parametrize("interp", ["bilinear", "nearest"])
def test_pushbroom_city(city, interp):
    dsm = pi.GeodeticDSM.from_array(city["heights"], city["lat_first"], city["lon_first"], city["dlat"],
                                    city["dlon"], interpolation=interp)
    s, l = sd.pushbroom_rays(city, 3000, seed=8)
    frac, counts, n_ref, n_ex = compare(dsm, s, l, min_fast=0.98)
    assert counts.get(HIT, 0) >= 2900
    assert n_ex < 0.5 * n_ref          # fewer exact conversions than the reference search


@pytest.mark.parametrize("interp", ["bilinear", "nearest"])
def test_airborne_and_grazing(city, interp):
    dsm = pi.GeodeticDSM.from_array(city["heights"], city["lat_first"], city["lon_first"], city["dlat"],
                                    city["dlon"], interpolation=interp)
    s1, l1 = sd.airborne_rays(city, 1500, seed=9)
    # grazing: 0.5-3 deg above the horizon, 100-400 m up (long slabs, several pieces)
    s2, l2 = sd.airborne_rays(city, 1500, altitude=(100.0, 400.0), elevation=(0.5, 3.0), seed=10, margin=0.45)
    s, l = np.vstack([s1, s2]), np.vstack([l1, l2])
    frac, counts, _, _ = compare(dsm, s, l, min_fast=0.95)
    assert counts.get(HIT, 0) >= 2900


@pytest.mark.parametrize("interp", ["bilinear", "nearest"])
def test_nodata_and_edges(city, interp):
    h = city["heights"].copy()
    rng = np.random.default_rng(12)
    for _ in range(40):                                        # no-data holes of 1-20 cells
        i, j = rng.integers(0, 240, 2)
        w, d = rng.integers(1, 21, 2)
        h[i:i + d, j:j + w] = np.nan
    dsm = pi.GeodeticDSM.from_array(h, city["lat_first"], city["lon_first"], city["dlat"], city["dlon"],
                                    interpolation=interp)
    s1, l1 = sd.pushbroom_rays(city, 2000, seed=13, margin=0.0)
    # aimed near and beyond the edges: the ray leaves or never enters while low
    s2, l2 = sd.pushbroom_rays(city, 1000, seed=14, margin=-0.05)
    s, l = np.vstack([s1, s2]), np.vstack([l1, l2])
    frac, counts, _, _ = compare(dsm, s, l, min_fast=0.9)   # LEFT_DSM rays are exact_ray's
    assert counts.get(NO_DATA, 0) >= 50 and counts.get(HIT, 0) >= 1500 and counts.get(LEFT_DSM, 0) >= 10


def _level_crossing(s, l, level, r_hi):
    """First r in [0, r_hi] with h(s + r l) <= level, by bisection with the references' own
    geodesy (h falls monotonically over the bracket for these steep rays)."""
    from references.geodesy import ecef_to_geodetic_rad
    lo, hi = np.zeros(len(s)), np.asarray(r_hi, dtype=np.float64).copy()
    for _ in range(90):
        mid = 0.5 * (lo + hi)
        p = s + mid[:, None] * l
        above = ecef_to_geodetic_rad(p[:, 0], p[:, 1], p[:, 2])[3] > level
        lo, hi = np.where(above, mid, lo), np.where(above, hi, mid)
    return hi


@pytest.mark.parametrize("interp", ["bilinear", "nearest"])
def test_slab_ends(interp):
    """The slab's ends are found with one conversion each (the Newton step from the raised
    ellipsoid is not converted; the H_min tail is converted only when the search reaches it).
    Hits and no-data events right at them: a plateau at H_max (the hit is where the ray
    crosses H_max), a no-data hole (the event is there), and flat ground at H_min (the hit
    is where it crosses H_min). Against exact_ray and an independent bisection of
    h(r) = level with tests/references/geodesy.py, to the contract's 1e-6 m."""
    rng = np.random.default_rng(21)
    d, n, m = 1e-4, 100, 400
    lat0, lon0 = 45.0, 10.0
    h = rng.uniform(0.0, 50.0, (n, n))
    h[30:71, 30:71] = 300.0                                    # a plateau at H_max
    h[5:16, 5:16] = np.nan                                     # a no-data hole
    flat = np.full((n, n), 100.0)                              # flat ground at H_min ...
    flat[95:, 95:] = 200.0                                     # ... and one tower (H_max)
    cases = [(h, 50.0, HIT, 300.0), (h, 10.0, NO_DATA, 300.0), (flat, 50.0, HIT, 100.0)]
    for k, (grid, centre, status, level) in enumerate(cases):
        dsm = pi.GeodeticDSM.from_array(grid, lat0, lon0, d, d, interpolation=interp)
        lat = lat0 + (centre + rng.uniform(-2.0, 2.0, m)) * d
        lon = lon0 + (centre + rng.uniform(-2.0, 2.0, m)) * d
        s, l = _patch_rays(lat, lon, m, 22 + k, zen=(0.0, 4.0))
        l = l / np.linalg.norm(l, axis=1, keepdims=True)
        frac, counts, _, _ = compare(dsm, s, l, min_fast=0.99)
        assert counts == {status: m}, f"case {k}: {counts}"
        st, r, _ = trace(dsm, s, l, EXACT)
        r_bis = _level_crossing(s, l, level, r + 50.0)
        dr = np.abs(r - r_bis)
        assert dr.max() <= TOL_R, f"case {k}: max |r - r(h = {level})| = {dr.max():.3g} m"


def _patch_rays(lat, lon, n, seed, zen=(0.0, 40.0), height=(5e3, 700e3)):
    rng = np.random.default_rng(seed)
    target = geodetic_to_ecef(lat, lon, np.zeros(n))
    return sd._from_above(target, lat, lon, rng.uniform(*height, n), rng.uniform(*zen, n),
                          rng.uniform(0, 2 * np.pi, n))


@pytest.mark.parametrize("interp", ["bilinear", "nearest"])
def test_antimeridian_and_poles(interp):
    rng = np.random.default_rng(15)
    # 0.01 deg cells (~1 km) of rough terrain across the antimeridian
    h = rng.uniform(0.0, 800.0, (60, 80))
    dsm = pi.GeodeticDSM.from_array(h, -0.3, 179.6, 0.01, 0.01, interpolation=interp)
    lat = rng.uniform(-0.28, 0.28, 1500)
    lon = 179.62 + rng.uniform(0.0, 0.76, 1500)
    s, l = _patch_rays(lat, lon, 1500, 16)
    frac, counts, _, _ = compare(dsm, s, l, min_fast=0.9)
    assert counts.get(HIT, 0) >= 1300
    # near the north pole: 1e-4 deg rows up to 89.99 deg; the fast path declines where its
    # latitude bound is too wide (close to the axis), exact_ray answers
    hp = rng.uniform(0.0, 50.0, (100, 100))
    dsmp = pi.GeodeticDSM.from_array(hp, 89.98, 10.0, 1e-4, 1e-3, interpolation=interp)
    lat = rng.uniform(89.981, 89.989, 1000)
    lon = rng.uniform(10.01, 10.09, 1000)
    s, l = _patch_rays(lat, lon, 1000, 17, height=(2e3, 600e3))
    frac_p, counts_p, _, _ = compare(dsmp, s, l, min_fast=0.0)
    assert counts_p.get(HIT, 0) >= 900


def test_mars_and_threads():
    rng = np.random.default_rng(18)
    a, f = 3396190.0, 1 / 169.894
    h = rng.uniform(-2000.0, 2000.0, (120, 120))
    dsm = pi.GeodeticDSM.from_array(h, -30.0, 40.0, 0.002, 0.002, a=a, f=f)
    lat = rng.uniform(-29.95, -29.77, 2000)
    lon = rng.uniform(40.02, 40.22, 2000)
    rng2 = np.random.default_rng(19)
    la, lo = np.radians(lat), np.radians(lon)
    target = geodetic_to_ecef(lat, lon, np.zeros(2000), a, f)
    up = np.stack([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)], axis=1)
    tilt = rng2.normal(0, 0.2, (2000, 3))
    d = up + tilt - (np.einsum("ij,ij->i", tilt, up))[:, None] * up
    s, l = target + 300e3 * d, -d
    frac, counts, _, _ = compare(dsm, s, l, min_fast=0.95)
    assert counts.get(HIT, 0) >= 1800
    st1, r1, _ = trace(dsm, s, l, EXACT, threads=1)
    st2, r2, _ = trace(dsm, s, l, EXACT, threads=2)
    np.testing.assert_array_equal(st1, st2)
    np.testing.assert_array_equal(r1, r2)                      # bit-identical for any thread count


SHARED = Path(os.environ.get("PI_SHARED_DATA", Path(__file__).resolve().parents[1].parent / "shared" / "data"))
ETOPO = SHARED / "earth_etopo20"


@pytest.mark.skipif(not (ETOPO / "etopo20data.gz").exists(), reason=f"{ETOPO}: ETOPO20 grid not available")
@pytest.mark.parametrize("interp", ["bilinear", "nearest"])
def test_etopo20_global(interp):
    """Real data: the global ETOPO20 grid (20', 1080 columns covering 360 deg, heights from
    -10 km to +6 km: slabs ~16 km long, cells ~37 km), rays from 500-700 km, 0-30 deg off nadir."""
    from references.earth_data import etopo20_grid

    g = etopo20_grid(ETOPO)
    dsm = pi.GeodeticDSM.from_array(g["heights"], g["lat_first"], g["lon_first"], g["dlat"], g["dlon"],
                                    interpolation=interp)
    rng = np.random.default_rng(7)
    n = 3000
    lat = np.degrees(np.arcsin(rng.uniform(-0.97, 0.97, n)))
    lon = rng.uniform(-180, 180, n)
    s, l = _patch_rays(lat, lon, n, 20, zen=(0.0, 30.0), height=(500e3, 700e3))
    assert g["heights"].shape[1] * g["dlon"] == 360.0 and g["lat_first"] == -90 + g["dlat"] / 2
    frac, counts, n_ref, n_ex = compare(dsm, s, l, min_fast=0.98)
    # a global grid: every ray from orbit hits (the loader took 0.3333333 for the step until
    # 2026-12-05: 1,080 columns then left a 4 m gap at the antimeridian's copy, and rays left there)
    assert counts == {HIT: n}
    assert n_ex < 0.8 * n_ref          # the pieces grow with the cells: fewer conversions on coarse grids too


@pytest.mark.parametrize("planet", ["earth", "mars"])
def test_hit_point_fields(city, planet):
    """The reported hit point against the references' own conversion of s + r l at the
    reported r: latitude, longitude (1e-13 rad, ~0.6 um), height (1e-8 m) and incidence
    (1e-9 rad). On "nearest" cells the fast path's Newton reports a point a few cm past its
    last conversion extrapolated along the ray (first order in lat/lon: skipping or
    mis-signing that step is off by ~1e-8 rad); Mars checks the ellipsoid's use."""
    from references.geodesy import ecef_to_geodetic_rad
    if planet == "earth":
        a, f = 6378137.0, 1 / 298.257223563
        dsm = pi.GeodeticDSM.from_array(city["heights"], city["lat_first"], city["lon_first"], city["dlat"],
                                        city["dlon"], interpolation="nearest")
        s1, l1 = sd.pushbroom_rays(city, 1500, seed=21)
        s2, l2 = sd.airborne_rays(city, 1500, seed=22)
        s, l = np.vstack([s1, s2]), np.vstack([l1, l2])
    else:
        a, f = 3396190.0, 1 / 169.894
        rng = np.random.default_rng(23)
        h = np.round(rng.uniform(-2000.0, 2000.0, (120, 120)), -2)   # flat blocks of 100 m steps
        dsm = pi.GeodeticDSM.from_array(h, -30.0, 40.0, 0.002, 0.002, a=a, f=f, interpolation="nearest")
        lat = rng.uniform(-29.95, -29.77, 3000)
        lon = rng.uniform(40.02, 40.22, 3000)
        target = geodetic_to_ecef(lat, lon, np.zeros(3000), a, f)
        la, lo = np.radians(lat), np.radians(lon)
        up = np.stack([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)], axis=1)
        tilt = rng.normal(0, 0.2, (3000, 3))
        d = up + tilt - (np.einsum("ij,ij->i", tilt, up))[:, None] * up
        s, l = target + 300e3 * d, -d
    s = np.ascontiguousarray(s, dtype=np.float64)
    l = np.ascontiguousarray(l / np.linalg.norm(l, axis=1, keepdims=True))
    pyr, meta = dsm.pyramid()
    g = dsm._core_grid()
    p, q, scal, status, nsteps, stat = _core.core_dsm_trace(*g[:7], g[7], dsm.hmax, dsm.hmin, pyr, meta.T,
                                                           s.T, l.T, EXACT, 1)
    assert stat == 0
    hit = status == HIT
    assert hit.sum() >= 2900
    r = scal[4][hit]
    pt = s[hit] + r[:, None] * l[hit]
    np.testing.assert_allclose(p.T[hit], pt, rtol=0, atol=1e-9 * a)
    sphi, cphi, lon, h = ecef_to_geodetic_rad(pt[:, 0], pt[:, 1], pt[:, 2], a, f)
    dlat = np.abs(np.arctan2(sphi, cphi) - scal[0][hit])
    dlon = np.abs(np.angle(np.exp(1j * (lon - scal[1][hit]))))
    assert dlat.max() <= 1e-13 and dlon.max() <= 1e-13, (dlat.max(), dlon.max())
    assert np.abs(h - scal[2][hit]).max() <= 1e-8
    n = np.stack([cphi * np.cos(lon), cphi * np.sin(lon), sphi], axis=1)
    inc = np.arccos(np.clip(-np.einsum("ij,ij->i", l[hit], n), -1.0, 1.0))
    assert np.abs(inc - scal[5][hit]).max() <= 1e-9


def test_geostationary_focal_points():
    """Focal points 3.6e7 m up (a geostationary imager): one ulp of r is 7.45e-9 m there, so a
    Newton step between 1e-9 m and half an ulp left r where it was, and level crossings that stopped
    only on a step <= 1e-9 m ran out of iterations: exact_ray (method 3, and method 1 wherever the
    fast path declines) reported 7 of these 20 hits as misses and, for rays beside the DSM, misses
    or a hit 23 km underground instead of LEFT_DSM (found by a review). Checked against the
    exhaustive NumPy reference, which shares none of that code."""
    from references.dsm_exhaustive import HIT as X_HIT, LEFT_DSM as X_LEFT, exhaustive_first_hit

    g = sd.building_scene(n=256, seed=5)
    g.pop("roof_id")
    dsm = pi.GeodeticDSM.from_array(g["heights"], g["lat_first"], g["lon_first"], g["dlat"], g["dlon"],
                                    interpolation="nearest")
    grid = dict(lat_first=g["lat_first"], lon_first=g["lon_first"], dlat=g["dlat"], dlon=g["dlon"])

    def agree(s, l, ref_status, status):
        # method="exact" and exact_ray alone: the reference's status on every ray, its r to 2e-6 m
        ref = exhaustive_first_hit(g["heights"], s=s, l=l, interpolation="nearest", **grid)
        assert np.all(ref["status"] == ref_status)
        for method in (EXACT, REFERENCE):
            st, r, _ = trace(dsm, s, l, method)
            np.testing.assert_array_equal(st, status)
            assert np.max(np.abs(r - ref["r"])) < 2 * TOL_R, (method, np.max(np.abs(r - ref["r"])))

    agree(*sd.pushbroom_rays(g, 20, altitude=(3.6e7, 3.6e7), off_nadir=(0.0, 0.2), seed=7), X_HIT, HIT)
    # aimed beside the DSM (north of it): the answer is LEFT_DSM where the ray leaves it
    rng = np.random.default_rng(3)
    nr, nc = g["heights"].shape
    lat = g["lat_first"] + rng.uniform(1.2, 1.5, 20) * nr * g["dlat"]
    lon = g["lon_first"] + rng.uniform(0.2, 0.8, 20) * nc * g["dlon"]
    agree(*_patch_rays(lat, lon, 20, 4, zen=(0.0, 0.5), height=(3.6e7, 3.6e7)), X_LEFT, LEFT_DSM)


def test_hit_fields_near_a_pole():
    """The hit's longitude without a conversion (extrapolate, a first-order step of up to 1e-8 a)
    erred by d^2 / rho^2: 7.7e-13 rad 6 km from the pole's axis (a review). The step is now also at
    most 1e-8 of the axis distance: every reported longitude within 1e-13 rad of the references'
    own conversion of s + r l."""
    from references.geodesy import ecef_to_geodetic_rad

    rng = np.random.default_rng(1)
    h = np.round(rng.uniform(0, 3000, (50, 200)), -2)
    dsm = pi.GeodeticDSM.from_array(h, 89.925, 0.0, 0.0005, 1.0, interpolation="nearest")
    n = 3000
    lat = rng.uniform(89.927, 89.925 + 45 * 0.0005, n)
    lon = rng.uniform(5.0, 190.0, n)
    s, l = _patch_rays(lat, lon, n, 2, zen=(20.0, 70.0), height=(3e5, 7e5))
    l = l / np.linalg.norm(l, axis=1, keepdims=True)
    pyr, meta = dsm.pyramid()
    g = dsm._core_grid()
    p, q, scal, status, nsteps, stat = _core.core_dsm_trace(*g[:7], g[7], dsm.hmax, dsm.hmin, pyr, meta.T,
                                                           np.ascontiguousarray(s).T, np.ascontiguousarray(l).T,
                                                           EXACT, 1)
    hit = status == HIT
    assert hit.sum() > 1500
    pt = s[hit] + scal[4][hit, None] * l[hit]
    sphi, cphi, lonr, _ = ecef_to_geodetic_rad(pt[:, 0], pt[:, 1], pt[:, 2])
    dlon = np.abs(np.angle(np.exp(1j * (lonr - scal[1][hit]))))
    dlat = np.abs(np.arctan2(sphi, cphi) - scal[0][hit])
    assert dlon.max() < 1e-13 and dlat.max() < 1e-13, (dlon.max(), dlat.max())


@pytest.mark.parametrize("interp", ["nearest", "bilinear"])
def test_rays_that_leave_the_dsm(interp):
    """A ray that leaves the DSM without a hit: the fast path searches its whole slab, finds no hit
    and no no-data point, then finds the first point outside on its pieces' models (left_search:
    the first r where the widened models may be past an edge and the first where they surely are,
    in closed form, pinned on a piece of its own and classified by one conversion). Where that does
    not settle it, exact_ray's search for the first point outside runs without its search of the
    slab for hits (res%slab_clear). An oblique scan at 30 deg across a whole 256^2 scene, whose far
    ends run out of the grid: the same statuses as exact_ray, the LEFT_DSM points within TOL_R of
    its, and ~6 conversions a leaving ray where exact_ray alone takes ~50 (before: the fast path's
    on top of all of exact_ray's)."""
    g = sd.building_scene(n=256, seed=8)
    g.pop("roof_id")
    dsm = pi.GeodeticDSM.from_array(g["heights"], g["lat_first"], g["lon_first"], g["dlat"], g["dlon"],
                                    interpolation=interp)
    sen = sd.ObliqueScan(g, zenith=30.0, azimuth=90.0, margin=8)
    k = np.linspace(0, sen.nlines - 1, 12).astype(int)
    parts = [sen.rays(int(i), int(i) + 1) for i in k]
    s = np.concatenate([p[0] for p in parts])
    l = np.concatenate([p[1] for p in parts])
    frac, counts, n_ref, n_ex = compare(dsm, s, l, 0.95)
    st_ref, r_ref, n_ref = trace(dsm, s, l, REFERENCE)
    st_ex, r_ex, n_ex = trace(dsm, s, l, EXACT)
    st_f, r_f, _ = trace(dsm, s, l, FAST_ONLY)
    left = st_ref == LEFT_DSM
    assert left.sum() >= 50, left.sum()
    assert np.mean(st_f[left] == LEFT_DSM) > 0.9, np.mean(st_f[left] == LEFT_DSM)   # decided by left_search
    assert np.mean(n_ex[left]) < 10.0 and np.mean(n_ref[left]) > 40.0, (np.mean(n_ex[left]), np.mean(n_ref[left]))
    # each event point is outside (the lookup) and the point refine_tol before it is not past the
    # references' first outside point by more than TOL_R: |r - r_ref| <= TOL_R (compare) covers it
    assert np.max(np.abs(r_ex[left] - r_ref[left])) <= TOL_R


def test_leaving_search_keeps_exact_rays_touches():
    """left_search and the skipped hit search only where the slab starts inside the area by 1e-3
    cells and the ray crosses H_max at dh/dr <= -1e-3. A review of the first version found rays
    that exact_ray (and the exhaustive reference) call hits, through contacts shorter than
    refine_tol that the fast path's search may step over, turned LEFT_DSM or MISS: (a) the corner
    pixel of an oblique scan passing through the grid's corner node 2.4 m below the surface, from
    outside to outside; (b) a ray through a corner node 1e-6 m below the surface; (c) a ray 1e-6 m
    below a bilinear peak node; (d) a nearly horizontal ray grazing H_max (1.8e-6 rad) 1e-3 m before
    a roof's edge, where the two searches' slab starts differ. Each now takes exact_ray's answer."""
    cases = []
    g = sd.building_scene(n=256, seed=8)
    g.pop("roof_id")
    dsm = pi.GeodeticDSM.from_array(g["heights"], g["lat_first"], g["lon_first"], g["dlat"], g["dlon"],
                                    interpolation="bilinear")
    sen = sd.ObliqueScan(g, zenith=60, azimuth=45, margin=0)
    s, l = sen.rays(sen.nlines - 1, sen.nlines)
    cases.append((dsm, s[-1], l[-1]))
    g2 = sd.building_scene(n=32, seed=4)
    g2.pop("roof_id")
    dsm2 = pi.GeodeticDSM.from_array(g2["heights"], g2["lat_first"], g2["lon_first"], g2["dlat"], g2["dlon"],
                                     interpolation="bilinear")
    cases.append((dsm2, np.array([507942.80083291745, -5102735.568496751, 3783135.6733008767]),
                  np.array([0.646671665530004, 0.5797441308298048, -0.49569395776935277])))
    dlat, dlon = sd.metre_steps(36.6)
    h = np.zeros((64, 64))
    h[32, 32] = 50.0
    dsm3 = pi.GeodeticDSM.from_array(h, 36.6 + 63 * dlat, -84.3, -dlat, dlon, interpolation="bilinear")
    cases.append((dsm3, np.array([509211.7903371872, -5101193.68736336, 3781983.445812029]),
                  np.array([-0.06811254670324139, -0.6011020080812421, -0.7962644390290811])))
    h4 = np.zeros((32, 32))
    h4[10:21, 10:17] = 30.0
    dsm4 = pi.GeodeticDSM.from_array(h4, 36.6 + 31 * dlat, -84.3, -dlat, dlon, interpolation="nearest")
    cases.append((dsm4, np.array([504225.0373858882, -5101745.957928515, 3781876.882066827]),
                  np.array([0.9950550313624322, 0.0993251456596419, 1.2649982604679078e-17])))
    for k, (d, s1, l1) in enumerate(cases):
        st_ref, r_ref, _ = trace(d, s1, l1, REFERENCE)
        st_ex, r_ex, _ = trace(d, s1, l1, EXACT)
        assert st_ref[0] == HIT, (k, st_ref)
        assert st_ex[0] == HIT and r_ex[0] == r_ref[0], (k, st_ex, r_ex, r_ref)


def test_ulp_is_spacing():
    """pi_dsm's ulp, which widens every bilinear box bound by 4 ulps ("Twelfth look"), is
    spacing to the bit: NumPy's spacing on heights from 1e-250 to 2^1023 (its fast
    path), powers of two and their neighbours, negative values; NaN and infinity go to
    spacing itself (NaN)."""
    rng = np.random.default_rng(12)
    x = np.concatenate([
        10.0 ** rng.uniform(-250, 308, 20000),
        [1.0, 2.0, 0.5, 300.0, 6378137.0, 8848.86, np.finfo(float).max, 2.0 ** -900, 2.0 ** 1000],
        np.nextafter(2.0 ** np.arange(-60, 60), 0.0), np.nextafter(2.0 ** np.arange(-60, 60), np.inf),
    ])
    x = np.concatenate([x, -x[:100]])
    s = _core.core_ulp(x)
    top = np.abs(x) >= 2.0 ** 1023        # NumPy's spacing there is the step to infinity
    np.testing.assert_array_equal(s[~top], np.spacing(np.abs(x[~top])))
    assert (s[top] == 2.0 ** 971).all() and top.sum() >= 1   # Fortran's spacing: 2^(1023 - 52)
    assert s[x == 300.0][0] == 2.0 ** -44                 # 300 in [2^8, 2^9): 2^(8 - 52)
    assert np.isnan(_core.core_ulp(np.array([np.nan, np.inf]))).all()


def test_trace_outputs_are_written_whole_without_a_fill():
    """core_dsm_trace's outputs reach the core unfilled (f2py intent(out, cache); before, f2py
    zeroed them and the core filled them with NaN, two passes over 136 bytes a ray): the core
    writes every element. Each call is preceded by freed arrays of the outputs' sizes holding a
    sentinel, which malloc hands to f2py again, so an element left unwritten keeps the sentinel.
    Every method (following, exact, iterative, exact_ray alone, the fast path alone, exact with
    fans) on hits, misses, rays that leave the grid, a focal point inside the surface and zero
    or NaN directions. An unknown method returns stat != 0 with every output filled (NaN,
    BAD_DIRECTION, 0 steps)."""
    g = sd.building_scene(n=48, seed=3)
    g.pop("roof_id")
    dsm = pi.GeodeticDSM.from_array(g["heights"], g["lat_first"], g["lon_first"], g["dlat"], g["dlon"],
                                    interpolation="nearest")
    sen = sd.ObliqueScan(g, zenith=35.0, azimuth=90.0, margin=0)
    s, l = sen.rays(20, 21)                                   # one line: hits, and rays leaving the grid
    s2, l2 = sd.pushbroom_rays(g, 16, seed=2)
    s = np.vstack([s, s2, s[:1], s[:1], s[:1]])
    l = np.vstack([l, l2, -l[:1], np.zeros((1, 3)), np.full((1, 3), np.nan)])   # miss, zero, NaN
    lat_c = g["lat_first"] + 24 * g["dlat"]
    lon_c = g["lon_first"] + 24 * g["dlon"]
    s = np.vstack([s, geodetic_to_ecef(lat_c, lon_c, -50.0)[None, :]])    # under the surface
    l = np.vstack([l, l2[:1]])
    s, l = np.ascontiguousarray(s), np.ascontiguousarray(l)
    n = len(s)
    pyr, meta = dsm.pyramid()
    grid = dsm._core_grid()
    sentinel = np.float64(-1.2345678901234567e-301)
    sbits = sentinel.view(np.int64)

    def call(method, fan=0):
        junk = [np.full(shape, sentinel, order="F") for shape in ((10, n), (3, n), (3, n))]
        junk += [np.full(n, -123456789, dtype=np.int32) for _ in range(2)]
        del junk                                               # all freed together: reused by f2py
        return _core.core_dsm_trace(*grid[:7], grid[7], dsm.hmax, dsm.hmin, pyr, meta.T, s.T, l.T, method, 1,
                                    fan)

    seen = set()
    for method, fan in ((0, 0), (1, 0), (2, 0), (3, 0), (4, 0), (1, sen.npixels)):
        for _ in range(3):
            p, q, scal, status, nsteps, stat = call(method, fan)
            assert stat == 0
            for name, arr in (("p", p), ("q", q), ("scal", scal)):
                left = np.flatnonzero(arr.view(np.int64) == sbits)
                assert left.size == 0, f"method {method}: {name} elements {left[:5]} never written"
            assert not np.any(status == -123456789) and not np.any(nsteps == -123456789)
            seen.update(int(v) for v in status)
    assert {HIT, LEFT_DSM, MISS, int(pi.DSMStatus.INSIDE), int(pi.DSMStatus.BAD_DIRECTION)} <= seen, seen
    p, q, scal, status, nsteps, stat = _core.core_dsm_trace(*grid[:7], grid[7], dsm.hmax, dsm.hmin, pyr, meta.T,
                                                           s.T, l.T, 9, 1)
    assert stat != 0
    assert np.isnan(p).all() and np.isnan(q).all() and np.isnan(scal).all()
    assert np.all(status == int(pi.DSMStatus.BAD_DIRECTION)) and np.all(nsteps == 0)
