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
from typing import NamedTuple

import numpy as np

from ._status import DEMError
from .dem import DEM

__all__ = ["PDSError", "Quantity", "Based", "read_pds3_label", "pds_dem", "import_pds", "RADIUS_FACTOR"]

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
_TOKEN = re.compile(r'"[^"]*"|\'[^\']*\'|<[^<>]*>|[{}(),=]|[^\s{}(),=<>"\']+')
_SPECIAL = re.compile(r'["\']|/\*')
_RADIX = re.compile(r"^([0-9]{1,2})#([+-]?[0-9A-Za-z]+)#$")


class Quantity(NamedTuple):
    """A label value with its unit, ``5 <KM>``."""

    value: object
    unit: str


class Based(int):
    """A based integer of the label, ``16#FF7FFFFB#`` (for a real sample type: its bits)."""


def _scalar(tok: str):
    """A PDS3 value token as int, float or str (quotes removed, white space collapsed); a
    based integer (16#FF7FFFFB#) as :class:`Based`."""
    if tok[:1] in "\"'":
        return " ".join(tok[1:-1].split())
    t = tok.strip()
    m = _RADIX.match(t)
    if m:
        try:
            return Based(int(m.group(2), int(m.group(1))))
        except ValueError:
            return t
    try:
        return int(t)
    except ValueError:
        pass
    try:
        return float(t)
    except ValueError:
        return t


def _label_text(text: str, bad) -> str:
    """The label's statements up to its END line: comments (which PDS3 closes on their own
    line) replaced by a space, quoted strings kept whole across lines. Linear in the text."""
    kept, quote = [], None
    for no, line in enumerate(text.split("\n"), 1):
        buf, j = [], 0
        starts_outside = quote is None
        while j < len(line):
            if quote is not None:
                k = line.find(quote, j)
                if k < 0:
                    buf.append(line[j:])
                    break
                buf.append(line[j:k + 1])
                j, quote = k + 1, None
                continue
            m = _SPECIAL.search(line, j)
            if m is None:
                buf.append(line[j:])
                break
            buf.append(line[j:m.start()])
            if m.group() == "/*":
                k = line.find("*/", m.end())
                if k < 0:
                    raise bad(f"line {no}: a comment '/*' is not closed on its line")
                buf.append(" ")
                j = k + 2
            else:
                quote = m.group()
                buf.append(quote)
                j = m.end()
        done = "".join(buf)
        if starts_outside and quote is None and done.strip().upper() == "END":
            return "\n".join(kept)
        kept.append(done)
    if quote is not None:
        raise bad(f"a quoted string ({quote}) is not closed")
    raise bad(f"no END statement in its first {LABEL_MAX_BYTES:,} bytes (not a PDS3 label?)")


