"""Faults in the image simulation's files found by an independent review of its outputs as a
GIS user would use them (2026-12-05; docs/simulation-notes.md note 18).

* ``save`` wrote straight to the final name: a full disk left a GeoTIFF that opened as
  complete but was three quarters zeros (libtiff only printed to stderr), Ctrl-C left all-zero
  bands or a truncated PNG under the final name, and the retry was then refused as "exists".
* ``out=DIR`` killed before its end left full-size maps that loaded as complete; the ortho-grid
  masks and the run's parameters were never written there.
* The files did not say what produced them (sensor, DSM, ortho, options, version), had no units,
  and the masks had no coordinates; the GeoTIFF had no status or ortho_value band.
* An orbit of 2,000,000 lines passed every check until the kernel killed the process.
* Ctrl-C in the CLI printed a traceback; simulate's run folders had no run.json.
"""

from __future__ import annotations

import json
import os
import shutil

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect import simulate as sim_mod
from planet_intersect.synthetic_dsm import oblique_pushbroom


@pytest.fixture(scope="module")
def sim():
    from test_simulate import box_scene

    dsm, ortho, scene = box_scene()
    sensor = pi.Pushbroom(*oblique_pushbroom(scene, zenith=9.0, azimuth=90.0, margin=10))
    return pi.simulate_image(dsm, ortho, sensor, threads=1), dsm, ortho, sensor


def _leftovers(folder):
    return sorted(p.name for p in folder.iterdir() if ".partial" in p.name)


def test_a_disk_without_room_is_refused_before_writing(sim, tmp_path, monkeypatch):
    res = sim[0]
    monkeypatch.setattr(shutil, "disk_usage", lambda p: shutil._ntuple_diskusage(10 ** 9, 10 ** 9 - 1000, 1000))
    for name in ("a.tif", "a.nc", "a.png"):
        if name.endswith(".tif"):
            pytest.importorskip("rasterio", reason="the GeoTIFF needs rasterio")
        with pytest.raises(OSError, match="MiB free"):
            res.save(tmp_path / name)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("suffix", [".tif", ".nc", ".png"])
def test_an_interrupted_save_leaves_nothing_and_the_retry_works(sim, tmp_path, monkeypatch, suffix):
    if suffix == ".tif":
        pytest.importorskip("rasterio", reason="the GeoTIFF needs rasterio")
    if suffix == ".nc":
        pytest.importorskip("h5netcdf", reason="the NetCDF needs h5netcdf")
    res = sim[0]
    real_link = os.link

    def interrupted(src, dst):                       # the data is written; Ctrl-C before it is named
        assert os.path.getsize(src) > 0
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "link", interrupted)
    with pytest.raises(KeyboardInterrupt):
        res.save(tmp_path / f"x{suffix}")
    assert list(tmp_path.iterdir()) == []            # no final name, no partial file
    monkeypatch.setattr(os, "link", real_link)
    assert res.save(tmp_path / f"x{suffix}").exists()
    assert _leftovers(tmp_path) == []


def test_a_geotiff_that_does_not_read_back_is_not_kept(sim, tmp_path, monkeypatch):
    rasterio = pytest.importorskip("rasterio", reason="the GeoTIFF needs rasterio")
    res = sim[0]
    real_write = rasterio.io.DatasetWriter.write

    def short_write(self, arr, indexes=None, **kw):   # what a full disk does: some bands never land
        return real_write(self, arr if indexes != 3 else np.zeros_like(arr), indexes, **kw)

    monkeypatch.setattr(rasterio.io.DatasetWriter, "write", short_write)
    with pytest.raises(OSError, match="did not read back"):
        res.save(tmp_path / "x.tif")
    assert list(tmp_path.iterdir()) == []


