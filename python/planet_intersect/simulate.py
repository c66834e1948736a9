"""Direct-model image simulation (Shin & Park section 4, issue 12).

Each image pixel's line of sight is followed to its first hit on a geodetic
DSM (``pi.intersect(dsm, s, l, method=...)``) and the ortho-photo's value
there becomes the pixel's value: buildings lean away from the sensor, their
sides appear, the ground behind them is hidden.

* :class:`OrthoImage` — an ortho-image (one band or several) on its own
  geodetic grid, sampled bilinearly.
* :func:`simulate_image` — the simulation, processed in blocks of image lines
  (memory bounded; ``out=`` writes the backplanes to memory-mapped files).
* :class:`SimResult` — the image and its backplanes, ``save()`` to PNG,
  GeoTIFF or NetCDF.

Choices where the paper is silent are numbered notes in
``docs/simulation-notes.md``; the code marks them as ``[sim note N]``.
"""

from __future__ import annotations

import math
import os
import sys
import time
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from .dsm import DSMStatus, GeodeticDSM, _file_nodata, _npz_arrays, _number, _unmask
from .geodetic import geodetic_to_ecef

__all__ = ["OrthoImage", "SimResult", "simulate_image", "SURFACE_CODES"]

#: sim.surface codes (DESIGN.md section 9)
SURFACE_CODES = {-1: "no hit", 0: "ground", 1: "roof", 2: "wall"}
_METHODS = ("exact", "following", "iterative")
#: largest image simulate_image takes (pixels): a million by a million was accepted and failed on a
#: 3.64 TiB allocation that did not name the sensor (a review)
MAX_PIXELS = 1 << 32


# --------------------------------------------------------------------- grids
def _grid_coords(lat, lon, lat_first, lon_first, dlat, dlon, ncols):
    """Fractional (row, col) of geodetic (lat, lon) on a pixel-centre grid;
    longitudes taken within 180 degrees of the grid's centre longitude (extents
    may cross 180), as the Fortran kernels do."""
    u = (np.asarray(lat, dtype=np.float64) - lat_first) / dlat
    lon = np.asarray(lon, dtype=np.float64)
    lon_c = lon_first + 0.5 * (ncols - 1) * dlon
    v = (lon - lon_first) / dlon                     # exact at the pixel centres
    far = ~(np.abs(lon - lon_c) <= 180.0)
    if far.any():
        w = np.mod(lon - lon_c + 180.0, 360.0) - 180.0
        v = np.where(far, (w + (lon_c - lon_first)) / dlon, v)
    return u, v


#: points within this many pixels of a pixel centre's row or column are taken on it (a neighbour
#: with that little weight is not read: a no-data neighbour 3e-10 pixel away made a hit at a valid
#: centre NaN, a review), and within this many pixels outside the image's bounds on its edge: the
#: shading kernel's ortho_edge_tol (fortran/pi_simulate.f90). OrthoImage.sample had none, and an
#: image's own edge centres, whose coordinates round to 5.000000000000342 of 5, sampled to NaN (the
#: simulation fuzzing, 2026-12-03)
ORTHO_EDGE_TOL = 1e-6


def _bilinear(values, u, v):
    """Bilinear interpolation of ``values`` (nrows, ncols[, bands]) at fractional
    (row, col) between pixel centres; over the outer half pixel of the image (its
    pixels are areas: the raster's bounds are half a pixel beyond its outer
    centres) the edge pixels' values, interpolated along the edge. NaN beyond the
    image's bounds (widened by ORTHO_EDGE_TOL, as the shading kernel does) or
    where a needed value is NaN (a neighbour within ORTHO_EDGE_TOL of no weight is
    not needed)."""
    nr, nc = values.shape[:2]
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    e = ORTHO_EDGE_TOL + 0.5
    inside = (u >= -e) & (u <= nr - 1 + e) & (v >= -e) & (v <= nc - 1 + e)
    uu = np.where(inside, np.clip(u, 0.0, nr - 1), 0.0)
    vv = np.where(inside, np.clip(v, 0.0, nc - 1), 0.0)
    i = np.minimum(np.floor(uu).astype(np.intp), max(nr - 2, 0))
    j = np.minimum(np.floor(vv).astype(np.intp), max(nc - 2, 0))
    fu, fv = uu - i, vv - j
    i1 = np.minimum(i + 1, nr - 1)
    j1 = np.minimum(j + 1, nc - 1)

    def interp(i, j, i1, j1, fu, fv):
        if values.ndim == 3:
            fu, fv = fu[..., None], fv[..., None]
        with np.errstate(invalid="ignore"):
            return ((1 - fu) * ((1 - fv) * values[i, j] + fv * values[i, j1])
                    + fu * ((1 - fv) * values[i1, j] + fv * values[i1, j1]))

    out = interp(i, j, i1, j1, fu, fv)
    nan = np.isnan(out)
    if nan.any():
        # a no-data pixel among the four: not needed when its weight is below ORTHO_EDGE_TOL (values
        # with data are not moved by this)
        up, left = fu >= 1.0 - ORTHO_EDGE_TOL, fv >= 1.0 - ORTHO_EDGE_TOL
        i2, j2 = np.where(up, i1, i), np.where(left, j1, j)
        fu2 = np.where(up | (fu <= ORTHO_EDGE_TOL), 0.0, fu)
        fv2 = np.where(left | (fv <= ORTHO_EDGE_TOL), 0.0, fv)
        snapped = interp(i2, j2, np.where(fu2 == 0.0, i2, i1), np.where(fv2 == 0.0, j2, j1), fu2, fv2)
        out = np.where(nan, snapped, out)
    if values.ndim == 3:
        inside = inside[..., None]
    return np.where(inside, out, np.nan)


def _crs_semi_major(crs):
    """The semi-major axis (metres) of a raster CRS's ellipsoid, or None when it has none."""
    try:
        import pyproj

        ell = pyproj.CRS.from_user_input(crs.to_wkt()).ellipsoid
        return None if ell is None else float(ell.semi_major_metre)
    except Exception:  # noqa: BLE001
        return None


def _same_body(a_crs_m: float, a) -> bool:
    """Whether an ortho-image's CRS (semi-major axis a_crs_m, metres) is on the body of a DSM of
    semi-major axis ``a`` in metres or kilometres (the DSM's unit is the user's: lat/lon are not)."""
    return any(abs(a * k - a_crs_m) <= 0.01 * a_crs_m for k in (1.0, 1000.0))


