"""PDS3 grids with labels (planet_intersect.pds): the real LOLA LDEM_4 and made-up products.

Expectations: the LOLA figures are those of ../shared/data/moon_lola_ldem_4/
PROVENANCE.md (extremes and their cells, mean radii), and its values are read
here a second time straight from the bytes the way that document describes
them (`<i2`, north row first, DN x 0.5 + 1,737,400 m), without the label. The
made-up products are built from arrays the tests choose, encoded as their
labels say; the DEM must give the arrays back. Rays on the Moon are checked
against NAIF SPICE on a DSK written from the same grid (tests/test_spice.py's
cross-check) and nadir rays against the cell radii.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import planet_intersect as pi
from planet_intersect.cli import main
from planet_intersect.pds import PDSError, import_pds, pds_dem, read_pds3_label

from conftest import mixed_rays, shared_data_or_skip

LOLA = ("moon_lola_ldem_4", "LDEM_4.LBL")


@pytest.fixture(scope="module")
def lola_label():
    return shared_data_or_skip(*LOLA)


@pytest.fixture(scope="module")
def lola(lola_label):
    return pds_dem(lola_label)


def _raw_lola(label):
    """Radii in km, row 0 SOUTH, from the bytes as PROVENANCE.md describes them."""
    dn = np.fromfile(label.with_name("LDEM_4.IMG"), dtype="<i2").reshape(720, 1440)
    return (dn[::-1].astype(np.float64) * 0.5 + 1737400.0) / 1000.0


def test_lola_label_and_grid_as_its_provenance_says(lola, lola_label):
    tree = read_pds3_label(lola_label)
    assert tree["PRODUCT_ID"] == "LDEM_4" and tree["TARGET_NAME"] == "MOON"
    img = tree["OBJECT:UNCOMPRESSED_FILE"]["OBJECT:IMAGE"]
    assert img["SCALING_FACTOR"] == 0.5 and img["OFFSET"] == 1737400.0 and img["SAMPLE_TYPE"] == "LSB_INTEGER"
    assert tree["OBJECT:IMAGE_MAP_PROJECTION"]["MAP_RESOLUTION"] == (4, "pix/deg")
    assert lola.ppd == 4 and lola.re == 1737.4 and lola.f == 0.0
    r = np.asarray(lola.radii, dtype=np.float64)
    np.testing.assert_allclose(r, _raw_lola(lola_label), rtol=0, atol=1.3e-4)   # float32 km: 0.12 m
    # PROVENANCE.md: the extremes and their cells, the Mare Imbrium and SPA cells, the mean radii
    assert lola.radius(5.375, 201.375) == pytest.approx(1737.4 + 10.504, abs=1e-4)
    assert lola.radius(-70.375, 187.625) == pytest.approx(1737.4 - 8.8785, abs=1e-4)
    assert r.max() == pytest.approx(1737.4 + 10.504, abs=1e-4)
    assert r.min() == pytest.approx(1737.4 - 8.8785, abs=1e-4)
    w = np.cos(np.radians((np.arange(720) + 0.5) / 4 - 90))[:, None] * np.ones((1, 1440))
    assert (r * w).sum() / w.sum() * 1000 == pytest.approx(1737151.7, abs=0.1)
    assert r.mean() * 1000 == pytest.approx(1736880.3, abs=0.1)
    near = [lola.radius(la, lo) for la in (-53.125, -52.875) for lo in (190.875, 191.125)]
    assert min(abs(v - (1737.4 - 7.2505)) for v in near) < 1e-4                 # "near 53S 191E: -7,250.5 m"


def test_lola_nadir_rays_hit_the_cell_radii(lola, lola_label):
    rng = np.random.default_rng(5)
    i, j = rng.integers(4, 716, 400), rng.integers(0, 1440, 400)
    lat, lon = (i + 0.5) / 4 - 90, (j + 0.5) / 4
    up = np.stack([np.cos(np.radians(lat)) * np.cos(np.radians(lon)),
                   np.cos(np.radians(lat)) * np.sin(np.radians(lon)), np.sin(np.radians(lat))], axis=1)
    expect = _raw_lola(lola_label)[i, j]
    for method in ("stepping", "exact"):
        res = pi.intersect(lola, up * 1900.0, -up, method=method)
        assert res.hit.all(), method
        got = np.linalg.norm(res.p, axis=1)
        assert np.max(np.abs(got - expect)) < 2e-4, method      # the float32 radii (0.12 m) + the tolerance


def test_lola_against_spice(tmp_path, lola):
    pytest.importorskip("spiceypy", reason="spiceypy (NAIF SPICE) is the independent reference here")
    from test_spice import cross_check

    s, l, _ = mixed_rays(lola, 8000, seed=12)
    figures = cross_check(lola, s, l, tmp_path / "moon.bds")
    assert figures["both_hit"] > 3000
    print("\nSPICE agreement, LOLA LDEM_4:", figures)


def test_exact_first_hits_are_never_after_the_paper_steps_on_the_moon(lola):
    s, l, _ = mixed_rays(lola, 8000, seed=13)
    st_, ex = pi.intersect(lola, s, l), pi.intersect(lola, s, l, method="exact")
    both = st_.hit & ex.hit
    assert both.sum() > 3000
    dist = {k: np.einsum("ij,ij->i", r.p[both] - s[both], l[both]) for k, r in (("st", st_), ("ex", ex))}
    assert np.all(dist["ex"] <= dist["st"] + 1e-6)
    assert not np.any(st_.hit & ~ex.hit)                     # a stepping hit is a surface point: exact has one


def test_import_pds_command(tmp_path, lola_label, capsys):
    out = tmp_path / "moon"
    assert main(["import-pds", str(lola_label), str(out)]) == 0
    d = pi.DEM.read(out.with_suffix(".hdr"))
    assert d.ppd == 4 and d.re == pytest.approx(1737.4) and d.radius(5.375, 201.375) == pytest.approx(1747.904, abs=1e-4)
    assert main(["import-pds", str(lola_label), str(out)]) == 2                  # nothing overwritten
    assert "--overwrite" in capsys.readouterr().err
    assert main(["import-pds", str(lola_label), str(out), "--overwrite"]) == 0


# ------------------------------------------------------------------ made-up products
LABEL = """PDS_VERSION_ID = PDS3
/* a made-up product of the kind the PDS holds */
RECORD_TYPE = FIXED_LENGTH
RECORD_BYTES = {record_bytes}
FILE_RECORDS = {records}
^IMAGE = {pointer}
OBJECT = IMAGE
  LINES = {lines}
  LINE_SAMPLES = {samples}
  SAMPLE_TYPE = {sample_type}
  SAMPLE_BITS = {bits}
  UNIT = {unit}
  SCALING_FACTOR = {scale}
  OFFSET = {offset}
  {extra}
