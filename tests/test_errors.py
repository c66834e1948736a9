"""Bad input gets a clear exception naming the file or argument; nothing read is written."""

import hashlib
import threading
from pathlib import Path

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect import _core
from planet_intersect import DEMError


def write_pair(tmp_path, header: str, radii=None, nbytes=None, name="d"):
    hdr = tmp_path / f"{name}.hdr"
    hdr.write_text(header)
    dem = tmp_path / f"{name}.dem"
    if radii is not None:
        dem.write_bytes(np.asarray(radii, "<f4").tobytes())
    elif nbytes is not None:
        dem.write_bytes(b"\0" * nbytes)
    return hdr


GOOD = "1\n3400.0\n0.0\n1.0\n"
FLAT = np.full((180, 360), 3390.0)


def test_missing_hdr(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"nothere\.hdr: no such file"):
        pi.DEM.read(tmp_path / "nothere.hdr")


def test_missing_dem(tmp_path):
    hdr = write_pair(tmp_path, GOOD)
    with pytest.raises(FileNotFoundError, match=r"d\.dem: no such file"):
        pi.DEM.read(hdr)


def test_dem_size_disagrees(tmp_path):
    hdr = write_pair(tmp_path, GOOD, nbytes=180 * 360 * 4 - 4)
    with pytest.raises(DEMError, match=r"d\.dem: size 259196 bytes.*needs 180 x 360 x 4 = 259200"):
        pi.DEM.read(hdr)


@pytest.mark.parametrize("header, message", [
    ("one\n3400\n0\n1\n", r"line 1: ppd must be an integer of at most 9 digits, got 'one'"),
    ("1.5\n3400\n0\n1\n", r"ppd must be an integer of at most 9 digits, got '1.5'"),
    ("1\nbig\n0\n1\n", r"line 2: rmax must be a decimal number, got 'big'"),
    ("1\n3400\n0\n", r"re is missing"),
    ("# only a comment\n", r"ppd is missing"),
    ("1\n3400\n0\n1\ncolour = red\n", r"unknown key 'colour'"),
    ("1\n3400\n0\n1\ndtype = int16\n", r"dtype must be one of float32, float64, got 'int16'"),
    ("1\n3400\n0\n1\nstray text\n", r"expected 'key = value'"),
    ("0\n3400\n0\n1\n", r"ppd must be in 1\.\.1000000, got 0"),
    ("1\n3400\n1.0\n1\n", r"flattening f must be in \[0, 1\), got 1.0"),
    ("1\n3400\n-0.1\n1\n", r"flattening f must be in \[0, 1\), got -0.1"),
    ("1\n3400\n0\n0\n", r"equatorial radius re must be in \[1e-100, 1e\+100\], got 0.0"),
    ("1\nnan\n0\n1\n", r"line 2: rmax must be a decimal number, got 'nan'"),
    ("1\n1e300\n0\n1\n", r"rmax must be in \[1e-100, 1e\+100\], got 1e\+300"),
])
def test_bad_headers(tmp_path, header, message):
    hdr = write_pair(tmp_path, header, radii=FLAT)
    with pytest.raises(DEMError, match=message) as info:
        pi.DEM.read(hdr)
    assert str(hdr) in str(info.value)


def test_header_comments_and_order(tmp_path):
    hdr = write_pair(tmp_path, "# a DEM\n\n1   ppd\n! note\n3400.0 km\n0.0\n1.0 re\ndtype = float32\nbyteorder = little\n",
                     radii=FLAT)
    dem = pi.DEM.read(hdr)
    assert (dem.ppd, dem.rmax, dem.f, dem.re) == (1, 3400.0, 0.0, 1.0)


def test_rmax_below_largest_radius(tmp_path):
    radii = FLAT.copy()
    radii[10, 20] = 3450.0
    hdr = write_pair(tmp_path, GOOD, radii=radii)
    with pytest.raises(DEMError, match=r"rmax = 3400.0 is below the largest radius 3450.0"):
        pi.DEM.read(hdr)
    with pytest.raises(DEMError, match="below the largest radius"):
        pi.DEM.from_array(radii, rmax=3400.0)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_radii(tmp_path, bad):
    radii = FLAT.copy()
    radii[3, 7] = bad
    hdr = write_pair(tmp_path, GOOD, radii=radii)
    with pytest.raises(DEMError, match=r"row 3, column 7 .*NaN/Inf not allowed"):
        pi.DEM.read(hdr)
    with pytest.raises(DEMError, match="NaN/Inf"):
        pi.DEM.from_array(radii)


def test_from_array_bad_shape():
    with pytest.raises(DEMError, match=r"shape \(180, 180\) is not \(180\*ppd, 360\*ppd\)"):
        pi.DEM.from_array(np.ones((180, 180)))


