"""An independent review of the sensor models (2026-12-05; simulation-notes note 17). The
geometry held against its own Kepler propagation and pyproj (centre pixels on their targets to
3e-6 m, focal points to 5.7e-9 m, 36 orbit configurations); these are the inputs it found
taken or refused badly.
"""

from __future__ import annotations

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect.synthetic_dsm import oblique_pushbroom


def test_a_frame_camera_has_one_focal_point():
    l = np.tile([-1.0, 0, 0], (4, 5, 1))
    # a (k, 3) position was a camera at its first row without a word, (0, 3) an IndexError
    for bad in (np.array([[7e6, 0, 0], [0, 7e6, 0.0]]), np.zeros((0, 3)), np.zeros(2)):
        with pytest.raises(ValueError, match=r"position: expected shape \(3,\)"):
            pi.FrameCamera(bad, l)
    assert np.array_equal(pi.FrameCamera(np.array([[7e6, 0, 0]]), l).position, [7e6, 0, 0])
    assert np.array_equal(pi.FrameCamera([7e6, 0, 0], l).position, [7e6, 0, 0])


def test_absurd_sensor_sizes_are_refused_by_name():
    with pytest.raises(ValueError, match=r"shape: 1,000,000 x 1,000,000 = 1,000,000,000,000 pixels"):
        pi.FrameCamera.nadir(10.0, 20.0, 3000.0, (10**6, 10**6), 1e-5)
    with pytest.raises(ValueError, match=r"nlines must be between 1 and 10000000"):
        pi.Pushbroom.from_orbit(altitude=685e3, inclination=98.0, npixels=10, ifov=1e-3, nlines=10**8,
                                line_period=1e-9, lat=10.0, lon=20.0)
    with pytest.raises(ValueError, match=r"nlines x npixels: 10,000,000 x 1,000 = 10,000,000,000 pixels"):
        pi.Pushbroom.from_orbit(altitude=685e3, inclination=98.0, npixels=1000, ifov=1e-3, nlines=10**7,
                                line_period=1e-3, lat=10.0, lon=20.0)


def test_a_huge_altitude_is_named():
    with pytest.raises(ValueError, match=r"^altitude = 1e\+30 is more than 1e\+15 semi-major axes"):
        pi.Pushbroom.from_orbit(altitude=1e30, inclination=98.0, npixels=10, ifov=1e-3, nlines=10,
                                line_period=1e-3, lat=10.0, lon=20.0)


@pytest.mark.parametrize("kw, match", [
    (dict(azimuth=float("nan")), r"azimuth must be a finite number"),
    (dict(altitude=float("inf")), r"altitude must be a finite number"),
    (dict(zenith="9"), r"zenith must be a finite number"),
    (dict(step=float("inf")), r"step must be a finite number"),
])
def test_oblique_scans_check_their_numbers(kw, match):
    scene = dict(heights=np.zeros((10, 10)), lat_first=0.0, lon_first=0.0, dlat=1e-5, dlon=1e-5)
    with pytest.raises(ValueError, match=match):
        oblique_pushbroom(scene, **kw)


def test_oblique_scans_check_their_grid():
    ok = dict(heights=np.zeros((10, 10)), lat_first=0.0, lon_first=0.0, dlat=1e-5, dlon=1e-5)
    s, l = oblique_pushbroom(ok)
    assert s.shape == (10, 3) and l.shape == (10, 10, 3)
    with pytest.raises(ValueError, match=r"scene\['dlat'\] and scene\['dlon'\] must be non-zero"):
        oblique_pushbroom({**ok, "dlat": 0.0})
    with pytest.raises(ValueError, match=r"scene\['heights'\] must be a 2-D array"):
        oblique_pushbroom({**ok, "heights": np.zeros(10)})
    with pytest.raises(ValueError, match=r"no finite height"):
        oblique_pushbroom({**ok, "heights": np.full((10, 10), np.nan)})
