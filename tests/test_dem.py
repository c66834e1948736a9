"""DEM files and interpolation (eqs. 1-12): round trips, nodes, wrap, poles, both readers."""

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect import _core


@pytest.fixture(scope="module")
def ramp():
    """Radii that identify each node: r = 3000 + row + column/1000 (1 ppd)."""
    j, i = np.mgrid[0:180, 0:360]
    return pi.DEM.from_array(3000.0 + j + i / 1000.0)


@pytest.mark.parametrize("dtype, byteorder", [("float32", "little"), ("float64", "little"),
                                              ("float32", "big"), ("float64", "big")])
def test_write_read_round_trip(tmp_path, rough, dtype, byteorder):
    hdr = rough.write(tmp_path / "x", dtype=dtype, byteorder=byteorder)
    back = pi.DEM.read(hdr)
    assert (back.ppd, back.f, back.re) == (rough.ppd, rough.f, rough.re)
    expect = np.asarray(rough.radii, dtype=dtype)
    np.testing.assert_array_equal(np.asarray(back.radii), expect)
    assert back.rmax >= expect.max()
    # record k = (j-1)*nlon + i (eq. 1): the byte offset of row 5, column 9
    raw = np.fromfile(hdr.with_suffix(".dem"), dtype=np.dtype(dtype).newbyteorder("<" if byteorder == "little" else ">"))
    assert raw[5 * rough.nlon + 9] == expect[5, 9]
    # the Fortran header reader sees the same values
    ppd, rmax, f, re, itemsize, swap, stat = _core.core_read_header(str(hdr))
    assert stat == 0 and (ppd, rmax, f, re) == (back.ppd, back.rmax, back.f, back.re)
    assert itemsize == np.dtype(dtype).itemsize and swap == (byteorder == "big")
    # and the Fortran mode-1 reader the same radii
    lat, lon = np.array([-89.9, -30.2, 0.0, 45.5, 89.95]), np.array([0.1, 359.9, 180.0, 12.3, 200.0])
    r1, st = _core.core_radius_file(str(hdr), 1, *back.header_args(), np.radians(lat), np.radians(lon))
    assert st == 0
    np.testing.assert_array_equal(r1, back.radius(lat, lon))


def test_radius_at_nodes_is_the_node_value(ramp):
    lat = ramp.lat[[1, 50, 120, 178]]
    lon = ramp.lon[[0, 10, 200, 359]]
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    j = np.array([1, 50, 120, 178])[:, None]
    i = np.array([0, 10, 200, 359])[None, :]
    np.testing.assert_allclose(ramp.radius(la, lo), 3000.0 + j + i / 1000.0, rtol=0, atol=1e-10)


def test_bilinear_between_nodes(ramp):
    # a quarter of the way east and three quarters north of node (row 40, column 100)
    lat = ramp.lat[40] + 0.75
    lon = ramp.lon[100] + 0.25
    np.testing.assert_allclose(ramp.radius(lat, lon), 3000.0 + 40.75 + 100.25 / 1000.0, rtol=0, atol=1e-10)


def test_longitude_wraps_across_0_360(ramp):
    # between the last column (359.5 E) and the first (0.5 E): eq. 7 wraps i2 to 1
    r_last, r_first = 3000.0 + 60 + 359 / 1000.0, 3000.0 + 60 + 0.0
    lat = ramp.lat[60]
    for lon, frac in [(359.75, 0.25), (0.0, 0.5), (360.0, 0.5), (0.25, 0.75), (-0.25, 0.25), (719.75, 0.25)]:
        np.testing.assert_allclose(ramp.radius(lat, lon), r_last + frac * (r_first - r_last), atol=1e-10)


