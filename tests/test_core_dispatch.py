"""The two builds of the compiled core: ``_core`` (any x86-64 CPU) and
``_core_v3`` (x86-64-v3: AVX2, FMA, BMI2, ...), chosen at import by
planet_intersect/_ext.py.

* the choice: PI_CORE (auto, portable, v3; anything else an error naming
  PI_CORE), the CPU's flags from a cpuinfo file (a CPU without AVX2 never gets
  the v3 build: it would stop with an illegal instruction);
* the results: both builds come from the same sources with the same IEEE flags
  (no fast-math, no FMA contraction), so every system must give the same bits
  with either: the planetary stepping and exact modes, the geodetic conversions,
  the DSM's three methods, the footprint geometry and the image simulation,
  each run once with each core on the same inputs and compared with
  array_equal (NaN in the same places). A difference here means the vector
  build changed the arithmetic (a contraction into FMA, a reassociation).
"""

from __future__ import annotations

import os
import subprocess
import sys
from contextlib import contextmanager

import numpy as np
import pytest

import planet_intersect as pi
from planet_intersect import _ext

INTEL_V3 = ("fpu vme de pse tsc msr pae mce cx8 apic sep mtrr pge mca cmov pat pse36 clflush mmx fxsr sse sse2 ss "
            "ht syscall nx pdpe1gb rdtscp lm constant_tsc rep_good nopl xtopology nonstop_tsc cpuid tsc_known_freq "
            "pni pclmulqdq ssse3 fma cx16 pcid sse4_1 sse4_2 x2apic movbe popcnt tsc_deadline_timer aes xsave avx "
            "f16c rdrand hypervisor lahf_lm abm 3dnowprefetch invpcid_single ssbd ibrs ibpb stibp fsgsbase "
            "tsc_adjust bmi1 avx2 smep bmi2 erms invpcid rdseed adx smap clflushopt xsaveopt xsavec xgetbv1 arat")
# a Sandy Bridge-era CPU: AVX but no AVX2, FMA, BMI, MOVBE, F16C, LZCNT
SANDY = ("fpu vme de pse tsc msr pae mce cx8 apic sep mtrr pge mca cmov pat pse36 clflush mmx fxsr sse sse2 ss ht "
         "syscall nx rdtscp lm constant_tsc pni pclmulqdq ssse3 cx16 sse4_1 sse4_2 x2apic popcnt aes xsave avx "
         "hypervisor lahf_lm xsaveopt")


def test_cpu_flags_from_a_cpuinfo_file(tmp_path):
    f = tmp_path / "cpuinfo"
    f.write_text(f"processor\t: 0\nvendor_id\t: GenuineIntel\nflags\t\t: {INTEL_V3}\nbugs\t\t: spectre_v1\n"
                 f"\nprocessor\t: 1\nflags\t\t: fpu\n")
    flags = _ext.cpu_flags(f)
    assert "avx2" in flags and "bmi2" in flags and "spectre_v1" not in flags   # the first flags line only
    assert _ext.missing_v3(flags) == []
    assert _ext.cpu_flags(tmp_path / "absent") is None
    (tmp_path / "noflags").write_text("processor : 0\n")
    assert _ext.cpu_flags(tmp_path / "noflags") is None


def test_missing_v3_names_each_absent_feature():
    assert _ext.missing_v3(SANDY.split()) == ["abm", "avx2", "bmi1", "bmi2", "f16c", "fma", "movbe"]
    assert _ext.missing_v3(set(INTEL_V3.split()) - {"fma"}) == ["fma"]


