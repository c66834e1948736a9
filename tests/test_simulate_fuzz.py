"""Property-based fuzzing of the image simulation (hypothesis): random small
DSMs (no-data, both interpolations, any heights), ortho-images on other grids
(partly off the DSM, no-data, 1 or 3 bands), sensors anywhere (above, inside,
looking up or sideways) and options. Every call either raises ValueError or
TypeError, or returns a result whose stated properties hold."""

from __future__ import annotations

import os
import warnings

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis", reason="fuzzing needs hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

import planet_intersect as pi  # noqa: E402

LAT0, LON0 = 10.0, 20.0
#: messages of errors from inside NumPy/f2py/Python that name no argument: never for the caller
INTERNAL = ("unexpected array size", "out of bounds", "object has no attribute", "NoneType", "could not broadcast",
            "zero-size array", "failed in converting")
D = 1e-5                                   # ~1 m cells


@st.composite
def cases(draw):
    nr, nc = draw(st.integers(2, 12)), draw(st.integers(2, 12))
    h = np.array(draw(st.lists(st.floats(-50, 300, allow_nan=False), min_size=nr * nc, max_size=nr * nc))).reshape(nr, nc)
    if draw(st.booleans()):
        h[draw(st.integers(0, nr - 1)), draw(st.integers(0, nc - 1))] = np.nan
    interp = draw(st.sampled_from(["nearest", "bilinear"]))
    bands = draw(st.sampled_from([1, 3]))
    onr, onc = draw(st.integers(2, 10)), draw(st.integers(2, 10))
    vals = np.array(draw(st.lists(st.floats(0, 255), min_size=onr * onc * bands, max_size=onr * onc * bands)))
    vals = vals.reshape(onr, onc) if bands == 1 else vals.reshape(onr, onc, bands)
    if draw(st.booleans()):
        vals.flat[0] = np.nan
    off = draw(st.floats(-5, 5)), draw(st.floats(-5, 5))
    scale = draw(st.sampled_from([0.5, 1.0, 2.0]))
    nl, npx = draw(st.integers(1, 4)), draw(st.integers(1, 5))
    kind = draw(st.sampled_from(["above", "high", "inside", "up", "sideways", "random"]))
    tgt_lat = LAT0 - D * np.array(draw(st.lists(st.floats(-3, nr + 3), min_size=nl * npx, max_size=nl * npx)))
    tgt_lon = LON0 + D * np.array(draw(st.lists(st.floats(-3, nc + 3), min_size=nl * npx, max_size=nl * npx)))
    alt = {"above": 2000.0, "high": 7e5, "inside": -100.0, "up": 1000.0, "sideways": 150.0,
           "random": draw(st.floats(-500, 1e6))}[kind]
    s_lat = LAT0 - D * nr / 2 + draw(st.floats(-0.01, 0.01))
    s_lon = LON0 + D * nc / 2 + draw(st.floats(-0.01, 0.01))
    s = pi.geodetic_to_ecef(s_lat, s_lon, alt)
    tgt = pi.geodetic_to_ecef(tgt_lat, tgt_lon, 0.0)
    l = tgt - s
    if kind == "up":
        l = -l
    if kind == "sideways":
        l = l - np.einsum("ij,j->i", l, s / np.linalg.norm(s))[:, None] * (s / np.linalg.norm(s))
    l = np.where(np.linalg.norm(l, axis=1, keepdims=True) > 0, l, 1.0)
    opts = draw(st.fixed_dictionaries({}, optional={
        "method": st.sampled_from(["exact", "following", "iterative", "bogus"]),
        "walls": st.sampled_from(["interpolate", "ortho"]),
        "shading": st.sampled_from(["none", "lambert"]),
        "sun": st.one_of(st.tuples(st.floats(-720, 720), st.floats(-100, 100)),
                         st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1))),
        "ambient": st.floats(-0.5, 1.5), "fill": st.floats(-1e3, 1e3),
        "occlusion": st.booleans(), "block_lines": st.integers(-1, 5), "threads": st.integers(-1, 3),
        "wall_slope": st.floats(-10, 100), "roof_min": st.floats(-5, 50)}))
    frame = draw(st.booleans())
    return dict(h=h, interp=interp, vals=vals, off=off, scale=scale, nl=nl, npx=npx, s=s, l=l.reshape(nl, npx, 3),
                opts=opts, frame=frame)


@settings(max_examples=max(10, int(150 * float(os.environ.get("PI_FUZZ_SCALE", "1")))), deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(cases())
def test_simulate_never_misleads(case):
    dsm = pi.GeodeticDSM.from_array(case["h"], LAT0, LON0, -D, D, interpolation=case["interp"])
    ortho = pi.OrthoImage.from_array(case["vals"], LAT0 + case["off"][0] * D, LON0 + case["off"][1] * D,
                                     -D * case["scale"], D * case["scale"])
    sensor = (pi.FrameCamera(case["s"], case["l"]) if case["frame"]
              else pi.Pushbroom(np.repeat(case["s"][None], case["nl"], axis=0), case["l"]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            sim = pi.simulate_image(dsm, ortho, sensor, **case["opts"])
        except (ValueError, TypeError) as exc:
            msg = str(exc)
            assert msg, "an exception without a message"
            assert not any(m in msg for m in INTERNAL), f"an internal error reached the caller: {msg}"
            return
    fill = case["opts"].get("fill", 0.0)
    shape = (case["nl"], case["npx"])
    assert sim.valid.shape == shape and sim.surface.shape == shape
    assert np.isin(sim.surface, (-1, 0, 1, 2)).all()
    assert ((sim.surface == -1) == ~sim.valid).all()
    assert np.isfinite(sim.lat[sim.valid]).all() and np.isnan(sim.lat[~sim.valid]).all()
    img = sim.image if sim.image.ndim == 2 else sim.image.reshape(shape + (-1,))
    assert np.isfinite(img).all()
    assert (img[~sim.valid] == np.float32(fill)).all()
    assert ((sim.status == pi.DSMStatus.HIT) | (sim.status == pi.DSMStatus.HIT_UNCONVERGED) == sim.valid).all()
    ok = sim.valid
    assert (sim.incidence[ok] >= 0).all() and (sim.incidence[ok] <= 180).all()
    assert (sim.local_incidence[ok] >= 0).all() and (sim.local_incidence[ok] <= 180).all()
    if sim.occlusion is not None:
        assert sim.occlusion.shape == ortho.shape and not (sim.occlusion & ~sim.footprint).any()


def test_dsm_height_of_no_points():
    """Found by this fuzzer: GeodeticDSM.height of zero points raised an f2py
    size error (an occlusion pass with no footprint pixel over data)."""
    dsm = pi.GeodeticDSM.from_array(np.zeros((2, 2)), LAT0, LON0, -D, D)
    assert dsm.height(np.zeros(0), np.zeros(0)).shape == (0,)
    assert dsm.height(np.zeros((0, 3)), np.zeros((0, 3))).shape == (0, 3)
