"""Exhaustive first hit of rays on a geodetic DSM (pure NumPy reference).

Written from ``briefs/dsm-contract.md`` and geometry only, as the independent
reference for issue 11's exact mode. It is deliberately dumb: fine fixed steps
along the ray, exact geodetic conversion at every step, no search structure.

Status codes (this module's own; the implementation's codes are unknown)
-----------------------------------------------------------------------
``HIT = 0, NO_DATA = 1, LEFT_DSM = 2, MISS = 3, INSIDE = 4`` with the
contract's meanings. Precedence: the first of {hit, low no-data point} along
the ray decides HIT / NO_DATA; otherwise LEFT_DSM if the ray was ever low
(h <= H_max) outside the area; otherwise MISS (never low, or low only over the
DSM without touching it). INSIDE: h(0) <= H at s over valid data.

Method
------
1. ``h(r)`` along a ray is convex (outside the evolute the geodetic height is
   the signed distance to the ellipsoid; see geodesy.py), so
   ``{h <= H_max}`` and ``{h <= H_min}`` are intervals. Newton from the left
   (monotone for a convex function) gives r_A (first ``h = H_max``) and r_C
   (first ``h = H_min``); without r_C the scan ends at r_B, where h rises
   above H_max again. The scan covers [r_A, r_C] (or [r_A, r_B]): no event
   can happen before r_A, and at r_C the ray is either over the area (a hit
   at r_C at the latest) or low outside.
2. Samples every ``step`` metres (default: 1/8 of the smallest cell size in
   metres anywhere on the grid, at most ``STEP_MAX = 1 m``; a given ``step``
   must be at most half the smallest cell), each converted EXACTLY to
   (lat, lon, h) by geodesy.py (iterated Bowring, checked against pyproj).
3. Cell boundaries: between two samples whose cell (nearest: pixel; bilinear:
   node cell) differs, the crossing of that row/column line is solved (linear
   interpolation of the grid coordinate plus one false-position step, error
   < 1e-12 m) and becomes a test point of its own. Nearest: the surface
   height on the boundary is the larger of the cells on either side (walls
   are solid), so a one-cell tower is never stepped over, whatever the step.
   Bilinear: H is continuous there but its gradient jumps (ridges).
4. Between consecutive test points the ray is inside ONE cell, where
   ``g = h - H`` is smooth with ``g'' <= K``; K bounds the curvature of the
   height level surfaces (h'' <= 1/(b^2/a + H_min - 1 km)) plus, for
   bilinear, ``-H''`` along the ray (2 |c_uv| |u'||v'| plus the curvature of
   lat(r), lon(r) times the cell's slopes). A segment whose two ends are
   clear of the surface with ``min(g_a, g_b) > K L^2 / 8`` cannot touch it
   (certificate). Segments that fail it ("grazing chords") are split in 4,
   level after level (the second pass), until certified or an earlier event
   appears; after ``MAX_LEVELS`` levels (segment 4**-40 of a step), or when
   more than ``MAX_SUS`` grazing segments of one ray remain at a level (a ray
   running along a surface within rounding), the ray is flagged ``uncertain``
   (a tangency within ~1e-12 m; none in the test scenes).
5. The first event bracket is refined by quartering (a level also checks the
   certificate of the sub-segments before the new bracket) to ``TOL_R =
   1e-7`` m; the reported r is the upper end (a point that satisfies the hit
   predicate: never early). A wall hit is reported exactly on the boundary.

Choices where the contract is silent (documented here)
------------------------------------------------------
* Bilinear no-data: a point is no-data if a node with NON-ZERO weight is
  no-data (on a node line only the two nodes of the line count).
* Nearest, a boundary between a valid and a no-data cell: the wall is the
  valid cell's; a point strictly inside a no-data cell is a no-data point.
* Nearest, a corner crossed exactly: each crossing is handled as a wall of
  the two cells it separates (measure zero).
* Reported ``h`` is the geodetic height of the hit point; ``H`` the surface
  height there by the contract (on a wall: the wall's top, the larger cell);
  ``wall`` is True when the hit lies on a boundary below the top (H - h >
  1e-6 m, nearest only).
* LEFT_DSM point: the first low point outside the area, i.e. the area edge
  crossing (or r_A when the ray is already outside there).
* Global grids (ncols*dlon >= 360) are not supported (ValueError).
* A ray that is low outside the area and then enters it and meets the
  surface is a HIT (the contract's HIT is the smallest r over the area with
  h <= H; LEFT_DSM only when there is no hit); ``r_low_outside`` tells which
  hits did so (some airborne wall and grazing rays of the scenes).
* Not searched: a ray below H_min OUTSIDE the area at r_C that re-enters the
  area further on while underground (below all terrain); it is reported
  LEFT_DSM, while the contract would call the underground entry a HIT.

Residual risks (bounded)
------------------------
* A double crossing of the same parallel within one step (the ray heading due
  east/west there) is not detected; the excursion into the next row is at most
  ``step^2 / (8 rho)`` (rho: distance from the axis; 2e-9 m at mid latitudes,
  2e-6 m 1 km from the pole for a 0.125 m step). Longitude is monotone along
  any straight line, so columns are never crossed twice.
* Tangencies closer than ~1e-12 m are reported as no hit with ``uncertain``.
"""

from __future__ import annotations

import math

import numpy as np

from .geodesy import WGS84_A, WGS84_F, _check_af, ecef_to_geodetic_rad, wrap_lon

