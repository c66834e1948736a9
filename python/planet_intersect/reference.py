"""An independent pure-NumPy transcription of Teanby (2008), sections 2.2-2.4.1.

Written from the paper's equations and the choices recorded in
``docs/paper-notes.md`` -- not translated from the Fortran -- so that the two
can be compared ray by ray. It works in degrees where the paper does, holds
all rays in arrays and advances the still-active ones together. It is slow
(pure NumPy) and meant for tests and small benchmarks.

Tangent points follow the paper's construction (eqs. 54-58): the reference
has no "exact" mode; that one is checked against SPICE's ``npedln``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["dem_radius", "intersect", "tangent_paper", "REFINE_TOL_REL", "REFINE_MAXIT"]

#: refinement stops when |r(p') - p'| <= REFINE_TOL_REL * rmax (paper-notes, note 5)
REFINE_TOL_REL = 1e-12
#: at most this many refinement iterations
REFINE_MAXIT = 100

HIT, LIMB, AWAY, HIT_UNCONVERGED, INSIDE = 0, 1, 2, 3, 6


class _Grid:
    """A DEM grid with its polar means (section 2.2)."""

    def __init__(self, radii, ppd):
        self.r = np.asarray(radii, dtype=np.float64)
        self.ppd = int(ppd)
        self.nlat, self.nlon = self.r.shape
        assert self.nlat == 180 * self.ppd and self.nlon == 360 * self.ppd
        self.south = self.r[0].sum() / self.nlon   # "average radius for the polar point"
        self.north = self.r[-1].sum() / self.nlon


def dem_radius(grid: _Grid, theta, phi):
    """Eqs. 2-12: bilinear radius at latitude theta, east longitude phi (degrees)."""
    theta = np.asarray(theta, dtype=np.float64)
    phi = np.asarray(phi, dtype=np.float64)
    m = grid.ppd
    phi_1 = 0.5 / m                      # minimum longitude of the grid (a pixel centre)
    theta_1 = -90.0 + 0.5 / m            # minimum latitude
    # Delta(phi_1, phi): eastward angle of phi from phi_1
    delta = np.mod(phi - phi_1, 360.0)
    delta = np.where(delta >= 360.0, 0.0, delta)
    i1 = np.floor(delta * m + 1).astype(np.int64)                  # eq. 6 (1-based)
    i1 = np.minimum(i1, grid.nlon)
    dphi_m = delta * m - (i1 - 1)                                    # m_pix * delta-phi
    i2 = i1 + 1                                                      # eq. 7
    i2 = np.where(i2 == grid.nlon + 1, 1, i2)                        # cyclicity
    j1 = np.floor((theta - theta_1) * m + 1).astype(np.int64)       # eq. 8
    j2 = j1 + 1                                                      # eq. 9

    south = j1 <= 0
    north = j1 >= grid.nlat
    mid = ~(south | north)
    # row fraction m_pix * delta-theta; at the caps the pole sits half a pixel from the last row
    dtheta_m = np.where(mid, (theta - theta_1) * m - (j1 - 1), 0.0)
    dtheta_m = np.where(south, np.clip((theta + 90.0) * 2 * m, 0.0, 1.0), dtheta_m)
    dtheta_m = np.where(north, np.clip((theta - (90.0 - 0.5 / m)) * 2 * m, 0.0, 1.0), dtheta_m)

    def rec(i, j):
        jj = np.clip(j, 1, grid.nlat)
        return grid.r[jj - 1, i - 1]

    r1 = np.where(south, grid.south, rec(i1, np.where(north, grid.nlat, j1)))   # eq. 2
    r2 = np.where(south, grid.south, rec(i2, np.where(north, grid.nlat, j1)))   # eq. 3
    r3 = np.where(north, grid.north, rec(i1, np.where(south, 1, j2)))           # eq. 4
    r4 = np.where(north, grid.north, rec(i2, np.where(south, 1, j2)))           # eq. 5
    ra = r1 + dphi_m * (r2 - r1)       # eq. 10
    rb = r3 + dphi_m * (r4 - r3)       # eq. 11
    return ra + dtheta_m * (rb - ra)   # eq. 12


def _latlon(g):
    """Eqs. 29-30 in the numerically safe form of paper-notes note 4 (degrees)."""
    theta = np.degrees(np.arctan2(g[..., 2], np.hypot(g[..., 0], g[..., 1])))
    phi = np.mod(np.degrees(np.arctan2(g[..., 1], g[..., 0])), 360.0)
    phi = np.where(phi >= 360.0, 0.0, phi)
    return theta, phi


def _angle(a, b):
    """Angle between vectors (radians), the paper's fvsep."""
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def _delta_alpha(theta, m, step_mode):
    """Eq. 23 in radians; theta clamped to the first/last row centre (step_mode 1)."""
    if step_mode == 1:
        lim = 90.0 - 0.5 / m
        return np.radians(np.cos(np.radians(np.clip(theta, -lim, lim))) / (2.0 * m))
    return np.full_like(theta, np.radians(1.0 / (2.0 * m)))


