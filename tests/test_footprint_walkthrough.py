"""Faults a newcomer's walk-through of the footprint system found (docs/grs-notes.md, notes 5,
19 and 20): km defaults applied to a DEM in metres, messages showing values the user never
passed or ranges that disagree, Hardie's air mass past its peak, ``==`` on results crashing, a
due-north position angle of 359.99999999999994, and to_xarray without per-variable units.

The snippets are the walk-through's: a sphere of 3396.19 (km, and the same in metres), 0.5 deg
cells, a spacecraft 400 km above (0 N, 0 E) moving north.
"""

from __future__ import annotations

import importlib
import math
import re

import numpy as np
import pytest

import planet_intersect as pi

F = importlib.import_module("planet_intersect.footprint")     # (pi.footprint is the function)

RE = 3396.19
R0 = np.array([3796.19, 0.0, 0.0])
V0 = [0.0, 0.0, 3.4]


@pytest.fixture(scope="module")
def km():
    return pi.CellTable(pi.DEM.from_array(np.full((720, 1440), RE), f=0, re=RE), 0.5)


@pytest.fixture(scope="module")
def metres():
    return pi.CellTable(pi.DEM.from_array(np.full((720, 1440), RE * 1e3), re=RE * 1e3), 0.5)


def _hardie(z):
    s = 1.0 / np.cos(np.radians(z)) - 1.0
    return s + 1.0 - 0.0018167 * s - 0.002875 * s ** 2 - 0.0008083 * s ** 3


# ---------------------------------------------------------------------------- finding 1: units
def test_metres_dem_refuses_the_km_defaults(metres):
    """A DEM in metres got the km defaults of area (3.4e-9 km^2) and H (10.8 km) without a word:
    solid angles 1e6 too small, air masses up to 612 [note 19]."""
    Rm = R0 * 1e3
    with pytest.raises(ValueError, match=r"^area and H: the DEM's largest cell radius reaches 3\.39619e\+06") as e:
        pi.footprint(metres, Rm, V0)
    assert "area=3.4e-3" in str(e.value) and "H=10807" in str(e.value) and "note 19" in str(e.value)
    with pytest.raises(ValueError, match=r"^H: .*airmass_model=None"):
        pi.footprint(metres, Rm, V0, area=3.4e-3)
    with pytest.raises(ValueError, match=r"^area: "):
        pi.footprint(metres, Rm, V0, H=1.08e4)
    with pytest.raises(ValueError, match=r"^area: "):
        pi.footprint(metres, Rm, V0, airmass_model=None)
    # explicit values are taken as given (3.4e-9 too: the user's word), and models without H need none
    for model in (None, "secant", "hardie", "notes"):
        assert len(pi.footprint(metres, Rm, V0, area=3.4e-3, airmass_model=model)) == 8928
    assert len(pi.footprint(metres, Rm, V0, area=3.4e-9, H=1.08e4)) == 8928
    # the km DEM keeps its defaults
    assert len(pi.footprint(pi.CellTable(pi.DEM.from_array(np.full((720, 1440), RE), re=RE), 0.5), R0, V0)) == 8928


def test_metres_dem_with_metre_values_equals_the_km_dem(km, metres):
    """The same scene in metres with area and H in metres: the km DEM's solid angles and air
    masses to 1e-12 relative (measured 2.8e-15 and 1.1e-14)."""
    R = np.array([[3796.19, 0.0, 0.0], [0.0, 2500.0, 2900.0], [1000.0, -3000.0, 2000.0]])
    a = pi.footprint(km, R, V0)
    b = pi.footprint(metres, R * 1e3, V0, area=F.ODYSSEY_AREA_KM2 * 1e6, H=pi.scale_height() * 1e3)
    assert np.array_equal(a.spectrum, b.spectrum) and np.array_equal(a.cell, b.cell)
    np.testing.assert_allclose(b.solid_angle, a.solid_angle, rtol=1e-12, atol=0)
    np.testing.assert_allclose(b.airmass, a.airmass, rtol=1e-12, atol=0)
    np.testing.assert_allclose(b.distance, a.distance * 1e3, rtol=1e-12, atol=0)
    assert np.isfinite(a.airmass).all() and np.max(a.airmass) < 23            # not 612
    # (not "secant": sec z at 89.96 deg turns the zenith angles' rounding, 1e-15 rad, into 5e-12)
    np.testing.assert_allclose(pi.footprint(metres, R * 1e3, V0, area=3.4e-3, airmass_model="hardie").airmass,
                               pi.footprint(km, R, V0, airmass_model="hardie").airmass, rtol=1e-12, atol=0)