HIT, NO_DATA, LEFT_DSM, MISS, INSIDE = 0, 1, 2, 3, 4
STATUS_NAMES = {HIT: "HIT", NO_DATA: "NO_DATA", LEFT_DSM: "LEFT_DSM", MISS: "MISS", INSIDE: "INSIDE"}
STEP_MAX = 1.0  # m, the largest default step
TOL_R = 1e-7  # m, final bracket length
MAX_LEVELS = 40  # quartering levels of the second pass
MAX_SUS = 64  # grazing segments followed per ray and level
BLOCK = 256  # samples per block
CHUNK = 1024  # rays per chunk


class Surface:
    """The contract's surface H(lat, lon) on a regular geodetic grid."""

    def __init__(self, heights, lat_first, lon_first, dlat, dlon, a=WGS84_A, f=WGS84_F,
                 interpolation="bilinear", nodata=None):
        self.a, self.f = _check_af(a, f)
        h = np.asarray(heights)
        if h.ndim != 2 or h.shape[0] < 1 or h.shape[1] < 1:
            raise ValueError(f"heights: must be a non-empty 2-D array, got shape {h.shape}")
        if not np.issubdtype(h.dtype, np.number) or np.iscomplexobj(h):
            raise ValueError(f"heights: must be real numbers, got dtype {h.dtype}")
        h = h.astype(np.float64)
        if interpolation not in ("bilinear", "nearest"):
            raise ValueError(f"interpolation: must be 'bilinear' or 'nearest', got {interpolation!r}")
        for name, val in (("lat_first", lat_first), ("lon_first", lon_first), ("dlat", dlat), ("dlon", dlon)):
            if not np.isfinite(float(val)):
                raise ValueError(f"{name}: must be finite, got {val!r}")
        dlat, dlon = float(dlat), float(dlon)
        if dlat == 0:
            raise ValueError("dlat: must be non-zero")
        if dlon <= 0:
            raise ValueError(f"dlon: must be > 0, got {dlon}")
        self.nrows, self.ncols = h.shape
        self.nearest = interpolation == "nearest"
        if not self.nearest and (self.nrows < 2 or self.ncols < 2):
            raise ValueError("heights: bilinear interpolation needs at least 2 x 2 nodes")
        self.lat_first, self.lon_first, self.dlat, self.dlon = float(lat_first), float(lon_first), dlat, dlon
        lat_last = self.lat_first + (self.nrows - 1) * dlat
        if max(abs(self.lat_first), abs(lat_last)) > 90:
            raise ValueError("lat_first/dlat: pixel centres must lie within [-90, 90] latitude")
        width = (self.ncols if self.nearest else self.ncols - 1) * dlon
        if width >= 360 - 1e-9:
            raise ValueError("dlon: global grids (ncols*dlon >= 360) are not supported by this reference")
        valid = np.isfinite(h)
        if nodata is not None:
            valid &= h != float(nodata)
        if not valid.any():
            raise ValueError("heights: no valid height (all NaN or nodata)")
        self.valid = valid
        self.Hz = np.where(valid, h, 0.0)
        self.hmax = float(h[valid].max())
        self.hmin = float(h[valid].min())
        off = 0.5 if self.nearest else 0.0
        self.u_lo, self.u_hi = -off, self.nrows - 1 + off
        self.v_lo, self.v_hi = -off, self.ncols - 1 + off
        self.west = self.lon_first - off * dlon
        self.width = width
        b = self.a * (1 - self.f)
        e2 = self.f * (2 - self.f)
        # smallest cell size in metres (metres per degree of latitude >= b^2/a; longitude at the poleward edge)
        lats = np.array([self.lat_first, lat_last])
        edge = np.clip(np.abs(lats) + off * abs(dlat), 0, 90).max()
        s = math.sin(math.radians(edge))
        n_edge = self.a / math.sqrt(1 - e2 * s * s)
        rho_min = n_edge * math.cos(math.radians(edge))
        self.cell_min = min(math.radians(abs(dlat)) * b * b / self.a, math.radians(dlon) * rho_min)
        self.rho_min = max(rho_min + min(self.hmin, 0.0) - 1.0, 1e-3)
        rmin = b * b / self.a + min(self.hmin, 0.0) - 1000.0
        self.kh = 1.0 / rmin  # bound of h'' along any straight line (curvature of the level surfaces)
        # bounds of |u''|, |v''| along a straight line (grid units per m^2)
        self.u2 = (2.0 / (rmin * self.rho_min) + 4.0 / rmin**2) / math.radians(abs(dlat))
        self.v2 = 2.0 / (self.rho_min**2 * math.radians(dlon))
        if not self.nearest:
            H = self.Hz
            self.c_uv = np.abs(H[:-1, :-1] - H[1:, :-1] - H[:-1, 1:] + H[1:, 1:])
            self.hu = np.maximum(np.abs(H[1:, :-1] - H[:-1, :-1]), np.abs(H[1:, 1:] - H[:-1, 1:]))
            self.hv = np.maximum(np.abs(H[:-1, 1:] - H[:-1, :-1]), np.abs(H[1:, 1:] - H[1:, :-1]))
            # per cell: H = c0 + cu t + cv q + cuv t q (t, q in [0, 1]), and "all four nodes valid"
            self.coef = np.stack([H[:-1, :-1], H[1:, :-1] - H[:-1, :-1], H[:-1, 1:] - H[:-1, :-1],
                                  H[:-1, :-1] - H[1:, :-1] - H[:-1, 1:] + H[1:, 1:]], axis=-1)
            v = self.valid
            self.cell_ok = v[:-1, :-1] & v[1:, :-1] & v[:-1, 1:] & v[1:, 1:]
            # curvature terms of the cell and its 3 neighbours of larger index (a sample interval
            # touches at most the 2 x 2 cells from its smaller indices)
            A2 = 2.0 * self.c_uv
            B2 = self.hu * self.u2 + self.hv * self.v2

            def max22(x):
                y = np.pad(x, ((0, 1), (0, 1)), mode="edge")
                return np.maximum.reduce([y[:-1, :-1], y[1:, :-1], y[:-1, 1:], y[1:, 1:]])

            self.A22, self.B22 = max22(A2), max22(B2)
            self.A_max, self.B_max = float(A2.max()), float(B2.max())

    # ---- grid coordinates -------------------------------------------------
    def uv(self, sphi, cphi, lon_rad):
        lat = np.degrees(np.arctan2(sphi, cphi))
        u = (lat - self.lat_first) / self.dlat
        c = 180.0 - self.width / 2
        d = (np.degrees(lon_rad) - self.west + c) % 360.0 - c
        v = d / self.dlon + self.v_lo
        return u, v

    def cell(self, u, v):
        if self.nearest:
            return np.floor(u + 0.5).astype(np.int64), np.floor(v + 0.5).astype(np.int64)
        return np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)

    def inside(self, u, v):
        return (u >= self.u_lo) & (u <= self.u_hi) & (v >= self.v_lo) & (v <= self.v_hi)

    def height(self, u, v):
        """(H, valid) at grid coordinates (only meaningful where inside)."""
        if self.nearest:
            i = np.clip(np.floor(u + 0.5).astype(np.int64), 0, self.nrows - 1)
            j = np.clip(np.floor(v + 0.5).astype(np.int64), 0, self.ncols - 1)
            return self.Hz[i, j], self.valid[i, j]
        i = np.clip(np.floor(u).astype(np.int64), 0, self.nrows - 2)
        j = np.clip(np.floor(v).astype(np.int64), 0, self.ncols - 2)
        t = np.clip(u - i, 0.0, 1.0)
        q = np.clip(v - j, 0.0, 1.0)
        c = self.coef[i, j]
        H = c[..., 0] + c[..., 1] * t + c[..., 2] * q + c[..., 3] * (t * q)
        ok = self.cell_ok[i, j]
        bad = ~ok
        if bad.any():  # a no-data node in the cell: the point is no-data only if that node has weight > 0
            ib, jb, tb, qb = i[bad], j[bad], t[bad], q[bad]
            okb = np.ones(ib.shape, bool)
            for wk, (ii, jj) in zip(((1 - tb) * (1 - qb), tb * (1 - qb), (1 - tb) * qb, tb * qb),
                                    ((ib, jb), (ib + 1, jb), (ib, jb + 1), (ib + 1, jb + 1))):
                okb &= ~((wk > 0) & ~self.valid[ii, jj])
            ok = ok.copy()
            ok[bad] = okb
        return H, ok

    def wall(self, axis, c0, c1, other):
        """Nearest: surface at a boundary between cells c0 and c1 along axis (0 rows, 1 cols).

        Returns (H, valid, inside): the larger height of the inside valid sides.
        """
        Hs, oks, ins = [], [], []
        for c in (c0, c1):
            if axis == 0:
                i, j = c, other
            else:
                i, j = other, c
            inn = (i >= 0) & (i < self.nrows) & (j >= 0) & (j < self.ncols)
            ic = np.clip(i, 0, self.nrows - 1)
            jc = np.clip(j, 0, self.ncols - 1)
            ok = inn & self.valid[ic, jc]
            Hs.append(np.where(ok, self.Hz[ic, jc], -np.inf))
            oks.append(ok)
            ins.append(inn)
        return np.maximum(Hs[0], Hs[1]), oks[0] | oks[1], ins[0] | ins[1]

    def seg_k(self, ua, va, ub, vb, L):
        """Upper bound of g'' = h'' - H'' on segments (one cell each) of length L."""
        if self.nearest:
            return np.full(np.shape(ua), self.kh)
        i = np.clip(np.floor(np.nan_to_num(0.5 * (ua + ub))).astype(np.int64), 0, self.nrows - 2)
        j = np.clip(np.floor(np.nan_to_num(0.5 * (va + vb))).astype(np.int64), 0, self.ncols - 2)
        with np.errstate(invalid="ignore", divide="ignore"):
            du = np.abs(ub - ua) / L + self.u2 * L
            dv = np.abs(vb - va) / L + self.v2 * L
        du = np.where(L > 0, du, 0.0)
        dv = np.where(L > 0, dv, 0.0)
        kH = 2.0 * self.c_uv[i, j] * du * dv + self.hu[i, j] * self.u2 + self.hv[i, j] * self.v2
        return self.kh + 1.01 * kH + 1e-12