END_OBJECT = IMAGE
OBJECT = IMAGE_MAP_PROJECTION
  MAP_PROJECTION_TYPE = "SIMPLE
     CYLINDRICAL"
  MAP_RESOLUTION = {res} <pix/deg>
  A_AXIS_RADIUS = {a} <km>
  B_AXIS_RADIUS = {a} <km>
  C_AXIS_RADIUS = {c} <km>
  POSITIVE_LONGITUDE_DIRECTION = "EAST"
  MAXIMUM_LATITUDE = 90 <deg>
  MINIMUM_LATITUDE = -90 <deg>
  WESTERNMOST_LONGITUDE = {west} <deg>
  EASTERNMOST_LONGITUDE = {east} <deg>
  LINE_PROJECTION_OFFSET = {lpo} <pix>
END_OBJECT = IMAGE_MAP_PROJECTION
END
"""


def make_product(tmp_path, radii_km_north_first, *, dtype="<i2", unit="METER", scale=0.5, offset=None, west=0,
                 attached=False, name="GRID", a=1000.0, c=None, extra="", height_ref=None, lpo=None):
    """Write a product whose decoded values are the given radii (km), north row first, column 0 at
    longitude ``west``; return the label's path."""
    lines, samples = radii_km_north_first.shape
    ppd = lines // 180
    per = 1.0 if unit.upper().startswith("K") else 1000.0
    value = radii_km_north_first * per - (height_ref or 0.0) * per
    if offset is None:
        offset = a * per if height_ref is None else 0.0
    dn = (value - offset) / scale
    dt = np.dtype(dtype)
    if dt.kind in "iu":
        dn = np.rint(dn)
    data = dn.astype(dt).tobytes()
    sample_type = {("<", "i"): "LSB_INTEGER", (">", "i"): "MSB_INTEGER", ("<", "f"): "PC_REAL",
                   (">", "f"): "IEEE_REAL", ("<", "u"): "LSB_UNSIGNED_INTEGER",
                   ("|", "i"): "MSB_INTEGER", ("|", "u"): "MSB_UNSIGNED_INTEGER"}[(dt.str[0], dt.kind)]
    record_bytes = samples * dt.itemsize
    fields = dict(record_bytes=record_bytes, records=lines, lines=lines, samples=samples, sample_type=sample_type,
                  bits=8 * dt.itemsize, unit=unit, scale=scale, offset=offset, extra=extra, res=ppd, a=a,
                  c=a if c is None else c, west=west, east=west + 360,
                  lpo=(90 - 0.5 / ppd) * ppd if lpo is None else lpo)
    if attached:
        # label records in front of the data: find a record count that holds the label
        for nrec in range(1, 1000):
            text = LABEL.format(pointer=nrec + 1, **fields)
            if len(text) <= nrec * record_bytes:
                break
        path = tmp_path / f"{name}.IMG"
        path.write_bytes(text.encode().ljust(nrec * record_bytes, b" ") + data)
        return path
    (tmp_path / f"{name.lower()}.img").write_bytes(data)               # lower case on disk, upper in the label
    path = tmp_path / f"{name}.LBL"
    path.write_text(LABEL.format(pointer=f'"{name}.IMG"', **fields))
    return path


