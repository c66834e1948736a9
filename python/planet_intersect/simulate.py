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
import sys
import time
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from .dsm import DSMStatus, GeodeticDSM, _number
from .geodetic import WGS84_A, WGS84_F, geodetic_to_ecef

__all__ = ["OrthoImage", "SimResult", "simulate_image", "SURFACE_CODES"]

#: sim.surface codes (DESIGN.md section 9)
SURFACE_CODES = {-1: "no hit", 0: "ground", 1: "roof", 2: "wall"}
_METHODS = ("exact", "following", "iterative")


# --------------------------------------------------------------------- grids
def _grid_coords(lat, lon, lat_first, lon_first, dlat, dlon):
    """Fractional (row, col) of geodetic (lat, lon) on a pixel-centre grid;
    longitudes taken modulo 360 from lon_first (extents may cross 180)."""
    u = (np.asarray(lat, dtype=np.float64) - lat_first) / dlat
    v = np.mod(np.asarray(lon, dtype=np.float64) - lon_first + 180.0, 360.0) - 180.0
    v = v / dlon
    return u, v


def _bilinear(values, u, v):
    """Bilinear interpolation of ``values`` (nrows, ncols[, bands]) at fractional
    (row, col); NaN outside the rectangle of pixel centres or where a needed
    value is NaN."""
    nr, nc = values.shape[:2]
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    inside = (u >= 0) & (u <= nr - 1) & (v >= 0) & (v <= nc - 1)
    uu = np.where(inside, u, 0.0)
    vv = np.where(inside, v, 0.0)
    i = np.minimum(np.floor(uu).astype(np.intp), max(nr - 2, 0))
    j = np.minimum(np.floor(vv).astype(np.intp), max(nc - 2, 0))
    fu, fv = uu - i, vv - j
    i1 = np.minimum(i + 1, nr - 1)
    j1 = np.minimum(j + 1, nc - 1)
    if values.ndim == 3:
        fu, fv, inside = fu[..., None], fv[..., None], inside[..., None]
    with np.errstate(invalid="ignore"):
        out = ((1 - fu) * ((1 - fv) * values[i, j] + fv * values[i, j1])
               + fu * ((1 - fv) * values[i1, j] + fv * values[i1, j1]))
    return np.where(inside, out, np.nan)


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
            the input dtype remembered for PNG scaling).
        lat_first, lon_first : float
            Geodetic latitude and east longitude of pixel (0, 0)'s centre, degrees.
        dlat, dlon : float
            Grid steps, degrees (dlat < 0 for north-up rows; dlon > 0).
        nodata : float, optional
            Value marking missing pixels (NaN always does).
        """
        try:
            arr = np.asarray(values)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"values: not an array of numbers ({exc})") from None
        if arr.dtype.kind not in "fiub":
            raise TypeError(f"values: must be real numbers, got dtype {arr.dtype}")
        if arr.ndim not in (2, 3) or arr.shape[0] < 2 or arr.shape[1] < 2 or (arr.ndim == 3 and arr.shape[2] < 1):
            raise ValueError(f"values: expected (nrows, ncols) or (nrows, ncols, bands) with at least 2 x 2 pixels, "
                             f"got shape {arr.shape}")
        lat_first = _number(lat_first, "lat_first")
        lon_first = _number(lon_first, "lon_first")
        dlat = _number(dlat, "dlat")
        dlon = _number(dlon, "dlon")
        if dlat == 0 or abs(dlat) > 90:
            raise ValueError(f"dlat must be non-zero and at most 90 degrees, got {dlat}")
        if not 0 < dlon <= 360:
            raise ValueError(f"dlon must be in (0, 360] degrees (east-going columns), got {dlon}")
        last = lat_first + (arr.shape[0] - 1) * dlat
        if not (-90 <= lat_first <= 90 and -90 <= last <= 90):
            raise ValueError(f"the grid's latitudes {lat_first}..{last} leave [-90, 90]")
        self = object.__new__(cls)
        v = arr.astype(np.float64, copy=True)
        if nodata is not None:
            nodata = _number(nodata, "nodata")
            v[v == nodata] = np.nan
        v.flags.writeable = False
        self._v = v
        self.dtype = arr.dtype
        self.lat_first, self.lon_first, self.dlat, self.dlon = lat_first, lon_first, dlat, dlon
        self.nodata = nodata
        self.path = None
        return self

    values = property(lambda self: self._v, doc="the image, float64 (read-only), NaN where no data")
    shape = property(lambda self: self._v.shape[:2])
    bands = property(lambda self: 1 if self._v.ndim == 2 else self._v.shape[2])

    def __repr__(self) -> str:
        return (f"OrthoImage({self.shape[0]} x {self.shape[1]} x {self.bands} band(s), lat {self.lat_first}"
                f"{self.dlat:+g}/row, lon {self.lon_first}{self.dlon:+g}/col)")

    def grid_coords(self, lat, lon):
        """Fractional (row, col) of (lat, lon) in degrees."""
        return _grid_coords(lat, lon, self.lat_first, self.lon_first, self.dlat, self.dlon)

    def sample(self, lat, lon) -> np.ndarray:
        """Bilinear value at geodetic (lat, lon), degrees: shape of lat (+ (bands,)
        for a multi-band image); NaN outside the rectangle of pixel centres or
        where a needed pixel has no data."""
        u, v = self.grid_coords(lat, lon)
        return _bilinear(self._v, u, v)

    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        """Latitudes (nrows,) and longitudes (ncols,) of the pixel centres, degrees."""
        return (self.lat_first + np.arange(self.shape[0]) * self.dlat,
                self.lon_first + np.arange(self.shape[1]) * self.dlon)

    @classmethod
    def read(cls, path, nodata=None) -> "OrthoImage":
        """Read an ortho-image from a GeoTIFF (all bands; rasterio) or an ``.npz``
        (arrays ``values``, ``lat_first``, ``lon_first``, ``dlat``, ``dlon``).

        A geographic CRS is read as it is (axis-aligned transform); a projected
        CRS is warped bilinearly to a geodetic grid of about the same resolution.
        The file is only read.
        """
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"ortho-image file {path}: no such file")
        if path.suffix.lower() == ".npz":
            try:
                with np.load(path, allow_pickle=False) as z:
                    d = {k: z[k] for k in z.files}
            except Exception as exc:  # noqa: BLE001 - any unreadable file
                raise ValueError(f"ortho-image file {path}: cannot be read as .npz ({exc})") from None
            missing = [k for k in ("values", "lat_first", "lon_first", "dlat", "dlon") if k not in d]
            if missing:
                raise ValueError(f"ortho-image file {path}: missing arrays {missing}")
            try:
                o = cls.from_array(d["values"], float(d["lat_first"]), float(d["lon_first"]), float(d["dlat"]),
                                   float(d["dlon"]), nodata=nodata)
            except (TypeError, ValueError) as exc:
                raise ValueError(f"ortho-image file {path}: {exc}") from None
            o.path = path
            return o
        try:
            import rasterio
            from rasterio.warp import Resampling, calculate_default_transform, reproject
        except ImportError:
            raise ImportError(f"reading {path} needs rasterio: pip install 'planet-intersect[geo]'") from None
        try:
            src = rasterio.open(path)
        except Exception as exc:  # noqa: BLE001
            raise ValueError(f"ortho-image file {path}: cannot be opened as a raster ({exc})") from None
        with src:
            if src.crs is None:
                raise ValueError(f"ortho-image file {path}: no CRS (a geographic or projected CRS is needed)")
            nd = nodata if nodata is not None else src.nodata
            data = src.read()                                   # (bands, rows, cols)
            dtype = data.dtype
            if src.crs.is_geographic:
                t = src.transform
                if t.b != 0 or t.d != 0:
                    raise ValueError(f"ortho-image file {path}: rotated or sheared pixel grid is not supported")
                values = np.moveaxis(data, 0, -1).astype(np.float64)
            else:
                tr, w, h = calculate_default_transform(src.crs, "EPSG:4326", src.width, src.height, *src.bounds)
                src_f = data.astype(np.float64)
                if nd is not None:
                    src_f[src_f == nd] = np.nan
                values = np.full((src.count, h, w), np.nan)
                for b in range(src.count):
                    reproject(src_f[b], values[b], src_transform=src.transform, src_crs=src.crs, src_nodata=np.nan,
                              dst_transform=tr, dst_crs="EPSG:4326", dst_nodata=np.nan,
                              resampling=Resampling.bilinear)
                values = np.moveaxis(values, 0, -1)
                nd = None
                t = tr
        if values.shape[2] == 1:
            values = values[:, :, 0]
        try:
            o = cls.from_array(values, t.f + 0.5 * t.e, t.c + 0.5 * t.a, t.e, t.a, nodata=nd)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"ortho-image file {path}: {exc}") from None
        o.dtype = dtype
        o.path = path
        return o


# ------------------------------------------------------------------- result
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
    occlusion: np.ndarray | None = None  #: ortho grid: ground in the footprint hidden from the sensor
    footprint: np.ndarray | None = None  #: ortho grid: inside the image's ground footprint
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
            elif f.name == "valid":
                data[f.name] = (("line", "pixel"), np.asarray(v, dtype=np.int8))
            else:
                data[f.name] = (("line", "pixel"), np.asarray(v))
        ds = xr.Dataset(data)
        ds.attrs["surface_codes"] = "; ".join(f"{k}: {v}" for k, v in SURFACE_CODES.items())
        ds.attrs["status_codes"] = "; ".join(f"{v}: {k}" for k, v in vars(DSMStatus).items() if k.isupper())
        ds.attrs["angles"] = "degrees; latitudes geodetic, longitudes east in [-180, 180)"
        for k, v in self.meta.items():
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
        surface, valid as float64 bands with descriptions), ``.nc`` (NetCDF of
        :meth:`to_xarray`). An existing file is not overwritten."""
        path = Path(path)
        if path.exists():
            raise FileExistsError(f"{path}: exists; choose another name (nothing is overwritten)")
        if not path.parent.is_dir():
            raise FileNotFoundError(f"{path.parent}: no such directory")
        suffix = path.suffix.lower()
        if suffix == ".png":
            from matplotlib import image as mimage

            img = self.display_image()
            if img.ndim == 3 and img.shape[2] not in (3, 4):
                img = img[:, :, 0]
            mimage.imsave(path, img, cmap="gray", vmin=0, vmax=255)
        elif suffix in (".tif", ".tiff"):
            import warnings

            import rasterio
            from rasterio.errors import NotGeoreferencedWarning

            img = np.asarray(self.image, dtype=np.float64)
            img = img[:, :, None] if img.ndim == 2 else img
            names = [f"image band {b + 1}" for b in range(img.shape[2])]
            planes = [img[:, :, b] for b in range(img.shape[2])]
            for name in ("lat", "lon", "height", "distance", "incidence", "local_incidence", "surface", "valid"):
                names.append(name)
                planes.append(np.asarray(getattr(self, name), dtype=np.float64))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", NotGeoreferencedWarning)
                with rasterio.open(path, "w", driver="GTiff", width=img.shape[1], height=img.shape[0],
                                   count=len(planes), dtype="float64") as dst:
                    for b, (name, plane) in enumerate(zip(names, planes), start=1):
                        dst.write(plane, b)
                        dst.set_band_description(b, name)
                    dst.update_tags(surface_codes=str(SURFACE_CODES), geometry="sensor (line, pixel)")
        elif suffix == ".nc":
            self.to_xarray().to_netcdf(path, engine="h5netcdf")
        else:
            raise ValueError(f"{path}: unknown format {suffix!r} (use .png, .tif or .nc)")
        return path


