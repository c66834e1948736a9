"""Same answers everywhere: dem_read_mode 0 and 1 bit-identical; threads agree with one."""

import threading

import numpy as np
import pytest

import planet_intersect as pi

from conftest import mixed_rays


@pytest.mark.parametrize("step_mode", [0, 1])
@pytest.mark.parametrize("tangent", ["exact", "paper"])
def test_read_modes_bit_identical(rough_file, step_mode, tangent):
    s, l, _ = mixed_rays(rough_file, 4000, seed=77)
    a = pi.intersect(rough_file, s, l, step_mode=step_mode, dem_read_mode=0, tangent=tangent)
    b = pi.intersect(rough_file, s, l, step_mode=step_mode, dem_read_mode=1, tangent=tangent)
    for name in a.__dataclass_fields__:
        x, y = getattr(a, name), getattr(b, name)
        assert np.array_equal(x, y, equal_nan=True), name     # bit for bit, NaN where NaN


def test_float32_file_mode_0_and_1_identical(tmp_path, rough):
    hdr = rough.write(tmp_path / "f32", dtype="float32", byteorder="big")
    dem = pi.DEM.read(hdr)
    s, l, _ = mixed_rays(dem, 2000, seed=8)
    a = pi.intersect(dem, s, l, dem_read_mode=0)
    b = pi.intersect(dem, s, l, dem_read_mode=1)
    assert np.array_equal(a.p, b.p, equal_nan=True) and np.array_equal(a.status, b.status)
    assert np.array_equal(a.tangent_altitude, b.tangent_altitude, equal_nan=True)


def test_two_threads_give_the_same_results_as_one(rough_file):
    s, l, _ = mixed_rays(rough_file, 20000, seed=99)
    single = {m: pi.intersect(rough_file, s, l, dem_read_mode=m) for m in (0, 1)}
    out = {}
    barrier = threading.Barrier(4)

    def work(key, mode):
        barrier.wait()
        out[key] = pi.intersect(rough_file, s, l, dem_read_mode=mode)

    threads = [threading.Thread(target=work, args=((k, m), m)) for k in range(2) for m in (0, 1)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(out) == 4
    for (k, m), res in out.items():
        assert np.array_equal(res.p, single[m].p, equal_nan=True)
        assert np.array_equal(res.tc, single[m].tc, equal_nan=True)
        assert np.array_equal(res.status, single[m].status)


@pytest.mark.parametrize("dem_read_mode", [0, 1])
def test_openmp_thread_counts_bit_identical(rough_file, dem_read_mode):
    s, l, _ = mixed_rays(rough_file, 6000, seed=5)
    one = pi.intersect(rough_file, s, l, dem_read_mode=dem_read_mode, threads=1)
    for threads in (2, 3, 0, None):
        other = pi.intersect(rough_file, s, l, dem_read_mode=dem_read_mode, threads=threads)
        for name in one.__dataclass_fields__:
            assert np.array_equal(getattr(one, name), getattr(other, name), equal_nan=True), (threads, name)


@pytest.mark.parametrize("bad", [-1, 1.5, "2", True])
def test_bad_thread_count(rough, bad):
    with pytest.raises(ValueError, match="threads must be an integer in 0..1024"):
        pi.intersect(rough, [5000.0, 0, 0], [-1.0, 0, 0], threads=bad)


@pytest.mark.parametrize("dtype, byteorder", [("float32", "little"), ("float64", "little"), ("float32", "big")])
@pytest.mark.parametrize("method", ["stepping", "exact"])
def test_mmap_path_bit_identical(tmp_path, rough, dtype, byteorder, method):
    hdr = rough.write(tmp_path / "m", dtype=dtype, byteorder=byteorder)
    dem = pi.DEM.read(hdr)
    s, l, _ = mixed_rays(dem, 3000, seed=14)
    a = pi.intersect(dem, s, l, dem_read_mode=1, io="records", method=method)
    b = pi.intersect(dem, s, l, dem_read_mode=1, io="mmap", method=method)
    c = pi.intersect(dem, s, l, dem_read_mode=0, method=method)
    for name in a.__dataclass_fields__:
        assert np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True), name
        assert np.array_equal(getattr(a, name), getattr(c, name), equal_nan=True), name


