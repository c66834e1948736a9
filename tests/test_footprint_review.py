"""An independent review of the footprint system (2026-12-05; docs/grs-notes.md note 21).
It found no wrong number (angles, frames, solid angles and occlusion matched its own
geometry to ~1e-12 deg); these are the faults it found in limits, outputs and messages.
"""

from __future__ import annotations

import importlib
import subprocess
import sys
import warnings

import numpy as np
import pytest

import planet_intersect as pi

F = importlib.import_module("planet_intersect.footprint")     # (pi.footprint is the function)

RE = 3396.19
R0 = np.array([3796.19, 0.0, 0.0])
V0 = [0.0, 0.0, 3.4]


@pytest.fixture(scope="module")
def km():
    return pi.CellTable(pi.DEM.from_array(np.full((180, 360), RE), f=0, re=RE), 1.0)


def test_a_cell_table_too_large_for_the_machine_is_refused_naming_cell_deg(monkeypatch):
    # 0.03 deg: 72 million cells, 15 GB of arrays and ~30 GB at the build's peak; it passed the
    # 16 GB check on a 23 GB machine and ran out of memory after 2.5 min inside NumPy
    monkeypatch.setattr(F, "_physical_memory", lambda: 23e9)
    dem = pi.DEM.from_array(np.full((180, 360), RE), f=0, re=RE)
    with pytest.raises(ValueError, match=r"cell_deg = 0.03 makes 72,000,000 cells, about 15.0 GB"):
        pi.CellTable(dem, 0.03)
    monkeypatch.setattr(F, "_physical_memory", lambda: 1e12)          # a big machine: 16 GB still the cap
    with pytest.raises(ValueError, match=r"limit here is 16.0 GB"):
        pi.CellTable(dem, 0.025)


def test_a_footprint_out_of_memory_names_its_cause(km, monkeypatch):
    def no_memory(*a, **k):
        raise MemoryError("Unable to allocate 549 MiB")

    monkeypatch.setattr(F, "_run_kernel", no_memory)
    with pytest.raises(MemoryError, match=r"footprint: 3 spectra over 64,800 cells of 1 deg .* fewer spectra"):
        pi.footprint(km, np.array([R0, R0, R0]), V0)


def test_every_variable_and_coordinate_has_units(km):
    pytest.importorskip("xarray", reason="to_xarray needs xarray")
    fp = pi.footprint(km, R0, V0, zeta=0.9)
    for layout in ("pairs", "dense"):
        ds = fp.to_xarray(layout=layout, length_unit="km")
        for name in ds.variables:
            assert ds[name].attrs.get("units"), (layout, name)        # (visible and the indices had none)
            assert ds[name].attrs.get("long_name"), (layout, name)
    ct = km.to_xarray()
    for name in ct.variables:
        assert ct[name].attrs.get("units") and ct[name].attrs.get("long_name"), name
    assert ct["lat"].attrs["units"] == "degrees_north" and ct["slope"].attrs["units"] == "degree"


def test_the_dense_layout_says_which_cells_are_in_the_footprint(km):
    pytest.importorskip("xarray", reason="to_xarray needs xarray")
    fp = pi.footprint(km, np.array([R0, -R0]), V0, zeta=0.95)
    ds = fp.to_xarray(layout="dense")
    inside = ds["in_footprint"].values
    assert inside.sum() == len(fp)                  # each pair once; the other cells are not in it
    assert ds["visible"].values[inside].all()       # no occlusion: every pair visible, none hidden
    assert not ds["visible"].values[~inside].any()
    # d is there too (it was left out), and agrees with the pairs
    d = ds["d"].values
    col = np.searchsorted(ds["cell"].values, fp.cell)
    np.testing.assert_array_equal(d[fp.spectrum, col], fp.d)


def test_the_notes_air_mass_warns_where_it_is_negative():
    with pytest.warns(UserWarning, match=r"'notes' .* negative at 2 of the zenith angles"):
        x = F.airmass([30.0, 60.0, 85.0, 88.0], model="notes")
    assert (x[:2] > 0).all() and (x[2:] < 0).all()          # (-3.55 and -518.7: as printed, note 4)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        F.airmass([30.0, 60.0, 80.0], model="notes")          # all positive: no word


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "planet_intersect.cli", *map(str, args)], capture_output=True,
                          text=True, timeout=300)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("fprev")
    lat = -90 + (np.arange(180) + 0.5)
    radii = np.repeat((3390.0 + 0.0 * lat)[:, None], 360, axis=1)
    hdr = pi.DEM.from_array(radii, f=0.0, re=3390.0).write(d / "small")
    t = np.arange(0.0, 60.0, 20.0)
    R, v = F.keplerian_states(t, 3780.0, 3840.0, 93.1)
    states = d / "states.csv"
    np.savetxt(states, np.column_stack([t, R, v]), delimiter=",", header="time,x,y,z,vx,vy,vz", comments="")
    hdr_m = pi.DEM.from_array(radii * 1e3, f=0.0, re=3390e3).write(d / "metres")
    states_m = d / "states_m.csv"
    np.savetxt(states_m, np.column_stack([t, R * 1e3, v * 1e3]), delimiter=",", header="time,x,y,z,vx,vy,vz",
               comments="")
    return d, hdr, states, hdr_m, states_m


def test_the_clis_netcdf_describes_the_states(files):
    xr = pytest.importorskip("xarray", reason="the CLI writes NetCDF through xarray")
    d, hdr, states, _, _ = files
    r = _cli("footprint", "--states", states, "--dem", hdr, "--cell-deg", "2", "--zeta", "0.9", "--out", d / "o")
    assert r.returncode == 0, r.stderr
    with xr.open_dataset(d / "o" / "run-001" / "footprint.nc", engine="h5netcdf") as ds:
        for name in ("R", "v", "time"):
            assert ds[name].attrs.get("units") and ds[name].attrs.get("long_name"), name
        assert ds["R"].attrs["units"] == "km"


def test_the_cli_speaks_in_options_and_does_not_echo_binary(files):
    d, _, states, hdr_m, states_m = files
    r = _cli("footprint", "--states", states_m, "--dem", hdr_m, "--cell-deg", "2", "--out", d / "o2")
    assert r.returncode == 2
    assert "--area 3.4e-3" in r.stderr and "--scale-height 10807" in r.stderr and "area=" not in r.stderr
    junk = d / "states.bin"
    junk.write_bytes(bytes(range(256)) * 4)
    r = _cli("footprint", "--states", junk, "--dem", hdr_m, "--out", d / "o3")
    assert r.returncode == 2 and "is not text" in r.stderr and "\\x" not in r.stderr
    assert "--occlusion" in _cli("footprint", "--help").stdout
    assert "hidden pairs are kept" in _cli("footprint", "--help").stdout
