"""Shin & Park's Figs. 1 and 2 on a building cross-section (``planet-intersect examples buildings``).

The paper draws, as sketches, why the conventional iterative ray tracing
fails on a building DSM (Fig. 1b: it oscillates where a wall is steeper than
the ray, Fig. 1c: it converges to the ground behind a building) and how ray
following avoids it (Fig. 2). :func:`buildings` computes the same pictures
with the package's three methods on the paper's scene (:func:`paper_scene`,
flat ground so that the section shows only the buildings, "nearest": flat
roofs and vertical walls): one row of rays aimed at the cell centres of an
east-west section through the L-shaped building (25 m) and the slab (60 m),
arriving from the east at ``zenith`` degrees, and the same rays over every
``stride``-th cell of the whole scene, each method's outcome sorted against
the exact mode's first hit.

The iterates drawn for the iterative method come from a few lines here that
repeat its rule (levels h_k: the ray's crossing of height h_k, the DSM
height H there, stop when H = h_k or a level repeats; shin-park-notes,
note 13) for the drawing only; the outcome reported for every ray is the
package's own ``method="iterative"`` result.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .dsm import DSMResult, DSMStatus, GeodeticDSM, _ellipsoid_entry, intersect_dsm
from .geodetic import ecef_to_geodetic, geodetic_to_ecef
from .synthetic_dsm import _from_above, paper_scene

__all__ = ["BuildingsResult", "buildings", "plot_buildings", "OUTCOMES", "outcome"]

#: outcome classes of a ray against the exact mode's first hit (index -> label)
OUTCOMES = ("first hit", "a later surface point (behind the first hit)", "oscillates", "does not converge",
            "no hit (left the DSM, no data, missed)", "a point before the first hit")

#: distance along the ray within which a hit counts as the exact mode's (m)
SAME_HIT = 1e-3


def outcome(res: DSMResult, ref: DSMResult, tol: float = SAME_HIT) -> np.ndarray:
    """Each ray's class in :data:`OUTCOMES` (0-5) for result ``res`` against the
    first hits ``ref`` (the exact mode's). A hit where ``ref`` has none is
    class 5 (it lies before whatever ``ref`` found: nothing)."""
    st = np.asarray(res.status)
    hit, rhit = np.asarray(res.hit), np.asarray(ref.hit)
    d, dref = np.asarray(res.distance), np.asarray(ref.distance)
    out = np.full(st.shape, 4, dtype=np.int8)
    both = hit & rhit
    out[both & (np.abs(d - dref) <= tol)] = 0
    out[both & (d > dref + tol)] = 1
    out[both & (d < dref - tol)] = 5
    out[hit & ~rhit] = 5
    out[st == DSMStatus.OSCILLATION] = 2
    out[st == DSMStatus.NOT_CONVERGED] = 3
    return out


def _rays_word(n: int) -> str:
    return f"{n:,} ray" + ("" if n == 1 else "s")


@dataclass
class BuildingsResult:
    """What :func:`buildings` computed (lengths in metres, angles in degrees)."""

    scene: dict  #: :func:`paper_scene`'s dict (flat base)
    dsm: GeodeticDSM  #: its heights, "nearest"
    zenith: float  #: the rays' zenith angle at their targets (arriving from the east)
    row: int  #: the section's row (0 = north)
    x: np.ndarray  #: the section's cell centres, metres east of the scene's west edge
    section: np.ndarray  #: DSM heights along the row
    s: np.ndarray  #: the section's rays: focal points (n, 3), ECR
    l: np.ndarray  #: unit directions (n, 3)
    results: dict  #: method -> DSMResult on the section's rays
    iterates: dict  #: ray index -> (x_k, h_k, H_k) arrays of the iterative method's levels
    scene_rows: np.ndarray | None = None  #: the scene rays' target cells (row, column)
    scene_cols: np.ndarray | None = None
    scene_class: dict = field(default_factory=dict)  #: method -> OUTCOMES class of each scene ray
    scene_height: np.ndarray | None = None  #: the exact mode's hit height of each scene ray
    scene_wall: np.ndarray | None = None  #: the exact mode's hit is on a wall (the surface is taller there)

    @property
    def nscene(self) -> int:
        """Rays over the scene."""
        return 0 if self.scene_rows is None else int(self.scene_rows.size)

    @property
    def counts(self) -> dict:
        """Method -> rays per OUTCOMES class, over the scene."""
        return {m: np.bincount(c, minlength=len(OUTCOMES)).tolist() for m, c in self.scene_class.items()}

    def x_of(self, lat, lon) -> np.ndarray:
        """Metres east of the scene's west edge of points (lat, lon) (1 m cells)."""
        sc = self.scene
        return (np.asarray(lon) - sc["lon_first"]) / sc["dlon"] + 0.5


def _rays(scene: dict, rows, cols, zenith: float, altitude: float):
    """Rays arriving from the east at ``zenith`` degrees at the ground of cells (rows, cols)."""
    rows, cols = np.broadcast_arrays(np.asarray(rows), np.asarray(cols))
    rows, cols = rows.ravel(), cols.ravel()
    lat = scene["lat_first"] + rows * scene["dlat"]
    lon = scene["lon_first"] + cols * scene["dlon"]
    target = geodetic_to_ecef(lat, lon, scene["ground"][rows, cols], a=scene["a"], f=scene["f"])
    return _from_above(target, lat, lon, altitude, np.full(lat.size, float(zenith)), np.full(lat.size, np.pi / 2))


def _crossing(s, l, h, a, f) -> float:
    """Distance along the ray s + r l to its crossing of geodetic height h near the ellipsoid
    raised by h (Newton with a 1 m secant slope from there, as note 13's iteration starts)."""
    b = a * (1 - f)
    r = float(_ellipsoid_entry(s[None, :], l[None, :], a + h, 1 - (b + h) / (a + h))[0])
    for _ in range(60):
        _, _, hr = ecef_to_geodetic(s + r * l, a=a, f=f)
        _, _, h1 = ecef_to_geodetic(s + (r + 1.0) * l, a=a, f=f)
        step = (float(hr) - h) / (float(hr) - float(h1))
        r += step
        if abs(step) < 1e-9:
            break
    return r


def _iterates(dsm: GeodeticDSM, s, l, nmax: int = 8):
    """The iterative method's levels for one ray, for the drawing (see the module's docstring):
    the (lat, lon) of each level's point, the levels h_k and the DSM heights H_k there. When a
    level repeats (an oscillation), the repeated level's point closes the lists (its H is NaN)."""
    pts, levels, heights = [], [], []
    h = 0.0
    for _ in range(nmax):
        r = _crossing(s, l, h, dsm.a, dsm.f)
        lat, lon, _ = ecef_to_geodetic(s + r * l, a=dsm.a, f=dsm.f)
        pts.append((float(lat), float(lon)))
        levels.append(h)
        if any(abs(h - g) <= 1e-6 for g in levels[:-1]):
            heights.append(np.nan)                        # the level repeats: it would cycle for ever
            break
        H = float(dsm.height(lat, lon))
        heights.append(H)
        if abs(H - h) <= 1e-6:
            break
        h = H
    return pts, np.array(levels), np.array(heights)


def buildings(size: int = 640, zenith: float = 25.0, stride: int = 2, altitude: float = 685e3,
              row: int | None = None, threads: int | None = None) -> BuildingsResult:
    """The three methods on a section through the paper's buildings and over the whole scene.

    size: the scene's side in metres (1 m cells; 64 to 4096); zenith: the rays'
    zenith angle (degrees, 0 < zenith < 80), arriving from the east;
    stride: every stride-th row and column of the scene gets a ray for the
    counts; row: the section's row (default: 430 m north of the scene's
    south edge, scaled with size, through the L-shaped building and the
    slab).
    """
    if isinstance(zenith, (bool, np.bool_)) or not isinstance(zenith, (int, float, np.integer, np.floating)) or \
            not 0.0 < zenith < 80.0:
        raise ValueError(f"zenith must be a number of degrees in (0, 80), got {zenith!r}")
    zenith = float(zenith)
    if isinstance(stride, (bool, np.bool_)) or not (isinstance(stride, (int, np.integer)) and stride >= 1):
        raise ValueError(f"stride must be an integer >= 1, got {stride!r}")
    if isinstance(size, (bool, np.bool_)) or not (isinstance(size, (int, np.integer)) and 64 <= size <= 4096):
        raise ValueError(f"size must be an integer from 64 to 4096 (metres; the scene is size x size cells), "
                         f"got {size!r}")
    sc = paper_scene(int(size), base="flat")
    n = sc["heights"].shape[0]
    dsm = GeodeticDSM.from_array(sc["heights"], sc["lat_first"], sc["lon_first"], sc["dlat"], sc["dlon"],
                                 interpolation="nearest")
    if row is None:
        row = n - 1 - int(round((0.1 + 0.8 * 366.0 / 512.0) * n))
    if isinstance(row, (bool, np.bool_)) or not (isinstance(row, (int, np.integer)) and 0 <= row < n):
        raise ValueError(f"row must be an integer in [0, {n}), got {row!r}")
    cols = np.arange(n)
    s, l = _rays(sc, row, cols, zenith, altitude)
    results = {m: intersect_dsm(dsm, s, l, method=m, threads=threads) for m in ("exact", "following", "iterative")}
    ex = BuildingsResult(scene=sc, dsm=dsm, zenith=float(zenith), row=int(row), x=cols + 0.5,
                         section=sc["heights"][row].copy(), s=s, l=l, results=results, iterates={})
    # the iterates of one ray that oscillates and one that converges behind a building (Fig. 1b, 1c)
    it = outcome(results["iterative"], results["exact"])
    for k in (2, 1):
        idx = np.flatnonzero(it == k)
        if idx.size:
            i = int(idx[idx.size // 2])
            pts, levels, heights = _iterates(dsm, s[i], l[i])
            lat, lon = np.array(pts).T
            ex.iterates[i] = (ex.x_of(lat, lon), levels, heights)
    rr, cc = np.meshgrid(np.arange(0, n, stride), np.arange(0, n, stride), indexing="ij")
    ex.scene_rows, ex.scene_cols = rr.ravel(), cc.ravel()
    ex.scene_height = np.empty(ex.nscene)
    ex.scene_wall = np.empty(ex.nscene, dtype=bool)
    ex.scene_class = {m: np.empty(ex.nscene, dtype=np.int8) for m in ("exact", "following", "iterative")}
    chunk = 131_072                                      # rays at a time: a few hundred MB at most
    for k0 in range(0, ex.nscene, chunk):
        part = slice(k0, k0 + chunk)
        s2, l2 = _rays(sc, ex.scene_rows[part], ex.scene_cols[part], zenith, altitude)
        ref = intersect_dsm(dsm, s2, l2, method="exact", threads=threads)
        ex.scene_height[part] = ref.height
        ex.scene_wall[part] = np.asarray(ref.surface_height) > np.asarray(ref.height) + 1e-6
        for m in ("exact", "following", "iterative"):
            res = ref if m == "exact" else intersect_dsm(dsm, s2, l2, method=m, threads=threads)
            ex.scene_class[m][part] = outcome(res, ref)
    return ex


def following_samples(ex: BuildingsResult, i: int):
    """The paper's ray-following samples of section ray i, for the drawing: (x, h) from the
    start r_min = r_e - H_max / sin(theta_i) (eq. 3, notes 3-4) in steps D / cos(theta_i)
    (eq. 4, notes 7-8: D the smaller side of a cell at the ray's projected point) up to the
    package's reported hit (the refinement between the last two samples is not drawn)."""
    dsm, s, l = ex.dsm, ex.s[i], ex.l[i]
    fo = ex.results["following"]
    r_e = float(_ellipsoid_entry(s[None, :], l[None, :], dsm.a, dsm.f)[0])
    lat, lon, _ = ecef_to_geodetic(s + r_e * l, a=dsm.a, f=dsm.f)
    la = np.radians(float(lat))
    e2 = dsm.f * (2 - dsm.f)
    w = np.sqrt(1 - e2 * np.sin(la) ** 2)
    d = min(dsm.a * (1 - e2) / w ** 3 * np.radians(abs(dsm.dlat)), dsm.a / w * np.cos(la) * np.radians(dsm.dlon))
    lo = np.radians(float(lon))
    up = np.array([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)])
    sin_ti = -float(np.dot(l, up))
    cos_ti = np.sqrt(max(0.0, 1 - sin_ti ** 2))
    r0, dr = r_e - dsm.hmax / sin_ti, d / cos_ti
    k = np.arange(int(np.ceil((float(fo.distance[i]) - r0) / dr)) + 1)
    lat, lon, h = ecef_to_geodetic(s + (r0 + k * dr)[:, None] * l, a=dsm.a, f=dsm.f)
    return ex.x_of(lat, lon), np.asarray(h)


def plot_buildings(ex: BuildingsResult, path) -> None:
    """Four panels as one PNG: (a) iterative ray tracing on the section (Fig. 1b, 1c),
    (b) ray following (Fig. 2), (c) the exact first hits, (d) outcomes over the scene."""
    from .examples import _plt

    plt = _plt()
    fig, ax = plt.subplots(2, 2, figsize=(14, 9))
    xs = np.r_[ex.x - 0.5, ex.x[-1] + 0.5]
    prof = np.r_[ex.section, ex.section[-1]]
    top = max(float(np.max(ex.section)) + 25.0, ex.dsm.hmax + 8.0)
    tz = np.tan(np.radians(ex.zenith))
    exact = ex.results["exact"]
    xe = ex.x_of(exact.lat, exact.lon)

    def ground(a, title):
        a.fill_between(xs, prof, -5.0, step="post", color="0.8", zorder=0)
        a.step(xs, prof, where="post", color="0.3", lw=1.0, zorder=1)
        a.set(xlim=(xs[0], xs[-1]), ylim=(-5.0, top), xlabel="metres east (the section's row)",
              ylabel="height above WGS-84 (m)", title=title)

    def rays(a, idx, colour="0.6"):
        for i in idx:
            a.plot([xe[i] + (top - exact.height[i]) * tz, xe[i]], [top, exact.height[i]], color=colour, lw=0.5,
                   zorder=2)

    oc = {m: outcome(ex.results[m], exact) for m in ("following", "iterative")}
    # (a) iterative
    a = ax[0, 0]
    ground(a, f"(a) iterative ray tracing (paper's Fig. 1), rays from the east at {ex.zenith:g}°")
    it = ex.results["iterative"]
    xi = ex.x_of(it.lat, it.lon)
    for k, (mark, colour) in {0: ("o", "tab:green"), 1: ("x", "tab:red")}.items():
        m = oc["iterative"] == k
        a.plot(xi[m], it.height[m], mark, ms=3, color=colour, zorder=3,
               label=f"{OUTCOMES[k]}: {_rays_word(int(m.sum()))}")
    m = oc["iterative"] == 2
    a.plot(ex.x[m], np.zeros(int(m.sum())) - 2.5, "|", color="tab:orange", ms=6, zorder=3,
           label=f"oscillates (aimed here): {_rays_word(int(m.sum()))}")
    for i, (xk, hk, Hk) in ex.iterates.items():
        a.plot([ex.x[i] + top * tz, ex.x[i]], [top, 0.0], color="k", lw=0.8, zorder=2)   # the whole ray
        zx, zy = [xk[0]], [hk[0]]
        for k in range(len(xk)):
            if np.isfinite(Hk[k]):
                zx.append(xk[k])                      # read the DSM: H_k under the level's point
                zy.append(Hk[k])
            if k + 1 < len(xk):
                zx.append(xk[k + 1])                  # the ray's crossing of the new level h_k+1 = H_k
                zy.append(hk[k + 1])
        a.plot(zx, zy, "--", color="tab:purple", lw=1.2, zorder=4)
        a.plot(xk, hk, "s", color="tab:purple", ms=4, zorder=4)
        if oc["iterative"][i] == 1:                   # Fig. 1c: A, the surface point that hides B
            a.plot(xe[i], exact.height[i], "*", color="k", ms=9, zorder=5)
            a.annotate("A", (xe[i], exact.height[i]), xytext=(4, 4), textcoords="offset points", fontsize=9)
            a.annotate("B", (xk[-1], hk[-1]), xytext=(-10, 4), textcoords="offset points", fontsize=9)
    a.plot([], [], "--s", color="tab:purple", ms=4, label="two rays' levels: ray at h_k, DSM height H there, ...")
    a.plot([], [], "*", color="k", ms=9, label="A: the first hit that B, where the iteration stops, hides")
    a.legend(loc="upper left", fontsize=7)
    # (b) following
    a = ax[0, 1]
    fo = ex.results["following"]
    xf = ex.x_of(fo.lat, fo.lon)
    ground(a, "(b) ray following (paper's Fig. 2)")
    m0, m1 = oc["following"] == 0, oc["following"] == 1
    a.plot(xf[m0], fo.height[m0], "o", ms=2.5, color="tab:blue", zorder=3, label=f"first hit: {_rays_word(int(m0.sum()))}")
    for i in np.flatnonzero(m1):
        a.annotate("", xy=(xf[i], fo.height[i]), xytext=(xe[i], exact.height[i]),
                   arrowprops=dict(arrowstyle="->", color="tab:red", lw=0.8), zorder=4)
    a.plot([], [], "-", color="tab:red", label=f"late (arrow from the first hit): {_rays_word(int(m1.sum()))}")
    for i in ex.iterates:
        if oc["iterative"][i] == 1:                   # the same ray as Fig. 1c's: the following's steps
            xs_, hs_ = following_samples(ex, i)
            a.plot([ex.x[i] + top * tz, ex.x[i]], [top, 0.0], color="k", lw=0.8, zorder=2)
            a.plot(xs_, hs_, "o", mfc="none", color="tab:purple", ms=4, zorder=4,
                   label=f"one ray's steps from H_max (eqs. 3-5), {len(xs_)} to its hit")
    steps = np.asarray(fo.nsteps)[np.asarray(fo.hit)]
    a.legend(loc="upper left", fontsize=7, title=f"{np.mean(steps):.0f} steps a ray", title_fontsize=7)
    # (c) exact
    a = ax[1, 0]
    ground(a, "(c) exact mode: the first entry into the surface")
    rays(a, range(0, len(xe), 8))
    a.plot(xe, exact.height, ".", ms=2.5, color="k", zorder=3, label=f"first hit: {_rays_word(int(np.sum(exact.hit)))}")
    a.legend(loc="upper left", fontsize=7)
    # (d) counts over the scene
    a = ax[1, 1]
    methods = ("following", "iterative")
    colours = ("tab:green", "tab:red", "tab:orange", "tab:brown", "0.5", "tab:pink")
    left = np.zeros(len(methods))
    for k, label in enumerate(OUTCOMES):
        c = np.array([ex.counts[m][k] for m in methods])
        v = c / max(ex.nscene, 1) * 100.0
        a.barh(methods, v, left=left, height=0.45, color=colours[k], label=label)
        left += v
    for j, m in enumerate(methods):
        parts = [f"{label.split(' (')[0]}: {c:,} ({c / max(ex.nscene, 1) * 100.0:.2f} %)"
                 for label, c in zip(OUTCOMES, ex.counts[m]) if c]
        a.text(2.0, j, "\n".join(parts), va="center", fontsize=7, bbox=dict(facecolor="white", alpha=0.85, lw=0))
    a.set(xlim=(0, 100), ylim=(2.3, -0.5), xlabel="% of rays",
          title=f"(d) {ex.nscene:,} rays over the whole scene, against the exact mode's first hit")
    a.legend(loc="lower center", fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