def test_airmass_scale_height_and_orbit_study_km_defaults(metres):
    z = np.array([0.0, 60.0, 89.0])
    with pytest.raises(ValueError, match=r"^H: R reaches 3\.3895e\+06, too large to be kilometres"):
        pi.airmass(z, R=3389.5e3)
    np.testing.assert_allclose(pi.airmass(z, R=3389.5e3, H=pi.scale_height() * 1e3), pi.airmass(z),
                               rtol=1e-12, atol=0)
    assert np.isfinite(pi.airmass(z, R=3389.5e3, model="secant")).all()      # H not used
    with pytest.raises(ValueError, match=r"^r = 3\.3895e\+06 is too large to be kilometres of Mars"):
        pi.scale_height(r=3389.5e3)
    assert math.isfinite(pi.scale_height(r=3389.5e3, GM=4.28e4))              # explicit: as given
    with pytest.raises(ValueError, match=r"^cells: the DEM's largest cell radius is 3\.39619e\+06"):
        F.orbit_study(metres, n=3)


# ---------------------------------------------------------------------------- finding 2: v message
def test_radial_velocity_message_shows_the_values_given(km):
    """It showed v[0] = [0.85 0. 0.], the internal power-of-two rescaling of [3.4, 0, 0]."""
    msg = "v[0] = [3.4, 0.0, 0.0] has no component perpendicular to R[0] = [3796.19, 0.0, 0.0]"
    with pytest.raises(ValueError, match=re.escape(msg)):
        pi.footprint(km, R0, [3.4, 0, 0])
    with pytest.raises(ValueError, match=re.escape(msg)):
        F.spacecraft_frame(R0, [3.4, 0, 0])
    with pytest.raises(ValueError, match=re.escape("v[1] = [-7.0, 0.0, 0.0] has no component perpendicular "
                                                   "to R[1] = [3796.19, 0.0, 0.0]")):
        pi.footprint(km, [R0, R0], [[0, 1.0, 0], [-7.0, 0, 0]])


# ---------------------------------------------------------------------------- finding 3: z range
@pytest.mark.parametrize("z, got", [(-10, "-10.0"), (181, "181.0"), (np.nan, "nan"), (np.inf, "inf"),
                                    ([10.0, 200.0], "200.0 at flat index 1")])
def test_airmass_zenith_range_message_agrees_with_what_is_accepted(z, got):
    """-10 said [0, 180], 181 and NaN said [-180, 180]; [0, 180] is what is accepted."""
    with pytest.raises(ValueError, match=re.escape(f"z_deg: angles must be finite and within [0, 180] "
                                                   f"degrees, got {got}")):
        pi.airmass(z)
    assert np.isfinite(pi.airmass([0.0, 180.0])).all()


# ---------------------------------------------------------------------------- finding 4: Hardie
def test_hardie_is_nan_beyond_its_peak(km):
    """Hardie's cubic in s = sec z - 1 peaks where 0.9981833 - 0.00575 s - 0.0024249 s^2 = 0:
    z = 87.1536556 deg, X = 13.3844128; beyond it the formula fell to -2.5e7 [note 20]."""
    zp, xp = F.HARDIE_PEAK_DEG, F.HARDIE_PEAK_AIRMASS
    assert zp == pytest.approx(87.1536556, abs=1e-7) and xp == pytest.approx(13.3844128, abs=1e-7)
    s = 1.0 / math.cos(math.radians(zp)) - 1.0
    assert abs(0.9981833 - 0.00575 * s - 0.0024249 * s * s) < 1e-12          # dX/ds = 0 there
    assert _hardie(zp - 1e-3) < xp and _hardie(zp + 1e-3) < xp
    # below the peak: the formula, unchanged (bit for bit with the same arithmetic)
    z = np.concatenate([np.linspace(0.0, zp - 1e-9, 2001), [85.0, 87.0, 87.15]])
    got = pi.airmass(z, model="hardie")
    np.testing.assert_allclose(got, _hardie(z), rtol=1e-15, atol=0)
    assert np.all(np.diff(got[:2001]) > 0) and got[2000] == pytest.approx(xp, abs=1e-9)
    # beyond it (and at and beyond 90 deg as before): NaN
    assert np.isnan(pi.airmass([zp + 1e-9, 87.2, 88.0, 89.98, 90.0, 120.0], model="hardie")).all()
    # in the footprint result: NaN exactly beyond the peak, the formula below, never below 1
    fp = pi.footprint(km, R0, V0, airmass_model="hardie")
    zc = fp.zenith_centric
    assert zc.max() > 89.9 and (zc < zp).sum() == 7200
    beyond = zc > zp
    assert np.isnan(fp.airmass[beyond]).all() and beyond.sum() > 0
    np.testing.assert_allclose(fp.airmass[~beyond], _hardie(zc[~beyond]), rtol=1e-15, atol=0)
    assert fp.airmass[~beyond].min() >= 1.0 and fp.airmass[~beyond].max() <= xp


