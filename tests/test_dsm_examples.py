"""`examples buildings`: Shin & Park's Figs. 1-2 on a section through the paper's buildings.

The expectations are closed forms on the scene's rows, written from the
geometry and the paper alone: flat ground at h = 0, flat-roofed "nearest"
cells, rays arriving from due east at zenith z, so that a ray aimed at the
centre of cell j of a row stays in that row (its track departs from the
parallel by ~5e-5 m over the 42 m it runs below 90 m) and its height above the
ground is (x - x_j) w / tan z at x cells east of its aim (w: the cell's width
in metres; Earth's curvature changes that by < 2 mm over 42 m). Then

* the first hit is in the easternmost column c whose west edge the ray passes
  below that column's height, at min(the ray's height at c's east edge, H_c)
  (a wall, or the roof);
* the paper's iterative ray tracing (Fig. 1) is the sequence of levels
  h_0 = 0, h_k+1 = H(the column the ray is in at height h_k): it converges
  when a level repeats at once, oscillates when an earlier level comes back;
* the paper's ray following (Fig. 2, steps of one cell D horizontally from
  H_max down) can only be late where the ray's first run below the surface is
  shorter than D horizontally, and is never late where it is longer.

Nothing here calls the package's conversions or methods: the only inputs are
the scene's heights and grid and the rays' geometry.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from planet_intersect import dsm_examples  # noqa: E402
from planet_intersect.synthetic_dsm import PAPER_BUILDINGS  # noqa: E402

A, F = 6378137.0, 1 / 298.257223563
ALT = 685e3


def _cell_width(scene, row):
    """Metres per column (east-west) and per row (north-south) at the row's latitude."""
    e2 = F * (2 - F)
    lat = math.radians(scene["lat_first"] + row * scene["dlat"])
    w = math.sqrt(1 - e2 * math.sin(lat) ** 2)
    n_rad, m_rad = A / w, A * (1 - e2) / w ** 3
    return math.radians(scene["dlon"]) * n_rad * math.cos(lat), math.radians(abs(scene["dlat"])) * m_rad


def closed_form_row(hrow, cols, w, zenith):
    """For rays aimed at the centres of columns ``cols`` of one row of heights ``hrow``:
    (first-hit height, whether it is on a wall, iterative class 0/1/2 with its converged height,
    horizontal length of the first run below the surface in metres (inf: down to the ground))."""
    tz = math.tan(math.radians(zenith))
    n = hrow.size
    out_h, out_wall, out_cls, out_hc, out_run = [], [], [], [], []
    reach = int(math.ceil(hrow.max() * tz / w)) + 2
    for j in cols:
        xt = j + 0.5

        def ray_h(x):                            # the ray's height x cells east of the row's west edge
            return (x - xt) * w / tz

        # first hit: the easternmost column whose west edge the ray passes below its top
        hit_c = max(c for c in range(j, min(j + reach, n - 1) + 1) if ray_h(c) <= hrow[c])
        h_hit = min(ray_h(hit_c + 1), hrow[hit_c])
        out_h.append(h_hit)
        out_wall.append(h_hit < hrow[hit_c])
        # the first run below the surface, from the entry westward
        x_in = xt + h_hit * tz / w
        c, run = hit_c, math.inf
        while c > j:
            if ray_h(c) > hrow[c - 1]:           # out of the west wall into a lower column
                run = (x_in - c) * w
                break
            c -= 1
        out_run.append(run)
        # the iterative levels (Fig. 1)
        levels, h = [], 0.0
        cls, hc = None, math.nan
        for _ in range(20):
            levels.append(h)
            H = hrow[int(math.floor(xt + h * tz / w))]
            if H == h:
                cls, hc = (0 if abs(h - h_hit) < 1e-9 else 1), h
                break
            if H in levels:
                cls = 2
                break
            h = H
        out_cls.append(cls)
        out_hc.append(hc)
    return np.array(out_h), np.array(out_wall), np.array(out_cls), np.array(out_hc), np.array(out_run)


@pytest.fixture(scope="module")
def ex():
    return dsm_examples.buildings()


def test_the_section_passes_through_the_l_building_and_the_slab(ex):
    # the default row: 430 m north of the 640 m scene's south edge (0.1 n + 0.8 n 366/512), through the
    # L-shaped building's lower part (east 184-294 m, 25 m) and the slab (east 364-424 m, 60 m)
    assert ex.row == 209
    roofs = sorted(set(ex.section[ex.section > 0].tolist()))
    assert roofs == [PAPER_BUILDINGS[0][1], PAPER_BUILDINGS[1][1]]
    assert np.flatnonzero(ex.section == 25.0)[[0, -1]].tolist() == [184, 293]
    assert np.flatnonzero(ex.section == 60.0)[[0, -1]].tolist() == [364, 423]


