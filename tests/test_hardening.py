"""Regression tests of issue 10 (hardening): every reproducer it lists, each of
which crashed, hung or silently misled on the main branch before the fix.

Calls that used to crash the interpreter (segfault, SIGBUS, abort) or hang run
in a child process with a time limit, so that a relapse is a failed test that
shows the input, not a dead test run.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect import _core
from planet_intersect._status import RayStatus


def run_child(code: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
    """Run Python code in a child process; fail the test on a signal or a hang."""
    prelude = "import numpy as np, planet_intersect as pi\n"
    try:
        r = subprocess.run([sys.executable, "-c", prelude + textwrap.dedent(code)], capture_output=True,
                           text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        pytest.fail(f"hung for more than {timeout} s:\n{code}")
    assert r.returncode >= 0, f"killed by signal {-r.returncode}:\n{code}\n{r.stderr[-2000:]}"
    return r


@pytest.fixture(scope="module")
def flat():
    """The issue's DEM: a sphere of radius 3390 at 1 pixel per degree."""
    return pi.DEM.from_array(np.full((180, 360), 3390.0))


# 1. crashes, hangs and silent wrong results -------------------------------------------

def test_far_spacecraft_is_a_clear_error_not_a_segfault():
    r = run_child("""
        D = pi.DEM.from_array(np.full((180, 360), 3390.))
        try:
            pi.intersect(D, [1e20, 0, 0], [-1, 0, 0])
        except ValueError as e:
            print("ValueError:", e)
    """)
    assert r.returncode == 0 and "ValueError: s[0]" in r.stdout and "rmax from the centre" in r.stdout, r.stderr


@pytest.mark.parametrize("radius, why", [(1.797e308, "outside"), (1e-160, "outside"), (1e101, "outside")])
def test_extreme_radii_are_rejected_where_data_enters(radius, why):
    radii = np.full((180, 360), 3390.0)
    radii[10, 20] = radius
    if radius < 1:
        radii[:] = radius                   # all radii tiny, as in the issue
    with pytest.raises(pi.DEMError, match=why):
        pi.DEM.from_array(radii)


def test_fortran_dem_radius_gives_a_status_for_non_finite_coordinates(flat):
    # the Python layer rejects these first; the core must not index with them anyway
    for lat, lon in [(np.nan, 0.0), (0.0, np.nan), (0.0, np.inf), (2.0, 0.0), (-np.inf, 1.0)]:
        r, stat = _core.core_radius_grid(flat.radii64().T, flat.ppd, flat.rmax, np.array([lat]), np.array([lon]))
        assert stat == 14 and r[0] == 0.0


def test_fortran_rejects_a_far_spacecraft_by_status(flat):
    # straight to the core, past the Python checks: a status, never an index from NaN
    pyr, meta = flat.pyramid()
    for method in (0, 1):
        out = _core.core_intersect_grid(flat.radii64().T, flat.ppd, flat.rmax, 0.0, 1.0,
                                        np.array([[1e20, 0, 0]]).T, np.array([[-1.0, 0, 0]]).T, 1, 1, pyr, meta.T,
                                        threads=1, method=method)
        assert out[-1] == 0 and out[5][0] == RayStatus.BAD_POSITION


def test_exact_mode_distant_phobos_does_not_hang():
    r = run_child("""
        D = pi.DEM.from_array(np.full((180, 360), 14.))
        res = pi.intersect(D, [1e8, 0, 0], [-1, 0, 0], method="exact")
        print(res.status[0], repr(float(res.p[0, 0])))
    """, timeout=60)
    status, x = r.stdout.split()
    assert status == "0" and abs(float(x) - 14.0) < 1e-8 * 14


