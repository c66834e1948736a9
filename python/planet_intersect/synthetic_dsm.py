"""Deterministic geodetic surface models and ray sets for benchmarks, examples
and the image simulation (Shin & Park's experiment: buildings on a coarse base
DEM).

* :func:`jacksboro_base` — the 3-arc-second DEM of the Jacksboro fault
  (Tennessee) that matplotlib ships as sample data: a real Earth base DEM,
  heights above the geoid in metres on a geodetic grid.
* :func:`building_scene` — a 1 m building DSM: the base DEM resampled
  bilinearly to 1 m cells plus rectangular blocks 3-150 m tall, one-cell towers
  and courtyards (ring buildings), heights above WGS-84.
* :func:`pushbroom_rays`, :func:`airborne_rays` — lines of sight from a 500-700 km
  orbit at 0-30 deg off nadir, and from an aircraft at low elevation angles.

Everything is seeded: the same arguments give the same arrays.
"""

from __future__ import annotations

import math

import numpy as np

from .geodetic import WGS84_A, WGS84_F, geodetic_to_ecef
from .sensors import Sensor

__all__ = ["jacksboro_base", "building_scene", "pushbroom_rays", "airborne_rays", "metre_steps", "paper_scene",
           "oblique_pushbroom", "ObliqueScan", "PAPER_BUILDINGS",
           "JACKSBORO_GEOID"]

#: Geoid undulation (EGM96) near the Jacksboro DEM, metres: N = -32 m over the
#: 0.3-degree area to within a metre; applied as a constant (h = H + N).
JACKSBORO_GEOID = -32.0


def jacksboro_base() -> dict:
    """The Jacksboro fault DEM (matplotlib sample data) as a DSM grid.

    Returns dict(heights, lat_first, lon_first, dlat, dlon, geoid): heights
    above the geoid (m) with row 0 in the north (dlat < 0), pixel centres;
    ``geoid`` the constant undulation to add for heights above WGS-84.
    """
    from matplotlib import cbook

    d = cbook.get_sample_data("jacksboro_fault_dem.npz")
    z = np.asarray(d["elevation"], dtype=np.float64)
    step = float(d["dx"])
    # the file's 'ymin' is the northern edge (its rows run north to south)
    north, west = float(d["ymin"]), float(d["xmin"])
    return dict(heights=z, lat_first=north - step / 2, lon_first=west + step / 2, dlat=-step, dlon=step,
                geoid=JACKSBORO_GEOID)


def metre_steps(lat_deg: float, cell: float = 1.0, a: float = WGS84_A, f: float = WGS84_F) -> tuple[float, float]:
    """(dlat, dlon) in degrees that make cells ``cell`` metres on a side at latitude
    ``lat_deg`` (meridional and prime-vertical radii of curvature)."""
    e2 = f * (2 - f)
    s = np.sin(np.radians(lat_deg))
    w = np.sqrt(1 - e2 * s * s)
    m_radius = a * (1 - e2) / w ** 3
    n_radius = a / w
    return float(np.degrees(cell / m_radius)), float(np.degrees(cell / (n_radius * np.cos(np.radians(lat_deg)))))


