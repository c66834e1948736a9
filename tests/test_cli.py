"""The planet-intersect command: demo, run, and one-line errors."""

import subprocess
import sys

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect.cli import main


def run_cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "planet_intersect.cli", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=300)


def test_demo_writes_results_and_never_overwrites(tmp_path):
    out = tmp_path / "demo"
    r = run_cli("demo", "--out", out, "--pixels", "41")
    assert r.returncode == 0, r.stderr
    assert "1681 rays" in r.stdout and "hit the surface" in r.stdout
    csv = out / "run-001" / "demo_pixels.csv"
    table = np.genfromtxt(csv, delimiter=",", names=True)
    assert len(table) == 41 * 41
    hit = table["hit"] == 1
    # the summary's figures are the file's
    n_hit = int(r.stdout.split(" rays in ")[1].split(":")[1].split()[0])
    assert n_hit == hit.sum() > 0
    assert np.all(np.isfinite(table["lat"][hit])) and np.all(np.isnan(table["lat"][~hit]))
    assert (out / "run-001" / "demo_map.png").stat().st_size > 10000
    # a second run goes to a new folder; the first is untouched
    before = csv.read_bytes()
    assert run_cli("demo", "--out", out, "--pixels", "11").returncode == 0
    assert (out / "run-002" / "demo_pixels.csv").exists() and csv.read_bytes() == before


def test_demo_scene_is_deterministic():
    from planet_intersect.synthetic import mars_like_dem, oblique_scene

    a, b = mars_like_dem(ppd=2), mars_like_dem(ppd=2)
    assert np.array_equal(a.radii, b.radii)
    # the volcano summit stands about 21 km above the spheroid
    from planet_intersect.synthetic import OLYMPUS
    top = a.radius(*OLYMPUS) - pi.spheroid_radius(OLYMPUS[0], a.f, a.re)
    assert 17.0 < top < 25.0
    s, l = oblique_scene(nh=3, nv=3)
    assert l.shape == (9, 3) and np.allclose(np.linalg.norm(l, axis=1), 1)


def test_run_subcommand(tmp_path, rough):
    hdr = rough.write(tmp_path / "dem")
    rays = tmp_path / "rays.txt"
    np.savetxt(rays, [[5000, 0, 0, -1, 0, 0], [5000, 0, 0, 1, 0, 0], [5000, 0, 0, -1, 1, 0]])
    r = run_cli("run", hdr, rays, "--out", tmp_path / "o")
    assert r.returncode == 0, r.stderr
    assert "3 rays: 1 hit, 1 limb, 1 away" in r.stdout
    r = run_cli("run", hdr, rays, "--out", tmp_path / "o", "--method", "exact", "--threads", "1",
                "--dem-read-mode", "1", "--io", "mmap")
    assert r.returncode == 0 and "3 rays: 1 hit, 1 limb, 1 away" in r.stdout, r.stderr
    r = run_cli("run", hdr, rays, "--threads", "-2")
    assert r.returncode == 2 and "threads must be an integer in 0..1024" in r.stderr
    xr = pytest.importorskip("xarray")
    ds = xr.open_dataset(tmp_path / "o" / "run-001" / "results.nc", engine="h5netcdf")
    res = pi.intersect(pi.DEM.read(hdr), [5000, 0, 0], [[-1, 0, 0], [1, 0, 0], [-1, 1, 0]])
    np.testing.assert_array_equal(ds["p"].values, res.p)


@pytest.mark.parametrize("args, message", [
    (["run", "nothere.hdr", "rays.txt"], "nothere.hdr: no such file"),
    (["run", "DEM", "missing_rays.txt"], "rays file missing_rays.txt: no such file"),
    (["run", "DEM", "bad_rays.txt"], "bad_rays.txt, line 1: expected 6 numbers"),
    (["run", "DEM.hdr", "bad_rays.txt", "--io", "mmap"], "--io mmap says how --dem-read-mode 1 reads"),
    (["run", "DEM.hdr", "bad_rays.txt", "--io", "mmap", "--dem-read-mode", "0"], "pass --dem-read-mode 1"),
])
def test_errors_are_one_line(tmp_path, rough, capsys, monkeypatch, args, message):
    rough.write(tmp_path / "DEM")
    (tmp_path / "bad_rays.txt").write_text("1 2 3\n")
    monkeypatch.chdir(tmp_path)
    assert main(args) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and "Traceback" not in err


def test_examples_and_import_mola_commands(tmp_path):
    from conftest import SHARED_DATA, shared_data_or_skip

    src = shared_data_or_skip("mars_mola_megdr_4ppd", "mars_radius_4ppd_megt_plus_areoid.i2be")
    r = run_cli("import-mola", tmp_path / "mola4", "--radius", src)
    assert r.returncode == 0 and "mola4.hdr" in r.stdout
    r = run_cli("import-mola", tmp_path / "mola4", "--radius", src)
    assert r.returncode == 2 and "exists; give --overwrite to replace it" in r.stderr
    r = run_cli("examples", "olympus", "--dem", tmp_path / "mola4.hdr", "--out", tmp_path / "ex")
    assert r.returncode == 0, r.stderr
    assert "10201 of 10201 pixels on the surface" in r.stdout
    assert (tmp_path / "ex" / "run-001" / "olympus_fig8.png").stat().st_size > 50000
    r = run_cli("examples", "limb", "--mola", src, "--out", tmp_path / "ex")
    assert r.returncode == 0 and "195 of them miss the smooth spheroid" in r.stdout
    assert (tmp_path / "ex" / "run-002" / "limb_fig9.png").exists()
    r = run_cli("examples", "olympus", "--mola", tmp_path / "none.img")
    assert r.returncode == 2 and "none.img is missing" in r.stderr


def test_run_in_chunks_equals_one_call(rough):
    from planet_intersect.cli import intersect_in_chunks

    from conftest import mixed_rays

    s, l, _ = mixed_rays(rough, 2500, seed=1)
    whole = pi.intersect(rough, s, l)
    parts = intersect_in_chunks(rough, s, l, chunk=1000)
    assert np.array_equal(whole.p, parts.p, equal_nan=True) and np.array_equal(whole.status, parts.status)


def test_help_for_every_subcommand():
    for sub in ("demo", "run", "examples", "import-mola", "fetch-mola"):
        r = run_cli(sub, "--help")
        assert r.returncode == 0 and "usage: planet-intersect " + sub in r.stdout
