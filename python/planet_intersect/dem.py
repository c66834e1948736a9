"""Digital elevation models: the ``.hdr``/``.dem`` file pair of DESIGN section 3.

A DEM is a global grid of planetocentric radii at pixel centres,
``radii[nlat, nlon]`` with ``nlat = 180*ppd`` rows (row 0 in the south, centre
latitude ``-90 + 1/(2 ppd)``) and ``nlon = 360*ppd`` columns (column 0 centred
at ``1/(2 ppd)`` degrees east). The header holds Table 1 of the paper: ``ppd``,
``rmax``, ``f``, ``re``.
"""

from __future__ import annotations

import errno
import math
import os
import re
import secrets
import stat
import warnings
from pathlib import Path

import numpy as np

from ._status import DEMError, raise_for_stat

__all__ = ["DEM", "read_header", "dem_paths", "regular_file", "RADIUS_MIN", "RADIUS_MAX", "MAX_PPD"]

_DTYPES = {"float32": 4, "float64": 8}
_BYTEORDERS = {"little": "<", "big": ">"}
_BLOCK_ROWS = 256  # rows checked at a time, bounding memory for large grids


def dem_paths(path: str | os.PathLike) -> tuple[Path, Path]:
    """The ``.hdr`` and ``.dem`` paths of a DEM given as NAME, NAME.hdr or NAME.dem."""
    p = Path(path)
    stem = p.with_suffix("") if p.suffix in (".hdr", ".dem") else p
    return stem.with_name(stem.name + ".hdr"), stem.with_name(stem.name + ".dem")


#: Largest ppd accepted (pi_dem::max_ppd): 360 ppd columns index in 32-bit integers.
MAX_PPD = 1_000_000
#: The range of radii, rmax and re accepted, in any unit (pi_dem::radius_min/max):
#: squares and products of lengths, with spacecraft up to 1e15 rmax away, stay far
#: from overflow and underflow (docs/paper-notes.md, note 19).
RADIUS_MIN, RADIUS_MAX = 1e-100, 1e100
#: Smallest radius / largest radius accepted: the paper's steps are proportional
#: to the distance from the centre (eq. 26), so a DEM spanning more would need
#: more steps than any budget, or steps below the rounding of the distance.
SPAN_MIN = 1e-6
#: Largest header file read (the Fortran reader's limit too).
_HDR_MAX_BYTES = 1_000_000

_INT_TOKEN = re.compile(rb"[+-]?[0-9]{1,9}\Z")
_REAL_TOKEN = re.compile(rb"[+-]?([0-9]+(\.[0-9]*)?|\.[0-9]+)([eE][+-]?[0-9]{1,3})?\Z")
_BLANKS = b" \t"


