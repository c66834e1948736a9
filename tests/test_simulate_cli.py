"""`planet-intersect simulate` as a newcomer meets it (a walk-through by a helper who had only the
README and the CLI's help, 2026-12-03): sensor options that the chosen sensor would ignore are
refused, files that are not what the option wants are named, warnings become one-line notes, and
the help states the defaults and the image's orientation. Each case is a subprocess-free call of
``cli.main`` on small .npz inputs (no rasterio needed) unless it says otherwise."""

from __future__ import annotations

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect.cli import main
from planet_intersect.synthetic_dsm import metre_steps, oblique_pushbroom

LAT0, LON0 = 36.6, -84.2


def _files(tmp_path, n=24, ortho_offset_deg=0.0):
    """A flat 1 m DSM with one 15 m box and an ortho on its grid, as .npz; returns (dsm, ortho, grid)."""
    dlat, dlon = metre_steps(LAT0)
    lat_first = LAT0 + (n - 1) * dlat
    h = np.full((n, n), 80.0)
    h[8:14, 8:14] = 95.0
    grid = dict(heights=h, lat_first=lat_first, lon_first=LON0, dlat=-dlat, dlon=dlon)
    np.savez(tmp_path / "dsm.npz", interpolation="nearest", **grid)
    vals = 10.0 + np.arange(n * n, dtype=np.float64).reshape(n, n)
    np.savez(tmp_path / "ortho.npz", values=vals, lat_first=lat_first + ortho_offset_deg, lon_first=LON0,
             dlat=-dlat, dlon=dlon)
    return tmp_path / "dsm.npz", tmp_path / "ortho.npz", grid


def _run(args, capsys):
    rc = main(["simulate", *map(str, args)])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


@pytest.mark.parametrize("extra, words", [
    (["--roll", "8"], "--roll: need --orbit"),
    (["--roll", "0"], "--roll: need --orbit"),                       # a zero is given too
    (["--lines", "30", "--pixels", "20"], "--lines, --pixels: need --orbit"),
    (["--target", "36.6,-84.2"], "--target: need --orbit"),
    (["--orbit", "--target", "36.6,-84.2", "--oblique", "30,0"], "--orbit: --oblique belongs to --oblique runs"),
    (["--orbit", "--target", "36.6,-84.2", "--step", "2"], "--orbit: --step belongs to --oblique runs"),
])
def test_options_the_sensor_would_ignore_are_refused(tmp_path, capsys, extra, words):
    """--roll without --orbit was ignored (the image came from --oblique's default sensor), and so
    were --oblique or --step beside --orbit: each is now an error naming the options."""
    dsm, ortho, _ = _files(tmp_path)
    rc, out, err = _run(["--dsm", dsm, "--ortho", ortho, "--quiet", "--out", tmp_path / "o", *extra], capsys)
    assert rc == 2 and words in err, err
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


