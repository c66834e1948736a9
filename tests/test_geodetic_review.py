"""Faults found by an independent numerical review of the geodetic conversions and DSM rays at
extreme inputs, against its own 50-digit reference (2026-12-05; shin-park-notes note 21).

* Eq. 2's h = p / cos(lat) - N turned lat's rounding into N^2 ulp / p of height near the poles:
  1.4 m at 1 mm from the axis, -210 km at 10 nm; the faithful following, which steps with it,
  then gave MISS for rays 1e-5 to 1e-3 deg off nadir down to a polar DSM.
* The exact conversion lost its height near the centre of a nearly round body (0 < f < ~1e-6):
  1,221 m at 6.4e-5 m from the Earth's centre with f = 1e-12, -1,489 km with f = 1e-15.
* The following's nadir shortcut put a hit 31 m above a DSM deeper than the ellipsoid's
  smallest radius of curvature.
"""

from __future__ import annotations

import numpy as np
import pytest

import planet_intersect as pi

A, F = 6378137.0, 1 / 298.257223563
B = A * (1 - F)


@pytest.mark.parametrize("off", [1e3, 1.0, 1e-3, 1e-5, 1e-8, 1e-12, 1e-44])
@pytest.mark.parametrize("h", [0.0, 8848.0, -500.0])
def test_eq2_height_near_the_polar_axis(off, h):
    # a point `off` metres from the axis, h above the ellipsoid near the north pole: its height by
    # the exact conversion (its own tests: SPICE, PROJ) and by eq. 2 (Bowring) agree to 1e-6 m
    z = B + h
    p = np.array([[off, 0.0, z], [0.0, -off, -z]])
    _, _, he = pi.ecef_to_geodetic(p, method="exact")
    _, _, hb = pi.ecef_to_geodetic(p, method="bowring")
    np.testing.assert_allclose(hb, he, rtol=0, atol=1e-6)
    # and both are the point's height: h plus the polar cap's sag off^2 / (2 (a^2/b + h)) (the next term ~1e-9 m)
    np.testing.assert_allclose(he, h + off ** 2 / (2 * (A * A / B + h)), rtol=0, atol=1e-6)


def test_the_following_near_a_pole_finds_the_exact_modes_hits():
    # the review's polar grid: 11 x 72 cells from 89.99 to 90.00 deg, heights 0-50 m; rays from
    # 3 km, 1e-6 m from the axis, 1e-5 to 1e-3 deg off nadir: all MISS before
    rng = np.random.default_rng(1)
    dsm = pi.GeodeticDSM.from_array(rng.uniform(0, 50, (11, 72)), 89.99, 0.0, 0.001, 5.0, interpolation="bilinear")
    s, l = [], []
    for zen_deg in (1e-5, 1e-3, 1e-2):
        for k in range(8):
            az, zen = 2 * np.pi * k / 8 + 0.1, np.radians(zen_deg)
            t = np.array([1e-6 * np.cos(az), 1e-6 * np.sin(az), B + 20.0])
            d = np.array([np.sin(zen) * np.cos(az + 1), np.sin(zen) * np.sin(az + 1), np.cos(zen)])
            s.append(t + 3000.0 * d)
            l.append(-d)
    s, l = np.array(s), np.array(l)
    fo = pi.intersect(dsm, s, l, method="following", threads=1)
    ex = pi.intersect(dsm, s, l, method="exact", threads=1)
    assert np.all(ex.status == 0) and np.all(fo.status == 0), fo.status
    np.testing.assert_allclose(fo.distance, ex.distance, rtol=0, atol=1e-5)


@pytest.mark.parametrize("f", [1e-15, 1e-12, 1e-9, 1e-6])
def test_heights_near_the_centre_of_a_nearly_round_body(f):
    # the ellipsoid lies between the spheres of radius b and a, so a point at distance r from the
    # centre is between b - r and a - r from it: the height is within [-(a - r), -(b - r)]
    a = 1.0
    b = a * (1 - f)
    e2 = f * (2 - f)
    rng = np.random.default_rng(3)
    d = rng.normal(size=(400, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    k = np.repeat([0.5, 1.5, 3.0, 10.0, 1e3, 1e6], 400 // 6 + 1)[:400]
    p = d * np.minimum(k * a * e2, 0.5)[:, None]
    r = np.linalg.norm(p, axis=1)
    lat, lon, h = pi.ecef_to_geodetic(p, a, f)
    assert np.all(h >= -(a - r) - 4e-16) and np.all(h <= -(b - r) + 4e-16), np.max(
        np.maximum(-(a - r) - h, h + (b - r)))
    # and the answer maps back to the point (its latitude may be ill-conditioned; the point is not)
    back = pi.geodetic_to_ecef(lat, lon, h, a, f)
    assert np.max(np.linalg.norm(back - p, axis=1)) < 1e-14


def test_the_following_refuses_a_dsm_deeper_than_the_smallest_radius_of_curvature():
    a, f = 1000.0, 0.3                                   # b^2 / a = 490
    dsm = pi.GeodeticDSM.from_array(np.full((19, 36), -630.0), -90.0, -180.0, 10.0, 10.0, a=a, f=f)   # global
    s, l = np.array([[2 * a, 0.0, 0.0]]), np.array([[-1.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match="smallest radius of curvature"):
        pi.intersect(dsm, s, l, method="following")
    ex = pi.intersect(dsm, s, l, method="exact")
    assert ex.status[0] == 0 and ex.height[0] == pytest.approx(-630.0, abs=1e-6)
    # the review's brute force: x = 311.2876 on the equator
    assert ex.p[0, 0] == pytest.approx(311.2876, abs=1e-4)


def test_eq2_at_the_centre_is_minus_b():
    # the centre's nearest surface points are the poles: h = -b, as the exact conversion says (the
    # polar form above first dropped the axis case and gave -a there: a second review)
    for method in ("bowring", "exact"):
        _, _, h = pi.ecef_to_geodetic([0.0, 0.0, 0.0], method=method)
        assert float(h) == pytest.approx(-B, abs=1e-6), method