def test_poles_use_the_mean_of_the_adjacent_row(ramp):
    south = 3000.0 + 0 + np.mean(np.arange(360) / 1000.0)
    north = 3000.0 + 179 + np.mean(np.arange(360) / 1000.0)
    lon = np.linspace(0, 359, 37)
    # at the pole itself every longitude gives the polar mean: the surface is single-valued
    np.testing.assert_allclose(ramp.radius(-90.0, lon), south, atol=1e-10)
    np.testing.assert_allclose(ramp.radius(90.0, lon), north, atol=1e-10)
    # half way between the pole and the first row centre (-89.75): half of each
    r_row = 3000.0 + 0 + 17 / 1000.0
    np.testing.assert_allclose(ramp.radius(-89.75, ramp.lon[17]), 0.5 * (south + r_row), atol=1e-10)
    # continuous across the cap boundary at the first/last row centre
    eps = 1e-9
    for lat in (ramp.lat[0], ramp.lat[-1]):
        np.testing.assert_allclose(ramp.radius(lat - eps, 33.3), ramp.radius(lat + eps, 33.3), atol=1e-6)


def test_interpolated_radius_is_continuous_everywhere(rough):
    """No jumps at cell, tile or wrap boundaries: tiny moves give tiny changes."""
    rng = np.random.default_rng(0)
    lat = rng.uniform(-90, 90, 20000)
    lon = rng.uniform(0, 360, 20000)
    # include exact cell edges (midway between centres) and centres
    lat[:500] = np.clip(np.round(lat[:500] * rough.ppd) / rough.ppd, -90, 90)
    lon[:500] = np.round(lon[:500] * rough.ppd) / rough.ppd
    d = 1e-7
    r0 = rough.radius(np.clip(lat - d, -90, 90), lon - d)
    r1 = rough.radius(np.clip(lat + d, -90, 90), lon + d)
    slope = np.max(np.abs(np.diff(np.asarray(rough.radii), axis=1))) * rough.ppd * 4
    assert np.max(np.abs(r1 - r0)) <= slope * 2 * d * 2


def test_legacy_flondiff_examples():
    # the paper's examples of the function Delta: Delta(10, 350) = 340, Delta(350, 10) = 20
    from planet_intersect import reference

    g = reference._Grid(np.full((180, 360), 1.0), 1)
    assert g.south == 1.0
    assert np.mod(350 - 10, 360.0) == 340 and np.mod(10 - 350, 360.0) == 20


def test_write_never_replaces_an_input_file_and_names_a_missing_folder(tmp_path):
    # DEM.write(inputs=...) guards the importers (import-mola, import-pds, import-shape-table,
    # import-shadr): a review made import-shape-table write its DEM over a table named X.dem
    dem = pi.DEM.from_array(np.full((180, 360), 10.0, dtype=np.float32))
    src = tmp_path / "grid.dem"
    src.write_bytes(b"the input")
    with pytest.raises(FileExistsError, match="is the input file"):
        dem.write(tmp_path / "grid", overwrite=True, inputs=[src])
    assert src.read_bytes() == b"the input"
    hdr_src = tmp_path / "other.hdr"
    hdr_src.write_text("x")
    with pytest.raises(FileExistsError, match="is the input file"):
        dem.write(tmp_path / "other", overwrite=True, inputs=[hdr_src])
    assert hdr_src.read_text() == "x"
    # an input elsewhere does not stop the write; a missing folder is named, not a .part file
    assert dem.write(tmp_path / "fine", inputs=[src, tmp_path / "never_existed"]).is_file()
    with pytest.raises(FileNotFoundError, match="does not exist"):
        dem.write(tmp_path / "no" / "folder" / "x")


def test_a_failed_write_leaves_no_temporary_files(tmp_path, monkeypatch):
    # DEM.write's parts have unique names now (a review); one that fails midway removes them
    dem = pi.DEM.from_array(np.full((180, 360), 10.0, dtype=np.float32))

    def full_disk(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(np, "ascontiguousarray", full_disk)
    with pytest.raises(OSError, match="No space"):
        dem.write(tmp_path / "x")
    monkeypatch.undo()
    assert sorted(p.name for p in tmp_path.iterdir()) == []
    dem.write(tmp_path / "x")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.dem", "x.hdr"]