@pytest.mark.parametrize("method", ["stepping", "exact"])
def test_rays_from_up_to_1e15_rmax_hit_where_geometry_says(method):
    """A sphere of radius 14 seen from 1e2..1e15 radii: rays aimed at known surface
    points hit them; the error allowed grows as the input's own resolution,
    |s| * 4e-16 (the direction of a unit vector is known to ~1e-16)."""
    rng = np.random.default_rng(10)
    R = 14.0
    dem = pi.DEM.from_array(np.full((180, 360), R))
    for dist in 10.0 ** np.arange(2, 16) * (1 - 1e-9):         # the last just inside the 1e15 limit
        target = rng.normal(size=(20, 3))
        target *= R / np.linalg.norm(target, axis=1)[:, None]
        view = target / R + 0.3 * rng.normal(size=(20, 3))          # spacecraft on the visible side
        view /= np.linalg.norm(view, axis=1)[:, None]
        s = view * dist * R
        l = target - s
        res = pi.intersect(dem, s, l, method=method)
        assert res.hit.all(), (dist, res.status)
        err = np.linalg.norm(res.p - target, axis=1)
        assert err.max() <= max(1e-8 * R, 8e-16 * dist * R), (dist, err.max())
        # and a miss stays a miss: aimed 1.5 R off the centre
        off = np.cross(view, [0.0, 0.0, 1.0])
        off /= np.linalg.norm(off, axis=1)[:, None]
        miss = pi.intersect(dem, s, -s + 1.5 * R * off, method=method)
        assert (miss.status == RayStatus.LIMB).all()
        closest = 1.5 * R / np.sqrt(1 + 2.25 / dist**2)      # the line through s and a point 1.5 R off, at right angles
        np.testing.assert_allclose(np.linalg.norm(miss.tc, axis=1), closest, rtol=1e-12 + 8e-16 * dist)


@pytest.mark.parametrize("threads", [100000, 2**31 - 1, 2**31, -1, 1.5, True])
def test_threads_out_of_range_is_a_value_error(flat, threads):
    with pytest.raises(ValueError, match=r"threads must be an integer in 0\.\.1024"):
        pi.intersect(flat, [5000.0, 0, 0], [-1.0, 0, 0], threads=threads)


def test_threads_beyond_the_rays_are_clamped(flat):
    res = pi.intersect(flat, [5000.0, 0, 0], [[-1.0, 0, 0], [-1.0, 0.1, 0]], threads=1024)
    assert res.hit.all()


def test_header_with_a_bare_cr_is_read_alike_by_both_layers(tmp_path):
    """The issue's reproducer: `byteorder = big` after a CR was honoured by Python
    and missed by the Fortran re-parse, which then read byte-swapped radii."""
    (tmp_path / "d.hdr").write_bytes(b"1\n3400\n0\n1\rbyteorder = big\n")
    np.full((180, 360), 3390.0, ">f4").tofile(tmp_path / "d.dem")
    d = pi.DEM.read(tmp_path / "d.hdr")
    for mode, io in ((0, "records"), (1, "records"), (1, "mmap")):
        res = pi.intersect(d, [6000.0, 0, 0], [-1.0, 0, 0], dem_read_mode=mode, io=io)
        assert res.hit[0] and res.radius[0] == pytest.approx(3390.0, rel=1e-12), (mode, io)
    ppd, rmax, f, re, itemsize, swap, stat = _core.core_read_header(str(tmp_path / "d.hdr"))
    assert stat == 0 and swap == (sys.byteorder == "little")