# ---------------------------------------------------------------- ortho image
class OrthoImage:
    """An ortho-image on a geodetic grid: ``values[nrows, ncols]`` or
    ``[nrows, ncols, bands]``, pixel-centre registered with the DSM's
    conventions (row i at geodetic latitude ``lat_first + i*dlat``, column j at
    east longitude ``lon_first + j*dlon``), not necessarily the DSM's grid."""

    def __init__(self):
        raise TypeError("use OrthoImage.from_array(...) or OrthoImage.read(path)")

    @classmethod
    def from_array(cls, values, lat_first, lon_first, dlat, dlon, nodata=None) -> "OrthoImage":
        """An ortho-image from an array and its grid.

        Parameters
        ----------
        values : array (nrows, ncols) or (nrows, ncols, bands)
            Brightness (any real dtype; kept as a private read-only float64 copy,
            the input dtype remembered for PNG scaling). Bands last: an array of
            at most 4 rows and more than 4 "bands" is refused as band-first
            (rasterio's ``read()`` layout; ``np.moveaxis(values, 0, -1)`` turns it).
        lat_first, lon_first : float
            Geodetic latitude and east longitude of pixel (0, 0)'s centre, degrees.
        dlat, dlon : float
            Grid steps, degrees (dlat < 0 for north-up rows; dlon > 0).
        nodata : float, optional
            Value marking missing pixels (NaN always does).
        """
        values = _unmask(values, "values", TypeError)           # masked elements are no data
        try:
            arr = np.asarray(values)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"values: not an array of numbers ({exc})") from None
        if arr.dtype.kind not in "fiub":
            raise TypeError(f"values: must be real numbers, got dtype {arr.dtype}")
        if arr.ndim not in (2, 3) or arr.shape[0] < 2 or arr.shape[1] < 2 or (arr.ndim == 3 and arr.shape[2] < 1):
            raise ValueError(f"values: expected (nrows, ncols) or (nrows, ncols, bands) with at least 2 x 2 pixels, "
                             f"got shape {arr.shape}")
        if arr.ndim == 3 and arr.shape[0] <= 4 < arr.shape[2]:
            # rasterio's read() and most image libraries' planar layouts are band-first: taken as
            # (nrows, ncols, bands) a (3, 48, 48) RGB array became 3 rows of 48-band pixels, and the
            # image came out nearly all fill with no error (a newcomer's walk-through)
            raise ValueError(f"values: shape {arr.shape} looks band-first (bands, nrows, ncols), as rasterio's "
                             f"read() returns it; give (nrows, ncols, bands), e.g. np.moveaxis(values, 0, -1)")
        lat_first = _number(lat_first, "lat_first")
        lon_first = _number(lon_first, "lon_first")
        dlat = _number(dlat, "dlat")
        dlon = _number(dlon, "dlon")
        if dlat == 0 or abs(dlat) > 90:
            raise ValueError(f"dlat must be non-zero and at most 90 degrees, got {dlat}")
        if not 0 < dlon <= 360:
            raise ValueError(f"dlon must be in (0, 360] degrees (east-going columns), got {dlon}")
        from .dsm import MIN_SPACING_DEG

        for name, d in (("dlat", dlat), ("dlon", dlon)):
            if abs(d) < MIN_SPACING_DEG:               # as for a GeodeticDSM (5e-324 overflowed: a review)
                raise ValueError(f"{name} = {d!r} degrees is below {MIN_SPACING_DEG:g} degrees: the image's "
                                 f"pixel coordinates would be lost to rounding")
        if abs(lon_first) >= 360.0:
            lon_first = math.fmod(lon_first, 360.0)       # exact, as GeodeticDSM does (7 + 360 * 2**40 drifted)
        last = lat_first + (arr.shape[0] - 1) * dlat
        if not (-90 <= lat_first <= 90 and -90 <= last <= 90):
            raise ValueError(f"lat_first, dlat: the grid's latitudes {lat_first}..{last} leave [-90, 90]")
        if arr.shape[1] * dlon > 360.0 * (1 + 1e-12):
            # (a 500-degree image was taken, and its columns wrapped onto each other: pixel (0, 0)
            # sampled as 3.6 where it holds 0, a review; a GeodeticDSM refuses it)
            raise ValueError(f"ncols * dlon = {arr.shape[1] * dlon} degrees exceeds 360")
        self = object.__new__(cls)
        v = arr.astype(np.float64, copy=True)
        if nodata is not None:
            from .dsm import _nodata_cells

            nodata = _number(nodata, "nodata")
            v[_nodata_cells(arr, nodata)] = np.nan            # (in the data's own precision: float32)
        v.flags.writeable = False
        self._v = v
        self.dtype = arr.dtype
        self.lat_first, self.lon_first, self.dlat, self.dlon = lat_first, lon_first, dlat, dlon
        self.nodata = nodata
        self.path = None
        #: semi-major axis (metres) of the body of the file's CRS (None: from an array); simulate_image
        #: checks it against the DSM's
        self.semi_major = None
        #: how a projected file was warped ("bilinear", "nearest"; None: not warped)
        self.resampling = None
        return self

    values = property(lambda self: self._v, doc="the image, float64 (read-only), NaN where no data")
    shape = property(lambda self: self._v.shape[:2])
    bands = property(lambda self: 1 if self._v.ndim == 2 else self._v.shape[2])

    def __repr__(self) -> str:
        return (f"OrthoImage({self.shape[0]} x {self.shape[1]} x {self.bands} band(s), lat {self.lat_first}"
                f"{self.dlat:+g}/row, lon {self.lon_first}{self.dlon:+g}/col)")

    def _core_values(self) -> np.ndarray:
        """values as the shading kernel takes them: (bands, ncols, nrows), Fortran order (no copy)."""
        nr, nc = self.shape
        return self._v.reshape(nr, nc, self.bands).T

    def _core_grid(self) -> tuple:
        return (math.radians(self.lat_first), math.radians(self.lon_first), math.radians(self.dlat),
                math.radians(self.dlon))

    def grid_coords(self, lat, lon):
        """Fractional (row, col) of (lat, lon) in degrees."""
        return _grid_coords(lat, lon, self.lat_first, self.lon_first, self.dlat, self.dlon, self.shape[1])

    def sample(self, lat, lon) -> np.ndarray:
        """Bilinear value at geodetic (lat, lon), degrees: their broadcast shape (+
        (bands,) for a multi-band image); the edge pixels' values over the image's
        outer half pixel; NaN beyond its bounds or where a needed pixel has no data."""
        arrs = []
        for name, x in (("lat", lat), ("lon", lon)):
            a = np.asarray(x)
            if a.dtype.kind not in "fiu":
                raise TypeError(f"{name}: must be real numbers (degrees), got dtype {a.dtype}")
            arrs.append(a.astype(np.float64))
        try:
            lat, lon = np.broadcast_arrays(*arrs)
        except ValueError:
            raise ValueError(f"lat and lon: shapes {arrs[0].shape} and {arrs[1].shape} do not broadcast") from None
        u, v = self.grid_coords(lat, lon)
        return _bilinear(self._v, u, v)

    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        """Latitudes (nrows,) and longitudes (ncols,) of the pixel centres, degrees."""
        return (self.lat_first + np.arange(self.shape[0]) * self.dlat,
                self.lon_first + np.arange(self.shape[1]) * self.dlon)

    @classmethod
    def read(cls, path, nodata=None, resampling: str = "bilinear") -> "OrthoImage":
        """Read an ortho-image from a GeoTIFF (all bands; rasterio) or an ``.npz``
        (arrays ``values``, ``lat_first``, ``lon_first``, ``dlat``, ``dlon``).

        A geographic CRS is read as it is (axis-aligned transform); a projected
        CRS is warped to a geodetic grid of about the same ground resolution, with
        ``resampling`` "bilinear" (default: a photo's texture, smooth) or
        "nearest" (every value one of the source's: one-pixel patterns kept),
        recorded in ``ortho.resampling``.
        Cells that the file's mask band marks invalid are no data; an alpha band
        is read as that mask, not as a band of brightness. The file is only read.
        """
        if not isinstance(path, (str, os.PathLike)):
            raise TypeError(f"path must be a file's path (str or pathlib.Path), got {type(path).__name__} {path!r}")
        if resampling not in ("bilinear", "nearest"):
            raise ValueError(f"resampling must be 'bilinear' or 'nearest', got {resampling!r}")
        path = Path(path)
        if path.is_dir():
            raise ValueError(f"ortho-image file {path}: is a directory, not a raster or .npz file")
        if not path.is_file():
            raise FileNotFoundError(f"ortho-image file {path}: no such file")
        if path.suffix.lower() == ".npz":
            d = _npz_arrays(path, ("values", "lat_first", "lon_first", "dlat", "dlon"), "ortho-image file")
            for key in ("lat_first", "lon_first", "dlat", "dlon"):
                if np.ndim(d[key]) != 0 or d[key].dtype.kind not in "fiu":
                    # (a string '1' was taken, an array gave NumPy's message without the name: a review)
                    raise ValueError(f"ortho-image file {path}: {key} must be a single number, got {d[key]!r}")
            try:
                o = cls.from_array(d["values"], float(d["lat_first"]), float(d["lon_first"]), float(d["dlat"]),
                                   float(d["dlon"]), nodata=nodata)
            except (TypeError, ValueError) as exc:
                raise ValueError(f"ortho-image file {path}: {exc}") from None
            o.path = path
            return o
        try:
            import rasterio
            from rasterio.warp import Resampling, reproject
        except ImportError:
            raise ImportError(f"reading {path} needs rasterio: pip install 'planet-intersect[geo]'") from None
        try:
            src = rasterio.open(path)
        except Exception as exc:  # noqa: BLE001
            raise ValueError(f"ortho-image file {path}: cannot be opened as a raster ({exc})") from None
        with src:
            from rasterio.enums import ColorInterp

            from .dsm import _geodetic_grid, _geographic_datum, _nodata_cells, _read_bands

            nd = _file_nodata(nodata, src.nodata)
            # an alpha band is the mask of the others, not brightness (an RGBA file was read as four
            # bands, its transparent pixels as values: a review)
            keep = [b for b in range(1, src.count + 1) if src.colorinterp[b - 1] != ColorInterp.alpha]
            if not keep:
                raise ValueError(f"ortho-image file {path}: has only alpha bands, no brightness")
            data, invalid = _read_bands(src, keep, path, "ortho-image", ValueError)   # (bands, rows, cols)
            if nd is not None:
                invalid |= _nodata_cells(data, nd)              # (in the data's own precision)
            nd_file, nd = nd, None                              # (applied above, in the file's dtype)
            dtype = data.dtype
            semi_major = _crs_semi_major(src.crs)
            warped = None
            if src.crs.is_geographic and _geographic_datum(src.crs, src.bounds, path, "ortho-image") == "as-is":
                t = src.transform
                if t.b != 0 or t.d != 0:
                    raise ValueError(f"ortho-image file {path}: rotated or sheared pixel grid is not supported")
                values = data.astype(np.float64)
                values[invalid] = np.nan
                values = np.moveaxis(values, 0, -1)
            else:
                dst_crs, tr, w, h = _geodetic_grid(src, path, "ortho-image", ValueError)
                warped = resampling
                src_f = data.astype(np.float64)
                src_f[invalid] = np.nan
                values = np.full((len(keep), h, w), np.nan)
                for b in range(len(keep)):
                    reproject(src_f[b], values[b], src_transform=src.transform, src_crs=src.crs, src_nodata=np.nan,
                              dst_transform=tr, dst_crs=dst_crs, dst_nodata=np.nan,
                              resampling=getattr(Resampling, resampling))
                values = np.moveaxis(values, 0, -1)
                t = tr
        if values.shape[2] == 1:
            values = values[:, :, 0]
        try:
            o = cls.from_array(values, t.f + 0.5 * t.e, t.c + 0.5 * t.a, t.e, t.a, nodata=nd)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"ortho-image file {path}: {exc}") from None
        o.dtype = dtype
        o.path = path
        o.semi_major = semi_major
        o.nodata = nd_file
        o.resampling = warped
        return o