def test_section_rays_against_the_closed_form(ex):
    w, _ = _cell_width(ex.scene, ex.row)
    cols = np.arange(ex.section.size)
    h_hit, wall, cls, hc, run = closed_form_row(ex.section, cols, w, ex.zenith)
    cz = math.cos(math.radians(ex.zenith))
    exact, it, fo = (ex.results[m] for m in ("exact", "iterative", "following"))
    # exact: every ray hits where the closed form says (roofs and walls), to 3 mm along the ray
    assert exact.hit.all()
    t = ALT / cz - exact.distance                                       # back from the aim point
    assert np.max(np.abs(t - h_hit / cz)) < 3e-3
    assert np.max(np.abs(exact.height - h_hit)) < 3e-3
    # walls: the package's surface height there (the taller cell) is above the hit
    np.testing.assert_array_equal(exact.surface_height > exact.height + 1e-6, wall)
    # the rays aimed within H tan z of an east wall (11.66 m and 27.98 m: 12 and 28 cell centres)
    assert wall.sum() == 12 + 28
    # iterative: the package's statuses and converged points are the closed form's, ray by ray
    oc = dsm_examples.outcome(it, exact)
    np.testing.assert_array_equal(oc, cls)
    assert (cls == 2).sum() == 40 and (cls == 1).sum() == 40        # the figure's counts
    conv = cls < 2
    np.testing.assert_allclose(it.height[conv], hc[conv], atol=3e-3)
    # following: never early, never a miss; late exactly where the first run below the surface is
    # shorter than one step (D = 1 m horizontally, shin-park-notes 7-8)
    assert fo.hit.all()
    assert np.all(fo.distance >= exact.distance - 1e-6)
    late = dsm_examples.outcome(fo, exact) == 1
    d = min(_cell_width(ex.scene, ex.row))
    assert np.all(run[late] < d) and not np.any(late[run >= d])
    assert late.sum() == 1 and run[late][0] == pytest.approx(0.158, abs=2e-3)   # the L-building's west edge


def test_scene_counts_against_the_closed_form(ex):
    # the counts of panel (d): every second row and column of the scene
    h = ex.scene["heights"]
    n = h.shape[0]
    expected = np.zeros(5, dtype=int)
    short = 0
    for r in range(0, n, 2):
        w, wn = _cell_width(ex.scene, r)
        _, _, cls, _, run = closed_form_row(h[r], np.arange(0, n, 2), w, ex.zenith)
        expected += np.bincount(cls, minlength=5)
        short += int(np.sum(run < min(w, wn)))
    assert ex.nscene == (n // 2) ** 2 == 102_400
    assert ex.counts["iterative"] == expected.tolist()
    assert ex.counts["exact"] == [ex.nscene, 0, 0, 0, 0]
    # the following is late at most where the closed form finds a run shorter than one step
    # (a ray's run along a slanted polygon edge is not a row's run: an upper bound only)
    assert 0 < ex.counts["following"][1] <= short
    assert ex.counts["following"][2:] == [0, 0, 0]


def test_the_figure_and_the_command(tmp_path):
    from planet_intersect.cli import main

    assert main(["examples", "buildings", "--size", "128", "--stride", "4", "--out", str(tmp_path / "ex")]) == 0
    png = tmp_path / "ex" / "run-001" / "buildings.png"
    assert png.stat().st_size > 20_000
    assert main(["examples", "buildings", "--size", "128", "--out", str(tmp_path / "ex")]) == 0
    assert (tmp_path / "ex" / "run-002" / "buildings.png").exists()            # a new folder, nothing overwritten


@pytest.mark.parametrize("args, msg", [
    (["--zenith", "0"], "--zenith"), (["--zenith", "85"], "--zenith"), (["--size", "32"], "--size"),
    (["--stride", "0"], "--stride"), (["--dem", "x.hdr"], "--dem is for the Mars examples"),
])
def test_the_command_refuses_bad_options(tmp_path, capsys, args, msg):
    from planet_intersect.cli import main

    assert main(["examples", "buildings", *args, "--out", str(tmp_path / "ex")]) == 2
    assert msg in capsys.readouterr().err
    assert not (tmp_path / "ex").exists()


def test_mars_examples_refuse_the_buildings_options(capsys):
    from planet_intersect.cli import main

    assert main(["examples", "olympus", "--zenith", "9"]) == 2
    assert "--zenith is for 'examples buildings'" in capsys.readouterr().err


def test_buildings_rejects_bad_arguments():
    with pytest.raises(ValueError, match="zenith"):
        dsm_examples.buildings(size=64, zenith=float("nan"))
    with pytest.raises(ValueError, match="stride"):
        dsm_examples.buildings(size=64, stride=0)
    with pytest.raises(ValueError, match="row"):
        dsm_examples.buildings(size=64, row=64)