def _bilinear(base: dict, lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
    z = base["heights"]
    y = (lat - base["lat_first"]) / base["dlat"]
    x = (lon - base["lon_first"]) / base["dlon"]
    y = np.clip(y, 0, z.shape[0] - 1 - 1e-9)
    x = np.clip(x, 0, z.shape[1] - 1 - 1e-9)
    i, j = np.floor(y).astype(int), np.floor(x).astype(int)
    fy, fx = y - i, x - j
    return ((1 - fy) * ((1 - fx) * z[i, j] + fx * z[i, j + 1]) + fy * ((1 - fx) * z[i + 1, j] + fx * z[i + 1, j + 1]))


def _base_terrain(base: str, lats: np.ndarray, lons: np.ndarray) -> np.ndarray:
    """Heights above WGS-84 at the grid (lats x lons): the Jacksboro DEM
    resampled bilinearly plus its geoid undulation, or flat (0)."""
    if base == "jacksboro":
        b = jacksboro_base()
        la, lo = np.meshgrid(lats, lons, indexing="ij")
        return _bilinear(b, la, lo) + b["geoid"]
    if base == "flat":
        return np.zeros((len(lats), len(lons)))
    raise ValueError(f"base must be 'jacksboro' or 'flat', got {base!r}")


def building_scene(n: int = 2048, seed: int = 0, lat0: float = 36.60, lon0: float = -84.30,
                   nblocks: int | None = None, towers: int | None = None, courtyards: int | None = None,
                   base: str = "jacksboro") -> dict:
    """A 1 m building DSM of n x n cells, heights above WGS-84 (m).

    The base terrain is the Jacksboro DEM resampled bilinearly to 1 m cells
    (``base="jacksboro"``) plus its geoid undulation, or flat (``base="flat"``,
    height 0). On it: ``nblocks`` rectangular blocks (5-60 m a side, 3-150 m
    tall, flat roofs at base + height), ``towers`` one-cell towers (20-150 m)
    and ``courtyards`` ring buildings (an open middle). Row 0 is in the north
    (dlat < 0). Returns dict(heights, lat_first, lon_first, dlat, dlon, a, f,
    roof_id) with ``roof_id[i, j]`` = 0 for ground, else the building's number.
    """
    rng = np.random.default_rng(seed)
    dlat, dlon = metre_steps(lat0)
    lat_first, lon_first = lat0 + (n - 1) * dlat, lon0          # north-west pixel centre
    lats = lat_first - np.arange(n) * dlat
    lons = lon_first + np.arange(n) * dlon
    ground = _base_terrain(base, lats, lons)
    h = ground.copy()
    roof = np.zeros((n, n), dtype=np.int32)
    area = n * n
    nblocks = int(area / 2500) if nblocks is None else nblocks
    towers = int(area / 40000) if towers is None else towers
    courtyards = int(area / 200000) if courtyards is None else courtyards
    k = 0
    for _ in range(nblocks):
        w, d = rng.integers(5, 61, 2)
        i, j = rng.integers(0, n - d), rng.integers(0, n - w)
        top = ground[i:i + d, j:j + w].max() + rng.uniform(3, 150)
        k += 1
        h[i:i + d, j:j + w] = np.maximum(h[i:i + d, j:j + w], top)
        roof[i:i + d, j:j + w] = np.where(h[i:i + d, j:j + w] == top, k, roof[i:i + d, j:j + w])
    for _ in range(towers):
        i, j = rng.integers(0, n, 2)
        k += 1
        h[i, j] = max(h[i, j], ground[i, j] + rng.uniform(20, 150))
        roof[i, j] = k
    for _ in range(courtyards):
        w = int(rng.integers(30, 81))
        t = int(rng.integers(6, 12))
        i, j = rng.integers(0, n - w, 2)
        top = ground[i:i + w, j:j + w].max() + rng.uniform(10, 40)
        ring = np.ones((w, w), dtype=bool)
        ring[t:w - t, t:w - t] = False
        k += 1
        sub = h[i:i + w, j:j + w]
        sub[ring] = np.maximum(sub[ring], top)
        roof[i:i + w, j:j + w][ring] = k
    return dict(heights=h, lat_first=float(lat_first), lon_first=float(lon_first), dlat=-dlat, dlon=dlon,
                a=WGS84_A, f=WGS84_F, roof_id=roof)


def pushbroom_rays(scene: dict, n: int, altitude: tuple[float, float] = (500e3, 700e3),
                   off_nadir: tuple[float, float] = (0.0, 30.0), seed: int = 0, margin: float = 0.1):
    """n lines of sight from an orbit ``altitude`` m above the ellipsoid, ``off_nadir``
    degrees from the local vertical, each aimed at the terrain (nearest cell's height)
    at a random point well inside the scene (``margin`` of each side left out).
    Returns s (n, 3), l (n, 3), ECR metres."""
    rng = np.random.default_rng(seed)
    h = scene["heights"]
    nr, nc = h.shape
    i = rng.uniform(margin, 1 - margin, n) * (nr - 1)
    j = rng.uniform(margin, 1 - margin, n) * (nc - 1)
    lat = scene["lat_first"] + i * scene["dlat"]
    lon = scene["lon_first"] + j * scene["dlon"]
    a, f = scene.get("a", WGS84_A), scene.get("f", WGS84_F)
    target = geodetic_to_ecef(lat, lon, _ground(scene, i, j), a, f)
    return _from_above(target, lat, lon, rng.uniform(*altitude, n), rng.uniform(*off_nadir, n),
                       rng.uniform(0, 2 * np.pi, n))


def _ground(scene: dict, i, j) -> np.ndarray:
    """The scene's height at fractional grid positions (nearest cell): rays are aimed
    at the terrain there, not at the bare ellipsoid (over 500 m high ground a ray
    aimed at height 0 from 30 deg off nadir lands 290 m off)."""
    h = np.asarray(scene["heights"], dtype=np.float64)
    ii = np.clip(np.rint(i).astype(int), 0, h.shape[0] - 1)
    jj = np.clip(np.rint(j).astype(int), 0, h.shape[1] - 1)
    return np.nan_to_num(h[ii, jj])


def airborne_rays(scene: dict, n: int, altitude: tuple[float, float] = (1000.0, 3000.0),
                  elevation: tuple[float, float] = (10.0, 45.0), seed: int = 0, margin: float = 0.3):
    """n oblique lines of sight from an aircraft ``altitude`` m up, ``elevation``
    degrees above the horizon, aimed at points in the middle of the scene."""
    rng = np.random.default_rng(seed)
    nr, nc = scene["heights"].shape
    i = rng.uniform(margin, 1 - margin, n) * (nr - 1)
    j = rng.uniform(margin, 1 - margin, n) * (nc - 1)
    lat = scene["lat_first"] + i * scene["dlat"]
    lon = scene["lon_first"] + j * scene["dlon"]
    a, f = scene.get("a", WGS84_A), scene.get("f", WGS84_F)
    target = geodetic_to_ecef(lat, lon, _ground(scene, i, j), a, f)
    zen = 90.0 - rng.uniform(*elevation, n)
    alt = rng.uniform(*altitude, n)
    dist = alt / np.cos(np.radians(zen))
    return _from_above(target, lat, lon, dist * np.cos(np.radians(zen)), zen, rng.uniform(0, 2 * np.pi, n))


def _from_above(target, lat, lon, height, zen_deg, az):
    """Rays ending at ``target`` that arrive from zenith angle zen (degrees, about the
    local vertical) and azimuth az, starting ``height`` m above the target's level."""
    la, lo = np.radians(lat), np.radians(lon)
    up = np.stack([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)], axis=1)
    east = np.stack([-np.sin(lo), np.cos(lo), np.zeros_like(lo)], axis=1)
    north = np.cross(up, east)
    z = np.radians(zen_deg)[:, None]
    back = np.cos(z) * up + np.sin(z) * (np.cos(az)[:, None] * north + np.sin(az)[:, None] * east)
    dist = height / np.cos(np.radians(zen_deg))
    s = target + dist[:, None] * back
    return s, -back


