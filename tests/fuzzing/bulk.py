"""Bulk fuzzing: the same cases, properties and judgement, without hypothesis.

``./dev fuzz --bulk --calls N`` (or ``--minutes M``). The hypothesis long mode
spends most of its time generating and shrinking, and makes one IPC round trip
per case (about 45 API calls/s here). The bulk mode keeps the crash-safe
worker of harness.py but

* draws the case dicts *in the worker* with a seeded ``numpy`` Generator from
  the same value pools as strategies.py (:func:`gen_case`; case ``i`` of batch
  ``b`` under seed ``S`` is ``gen_case(default_rng([S, b, i]))``, so the parent
  can regenerate any case);
* runs a whole batch of cases per round trip (:func:`run_batch`): each case is
  performed by the ops.py operation (the same property checks) and judged by
  harness.judge (the same rules for exceptions); the parent receives a summary
  and every failing case with its failure text;
* reuses DEMs across cases (ops.DEM_CACHE, keyed by the spec; the DEMs are
  immutable) and a pool of valid DEM specs drawn once per worker seed.

A crash or hang kills only the worker, as in the hypothesis mode: the parent
then regenerates the batch and replays its cases one at a time through the
normal per-case path until the culprit crashes (or hangs) again, and reports
it with a reproducer; the worker is restarted and the run goes on. API calls
are counted as the long mode counts them (each case's ``calls``, per ray and
per configuration; 1 for a case that raised).
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np

DBL_MAX = float(np.finfo(np.float64).max)
FLT_MAX = float(np.finfo(np.float32).max)
# the value pools of strategies.py (copied, so that the worker does not import hypothesis;
# tests/test_fuzz.py checks that they are the same)
EXTREME = [0.0, -0.0, 5e-324, 1e-300, 1e-200, 1e-160, 1e-20, 1e20, 1e100, 1e200, 1e300, DBL_MAX,
           -1.0, -DBL_MAX, math.inf, -math.inf, math.nan]
INTERSECT_NAMES = ["s", "l", "dem", "step_mode", "dem_read_mode", "tangent", "threads", "method", "io"]
EOLS = ["\n", "\r\n", "\r"]

#: share of each operation among the cases (file-writing ones rarer: they cost ~10-50x more)
MIX = {"intersect": 0.52, "radius": 0.26, "detector": 0.12, "from_array": 0.05, "mutate": 0.02,
       "read": 0.02, "cli_run": 0.005}
#: the geodetic system's operations (tests/fuzzing/geo.py): ``--geo``, test_bulk_fuzz_geo
MIX_GEO = {"dsm_intersect": 0.6, "dsm_from_array": 0.25, "geodetic": 0.15}
#: the footprint system's operations (tests/fuzzing/grs.py): ``--grs``, test_bulk_fuzz_grs
MIX_GRS = {"footprint": 0.5, "frame": 0.15, "airmass": 0.12, "cell_table": 0.08, "helpers": 0.15}
#: the image simulation's operations (tests/fuzzing/sim.py): ``--sim``, test_bulk_fuzz_sim
MIX_SIM = {"simulate": 0.6, "sensor": 0.25, "ortho_from_array": 0.15}


class R:
    """Draws from a numpy Generator, in the vocabulary of strategies.py."""

    def __init__(self, g: np.random.Generator):
        self.g = g

    def chance(self, p: float) -> bool:
        return bool(self.g.random() < p)

    def pick(self, seq):
        return seq[int(self.g.integers(len(seq)))]

    def int(self, lo: int, hi: int) -> int:          # inclusive, like st.integers
        return int(self.g.integers(lo, hi + 1))

    def float(self, lo: float, hi: float) -> float:
        return float(self.g.uniform(lo, hi))

    def any_float(self) -> float:                    # st.floats(allow_nan=True, allow_infinity=True)
        k = self.int(0, 3)
        if k == 0:
            return float(np.frombuffer(self.g.bytes(8), np.float64)[0])
        if k == 1:
            return float(np.frombuffer(self.g.bytes(4), np.float32)[0])
        return float(self.g.standard_normal() * 10.0 ** self.int(-30, 30))


# ---------------------------------------------------------------------------- DEMs
def radius_value(r: R, base: float) -> float:
    k = r.int(0, 2)
    if k == 0:
        return r.pick(EXTREME + [FLT_MAX, 3.5e38])
    if k == 1:
        return base * r.float(0.5, 2.0)
    return r.any_float()


def dem_spec(r: R, valid_only: bool = False, max_ppd: int = 1) -> dict:
    """strategies.dem_specs"""
    base = r.pick([3390.0, 14.0, 1.0, 6371.0, 0.5, 1737.4]) if r.chance(0.5) else 10.0 ** r.float(-3, 7)
    if not valid_only and r.chance(0.1):
        base = r.pick(EXTREME + [1e-150, 1e250])
    spec = {"ppd": r.int(1, max_ppd), "base": base}
    if r.chance(0.5):
        spec["rough"] = r.pick([1e-6, 0.01, 0.1]) * abs(base) if math.isfinite(base) else 1.0
        spec["seed"] = r.int(0, 3)
    spikes = []
    for _ in range(r.int(0, 3)):
        j, i = r.int(0, 180 * spec["ppd"] - 1), r.int(0, 360 * spec["ppd"] - 1)
        if valid_only or not r.chance(0.4):
            v = abs(base) * r.float(1.0, 1.3)
        else:
            v = radius_value(r, abs(base))
        spikes.append((j, i, v))
    if spikes:
        spec["spikes"] = spikes
    sph = r.pick(["none", "none", "own", "own", "odd"] if not valid_only else ["none", "own"])
    if sph == "own" and math.isfinite(base) and base > 0:
        spec["f"] = r.pick([0.0, 1 / 169.8, 1 / 298.257, 0.3])
        spec["re"] = base * r.pick([1.0, 0.999, 0.9])
    elif sph == "odd":
        spec["f"] = r.pick([0.0, 0.5, 0.999999, 1.0, -0.1, math.nan, 2.0])
        spec["re"] = r.pick([1.0, 1e-300, DBL_MAX, 0.0, -1.0, math.inf, math.nan])
    if r.chance(0.1):
        spec["rmax"] = r.pick(EXTREME + [abs(base) * 1.5, abs(base) * 0.5])
    if not valid_only and r.chance(0.07):
        spec["dtype"] = r.pick(["float32", "int64", "complex128", "float16", "object", "bool"])
    if not valid_only and r.chance(0.05):
        spec["shape"] = r.pick([(0, 0), (180, 361), (181, 362), (1, 2), (360, 180), (90, 180), (180, 360, 1), (0,)])
    return spec


#: valid DEM specs drawn once per seed and shared by most cases (their DEMs are cached)
_POOLS: dict = {}


def valid_pool(seed: int, n: int = 48) -> list:
    if seed not in _POOLS:
        r = R(np.random.default_rng([seed, 2**31]))
        _POOLS[seed] = [dem_spec(r, valid_only=True) for _ in range(n)]
    return _POOLS[seed]


def some_dem(r: R, seed: int, p_invalid: float) -> dict:
    """A DEM spec: from the shared valid pool, a fresh valid one, or (p_invalid) a fresh odd one."""
    if r.chance(p_invalid):
        return dem_spec(r)
    if r.chance(0.05):
        return dem_spec(r, valid_only=True)
    return dict(r.pick(valid_pool(seed)))


# ---------------------------------------------------------------------------- rays
def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def spoil_ray_line(lines: list, rows: list, bad, integer):
    """Spoil one data line of a ray file in the way ``bad`` names ("nan", "inf", "word",
    "hex": one token; "cols5", "cols7": a column short or over; "comma": commas as separators;
    "inside": a position inside the body; None: none). ``lines`` holds (text, data row index
    or None) and is changed in place; ``integer(lo, hi)`` draws an int in [lo, hi] (the bulk
    mode's R.int, or hypothesis' draw in strategies.py). Returns (why, the 1-based line
    number the error must name, or None)."""
    if not bad:
        return "", None
    idx = [i for i, (_, k) in enumerate(lines) if k is not None]
    at = idx[integer(0, len(idx) - 1)]
    text, k = lines[at]
    toks = rows[k][:]
    if bad in ("nan", "inf", "word", "hex"):
        toks[integer(0, 5)] = {"nan": "nan", "inf": "-inf", "word": "abc", "hex": "0x10"}[bad]
    elif bad == "cols5":
        toks = toks[:5]
    elif bad == "cols7":
        toks = toks + ["1.0"]
    elif bad == "comma":
        toks = [",".join(toks)]
    elif bad == "inside":
        toks[:3] = ["0.0", "0.0", "10.0"]
    lines[at] = (" ".join(toks), k)
    return f"{bad} on line {at + 1}", (at + 1 if bad in ("nan", "inf", "inside") else None)


def resize_data(data: bytes, size: str, ppd: int, why: list) -> bytes:
    """A .dem file's bytes made the wrong size ("short", "long", "empty", "ppd2": a 1 ppd grid's
    bytes repeated as if 2 ppd) or left "exact"; a wrong size is appended to ``why``. Shared by
    both fuzz modes (strategies.py draws ``size`` with hypothesis)."""
    if size == "short":
        data = data[:-1]
    elif size == "long":
        data = data + b"\0\0\0\0"
    elif size == "empty":
        data = b""
    elif size == "ppd2" and ppd == 1:
        data = data * 4
    if size != "exact" and not (size == "ppd2" and ppd != 1):
        why.append(f"the .dem size ({size})")
    return data


def read_expect(why: list, ppd, rmax, f, re_, dtype, order):
    """(expect, either) of a read case: what the reader should return (None: an error), from
    the reasons ``why`` it should fail (none, or only one that may go "either" way), and
    whether some reason may go either way."""
    either = any("either" in w for w in why)
    if not why or (either and len(why) == 1):
        return {"ppd": ppd, "rmax": rmax, "f": f, "re": re_, "dtype": dtype, "byteorder": order}, either
    return None, either


def ray_geometry(g, n: int, expo: float, kind: str, rmax: float):
    """(s, l, target) of ``n`` rays of one ``kind`` ("aim", "graze", "limb", "away", "mixed",
    "axis") whose spacecraft lie at 1 + 10^(expo +- 1/2) ``rmax`` from the centre, drawn from
    the numpy Generator ``g``: the geometry both fuzz modes share (strategies.geometry draws
    its n, expo and kind with hypothesis, :func:`geometry` with the bulk mode's R; the same
    draws give the same rays). l is not yet scaled."""
    u = _unit(g.standard_normal((n, 3)))
    if kind == "axis":           # the reproducers: on an axis, straight through the centre
        u = np.zeros((n, 3))
        u[np.arange(n), g.integers(0, 3, n)] = g.choice([-1.0, 1.0], n)
    dist = rmax * (1.0 + 10.0 ** (expo + g.uniform(-0.5, 0.5, n)))
    s = u * dist[:, None]
    target = _unit(g.standard_normal((n, 3))) * (rmax * g.uniform(0.0, 1.3, n))[:, None]
    if kind == "axis":
        target = np.zeros((n, 3))
    elif kind == "graze":
        target = _unit(target) * (rmax * g.uniform(0.95, 1.0, n))[:, None]
    elif kind == "limb":
        target = _unit(target) * (rmax * g.uniform(1.0, 1.1, n))[:, None]
    l = target - s
    if kind == "away":
        l = s + g.standard_normal((n, 3)) * dist[:, None] * 0.3
    if kind == "mixed":
        pick = g.integers(0, 2, n).astype(bool)
        l[pick] = -l[pick]
    bad = np.linalg.norm(l, axis=1) == 0
    l[bad] = -s[bad]
    return s, l, target


def geometry(r: R, rmax: float, n_max: int = 8):
    """strategies.geometry: aimed, grazing, limb, away, mixed and on-axis rays, |s| up to 1e16.5 rmax."""
    with np.errstate(all="ignore"):
        if not (math.isfinite(rmax) and 1e-100 < rmax < 1e100):
            rmax = 1.0
        n = r.int(1, n_max)
        g = r.g
        k = r.int(0, 2)
        expo = r.float(-3, 1) if k == 0 else r.float(1, 16) if k == 1 else r.pick([0.0, 6.0, 8.0, 10.0, 12.0, 15.0, 16.5])
        kind = r.pick(["aim", "aim", "graze", "limb", "away", "mixed", "axis"])
        s, l, target = ray_geometry(g, n, expo, kind, rmax)
        l = l * r.pick([1.0, 1.0, 1e-150, 1e-300, 1e150, 1.0 / max(float(np.abs(l).max()), 1e-300)])
        if not np.isfinite(l).all() or (np.linalg.norm(l, axis=1) == 0).any():
            l = target - s
    return s, l


def bad_vector(r: R, n: int):
    """strategies.bad_vector"""
    pool = [
        lambda: [1.0, 2.0], lambda: [[1.0, 2.0, 3.0, 4.0]], lambda: np.zeros((2, 3, 3)), lambda: "1 2 3",
        lambda: None, lambda: [1.0, "x", 3.0], lambda: np.zeros((0, 3)), lambda: [0.0, 0.0, 0.0],
        lambda: [math.nan, 0.0, 1.0], lambda: [math.inf, 0.0, 0.0], lambda: [-1e-200, 0.0, 0.0],
        lambda: [1e308, 1e308, 0.0], lambda: [1 + 2j, 0.0, 0.0], lambda: np.array([1.0, 0.0, 0.0], dtype=object),
        lambda: [True, False, True], lambda: {"x": 1},
        lambda: [[1.0, 0.0, 0.0]] * (n + 1) if n > 1 else [[1.0, 0, 0]] * 3, lambda: [1e-320, 0.0, 0.0],
        lambda: [DBL_MAX, 0.0, 0.0], lambda: [-DBL_MAX, DBL_MAX, DBL_MAX],
    ]
    return r.pick(pool)()


KW_VALID = {"method": ["stepping", "exact"], "dem_read_mode": [0, 1], "io": ["records", "mmap"],
            "threads": [None, 0, 1, 2, 3, 4], "step_mode": [0, 1], "tangent": ["exact", "paper"]}
KW_INVALID = {"method": ["Exact", "", [], None, 1, b"exact"], "dem_read_mode": [2, -1, True, 1.0, "1", None],
              "io": ["MMAP", "file", None, 0],
              "threads": [-1, 100000, 2**31 - 1, 2**31, 2**63, 1.5, True, "2", np.int64(-3)],
              "step_mode": [2, -1, False, 0.0, "1"], "tangent": ["Paper", 1, None]}


def kwargs(r: R, p_file: float):
    kw, bad = {}, []
    for k in KW_VALID:
        if r.chance(0.4):
            continue
        if r.chance(0.03):
            kw[k] = r.pick(KW_INVALID[k])
            bad.append(k)
        elif k == "dem_read_mode":
            kw[k] = 1 if r.chance(p_file) else 0      # mode 1 writes the DEM to a file: rarer than in hypothesis
        else:
            kw[k] = r.pick(KW_VALID[k])
    return kw, bad


def intersect_case(r: R, seed: int) -> dict:
    spec = some_dem(r, seed, 0.08)
    base = spec["base"]
    rmax = abs(base) if math.isfinite(base) and base != 0 else 1.0
    for _, _, v in spec.get("spikes", ()):
        if math.isfinite(v):
            rmax = max(rmax, abs(v))
    s, l = geometry(r, rmax)
    kw, bad = kwargs(r, 0.1)
    case = {"op": "intersect", "dem": spec, "s": s, "l": l, "kwargs": kw, "names": INTERSECT_NAMES + ["dem.hdr"],
            "files": True, "per_ray": True}
    which = r.int(0, 19)
    if which == 0:
        case["s"] = bad_vector(r, len(s))
    elif which == 1:
        case["l"] = bad_vector(r, len(l))
    elif which == 2 and not bad and r.chance(0.3):
        case["all_configs"] = True                     # every method/read mode/io/threads: writes a file
        if r.chance(0.5):
            spec["file_dtype"] = "float32"
            spec["byteorder"] = r.pick(["little", "big"])
    elif which == 5:
        case["s"] = s[0]
    return case


def mutate_case(r: R, seed: int) -> dict:
    spec = dem_spec(r, valid_only=True)
    s, l = geometry(r, spec["base"] * 1.3, n_max=4)
    muts = [(r.int(0, 179), r.int(0, 359), r.pick([math.nan, 1e300, -1.0, 0.0, math.inf, spec["base"] * 2]))
            for _ in range(3)]
    muts.append((0, 0, math.nan))
    return {"op": "mutate", "dem": spec, "s": s, "l": l, "mutations": muts, "names": INTERSECT_NAMES}


def radius_case(r: R, seed: int) -> dict:
    spec = some_dem(r, seed, 0.1)
    n = r.int(0, 6)
    lat = np.array([r.float(-90, 90) if r.chance(0.5) else r.pick([-90.0, 90.0, 89.999999, 0.0]) for _ in range(n)],
                   dtype=float)
    lon = np.array([r.float(-1e4, 1e4) if r.chance(0.5) else r.pick([0.0, 360.0, -0.0, 359.9999999999])
                    for _ in range(n)], dtype=float)
    k = r.int(0, 12)
    if k == 0:
        lat = r.pick([[math.nan], [91.0], [math.inf], "0", None, [[1.0, 2.0]], [1 + 1j], [1e308], [-90.0000001]])
    elif k == 1:
        lon = r.pick([[math.nan], [1e300], [-math.inf], "0", [[1.0, 2.0, 3.0]], [1e20], [1 + 1j]])
    elif k == 2:
        lat, lon = float(lat[0]) if n else 0.0, lon
    elif k == 3:
        lat, lon = lat.reshape(-1, 1), lon
    elif k == 4:
        lat, lon = [], []
    return {"op": "radius", "dem": spec, "lat": lat, "lon": lon, "names": ["lat", "lon"], "per_ray": True}


def detector_case(r: R, seed: int) -> dict:
    def vec():
        if not r.chance(0.15):
            return (r.g.standard_normal(3) * r.pick([1.0, 1e-3, 1e3, 1e-150, 1e150])).tolist()
        if r.chance(0.5):
            return [r.float(-10, 10) for _ in range(3)]
        return r.pick([[0, 0, 0], [1e-200, 0, 0], [1e308, 1e308, 0], [math.nan, 0, 1], [1, 2], "x", [0, 0, 1e-320]])

    args = {
        "l0": vec(), "q": vec(),
        "nh": r.int(1, 9) if not r.chance(0.08) else r.pick([0, -1, 2.5, 1.0, True, "3", 10**12, None]),
        "nv": r.int(1, 9) if not r.chance(0.05) else r.pick([0, -3, 3.0, 10**12]),
        "dh": 10.0 ** r.float(-6, -1) if not r.chance(0.08) else r.pick([0.0, -0.01, math.nan, math.inf, 1e300, "0.1"]),
        "dv": 10.0 ** r.float(-6, -1) if not r.chance(0.05) else r.pick([0.0, math.nan, 1e300]),
    }
    return {"op": "detector", "args": args, "names": ["l0", "q", "nh", "nv", "dh", "dv"]}


def from_array_case(r: R, seed: int) -> dict:
    return {"op": "from_array", "dem": dem_spec(r, valid_only=r.chance(0.5)), "names": ["radii", "f", "re", "rmax"]}


# ---------------------------------------------------------------------------- files
def header_case(r: R, seed: int) -> dict:
    """strategies.header_cases"""
    why = []
    ppd_ok = not r.chance(0.1)
    ppd = 2 if r.chance(0.07) else 1
    rmax = r.pick([3400.0, 3396.19 + 25, 14.0, 1.5, 1e-3, 1e6])
    f = r.pick([0.0, 1 / 169.8, 0.5])
    re_ = r.pick([1.0, rmax * 0.99])
    toks = {"ppd": str(ppd), "rmax": repr(rmax), "f": repr(f), "re": repr(re_)}
    if r.chance(0.5):
        toks["rmax"] = r.pick([f"{rmax:.17e}", f"{rmax:.17E}", f"+{rmax!r}"])
    if not ppd_ok:
        k = r.pick(["ppd", "rmax", "f", "re"])
        toks[k] = r.pick({"ppd": ["0", "-1", "1.5", "x", "1e0", "99999999999999999999"],
                          "rmax": ["nan", "inf", "-5", "abc", "1e400", "0"],
                          "f": ["1", "1.5", "-0.1", "nan", "f"],
                          "re": ["0", "-1", "inf", "nan", "q"]}[k])
        why.append(f"{k} = {toks[k]!r}")
    lines = []
    for name in ("ppd", "rmax", "f", "re"):
        for _ in range(r.int(0, 1)):
            lines.append(r.pick(["# comment", "! comment", "", "   ", "\t# indented", "# " + "x" * 1100]))
        tail = r.pick(["", "    " + name + ": comment", " ! c", "\t# c"])
        lines.append(r.pick(["", " ", "\t"]) + toks[name] + tail)
    dtype, order = "float32", "little"
    keys = [k for k in ["dtype", "byteorder", "comment", "longcomment"] if r.chance(0.3)]
    r.g.shuffle(keys)
    if r.chance(0.15):
        keys.insert(r.int(0, len(keys)), r.pick(["unknown", "badvalue", "noequals"]))
    for k in keys:
        if k == "dtype":
            dtype = r.pick(["float32", "float64"])
            lines.append(r.pick([f"dtype = {dtype}", f"dtype={dtype}", f"DTYPE = {dtype.upper()}",
                                 f"  dtype =  {dtype}   # comment"]))
        elif k == "byteorder":
            order = r.pick(["little", "big"])
            lines.append(r.pick([f"byteorder = {order}", f"byteorder={order}", f"ByteOrder = {order.title()}"]))
        elif k == "unknown":
            lines.append(r.pick(["units = km", "endian = big", "foo = bar", "= big"]))
            why.append("unknown key")
        elif k == "badvalue":
            lines.append(r.pick(["dtype = int16", "byteorder = middle", "dtype =", "byteorder = "]))
            why.append("bad key value")
        elif k == "noequals":
            lines.append(r.pick(["byteorder big", "3390", "extra words here"]))
            why.append("a line without '=' after the four values")
        elif k == "comment":
            lines.append("# trailing comment")
        else:
            lines.append("! " + "y" * 1500)
    eol_mode = r.pick(["\n", "\r\n", "\r", "mixed"])
    text = "".join(line + (r.pick(EOLS) if eol_mode == "mixed" else eol_mode) for line in lines)
    if r.chance(0.15):
        text = text.rstrip("\r\n")
    header = text.encode()
    if r.chance(0.05):
        header = b"\xef\xbb\xbf" + header
        why.append("a byte-order mark (either outcome acceptable)")
    n = 64800 * ppd * ppd
    dt = np.dtype(dtype).newbyteorder("<" if order == "little" else ">")
    base = rmax * r.pick([1.0, 0.99, 0.6])            # rmax at most twice the largest radius
    values = np.full(n, base, dtype=np.float64)
    bad_value = r.pick([math.nan, math.inf, 0.0, -1.0, rmax * 1.01, 1e-300, DBL_MAX, FLT_MAX]) if r.chance(0.15) else None
    if bad_value is not None:
        values[r.int(0, n - 1)] = bad_value
    with np.errstate(over="ignore"):
        stored = values.astype(dt)
    back = stored.astype(np.float64)
    if not (np.isfinite(back).all() and (back >= 1e-100).all() and back.max() <= min(rmax, 1e100)
            and rmax <= 2.0 * back.max()):
        why.append(f"a stored radius of {bad_value if bad_value is not None else back.max()!r} (rmax {rmax!r}, {dtype})")
    data = stored.tobytes()
    size = r.pick(["short", "long", "empty", "ppd2"]) if r.chance(0.1) else "exact"
    data = resize_data(data, size, ppd, why)
    expect, either = read_expect(why, ppd, rmax, f, re_, dtype, order)
    case = {"op": "read", "header": header, "data": data, "expect": expect, "why": "; ".join(why),
            "open": r.pick(["hdr", "hdr", "dem", "stem"]), "names": ["d.hdr", "d.dem"], "files": True}
    if r.chance(0.04):
        case["special"] = r.pick(["dir", "fifo", "loop", "dangling"])
        case["special_which"] = r.pick(["hdr", "dem"])
        case["expect"], case["why"] = None, f"the .{case['special_which']} is a {case['special']}"
        return case
    if either and len(why) == 1:
        case["either"] = True
    if expect is not None and not either:
        case["must_succeed"] = True
        u = np.array([[1.0, 0, 0], [0, 0, 1.0], [0.3, -0.5, 0.8], [0, 1.0, 0]])
        case["rays"] = (u * rmax * 2.0, -u + np.array([0, 0.1, 0]) * r.pick([0.0, 0.3]))
        if r.chance(0.2):
            case["shrink"] = r.pick([0, len(data) // 2, len(data) - 4])
    return case


def cli_case(r: R, seed: int) -> dict:
    """strategies.cli_cases"""
    rmax = 3390.0
    n = r.int(0, 6)
    g = r.g
    u = _unit(g.standard_normal((max(n, 1), 3)))
    s = u * rmax * g.uniform(1.1, 3.0, (max(n, 1), 1))
    l = -u + 0.2 * g.standard_normal((max(n, 1), 3))
    rows = [[repr(float(x)) for x in np.concatenate([s[k], l[k]])] for k in range(n)]
    lines = []
    for k, row in enumerate(rows):
        for _ in range(r.int(0, 1)):
            lines.append((r.pick(["# comment", "", "   ", "#"]), None))
        sep = r.pick([" ", "  ", "\t", " \t "])
        tail = r.pick(["", "", "  # ray comment"])
        lines.append((sep.join(row) + tail, k))
    bad = r.pick(["nan", "inf", "word", "cols5", "cols7", "comma", "inside", "hex"]) if n and r.chance(0.25) else None
    why, bad_line = spoil_ray_line(lines, rows, bad, r.int)
    eol = r.pick(["\n", "\r\n", "\r"])
    content = eol.join(t for t, _ in lines) + (eol if r.chance(0.5) else "")
    if r.chance(0.1) and not bad:
        content = r.pick(["", "# only a comment\n", "\n\n"])
        n = 0
    options = []
    threads = None
    for opt, vals in (("--method", ["stepping", "exact"]), ("--dem-read-mode", ["0", "1"]),
                      ("--io", ["records", "mmap"]), ("--threads", ["0", "1", "2", "-1", "100000", "x"])):
        if r.chance(0.3):
            v = r.pick(vals)
            options += [opt, v]
            if opt == "--threads":
                threads = v
    case = {"op": "cli_run", "dem": {"ppd": 1, "base": 3380.0, "rough": 1.0, "seed": 1, "f": 1 / 169.8,
                                     "re": 3390.0, "rmax": rmax},
            "rays": content.encode(), "options": options, "why": why,
            "names": ["rays.txt", "cli.hdr", "cli.dem", "threads", "--threads", "--io"]}
    bad_threads = threads in ("-1", "100000", "x")
    # --io mmap needs --dem-read-mode 1 (refused before the rays file is read)
    given = dict(zip(options[::2], options[1::2]))
    bad_io = given.get("--io") == "mmap" and given.get("--dem-read-mode") != "1"
    if r.chance(0.03):
        case["special"] = r.pick(["dir", "fifo", "loop", "dangling"])
        return case
    if bad_io:
        case["why"] = "--io mmap without --dem-read-mode 1"
        return case
    if not bad:
        case["nrays"] = n
        if n and not bad_threads:
            case["must_succeed"] = True
    if bad_line is not None and not bad_threads:
        case["bad_line"] = bad_line
    return case


def selftest_case(r: R, seed: int) -> dict:
    """The harness's own test (never in MIX): now and then a real segfault in the worker."""
    return {"op": "selftest", "action": "segfault" if r.chance(0.02) else "none", "names": []}


