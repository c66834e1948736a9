"""The cell-walk speed probe (benchmarks/cell_walk.py, docs/shin-park-notes.md "Fifteenth look").

The probe is unsound on purpose. Its speed bounds what a sound cell walk could reach, so the
notes' argument rests on two things it claims to do, and this file checks both:

* it finds the same first hits as the exact mode, up to its straight track's error;
* its cubic map gives (row, column, height) to a few nanometres over the scene's box.

The exact mode is itself checked against the exhaustive reference (test_dsm_references.py).
The cubic map is checked against the package's geodetic_to_ecef (by fit_cubic) and against
pyproj's geodetic conversion. Nothing here is timed.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "benchmarks"))

import planet_intersect as pi  # noqa: E402
from planet_intersect import synthetic_dsm as sd  # noqa: E402

pytestmark = pytest.mark.skipif(shutil.which("gfortran") is None,
                                reason="gfortran not found: the probe is compiled at run time (./dev setup installs it)")


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    import cell_walk as cw

    grid = sd.building_scene(n=256, seed=11)
    grid.pop("roof_id")
    s, l = sd.pushbroom_rays(grid, 600, seed=3)
    h = grid["heights"]
    coef, cen, err = cw.fit_cubic(grid, float(h.min()), float(h.max()), npts=40_000)
    probe = cw.CellWalk(tmp_path_factory.mktemp("cell_walk"))
    probe.prepare(grid, coef, cen)
    dsm = pi.GeodeticDSM.from_array(h, grid["lat_first"], grid["lon_first"], grid["dlat"], grid["dlon"],
                                    a=grid["a"], f=grid["f"])
    ex = pi.intersect(dsm, s, l, method="exact", threads=1)
    return dict(grid=grid, s=s, l=l, coef=coef, cen=cen, err=err, probe=probe, exact=ex)


def test_the_cubic_map_is_nanometre_accurate_over_the_scene(scene):
    # measured on fresh points by fit_cubic itself (against geodetic_to_ecef) ...
    err = scene["err"]
    assert err[0] < 1e-7 and err[1] < 1e-7          # rows, columns
    assert err[2] < 1e-7                             # metres
    # ... and here against pyproj's geodetic conversion, a code the package does not share
    pyproj = pytest.importorskip("pyproj")
    import cell_walk as cw

    g = scene["grid"]
    rng = np.random.default_rng(5)
    nr, nc = g["heights"].shape
    i, j = rng.uniform(0, nr - 1, 2000), rng.uniform(0, nc - 1, 2000)
    hmin, hmax = float(g["heights"].min()), float(g["heights"].max())
    h = rng.uniform(hmin, hmax, 2000)
    lat, lon = g["lat_first"] + i * g["dlat"], g["lon_first"] + j * g["dlon"]
    to_xyz = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    x, y, z = to_xyz.transform(lon, lat, h)
    off = (np.c_[x, y, z] - scene["cen"]) * 1e-3
    mons = cw.monomials()
    design = np.stack([off[:, 0] ** a * off[:, 1] ** b * off[:, 2] ** c for a, b, c in mons], axis=1)
    got = design @ scene["coef"]
    assert np.abs(got[:, 0] - i).max() < 1e-7
    assert np.abs(got[:, 1] - j).max() < 1e-7
    assert np.abs(got[:, 2] - h).max() < 1e-7


@pytest.mark.parametrize("conv", [0, 1], ids=["heikkinen", "cubic"])
def test_the_probe_finds_the_exact_modes_hits_to_its_straight_tracks_error(scene, conv):
    d, count = scene["probe"].trace(scene["s"], scene["l"], conv)
    ex = scene["exact"]
    ref = np.where(ex.hit, ex.distance, np.nan)
    both = np.isfinite(d) & np.isfinite(ref)
    # it walks: a few blocks and cells a ray, not the slab's ~100 cells one by one
    assert 1 <= count[1] <= 40 and 1 <= count[0] <= 40
    # hits where the exact mode hits, at its distance: the straight track's sagitta is
    # millimetres over the slab (the notes: median 0.5 mm, 99th percentile 1.6-2.3 cm on 2,048^2)
    assert both.sum() >= 0.97 * np.isfinite(ref).sum()
    diff = np.abs(d - ref)[both]
    assert np.median(diff) < 2e-3
    assert np.mean(diff < 0.05) >= 0.97


def test_the_two_conversions_give_the_same_walk(scene):
    a, ca = scene["probe"].trace(scene["s"], scene["l"], 0)
    b, cb = scene["probe"].trace(scene["s"], scene["l"], 1)
    both = np.isfinite(a) & np.isfinite(b)
    assert both.sum() == np.isfinite(a).sum() == np.isfinite(b).sum()
    # a 3e-9-cell map error moves a root by far less than the track's own error
    assert np.mean(np.abs(a - b)[both] < 1e-4) >= 0.99
    # the levels change what is skipped, not what is hit: cells alone and three levels find the
    # two-level walk's hits (a block's max bounds its cells', a superblock's its blocks')
    for level in (0, 3):
        e, ce = scene["probe"].trace(scene["s"], scene["l"], 0, level=level)
        np.testing.assert_array_equal(e, a)
    assert ce[2] > 0 and ce[1] < ca[1]                # three levels: superblocks visited, fewer blocks
    # the set-up alone (level 2) makes no hit
    c, cc = scene["probe"].trace(scene["s"], scene["l"], 0, level=2)
    assert not np.isfinite(c).any() and cc[0] == 0 and cc[1] == 0


def test_a_bound_call_does_no_work_over_the_grid(scene):
    # the first timed version computed H_min and H_max over all heights inside every call:
    # ~0.08 us a ray of a 0.45 us probe on 2,048^2, and the grid pushed its maxima out of the
    # cache (an independent review). The timed call must reach the grid only through Fortran.
    class NoGridWork:
        def __getattr__(self, name):
            raise AssertionError(f"the timed call touched the grid's heights in Python ({name})")

    probe = scene["probe"]
    call = probe.bind(scene["s"], scene["l"])
    want, _ = probe.trace(scene["s"], scene["l"], 0)
    saved = probe.h
    probe.h = NoGridWork()
    try:
        dist, count = call(0, 1)
        got = np.where(dist >= 0, dist, np.nan)
    finally:
        probe.h = saved
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("conv", [0, 1], ids=["heikkinen", "cubic"])
def test_the_least_refinement_pins_bracketed_roots_to_a_micrometre(scene, conv):
    # level 4 (the notes' "Sixteenth look"): two exact conversions 1 mm either side of the walk's
    # root and the root again between them. Where the exact hit lies inside that bracket, the
    # refined root is the exact mode's to 1e-6 m: the work timed is the work a sound answer needs.
    walk, _ = scene["probe"].trace(scene["s"], scene["l"], conv, level=1)
    refined, _ = scene["probe"].trace(scene["s"], scene["l"], conv, level=4)
    ex = scene["exact"]
    ref = np.where(ex.hit, ex.distance, np.nan)
    bracketed = np.isfinite(walk) & np.isfinite(ref) & (np.abs(walk - ref) < 0.9e-3)
    assert bracketed.sum() >= 0.3 * np.isfinite(ref).sum()
    close = np.abs(refined - ref)[bracketed] <= 1e-6
    assert close.mean() >= 0.9
    # and it moved them: the walk alone is within 1e-6 m on far fewer of those rays
    assert (np.abs(walk - ref)[bracketed] <= 1e-6).mean() < 0.5 * close.mean()


def test_the_timed_line_sweep_certifies_the_scans_as_the_exact_mode_does():
    # "Seventeenth look": the bound on the package's sharing design adds the line sweep's time to the
    # least refinement. The call timed must be the sweep the exact mode runs on the scans (fans found
    # from the focal points, fan=-1), doing its real work: most scan rays certified, none past its
    # first event, and the exact mode's answers the same with and without that sharing.
    from geodetic import scan_rays

    from planet_intersect import _core

    grid = sd.building_scene(n=512, seed=11)       # scans of 170-pixel lines
    grid.pop("roof_id")
    s, l = scan_rays(grid, 2000, seed=3)
    dsm = pi.GeodeticDSM.from_array(grid["heights"], grid["lat_first"], grid["lon_first"], grid["dlat"],
                                    grid["dlon"], a=grid["a"], f=grid["f"])
    pyr, meta = dsm.pyramid()
    g = dsm._core_grid()
    s_t = np.ascontiguousarray(np.asarray(s, dtype=np.float64).T)
    l_t = np.ascontiguousarray((l / np.linalg.norm(l, axis=1, keepdims=True)).T)
    rclear = _core.core_dsm_sweep(*g[:7], g[7], dsm.hmax, dsm.hmin, pyr, meta.T, s_t, l_t, -1)
    ex = pi.intersect(dsm, s, l, method="exact", threads=1)
    assert (rclear > 0).mean() >= 0.9
    hit = np.asarray(ex.hit)
    assert hit.sum() >= 0.8 * len(s)                 # 1,481 of 1,700: the rest leave the grid
    assert np.all(rclear[hit] <= ex.distance[hit])
    # the certificate ends near the surface: most of each ray's way down to its hit is proved clear
    frac = rclear[hit & (rclear > 0)] / ex.distance[hit & (rclear > 0)]
    assert np.median(frac) > 0.999
