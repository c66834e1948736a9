"""State vectors from SPICE kernels (issue 13, section 5), offline.

The test writes its own kernels: a type-5 SPK of a synthetic Odyssey-like
Keplerian orbit (J2000, centre Mars), a text PCK with Mars' IAU rotation and
radii, and a leapseconds kernel. Expectations: the two-body orbit itself
(energy, the same Kepler solution) and the IAU rotation written out here.
"""

import math
import sys

import numpy as np
import pytest

import planet_intersect.footprint  # noqa: F401

sp = pytest.importorskip("spiceypy", reason="spiceypy (NAIF SPICE) reads the kernels")
from planet_intersect.spice_states import state_vectors  # noqa: E402

F = sys.modules["planet_intersect.footprint"]

LEAPS = [(10, "1972-JAN-1"), (11, "1972-JUL-1"), (12, "1973-JAN-1"), (13, "1974-JAN-1"), (14, "1975-JAN-1"),
         (15, "1976-JAN-1"), (16, "1977-JAN-1"), (17, "1978-JAN-1"), (18, "1979-JAN-1"), (19, "1980-JAN-1"),
         (20, "1981-JUL-1"), (21, "1982-JUL-1"), (22, "1983-JUL-1"), (23, "1985-JUL-1"), (24, "1988-JAN-1"),
         (25, "1990-JAN-1"), (26, "1991-JAN-1"), (27, "1992-JUL-1"), (28, "1993-JUL-1"), (29, "1994-JUL-1"),
         (30, "1996-JAN-1"), (31, "1997-JUL-1"), (32, "1999-JAN-1"), (33, "2006-JAN-1"), (34, "2009-JAN-1"),
         (35, "2012-JUL-1"), (36, "2015-JUL-1"), (37, "2017-JAN-1")]
PM = (176.630, 350.89198226)
RA = (317.68143, -0.1061)
DEC = (52.88650, -0.0609)
ET0 = 73_000_000.0              # 2002-04-25, the start of Odyssey's mapping
RP, RA_ORB = 3396.19 + 387.0, 3396.19 + 450.0


@pytest.fixture(scope="module")
def kernels(tmp_path_factory):
    d = tmp_path_factory.mktemp("spice")
    lsk = d / "test.tls"
    pairs = "\n".join(f"    {n}, @{date}" for n, date in LEAPS)
    lsk.write_text("KPL/LSK\n\\begindata\nDELTET/DELTA_T_A = 32.184\nDELTET/K = 1.657D-3\nDELTET/EB = 1.671D-2\n"
                   f"DELTET/M = ( 6.239996D0 1.99096871D-7 )\nDELTET/DELTA_AT = (\n{pairs} )\n\\begintext\n")
    pck = d / "mars.tpc"
    pck.write_text("KPL/PCK\n\\begindata\nBODY499_RADII = ( 3396.19 3396.19 3376.20 )\n"
                   f"BODY499_POLE_RA = ( {RA[0]} {RA[1]} 0. )\nBODY499_POLE_DEC = ( {DEC[0]} {DEC[1]} 0. )\n"
                   f"BODY499_PM = ( {PM[0]} {PM[1]} 0. )\n\\begintext\n")
    spk = d / "odyssey_synthetic.bsp"
    epochs = ET0 + np.arange(0, 4 * 3600 + 1, 300.0)
    R, v = F.keplerian_states(epochs - ET0, RP, RA_ORB, 93.1, node_deg=30.0, argp_deg=60.0, rotation_rate=0.0)
    handle = sp.spkopn(str(spk), "synthetic odyssey", 0)
    sp.spkw05(handle, -53, 499, "J2000", epochs[0], epochs[-1], "keplerian", F.MARS_GM, len(epochs),
              np.hstack([R, v]), epochs)
    sp.spkcls(handle)
    return [str(spk), str(pck), str(lsk)]


def _iau_mars(et):
    """J2000 -> IAU_MARS rotation from the PCK constants (passive: R3(W) R1(90 - dec) R3(90 + ra))."""
    d = et / 86400.0
    T = d / 36525.0
    w = math.radians(PM[0] + PM[1] * d)
    a = math.radians(RA[0] + RA[1] * T)
    dec = math.radians(DEC[0] + DEC[1] * T)

    def r1(t):
        c, s = math.cos(t), math.sin(t)
        return np.array([[1, 0, 0], [0, c, s], [0, -s, c]])

    def r3(t):
        c, s = math.cos(t), math.sin(t)
        return np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]])

    return r3(w) @ r1(math.pi / 2 - dec) @ r3(math.pi / 2 + a)