# ------------------------------------------------- Shin & Park's experiment (Fig. 3-4)
#: the four buildings of :func:`paper_scene`: polygon vertices in metres (east, north)
#: from the scene's south-west corner, roof height above the ground's highest
#: point under the footprint (m), and roof colour (RGB)
PAPER_BUILDINGS = (
    (((120, 330), (230, 330), (230, 400), (170, 400), (170, 450), (120, 450)), 25.0, (200, 60, 50)),   # L-shaped
    (((300, 300), (360, 300), (360, 470), (300, 470)), 60.0, (60, 90, 200)),                           # slab
    (((150, 120), (230, 100), (260, 180), (180, 210)), 40.0, (230, 200, 40)),                          # rotated block
    (((370, 120), (420, 90), (470, 120), (470, 180), (420, 210), (370, 180)), 90.0, (240, 240, 240)),  # hexagonal tower
)


def _texture(nr: int, nc: int, rng) -> np.ndarray:
    """A recognisable, deterministic ground texture (RGB, 0-255): fields of
    smooth random tone, a road grid every 100 m, and fine grain."""
    from scipy import ndimage

    base = ndimage.gaussian_filter(rng.normal(size=(nr, nc)), 12.0)
    base = (base - base.min()) / max(np.ptp(base), 1e-12)
    grain = ndimage.gaussian_filter(rng.normal(size=(nr, nc)), 1.0) * 0.15
    tone = np.clip(0.35 + 0.45 * base + grain, 0, 1)
    rgb = np.stack([90 + 80 * tone, 110 + 100 * tone, 60 + 60 * tone], axis=-1)        # greenish fields
    rows, cols = np.arange(nr)[:, None], np.arange(nc)[None, :]
    road = ((rows % 100) < 6) | ((cols % 100) < 6)
    rgb[road] = (150, 150, 150)
    stripe = road & ((((rows % 100) == 3) & (cols % 12 < 6)) | (((cols % 100) == 3) & (rows % 12 < 6)))
    rgb[stripe] = (250, 250, 250)                                                      # dashed centre lines
    return rgb


