"""Spherical-harmonic shape models as DEMs (planet_intersect.shadr, `import-shadr`).

The real model is MOLA's GTM090AA in ../shared/data/mars_mola_shadr_gtm090aa (skipped with a
reason when absent). Expectations come from its PROVENANCE.md (a NumPy synthesis made when
the data were gathered), from SciPy's spherical harmonics (sph_harm_y, a different
implementation with the Condon-Shortley phase and orthonormal scaling), from closed forms of
single terms, from the MEGDR radius grid (a different product of the same instrument) and
from NAIF SPICE on a plate model of the DEM.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect.shadr import (SHADRError, import_shadr, legendre_normalised, read_shadr, shadr_dem,
                                    shadr_radius)

SHARED = Path(os.environ.get("PI_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
GTM = SHARED / "mars_mola_shadr_gtm090aa" / "gtm090aa_sha.txt"
MEGDR = SHARED / "mars_mola_megdr_4ppd" / "mars_radius_4ppd_megt_plus_areoid.i2be"
need_gtm = pytest.mark.skipif(not GTM.is_file(), reason=f"{GTM} not found (../shared/data or PI_SHARED_DATA)")

LAT = -89.5 + np.arange(180)
LON = 0.5 + np.arange(360)


def write_sha(path: Path, terms: dict, degree: int = 3, ref: float = 3396.0, const: float = 1.0) -> Path:
    """A SHADR file: the header record, then every (n, m) to ``degree`` (``terms``: (n, m) -> (C, S))."""
    lines = [f"{ref:23.16E}, {const:23.16E}, {0.0:23.16E}, {degree:4d}, {degree:4d}, {0:4d}, {0.0:23.16E}, {0.0:23.16E}"]
    for n in range(degree + 1):
        for m in range(n + 1):
            c, s = terms.get((n, m), (0.0, 0.0))
            lines.append(f"{n:5d},{m:5d},{c:23.16E},{s:23.16E},{0.0:23.16E},{0.0:23.16E}")
    path.write_text("\n".join(lines) + "\n")
    return path


# ---- the Legendre functions against SciPy -----------------------------------------------------

def test_fully_normalised_legendre_functions_match_scipy():
    from scipy.special import sph_harm_y

    lat = np.array([-89.9, -60.0, -12.3, 0.0, 7.7, 45.0, 80.0, 89.9])
    P = legendre_normalised(90, np.sin(np.radians(lat)))
    theta = np.radians(90.0 - lat)                                   # colatitude
    worst = 0.0
    for n in range(91):
        for m in range(n + 1):
            y = sph_harm_y(n, m, theta, 0.0).real                     # orthonormal, Condon-Shortley phase
            want = math.sqrt(4 * math.pi * (2 - (m == 0))) * (-1) ** m * y
            worst = max(worst, float(np.max(np.abs(P[n, m] - want) / (1.0 + np.abs(want)))))
    assert worst < 1e-10


# ---- closed forms of single terms -------------------------------------------------------------

def test_single_terms_give_their_closed_forms(tmp_path):
    r0, c22, s31 = 100.0, 3.0, -2.0
    p = write_sha(tmp_path / "t.sha", {(0, 0): (r0, 0.0), (2, 2): (c22, 0.0), (3, 1): (0.0, s31)}, ref=0.1)
    model = read_shadr(p)
    lat = np.array([-70.0, -5.0, 33.0, 61.0])
    lon = np.array([10.0, 123.0, 250.0])
    got = shadr_radius(model, lat, lon)
    phi, lam = np.radians(lat)[:, None], np.radians(lon)[None, :]
    x, u = np.sin(phi), np.cos(phi)
    p22 = math.sqrt(15) / 2 * u ** 2                                 # 4-pi normalised, no Condon-Shortley
    # Pbar_31 = sqrt(2 * 7 * 2!/4!) * P_31, P_31 = (3/2) cos(phi) (5 sin^2 - 1)
    p31 = math.sqrt(2 * 7 * 2 / 24) * 1.5 * u * (5 * x ** 2 - 1)
    want = r0 + c22 * p22 * np.cos(2 * lam) + s31 * p31 * np.sin(lam)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    # a constant model is a sphere: a DEM of radius C_00 / 1000 km, and rays hit it at the closed form
    sphere = write_sha(tmp_path / "s.sha", {(0, 0): (5000.0, 0.0)}, degree=2, ref=5.0)
    dem = shadr_dem(sphere)
    assert np.all(np.asarray(dem.radii) == np.float32(5.0)) and (dem.re, dem.f) == (5.0, 0.0)
    res = pi.intersect(dem, np.array([[20.0, 3.0, -1.0]]), np.array([[-1.0, 0.0, 0.0]]), method="exact")
    assert res.hit[0] and res.p[0, 0] == pytest.approx(math.sqrt(25.0 - 9.0 - 1.0), abs=1e-9)


# ---- the real model -----------------------------------------------------------------------------

@need_gtm
def test_gtm090aa_reproduces_its_provenance_figures():
    model = read_shadr(GTM)
    assert (model["degree"], model["order"], model["normalisation"]) == (90, 90, 0)
    assert model["C"][0, 0] == pytest.approx(3389501.0853) and model["C"][2, 0] == pytest.approx(-5967.15966059)
    r = shadr_radius(model, LAT, LON)
    i, j = np.unravel_index(np.argmin(r), r.shape)
    assert round(r[i, j]) == 3373522 and (LAT[i], LON[j]) == (79.5, 304.5)
    i, j = np.unravel_index(np.argmax(r), r.shape)
    assert round(r[i, j]) == 3417062 and (LAT[i], LON[j]) == (17.5, 226.5)
    w = np.cos(np.radians(LAT))[:, None]
    assert float((r * w).sum() / (w.sum() * 360)) == pytest.approx(3389501.0, abs=0.1)
    assert round(float(shadr_radius(model, 18.5, 226.5)[0, 0])) == 3415720           # Olympus Mons' cell
    assert round(float(shadr_radius(model, -42.5, 70.5)[0, 0])) == 3381671           # Hellas' cell


@need_gtm
def test_gtm090aa_against_the_megdr_radius_grid():
    # a different product of the same instrument (the 4 ppd MEGDR radius grid, its 1-degree block
    # means); PROVENANCE.md: grid minus model -2.8 m on average, 247 m RMS (area-weighted); the
    # model is degree 90 (~118 km half-wavelength) and in the IAU 1991 frame
    if not MEGDR.is_file():
        pytest.skip(f"{MEGDR} not found")
    from planet_intersect.mola import mola_dem

    grid = np.asarray(mola_dem(MEGDR).radii, dtype=float).reshape(180, 4, 360, 4).mean(axis=(1, 3)) * 1000.0
    d = grid - shadr_radius(read_shadr(GTM), LAT, LON)
    w = np.cos(np.radians(LAT))[:, None]
    assert float((d * w).sum() / (w.sum() * 360)) == pytest.approx(-2.8, abs=0.1)
    assert math.sqrt(float((d ** 2 * w).sum() / (w.sum() * 360))) == pytest.approx(247.0, abs=0.5)


@need_gtm
def test_gtm090aa_dem_and_spice(tmp_path):
    dem = shadr_dem(GTM)
    model = read_shadr(GTM)
    want = shadr_radius(model, LAT, LON) / 1000.0
    np.testing.assert_allclose(np.asarray(dem.radii, dtype=float), want, rtol=1e-7)   # float32 km
    assert dem.re == pytest.approx(3396.19) and dem.f == pytest.approx(1 / 169.8, rel=1e-3)
    truncated = shadr_dem(GTM, degree=2)
    assert np.ptp(np.asarray(truncated.radii)) < np.ptp(np.asarray(dem.radii))
    pytest.importorskip("spiceypy", reason="spiceypy (NAIF SPICE) is the independent reference here")
    from conftest import mixed_rays
    from test_spice import cross_check

    s, l, _ = mixed_rays(dem, 6000, seed=24)
    figures = cross_check(dem, s, l, tmp_path / "gtm.bds")
    assert figures["both_hit"] > 3000 and figures["flags_agree"] >= 5990
    print("\nSPICE agreement, GTM090AA at 1 ppd:", figures)


# ---- refusals -----------------------------------------------------------------------------------

def test_malformed_models_are_refused_naming_the_file(tmp_path):
    good = write_sha(tmp_path / "g.sha", {(0, 0): (3.4e6, 0.0)})
    lines = good.read_text().splitlines()

    def variant(name, edit):
        p = tmp_path / name
        ls = list(lines)
        edit(ls)
        p.write_text("\n".join(ls) + "\n")
        return p

    cases = [
        (write_sha(tmp_path / "grav.sha", {(0, 0): (1.0, 0.0)}, const=42828.37), "gravity field"),
        (variant("miss.sha", lambda ls: ls.pop(5)), "missing"),
        (variant("dup.sha", lambda ls: ls.append(ls[3])), "given twice"),
        (variant("nan.sha", lambda ls: ls.__setitem__(2, "1, 0, nan, 0, 0, 0")), "C is nan"),
        (variant("word.sha", lambda ls: ls.__setitem__(2, "1, 0, one, 0, 0, 0")), "not a number"),
        (variant("s0.sha", lambda ls: ls.__setitem__(2, "1, 0, 1, 2, 0, 0")), "no sine part"),
        (variant("big.sha", lambda ls: ls.__setitem__(2, "7, 0, 1, 0, 0, 0")), "outside the header"),
        (variant("short.sha", lambda ls: ls.__setitem__(2, "1, 0")), "fields"),
        (variant("c00.sha", lambda ls: ls.__setitem__(1, "0, 0, -5, 0, 0, 0")), "C_00"),
        (variant("ref.sha", lambda ls: ls.__setitem__(0, ls[0].replace("3.3960000000000000E+03", "-1", 1))),
         "reference radius"),
    ]
    for path, match in cases:
        with pytest.raises(SHADRError, match=match) as err:
            read_shadr(path)
        assert str(path) in str(err.value), path
    with pytest.raises(SHADRError, match="cannot read"):
        read_shadr(tmp_path / "none.sha")
    (tmp_path / "empty.sha").write_text("\n\n")
    with pytest.raises(SHADRError, match="empty"):
        read_shadr(tmp_path / "empty.sha")
    for kw, match in [(dict(ppd=0), "ppd"), (dict(ppd=65), "ppd"), (dict(ppd=2.0), "ppd"), (dict(degree=9), "degree"),
                      (dict(degree=-1), "degree"), (dict(degree=1.5), "degree")]:
        with pytest.raises(ValueError, match=match):
            shadr_dem(good, **kw)


def test_mangled_models_give_a_dem_or_a_named_refusal(tmp_path):
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    base = write_sha(tmp_path / "b.sha", {(0, 0): (3.4e6, 0.0), (2, 0): (-6e3, 0.0), (1, 1): (10.0, 5.0)},
                     degree=2).read_text().splitlines()
    tokens = ["nan", "inf", "-1", "0", "1e308", "3", "99", "x", "", "1D3", "2,", "0x10"]

    @settings(max_examples=250, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
    @given(st.lists(st.tuples(st.integers(0, len(base) - 1), st.integers(0, 8), st.sampled_from(tokens)),
                    min_size=1, max_size=3))
    def check(edits):
        lines = list(base)
        for k, col, tok in edits:
            parts = lines[k].split(",")
            if col >= len(parts):
                lines.insert(k, tok)
            else:
                parts[col] = tok
                lines[k] = ",".join(parts)
        p = tmp_path / "m.sha"
        p.write_text("\n".join(lines) + "\n")
        try:
            dem = shadr_dem(p)
        except SHADRError as exc:
            assert str(p) in str(exc)
        else:
            assert np.isfinite(np.asarray(dem.radii)).all()

    check()


def test_cli_import_never_overwrites_silently(tmp_path, capsys):
    from planet_intersect.cli import main

    sha = write_sha(tmp_path / "s.sha", {(0, 0): (3.4e6, 0.0), (2, 0): (-6e3, 0.0)})
    out = tmp_path / "mars_sh"
    assert main(["import-shadr", str(sha), str(out), "--ppd", "2"]) == 0
    dem = pi.DEM.read(str(out) + ".hdr")
    assert dem.ppd == 2 and dem.re == pytest.approx(3396.19)
    before = (tmp_path / "mars_sh.dem").read_bytes()
    assert main(["import-shadr", str(sha), str(out)]) == 2
    assert "--overwrite" in capsys.readouterr().err
    assert (tmp_path / "mars_sh.dem").read_bytes() == before
    assert main(["import-shadr", str(sha), str(out), "--overwrite", "--degree", "0"]) == 0
    assert np.ptp(np.asarray(pi.DEM.read(str(out) + ".hdr").radii)) == 0.0
    assert main(["import-shadr", str(tmp_path / "none.sha"), str(tmp_path / "x")]) == 2
    assert "none.sha" in capsys.readouterr().err
    assert import_shadr(sha, tmp_path / "lib").is_file()


def test_legendre_functions_stay_orthonormal_at_high_degree():
    # the recursions' own identity, by Gauss-Legendre quadrature: (1/2) integral of Pbar_nm Pbar_n'm
    # over sin(lat) is (2 - delta_m0) delta_nn'. Measured at the cap, degree 1,800, for orders 0 to
    # 1,790: 7e-11 (docs/paper-notes.md note 24); here degree 400, every order
    from planet_intersect.shadr import MAX_DEGREE

    assert MAX_DEGREE <= 1900                       # where the sectorials' underflow starts to matter
    N = 400
    x, w = np.polynomial.legendre.leggauss(N + 20)
    P = legendre_normalised(N, x)
    worst = 0.0
    for m in range(0, N + 1, 7):
        V = P[m:, m, :]
        G = (V * w) @ V.T
        worst = max(worst, float(np.abs(G - 2 * (2 - (m == 0)) * np.eye(len(V))).max()))
    assert worst < 1e-10


def test_ppd_2_pixels_and_longitude_varying_terms(tmp_path):
    # a model that varies with longitude, at 2 pixels a degree: the pixel centres' closed form
    p = write_sha(tmp_path / "v.sha", {(0, 0): (3.4e6, 0.0), (1, 1): (2.0e3, -1.0e3)})
    dem = shadr_dem(p, ppd=2)
    lat = -90.0 + (np.arange(360) + 0.5) / 2
    lon = (np.arange(720) + 0.5) / 2
    phi, lam = np.radians(lat)[:, None], np.radians(lon)[None, :]
    want = (3.4e6 + math.sqrt(3) * np.cos(phi) * (2.0e3 * np.cos(lam) - 1.0e3 * np.sin(lam))) / 1000.0
    np.testing.assert_allclose(np.asarray(dem.radii, dtype=float), want, rtol=1e-7)


def test_review_refusals(tmp_path):
    base = write_sha(tmp_path / "b.sha", {(0, 0): (3.4e6, 0.0)})
    lines = base.read_text().splitlines()
    # an empty field is an error, not skipped (it shifted C into S's column)
    lines_e = list(lines)
    lines_e[1] = "0, 0, , 3.4E6, 0, 0"
    (tmp_path / "e.sha").write_text("\n".join(lines_e) + "\n")
    with pytest.raises(SHADRError, match="none empty"):
        read_shadr(tmp_path / "e.sha")
    # fields separated by spaces read as by commas
    (tmp_path / "sp.sha").write_text("\n".join(ln.replace(",", " ") for ln in lines) + "\n")
    assert read_shadr(tmp_path / "sp.sha")["C"][0, 0] == 3.4e6
    # a rotated reference pole, a degree above the recursion's range, a device, a directory
    lines_r = list(lines)
    lines_r[0] = lines_r[0].rsplit(",", 2)[0] + ", 10.0, 0.0"
    (tmp_path / "r.sha").write_text("\n".join(lines_r) + "\n")
    with pytest.raises(SHADRError, match="rotated pole"):
        read_shadr(tmp_path / "r.sha")
    lines_d = list(lines)
    lines_d[0] = lines_d[0].replace("   3,    3,", " 5000, 5000,")
    (tmp_path / "d.sha").write_text("\n".join(lines_d) + "\n")
    with pytest.raises(SHADRError, match="above 1800"):
        read_shadr(tmp_path / "d.sha")
    for special in ("/dev/null", str(tmp_path)):
        with pytest.raises(SHADRError, match="not a regular file"):
            read_shadr(special)
    # the gravity field in ../shared/data (space-separated) is refused as a gravity field
    grav = SHARED / "mars_mola_megdr_4ppd" / "gravity_input" / "GGM1025A.txt"
    if grav.is_file():
        with pytest.raises(SHADRError, match="gravity field"):
            read_shadr(grav)
    # the input is never written, overwrite or not
    victim = tmp_path / "m.dem"
    victim.write_bytes(base.read_bytes())
    with pytest.raises(FileExistsError, match="is the input file"):
        import_shadr(victim, tmp_path / "m", overwrite=True)
    assert victim.read_bytes() == base.read_bytes()