def test_the_files_say_what_made_them_with_units_and_the_masks_coordinates(sim, tmp_path):
    xr = pytest.importorskip("xarray", reason="the NetCDF needs xarray")
    pytest.importorskip("h5netcdf", reason="the NetCDF needs h5netcdf")
    res, dsm, ortho, sensor = sim
    res.save(tmp_path / "x.nc")
    with xr.open_dataset(tmp_path / "x.nc", engine="h5netcdf") as ds:
        a = ds.attrs
        assert a["sensor"] == "Pushbroom" and a["sensor_lines"] == sensor.shape[0]
        assert a["dsm_interpolation"] == dsm.interpolation and a["dsm_dlat"] == dsm.dlat
        assert a["ortho_shape"] == f"{ortho.shape[0]} x {ortho.shape[1]}"
        assert a["planet_intersect_version"] == pi.__version__ and a["created_utc"].endswith("Z")
        assert a["fill"] == 0.0 and a["ground"].startswith("opening of 100 m") and a["occlusion"] == 1
        assert a["sensor_focal_point_first"].split()[0] == f"{np.atleast_2d(sensor.s)[0, 0]:.6f}"
        assert ds["lat"].attrs["units"] == "degrees_north" and ds["distance"].attrs["units"] == "DSM units"
        assert "long_name" in ds["surface"].attrs
        # the masks on the ortho-image's grid: a hidden pixel's coordinates are its centre's
        i, j = np.argwhere(ds["occlusion"].values == 1)[0]
        assert ds["ortho_lat"].values[i] == pytest.approx(ortho.lat_first + i * ortho.dlat, abs=1e-12)
        assert ds["ortho_lon"].values[j] == pytest.approx(ortho.lon_first + j * ortho.dlon, abs=1e-12)
    # two runs with other options can be told apart from their files
    other = pi.simulate_image(dsm, ortho, sensor, threads=1, fill=-1.0, roof_min=3.0)
    assert other.meta["fill"] == -1.0 and other.meta["roof_min"] == 3.0 and res.meta["roof_min"] == 2.0


def test_the_geotiff_has_status_and_ortho_value_bands_and_the_parameters(sim, tmp_path):
    rasterio = pytest.importorskip("rasterio", reason="the GeoTIFF needs rasterio")
    res = sim[0]
    res.save(tmp_path / "x.tif")
    with rasterio.open(tmp_path / "x.tif") as src:
        names = list(src.descriptions)
        assert names[-2:] == ["status", "ortho_value"]
        np.testing.assert_array_equal(src.read(names.index("status") + 1), res.status)
        np.testing.assert_array_equal(src.read(names.index("ortho_value") + 1), res.ortho_value)
        tags = src.tags()
        assert tags["sensor"] == "Pushbroom" and tags["dsm_interpolation"] == "nearest"
        assert src.units[names.index("lat")] == "degrees_north"
        assert src.tags(names.index("distance") + 1)["long_name"].startswith("distance from the focal point")


def test_out_dir_holds_the_masks_and_meta_json_written_last(sim, tmp_path):
    _, dsm, ortho, sensor = sim
    res = pi.simulate_image(dsm, ortho, sensor, threads=1, out=tmp_path / "maps")
    d = tmp_path / "maps"
    np.testing.assert_array_equal(np.load(d / "occlusion.npy"), res.occlusion)
    np.testing.assert_array_equal(np.load(d / "footprint.npy"), res.footprint)
    meta = json.loads((d / "meta.json").read_text())
    assert meta["complete"] is True and meta["sensor_lines"] == sensor.shape[0]
    newest = max(d.iterdir(), key=lambda p: p.stat().st_mtime_ns)
    assert newest.name == "meta.json"                 # a folder without it did not finish
    assert _leftovers(d) == []


def test_a_result_larger_than_the_machine_is_refused_before_any_work(sim, monkeypatch):
    _, dsm, ortho, sensor = sim
    real = os.sysconf
    monkeypatch.setattr(os, "sysconf", lambda k: 64 if k == "SC_PHYS_PAGES" else real(k))
    with pytest.raises(MemoryError, match="pass out=DIR"):
        pi.simulate_image(dsm, ortho, sensor, threads=1)


def test_the_cli_says_interrupted_in_one_line(monkeypatch, capsys):
    from planet_intersect import cli

    real = cli._parser

    def parser():
        p = real()
        parse = p.parse_args

        def parse_args(argv=None):
            a = parse(argv)
            a.func = lambda args: (_ for _ in ()).throw(KeyboardInterrupt())
            return a

        p.parse_args = parse_args
        return p

    monkeypatch.setattr(cli, "_parser", parser)
    assert cli.main(["config", "--core"]) == 130
    assert capsys.readouterr().err.strip() == "planet-intersect: interrupted"


def test_simulate_run_folders_hold_run_json(tmp_path, capsys):
    pytest.importorskip("xarray", reason="the NetCDF output needs xarray")
    from test_simulate_cli import _files, _run

    dsm, ortho, _ = _files(tmp_path)
    rc, out, err = _run(["--dsm", dsm, "--ortho", ortho, "--oblique", "9,90", "--quiet", "--out", tmp_path / "o"],
                        capsys)
    assert rc == 0, err
    rec = json.loads((tmp_path / "o" / "run-001" / "run.json").read_text())
    assert rec["dsm"] == str(dsm.resolve()) and rec["oblique"] == [9.0, 90.0] and rec["method"] == "exact"
    assert rec["planet_intersect_version"] == pi.__version__


