"""Closed-form references: a constant-radius sphere and an exact spheroid written as DEMs."""

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect.geometry import ray_spheroid_intersection, spheroid_radius
from planet_intersect.synthetic import MARS_F, MARS_RE

from conftest import mixed_rays, perpendicular_unit, random_unit, unit

R_SPHERE = 3390.0


@pytest.fixture(scope="module")
def sphere():
    # f = 0 and re = R: the reference spheroid is the sphere itself
    return pi.DEM.from_array(np.full((360, 720), R_SPHERE), f=0.0, re=R_SPHERE, rmax=R_SPHERE + 10.0)


def spheroid_dem(ppd):
    lat = -90 + (np.arange(180 * ppd) + 0.5) / ppd
    r = np.repeat(spheroid_radius(lat, MARS_F, MARS_RE)[:, None], 360 * ppd, axis=1)
    return pi.DEM.from_array(r, f=MARS_F, re=MARS_RE)


@pytest.mark.parametrize("step_mode", [0, 1])
def test_sphere_hits_and_tangents_equal_closed_form(sphere, step_mode):
    s, l, kind = mixed_rays(sphere, 6000, seed=5)
    res = pi.intersect(sphere, s, l, step_mode=step_mode)
    # closed-form ray-sphere intersection: smallest d >= 0 with |s + d l| = R
    b = np.sum(s * l, axis=1)
    c = np.sum(s * s, axis=1) - R_SPHERE ** 2
    disc = b * b - c
    d = -b - np.sqrt(np.where(disc >= 0, disc, np.nan))
    expect_hit = (disc >= 0) & (d >= 0)
    assert expect_hit.sum() > 2000 and (~expect_hit).sum() > 2000
    # The paper samples the ray every delta-alpha (eq. 23): a chord below the surface that
    # subtends less than one step can fall between two test points. Its depth is then below
    # R (1 - cos(delta-alpha / 2)) (8 m here); every deeper chord must be found.
    t_len = np.linalg.norm(s - b[:, None] * l, axis=1)
    depth_limit = R_SPHERE * (1 - np.cos(np.radians(1.0 / (2 * sphere.ppd)) / 2))
    decided = (t_len > R_SPHERE) | (R_SPHERE - t_len > depth_limit)
    np.testing.assert_array_equal(res.hit[decided], expect_hit[decided])
    missed = expect_hit & ~res.hit
    assert np.all(kind[missed] == "grazing") and np.all(R_SPHERE - t_len[missed] <= depth_limit)
    both = res.hit & expect_hit
    p = s + d[:, None] * l
    assert np.max(np.abs(res.p[both] - p[both])) <= 1e-9 * R_SPHERE
    np.testing.assert_allclose(res.radius[both], R_SPHERE, rtol=0, atol=1e-9 * R_SPHERE)
    # emission: angle between -l and the radial direction
    cos_e = -np.sum(unit(p[both]) * l[both], axis=1)
    assert np.max(np.abs(res.emission[both] - np.degrees(np.arccos(np.clip(cos_e, -1, 1))))) <= 1e-6
    # limb: spherical tangent point t = s - (s.l) l, tc = t, tangent altitude = |t| - R
    limb = res.status == pi.RayStatus.LIMB
    assert limb.sum() > 1000
    t = s - b[:, None] * l
    assert np.max(np.abs(res.t[limb] - t[limb])) <= 1e-9 * R_SPHERE
    assert np.max(np.abs(res.tc[limb] - t[limb])) <= 1e-9 * R_SPHERE
    assert np.max(np.abs(res.sc[limb] - R_SPHERE * unit(t[limb]))) <= 1e-9 * R_SPHERE
    np.testing.assert_allclose(res.tangent_altitude[limb], t_len[limb] - R_SPHERE, rtol=0, atol=1e-9 * R_SPHERE)
    # rays pointing away from the planet have no tangent point
    away = res.status == pi.RayStatus.AWAY
    assert away.sum() > 100 and np.all(b[away] > 0) and np.isnan(res.t[away]).all()