def tangent_paper(s, l, f, re):
    """Eqs. 54-58: tc, sc and the signed distance d (negative when tc is inside)."""
    w = 1.0 / (1.0 - f)                                       # eq. 54
    stretch = np.array([1.0, 1.0, w])
    s_ = s * stretch
    l_ = l * stretch
    l_ = l_ / np.linalg.norm(l_, axis=-1, keepdims=True)
    t_ = s_ - np.sum(s_ * l_, axis=-1, keepdims=True) * l_    # eq. 55
    tn = np.linalg.norm(t_, axis=-1, keepdims=True)
    sc_ = t_ * (re / tn)                                      # eq. 56
    sc = sc_ / stretch
    a = np.sum(l * (sc - s), axis=-1, keepdims=True)          # eq. 53
    tc = s + a * l                                            # eq. 57
    d = np.linalg.norm(tc - sc, axis=-1)                      # eq. 58
    d = np.where(tn[..., 0] < re, -d, d)
    return tc, sc, d


def intersect(radii, ppd, rmax, f, re, s, l, step_mode=1):
    """Ray stepping for rays ``s + d l`` (arrays (N, 3)); returns a dict of arrays.

    Keys: status, p, lat, lon, radius, emission, t, tc, sc, tangent_lat,
    tangent_lon, tangent_altitude, tangent_height, nsteps (degrees, DEM units).
    """
    grid = _Grid(radii, ppd)
    s = np.array(s, dtype=np.float64, ndmin=2)
    l = np.array(l, dtype=np.float64, ndmin=2)
    s, l = np.broadcast_arrays(s, l)
    s = s.copy()
    l = l / np.linalg.norm(l, axis=1, keepdims=True)
    n = len(s)
    nan3 = np.full((n, 3), np.nan)
    out = {
        "status": np.full(n, LIMB, dtype=np.int64), "p": nan3.copy(), "t": nan3.copy(),
        "tc": nan3.copy(), "sc": nan3.copy(), "nsteps": np.zeros(n, dtype=np.int64),
    }
    for key in ("lat", "lon", "radius", "emission", "tangent_lat", "tangent_lon",
                "tangent_altitude", "tangent_height"):
        out[key] = np.full(n, np.nan)

    s_len = np.linalg.norm(s, axis=1)
    # the spacecraft must not be below the surface
    inside = np.zeros(n, bool)
    low = s_len <= rmax
    if low.any():
        th, ph = _latlon(s[low])
        inside[low] = s_len[low] < dem_radius(grid, th, ph)
    out["status"][inside] = INSIDE

    cos_psi0 = -np.sum(s * l, axis=1) / s_len                       # eq. 19
    t = s + (s_len * cos_psi0)[:, None] * l                         # eq. 20
    t_len = np.linalg.norm(t, axis=1)
    search = (~inside) & (t_len < rmax)
    half = np.sqrt(np.where(search, rmax ** 2 - t_len ** 2, 0.0))
    d0 = s_len * cos_psi0 - half                                     # eq. 21
    dm = s_len * cos_psi0 + half                                     # eq. 22
    search &= dm > 0

    # stepping state (for every ray; only `active` ones advance)
    d = np.maximum(d0, 0.0)
    g = s + d[:, None] * l                                           # eq. 24
    g_len = np.linalg.norm(g, axis=1)
    psi = _angle(l, -g)               # angle at the test point between l and the centre
    theta, phi = _latlon(g)
    r_g = np.full(n, np.nan)
    active = search.copy()
    hit = np.zeros(n, bool)
    # bracket for refinement
    ga = np.zeros((n, 3)); ga_len = np.zeros(n); ra = np.zeros(n)
    gb_len = np.zeros(n); rb = np.zeros(n); dg_b = np.zeros(n)
    while active.any():
        k = np.flatnonzero(active)
        dalpha = _delta_alpha(theta[k], grid.ppd, step_mode)               # eq. 23
        psi_next = psi[k] + dalpha                                         # eq. 25
        dg = np.sin(dalpha) * g_len[k] / np.maximum(np.sin(np.pi - psi_next), np.sin(dalpha))  # eq. 26
        d_next = d[k] + dg                                                 # eq. 27
        beyond = d_next > dm[k]
        active[k[beyond]] = False
        keep = ~beyond
        k, dg, d_next, psi_next = k[keep], dg[keep], d_next[keep], psi_next[keep]
        if k.size == 0:
            break
        g_next = s[k] + d_next[:, None] * l[k]                             # eq. 28
        gn_next = np.linalg.norm(g_next, axis=1)
        th_next, ph_next = _latlon(g_next)                                 # eqs. 29-30
        r_next = dem_radius(grid, th_next, ph_next)
        out["nsteps"][k] += 1
        below = gn_next < r_next
        if below.any():
            kb = k[below]
            first = out["nsteps"][kb] == 1
            r_here = r_g[kb].copy()
            if first.any():
                r_here[first] = dem_radius(grid, theta[kb[first]], phi[kb[first]])
            ga[kb] = g[kb]; ga_len[kb] = g_len[kb]; ra[kb] = r_here
            gb_len[kb] = gn_next[below]; rb[kb] = r_next[below]; dg_b[kb] = dg[below]
            hit[kb] = True
            active[kb] = False
        a = ~below
        ka = k[a]
        d[ka] = d_next[a]; g[ka] = g_next[a]; g_len[ka] = gn_next[a]; r_g[ka] = r_next[a]
        psi[ka] = psi_next[a]; theta[ka] = th_next[a]; phi[ka] = ph_next[a]

    # refinement, eqs. 31-41
    tol = REFINE_TOL_REL * rmax
    p = np.full((n, 3), np.nan)
    status = out["status"]
    status[hit] = HIT_UNCONVERGED
    todo = hit.copy()
    kept = np.zeros(n, dtype=np.int64)      # which end was replaced last: 1 the lower, 2 the upper
    halve = np.zeros(n, bool)               # the same end kept twice running: try the midpoint
    for _ in range(REFINE_MAXIT):
        k = np.flatnonzero(todo)
        if k.size == 0:
            break
        v = rb[k] * (ra[k] - ga_len[k]) / (gb_len[k] * ra[k] - ga_len[k] * rb[k])   # eq. 34
        v = np.where(halve[k], 0.5, v)
        pp = ga[k] + (v * dg_b[k])[:, None] * l[k]                                 # eq. 35
        pn = np.linalg.norm(pp, axis=1)
        rp = dem_radius(grid, *_latlon(pp))
        p[k] = pp
        done = np.abs(rp - pn) <= tol
        status[k[done]] = HIT
        todo[k[done]] = False
        under = (~done) & (rp > pn)
        over = (~done) & ~(rp > pn)
        ku, ko = k[under], k[over]
        gb_len[ku] = pn[under]; rb[ku] = rp[under]; dg_b[ku] = v[under] * dg_b[ku]          # eqs. 36-38
        ga[ko] = pp[over]; ga_len[ko] = pn[over]; ra[ko] = rp[over]; dg_b[ko] = (1 - v[over]) * dg_b[ko]  # eqs. 39-41
        side = np.where(under, 1, 2)
        halve[k] = side == kept[k]
        kept[k] = side

    # hit properties, eqs. 42-50
    e2 = f * (2.0 - f)
    if hit.any():
        ph = p[hit]
        out["p"][hit] = ph
        out["lat"][hit], out["lon"][hit] = _latlon(ph)                      # eqs. 42-43
        out["radius"][hit] = np.linalg.norm(ph, axis=1)                     # eq. 44
        normal = ph * np.array([1.0, 1.0, 1.0 / (1.0 - e2)])                 # eq. 50
        out["emission"][hit] = np.degrees(_angle(normal, -l[hit]))          # eq. 45

    # rays that miss
    miss = ~hit & ~inside
    away = miss & (cos_psi0 < 0)
    status[away] = AWAY
    limb = miss & ~away
    status[limb] = LIMB
    if limb.any():
        out["t"][limb] = t[limb]
        tc, sc, dd = tangent_paper(s[limb], l[limb], f, re)
        out["tc"][limb], out["sc"][limb], out["tangent_height"][limb] = tc, sc, dd
        lat_c, lon_c = _latlon(sc)                                          # eqs. 59-60 (labels as in note 8)
        out["tangent_lat"][limb], out["tangent_lon"][limb] = lat_c, lon_c
        c2 = np.cos(np.radians(lat_c)) ** 2
        r_c = np.sqrt(re * re * (1 - e2) / (1 - e2 * c2))                   # eq. 61
        r_dem = dem_radius(grid, lat_c, lon_c)
        normal = sc * np.array([1.0, 1.0, 1.0 / (1.0 - e2)])
        cos_gamma = np.sum(sc * normal, axis=1) / (np.linalg.norm(sc, axis=1) * np.linalg.norm(normal, axis=1))
        out["tangent_altitude"][limb] = (r_c - r_dem) * cos_gamma + dd      # eq. 63
    out["status"] = status
    return out


