"""Global PDS3 radius and height grids (simple cylindrical, with a label) as DEMs.

Most planetary shape products in the PDS archive are raw grids described by a
PDS3 label: LRO LOLA's LDEM_*, MGS MOLA's MEGDR (``megr``/``megt``), and many
more. :func:`pds_dem` reads such a label (detached ``.LBL`` or attached at the
start of the ``.IMG``), checks that the grid is what a planet-intersect DEM is
(global, 180 ppd x 360 ppd, pixel-registered, east longitudes from a multiple
of a pixel, one band, no prefix or suffix bytes, every value valid), and
returns a :class:`~planet_intersect.DEM` in km, south row first, with the
label's reference spheroid (A_AXIS_RADIUS, C_AXIS_RADIUS) in the header.

Values: ``DN * SCALING_FACTOR + OFFSET`` in the image's ``UNIT`` is a radius
(LOLA: OFFSET = 1,737,400 m, MEGDR radius grids: 3,396,000 m). A product of
heights (MEGDR topography: OFFSET = 0) needs ``heights_above`` (the sphere's
radius in km that the heights are above; a geoid grid is not a sphere: add it
with :func:`planet_intersect.mola.mola_dem` or by hand). A grid whose median
value is not within a factor 2 of A_AXIS_RADIUS is refused as heights, with
that hint.

Only what the DEM format can hold is accepted; anything else is a
:class:`PDSError` naming the file and the keyword: west-positive longitudes,
regional or node-registered grids, several bands, line prefixes, values equal
to MISSING_CONSTANT or not finite (the format has no no-data).
"""

from __future__ import annotations

import math
import os
import re
import warnings
from pathlib import Path

import numpy as np

from .dem import DEM

__all__ = ["PDSError", "read_pds3_label", "pds_dem", "import_pds"]

#: the most label bytes read (an attached label sits in front of its data)
LABEL_MAX_BYTES = 1_000_000
_MAX_DEPTH = 32

#: PDS3 SAMPLE_TYPE -> NumPy byte order and kind
_SAMPLE_TYPES = {
    "MSB_INTEGER": (">", "i"), "SUN_INTEGER": (">", "i"), "MAC_INTEGER": (">", "i"), "INTEGER": (">", "i"),
    "LSB_INTEGER": ("<", "i"), "PC_INTEGER": ("<", "i"), "VAX_INTEGER": ("<", "i"),
    "MSB_UNSIGNED_INTEGER": (">", "u"), "UNSIGNED_INTEGER": (">", "u"), "SUN_UNSIGNED_INTEGER": (">", "u"),
    "MAC_UNSIGNED_INTEGER": (">", "u"),
    "LSB_UNSIGNED_INTEGER": ("<", "u"), "PC_UNSIGNED_INTEGER": ("<", "u"), "VAX_UNSIGNED_INTEGER": ("<", "u"),
    "IEEE_REAL": (">", "f"), "FLOAT": (">", "f"), "REAL": (">", "f"), "SUN_REAL": (">", "f"),
    "MAC_REAL": (">", "f"), "PC_REAL": ("<", "f"),
}
#: value UNIT -> factor to km
_UNITS = {"METER": 1e-3, "METERS": 1e-3, "M": 1e-3, "KILOMETER": 1.0, "KILOMETERS": 1.0, "KM": 1.0}


class PDSError(ValueError):
    """A PDS3 label or its grid that cannot be read as a DEM (the message names the file)."""


# ------------------------------------------------------------------ the label
_TOKEN = re.compile(r'"[^"]*"|\'[^\']*\'|/\*.*?\*/|<[^<>]*>|[{}(),=]|[^\s{}(),=<>"\']+', re.S)


def _scalar(tok: str):
    """A PDS3 value token as int, float or str (quotes removed, white space collapsed)."""
    if tok[:1] in "\"'":
        return " ".join(tok[1:-1].split())
    t = tok.strip()
    try:
        return int(t)
    except ValueError:
        pass
    try:
        v = float(t)
        return v
    except ValueError:
        return t


