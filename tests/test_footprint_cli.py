"""The `planet-intersect footprint` subcommand: CSV states in, CSV/NetCDF/PNGs out, clear errors."""

import subprocess
import sys

import numpy as np
import pytest

import planet_intersect as pi
import planet_intersect.footprint  # noqa: F401

F = sys.modules["planet_intersect.footprint"]


def run_cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "planet_intersect.cli", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=300)


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    d = tmp_path_factory.mktemp("fpcli")
    lat = -90 + (np.arange(180) + 0.5)
    radii = np.repeat((3390.0 + 3.0 * np.cos(np.radians(lat)))[:, None], 360, axis=1)
    radii[100:104, 200:204] += 15.0                      # a mesa
    hdr = pi.DEM.from_array(radii, f=0.0, re=3390.0).write(d / "small")
    t = np.arange(0.0, 200.0, 20.0)
    R, v = F.keplerian_states(t, 3780.0, 3840.0, 93.1)
    states = d / "states.csv"
    np.savetxt(states, np.column_stack([t, R, v]), delimiter=",", header="time,x,y,z,vx,vy,vz", comments="")
    return d, hdr, states, R, v


def test_footprint_cli_writes_results(small):
    pytest.importorskip("xarray")
    d, hdr, states, R, v = small
    out = d / "out"
    r = run_cli("footprint", "--states", states, "--dem", hdr, "--cell-deg", "1", "--zeta", "0.6",
                "--out", out, "--chunk", "4", "--color", "emission")
    assert r.returncode == 0, r.stderr
    run = out / "run-001"
    table = np.genfromtxt(run / "footprint.csv", delimiter=",", names=True)
    fp = pi.footprint(pi.CellTable(pi.DEM.read(hdr), 1.0), R, v, zeta=0.6)
    assert len(table) == len(fp)
    assert np.array_equal(table["spectrum"].astype(int), fp.spectrum)
    assert np.array_equal(table["cell"].astype(int), fp.cell)
    assert np.allclose(table["emission"], fp.emission, rtol=1e-9, atol=1e-9)
    assert f"{len(fp)} (spectrum, cell) pairs" in r.stdout
    import xarray as xr

    with xr.open_dataset(run / "footprint.nc", engine="h5netcdf") as ds:
        assert ds.sizes["pair"] == len(fp) and np.allclose(ds["R"].values, R)
    assert (run / "footprint_map.png").stat().st_size > 10000 and (run / "orbit.png").stat().st_size > 10000
    # a second run goes to a new folder
    r = run_cli("footprint", "--states", states, "--dem", hdr, "--cell-deg", "1", "--zeta", "0.9", "--out", out)
    assert r.returncode == 0 and (out / "run-002" / "footprint.csv").exists()
    assert len(np.genfromtxt(run / "footprint.csv", delimiter=",", names=True)) == len(fp)


def test_footprint_cli_errors(small, tmp_path):
    d, hdr, states, R, v = small
    bad = tmp_path / "bad.csv"
    bad.write_text("1,2,3\n4,5,6\n")
    cases = [
        (("--states", tmp_path / "none.csv", "--dem", hdr), "states file"),
        (("--states", bad, "--dem", hdr), "expected 6 columns"),
        (("--states", states, "--dem", hdr, "--zeta", "0.5", "--flux-fraction", "0.5"), "not both"),
        (("--dem", hdr), "give --states"),
        (("--kernels", tmp_path / "k.bsp", "--dem", hdr), "--times"),
        (("--states", states, "--dem", hdr, "--cell-deg", "0.7"), "cell_deg must divide 180"),
        (("--states", states, "--dem", tmp_path / "nodem.hdr"), "nodem.hdr"),
    ]
    for args, message in cases:
        r = run_cli("footprint", *args, "--out", tmp_path / "o")
        assert r.returncode == 2, (args, r.stderr)
        assert message in r.stderr and r.stderr.count("\n") == 1, (args, r.stderr)
    inside = tmp_path / "inside.csv"
    np.savetxt(inside, [[3000.0, 0, 0, 0, 1, 0]], delimiter=",")
    r = run_cli("footprint", "--states", inside, "--dem", hdr, "--out", tmp_path / "o")
    assert r.returncode == 2 and "is not above the surface" in r.stderr