def regular_file(path: str | os.PathLike, what: str) -> Path:
    """``path`` as a Path after checking that it names a readable regular file;
    otherwise an exception that says what is wrong with it (missing, a directory,
    a FIFO or device, a symlink loop, unreadable)."""
    path = Path(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise FileNotFoundError(f"{what} {path}: no such file") from None
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise DEMError(f"{what} {path}: a loop of symbolic links") from None
        raise DEMError(f"{what} {path}: cannot be used ({exc.strerror})") from None
    if stat.S_ISDIR(st.st_mode):
        raise IsADirectoryError(f"{what} {path}: is a directory, not a file")
    if not stat.S_ISREG(st.st_mode):
        raise DEMError(f"{what} {path}: not a regular file (a FIFO, socket or device)")
    if not os.access(path, os.R_OK):
        raise PermissionError(f"{what} {path}: not readable")
    return path


def read_header(hdr: str | os.PathLike) -> dict:
    """Parse and check a ``.hdr`` file; return ppd, rmax, f, re, dtype, byteorder.

    The grammar (docs/dem-format.md; the Fortran reader ``pi_dem::dem_read_header``
    implements the same one, and tests feed both the same headers): the file is
    bytes, at most 999,999; lines end at LF, CR or CRLF; space and tab are the
    only white space. Blank lines and lines starting with ``#`` or ``!`` are
    skipped. The first four other lines hold the values of the paper's Table 1,
    ppd (``[+-]`` and 1-9 digits), rmax, f, re (decimal reals: digits with an
    optional point, or a point and digits, and an optional exponent of 1-3
    digits); anything after the value on its line is a comment. ``key = value``
    lines may follow: ``dtype`` (float32, float64) and ``byteorder`` (little,
    big), without case. Any other line is an error.
    """
    hdr = regular_file(hdr, "DEM header")
    if hdr.stat().st_size >= _HDR_MAX_BYTES:
        raise DEMError(f"DEM header {hdr}: {hdr.stat().st_size} bytes; a header has at most {_HDR_MAX_BYTES - 1}")
    raw = hdr.read_bytes()
    names = ("ppd", "rmax", "f", "re")
    values: dict = {"dtype": "float32", "byteorder": "little"}
    seen = 0
    for lineno, line in enumerate(re.split(rb"\r\n|\r|\n", raw), start=1):
        line = line.strip(_BLANKS)
        if not line or line[:1] in (b"#", b"!"):
            continue
        text = line.decode("ascii", errors="backslashreplace")
        if seen < 4:
            name = names[seen]
            token = re.split(rb"[ \t]", line, maxsplit=1)[0]
            pattern = _INT_TOKEN if name == "ppd" else _REAL_TOKEN
            if not pattern.match(token):
                kind = "an integer of at most 9 digits" if name == "ppd" else "a decimal number"
                raise DEMError(f"DEM header {hdr}, line {lineno}: {name} must be {kind}, "
                               f"got {token.decode('ascii', errors='backslashreplace')!r}")
            values[name] = int(token) if name == "ppd" else float(token)
            seen += 1
            continue
        if b"=" not in line:
            raise DEMError(f"DEM header {hdr}, line {lineno}: expected 'key = value' after the four values, got {text!r}")
        key, _, rest = line.partition(b"=")
        key = key.strip(_BLANKS).lower().decode("ascii", errors="backslashreplace")
        words = re.split(rb"[ \t]+", rest.strip(_BLANKS))
        word = words[0].lower().decode("ascii", errors="backslashreplace")
        if key == "dtype" and word in _DTYPES:
            values["dtype"] = word
        elif key == "byteorder" and word in _BYTEORDERS:
            values["byteorder"] = word
        elif key in ("dtype", "byteorder"):
            allowed = ", ".join(_DTYPES if key == "dtype" else _BYTEORDERS)
            raise DEMError(f"DEM header {hdr}, line {lineno}: {key} must be one of {allowed}, got {word!r}")
        else:
            raise DEMError(f"DEM header {hdr}, line {lineno}: unknown key {key!r} (known: dtype, byteorder)")
    if seen < 4:
        raise DEMError(f"DEM header {hdr}: {names[seen]} is missing (the header needs ppd, rmax, f, re)")
    _check_parameters(values["ppd"], values["rmax"], values["f"], values["re"], where=f"DEM header {hdr}")
    return values


def _real(value, name: str, where: str) -> float:
    """A real number argument as float; TypeError naming it for anything else."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{where}: {name} must be a real number, got {type(value).__name__} {value!r}")
    return float(value)


#: how far the reference spheroid's re may be from the DEM's rmax (a factor; re = 1, Table 1's
#: placeholder, is exempt: with f = 0 it is the "no spheroid" setting, and the format allows it with any f)
RE_RATIO_MAX = 10.0


def _check_parameters(ppd, rmax, f, re, where):
    if not 1 <= ppd <= MAX_PPD:
        raise DEMError(f"{where}: ppd must be in 1..{MAX_PPD}, got {ppd}")
    if not (RADIUS_MIN <= rmax <= RADIUS_MAX):
        raise DEMError(f"{where}: rmax must be in [{RADIUS_MIN:g}, {RADIUS_MAX:g}], got {rmax}")
    if not (math.isfinite(f) and 0 <= f < 1):
        raise DEMError(f"{where}: flattening f must be in [0, 1), got {f}")
    if not (RADIUS_MIN <= re <= RADIUS_MAX):
        raise DEMError(f"{where}: equatorial radius re must be in [{RADIUS_MIN:g}, {RADIUS_MAX:g}], got {re}")
    if re != 1.0 and not (rmax / RE_RATIO_MAX <= re <= RE_RATIO_MAX * rmax):
        # re in metres over radii in km gave altitudes of -1.7e6 km without a word (a walk-through);
        # rmax was checked against the radii, re against nothing
        raise DEMError(f"{where}: equatorial radius re = {re:g} is not within a factor {RE_RATIO_MAX:g} of "
                       f"rmax = {rmax:g}: the reference spheroid and the radii must be in one unit (re = 1, "
                       f"Table 1's placeholder, is exempt; with f = 0 it means 'no spheroid')")
    if re == 1.0 and f != 0.0 and not (rmax / RE_RATIO_MAX <= re <= RE_RATIO_MAX * rmax):
        # Table 1's placeholder means "no spheroid" only with f = 0; with a flattening it is a spheroid
        # of radius 1 under radii of thousands: altitudes of 3389 km without a word (a review). The
        # format allows it, so it is read, and said
        warnings.warn(f"{where}: re = 1 with f = {f:g} is a reference spheroid of radius 1 under radii up to "
                      f"rmax = {rmax:g}: altitude, sc and tangent_height are measured from it (give re in the "
                      f"radii's unit, or f = 0 for Table 1's 'no spheroid')", UserWarning, stacklevel=3)


def _check_rmax_tight(rmax: float, top: float, where: str) -> None:
    """rmax may exceed the largest radius, but not by more than a factor 2: the
    search starts on the r_max sphere and a spacecraft's distance is judged
    against it, so a loose rmax (1e20 for a body of radius 1) would put the whole
    search far from the surface and defeat the far-spacecraft rules (note 19)."""
    if rmax > 2.0 * top:
        raise DEMError(f"{where}: rmax = {rmax:g} is more than twice the largest radius {top:g}; "
                       "give an rmax close to the largest radius")


def _row_blocks(radii):
    """(first row, float64 block) over an array, or over a file as (path, dtype, shape):
    a file is read with plain reads, so checking it never maps it into memory."""
    if isinstance(radii, tuple):
        path, dtype, (nlat, nlon) = radii
        rows = max(1, (1 << 20) // (nlon * dtype.itemsize))      # 1 MB blocks: a small, fixed footprint
        with open(path, "rb") as fh:
            for j in range(0, nlat, rows):
                n = min(rows, nlat - j)
                yield j, np.fromfile(fh, dtype=dtype, count=n * nlon).reshape(n, nlon).astype(np.float64)
    else:
        for j in range(0, radii.shape[0], _BLOCK_ROWS):
            yield j, np.asarray(radii[j:j + _BLOCK_ROWS], dtype=np.float64)


def _check_radii(radii, rmax: float, where: str) -> float:
    """Check finite radii in [RADIUS_MIN, RADIUS_MAX] not above rmax, block by block;
    return the maximum."""
    top, low = -math.inf, math.inf
    for j, block in _row_blocks(radii):
        bad = ~np.isfinite(block)
        if bad.any():
            jj, ii = np.argwhere(bad)[0]
            raise DEMError(f"{where}: radius at row {j + jj}, column {ii} is {block[jj, ii]} (NaN/Inf not allowed)")
        if (block <= 0).any():
            jj, ii = np.argwhere(block <= 0)[0]
            raise DEMError(f"{where}: radius at row {j + jj}, column {ii} is {block[jj, ii]} (must be positive)")
        out = (block < RADIUS_MIN) | (block > RADIUS_MAX)
        if out.any():
            jj, ii = np.argwhere(out)[0]
            raise DEMError(f"{where}: radius at row {j + jj}, column {ii} is {block[jj, ii]:g}, outside "
                           f"[{RADIUS_MIN:g}, {RADIUS_MAX:g}] (a no-data value? fill it before making a DEM)")
        top = max(top, float(block.max()))
        low = min(low, float(block.min()))
    if rmax is not None and top > rmax:
        raise DEMError(f"{where}: rmax = {rmax} is below the largest radius {top}")
    if low < top * SPAN_MIN:
        raise DEMError(f"{where}: radii span {low:g} .. {top:g}; they must lie within a factor "
                       f"{1 / SPAN_MIN:g} of each other (a spike or no-data value? the search steps "
                       "in proportion to the distance from the centre: note 19)")
    return top


def _byteswap_hint(dem: Path, dtype: np.dtype, nlon: int, h: dict) -> str:
    """' (the data look byte-swapped: ...)' when the first rows of ``dem`` read in the other byte
    order are finite radii within [rmax / 1e6, rmax], else ''."""
    try:
        n = min(64 * nlon, dem.stat().st_size // dtype.itemsize)
        raw = np.fromfile(dem, dtype=dtype.newbyteorder(), count=n)
    except (OSError, ValueError):
        return ""
    with np.errstate(invalid="ignore", over="ignore"):
        ok = raw.size > 0 and bool(np.all(np.isfinite(raw))) and bool(np.all(raw > h["rmax"] * 1e-6)) \
            and bool(np.all(raw <= h["rmax"]))
    if not ok:
        return ""
    other = "little" if h["byteorder"] == "big" else "big"
    return f" (the data look byte-swapped: they read as radii with 'byteorder = {other}' in the header)"


def _float32_up(x: np.ndarray) -> np.ndarray:
    """float64 values as the nearest float32 at or above each."""
    with np.errstate(over="ignore"):          # radii beyond float32 (up to 1e100) become +inf: still a bound
        f = x.astype(np.float32)
    low = f.astype(np.float64) < x
    f[low] = np.nextafter(f[low], np.float32(np.inf))
    return f



def checked_ppd(ppd, limit: int) -> int:
    """An importer's ppd argument as an int from 1 to ``limit`` (ValueError naming ppd otherwise)."""
    if isinstance(ppd, bool) or not isinstance(ppd, (int, np.integer)) or not 1 <= int(ppd) <= limit:
        raise ValueError(f"ppd must be an integer from 1 to {limit}, got {ppd!r}")
    return int(ppd)


def read_small_text(path: Path, where: str, max_bytes: int, error: type) -> str:
    """The ASCII text of a regular file of at most ``max_bytes`` (an importer's input: shape
    tables, SHADR models); anything else raises ``error`` with ``where`` (a FIFO hung and
    /dev/zero filled the memory before this check: a review)."""
    try:
        st = path.stat()
        if not stat.S_ISREG(st.st_mode):
            raise error(f"{where}: not a regular file")
        if st.st_size > max_bytes:
            raise error(f"{where}: {st.st_size:,} bytes, more than the {max_bytes:,} it may have")
        with open(path, "rb") as fh:
            raw = fh.read(max_bytes + 1)
        if len(raw) > max_bytes:
            raise error(f"{where}: more than the {max_bytes:,} bytes it may have")
        return raw.decode("ascii")
    except OSError as exc:
        raise error(f"{where}: cannot read it ({exc.strerror or exc})") from None
    except UnicodeDecodeError as exc:
        raise error(f"{where}: not ASCII text (byte {exc.start})") from None


class DEM:
    """A global DEM of planetocentric radii (see the module docstring for the grid).

    Make one with :meth:`read` (a file pair, memory-mapped) or
    :meth:`from_array`. Attributes: ``radii`` (``[nlat, nlon]``, a read-only
    memory map for a file-backed DEM), ``ppd``, ``rmax``, ``f``, ``re`` and
    ``path`` (the ``.hdr`` path, None in memory).
    """

    def __init__(self, radii: np.ndarray, ppd: int, rmax: float, f: float, re: float, path: Path | None = None,
                 header: dict | None = None):
        self._radii = radii
        self.ppd = int(ppd)
        self.rmax = float(rmax)
        self.f = float(f)
        self.re = float(re)
        self.path = path
        self._header = header
        self._identity = None
        if path is not None:
            self._identity = self._file_identity()
        self._radii64 = None
        self._pyramid = None
        self._map_poles = None

    @property
    def radii(self) -> np.ndarray:
        """The radii ``[nlat, nlon]`` (read-only; a memory map for a file-backed DEM).

        A file-backed DEM checks its ``.dem`` file first (:meth:`check_file`):
        reading the map of a file truncated since :meth:`read` killed the process
        with SIGBUS (a walk-through: ``dem.radii.max()``); it is a
        :class:`DEMError` now. An array taken from here earlier and kept is the
        map itself: read the DEM again after its file changes."""
        self.check_file()
        return self._radii

    # the file behind a DEM ---------------------------------------------------------
    def _file_identity(self):
        st = os.stat(dem_paths(self.path)[1])
        return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)

    def check_file(self) -> None:
        """Raise :class:`DEMError` when the ``.dem`` file of a file-backed DEM has
        been removed, replaced, resized or rewritten since :meth:`read` (reading
        it through the memory map would then kill the process with SIGBUS, or
        give radii that were never checked). Called before every use of the file."""
        if self.path is None:
            return
        dem = dem_paths(self.path)[1]
        try:
            now = self._file_identity()
        except OSError as exc:
            raise DEMError(f"DEM data {dem}: cannot be used any more ({exc.strerror}); read the DEM again") from None
        if now != self._identity:
            what = "its size changed" if now[2] != self._identity[2] else "it was replaced or rewritten"
            raise DEMError(f"DEM data {dem}: {what} since DEM.read (size {self._identity[2]} -> {now[2]} bytes); "
                           "read the DEM again")

    def header_args(self) -> tuple:
        """(ppd, rmax, f, re, itemsize, swap) of a file-backed DEM as Python parsed
        them, for the Fortran core's file routines (one header parser for both
        storage modes)."""
        itemsize = self._radii.dtype.itemsize              # (no file check: only the header's values)
        swap = int(not self._radii.dtype.isnative)
        return self.ppd, self.rmax, self.f, self.re, itemsize, swap

    # construction -----------------------------------------------------------------
    @classmethod
    def read(cls, path: str | os.PathLike) -> "DEM":
        """Read and validate a DEM file pair (NAME, NAME.hdr or NAME.dem).

        The ``.dem`` is memory-mapped read-only; it is checked once here: size,
        finite positive radii, ``rmax >= max(radii)``.
        """
        if Path(path).is_dir():
            raise IsADirectoryError(f"DEM {path}: is a directory; give the DEM as NAME, NAME.hdr or NAME.dem")
        hdr, dem = dem_paths(path)
        h = read_header(hdr)
        regular_file(dem, f"DEM data (header {hdr})")
        ppd = h["ppd"]
        nlat, nlon = 180 * ppd, 360 * ppd
        itemsize = _DTYPES[h["dtype"]]
        expected = nlat * nlon * itemsize
        size = dem.stat().st_size
        if size != expected:
            raise DEMError(
                f"DEM data {dem}: size {size} bytes, but the header (ppd = {ppd}, {h['dtype']}) "
                f"needs {nlat} x {nlon} x {itemsize} = {expected} bytes")
        dtype = np.dtype(h["dtype"]).newbyteorder(_BYTEORDERS[h["byteorder"]])
        try:
            with np.errstate(invalid="ignore", over="ignore"):
                top = _check_radii((dem, dtype, (nlat, nlon)), h["rmax"], where=f"DEM data {dem}")
                _check_rmax_tight(h["rmax"], top, f"DEM header {hdr}")
        except DEMError as exc:
            # data that would pass in the other byte order: say so (the messages blamed rmax or a NaN
            # radius, never the byte order: a review)
            raise DEMError(f"{exc}{_byteswap_hint(dem, dtype, nlon, h)}") from None
        radii = np.memmap(dem, dtype=dtype, mode="r", shape=(nlat, nlon))
        out = cls(radii, ppd, h["rmax"], h["f"], h["re"], path=hdr, header=h)
        if out._identity[2] != expected:                    # changed between the check and the map
            raise DEMError(f"DEM data {dem}: its size changed while it was being read")
        return out

    @classmethod
    def from_array(cls, radii, f: float = 0.0, re: float | None = None, rmax: float | None = None) -> "DEM":
        """A DEM in memory from ``radii[nlat, nlon]`` (row 0 south).

        ``ppd`` follows from the shape (``nlat = 180 ppd``, ``nlon = 360 ppd``);
        ``rmax`` defaults to the largest radius. ``f``, ``re``: the reference
        spheroid (flattening, equatorial radius in the radii's unit, within a
        factor 10 of rmax). Without ``re`` the DEM has none: Table 1's "no
        spheroid" setting of an irregular body (stored as f = 0, re = 1), for
        which ``altitude``, ``sc`` and ``tangent_height`` are NaN
        (paper-notes 20); ``re=1.0`` with ``f=0`` given explicitly means the
        same and warns, since a DEM in units of the body's radius would want a
        unit sphere (scale the radii, e.g. to km, for one). The DEM keeps a private,
        read-only copy of the radii (float32 stays float32, other real or
        integer types become float64): changing the caller's array afterwards
        does not change the DEM.
        """
        where = "DEM.from_array"
        f = _real(f, "f", where)
        if re is None:
            re_ = 1.0                                    # no spheroid with f = 0 (Table 1's f = 0, re = 1)
        else:
            re_ = _real(re, "re", where)
            if f == 0.0 and re_ == 1.0:
                warnings.warn(f"{where}: f = 0 with re = 1 is Table 1's 'no spheroid' setting: altitude, sc and "
                              f"tangent_height will be NaN (leave re out to say so without this warning)",
                              UserWarning, stacklevel=2)
        if rmax is not None:
            rmax = _real(rmax, "rmax", where)
        try:
            arr = np.asarray(radii)
        except (TypeError, ValueError) as exc:
            raise TypeError(f"{where}: radii is not an array of numbers ({exc})") from None
        if arr.dtype.kind not in "fiu":
            raise TypeError(f"{where}: radii must be real numbers, got dtype {arr.dtype}")
        if arr.ndim != 2 or arr.shape[1] != 2 * arr.shape[0] or arr.shape[0] % 180 or arr.shape[0] == 0:
            raise DEMError(f"radii: shape {arr.shape} is not (180*ppd, 360*ppd) for an integer ppd >= 1")
        dtype = np.float32 if arr.dtype == np.float32 else np.float64
        arr = np.array(arr, dtype=dtype, order="C", copy=True)     # private: the caller's array stays theirs
        arr.flags.writeable = False
        ppd = arr.shape[0] // 180
        top = _check_radii(arr, rmax, where="radii")
        rmax = top if rmax is None else rmax
        _check_rmax_tight(rmax, top, where)
        _check_parameters(ppd, rmax, f, re_, where=where)
        return cls(arr, ppd, rmax, f, re_, path=None)

    # properties ---------------------------------------------------------------------
    @property
    def nlat(self) -> int:
        """Number of latitude rows, 180 ppd."""
        return 180 * self.ppd

    @property
    def nlon(self) -> int:
        """Number of longitude columns, 360 ppd."""
        return 360 * self.ppd

    @property
    def lat(self) -> np.ndarray:
        """Row-centre latitudes, degrees (south to north)."""
        return -90.0 + (np.arange(self.nlat) + 0.5) / self.ppd

    @property
    def lon(self) -> np.ndarray:
        """Column-centre east longitudes, degrees."""
        return (np.arange(self.nlon) + 0.5) / self.ppd

    def __repr__(self) -> str:
        where = f"path={str(self.path)!r}" if self.path else "in memory"
        return f"DEM(ppd={self.ppd}, rmax={self.rmax}, f={self.f}, re={self.re}, {where})"

    def _read_rows(self, j0: int, j1: int) -> np.ndarray:
        """Rows j0..j1-1 as float64; a file-backed DEM is read with plain reads (not
        through its memory map, whose touched pages would stay resident)."""
        if self.path is not None and isinstance(self._radii, np.memmap):
            dtype = self._radii.dtype
            with open(dem_paths(self.path)[1], "rb") as fh:
                fh.seek(j0 * self.nlon * dtype.itemsize)
                out = np.fromfile(fh, dtype=dtype, count=(j1 - j0) * self.nlon)
            return out.reshape(j1 - j0, self.nlon).astype(np.float64)
        return np.asarray(self._radii[j0:j1], dtype=np.float64)

    def mapped_bytes(self) -> np.ndarray | None:
        """The bytes of this DEM's read-only memory map of its ``.dem`` file, as a
        flat int8 view (no copy), for the Fortran core to read records from in
        dem_read_mode 1; None when the DEM is in memory or its byte order is not
        the machine's (the core then maps the file itself for each call)."""
        if not isinstance(self._radii, np.memmap) or not self._radii.dtype.isnative:
            return None
        self.check_file()
        if not self._radii.flags.c_contiguous:
            return None
        return self._radii.reshape(-1).view(np.int8)

    def mapped_poles(self) -> np.ndarray:
        """The polar means (south, north) of the rows next to the poles, as the
        Fortran core computes them from :meth:`mapped_bytes` (section 2.2),
        computed once and kept, so that each ``io="mmap"`` call does not re-read
        the two polar rows (92,160 records at 128 ppd)."""
        if self._map_poles is None:
            from ._ext import core as _core

            poles, stat = _core.core_map_poles(self.mapped_bytes(), self._radii.dtype.itemsize, self.ppd,
                                               self.rmax, self.f, self.re)
            raise_for_stat(stat, f"DEM polar rows ({self.path})")
            self._map_poles = poles
        return self._map_poles

    def radii64(self) -> np.ndarray:
        """The grid as a C-ordered float64 array (converted once and kept, read-only). A
        file-backed DEM checks its file on every call, also when the copy is kept: after the
        file changed, answers came from the old grid while ``dem.radii`` raised (a review)."""
        self.check_file()
        if self._radii64 is None:
            if self.path is not None:
                r64 = np.empty((self.nlat, self.nlon))
                for j in range(0, self.nlat, _BLOCK_ROWS):
                    r64[j:j + _BLOCK_ROWS] = self._read_rows(j, min(j + _BLOCK_ROWS, self.nlat))
            else:
                r64 = np.ascontiguousarray(self._radii, dtype=np.float64)
                if r64 is self._radii:
                    r64 = r64.copy()
            r64.flags.writeable = False
            self._radii64 = r64
        return self._radii64

    def pyramid(self) -> tuple[np.ndarray, np.ndarray]:
        """The max-pyramid of the exact first-hit mode, built once and kept.

        Cells: row 0 is the south polar cap (pole to the first row), rows 1..nlat-1
        lie between DEM rows, row nlat is the north cap; column i spans DEM columns
        i and i+1 (wrapping). A bilinear cell never exceeds its four corner radii.
        Level k >= 1 holds, for each block of 2^k x 2^k cells, the largest node
        radius bordering the block, as float32 rounded up and then one more
        float32 ulp up (0.2 m at Mars' radius), so that neither the conversion nor
        rounding in the float64 interpolation can make it a hair low; half the
        memory of float64 (1.4 GB at 128 ppd). Returns ``(data, meta)``: all
        levels in one float32 array, and ``meta[k-1] = (rows, cols, offset)``.
        """
        if self._pyramid is not None:
            return self._pyramid
        self.check_file()
        nlat, nlon = self.nlat, self.nlon
        shapes = [((nlat + 2) // 2, nlon // 2)]            # level 1: cell rows 0..nlat in pairs
        while shapes[-1] != (1, 1):
            r, c = shapes[-1]
            shapes.append(((r + 1) // 2, (c + 1) // 2))
        sizes = [r * c for r, c in shapes]
        offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        data = np.empty(int(sum(sizes)), dtype=np.float32)  # all levels, written in place
        meta = np.array([(r, c, o) for (r, c), o in zip(shapes, offsets)], dtype=np.int32)
        level = data[:sizes[0]].reshape(shapes[0])
        rows = self._read_rows
        south = float(np.sum(rows(0, 1)[0])) / nlon
        north = float(np.sum(rows(nlat - 1, nlat)[0])) / nlon
        step = max(1, (8 << 20) // (8 * nlon))              # row pairs per block: ~8 MB of radii at a time
        for bc in range(0, shapes[0][0], step):             # extended node rows 2bc..2bc+2 (0 = south pole)
            top = min(bc + step, shapes[0][0])
            e0, e1 = 2 * bc, 2 * top + 1                     # extended rows e0..e1-1; DEM row = e - 1
            ext = np.full((e1 - e0, nlon), -np.inf)
            lo, hi = max(e0, 1), min(e1, nlat + 1)
            if hi > lo:
                ext[lo - e0:hi - e0] = rows(lo - 1, hi - 1)
            if e0 == 0:
                ext[0] = south
            if e0 <= nlat + 1 < e1:
                ext[nlat + 1 - e0] = north
            r3 = np.maximum(np.maximum(ext[0:-1:2], ext[1::2]), ext[2::2])
            level[bc:top] = _float32_up(np.maximum(np.maximum(r3[:, 0::2], r3[:, 1::2]),
                                                   np.roll(r3, -1, axis=1)[:, 1::2]))
        for k in range(1, len(shapes)):
            fine = data[offsets[k - 1]:offsets[k - 1] + sizes[k - 1]].reshape(shapes[k - 1])
            pairs = fine[0::2].copy()
            pairs[:fine[1::2].shape[0]] = np.maximum(pairs[:fine[1::2].shape[0]], fine[1::2])
            coarse = data[offsets[k]:offsets[k] + sizes[k]].reshape(shapes[k])
            coarse[...] = pairs[:, 0::2]
            odd = pairs[:, 1::2]
            np.maximum(coarse[:, :odd.shape[1]], odd, out=coarse[:, :odd.shape[1]])
        with np.errstate(over="ignore"):
            np.nextafter(data, np.float32(np.inf), out=data)     # one float32 ulp up: rounding can never make it low
        self._pyramid = (data, meta)
        return self._pyramid

    # output -------------------------------------------------------------------------
    def write(self, path: str | os.PathLike, dtype: str | None = None, byteorder: str = "little",
              overwrite: bool = False, inputs=()) -> Path:
        """Write the file pair NAME.hdr + NAME.dem; return the ``.hdr`` path.

        ``dtype`` defaults to the array's (float32 or float64); ``float32`` with
        ``little`` byte order is what a reader knowing only Table 1 expects.
        Existing files are never replaced unless ``overwrite=True``, and a DEM
        is never written over the files it was read from, nor over any of
        ``inputs`` (the files an importer read it from), overwrite or not.
        """
        hdr, dem = dem_paths(path)
        if not hdr.parent.is_dir():
            raise FileNotFoundError(f"{path}: the folder {hdr.parent} does not exist")
        for src in inputs:
            for p in (hdr, dem):
                try:
                    same = p.exists() and os.path.samefile(p, src)
                except OSError:
                    same = False
                if same:
                    raise FileExistsError(f"{p} is the input file {src}: write the DEM elsewhere")
        if dtype is None:
            dtype = "float32" if self._radii.dtype.itemsize == 4 else "float64"
        if dtype not in _DTYPES:
            raise ValueError(f"dtype must be one of {', '.join(_DTYPES)}, got {dtype!r}")
        if byteorder not in _BYTEORDERS:
            raise ValueError(f"byteorder must be one of {', '.join(_BYTEORDERS)}, got {byteorder!r}")
        if self.path is not None and Path(self.path).resolve() == hdr.resolve():
            raise FileExistsError(f"{hdr}: this DEM was read from there; write it elsewhere")
        for p in (hdr, dem):
            if p.exists() and not overwrite:
                raise FileExistsError(f"{p} exists; pass overwrite=True to replace it")
        if self.path is not None:
            # the map of a file truncated since it was read would die of SIGBUS here (a review)
            self.check_file()
        if dtype == "float32":
            # float32 holds about 1.2e-38 .. 3.4e38 as normal numbers: outside, radii the format
            # accepts became inf or 0 and the pair could not be read back (a review)
            lo, hi = float(np.min(self._radii)), max(float(np.max(self._radii)), self.rmax)
            fi = np.finfo(np.float32)
            if not (lo >= float(fi.tiny) and hi <= float(fi.max)):
                raise ValueError(f"dtype='float32' cannot hold these radii ({lo:g} .. {hi:g}; float32 holds "
                                 f"{float(fi.tiny):g} .. {float(fi.max):g}): write float64")
        data = np.asarray(self._radii, dtype=np.dtype(dtype).newbyteorder(_BYTEORDERS[byteorder]))
        # temporary files under new unique names beside the targets, created exclusively (a fixed
        # NAME.dem.part was renamed over an input of that name: a review)
        tag = secrets.token_hex(6)
        tmp_dem = dem.with_name(f"{dem.name}.{tag}.part")
        tmp_hdr = hdr.with_name(f"{hdr.name}.{tag}.part")
        rmax = max(self.rmax, float(np.max(data)))
        text = (f"{self.ppd:d}    ppd: pixels per degree\n"
                f"{rmax!r}    rmax: maximum radius\n"
                f"{self.f!r}    f: flattening of the reference spheroid\n"
                f"{self.re!r}    re: equatorial radius of the spheroid\n"
                f"dtype = {dtype}\n"
                f"byteorder = {byteorder}\n")
        made = []
        try:
            with open(tmp_dem, "xb") as fh:              # "x": fails rather than replace anything
                made.append(tmp_dem)
                for j in range(0, self.nlat, _BLOCK_ROWS):
                    fh.write(np.ascontiguousarray(data[j:j + _BLOCK_ROWS]).tobytes())
            with open(tmp_hdr, "x", encoding="utf-8") as fh:
                made.append(tmp_hdr)
                fh.write(text)
        except BaseException:                            # a full disk, an interrupt: no stray parts left
            for t in made:
                t.unlink(missing_ok=True)
            raise
        os.replace(tmp_dem, dem)
        os.replace(tmp_hdr, hdr)
        return hdr

    # interpolation -------------------------------------------------------------------
    def radius(self, lat, lon) -> np.ndarray:
        """Bilinear DEM radius at planetocentric latitude/east longitude (degrees),
        eqs. 2-12 (the paper's zdem_radius): longitude wraps, and within half a
        pixel of a pole the pole carries the mean of the adjacent row."""
        from ._ext import core as _core

        lat = _real_array(lat, "lat")
        lon = _real_array(lon, "lon")
        try:
            lat, lon = np.broadcast_arrays(lat, lon)
        except ValueError:
            raise ValueError(f"lat and lon: shapes {lat.shape} and {lon.shape} do not broadcast") from None
        shape = lat.shape
        flat_lat, flat_lon = lat.ravel(), lon.ravel()
        if flat_lat.size == 0:
            return np.zeros(shape)
        if not (np.isfinite(flat_lat).all() and np.isfinite(flat_lon).all()):
            bad = ~(np.isfinite(flat_lat) & np.isfinite(flat_lon))
            raise ValueError(f"lat/lon: NaN or Inf at index {int(np.argmax(bad))}")
        if (np.abs(flat_lat) > 90).any():
            k = int(np.argmax(np.abs(flat_lat) > 90))
            raise ValueError(f"lat[{k}] = {flat_lat[k]} is outside [-90, 90] degrees")
        r, stat = _core.core_radius_grid(self.radii64().T, self.ppd, self.rmax, np.radians(flat_lat),
                                         np.radians(flat_lon))
        raise_for_stat(stat, "DEM.radius")
        return r.reshape(shape)


def _real_array(value, name: str) -> np.ndarray:
    """``value`` as a float64 array; a clear error for complex, text or objects."""
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name}: not an array of numbers ({exc})") from None
    if arr.dtype.kind not in "fiub":
        raise TypeError(f"{name}: must be real numbers, got dtype {arr.dtype}")
    if arr.dtype.kind == "b":
        raise TypeError(f"{name}: must be real numbers, got booleans")
    return arr.astype(np.float64, copy=False)
