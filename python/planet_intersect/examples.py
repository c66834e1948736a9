"""The paper's section 4 examples on Mars (Teanby 2008, Figs. 8 and 9).

* :func:`olympus` -- example 1 (section 4.1): a 101 x 101 detector with 0.015 rad
  pixels, due south of Olympus Mons, 325 km above the mean surface; surface
  temperature T(z) = T0 - Gamma z (eq. 64), Planck radiances (eq. 65) with seeded
  Gaussian noise, inverted to brightness temperature and fitted against the
  altitude that ray stepping assigns to each pixel.
* :func:`limb` -- example 2 (section 4.2): a Mars-Climate-Sounder-like linear
  array of 21 pixels looking forward at the limb from a near-polar orbit 300 km
  up whose ground track crosses Olympus Mons, over a sequence of frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .dem import DEM
from .geometry import detector_los, ray_spheroid_intersection, spheroid_radius
from .intersect import IntersectResult, intersect
from .synthetic import MARS_MEAN_RADIUS, OLYMPUS

__all__ = ["planck", "brightness_temperature", "OlympusResult", "olympus", "olympus_geometry", "LimbResult",
           "limb", "limb_geometry",
           "plot_olympus", "plot_limb"]

H = 6.62607015e-34      # Planck constant, J s
C = 2.99792458e8        # speed of light, m/s
K = 1.380649e-23        # Boltzmann constant, J/K


def planck(T, wavelength):
    """Spectral radiance F(T, lambda) of a black body, W m^-2 sr^-1 m^-1 (eq. 65)."""
    return 2 * H * C ** 2 / (wavelength ** 5 * (np.exp(H * C / (K * np.asarray(T) * wavelength)) - 1))


def brightness_temperature(F, wavelength):
    """Eq. 65 solved for T."""
    return H * C / (wavelength * K * np.log1p(2 * H * C ** 2 / (wavelength ** 5 * np.asarray(F))))


def _xyz(lat, lon, r):
    la, lo = np.radians(lat), np.radians(lon)
    return r * np.array([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)])


@dataclass
class OlympusResult:
    """Example 1: geometry, radiances and the lapse-rate fit."""
    s: np.ndarray                   #: spacecraft position (km)
    los: np.ndarray                 #: (nv*nh, 3) lines of sight
    nh: int
    nv: int
    res: IntersectResult
    z: np.ndarray                   #: altitude above the mean surface (km), NaN off the surface
    brightness: np.ndarray          #: brightness temperature (K), NaN off the surface
    T0: float                       #: true surface temperature at z = 0 (K)
    lapse: float                    #: true lapse rate Gamma (K/km)
    T0_fit: float
    lapse_fit: float
    T0_se: float
    lapse_se: float


def olympus_geometry(nh: int = 101, nv: int = 101, pixel: float = 0.015, altitude: float = 325.0,
                     off_nadir_deg: float = 20.0):
    """Example 1's viewing geometry: ``(s, los)`` for a detector due south of Olympus Mons,
    ``altitude`` km above the mean radius, its centre pixel aimed at the volcano on the
    mean sphere ``off_nadir_deg`` from nadir, vertical side towards north in the image."""
    lat0, lon0 = OLYMPUS
    target = _xyz(lat0, lon0, MARS_MEAN_RADIUS)
    r_s = MARS_MEAN_RADIUS + altitude

    def off_nadir(dlat):
        s = _xyz(lat0 - dlat, lon0, r_s)
        v = target - s
        return np.degrees(np.arccos(np.dot(-s, v) / (np.linalg.norm(s) * np.linalg.norm(v)))), s

    lo, hi = 0.0, 30.0                       # bisection on the spacecraft's latitude offset
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if off_nadir(mid)[0] < off_nadir_deg else (lo, mid)
    s = off_nadir(0.5 * (lo + hi))[1]
    l0 = (target - s) / np.linalg.norm(target - s)
    north = np.array([0.0, 0.0, 1.0])
    q = north - np.dot(north, l0) * l0
    return s, detector_los(l0, q / np.linalg.norm(q), nh, nv, pixel, pixel)


def olympus(dem: DEM, *, nh: int = 101, nv: int = 101, pixel: float = 0.015, altitude: float = 325.0,
            off_nadir_deg: float = 20.0, T0: float = 260.0, lapse: float = 2.0, wavelength: float = 12e-6,
            noise_K: float = 0.5, seed: int = 2008, step_mode: int = 1) -> OlympusResult:
    """Example 1 (Fig. 8): oblique view of Olympus Mons, lapse rate from brightness temperatures.

    The spacecraft is on the meridian of the volcano (due south of it), ``altitude``
    km above the mean radius 3389.5 km, placed so that the centre pixel, aimed at the
    volcano, is ``off_nadir_deg`` from nadir (20 deg keeps the 1.5 rad field of view
    below the horizon). The array's vertical side points north in the image.
    Radiance noise is Gaussian with the standard deviation that ``noise_K`` of
    temperature makes at T0 (NE-dT), from ``numpy.random.default_rng(seed)``.
    """
    s, los = olympus_geometry(nh=nh, nv=nv, pixel=pixel, altitude=altitude, off_nadir_deg=off_nadir_deg)
    res = intersect(dem, s, los, step_mode=step_mode)

    z = res.radius - MARS_MEAN_RADIUS                       # altitude above the mean surface
    T = T0 - lapse * z                                      # eq. 64
    F = planck(T, wavelength)                               # eq. 65
    dFdT = (planck(T0 + 0.01, wavelength) - planck(T0 - 0.01, wavelength)) / 0.02
    rng = np.random.default_rng(seed)
    F_obs = F + rng.standard_normal(F.shape) * noise_K * dFdT
    Tb = brightness_temperature(F_obs, wavelength)
    ok = res.hit
    if np.count_nonzero(ok) < 3:
        # (np.polyfit's own "expected non-empty vector for x" said nothing of the DEM: a review)
        raise ValueError(f"example 1 (Olympus Mons): {int(np.count_nonzero(ok))} of {ok.size} pixels hit the DEM, "
                         "at least 3 are needed for the lapse-rate fit; the example is Mars in km (mean radius "
                         f"{MARS_MEAN_RADIUS} km), and this DEM's rmax is {dem.rmax:g}")
    (slope, icpt), cov = np.polyfit(z[ok], Tb[ok], 1, cov=True)
    return OlympusResult(s=s, los=los, nh=nh, nv=nv, res=res, z=z, brightness=np.where(ok, Tb, np.nan),
                         T0=T0, lapse=lapse, T0_fit=float(icpt), lapse_fit=float(-slope),
                         T0_se=float(np.sqrt(cov[1, 1])), lapse_se=float(np.sqrt(cov[0, 0])))


@dataclass
class LimbResult:
    """Example 2: frames x pixels of a forward-looking limb array."""
    spacecraft_lat: np.ndarray      #: (nframes,) planetocentric latitude of the spacecraft
    s: np.ndarray                   #: (nframes, 3)
    los: np.ndarray                 #: (nframes, npix, 3); pixel 0 lowest
    res: IntersectResult            #: flattened (nframes*npix)
    nframes: int
    npix: int
    spheroid_miss: np.ndarray       #: (nframes, npix) True where the line misses the smooth spheroid
    track_lat: np.ndarray           #: along-track latitudes for the topography profile
    track_height: np.ndarray        #: DEM height above the spheroid along the track (km)

    def grid(self, name):
        """A per-pixel result field as (nframes, npix)."""
        return getattr(self.res, name).reshape(self.nframes, self.npix)


def limb_geometry(lats, lon: float = OLYMPUS[1], altitude: float = 300.0, npix: int = 21,
                  tangent_range=(-25.0, 75.0)):
    """Example 2's viewing geometry: spacecraft positions (nframes, 3) at latitudes
    ``lats`` on the meridian ``lon``, ``altitude`` km above the mean radius, and their
    lines of sight (nframes, npix, 3), forward along the meridian, pixel 0 lowest,
    spaced so that over the mean sphere the tangent heights run evenly over
    ``tangent_range`` km."""
    r_s = MARS_MEAN_RADIUS + altitude
    dist = np.sqrt(r_s ** 2 - MARS_MEAN_RADIUS ** 2)               # to the mean-sphere limb
    dip = np.arccos(MARS_MEAN_RADIUS / r_s)                        # limb below the horizontal
    heights = np.linspace(tangent_range[0], tangent_range[1], npix)
    elevation = -dip + heights / dist                              # pixel elevation angles
    S, L = [], []
    for la in np.atleast_1d(lats):
        s = _xyz(la, lon, r_s)
        up = s / r_s
        north = _xyz(la + 90.0, lon, 1.0)                          # forward, along the meridian
        S.append(s)
        L.append(np.cos(elevation)[:, None] * north + np.sin(elevation)[:, None] * up)
    return np.array(S), np.array(L)


def limb(dem: DEM, *, lon: float = OLYMPUS[1], lat_start: float = -20.0, lat_end: float = 10.0,
         frame_step: float = 0.25, altitude: float = 300.0, npix: int = 21,
         tangent_range=(-25.0, 75.0), step_mode: int = 1) -> LimbResult:
    """Example 2 (Fig. 9): an MCS-like limb sounder on a polar orbit over Olympus Mons.

    The orbit lies in the meridian plane of ``lon`` (its ground track crosses the
    volcano), ``altitude`` km above the mean radius, moving north. Each frame's
    21 pixels look forward along the track in that plane, perpendicular to the
    horizon, spaced so that over a smooth mean sphere their tangent heights would
    run evenly over ``tangent_range`` km (pixel 0 lowest).
    """
    lats = np.arange(lat_start, lat_end + 1e-9, frame_step)
    S, L = limb_geometry(lats, lon=lon, altitude=altitude, npix=npix, tangent_range=tangent_range)
    s_all = np.repeat(S, npix, axis=0)
    l_all = L.reshape(-1, 3)
    res = intersect(dem, s_all, l_all, step_mode=step_mode)
    _, d = ray_spheroid_intersection(s_all, l_all, dem.f, dem.re)
    track_lat = np.linspace(lat_start - 5, lat_end + 40, 1200)
    track_h = dem.radius(track_lat, np.full_like(track_lat, lon)) - spheroid_radius(track_lat, dem.f, dem.re)
    return LimbResult(spacecraft_lat=lats, s=S, los=L, res=res, nframes=len(lats), npix=npix,
                      spheroid_miss=np.isnan(d).reshape(len(lats), npix), track_lat=track_lat,
                      track_height=track_h)


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def plot_olympus(ex: OlympusResult, path) -> None:
    """The four panels of Fig. 8 as one PNG."""
    plt = _plt()
    r = ex.res
    fig, ax = plt.subplots(2, 2, figsize=(12, 10))
    img = ex.brightness.reshape(ex.nv, ex.nh)
    a = ax[0, 0].imshow(img, origin="lower", cmap="inferno")
    ax[0, 0].set(title="(a) brightness temperature, detector space", xlabel="horizontal pixel", ylabel="vertical pixel")
    fig.colorbar(a, ax=ax[0, 0], label="K")
    h = r.hit
    b = ax[0, 1].scatter(r.lon[h], r.lat[h], c=ex.brightness[h], s=2, cmap="inferno")
    ax[0, 1].set(title="(b) brightness temperature, map view", xlabel="east longitude (deg)", ylabel="latitude (deg)")
    fig.colorbar(b, ax=ax[0, 1], label="K")
    c = ax[1, 0].scatter(r.lon[h], r.lat[h], c=ex.z[h], s=2, cmap="terrain")
    ax[1, 0].set(title="(c) altitude of hit points above the mean surface", xlabel="east longitude (deg)",
                 ylabel="latitude (deg)")
    fig.colorbar(c, ax=ax[1, 0], label="km")
    ax[1, 1].plot(ex.z[h], ex.brightness[h], ".", ms=1.5, alpha=0.5)
    zz = np.linspace(np.nanmin(ex.z[h]), np.nanmax(ex.z[h]), 10)
    ax[1, 1].plot(zz, ex.T0_fit - ex.lapse_fit * zz, "r-",
                  label=f"fit: T0 = {ex.T0_fit:.2f} ± {ex.T0_se:.2f} K, Γ = {ex.lapse_fit:.3f} ± {ex.lapse_se:.3f} K/km\n"
                        f"true: T0 = {ex.T0:.1f} K, Γ = {ex.lapse:.2f} K/km")
    ax[1, 1].set(title="(d) brightness temperature against altitude", xlabel="altitude (km)", ylabel="K")
    ax[1, 1].legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_limb(ex: LimbResult, path, scale_height: float = 11.0) -> None:
    """Fig. 9c in spirit: a per-pixel radiance against latitude and tangent height above the
    spheroid, contours of tangent altitude above the local surface, hits masked, the
    along-track topography beneath."""
    plt = _plt()
    lat = ex.grid("tangent_lat")
    height = ex.grid("tangent_height")
    above_surface = ex.grid("tangent_altitude")
    radiance = np.exp(-height / scale_height)          # a simple model atmosphere
    fig, ax = plt.subplots(figsize=(11, 6))
    ax.fill_between(ex.track_lat, -30, ex.track_height, color="0.75", hatch="//", edgecolor="0.5",
                    label="along-track topography (above spheroid)")
    sc = ax.scatter(lat.ravel(), height.ravel(), c=radiance.ravel(), s=14, cmap="viridis", marker="s")
    fig.colorbar(sc, ax=ax, label=f"model radiance exp(-h / {scale_height:g} km)")
    # contour on the frames x pixels grid itself, so masked (hit) pixels stay gaps
    cs = ax.contour(np.ma.masked_invalid(lat), np.ma.masked_invalid(height), np.ma.masked_invalid(above_surface),
                    levels=[5, 10, 20, 30, 40, 60], colors="k", linewidths=0.7)
    ax.clabel(cs, fmt="%g km", fontsize=7)
    ax.set(xlabel="latitude of tangent point (deg)", ylabel="tangent height above the spheroid (km)",
           title="Limb view over Olympus Mons: surface-hitting pixels masked; contours: height above local surface",
           ylim=(-30, 80), xlim=(np.nanmin(lat) - 1, np.nanmax(lat) + 1))
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