def read_pds3_label(path: str | os.PathLike) -> dict:
    """The PDS3 label at the start of ``path`` as nested dicts.

    Keys keep their case-folded names (upper case); an ``OBJECT = NAME`` block
    becomes a dict stored under ``"OBJECT:NAME"`` (a second one of the same
    name under ``"OBJECT:NAME#2"``...), a GROUP likewise under ``"GROUP:NAME"``.
    Values are int, float or str; a based integer is a :class:`Based`; a
    value with a unit is a :class:`Quantity` (a tuple ``(value, "unit")``);
    sets and sequences are tuples.
    Reading stops at the ``END`` statement; the label must end within the first
    :data:`LABEL_MAX_BYTES` bytes. A keyword given twice in one object, an
    ``END_OBJECT`` naming another object, a comment not closed on its line
    and lists nested deeper than 32 are refused.
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

    def bad(what):
        return PDSError(f"PDS label {path}: {what}")

    head = raw.lstrip()[:64].upper()
    if raw and not head.startswith(b"PDS_VERSION_ID") and not head.startswith(b"/*") and \
            sum(32 <= b < 127 or b in (9, 10, 13) for b in raw[:512]) < 0.9 * min(len(raw), 512):
        # a data file without an attached label (LOLA's LDEM_4.IMG): its bytes were parsed as a label and
        # the message spoke of an unclosed comment at line 4735 (a review)
        raise bad("no PDS label at the start of this file (an attached label begins with PDS_VERSION_ID): "
                  "give the detached label, the .LBL file beside it")
    toks = _TOKEN.findall(_label_text(raw.decode("latin-1"), bad))
    root: dict = {}
    stack: list = [(root, None)]
    i, n = 0, len(toks)

    def value(i, depth=0):
        """Parse one value from toks[i]; return (value, next index)."""
        if depth > _MAX_DEPTH:
            raise bad("lists nested too deep")
        if i >= n:
            raise bad("a keyword without a value at the end")
        t = toks[i]
        if t in "({":
            close = ")" if t == "(" else "}"
            items, i = [], i + 1
            while True:
                if i >= n:
                    raise bad(f"an unclosed {t!r} list")
                if toks[i] == close:
                    v, i = tuple(items), i + 1
                    break
                if toks[i] == ",":
                    i += 1
                    continue
                v, i = value(i, depth + 1)
                items.append(v)
        else:
            if t in "=),}" or t.startswith("<"):
                raise bad(f"unexpected {t!r} where a value should be")
            v, i = _scalar(t), i + 1
        if i < n and toks[i].startswith("<"):
            return Quantity(v, toks[i][1:-1].strip()), i + 1
        return v, i

    while i < n:
        key = toks[i]
        if key in "={}(),<>" or key[:1] in "\"'<":
            raise bad(f"unexpected {key!r} where a keyword should be")
        k = key.upper()
        if i + 1 >= n or toks[i + 1] != "=":
            if k in ("END_OBJECT", "END_GROUP"):
                v, i = None, i + 1
            else:
                raise bad(f"keyword {key!r} without '='")
        else:
            v, i = value(i + 2)
        if k in ("OBJECT", "GROUP"):
            if not isinstance(v, str):
                raise bad(f"{k} = {v!r}: not a name")
            name = f"{k}:{v.upper()}"
            j = 2
            while name in stack[-1][0]:
                name = f"{k}:{v.upper()}#{j}"
                j += 1
            child: dict = {}
            stack[-1][0][name] = child
            stack.append((child, f"{k}:{v.upper()}"))
            if len(stack) > _MAX_DEPTH:
                raise bad("objects nested too deep")
        elif k in ("END_OBJECT", "END_GROUP"):
            opened = stack[-1][1]
            if opened is None or opened.split(":")[0] != k[4:]:
                raise bad(f"{k} without its {k[4:]}")
            if v is not None and f"{k[4:]}:{str(v).upper()}" != opened:
                raise bad(f"{k} = {v} closes {opened.replace(':', ' = ')}")
            stack.pop()
        else:
            if k in stack[-1][0]:
                raise bad(f"keyword {k} given twice" + (f" in {stack[-1][1].replace(':', ' = ')}"
                                                        if stack[-1][1] else ""))
            stack[-1][0][k] = v
    if len(stack) != 1:
        raise bad(f"{stack[-1][1].replace(':', ' = ')} is not closed before END")
    return root


def _find(tree: dict, key: str):
    """(value, the dict holding it) of the first ``key`` in ``tree``, depth first; (None, None)."""
    if key in tree:
        return tree[key], tree
    for v in tree.values():
        if isinstance(v, dict):
            got, holder = _find(v, key)
            if holder is not None:
                return got, holder
    return None, None


def _num(obj: dict, key: str, path, what: str, default=None, unit_to=None):
    """A finite number from ``obj[key]`` (units: ``unit_to`` maps an upper-case unit to a factor)."""
    v = obj.get(key, default)
    if v is None:
        raise PDSError(f"PDS label {path}: {what} has no {key}")
    unit = None
    if isinstance(v, Quantity):
        v, unit = v
    ok = not isinstance(v, bool) and isinstance(v, (int, float))
    if ok:
        try:
            ok = math.isfinite(float(v))
        except OverflowError:
            ok = False
    if not ok:
        raise PDSError(f"PDS label {path}: {key} = {v!r} is not a usable number")
    if unit_to is not None and unit is not None:
        u = unit.upper().replace(" ", "")
        if u not in unit_to:
            raise PDSError(f"PDS label {path}: {key} in <{unit}>, expected one of {sorted(unit_to)}")
        v = v * unit_to[u]
    return v


def _count(obj: dict, key: str, path, what: str, default=None, unit: str | None = None) -> int:
    """A non-negative integer from ``obj[key]`` (``unit``: the one unit it may carry)."""
    v = obj.get(key, default)
    if isinstance(v, Quantity) and unit is not None and v.unit.upper().replace(" ", "") == unit:
        v = v.value
    if v is None:
        raise PDSError(f"PDS label {path}: {what} has no {key}")
    if isinstance(v, bool) or not isinstance(v, int) or v < 0 or v > 2 ** 62:
        raise PDSError(f"PDS label {path}: {key} = {v!r} is not a whole number")
    return int(v)


def _text(obj: dict, key: str, default=None):
    v = obj.get(key, default)
    if isinstance(v, Quantity):
        v = v.value
    return " ".join(str(v).upper().split()) if v is not None else None


# ------------------------------------------------------------------ the grid
def _data_file(path: Path, pointer, holder: dict) -> tuple[Path, int]:
    """(file, byte offset) of ^IMAGE: "FILE", ("FILE", record), record, or n <BYTES>."""

    def records(nrec):
        if isinstance(nrec, Quantity) and str(nrec.unit).upper() == "BYTES":
            b = nrec.value
            if isinstance(b, bool) or not isinstance(b, int) or not 1 <= b <= 2 ** 62:
                raise PDSError(f"PDS label {path}: ^IMAGE byte offset {b!r} is not a positive integer")
            return b - 1
        if isinstance(nrec, bool) or not isinstance(nrec, int) or not 1 <= nrec <= 2 ** 40:
            raise PDSError(f"PDS label {path}: ^IMAGE record {nrec!r} is not a positive integer")
        record_bytes = _count(holder, "RECORD_BYTES", path, "the label (^IMAGE counts records)", unit="BYTES")
        if record_bytes < 1:
            raise PDSError(f"PDS label {path}: RECORD_BYTES = {record_bytes}")
        return (nrec - 1) * record_bytes

    if isinstance(pointer, str):
        name, offset = pointer, 0
    elif type(pointer) is tuple and len(pointer) == 2 and isinstance(pointer[0], str):
        name, offset = pointer[0], records(pointer[1])
    else:
        return path, records(pointer)                    # attached: the data follow in the same file
    if not name or "\x00" in name:
        raise PDSError(f"PDS label {path}: ^IMAGE names no file ({name!r})")
    cand = path.parent / name
    try:
        if not cand.is_file():                           # PDS names are upper case; disks often not
            low = {p.name.lower(): p for p in path.parent.iterdir()} if path.parent.is_dir() else {}
            cand = low.get(name.lower(), cand)
    except OSError as exc:
        raise PDSError(f"PDS label {path}: cannot look for its ^IMAGE file {name!r} "
                       f"({exc.strerror or exc})") from None
    if not cand.is_file():
        raise PDSError(f"PDS label {path}: its ^IMAGE file {name!r} is not beside it ({cand})")
    return cand, offset


def _missing_values(img: dict, dtype: np.dtype, path) -> list:
    """The label's missing/invalid constants as values of the sample type (based integers are
    bit patterns of the sample's width, the usual form for real samples)."""
    out = []
    for k in ("MISSING_CONSTANT", "INVALID_CONSTANT", "NULL_CONSTANT", "CORE_NULL"):
        v = img.get(k)
        if v is None:
            continue
        if isinstance(v, Quantity):
            v = v.value
        if isinstance(v, Based):
            width = dtype.itemsize * 8
            if not 0 <= v < 2 ** width:
                raise PDSError(f"PDS label {path}: {k} = {v:#x} does not fit {width}-bit samples")
            out.append(np.array(int(v), dtype=f"u{dtype.itemsize}").view(dtype.newbyteorder("=")).item())
        elif isinstance(v, (int, float)) and not isinstance(v, bool):
            if dtype.kind == "f":
                with np.errstate(over="ignore"):
                    out.append(np.array(v, dtype=dtype.newbyteorder("=")).item())
            elif dtype.kind in "iu" and float(v) == int(v) and \
                    np.iinfo(dtype).min <= int(v) <= np.iinfo(dtype).max:
                out.append(int(v))
            # an integer constant outside the sample type's range cannot occur in the data
        else:
            raise PDSError(f"PDS label {path}: {k} = {v!r} is not a number")
    return out