def test_a_second_review_of_the_new_files(sim, tmp_path):
    # two saves to one path at once wrote one temporary file (its name was the pid's); names of
    # 241-255 characters failed on the temporary's longer name; meta.json held a bare NaN; frame
    # cameras 5 m apart left the same record (a second review, 2026-12-05)
    import threading

    res, dsm, ortho, sensor = sim
    other = pi.simulate_image(dsm, ortho, sensor, threads=1, fill=7.0, occlusion=False)
    target, errors, done = tmp_path / "same.nc", [], []

    def save(r):
        try:
            done.append((r, r.save(target)))
        except FileExistsError as exc:
            errors.append(exc)

    pytest.importorskip("h5netcdf", reason="the NetCDF needs h5netcdf")
    ts = [threading.Thread(target=save, args=(r,)) for r in (res, other)]
    for t_ in ts:
        t_.start()
    for t_ in ts:
        t_.join()
    assert len(done) == 1 and len(errors) == 1
    xr = pytest.importorskip("xarray")
    with xr.open_dataset(target, engine="h5netcdf") as ds:
        assert ds.attrs["fill"] == done[0][0].meta["fill"]       # the file holds the winner's data
    long = tmp_path / ("x" * 250 + ".png")
    assert res.save(long).exists()
    nan_run = pi.simulate_image(dsm, ortho, sensor, threads=1, fill=float("nan"), out=tmp_path / "nan")
    meta = json.loads((tmp_path / "nan" / "meta.json").read_text())   # strict: NaN as a string
    json.dumps(meta, allow_nan=False)
    assert meta["fill"] == "nan" and nan_run.meta["fill"] != nan_run.meta["fill"]
    npx = sensor.shape[1]
    s4, l4 = sensor.rays(0, 4)
    cams = [pi.FrameCamera(np.atleast_2d(s4)[0] + dx, np.asarray(l4).reshape(4, npx, 3)) for dx in (0.0, 5.0)]
    recs = [pi.simulate_image(dsm, ortho, c, threads=1, occlusion=False).meta["sensor_focal_point_first"]
            for c in cams]
    assert recs[0] != recs[1]



def test_the_cli_takes_a_bare_earth_model_or_the_openings_width(tmp_path, capsys):
    # the review's hilly paper scene mislabelled bare terrain as roof with the fixed 100 m opening,
    # and the CLI could not be told otherwise: --ground FILE and --ground-window METRES
    from test_simulate_cli import _files, _run

    xr = pytest.importorskip("xarray", reason="the NetCDF output needs xarray")
    dsm, ortho, grid = _files(tmp_path)                  # flat 80 m ground, a 15 m box of 6 x 6 cells
    flat = dict(grid, heights=np.full_like(grid["heights"], 80.0))
    np.savez(tmp_path / "ground.npz", interpolation="nearest", **flat)
    common = ["--dsm", dsm, "--ortho", ortho, "--oblique", "0,90", "--quiet", "--no-occlusion"]
    runs = {}
    for name, extra in (("default", []), ("ground", ["--ground", tmp_path / "ground.npz"]),
                        ("narrow", ["--ground-window", "3"])):
        rc, out, err = _run([*common, *extra, "--out", tmp_path / name], capsys)
        assert rc == 0, err
        with xr.open_dataset(tmp_path / name / "run-001" / "simulated.nc", engine="h5netcdf") as ds:
            runs[name] = ds["surface"].values.copy()
    roof = 1
    # the true bare earth: the box's 36 cells are roof, as with the 100 m opening on this small scene
    assert (runs["ground"] == roof).sum() == (runs["default"] == roof).sum() > 0
    # a 3 m opening is narrower than the 6 m box: the box survives the opening and reads as ground
    assert (runs["narrow"] == roof).sum() < (runs["default"] == roof).sum()
    rc, out, err = _run([*common, "--ground", tmp_path / "ground.npz", "--ground-window", "5",
                         "--out", tmp_path / "both"], capsys)
    assert rc == 2 and "--ground-window" in err
    rc, out, err = _run([*common, "--ground-window", "-1", "--out", tmp_path / "neg"], capsys)
    assert rc == 2 and "positive" in err