# ---------------------------------------------------------------------------- finding 5: ==
def test_footprint_results_compare_with_eq(km):
    """a == b raised "the truth value of an array ... is ambiguous" (the dataclass's tuple ==)."""
    a = pi.footprint(km, R0, V0)
    b = pi.footprint(km, R0, V0)
    assert (a == b) is True and (a != b) is False and a == a
    assert a == pi.footprint(pi.CellTable(km.dem, 0.5), R0, V0)                # another table, same DEM
    assert a == a.subset(np.ones(len(a), bool))
    assert pi.footprint(km, R0) == pi.footprint(km, R0)                         # NaN azimuths equal
    assert (a == pi.footprint(km, R0 * 1.001, V0)) is False
    assert (a == pi.footprint(km, R0, V0, zeta=0.5)) is False
    assert (a == pi.footprint(km, R0, V0, airmass_model="secant")) is False
    assert (a == pi.footprint(km, R0, V0, area=1.0)) is False
    assert (a == 3) is False and a != "x"
    with pytest.raises(TypeError):
        hash(a)


# ---------------------------------------------------------------------------- finding 6: PA 360
def test_due_north_position_angle_is_zero(km):
    """A spacecraft over the cell at (0.25 N, 10.25 E) saw the cell at (2.25 N, 10.25 E) at
    359.99999999999994 deg; the documented range is [0, 360)."""
    k, kk = int(km.index(0.25, 10.25)), int(km.index(2.25, 10.25))
    R = km.u[k] * 3796.19
    fp = pi.footprint(km, R, V0)
    pa = fp.position_angle[fp.cell == kk]
    assert pa.tolist() == [0.0]
    assert F.position_angle(R, km.r[kk]).tolist() == [0.0]
    for a in (fp.position_angle, fp.azimuth):
        a = a[np.isfinite(a)]
        assert np.all((a >= 0) & (a < 360.0 - 4 * 2.0 ** -44))
    # only the last four ulp below 360 move: the next representable values stay
    x = np.array([360.0 - 5 * 2.0 ** -44, 360.0 - 4 * 2.0 ** -44, 360.0 - 2.0 ** -44, np.nan, 1e-14])
    F._snap_360(x)
    assert x[0] == 360.0 - 5 * 2.0 ** -44 and x[1] == 0.0 and x[2] == 0.0 and np.isnan(x[3]) and x[4] == 1e-14


# ---------------------------------------------------------------------------- finding 7: units
@pytest.mark.parametrize("layout", ["pairs", "dense"])
def test_to_xarray_has_units_and_long_names(km, layout):
    pytest.importorskip("xarray")
    fp = pi.footprint(km, R0, V0)
    ds = fp.to_xarray(layout)
    want = {"solid_angle": "sr", "emission": "degree", "position_angle": "degree", "azimuth": "degree",
            "elevation": "degree", "nadir_angle": "degree", "zenith_centric": "degree", "zenith_detic": "degree",
            "airmass": "1", "zeta": "1", "distance": "DEM length unit", "gsh": "DEM length unit",
            "lat": "degrees_north", "lon": "degrees_east"}
    if layout == "pairs":
        want["d"] = "DEM length unit"
    for name, units in want.items():
        assert ds[name].attrs["units"] == units, name
    for name in ds.variables:
        assert ds[name].attrs.get("long_name"), name
    # (a flag: "1" since the third review found it, and the index coordinates, without any units)
    assert ds["visible"].attrs["units"] == "1" and "chapman" in ds["airmass"].attrs["long_name"]
    dk = fp.to_xarray(layout, length_unit="km")
    assert dk["distance"].attrs["units"] == "km" and dk["gsh"].attrs["units"] == "km"
    assert dk["solid_angle"].attrs["units"] == "sr"
    with pytest.raises(TypeError, match="length_unit"):
        fp.to_xarray(layout, length_unit=1000)