def _surface(ppd=1, seed=0, base=1000.0):
    rng = np.random.default_rng(seed)
    lat = np.radians(90 - (np.arange(180 * ppd) + 0.5) / ppd)[:, None]
    lon = np.radians((np.arange(360 * ppd) + 0.5) / ppd)[None, :]
    smooth = np.rint(3.0 * np.sin(2 * lat) * np.cos(3 * lon) / 0.5e-3)      # 0.5 m steps, as LOLA's
    return base + (smooth + rng.integers(-200, 200, (180 * ppd, 360 * ppd))) * 0.5e-3


@pytest.mark.parametrize("kw", [
    dict(dtype="<i2"), dict(dtype=">i2"), dict(dtype="<f4", scale=1.0), dict(dtype=">f8", scale=1.0),
    dict(dtype=">i4", unit="KILOMETER", scale=1e-6), dict(dtype="<u2", offset=990_000.0),
    dict(dtype=">i2", attached=True), dict(dtype="<i2", c=990.0),
])
def test_made_up_products_give_their_arrays_back(tmp_path, kw):
    r = _surface()
    dem = pds_dem(make_product(tmp_path, r, **kw), dtype="float64")
    np.testing.assert_allclose(np.asarray(dem.radii), r[::-1], rtol=0, atol=1e-9)
    assert dem.re == 1000.0 and dem.f == pytest.approx(1 - kw.get("c", 1000.0) / 1000.0)


def test_a_grid_from_minus_180_is_rolled_to_start_at_0_east(tmp_path):
    r = _surface(ppd=2)                                  # column j is at (j + 0.5) / 2 E
    rolled = np.roll(r, 360, axis=1)                     # column 0 now at -180 E
    dem = pds_dem(make_product(tmp_path, rolled, west=-180), dtype="float64")
    np.testing.assert_allclose(np.asarray(dem.radii), r[::-1], rtol=0, atol=1e-9)
    assert dem.radius(10.25, 0.25) == pytest.approx(r[159, 0], abs=1e-9)


def test_heights_need_their_reference(tmp_path):
    r = _surface()
    path = make_product(tmp_path, r, height_ref=1000.0)              # OFFSET 0: heights above 1000 km
    with pytest.raises(PDSError, match="heights_above"):
        pds_dem(path)
    dem = pds_dem(path, heights_above=1000.0, dtype="float64")
    np.testing.assert_allclose(np.asarray(dem.radii), r[::-1], rtol=0, atol=1e-9)
    with pytest.raises(PDSError, match="heights_above"):
        pds_dem(path, heights_above=-1.0)


