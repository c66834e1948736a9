"""Image simulation runs for people: Shin & Park's Fig. 4 reproduced on the
built-in scene, and the figures and files of a simulation (used by the CLI
``planet-intersect simulate``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["paper_experiment", "fig4", "write_outputs", "wrong_surface"]


def paper_experiment(size: int = 640, methods=("exact", "iterative"), zenith: float = 9.0, threads=None,
                     progress: bool = False, interpolation: str = "nearest") -> dict:
    """Shin & Park's experiment: the paper scene (:func:`synthetic_dsm.paper_scene`,
    Jacksboro base DEM, four polygon buildings, synthetic ortho-photo), seen by
    a north-bound pushbroom from the East at ``zenith`` degrees, simulated with
    each method. Returns dict(scene, dsm, ortho, sensor, sims={method: SimResult})."""
    from . import GeodeticDSM, OrthoImage, Pushbroom, simulate_image
    from .synthetic_dsm import oblique_pushbroom, paper_scene

    sc = paper_scene(size)
    dsm = GeodeticDSM.from_array(sc["heights"], sc["lat_first"], sc["lon_first"], sc["dlat"], sc["dlon"],
                                 interpolation=interpolation)
    ortho = OrthoImage.from_array(sc["ortho"], sc["lat_first"], sc["lon_first"], sc["dlat"], sc["dlon"])
    # a margin of 1/10 of the scene (64 m) keeps every ray's first iterate of the
    # conventional method (from h = 0, ~300 m x tan 9 deg = 48 m off) over the DSM
    sensor = Pushbroom(*oblique_pushbroom(sc, zenith=zenith, azimuth=90.0, margin=size // 10))
    sims = {m: simulate_image(dsm, ortho, sensor, method=m, ground=sc["ground"], occlusion=(m == "exact"),
                              threads=threads, progress=progress) for m in methods}
    return dict(scene=sc, dsm=dsm, ortho=ortho, sensor=sensor, sims=sims)


def wrong_surface(sim, truth, tol: float = 0.5) -> np.ndarray:
    """Pixels that ``sim`` gave a hit whose distance along the ray differs from
    ``truth``'s (the exact first hit) by more than ``tol`` (m): a hit on the
    wrong surface, e.g. the ground behind a roof (Shin & Park Fig. 1c) [sim note 7]."""
    both = np.asarray(sim.valid) & np.asarray(truth.valid)
    with np.errstate(invalid="ignore"):
        return both & (np.abs(np.asarray(sim.distance) - np.asarray(truth.distance)) > tol)


def fig4(exp: dict, path) -> dict:
    """The paper's Fig. 3 and 4 side by side: the ortho-photo with the building
    polygons, (a) the exact simulation, (b) the conventional iterative ray
    tracing with its non-converged pixels white (as in the paper) and its
    wrong-surface pixels outlined. Returns the counts shown in the titles."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .dsm import DSMStatus

    sc, sims = exp["scene"], exp["sims"]
    ex, it = sims["exact"], sims["iterative"]
    n_px = ex.valid.size
    nonconv = np.isin(np.asarray(it.status), (DSMStatus.OSCILLATION, DSMStatus.NOT_CONVERGED, DSMStatus.STEP_LIMIT))
    lost = ~np.asarray(it.valid) & ~nonconv
    wrong = wrong_surface(it, ex)
    counts = dict(pixels=n_px, exact_walls=int((ex.surface == 2).sum()), exact_roofs=int((ex.surface == 1).sum()),
                  occluded_ortho_pixels=int(ex.occlusion.sum()) if ex.occlusion is not None else 0,
                  iterative_not_converged=int(nonconv.sum()), iterative_wrong_surface=int(wrong.sum()),
                  iterative_left_dsm=int(lost.sum()), iterative_walls=int((it.surface == 2).sum()),
                  iterative_roofs=int((it.surface == 1).sum()))
    a = ex.display_image()
    b = it.display_image().copy()
    b[nonconv] = 255
    fig, axes = plt.subplots(1, 3, figsize=(15, 5.4))
    n = sc["ortho"].shape[0]
    axes[0].imshow(sc["ortho"])
    for bl in sc["buildings"]:
        v = bl["vertices_m"]
        axes[0].plot(np.r_[v[:, 0], v[0, 0]] - 0.5, n - np.r_[v[:, 1], v[0, 1]] - 0.5, "k-", lw=0.8)
        c = v.mean(axis=0)
        axes[0].text(c[0], n - c[1], f"{bl['height']:.0f} m", ha="center", va="center", fontsize=8)
    m = n // 10
    axes[0].add_patch(plt.Rectangle((m - 0.5, m - 0.5), n - 2 * m, n - 2 * m, fill=False, ec="w", ls="--", lw=0.8))
    axes[0].set_title("ortho-photo (1 m) and building polygons\n(dashed: the simulated scene)", fontsize=9)
    axes[1].imshow(a)
    axes[1].set_title(f"(a) exact first hits: roofs displaced, {counts['exact_walls']:,} wall pixels,\n"
                      f"{counts['occluded_ortho_pixels']:,} ortho pixels of ground occluded", fontsize=9)
    axes[2].imshow(b)
    if wrong.any():
        axes[2].contour(wrong.astype(float), levels=[0.5], colors="m", linewidths=0.6)
    axes[2].set_title(f"(b) iterative ray tracing: {counts['iterative_not_converged']:,} pixels not converged (white),\n"
                      f"{counts['iterative_wrong_surface']:,} on the wrong surface (magenta), no walls", fontsize=9)
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle("Shin & Park Fig. 4 rebuilt: north-bound pushbroom viewing from the East at 9 deg, "
                 "Jacksboro base DEM + 4 buildings", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.94))
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return counts


def write_outputs(sim, out: Path, stem: str = "simulated", netcdf: bool = True, geotiff: bool = True) -> list:
    """The files of a simulation in the folder ``out``: the image (PNG), the
    surface kinds and the occlusion mask (PNG), GeoTIFF and NetCDF in sensor
    geometry. Returns the paths written."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out)
    written = [sim.save(out / f"{stem}.png")]

    def picture(name, data, cmap, vmin, vmax, title):
        fig, ax = plt.subplots(figsize=(6, 6))
        ax.imshow(data, cmap=cmap, vmin=vmin, vmax=vmax, interpolation="nearest")
        ax.set_title(title, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
        fig.tight_layout()
        fig.savefig(out / name, dpi=100)
        plt.close(fig)
        written.append(out / name)

    picture(f"{stem}_surface.png", np.asarray(sim.surface),
            matplotlib.colors.ListedColormap(["black", "#6a8f3a", "#c0392b", "#f1c40f"]), -1.5, 2.5,
            "surface hit: black none, green ground, red roof, yellow wall")
    if sim.occlusion is not None:
        picture(f"{stem}_occlusion.png", np.where(sim.occlusion, 2, np.where(sim.footprint, 1, 0)), "gray_r", 0, 2,
                "ortho grid: grey footprint, black ground no pixel sees")
    if geotiff:
        try:
            written.append(sim.save(out / f"{stem}.tif"))
        except ImportError as exc:
            print(f"  (no GeoTIFF: {exc}; pip install 'planet-intersect[geo]')")
    if netcdf:
        try:
            written.append(sim.save(out / f"{stem}.nc"))
        except ImportError as exc:
            print(f"  (no NetCDF: {exc}; pip install 'planet-intersect[xarray]')")
    return written