# ----------------------------------------------------------- surface geometry
def _enu(lat_deg, lon_deg):
    """East, north, up unit vectors (N, 3) at geodetic (lat, lon)."""
    la, lo = np.radians(lat_deg), np.radians(lon_deg)
    sl, cl, so, co = np.sin(la), np.cos(la), np.sin(lo), np.cos(lo)
    e = np.stack([-so, co, np.zeros_like(so)], axis=-1)
    n = np.stack([-sl * co, -sl * so, cl], axis=-1)
    u = np.stack([cl * co, cl * so, sl], axis=-1)
    return e, n, u


def _metres_per_degree(lat_deg, h, a, f):
    """(north, east) metres per degree of latitude / longitude at (lat, h)."""
    e2 = f * (2 - f)
    s = np.sin(np.radians(lat_deg))
    w = np.sqrt(1 - e2 * s * s)
    m = a * (1 - e2) / w ** 3
    n = a / w
    return np.radians(1.0) * (m + h), np.radians(1.0) * (n + h) * np.cos(np.radians(lat_deg))


class _Surface:
    """What the simulation needs of the DSM beyond the ray's hit: heights at
    fractional grid positions, the local gradient in metres, the ground model."""

    def __init__(self, dsm: GeodeticDSM, ground):
        self.dsm = dsm
        self.h = np.asarray(dsm.heights, dtype=np.float64)
        self.nearest = dsm.interpolation == "nearest"
        lat_mid = dsm.lat_first + 0.5 * (dsm.nrows - 1) * dsm.dlat
        my, mx = _metres_per_degree(lat_mid, 0.0, dsm.a, dsm.f)
        self.cell_y, self.cell_x = abs(dsm.dlat) * my, dsm.dlon * mx     # metres per cell (scene middle)
        self.ground = ground

    def uv(self, lat, lon):
        d = self.dsm
        return _grid_coords(lat, lon, d.lat_first, d.lon_first, d.dlat, d.dlon)

    def height_at(self, lat, lon):
        return np.asarray(self.dsm.height(lat, lon), dtype=np.float64)

    def gradient(self, lat, lon, h):
        """(dH/d east, dH/d north) in m/m of the DSM at the hits: the bilinear
        patch's gradient ("bilinear"); for "nearest" the step across the cell
        side the hit lies on, per cell width (zero on a flat top)."""
        d = self.dsm
        u, v = self.uv(lat, lon)
        my, mx = _metres_per_degree(lat, h, d.a, d.f)
        nr, nc = self.h.shape
        if not self.nearest:
            i = np.clip(np.floor(u).astype(np.intp), 0, max(nr - 2, 0))
            j = np.clip(np.floor(v).astype(np.intp), 0, max(nc - 2, 0))
            fu, fv = np.clip(u - i, 0, 1), np.clip(v - j, 0, 1)
            z = self.h
            i1, j1 = np.minimum(i + 1, nr - 1), np.minimum(j + 1, nc - 1)
            dhdu = (1 - fv) * (z[i1, j] - z[i, j]) + fv * (z[i1, j1] - z[i, j1])
            dhdv = (1 - fu) * (z[i, j1] - z[i, j]) + fu * (z[i1, j1] - z[i1, j])
        else:
            # the hit is on the side between the cell it is over and a neighbour when
            # u or v is within rounding of a half-integer [sim note 3]
            dhdu = np.zeros_like(u)
            dhdv = np.zeros_like(v)
            eps = 1e-6
            ic = np.clip(np.rint(u).astype(np.intp), 0, nr - 1)
            jc = np.clip(np.rint(v).astype(np.intp), 0, nc - 1)
            for axis, coord, out in ((0, u, dhdu), (1, v, dhdv)):
                frac = coord - np.floor(coord)
                side = np.abs(frac - 0.5) < eps
                lo = np.clip(np.floor(coord).astype(np.intp), 0, (nr if axis == 0 else nc) - 1)
                hi = np.clip(lo + 1, 0, (nr if axis == 0 else nc) - 1)
                if axis == 0:
                    step = self.h[hi, jc] - self.h[lo, jc]
                else:
                    step = self.h[ic, hi] - self.h[ic, lo]
                out[side] = np.nan_to_num(step[side])
        dnorth = dhdu / (d.dlat * my)            # d/d(lat deg) / (m per deg), sign of dlat included
        deast = dhdv / (d.dlon * mx)
        return deast, dnorth

    def ground_height(self, lat, lon):
        if self.ground is None:
            return None
        u, v = self.uv(lat, lon)
        return _bilinear(self.ground, u, v)