def read_pds3_label(path: str | os.PathLike) -> dict:
    """The PDS3 label at the start of ``path`` as nested dicts.

    Keys keep their case-folded names (upper case); an ``OBJECT = NAME`` block
    becomes a dict stored under ``"OBJECT:NAME"`` (a second one of the same
    name under ``"OBJECT:NAME#2"``...), a GROUP likewise under ``"GROUP:NAME"``.
    Values are int, float or str; a value with a unit is ``(value, "unit")``;
    sets and sequences are tuples. Reading stops at the ``END`` statement; the
    label must end within the first :data:`LABEL_MAX_BYTES` bytes.
    """
    path = Path(path)
    if not path.exists():
        raise PDSError(f"PDS label {path}: no such file")
    if not path.is_file():
        raise PDSError(f"PDS label {path}: not a regular file")
    try:
        with open(path, "rb") as fh:
            raw = fh.read(LABEL_MAX_BYTES)
    except OSError as exc:
        raise PDSError(f"PDS label {path}: cannot be read ({exc.strerror or exc})") from None
    text = raw.decode("latin-1")
    m = re.search(r"(?m)^[ \t]*END[ \t]*(?:/\*.*?\*/[ \t]*)?\r?$", text)
    if m is None:
        raise PDSError(f"PDS label {path}: no END statement in its first {LABEL_MAX_BYTES:,} bytes "
                       f"(not a PDS3 label?)")
    toks = [t for t in _TOKEN.findall(text[:m.start()]) if not t.startswith("/*")]
    root: dict = {}
    stack = [root]
    i, n = 0, len(toks)

    def bad(what):
        return PDSError(f"PDS label {path}: {what}")

    def value(i):
        """Parse one value from toks[i]; return (value, next index)."""
        if i >= n:
            raise bad("a keyword without a value at the end")
        t = toks[i]
        if t in "({":
            close = ")" if t == "(" else "}"
            items, i = [], i + 1
            depth = 0
            while True:
                if i >= n:
                    raise bad(f"an unclosed {t!r} list")
                if toks[i] == close:
                    return tuple(items), i + 1
                if toks[i] == ",":
                    i += 1
                    continue
                if toks[i] in "({":
                    depth += 1
                    if depth > _MAX_DEPTH:
                        raise bad("lists nested too deep")
                v, i = value(i)
                items.append(v)
        if t in "=),}" or t.startswith("<"):
            raise bad(f"unexpected {t!r} where a value should be")
        v = _scalar(t)
        if i + 1 < n and toks[i + 1].startswith("<"):
            return (v, toks[i + 1][1:-1].strip()), i + 2
        return v, i + 1

    while i < n:
        key = toks[i]
        if key in "={}(),<>" or key[:1] in "\"'<":
            raise bad(f"unexpected {key!r} where a keyword should be")
        if i + 1 >= n or toks[i + 1] != "=":
            if key.upper() in ("END_OBJECT", "END_GROUP"):
                i += 1
                if len(stack) == 1:
                    raise bad(f"{key.upper()} without its OBJECT or GROUP")
                stack.pop()
                continue
            raise bad(f"keyword {key!r} without '='")
        v, i = value(i + 2)
        k = key.upper()
        if k in ("OBJECT", "GROUP"):
            if not isinstance(v, str):
                raise bad(f"{k} = {v!r}: not a name")
            name = f"{k}:{v.upper()}"
            j = 2
            while name in stack[-1]:
                name = f"{k}:{v.upper()}#{j}"
                j += 1
            child: dict = {}
            stack[-1][name] = child
            stack.append(child)
            if len(stack) > _MAX_DEPTH:
                raise bad("objects nested too deep")
        elif k in ("END_OBJECT", "END_GROUP"):
            if len(stack) == 1:
                raise bad(f"{k} without its OBJECT or GROUP")
            stack.pop()
        else:
            stack[-1][k] = v
    if len(stack) != 1:
        raise bad("an OBJECT or GROUP is not closed before END")
    return root


def _find(tree: dict, key: str, where=None):
    """(value, the dict holding it) of the first ``key`` in ``tree``, depth first; (None, None)."""
    if key in tree:
        return tree[key], tree
    for k, v in tree.items():
        if isinstance(v, dict):
            got, holder = _find(v, key)
            if holder is not None:
                return got, holder
    return None, None


def _num(obj: dict, key: str, path, what: str, default=None, unit_to=None):
    """A number from ``obj[key]`` (units: ``unit_to`` maps a unit to a factor)."""
    v = obj.get(key, default)
    if v is None:
        raise PDSError(f"PDS label {path}: {what} has no {key}")
    unit = None
    if isinstance(v, tuple) and len(v) == 2 and isinstance(v[1], str):
        v, unit = v
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise PDSError(f"PDS label {path}: {key} = {v!r} is not a number")
    if unit_to is not None and unit is not None:
        u = unit.upper().replace(" ", "")
        if u not in unit_to:
            raise PDSError(f"PDS label {path}: {key} in <{unit}>, expected one of {sorted(unit_to)}")
        v = v * unit_to[u]
    return v