@pytest.mark.parametrize("change, match", [
    (dict(extra="MISSING_CONSTANT = -32768"), "missing/invalid constant"),
    (dict(extra="BANDS = 3"), "one band"),
    (dict(extra="LINE_PREFIX_BYTES = 4"), "LINE_PREFIX_BYTES"),
    (dict(unit="FURLONG"), "UNIT"),
    (dict(west=0.25), "pixel edge"),
    (dict(lpo=90.0), "node-registered"),
    (dict(c=1100.0), "oblate"),
])
def test_what_a_dem_cannot_hold_is_refused_by_name(tmp_path, change, match):
    r = _surface()
    if "MISSING" in change.get("extra", ""):
        kw = dict(offset=1000.0 * 1000 - 200.0 * 0.5)    # a DN of -32768 somewhere: make one
        path = make_product(tmp_path, r, **kw, **change)
        img = tmp_path / "grid.img"
        raw = bytearray(img.read_bytes())
        raw[0:2] = np.int16(-32768).tobytes()
        img.write_bytes(bytes(raw))
    else:
        path = make_product(tmp_path, r, **change)
    with pytest.raises(PDSError, match=match) as err:
        pds_dem(path)
    assert str(path) in str(err.value) or "grid.img" in str(err.value)


def test_broken_labels_and_files_are_refused_by_name(tmp_path):
    r = _surface()
    path = make_product(tmp_path, r)
    text = path.read_text()
    cases = {
        "no END": text.replace("\nEND\n", "\n"),
        "regional": text.replace("MINIMUM_LATITUDE = -90", "MINIMUM_LATITUDE = -60"),
        "resolution": text.replace("MAP_RESOLUTION = 1", "MAP_RESOLUTION = 2"),
        "west": text.replace('"EAST"', '"WEST"'),
        "sample type": text.replace("LSB_INTEGER", "VAX_REAL"),
        "projection": text.replace('"SIMPLE\n     CYLINDRICAL"', "POLAR_STEREOGRAPHIC"),
        "no image": text.replace("OBJECT = IMAGE\n", "OBJECT = TABLE\n").replace("END_OBJECT = IMAGE\n",
                                                                                 "END_OBJECT = TABLE\n"),
        "no projection": text.replace("OBJECT = IMAGE_MAP_PROJECTION", "OBJECT = MAP"),
        "unclosed": text.replace("END_OBJECT = IMAGE_MAP_PROJECTION\n", ""),
        "missing file": text.replace('"GRID.IMG"', '"NONE.IMG"'),
        "short file": text.replace("LINES = 180", "LINES = 360").replace("LINE_SAMPLES = 360",
                                                                         "LINE_SAMPLES = 720").replace(
            "MAP_RESOLUTION = 1", "MAP_RESOLUTION = 2").replace("OFFSET = 89.5", "OFFSET = 179.5"),
    }
    words = {"no END": "no END", "regional": "global", "resolution": "180 ppd", "west": "WEST",
             "sample type": "SAMPLE_TYPE", "projection": "MAP_PROJECTION_TYPE", "no image": "no IMAGE",
             "unclosed": "not closed", "missing file": "not beside it", "short file": "bytes",
             "no projection": "no IMAGE_MAP_PROJECTION"}
    for what, t in cases.items():
        p = tmp_path / f"case_{what.replace(' ', '_')}.LBL"
        p.write_text(t)
        with pytest.raises(PDSError, match=words[what]):
            pds_dem(p)
    with pytest.raises(PDSError, match="no such file"):
        pds_dem(tmp_path / "nothing.LBL")
    with pytest.raises(PDSError, match="not a regular file"):
        pds_dem(tmp_path)
    assert main(["import-pds", str(tmp_path / "case_regional.LBL"), str(tmp_path / "x")]) == 2
    assert not (tmp_path / "x.hdr").exists()


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_mangled_labels_give_a_dem_or_a_named_refusal(tmp_path_factory, data):
    tmp = tmp_path_factory.mktemp("pds")
    path = make_product(tmp, _surface())
    text = path.read_text()
    for _ in range(data.draw(st.integers(1, 4))):
        k = data.draw(st.integers(0, len(text)))
        op = data.draw(st.sampled_from(["del", "ins", "dup"]))
        if op == "del":
            text = text[:k] + text[k + data.draw(st.integers(1, 30)):]
        elif op == "ins":
            text = text[:k] + data.draw(st.sampled_from(['"', "'", "(", ")", "{", "}", "=", "<", ">", "/*", "*/",
                                                         "\n", "END\n", "OBJECT = X\n", "END_OBJECT\n", "1e999",
                                                         "nan", "-7", "0", "\x00", "é", "9" * 400, "(((((",
                                                         "<BYTES>", "^IMAGE = 3\n", "GROUP = G\n",
                                                         "END_GROUP = G\n", "16#FF#", "_", "inf"])) + text[k:]
        else:
            j = data.draw(st.integers(0, len(text)))
            text = text[:k] + text[min(j, k):max(j, k)] + text[k:]
    path.write_bytes(text.encode("utf-8", "replace"))
    try:
        dem = pds_dem(path)
    except (PDSError, pi.DEMError) as exc:
        assert str(exc)
    else:
        assert dem.ppd >= 1


