"""Small-body shape tables as DEMs (planet_intersect.shape_table, `import-shape-table`).

The real table is P. C. Thomas' Phobos model in ../shared/data/phobos_thomas_m1phobos (skipped
with a reason when absent). Expectations come from its PROVENANCE.md (figures computed there
with NumPy from the raw file), from SciPy's grid interpolator on the raw nodes (not the
module's own resampling), and from geometry: a ray aimed at the body's centre meets a radius
grid at the grid's radius in its direction.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect.shape_table import (MAX_PPD, ShapeTableError, import_shape_table, read_shape_table,
                                          shape_table_dem)

SHARED = Path(os.environ.get("PI_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
PHOBOS = SHARED / "phobos_thomas_m1phobos" / "m1phobos.tab"
need_phobos = pytest.mark.skipif(not PHOBOS.is_file(), reason=f"{PHOBOS} not found (../shared/data or PI_SHARED_DATA)")


def write_table(path: Path, radius_fn, step: float = 10.0, with_360: bool = True) -> Path:
    lats = np.arange(-90.0, 90.0 + step / 2, step)
    lons = np.arange(0.0, (360.0 if with_360 else 360.0 - step) + step / 2, step)
    lines = []
    for la in lats:
        for lo in lons:
            r = radius_fn(la, lo % 360.0) if abs(la) < 90 else radius_fn(la, 0.0)
            lines.append(f"{la:9.4f} {lo:9.4f} {r:9.4f}")
    path.write_text("\n".join(lines) + "\n")
    return path


# ---- the real table ---------------------------------------------------------------------------

@need_phobos
def test_phobos_table_reproduces_its_provenance_figures():
    lats, lons, r = read_shape_table(PHOBOS)
    assert r.shape == (91, 181) and lats[0] == -90 and lons[-1] == 360
    i, j = np.unravel_index(np.argmin(r), r.shape)
    assert r[i, j] == pytest.approx(8.1245) and (lats[i], lons[j]) == (-80, 338)
    i, j = np.unravel_index(np.argmax(r), r.shape)
    assert r[i, j] == pytest.approx(13.9822) and (lats[i], lons[j]) == (4, 28)
    eq = r[45]
    assert [eq[0], eq[45], eq[90], eq[135]] == pytest.approx([12.3668, 11.3709, 12.8225, 11.8506])
    assert r[0, 0] == pytest.approx(8.3726) and r[-1, 0] == pytest.approx(9.5983)
    mismatch = np.abs(r[:, 0] - r[:, -1])
    assert int((mismatch > 0).sum()) == 15 and mismatch.max() == pytest.approx(0.023, abs=5e-4)


@need_phobos
@pytest.mark.parametrize("longitude,ppd", [("west", None), ("east", None), ("west", 2), ("east", 3)])
def test_phobos_dem_is_the_bilinear_of_the_tables_nodes(longitude, ppd):
    from scipy.interpolate import RegularGridInterpolator

    lats, lons, r = read_shape_table(PHOBOS)
    interp = RegularGridInterpolator((lats, lons), r)              # the raw nodes, 360 column as stored
    dem = shape_table_dem(PHOBOS, longitude=longitude, ppd=ppd)
    n = ppd or 1
    assert dem.ppd == n and (dem.re, dem.f) == (1.0, 0.0)           # no spheroid: an irregular body
    lat_c = -90.0 + (np.arange(180 * n) + 0.5) / n
    lon_e = (np.arange(360 * n) + 0.5) / n
    lon_t = (360.0 - lon_e) % 360.0 if longitude == "west" else lon_e
    la, lo = np.meshgrid(lat_c, lon_t, indexing="ij")
    want = interp(np.c_[la.ravel(), lo.ravel()]).reshape(180 * n, 360 * n)
    got = np.asarray(dem.radii, dtype=float)
    assert dem.rmax == pytest.approx(got.max(), rel=1e-7)            # resampled: below the nodes' 13.9822
    diff = np.abs(got - want)
    # the module takes the mean of the 0 and 360 columns where they differ (<= 0.023 km):
    # within a node step of longitude 0 the two readings may differ by up to half of that
    near0 = (lo < 2.0) | (lo > 358.0)
    assert diff[near0].max() <= 0.0116
    assert diff[~near0].max() <= 2e-6                                # float32 of ~13 km
    # the volume, as PROVENANCE's quadrature of the raw table (about 5,750 km^3, 11.12 km)
    cell = np.radians(1.0 / n) ** 2 * np.cos(np.radians(lat_c))[:, None]
    vol = float((got ** 3 / 3.0 * cell).sum())
    assert vol == pytest.approx(5750, rel=0.01)
    assert (3 * vol / (4 * np.pi)) ** (1 / 3) == pytest.approx(11.12, abs=0.02)


@need_phobos
def test_west_and_east_readings_are_mirror_images():
    w = np.asarray(shape_table_dem(PHOBOS, longitude="west").radii)
    e = np.asarray(shape_table_dem(PHOBOS, longitude="east").radii)
    # pixel j (centre j + 0.5 deg E) read west is table longitude 359.5 - j: pixel 359 - j read east
    np.testing.assert_array_equal(w, e[:, ::-1])


@need_phobos
@pytest.mark.parametrize("method", ["stepping", "exact"])
def test_rays_at_phobos_centre_meet_the_grid_radius(method):
    from scipy.interpolate import RegularGridInterpolator

    dem = shape_table_dem(PHOBOS)
    radii = np.asarray(dem.radii, dtype=float)
    # an independent bilinear on the DEM's pixel centres, longitude wrapped by one column each side
    lat_c = -89.5 + np.arange(180)
    lon_c = np.r_[-0.5, 0.5 + np.arange(360), 360.5]
    interp = RegularGridInterpolator((lat_c, lon_c), np.c_[radii[:, -1], radii, radii[:, 0]])
    rng = np.random.default_rng(23)
    lat = rng.uniform(-80, 80, 400)
    lon = rng.uniform(0, 360, 400)
    u = np.c_[np.cos(np.radians(lat)) * np.cos(np.radians(lon)), np.cos(np.radians(lat)) * np.sin(np.radians(lon)),
              np.sin(np.radians(lat))]
    s = 100.0 * u                                                    # 100 km out, looking at the centre
    res = pi.intersect(dem, s, -u, method=method)
    want = interp(np.c_[lat, lon])
    assert np.all(res.hit)
    along = np.einsum("ij,ij->i", res.p, u)                        # the hit stays on the radial line
    assert np.abs(np.linalg.norm(res.p - along[:, None] * u, axis=1)).max() < 1e-9
    # both land on the grid's radius (measured: 1e-11 km and better; a radial ray crosses the
    # surface once, so the stepping's bracket holds the one root)
    assert np.abs(res.radius - want).max() < 1e-6


@need_phobos
def test_phobos_against_spice(tmp_path):
    # NAIF SPICE's plate model written from the same DEM (tests/test_spice.py's cross-check and its
    # derived bounds): an irregular 8-14 km body whose relief is a third of its radius
    pytest.importorskip("spiceypy", reason="spiceypy (NAIF SPICE) is the independent reference here")
    from conftest import mixed_rays
    from test_spice import cross_check

    dem = shape_table_dem(PHOBOS)
    s, l, _ = mixed_rays(dem, 8000, seed=23)
    figures = cross_check(dem, s, l, tmp_path / "phobos.bds")
    # measured 2026-12-05: every flag agrees, 4,810 common hits, 0.6 m median and 4.7 m 99th
    # percentile along the ray (the plates' bound B: 3.0 m median)
    assert figures["flags_agree"] == 8000 and figures["both_hit"] > 4500
    assert figures["median_dd"] < 0.002 and figures["near_misses"] <= 5
    print("\nSPICE agreement, Phobos (Thomas) at 1 ppd:", figures)


# ---- synthetic tables -------------------------------------------------------------------------

def bump(la, lo):
    """A 10 km sphere with a 1 km bump at latitude 10, table longitude 40."""
    return 10.0 + (1.0 if (la, lo) == (10.0, 40.0) else 0.0)


@pytest.mark.parametrize("longitude,east", [("west", 320.0), ("east", 40.0)])
def test_a_bump_lands_at_the_east_longitude_its_convention_says(tmp_path, longitude, east):
    t = write_table(tmp_path / "b.tab", bump)
    dem = shape_table_dem(t, longitude=longitude)
    assert dem.ppd == 1                                             # a 10-degree table: 1 pixel a degree
    # pixel centres lie half a degree off the nodes: the four around the bump hold 0.95^2 of it,
    # and the DEM's own bilinear between them gives that at the bump's node
    assert dem.radius(10.0, east) == pytest.approx(10.9025, abs=1e-5)
    assert dem.radius(10.0, 360.0 - east) == pytest.approx(10.0, abs=1e-5)
    # 5 deg from the bump in longitude: half of it in longitude, 0.95 in latitude
    assert dem.radius(10.0, east + 5.0) == pytest.approx(10.475, abs=1e-5)


def test_tables_without_the_360_column_and_finer_dems(tmp_path):
    t = write_table(tmp_path / "a.tab", lambda la, lo: 10.0 + 0.01 * la, step=5.0, with_360=False)
    dem = shape_table_dem(t, ppd=4, longitude="east", re=10.0)
    assert dem.ppd == 4 and dem.re == 10.0
    # a half-degree table makes 2 pixels a degree by default (pixels no larger than its step)
    half = write_table(tmp_path / "h.tab", lambda la, lo: 10.0, step=0.5)
    assert shape_table_dem(half).ppd == 2
    # linear in latitude: the bilinear is exact at every pixel centre
    lat_c = -90.0 + (np.arange(720) + 0.5) / 4
    np.testing.assert_allclose(np.asarray(dem.radii)[:, 7], 10.0 + 0.01 * lat_c, atol=2e-6)


@pytest.mark.parametrize("text,match", [
    ("1 2\n", "2 columns"),
    ("a b c\n", "not three numbers"),
    ("0 0 nan\n" * 5, "NaN or infinity"),
    ("-90 0 1\n-90 180 1\n90 0 1\n90 180 1\n0 0 1\n0 180 1\n", "latitudes run"),
    ("-90 0 1\n-90 90 1\n-90 180 1\n90 0 1\n90 90 1\n", "do not form rows"),
    ("-90 0 1\n-90 10 1\n0 0 1\n0 10 1\n90 0 1\n90 10 1\n", "longitudes must run"),
])
def test_malformed_tables_are_refused_naming_the_file(tmp_path, text, match):
    p = tmp_path / "bad.tab"
    p.write_text(text)
    with pytest.raises(ShapeTableError, match=match) as err:
        read_shape_table(p)
    assert str(p) in str(err.value)


def test_other_refusals(tmp_path):
    with pytest.raises(ShapeTableError, match="cannot read"):
        read_shape_table(tmp_path / "missing.tab")
    p = tmp_path / "bin.tab"
    p.write_bytes(b"\xff\xfe 1 2\n")
    with pytest.raises(ShapeTableError, match="not ASCII"):
        read_shape_table(p)
    neg = write_table(tmp_path / "neg.tab", lambda la, lo: -1.0 if la == 0 else 10.0)
    with pytest.raises(ShapeTableError, match="not positive"):
        read_shape_table(neg)
    pole = write_table(tmp_path / "pole.tab", bump)
    text = pole.read_text().splitlines()
    text[1] = text[1][:-9] + f"{12.0:9.4f}"                       # a second radius in the south pole row
    pole.write_text("\n".join(text) + "\n")
    with pytest.raises(ShapeTableError, match="pole row"):
        read_shape_table(pole)
    good = write_table(tmp_path / "g.tab", bump)
    for kw, match in [(dict(ppd=0), "ppd"), (dict(ppd=MAX_PPD + 1), "ppd"), (dict(ppd=1.5), "ppd"),
                      (dict(ppd=True), "ppd"), (dict(longitude="up"), "longitude"), (dict(f=0.1), "needs re"),
                      (dict(re=-1.0), "re must"), (dict(re=float("nan")), "re must"), (dict(re=1.0), "placeholder"),
                      (dict(re=1000.0), "factor 10")]:
        with pytest.raises(ValueError, match=match):
            shape_table_dem(good, **kw)


def test_a_seam_wider_than_one_percent_is_refused(tmp_path):
    # the 360 column repeats the 0 column; m1phobos's differ by <= 0.23 %, here by 100 %
    lines = write_table(tmp_path / "s.tab", lambda la, lo: 10.0).read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.split()[:2] == ["30.0000", "360.0000"])
    lines[k] = "  30.0000  360.0000   20.0000"
    (tmp_path / "s.tab").write_text("\n".join(lines) + "\n")
    with pytest.raises(ShapeTableError, match="360 and 0 longitude columns differ"):
        read_shape_table(tmp_path / "s.tab")


def test_import_writes_a_dem_and_never_overwrites_silently(tmp_path, capsys):
    from planet_intersect.cli import main

    t = write_table(tmp_path / "b.tab", bump)
    out = tmp_path / "phobos_like"
    assert main(["import-shape-table", str(t), str(out)]) == 0
    dem = pi.DEM.read(str(out) + ".hdr")
    assert dem.radius(10.0, 320.0) == pytest.approx(10.9025, abs=1e-5)
    before = (tmp_path / "phobos_like.dem").read_bytes()
    assert main(["import-shape-table", str(t), str(out), "--longitude", "east"]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert (tmp_path / "phobos_like.dem").read_bytes() == before
    assert main(["import-shape-table", str(t), str(out), "--longitude", "east", "--overwrite"]) == 0
    assert pi.DEM.read(str(out) + ".hdr").radius(10.0, 40.0) == pytest.approx(10.9025, abs=1e-5)
    assert main(["import-shape-table", str(tmp_path / "nope.tab"), str(tmp_path / "x")]) == 2
    assert "nope.tab" in capsys.readouterr().err
    hdr = import_shape_table(t, tmp_path / "lib", re=10.0)
    assert pi.DEM.read(hdr).re == 10.0
    # the input is never written, --overwrite or not (a review: a table named X.dem became the DEM)
    victim = tmp_path / "t2.dem"
    victim.write_bytes(t.read_bytes())
    assert main(["import-shape-table", str(victim), str(tmp_path / "t2"), "--overwrite"]) == 2
    assert "is the input file" in capsys.readouterr().err and victim.read_bytes() == t.read_bytes()
    assert main(["import-shape-table", str(t), str(tmp_path / "no" / "such" / "out")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_mangled_tables_give_a_dem_or_a_named_refusal(tmp_path):
    # the PDS reader's lesson (tests/test_pds.py): a reader of user files meets every kind of
    # damage; each must end as a DEM or a ShapeTableError naming the file, nothing else
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    base = write_table(tmp_path / "base.tab", bump, step=30.0).read_text().splitlines()
    tokens = ["nan", "inf", "-1", "0", "1e308", "1e-300", "x", "", "90", "-90", "360", "1e5", "10.0 10.0"]

    @settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
    @given(st.lists(st.tuples(st.integers(0, len(base) - 1), st.integers(0, 3), st.sampled_from(tokens)),
                    min_size=1, max_size=4))
    def check(edits):
        lines = list(base)
        for k, col, tok in edits:
            parts = lines[k].split() if k < len(lines) else []
            if col == 3 or not parts:
                lines.insert(k, tok)                                  # a line inserted
            elif col < len(parts):
                parts[col] = tok
                lines[k] = " ".join(parts)
        p = tmp_path / "m.tab"
        p.write_text("\n".join(lines) + "\n")
        try:
            dem = shape_table_dem(p)
        except ShapeTableError as exc:
            assert str(p) in str(exc)
        else:
            assert np.isfinite(np.asarray(dem.radii)).all()

    check()


def test_a_subnormal_radius_at_the_seam_is_refused_without_a_warning(tmp_path):
    # found by fuzzing 120,000 mangled tables with warnings as errors (the seam's relative
    # difference overflowed, and its message multiplied a NumPy scalar again)
    import warnings

    lines = write_table(tmp_path / "s.tab", lambda la, lo: 10.0).read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.split()[:2] == ["30.0000", "0.0000"])
    lines[k] = "  30.0000    0.0000   1e-320"
    (tmp_path / "s.tab").write_text("\n".join(lines) + "\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ShapeTableError, match="360 and 0 longitude columns differ by inf"):
            read_shape_table(tmp_path / "s.tab")