def test_states_in_j2000_follow_the_two_body_orbit(kernels):
    t = np.array([100.0, 1234.5, 5000.0, 9999.0])
    R, v, et = state_vectors(ET0 + t, kernels=kernels, frame="J2000")
    Rk, vk = F.keplerian_states(t, RP, RA_ORB, 93.1, node_deg=30.0, argp_deg=60.0, rotation_rate=0.0)
    assert np.max(np.linalg.norm(R - Rk, axis=1)) < 1e-6           # km
    assert np.max(np.linalg.norm(v - vk, axis=1)) < 1e-9           # km/s
    assert np.array_equal(et, ET0 + t)
    assert not sp.ktotal("ALL")                                     # the kernels were unloaded


def test_states_in_iau_mars_and_from_utc(kernels):
    t = np.array([600.0, 7000.0])
    R, v, et = state_vectors(ET0 + t, kernels=kernels)               # default frame IAU_MARS, observer MARS
    Rj, vj, _ = state_vectors(ET0 + t, kernels=kernels, frame="J2000")
    omega = math.radians(PM[1]) / 86400.0
    for k in range(len(t)):
        M = _iau_mars(et[k])
        assert np.max(np.abs(R[k] - M @ Rj[k])) < 1e-8
        vb = M @ vj[k] - np.cross([0, 0, omega], M @ Rj[k])
        assert np.max(np.abs(v[k] - vb)) < 1e-8
    # altitude above the 3396.19 km sphere stays within the orbit's 387-450 km
    alt = np.linalg.norm(R, axis=1) - 3396.19
    assert np.all((alt > 386.9) & (alt < 450.1))
    # UTC strings give the same states as their ET (TDB - UTC = 32 + 32.184 s +- 1.7 ms in 2002)
    sp.furnsh(kernels[2])
    try:
        utc = [sp.et2utc(e, "ISOC", 6) for e in et]
        delta = [sp.deltet(e, "ET") for e in et]
    finally:
        sp.unload(kernels[2])
    assert np.allclose(delta, 64.184, atol=2e-3)
    R2, v2, et2 = state_vectors(utc, kernels=kernels)
    assert np.max(np.abs(et2 - et)) < 1e-5
    assert np.max(np.abs(R2 - R)) < 1e-4


def test_state_vector_errors(kernels, tmp_path):
    with pytest.raises(FileNotFoundError, match="no such file"):
        state_vectors([ET0], kernels=[tmp_path / "missing.bsp"])
    with pytest.raises(ValueError, match="abcorr"):
        state_vectors([ET0], kernels=kernels, abcorr="SOMETIMES")
    with pytest.raises(ValueError, match=r"times\[0\]"):
        state_vectors(["not a time"], kernels=kernels)
    with pytest.raises(ValueError, match="spkezr"):
        state_vectors([ET0 - 1e6], kernels=kernels)                   # no SPK data then
    with pytest.raises(ValueError, match=r"times\[1\]"):
        state_vectors([ET0, float("nan")], kernels=kernels)
    assert not sp.ktotal("ALL")


def test_footprint_cli_from_spice_kernels(kernels, tmp_path):
    """The CLI's --kernels/--times path gives the footprint of the SPICE states."""
    import planet_intersect as pi
    from planet_intersect.cli import main

    hdr = pi.DEM.from_array(np.full((180, 360), 3390.0)).write(tmp_path / "sphere")
    times = tmp_path / "times.txt"
    times.write_text(f"# ET seconds\n{ET0 + 100.0!r}\n{ET0 + 700.0!r}\n")
    out = tmp_path / "out"
    assert main(["footprint", "--kernels", *kernels, "--times", str(times), "--dem", str(hdr), "--cell-deg", "1",
                 "--zeta", "0.9", "--out", str(out)]) == 0
    table = np.genfromtxt(out / "run-001" / "footprint.csv", delimiter=",", names=True)
    R, v, _ = state_vectors([ET0 + 100.0, ET0 + 700.0], kernels=kernels)
    fp = pi.footprint(pi.CellTable(pi.DEM.read(hdr), 1.0), R, v, zeta=0.9)
    assert len(table) == len(fp) > 0
    assert np.allclose(table["nadir_angle"], fp.nadir_angle, atol=1e-9)
    assert not sp.ktotal("ALL")
