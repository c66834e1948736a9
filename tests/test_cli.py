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
    xr = pytest.importorskip("xarray")
    ds = xr.open_dataset(tmp_path / "o" / "run-001" / "results.nc", engine="h5netcdf")
    res = pi.intersect(pi.DEM.read(hdr), [5000, 0, 0], [[-1, 0, 0], [1, 0, 0], [-1, 1, 0]])
    np.testing.assert_array_equal(ds["p"].values, res.p)


@pytest.mark.parametrize("args, message", [
    (["run", "nothere.hdr", "rays.txt"], "nothere.hdr: no such file"),
    (["run", "DEM", "missing_rays.txt"], "rays file missing_rays.txt: no such file"),
    (["run", "DEM", "bad_rays.txt"], "expected 6 columns"),
])
def test_errors_are_one_line(tmp_path, rough, capsys, monkeypatch, args, message):
    rough.write(tmp_path / "DEM")
    (tmp_path / "bad_rays.txt").write_text("1 2 3\n")
    monkeypatch.chdir(tmp_path)
    assert main(args) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and "Traceback" not in err
