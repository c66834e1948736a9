"""`examples buildings`: Shin & Park's Figs. 1-2 on a section through the paper's buildings.

The expectations are closed forms on the scene's rows, written from the
geometry and the paper alone: flat ground at h = 0, flat-roofed "nearest"
cells, rays arriving from due east at zenith z, so that a ray aimed at the
centre of cell j of a row stays in that row (its track departs from the
parallel by 1e-4 m over the 42 m it runs below 90 m) and its height above the
ground is (x - x_j) w / tan z at x cells east of its aim (w: the cell's width
in metres; Earth's curvature adds d^2 / 2R, 1.4e-4 m at d = 42 m). Then

* the first hit is in the easternmost column c whose west edge the ray passes
  below that column's height, at min(the ray's height at c's east edge, H_c)
  (a wall, or the roof);
* the paper's iterative ray tracing (Fig. 1) is the sequence of levels
  h_0 = 0, h_k+1 = H(the column the ray is in at height h_k): it converges
  when a level repeats at once, oscillates when an earlier level comes back;
* the paper's ray following (Fig. 2) samples the ray from where it is at
  H_max (eq. 3 with shin-park-notes 3-4; curvature puts that sample at or
  just above H_max, so it counts as above) in steps whose horizontal length
  is D, the smaller side of a cell (eq. 4, notes 7-8), and refines between
  the last sample above the surface and the first at or below it (h <= H,
  note 11); a sample outside the grid is skipped, or ends the ray LEFT_DSM
  when it is below H_min (notes 12, 15). It answers the first hit when that
  first entry lies between those two samples, else a later point.

Nothing here calls the package's conversions or methods: the only inputs are
the scene's heights and grid and the rays' geometry.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from planet_intersect import GeodeticDSM, dsm_examples  # noqa: E402
from planet_intersect.dsm import intersect_dsm  # noqa: E402
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
    horizontal length of the first run below the surface in metres (inf: down to the ground),
    the first entry's position in cells)."""
    tz = math.tan(math.radians(zenith))
    n = hrow.size
    out_h, out_wall, out_cls, out_hc, out_run, out_x = [], [], [], [], [], []
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
        out_x.append(x_in)
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
    return (np.array(out_h), np.array(out_wall), np.array(out_cls), np.array(out_hc), np.array(out_run),
            np.array(out_x))


def following_row(hrow, cols, w, d, zenith, hmax, hmin, x_in):
    """The paper's following on one row (see the module's docstring): class 0 (the first hit),
    1 (later) or 4 (LEFT_DSM) of rays aimed at ``cols``, from their first entries ``x_in`` (cells)."""
    tz = math.tan(math.radians(zenith))
    n = hrow.size
    out = []
    for j, xin in zip(cols, x_in):
        xt = j + 0.5
        x0 = xt + hmax * tz / w
        prev, cls = x0, None
        for k in range(1, 100_000):
            x, h = x0 - k * d / w, hmax - k * d / tz
            if not 0 <= x < n:
                if h <= hmin:
                    cls = 4
                    break
                prev = x
                continue
            if h <= hrow[int(math.floor(x))]:
                cls = 1 if xin > prev else 0
                break
            prev = x
        out.append(cls)
    return np.array(out)


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
    h_hit, wall, cls, hc, run, x_in = closed_form_row(ex.section, cols, w, ex.zenith)
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
    # following: never early, never a miss; late exactly where its samples say, ray by ray, and only
    # where the first run below the surface is shorter than one step D
    assert fo.hit.all()
    assert np.all(fo.distance >= exact.distance - 1e-6)
    late = dsm_examples.outcome(fo, exact) == 1
    d = min(_cell_width(ex.scene, ex.row))
    expect = following_row(ex.section, cols, w, d, ex.zenith, ex.dsm.hmax, ex.dsm.hmin, x_in)
    np.testing.assert_array_equal(dsm_examples.outcome(fo, exact), expect)
    assert not np.any(late[run > d])
    assert late.sum() == 1 and run[late][0] == pytest.approx(0.158, abs=2e-3)   # the L-building's west edge


