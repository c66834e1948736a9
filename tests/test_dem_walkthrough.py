"""Faults a newcomer's walk-through of the planetary system found (2026-12-04): the spheroid's
re against the radii, Table 1's "no spheroid" setting said, a truncated file behind `radii`,
the geometry helpers' inputs, what the result fields are. Expectations from geometry written
here (closed forms on a sphere), not from the package's code."""

from __future__ import annotations

import os
import warnings

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect import DEMError


def test_re_in_another_unit_than_the_radii_is_refused(tmp_path):
    radii = np.full((180, 360), 1737.4)                          # the Moon in km
    with pytest.raises(DEMError, match=r"re = 1\.7374e\+06 is not within a factor 10 of rmax = 1737\.4"):
        pi.DEM.from_array(radii, f=0.0, re=1737400.0)           # re in metres: altitudes were -1.7e6 km
    with pytest.raises(DEMError, match="re = 0.0111 is not within a factor 10"):
        pi.DEM.from_array(radii * 1000.0, f=0.0, re=0.0111)
    dem = pi.DEM.from_array(radii, f=0.0, re=1737.4)
    hdr = dem.write(tmp_path / "moon")
    lines = hdr.read_text().splitlines()
    # the fourth value line is re: write a header with re in metres next to km radii
    vals = [i for i, ln in enumerate(lines) if ln.strip() and not ln.lstrip().startswith(("#", "!"))]
    lines[vals[3]] = "1737400.0"
    bad = tmp_path / "moon_m.hdr"
    bad.write_text("\n".join(lines) + "\n")
    os.link(tmp_path / "moon.dem", tmp_path / "moon_m.dem")
    with pytest.raises(DEMError, match="not within a factor 10 of rmax"):
        pi.DEM.read(bad)


def test_no_spheroid_is_said_and_a_unit_spheroid_with_flattening_still_works():
    radii = np.full((180, 360), 1.0)
    with pytest.warns(UserWarning, match="'no spheroid' setting"):
        pi.DEM.from_array(radii, f=0.0, re=1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        dem = pi.DEM.from_array(radii)                           # no re: no spheroid, no warning
    r = pi.intersect(dem, [1.1, 0.0, 0.0], [[-1.0, 0.0, 0.0], [-0.3, 1.0, 0.0]])
    assert list(r.status) == [0, 1] and np.isnan(r.altitude[0]) and np.isnan(r.tangent_height[1])
    # the tangent altitude above the DEM still holds: closest approach of the line to the centre
    # (x = 1.1 - 0.3 t, y = t) is 1.1 / sqrt(1.09), minus the radius 1
    assert r.tangent_altitude[1] == pytest.approx(1.1 / np.sqrt(1.09) - 1.0, abs=1e-12)
    # a body in units of its own radius with a spheroid: f > 0 keeps re = 1 meaningful
    f = 0.01
    lat = -90 + (np.arange(180) + 0.5)
    b = 1.0 - f
    c = np.cos(np.radians(lat))
    rs = np.sqrt(b * b / (1.0 - (2 * f - f * f) * c * c))       # the spheroid's own radius
    dem = pi.DEM.from_array(np.repeat(rs[:, None], 360, axis=1) + 0.001, f=f, re=1.0)
    r = pi.intersect(dem, [1.5, 0.0, 0.0], [-1.0, 0.0, 0.0])
    assert r.status[0] == 0 and r.altitude[0] == pytest.approx(0.001, abs=1e-6)


def test_radii_of_a_truncated_file_raise_instead_of_sigbus(tmp_path):
    dem = pi.DEM.from_array(np.full((180, 360), 3390.0), f=0.0, re=3390.0)
    hdr = dem.write(tmp_path / "m")
    d = pi.DEM.read(hdr)
    assert float(d.radii.max()) == 3390.0
    del d
    d = pi.DEM.read(hdr)
    os.truncate(tmp_path / "m.dem", 1000)
    with pytest.raises(DEMError, match="its size changed since DEM.read"):
        d.radii                                                  # noqa: B018 (the access itself)


def test_spheroid_helpers_refuse_impossible_inputs():
    assert pi.spheroid_radius(0.0, 0.1, 2.0) == pytest.approx(2.0, rel=1e-15)
    assert pi.spheroid_radius(90.0, 0.1, 2.0) == pytest.approx(1.8, rel=1e-15)
    with pytest.raises(ValueError, match=r"lat_deg must be finite and within \[-90, 90\], got 95.0"):
        pi.spheroid_radius(95.0, 0.1, 1.0)
    with pytest.raises(ValueError, match=r"flattening f must be in \[0, 1\), got 2.0"):
        pi.spheroid_radius(45.0, 2.0, 1.0)
    with pytest.raises(ValueError, match="re must be finite and > 0, got -5.0"):
        pi.spheroid_radius(45.0, 0.1, -5.0)
    with pytest.raises(ValueError, match="l must be non-zero and finite"):
        pi.ray_spheroid_intersection([2.0, 0, 0], [0.0, 0, 0], 0.0, 1.0)
    p, d = pi.ray_spheroid_intersection([0.5, 0, 0], [1.0, 0, 0], 0.0, 1.0)   # from inside: no entry
    assert np.isnan(d[0])
    p, d = pi.ray_spheroid_intersection([3.0, 0, 0], [-1.0, 0, 0], 0.0, 1.0)
    assert d[0] == 2.0


def test_detector_field_beyond_a_right_angle_is_refused():
    with pytest.raises(ValueError, match=r"dh = 0.86 rad over 101 pixels: the field reaches 43 rad"):
        pi.detector_los([-1, 0, 0], [0, 0, 1], nh=101, nv=101, dh=0.86, dv=0.86)
    los = pi.detector_los([-1, 0, 0], [0, 0, 1], nh=3, nv=1, dh=np.pi / 2, dv=0.1)   # the edge: +-90 deg
    assert los.shape == (3, 3)


def test_result_fields_say_what_they_are():
    doc = pi.IntersectResult.__doc__
    assert "tangent_height" in doc and "Attributes" in doc and "height above the spheroid" in doc
    assert "surface_height" in pi.DSMResult.__doc__
    xr = pytest.importorskip("xarray")  # noqa: F841
    dem = pi.DEM.from_array(np.full((180, 360), 10.0), f=0.0, re=10.0)
    ds = pi.intersect(dem, [20.0, 0, 0], [[-1.0, 0, 0], [-1.0, 1.0, 0]]).to_xarray()
    assert "nearest the spheroid" in ds["tc"].attrs["long_name"]


def test_unknown_keyword_to_intersect_on_a_dem_is_called_unknown():
    dem = pi.DEM.from_array(np.full((180, 360), 10.0), f=0.0, re=10.0)
    with pytest.raises(TypeError, match=r"unexpected keyword argument\(s\) \['stepmode'\]"):
        pi.intersect(dem, [20.0, 0, 0], [-1.0, 0, 0], stepmode=1)
