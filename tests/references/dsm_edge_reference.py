"""Brute-force first event of a ray on a geodetic DSM: the adversarial reviewer's own reference.

Written by an independent review helper (2026-12-02) from the contract
(``../shared/DESIGN.md`` section 8, the surface and its edge slack) without
reading the package's code; kept as it was written, only this header added and
the module's names left alone. It shares no code with planet_intersect:
its own geodetic conversion (Bowring's start + six iterations on latitude),
its own surface (bilinear on the closed rectangle of centres, nearest with
cells half a cell beyond the edge centres and walls taking the taller cell, the
global seam, the same 8 ulp(pi)/spacing edge slack), and a search by fixed
steps of ``ds`` then bisection to 1e-10 m. Events: a hit, a low point over
no-data, or a point below H_min outside the grid (the shin-park-notes note-15
rule); ``first_out`` is the first low (h <= H_max) point outside.

Used by tests/test_dsm_edge_rays.py for the rays that run along a grid's edge,
a wall or the polar axis.
"""
import numpy as np
A = 6378137.0; F = 1/298.257223563
B = A*(1-F); E2 = F*(2-F); EP2 = E2/(1-E2)

def ecef2geo(p, a=A, f=F):
    """Exact-ish geodetic conversion: Bowring start + Newton iterations on latitude (vectorised).
    returns lat, lon (radians), h."""
    p = np.atleast_2d(p)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    e2 = f*(2-f); b = a*(1-f)
    rho = np.hypot(x, y)
    lon = np.arctan2(y, x)
    # iterate on parametric latitude (Bowring), converges fast; then robust height
    beta = np.arctan2(z*a, rho*b)
    ep2 = e2/(1-e2)
    for _ in range(6):
        lat = np.arctan2(z + ep2*b*np.sin(beta)**3, rho - e2*a*np.cos(beta)**3)
        beta = np.arctan2((1-f)*np.sin(lat), np.cos(lat))
    s, c = np.sin(lat), np.cos(lat)
    N = a/np.sqrt(1-e2*s*s)
    h = rho*c + z*s - a*a/N   # = rho cos + z sin - N(1-e2 sin^2)
    return lat, lon, h

class Surf:
    """Contract surface: heights[nrows,ncols], degrees grid."""
    def __init__(self, H, lat0, lon0, dlat, dlon, interp, tol=None):
        self.H = np.asarray(H, float); self.nr, self.nc = self.H.shape
        self.lat0, self.lon0, self.dlat, self.dlon = lat0, lon0, dlat, dlon
        self.interp = interp; self.tol = tol
        self.tu = 8*np.spacing(np.pi)/np.radians(dlon) if tol is None else tol
        self.tv = 8*np.spacing(np.pi)/np.radians(abs(dlat)) if tol is None else tol
        self.glob = self.nc*dlon >= 360*(1-1e-12)
        d = np.isfinite(self.H); self.hmax = self.H[d].max(); self.hmin = self.H[d].min()

    def uv(self, latd, lond):
        v = (latd - self.lat0)/self.dlat
        d = np.mod(lond - self.lon0, 360.0)
        if not self.glob:
            span = (self.nc-1)*self.dlon
            d = np.where(d > span + (360-span)/2, d-360, d)
        u = d/self.dlon
        return u, v

    def height(self, latd, lond):
        """returns H (nan where nodata), code 0 ok, 1 outside, 2 nodata"""
        latd = np.asarray(latd, float); lond = np.asarray(lond, float)
        u, v = self.uv(latd, lond)
        tu_, tv_ = self.tu, self.tv
        out = np.full(u.shape, np.nan); code = np.ones(u.shape, int)
        nr, nc = self.nr, self.nc
        if self.interp == "bilinear":
            ncells = nc if self.glob else nc-1   # node columns 0..nc-1 (+ seam wrap to col 0 at u=nc)
            ins = (v >= -tv_) & (v <= nr-1+tv_) & (u >= -tu_) & (u <= ncells + tu_)
            vv = np.clip(v, 0, nr-1); uu = np.clip(u, 0, ncells)
            i = np.minimum(np.floor(vv).astype(int), nr-2); j = np.minimum(np.floor(uu).astype(int), ncells-1)
            fv = vv-i; fu = uu-j
            j1 = (j+1) % nc if self.glob else j+1
            i = np.where(ins, i, 0); j = np.where(ins, j, 0); j1 = np.where(ins, j1, 0)
            h00 = self.H[i, j]; h01 = self.H[i, j1]; h10 = self.H[i+1, j]; h11 = self.H[i+1, j1]
            val = (1-fv)*((1-fu)*h00+fu*h01) + fv*((1-fu)*h10+fu*h11)
            nod = ~(np.isfinite(h00)&np.isfinite(h01)&np.isfinite(h10)&np.isfinite(h11))
            code = np.where(ins, np.where(nod, 2, 0), 1)
            out = np.where(code == 0, val, np.nan)
            return out, code
        else:
            tv = v+0.5; tu = u+0.5
            if self.glob: tu = np.mod(tu, nc)
            ins = (tv >= -tv_) & (tv <= nr+tv_) & (tu >= -tu_) & (tu <= nc+tu_)
            tv = np.clip(tv, 0, nr); tu = np.clip(tu, 0, nc)
            best = np.full(u.shape, -np.inf); nod = np.zeros(u.shape, bool)
            # cells touched: floor(tv) and, on boundary (within tol), neighbours
            for di in (-1, 0):
                for dj in (-1, 0):
                    ii = np.floor(tv + (0 if di == 0 else 0)).astype(int)
                    jj = np.floor(tu).astype(int)
                    if di == -1:
                        onb = np.abs(tv - np.round(tv)) <= 0  # exact boundary only
                        ii = np.where(onb, np.round(tv).astype(int)-1, ii)
                    else:
                        ii = np.where(np.abs(tv-np.round(tv)) <= 0, np.round(tv).astype(int), ii)
                    if dj == -1:
                        onb = np.abs(tu - np.round(tu)) <= 0
                        jj = np.where(onb, np.round(tu).astype(int)-1, jj)
                    else:
                        jj = np.where(np.abs(tu-np.round(tu)) <= 0, np.round(tu).astype(int), jj)
                    if self.glob:
                        jj = np.mod(jj, nc)
                    else:
                        jj = np.clip(jj, 0, nc-1)
                    ii = np.clip(ii, 0, nr-1)
                    w = self.H[ii, jj]
                    nod |= ~np.isfinite(w)
                    best = np.maximum(best, np.where(np.isfinite(w), w, -np.inf))
            code = np.where(ins, np.where(nod, 2, 0), 1)
            out = np.where(code == 0, best, np.nan)
            return out, code