def test_scene_rays_against_the_closed_form(ex):
    # panel (d): every second row and column of the scene, ray by ray, for the three methods
    h = ex.scene["heights"]
    n = h.shape[0]
    assert ex.nscene == (n // 2) ** 2 == 102_400
    cz = math.cos(math.radians(ex.zenith))
    exp_h, exp_wall, exp_it, exp_fo = (np.zeros(ex.nscene), np.zeros(ex.nscene, bool),
                                       np.zeros(ex.nscene, int), np.zeros(ex.nscene, int))
    short = 0
    for r in range(0, n, 2):
        sel = np.flatnonzero(ex.scene_rows == r)
        cols = ex.scene_cols[sel]
        w, wn = _cell_width(ex.scene, r)
        hh, wall, cls, _, run, x_in = closed_form_row(h[r], cols, w, ex.zenith)
        exp_h[sel], exp_wall[sel], exp_it[sel] = hh, wall, cls
        exp_fo[sel] = following_row(h[r], cols, w, min(w, wn), ex.zenith, ex.dsm.hmax, ex.dsm.hmin, x_in)
        short += int(np.sum(run <= min(w, wn)))
    assert np.max(np.abs(ex.scene_height - exp_h)) < 3e-3 / cz
    np.testing.assert_array_equal(ex.scene_wall, exp_wall)
    np.testing.assert_array_equal(ex.scene_class["iterative"], exp_it)
    np.testing.assert_array_equal(ex.scene_class["following"], exp_fo)
    assert ex.counts["iterative"] == [95_900, 3_320, 3_180, 0, 0, 0]
    assert ex.counts["following"] == [102_280, 120, 0, 0, 0, 0] and short == 214
    assert ex.counts["exact"] == [ex.nscene, 0, 0, 0, 0, 0]


def _row_scene(hrow):
    """A one-row scene of 1 m cells on flat ground (the shape `dsm_examples._rays` reads)."""
    from planet_intersect.synthetic_dsm import metre_steps

    dlat, dlon = metre_steps(36.5)
    h = np.vstack([hrow, hrow, hrow]).astype(float)
    return dict(heights=h, ground=np.zeros_like(h), lat_first=36.5 + dlat, lon_first=-84.0, dlat=-dlat, dlon=dlon,
                a=A, f=F)


def test_longer_cycles_and_slow_convergence_of_the_iterative_method():
    # the paper's scene has only 2-cycles and convergence within 2 levels: a row built for more.
    # Rays from the east at 45 deg (tan z = 1): aimed at cell 10, levels 0 -> 12 -> 24 -> 0 (a
    # 3-cycle); aimed at cell 40, 0 -> 5 -> 9 -> 9 (converges on the third level, behind nothing)
    from planet_intersect.dsm_examples import _rays

    hrow = np.zeros(120)
    hrow[[10]] = 12.0
    hrow[[22]] = 24.0                                   # 10.5 + 12 = 22.5: cell 22
    hrow[40] = 5.0
    hrow[45:50] = 9.0                                   # 40.5 + 5 = 45.5, 40.5 + 9 = 49.5: cells 45, 49
    sc = _row_scene(hrow)
    dsm = GeodeticDSM.from_array(sc["heights"], sc["lat_first"], sc["lon_first"], sc["dlat"], sc["dlon"],
                                 interpolation="nearest")
    cols = np.arange(120)
    s, l = _rays(sc, np.ones(120, int), cols, 45.0, 685e3)
    res = {m: intersect_dsm(dsm, s, l, method=m) for m in ("exact", "iterative")}
    w, _ = _cell_width(sc, 1)
    h_hit, _, cls, hc, _, _ = closed_form_row(hrow, cols, w, 45.0)
    got = dsm_examples.outcome(res["iterative"], res["exact"])
    np.testing.assert_array_equal(got, cls)
    assert cls[10] == 2 and got[10] == 2                # the 3-cycle
    assert cls[40] == 0 and hc[40] == 9.0 and res["iterative"].height[40] == pytest.approx(9.0, abs=1e-6)
    assert np.max(np.abs(res["exact"].height - h_hit)) < 3e-3


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
    for size in (10 ** 6, 63, 64.0, True):              # 10**6: a TiB allocation before the check
        with pytest.raises(ValueError, match="size must be an integer from 64 to 4096"):
            dsm_examples.buildings(size=size)
