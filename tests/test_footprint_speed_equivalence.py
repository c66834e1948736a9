"""The fast footprint kernel (issue 13 speed work) against a plain NumPy
evaluation of the same geometry, pair by pair.

The kernel selects cells without a square root outside a narrow band, takes
cells certainly inside without testing them, computes every angle from squared
chords with one square root and one division (the cosine between 60 and 120
deg) in branch-free vectorised loops, and shares one 1/|d| between them
(docs/grs-notes.md, speed section). The expectation here is written
independently with NumPy over every cell of the table:

* selection: the exhaustive test d . u > 0 and not (d . R_hat < zeta |d|), in
  the kernel's order of operations, so the selected pairs must be identical;
* angles between vectors as arctan2(|a x b|, a . b) (accurate at every angle),
  the position angle as the bearing arctan2(u . E, u . N), the frame coordinates
  from spacecraft_frame, azimuth and elevation from those coordinates;

to 1e-9 deg and 1e-12 relative, on a rough DEM (topographic normals up to tens
of degrees off the radial, emission angles beyond 90 deg), with spacecraft from
orbit to 30,000 km (angles across 0..180 deg, all three arms of the angle
kernel), over a pole (position angle NaN) and exactly over a cell centre.
"""

import math
import sys

import numpy as np
import pytest

import planet_intersect as pi
import planet_intersect.footprint  # noqa: F401  (the module; pi.footprint is the function)

F = sys.modules["planet_intersect.footprint"]

TOL_DEG = 1e-9


@pytest.fixture(scope="module")
def cells(rough):
    return pi.CellTable(rough, 1.0)


def _angle(a, b):
    """Angle (deg) between the rows of a and b, stable at 0 and 180."""
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.sum(a * b, axis=1)))


def _reference(cells, R, v, zeta):
    """Pairs and geometry by NumPy over every cell (spectra in order, cells by index)."""
    u, rc = cells.u, cells.radius
    M = F.spacecraft_frame(R, v, method="state").reshape(-1, 3, 3)
    rows = []
    for s in range(len(R)):
        r = R[s]
        dv = r[None, :] - rc[:, None] * u
        hz = dv[:, 0] * u[:, 0] + dv[:, 1] * u[:, 1] + dv[:, 2] * u[:, 2]
        rhat = r / np.linalg.norm(r)
        a = dv[:, 0] * rhat[0] + dv[:, 1] * rhat[1] + dv[:, 2] * rhat[2]
        dist = np.sqrt(dv[:, 0] * dv[:, 0] + dv[:, 1] * dv[:, 1] + dv[:, 2] * dv[:, 2])
        k = np.flatnonzero((hz > 0) & ~(a < zeta * dist))
        d = dv[k]
        east = np.array([-rhat[1], rhat[0], 0.0])
        north = np.array([-rhat[2] * rhat[0], -rhat[2] * rhat[1], 1.0 - rhat[2] ** 2])
        x, y = u[k] @ east, u[k] @ north
        pa = np.degrees(np.arctan2(x, y)) % 360.0
        if math.hypot(rhat[0], rhat[1]) <= 1e-12:
            pa[:] = np.nan
        g = -(d @ M[s].T)                     # r_C - R in the spacecraft frame: rows of M are its axes
        rows.append(dict(
            spectrum=np.full(len(k), s), cell=k, d=d, distance=np.linalg.norm(d, axis=1),
            solid_angle=F.ODYSSEY_AREA_KM2 / np.sum(d * d, axis=1),
            zenith_centric=_angle(d, u[k]), zenith_detic=_angle(d, cells.normal_detic[k]),
            emission=_angle(d, cells.normal[k]), nadir_angle=_angle(d, np.broadcast_to(r, d.shape)),
            position_angle=pa, gsh=g, azimuth=np.degrees(np.arctan2(g[:, 2], g[:, 1])) % 360.0,
            elevation=np.degrees(np.arctan2(g[:, 0], np.hypot(g[:, 1], g[:, 2]))),
            rho=np.hypot(x, y)))
    return {name: np.concatenate([r[name] for r in rows]) for name in rows[0]}