def test_footprint_cli_states_file_faults(small, tmp_path):
    """A damaged first data line is an error naming the bad token (it was dropped as a "header",
    shifting every spectrum number by one); a file with only a header and --chunk < 1 are errors."""
    d, hdr, states, R, v = small
    rows = np.hstack([R, v])[:3]
    damaged = tmp_path / "damaged.csv"
    lines = [",".join(f"{x:.8f}" for x in row) for row in rows]
    lines[0] = lines[0].replace(",", "S,", 1)
    damaged.write_text("\n".join(lines) + "\n")
    header_only = tmp_path / "header.csv"
    header_only.write_text("x,y,z,vx,vy,vz\n")
    ragged = tmp_path / "ragged.csv"
    ragged.write_text("x,y,z,vx,vy,vz\n" + "\n".join(lines[1:]) + "\n1,2,3\n")
    cases = [
        (("--states", damaged), "data line 1: cannot read"),
        (("--states", header_only), "only a header line"),
        (("--states", ragged), "data line 3 has 3 columns"),
        (("--states", states, "--chunk", "0"), "--chunk must be a positive"),
        (("--states", tmp_path), "is a directory"),
    ]
    for args, message in cases:
        r = run_cli("footprint", *args, "--dem", hdr, "--out", tmp_path / "o")
        assert r.returncode == 2, (args, r.stderr)
        assert message in r.stderr and r.stderr.count("\n") == 1, (args, r.stderr)
    # a header line, then good rows: all of them are read (the header is not data)
    good = tmp_path / "good.csv"
    good.write_text("x,y,z,vx,vy,vz\n" + "\n".join(",".join(f"{x:.8f}" for x in row) for row in rows) + "\n")
    r = run_cli("footprint", "--states", good, "--dem", hdr, "--cell-deg", "1", "--zeta", "0.9", "--out",
                tmp_path / "g")
    assert r.returncode == 0, r.stderr
    table = np.genfromtxt(tmp_path / "g" / "run-001" / "footprint.csv", delimiter=",", names=True)
    assert set(table["spectrum"].astype(int)) == {0, 1, 2}


def test_footprint_cli_on_a_dem_in_metres(small, tmp_path):
    """A DEM in metres with the km defaults of --area and H is refused, naming them (a walk-through
    saw solid angles 1e6 too small and air masses up to 612); with both in metres the pairs equal
    the km DEM's, solid angles to 1e-12 and air masses to 1e-12 relative (grs-notes 19)."""
    pytest.importorskip("xarray")
    d, hdr, states, R, v = small
    dem = pi.DEM.read(hdr)
    hdr_m = pi.DEM.from_array(np.asarray(dem.radii, dtype=np.float64) * 1000.0, f=0.0, re=3390.0e3).write(
        tmp_path / "small_m")
    states_m = tmp_path / "states_m.csv"
    t = np.arange(0.0, 200.0, 20.0)
    np.savetxt(states_m, np.column_stack([t, R * 1000.0, v * 1000.0]), delimiter=",",
               header="time,x,y,z,vx,vy,vz", comments="")
    r = run_cli("footprint", "--states", states_m, "--dem", hdr_m, "--cell-deg", "1", "--out", tmp_path / "o")
    assert r.returncode == 2 and "area and H:" in r.stderr and "too large to be kilometres" in r.stderr, r.stderr
    H = F.scale_height()
    r = run_cli("footprint", "--states", states_m, "--dem", hdr_m, "--cell-deg", "1", "--area", 3.4e-3,
                "--scale-height", H * 1000.0, "--out", tmp_path / "o")
    assert r.returncode == 0, r.stderr
    r_km = run_cli("footprint", "--states", states, "--dem", hdr, "--cell-deg", "1", "--out", tmp_path / "k")
    assert r_km.returncode == 0, r_km.stderr
    m = np.genfromtxt(tmp_path / "o" / "run-001" / "footprint.csv", delimiter=",", names=True)
    k = np.genfromtxt(tmp_path / "k" / "run-001" / "footprint.csv", delimiter=",", names=True)
    assert np.array_equal(m["cell"], k["cell"]) and np.array_equal(m["spectrum"], k["spectrum"])
    assert np.allclose(m["solid_angle"], k["solid_angle"], rtol=1e-9, atol=0)   # (CSV: 10 digits)
    assert np.allclose(m["airmass"], k["airmass"], rtol=1e-9, atol=0, equal_nan=True)
    import xarray as xr

    with xr.open_dataset(tmp_path / "k" / "run-001" / "footprint.nc", engine="h5netcdf") as ds:
        assert ds["distance"].attrs["units"] == "km" and ds["solid_angle"].attrs["units"] == "sr"
    with xr.open_dataset(tmp_path / "o" / "run-001" / "footprint.nc", engine="h5netcdf") as ds:
        assert ds["distance"].attrs["units"] != "km"