def test_irregular_body_reduces_to_spherical_tangent():
    """f = 0, re = 1 (Table 1 for irregular bodies): tc = t and the altitude is |t| - r_DEM."""
    rng = np.random.default_rng(4)
    radii = 11.0 + rng.uniform(-1, 1, (180, 360))
    dem = pi.DEM.from_array(radii, f=0.0)   # no re: no spheroid
    u = random_unit(rng, 2000)
    e = perpendicular_unit(rng, u)
    s = u * rng.uniform(dem.rmax + 0.5, dem.rmax + 20, 2000)[:, None] - e * 60
    res = pi.intersect(dem, s, e)
    assert (res.status == 1).all()
    t = s - np.sum(s * e, axis=1)[:, None] * e
    for mode in ("paper", "exact"):
        r2 = pi.intersect(dem, s, e, tangent=mode)
        assert np.max(np.abs(r2.tc - t)) <= 1e-12 * 30
    r_dem = dem.radius(res.tangent_lat, res.tangent_lon)
    np.testing.assert_allclose(res.tangent_altitude, np.linalg.norm(t, axis=1) - r_dem, rtol=0, atol=1e-11)
    assert np.isnan(res.altitude).all()


@pytest.fixture(scope="module")
def spheroid4():
    return spheroid_dem(4)


@pytest.fixture(scope="module")
def limb_rays():
    rng = np.random.default_rng(9)
    n = 4000
    u = random_unit(rng, n)
    e = perpendicular_unit(rng, u)
    height = rng.uniform(0.5, 200.0, n)       # above the spheroid: these rays miss the DEM
    s = u * (MARS_RE + height)[:, None] - e * rng.uniform(500, 4000, n)[:, None]
    return s, e


def test_spheroid_tangent_points_equal_npedln(spheroid4, limb_rays):
    sp = pytest.importorskip("spiceypy", reason="spiceypy is the independent reference for the spheroid tangent")
    s, l = limb_rays
    res = pi.intersect(spheroid4, s, l)               # tangent="exact"
    assert (res.status == pi.RayStatus.LIMB).all()
    b = MARS_RE * (1 - MARS_F)
    near = np.empty_like(s)
    dist = np.empty(len(s))
    for k in range(len(s)):
        near[k], dist[k] = sp.npedln(MARS_RE, MARS_RE, b, s[k], l[k])
    tc = s + np.sum((near - s) * l, axis=1)[:, None] * l
    assert np.max(np.abs(res.sc - near)) <= 1e-9 * MARS_RE
    assert np.max(np.abs(res.tc - tc)) <= 1e-9 * MARS_RE
    assert np.max(np.abs(res.tangent_height - dist)) <= 1e-9 * MARS_RE

    # tangent altitude above the DEM = d up to the bilinear interpolation error of the grid:
    # |r_c - r_DEM| <= h^2/8 max|r''| inside the grid (h = 1/ppd deg in radians), and near a
    # pole the cap node carries r(theta_n) instead of r(90): at most r(theta_n) - r(90).
    h = np.radians(1.0 / spheroid4.ppd)
    th = np.radians(np.linspace(-90, 90, 200001))
    r = spheroid_radius(np.degrees(th), MARS_F, MARS_RE)
    r2 = np.max(np.abs(np.diff(r, 2))) / (th[1] - th[0]) ** 2
    cap = spheroid_radius(90 - 0.5 / spheroid4.ppd, MARS_F, MARS_RE) - spheroid_radius(90.0, MARS_F, MARS_RE)
    bound = h * h / 8 * r2 + cap
    diff = np.abs(res.tangent_altitude - res.tangent_height)
    assert diff.max() <= bound
    assert diff.max() > 0.3 * bound      # the bound is tight, not vacuous
    # 4 ppd Mars: the bound is about 0.1 m


def test_paper_tangent_construction_differs_from_exact_by_order_f_times_d(spheroid4, limb_rays):
    """The paper's eqs. 55-58 give a point whose normal is perpendicular to l, but
    tc - sc is along that normal only when d -> 0: the offset of sc is O(f d)."""
    s, l = limb_rays
    exact = pi.intersect(spheroid4, s, l, tangent="exact")
    paper = pi.intersect(spheroid4, s, l, tangent="paper")
    d = exact.tangent_height
    offset = np.linalg.norm(paper.sc - exact.sc, axis=1)
    assert np.all(offset <= 2 * MARS_F * d + 1e-9)
    assert np.all(paper.tangent_height >= exact.tangent_height - 1e-9)   # exact is the minimum distance
    assert np.max(paper.tangent_height - d) < 0.005                      # km, over 0-200 km heights
    small = d < 1.0
    assert np.all(offset[small] <= 2 * MARS_F * 1.0)


