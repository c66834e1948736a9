"""Hypothesis strategies that generate fuzz cases (dicts performed by ops.py).

Most cases are valid, so that the deep paths (hits, limb rays, every read
mode) are exercised; a minority carry one bad or extreme ingredient at a time
(extreme finite values, NaN/Inf, wrong shapes and types, odd headers and line
endings, wrong file sizes, special files) so that a failure points at it.
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import strategies as st

from .bulk import ray_geometry, read_expect, resize_data, spoil_ray_line

DBL_MAX = float(np.finfo(np.float64).max)
FLT_MAX = float(np.finfo(np.float32).max)

#: finite values at the edges of the double range, and the non-finite ones
EXTREME = [0.0, -0.0, 5e-324, 1e-300, 1e-200, 1e-160, 1e-20, 1e20, 1e100, 1e200, 1e300, DBL_MAX,
           -1.0, -DBL_MAX, math.inf, -math.inf, math.nan]

INTERSECT_NAMES = ["s", "l", "dem", "step_mode", "dem_read_mode", "tangent", "threads", "method", "io"]


def chance(p: float):
    """True with probability about ``p``. Hypothesis favours the ends of an
    integer range (0, the maximum), so the draw is scrambled by a bijection
    (k -> 7919 k + 5003 mod 10000) that sends both ends into the common case;
    shrinking (towards k = 0) then also leads towards the common case."""
    return st.integers(0, 9999).map(lambda k: (k * 7919 + 5003) % 10000 < p * 10000)


def weighted(common, rare, p_rare: float = 0.1):
    """``common`` most of the time, ``rare`` with probability about ``p_rare``."""
    return chance(p_rare).flatmap(lambda r: rare if r else common)


# ---------------------------------------------------------------------------- DEMs
def radius_value(base: float):
    return st.one_of(st.sampled_from(EXTREME + [FLT_MAX, 3.5e38]),
                     st.floats(0.5, 2.0).map(lambda x: base * x),
                     st.floats(allow_nan=True, allow_infinity=True))


@st.composite
def dem_specs(draw, valid_only: bool = False, max_ppd: int = 1):
    """A DEM spec (ops.dem_array): a constant or rough grid, a few spikes, f/re/rmax."""
    base = draw(st.one_of(st.sampled_from([3390.0, 14.0, 1.0, 6371.0, 0.5, 1737.4]),
                          st.floats(1e-3, 1e7)))
    if not valid_only:
        base = draw(weighted(st.just(base), st.sampled_from(EXTREME + [1e-150, 1e250]), 0.1))
    spec = {"ppd": draw(st.integers(1, max_ppd)), "base": base}
    if draw(st.booleans()):
        spec["rough"] = draw(st.sampled_from([1e-6, 0.01, 0.1])) * abs(base) if math.isfinite(base) else 1.0
        spec["seed"] = draw(st.integers(0, 3))
    spikes = []
    for _ in range(draw(st.integers(0, 3))):
        j, i = draw(st.integers(0, 180 * spec["ppd"] - 1)), draw(st.integers(0, 360 * spec["ppd"] - 1))
        ok = st.floats(1.0, 1.3).map(lambda x: abs(base) * x)
        v = draw(ok) if valid_only else draw(weighted(ok, radius_value(abs(base)), 0.4))
        spikes.append((j, i, v))
    if spikes:
        spec["spikes"] = spikes
    # spheroid: none (irregular body), the body's own, or odd values
    sph = draw(st.sampled_from(["none", "none", "own", "own", "odd"] if not valid_only else ["none", "own"]))
    if sph == "own" and math.isfinite(base) and base > 0:
        spec["f"] = draw(st.sampled_from([0.0, 1 / 169.8, 1 / 298.257, 0.3]))
        spec["re"] = base * draw(st.sampled_from([1.0, 0.999, 0.9]))
    elif sph == "odd":
        spec["f"] = draw(st.sampled_from([0.0, 0.5, 0.999999, 1.0, -0.1, math.nan, 2.0]))
        spec["re"] = draw(st.sampled_from([1.0, 1e-300, DBL_MAX, 0.0, -1.0, math.inf, math.nan]))
    if draw(chance(0.1)):
        spec["rmax"] = draw(st.sampled_from(EXTREME + [abs(base) * 1.5, abs(base) * 0.5]))
    if not valid_only and draw(chance(0.07)):
        spec["dtype"] = draw(st.sampled_from(["float32", "int64", "complex128", "float16", "object", "bool"]))
    if not valid_only and draw(chance(0.05)):
        spec["shape"] = draw(st.sampled_from([(0, 0), (180, 361), (181, 362), (1, 2), (360, 180), (90, 180),
                                               (180, 360, 1), (0,)]))
    return spec


def from_array_cases():
    return weighted(dem_specs(valid_only=True), dem_specs(), 0.5).map(
        lambda d: {"op": "from_array", "dem": d, "names": ["radii", "f", "re", "rmax"]})


# ---------------------------------------------------------------------------- rays
def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@st.composite
def geometry(draw, rmax: float, n_max: int = 8):
    """Valid rays (s, l) of mixed kinds around a body of radius about ``rmax``:
    aimed at the body, grazing, limb, away; spacecraft from just above the
    surface to 1e15 rmax (and occasionally one inside r_max)."""
    with np.errstate(all="ignore"):
        return _geometry(draw, rmax, n_max)


def _geometry(draw, rmax, n_max):
    if not (math.isfinite(rmax) and 1e-100 < rmax < 1e100):
        rmax = 1.0                               # an extreme DEM: its own refusal is what is tested
    n = draw(st.integers(1, n_max))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    expo = draw(st.one_of(st.floats(-3, 1), st.floats(1, 16), st.sampled_from([0.0, 6.0, 8.0, 10.0, 12.0, 15.0, 16.5])))
    kind = draw(st.sampled_from(["aim", "aim", "graze", "limb", "away", "mixed", "axis"]))
    s, l, target = ray_geometry(rng, n, expo, kind, rmax)
    # scale l: its length must not matter (tiny and huge lengths included)
    l = l * draw(st.sampled_from([1.0, 1.0, 1e-150, 1e-300, 1e150, 1.0 / max(float(np.abs(l).max()), 1e-300)]))
    if not np.isfinite(l).all() or (np.linalg.norm(l, axis=1) == 0).any():
        l = target - s
    return s, l


def bad_vector(n: int):
    """Inputs for s or l that are wrong in one way (each must give a clear error)."""
    return st.sampled_from([
        [1.0, 2.0], [[1.0, 2.0, 3.0, 4.0]], np.zeros((2, 3, 3)), "1 2 3", None, [1.0, "x", 3.0],
        np.zeros((0, 3)), [0.0, 0.0, 0.0], [math.nan, 0.0, 1.0], [math.inf, 0.0, 0.0], [-1e-200, 0.0, 0.0],
        [1e308, 1e308, 0.0], [1 + 2j, 0.0, 0.0], np.array([1.0, 0.0, 0.0], dtype=object), [True, False, True],
        {"x": 1}, [[1.0, 0.0, 0.0]] * (n + 1) if n > 1 else [[1.0, 0, 0]] * 3, [1e-320, 0.0, 0.0],
        [DBL_MAX, 0.0, 0.0], [-DBL_MAX, DBL_MAX, DBL_MAX],
    ])


def kwargs_strategy(allow_file: bool = True):
    valid = {
        "method": st.sampled_from(["stepping", "exact"]),
        "dem_read_mode": st.sampled_from([0, 1] if allow_file else [0]),
        "io": st.sampled_from(["records", "mmap"]),
        "threads": st.sampled_from([None, 0, 1, 2, 3]),
        "step_mode": st.sampled_from([0, 1]),
        "tangent": st.sampled_from(["exact", "paper"]),
    }
    invalid = {
        "method": st.sampled_from(["Exact", "", [], None, 1, b"exact"]),
        "dem_read_mode": st.sampled_from([2, -1, True, 1.0, "1", None]),
        "io": st.sampled_from(["MMAP", "file", None, 0]),
        "threads": st.sampled_from([-1, 100000, 2**31 - 1, 2**31, 2**63, 1.5, True, "2", np.int64(-3)]),
        "step_mode": st.sampled_from([2, -1, False, 0.0, "1"]),
        "tangent": st.sampled_from(["Paper", 1, None]),
    }

    @st.composite
    def build(draw):
        kw, bad = {}, []
        for k in valid:
            if draw(chance(0.4)):
                continue
            if draw(chance(0.03)):
                kw[k] = draw(invalid[k])
                bad.append(k)
            else:
                kw[k] = draw(valid[k])
        return kw, bad

    return build()


@st.composite
def intersect_cases(draw):
    spec = draw(weighted(dem_specs(valid_only=True), dem_specs(), 0.08))
    base = spec["base"]
    rmax = abs(base) if math.isfinite(base) and base != 0 else 1.0
    for _, _, v in spec.get("spikes", ()):
        if math.isfinite(v):
            rmax = max(rmax, abs(v))
    s, l = draw(geometry(rmax))
    kw, bad = draw(kwargs_strategy())
    case = {"op": "intersect", "dem": spec, "s": s, "l": l, "kwargs": kw, "names": INTERSECT_NAMES + ["dem.hdr"],
            "files": True}
    which = draw(st.integers(0, 9999).map(lambda k: (k * 7919 + 5003) % 10000 // 500))   # 0..19, scrambled
    if which == 0:
        case["s"] = draw(bad_vector(len(s)))
    elif which == 1:
        case["l"] = draw(bad_vector(len(l)))
    elif which in (2, 3, 4) and not bad:
        case["all_configs"] = True
        if draw(st.booleans()):
            spec["file_dtype"] = "float32"
            spec["byteorder"] = draw(st.sampled_from(["little", "big"]))
    elif which == 5:                                   # one position for all rays, or all positions for one ray
        case["s"] = s[0]
    return case


@st.composite
def mutate_cases(draw):
    spec = draw(dem_specs(valid_only=True))
    rmax = spec["base"] * 1.3
    s, l = draw(geometry(rmax, n_max=4))
    muts = [(draw(st.integers(0, 179)), draw(st.integers(0, 359)),
             draw(st.sampled_from([math.nan, 1e300, -1.0, 0.0, math.inf, spec["base"] * 2]))) for _ in range(3)]
    muts.append((0, 0, math.nan))
    return {"op": "mutate", "dem": spec, "s": s, "l": l, "mutations": muts, "names": INTERSECT_NAMES}


@st.composite
def radius_cases(draw):
    spec = draw(weighted(dem_specs(valid_only=True), dem_specs(), 0.1))
    n = draw(st.integers(0, 6))
    lat = draw(st.lists(st.one_of(st.floats(-90, 90), st.sampled_from([-90.0, 90.0, 89.999999, 0.0])),
                        min_size=n, max_size=n))
    lon = draw(st.lists(st.one_of(st.floats(-1e4, 1e4), st.sampled_from([0.0, 360.0, -0.0, 359.9999999999])),
                        min_size=n, max_size=n))
    lat, lon = np.array(lat, dtype=float), np.array(lon, dtype=float)
    k = draw(st.integers(0, 9999).map(lambda k: (k * 7919 + 5003) % 10000 // 770))        # 0..12, scrambled
    if k == 0:
        lat = draw(st.sampled_from([[math.nan], [91.0], [math.inf], "0", None, [[1.0, 2.0]], [1 + 1j], [1e308]]))
    elif k == 1:
        lon = draw(st.sampled_from([[math.nan], [1e300], [-math.inf], "0", [[1.0, 2.0, 3.0]], [1e20], [1 + 1j]]))
    elif k == 2:
        lat, lon = float(lat[0]) if n else 0.0, lon                # a scalar against an array
    elif k == 3:
        lat, lon = lat.reshape(-1, 1), lon                         # broadcast to a matrix
    elif k == 4:
        lat, lon = [], []
    return {"op": "radius", "dem": spec, "lat": lat, "lon": lon, "names": ["lat", "lon"]}


@st.composite
def detector_cases(draw):
    good = st.tuples(st.integers(0, 2**32 - 1), st.sampled_from([1.0, 1e-3, 1e3, 1e-150, 1e150])).map(
        lambda a: (np.random.default_rng(a[0]).standard_normal(3) * a[1]).tolist())
    vec = weighted(good, st.one_of(st.lists(st.floats(-10, 10), min_size=3, max_size=3),
                                   st.sampled_from([[0, 0, 0], [1e-200, 0, 0], [1e308, 1e308, 0], [math.nan, 0, 1],
                                                    [1, 2], "x", [0, 0, 1e-320]])), 0.15)
    args = {
        "l0": draw(vec), "q": draw(vec),
        "nh": draw(weighted(st.integers(1, 9), st.sampled_from([0, -1, 2.5, 1.0, True, "3", 10**12, None]), 0.08)),
        "nv": draw(weighted(st.integers(1, 9), st.sampled_from([0, -3, 3.0, 10**12]), 0.05)),
        "dh": draw(weighted(st.floats(1e-6, 0.1), st.sampled_from([0.0, -0.01, math.nan, math.inf, 1e300, "0.1"]), 0.08)),
        "dv": draw(weighted(st.floats(1e-6, 0.1), st.sampled_from([0.0, math.nan, 1e300]), 0.05)),
    }
    return {"op": "detector", "args": args, "names": ["l0", "q", "nh", "nv", "dh", "dv"]}


# ---------------------------------------------------------------------------- files
EOLS = ["\n", "\r\n", "\r"]


@st.composite
def header_cases(draw):
    """A generated .hdr/.dem pair and what it must mean (``expect``) or why it must be refused."""
    why = []
    ppd_ok = not draw(chance(0.1))
    ppd = 2 if draw(chance(0.07)) else 1
    rmax = draw(st.sampled_from([3400.0, 3396.19 + 25, 14.0, 1.5, 1e-3, 1e6]))
    f = draw(st.sampled_from([0.0, 1 / 169.8, 0.5]))
    re_ = draw(st.sampled_from([1.0, rmax * 0.99]))
    toks = {"ppd": str(ppd), "rmax": repr(rmax), "f": repr(f), "re": repr(re_)}
    # alternative spellings of valid values
    if draw(st.booleans()):
        toks["rmax"] = draw(st.sampled_from([f"{rmax:.17e}", f"{rmax:.17E}", f"+{rmax!r}"]))
    if not ppd_ok:
        k = draw(st.sampled_from(["ppd", "rmax", "f", "re"]))
        toks[k] = draw(st.sampled_from({"ppd": ["0", "-1", "1.5", "x", "1e0", "99999999999999999999"],
                                        "rmax": ["nan", "inf", "-5", "abc", "1e400", "0"],
                                        "f": ["1", "1.5", "-0.1", "nan", "f"],
                                        "re": ["0", "-1", "inf", "nan", "q"]}[k]))
        why.append(f"{k} = {toks[k]!r}")
    lines = []
    for name in ("ppd", "rmax", "f", "re"):
        for _ in range(draw(st.integers(0, 1))):
            lines.append(draw(st.sampled_from(["# comment", "! comment", "", "   ", "\t# indented",
                                               "# " + "x" * 1100])))
        tail = draw(st.sampled_from(["", "    " + name + ": comment", " ! c", "\t# c"]))
        lines.append(draw(st.sampled_from(["", " ", "\t"])) + toks[name] + tail)
    dtype, order = "float32", "little"
    keys = draw(st.lists(st.sampled_from(["dtype", "byteorder", "comment", "longcomment"]), max_size=3, unique=True))
    if draw(chance(0.15)):
        keys.insert(draw(st.integers(0, len(keys))), draw(st.sampled_from(["unknown", "badvalue", "noequals"])))
    for k in keys:
        if k == "dtype":
            dtype = draw(st.sampled_from(["float32", "float64"]))
            lines.append(draw(st.sampled_from([f"dtype = {dtype}", f"dtype={dtype}", f"DTYPE = {dtype.upper()}",
                                               f"  dtype =  {dtype}   # comment"])))
        elif k == "byteorder":
            order = draw(st.sampled_from(["little", "big"]))
            lines.append(draw(st.sampled_from([f"byteorder = {order}", f"byteorder={order}",
                                               f"ByteOrder = {order.title()}"])))
        elif k == "unknown":
            lines.append(draw(st.sampled_from(["units = km", "endian = big", "foo = bar", "= big"])))
            why.append("unknown key")
        elif k == "badvalue":
            lines.append(draw(st.sampled_from(["dtype = int16", "byteorder = middle", "dtype =", "byteorder = "])))
            why.append("bad key value")
        elif k == "noequals":
            lines.append(draw(st.sampled_from(["byteorder big", "3390", "extra words here"])))
            why.append("a line without '=' after the four values")
        elif k == "comment":
            lines.append("# trailing comment")
        else:
            lines.append("! " + "y" * 1500)
    eol_mode = draw(st.sampled_from(["\n", "\r\n", "\r", "mixed"]))
    text = ""
    for line in lines:
        text += line + (draw(st.sampled_from(EOLS)) if eol_mode == "mixed" else eol_mode)
    if draw(chance(0.15)):
        text = text.rstrip("\r\n")                      # no final line end
    header = text.encode()
    if draw(chance(0.05)):
        header = b"\xef\xbb\xbf" + header               # a UTF-8 byte-order mark: either reading is acceptable
        why.append("a byte-order mark (either outcome acceptable)")
    # the data: what the header says, with valid radii or one bad value
    n = 64800 * ppd * ppd
    dt = np.dtype(dtype).newbyteorder("<" if order == "little" else ">")
    base = rmax * draw(st.sampled_from([1.0, 0.99, 0.6]))   # rmax at most twice the largest radius
    values = np.full(n, base, dtype=np.float64)
    bad_value = draw(weighted(st.none(), st.sampled_from([math.nan, math.inf, 0.0, -1.0, rmax * 1.01, 1e-300,
                                                           DBL_MAX, FLT_MAX]), 0.15))
    if bad_value is not None:
        values[draw(st.integers(0, n - 1))] = bad_value
    with np.errstate(over="ignore"):
        stored = values.astype(dt)
    back = stored.astype(np.float64)          # what the file holds (float32 rounds: 1e-3 is stored above 1e-3)
    # the accepted range of radii (docs/dem-format.md): finite, in [1e-100, 1e100], <= rmax
    if not (np.isfinite(back).all() and (back >= 1e-100).all() and back.max() <= min(rmax, 1e100)
            and rmax <= 2.0 * back.max()):
        why.append(f"a stored radius of {bad_value if bad_value is not None else back.max()!r} "
                   f"(rmax {rmax!r}, {dtype})")
    data = stored.tobytes()
    size = draw(weighted(st.just("exact"), st.sampled_from(["short", "long", "empty", "ppd2"]), 0.1))
    data = resize_data(data, size, ppd, why)
    expect, either = read_expect(why, ppd, rmax, f, re_, dtype, order)
    case = {"op": "read", "header": header, "data": data, "expect": expect, "why": "; ".join(why),
            "open": draw(st.sampled_from(["hdr", "hdr", "dem", "stem"])), "names": ["d.hdr", "d.dem"],
            "files": True}
    if draw(chance(0.04)):                             # not a regular file where one is expected
        case["special"] = draw(st.sampled_from(["dir", "fifo", "loop", "dangling"]))
        case["special_which"] = draw(st.sampled_from(["hdr", "dem"]))
        case["expect"], case["why"] = None, f"the .{case['special_which']} is a {case['special']}"
        return case
    if either and len(why) == 1:
        case["either"] = True
    if expect is not None and not either:
        case["must_succeed"] = True
        # rays: every read mode must give the same answer (the Python and Fortran readers agree)
        u = np.array([[1.0, 0, 0], [0, 0, 1.0], [0.3, -0.5, 0.8], [0, 1.0, 0]])
        case["rays"] = (u * rmax * 2.0, -u + np.array([0, 0.1, 0]) * draw(st.sampled_from([0.0, 0.3])))
        if draw(chance(0.2)):
            case["shrink"] = draw(st.sampled_from([0, len(data) // 2, len(data) - 4]))
    return case


@st.composite
def cli_cases(draw):
    """A generated rays file for ``planet-intersect run`` and whether it is valid."""
    rmax = 3390.0
    n = draw(st.integers(0, 6))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    u = _unit(rng.standard_normal((max(n, 1), 3)))
    s = u * rmax * rng.uniform(1.1, 3.0, (max(n, 1), 1))
    l = -u + 0.2 * rng.standard_normal((max(n, 1), 3))
    rows = [[repr(float(x)) for x in np.concatenate([s[k], l[k]])] for k in range(n)]
    lines = []         # (text, data row index or None)
    for k, row in enumerate(rows):
        for _ in range(draw(st.integers(0, 1))):
            lines.append((draw(st.sampled_from(["# comment", "", "   ", "#"])), None))
        sep = draw(st.sampled_from([" ", "  ", "\t", " \t "]))
        tail = draw(st.sampled_from(["", "", "  # ray comment"]))
        lines.append((sep.join(row) + tail, k))
    bad = draw(weighted(st.none(), st.sampled_from(["nan", "inf", "word", "cols5", "cols7", "comma", "inside",
                                                    "hex"]), 0.25)) if n else None
    why, bad_line = spoil_ray_line(lines, rows, bad, lambda lo, hi: draw(st.integers(lo, hi)))
    eol = draw(st.sampled_from(["\n", "\r\n", "\r"]))
    content = eol.join(t for t, _ in lines) + (eol if draw(st.booleans()) else "")
    if draw(chance(0.1)) and not bad:
        content = draw(st.sampled_from(["", "# only a comment\n", "\n\n"]))
        n = 0
    options = []
    for opt, vals in (("--method", ["stepping", "exact"]), ("--dem-read-mode", ["0", "1"]),
                      ("--io", ["records", "mmap"]), ("--threads", ["0", "1", "2", "-1", "100000", "x"])):
        if draw(chance(0.3)):
            options += [opt, draw(st.sampled_from(vals))]
    case = {"op": "cli_run", "dem": {"ppd": 1, "base": 3380.0, "rough": 1.0, "seed": 1, "f": 1 / 169.8,
                                     "re": 3390.0, "rmax": rmax},
            "rays": content.encode(), "options": options, "why": why,
            "names": ["rays.txt", "cli.hdr", "cli.dem", "threads", "--threads", "--io"]}
    bad_threads = any(v in ("-1", "100000", "x") for v in options[1::2] if options[options.index(v) - 1] == "--threads") \
        if "--threads" in options else False
    given = dict(zip(options[::2], options[1::2]))
    if draw(chance(0.03)):                             # the rays file is not a regular file
        case["special"] = draw(st.sampled_from(["dir", "fifo", "loop", "dangling"]))
        return case
    if given.get("--io") == "mmap" and given.get("--dem-read-mode") != "1":
        case["why"] = "--io mmap without --dem-read-mode 1"   # refused before the rays file is read
        return case
    if not bad:
        case["nrays"] = n
        if n and not bad_threads:
            case["must_succeed"] = True
    if bad_line is not None and not bad_threads:     # (a bad --threads may be reported first)
        case["bad_line"] = bad_line
    return case


#: every target of the fuzzer: name -> strategy
TARGETS = {
    "from_array": from_array_cases(),
    "read": header_cases(),
    "radius": radius_cases(),
    "intersect": intersect_cases(),
    "mutate": mutate_cases(),
    "detector": detector_cases(),
    "cli_run": cli_cases(),
}