def _opening_ground(dsm: GeodeticDSM, window_m: float) -> np.ndarray:
    """Bare-earth estimate from the DSM by a grey-scale morphological opening
    (erosion then dilation) with a square window about ``window_m`` wide: it
    removes every raised object narrower than the window and keeps planar
    slopes exactly [sim note 1]."""
    from scipy import ndimage

    h = np.asarray(dsm.heights, dtype=np.float64)
    lat_mid = dsm.lat_first + 0.5 * (dsm.nrows - 1) * dsm.dlat
    my, mx = _metres_per_degree(lat_mid, 0.0, dsm.a, dsm.f)
    wy = max(3, int(math.ceil(window_m / (abs(dsm.dlat) * my))) | 1)
    wx = max(3, int(math.ceil(window_m / (dsm.dlon * mx))) | 1)
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


def _sun_vectors(sun, lat, lon):
    """Unit vectors toward the Sun (N, 3), ECR: from (azimuth, elevation) in
    degrees at each hit (azimuth clockwise from north) or one ECR vector."""
    arr = np.asarray(sun, dtype=np.float64)
    if arr.shape == (2,):
        az, el = np.radians(arr)
        e, n, u = _enu(lat, lon)
        return np.cos(el) * (np.sin(az) * e + np.cos(az) * n) + np.sin(el) * u
    if arr.shape == (3,):
        nrm = np.linalg.norm(arr)
        return np.broadcast_to(arr / nrm, (len(lat), 3))
    arr = arr.reshape(-1, 3)
    return arr / np.linalg.norm(arr, axis=1, keepdims=True)