def _grid(path: Path, tree: dict, heights_above, dtype_out):
    """The radii in km as a DEM wants them (row 0 south, column 0 at 0 E) and the data file."""
    img, _ = _find(tree, "OBJECT:IMAGE")
    if not isinstance(img, dict):
        raise PDSError(f"PDS label {path}: no IMAGE object")
    lines = _count(img, "LINES", path, "IMAGE")
    samples = _count(img, "LINE_SAMPLES", path, "IMAGE")
    bits = _count(img, "SAMPLE_BITS", path, "IMAGE")
    bands = _count(img, "BANDS", path, "IMAGE", default=1)
    if bands != 1:
        raise PDSError(f"PDS label {path}: BANDS = {bands}: a DEM has one band")
    for k in ("LINE_PREFIX_BYTES", "LINE_SUFFIX_BYTES"):
        if _count(img, k, path, "IMAGE", default=0, unit="BYTES"):
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
    missing = _missing_values(img, dtype, path)

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
    if not (lat_hi == 90 and lat_lo == -90 and east - west == 360):
        raise PDSError(f"PDS label {path}: latitudes {lat_lo}..{lat_hi}, longitudes {west}..{east}: a DEM is a "
                       f"global grid (-90..90, and EASTERNMOST_LONGITUDE = WESTERNMOST_LONGITUDE + 360)")
    ppd = lines // 180
    if not (ppd >= 1 and lines == 180 * ppd and samples == 360 * ppd and res == ppd):
        raise PDSError(f"PDS label {path}: LINES = {lines}, LINE_SAMPLES = {samples} and MAP_RESOLUTION = {res} "
                       f"pixels/degree are not a 180 ppd x 360 ppd grid with a whole ppd >= 1")
    shift = west * ppd
    if abs(shift - round(shift)) > 1e-6:
        raise PDSError(f"PDS label {path}: WESTERNMOST_LONGITUDE = {west} is not on a pixel edge "
                       f"(multiples of 1/{ppd} degree)")
    # where the offsets are given, they must put the first line's centre half a pixel below 90 degrees
    # and the first sample's half a pixel east of WESTERNMOST_LONGITUDE. Archives count lines two ways:
    # LINE = LINE_PROJECTION_OFFSET - RES LAT + 1 (the MGS MOC and RSS data sets' DSMAP.CAT; LOLA's
    # LDEM: 359.5 at 4 ppd) and LINE = LINE_PROJECTION_OFFSET - RES LAT (MOLA's EGDR SIS; MEGDR: 360.5
    # at 4 ppd), line 1 at the top, and samples likewise: both are accepted. A node-registered grid
    # is half a pixel off either.
    if proj.get("LINE_PROJECTION_OFFSET") is not None:
        lpo = _num(proj, "LINE_PROJECTION_OFFSET", path, "IMAGE_MAP_PROJECTION")
        clat = _num(proj, "CENTER_LATITUDE", path, "IMAGE_MAP_PROJECTION", default=0.0)
        d = lpo - (90.0 - 0.5 / ppd - clat) * ppd
        if not any(abs(d - k) < 1e-6 for k in (0, 1)):
            raise PDSError(f"PDS label {path}: LINE_PROJECTION_OFFSET = {lpo} does not put the first line's "
                           f"centre at {90.0 - 0.5 / ppd} degrees (a node-registered grid?)")
    if proj.get("SAMPLE_PROJECTION_OFFSET") is not None and proj.get("CENTER_LONGITUDE") is not None:
        spo = _num(proj, "SAMPLE_PROJECTION_OFFSET", path, "IMAGE_MAP_PROJECTION")
        clon = _num(proj, "CENTER_LONGITUDE", path, "IMAGE_MAP_PROJECTION")
        d = (spo - (clon - west - 0.5 / ppd) * ppd) % samples
        if not any(abs(d - k) < 1e-6 or abs(d - k - samples) < 1e-6 for k in (0, 1)):
            raise PDSError(f"PDS label {path}: SAMPLE_PROJECTION_OFFSET = {spo} with CENTER_LONGITUDE = {clon} "
                           f"does not put the first sample's centre at {west + 0.5 / ppd} degrees")
    nbytes = lines * samples * dtype.itemsize
    pointer, holder = _find(tree, "^IMAGE")
    if pointer is None:
        raise PDSError(f"PDS label {path}: no ^IMAGE pointer")
    data, start = _data_file(path, pointer, holder)
    try:
        size = data.stat().st_size
        if size < start + nbytes:
            raise PDSError(f"PDS data {data}: {size:,} bytes, the label needs {start + nbytes:,} "
                           f"({lines} x {samples} samples of {dtype.itemsize} bytes from byte {start:,})")
        if data != path and size > start + nbytes + samples * dtype.itemsize:
            warnings.warn(f"PDS data {data}: {size - start - nbytes:,} bytes after the grid that its label "
                          f"{path} describes (read: the first {nbytes:,} from byte {start:,})", UserWarning,
                          stacklevel=4)
        raw = np.memmap(data, dtype=dtype, mode="r", offset=start, shape=(lines, samples))
    except OSError as exc:
        raise PDSError(f"PDS data {data}: cannot be read ({exc.strerror or exc})") from None
    unit_km = _UNITS[unit]
    roll = int(round(shift)) % samples
    try:
        out = np.empty((lines, samples), dtype=dtype_out)
        nbad = nonfinite = 0
        step = max(1, (1 << 22) // samples)               # ~4 M samples a block
        for r0 in range(0, lines, step):
            block = np.asarray(raw[r0:r0 + step])
            if missing:
                nbad += int(np.isin(block, missing).sum())
            v = block.astype(np.float64) * scale + offset
            v *= unit_km
            if heights_above is not None:
                v += heights_above
            nonfinite += int((~np.isfinite(v)).sum())
            if roll:
                v = np.roll(v, roll, axis=1)                # column 0 at 0 E
            out[lines - r0 - v.shape[0]:lines - r0] = v[::-1]   # north-first -> south-first
    except OSError as exc:
        raise PDSError(f"PDS data {data}: cannot be read ({exc.strerror or exc})") from None
    except MemoryError:
        raise PDSError(f"PDS data {data}: {lines:,} x {samples:,} radii of {np.dtype(dtype_out).itemsize} bytes "
                       f"do not fit in memory") from None
    finally:
        del raw
    if nbad:
        raise PDSError(f"PDS data {data}: {nbad:,} samples equal a missing/invalid constant "
                       f"({', '.join(map(repr, missing))}); a DEM has no no-data cells")
    if nonfinite:
        raise PDSError(f"PDS data {data}: {nonfinite:,} values are NaN or infinite (as samples, or after "
                       f"SCALING_FACTOR and OFFSET)")
    return out, data


def _spheroid(path: Path, tree: dict):
    """(re km, f) from A_AXIS_RADIUS, B and C (km unless a unit says otherwise); (None, 0) if absent."""
    proj, _ = _find(tree, "OBJECT:IMAGE_MAP_PROJECTION")
    if not isinstance(proj, dict):
        raise PDSError(f"PDS label {path}: no IMAGE_MAP_PROJECTION object (is the grid in latitude/longitude?)")
    units = {"KM": 1.0, "KILOMETER": 1.0, "KILOMETERS": 1.0, "M": 1e-3, "METER": 1e-3, "METERS": 1e-3}
    if proj.get("A_AXIS_RADIUS") is None:
        return None, 0.0
    a = _num(proj, "A_AXIS_RADIUS", path, "IMAGE_MAP_PROJECTION", unit_to=units)
    b = _num(proj, "B_AXIS_RADIUS", path, "IMAGE_MAP_PROJECTION", default=proj["A_AXIS_RADIUS"], unit_to=units)
    c = _num(proj, "C_AXIS_RADIUS", path, "IMAGE_MAP_PROJECTION", default=proj["A_AXIS_RADIUS"], unit_to=units)
    if not (a > 0 and 0 < c <= a):
        raise PDSError(f"PDS label {path}: A_AXIS_RADIUS = {a} km and C_AXIS_RADIUS = {c} km are not an oblate "
                       f"spheroid (0 < C <= A)")
    if abs(b - a) > 1e-9 * a:
        warnings.warn(f"PDS label {path}: a triaxial reference (A {a}, B {b}, C {c} km); the DEM's spheroid is "
                      f"A and C", UserWarning, stacklevel=3)
    return float(a), float(1.0 - c / a)


#: the median radius must lie within this factor of A_AXIS_RADIUS (else: heights, or heights added twice)
RADIUS_FACTOR = 1.5


def pds_dem(label: str | os.PathLike, *, heights_above: float | None = None, dtype="float32") -> DEM:
    """A DEM in km from a global PDS3 simple-cylindrical grid and its label.

    label: the ``.LBL`` (or an ``.IMG`` with its label attached).
    heights_above: for a product of heights, the radius (km) of the sphere
    they are above; added to every value. dtype: the radii's type in memory
    (float32, as the MOLA reader; its rounding at a 1,737 km radius is
    0.12 m, below LOLA's 0.5 m steps; "float64" to keep every bit).
    When the label gives A_AXIS_RADIUS, the median radius must lie within a
    factor :data:`RADIUS_FACTOR` of it (heights without ``heights_above``,
    or ``heights_above`` on a product of radii, are refused).
    See the module's docstring for what is accepted.
    """
    return _pds_dem(label, heights_above=heights_above, dtype=dtype)[0]


def _pds_dem(label: str | os.PathLike, *, heights_above: float | None = None, dtype="float32") -> tuple[DEM, Path]:
    """pds_dem, and the data file it read (what import_pds must never write over)."""
    if dtype not in ("float32", "float64", np.float32, np.float64):
        raise PDSError(f"dtype: float32 or float64, got {dtype!r}")
    if heights_above is not None:
        if isinstance(heights_above, (bool, np.bool_)) or not isinstance(heights_above, (int, float, np.integer,
                                                                                           np.floating)) \
                or not (math.isfinite(float(heights_above)) and heights_above > 0):
            raise PDSError(f"heights_above: a positive radius in km, got {heights_above!r}")
        heights_above = float(heights_above)
    path = Path(label)
    tree = read_pds3_label(path)
    re_km, f = _spheroid(path, tree)
    km, data = _grid(path, tree, heights_above, dtype)
    if re_km is not None:
        sub = km[::max(1, km.shape[0] // 360), ::max(1, km.shape[1] // 720)]
        med = float(np.median(sub))
        if not (re_km / RADIUS_FACTOR <= med <= re_km * RADIUS_FACTOR):
            hint = ("heights? give heights_above=the radius they are above" if heights_above is None else
                    f"heights_above={heights_above} added to a product of radii?" if med > re_km else
                    f"heights_above={heights_above} is not the radius the heights are above?")
            raise PDSError(f"PDS data {data}: its median radius {med:.6g} km is not within a factor "
                           f"{RADIUS_FACTOR} of A_AXIS_RADIUS = {re_km} km ({hint})")
    try:
        return DEM.from_array(km, f=f, re=re_km), data
    except DEMError as exc:
        raise PDSError(f"PDS data {data} (label {path}): {exc}") from None


def import_pds(label: str | os.PathLike, out: str | os.PathLike, *, heights_above: float | None = None,
               overwrite: bool = False) -> Path:
    """Convert a PDS3 grid (see :func:`pds_dem`) to a ``.hdr``/``.dem`` pair (float32 km); return the ``.hdr``.
    Never over the label or the data file."""
    dem, data = _pds_dem(label, heights_above=heights_above)
    return dem.write(out, dtype="float32", overwrite=overwrite, inputs=[label, data])