def ray_ref(surf, s, l, r0=0.0, r1=None, ds=0.5, a=A, f=F, maxpts=4_000_000):
    """first event along s + r l (l unit). Returns (kind, r): kind in HIT, NO_DATA, LEFT_DSM, MISS."""
    s = np.asarray(s, float); l = np.asarray(l, float); l = l/np.linalg.norm(l)
    hmax, hmin = surf.hmax, surf.hmin
    if r1 is None:
        r1 = 2*np.linalg.norm(s) + 1e3
    # coarse pass to find where h <= hmax + margin
    n = 200001
    rc = np.linspace(r0, r1, n)
    _, _, hc = ecef2geo(s + rc[:, None]*l, a, f)
    dr = rc[1]-rc[0]
    low = np.flatnonzero(hc <= hmax + dr + 1.0)
    if low.size == 0:
        return "MISS", np.nan, None
    ra = max(r0, rc[low[0]] - dr); rb = rc[min(low[-1]+1, n-1)]
    # fine pass in chunks
    def ev(r):
        p = s + np.atleast_1d(r)[:, None]*l
        la, lo, h = ecef2geo(p, a, f)
        H, code = surf.height(np.degrees(la), np.degrees(lo))
        hit = (code == 0) & (h <= H)
        nod = (code == 2) & (h <= hmax)
        outl = (code == 1) & (h <= hmax)
        below_min = h <= hmin
        return hit, nod, outl, below_min, h
    r = ra; first_out = None
    chunk = 200000
    while r < rb:
        rr = r + ds*np.arange(chunk)
        rr = rr[rr <= rb + ds]
        hit, nod, outl, bm, h = ev(rr)
        lowout = outl & bm
        evt = hit | nod | lowout
        k_evt = np.flatnonzero(evt); k_out = np.flatnonzero(outl)
        if first_out is None and k_out.size and (not k_evt.size or k_out[0] < k_evt[0]):
            first_out = rr[k_out[0]]
        if k_evt.size:
            k = k_evt[0]
            lo_ = rr[k-1] if k > 0 else rr[0]-ds
            if k == 0 and r <= ra: lo_ = max(r0, rr[0]-ds)
            hi_ = rr[k]
            for _ in range(80):
                mid = 0.5*(lo_+hi_)
                hh, nn, oo, bb, _ = ev(mid)
                if hh[0] or nn[0] or (oo[0] and bb[0]):
                    hi_ = mid
                else:
                    lo_ = mid
                if hi_ - lo_ < 1e-10: break
            hh, nn, oo, bb, _ = ev(hi_)
            if hh[0]: return ("HIT", hi_, first_out)
            if nn[0]: return ("NO_DATA", hi_, first_out)
            # below H_min outside: LEFT_DSM; the first low outside point may be in this interval
            if first_out is None: first_out = hi_
            return ("LEFT_DSM", np.nan, first_out)
        kend = len(rr)
        if bm.any() and not (bm & ~(outl | hit | nod)).any() and False:
            break
        r = rr[-1] + ds
        if len(rr) == 0: break
    if first_out is not None:
        return ("LEFT_DSM", np.nan, first_out)
    return ("MISS", np.nan, None)
