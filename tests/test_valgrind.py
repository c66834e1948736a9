"""The installed legacy driver under valgrind memcheck: no memory errors, no definite leaks.

`valgrind --error-exitcode=1 --leak-check=full test_planet_intersect ...` on a
small DEM and a few rays of every kind (hit, limb, pointing away, pole, a zero
line of sight), in both DEM read modes, and on the driver's error paths (mode
out of range, missing DEM, unreadable rays line), which free their arrays
before exiting too. The summary lines valgrind writes are parsed, not only
its exit status. About 15 s in all.
"""

import os
import re
import shutil
import subprocess

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect.synthetic import MARS_F, MARS_RE, rough_dem

pytestmark = pytest.mark.skipif(shutil.which("valgrind") is None,
                                reason="valgrind is not installed (apt-get install valgrind)")

# libgomp does not join its pool threads at exit, so with more than one thread
# the thread-local blocks glibc gave them are "possibly lost" (not ours: they
# are libgomp's, and not definite). Only that one allocation path is suppressed.
LIBGOMP_POOL = """{
   libgomp-pool-thread-tls
   Memcheck:Leak
   match-leak-kinds: possible
   fun:calloc
   ...
   fun:_dl_allocate_tls
   ...
   fun:GOMP_parallel
}
"""

RAYS = np.array([
    [5000.0, 0.0, 0.0, -1.0, 0.0, 0.0],          # nadir hit
    [2000.0, 2500.0, 1500.0, -0.6, -0.7, -0.3],  # oblique
    [5000.0, 0.0, 0.0, 0.0, 1.0, 0.0],           # limb
    [5000.0, 0.0, 0.0, 1.0, 0.0, 0.0],           # pointing away
    [0.0, 0.0, 6000.0, 1e-4, 0.0, -1.0],         # over the north pole
    [0.0, 0.0, -6000.0, 0.0, 0.0, 1.0],          # at the south pole
    [5000.0, 0.0, 0.0, 0.0, 0.0, 0.0],           # zero line of sight: status 4
])


@pytest.fixture(scope="module")
def driver():
    path = pi.legacy_paths()["driver"]
    if not path.exists():
        pytest.fail(f"the legacy driver was not installed at {path}")
    return path


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    d = tmp_path_factory.mktemp("valgrind")
    dem = rough_dem(ppd=1, base=3390.0, rms=3.0, seed=4, f=MARS_F, re=MARS_RE)
    hdr = dem.write(d / "small", dtype="float32")
    rays = d / "rays.txt"
    np.savetxt(rays, RAYS, fmt="%.17e", header="sx sy sz lx ly lz")
    (d / "libgomp.supp").write_text(LIBGOMP_POOL)
    return d, hdr, rays, pi.DEM.read(hdr)


def memcheck(driver, tmp, args, threads=1, suppress=False):
    """Run the driver under valgrind; return (exit code, errors, definitely lost bytes, stdout, stderr)."""
    log = tmp / f"vg-{len(list(tmp.glob('vg-*')))}.log"
    cmd = ["valgrind", "--error-exitcode=1", "--leak-check=full", f"--log-file={log}"]
    if suppress:
        cmd.append(f"--suppressions={tmp / 'libgomp.supp'}")
    env = dict(os.environ, OMP_NUM_THREADS=str(threads))
    run = subprocess.run(cmd + [str(driver), *map(str, args)], capture_output=True, text=True, timeout=120, env=env)
    text = log.read_text()
    summary = re.findall(r"ERROR SUMMARY: ([\d,]+) errors", text)
    assert len(summary) == 1, text
    errors = int(summary[0].replace(",", ""))
    lost = re.findall(r"definitely lost: ([\d,]+) bytes", text)
    if lost:
        definite = int(lost[0].replace(",", ""))
    else:
        assert "All heap blocks were freed -- no leaks are possible" in text, text
        definite = 0
    return run.returncode, errors, definite, run.stdout, text


@pytest.mark.parametrize("read_mode, step_mode", [(0, 1), (1, 0)])
def test_driver_is_clean_under_memcheck(driver, case, read_mode, step_mode):
    tmp, hdr, rays, dem = case
    rc, errors, definite, out, log = memcheck(driver, tmp, [hdr, read_mode, step_mode, rays])
    assert (rc, errors, definite) == (0, 0, 0), log
    # and it computed the right thing under valgrind: statuses as the Python API's
    table = np.loadtxt(out.splitlines(), comments="#")
    res = pi.intersect(dem, RAYS[:6, :3], RAYS[:6, 3:], step_mode=step_mode, dem_read_mode=read_mode,
                       tangent="paper")
    np.testing.assert_array_equal(table[:6, 1], res.status)
    np.testing.assert_array_equal(table[:, 1], [0, 0, 1, 2, 0, 0, 4])
    np.testing.assert_allclose(table[:6, 2:5], res.p, rtol=1e-15, equal_nan=True)


def test_driver_with_two_threads_has_no_errors(driver, case):
    """The OpenMP loop itself under memcheck; only libgomp's own pool-thread blocks are suppressed."""
    tmp, hdr, rays, _ = case
    rc, errors, definite, _, log = memcheck(driver, tmp, [hdr, 1, 1, rays], threads=2, suppress=True)
    assert (rc, errors, definite) == (0, 0, 0), log


@pytest.mark.parametrize("what", ["mode", "no_dem", "bad_rays"])
def test_driver_error_paths_free_everything(driver, case, what):
    tmp, hdr, rays, _ = case
    if what == "mode":
        args, code = [hdr, 0, 3, rays], 2
    elif what == "no_dem":
        args, code = [tmp / "missing", 0, 1, rays], 2
    else:
        bad = tmp / "bad_rays.txt"
        bad.write_text("5000 0 0 -1 0 0\n5000 0 0 -1 zero 0\n")
        args, code = [hdr, 0, 1, bad], 1
    rc, errors, definite, _, log = memcheck(driver, tmp, args)
    assert (rc, errors, definite) == (code, 0, 0), log