def paper_scene(size: int = 640, seed: int = 7, lat0: float = 36.52, lon0: float = -84.16,
                base: str = "jacksboro") -> dict:
    """Shin & Park's test scene (their Fig. 3), rebuilt: a 1 m ortho-photo on a
    coarse base DEM with four polygon buildings of different heights on top.

    The base DEM is the Jacksboro 3-arc-second DEM (matplotlib's sample data;
    ``base="flat"`` for height 0) resampled bilinearly to 1 m cells plus its
    geoid undulation (heights above WGS-84). The buildings
    (:data:`PAPER_BUILDINGS`, laid out on 512 m, scaled into the middle 80 % of
    ``size``) are flat-roofed polygons. The
    ortho-photo is synthetic and deterministic: textured fields, a road grid
    with dashed centre lines, and one distinct colour per roof.

    Returns dict(heights, ground, ortho (size, size, 3) uint8, roof_id,
    lat_first, lon_first, dlat, dlon, a, f, buildings) with row 0 in the
    north; ``ground`` is the bare base terrain (for the roof/ground classes).
    """
    from matplotlib.path import Path as MPath

    if not isinstance(size, (int, np.integer)) or size < 64:
        raise ValueError(f"size must be an integer >= 64 (metres), got {size!r}")
    rng = np.random.default_rng(seed)
    dlat, dlon = metre_steps(lat0)
    n = int(size)
    lat_first = lat0 + (n - 1) * dlat                                   # north-west pixel centre
    lats = lat_first - np.arange(n) * dlat
    lons = lon0 + np.arange(n) * dlon
    ground = _base_terrain(base, lats, lons)
    h = ground.copy()
    roof = np.zeros((n, n), dtype=np.int32)
    rgb = _texture(n, n, rng)
    scale = 0.8 * n / 512.0            # the layout fills the middle 80 % of the scene
    offset = 0.1 * n
    east = (np.arange(n) + 0.5)[None, :].repeat(n, 0)
    north = (n - 1 - np.arange(n) + 0.5)[:, None].repeat(n, 1)
    pts = np.column_stack([east.ravel(), north.ravel()])
    buildings = []
    for k, (poly, height, colour) in enumerate(PAPER_BUILDINGS, start=1):
        verts = np.array(poly, dtype=np.float64) * scale + offset
        inside = MPath(verts).contains_points(pts).reshape(n, n)
        top = float(ground[inside].max()) + height
        h[inside] = top
        roof[inside] = k
        shade = 0.9 + 0.1 * ((np.arange(n)[:, None] // 4 + np.arange(n)[None, :] // 4) % 2)  # roof tiles
        rgb[inside] = (np.array(colour)[None, :] * shade[inside][:, None])
        buildings.append(dict(vertices_m=verts, height=height, roof=top, colour=colour))
    return dict(heights=h, ground=ground, ortho=np.clip(np.rint(rgb), 0, 255).astype(np.uint8), roof_id=roof,
                lat_first=float(lat_first), lon_first=float(lon0), dlat=-dlat, dlon=dlon, a=WGS84_A, f=WGS84_F,
                buildings=buildings)


#: most lines or pixels per line of an ObliqueScan (a tiny step asked for 4e10 and a traceback)
_OBLIQUE_MAX = 1_000_000


class ObliqueScan(Sensor):
    """A pushbroom over a scene grid whose every line views the ground at one
    zenith angle from one azimuth, its rays made a block of lines at a time (a
    :class:`~planet_intersect.sensors.Sensor`; see :func:`oblique_pushbroom`).
    Nothing per pixel is stored, so an image of any size costs only its blocks."""

    def __init__(self, scene: dict, zenith: float = 9.0, azimuth: float = 90.0, altitude: float = 685e3,
                 margin: int = 0, step: float = 1.0):
        h = np.asarray(scene["heights"])
        if h.ndim != 2 or h.dtype.kind not in "fiu":
            raise ValueError(f"scene['heights'] must be a 2-D array of numbers, got shape {h.shape}, dtype {h.dtype}")
        nr, nc = h.shape
        # every number checked by name (azimuth=nan and altitude=inf gave NaN focal points reported
        # later as "s[0] has NaN or Inf"; zenith="9" a TypeError from '<='; dlat=0 one row imaged by
        # every line: a review)
        for name, value in (("zenith", zenith), ("azimuth", azimuth), ("altitude", altitude), ("step", step),
                            ("scene['lat_first']", scene["lat_first"]), ("scene['lon_first']", scene["lon_first"]),
                            ("scene['dlat']", scene["dlat"]), ("scene['dlon']", scene["dlon"])):
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)) \
                    or not math.isfinite(float(value)):
                raise ValueError(f"{name} must be a finite number, got {value!r}")
        if scene["dlat"] == 0 or scene["dlon"] == 0:
            raise ValueError(f"scene['dlat'] and scene['dlon'] must be non-zero, got {scene['dlat']!r}, "
                             f"{scene['dlon']!r}")
        if not np.isfinite(h).any():
            raise ValueError("scene['heights'] has no finite height to aim the rays at")
        if not 0 <= zenith < 80:
            raise ValueError(f"zenith must be in [0, 80) degrees, got {zenith}")
        if not step > 0:
            raise ValueError(f"step must be positive, got {step}")
        if not (isinstance(margin, (int, np.integer)) and not isinstance(margin, bool) and margin >= 0):
            raise ValueError(f"margin must be a whole number of cells >= 0, got {margin!r}")
        for what, n in (("lines", nr), ("pixels", nc)):
            if (n - 2 * margin) / step > _OBLIQUE_MAX:
                raise ValueError(f"step {step:g} makes {(n - 2 * margin) / step:.3g} {what} of a {nr} x {nc} grid "
                                 f"(at most {_OBLIQUE_MAX:,} each)")
        if not altitude > 0:
            raise ValueError(f"altitude must be positive, got {altitude}")
        self.a, self.f = scene.get("a", WGS84_A), scene.get("f", WGS84_F)
        self.rows = np.arange(margin, nr - margin, step, dtype=np.float64)
        self.cols = np.arange(margin, nc - margin, step, dtype=np.float64)
        if len(self.rows) == 0 or len(self.cols) == 0:
            raise ValueError(f"margin {margin} leaves no line or pixel of a {nr} x {nc} grid")
        self.lat_first, self.dlat = scene["lat_first"], scene["dlat"]
        self.lon_first, self.dlon = scene["lon_first"], scene["dlon"]
        self.href = float(np.nanmedian(np.asarray(scene.get("ground", h))))
        self.lon_c = self.lon_first + 0.5 * (nc - 1) * self.dlon
        self.zenith, self.azimuth, self.altitude = float(zenith), float(azimuth), float(altitude)
        self.shape = (len(self.rows), len(self.cols))

    def rays(self, k0: int = 0, k1: int | None = None):
        k0, k1 = self._check_block(k0, self.nlines if k1 is None else k1)
        rows = self.rows[k0:k1]
        lat = self.lat_first + rows * self.dlat
        npx = len(self.cols)
        lons = self.lon_first + self.cols * self.dlon
        # the targets' ECR points on the grid of rows x columns, from a conversion per row and one per
        # column instead of one per pixel: geodetic_to_ecr's x = ((N + h) cos lat) cos lon is that
        # product of IEEE-rounded factors, so the row's (N + h) cos lat (its x at lon = 0, times
        # cos 0 = 1) and z, and the column's cos lon and sin lon (its x and y on the unit sphere,
        # N = 1, h = 0) give every pixel's point identical to the bit (tests/test_simulate.py)
        nr = len(rows)
        rx = geodetic_to_ecef(lat, np.zeros(nr), self.href, self.a, self.f).reshape(-1, 3)
        cs = geodetic_to_ecef(np.zeros(npx), lons, 0.0, 1.0, 0.0).reshape(-1, 3)
        c = geodetic_to_ecef(lat, np.full(nr, self.lon_c), self.href, self.a, self.f).reshape(-1, 3)
        la, lo = np.radians(lat), np.radians(self.lon_c)
        up = np.stack([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)], axis=1)
        e = np.broadcast_to(np.array([-np.sin(lo), np.cos(lo), 0.0]), up.shape)
        nvec = np.cross(up, e)
        z, az = np.radians(self.zenith), np.radians(self.azimuth)
        back = np.cos(z) * up + np.sin(z) * (np.cos(az) * nvec + np.sin(az) * e)
        s = c + (self.altitude / np.cos(z)) * back
        l = np.empty((nr, npx, 3))
        np.multiply(rx[:, None, 0], cs[None, :, 0], out=l[:, :, 0])
        np.multiply(rx[:, None, 0], cs[None, :, 1], out=l[:, :, 1])
        l[:, :, 2] = rx[:, None, 2]
        l -= s[:, None, :]
        return np.repeat(s, npx, axis=0), l.reshape(-1, 3)

    def __repr__(self) -> str:
        return (f"ObliqueScan({self.nlines} lines x {self.npixels} pixels, zenith {self.zenith} deg "
                f"from azimuth {self.azimuth} deg)")


