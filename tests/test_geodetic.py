"""Geodetic conversions (Shin & Park eq. 2 and the exact method) against PROJ and SPICE."""

from __future__ import annotations

import numpy as np
import pytest

import planet_intersect as pi

A, F = 6378137.0, 1 / 298.257223563
B = A * (1 - F)


def random_points(n, seed=1):
    """Geodetic points uniform on the sphere of directions, h from -1 km to beyond the Moon."""
    rng = np.random.default_rng(seed)
    lat = np.degrees(np.arcsin(rng.uniform(-1, 1, n)))
    lon = rng.uniform(-180, 180, n)
    h = np.concatenate([rng.uniform(-1000, 1e4, n // 2), 10 ** rng.uniform(1, 8.7, n - n // 2)])
    lat[:8] = [90, -90, 0, 0, 89.9999999, -89.9999999, 1e-12, -1e-12]
    return lat, lon, h


def test_geodetic_to_ecef_against_pyproj():
    pyproj = pytest.importorskip("pyproj", reason="pyproj (extra 'geo') is not installed")
    lat, lon, h = random_points(100_000)
    p = pi.geodetic_to_ecef(lat, lon, h)
    t = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    q = np.stack(t.transform(lon, lat, h), axis=1)
    rel = np.linalg.norm(p - q, axis=1) / np.linalg.norm(q, axis=1)
    assert rel.max() < 1e-9


def test_ecef_to_geodetic_against_pyproj():
    """PROJ's geocentric inverse agrees to 1e-9 relative up to 1000 km; above, PROJ
    itself drifts (measured up to 8.4e-9 rad at 12,000 km against SPICE and the
    round trip), so the comparison stops at 1000 km."""
    pyproj = pytest.importorskip("pyproj", reason="pyproj (extra 'geo') is not installed")
    lat, lon, h = random_points(200_000, seed=2)
    keep = h <= 1.0e6
    lat, lon, h = lat[keep][:100_000], lon[keep][:100_000], h[keep][:100_000]
    t = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    q = np.stack(t.transform(lon, lat, h), axis=1)
    la, lo, hh = pi.ecef_to_geodetic(q)
    t2 = pyproj.Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
    lo2, la2, h2 = t2.transform(q[:, 0], q[:, 1], q[:, 2])
    r = np.linalg.norm(q, axis=1)
    dlon = (lo - lo2 + 180) % 360 - 180
    away = np.abs(la2) < 89.9                      # longitude is arbitrary on the axis
    assert np.max(np.abs(np.radians(la - la2))) < 1e-9
    assert np.max(np.abs(np.radians(dlon[away]) * np.cos(np.radians(la2[away])))) < 1e-9
    assert np.max(np.abs(hh - h2) / r) < 1e-9


def test_ecef_to_geodetic_against_spice():
    sp = pytest.importorskip("spiceypy", reason="spiceypy is not installed")
    lat, lon, h = random_points(100_000, seed=3)
    q = pi.geodetic_to_ecef(lat, lon, h)
    la, lo, hh = pi.ecef_to_geodetic(q)
    g = np.array([sp.recgeo(x, A, F) for x in q])       # (lon, lat, alt), radians
    r = np.linalg.norm(q, axis=1)
    assert np.max(np.abs(np.radians(la) - g[:, 1])) < 1e-9
    off_axis = np.abs(lat) < 89.9999
    dlon = (np.radians(lo) - g[:, 0] + np.pi) % (2 * np.pi) - np.pi
    assert np.max(np.abs(dlon[off_axis] * np.cos(g[off_axis, 1]))) < 1e-9
    assert np.max(np.abs(hh - g[:, 2]) / r) < 1e-9
    # and georec for the forward direction
    k = np.arange(0, 100_000, 10)
    p2 = np.array([sp.georec(np.radians(lon[i]), np.radians(lat[i]), h[i], A, F) for i in k])
    assert np.max(np.linalg.norm(p2 - q[k], axis=1) / r[k]) < 1e-9


def test_round_trip_and_truth():
    lat, lon, h = random_points(100_000, seed=4)
    la, lo, hh = pi.ecef_to_geodetic(pi.geodetic_to_ecef(lat, lon, h))
    assert np.max(np.abs(la - lat)) < 1e-12
    off_axis = np.abs(lat) < 89.9999
    assert np.max(np.abs(((lo - lon + 180) % 360 - 180)[off_axis])) < 1e-9
    assert np.max(np.abs(hh - h) / (A + np.abs(h))) < 1e-14


def test_special_points():
    # poles, equator, centre, inside the evolute
    assert pi.ecef_to_geodetic([0, 0, B + 5.0]) == (90.0, 0.0, pytest.approx(5.0, abs=1e-9))
    assert pi.ecef_to_geodetic([0, 0, -B + 5.0]) == (-90.0, 0.0, pytest.approx(-5.0, abs=1e-9))
    lat, lon, h = pi.ecef_to_geodetic([A + 7.0, 0, 0])
    assert (lat, lon) == (0.0, 0.0) and h == pytest.approx(7.0, abs=1e-9)
    lat, lon, h = pi.ecef_to_geodetic([0, 0, 0])
    assert abs(lat) == 90.0 and h == pytest.approx(-B, abs=1e-6)          # nearest surface: a pole
    # 10 km from the centre on the equatorial plane (inside the evolute): nearest point off the plane
    lat, lon, h = pi.ecef_to_geodetic([1.0e4, 0, 0])
    p = pi.geodetic_to_ecef(lat, lon, 0.0)
    assert abs(h) == pytest.approx(np.linalg.norm(p - [1.0e4, 0, 0]), rel=1e-9)
    assert h < 0 and abs(h) < B


@pytest.mark.parametrize("a, f", [(A, F), (3396190.0, 1 / 169.894), (13000.0, 0.3), (13000.0, 0.6),
                                  (1737400.0, 0.0)])
def test_inside_the_evolute(a, f):
    """Points deep inside the body, near and off the equatorial plane (the evolute, where
    several normals pass through a point): the conversion returns a foot point that
    reproduces the point (round trip) and is the nearest one (brute force over the
    meridian ellipse, 200,001 samples). A fuzz case, 7.8 km from the Earth's centre and
    1e-20 m off the plane, came back 5,000 km from itself before the root was solved
    for t + b^2 (docs/shin-park-notes.md note 2)."""
    b = a * (1 - f)
    c2 = a * a - b * b
    reach = c2 / a if c2 > 0 else 0.4 * a          # a sphere has no evolute: points near its centre
    rng = np.random.default_rng(11)
    n = 3000
    y0 = rng.uniform(0, 1.2 * reach, n)
    z = np.where(rng.random(n) < 0.5, 10.0 ** rng.uniform(-300, 0, n), rng.uniform(-1, 1, n)) * reach
    z[:4] = [1e-20, -1e-300, 5e-324, 1e-3]
    lon = rng.uniform(-np.pi, np.pi, n)
    p = np.stack([y0 * np.cos(lon), y0 * np.sin(lon), z], 1)
    lat, lo, h = pi.ecef_to_geodetic(p, a, f)
    q = pi.geodetic_to_ecef(lat, lo, h, a, f)
    assert np.max(np.linalg.norm(q - p, axis=1)) < 1e-14 * a
    beta = np.linspace(-np.pi / 2, np.pi / 2, 200_001)
    ex, ez = a * np.cos(beta), b * np.sin(beta)
    k = np.arange(300)
    nearest = np.array([np.min(np.hypot(ex - y0[i], ez - z[i])) for i in k])
    # never farther than the brute force's nearest sample; nearer by at most its sampling
    # error (half a sample spacing squared over the radius of curvature: < 1e-7 a)
    assert np.all(np.abs(h[k]) <= nearest + 1e-15 * a)
    assert np.all(np.abs(h[k]) >= nearest - 1e-7 * a)


def test_paper_eq2_error():
    """Eq. 2 (Bowring's one step) against the exact method: tiny near the surface,
    growing with height (values in docs/shin-park-notes.md note 2); as printed
    (b missing) it is off by ~0.125 deg and ~43 km (note 1)."""
    rng = np.random.default_rng(5)
    lat = np.degrees(np.arcsin(rng.uniform(-0.999, 0.999, 20_000)))
    lon = rng.uniform(-180, 180, 20_000)
    for hmax, lat_bound, h_bound in ((1.0e4, 1e-10, 1e-5), (1.0e6, 1e-6, 0.2)):
        h = rng.uniform(-1000, hmax, 20_000)
        p = pi.geodetic_to_ecef(lat, lon, h)
        la, lo, hh = pi.ecef_to_geodetic(p, method="bowring")
        assert np.max(np.abs(la - lat)) < lat_bound
        assert np.max(np.abs(hh - h)) < h_bound
    # eq. 2 as printed, transcribed here from the paper: z + (a^2/b^2) e^2 sin^3(theta)
    x, y, z = pi.geodetic_to_ecef(45.0, 0.0, 0.0)
    e2 = F * (2 - F)
    th = np.arctan(z * A / (B * np.hypot(x, y)))
    phi = np.arctan((z + A**2 / B**2 * e2 * np.sin(th) ** 3) / (np.hypot(x, y) - e2 * A * np.cos(th) ** 3))
    la, lo, hh = pi.ecef_to_geodetic([x, y, z], method="printed")
    assert la == pytest.approx(np.degrees(phi), abs=1e-12)
    assert la == pytest.approx(44.9039, abs=1e-4)            # 0.096 deg (10.6 km) south of the truth
    assert hh == pytest.approx(-10647.39, abs=0.01)


def test_other_body_and_sphere():
    # Mars areodetic and f = 0 (geodetic = geocentric on a sphere)
    a, f = 3396190.0, 1 / 169.8
    lat, lon, h = random_points(10_000, seed=6)
    la, lo, hh = pi.ecef_to_geodetic(pi.geodetic_to_ecef(lat, lon, h, a, f), a, f)
    assert np.max(np.abs(la - lat)) < 1e-12
    p = np.array([[1.0, 2.0, 3.0]]) * 1e6
    la, lo, hh = pi.ecef_to_geodetic(p, 3.0e6, 0.0)
    assert hh[0] == pytest.approx(np.linalg.norm(p) - 3.0e6, rel=1e-14)
    assert la[0] == pytest.approx(np.degrees(np.arcsin(3 / np.sqrt(14))), abs=1e-12)


@pytest.mark.parametrize("call, match", [
    (lambda: pi.ecef_to_geodetic([1, 2]), "p: expected shape"),
    (lambda: pi.ecef_to_geodetic([np.nan, 0, 0]), r"p\[0\] has NaN"),
    (lambda: pi.ecef_to_geodetic([1, 0, 0], method="fast"), "method must be"),
    (lambda: pi.ecef_to_geodetic([1, 0, 0], a=-1), "a .semi-major axis. must be in"),
    # the range where the exact conversion's tolerances hold (a review: silently wrong at a = 1e-90,
    # NaN at 1e120 and for |p| > 1e154 with WGS-84)
    (lambda: pi.ecef_to_geodetic([1e-90, 0, 1e-90], a=1e-90), "a .semi-major axis. must be in"),
    (lambda: pi.ecef_to_geodetic([1e120, 0, 1e120], a=1e120), "a .semi-major axis. must be in"),
    (lambda: pi.ecef_to_geodetic([1e155, 0, 0]), r"p\[0\] .* farther than 1e\+15 a"),
    (lambda: pi.ecef_to_geodetic([1, 0, 0], f=1.0), r"f \(flattening\) must be in \[0, 1\)"),
    (lambda: pi.geodetic_to_ecef(91.0, 0, 0), r"lat\[0\] = 91.0 is outside"),
    (lambda: pi.geodetic_to_ecef([0, 1], [0, 1, 2], 0), "do not broadcast"),
    (lambda: pi.geodetic_to_ecef(0, np.inf, 0), r"lon\[0\] is NaN or Inf"),
])
def test_bad_input(call, match):
    with pytest.raises(ValueError, match=match):
        call()


@pytest.mark.parametrize("lat_r, lon_r", [(36.6, -84.3), (-45.0, 179.995), (89.99, 30.0), (-89.99, -150.0),
                                          (0.004, 10.0), (60.0, 0.0)])
def test_conversion_from_a_far_reference_is_exact(lat_r, lon_r):
    """The exact DSM mode's first conversion of a ray (pi_dsm_fast's eval_x without a point of the ray)
    runs ecr_to_geodetic_near from the DSM's centre, up to ~0.01 rad away, with the slab's middle
    height as the estimate, km off: it must give the exact conversion's answer. Points within 0.02
    rad of the reference (beyond 0.01 its fallback), h from -1 km to 20 km, estimates 10 km off;
    truth from geodetic_to_ecef, and the exact conversion (checked against PROJ and SPICE above)."""
    from planet_intersect._ext import core

    rng = np.random.default_rng(int(abs(lat_r * 1000 + lon_r)))
    n = 20_000
    lat = np.clip(lat_r + np.degrees(rng.uniform(-0.02, 0.02, n)), -90, 90)
    lon = (lon_r + np.degrees(rng.uniform(-0.02, 0.02, n)) + 180) % 360 - 180
    h = rng.uniform(-1000.0, 2.0e4, n)
    lat[:3] = [lat_r, lat_r, lat[2]]
    lon[:3] = [lon_r, lon_r, lon_r]
    p = pi.geodetic_to_ecef(lat, lon, h)
    ex_lat, ex_lon, ex_h = core.core_ecr_to_geodetic(np.ascontiguousarray(p).T, A, F, 0)
    for h_est in (500.0, -1.0e4, 3.0e4):
        la, lo, hh = core.core_ecr_to_geodetic_near(np.ascontiguousarray(p).T, A, F, np.radians(lat_r),
                                                    np.radians(lon_r), h_est)
        assert np.all(np.abs(lo) <= np.pi)
        dlon = (lo - ex_lon + np.pi) % (2 * np.pi) - np.pi
        off_axis = np.abs(lat) < 89.9999
        # the same answer as the exact conversion to its ~1e-15 relative accuracy
        assert np.max(np.abs(la - ex_lat)) < 4e-15
        assert np.max(np.abs(dlon[off_axis] * np.cos(ex_lat[off_axis]))) < 4e-15
        assert np.max(np.abs(hh - ex_h)) < 4e-15 * A
        # and the truth it was made from (geodetic_to_ecef's own rounding included)
        assert np.max(np.abs(la - np.radians(lat))) < 1e-14
        assert np.max(np.abs(hh - h)) < 1e-8
