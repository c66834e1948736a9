"""Terrain occlusion of footprint cells (issue 13, beyond the notes): the line
from the spacecraft to each cell is cast with the package's exact first hit.

References: a meridional wall on a sphere, whose surface is known in closed
form along every line (the radius of the bilinear surface depends on longitude
only), and, on the real MOLA grid, the line sampled every ~0.25 km against the
DEM's bilinear radius.
"""

import math
import sys

import numpy as np
import pytest

import planet_intersect as pi
import planet_intersect.footprint  # noqa: F401

from conftest import shared_data_or_skip

F = sys.modules["planet_intersect.footprint"]


def _xyz(lat, lon, r):
    la, lo = np.radians(lat), np.radians(lon)
    return np.stack([r * np.cos(la) * np.cos(lo), r * np.cos(la) * np.sin(lo), r * np.sin(la)], axis=-1)


def _wall_surface(lon):
    """Bilinear radius of the wall DEM along longitude (pixel centres 10.125 and 10.375 E are 30 km up)."""
    lon = np.asarray(lon) % 360
    up = np.interp(lon, [9.875, 10.125, 10.375, 10.625], [0.0, 30.0, 30.0, 0.0], left=0.0, right=0.0)
    return 3390.0 + up


def _min_clearance(S, T, surface_of_lon, n=200_001):
    """Least (radius - surface) along the segment S -> T over the wall (inf when the line does not
    cross it: on the sphere itself a cell above its horizon is seen)."""
    k = np.linspace(0, 1, n)[:, None]
    p = S + k * (T - S)
    r = np.linalg.norm(p, axis=1)
    lon = np.degrees(np.arctan2(p[:, 1], p[:, 0])) % 360
    wall = (lon > 9.875) & (lon < 10.625) & (k[:, 0] < 1 - 1e-6)
    return float(np.min(r[wall] - surface_of_lon(lon[wall]))) if wall.any() else math.inf


def test_wall_hides_the_cells_behind_it():
    radii = np.full((720, 1440), 3390.0)
    radii[:, 40:42] += 30.0                              # columns centred at 10.125 and 10.375 E
    dem = pi.DEM.from_array(radii)
    cells = pi.CellTable(dem, 0.5)
    S = _xyz(0.25, 350.25, 3790.0)                      # the wall 20 deg east, near the footprint's edge
    fp = pi.footprint(cells, S, [0, 0, 1.0], occlusion=True)
    row = np.isclose(cells.lat[fp.cell], 0.25) & (cells.lon[fp.cell] > 8) & (cells.lon[fp.cell] < 30)
    assert row.sum() > 10
    hidden = ~fp.visible[row]
    clear = np.array([_min_clearance(S, cells.u[k] * cells.radius_dem[k], _wall_surface) for k in fp.cell[row]])
    decided = np.abs(clear) > 0.01                        # lines within 10 m of the wall top are not asserted
    assert decided.sum() >= row.sum() - 1
    assert np.array_equal(hidden[decided], clear[decided] < 0)
    print(f"\nwall: {hidden.sum()} of {row.sum()} cells behind it hidden")
    assert 3 <= hidden.sum() < row.sum()                 # some hidden, the wall itself and cells before it not
    assert not hidden[cells.lon[fp.cell[row]] < 10.5].any()
    # nothing is hidden on the plain sphere
    flat = pi.CellTable(pi.DEM.from_array(np.full((720, 1440), 3390.0)), 0.5)
    assert pi.footprint(flat, S, [0, 0, 1.0], occlusion=True).visible.all()


@pytest.mark.parametrize("name,lat,lon", [("Olympus Mons", 18.65, 226.2), ("Valles Marineris", -13.9, 300.8)])
def test_occlusion_on_mola_at_the_footprint_edge(name, lat, lon):
    path = shared_data_or_skip("mars_mola_megdr_4ppd", "mars_radius_4ppd_megt_plus_areoid.i2be")
    from planet_intersect.mola import mola_dem

    dem = mola_dem(path)
    cells = pi.CellTable(dem, 0.5)
    S = _xyz(lat, lon + 22.0, 3389.5 + 400.0)             # the feature 22 deg west: at the footprint's edge
    fp = pi.footprint(cells, S, [0, 0, 1.0], occlusion=True)
    hidden = ~fp.visible
    near = np.degrees(np.arccos(np.clip(cells.u[fp.cell] @ _xyz(lat, lon, 1.0), -1, 1))) < 5
    print(f"\n{name} from 400 km, 22 deg east of it: {len(fp)} footprint cells, {hidden.sum()} hidden, "
          f"{(hidden & near).sum()} of the {near.sum()} within 5 deg of it")
    assert hidden.sum() > 50 and (hidden & near).sum() > 10
    assert fp.nadir_angle[hidden].min() > 55            # only near the limb
    # reference: sample the lines of a random subset every ~0.25 km against the bilinear DEM
    rng = np.random.default_rng(0)
    pick = np.concatenate([rng.choice(np.flatnonzero(hidden), 40, replace=False),
                           rng.choice(np.flatnonzero(~hidden & (fp.nadir_angle > 55)), 40, replace=False)])

    def surface(p):
        la = np.degrees(np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1])))
        lo = np.degrees(np.arctan2(p[:, 1], p[:, 0])) % 360
        return dem.radius(la, lo)

    for k in pick:
        T = cells.u[fp.cell[k]] * cells.radius_dem[fp.cell[k]]
        n = int(np.linalg.norm(T - S) / 0.25)
        t = np.linspace(0, 1 - 2e-4, n)[:, None]
        p = S + t * (T - S)
        clear = np.min(np.linalg.norm(p, axis=1) - surface(p))
        if abs(clear) > 0.02:                             # decided by more than 20 m
            assert (clear < 0) == hidden[k], (k, clear)


def test_occlusion_tol_below_the_casting_accuracy_is_refused():
    """The footprint fuzzing (2026-12-03): occlusion_tol = 0 called 8-34 cells of a bare sphere
    hidden (the exact casting's hits may come up to 1e-9 rmax early). Below 1e-9 rmax it is now
    refused; at 1e-9 rmax a sphere, which hides none of the cells it selects (d . u > 0 on a
    sphere is above the horizon), hides none from any distance."""
    dem = pi.DEM.from_array(np.full((180, 360), 3390.0))
    cells = pi.CellTable(dem, 2.0)
    for tol in (0.0, 1e-12 * 3390.0, 0.99e-9 * 3390.0):
        with pytest.raises(ValueError, match="occlusion_tol = .* below the exact ray casting's accuracy"):
            pi.footprint(cells, [3490.0, 1.0, 2.0], [0, 1, 0], occlusion=True, occlusion_tol=tol)
    for alt in (100.0, 1e3, 1e6, 1e8, 1e12):
        fp = pi.footprint(cells, [3390.0 + alt, 1.0, 2.0], [0, 1, 0], occlusion=True,
                          occlusion_tol=1e-9 * 3390.0)
        assert len(fp) > 100 and fp.visible.all(), (alt, len(fp), int(np.sum(~fp.visible)))