class _Eval:
    """Evaluate points s + r l (flattened arrays) against the surface."""

    def __init__(self, srf):
        self.srf = srf

    def __call__(self, s, l, r, snap_axis=None, snap_val=None, walls=None):
        srf = self.srf
        p = s + r[..., None] * l
        sphi, cphi, lon, h = ecef_to_geodetic_rad(p[..., 0], p[..., 1], p[..., 2], srf.a, srf.f)
        u, v = srf.uv(sphi, cphi, lon)
        if snap_axis == 0:
            u = snap_val
        elif snap_axis == 1:
            v = snap_val
        if walls is not None and srf.nearest:
            axis, c0, c1 = walls
            other = srf.cell(u, v)[1 - axis]
            H, ok, inn = srf.wall(axis, c0, c1, other)
        else:
            inn = srf.inside(u, v)
            H, ok = srf.height(u, v)
            ok = ok & inn
        hit = ok & (h <= H)
        nod = inn & ~ok & (h <= srf.hmax)
        low_out = ~inn & (h <= srf.hmax)
        g = np.where(ok, h - H, np.inf)
        return dict(r=r, u=u, v=v, h=h, H=np.where(ok, H, np.nan), hit=hit, nod=nod, ev=hit | nod,
                    low_out=low_out, g=g)


