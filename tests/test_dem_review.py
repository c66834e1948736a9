"""Faults of the planetary DEM's Python side found by an adversarial review
(2026-12-02), each with a test that fails before its fix: float32 writes of
radii float32 cannot hold, writing a DEM whose file was truncated (SIGBUS),
record reads of a DEM under a non-ASCII path, and the message for a
byte-swapped file (the limb classification it found is paper-notes note 22)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import planet_intersect as pi


def test_float32_write_refuses_radii_it_cannot_hold(tmp_path):
    for r in (1e50, 1e-50):
        dem = pi.DEM.from_array(np.full((180, 360), r))
        with pytest.raises(ValueError, match="dtype='float32' cannot hold these radii"):
            dem.write(tmp_path / f"b{r:g}", dtype="float32")
        assert not (tmp_path / f"b{r:g}.hdr").exists() and not (tmp_path / f"b{r:g}.dem").exists()
        back = pi.DEM.read(dem.write(tmp_path / f"ok{r:g}", dtype="float64"))
        assert float(back.radii[0, 0]) == r


def test_writing_a_dem_whose_file_was_truncated(tmp_path):
    """It died of SIGBUS (write read the memory map without the file check); now DEMError. Run in
    a subprocess, so that a regression kills that process, not the test run."""
    code = f"""
import numpy as np, planet_intersect as pi
from planet_intersect.dem import DEMError
p = pi.DEM.from_array(np.full((180, 360), 3390.0)).write({str(tmp_path / 'm')!r})
d = pi.DEM.read(p)
with open({str(tmp_path / 'm.dem')!r}, 'r+b') as fh:
    fh.truncate(1000)
try:
    d.write({str(tmp_path / 'copy')!r})
except DEMError as exc:
    print("DEMError", exc)
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, (r.returncode, r.stderr)
    assert "DEMError" in r.stdout and "size changed" in r.stdout, r.stdout


def test_record_reads_under_a_non_ascii_path(tmp_path):
    d = tmp_path / "Mars_données_Ø"
    d.mkdir()
    dem = pi.DEM.read(pi.DEM.from_array(np.full((180, 360), 3390.0)).write(d / "m"))
    s, l = np.array([[4000.0, 0, 0]]), np.array([[-1.0, 0.0, 0.0]])
    for method in ("stepping", "exact"):
        r = pi.intersect(dem, s, l, method=method, dem_read_mode=1)
        assert r.status[0] == 0 and r.p[0, 0] == pytest.approx(3390.0, abs=1e-6)


def test_byte_swapped_data_are_named(tmp_path):
    radii = np.full((180, 360), 3390.0) + np.random.default_rng(1).uniform(-5, 5, (180, 360))
    (tmp_path / "m.dem").write_bytes(radii.astype(">f4").tobytes())
    (tmp_path / "m.hdr").write_text("1\n3400\n0\n3390\n")              # the paper's four values: little-endian
    with pytest.raises(pi.dem.DEMError if hasattr(pi, "dem") else ValueError,
                       match="the data look byte-swapped: they read as radii with 'byteorder = big'"):
        pi.DEM.read(tmp_path / "m.hdr")
    (tmp_path / "m.hdr").write_text("1\n3400\n0\n3390\nbyteorder = big\n")
    assert pi.DEM.read(tmp_path / "m.hdr").radii[0, 0] == pytest.approx(radii[0, 0], rel=1e-6)