def _states():
    rng = np.random.default_rng(2026)
    n = 10
    R = rng.standard_normal((n, 3))
    R /= np.linalg.norm(R, axis=1, keepdims=True)
    alt = np.array([380.0, 400.0, 450.0, 800.0, 2000.0, 6000.0, 30000.0, 420.0, 3000.0, 500.0])
    R *= (3390.0 + alt)[:, None]
    v = rng.standard_normal((n, 3))
    R[7] = [0.0, 0.0, 3810.0]             # over the north pole: no north, position angle NaN
    return R, v


def _over_cell(cells, R):
    """Spectrum 8 put exactly over a cell centre, 3010 km up."""
    c = len(cells) // 2 + 200             # a cell on the first row north of the equator
    R[8] = cells.u[c] * 6400.0
    return c


@pytest.mark.parametrize("zeta", [None, 0.45, -0.5, 0.97])
def test_fast_kernel_equals_numpy_reference(cells, zeta):
    R, v = _states()
    _over_cell(cells, R)
    fp = pi.footprint(cells, R, v, zeta=zeta, airmass_model=None, threads=1)
    ref = _reference(cells, R, v, 0.0 if zeta is None else zeta)
    # identical pairs; within a spectrum the kernel runs row by row (south to north)
    assert len(fp) == len(ref["cell"]) > 2000
    key = fp.spectrum.astype(np.int64) * len(cells) + fp.cell
    order = np.argsort(key, kind="stable")
    assert np.array_equal(key[order], ref["spectrum"].astype(np.int64) * len(cells) + ref["cell"])
    assert np.all(np.diff(fp.spectrum) >= 0)
    row = fp.cell // cells.ncol
    assert np.all(np.diff(row)[np.diff(fp.spectrum) == 0] >= 0)
    assert np.array_equal(fp.d[order], ref["d"])            # the same subtraction, bit for bit
    for name in ("distance", "solid_angle"):
        got, exp = getattr(fp, name)[order], ref[name]
        assert np.max(np.abs(got - exp) / exp) < 1e-12, name
    assert np.max(np.abs(fp.gsh[order] - ref["gsh"])) < 1e-12 * np.max(np.abs(ref["gsh"]))
    for name in ("zenith_centric", "zenith_detic", "emission", "nadir_angle", "elevation"):
        err = np.max(np.abs(getattr(fp, name)[order] - ref[name]))
        assert err < TOL_DEG, (name, err)
    # the bearing of a cell within 1e-6 rad of the sub-spacecraft point is ill-conditioned
    # (rounding eps/rho): only the cell under spectrum 8 (over the pole, spectrum 7, rho = 0
    # for every cell and both are NaN)
    near = (ref["rho"] < 1e-6) & (ref["spectrum"] != 7)
    assert np.array_equal(ref["cell"][near], [len(cells) // 2 + 200]) and ref["spectrum"][near] == [8]
    for name in ("position_angle", "azimuth"):
        got, exp = getattr(fp, name)[order], ref[name]
        assert np.array_equal(np.isnan(got[~near]), np.isnan(exp[~near])), name
        ok = ~np.isnan(exp) & ~near
        # both in [0, 360): compare across the wrap
        assert np.all((got[ok] >= 0) & (got[ok] < 360)), name
        err = np.max(np.abs((got[ok] - exp[ok] + 180.0) % 360.0 - 180.0))
        assert err < TOL_DEG, (name, err)
    # coverage: the far spacecraft and the rough terrain reach every arm of the angle kernel
    if zeta is None:
        angles = np.concatenate([fp.zenith_centric, fp.emission, fp.nadir_angle])
        assert angles.min() < 1e-3 and np.any((angles > 60) & (angles < 120)) and np.any(fp.emission > 120)
        pa = fp.position_angle[~np.isnan(fp.position_angle)]
        assert np.any(np.abs(pa - 180) < 1) and np.any((pa < 1) | (pa > 359))
        assert np.isnan(fp.position_angle[fp.spectrum == 7]).all()
        # NaN only for the cell under spectrum 8 (within 1e-13 rad of its sub-spacecraft point:
        # straight down, grs-notes note 5); everywhere else in [0, 360)
        nan_az = np.isnan(fp.azimuth)
        assert np.array_equal(fp.cell[nan_az], [len(cells) // 2 + 200]) and fp.spectrum[nan_az].tolist() == [8]
        assert np.all((fp.azimuth[~nan_az] >= 0) & (fp.azimuth[~nan_az] < 360))