def _text(obj: dict, key: str, default=None):
    v = obj.get(key, default)
    if isinstance(v, tuple) and len(v) == 2 and isinstance(v[1], str):
        v = v[0]
    return " ".join(str(v).upper().split()) if v is not None else None


# ------------------------------------------------------------------ the grid
def _data_file(label_path: Path, pointer, holder: dict, path) -> tuple[Path, int]:
    """(file, byte offset) of ^IMAGE: "FILE", ("FILE", record), record, or n <BYTES>."""
    record_bytes = holder.get("RECORD_BYTES")

    def records(nrec):
        if isinstance(nrec, tuple) and len(nrec) == 2 and str(nrec[1]).upper() == "BYTES":
            b = nrec[0]
            if not isinstance(b, int) or b < 1:
                raise PDSError(f"PDS label {path}: ^IMAGE byte offset {b!r} is not a positive integer")
            return b - 1
        if not isinstance(nrec, int) or nrec < 1:
            raise PDSError(f"PDS label {path}: ^IMAGE record {nrec!r} is not a positive integer")
        if not isinstance(record_bytes, int) or record_bytes < 1:
            raise PDSError(f"PDS label {path}: ^IMAGE points to record {nrec} but RECORD_BYTES is "
                           f"{record_bytes!r}")
        return (nrec - 1) * record_bytes

    if isinstance(pointer, str):
        name, offset = pointer, 0
    elif isinstance(pointer, tuple) and len(pointer) == 2 and isinstance(pointer[0], str) and \
            not (isinstance(pointer[1], str)):
        name, offset = pointer[0], records(pointer[1])
    else:
        return label_path, records(pointer)              # attached: the data follow in the same file
    cand = label_path.parent / name
    if not cand.is_file():                               # PDS names are upper case; disks often not
        low = {p.name.lower(): p for p in label_path.parent.iterdir()} if label_path.parent.is_dir() else {}
        cand = low.get(name.lower(), cand)
    if not cand.is_file():
        raise PDSError(f"PDS label {path}: its ^IMAGE file {name!r} is not beside it ({cand})")
    return cand, offset