def test_mmap_reads_the_dems_own_map(tmp_path, rough):
    """io="mmap" attaches the memory map DEM.read already holds (no copy, kept
    between calls) when the file is in the machine's byte order; otherwise the
    core maps the file for the call (covered by the bit-identity test above)."""
    native = "little" if np.little_endian else "big"
    other = "big" if np.little_endian else "little"
    mine = pi.DEM.read(rough.write(tmp_path / "n", dtype="float32", byteorder=native))
    b = mine.mapped_bytes()
    assert b is not None and b.nbytes == mine.nlat * mine.nlon * 4 and np.shares_memory(b, mine.radii)
    assert pi.DEM.read(rough.write(tmp_path / "o", dtype="float32", byteorder=other)).mapped_bytes() is None
    assert rough.mapped_bytes() is None                      # in memory: nothing to map
    # the polar means (section 2.2) are computed once per DEM and kept for later calls
    poles = mine.mapped_poles()
    rows = np.asarray(mine.radii, dtype=np.float64)
    np.testing.assert_allclose(poles, [rows[0].mean(), rows[-1].mean()], rtol=1e-14)
    assert mine.mapped_poles() is poles


def test_bad_io(rough_file):
    with pytest.raises(ValueError, match="io must be one of 'records', 'mmap', got 'cache'"):
        pi.intersect(rough_file, [5000.0, 0, 0], [-1.0, 0, 0], dem_read_mode=1, io="cache")


def test_mmap_with_mode_0_is_refused(rough_file):
    """io only says how dem_read_mode=1 reads the file: with the in-memory mode 0 it
    was taken and ignored (listed as left alone in stop 30), now it is refused."""
    for method in ("stepping", "exact"):
        with pytest.raises(ValueError, match=r"io='mmap' says how dem_read_mode=1 reads .*dem_read_mode=0"):
            pi.intersect(rough_file, [5000.0, 0, 0], [-1.0, 0, 0], io="mmap", method=method)
    res = pi.intersect(rough_file, [5000.0, 0, 0], [-1.0, 0, 0], io="records")     # the default: accepted
    assert res.hit[0]


def test_mode1_reads_do_not_map_the_file(tmp_path):
    """DEM.read checks the file with plain reads and mode 1 reads records with pread:
    resident memory does not grow with the DEM. Measured in a child process that only
    imports, reads and intersects; a control run that touches the memory map shows
    that the measurement would see the file if it were mapped in."""
    import subprocess
    import sys
    import textwrap

    from planet_intersect.synthetic import rough_dem

    hdr = rough_dem(ppd=16, base=3390.0, rms=3.0, seed=1).write(tmp_path / "big", dtype="float32")   # 66 MB

    def grown_mb(touch_map: bool) -> float:
        code = textwrap.dedent(f"""
            import numpy as np, planet_intersect as pi
            def hwm_kb():   # this address space's peak RSS (ru_maxrss would include the parent's)
                return int(open("/proc/self/status").read().split("VmHWM:")[1].split()[0])
            base = hwm_kb()
            d = pi.DEM.read({str(hdr)!r})
            s = np.array([5000.0, 0, 0]); l = np.array([[-1.0, 0.01 * k, 0.02] for k in range(50)])
            pi.intersect(d, s, l, dem_read_mode=1)
            if {touch_map}:
                float(np.asarray(d.radii).sum())
            print((hwm_kb() - base) / 1024)
        """)
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr
        return float(out.stdout.strip().splitlines()[-1])

    assert grown_mb(False) < 20.0
    assert grown_mb(True) > 50.0      # control: a mapped and touched file does show