GENERATORS = {"selftest": selftest_case, "intersect": intersect_case, "radius": radius_case, "detector": detector_case,
              "from_array": from_array_case, "mutate": mutate_case, "read": header_case, "cli_run": cli_case}


def gen_case(seed: int, batch: int, i: int, mix: dict | None = None) -> dict:
    """Case ``i`` of batch ``batch`` under ``seed`` (deterministic)."""
    mix = mix or MIX
    r = R(np.random.default_rng([seed, batch, i]))
    ops_, w = list(mix), np.array(list(mix.values()), dtype=float)
    op = ops_[int(np.searchsorted(np.cumsum(w / w.sum()), r.g.random(), side="right").clip(0, len(ops_) - 1))]
    if op not in GENERATORS:
        return family_generators()[op](r, seed)
    return GENERATORS[op](r, seed)


def spec_cached(cache: dict, spec: dict, build, limit: int = 200):
    """The object a spec describes, built once per worker (``build()``; DSMs, DEMs and images are
    immutable), the cache emptied when it holds more than ``limit``."""
    key = repr(sorted(spec.items()))
    obj = cache.get(key)
    if obj is None:
        obj = build()
        if len(cache) > limit:
            cache.clear()
        cache[key] = obj
    return obj


def family_generators() -> dict:
    """The generators of the other systems' families (geo.py, grs.py, sim.py), which import this module."""
    from .geo import GENERATORS as geo_generators
    from .grs import GENERATORS as grs_generators
    from .sim import GENERATORS as sim_generators

    return {**geo_generators, **grs_generators, **sim_generators}