def test_spheroid_emission_equals_closed_form():
    """Hits on a 16 ppd spheroid DEM against the exact ray-spheroid intersection."""
    dem = spheroid_dem(16)
    rng = np.random.default_rng(12)
    n = 3000
    u = random_unit(rng, n)
    e = perpendicular_unit(rng, u)
    off = np.radians(rng.uniform(0, 70, n))                  # emission up to ~70 deg
    target = u * spheroid_radius(np.degrees(np.arcsin(u[:, 2])), MARS_F, MARS_RE)[:, None]
    s = target + (np.cos(off)[:, None] * u + np.sin(off)[:, None] * e) * rng.uniform(300, 2000, n)[:, None]
    l = unit(target - s)
    res = pi.intersect(dem, s, l)
    p, d = ray_spheroid_intersection(s, l, MARS_F, MARS_RE)
    assert res.hit.all() and np.isfinite(d).all()
    n_hat = unit(p * np.array([1.0, 1.0, 1.0 / (1.0 - MARS_F * (2 - MARS_F))]))   # eq. 50
    emission = np.degrees(np.arccos(np.clip(-np.sum(n_hat * l, axis=1), -1, 1)))
    assert np.max(np.abs(res.emission - emission)) <= 1e-6
    # the hit point is the spheroid point up to the radial interpolation error h^2/8 max|r''|
    # (6e-6 km at 16 ppd), stretched along the ray by 1/cos(emission)
    h = np.radians(1.0 / dem.ppd)
    radial = h * h / 8 * 2 * MARS_RE * MARS_F * 1.01
    assert np.all(np.abs(res.altitude) <= radial)
    along = np.linalg.norm(res.p - p, axis=1)
    assert np.all(along <= radial / np.cos(np.radians(emission)))


def test_grazing_tolerances_are_what_the_readme_states():
    """Issue 10 §5: the stated tolerances for grazing rays, measured.

    (a) Sphere, chords 1 cm-2 m deep: the stepping refinement stops on a radial
    criterion (|r(p') - |p'|| <= 1e-12 rmax, note 5), so along the ray its error
    may reach 1e-12 R / sin(entry angle); the exact mode refines along the ray
    (to 1e-12 rmax). (b) Spheroid DEM, views 85-89 deg off the normal: the hit
    moves along the ray by the interpolation error / cos e, which turns the
    spheroid normal by that over the radius of curvature."""
    rng = np.random.default_rng(105)
    R, n = 3390.0, 20000
    dem = pi.DEM.from_array(np.full((180, 360), R))
    u = random_unit(rng, n)
    w = perpendicular_unit(rng, u)
    depth = 10 ** rng.uniform(-5, np.log10(2e-3), n)           # km: 1 cm .. 2 m
    t = (R - depth)[:, None] * u
    half = np.sqrt(R ** 2 - (R - depth) ** 2)
    p_true = t - half[:, None] * w
    sin_entry = half / R
    for method, bound in (("stepping", 1e-12 * R / sin_entry + 1e-12 * R), ("exact", np.full(n, 1e-11 * R))):
        res = pi.intersect(dem, t - 3000.0 * w, w, method=method)
        h = res.hit
        err = np.linalg.norm(res.p[h] - p_true[h], axis=1)
        assert np.all(err <= bound[h]), (method, np.max(err / bound[h]))
        assert err.max() <= (6e-10 if method == "stepping" else 1e-11) * R    # README: measured maxima
    assert pi.intersect(dem, t - 3000.0 * w, w, method="exact").hit.all()

    dem = spheroid_dem(16)
    m = 2000
    u = random_unit(rng, m)
    e = perpendicular_unit(rng, u)
    off = np.radians(rng.uniform(85, 89, m))
    target = u * spheroid_radius(np.degrees(np.arcsin(u[:, 2])), MARS_F, MARS_RE)[:, None]
    s = target + (np.cos(off)[:, None] * u + np.sin(off)[:, None] * e) * 400.0
    l = unit(target - s)
    res = pi.intersect(dem, s, l)
    p, d = ray_spheroid_intersection(s, l, MARS_F, MARS_RE)
    ok = res.hit & np.isfinite(d)
    assert ok.sum() > 0.95 * m
    n_hat = unit(p * np.array([1.0, 1.0, 1.0 / (1.0 - MARS_F * (2 - MARS_F))]))
    emission = np.degrees(np.arccos(np.clip(-np.sum(n_hat * l, axis=1), -1, 1)))
    h = np.radians(1.0 / dem.ppd)
    radial = h * h / 8 * 2 * MARS_RE * MARS_F * 1.01
    turn = np.degrees(radial / np.cos(np.radians(emission)) / (MARS_RE * (1 - 2 * MARS_F)))
    diff = np.abs(res.emission - emission)
    assert np.all(diff[ok] <= turn[ok] + 1e-9)
    assert diff[ok].max() <= 1e-5                                # README: measured maximum