@pytest.fixture(scope="module")
def flat():
    return pi.DEM.from_array(FLAT, rmax=3400.0)


@pytest.mark.parametrize("s, l, message", [
    ([np.nan, 0, 5000], [-1, 0, 0], r"s\[0\] has NaN or Inf"),
    ([5000, 0, 0], [-1, np.inf, 0], r"l\[0\] has NaN or Inf"),
    ([5000, 0, 0], [0, 0, 0], r"l\[0\] has zero length"),
    ([0, 0, 0], [1, 0, 0], r"s\[0\] has zero length"),
    ([5000, 0], [-1, 0, 0], r"s: expected shape \(3,\) or \(N, 3\), got \(2,\)"),
    ([5000, 0, 0], np.ones((4, 2)), r"l: expected shape \(3,\) or \(N, 3\), got \(4, 2\)"),
    (np.ones((2, 3)) * 5000, np.ones((3, 3)), r"2 positions do not broadcast against 3 lines of sight"),
    ([3000, 0, 0], [1, 0, 0], r"s\[0\] = .* is inside the planet surface"),
    (["a", 0, 0], [1, 0, 0], r"s: must be real numbers, got dtype <U"),
])
def test_bad_vectors(flat, s, l, message):
    with pytest.raises((ValueError, TypeError), match=message):
        pi.intersect(flat, s, l)


@pytest.mark.parametrize("kwargs, message", [
    ({"step_mode": 2}, r"step_mode must be 0 or 1, got 2"),
    ({"step_mode": -1}, r"step_mode must be 0 or 1, got -1"),
    ({"dem_read_mode": 3}, r"dem_read_mode must be 0 or 1, got 3"),
    ({"dem_read_mode": "0"}, r"dem_read_mode must be 0 or 1, got '0'"),
    ({"step_mode": True}, r"step_mode must be 0 or 1, got True"),
    ({"tangent": "fast"}, r"tangent must be one of 'paper', 'exact', got 'fast'"),
    ({"dem_read_mode": 1}, r"dem_read_mode=1 reads records from the DEM's file: this DEM is in memory"),
])
def test_bad_modes(flat, kwargs, message):
    with pytest.raises(ValueError, match=message):
        pi.intersect(flat, [5000, 0, 0], [-1, 0, 0], **kwargs)


def test_dem_argument_type():
    with pytest.raises(TypeError, match="dem must be a planet_intersect.DEM"):
        pi.intersect("mars.hdr", [5000, 0, 0], [-1, 0, 0])


def test_radius_bad_latitude(flat):
    with pytest.raises(ValueError, match=r"lat\[0\] = 91.0 is outside \[-90, 90\]"):
        flat.radius(91.0, 0.0)


def _digest(paths):
    return {p: (hashlib.sha256(p.read_bytes()).hexdigest(), p.stat().st_mtime_ns) for p in paths}


def test_nothing_read_is_written(tmp_path, rough):
    hdr = rough.write(tmp_path / "keep")
    files = [hdr, hdr.with_suffix(".dem")]
    before = _digest(files)
    dem = pi.DEM.read(hdr)
    assert not dem.radii.flags.writeable
    s = np.array([5000.0, 0, 0])
    l = np.array([[-1.0, 0.01 * k, 0.02] for k in range(20)])
    for mode in (0, 1):
        pi.intersect(dem, s, l, dem_read_mode=mode)
    dem.radius([0, 10], [5, 6])
    # writing refuses to replace the files it came from or any existing file
    with pytest.raises(FileExistsError, match="this DEM was read from there"):
        dem.write(hdr, overwrite=True)
    with pytest.raises(FileExistsError, match="exists; pass overwrite=True"):
        rough.write(tmp_path / "keep")
    assert _digest(files) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.dem", "keep.hdr"]


def test_fortran_reader_errors_surface_as_dem_errors(tmp_path):
    """The Fortran mode-1 reader reports its own status codes; a file changed under
    a DEM after it was read gives a clear error, not a crash."""
    radii = FLAT.copy()
    hdr = write_pair(tmp_path, GOOD, radii=radii)
    dem = pi.DEM.read(hdr)
    hdr.with_suffix(".dem").write_bytes(b"\0" * 100)
    with pytest.raises(DEMError, match=r"d\.dem: its size changed since DEM\.read \(size 259200 -> 100 bytes\)"):
        pi.intersect(dem, [5000, 0, 0], [-1, 0, 0], dem_read_mode=1)
    # the Fortran reader's own check, reached without the Python one: status 5
    out = _core.core_intersect_file(str(hdr), 1, *dem.header_args(), np.array([[5000.0, 0, 0]]).T,
                                    np.array([[-1.0, 0, 0]]).T, 1, 1, np.zeros(1, np.float32),
                                    np.zeros((3, 1), np.int32))
    assert out[-1] == 5