def _check_sun(sun):
    if sun is None:
        raise ValueError("shading='lambert' needs sun=(azimuth_deg, elevation_deg) or an ECR vector (3,)")
    try:
        arr = np.asarray(sun, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"sun: expected (azimuth_deg, elevation_deg) or an ECR vector (3,), got {sun!r}") from None
    if arr.shape not in ((2,), (3,)) or not np.isfinite(arr).all():
        raise ValueError(f"sun: expected 2 finite angles (deg) or a finite ECR vector (3,), got {sun!r}")
    if arr.shape == (3,) and not np.linalg.norm(arr) > 0:
        raise ValueError("sun: the ECR vector has zero length")
    if arr.shape == (2,) and not -90 <= arr[1] <= 90:
        raise ValueError(f"sun: elevation {arr[1]} outside [-90, 90] degrees")
    return arr


def _alloc(out_dir, name, shape, dtype, fill):
    if out_dir is None:
        return np.full(shape, fill, dtype=dtype)
    arr = np.lib.format.open_memmap(out_dir / f"{name}.npy", mode="w+", dtype=dtype, shape=shape)
    arr[...] = fill
    return arr


def simulate_image(dsm: GeodeticDSM, ortho: OrthoImage, sensor, method: str = "exact",
                   walls: str = "interpolate", shading: str = "none", sun=None, ambient: float = 0.0,
                   fill: float = 0.0, occlusion: bool = True, ground=None, ground_window: float = 100.0,
                   wall_slope: float = 60.0, roof_min: float = 2.0, threads: int | None = None,
                   block_lines: int = 256, progress: bool = False, out=None) -> SimResult:
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
    block_lines : int
        Lines per block (memory per block ~ 0.5 kB per pixel).
    progress : bool
        A progress bar on stderr.
    out : path, optional
        A new directory: the backplanes are memory-mapped ``.npy`` files there
        (images larger than memory), and the result's arrays are those maps.

    Returns
    -------
    SimResult
    """
    from .dsm import intersect_dsm
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
    fill = float(fill) if isinstance(fill, (int, float, np.floating, np.integer)) else _number(fill, "fill")
    wall_slope = _number(wall_slope, "wall_slope")
    if not 0 < wall_slope < 90:
        raise ValueError(f"wall_slope must be in (0, 90) degrees, got {wall_slope}")
    roof_min = _number(roof_min, "roof_min")
    ground_window = _number(ground_window, "ground_window")
    if ground_window <= 0:
        raise ValueError(f"ground_window must be positive (metres), got {ground_window}")
    if not isinstance(block_lines, (int, np.integer)) or isinstance(block_lines, bool) or block_lines < 1:
        raise ValueError(f"block_lines must be a positive integer, got {block_lines!r}")
    check_threads(threads, 1)
    if ground is None:
        ground_grid = _opening_ground(dsm, ground_window)
    else:
        g = ground.heights if isinstance(ground, GeodeticDSM) else ground
        try:
            ground_grid = np.asarray(g, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError("ground: expected an array of heights like dsm.heights") from None
        if ground_grid.shape != dsm.heights.shape:
            raise ValueError(f"ground: shape {ground_grid.shape} differs from the DSM's {dsm.heights.shape}")
    out_dir = None
    if out is not None:
        out_dir = Path(out)
        if out_dir.exists():
            raise FileExistsError(f"out={out_dir}: exists; choose a new directory (nothing is overwritten)")
        out_dir.mkdir(parents=True)

    surf = _Surface(dsm, ground_grid)
    nl, npx = sensor.shape
    bands = ortho.bands
    ishape = (nl, npx) if bands == 1 else (nl, npx, bands)
    image = _alloc(out_dir, "image", ishape, np.float32, fill)
    valid = _alloc(out_dir, "valid", (nl, npx), bool, False)
    planes = {name: _alloc(out_dir, name, (nl, npx), np.float64, np.nan)
              for name in ("lat", "lon", "height", "distance", "incidence", "local_incidence")}
    surface = _alloc(out_dir, "surface", (nl, npx), np.int8, -1)
    status = _alloc(out_dir, "status", (nl, npx), np.int8, -1)
    pts = _alloc(out_dir, "p", (nl, npx, 3), np.float64, np.nan)
    cos_wall = math.cos(math.radians(wall_slope))
    bar = _Progress(nl, progress)
    t0 = time.perf_counter()
    t_rays = 0.0
    for k0 in range(0, nl, block_lines):
        k1 = min(nl, k0 + block_lines)
        s, l = sensor.rays(k0, k1)
        ta = time.perf_counter()
        with np.errstate(all="ignore"):
            import warnings

            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                try:
                    res = intersect_dsm(dsm, s, l, method=method, threads=threads)
                except ValueError as exc:
                    # name the image pixel, not the block's flat ray index
                    raise ValueError(f"sensor lines {k0}..{k1 - 1} (ray index = (line - {k0}) * {npx} + pixel): "
                                     f"{exc}") from None
        t_rays += time.perf_counter() - ta
        blk = slice(k0, k1)
        shape2 = (k1 - k0, npx)
        status[blk] = res.status.reshape(shape2)
        ok = res.hit                      # HIT (and HIT_UNCONVERGED: a hit, best estimate) [sim note 8]
        valid[blk] = ok.reshape(shape2)
        planes["lat"][blk] = res.lat.reshape(shape2)
        planes["lon"][blk] = res.lon.reshape(shape2)
        planes["height"][blk] = res.height.reshape(shape2)
        planes["distance"][blk] = res.distance.reshape(shape2)
        planes["incidence"][blk] = res.incidence.reshape(shape2)
        pts[blk] = res.p.reshape(shape2 + (3,))
        idx = np.flatnonzero(ok)
        if idx.size:
            vals, kind, loc_inc = _shade_hits(surf, ortho, res, idx, l, walls, shading, sun_arr, ambient,
                                              cos_wall, roof_min)
            flat_img = image[blk].reshape((-1,) + ishape[2:])
            vals = np.where(np.isfinite(vals), vals, fill)
            flat_img[idx] = vals
            image[blk] = flat_img.reshape(((k1 - k0), npx) + ishape[2:])
            sk = np.full(len(ok), -1, dtype=np.int8)
            sk[idx] = kind
            surface[blk] = sk.reshape(shape2)
            li = np.full(len(ok), np.nan)
            li[idx] = loc_inc
            planes["local_incidence"][blk] = li.reshape(shape2)
        bar.update(k1, k1 * npx)
    t_sim = time.perf_counter() - t0
    sim = SimResult(image=image, valid=valid, surface=surface, status=status, p=pts, **planes)
    sim.meta.update(method=method, walls=walls, shading=shading, nlines=nl, npixels=npx,
                    ortho_dtype=str(ortho.dtype), seconds_simulation=t_sim, seconds_rays=t_rays,
                    pixels_per_second=nl * npx / max(t_sim, 1e-12))
    if occlusion:
        ta = time.perf_counter()
        sim.occlusion, sim.footprint = _occlusion(dsm, ortho, sensor, sim, threads)
        sim.meta["seconds_occlusion"] = time.perf_counter() - ta
    return sim


def _shade_hits(surf: _Surface, ortho: OrthoImage, res, idx, l, walls, shading, sun_arr, ambient, cos_wall,
                roof_min):
    """Values, surface kinds and local incidence angles of the hit rays ``idx``."""
    lat, lon, h = res.lat[idx], res.lon[idx], res.height[idx]
    li = l[idx] / np.linalg.norm(l[idx], axis=1, keepdims=True)
    gx, gy = surf.gradient(lat, lon, h)                   # dH/deast, dH/dnorth (m/m)
    e, n, u = _enu(lat, lon)
    g2 = gx * gx + gy * gy
    # slope steeper than wall_slope <=> cos(slope) = 1/sqrt(1+g^2) < cos(wall_slope)  [sim note 1]
    wall = 1.0 / np.sqrt(1.0 + g2) < cos_wall
    if surf.nearest:
        # "nearest": a hit below the cell-top height lies on a cell side; it is a wall
        # when the step there is steep at cell scale (the gradient above) [sim note 3]
        on_side = res.surface_height[idx] - h > 1e-6
        wall &= on_side
    gn = np.sqrt(np.maximum(g2, 1e-300))
    horiz = (-(gx / gn))[:, None] * e + (-(gy / gn))[:, None] * n    # outward horizontal: downhill
    normal = (-gx)[:, None] * e + (-gy)[:, None] * n + u
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    if surf.nearest:
        normal = np.where(wall[:, None], horiz, u)         # flat tops; vertical sides
    else:
        normal = np.where(wall[:, None], horiz, normal)
    cosi = np.clip(-np.einsum("ij,ij->i", li, normal), -1, 1)
    loc_inc = np.degrees(np.arccos(cosi))
    ground = surf.ground_height(lat, lon)
    roof = ~wall & (h - ground > roof_min)
    kind = np.where(wall, 2, np.where(roof, 1, 0)).astype(np.int8)
    vals = ortho.sample(lat, lon)
    if walls == "interpolate" and wall.any():
        w = np.flatnonzero(wall)
        vals = np.array(vals, dtype=np.float64)
        vals[w] = _wall_values(surf, ortho, lat[w], lon[w], h[w], gx[w], gy[w], gn[w])
    if shading == "lambert":
        sun = _sun_vectors(sun_arr, lat, lon)
        fac = ambient + (1 - ambient) * np.maximum(0.0, np.einsum("ij,ij->i", normal, sun))
        vals = vals * (fac if vals.ndim == 1 else fac[:, None])
    return vals, kind, loc_inc


def _wall_values(surf: _Surface, ortho: OrthoImage, lat, lon, h, gx, gy, gn):
    """Wall texture [sim note 2]: the ortho-photo has none, so a wall hit's value
    is interpolated linearly in height between the ortho value at the roof edge
    (a point one sample inside the building, against the outward horizontal
    normal) and at the wall's foot (one sample outside): a vertical ramp from
    the roof-edge colour at the top to the ground colour at the bottom.

    The sample step is half a cell for "nearest" (the wall is a cell side: the
    two cell centres) and one cell for "bilinear" (the wall is a one-cell ramp
    between the roof's last node and the ground's first)."""
    d = surf.dsm
    step_cells = 0.5 if surf.nearest else 1.0
    dx, dy = gx / gn, gy / gn                               # uphill unit direction (east, north)
    my, mx = _metres_per_degree(lat, h, d.a, d.f)
    # one step in cells along the direction: metres per cell projected on it
    cell_m = np.abs(dx) * surf.cell_x + np.abs(dy) * surf.cell_y
    step_m = step_cells * np.maximum(cell_m, 1e-9)
    lat_in = lat + dy * step_m / my
    lon_in = lon + dx * step_m / mx
    lat_out = lat - dy * step_m / my
    lon_out = lon - dx * step_m / mx
    h_top = surf.height_at(lat_in, lon_in)
    h_foot = surf.height_at(lat_out, lon_out)
    v_top = ortho.sample(lat_in, lon_in)
    v_foot = ortho.sample(lat_out, lon_out)
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.clip((h - h_foot) / (h_top - h_foot), 0.0, 1.0)
    t = np.where(np.isfinite(t), t, 0.5)
    if v_top.ndim == 2:
        t = t[:, None]
    val = (1 - t) * v_foot + t * v_top
    # a sample that fell outside the ortho-image: the other one, then the plain value
    plain = ortho.sample(lat, lon)
    val = np.where(np.isfinite(val), val, np.where(np.isfinite(v_top), v_top, np.where(np.isfinite(v_foot),
                                                                                      v_foot, plain)))
    return val


def _occlusion(dsm: GeodeticDSM, ortho: OrthoImage, sensor, sim: SimResult, threads):
    """Ortho-grid masks: ``footprint`` (inside the polygon of the image border's
    hits) and ``occlusion`` (footprint pixels whose surface point is hidden).

    [sim note 5] For each footprint pixel X (its centre at the DSM height) the
    sensor position is that of the image line whose hit lands nearest to X
    (nearest in the ortho grid); the exact ray from there to X is cast and X is
    hidden when the ray meets the surface more than 1 cm before X. For a
    pushbroom the true line differs by a fraction of a line, a direction
    change of ~1e-7 rad at 700 km."""
    from matplotlib.path import Path as MPath
    from scipy import ndimage

    from .dsm import intersect_dsm

    nr, nc = ortho.shape
    occ = np.zeros((nr, nc), dtype=bool)
    foot = np.zeros((nr, nc), dtype=bool)
    valid = np.asarray(sim.valid)
    if not valid.any():
        return occ, foot
    lat, lon = np.asarray(sim.lat), np.asarray(sim.lon)
    # the image border, in order, as a polygon in ortho (row, col) coordinates
    nl, npx = valid.shape
    border = ([(0, m) for m in range(npx)] + [(k, npx - 1) for k in range(1, nl)]
              + [(nl - 1, m) for m in range(npx - 2, -1, -1)] + [(k, 0) for k in range(nl - 2, 0, -1)])
    bk = np.array([b[0] for b in border])
    bm = np.array([b[1] for b in border])
    keep = valid[bk, bm]
    if keep.sum() < 3:
        return occ, foot
    bu, bv = ortho.grid_coords(lat[bk, bm][keep], lon[bk, bm][keep])
    poly = MPath(np.column_stack([bu, bv]))
    u0, u1 = max(0, int(np.floor(bu.min()))), min(nr - 1, int(np.ceil(bu.max())))
    v0, v1 = max(0, int(np.floor(bv.min()))), min(nc - 1, int(np.ceil(bv.max())))
    if u1 < u0 or v1 < v0:
        return occ, foot
    uu, vv = np.meshgrid(np.arange(u0, u1 + 1), np.arange(v0, v1 + 1), indexing="ij")
    inside = poly.contains_points(np.column_stack([uu.ravel(), vv.ravel()])).reshape(uu.shape)
    foot[u0:u1 + 1, v0:v1 + 1] = inside
    # which image line saw each ortho pixel: the hits binned to the nearest pixel
    line_of = np.full((u1 - u0 + 1, v1 - v0 + 1), -1, dtype=np.int64)
    ku, kv = ortho.grid_coords(lat[valid], lon[valid])
    iu = np.rint(ku).astype(np.int64) - u0
    iv = np.rint(kv).astype(np.int64) - v0
    lines = np.nonzero(valid)[0]
    okb = (iu >= 0) & (iu < line_of.shape[0]) & (iv >= 0) & (iv < line_of.shape[1])
    line_of[iu[okb], iv[okb]] = lines[okb]
    seen = line_of >= 0
    if not seen.any():
        return occ, foot
    _, (ni, nj) = ndimage.distance_transform_edt(~seen, return_indices=True)
    nearest_line = line_of[ni, nj]
    cu, cv = np.nonzero(inside)
    olat = ortho.lat_first + (cu + u0) * ortho.dlat
    olon = ortho.lon_first + (cv + v0) * ortho.dlon
    hs = np.asarray(dsm.height(olat, olon), dtype=np.float64)
    ok = np.isfinite(hs)
    cu, cv, olat, olon, hs = cu[ok], cv[ok], olat[ok], olon[ok], hs[ok]
    if cu.size == 0:
        return occ, foot
    x = np.asarray(geodetic_to_ecef(olat, olon, hs, dsm.a, dsm.f)).reshape(-1, 3)
    kl = nearest_line[cu, cv]
    uniq, inv = np.unique(kl, return_inverse=True)
    focal = np.array([sensor.rays(int(k), int(k) + 1)[0][0] for k in uniq])
    s = focal[inv]
    d = x - s
    dist = np.linalg.norm(d, axis=1)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        res = intersect_dsm(dsm, s, d, method="exact", threads=threads)
    hidden = (res.status == DSMStatus.HIT) & (res.distance < dist - 0.01)
    occ[cu[hidden] + u0, cv[hidden] + v0] = True
    return occ, foot