# ------------------------------------------------------------------- result
#: units and long names of SimResult's variables in its NetCDF (to_xarray) and GeoTIFF band descriptions
#: (a review found none: lengths are in the DSM's units, metres for an Earth DSM)
_SIM_VARIABLE_ATTRS = {
    "image": ("", "simulated brightness (the ortho-image's values, shaded if asked); fill where not valid"),
    "valid": ("", "1 where the ray hit the DSM (status HIT or HIT_UNCONVERGED)"),
    "lat": ("degrees_north", "geodetic latitude of the hit"),
    "lon": ("degrees_east", "east longitude of the hit, [-180, 180)"),
    "height": ("DSM units", "geodetic height of the hit above the ellipsoid"),
    "distance": ("DSM units", "distance from the focal point to the hit along the ray"),
    "incidence": ("degrees", "angle between the reversed ray and the ellipsoid normal at the hit"),
    "local_incidence": ("degrees", "angle between the reversed ray and the surface normal used (walls: horizontal)"),
    "surface": ("", "kind of surface hit: 0 ground, 1 roof, 2 wall, -1 no hit"),
    "status": ("", "DSM ray status code (docs/status-codes.md)"),
    "p": ("DSM units", "hit point in the body-fixed (ECR) frame"),
    "ortho_value": ("", "1 where the ray hit and the ortho-image had a value there in every band"),
    "occlusion": ("", "1 on ortho pixels inside the footprint that no image pixel sees"),
    "footprint": ("", "1 on ortho pixels inside the image's ground footprint, on the DSM"),
}


@dataclass
class SimResult:
    """A simulated image and its per-pixel backplanes, all (nlines, npixels)
    except ``image`` ((nlines, npixels) or (nlines, npixels, bands)), ``p``
    (nlines, npixels, 3) and the ortho-grid masks. Angles in degrees; lengths
    in the DSM's units; NaN (surface -1, valid False) where a ray did not hit."""

    image: np.ndarray  #: simulated brightness (float32); ``fill`` where not valid
    valid: np.ndarray  #: True where the ray hit the DSM (status HIT)
    lat: np.ndarray  #: geodetic latitude of the hit
    lon: np.ndarray  #: east longitude of the hit, [-180, 180)
    height: np.ndarray  #: exact geodetic height of the hit above the ellipsoid
    distance: np.ndarray  #: from the focal point along the unit ray
    incidence: np.ndarray  #: angle of -l to the ellipsoid normal at the hit
    local_incidence: np.ndarray  #: angle of -l to the surface normal used (walls: outward horizontal)
    surface: np.ndarray  #: int8: 0 ground, 1 roof, 2 wall, -1 no hit
    status: np.ndarray  #: int8 DSM ray status (DSMStatus)
    p: np.ndarray  #: hit point, ECR
    #: True where the ray hit and the ortho-image had a value there in every band (a hit without one
    #: gets ``fill``; in a multi-band image, only in the bands that have no value there)
    ortho_value: np.ndarray | None = None
    occlusion: np.ndarray | None = None  #: ortho grid: ground in the footprint hidden from the sensor
    footprint: np.ndarray | None = None  #: ortho grid: inside the image's ground footprint, on the DSM
    meta: dict = field(default_factory=dict)  #: run parameters, counts and timings

    @property
    def shape(self) -> tuple[int, int]:
        return self.valid.shape

    def counts(self) -> dict:
        """Pixels by surface kind and by ray status."""
        out = {name: int(np.count_nonzero(self.surface == code)) for code, name in SURFACE_CODES.items()}
        names = {v: k for k, v in vars(DSMStatus).items() if k.isupper()}
        for code in np.unique(self.status):
            out[f"status {names.get(int(code), int(code))}"] = int(np.count_nonzero(self.status == code))
        if self.ortho_value is not None:
            out["hits without an ortho value"] = int(np.count_nonzero(self.valid)) - int(
                np.count_nonzero(self.ortho_value))
        if self.occlusion is not None:
            out["occluded ortho pixels"] = int(np.count_nonzero(self.occlusion))
            out["footprint ortho pixels"] = int(np.count_nonzero(self.footprint))
        return out

    def to_xarray(self):
        """An :class:`xarray.Dataset` in sensor geometry (dims line, pixel[, band,
        xyz]) plus the ortho-grid masks (dims ortho_row, ortho_col)."""
        import xarray as xr

        data = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "meta" or v is None:
                continue
            if f.name in ("occlusion", "footprint"):
                data[f.name] = (("ortho_row", "ortho_col"), np.asarray(v, dtype=np.int8))
            elif f.name == "p":
                data[f.name] = (("line", "pixel", "xyz"), np.asarray(v))
            elif f.name == "image" and v.ndim == 3:
                data[f.name] = (("line", "pixel", "band"), np.asarray(v))
            elif f.name in ("valid", "ortho_value"):
                data[f.name] = (("line", "pixel"), np.asarray(v, dtype=np.int8))
            else:
                data[f.name] = (("line", "pixel"), np.asarray(v))
        ds = xr.Dataset(data)
        for name, (units, long_name) in _SIM_VARIABLE_ATTRS.items():
            if name in ds:
                ds[name].attrs.update(long_name=long_name, **({"units": units} if units else {}))
        g = self.meta
        if "occlusion" in ds and all(k in g for k in ("ortho_lat_first", "ortho_dlat", "ortho_lon_first", "ortho_dlon")):
            # the masks' grid (the ortho-image's geodetic grid, after any warp): pixel centres, so that a map
            # reader can place them (a review: no coordinates, and after a warp a grid no file defined)
            ds = ds.assign_coords(
                ortho_lat=("ortho_row", g["ortho_lat_first"] + g["ortho_dlat"] * np.arange(ds.sizes["ortho_row"])),
                ortho_lon=("ortho_col", g["ortho_lon_first"] + g["ortho_dlon"] * np.arange(ds.sizes["ortho_col"])))
            ds["ortho_lat"].attrs.update(units="degrees_north", long_name="geodetic latitude of the ortho pixel centre")
            ds["ortho_lon"].attrs.update(units="degrees_east", long_name="east longitude of the ortho pixel centre")
        ds.attrs["surface_codes"] = "; ".join(f"{k}: {v}" for k, v in SURFACE_CODES.items())
        ds.attrs["status_codes"] = "; ".join(f"{v}: {k}" for k, v in vars(DSMStatus).items() if k.isupper())
        ds.attrs["angles"] = "degrees; latitudes geodetic, longitudes east in [-180, 180)"
        for k, v in self.meta.items():
            if isinstance(v, np.generic):
                v = v.item()                          # (numpy scalars were dropped: a review)
            if isinstance(v, bool):
                v = int(v)                            # (NetCDF has no boolean attribute)
            if isinstance(v, (int, float, str)):
                ds.attrs[k] = v
        return ds

    def display_image(self) -> np.ndarray:
        """The image as 8-bit for people: values as they are when the ortho-image
        was 8-bit, else a 1-99 percentile stretch; no-hit pixels black."""
        img = np.asarray(self.image, dtype=np.float64)
        if self.meta.get("ortho_dtype") == "uint8":
            lo, hi = 0.0, 255.0
        else:
            ok = np.asarray(self.valid)
            vals = img[ok] if ok.any() else img.ravel()
            vals = vals[np.isfinite(vals)]
            lo, hi = (np.percentile(vals, [1, 99]) if vals.size else (0.0, 1.0))
            if hi <= lo:
                hi = lo + 1.0
        out = np.clip((img - lo) / (hi - lo), 0, 1)
        out = np.where(np.isfinite(out), out, 0.0)
        return np.rint(out * 255).astype(np.uint8)

    def save(self, path) -> Path:
        """Write the result: ``.png`` (the image, 8-bit, for people), ``.tif``
        (GeoTIFF in sensor geometry, no georeference: the image bands then the
        backplanes lat, lon, height, distance, incidence, local_incidence,
        surface, valid, status, ortho_value as float64 bands with those names as
        descriptions, units and long names, and the run's parameters as tags), ``.nc`` (NetCDF of :meth:`to_xarray`,
        the parameters as attributes). An existing file is not overwritten.

        The file appears under its name only when it is complete: it is written
        to a hidden ``.pi-save-XXXXXXXX.partial.EXT`` beside it and linked to its name at the end (a
        GeoTIFF after reading it back); a run that fails or is interrupted
        removes that file. A disk without room for it is refused before writing
        (a review found a full disk leaving a GeoTIFF that opened as complete
        but was three quarters zeros, and Ctrl-C leaving all-zero bands)."""
        import os
        import shutil

        path = Path(path)
        if path.exists():
            raise FileExistsError(f"{path}: exists; choose another name (nothing is overwritten)")
        if not path.parent.is_dir():
            raise FileNotFoundError(f"{path.parent}: no such directory")
        suffix = path.suffix.lower()
        if suffix not in (".png", ".tif", ".tiff", ".nc"):
            raise ValueError(f"{path}: unknown format {suffix!r} (use .png, .tif or .nc)")
        nl, npx = self.shape
        bands = 1 if np.ndim(self.image) == 2 else np.shape(self.image)[2]
        need = {".png": nl * npx * 4, ".nc": sum(np.asarray(getattr(self, f.name)).nbytes for f in fields(self)
                                                 if f.name != "meta" and getattr(self, f.name) is not None)}.get(
            suffix, nl * npx * 8 * (bands + 10))
        free = shutil.disk_usage(path.parent).free
        if need * 1.02 + 2 ** 20 > free:
            raise OSError(28, f"{path}: needs about {need / 2 ** 20:,.0f} MiB, and {path.parent} has "
                              f"{free / 2 ** 20:,.0f} MiB free (nothing written)")
        import tempfile

        # a name of its own (two saves to one path, from two threads or two hosts with one pid, wrote
        # one file: a review), short whatever the target's name (241-255 characters must still save)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".pi-save-", suffix=f".partial{path.suffix}")
        os.close(fd)
        tmp = Path(tmp)
        try:
            try:
                if suffix == ".png":
                    from matplotlib import image as mimage

                    img = self.display_image()
                    if img.ndim == 3 and img.shape[2] not in (3, 4):
                        img = img[:, :, 0]
                    mimage.imsave(tmp, img, cmap="gray", vmin=0, vmax=255, format="png")
                elif suffix in (".tif", ".tiff"):
                    self._write_tif(tmp)
                else:
                    self.to_xarray().to_netcdf(tmp, engine="h5netcdf")
            except OSError as exc:                  # named after the file asked for, not the temporary
                if exc.errno is None:
                    raise OSError(f"{path}: not written ({exc})") from exc
                raise OSError(exc.errno, f"{path}: not written ({exc.strerror or exc})") from exc
            try:
                os.link(tmp, path)                  # no overwrite, even of a file made meanwhile
            except FileExistsError:
                raise FileExistsError(f"{path}: appeared while it was written; choose another name "
                                      "(nothing is overwritten)") from None
            except OSError:                         # a file system without hard links
                if path.exists():
                    raise FileExistsError(f"{path}: exists; choose another name (nothing is overwritten)") from None
                os.rename(tmp, path)
        finally:                                    # whatever happened, no partial file stays
            if tmp.exists():
                tmp.unlink()
        return path

    def _write_tif(self, tmp: Path) -> None:
        """The GeoTIFF of :meth:`save`, read back before it counts as written."""
        import warnings

        import rasterio
        from rasterio.errors import NotGeoreferencedWarning

        img = np.asarray(self.image, dtype=np.float64)
        img = img[:, :, None] if img.ndim == 2 else img
        names = [f"image band {b + 1}" for b in range(img.shape[2])]
        planes = [img[:, :, b] for b in range(img.shape[2])]
        for name in ("lat", "lon", "height", "distance", "incidence", "local_incidence", "surface", "valid",
                     "status", "ortho_value"):
            if getattr(self, name) is None:
                continue
            names.append(name)
            planes.append(np.asarray(getattr(self, name), dtype=np.float64))
        tags = {k: v for k, v in self.meta.items() if isinstance(v, (int, float, str))}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(tmp, "w", driver="GTiff", width=img.shape[1], height=img.shape[0],
                               count=len(planes), dtype="float64") as dst:
                for b, (name, plane) in enumerate(zip(names, planes), start=1):
                    dst.write(plane, b)
                    dst.set_band_description(b, name)
                    units, long_name = _SIM_VARIABLE_ATTRS.get(name.split(" band")[0], ("", ""))
                    if units:
                        dst.set_band_unit(b, units)
                    if long_name:
                        dst.update_tags(b, long_name=long_name)
                dst.update_tags(surface_codes="; ".join(f"{k}: {v}" for k, v in SURFACE_CODES.items()),
                                status_codes="; ".join(f"{v}: {k}" for k, v in vars(DSMStatus).items()
                                                       if k.isupper()),
                                geometry="sensor (line, pixel)", **tags)
            # libtiff reports a failed write (a full disk) on stderr only: read every band back
            with rasterio.open(tmp) as src:
                for b, plane in enumerate(planes, start=1):
                    if not np.array_equal(src.read(b), plane, equal_nan=True):
                        raise OSError(f"{tmp}: band {b} ({names[b - 1]}) did not read back as written "
                                      "(a full disk or a failing device); nothing kept")