def _conv_h_dh(s, l, r, a, f):
    p = s + r[:, None] * l
    sphi, cphi, lon, h = ecef_to_geodetic_rad(p[:, 0], p[:, 1], p[:, 2], a, f)
    n = np.stack([cphi * np.cos(lon), cphi * np.sin(lon), sphi], axis=-1)
    return h, np.sum(n * l, axis=-1)


def _newton_first(s, l, c, r0, a, f, maxit=200):
    """First r >= r0 with h(r) = c on a convex h (Newton from the left, monotone).

    Returns (r, found, r_stop): r_stop is where the search stopped (h'(r_stop)
    >= 0 without a root: the minimum of h lies before r_stop).
    """
    r = r0.copy()
    n = r.size
    found = np.zeros(n, bool)
    active = np.ones(n, bool)
    tol = 1e-9 * max(1.0, abs(c))
    for _ in range(maxit):
        idx = np.nonzero(active)[0]
        if idx.size == 0:
            break
        h, dh = _conv_h_dh(s[idx], l[idx], r[idx], a, f)
        g = h - c
        root = g <= tol
        found[idx[root]] = True
        up = ~root & (dh >= 0)
        step = ~root & ~up
        with np.errstate(divide="ignore", invalid="ignore"):
            r[idx[step]] = r[idx[step]] - g[step] / dh[step]
        bad = ~np.isfinite(r[idx])
        active[idx[root | up | bad]] = False
    else:
        # cap reached (near tangency): accept tiny residuals as roots
        idx = np.nonzero(active)[0]
        if idx.size:
            h, _ = _conv_h_dh(s[idx], l[idx], r[idx], a, f)
            found[idx[h - c <= 1e-6]] = True
    return r, found


def _scan_interval(srf, s, l):
    """(rA, rE, low) per ray: the part of the ray that can matter; low=False: never h <= H_max."""
    a, f = srf.a, srf.f
    n = s.shape[0]
    zero = np.zeros(n)
    rA, fA = _newton_first(s, l, srf.hmax, zero, a, f)
    rE = np.full(n, np.nan)
    idx = np.nonzero(fA)[0]
    if idx.size:
        rC, fC = _newton_first(s[idx], l[idx], srf.hmin, rA[idx], a, f)
        rE[idx[fC]] = rC[fC] + 1e-3  # 1 mm past h = H_min: h < H_min there (Newton stops within 1e-9 m above)
        jdx = idx[~fC]
        if jdx.size:  # the ray bottoms out between H_min and H_max: find where it rises above H_max
            rs = rC[~fC]  # past the minimum of h
            far = rs + np.maximum(1.0, rs - rA[jdx])
            for _ in range(80):
                h, _ = _conv_h_dh(s[jdx], l[jdx], far, a, f)
                low = h <= srf.hmax
                if not low.any():
                    break
                far = np.where(low, rs + 2.0 * (far - rs), far)
            sb = s[jdx] + far[:, None] * l[jdx]
            back, fB = _newton_first(sb, -l[jdx], srf.hmax, np.zeros(jdx.size), a, f)
            rE[jdx] = np.where(fB, far - back, far)
    return rA, rE, fA


def _solve_cross(ev, s, l, ra, rb, xa, xb_, ca, cb_, axis, srf):
    """Crossing of the grid line between cells ca and cb along axis (0: rows/u, 1: cols/v).

    xa, xb_: the grid coordinate (u or v) at ra and rb. Linear interpolation of
    the coordinate, then one false-position step; the point is evaluated with
    the coordinate snapped onto the line (and, for nearest, the wall rule).
    """
    if srf.nearest:
        xb = np.minimum(ca, cb_) + 0.5
    else:
        xb = np.maximum(ca, cb_).astype(np.float64)
    key = "u" if axis == 0 else "v"
    with np.errstate(invalid="ignore", divide="ignore"):
        r1 = ra + (rb - ra) * (xb - xa) / (xb_ - xa)
    r1 = np.clip(np.where(np.isfinite(r1), r1, 0.5 * (ra + rb)), ra, rb)
    x1 = ev(s, l, r1)[key]
    same_a = np.sign(x1 - xb) == np.sign(xa - xb)
    r_o = np.where(same_a, rb, ra)
    x_o = np.where(same_a, xb_, xa)
    with np.errstate(invalid="ignore", divide="ignore"):
        r2 = r1 + (r_o - r1) * (xb - x1) / (x_o - x1)
    r2 = np.where(np.isfinite(r2), r2, r1)
    r2 = np.clip(r2, ra, rb)
    walls = (axis, ca, cb_) if srf.nearest else None
    return ev(s, l, r2, snap_axis=axis, snap_val=xb, walls=walls)


_FIELDS = ("r", "u", "v", "h", "H", "hit", "nod", "ev", "low_out", "g")


def _cat(parts):
    return {k: np.concatenate([p[k] for p in parts]) for k in _FIELDS}