def oblique_pushbroom(scene: dict, zenith: float = 9.0, azimuth: float = 90.0, altitude: float = 685e3,
                      margin: int = 0, step: float = 1.0):
    """A pushbroom over ``scene`` whose every line views the ground at one zenith
    angle from one azimuth (the sensor's side): line k images the row of ground
    points at the scene's row k (north to south), pixel m the column m, with the
    focal point ``altitude`` m above the row's centre and displaced toward
    ``azimuth`` (degrees clockwise from north) so that the row centre is seen at
    ``zenith`` degrees. ``azimuth=90``: the sensor is east of the scene, looking
    west (Shin & Park's north-bound satellite scanning from East to West;
    zenith at the ground, not off-nadir at the satellite [sim note 6]).
    Returns (s (nlines, 3), l (nlines, npixels, 3)) for ``pi.Pushbroom``;
    :class:`ObliqueScan` gives the same rays a block at a time.

    ``step`` (cells) spaces lines and pixels; ``margin`` cells are left out on
    each side. The directions aim at the scene's median ground height, not at
    the terrain: a pixel's ray hits what is in front.
    """
    scan = ObliqueScan(scene, zenith, azimuth, altitude, margin, step)
    s, l = scan.rays()
    nl, npx = scan.shape
    return s.reshape(nl, npx, 3)[:, 0].copy(), l.reshape(nl, npx, 3)