# ----------------------------------------------------------- surface geometry
def _metres_per_degree(lat_deg, h, a, f):
    """(north, east) metres per degree of latitude / longitude at (lat, h)."""
    e2 = f * (2 - f)
    s = np.sin(np.radians(lat_deg))
    w = np.sqrt(1 - e2 * s * s)
    m = a * (1 - e2) / w ** 3
    n = a / w
    return np.radians(1.0) * (m + h), np.radians(1.0) * (n + h) * np.cos(np.radians(lat_deg))


def _opening_ground(dsm: GeodeticDSM, window_m: float) -> np.ndarray:
    """Bare-earth estimate from the DSM by a grey-scale morphological opening
    (erosion then dilation) with a square window about ``window_m`` wide: it
    removes every raised object narrower than the window and keeps planar
    slopes exactly [sim note 1]."""
    from scipy import ndimage

    h = np.asarray(dsm.heights, dtype=np.float64)
    lat_mid = dsm.lat_first + 0.5 * (dsm.nrows - 1) * dsm.dlat
    my, mx = _metres_per_degree(lat_mid, 0.0, dsm.a, dsm.f)
    # a window wider than twice the grid opens exactly as one of 2 n + 1 (every window then holds the
    # whole grid): clipped, so that a huge ground_window costs nothing (it took minutes, then a
    # MemoryError, found by a review)
    wy = min(max(3, int(min(math.ceil(window_m / (abs(dsm.dlat) * my)), 4 * dsm.nrows + 3)) | 1),
             2 * dsm.nrows + 1)
    wx = min(max(3, int(min(math.ceil(window_m / (dsm.dlon * mx)), 4 * dsm.ncols + 3)) | 1), 2 * dsm.ncols + 1)
    filled = np.where(np.isfinite(h), h, np.nanmax(h) if np.isfinite(h).any() else 0.0)
    return ndimage.grey_opening(filled, size=(wy, wx), mode="nearest")


# ------------------------------------------------------------- the simulation
class _Progress:
    """A one-line progress bar on stderr for long runs (lines done, rate, ETA)."""

    def __init__(self, total: int, enabled: bool):
        self.total, self.enabled = total, enabled
        self.t0 = time.perf_counter()
        self.last = 0.0

    def update(self, done: int, pixels: int):
        if not self.enabled:
            return
        now = time.perf_counter()
        if done < self.total and now - self.last < 0.5:
            return
        self.last = now
        el = now - self.t0
        frac = done / self.total
        eta = el / frac - el if frac > 0 else float("nan")
        bar = "#" * int(30 * frac)
        sys.stderr.write(f"\rsimulate [{bar:<30}] {done}/{self.total} lines, {pixels / max(el, 1e-9):,.0f} px/s, "
                         f"ETA {eta:5.0f} s")
        if done >= self.total:
            sys.stderr.write("\n")
        sys.stderr.flush()