# ---------------------------------------------------------------------------- worker side
def run_batch(msg: dict) -> dict:
    """Generate and perform ``msg["n"]`` cases in this (worker) process; judge each."""
    import os
    import tempfile
    import traceback
    import warnings
    from pathlib import Path

    from . import ops
    from .harness import Outcome, judge, signature

    if ops.DEM_CACHE is None:
        ops.DEM_CACHE = {}
    seed, batch, n = msg["seed"], msg["batch"], msg["n"]
    mix = msg.get("mix")
    shared = Path(tempfile.mkdtemp(prefix="pifuzz-bulk-"))
    out = {"cases": 0, "api_calls": 0, "by_op": {}, "failures": [], "kinds": {}}
    try:
        for i in range(n):
            case = gen_case(seed, batch, i, mix)
            op = case["op"]
            t_dir = None
            try:
                if op in ("read", "cli_run") or case.get("all_configs") or case.get("kwargs", {}).get("dem_read_mode") == 1:
                    t_dir = tempfile.TemporaryDirectory(prefix="pifuzz-", dir=None)
                    tmp = Path(t_dir.name)
                else:
                    tmp = shared                                   # these ops write nothing
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always")
                    info = ops.OPS[op](case, tmp) or {}
                    caught = [w for w in caught if not issubclass(w.category, (DeprecationWarning, ResourceWarning))
                              and not ops.documented_warning(w)]
                    if caught:
                        w = caught[0]
                        ops.fail(f"a {w.category.__name__} was emitted: {w.message} "
                                 f"({os.path.basename(w.filename)}:{w.lineno})")
                res = Outcome("ok", info)
            except ops.PropertyViolation as exc:
                res = Outcome("violation", str(exc))
            except ops.CLIFailure as exc:
                res = Outcome("cli", str(exc))
            except MemoryError as exc:
                res = Outcome("error", (["MemoryError"], str(exc), traceback.format_exc(limit=-8)))
            except Exception as exc:  # noqa: BLE001 - judged below, as the worker's per-case path does
                res = Outcome("error", ([c.__name__ for c in type(exc).__mro__], str(exc),
                                       traceback.format_exc(limit=-8)))
            finally:
                if t_dir is not None:
                    t_dir.cleanup()
            out["cases"] += 1
            out["by_op"][op] = out["by_op"].get(op, 0) + 1
            calls = int(res.detail.get("calls", 1)) if res.kind == "ok" and isinstance(res.detail, dict) else 1
            out["api_calls"] += calls
            kind = res.kind if res.kind != "error" else "error:" + res.detail[0][0]
            out["kinds"][kind] = out["kinds"].get(kind, 0) + 1
            failure = judge(case, res)
            if failure and len(out["failures"]) < 20:
                out["failures"].append((i, signature(case, failure), case, failure))
            if len(ops.DEM_CACHE) > 400:
                ops.DEM_CACHE.clear()
    finally:
        import shutil

        shutil.rmtree(shared, ignore_errors=True)
    return out