def _take(d, idx):
    return {k: d[k][idx] for k in _FIELDS}


class _Chunk:
    """All state of one chunk of rays."""

    def __init__(self, srf, s, l, rA, rE, step):
        self.srf, self.s, self.l = srf, s, l
        self.ev = _Eval(srf)
        n = s.shape[0]
        self.n = n
        self.rA = rA
        length = np.maximum(rE - rA, 0.0)
        self.nsamp = np.maximum(np.ceil(length / step).astype(np.int64), 1)
        self.dr = length / self.nsamp
        self.has_ev = np.zeros(n, bool)
        self.lo = None  # dicts of per-ray point data, filled on events
        self.hi = None
        self.left_r = np.full(n, np.nan)
        self.clear = np.full(n, np.inf)
        self.ntest = np.zeros(n, np.int64)
        # suspicious segments: list of (ray, pa dict, pb dict, K)
        self.sus_ray = []
        self.sus_a = []
        self.sus_b = []

    # -- helpers ------------------------------------------------------------
    def _certify(self, pa, pb):
        """True where a segment (both ends clear, in valid data) is certified free of hits."""
        with np.errstate(invalid="ignore"):
            L = np.abs(pb["r"] - pa["r"])
        K = self.srf.seg_k(pa["u"], pa["v"], pb["u"], pb["v"], L)
        gmin = np.minimum(pa["g"], pb["g"])
        both = np.isfinite(pa["g"]) & np.isfinite(pb["g"])
        return ~both | (gmin > K * L * L / 8.0)

    def _add_sus(self, ray, pa, pb):
        if ray.size:
            self.sus_ray.append(ray)
            self.sus_a.append(pa)
            self.sus_b.append(pb)

    def _set_event(self, ray, plo, phi):
        """Set (or move earlier) the event bracket of rays."""
        if self.lo is None:
            nanp = {k: np.full(self.n, np.nan) if k not in ("hit", "nod", "ev", "low_out")
                    else np.zeros(self.n, bool) for k in _FIELDS}
            self.lo = {k: v.copy() for k, v in nanp.items()}
            self.hi = {k: v.copy() for k, v in nanp.items()}
        # several candidates per ray: keep the earliest hi
        order = np.lexsort((phi["r"], ray))
        ray_o = ray[order]
        first = np.ones(ray_o.size, bool)
        first[1:] = ray_o[1:] != ray_o[:-1]
        sel = order[first]
        ray_s = ray[sel]
        better = ~self.has_ev[ray_s] | (phi["r"][sel] < self.hi["r"][ray_s])
        sel = sel[better]
        ray_s = ray_s[better]
        for k in _FIELDS:
            self.lo[k][ray_s] = plo[k][sel]
            self.hi[k][ray_s] = phi[k][sel]
        self.has_ev[ray_s] = True

    # -- stage 1: the fixed-step scan --------------------------------------
    def _interval_k(self, pv, cur, L, cand=None):
        """Bound of g'' over sample intervals (all cells they may touch); cand: where it is needed."""
        srf = self.srf
        if srf.nearest:
            return np.full(L.shape, srf.kh)
        with np.errstate(invalid="ignore", divide="ignore"):
            du = np.where(L > 0, np.abs(cur["u"] - pv["u"]) / L, 0.0) + srf.u2 * L
            dv = np.where(L > 0, np.abs(cur["v"] - pv["v"]) / L, 0.0) + srf.v2 * L
        du = np.nan_to_num(du)
        dv = np.nan_to_num(dv)
        if cand is None:  # the global bound
            return srf.kh + 1.01 * (srf.A_max * du * dv + srf.B_max) + 1e-12
        K = np.full(L.shape, np.inf)
        ii, jj = np.nonzero(cand)
        uu = np.minimum(pv["u"][ii, jj], cur["u"][ii, jj])
        vv = np.minimum(pv["v"][ii, jj], cur["v"][ii, jj])
        i = np.clip(np.floor(np.nan_to_num(uu)).astype(np.int64), 0, srf.nrows - 2)
        j = np.clip(np.floor(np.nan_to_num(vv)).astype(np.int64), 0, srf.ncols - 2)
        K[ii, jj] = srf.kh + 1.01 * (srf.A22[i, j] * du[ii, jj] * dv[ii, jj] + srf.B22[i, j]) + 1e-12
        return K

    def scan(self):
        srf, ev = self.srf, self.ev
        n = self.n
        allr = np.arange(n)
        p0 = ev(self.s, self.l, self.rA.copy())
        self.ntest += 1
        self.left_r[p0["low_out"]] = self.rA[p0["low_out"]]
        e0 = p0["ev"]
        self.clear = np.minimum(self.clear, np.where(e0, np.inf, p0["g"]))
        if e0.any():
            self._set_event(allr[e0], _take(p0, e0), _take(p0, e0))
        prev = p0
        k0 = 1
        active = ~e0
        while True:
            act = np.nonzero(active & (self.nsamp >= k0))[0]
            if act.size == 0:
                break
            na = act.size
            ar = np.arange(na)
            s, l = self.s[act], self.l[act]
            k = k0 + np.arange(BLOCK)
            okk = k[None, :] <= self.nsamp[act, None]
            r = self.rA[act, None] + np.minimum(k[None, :], self.nsamp[act, None]) * self.dr[act, None]
            cur = ev(s[:, None, :], l[:, None, :], r)
            cur["r"] = np.where(okk, cur["r"], np.inf)
            cur["g"] = np.where(okk, cur["g"], np.inf)
            for kk in ("hit", "nod", "ev", "low_out"):
                cur[kk] &= okk
            # the previous point of each sample: fields needed everywhere (others gathered on demand)
            pv = {kk: np.concatenate([prev[kk][act, None], cur[kk][:, :-1]], axis=1) for kk in ("r", "u", "v", "g")}
            cells_cur = srf.cell(cur["u"], cur["v"])
            cells_prev = srf.cell(prev["u"][act], prev["v"][act])
            # crossings of grid lines between consecutive samples: test points of their own
            groups = [cur]
            for axis, key in ((0, "u"), (1, "v")):
                cb_ = cells_cur[axis]
                ca = np.concatenate([cells_prev[axis][:, None], cb_[:, :-1]], axis=1)
                nmax = (srf.nrows if axis == 0 else srf.ncols) - (0 if srf.nearest else 1)
                rel = (ca >= -1) & (ca <= nmax) & (cb_ >= -1) & (cb_ <= nmax)  # a grid line of the area
                m = okk & (ca != cb_) & rel
                if np.any(m & (np.abs(ca - cb_) > 1)):
                    raise RuntimeError("step crosses more than one cell line: step too large for this grid")
                d = {kk: (np.zeros((na, BLOCK), bool) if cur[kk].dtype == bool else np.full((na, BLOCK), np.nan))
                     for kk in _FIELDS}
                d["r"][:] = np.inf
                d["g"][:] = np.inf
                if m.any():
                    ii, jj = np.nonzero(m)
                    c = _solve_cross(ev, s[ii], l[ii], pv["r"][ii, jj], cur["r"][ii, jj], pv[key][ii, jj],
                                     cur[key][ii, jj], ca[ii, jj], cb_[ii, jj], axis, srf)
                    for kk in _FIELDS:
                        d[kk][ii, jj] = c[kk]
                    self.ntest[act] += m.sum(axis=1)
                groups.append(d)
            self.ntest[act] += okk.sum(axis=1)
            Rcat = np.concatenate([g_["r"] for g_ in groups], axis=1)
            Ecat = np.concatenate([g_["ev"] for g_ in groups], axis=1)
            RE = np.where(Ecat, Rcat, np.inf)
            r_ev = RE.min(axis=1)
            has = np.isfinite(r_ev)
            before = Rcat < r_ev[:, None]
            Gcat = np.concatenate([g_["g"] for g_ in groups], axis=1)
            self.clear[act] = np.minimum(self.clear[act], np.where(before, Gcat, np.inf).min(axis=1))
            # first low point outside the area
            need_l = np.isnan(self.left_r[act])
            if need_l.any():
                LOcat = np.concatenate([g_["low_out"] for g_ in groups], axis=1)
                r_lo = np.where(LOcat, Rcat, np.inf).min(axis=1)
                hl = need_l & np.isfinite(r_lo)
                if hl.any():
                    pred = np.where(Rcat < r_lo[:, None], Rcat, -np.inf).max(axis=1)
                    pred = np.where(np.isfinite(pred), pred, prev["r"][act])
                    self.left_r[act[hl]] = pred[hl]
            # certificates on sample intervals that start before the event
            start_before = okk & (pv["r"] < r_ev[:, None])
            with np.errstate(invalid="ignore"):
                Lf = cur["r"] - pv["r"]
                L = np.minimum(cur["r"], r_ev[:, None]) - pv["r"]
            gmin = pv["g"].copy()
            for g_ in groups:
                gmin = np.minimum(gmin, np.where(g_["r"] < r_ev[:, None], g_["g"], np.inf))
            Lf = np.where(start_before, Lf, 0.0)
            K = self._interval_k(pv, cur, Lf)  # global bound first: most intervals pass it
            sus = start_before & np.isfinite(gmin) & (gmin <= K * L * L / 8.0)
            if sus.any() and not srf.nearest:
                K = self._interval_k(pv, cur, Lf, cand=sus)
                with np.errstate(invalid="ignore"):
                    sus &= gmin <= K * L * L / 8.0
            if sus.any():
                pvf = {kk: (pv[kk] if kk in pv else
                            np.concatenate([prev[kk][act, None], cur[kk][:, :-1]], axis=1)) for kk in _FIELDS}
                self._split_sus(act, sus, [pvf] + groups[1:] + [cur], r_ev)
            # events: bracket (last test point before, first event)
            if has.any():
                rows = np.nonzero(has)[0]
                jhi = np.argmin(RE[rows], axis=1)
                Rm = np.where(before[rows], Rcat[rows], -np.inf)
                jlo = np.argmax(Rm, axis=1)
                nolo = ~np.isfinite(Rm[np.arange(rows.size), jlo])
                phi, plo = {}, {}
                for kk in _FIELDS:
                    catf = np.concatenate([g_[kk][rows] for g_ in groups], axis=1)
                    phi[kk] = catf[np.arange(rows.size), jhi]
                    plo[kk] = np.where(nolo, prev[kk][act[rows]], catf[np.arange(rows.size), jlo])
                self._set_event(act[rows], plo, phi)
                active[act[rows]] = False
            last = np.minimum(self.nsamp[act] - k0, BLOCK - 1)
            for kk in _FIELDS:
                prev[kk][act] = cur[kk][ar, last]
            k0 += BLOCK

    def _split_sus(self, act, sus, pts, r_ev):
        """Suspicious sample intervals -> their single-cell sub-segments before the event, certified one by one."""
        ii, jj = np.nonzero(sus)
        m = ii.size
        R = np.stack([np.where(p["r"][ii, jj] < r_ev[ii], p["r"][ii, jj], np.inf) for p in pts], axis=1)
        order = np.argsort(R, axis=1, kind="stable")
        F = {kk: np.take_along_axis(np.stack([p[kk][ii, jj] for p in pts], axis=1), order, axis=1)
             for kk in _FIELDS}
        F["r"] = np.take_along_axis(R, order, axis=1)
        for c in range(len(pts) - 1):
            pa = {kk: F[kk][:, c] for kk in _FIELDS}
            pb = {kk: F[kk][:, c + 1] for kk in _FIELDS}
            ok = np.isfinite(pa["r"]) & np.isfinite(pb["r"])
            bad = ok & ~self._certify(pa, pb)
            if bad.any():
                self._add_sus(act[ii[bad]], _take(pa, bad), _take(pb, bad))

    # -- stage 2: second pass on grazing chords, bracket refinement -------
    def refine(self):
        ev = self.ev
        uncertain = np.zeros(self.n, bool)
        if self.sus_ray:
            sray = np.concatenate(self.sus_ray)
            sa = _cat(self.sus_a)
            sb = _cat(self.sus_b)
        else:
            sray = np.zeros(0, np.int64)
            sa = sb = None
        for level in range(MAX_LEVELS + 12):
            # drop suspicious segments after their ray's current event
            if sray.size:
                keep = ~self.has_ev[sray] | (sb["r"] <= self.lo["r"][sray] if self.lo is not None else True)
                sray, sa, sb = sray[keep], _take(sa, keep), _take(sb, keep)
            need = np.zeros(self.n, bool)
            if self.lo is not None:
                need = self.has_ev & (self.hi["r"] - self.lo["r"] > TOL_R)
            if sray.size == 0 and not need.any():
                break
            if level >= MAX_LEVELS and sray.size:
                uncertain[sray] = True
                sray = np.zeros(0, np.int64)
                if not need.any():
                    break
            # candidates: suspicious segments and event brackets, each split in 4
            bray = np.nonzero(need)[0]
            segs_ray = np.concatenate([sray, bray])
            if segs_ray.size == 0:
                break
            A = _cat([sa, _take(self.lo, bray)]) if sray.size else _take(self.lo, bray)
            B = _cat([sb, _take(self.hi, bray)]) if sray.size else _take(self.hi, bray)
            m = segs_ray.size
            q = np.array([0.25, 0.5, 0.75])
            rq = A["r"][:, None] + (B["r"] - A["r"])[:, None] * q[None, :]
            Q = ev(np.repeat(self.s[segs_ray], 3, axis=0), np.repeat(self.l[segs_ray], 3, axis=0), rq.reshape(-1))
            pts = [A] + [{kk: Q[kk].reshape(m, 3)[:, c] for kk in _FIELDS} for c in range(3)] + [B]
            evs = np.stack([p["ev"] for p in pts[1:]], axis=1)  # (m, 4): q1, q2, q3, B
            evs[: sray.size, 3] = False  # a suspicious segment's end is known clear
            has = evs.any(axis=1)
            jfirst = np.where(has, np.argmax(evs, axis=1), 4)
            new_sray, new_sa, new_sb = [], [], []
            cand_ray, cand_lo, cand_hi = [], [], []
            for c in range(4):  # sub-segment c: pts[c] -> pts[c+1]
                pa, pb = pts[c], pts[c + 1]
                before = c < jfirst  # sub-segment entirely before the first event
                okc = before & ~self._certify(pa, pb)
                idx = np.nonzero(okc)[0]
                if idx.size:
                    new_sray.append(segs_ray[idx])
                    new_sa.append(_take(pa, idx))
                    new_sb.append(_take(pb, idx))
                idx = np.nonzero(has & (jfirst == c))[0]
                if idx.size:
                    # new bracket pts[c] (clear) -> pts[c+1] (event)
                    is_b = idx >= sray.size
                    rays = segs_ray[idx]
                    if is_b.any():  # event brackets shrink in place
                        rb_ = rays[is_b]
                        for kk in _FIELDS:
                            self.lo[kk][rb_] = pa[kk][idx[is_b]]
                            self.hi[kk][rb_] = pb[kk][idx[is_b]]
                    if (~is_b).any():
                        cand_ray.append(rays[~is_b])
                        cand_lo.append(_take(pa, idx[~is_b]))
                        cand_hi.append(_take(pb, idx[~is_b]))
            if cand_ray:  # events inside grazing chords: earlier than any bracket of their ray
                self._set_event(np.concatenate(cand_ray), _cat(cand_lo), _cat(cand_hi))
            if new_sray:
                sray = np.concatenate(new_sray)
                sa = _cat(new_sa)
                sb = _cat(new_sb)
                # a ray running along a surface within rounding would multiply its segments by 4 per
                # level: keep its MAX_SUS earliest ones and call the ray uncertain
                order = np.lexsort((sa["r"], sray))
                so = sray[order]
                start = np.r_[0, np.nonzero(so[1:] != so[:-1])[0] + 1]
                rank = np.arange(so.size) - np.repeat(start, np.diff(np.r_[start, so.size]))
                over = rank >= MAX_SUS
                if over.any():
                    uncertain[np.unique(so[over])] = True
                    keep = order[~over]
                    sray, sa, sb = sray[keep], _take(sa, keep), _take(sb, keep)
            else:
                sray = np.zeros(0, np.int64)
        return uncertain