@pytest.mark.parametrize("env, built, flags, expect", [
    (None, True, INTEL_V3, "_core_v3"),
    ("", True, INTEL_V3, "_core_v3"),
    ("auto", True, INTEL_V3, "_core_v3"),
    (" V3 ", True, INTEL_V3, "_core_v3"),
    ("portable", True, INTEL_V3, "_core"),
    (None, True, SANDY, "_core"),             # no AVX2: never the v3 build
    (None, False, INTEL_V3, "_core"),         # not built (other CPU family, -Dcpu_dispatch=false, checked build)
    (None, True, None, "_core"),              # no /proc/cpuinfo: the safe choice
    ("v3", True, None, "_core_v3"),           # the user insists and the flags cannot be read
])
def test_choice_of_the_core(env, built, flags, expect):
    name, reason = _ext.choose(env, built, None if flags is None else flags.split())
    assert name == expect and reason


@pytest.mark.parametrize("env, built, flags, exc, match", [
    ("avx2", True, INTEL_V3, ValueError, "PI_CORE='avx2': expected one of auto, portable, v3"),
    ("v3", True, SANDY, RuntimeError, "PI_CORE=v3: this CPU lacks x86-64-v3 features abm, avx2, bmi1"),
    ("v3", False, INTEL_V3, RuntimeError, "PI_CORE=v3: this installation has no _core_v3"),
])
def test_choice_errors_name_pi_core(env, built, flags, exc, match):
    with pytest.raises(exc, match=match):
        _ext.choose(env, built, flags.split())


def _run(env_value, code):
    env = dict(os.environ)
    env["PI_CORE"] = env_value
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)


def test_pi_core_in_a_fresh_process():
    """The variable is read at the first call into the core, in a new process."""
    p = _run("portable", "import planet_intersect as pi; print(pi.core_info()['module'])")
    assert p.returncode == 0 and p.stdout.strip() == "_core"
    p = _run("fast", "import planet_intersect as pi; print(pi.core_info())")
    assert p.returncode != 0 and "PI_CORE='fast': expected one of auto, portable, v3" in p.stderr
    # the CLI names it too, with its usual error exit
    p = _run("fast", "from planet_intersect.cli import main; raise SystemExit(main(['config', '--core']))")
    assert p.returncode == 2 and "PI_CORE='fast'" in p.stderr
    p = _run("portable", "from planet_intersect.cli import main; raise SystemExit(main(['config', '--core']))")
    assert p.returncode == 0 and p.stdout.startswith("_core: PI_CORE=portable")


def test_core_info_matches_this_machine():
    info = pi.core_info()
    expect, _ = _ext.choose(os.environ.get("PI_CORE"), info["v3_built"], _ext.cpu_flags())
    assert info["module"] == expect


# ------------------------------------------------------------ same bits from both builds
def _v3_usable():
    if not _ext._v3_built():
        return False, "no _core_v3 in this installation (not x86_64, -Dcpu_dispatch=false or the checked build)"
    flags = _ext.cpu_flags()
    if flags is None:
        return False, "no /proc/cpuinfo: cannot tell whether this CPU runs x86-64-v3 code"
    miss = _ext.missing_v3(flags)
    if miss:
        return False, f"this CPU lacks x86-64-v3 features {', '.join(miss)}"
    return True, ""


_ok, _why = _v3_usable()
needs_v3 = pytest.mark.skipif(not _ok, reason=_why)


@contextmanager
def use_core(name):
    import importlib
    saved = _ext._chosen
    _ext._chosen = (importlib.import_module(f"planet_intersect.{name}"), name, "test")
    try:
        yield
    finally:
        _ext._chosen = saved


def both(fn):
    """fn() with each core: (portable result, v3 result)."""
    with use_core("_core"):
        a = fn()
    with use_core("_core_v3"):
        b = fn()
    return a, b


def assert_same_bits(a, b, name):
    """Every array of two results equal value for value (NaN where NaN), same dtype and shape."""
    if isinstance(a, np.ndarray):
        np.testing.assert_array_equal(a, b, err_msg=name, strict=True)
        return
    fa = {k: v for k, v in vars(a).items() if isinstance(v, np.ndarray)}
    fb = {k: v for k, v in vars(b).items() if isinstance(v, np.ndarray)}
    assert fa.keys() == fb.keys() and len(fa) >= 3, name
    for k in fa:
        np.testing.assert_array_equal(fa[k], fb[k], err_msg=f"{name}.{k}", strict=True)