# the same odd and bad headers, fed to both parsers: same values, or both refuse
HEADERS = [
    b"1\n3400\n0\n1\n", b"1\r3400\r0\r1\r", b"1\r\n3400\r\n0\r\n1\r\n", b"1\n3400\n0\n1",
    b"  1  ppd\n\t3400 rmax\n0\t f\n1 # re\n", b"# c\n! c\n\n1\n3400\n0\n1\ndtype = float64\n",
    b"1\n3400\n0\n1\nDTYPE=FLOAT64\nByteOrder =  Big  # c\n", b"+1\n+3.4e3\n.0\n1.\n",
    b"1\n3400\n0\n1\n\tbyteorder = big\n", b"1\n3400\n0\n1\n\r\n\r\n",
    b"1\n3400\n0\n1\n\x0bbyteorder = big\n", b"1\n3400\n0\n1\nbyteorder big\n", b"1\n3400\n0\n1\nfoo = 1\n",
    b"1\n3400\n0\n", b"1.0\n3400\n0\n1\n", b"1e0\n3400\n0\n1\n", b"1,2\n3400\n0\n1\n", b"1\n3400,\n0\n1\n",
    b"1\n3400d0\n0\n1\n", b"1\n1e999\n0\n1\n", b"1\n3400\n1e-999\n1\n", b"1\nnan\n0\n1\n", b"1\ninf\n0\n1\n",
    b"1\n3400\n0\n1\ndtype = float16\n", b"0\n3400\n0\n1\n", b"2000000\n3400\n0\n1\n", b"1234567890\n3400\n0\n1\n",
    b"1\n-3400\n0\n1\n", b"1\n3400\n1\n1\n", b"1\n1e101\n0\n1\n", b"1\n3400\n0\n0\n",
    b"1\n3400\n0\n1\n" + b"#" * 2000 + b"\nbyteorder = big\n", b"1 \xc2\xb0 ppd\n3400\n0\n1\n",
    b"\xef\xbb\xbf1\n3400\n0\n1\n", b"1\x00\n3400\n0\n1\n", b"", b"1\n3400\n0\n1\n=\n",
    b"1\n3400\n0\n1\ndtype =\n", b"1\n3400\n0.00589\n3396.19\nbyteorder = little\ndtype = float32\n",
]


@pytest.mark.parametrize("text", HEADERS, ids=range(len(HEADERS)))
def test_python_and_fortran_header_parsers_agree(tmp_path, text):
    hdr = tmp_path / "h.hdr"
    hdr.write_bytes(text)
    try:
        h = pi.read_header(hdr)
    except pi.DEMError:
        h = None
    ppd, rmax, f, re, itemsize, swap, stat = _core.core_read_header(str(hdr))
    if h is None:
        assert stat != 0
        return
    assert stat == 0
    assert (ppd, rmax, f, re) == (h["ppd"], h["rmax"], h["f"], h["re"])
    assert itemsize == (4 if h["dtype"] == "float32" else 8)
    assert bool(swap) == ((h["byteorder"] == "big") == (sys.byteorder == "little"))


def test_from_array_keeps_a_private_read_only_copy():
    radii = np.full((180, 360), 3390.0)
    dem = pi.DEM.from_array(radii)
    before = pi.intersect(dem, [6000.0, 0, 0], [-1.0, 0.01, 0], method="exact")
    radii[:] = np.nan                      # hung the core before (NaN radii)
    radii[0, 0] = 1e300                    # segfaulted it
    assert not dem.radii.flags.writeable
    with pytest.raises(ValueError):
        dem.radii[0, 0] = 1.0
    for method in ("stepping", "exact"):
        after = pi.intersect(dem, [6000.0, 0, 0], [-1.0, 0.01, 0], method=method)
        np.testing.assert_allclose(after.p, before.p, rtol=1e-12)


def test_a_file_that_shrinks_after_read_is_a_dem_error(tmp_path):
    hdr = pi.DEM.from_array(np.full((180, 360), 3390.0)).write(tmp_path / "d")
    r = run_child(f"""
        import os
        d = pi.DEM.read({str(hdr)!r})
        pi.intersect(d, [6000., 0, 0], [-1., 0, 0], dem_read_mode=1, io="mmap")   # map in use
        os.truncate({str(tmp_path / 'd.dem')!r}, 1000)
        for kw in (dict(dem_read_mode=1, io="mmap"), dict(dem_read_mode=1), dict(dem_read_mode=0),
                   dict(method="exact")):
            try:
                pi.intersect(d, [6000., 0, 0], [-1., 0, 0], **kw)
                print("no error", kw)
            except pi.DEMError as e:
                print("DEMError:", e)
        try:
            d.radius(0.0, 0.0)
        except pi.DEMError as e:
            print("DEMError:", e)
    """)
    lines = r.stdout.strip().splitlines()
    assert len(lines) == 5 and all(x.startswith("DEMError:") and "size changed since DEM.read" in x
                                   for x in lines), r.stdout + r.stderr