def exhaustive_first_hit(heights, lat_first, lon_first, dlat, dlon, s, l, a=WGS84_A, f=WGS84_F,
                         interpolation="bilinear", nodata=None, step=None):
    """First hit of rays P(r) = s + r l on a geodetic DSM, by exhaustive stepping.

    Parameters
    ----------
    heights : (nrows, ncols) array, heights above the ellipsoid [units of a].
    lat_first, lon_first : geodetic latitude / east longitude of pixel (0, 0) [deg].
    dlat, dlon : grid spacing [deg]; dlat < 0 for north-up rows, dlon > 0.
    s : (N, 3) or (3,) ray origins in ECEF (body-fixed) [units of a].
    l : (N, 3) or (3,) directions in ECEF (normalised here).
    a, f : ellipsoid semi-major axis and flattening.
    interpolation : "bilinear" or "nearest" (see the contract).
    nodata : value marking no-data cells (NaN always does).
    step : sampling step along the ray [m]; default min(cell_min / 8, 1 m).

    Returns
    -------
    dict of arrays, N each: ``status`` (HIT/NO_DATA/LEFT_DSM/MISS/INSIDE of
    this module), ``r`` distance from s, ``p`` (N, 3) point, ``lat``, ``lon``
    [deg, lon in [-180, 180)], ``h`` geodetic height of p, ``H`` surface height
    there (hits), ``wall`` (bool), ``uncertain`` (bool), ``clearance`` (the
    smallest h - H over the test points before the event, a grazing measure),
    ``ntest`` (test points per ray), ``r_low_outside`` (the first low point
    outside the area, also for rays that enter later and hit: NaN if none),
    and ``step`` the step used.
    NaN for the point fields of MISS and INSIDE rays.
    """
    srf = Surface(heights, lat_first, lon_first, dlat, dlon, a, f, interpolation, nodata)
    s = np.asarray(s, dtype=np.float64)
    l = np.asarray(l, dtype=np.float64)
    if s.ndim == 1:
        s = s[None, :]
    if l.ndim == 1:
        l = l[None, :]
    if s.ndim != 2 or s.shape[1] != 3:
        raise ValueError(f"s: must have shape (N, 3), got {s.shape}")
    if l.shape != s.shape:
        if l.shape[0] == 1:
            l = np.broadcast_to(l, s.shape).copy()
        elif s.shape[0] == 1:
            s = np.broadcast_to(s, l.shape).copy()
        else:
            raise ValueError(f"l: shape {l.shape} does not match s {s.shape}")
    if not np.all(np.isfinite(s)):
        raise ValueError("s: all ray origins must be finite")
    if not np.all(np.isfinite(l)):
        raise ValueError("l: all directions must be finite")
    nl = np.linalg.norm(l, axis=1)
    if np.any(nl == 0):
        raise ValueError(f"l: zero direction for ray {int(np.argmin(nl))}")
    l = l / nl[:, None]
    if step is None:
        step = min(srf.cell_min / 8.0, STEP_MAX)
    step = float(step)
    if not (step > 0 and step <= srf.cell_min / 2.0):
        raise ValueError(f"step: must be in (0, {srf.cell_min / 2.0:.6g}] m (half the smallest cell), got {step}")
    n = s.shape[0]
    status = np.full(n, MISS, np.int64)
    r_out = np.full(n, np.nan)
    H_out = np.full(n, np.nan)
    uncertain = np.zeros(n, bool)
    clear = np.full(n, np.inf)
    ntest = np.zeros(n, np.int64)
    r_low_out = np.full(n, np.nan)
    # inside check at r = 0
    p0 = _Eval(srf)(s, l, np.zeros(n))
    inside = p0["hit"]
    status[inside] = INSIDE
    rA, rE, low = _scan_interval(srf, s, l)
    work = np.nonzero(low & ~inside)[0]
    # sort by number of samples so chunks hold similar rays
    work = work[np.argsort(rE[work] - rA[work], kind="stable")]
    for c0 in range(0, work.size, CHUNK):
        idx = work[c0:c0 + CHUNK]
        ch = _Chunk(srf, s[idx], l[idx], rA[idx], rE[idx], step)
        ch.scan()
        unc = ch.refine()
        uncertain[idx] = unc
        clear[idx] = ch.clear
        ntest[idx] = ch.ntest
        r_low_out[idx] = ch.left_r
        if ch.lo is not None:
            e = ch.has_ev
            status[idx[e]] = np.where(ch.hi["hit"][e], HIT, NO_DATA)
            r_out[idx[e]] = ch.hi["r"][e]
            H_out[idx[e]] = ch.hi["H"][e]
        else:
            e = np.zeros(idx.size, bool)
        lft = ~e & np.isfinite(ch.left_r)
        status[idx[lft]] = LEFT_DSM
        r_out[idx[lft]] = ch.left_r[lft]
    p = s + r_out[:, None] * l
    sphi, cphi, lon, h = ecef_to_geodetic_rad(p[:, 0], p[:, 1], p[:, 2], srf.a, srf.f)
    lat = np.degrees(np.arctan2(sphi, cphi))
    lon = wrap_lon(np.degrees(lon))
    wall = (status == HIT) & (H_out - h > 1e-6) if srf.nearest else np.zeros(n, bool)
    return dict(status=status, r=r_out, p=p, lat=lat, lon=lon, h=h, H=H_out, wall=wall, uncertain=uncertain,
                clearance=clear, ntest=ntest, r_low_outside=r_low_out, step=step, hmax=srf.hmax, hmin=srf.hmin)