def _flag(value, name: str) -> bool:
    """A boolean argument: True/False (or NumPy's); "no" was taken as True (a review)."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    raise TypeError(f"{name} must be True or False, got {value!r}")


def _check_sun(sun):
    if sun is None:
        raise ValueError("shading='lambert' needs sun=(azimuth_deg, elevation_deg) or an ECR vector (3,)")
    try:
        arr = np.asarray(sun, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"sun: expected (azimuth_deg, elevation_deg) or an ECR vector (3,), got {sun!r}") from None
    if arr.shape not in ((2,), (3,)) or not np.isfinite(arr).all():
        raise ValueError(f"sun: expected 2 finite angles (deg) or a finite ECR vector (3,), got {sun!r}")
    if arr.shape == (3,):
        big = np.abs(arr).max()
        if not big > 0:
            raise ValueError("sun: the ECR vector has zero length")
        arr = arr / big                               # a direction: 1e308 components overflowed (a review)
    if arr.shape == (2,) and not -90 <= arr[1] <= 90:
        raise ValueError(f"sun: elevation {arr[1]} outside [-90, 90] degrees")
    return arr


#: pixels per block when simulate_image's block_lines is None [sim note 9]: blocks of ~131,072 pixels
#: (32 lines of 4,096) simulated 1,024 lines of the 4,096^2 benchmark scene 1.16-1.24x as fast as blocks
#: of 256 lines on one thread and 1.06-1.34x on two (3 rounds in one process, memory-mapped outputs):
#: each block's rays, results and temporaries (~0.5 kB per pixel) stay in cache, and the threads'
#: work between serial steps is shorter
BLOCK_PIXELS = 131_072


class _BlockFile:
    """One output of ``simulate_image(out=DIR)``: a new ``DIR/NAME.npy`` of the whole image's
    shape, written a block of lines at a time from one reused in-memory block buffer
    [sim note 9]. The kernel writes each block into ``buf``; ``emit`` appends its first
    ``nb`` lines to the file. ``result`` maps the finished file (mode r+).

    Assigning into a memory map of the new (sparse) file instead costs a page fault per page
    and the file system's zero-fill of every page before it is written: measured on the
    4,096^2 benchmark image, 2.8-3.1 s of its ~18 s in the kernel's zero-fill; a buffered
    ``write`` of whole pages skips it (sim note 9)."""

    def __init__(self, out_dir, name, shape, dtype, block_lines):
        self.path = out_dir / f"{name}.npy"
        # plain ints: a sensor's shape of NumPy integers wrote "np.int64(100)" into the header,
        # which np.load could not parse after the whole image was done (a review)
        self.shape, self.dtype = tuple(int(k) for k in shape), np.dtype(dtype)
        # the buffer before the file: a MemoryError here leaves no open handle (a review)
        self.buf = np.empty((min(int(block_lines), self.shape[0]),) + self.shape[1:], dtype=self.dtype)
        self.row_bytes = int(np.prod(self.shape[1:])) * self.dtype.itemsize
        with open(self.path, "xb") as f:                 # (x: a file that exists is never overwritten)
            np.lib.format.write_array_header_1_0(f, {"descr": np.lib.format.dtype_to_descr(self.dtype),
                                                     "fortran_order": False, "shape": self.shape})
            self.offset = f.tell()
            f.truncate(self.offset + int(np.prod(self.shape)) * self.dtype.itemsize)
        self.file = open(self.path, "r+b")

    def emit(self, k0: int, nb: int):
        self.file.seek(self.offset + k0 * self.row_bytes)
        self.file.write(memoryview(self.buf[:nb]).cast("B"))

    def result(self) -> np.ndarray:
        self.file.close()
        return np.load(self.path, mmap_mode="r+")

    def close(self):
        self.file.close()


def simulate_image(dsm: GeodeticDSM, ortho: OrthoImage, sensor, method: str = "exact",
                   walls: str = "interpolate", shading: str = "none", sun=None, ambient: float = 0.0,
                   fill: float = 0.0, occlusion: bool = True, ground=None, ground_window: float = 100.0,
                   wall_slope: float = 60.0, roof_min: float = 2.0, threads: int | None = None,
                   block_lines: int | None = None, progress: bool = False, out=None) -> SimResult:
    """Simulate the image a sensor takes of an ortho-photo draped on a DSM
    (Shin & Park's direct modelling).

    Parameters
    ----------
    dsm : GeodeticDSM
        The surface model (heights above its ellipsoid).
    ortho : OrthoImage
        Brightness on a geodetic grid, sampled bilinearly at each hit.
    sensor : Pushbroom or FrameCamera
        Which ray each pixel casts (ECR, units of ``dsm.a``).
    method : "exact" (default), "following" or "iterative"
        The intersection method (``pi.intersect``): exact first hits, the
        paper's ray following, or the conventional iterative ray tracing (its
        non-converged pixels get ``fill``; Fig. 4(b)).
    walls : "interpolate" (default) or "ortho"
        A wall hit's value: linear in height between the ortho value at the roof
        edge above and at the wall's foot [sim note 2], or the ortho value at the
        hit's (lat, lon) as for any other surface.
    shading : "none" (default) or "lambert"
        Lambertian shading [sim note 4]: values times ``ambient + (1 - ambient) max(0, n.sun)``
        with n the surface normal used for ``local_incidence``.
    sun : (azimuth_deg, elevation_deg) or ECR vector (3,)
        Direction toward the Sun (needed for "lambert"); the angles are taken
        at each hit, azimuth clockwise from north.
    ambient : float in [0, 1]
    fill : float
        Image value of pixels whose ray does not hit (left the DSM, no data, ...).
    occlusion : bool
        Compute ``occlusion`` and ``footprint`` on the ortho grid (one more
        exact ray per ortho pixel in the footprint).
    ground : array like ``dsm.heights`` or GeodeticDSM, optional
        Bare-earth heights on the DSM grid for the roof/ground classification;
        default: a morphological opening of the DSM ``ground_window`` metres wide.
    wall_slope : float, degrees
        A hit where the DSM is steeper than this is a wall.
    roof_min : float
        A non-wall hit more than this above the ground is a roof.
    threads : int, optional
        OpenMP threads (results identical for any count).
    block_lines : int, optional
        Lines per block (memory per block ~ 0.5 kB per pixel); default: as many
        lines as make about 131,072 pixels (at least one line) [sim note 9].
    progress : bool
        A progress bar on stderr.
    out : path, optional
        A new directory: the backplanes are memory-mapped ``.npy`` files there
        (images larger than memory), and the result's arrays are those maps.

    Returns
    -------
    SimResult
    """
    from ._ext import core as _core
    from .dsm import _trace_raw
    from .geodetic import _wrap180
    from .intersect import _choice, check_threads
    from .sensors import Sensor

    if not isinstance(dsm, GeodeticDSM):
        raise TypeError(f"dsm must be a planet_intersect.GeodeticDSM, got {type(dsm).__name__}")
    if not isinstance(ortho, OrthoImage):
        raise TypeError(f"ortho must be a planet_intersect.OrthoImage, got {type(ortho).__name__}")
    if not isinstance(sensor, Sensor):
        raise TypeError(f"sensor must be a planet_intersect.Pushbroom or FrameCamera, got {type(sensor).__name__}")
    _choice(method, "method", _METHODS)
    _choice(walls, "walls", ("interpolate", "ortho"))
    _choice(shading, "shading", ("none", "lambert"))
    sun_arr = _check_sun(sun) if shading == "lambert" else None
    ambient = _number(ambient, "ambient")
    if not 0 <= ambient <= 1:
        raise ValueError(f"ambient must be in [0, 1], got {ambient}")
    if shading != "lambert" and (sun is not None or ambient != 0):
        # (they were ignored without a word: a review)
        raise ValueError(f"sun and ambient apply only with shading='lambert' (got shading={shading!r}, "
                         f"sun={sun!r}, ambient={ambient!r})")
    fill = float(fill) if isinstance(fill, (int, float, np.floating, np.integer)) and not \
        isinstance(fill, (bool, np.bool_)) else _number(fill, "fill")
    if math.isfinite(fill) and abs(fill) > float(np.finfo(np.float32).max):
        raise ValueError(f"fill = {fill!r}: the image is float32, whose largest value is "
                         f"{float(np.finfo(np.float32).max):g} (NaN is allowed)")
    occlusion = _flag(occlusion, "occlusion")
    progress = _flag(progress, "progress")
    wall_slope = _number(wall_slope, "wall_slope")
    if not 0 < wall_slope < 90:
        raise ValueError(f"wall_slope must be in (0, 90) degrees, got {wall_slope}")
    roof_min = _number(roof_min, "roof_min")
    ground_window = _number(ground_window, "ground_window")
    if ground_window <= 0:
        raise ValueError(f"ground_window must be positive (metres), got {ground_window}")
    if block_lines is not None and (not isinstance(block_lines, (int, np.integer)) or isinstance(block_lines, bool)
                                    or block_lines < 1):
        raise ValueError(f"block_lines must be a positive integer or None, got {block_lines!r}")
    if block_lines is not None:
        block_lines = int(block_lines)                # np.int8(100) overflowed in the block arithmetic
    check_threads(threads, 1)
    if ortho.semi_major is not None and not _same_body(ortho.semi_major, dsm.a):
        # (a Mars ortho-photo was draped on an Earth DSM without a word: a review)
        raise ValueError(f"ortho: its file {ortho.path} is on a body of semi-major axis {ortho.semi_major:.10g} m, "
                         f"the DSM's a = {dsm.a:.10g}: an ortho-image must be on the DSM's body")
    npx = int(sensor.shape[0]) * int(sensor.shape[1])
    if npx > MAX_PIXELS:
        raise ValueError(f"sensor: {sensor.shape[0]:,} x {sensor.shape[1]:,} = {npx:,} pixels, more than "
                         f"{MAX_PIXELS:,} (its backplanes alone would take ~{npx * 100 / 2**40:.3g} TiB)")
    orb = getattr(sensor, "orbit", None)
    if isinstance(orb, dict) and "a" in orb and "f" in orb:
        if not (math.isclose(orb["a"], dsm.a, rel_tol=1e-12) and math.isclose(orb["f"], dsm.f, rel_tol=1e-12,
                                                                               abs_tol=1e-15)):
            raise ValueError(f"sensor: its orbit was built on the ellipsoid a = {orb['a']:.10g}, f = {orb['f']:.10g}, "
                             f"the DSM's is a = {dsm.a:.10g}, f = {dsm.f:.10g} (pass a=, f= to from_orbit)")
    if ground is None:
        ground_grid = _opening_ground(dsm, ground_window)
    elif isinstance(ground, GeodeticDSM):
        # its own grid: sampled at the DSM's nodes (its heights array alone was used, whatever its
        # grid or row order: a review saw a south-up copy of the same ground relabel 1,296 pixels)
        if not (math.isclose(ground.a, dsm.a, rel_tol=1e-12) and math.isclose(ground.f, dsm.f, rel_tol=1e-12,
                                                                               abs_tol=1e-15)):
            raise ValueError(f"ground: its ellipsoid (a = {ground.a:.10g}, f = {ground.f:.10g}) differs from the "
                             f"DSM's (a = {dsm.a:.10g}, f = {dsm.f:.10g})")
        lat_g, lon_g = np.meshgrid(dsm.lats, dsm.lons, indexing="ij")
        ground_grid = np.asarray(ground.height(lat_g, lon_g), dtype=np.float64)
    else:
        g = ground
        try:
            ground_grid = np.asarray(g, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError("ground: expected an array of heights like dsm.heights") from None
        if ground_grid.shape != dsm.heights.shape:
            raise ValueError(f"ground: shape {ground_grid.shape} differs from the DSM's {dsm.heights.shape}")
    out_dir = None
    if out is not None:
        # absolute now: the result maps the files at the end, and a failed run removes the folder,
        # both after a sensor's rays() may have changed the working directory (a review)
        out_dir = Path(out).absolute()
        if out_dir.exists():
            raise FileExistsError(f"out={out_dir}: exists; choose a new directory (nothing is overwritten)")
        out_dir.mkdir(parents=True)
    if out_dir is None:
        _check_memory(sensor.shape, ortho.bands)
    try:
        sim = _simulate(dsm, ortho, sensor, method, walls, shading, sun_arr, ambient, fill, occlusion, ground_grid,
                        wall_slope, roof_min, threads, block_lines, progress, out_dir)
        sim.meta.update(_provenance(dsm, ortho, sensor, sun=sun, ambient=ambient, fill=fill, occlusion=occlusion,
                                    ground="given" if ground is not None else f"opening of {ground_window:g} m",
                                    wall_slope=wall_slope, roof_min=roof_min))
    except BaseException:
        # a failed run leaves no half-filled maps that look like a result (the folder is this call's own)
        if out_dir is not None:
            import shutil

            shutil.rmtree(out_dir, ignore_errors=True)
        raise
    if out_dir is not None:
        # the maps are complete here: if the masks or meta.json cannot be written (a full disk), the
        # maps stay and the folder has no meta.json (a review: a failure here deleted a finished run)
        _finish_out_dir(out_dir, sim)
    return sim


#: bytes a pixel of the in-memory result holds: image (float32 a band), valid, surface, ortho_value,
#: status (1 each), six float64 backplanes and p (3 float64)
_BYTES_PER_PIXEL = 4 + 4 + 6 * 8 + 24


def _check_memory(shape, bands: int) -> None:
    """Refuse an in-memory result larger than the machine's physical memory (a review: an orbit of
    2,000,000 lines passed every check and the kernel killed the process)."""
    from .footprint import _physical_memory           # (the cell table's check asks the same)

    nl, npx = shape
    need = nl * npx * (_BYTES_PER_PIXEL + 4 * (bands - 1))
    phys = _physical_memory()
    if need > phys:
        raise MemoryError(f"sensor: {nl:,} lines x {npx:,} pixels need {need / 2 ** 30:,.1f} GiB for the result, "
                          f"more than this machine's {phys / 2 ** 30:,.1f} GiB: pass out=DIR (the outputs then go to "
                          f"memory-mapped files, block by block; the CLI's --memmap) or simulate fewer lines per call")


def _provenance(dsm, ortho, sensor, **options) -> dict:
    """What a simulation was made from, as numbers and strings for its files' attributes and tags (a
    review: two runs with other sensors or options could not be told apart from their files)."""
    import datetime

    from . import __version__

    out = {"planet_intersect_version": __version__,
           "created_utc": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
           "dsm_shape": f"{dsm.nrows} x {dsm.ncols}", "dsm_lat_first": dsm.lat_first, "dsm_lon_first": dsm.lon_first,
           "dsm_dlat": dsm.dlat, "dsm_dlon": dsm.dlon, "dsm_a": dsm.a, "dsm_f": dsm.f,
           "dsm_interpolation": dsm.interpolation, "dsm_file": str(getattr(dsm, "path", None) or "(array)"),
           "ortho_shape": f"{ortho.shape[0]} x {ortho.shape[1]}", "ortho_bands": ortho.bands,
           "ortho_lat_first": ortho.lat_first, "ortho_lon_first": ortho.lon_first, "ortho_dlat": ortho.dlat,
           "ortho_dlon": ortho.dlon, "ortho_file": str(getattr(ortho, "path", None) or "(array)"),
           "ortho_resampling": str(getattr(ortho, "resampling", None) or "(not warped)"),
           "sensor": type(sensor).__name__, "sensor_lines": int(sensor.shape[0]), "sensor_pixels": int(sensor.shape[1])}
    nl, npx = sensor.shape
    for tag, k in (("first", 0), ("last", nl - 1)):
        # each end line's centre pixel: where it was and where it looked (a review: two frame cameras
        # 5 m apart, or two rolls, left the same record)
        s, l = sensor.rays(k, k + 1)
        s, l = np.atleast_2d(s), np.atleast_2d(l)
        j = min(npx // 2, len(l) - 1)
        out[f"sensor_focal_point_{tag}"] = " ".join(f"{x:.6f}" for x in s[min(j, len(s) - 1)])
        v = np.asarray(l[j], dtype=np.float64)
        v = v / np.max(np.abs(v))                       # (rays of 1e154 overflowed the norm: the fuzz)
        out[f"sensor_centre_ray_{tag}"] = " ".join(f"{x:.12f}" for x in v / np.linalg.norm(v))
    for k, v in options.items():
        out[k] = v if isinstance(v, (bool, int, float, str)) else ("none" if v is None else
                                                                   " ".join(f"{x:g}" for x in np.ravel(v)))
        if isinstance(out[k], bool):
            out[k] = int(out[k])
    return out


def _jsonable(v):
    """A value strict JSON can hold: numbers as numbers (numpy scalars too), NaN and infinities and
    anything else as strings (json's bare NaN is refused by strict parsers: a review)."""
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return str(v)
    return v if isinstance(v, (bool, int, float, str, type(None))) else str(v)


def _finish_out_dir(out_dir: Path, sim) -> None:
    """out=DIR's last files: the ortho-grid masks and meta.json, written last and renamed into place,
    so that a folder without meta.json is a run that did not finish (a review: a killed run left
    full-size maps that loaded as complete, their unwritten lines saying HIT at 0 N 0 E)."""
    import json
    import os

    for name in ("occlusion", "footprint"):
        v = getattr(sim, name)
        if v is not None:
            np.save(out_dir / f"{name}.npy", np.asarray(v))
    meta = {k: _jsonable(v) for k, v in sim.meta.items()}
    meta["complete"] = True
    tmp = out_dir / ".meta.json.partial"
    tmp.write_text(json.dumps(meta, indent=1) + "\n")
    os.replace(tmp, out_dir / "meta.json")


def _rows(arr, blk: slice, shape):
    """A view of the rows ``blk`` of a C-ordered output array, reshaped (the kernel writes into
    it in place: a reshape that had to copy would lose the results, so it is refused)."""
    block = arr[blk]
    if not block.flags.c_contiguous:                       # (np.full and the block buffers are C-ordered)
        raise RuntimeError("simulate_image: an output block is not contiguous (internal error)")
    return block.reshape(shape)


def _simulate(dsm, ortho, sensor, method, walls, shading, sun_arr, ambient, fill, occlusion, ground_grid, wall_slope,
              roof_min, threads, block_lines, progress, out_dir) -> SimResult:
    """simulate_image after its checks (out_dir: the new folder of the maps, or None)."""
    nl, npx = sensor.shape
    if block_lines is None:
        block_lines = max(1, BLOCK_PIXELS // max(npx, 1))     # [sim note 9]
    bands = ortho.bands
    ishape = (nl, npx) if bands == 1 else (nl, npx, bands)
    specs = [("image", ishape, np.float32, fill), ("valid", (nl, npx), bool, False)]
    specs += [(name, (nl, npx), np.float64, np.nan)
              for name in ("lat", "lon", "height", "distance", "incidence", "local_incidence")]
    specs += [("surface", (nl, npx), np.int8, -1), ("ortho_value", (nl, npx), bool, False),
              ("status", (nl, npx), np.int8, -1), ("p", (nl, npx, 3), np.float64, np.nan)]
    files = {}
    try:
        if out_dir is None:
            arrays = {name: np.full(shape, fv, dtype=dtype) for name, shape, dtype, fv in specs}
        else:
            for name, shape, dtype, _ in specs:
                files[name] = _BlockFile(out_dir, name, shape, dtype, block_lines)
            arrays = {name: f.buf for name, f in files.items()}
        sim = _simulate_blocks(dsm, ortho, sensor, method, walls, shading, sun_arr, ambient, fill, occlusion,
                               ground_grid, wall_slope, roof_min, threads, block_lines, progress, arrays, files)
    except BaseException:
        # every file closed, and the error that stopped the run is the one raised: a close that
        # fails here (its flush on a full disk) must neither hide it nor leave the other files
        # open (a review)
        _close_all(files.values(), raise_first=False)
        raise
    _close_all(files.values())
    return sim


def _close_all(files, raise_first: bool = True) -> None:
    """Close every file; then raise the first error a close raised, if any and if asked."""
    first = None
    for f in files:
        try:
            f.close()
        except OSError as exc:
            first = first or exc
    if first is not None and raise_first:
        raise first


def _simulate_blocks(dsm, ortho, sensor, method, walls, shading, sun_arr, ambient, fill, occlusion, ground_grid,
                     wall_slope, roof_min, threads, block_lines, progress, arrays, files) -> SimResult:
    """_simulate's block loop: ``arrays`` are the whole outputs (in memory), or, with ``files``
    (out=DIR), each output's block buffer, written to its file after every block."""
    from ._ext import core as _core
    from .dsm import _trace_raw
    from .geodetic import _wrap180
    from .intersect import check_threads

    nl, npx = sensor.shape
    bands = ortho.bands
    image, valid, surface, ortho_value, status, pts = (arrays[k] for k in ("image", "valid", "surface",
                                                                             "ortho_value", "status", "p"))
    planes = {name: arrays[name] for name in ("lat", "lon", "height", "distance", "incidence", "local_incidence")}
    # what the shading kernel (fortran/pi_simulate.f90) needs, made once
    lat_mid = dsm.lat_first + 0.5 * (dsm.nrows - 1) * dsm.dlat
    my, mx = _metres_per_degree(lat_mid, 0.0, dsm.a, dsm.f)
    grid = dsm._core_grid()
    if grid[0].shape[0] == ground_grid.shape[1] + 1:          # a global bilinear DSM's seam column
        ground_grid = np.concatenate([ground_grid, ground_grid[:, :1]], axis=1)
    gnd = np.ascontiguousarray(ground_grid, dtype=np.float64).T
    ov = ortho._core_values()
    if sun_arr is None:
        sunmode, sunv = 0, np.zeros(3)
    elif sun_arr.shape == (2,):
        sunmode, sunv = 0, np.array([math.radians(sun_arr[0]), math.radians(sun_arr[1]), 0.0])
    else:
        sunmode, sunv = 1, sun_arr / np.linalg.norm(sun_arr)
    shade_args = dict(walls=0 if walls == "interpolate" else 1, shading=0 if shading == "none" else 1,
                      sunmode=sunmode, sun=sunv, ambient=ambient, cos_wall=math.cos(math.radians(wall_slope)),
                      roof_min=roof_min, cell_x=dsm.dlon * mx, cell_y=abs(dsm.dlat) * my, fill=fill)
    # the shading pass's threads (a block's pixels; before 2026-12-03 this was capped at 1 by passing
    # n = 1, so the pass ran on one thread whatever `threads` said: simulation note 13)
    nthreads = check_threads(threads, block_lines * npx)
    bar = _Progress(nl, progress)
    t0 = time.perf_counter()
    t_rays = 0.0
    for k0 in range(0, nl, block_lines):
        k1 = min(nl, k0 + block_lines)
        s, l = sensor.rays(k0, k1)
        ta = time.perf_counter()
        try:
            n, s, l, p, _, scal, st, _ = _trace_raw(dsm, s, l, method, threads, fan=npx)
        except ValueError as exc:
            # name the image pixel, not the block's flat ray index
            raise ValueError(f"sensor lines {k0}..{k1 - 1} (ray index = (line - {k0}) * {npx} + pixel): "
                             f"{exc}") from None
        t_rays += time.perf_counter() - ta
        nb_ = k1 - k0
        blk = slice(0, nb_) if files else slice(k0, k1)
        hit = (st == DSMStatus.HIT) | (st == DSMStatus.HIT_UNCONVERGED)   # [sim note 8]
        status[blk] = st.reshape(nb_, npx)
        valid[blk] = hit.reshape(nb_, npx)
        # the value, kind and every backplane written in place into the block of each output
        # array by one parallel pass (the block's rows are contiguous: 1-D views of length n,
        # and (3, n) / (bands, n) Fortran-ordered views of the transposed blocks) [sim note 13]
        _core.core_sim_shade(*grid[:7], grid[7], gnd, ov, *ortho._core_grid(), scal, p,
                             hit.astype(np.int32), l.T, threads=nthreads, **shade_args,
                             img=_rows(image, blk, (n, bands)).T, kind=_rows(surface, blk, n),
                             locinc=_rows(planes["local_incidence"], blk, n), lat=_rows(planes["lat"], blk, n),
                             lon=_rows(planes["lon"], blk, n), height=_rows(planes["height"], blk, n),
                             dist=_rows(planes["distance"], blk, n), inc=_rows(planes["incidence"], blk, n),
                             pts=_rows(pts, blk, (n, 3)).T, oval=_rows(ortho_value, blk, n).view(np.int8))
        lon = planes["lon"][blk]
        wrap = (lon >= 180.0) | (lon < -180.0)              # atan2's +-180 and rounding (NaN compares false)
        if wrap.any():
            lon[wrap] = _wrap180(lon[wrap])                 # pi.intersect's arithmetic, to the bit
        for f in files.values():
            f.emit(k0, nb_)
        bar.update(k1, k1 * npx)
    t_sim = time.perf_counter() - t0
    if files:
        res = {name: f.result() for name, f in files.items()}
        image, valid, surface, ortho_value, status, pts = (res[k] for k in ("image", "valid", "surface",
                                                                              "ortho_value", "status", "p"))
        planes = {name: res[name] for name in planes}
    sim = SimResult(image=image, valid=valid, surface=surface, status=status, p=pts, ortho_value=ortho_value,
                    **planes)
    n_noval = int(np.count_nonzero(np.asarray(valid))) - int(np.count_nonzero(np.asarray(ortho_value)))
    sim.meta["hits_without_ortho_value"] = n_noval
    if n_noval:
        import warnings

        warnings.warn(f"{n_noval} pixel(s) hit the DSM where the ortho-image has no value (outside it or over its "
                      f"no-data): their image value is fill = {fill:g} (SimResult.ortho_value is False there)",
                      stacklevel=3)
    sim.meta.update(method=method, walls=walls, shading=shading, nlines=nl, npixels=npx,
                    ortho_dtype=str(ortho.dtype), seconds_simulation=t_sim, seconds_rays=t_rays,
                    pixels_per_second=nl * npx / max(t_sim, 1e-12))
    if occlusion:
        ta = time.perf_counter()
        sim.occlusion, sim.footprint = _occlusion(dsm, ortho, sensor, sim, threads)
        sim.meta["seconds_occlusion"] = time.perf_counter() - ta
    return sim


def _fill_polygon(pu, pv, nrows: int, ncols: int) -> np.ndarray:
    """Grid points (row i, col j), 0 <= i < nrows, 0 <= j < ncols, inside the
    closed polygon of vertices (pu, pv) in fractional (row, col), by scanlines
    and the even-odd rule: O(vertices + area), where a point-in-polygon test of
    every point against every edge is O(vertices x area)."""
    ua, va = pu, pv
    ub, vb = np.roll(pu, -1), np.roll(pv, -1)
    lo, hi = np.minimum(ua, ub), np.maximum(ua, ub)
    # rows r with lo <= r < hi (half-open: a vertex on a row counts once)
    r0 = np.ceil(lo).astype(np.int64)
    r1 = np.ceil(hi).astype(np.int64)                  # exclusive
    r0, r1 = np.clip(r0, 0, nrows), np.clip(r1, 0, nrows)
    count = np.maximum(r1 - r0, 0)
    inside = np.zeros((nrows, ncols), dtype=bool)
    if count.sum() == 0:
        return inside
    e = np.repeat(np.arange(len(ua)), count)
    rows = r0[e] + (np.arange(len(e)) - np.repeat(np.cumsum(count) - count, count))
    with np.errstate(invalid="ignore", divide="ignore"):
        x = va[e] + (rows - ua[e]) * (vb[e] - va[e]) / (ub[e] - ua[e])
    order = np.lexsort((x, rows))
    rows, x = rows[order], x[order]
    # pair the crossings of each row: (1st, 2nd), (3rd, 4th), ...
    starts = np.flatnonzero(np.r_[True, rows[1:] != rows[:-1]])
    rank = np.arange(len(rows)) - np.repeat(starts, np.diff(np.r_[starts, len(rows)]))
    first = rank % 2 == 0
    has_pair = np.r_[first[:-1] & (rows[1:] == rows[:-1]), False]
    a = np.flatnonzero(first & has_pair)
    c0 = np.clip(np.ceil(x[a]).astype(np.int64), 0, ncols)
    c1 = np.clip(np.floor(x[a + 1]).astype(np.int64) + 1, 0, ncols)
    ok = c1 > c0
    diff = np.zeros((nrows, ncols + 1), dtype=np.int32)
    np.add.at(diff, (rows[a][ok], c0[ok]), 1)
    np.add.at(diff, (rows[a][ok], c1[ok]), -1)
    return np.cumsum(diff[:, :ncols], axis=1) > 0


def _occlusion(dsm: GeodeticDSM, ortho: OrthoImage, sensor, sim: SimResult, threads, chunk: int = 1 << 18):
    """Ortho-grid masks: ``footprint`` (inside the polygon of the image border's
    hits, and every ortho pixel an image pixel's hit lands on) and ``occlusion``
    (footprint pixels whose surface point is hidden).

    [sim note 5] For each footprint pixel X (its centre at the DSM height) the
    sensor position is that of the image line whose hit lands nearest to X
    (nearest in the ortho grid); the exact ray from there to X is cast and X is
    hidden when the ray meets the surface more than 1 cm before X. For a
    pushbroom the true line differs by a fraction of a line, a direction
    change of ~1e-7 rad at 700 km.

    Memory: the image's backplanes are read in blocks of lines and the rays
    cast in chunks of ``chunk`` ortho pixels; what grows with the scene is
    ~13 bytes per ortho pixel of the footprint's bounding box (the line of
    each pixel and the nearest-seen-pixel indices) [sim note 9]."""
    from scipy import ndimage

    from .dsm import intersect_dsm

    nr, nc = ortho.shape
    occ = np.zeros((nr, nc), dtype=bool)
    foot = np.zeros((nr, nc), dtype=bool)
    valid_all = sim.valid
    nl, npx = valid_all.shape
    block = max(1, chunk // max(npx, 1))
    # the image border, in order (lines 0 and nl - 1, pixels 0 and npx - 1)
    border = ([(0, m) for m in range(npx)] + [(k, npx - 1) for k in range(1, nl)]
              + [(nl - 1, m) for m in range(npx - 2, -1, -1)] + [(k, 0) for k in range(nl - 2, 0, -1)])
    bk = np.array([b[0] for b in border])
    bm = np.array([b[1] for b in border])
    # first pass, in blocks of lines: each line's focal point, the border pixels' rays, and the box
    # of every hit (hits outside the border's box were dropped once: the simulation fuzzing, 2026-12-03)
    focal = np.empty((nl, 3))
    bs = np.empty((len(border), 3))
    bl = np.empty((len(border), 3))
    lo_u = lo_v = math.inf
    hi_u = hi_v = -math.inf
    for k0 in range(0, nl, block):
        k1 = min(nl, k0 + block)
        s_b, l_b = sensor.rays(k0, k1)                         # (a row per pixel, line by line)
        focal[k0:k1] = s_b[::npx]
        sel = np.flatnonzero((bk >= k0) & (bk < k1))
        rows = (bk[sel] - k0) * npx + bm[sel]
        bs[sel] = s_b[rows]
        bl[sel] = l_b[rows]
        vb = np.asarray(valid_all[k0:k1])
        if vb.any():
            ku, kv = ortho.grid_coords(np.asarray(sim.lat[k0:k1])[vb], np.asarray(sim.lon[k0:k1])[vb])
            ku, kv = np.rint(ku), np.rint(kv)                    # the pixels the second pass bins them to
            lo_u, hi_u = min(lo_u, ku.min()), max(hi_u, ku.max())
            lo_v, hi_v = min(lo_v, kv.min()), max(hi_v, kv.max())
    # the border's ground points as a polygon in ortho (row, col) coordinates: a border pixel's hit,
    # or, where its ray left the DSM or met no data, its crossing of the ellipsoid raised by the
    # DSM's mean height (a = a + h, b = b + h: within ~h e^2 of that height, ample for a polygon).
    # With the hits alone, an image larger than its DSM had no polygon: its footprint was the ortho
    # pixels its hits landed on and its occlusion mask missed the hidden ground (332 pixels of ~3,200
    # on a 700^2 orbit image of a 600 m DSM: a newcomer's walk-through, 2026-12-04)
    keep = np.asarray(valid_all[bk, bm])
    blat = np.where(keep, np.asarray(sim.lat[bk, bm]), np.nan)
    blon = np.where(keep, np.asarray(sim.lon[bk, bm]), np.nan)
    miss = ~keep
    if miss.any():
        from .dsm import _ellipsoid_entry
        from .geodetic import ecef_to_geodetic

        hv = np.asarray(dsm.heights, dtype=np.float64)
        h_ref = float(np.mean(hv[np.isfinite(hv)])) if np.isfinite(hv).any() else 0.0
        b_ax = dsm.a * (1 - dsm.f)
        a_r, b_r = dsm.a + h_ref, b_ax + h_ref
        if a_r > 0 and b_r > 0:
            lm = bl[miss] / np.abs(bl[miss]).max(axis=1)[:, None]   # (scaled first: |l| up to 1e308 is
            lm /= np.linalg.norm(lm, axis=1)[:, None]                # allowed, its square overflowed: fuzz)
            r = _ellipsoid_entry(bs[miss], lm, a_r, 1 - b_r / a_r)
            ok = np.isfinite(r)
            if ok.any():
                q = bs[miss][ok] + r[ok, None] * lm[ok]
                la, lo, _ = ecef_to_geodetic(q, dsm.a, dsm.f)
                idx = np.flatnonzero(miss)[ok]
                blat[idx], blon[idx] = la, lo
    have = np.isfinite(blat) & np.isfinite(blon)
    polygon = have.sum() >= 3
    if polygon:
        bu, bv = ortho.grid_coords(blat[have], blon[have])
        lo_u, hi_u = min(lo_u, bu.min()), max(hi_u, bu.max())
        lo_v, hi_v = min(lo_v, bv.min()), max(hi_v, bv.max())
    if not (math.isfinite(lo_u) and math.isfinite(lo_v)):
        return occ, foot
    u0, u1 = max(0, int(np.floor(lo_u))), min(nr - 1, int(np.ceil(hi_u)))
    v0, v1 = max(0, int(np.floor(lo_v))), min(nc - 1, int(np.ceil(hi_v)))
    if u1 < u0 or v1 < v0:
        return occ, foot
    if polygon:
        inside = _fill_polygon(bu - u0, bv - v0, u1 - u0 + 1, v1 - v0 + 1)
    else:
        inside = np.zeros((u1 - u0 + 1, v1 - v0 + 1), dtype=bool)
    # which image line saw each ortho pixel: the hits binned to the nearest pixel, in blocks of lines
    # (a later line overwrites an earlier one)
    line_of = np.full((u1 - u0 + 1, v1 - v0 + 1), -1, dtype=np.int32)
    for k0 in range(0, nl, block):
        k1 = min(nl, k0 + block)
        vb = np.asarray(valid_all[k0:k1])
        if not vb.any():
            continue
        ku, kv = ortho.grid_coords(np.asarray(sim.lat[k0:k1])[vb], np.asarray(sim.lon[k0:k1])[vb])
        iu = np.rint(ku).astype(np.int64) - u0
        iv = np.rint(kv).astype(np.int64) - v0
        lines = (np.nonzero(vb)[0] + k0).astype(np.int32)
        okb = (iu >= 0) & (iu < line_of.shape[0]) & (iv >= 0) & (iv < line_of.shape[1])
        line_of[iu[okb], iv[okb]] = lines[okb]
    seen = line_of >= 0
    # the footprint: the ortho pixels inside the polygon where the DSM has a height (an image larger
    # than its DSM covers ground the DSM does not describe, which no pixel sees), and every ortho
    # pixel an image pixel looks at (the polygon decided the border row and column by rounding: a
    # review)
    inside |= seen
    foot[u0:u1 + 1, v0:v1 + 1] = seen
    nearest_line = None
    if seen.any():
        ni, nj = ndimage.distance_transform_edt(~seen, return_distances=False, return_indices=True)
        nearest_line = line_of[ni, nj]
        del ni, nj
    del line_of

    rows_per = max(1, chunk // inside.shape[1])
    for r0 in range(0, inside.shape[0], rows_per):
        cu, cv = np.nonzero(inside[r0:r0 + rows_per])
        if cu.size == 0:
            continue
        cu += r0
        olat = ortho.lat_first + (cu + u0) * ortho.dlat
        olon = ortho.lon_first + (cv + v0) * ortho.dlon
        hs = np.asarray(dsm.height(olat, olon), dtype=np.float64)
        ok = np.isfinite(hs)
        cu, cv, olat, olon, hs = cu[ok], cv[ok], olat[ok], olon[ok], hs[ok]
        foot[cu + u0, cv + v0] = True
        if cu.size == 0 or nearest_line is None:
            continue
        x = np.asarray(geodetic_to_ecef(olat, olon, hs, dsm.a, dsm.f)).reshape(-1, 3)
        s = focal[nearest_line[cu, cv]]
        d = x - s
        dist = np.linalg.norm(d, axis=1)
        # (no warnings.catch_warnings here: it swaps the process's filter list, so another thread's
        # warnings were lost while it ran, and two overlapping calls could leave "ignore" installed
        # for good; intersect_dsm emits no RuntimeWarning of its own to hide: a review, 2026-12-05)
        res = intersect_dsm(dsm, s, d, method="exact", threads=threads)
        hidden = (res.status == DSMStatus.HIT) & (res.distance < dist - 0.01)
        occ[cu[hidden] + u0, cv[hidden] + v0] = True
    return occ, foot