def exhaustive_first_hit(radii, ppd, rmax, s, l, substeps=64):
    """Brute-force first entry into the bilinear surface: steps no longer than
    1/``substeps`` of a cell along the ray, then bisection of the first bracket.

    Each step is ``min(radii) * (1/ppd deg) / substeps * cos(lat)`` long, lat the
    current latitude clamped to the first/last row centre: until the ray is below
    the surface |g| >= min(radii), so a step moves it at most 1/substeps of a
    cell in latitude and in longitude. Where the sampled height |g| - r has a
    local minimum, the minimum is searched (ternary search) before moving on:
    the surface's creases at cell edges make V-shaped dips whose chord below the
    surface can be far shorter than a step. Returns ``(hit, d)``; d NaN where none.
    Independent of the Fortran exact mode (no pyramid, no bounds).
    """
    grid = _Grid(radii, ppd)
    s = np.array(s, dtype=np.float64, ndmin=2)
    l = np.array(l, dtype=np.float64, ndmin=2)
    l = l / np.linalg.norm(l, axis=1, keepdims=True)
    n = len(s)
    hit = np.zeros(n, bool)
    d_hit = np.full(n, np.nan)
    b = np.sum(s * l, axis=1)
    t_len = np.linalg.norm(s - b[:, None] * l, axis=1)
    half = np.sqrt(np.maximum(rmax ** 2 - t_len ** 2, 0.0))
    d = np.maximum(-b - half, 0.0)
    d1 = -b + half
    base = float(grid.r.min()) * np.radians(1.0 / ppd) / substeps
    lim = np.radians(90.0 - 0.5 / ppd)

    def height(k, dd):
        g = s[k] + dd[:, None] * l[k]
        th, ph = _latlon(g)
        return np.linalg.norm(g, axis=1) - dem_radius(grid, th, ph), th

    active = np.flatnonzero((t_len < rmax) & (d1 > 0))
    f, th = height(active, d[active])
    d_prev = d[active].copy()            # the sample before d, and its height
    f_prev = np.full(active.size, np.inf)
    while active.size:
        step = base * np.cos(np.minimum(np.abs(np.radians(th)), lim))
        d_new = d[active] + step
        end = d_new > d1[active]
        d_new = np.minimum(d_new, d1[active])
        f_new, th_new = height(active, d_new)
        below = f_new < 0
        lo_b = d[active].copy()              # bracket start for a hit (height > 0 there)
        hi_b = d_new.copy()
        # a sampled local minimum (f_prev > f <= f_new): search it for a dip below the surface
        dip = ~below & (f_prev > f) & (f <= f_new)
        if dip.any():
            j = np.flatnonzero(dip)
            k = active[j]
            a, c = d_prev[j], d_new[j]
            for _ in range(56):
                m1, m2 = a + (c - a) / 3, c - (c - a) / 3
                f1, f2 = height(k, m1)[0], height(k, m2)[0]
                c = np.where(f1 < f2, m2, c)
                a = np.where(f1 < f2, a, m1)
            dm = 0.5 * (a + c)
            fm = height(k, dm)[0]
            neg = fm < 0
            below[j[neg]] = True
            lo_b[j[neg]] = d_prev[j[neg]]
            hi_b[j[neg]] = dm[neg]
        k = active[below]
        if k.size:
            lo, hi = lo_b[below], hi_b[below]
            for _ in range(60):
                mid = 0.5 * (lo + hi)
                fm = height(k, mid)[0]
                hi = np.where(fm < 0, mid, hi)
                lo = np.where(fm < 0, lo, mid)
            hit[k] = True
            d_hit[k] = hi
        keep = ~below & ~end
        d_prev, f_prev = d[active[keep]].copy(), f[keep]
        d[active[keep]] = d_new[keep]
        active, f, th = active[keep], f_new[keep], th_new[keep]
    return hit, d_hit