def test_geometry_file_conflicts_and_mistakes(tmp_path, capsys):
    """--geometry takes the whole sensor from its file: --oblique or --orbit beside it were ignored;
    a file holding both s and position was taken as a pushbroom; positions in km were reported only
    as a ray's error without the file's name; a GeoTIFF given as --geometry got numpy's pickle text."""
    dsm, ortho, grid = _files(tmp_path)
    s, l = oblique_pushbroom(grid, zenith=9.0, azimuth=90.0)
    np.savez(tmp_path / "push.npz", s=s, l=l)
    base = ["--dsm", dsm, "--ortho", ortho, "--quiet", "--out", tmp_path / "o"]
    rc, _, err = _run([*base, "--geometry", tmp_path / "push.npz", "--oblique", "30,0"], capsys)
    assert rc == 2 and "--geometry takes the whole sensor from its file: --oblique would be ignored" in err, err
    rc, _, err = _run([*base, "--geometry", tmp_path / "push.npz", "--orbit", "--target", "36.6,-84.2"], capsys)
    assert rc == 2 and "--orbit, --target would be ignored" in err, err
    np.savez(tmp_path / "both.npz", s=s, l=l, position=s[0])
    rc, _, err = _run([*base, "--geometry", tmp_path / "both.npz"], capsys)
    assert rc == 2 and "holds both s (a pushbroom) and position (a frame camera)" in err, err
    np.savez(tmp_path / "km.npz", s=s / 1000.0, l=l)
    rc, _, err = _run([*base, "--geometry", tmp_path / "km.npz"], capsys)
    assert rc == 2 and "km.npz" in err and "inside the ellipsoid" in err and "ECR metres" in err, err
    (tmp_path / "not.npz").write_bytes(b"II*\x00" + bytes(100))         # a TIFF's header
    rc, _, err = _run([*base, "--geometry", tmp_path / "not.npz"], capsys)
    assert rc == 2 and "not.npz: not an .npz file" in err and "pickle" not in err, err
    # the file's own sensor, alone, runs
    rc, out, err = _run([*base, "--geometry", tmp_path / "push.npz", "--no-occlusion"], capsys)
    assert rc == 0, err


def test_ortho_off_the_dsm_is_a_one_line_note(tmp_path, capsys):
    """An ortho-photo that does not overlap the DSM: the run succeeds with an image of fill, and
    says so in one line naming --ortho and its file (it printed Python's warning with cli.py's
    line and source)."""
    dsm, ortho, _ = _files(tmp_path, ortho_offset_deg=1.0)                # 111 km north of the DSM
    rc, out, err = _run(["--dsm", dsm, "--ortho", ortho, "--quiet", "--no-occlusion", "--out", tmp_path / "o"],
                        capsys)
    assert rc == 0, err
    notes = [ln for ln in err.splitlines() if ln.strip()]
    assert len(notes) == 1, err
    assert notes[0].startswith(f"simulate: note: --ortho {ortho}: 576 pixel(s) hit the DSM where the "
                               "ortho-image has no value"), notes[0]
    assert "cli.py" not in err and "UserWarning" not in err
    # the summary's rate is the simulation's, and says so
    assert "s in all (the simulation itself" in out and "px/s; reading, occlusion and writing the rest)" in out


def test_help_states_defaults_and_orientation(capsys):
    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for words in ("image lines (default 1024)", "pixels per line (default 1024)", "(default: simulate-output)",
                  "nearest for buildings: flat roofs, vertical walls", "an ascending pass's image has south at "
                  "the top", "pixels its columns west to east"):
        assert words in text, words


def test_oblique_image_orientation_is_the_dsms(tmp_path, capsys):
    """What the help says of --oblique: line k is the DSM's row k as stored, pixel m its column m
    (west to east): at nadir the latitude backplane falls down the image of a north-up DSM and the
    longitude rises along a line."""
    xr = pytest.importorskip("xarray", reason="the NetCDF output needs xarray")
    pytest.importorskip("h5netcdf", reason="the NetCDF output needs h5netcdf")
    dsm, ortho, grid = _files(tmp_path)
    rc, out, err = _run(["--dsm", dsm, "--ortho", ortho, "--oblique", "0,90", "--quiet", "--no-occlusion",
                         "--out", tmp_path / "o"], capsys)
    assert rc == 0, err
    with xr.open_dataset(tmp_path / "o" / "run-001" / "simulated.nc", engine="h5netcdf") as ds:
        lat, lon = ds["lat"].values, ds["lon"].values
    assert np.all(np.diff(lat[:, 5]) < 0) and np.all(np.diff(lon[5, :]) > 0)
    d = pi.GeodeticDSM.read(dsm)
    np.testing.assert_allclose(lat[:, 5], d.lats, atol=1e-7)            # row k of the DSM, to 1 cm