@pytest.mark.parametrize("method", ["stepping", "exact"])
def test_a_ray_down_a_spike_to_the_centre_ends(method):
    """One node at the deepest radius accepted (1e-6 of the largest; a node at
    1e-100 is now refused, checked first) under a unit sphere: a ray aimed
    straight down the spike passes close to the centre, where the paper's steps
    (eq. 26, proportional to |g|) shrink geometrically. The loop ends: a hit
    beyond, or status UNRESOLVED. (With a spike at 1e-100 the old loop never ended.)"""
    deep = np.ones((180, 360))
    deep[90, 0] = 1e-100
    with pytest.raises(pi.DEMError, match="must lie within a factor"):
        pi.DEM.from_array(deep)
    r = run_child(f"""
        radii = np.ones((180, 360)); radii[90, 0] = 1.0000001e-6
        dem = pi.DEM.from_array(radii)
        u = np.array([np.cos(np.radians(0.5))**2, np.cos(np.radians(0.5)) * np.sin(np.radians(0.5)),
                      np.sin(np.radians(0.5))])
        res = pi.intersect(dem, 2 * u, -u, method={method!r})
        print(int(res.status[0]), res.nsteps[0])
    """, timeout=120)
    status, nsteps = map(int, r.stdout.split())
    assert status in (RayStatus.HIT, RayStatus.HIT_UNCONVERGED, RayStatus.UNRESOLVED), r.stdout


# 2. clear errors -------------------------------------------------------------------------

def test_zero_rays_give_an_empty_result(flat):
    for method in ("stepping", "exact"):
        res = pi.intersect(flat, np.zeros((0, 3)), [-1.0, 0, 0], method=method)
        assert len(res) == 0 and res.p.shape == (0, 3) and res.status.dtype == np.int8
    assert flat.radius([], []).shape == (0,)


def test_radius_with_shapes_that_do_not_broadcast(flat):
    with pytest.raises(ValueError, match=r"lat and lon: shapes \(2,\) and \(3,\) do not broadcast"):
        flat.radius([0.0, 1.0], [0.0, 1.0, 2.0])


@pytest.mark.parametrize("kwargs, exc, match", [
    (dict(f="x"), TypeError, "f must be a real number"),
    (dict(rmax="3400"), TypeError, "rmax must be a real number"),
    (dict(re=[1.0]), TypeError, "re must be a real number"),
])
def test_from_array_parameters_of_the_wrong_type(kwargs, exc, match):
    with pytest.raises(exc, match=match):
        pi.DEM.from_array(np.full((180, 360), 3390.0), **kwargs)


@pytest.mark.parametrize("kwargs, match", [
    (dict(method=[]), r"method \(for a planetary DEM\) must be one of 'stepping', 'exact', got"),
    (dict(tangent=None), "tangent must be one of"),
    (dict(io=3), "io must be one of"),
])
def test_unhashable_or_odd_option_values(flat, kwargs, match):
    with pytest.raises(ValueError, match=match):
        pi.intersect(flat, [5000.0, 0, 0], [-1.0, 0, 0], **kwargs)


@pytest.mark.parametrize("l", [[-1e-200, 0, 0], [-1e-160, 1e-162, 0], [-1e200, 0, 0], [-1e300, 1e299, 0]])
def test_tiny_and_huge_directions_are_directions(flat, l):
    res = pi.intersect(flat, [5000.0, 0, 0], l)
    expect = pi.intersect(flat, [5000.0, 0, 0], np.asarray(l) / np.abs(l).max())
    assert res.hit[0]
    np.testing.assert_allclose(res.p, expect.p, rtol=1e-14)


