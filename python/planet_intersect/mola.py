"""Mars MOLA MEGDR grids as planet-intersect DEMs.

MEGDR grids (PDS data set MGS-M-MOLA-5-MEGDR-L3-V1.0) are raw big-endian
16-bit integers, ``180 ppd`` rows by ``360 ppd`` columns, **north row first**,
column 0 starting at 0 deg E, planetocentric. Radius grids (``megr*``) hold
radius - 3,396,000 m; topography grids (``megt*``) hold height above the
areoid, which becomes a radius once an areoid grid (radius - 3,396,000 m, same
layout) is added. The result is a :class:`~planet_intersect.DEM` in km, south
row first, with the Mars reference spheroid in the header.
"""

from __future__ import annotations

import hashlib
import os
import urllib.error
import urllib.request
import warnings
from pathlib import Path

import numpy as np

from .dem import DEM
from .synthetic import MARS_F, MARS_RE

__all__ = ["MEGDR_OFFSET_M", "read_megdr", "mola_dem", "import_mola", "fetch_mola", "PDS_MEGDR_URL",
           "MEGDR_PRODUCTS"]

#: MEGDR value offset: radius = value + 3,396,000 m
MEGDR_OFFSET_M = 3_396_000
#: where the PDS Geosciences Node serves the MEGDR products (meg004 = 4 ppd, meg016, ...)
PDS_MEGDR_URL = "https://pds-geosciences.wustl.edu/mgs/mgs-m-mola-5-megdr-l3-v1/mgsl_300x"
#: radius products fetch-mola knows: name -> (folder, ppd). Global grids only.
MEGDR_PRODUCTS = {
    "megr90n000cb": ("meg004", 4),
    "megr90n000eb": ("meg016", 16),
}


def _ppd_of(path: Path) -> int:
    n = path.stat().st_size // 2
    for ppd in range(1, 1025):
        if 180 * ppd * 360 * ppd == n:
            return ppd
    raise ValueError(f"MEGDR grid {path}: {path.stat().st_size} bytes is not a global 180 ppd x 360 ppd grid of 16-bit values")


def read_megdr(path: str | os.PathLike) -> np.ndarray:
    """Raw MEGDR values (int16, metres) as ``[nlat, nlon]`` with row 0 in the SOUTH."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"MEGDR grid {path}: no such file")
    ppd = _ppd_of(path)
    raw = np.fromfile(path, dtype=">i2").reshape(180 * ppd, 360 * ppd)
    return raw[::-1]                      # north-first -> south-first (DESIGN section 3)


def mola_dem(radius: str | os.PathLike | None = None, *, topography: str | os.PathLike | None = None,
             areoid: str | os.PathLike | None = None) -> DEM:
    """A Mars DEM in km from a MEGDR radius grid, or from a topography + areoid pair.

    ``radius``: a ``megr``-style grid (value + 3,396,000 m). Or ``topography``
    (``megt``, metres above the areoid) with ``areoid`` (value + 3,396,000 m).
    The header gets re = 3396.19 km and f = 1/169.8 (the Mars reference spheroid).
    """
    if (radius is None) == (topography is None):
        raise ValueError("give either a radius grid or a topography grid (with its areoid)")
    if radius is not None:
        name = Path(radius).name.lower()
        if name.startswith(("megt", "mega", "megc", "megn", "megb")):
            # MEGDR names say what a grid holds (megr radius, megt topography, mega areoid, ...): a
            # topography grid given as radii was converted without a word, off by the areoid (a review)
            warnings.warn(f"{radius}: the name says a MEGDR '{name[:4]}' grid, not a radius grid ('megr'): it is "
                          f"read as radii; a topography grid ('megt') goes with its areoid (topography=, "
                          f"areoid=; --topography, --areoid)", UserWarning, stacklevel=2)
        metres = read_megdr(radius).astype(np.float64) + MEGDR_OFFSET_M
    else:
        if areoid is None:
            raise ValueError("a topography grid needs its areoid grid to become radii")
        topo, geoid = read_megdr(topography), read_megdr(areoid)
        if topo.shape != geoid.shape:
            raise ValueError(f"topography {topo.shape} and areoid {geoid.shape} grids differ in size")
        metres = topo.astype(np.float64) + geoid.astype(np.float64) + MEGDR_OFFSET_M
    return DEM.from_array((metres / 1000.0).astype(np.float32), f=MARS_F, re=MARS_RE)


def import_mola(out: str | os.PathLike, radius=None, *, topography=None, areoid=None,
                overwrite: bool = False) -> Path:
    """Convert MEGDR grids to a ``.hdr``/``.dem`` pair (float32 km); return the ``.hdr`` path."""
    dem = mola_dem(radius, topography=topography, areoid=areoid)
    return dem.write(out, dtype="float32", overwrite=overwrite,
                     inputs=[p for p in (radius, topography, areoid) if p is not None])


def fetch_mola(dest: str | os.PathLike, product: str = "megr90n000cb", base_url: str = PDS_MEGDR_URL,
               progress=None) -> Path:
    """Download a MEGDR radius grid from the PDS Geosciences Node and import it.

    Writes ``dest/PRODUCT.img`` (checked: exact size of a global grid) and the
    DEM pair ``dest/mola_PRODUCT.hdr/.dem``; returns the ``.hdr`` path. Nothing
    existing is overwritten; a partial download is removed. ``progress(done, total)``
    is called as bytes arrive. Needs internet access (not exercised by the tests,
    which run the same code on a ``file://`` URL).
    """
    if product not in MEGDR_PRODUCTS:
        raise ValueError(f"product must be one of {', '.join(MEGDR_PRODUCTS)}, got {product!r}")
    folder, ppd = MEGDR_PRODUCTS[product]
    dest = Path(dest)
    created = not dest.exists()
    dest.mkdir(parents=True, exist_ok=True)
    img = dest / f"{product}.img"
    expected = 180 * ppd * 360 * ppd * 2
    if img.exists():
        if img.stat().st_size != expected:
            raise FileExistsError(f"{img} exists with {img.stat().st_size} bytes, not {expected}: remove it first")
    else:
        url = f"{base_url.rstrip('/')}/{folder}/{product}.img"
        part = img.with_name(img.name + ".part")
        try:
            with urllib.request.urlopen(url, timeout=60) as response, open(part, "wb") as fh:
                total = int(response.headers.get("Content-Length") or expected)
                done = 0
                while True:
                    chunk = response.read(1 << 20)
                    if not chunk:
                        break
                    fh.write(chunk)
                    done += len(chunk)
                    if progress:
                        progress(done, total)
            size = part.stat().st_size
            if size != expected:
                raise OSError(f"download of {url} gave {size} bytes, expected {expected}")
            os.replace(part, img)
        except urllib.error.URLError as exc:
            # (the message was urllib's alone, "<urlopen error [Errno -2] Name or service not known>",
            # and an empty DEST was left behind: a review)
            raise OSError(f"download of {url} failed ({exc.reason}): check the network, or fetch the file "
                          f"yourself and run import-mola on it") from None
        finally:
            if part.exists():
                part.unlink()
            if created and dest.is_dir() and not any(dest.iterdir()):
                dest.rmdir()
    return import_mola(dest / f"mola_{product}", radius=img)


def sha256(path: str | os.PathLike) -> str:
    """SHA-256 of a file, for provenance records."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()
