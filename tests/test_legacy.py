"""The legacy workflow: the compiled test_planet_intersect driver against intersect()."""

import subprocess

import numpy as np
import pytest

import planet_intersect as pi

from conftest import mixed_rays


@pytest.fixture(scope="module")
def driver():
    path = pi.legacy_paths()["driver"]
    if not path.exists():
        pytest.fail(f"the legacy driver was not installed at {path}")
    return path


@pytest.mark.parametrize("read_mode, step_mode", [(0, 1), (1, 0)])
def test_driver_matches_intersect(tmp_path, rough, driver, read_mode, step_mode):
    hdr = rough.write(tmp_path / "legacy", dtype="float32")
    dem = pi.DEM.read(hdr)
    s, l, _ = mixed_rays(dem, 3000, seed=21)
    rays = tmp_path / "rays.txt"
    np.savetxt(rays, np.hstack([s, l]), fmt="%.17e", header="sx sy sz lx ly lz")
    out = tmp_path / "out.txt"
    run = subprocess.run([str(driver), str(hdr.with_suffix("")), str(read_mode), str(step_mode), str(rays), str(out)],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    table = np.loadtxt(out, comments="#")
    assert table.shape == (3000, 15)
    res = pi.intersect(dem, s, l, step_mode=step_mode, dem_read_mode=read_mode, tangent="paper")
    np.testing.assert_array_equal(table[:, 0], np.arange(1, 3001))
    np.testing.assert_array_equal(table[:, 1], res.status)
    # the driver prints 17 significant digits: equal to the last printed digit
    for cols, vec in [((2, 5), res.p), ((5, 8), res.t), ((8, 11), res.tc), ((11, 14), res.sc)]:
        np.testing.assert_allclose(table[:, cols[0]:cols[1]], vec, rtol=1e-15, atol=0, equal_nan=True)
    np.testing.assert_allclose(table[:, 14], res.emission, rtol=1e-14, atol=1e-13, equal_nan=True)
    assert (res.status == 0).sum() > 500 and (res.status == 1).sum() > 500


def test_driver_reports_bad_input(tmp_path, driver):
    run = subprocess.run([str(driver), str(tmp_path / "missing"), "0", "1", str(tmp_path / "none.txt")],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 1 and "cannot open rays file" in run.stderr
    rays = tmp_path / "rays.txt"
    rays.write_text("5000 0 0 -1 0 0\n")
    run = subprocess.run([str(driver), str(tmp_path / "missing"), "0", "1", str(rays)],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and "cannot use DEM" in run.stderr and "status 1" in run.stderr


def test_legacy_library_exports_the_paper_names():
    lib = pi.legacy_paths()["library"]
    assert lib.exists()
    nm = subprocess.run(["nm", "-g", "--defined-only", str(lib)], capture_output=True, text=True)
    if nm.returncode != 0:
        pytest.skip("nm (binutils) is not available to list the library's symbols")
    names = {line.split()[-1] for line in nm.stdout.splitlines() if line.strip() and not line.endswith(":")}
    for routine in ("zcalc_planet_intersect", "zdem_open", "zdem_read", "zdem_radius", "zdem_radius_increment",
                    "ztangent_ellipsoid", "zcrossp", "zrotate_about_vector", "flondiff", "fvsep"):
        assert routine + "_" in names, routine


def test_fortran77_style_program_links_and_runs(tmp_path, rough):
    """An old fixed-form program, calling the legacy names with implicit interfaces."""
    import shutil

    if shutil.which("gfortran") is None:
        pytest.skip("gfortran is not on PATH to compile the FORTRAN77 example")
    hdr = rough.write(tmp_path / "f77dem", dtype="float32")
    src = tmp_path / "old.f"
    src.write_text(
        "      PROGRAM OLD\n"
        "      DOUBLE PRECISION S(3,1), L(3,1), P(3,1), T(3,1), TC(3,1)\n"
        "      DOUBLE PRECISION SC(3,1), EM(1), R, FLONDIFF, FVSEP\n"
        "      DOUBLE PRECISION A(3), B(3), C(3)\n"
        "      INTEGER IST(1), IERR, PPD\n"
        "      DOUBLE PRECISION RMAX, F, RE\n"
        "      EXTERNAL FLONDIFF, FVSEP\n"
        "      DATA S /5000.D0, 0.D0, 0.D0/, L /-1.D0, 0.D0, 0.D0/\n"
        "      DATA A /1.D0, 0.D0, 0.D0/, B /0.D0, 1.D0, 0.D0/\n"
        "      CALL ZDEM_OPEN('f77dem.hdr', PPD, RMAX, F, RE, IERR)\n"
        "      WRITE(*,*) PPD, IERR\n"
        "      CALL ZCALC_PLANET_INTERSECT(1, S, L, 'f77dem', 1, 1,\n"
        "     &  P, T, TC, SC, EM, IST, IERR)\n"
        "      WRITE(*,'(I3,1X,I3,3(1X,ES23.15E3))') IST(1), IERR, P(1,1), P(2,1), P(3,1)\n"
        "      CALL ZDEM_RADIUS_INCREMENT('f77dem.dem', 0.D0, 0.D0, R, IERR)\n"
        "      WRITE(*,'(ES23.15E3)') R\n"
        "      CALL ZCROSSP(A, B, C)\n"
        "      WRITE(*,'(3F5.1,2F7.1)') C, FLONDIFF(10.D0, 350.D0), FVSEP(A, B)\n"
        "      END\n")
    exe = tmp_path / "old"
    lib = pi.legacy_paths()["library"]
    comp = subprocess.run(["gfortran", "-std=legacy", "-fopenmp", str(src), str(lib), "-o", str(exe)], capture_output=True, text=True)
    assert comp.returncode == 0, comp.stderr
    lines = subprocess.run([str(exe)], capture_output=True, text=True, timeout=60, cwd=tmp_path).stdout.splitlines()
    dem = pi.DEM.read(hdr)
    res = pi.intersect(dem, [5000.0, 0, 0], [-1.0, 0, 0], dem_read_mode=1)
    assert lines[0].split() == [str(dem.ppd), "0"]
    st, ierr, px = lines[1].split()[:3]
    assert (int(st), int(ierr)) == (0, 0)
    np.testing.assert_allclose(float(px), res.p[0, 0], rtol=1e-14)
    np.testing.assert_allclose(float(lines[2]), dem.radius(0.0, 0.0), rtol=1e-14)
    assert lines[3].split() == ["0.0", "0.0", "1.0", "340.0", "90.0"]