def test_complex_input_is_refused(flat):
    with pytest.raises(TypeError, match="s: must be real numbers, got dtype complex128"):
        pi.intersect(flat, [5000.0 + 1j, 0, 0], [-1.0, 0, 0])
    with pytest.raises(TypeError, match="lat: must be real numbers"):
        flat.radius([1j], [0.0])
    with pytest.raises(TypeError, match="radii must be real numbers"):
        pi.DEM.from_array(np.full((180, 360), 3390.0 + 0j))


def test_directory_fifo_and_symlink_loop_are_named(tmp_path):
    (tmp_path / "dir.hdr").mkdir()
    with pytest.raises(IsADirectoryError, match="is a directory"):
        pi.DEM.read(tmp_path / "dir.hdr")
    os.mkfifo(tmp_path / "fifo.hdr")
    with pytest.raises(pi.DEMError, match="not a regular file"):
        pi.DEM.read(tmp_path / "fifo.hdr")
    os.symlink(tmp_path / "loop.hdr", tmp_path / "loop.hdr")
    with pytest.raises(pi.DEMError, match="a loop of symbolic links"):
        pi.DEM.read(tmp_path / "loop.hdr")
    hdr = pi.DEM.from_array(np.full((180, 360), 3390.0)).write(tmp_path / "ok")
    (tmp_path / "ok.dem").unlink()
    (tmp_path / "ok.dem").mkdir()
    with pytest.raises(IsADirectoryError, match=r"ok\.dem: is a directory"):
        pi.DEM.read(hdr)


# 5. honest claims ----------------------------------------------------------------------

def test_irregular_body_has_no_spheroid_quantities():
    """f = 0, re = 1 means no spheroid (Table 1): sc and the height above it are
    NaN, as altitude is; the altitude above the DEM is |tc| - r there."""
    dem = pi.DEM.from_array(np.full((180, 360), 20.0), f=0.0)   # no re: no spheroid
    res = pi.intersect(dem, [100.0, 0, 0], [[-1.0, 0.3, 0.0], [-1.0, 0.0, 0.0]])
    limb, hit = 0, 1
    assert res.status[limb] == RayStatus.LIMB and res.hit[hit]
    assert np.isnan(res.sc[limb]).all() and np.isnan(res.tangent_height[limb])
    assert np.isnan(res.altitude[hit])
    d = 100.0 * 0.3 / np.hypot(1.0, 0.3)             # closest approach of the limb ray to the centre
    assert res.tangent_altitude[limb] == pytest.approx(d - 20.0, rel=1e-12)
    assert np.isfinite(res.tangent_lat[limb]) and np.isfinite(res.tc[limb]).all()


# the command line (issue 10, section 2) ---------------------------------------------------

def cli(*args, cwd=None, env=None):
    return subprocess.run([sys.executable, "-m", "planet_intersect.cli", *map(str, args)], capture_output=True,
                          text=True, cwd=cwd, env=env, timeout=300)


def one_line_error(r, text):
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr and "Warning" not in r.stderr, r.stderr
    assert text in r.stderr, r.stderr


def test_examples_without_matplotlib_is_one_line_and_leaves_nothing(tmp_path):
    fake = tmp_path / "fake"
    fake.mkdir()
    (fake / "matplotlib.py").write_text("raise ImportError('no matplotlib here')\n")
    env = dict(os.environ, PYTHONPATH=str(fake))
    r = cli("examples", "olympus", "--out", tmp_path / "ex", env=env)
    one_line_error(r, "examples olympus (its figure) needs the Python package 'matplotlib'")
    assert "pip install 'planet-intersect[plot]'" in r.stderr
    assert not (tmp_path / "ex").exists() or not any((tmp_path / "ex").iterdir())