def test_a_multi_band_raster_given_as_the_dsm_is_refused(tmp_path, capsys):
    """An RGB image given as --dsm ran with its first band as heights."""
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF files need rasterio")
    from rasterio.transform import from_origin

    dsm, ortho, grid = _files(tmp_path)
    n = grid["heights"].shape[0]
    tr = from_origin(LON0 - grid["dlon"] / 2, grid["lat_first"] - grid["dlat"] / 2, grid["dlon"], -grid["dlat"])
    with rasterio.open(tmp_path / "rgb.tif", "w", driver="GTiff", width=n, height=n, count=3, dtype="uint8",
                       crs="EPSG:4326", transform=tr) as dst:
        dst.write(np.full((3, n, n), 100, dtype=np.uint8))
    rc, _, err = _run(["--dsm", tmp_path / "rgb.tif", "--ortho", ortho, "--quiet", "--out", tmp_path / "o"],
                      capsys)
    assert rc == 2 and "rgb.tif: the file has 3 bands; a DSM has one band of heights" in err, err
    assert pi.GeodeticDSM.read(tmp_path / "rgb.tif").file_bands == 3       # the API still reads band 1


def test_a_warped_dsm_is_reported(tmp_path, capsys):
    """A DSM in a projected CRS is warped to a geodetic grid of rasterio's choosing (a newcomer's
    24 x 24 grid of 1 m UTM cells became 19 x 28 cells of 1.29 x 0.85 m, silently): the run says
    what grid it became, with the cell sizes in metres and the interpolation read."""
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF files need rasterio")
    from rasterio.transform import from_origin

    n = 30
    h = np.full((n, n), 50.0)
    h[10:20, 10:20] = 70.0
    tr = from_origin(448_000.0, 5_411_000.0, 1.0, 1.0)                    # UTM 31N, near Paris
    with rasterio.open(tmp_path / "dsm.tif", "w", driver="GTiff", width=n, height=n, count=1, dtype="float32",
                       crs="EPSG:32631", transform=tr) as dst:
        dst.write(h.astype(np.float32), 1)
    d = pi.GeodeticDSM.read(tmp_path / "dsm.tif")
    np.savez(tmp_path / "ortho.npz", values=np.ones(d.shape), lat_first=d.lat_first, lon_first=d.lon_first,
             dlat=d.dlat, dlon=d.dlon)
    rc, out, err = _run(["--dsm", tmp_path / "dsm.tif", "--ortho", tmp_path / "ortho.npz", "--oblique", "0,90",
                         "--quiet", "--no-occlusion", "--out", tmp_path / "o"], capsys)
    assert rc == 0, err
    note = [ln for ln in err.splitlines() if "warped" in ln]
    assert len(note) == 1, err
    dy = abs(np.radians(d.dlat)) * d.a
    assert note[0].startswith(f"simulate: note: --dsm {tmp_path / 'dsm.tif'} (EPSG:32631) warped (nearest) to a "
                              f"geodetic grid of {d.nrows} x {d.ncols} cells of {dy:.3g} m x "), note[0]
    assert note[0].endswith("read 'nearest'"), note[0]
    assert 0.5 < dy < 2.0


def test_sensor_options_without_a_dsm_are_refused(tmp_path, capsys):
    """Without --dsm the built-in paper scene runs with --oblique's zenith and --size only: --orbit's
    options or --step there were ignored."""
    rc, _, err = _run(["--size", "128", "--quiet", "--roll", "5", "--out", tmp_path / "o"], capsys)
    assert rc == 2 and "--roll: need --dsm" in err, err
    rc, _, err = _run(["--size", "128", "--quiet", "--orbit", "--step", "2", "--out", tmp_path / "o"], capsys)
    assert rc == 2 and "--orbit, --step: need --dsm" in err, err
    assert not (tmp_path / "o").exists()


def test_frame_camera_position_of_the_wrong_length_is_named():
    l = np.zeros((2, 2, 3))
    l[..., 2] = -1.0
    with pytest.raises(ValueError, match=r"position: expected shape \(3,\), got \(2,\)"):
        pi.FrameCamera(np.array([6.4e6, 0.0]), l)