def test_a_megdr_label_gives_what_the_mola_reader_gives(tmp_path):
    """The Mars radius grid of ../shared/data with a label in the MEGDR products' form (MSB_INTEGER,
    METER, OFFSET 3396000; line and sample offsets 1-based as the MOLA EGDR SIS's map projection
    description counts them, where LOLA's are 0-based): the PDS reader and planet_intersect.mola
    (which knows the layout without a label) must give the same radii."""
    from planet_intersect.mola import mola_dem

    src = shared_data_or_skip("mars_mola_megdr_4ppd", "mars_radius_4ppd_megt_plus_areoid.i2be")
    label = tmp_path / "MEGR.LBL"
    label.write_text(f"""PDS_VERSION_ID = PDS3
RECORD_TYPE = FIXED_LENGTH
RECORD_BYTES = 2880
FILE_RECORDS = 720
^IMAGE = "{src.resolve()}"
OBJECT = IMAGE
  LINES = 720
  LINE_SAMPLES = 1440
  SAMPLE_TYPE = MSB_INTEGER
  SAMPLE_BITS = 16
  UNIT = METER
  SCALING_FACTOR = 1
  OFFSET = 3396000
END_OBJECT = IMAGE
OBJECT = IMAGE_MAP_PROJECTION
  MAP_PROJECTION_TYPE = "SIMPLE CYLINDRICAL"
  A_AXIS_RADIUS = 3396.0 <KM>
  B_AXIS_RADIUS = 3396.0 <KM>
  C_AXIS_RADIUS = 3396.0 <KM>
  POSITIVE_LONGITUDE_DIRECTION = "EAST"
  MAP_RESOLUTION = 4 <PIXEL/DEGREE>
  MAXIMUM_LATITUDE = 90.0 <DEGREE>
  MINIMUM_LATITUDE = -90.0 <DEGREE>
  WESTERNMOST_LONGITUDE = 0.0 <DEGREE>
  EASTERNMOST_LONGITUDE = 360.0 <DEGREE>
  LINE_PROJECTION_OFFSET = 360.5 <PIXEL>
  SAMPLE_PROJECTION_OFFSET = 720.5 <PIXEL>
  CENTER_LONGITUDE = 180.0 <DEGREE>
END_OBJECT = IMAGE_MAP_PROJECTION
END
""")
    a, b = pds_dem(label), mola_dem(src)
    np.testing.assert_array_equal(np.asarray(a.radii), np.asarray(b.radii))
    assert a.re == 3396.0 and a.f == 0.0 and a.ppd == b.ppd == 4