def test_run_without_the_netcdf_writer_is_one_line(tmp_path):
    fake = tmp_path / "fake"
    fake.mkdir()
    (fake / "h5netcdf.py").write_text("raise ImportError('no h5netcdf here')\n")
    hdr = pi.DEM.from_array(np.full((180, 360), 3390.0)).write(tmp_path / "d")
    (tmp_path / "rays.txt").write_text("6000 0 0 -1 0 0\n")
    r = cli("run", hdr, tmp_path / "rays.txt", "--out", tmp_path / "o", env=dict(os.environ, PYTHONPATH=str(fake)))
    one_line_error(r, "needs the Python package 'h5netcdf'")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("content, text", [
    ("", "no rays (every line is blank or a comment)"),
    ("# only a comment\n\n   \n", "no rays (every line is blank or a comment)"),
    ("6000 0 0 -1 0 0\n# c\n6000 0 0 nan 0 0\n", "rays.txt, line 3: NaN or Inf"),
    ("6000 0 0 -1 0 0\n\n# c\n3000 0 0 -1 0 0\n", "s on line 4 of"),
    ("6000 0 0 -1 0 0\n6000 0 0 0 0 0\n", "l on line 2 of"),
    ("6000 0 0 -1 0 x\n", "line 1: not a number"),
])
def test_rays_file_errors_name_the_line(tmp_path, content, text):
    hdr = pi.DEM.from_array(np.full((180, 360), 3390.0)).write(tmp_path / "d")
    (tmp_path / "rays.txt").write_text(content)
    r = cli("run", hdr, tmp_path / "rays.txt", "--out", tmp_path / "o")
    one_line_error(r, text)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("args, text", [
    (["demo", "--ppd", "0"], "--ppd must be in 1..64, got 0"),
    (["demo", "--pixels", "-3"], "--pixels must be in 1..4001, got -3"),
])
def test_demo_bad_numbers(tmp_path, args, text):
    one_line_error(cli(*args, "--out", tmp_path / "o"), text)


def test_out_naming_an_existing_file(tmp_path):
    (tmp_path / "taken").write_text("mine\n")
    one_line_error(cli("demo", "--pixels", "3", "--out", tmp_path / "taken"), "exists and is not a folder")
    assert (tmp_path / "taken").read_text() == "mine\n"


def test_dem_and_rays_that_are_not_files(tmp_path):
    hdr = pi.DEM.from_array(np.full((180, 360), 3390.0)).write(tmp_path / "d")
    (tmp_path / "dir").mkdir()
    os.mkfifo(tmp_path / "fifo")
    one_line_error(cli("run", hdr, tmp_path / "dir"), "is a directory")
    one_line_error(cli("run", hdr, tmp_path / "fifo"), "not a regular file")
    one_line_error(cli("run", tmp_path / "dir", tmp_path / "fifo"), "is a directory")


# defects the fuzz harness found (tests/fuzzing) --------------------------------------------

@pytest.mark.parametrize("method", ["stepping", "exact"])
def test_ray_along_the_polar_axis_hits_the_pole(method):
    """A ray straight down the polar axis, with a high node near the pole: the
    exact search hung on the south polar axis (fuzz case); the hit is the pole,
    at the mean radius of the polar row (section 2.2)."""
    r = run_child(f"""
        r = np.full((180, 360), 3390.); r[123, 38] = 3439.32
        res = pi.intersect(pi.DEM.from_array(r), [[0, 0, -5000], [0, 0, 5000]], [[0, 0, 1], [0, 0, -1]],
                           method={method!r})
        print(res.status.tolist(), float(res.p[0, 2]), float(res.p[1, 2]))
    """, timeout=120)
    status, south, north = r.stdout.rsplit("]", 1)[0] + "]", *r.stdout.rsplit("]", 1)[1].split()
    assert status == "[0, 0]" and float(south) == pytest.approx(-3390.0, rel=1e-9) \
        and float(north) == pytest.approx(3390.0, rel=1e-9), r.stdout