def _planet_rays(n=3000, seed=5):
    rng = np.random.default_rng(seed)
    s = rng.normal(size=(n, 3))
    s *= (3390.0 + rng.uniform(200, 5000, n))[:, None] / np.linalg.norm(s, axis=1)[:, None]
    t = rng.normal(size=(n, 3))
    t *= (3390.0 + rng.uniform(-6, 6, n))[:, None] / np.linalg.norm(t, axis=1)[:, None]
    near = rng.uniform(size=n) < 0.8                  # most rays aimed near the sub-spacecraft point
    t[near] = s[near] / np.linalg.norm(s[near], axis=1)[:, None] * 3390.0 + rng.normal(0, 800, (near.sum(), 3))
    return s, t - s


@needs_v3
@pytest.mark.parametrize("method", ["stepping", "exact"])
def test_planetary_modes_same_bits(rough, method):
    s, l = _planet_rays()
    a, b = both(lambda: pi.intersect(rough, s, l, method=method, threads=2))
    assert_same_bits(a, b, method)
    assert np.sum(a.hit) > 1000 and np.sum(~a.hit) > 100   # hits and limb rays, not empty results


@needs_v3
def test_geodetic_conversions_same_bits():
    rng = np.random.default_rng(8)
    n = 20000
    p = rng.normal(size=(n, 3))
    p *= (6.4e6 + rng.uniform(-2e4, 2e6, n))[:, None] / np.linalg.norm(p, axis=1)[:, None]
    p[:50, :2] = rng.normal(0, 1e-3, (50, 2))               # on and near the polar axis
    for method in ("exact", "bowring"):
        a, b = both(lambda: pi.ecef_to_geodetic(p, method=method))
        for k, (x, y) in enumerate(zip(a, b)):
            assert_same_bits(x, y, f"{method}[{k}]")
    lat, lon, h = rng.uniform(-90, 90, n), rng.uniform(-180, 180, n), rng.uniform(-1e3, 1e6, n)
    a, b = both(lambda: pi.geodetic_to_ecef(lat, lon, h))
    assert_same_bits(a, b, "geodetic_to_ecef")


@pytest.fixture(scope="module")
def buildings():
    from planet_intersect import synthetic_dsm as sd
    grid = sd.building_scene(n=384, seed=2)
    grid.pop("roof_id")
    dsm = pi.GeodeticDSM.from_array(grid["heights"], grid["lat_first"], grid["lon_first"], grid["dlat"],
                                    grid["dlon"], a=grid["a"], f=grid["f"])
    s1, l1 = sd.pushbroom_rays(grid, 3000, seed=1)
    s2, l2 = sd.airborne_rays(grid, 2000, seed=2)
    return dsm, np.vstack([s1, s2]), np.vstack([l1, l2])


@needs_v3
@pytest.mark.parametrize("method", ["exact", "following", "iterative"])
def test_dsm_methods_same_bits(buildings, method):
    dsm, s, l = buildings
    a, b = both(lambda: pi.intersect(dsm, s, l, method=method, threads=2))
    assert_same_bits(a, b, method)
    assert np.sum(a.hit) > (1000 if method == "iterative" else 3000)   # the iterative one fails on walls


@needs_v3
def test_footprint_same_bits(rough):
    from planet_intersect.footprint import keplerian_states
    cells = pi.CellTable(rough, 1.0)
    R, v = keplerian_states(np.arange(0, 6000, 400.0), 3390 + 300, 3390 + 450, 93.1)
    a, b = both(lambda: pi.footprint(cells, R, v, zeta=0.3, threads=2))
    assert len(a) > 20000
    assert_same_bits(a, b, "footprint")


@needs_v3
def test_simulation_same_bits():
    from planet_intersect.sim_run import paper_experiment

    a, b = both(lambda: paper_experiment(size=128, methods=("exact",), threads=2)["sims"]["exact"])
    assert_same_bits(a, b, "simulation")