def _grid(path: Path, tree: dict):
    """(values [nlat, nlon] float64 as in the file's order, row 0 north, and the metadata)."""
    img, _ = _find(tree, "OBJECT:IMAGE")
    if not isinstance(img, dict):
        raise PDSError(f"PDS label {path}: no IMAGE object")
    lines = _num(img, "LINES", path, "IMAGE")
    samples = _num(img, "LINE_SAMPLES", path, "IMAGE")
    bits = _num(img, "SAMPLE_BITS", path, "IMAGE")
    bands = _num(img, "BANDS", path, "IMAGE", default=1)
    for k, v in (("LINES", lines), ("LINE_SAMPLES", samples), ("SAMPLE_BITS", bits), ("BANDS", bands)):
        if not isinstance(v, int) or v < 1:
            raise PDSError(f"PDS label {path}: {k} = {v!r} is not a positive integer")
    if bands != 1:
        raise PDSError(f"PDS label {path}: BANDS = {bands}: a DEM has one band")
    for k in ("LINE_PREFIX_BYTES", "LINE_SUFFIX_BYTES"):
        if img.get(k, 0) not in (0, (0, "BYTES")):
            raise PDSError(f"PDS label {path}: {k} = {img[k]!r} is not supported (only plain rows of samples)")
    st = _text(img, "SAMPLE_TYPE")
    if st not in _SAMPLE_TYPES:
        raise PDSError(f"PDS label {path}: SAMPLE_TYPE = {st!r} is not one of {sorted(_SAMPLE_TYPES)}")
    order, kind = _SAMPLE_TYPES[st]
    if (kind == "f" and bits not in (32, 64)) or (kind in "iu" and bits not in (8, 16, 32)):
        raise PDSError(f"PDS label {path}: SAMPLE_BITS = {bits} with SAMPLE_TYPE = {st}")
    dtype = np.dtype(f"{order if bits > 8 else '|'}{kind}{bits // 8}")
    unit = _text(img, "UNIT")
    if unit not in _UNITS:
        raise PDSError(f"PDS label {path}: the IMAGE's UNIT is {unit!r}; expected metres or km "
                       f"({', '.join(sorted(_UNITS))})")
    scale = _num(img, "SCALING_FACTOR", path, "IMAGE", default=1.0)
    offset = _num(img, "OFFSET", path, "IMAGE", default=0.0)
    if scale == 0:
        raise PDSError(f"PDS label {path}: SCALING_FACTOR = 0")
    missing = [img[k] for k in ("MISSING_CONSTANT", "INVALID_CONSTANT", "NULL_CONSTANT", "CORE_NULL")
               if isinstance(img.get(k), (int, float))]

    proj, _ = _find(tree, "OBJECT:IMAGE_MAP_PROJECTION")
    if not isinstance(proj, dict):
        raise PDSError(f"PDS label {path}: no IMAGE_MAP_PROJECTION object (is the grid in latitude/longitude?)")
    ptype = _text(proj, "MAP_PROJECTION_TYPE")
    if ptype not in ("SIMPLE CYLINDRICAL", "EQUIRECTANGULAR"):
        raise PDSError(f"PDS label {path}: MAP_PROJECTION_TYPE = {ptype!r}; only SIMPLE CYLINDRICAL (or "
                       f"EQUIRECTANGULAR about the equator) grids are latitude/longitude grids")
    if ptype == "EQUIRECTANGULAR" and _num(proj, "CENTER_LATITUDE", path, "IMAGE_MAP_PROJECTION", 0.0) != 0:
        raise PDSError(f"PDS label {path}: EQUIRECTANGULAR with CENTER_LATITUDE != 0 has non-square degrees")
    direction = _text(proj, "POSITIVE_LONGITUDE_DIRECTION", "EAST")
    if direction != "EAST":
        raise PDSError(f"PDS label {path}: POSITIVE_LONGITUDE_DIRECTION = {direction}: only east longitudes are "
                       f"read (flip the columns and relabel the grid)")
    res = _num(proj, "MAP_RESOLUTION", path, "IMAGE_MAP_PROJECTION")
    lat_hi = _num(proj, "MAXIMUM_LATITUDE", path, "IMAGE_MAP_PROJECTION")
    lat_lo = _num(proj, "MINIMUM_LATITUDE", path, "IMAGE_MAP_PROJECTION")
    west = _num(proj, "WESTERNMOST_LONGITUDE", path, "IMAGE_MAP_PROJECTION")
    east = _num(proj, "EASTERNMOST_LONGITUDE", path, "IMAGE_MAP_PROJECTION")
    if not (lat_hi == 90 and lat_lo == -90 and abs(east - west) == 360):
        raise PDSError(f"PDS label {path}: latitudes {lat_lo}..{lat_hi}, longitudes {west}..{east}: a DEM is a "
                       f"global grid (-90..90, 360 degrees of longitude)")
    if not (res > 0 and lines == round(180 * res) and samples == 2 * lines and abs(lines - 180 * res) < 1e-9):
        raise PDSError(f"PDS label {path}: LINES = {lines}, LINE_SAMPLES = {samples} and MAP_RESOLUTION = {res} "
                       f"pixels/degree are not a 180 ppd x 360 ppd grid")
    ppd = lines // 180
    shift = west * ppd
    if abs(shift - round(shift)) > 1e-6:
        raise PDSError(f"PDS label {path}: WESTERNMOST_LONGITUDE = {west} is not on a pixel edge "
                       f"(multiples of 1/{ppd} degree)")
    # where the offset is given, it must put the first line's centre half a pixel below 90 degrees.
    # Archives count lines two ways: LINE = LINE_PROJECTION_OFFSET - RES LAT + 1 (the MGS MOC and
    # RSS data sets' DSMAP.CAT; LOLA's LDEM: 359.5 at 4 ppd) and LINE = LINE_PROJECTION_OFFSET -
    # RES LAT (MOLA's EGDR SIS; MEGDR: 360.5 at 4 ppd), line 1 at the top: both are accepted.
    # A node-registered grid is half a pixel off either.
    lpo = proj.get("LINE_PROJECTION_OFFSET")
    if lpo is not None:
        lpo = _num(proj, "LINE_PROJECTION_OFFSET", path, "IMAGE_MAP_PROJECTION")
        first = 90.0 - 0.5 / ppd
        if not any(abs(lpo - k - first * ppd) < 1e-6 for k in (0, 1)):
            raise PDSError(f"PDS label {path}: LINE_PROJECTION_OFFSET = {lpo} does not put the first line's "
                           f"centre at {first} degrees (a node-registered grid?)")
    nbytes = lines * samples * dtype.itemsize
    pointer, holder = _find(tree, "^IMAGE")
    if pointer is None:
        raise PDSError(f"PDS label {path}: no ^IMAGE pointer")
    data, start = _data_file(path, pointer, holder, path)
    size = data.stat().st_size
    if size < start + nbytes:
        raise PDSError(f"PDS data {data}: {size:,} bytes, the label needs {start + nbytes:,} "
                       f"({lines} x {samples} samples of {dtype.itemsize} bytes from byte {start:,})")
    raw = np.memmap(data, dtype=dtype, mode="r", offset=start, shape=(lines, samples))
    if missing:
        bad = int(np.isin(raw, np.asarray(missing, dtype=np.float64)).sum())
        if bad:
            raise PDSError(f"PDS data {data}: {bad:,} samples equal a missing/invalid constant "
                           f"({', '.join(map(repr, missing))}); a DEM has no no-data cells")
    if kind == "f":
        finite = np.isfinite(raw)
        if not finite.all():
            raise PDSError(f"PDS data {data}: {int((~finite).sum()):,} samples are NaN or infinite")
    values = raw.astype(np.float64) * scale + offset
    del raw
    meta = dict(ppd=ppd, west=west, unit_km=_UNITS[unit], data=data, scale=scale, offset=offset, unit=unit,
                sample_type=st, bits=bits)
    return values, meta