# ------------------------------------------------------------------ a review's reproducers (2026-12-05)
def _with(tmp_path, text, name="case.LBL"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_review_faults_are_named_refusals(tmp_path):
    """Each of these raised another exception type, hung or was read wrong before the review."""
    r = _surface()
    base = make_product(tmp_path, r).read_text()
    extra = "  SCALING_FACTOR = 0.5\n"
    cases = {
        # a RecursionError: nesting was never counted
        "X = " + "(" * 2000 + "1" + ")" * 2000 + "\n" + base: "nested too deep",
        # an OverflowError: a 400-digit integer
        base.replace("OFFSET = 1000000.0", "OFFSET = " + "9" * 400): "not a usable number",
        # a ZeroDivisionError: ppd 0
        base.replace("LINES = 180", "LINES = 90").replace("LINE_SAMPLES = 360", "LINE_SAMPLES = 180")
            .replace("MAP_RESOLUTION = 1", "MAP_RESOLUTION = 0.5").replace("OFFSET = 89.5", "OFFSET = 44.5"):
            "whole ppd",
        # a comment left open swallowed SCALING_FACTOR (heights doubled, no error)
        base.replace("  UNIT = METER\n", "  UNIT = METER   /* unit of the values\n"): "not closed on its line",
        # east < west was taken as 360 degrees
        base.replace("WESTERNMOST_LONGITUDE = 0 ", "WESTERNMOST_LONGITUDE = 360 ")
            .replace("EASTERNMOST_LONGITUDE = 360 ", "EASTERNMOST_LONGITUDE = 0 "): "global grid",
        # SAMPLE_PROJECTION_OFFSET against CENTER_LONGITUDE was not checked
        base.replace("END_OBJECT = IMAGE_MAP_PROJECTION",
                     "  CENTER_LONGITUDE = 180\n  SAMPLE_PROJECTION_OFFSET = 89.5\nEND_OBJECT = IMAGE_MAP_PROJECTION"):
            "SAMPLE_PROJECTION_OFFSET",
        # a keyword twice: the last one won
        base.replace("  SCALING_FACTOR = 0.5\n", extra + "  SCALING_FACTOR = 0.25\n"): "given twice",
        # END_OBJECT = FOO closed IMAGE
        base.replace("END_OBJECT = IMAGE\n", "END_OBJECT = FOO\n"): "closes OBJECT = IMAGE",
        # a non-integer ppd that fits the file ended in DEM.from_array's message without the file
        base.replace("MAP_RESOLUTION = 1", "MAP_RESOLUTION = 1.5"): "whole ppd",
    }
    for k, (text, why) in enumerate(cases.items()):
        p = _with(tmp_path, text, f"c{k}.LBL")
        with pytest.raises(PDSError, match=why) as err:
            pds_dem(p)
        assert str(p) in str(err.value)


def test_linear_time_on_comment_openers(tmp_path):
    # 300,000 unclosed openers took ~14 minutes (quadratic); one line's check now refuses them at once
    base = make_product(tmp_path, _surface()).read_text()
    p = _with(tmp_path, base.replace("\n", "\n" + "/* " * 300_000 + "\n", 1))
    with pytest.raises(PDSError, match="not closed on its line"):
        pds_dem(p)


def test_missing_constants_in_every_form(tmp_path):
    r = _surface()
    for form, dtype, cell in [("16#FFFF#", "<u2", 0xFFFF), ("-32000 <METER>", "<i2", -32000), ("0.1", "<f4", 0.1),
                              ("-3.4028227E+38", "<f4", -3.4028227e38), ("16#FF7FFFFB#", ">f4", None)]:
        kw = dict(dtype=dtype, offset=990_000.0) if dtype == "<u2" else dict(dtype=dtype)
        if dtype[-2] == "f":
            kw["scale"] = 1.0
        path = make_product(tmp_path, r, extra=f"MISSING_CONSTANT = {form}", **kw)
        img = tmp_path / "grid.img"
        raw = bytearray(img.read_bytes())
        dt = np.dtype(dtype)
        raw[0:dt.itemsize] = (np.array(cell, dtype=dt).tobytes() if cell is not None
                              else np.array(0xFF7FFFFB, dtype=">u4").tobytes())
        img.write_bytes(bytes(raw))
        with pytest.raises(PDSError, match="missing/invalid constant") as err:
            pds_dem(path)
        assert "1 samples" in str(err.value) or "1 sample" in str(err.value), form


def test_heights_above_on_radii_and_too_small(tmp_path, lola_label):
    with pytest.raises(PDSError, match="added to a product of radii"):
        pds_dem(lola_label, heights_above=1737.4)
    r = _surface()
    path = make_product(tmp_path, r, height_ref=1000.0)
    with pytest.raises(PDSError, match="grid.img.*not the radius the heights are above"):
        pds_dem(path, heights_above=0.05)                      # radii 0.05 km +- heights: not a body
    # without A_AXIS_RADIUS there is nothing to compare: the DEM's own refusal, with the files named
    bare = _with(tmp_path, "\n".join(ln for ln in path.read_text().split("\n") if "AXIS_RADIUS" not in ln), "bare.LBL")
    with pytest.raises(PDSError, match=r"grid.img \(label .*bare.LBL\): radii: .*must be positive"):
        pds_dem(bare, heights_above=0.05)
    dem = pds_dem(path, heights_above=np.float32(1000.0), dtype="float64")   # NumPy numbers are numbers
    assert dem.radius(0.5, 0.5) == pytest.approx(r[89, 0], abs=1e-9)


def test_forms_the_review_found_refused_are_read(tmp_path):
    r = _surface()
    base = make_product(tmp_path, r).read_text()
    variants = {
        "a line END inside a quoted string": base.replace("PDS_VERSION_ID = PDS3",
                                                          'PDS_VERSION_ID = PDS3\nNOTE = "one\nEND\nthree"'),
        "RECORD_BYTES with its unit": base.replace("RECORD_BYTES = 720", "RECORD_BYTES = 720 <BYTES>"),
        "LINE_PREFIX_BYTES = 0 <bytes>": base.replace("  UNIT = METER", "  LINE_PREFIX_BYTES = 0 <bytes>\n  UNIT = METER"),
        "a unit after a sequence": base.replace("PDS_VERSION_ID = PDS3", "PDS_VERSION_ID = PDS3\nX = (1, 2) <km>"),
        "a comment after a value": base.replace("SCALING_FACTOR = 0.5", "SCALING_FACTOR = 0.5/* m per DN */"),
        "lower-case end": base.replace("\nEND\n", "\nend\n"),
    }
    for what, text in variants.items():
        dem = pds_dem(_with(tmp_path, text, "v.LBL"), dtype="float64")
        np.testing.assert_allclose(np.asarray(dem.radii), r[::-1], rtol=0, atol=1e-9, err_msg=what)


def test_unreadable_data_and_memory_are_named(tmp_path, monkeypatch):
    import planet_intersect.pds as pds_mod

    path = make_product(tmp_path, _surface())

    def no_read(*a, **k):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(pds_mod.np, "memmap", no_read)
    with pytest.raises(PDSError, match="cannot be read.*Permission denied"):
        pds_dem(path)
    monkeypatch.undo()

    def no_memory(*a, **k):
        raise MemoryError

    monkeypatch.setattr(pds_mod.np, "empty", no_memory)
    with pytest.raises(PDSError, match="do not fit in memory"):
        pds_dem(path)


def test_a_data_file_longer_than_its_grid_warns(tmp_path):
    path = make_product(tmp_path, _surface())
    img = tmp_path / "grid.img"
    img.write_bytes(img.read_bytes() * 2)
    with pytest.warns(UserWarning, match="bytes after the grid"):
        pds_dem(path)


def test_import_never_writes_over_the_label_or_its_data_file(tmp_path):
    # a review: import-pds protected only the label; with --overwrite an output named like the
    # data file replaced it. OUT.dem / OUT.hdr that are (links to) the inputs are refused
    label = make_product(tmp_path, _surface())
    data = tmp_path / "grid.img"
    before = data.read_bytes(), label.read_bytes()
    (tmp_path / "out.dem").symlink_to(data)
    with pytest.raises(FileExistsError, match="is the input file"):
        import_pds(label, tmp_path / "out", overwrite=True)
    (tmp_path / "out2.hdr").symlink_to(label)
    with pytest.raises(FileExistsError, match="is the input file"):
        import_pds(label, tmp_path / "out2", overwrite=True)
    assert (data.read_bytes(), label.read_bytes()) == before
    assert import_pds(label, tmp_path / "fine").is_file()