# ---------------------------------------------------------------------------- parent side
class BulkRun:
    """Batches over one or more crash-safe workers until a call count or a time is reached."""

    def __init__(self, seed: int, calls: int | None = None, minutes: float | None = None, jobs: int = 1,
                 batch: int = 300, timeout: float = 20.0, mix: dict | None = None, log=print):
        from .harness import Worker

        self.seed, self.target_calls, self.jobs, self.batch = seed, calls, jobs, batch
        self.t_end = time.monotonic() + 60.0 * minutes if minutes else None
        self.timeout, self.mix, self.log = timeout, mix, log
        self.workers = [Worker(timeout=timeout) for _ in range(jobs)]
        self.lock = threading.Lock()
        self.next_batch = 0
        self.cases = self.api_calls = self.batches = 0
        self.by_op, self.kinds = {}, {}
        self.failures = {}                     # signature -> (case, failure)
        self.t0 = time.monotonic()

    def _more(self) -> int | None:
        with self.lock:
            if self.target_calls is not None and self.api_calls >= self.target_calls:
                return None
            if self.t_end is not None and time.monotonic() >= self.t_end:
                return None
            b = self.next_batch
            self.next_batch += 1
            return b

    def _record(self, sig, case, failure):
        from .harness import describe

        with self.lock:
            new = sig not in self.failures
            self.failures.setdefault(sig, (case, failure))
        if new:
            self.log(f"[bulk] NEW FAILURE:\n{describe(case, failure)}\n")

    def _replay(self, worker, b: int, first_failure: str):
        """A batch crashed or hung: find the case by performing them one at a time."""
        from .harness import judge, signature

        self.log(f"[bulk] batch {b} (seed {self.seed}): {first_failure.splitlines()[0]}; replaying its cases singly")
        for i in range(self.batch):
            case = gen_case(self.seed, b, i, self.mix)
            failure = judge(case, worker.call(case))
            if failure and (failure.startswith("CRASH") or failure.startswith("HANG")):
                self._record(signature(case, failure), dict(case, bulk_id=(self.seed, b, i)), failure)
                return
        self._record(f"batch: {first_failure.splitlines()[0][:80]}",
                     {"op": "bulk", "seed": self.seed, "batch": b, "n": self.batch, "names": []},
                     first_failure + "\n(not reproduced by its cases one at a time: depends on the worker's state)")

    def _loop(self, worker):
        from .harness import judge

        while (b := self._more()) is not None:
            msg = {"op": "bulk", "seed": self.seed, "batch": b, "n": self.batch, "mix": self.mix, "names": []}
            res = worker.call(msg, timeout=self.timeout + 0.5 * self.batch)
            if res.kind != "ok":
                failure = judge(msg, res) or f"{res.kind}: {res.detail}"
                self._replay(worker, b, failure)
                continue
            d = res.detail
            with self.lock:
                self.batches += 1
                self.cases += d["cases"]
                self.api_calls += d["api_calls"]
                for k, v in d["by_op"].items():
                    self.by_op[k] = self.by_op.get(k, 0) + v
                for k, v in d["kinds"].items():
                    self.kinds[k] = self.kinds.get(k, 0) + v
            for i, sig, case, failure in d["failures"]:
                self._record(sig, dict(case, bulk_id=(self.seed, b, i)), failure)

    def run(self, progress: float = 60.0):
        threads = [threading.Thread(target=self._loop, args=(w,), daemon=True) for w in self.workers]
        for t in threads:
            t.start()
        last = time.monotonic()
        try:
            while any(t.is_alive() for t in threads):
                for t in threads:
                    t.join(timeout=1.0)
                if time.monotonic() - last > progress:
                    last = time.monotonic()
                    dt = last - self.t0
                    self.log(f"[bulk] {dt / 60:.1f} min: {self.cases} cases, {self.api_calls} API calls "
                             f"({self.api_calls / dt:.0f}/s), {len(self.failures)} kinds of failure, "
                             f"restarts {self.restarts}")
        finally:
            for w in self.workers:
                w.close()
        self.seconds = time.monotonic() - self.t0
        return self

    @property
    def restarts(self) -> int:
        return sum(w.restarts for w in self.workers)