def _spheroid(path: Path, tree: dict):
    """(re km, f) from A_AXIS_RADIUS, B and C (km unless a unit says otherwise); (None, 0) if absent."""
    proj, _ = _find(tree, "OBJECT:IMAGE_MAP_PROJECTION")
    units = {"KM": 1.0, "KILOMETER": 1.0, "KILOMETERS": 1.0, "M": 1e-3, "METER": 1e-3, "METERS": 1e-3}
    if proj.get("A_AXIS_RADIUS") is None:
        return None, 0.0
    a = _num(proj, "A_AXIS_RADIUS", path, "IMAGE_MAP_PROJECTION", unit_to=units)
    b = _num(proj, "B_AXIS_RADIUS", path, "IMAGE_MAP_PROJECTION", default=a, unit_to=units)
    c = _num(proj, "C_AXIS_RADIUS", path, "IMAGE_MAP_PROJECTION", default=a, unit_to=units)
    if not (a > 0 and 0 < c <= a):
        raise PDSError(f"PDS label {path}: A_AXIS_RADIUS = {a} km and C_AXIS_RADIUS = {c} km are not an oblate "
                       f"spheroid (0 < C <= A)")
    if abs(b - a) > 1e-9 * a:
        warnings.warn(f"PDS label {path}: a triaxial reference (A {a}, B {b}, C {c} km); the DEM's spheroid is "
                      f"A and C", UserWarning, stacklevel=3)
    return float(a), float(1.0 - c / a)


def pds_dem(label: str | os.PathLike, *, heights_above: float | None = None, dtype="float32") -> DEM:
    """A DEM in km from a global PDS3 simple-cylindrical grid and its label.

    label: the ``.LBL`` (or an ``.IMG`` with its label attached).
    heights_above: for a product of heights, the radius (km) of the sphere
    they are above; added to every value. dtype: the radii's type in memory
    (float32, as the MOLA reader; its rounding at a 1,737 km radius is
    0.12 m, below LOLA's 0.5 m steps; "float64" to keep every bit).
    See the module's docstring for what is accepted.
    """
    path = Path(label)
    tree = read_pds3_label(path)
    values, meta = _grid(path, tree)
    re_km, f = _spheroid(path, tree)
    km = values * meta["unit_km"]
    if heights_above is not None:
        if isinstance(heights_above, bool) or not isinstance(heights_above, (int, float)) or \
                not (math.isfinite(heights_above) and heights_above > 0):
            raise PDSError(f"heights_above: a positive radius in km, got {heights_above!r}")
        km = km + float(heights_above)
    elif re_km is not None:
        med = float(np.median(km))
        if not (0.5 * re_km <= med <= 2.0 * re_km):
            raise PDSError(f"PDS data {meta['data']}: its median value {med:.6g} km is not a radius near "
                           f"A_AXIS_RADIUS = {re_km} km (heights? give heights_above=the radius they are above)")
    if meta["west"] % 360:
        km = np.roll(km, int(round(meta["west"] * meta["ppd"])), axis=1)   # column 0 at 0 E
    if dtype not in ("float32", "float64", np.float32, np.float64):
        raise PDSError(f"dtype: float32 or float64, got {dtype!r}")
    return DEM.from_array(km[::-1].astype(dtype), f=f, re=re_km)        # north-first -> south-first


def import_pds(label: str | os.PathLike, out: str | os.PathLike, *, heights_above: float | None = None,
               overwrite: bool = False) -> Path:
    """Convert a PDS3 grid (see :func:`pds_dem`) to a ``.hdr``/``.dem`` pair (float32 km); return the ``.hdr``."""
    return pds_dem(label, heights_above=heights_above).write(out, dtype="float32", overwrite=overwrite)