def test_no_overflow_warnings_for_huge_vectors(flat):
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = pi.intersect(flat, [5000.0, 0, 0], [-4e159, 0, 0])
        assert res.hit[0]
        with pytest.raises(ValueError, match="rmax from the centre"):
            pi.intersect(flat, [1e300, 0, 0], [-1.0, 0, 0])


def test_header_tabs_are_white_space_in_both_parsers(tmp_path):
    (tmp_path / "t.hdr").write_bytes(b"1\n3400\n\t\n0\n\t# c\n1\n\tbyteorder = little\n")
    np.full((180, 360), 3390.0, "<f4").tofile(tmp_path / "t.dem")
    d = pi.DEM.read(tmp_path / "t.hdr")
    for mode in (0, 1):
        assert pi.intersect(d, [6000.0, 0, 0], [-1.0, 0, 0], dem_read_mode=mode).hit[0]


def test_a_file_shrunk_by_one_record_is_noticed(tmp_path):
    hdr = pi.DEM.from_array(np.full((180, 360), 3390.0)).write(tmp_path / "d")
    d = pi.DEM.read(hdr)
    size = (tmp_path / "d.dem").stat().st_size
    os.truncate(tmp_path / "d.dem", size - 4)
    with pytest.raises(pi.DEMError, match="size changed since DEM.read"):
        pi.intersect(d, [6000.0, 0, 0], [-1.0, 0, 0], dem_read_mode=1, io="mmap")


@pytest.mark.parametrize("kwargs, exc, match", [
    (dict(dh=np.nan), ValueError, "dh: must be a finite pixel spacing"),
    (dict(dv=np.inf), ValueError, "dv: must be a finite pixel spacing"),
    (dict(dh=-0.01), ValueError, "dh: must be a finite pixel spacing"),
    (dict(nh=3.0), TypeError, "nh: must be an integer"),
    (dict(nv=None), TypeError, "nv: must be an integer"),
    (dict(nh=10**12), ValueError, r"nh: must be in 1\.\.100000"),
    (dict(l0="x"), TypeError, "l0: must be real numbers"),
    (dict(l0=[1 + 1j, 0, 0]), TypeError, "l0: must be real numbers"),
])
def test_detector_los_bad_arguments(kwargs, exc, match):
    args = dict(l0=[0.0, 0.0, -1.0], q=[1.0, 0.0, 0.0], nh=3, nv=3, dh=0.01, dv=0.01)
    args.update(kwargs)
    with pytest.raises(exc, match=match):
        pi.detector_los(**args)


def test_detector_los_tiny_and_huge_vectors_are_directions():
    import warnings
    ref = pi.detector_los([0.0, 0.0, -1.0], [1.0, 0.0, 0.0], 3, 3, 0.01, 0.01)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = pi.detector_los([0.0, 0.0, -1e308], [1e-200, 0.0, 0.0], 3, 3, 0.01, 0.01)
    np.testing.assert_array_equal(got, ref)


def test_dsm_inputs_follow_the_same_rules():
    """The geodetic DSM path checks its inputs with the planetary path's helpers."""
    dsm = pi.GeodeticDSM.from_array(np.zeros((3, 3)), 0.001, 0.0, -0.001, 0.001)
    s = pi.geodetic_to_ecef(0.0, 0.001, 700e3)
    assert len(pi.intersect(dsm, np.zeros((0, 3)), [0, 0, -1.0])) == 0
    with pytest.raises(TypeError, match="s: must be real numbers"):
        pi.intersect(dsm, s + 0j, -s)
    with pytest.raises(ValueError, match=r"threads must be an integer in 0\.\.1024"):
        pi.intersect(dsm, s, -s, threads=100000)
    with pytest.raises(ValueError, match="semi-major axes from the centre"):
        pi.intersect(dsm, s * 1e16, -s)
    tiny = pi.intersect(dsm, s, -s * 1e-300, method="exact")
    ref = pi.intersect(dsm, s, -s, method="exact")
    assert tiny.hit[0] and np.allclose(tiny.p, ref.p, rtol=1e-14)
