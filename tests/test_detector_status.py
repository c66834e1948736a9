"""Detector lines of sight (eqs. 16-18) and the status table."""

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect import _core
from planet_intersect._status import STAT_MESSAGES


def test_detector_los_geometry():
    l0 = np.array([0.0, 0.0, -1.0])
    q = np.array([0.0, 1.0, 0.0])
    los = pi.detector_los(l0, q, nh=5, nv=3, dh=0.01, dv=0.02)
    assert los.shape == (15, 3)
    np.testing.assert_allclose(np.linalg.norm(los, axis=1), 1.0, atol=1e-15)
    # centre pixel (i=3, j=2) looks along l0
    np.testing.assert_allclose(los[(2 - 1) * 5 + (3 - 1)], l0, atol=1e-15)
    h = np.cross(l0, q)                                   # eq. 16: (1, 0, 0) x ... = (1,0,0)
    # pixel (i=5, j=2): l0 + sin(2 dh) h, normalised (eq. 18)
    expect = l0 + np.sin(2 * 0.01) * h
    np.testing.assert_allclose(los[(2 - 1) * 5 + 4], expect / np.linalg.norm(expect), atol=1e-15)
    # pixel (i=3, j=1): l0 - sin(dv) q
    expect = l0 - np.sin(0.02) * q
    np.testing.assert_allclose(los[2], expect / np.linalg.norm(expect), atol=1e-15)


def test_detector_los_rejects_parallel_q():
    with pytest.raises(ValueError, match="q is parallel to l0"):
        pi.detector_los([0, 0, 1], [0, 0, 2], 3, 3, 0.01, 0.01)


def test_status_table_matches_compiled_codes():
    codes = _core.core_codes()
    assert list(codes[:16]) == sorted(STAT_MESSAGES)
    ray = [pi.RayStatus.HIT, pi.RayStatus.LIMB, pi.RayStatus.AWAY, pi.RayStatus.HIT_UNCONVERGED,
           pi.RayStatus.BAD_DIRECTION, pi.RayStatus.BAD_POSITION, pi.RayStatus.INSIDE, pi.RayStatus.READ_ERROR,
           pi.RayStatus.UNRESOLVED]
    assert list(codes[16:]) == ray
    assert sorted(pi.RAY_STATUS) == ray


def test_to_xarray_and_table(rough):
    xr = pytest.importorskip("xarray", reason="xarray is an optional extra")
    res = pi.intersect(rough, [5000.0, 0, 0], [[-1.0, 0, 0], [1.0, 0, 0], [-1.0, 1.0, 0]])
    ds = res.to_xarray()
    assert isinstance(ds, xr.Dataset)
    assert ds["p"].dims == ("ray", "xyz") and ds.sizes["ray"] == 3
    np.testing.assert_array_equal(ds["status"].values, res.status)
    table = res.to_table()
    np.testing.assert_array_equal(table["p_x"], res.p[:, 0])
    assert list(res.status) == [0, 2, 1]
